"""Tests of reading a view's images by frame number (xvmatch.formats.frame_sources)."""

from __future__ import annotations

import os
import re
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.formats import frame_sources
from xvmatch.formats.frame_sources import (
    FrameImage,
    FrameSource,
    FrameSourceError,
    check_frames,
    open_frames,
    video_container,
)

W, H = 40, 30  # (width, height) of the test images


def _image(frame: int, size: tuple[int, int] = (W, H)) -> np.ndarray:
    """A distinct, reproducible (H, W, 3) uint8 image for ``frame``."""
    return np.random.default_rng(frame).integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)


def _smooth(frame: int, size: tuple[int, int] = (W, H)) -> np.ndarray:
    """A smooth image (gradient plus a per-frame level) that lossy codecs keep close; frames
    differ by 20 grey levels so each decoded frame is nearest to its own original."""
    x = np.linspace(0, 60, size[0])[None, :, None]
    y = np.linspace(0, 40, size[1])[:, None, None]
    level = 20.0 * (frame % 8) + np.array([0.0, 10.0, 20.0])
    return np.clip(x + y + level, 0, 255).astype(np.uint8)


def _write(path: Path, image: np.ndarray) -> Path:
    assert cv2.imwrite(str(path), image), path
    return path


def _folder(tmp_path: Path, frames, pattern: str = "{:04d}.png", image=_image) -> Path:
    folder = tmp_path / "frames"
    folder.mkdir(exist_ok=True)
    for f in frames:
        _write(folder / pattern.format(f), image(f))
    return folder


def _message(path: Path | str, rest: str) -> str:
    """Regex for the whole one-line message ``"<path>: <rest>"``."""
    return "^" + re.escape(f"{path}: {rest}") + "$"


def _close(a: np.ndarray, b: np.ndarray, tol: float) -> bool:
    return a.shape == b.shape and float(np.abs(a.astype(float) - b).mean()) < tol


def test_public_names():
    assert set(frame_sources.__all__) == {
        "FrameImage", "FrameSource", "FrameSourceError", "check_frames", "open_frames",
        "video_container",
    }
    assert issubclass(FrameSourceError, ValueError)


# --------------------------------------------------------------------------------------------
# Folders


def test_folder_png_exact_pixels_size_and_frames(tmp_path):
    folder = _folder(tmp_path, [3, 1, 2, 10])
    with open_frames(folder) as source:
        assert isinstance(source, FrameSource)
        assert source.path == str(folder)
        assert source.frames == [1, 2, 3, 10]
        assert source.size == (W, H)
        for f in source.frames:
            image = source.get(f)
            assert image.dtype == np.uint8 and image.shape == (H, W, 3)
            np.testing.assert_array_equal(image, _image(f))
        record = source.read(10)
        assert isinstance(record, FrameImage)
        assert record.frame == 10 and record.path == str(folder / "0010.png")
        np.testing.assert_array_equal(record.image, _image(10))
        check_frames(source, [1, 2, 3, 10])  # all there: no error


def test_folder_jpeg_pixels_are_close(tmp_path):
    folder = _folder(tmp_path, [1, 2], pattern="{:04d}.jpg", image=_smooth)
    with open_frames(folder) as source:
        for f in (1, 2):
            assert _close(source.get(f), _smooth(f), tol=3.0)


@pytest.mark.parametrize(
    ("name", "frame"),
    [
        ("0212.jpg", 212),
        ("frame_000212.png", 212),
        ("s00000_000001.jpg", 1),
        ("7.JPEG", 7),
        ("cam2-0042.Png", 42),
        ("x_15.bmp", 15),
        ("x_16.TIF", 16),
        ("x_17.tiff", 17),
        ("x_18.webp", 18),
    ],
)
def test_folder_frame_number_is_the_number_the_name_ends_in(tmp_path, name, frame):
    folder = tmp_path / "frames"
    folder.mkdir()
    _write(folder / name, _image(frame))
    with open_frames(folder) as source:
        assert source.frames == [frame]
        assert source.read(frame).path == str(folder / name)


