"""Calibrated cameras of a sequence pair: one camera file for every frame, or one per frame.

``--cameras PATH`` takes a camera file (:mod:`xvmatch.formats.camera_io`, cameras named
``top`` and ``ego``) when both cameras are fixed, e.g. a single image pair or a horizontal camera
on a tripod; or a folder of camera files whose names end in the frame number
(``000212.json``), for a moving egocentric camera.
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from xvmatch.core.folder_marker import record_own_files, remove_own_files
from xvmatch.core.input_files import InputFileError, check_input_file
from xvmatch.core.output_paths import claim_folder
from xvmatch.formats.camera_io import CameraFileError, load_cameras, save_cameras
from xvmatch.geometry.camera import FrameCameras

__all__ = ["CameraFrames", "ego_camera_size", "given_hor_sizes", "open_cameras",
           "save_camera_frames", "write_camera_frames"]

_TRAILING_NUMBER = re.compile(r"(\d+)$")


@dataclass(frozen=True)
class CameraFrames:
    """The cameras of every frame: ``static`` for all of them, or ``per_frame``.

    Attributes:
        path: the file or folder they were read from.
        static: the cameras of every frame, or None.
        per_frame: ``{frame: cameras}`` when they change from frame to frame.
        files: ``{frame: camera file}`` of ``per_frame``.
    """

    path: str
    static: FrameCameras | None = None
    per_frame: dict[int, FrameCameras] = field(default_factory=dict)
    files: dict[int, str] = field(default_factory=dict)

    def get(self, frame: int) -> FrameCameras:
        """The cameras of ``frame``.

        Raises:
            CameraFileError: no camera file for the frame.
        """
        if self.static is not None:
            return self.static
        cams = self.per_frame.get(int(frame))
        if cams is None:
            raise CameraFileError(f"{self.path}: no camera file for frame {frame}")
        return cams

    def all(self) -> list[tuple[str, FrameCameras]]:
        """Every set of cameras held, with the file it was read from (for checks)."""
        if self.static is not None:
            return [(self.path, self.static)]
        return [(self.files[f], c) for f, c in sorted(self.per_frame.items())]


def _pair(path: str | os.PathLike) -> FrameCameras:
    """The ``top`` and ``ego`` cameras of the camera file ``path``, a regular file: a FIFO, a
    device or a folder named like one is refused at once, never read (it would block or never
    end)."""
    try:
        check_input_file(path)
    except InputFileError as exc:
        raise CameraFileError(str(exc)) from None
    cams = load_cameras(path, required=("top", "ego"))
    return FrameCameras(cams["top"], cams["ego"])


def open_cameras(path: str | os.PathLike, frames: Sequence[int] = ()) -> CameraFrames:
    """Read ``--cameras PATH`` (see the module docstring).

    Args:
        path: a camera file or a folder of per-frame camera files.
        frames: frames that need cameras (a folder must hold a file for each).

    Raises:
        CameraFileError: a missing path, a malformed file (naming it and the field), a folder
            without numbered ``.json`` files, two files for one frame, or a wanted frame without
            a file.
    """
    name = os.fspath(path)
    if not os.path.lexists(name):
        raise CameraFileError(f"{name}: no such camera file or folder")
    if not os.path.isdir(name):
        return CameraFrames(name, static=_pair(name))
    per_frame: dict[int, FrameCameras] = {}
    files: dict[int, str] = {}
    for entry in sorted(Path(name).glob("*.json")):
        match = _TRAILING_NUMBER.search(entry.stem)
        if match is None or entry.name.startswith("."):
            continue
        frame = int(match.group(1))
        if frame in files:
            raise CameraFileError(f"{name}: {files[frame]} and {entry} both give frame {frame}")
        files[frame] = os.fspath(entry)
        per_frame[frame] = _pair(entry)
    if not per_frame:
        raise CameraFileError(f"{name}: no camera file whose name ends in a frame number "
                              "(e.g. 000001.json)")
    missing = [f for f in sorted(set(int(f) for f in frames)) if f not in per_frame]
    if missing:
        raise CameraFileError(f"{name}: no camera file for frame {missing[0]} (the boxes have "
                              f"it; {len(missing)} frame(s) missing)")
    return CameraFrames(name, per_frame=per_frame, files=files)


def save_camera_frames(cameras: CameraFrames, path: str | os.PathLike) -> list[Path]:
    """Write ``cameras`` where :func:`open_cameras` reads them back the same: a camera file for
    ``static`` ones; else, in the existing folder ``path``, one file per frame under the name of
    the file it was read from. Each file is written atomically (a round trip is exact).

    Returns:
        The files written.
    """
    if cameras.static is not None:
        save_cameras(path, {"top": cameras.static.top, "ego": cameras.static.hor})
        return [Path(path)]
    written = []
    for frame, cams in sorted(cameras.per_frame.items()):
        name = Path(cameras.files[frame]).name if frame in cameras.files else f"{frame:06d}.json"
        written.append(Path(path) / name)
        save_cameras(written[-1], {"top": cams.top, "ego": cams.hor})
    return written


def write_camera_frames(cameras: CameraFrames, path: str | os.PathLike, owner: str,
                        option: str) -> int | None:
    """Write ``cameras`` in the form they were read in (:func:`save_camera_frames`): a camera
    file, or a folder of per-frame files that ``owner`` claims (new, empty or its own,
    :func:`~xvmatch.core.output_paths.claim_folder`; ``option`` names it in messages). A folder
    it made before loses the camera files it wrote of frames ``cameras`` has not: they would be
    read with the new ones; a file the user put there is kept.

    Returns:
        How many camera files the folder got, or None for a camera file.
    """
    if cameras.static is not None:
        save_camera_frames(cameras, path)
        return None
    folder = claim_folder(path, owner, option)
    written = [p.name for p in save_camera_frames(cameras, folder)]
    remove_own_files(folder, owner, keep=written)
    record_own_files(folder, owner, written)
    return len(written)


def ego_camera_size(cameras: str | os.PathLike) -> tuple[tuple[int, int], str]:
    """The horizontal image size that the ego cameras of ``cameras`` (a camera file or folder)
    give, and where it comes from (for :func:`~xvmatch.formats.box_image_size.resolve_size`);
    one size for all of them, or an error asking for ``--image-size``.

    Raises:
        ValueError: the ego cameras have several image sizes (one line naming ``cameras``).
    """
    sizes = {tuple(c.hor.image_size) for _, c in open_cameras(cameras).all()}
    if len(sizes) != 1:
        raise ValueError(f"{cameras}: the ego cameras have several image sizes "
                         f"({', '.join(f'{w}x{h}' for w, h in sorted(sizes))}); pass "
                         "--image-size")
    return sizes.pop(), f"the camera files {cameras}"


def given_hor_sizes(image_size: tuple[int, int] | None, hor_images: str | None,
                    cameras: str | None, box_frames: Sequence[int]
                    ) -> list[tuple[tuple[int, int], str]]:
    """The horizontal image sizes a run's inputs give, each with where it comes from (for
    :func:`~xvmatch.formats.box_image_size.resolve_size`, which wants them to agree):
    ``image_size`` (``--image-size``), the horizontal images (opened at ``box_frames``) or, with
    none, the ego cameras of ``cameras`` (:func:`ego_camera_size`; with images, each camera file
    is checked against them by :mod:`~xvmatch.inference.matching.learned_pipeline`)."""
    given = [] if image_size is None else [(tuple(image_size), "--image-size")]
    if hor_images:
        from xvmatch.formats.frame_sources import open_frames  # OpenCV: only with images

        with open_frames(hor_images, box_frames=box_frames) as source:
            given.append((tuple(source.size), f"the horizontal images {hor_images}"))
    elif cameras:
        given.append(ego_camera_size(cameras))
    return given
