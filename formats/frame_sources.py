"""The images of one view, read frame by frame from an image, a folder of frames or a video.

The deployed matcher takes the images of each view as ``--top-images PATH`` /
``--hor-images PATH``. :func:`open_frames` turns ``PATH`` into a :class:`FrameSource`:

* a folder of frames, each file named so that it *ends* in its frame number (``0212.jpg``,
  ``frame_000212.png``, ``s00000_000001.jpg`` is frame 1). Extensions ``.jpg .jpeg .png .bmp
  .tif .tiff .webp`` in any case count; other files, sub-folders and hidden files (``.*``, e.g.
  the ``._0001.jpg`` files macOS leaves behind) are ignored. Numbers are taken as written, so a
  folder numbered from 0 serves frame 0 (MOT box frames start at 1: :func:`check_frames` then
  reports the frame the images lack);
* one image file, which serves a single frame (see :func:`open_frames` for which one);
* a video file read with OpenCV, video frame index 0 being frame 1 (MOT frame numbers are
  1-based). A file is taken for a video only when its first bytes are a known container's
  signature (:func:`video_container`: MP4/MOV, AVI, Matroska/WebM, MPEG-TS/PS, FLV, ...):
  FFmpeg would otherwise "decode" a text file as a picture of its characters. Frames are
  expected in ascending order and read sequentially; asking for an earlier frame re-opens the
  video and reads up to it again (correct, but slow).

Every problem with the user's input is a :class:`FrameSourceError` whose message is one line
naming the path (and the frame when there is one), so the command can stop with it as is.
:func:`check_frames` checks up front that a source covers the frames the boxes list, so a run fails
before doing any work.
"""

from __future__ import annotations

import abc
import bisect
import glob
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from types import TracebackType

import cv2
import numpy as np

from xvmatch.formats.image_size import ImageTooLargeError, check_image_size

__all__ = [
    "FrameImage",
    "FrameSource",
    "FrameSourceError",
    "check_frames",
    "open_frames",
    "video_container",
]

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")
"""File extensions (compared in lower case) read as images."""

_TRAILING_NUMBER = re.compile(r"(\d+)$")
_MAX_LISTED = 6  # frame numbers / ranges spelled out in a message before "..."


class FrameSourceError(ValueError):
    """Images that cannot serve the frames asked of them.

    The message is a single line that starts with the path (``"top.mp4: frame 212 is past the
    end of the video (150 frames)"``). ``path`` and ``frame`` (None for whole-source problems) are
    also kept as attributes.
    """

    def __init__(self, message: str, *, path: str | None = None, frame: int | None = None):
        super().__init__(" ".join(str(message).splitlines()))
        self.path = path
        self.frame = frame


@dataclass(frozen=True, eq=False)
class FrameImage:
    """One frame's image and where it came from.

    Equality is identity (``eq=False``), as for other records holding arrays.

    Attributes:
        frame: frame number (1-based, as in MOT files).
        image: ``(H, W, 3)`` uint8 BGR image.
        path: file the pixels came from; for a video ``"video.mp4#frame"``.
    """

    frame: int
    image: np.ndarray
    path: str

    def __post_init__(self) -> None:
        image = np.asarray(self.image)
        if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
            raise ValueError(
                f"FrameImage({self.path!r}): image must be (H, W, 3) uint8, "
                f"got {image.shape} {image.dtype}"
            )
        object.__setattr__(self, "frame", int(self.frame))
        object.__setattr__(self, "image", image)


