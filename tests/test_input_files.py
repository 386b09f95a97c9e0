"""Inputs that are not files of records (issue 65): a FIFO, a device, a folder, a binary file or
a line over a megabyte ends at once in one line, from the reader and through the commands,
never in a hang or a machine out of memory."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest

from tests.test_box_input_errors import _error_line
from xvmatch.cli import main
from xvmatch.core.input_files import (
    MAX_LINE_BYTES,
    InputFileError,
    check_input_file,
    read_input_text,
)
from xvmatch.formats.camera_frames import open_cameras
from xvmatch.formats.camera_io import CameraFileError
from xvmatch.formats.mot_boxes import BoxFileError, read_mot_boxes

WAIT_S = 20.0
"""How long a call on a FIFO may take before it counts as a hang (it takes milliseconds)."""


def _at_once(call, *fifos: Path):
    """``call()``'s result or exception, from a thread given :data:`WAIT_S`: a call that
    blocks on a FIFO fails the test (and is released by a writer's open and close) instead of
    hanging the run."""
    box: dict = {}

    def run() -> None:
        try:
            box["value"] = call()
        except BaseException as exc:  # handed to the test
            box["error"] = exc

    worker = threading.Thread(target=run, daemon=True)
    worker.start()
    worker.join(WAIT_S)
    if worker.is_alive():
        for fifo in fifos:  # a blocked reader's open returns once a writer comes and goes
            os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        worker.join(WAIT_S)
        pytest.fail(f"the call blocked on a FIFO for more than {WAIT_S:g} s")
    if "error" in box:
        raise box["error"]
    return box.get("value")


@pytest.fixture
def fifo(tmp_path) -> Path:
    path = tmp_path / "pipe.txt"
    os.mkfifo(path)
    return path




# --------------------------------------------------------------------------------------------
# The reader


def test_a_fifo_is_refused_without_blocking(fifo):
    with pytest.raises(InputFileError, match=r"pipe\.txt: is a FIFO, not a regular file"):
        _at_once(lambda: read_input_text(fifo, "--top"), fifo)
    with pytest.raises(InputFileError, match=r"^--top "):
        _at_once(lambda: read_input_text(fifo, "--top"), fifo)
    with pytest.raises(InputFileError, match="is a FIFO"):
        _at_once(lambda: check_input_file(fifo), fifo)


@pytest.mark.parametrize("device", ["/dev/zero", "/dev/urandom"])
def test_a_device_is_refused_before_any_byte_is_read(device):
    if not os.path.exists(device):
        pytest.skip(f"no {device} here")
    with pytest.raises(InputFileError, match=f"^{device}: is a character device"):
        _at_once(lambda: read_input_text(device))


def test_a_folder_is_refused(tmp_path):
    with pytest.raises(InputFileError, match="is a folder"):
        read_input_text(tmp_path)


def test_a_missing_file_is_one_line(tmp_path):
    with pytest.raises(InputFileError, match=r"nowhere\.txt: no such file$"):
        read_input_text(tmp_path / "nowhere.txt")


def test_a_nul_byte_is_refused_at_its_line(tmp_path):
    path = tmp_path / "boxes.txt"
    path.write_bytes(b"1,1,10,20,30,40\n2,1,10,20,30,40\n3,1,\x00\n")
    with pytest.raises(InputFileError, match=r"boxes\.txt:3: not a text file \(a NUL byte\)"):
        read_input_text(path)


@pytest.mark.parametrize("ending", [b"", b"\n1,1,10,20,30,40\n"], ids=["last", "inner"])
def test_a_line_over_a_megabyte_is_refused(tmp_path, ending):
    path = tmp_path / "boxes.txt"
    path.write_bytes(b"1,1,10,20,30,40\n" + b"7" * 1_500_000 + ending)
    with pytest.raises(InputFileError, match=f"a line of over {MAX_LINE_BYTES:,} bytes"):
        read_input_text(path)


def test_a_line_just_under_the_bound_is_read(tmp_path):
    path = tmp_path / "long.txt"
    path.write_bytes(b"a\n" + b"b" * (MAX_LINE_BYTES - 1) + b"\nc\n")
    assert read_input_text(path).split("\n")[1] == "b" * (MAX_LINE_BYTES - 1)


def test_a_byte_order_mark_is_dropped_with_utf8_sig(tmp_path):
    path = tmp_path / "boxes.txt"
    path.write_bytes(b"\xef\xbb\xbf1,1,10,20,30,40\r\n")
    assert read_input_text(path, encoding="utf-8-sig") == "1,1,10,20,30,40\r\n"
    assert read_input_text(path).startswith("\ufeff")
    np_frames = read_mot_boxes(path)
    assert list(np_frames) == [1]


def test_the_box_reader_keeps_its_error_with_path_and_line(tmp_path, fifo):
    path = tmp_path / "boxes.txt"
    path.write_bytes(b"1,1,10,20,30,40\n\x00\n")
    with pytest.raises(BoxFileError) as info:
        read_mot_boxes(path)
    assert (info.value.path, info.value.line) == (str(path), 2)
    with pytest.raises(BoxFileError, match="is a FIFO") as info:
        _at_once(lambda: read_mot_boxes(fifo), fifo)
    assert (info.value.path, info.value.line) == (str(fifo), None)


def test_a_fifo_among_per_frame_camera_files_is_refused(tmp_path):
    folder = tmp_path / "cameras"
    folder.mkdir()
    os.mkfifo(folder / "000001.json")
    with pytest.raises(CameraFileError, match=r"000001\.json: is a FIFO"):
        _at_once(lambda: open_cameras(folder), folder / "000001.json")
    os.mkfifo(tmp_path / "cams.json")
    with pytest.raises(CameraFileError, match=r"cams\.json: is a FIFO"):
        _at_once(lambda: open_cameras(tmp_path / "cams.json"), tmp_path / "cams.json")


# --------------------------------------------------------------------------------------------
# Through the commands: exit 2, one line, at once


def test_associate_refuses_a_fifo_as_the_top_file(scene_files, tmp_path, capsys, fifo):
    argv = ["associate", "--top", str(fifo), "--hor", str(scene_files[1]), "--out",
            str(tmp_path / "p.csv"), "--quiet"]
    assert _at_once(lambda: main(argv), fifo) == 2
    assert f"{fifo}: is a FIFO, not a regular file" in _error_line(capsys)
    assert not (tmp_path / "p.csv").exists()


def test_evaluate_refuses_a_fifo_as_the_predictions(scene_files, capsys, fifo):
    argv = ["evaluate", "--pred", str(fifo), "--top", str(scene_files[0]), "--hor",
            str(scene_files[1])]
    assert _at_once(lambda: main(argv), fifo) == 2
    assert f"{fifo}: is a FIFO, not a regular file" in _error_line(capsys)


def test_associate_refuses_a_fifo_among_the_per_frame_cameras(scene_files, tmp_path, capsys):
    folder = tmp_path / "cameras"
    folder.mkdir()
    os.mkfifo(folder / "000001.json")
    argv = ["associate", "--top", str(scene_files[0]), "--hor", str(scene_files[1]),
            "--model", "default", "--cameras", str(folder), "--out", str(tmp_path / "p.csv"),
            "--quiet"]
    assert _at_once(lambda: main(argv), folder / "000001.json") == 2
    assert f"{folder / '000001.json'}: is a FIFO" in _error_line(capsys)
    assert not (tmp_path / "p.csv").exists()


@pytest.mark.parametrize("device", ["/dev/zero", "/dev/urandom"])
@pytest.mark.parametrize("view", ["--top", "--hor"])
def test_a_device_as_a_box_file_is_one_line(scene_files, tmp_path, capsys, device, view):
    if not os.path.exists(device):
        pytest.skip(f"no {device} here")
    files = {"--top": str(scene_files[0]), "--hor": str(scene_files[1]), view: device}
    argv = ["associate", "--top", files["--top"], "--hor", files["--hor"], "--out",
            str(tmp_path / "p.csv"), "--quiet"]
    assert _at_once(lambda: main(argv)) == 2
    assert f"{device}: is a character device" in _error_line(capsys)


def test_a_folder_and_a_long_line_as_box_files_are_one_line(scene_files, tmp_path, capsys):
    long = tmp_path / "long_top.txt"
    long.write_bytes(b"1,1,10,20,30,40\n" + b"9" * 1_500_000 + b"\n")
    for top, what in ((tmp_path, "is a folder"), (long, "a line of over")):
        argv = ["associate", "--top", str(top), "--hor", str(scene_files[1]), "--out",
                str(tmp_path / "p.csv"), "--quiet"]
        assert main(argv) == 2
        line = _error_line(capsys)
        assert f"{top}" in line and what in line, line


def test_a_fifo_as_a_folder_marker_is_no_marker(tmp_path):
    from xvmatch.core.folder_marker import MARKER, is_own_folder

    os.mkfifo(tmp_path / MARKER)
    assert _at_once(lambda: is_own_folder(tmp_path, "xvmatch demo"), tmp_path / MARKER) is False
    (tmp_path / MARKER).unlink()
    (tmp_path / MARKER).write_text('{"written_by": "xvmatch demo"}\n')
    assert is_own_folder(tmp_path, "xvmatch demo")


def test_a_fifo_as_a_synthetic_annotation_is_one_line(tmp_path):
    from xvmatch.datasets.synthetic_io import SchemaError, read_scene

    os.mkfifo(tmp_path / "scene.json")
    with pytest.raises(SchemaError, match=r"scene\.json: is a FIFO"):
        _at_once(lambda: read_scene(tmp_path / "scene.json"), tmp_path / "scene.json")
