"""Tests of xvmatch.formats.camera_io (version-1 camera JSON files)."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from xvmatch.formats import camera_io
from xvmatch.formats.camera_io import CameraFileError, load_cameras, save_cameras
from xvmatch.geometry.camera import Camera, intrinsics_from_fov, look_rotation


def _cameras() -> dict[str, Camera]:
    top = Camera(
        intrinsics_from_fov(1920, 1080, 90.0),
        look_rotation(0.3, math.radians(40)),
        [1.0 / 3.0, -7.25, 9.5],
        1920,
        1080,
    )
    K_ego = intrinsics_from_fov(1280, 720, 66.6)
    ego = Camera(K_ego, look_rotation(2.1, 0.05, 0.01), [2.0, 0.1, 1.5], 1280, 720)
    return {"top": top, "ego": ego}


def _record() -> dict:
    return {
        "version": 1,
        "cameras": {name: cam.to_dict() for name, cam in _cameras().items()},
    }


def _write(tmp_path: Path, data: object, name: str = "cams.json") -> Path:
    path = tmp_path / name
    path.write_text(data if isinstance(data, str) else json.dumps(data))
    return path


def test_round_trip_is_exact(tmp_path: Path) -> None:
    path = tmp_path / "cams.json"
    save_cameras(path, _cameras())
    loaded = load_cameras(path, required=("top", "ego"))
    assert list(loaded) == ["top", "ego"]
    for name, cam in _cameras().items():
        got = loaded[name]
        np.testing.assert_array_equal(got.K, cam.K)
        np.testing.assert_array_equal(got.R, cam.R)
        np.testing.assert_array_equal(got.c, cam.c)
        assert (got.width, got.height) == (cam.width, cam.height)
    data = json.loads(path.read_text())
    assert data["version"] == 1
    assert set(data["cameras"]["top"]) == {"K", "R", "c", "width", "height"}


def test_save_is_atomic_and_leaves_no_temp_files(tmp_path: Path, monkeypatch) -> None:
    path = tmp_path / "cams.json"
    save_cameras(path, _cameras())
    save_cameras(str(path), {"top": _cameras()["top"]})  # overwrite through os.replace
    assert list(load_cameras(path)) == ["top"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cams.json"]

    # A crash before the rename keeps the previous file intact and cleans the temp file.
    save_cameras(path, _cameras())
    before = path.read_text()

    def boom(src: str, dst: str) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(camera_io.os, "replace", boom)
    with pytest.raises(OSError, match="disk full"):
        save_cameras(path, {"top": _cameras()["top"]})
    assert path.read_text() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cams.json"]


def test_save_errors(tmp_path: Path) -> None:
    with pytest.raises(CameraFileError, match="non-empty"):
        save_cameras(tmp_path / "cams.json", {})
    with pytest.raises(CameraFileError, match=r"cameras\.top: expected a Camera"):
        save_cameras(tmp_path / "cams.json", {"top": {"K": 1}})  # type: ignore[dict-item]
    nan_cam = Camera(np.eye(3), np.eye(3), [np.nan, 0.0, 0.0], 10, 10)
    with pytest.raises(CameraFileError, match=r"cameras\.ego\.c: contains NaN"):
        save_cameras(tmp_path / "cams.json", {"ego": nan_cam})
    with pytest.raises(FileNotFoundError, match="does not exist"):
        save_cameras(tmp_path / "missing" / "cams.json", _cameras())
    assert list(tmp_path.iterdir()) == []


def _set(data: dict, dotted: str, value: object) -> dict:
    *parents, last = dotted.split(".")
    node = data
    for key in parents:
        node = node[key]
    if value is _DELETE:
        del node[last]
    else:
        node[last] = value
    return data


_DELETE = object()


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("cameras.ego.K", [[1, 0, 0], [0, 1, 0]], r"cameras\.ego\.K: expected 3x3 numbers"),
        ("cameras.ego.K", [[1, 0, 0], [0, 1, 0], [0, 0, "1"]], r"cameras\.ego\.K: expected 3x3"),
        ("cameras.ego.K", [[1, 0, 0], [0, 1, 0], [0, 0, True]], r"cameras\.ego\.K: expected 3x3"),
        ("cameras.ego.K", [[1, 0, 0], [0, 0, 0], [0, 0, 1]], r"cameras\.ego\.K: singular"),
        ("cameras.top.R", [[1, 0, 0], [0, 1, 0], [0, 0, -1]], r"cameras\.top\.R: not a proper"),
        ("cameras.top.R", [[1, 0.01, 0], [0, 1, 0], [0, 0, 1]], r"cameras\.top\.R: not a proper"),
        ("cameras.top.c", [1, 2], r"cameras\.top\.c: expected 3 numbers"),
        ("cameras.top.width", -5, r"cameras\.top\.width: expected a positive integer"),
        ("cameras.top.height", 10.5, r"cameras\.top\.height: expected a positive integer"),
        ("cameras.top.height", True, r"cameras\.top\.height: expected a positive integer"),
        ("cameras.top.height", math.inf, r"cameras\.top\.height: expected a positive integer"),
        ("cameras.top.K", _DELETE, r"cameras\.top: missing field\(s\) K"),
        ("cameras.top.k", [[1]], r"cameras\.top: unknown field\(s\) k"),
        ("cameras.top", [1, 2], r"cameras\.top: expected an object"),
        ("cameras", {}, r"cameras: expected a non-empty object"),
        ("version", 2, r"version: unsupported 2"),
        ("version", _DELETE, r"version: missing"),
        ("notes", "x", r"unknown top-level field\(s\) notes"),
    ],
)
def test_load_errors_name_file_and_field(
    tmp_path: Path, field: str, value: object, message: str
) -> None:
    path = _write(tmp_path, _set(_record(), field, value))
    with pytest.raises(CameraFileError, match=r"cams\.json: " + message):
        load_cameras(path)


def test_load_rejects_nan_invalid_json_and_missing_cameras(tmp_path: Path) -> None:
    text = json.dumps(_record()).replace('"c": [2.0', '"c": [NaN', 1)
    assert "NaN" in text
    with pytest.raises(CameraFileError, match=r"cams\.json: cameras\.ego\.c: expected 3 numbers"):
        load_cameras(_write(tmp_path, text))
    with pytest.raises(CameraFileError, match=r"bad\.json: line 1 column \d+: not valid JSON"):
        load_cameras(_write(tmp_path, '{"version": 1,', name="bad.json"))
    with pytest.raises(CameraFileError, match=r"list\.json: expected a JSON object"):
        load_cameras(_write(tmp_path, "[]", name="list.json"))
    missing = r"cams\.json: cameras: missing required camera\(s\) side"
    with pytest.raises(CameraFileError, match=missing):
        load_cameras(_write(tmp_path, _record()), required=("top", "side"))
    with pytest.raises(FileNotFoundError):
        load_cameras(tmp_path / "nope.json")


def test_written_file_is_readable_json_with_newline(tmp_path: Path) -> None:
    path = tmp_path / "cams.json"
    save_cameras(path, _cameras())
    text = path.read_text()
    assert text.endswith("\n") and json.loads(text)["cameras"]["ego"]["width"] == 1280
    assert os.stat(path).st_mode & 0o777 == 0o644