def test_folder_ignores_other_files_hidden_files_and_subfolders(tmp_path):
    folder = _folder(tmp_path, [1, 2])
    (folder / "notes.txt").write_text("0003")
    (folder / "boxes_0004.csv").write_text("1,1,0,0,1,1")
    _write(folder / "thumbnail.png", _image(99))  # an image, but no frame number
    (folder / "._0001.jpg").write_bytes(b"macOS resource fork")  # would duplicate frame 1
    (folder / "0005.png").mkdir()  # a sub-folder named like a frame
    with open_frames(folder) as source:
        assert source.frames == [1, 2]


def test_folder_grey_and_alpha_images_come_back_bgr(tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    grey = _image(1)[:, :, 0]
    _write(folder / "0001.png", grey)
    bgra = np.dstack([_image(2), np.full((H, W), 255, np.uint8)])
    _write(folder / "0002.png", bgra)
    with open_frames(folder) as source:
        np.testing.assert_array_equal(source.get(1), np.dstack([grey] * 3))
        np.testing.assert_array_equal(source.get(2), bgra[:, :, :3])


def test_folder_frame_of_another_size(tmp_path):
    folder = _folder(tmp_path, [1, 2])
    _write(folder / "0009.png", _image(9, size=(64, 48)))
    with open_frames(folder) as source:
        assert source.size == (W, H)  # from the first frame
        with pytest.raises(FrameSourceError, match=_message(
            folder / "0009.png", f"64x48 but the other frames are {W}x{H}"
        )) as info:
            source.get(9)
        assert info.value.frame == 9


def test_folder_undecodable_file(tmp_path):
    folder = _folder(tmp_path, [1, 2, 4])
    (folder / "0003.jpg").write_bytes(b"\x00garbage, not a JPEG" * 10)
    with open_frames(folder) as source:  # only the first file is decoded on opening
        assert source.frames == [1, 2, 3, 4]
        np.testing.assert_array_equal(source.get(4), _image(4))
        with pytest.raises(FrameSourceError, match=_message(
            folder / "0003.jpg", "not a decodable image (frame 3)"
        )):
            source.get(3)


def test_folder_whose_first_file_is_undecodable_fails_on_opening(tmp_path):
    folder = _folder(tmp_path, [2])
    (folder / "0001.png").write_bytes(b"")
    with pytest.raises(FrameSourceError, match=_message(
        folder / "0001.png", "not a decodable image (frame 1)"
    )):
        open_frames(folder)


def test_folder_missing_frame(tmp_path):
    folder = _folder(tmp_path, range(1, 17))
    with open_frames(folder) as source:
        with pytest.raises(FrameSourceError, match=_message(
            f"{folder}/", "no image for frame 17 (images cover 1-16)"
        )) as info:
            source.get(17)
        assert info.value.frame == 17
        with pytest.raises(FrameSourceError, match=_message(
            f"{folder}/", "no image for frame 17 (the boxes have it; images cover 1-16)"
        )):
            check_frames(source, [1, 5, 17, 18])  # the first missing one is named


def test_folder_gaps_are_spelled_as_ranges(tmp_path):
    folder = _folder(tmp_path, [1, 2, 3, 5, 7, 8])
    with open_frames(folder) as source, pytest.raises(
        FrameSourceError, match=re.escape("(the boxes have it; images cover 1-3, 5, 7-8)")
    ):
        check_frames(source, [4])


def test_folder_duplicate_frame_numbers(tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    _write(folder / "1.jpg", _image(1))
    _write(folder / "0001.png", _image(1))
    with pytest.raises(FrameSourceError, match=_message(
        f"{folder}/",
        f"{folder / '0001.png'} and {folder / '1.jpg'} both give frame 1 (keep one file per frame)",
    )):
        open_frames(folder)


@pytest.mark.parametrize("content", ["empty", "text", "unnumbered"])
def test_folder_without_numbered_images(tmp_path, content):
    folder = tmp_path / "frames"
    folder.mkdir()
    if content == "text":
        (folder / "0001.txt").write_text("x")
    if content == "unnumbered":
        _write(folder / "first.png", _image(1))
    with pytest.raises(
        FrameSourceError,
        match="^" + re.escape(f"{folder}/: no image file whose name ends in a frame number ("),
    ):
        open_frames(folder)


@settings(max_examples=20, deadline=None)
@given(data=st.data(), frames=st.sets(st.integers(0, 10**7), min_size=1, max_size=8))
def test_folder_frames_are_the_sorted_numbers_whatever_the_prefix(data, frames):
    png = cv2.imencode(".png", _image(0, size=(4, 3)))[1].tobytes()
    prefixes = st.from_regex(r"[A-Za-z0-9_-]{0,8}", fullmatch=True).filter(
        lambda p: not p[-1:].isdigit()  # else the prefix's digits would join the number
    )
    extensions = st.sampled_from([".png", ".PNG", ".jpg", ".Jpeg", ".bmp", ".tif", ".webp"])
    with tempfile.TemporaryDirectory() as tmp:
        for f in frames:
            width = len(str(f)) + data.draw(st.integers(0, 6), label="padding")
            name = f"{data.draw(prefixes, label='prefix')}{f:0{width}d}{data.draw(extensions)}"
            Path(tmp, name).write_bytes(png)
        with open_frames(tmp) as source:
            assert source.frames == sorted(frames)
            assert source.size == (4, 3)


# --------------------------------------------------------------------------------------------
# Single images


def _with_orientation(jpeg: bytes, orientation: int) -> bytes:
    """``jpeg`` with an EXIF segment holding only the orientation tag (0x0112), as a phone
    writes a photo it stored sideways."""
    tiff = (b"MM\x00\x2a\x00\x00\x00\x08" + b"\x00\x01"  # big-endian header, one entry
            + b"\x01\x12\x00\x03\x00\x00\x00\x01" + orientation.to_bytes(2, "big")
            + b"\x00\x00" + b"\x00\x00\x00\x00")  # SHORT value, padding, no next IFD
    body = b"Exif\x00\x00" + tiff
    return jpeg[:2] + b"\xff\xe1" + (len(body) + 2).to_bytes(2, "big") + body + jpeg[2:]


def test_a_photo_stored_sideways_is_read_upright(tmp_path):
    """An EXIF orientation tag is applied, as photo viewers (and box tools) show the picture:
    orientation 6 (turn 90 degrees clockwise) swaps the width and height."""
    ok, jpeg = cv2.imencode(".jpg", _smooth(1), [cv2.IMWRITE_JPEG_QUALITY, 100])
    assert ok
    path = tmp_path / "photo.jpg"
    path.write_bytes(_with_orientation(jpeg.tobytes(), 6))
    with open_frames(path) as source:
        assert source.size == (H, W)
        upright = cv2.rotate(cv2.imdecode(jpeg, cv2.IMREAD_COLOR), cv2.ROTATE_90_CLOCKWISE)
        np.testing.assert_array_equal(source.get(1), upright)


def test_single_image_exact_pixels(tmp_path):
    path = _write(tmp_path / "top.png", _image(5))
    with open_frames(path) as source:
        assert source.frames == [1] and source.size == (W, H)
        np.testing.assert_array_equal(source.get(1), _image(5))
        assert source.read(1).path == str(path)


@pytest.mark.parametrize(
    ("name", "box_frames", "frame"),
    [
        ("view_0212.png", [100, 212, 300], 212),  # the name's number, being among the boxes'
        ("view_0212.png", [7], 7),  # the boxes' only frame, whatever the name
        ("top.png", [3, 3, 3], 3),  # one frame, listed once per box
        ("view_0212.png", None, 1),  # no boxes given: frame 1
        ("top.png", [], 1),
    ],
)
def test_single_image_frame_rules(tmp_path, name, box_frames, frame):
    path = _write(tmp_path / name, _image(1))
    with open_frames(path, box_frames) as source:
        assert source.frames == [frame]
        np.testing.assert_array_equal(source.get(frame), _image(1))
        check_frames(source, [frame])


def test_single_image_cannot_serve_several_frames(tmp_path):
    path = _write(tmp_path / "top.jpg", _smooth(1))
    with pytest.raises(FrameSourceError, match=_message(
        path, "one image serves one frame, but the boxes list 3 frames (1, 2, 3)"
    )):
        open_frames(path, [3, 1, 2, 1])
    with pytest.raises(FrameSourceError, match=_message(
        path, "one image serves one frame, but the boxes list 500 frames (1, 2, 3, 4, 5, ..., 500)"
    )):
        open_frames(path, range(1, 501))


def test_single_image_other_frame(tmp_path):
    path = _write(tmp_path / "top.jpg", _smooth(1))
    with open_frames(path, [4]) as source:
        assert _close(source.get(4), _smooth(1), tol=3.0)
        with pytest.raises(FrameSourceError, match=_message(
            path, "no image for frame 5 (the image serves frame 4)"
        )):
            source.get(5)
        with pytest.raises(FrameSourceError, match=_message(
            path, "no image for frame 5 (the boxes have it; the image serves frame 4)"
        )):
            check_frames(source, [4, 5])


def test_single_image_undecodable(tmp_path):
    path = tmp_path / "top.JPG"
    path.write_bytes(b"not an image")
    with pytest.raises(FrameSourceError,
                       match=_message(path, "not a decodable image (frame 1)")):
        open_frames(path)


def test_get_returns_a_copy_the_caller_may_draw_on(tmp_path):
    path = _write(tmp_path / "top.png", _image(1))
    with open_frames(path) as source:
        source.get(1)[:] = 0
        np.testing.assert_array_equal(source.get(1), _image(1))


# --------------------------------------------------------------------------------------------
# Path errors


def test_missing_path(tmp_path):
    path = tmp_path / "nope.mp4"
    with pytest.raises(FrameSourceError, match=_message(path, "no such file or folder")) as info:
        open_frames(path)
    assert info.value.path == str(path)


@pytest.mark.parametrize("content", [b"", b"\x00\x01garbage" * 100])
def test_file_opencv_cannot_read(tmp_path, content):
    path = tmp_path / "x.bin"
    path.write_bytes(content)
    with pytest.raises(
        FrameSourceError,
        match="^" + re.escape(f"{path}: neither an image nor a video OpenCV can read"),
    ):
        open_frames(path)


def test_a_text_file_is_not_taken_for_a_video(tmp_path):
    # FFmpeg "decodes" text (as tty art): without the container check this opened as a video.
    path = tmp_path / "notes.txt"
    path.write_text("frame,id,x,y,w,h\n" * 200)
    with pytest.raises(FrameSourceError, match=(
            "^" + re.escape(f"{path}: neither an image nor a video OpenCV can read (no image "
                            "extension") + r".*no known video container: MP4/MOV, AVI")) as info:
        open_frames(path)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(("head", "container"), [
    (b"\x00\x00\x00\x20ftypisom" + bytes(20), "MP4/MOV"),
    (b"RIFF\x00\x10\x00\x00AVI LIST", "AVI"),
    (b"\x1a\x45\xdf\xa3\x9f\x42\x86\x81", "Matroska/WebM"),
    (b"\x00\x00\x01\xba\x44\x00", "MPEG-PS"),
    ((b"\x47" + bytes(187)) * 3, "MPEG-TS"),
    ((bytes(4) + b"\x47" + bytes(187)) * 3, "MPEG-TS"),
    (b"FLV\x01\x05\x00\x00\x00\x09", "FLV"),
    (b"OggS\x00\x02", "Ogg"),
    (b"hello, world\n", None),
    (b"Good morning\n", None),
    (b"\x47 is a capital G, and this line is plain text" * 10, None),
    (b"", None),
])
def test_video_containers_by_signature(head, container):
    assert video_container(head) == container


def test_a_damaged_video_says_which_container_it_is(tmp_path):
    path = tmp_path / "broken.avi"
    path.write_bytes(b"RIFF\x00\x10\x00\x00AVI LIST" + b"\x00garbage" * 50)
    with pytest.raises(FrameSourceError, match=re.escape(f"{path}: neither an image nor a video "
                                                         "OpenCV can read (AVI container, ")):
        open_frames(path)


def test_frame_image_checks_its_image():
    with pytest.raises(ValueError, match=r"\(H, W, 3\) uint8"):
        FrameImage(1, np.zeros((4, 4), np.uint8), "x.png")


# --------------------------------------------------------------------------------------------
# Videos

N_VIDEO = 12


@pytest.fixture(scope="module")
def video(tmp_path_factory) -> Path:
    """An MJPG .avi of ``N_VIDEO`` frames, frame f (1-based) showing ``_smooth(f)``; the tests
    using it are skipped when this OpenCV build can neither write nor read it back."""
    path = tmp_path_factory.mktemp("video") / "top.avi"
    size = (64, 48)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, size)
    if not writer.isOpened():
        pytest.skip("this OpenCV build cannot write MJPG .avi videos (no video codec)")
    for f in range(1, N_VIDEO + 1):
        writer.write(_smooth(f, size))
    writer.release()
    capture = cv2.VideoCapture(str(path))
    readable = capture.isOpened() and capture.read()[0]
    capture.release()
    if not readable:
        pytest.skip("this OpenCV build cannot read back the MJPG .avi it wrote")
    return path


def _nearest(image: np.ndarray) -> int:
    """The frame whose original image is nearest to a decoded video frame."""
    h, w = image.shape[:2]
    errors = [np.abs(image.astype(float) - _smooth(f, (w, h))).mean() for f in range(1, 9)]
    return int(np.argmin(errors)) + 1


def test_video_sequential_reads(video):
    with open_frames(video) as source:
        assert source.size == (64, 48)
        assert source.frames in (list(range(1, N_VIDEO + 1)), None)
        for f in range(1, N_VIDEO + 1):
            image = source.get(f)
            assert image.dtype == np.uint8 and image.shape == (48, 64, 3)
            assert _close(image, _smooth(f, (64, 48)), tol=4.0), f
            assert _nearest(image) == (f - 1) % 8 + 1
        assert source.read(3).path == f"{video}#3"


def test_video_skips_forward_and_reads_backward(video):
    with open_frames(video) as source:
        for f in [2, 7, 7, 11, 3, 1, 12, 5]:
            assert _nearest(source.get(f)) == (f - 1) % 8 + 1, f


def test_video_past_the_end(video):
    with open_frames(video) as source:
        with pytest.raises(FrameSourceError, match=_message(
            video, f"frame 13 is past the end of the video ({N_VIDEO} frames)"
        )) as info:
            source.get(13)
        assert info.value.frame == 13
        assert _nearest(source.get(4)) == 4  # still usable afterwards
        with pytest.raises(FrameSourceError, match=_message(
            video, "no frame 0 in a video (video frames are numbered from 1)"
        )):
            source.get(0)


def test_video_check_frames(video):
    with open_frames(video) as source:
        if source.frames is None:
            pytest.skip("OpenCV does not report the frame count of this video")
        check_frames(source, range(1, N_VIDEO + 1))
        with pytest.raises(FrameSourceError, match=_message(
            video,
            f"frame 212 is past the end of the video (the boxes have it; the video has {N_VIDEO} "
            "frames)",
        )):
            check_frames(source, [1, 212])


def test_video_closed(video):
    source = open_frames(os.fspath(video))
    source.close()
    source.close()  # idempotent
    with pytest.raises(ValueError, match="after close"):
        source.get(1)


def test_video_that_stops_before_its_reported_count(video, tmp_path):
    cut = tmp_path / "cut.avi"
    data = video.read_bytes()
    cut.write_bytes(data[: len(data) * 17 // 20])  # the index and the last frames cut off
    try:
        source = open_frames(cut)
    except FrameSourceError:
        pytest.skip("OpenCV cannot open this truncated .avi at all")
    with source:
        if source.frames != list(range(1, N_VIDEO + 1)):
            pytest.skip("OpenCV does not report the original count for a truncated .avi")
        with pytest.raises(FrameSourceError, match=(
            "^" + re.escape(f"{cut}: frame {N_VIDEO} could not be read (the video stops after "
                            "frame ") + rf"\d+ although it reports {N_VIDEO} frames\)$"
        )):
            source.get(N_VIDEO)


def test_a_glob_pattern_reads_like_a_folder_of_the_files_it_matches(tmp_path):
    # Two scenes in one folder (as `xvmatch synth` writes them): a pattern picks one scene.
    for scene in ("s00000", "s00001"):
        for frame in (1, 2):
            image = np.full((6, 8, 3), 10 * frame + (scene == "s00001"), np.uint8)
            cv2.imwrite(str(tmp_path / f"{scene}_{frame:06d}.png"), image)
    with pytest.raises(FrameSourceError, match="both give frame 1"):
        open_frames(tmp_path)
    with open_frames(str(tmp_path / "s00001_*.png")) as source:
        assert source.frames == [1, 2]
        assert source.get(2)[0, 0, 0] == 21
    with pytest.raises(FrameSourceError, match="no image file whose name ends in a frame"):
        open_frames(str(tmp_path / "s9*.png"))