class FrameSource(abc.ABC):
    """The images of one view, by frame number. Use as a context manager, or call :meth:`close`.

    Made by :func:`open_frames`; a new kind implements :meth:`get` and :meth:`where`, and sets the
    attributes below.

    Attributes:
        path: the path it was opened from, as given.
        frames: ascending frame numbers it holds; for a video ``1..count`` as OpenCV reports the
            count, None when OpenCV cannot tell it.
        size: ``(width, height)`` in pixels of its images.
    """

    path: str
    frames: list[int] | None
    size: tuple[int, int]

    @abc.abstractmethod
    def get(self, frame: int) -> np.ndarray:
        """The image of one frame.

        Args:
            frame: frame number (1-based for a video).

        Returns:
            ``(H, W, 3)`` uint8 BGR image, ``(H, W) == (size[1], size[0])``; the caller owns it.

        Raises:
            FrameSourceError: the frame is missing, cannot be decoded, or its size differs from
                ``size``; the message names the path and the frame.
        """

    @abc.abstractmethod
    def where(self, frame: int) -> str:
        """Where the pixels of ``frame`` come from: a file, or ``"video.mp4#frame"``."""

    def _missing(self, frame: int) -> tuple[str, str] | None:
        """None when the source has ``frame`` (or cannot tell without decoding), else what is
        missing and the context to put in parentheses: ``("no image for frame 17", "images
        cover 1-16")``."""
        frames = self.frames
        if frames is None:
            return None
        k = bisect.bisect_left(frames, frame)
        if k < len(frames) and frames[k] == frame:
            return None
        return f"no image for frame {frame}", f"images cover {_spell_ranges(frames)}"

    def _missing_error(self, frame: int, why: tuple[str, str], boxes: bool) -> FrameSourceError:
        """The one-line error for a missing frame (``boxes``: the boxes list it)."""
        what, context = why
        context = f"the boxes have it; {context}" if boxes else context
        return FrameSourceError(f"{self._label}: {what} ({context})", path=self.path, frame=frame)

    @property
    def _label(self) -> str:
        """The path as messages spell it."""
        return self.path

    def read(self, frame: int) -> FrameImage:
        """:meth:`get` with the frame number and the origin of the pixels attached."""
        return FrameImage(int(frame), self.get(frame), self.where(frame))

    def close(self) -> None:  # noqa: B027 (a hook: only a video holds anything open)
        """Release what the source holds open (a video capture); idempotent."""

    def __enter__(self) -> FrameSource:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        count = "?" if self.frames is None else len(self.frames)
        return f"{type(self).__name__}({self.path!r}, {count} frames, {_wxh(self.size)})"


# --------------------------------------------------------------------------------------------
# Helpers


def _wxh(size: tuple[int, int]) -> str:
    return f"{size[0]}x{size[1]}"


def _frame_number(name: str) -> int | None:
    """The number a file name (without its extension) ends in, or None."""
    match = _TRAILING_NUMBER.search(os.path.splitext(name)[0])
    return int(match.group(1)) if match else None


def _is_image_name(name: str) -> bool:
    return os.path.splitext(name)[1].lower() in IMAGE_EXTENSIONS


def _spell_frames(frames: Sequence[int]) -> str:
    """``"1, 2, 3"``, with the middle left out as ``...`` when there are many."""
    frames = [int(f) for f in frames]
    if len(frames) > _MAX_LISTED:
        head = ", ".join(map(str, frames[: _MAX_LISTED - 1]))
        return f"{head}, ..., {frames[-1]}"
    return ", ".join(map(str, frames))


def _spell_ranges(frames: Sequence[int]) -> str:
    """Ascending frame numbers as ranges, ``"1-16"`` or ``"1-5, 7, 9-12"``."""
    ranges: list[str] = []
    start = prev = None
    for f in frames:
        if start is not None and f == prev + 1:
            prev = f
            continue
        if start is not None:
            ranges.append(f"{start}-{prev}" if prev != start else f"{start}")
        start = prev = f
    if start is not None:
        ranges.append(f"{start}-{prev}" if prev != start else f"{start}")
    if len(ranges) > _MAX_LISTED:
        ranges = [*ranges[: _MAX_LISTED - 1], "...", ranges[-1]]
    return ", ".join(ranges)


def _decode(path: str, frame: int | None = None) -> np.ndarray:
    """Decode one image file to ``(H, W, 3)`` uint8 BGR (grey and alpha images are converted).

    Reads the bytes with numpy rather than ``cv2.imread`` so that unreadable files and
    undecodable ones get different messages, and non-ASCII paths work on every platform; an
    image whose header declares too many pixels is refused before decoding
    (:func:`~xvmatch.formats.image_size.check_image_size`).
    """
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as exc:
        raise FrameSourceError(
            f"{path}: cannot read: {exc.strerror or exc}", path=path, frame=frame
        ) from None
    try:
        check_image_size(data, path)  # a decompression bomb: refused before decoding
    except ImageTooLargeError as exc:
        raise FrameSourceError(str(exc), path=path, frame=frame) from None
    try:
        image = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    except cv2.error as exc:  # e.g. OpenCV's own pixel limit, for formats read by none above
        lines = [line for line in str(exc).splitlines() if line.strip()]
        raise FrameSourceError(f"{path}: not a decodable image ({lines[-1] if lines else exc})",
                               path=path, frame=frame) from None
    if image is None:
        which = f" (frame {frame})" if frame is not None else ""
        raise FrameSourceError(f"{path}: not a decodable image{which}", path=path, frame=frame)
    return image


