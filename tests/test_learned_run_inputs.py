"""The learned run's inputs and outputs in the library (issue 66): opening the matchers a command
names (inference/matching/run_inputs.py: a torch file's bundle exported once into the cache), the
``--precision`` rule, the horizontal sizes the inputs give and ``--write-cameras``' form
(formats/camera_frames.py), and the ``--costs`` record (inference/matching/costs_record.py)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from tests.test_top_camera_refinement import _scene
from xvmatch.formats.camera_frames import (
    CameraFrames,
    ego_camera_size,
    given_hor_sizes,
    open_cameras,
    write_camera_frames,
)
from xvmatch.formats.camera_io import save_cameras
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.geometry.camera import FrameCameras
from xvmatch.inference.matching.costs_record import costs_record, write_costs_record
from xvmatch.inference.matching.run_inputs import (
    cached_bundle_folder,
    open_matchers,
    precision_problem,
)

DEFAULT_BUNDLE = Path(__file__).resolve().parents[1] / "inference" / "default_bundle"


def test_a_torch_file_is_exported_once_into_the_cache(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("XVMATCH_CACHE", str(tmp_path / "cache"))
    torch_file = tmp_path / "matcher.pt"
    torch_file.write_bytes(b"a matcher's weights")
    with pytest.raises(ValueError, match=r"matcher\.pt: a torch matcher file; export it"):
        open_matchers([str(torch_file)])
    exported = []

    def export(path: str, folder: Path) -> None:  # the shipped bundle stands for the export
        exported.append((path, folder))
        shutil.copytree(DEFAULT_BUNDLE, folder)

    folder = cached_bundle_folder(torch_file)
    assert folder.parent == tmp_path / "cache" / "bundles" and len(folder.name) == 20
    for _ in range(2):
        (model,) = open_matchers([str(torch_file)], export=export)
        assert model.bundle.manifest.appearance is not None
    assert exported == [(str(torch_file), folder)]  # once: the second run opens the cache
    torch_file.write_bytes(b"other weights")
    assert cached_bundle_folder(torch_file) != folder


def test_precision_needs_images_and_an_appearance_network() -> None:
    assert precision_problem(None, False) is None
    assert precision_problem("int8", False) == (
        "--precision int8 chooses the appearance network, which runs only on images: give "
        "--top-images and --hor-images, or leave --precision out")
    models = open_matchers(["default"])
    assert precision_problem("fp32", True, models, ["default"]) is None
    assert precision_problem("fp32", True) is None  # not opened yet


def _cameras(frames: list[int]) -> dict[int, FrameCameras]:
    top, hors, _, _ = _scene(11, frames=max(frames))
    return {f: FrameCameras(top=top, hor=hors[f - 1]) for f in frames}


def test_sizes_the_inputs_give(tmp_path) -> None:
    cams = _cameras([1])[1]
    path = tmp_path / "cams.json"
    save_cameras(path, {"top": cams.top, "ego": cams.hor})
    size = (int(cams.hor.width), int(cams.hor.height))
    assert ego_camera_size(str(path)) == (size, f"the camera files {path}")
    assert given_hor_sizes(None, None, str(path), [1]) == [(size, f"the camera files {path}")]
    assert given_hor_sizes((640, 480), None, None, [1]) == [((640, 480), "--image-size")]
    assert given_hor_sizes(None, None, None, [1]) == []


def test_written_cameras_keep_their_form(tmp_path) -> None:
    per_frame = _cameras([1, 2, 3])
    static = CameraFrames("given.json", static=per_frame[1])
    assert write_camera_frames(static, tmp_path / "one.json", "owner", "--opt") is None
    assert open_cameras(tmp_path / "one.json").static is not None
    folder = tmp_path / "many"
    frames = CameraFrames("given", per_frame=per_frame)
    assert write_camera_frames(frames, folder, "owner", "--opt") == 3
    (folder / "notes.txt").write_text("the user's")
    fewer = CameraFrames("given", per_frame={f: per_frame[f] for f in (1, 2)})
    assert write_camera_frames(fewer, folder, "owner", "--opt") == 2
    left = sorted(p.name for p in folder.iterdir() if not p.name.startswith("."))
    assert left == ["000001.json", "000002.json", "notes.txt"]  # its own frame 3 removed
    assert sorted(open_cameras(folder).per_frame) == [1, 2]


def test_costs_record_holds_each_frame_ids_and_rounded_costs(tmp_path) -> None:
    boxes = np.array([[0.0, 0.0, 10.0, 20.0], [5.0, 5.0, 10.0, 20.0]])
    top = {3: FrameBoxes(3, np.array([7, 9]), boxes)}
    hor = {3: FrameBoxes(3, np.array([4]), boxes[:1])}
    costs = {3: np.array([[0.12345678], [1.0]])}
    record = costs_record(top, hor, costs, 0.5)
    assert record == {"version": 1, "gamma": 0.5, "frames": {
        "3": {"top_ids": [7, 9], "hor_ids": [4], "cost": [[0.123457], [1.0]]}}}
    write_costs_record(tmp_path / "c.json", top, hor, costs, 0.5)
    assert json.loads((tmp_path / "c.json").read_text()) == record