def _check_size(image: np.ndarray, size: tuple[int, int], where: str, frame: int) -> np.ndarray:
    """``image`` itself, after checking it has the source's ``(width, height)``."""
    got = (int(image.shape[1]), int(image.shape[0]))
    if got != size:
        raise FrameSourceError(
            f"{where}: {_wxh(got)} but the other frames are {_wxh(size)}",
            path=where,
            frame=frame,
        )
    return image


_QUICKTIME_ATOMS = (b"ftyp", b"moov", b"mdat", b"wide", b"free", b"skip", b"pnot")
_TS_PACKET, _M2TS_PACKET = 188, 192


def video_container(head: bytes) -> str | None:
    """The video container a file's first bytes announce, or None for none known.

    FFmpeg (behind ``cv2.VideoCapture``) probes any file and decodes some that are no video at
    all (a text file as "tty" art), so a file is read as a video only when its first bytes are
    a known container's signature. ``head``: at least the first 400 bytes when the file has
    them (an MPEG transport stream is recognised by three packets' sync bytes).
    """
    if len(head) >= 8 and head[4:8] in _QUICKTIME_ATOMS:
        return "MP4/MOV"
    if head[:4] == b"RIFF" and head[8:12] in (b"AVI ", b"AVIX"):
        return "AVI"
    if head[:4] == b"\x1a\x45\xdf\xa3":
        return "Matroska/WebM"
    if head[:4] == b"\x00\x00\x01\xba":
        return "MPEG-PS"
    if head[:4] == b"\x00\x00\x01\xb3":
        return "MPEG video"
    if head[:4] == b"\x00\x00\x00\x01" or head[:3] == b"\x00\x00\x01":
        return "H.264/H.265 stream"
    for step, first in ((_TS_PACKET, 0), (_M2TS_PACKET, 4)):
        syncs = [first + k * step for k in range(3)]
        if len(head) > syncs[-1] and all(head[i] == 0x47 for i in syncs):
            return "MPEG-TS"
    if head[:3] == b"FLV":
        return "FLV"
    if head[:8] == b"\x30\x26\xb2\x75\x8e\x66\xcf\x11":
        return "ASF/WMV"
    if head[:4] == b"OggS":
        return "Ogg"
    if head[:9] == b"YUV4MPEG2":
        return "Y4M"
    if head[:6] in (b"GIF87a", b"GIF89a"):
        return "GIF"
    if head[:2] == b"\xff\xd8":
        return "Motion JPEG"
    return None


def _sniff_video(path: str) -> str:
    """The container of a file to be read as a video; a one-line error when it has none."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(_M2TS_PACKET * 3)
    except OSError as exc:
        raise FrameSourceError(f"{path}: cannot read: {exc.strerror or exc}", path=path) from None
    container = video_container(head)
    if container is None:
        raise FrameSourceError(
            f"{path}: neither an image nor a video OpenCV can read (no image extension "
            f"({' '.join(IMAGE_EXTENSIONS)}) and no known video container: MP4/MOV, AVI, "
            "Matroska/WebM, MPEG-TS/PS, FLV, ASF/WMV, Ogg, Y4M, GIF, Motion JPEG)",
            path=path,
        )
    return container


# --------------------------------------------------------------------------------------------
# The three kinds of source


class _ImageSource(FrameSource):
    """One image file serving one frame."""

    def __init__(self, path: str, frame: int):
        self.path = path
        self.frame = int(frame)
        self.frames = [self.frame]
        self._image = _decode(path, self.frame)
        self.size = (int(self._image.shape[1]), int(self._image.shape[0]))

    def get(self, frame: int) -> np.ndarray:
        frame = int(frame)
        if (why := self._missing(frame)) is not None:
            raise self._missing_error(frame, why, boxes=False)
        return self._image.copy()

    def where(self, frame: int) -> str:
        return self.path

    def _missing(self, frame: int) -> tuple[str, str] | None:
        if frame == self.frame:
            return None
        return f"no image for frame {frame}", f"the image serves frame {self.frame}"


class _FolderSource(FrameSource):
    """A folder of image files named by frame number; decodes each file when asked for it."""

    def __init__(self, path: str, pattern: bool = False):
        self.path = path
        self._pattern = pattern
        files: dict[int, str] = {}
        images = 0
        if pattern:
            names = sorted(glob.glob(path))
        else:
            try:
                names = [e.path for e in sorted(os.scandir(path), key=lambda e: e.name)]
            except OSError as exc:
                raise FrameSourceError(
                    f"{self._label}: cannot list the folder: {exc.strerror or exc}", path=path
                ) from None
        for file in names:
            name = os.path.basename(file)
            if name.startswith(".") or not _is_image_name(name) or not os.path.isfile(file):
                continue
            images += 1
            frame = _frame_number(name)
            if frame is None:
                continue
            if frame in files:
                raise FrameSourceError(
                    f"{self._label}: {files[frame]} and {file} both give frame {frame} "
                    "(keep one file per frame)",
                    path=path,
                    frame=frame,
                )
            files[frame] = file
        if not files:
            found = (f"its {images} image files have none" if images
                     else f"it holds no {'/'.join(IMAGE_EXTENSIONS)} file")
            raise FrameSourceError(
                f"{self._label}: no image file whose name ends in a frame number ({found})",
                path=path,
            )
        self._files = files
        self.frames = sorted(files)
        first = _decode(files[self.frames[0]], self.frames[0])
        self.size = (int(first.shape[1]), int(first.shape[0]))

    def get(self, frame: int) -> np.ndarray:
        frame = int(frame)
        file = self._files.get(frame)
        if file is None:
            raise self._missing_error(frame, self._missing(frame), boxes=False)
        return _check_size(_decode(file, frame), self.size, file, frame)

    def where(self, frame: int) -> str:
        return self._files.get(int(frame), self._label)

    @property
    def _label(self) -> str:
        if self._pattern:
            return self.path
        return os.path.join(self.path, "")  # "frames/": reads as a folder in messages


class _VideoSource(FrameSource):
    """A video read sequentially with OpenCV; frame 1 is the video's first frame."""

    def __init__(self, path: str):
        self.path = path
        self.container = _sniff_video(path)
        self._capture: cv2.VideoCapture | None = None
        self._next = 1  # frame number the next read() of the capture returns
        self._last: tuple[int, np.ndarray] | None = None
        self._closed = False
        self.frames: list[int] | None = None
        self._open()
        try:
            first = self._grab_frame(1)
        except FrameSourceError:
            self.close()
            raise FrameSourceError(
                f"{path}: neither an image nor a video OpenCV can read ({self.container} "
                "container, but no frame decodes: damaged, or a codec this OpenCV build lacks)",
                path=path,
            ) from None
        self._last = (1, first)
        self.size = (int(first.shape[1]), int(first.shape[0]))
        count = int(self._capture.get(cv2.CAP_PROP_FRAME_COUNT))
        self.frames = list(range(1, count + 1)) if count > 0 else None

    def _open(self) -> None:
        if self._capture is not None:
            self._capture.release()
        self._capture = cv2.VideoCapture(self.path)
        self._next = 1
        if not self._capture.isOpened():
            self._capture.release()
            raise FrameSourceError(
                f"{self.path}: neither an image nor a video OpenCV can read ("
                f"{self.container} container, but OpenCV cannot open it: damaged, or a "
                "container this OpenCV build lacks)", path=self.path
            )

    def _grab_frame(self, frame: int) -> np.ndarray:
        """Advance the capture to ``frame`` (>= the cursor) and decode it."""
        capture = self._capture
        while self._next < frame and capture.grab():
            self._next += 1
        ok, image = capture.read() if self._next == frame else (False, None)
        if not ok or image is None:
            raise self._past_end(frame)
        self._next += 1
        if image.ndim == 2:
            image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        elif image.shape[2] == 4:
            image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
        return image

    def _past_end(self, frame: int) -> FrameSourceError:
        read = self._next - 1  # frames the capture gave since it was opened
        reported = None if self.frames is None else len(self.frames)
        if reported is not None and read < reported:
            what = (f"{self.path}: frame {frame} could not be read (the video stops after "
                    f"frame {read} although it reports {reported} frames)")
        else:
            what = f"{self.path}: frame {frame} is past the end of the video ({read} frames)"
        return FrameSourceError(what, path=self.path, frame=frame)

    def get(self, frame: int) -> np.ndarray:
        frame = int(frame)
        if self._closed:
            raise ValueError(f"{self.path}: get({frame}) after close()")
        if frame < 1:
            raise self._missing_error(frame, self._missing(frame), boxes=False)
        if self._last is not None and self._last[0] == frame:
            return self._last[1].copy()
        if frame < self._next:
            self._open()  # backwards: start over
        image = _check_size(self._grab_frame(frame), self.size, self.where(frame), frame)
        self._last = (frame, image)
        return image.copy()

    def where(self, frame: int) -> str:
        return f"{self.path}#{int(frame)}"

    def _missing(self, frame: int) -> tuple[str, str] | None:
        if frame < 1:
            return f"no frame {frame} in a video", "video frames are numbered from 1"
        if self.frames is not None and frame > len(self.frames):
            n = len(self.frames)
            return f"frame {frame} is past the end of the video", f"the video has {n} frames"
        return None

    def close(self) -> None:
        if self._capture is not None:
            self._capture.release()
            self._capture = None
        self._last = None
        self._closed = True


# --------------------------------------------------------------------------------------------
# Entry points


def open_frames(
    path: str | os.PathLike, box_frames: Sequence[int] | None = None
) -> FrameSource:
    """Open the images of one view, choosing the kind of source by what ``path`` is.

    A folder is read as frames named by number, a file with an image extension as one image,
    and any other file as a video when its first bytes are a known video container's
    (:func:`video_container`; see the module docstring). A glob pattern (quoted on the
    command line, e.g. ``'data/images/top/s00003_*.jpg'``) is read like a folder holding just
    the files it matches.

    One image serves a single frame: the number its file name ends in when that number is among
    ``box_frames``; otherwise the only frame of ``box_frames`` when it lists exactly one; otherwise
    frame 1 when ``box_frames`` is None (or empty). It is an error for the boxes to list several
    frames none of which the name gives.

    Args:
        path: ``--top-images`` / ``--hor-images`` value.
        box_frames: frame numbers the boxes of this view list; used only for a single image.

    Returns:
        An open :class:`FrameSource`; close it (or use ``with``) when done.

    Raises:
        FrameSourceError: missing path, a folder without numbered images or with two files for
            one frame, an undecodable image, a file OpenCV cannot read, or a single image that
            cannot serve the boxes' frames.
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        return _FolderSource(path)
    if not os.path.exists(path) and glob.has_magic(path):
        return _FolderSource(path, pattern=True)
    if not os.path.exists(path):
        raise FrameSourceError(f"{path}: no such file or folder", path=path)
    if _is_image_name(path):
        return _ImageSource(path, _single_image_frame(path, box_frames))
    return _VideoSource(path)


def _single_image_frame(path: str, box_frames: Sequence[int] | None) -> int:
    """The frame one image serves (rules in :func:`open_frames`)."""
    wanted = sorted({int(f) for f in box_frames}) if box_frames is not None else []
    named = _frame_number(os.path.basename(path))
    if named is not None and named in wanted:
        return named
    if len(wanted) == 1:
        return wanted[0]
    if not wanted:
        return 1
    raise FrameSourceError(
        f"{path}: one image serves one frame, but the boxes list {len(wanted)} frames "
        f"({_spell_frames(wanted)})",
        path=path,
    )


def check_frames(source: FrameSource, wanted: Sequence[int]) -> None:
    """Fail early when ``source`` lacks a frame the boxes list.

    For a folder or an image a frame must be among ``source.frames``; for a video, within
    ``1..count`` when OpenCV reports the count (a video whose count is unknown is only checked
    for frames below 1). Nothing is decoded.

    Args:
        source: an open source.
        wanted: frame numbers the boxes list, checked in the order given.

    Raises:
        FrameSourceError: naming the first wanted frame the source does not have.
    """
    for frame in wanted:
        frame = int(frame)
        if (why := source._missing(frame)) is not None:
            raise source._missing_error(frame, why, boxes=True)
