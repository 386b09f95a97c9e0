"""Tests of xvmatch.datasets.multicam_scenes (the multi-camera box simulator)."""

from __future__ import annotations

import numpy as np
import pytest

from xvmatch.datasets.detector_noise import DetectorNoise
from xvmatch.datasets.multicam_scenes import (
    MulticamConfig,
    TrackerNoise,
    add_tracker_noise,
    simulate_multicam_scene,
    write_multicam_scene,
)
from xvmatch.formats.camera_io import load_ground_cameras
from xvmatch.formats.mot_boxes import read_mot_boxes


def _scene(seed=3, n_cameras=3):
    return simulate_multicam_scene(MulticamConfig(n_cameras=n_cameras, n_people=(6, 6)), 60,
                                   seed=seed)


def test_seeded_and_deterministic():
    a, b, c = _scene(3), _scene(3), _scene(4)
    for name in a.cameras:
        for f in a.boxes[name]:
            np.testing.assert_array_equal(a.boxes[name][f].ids, b.boxes[name][f].ids)
            np.testing.assert_array_equal(a.boxes[name][f].boxes, b.boxes[name][f].boxes)
    assert not np.allclose(a.positions, c.positions)


def test_boxes_are_the_people_seen_by_each_camera():
    scene = _scene()
    assert list(scene.cameras) == ["cam1", "cam2", "cam3"]
    for name, cam in scene.cameras.items():
        for f, rec in scene.gt[name].items():
            if not len(rec):
                continue
            # Each box's bottom centre is near the projection of its person's feet, unless a
            # nearer person or the border cut the box's bottom.
            feet = np.concatenate([scene.positions[f - 1, rec.ids - 1],
                                   np.zeros((len(rec), 1))], axis=1)
            uv, depth = cam.project(feet)
            assert (depth > 0).all()
            bottom = rec.boxes[:, 1] + rec.boxes[:, 3]
            assert (bottom <= uv[:, 1] + 0.1 * rec.boxes[:, 3]).all()
            assert np.median(np.abs(bottom - uv[:, 1]) / rec.boxes[:, 3]) < 0.05
            # Per-camera track ids differ from the global ids, and map to one person each.
            tracks = scene.boxes[name][f].ids
            assert not np.array_equal(tracks, rec.ids)
    for name in scene.cameras:
        owner: dict[int, int] = {}
        for f, rec in scene.boxes[name].items():
            for t, g in zip(rec.ids.tolist(), scene.gt[name][f].ids.tolist(), strict=True):
                assert owner.setdefault(t, g) == g


def test_noise_and_writer(tmp_path):
    scene = _scene()
    noisy = add_tracker_noise(scene, TrackerNoise(DetectorNoise(0.05, 0.1, 0.3), 0.2, 0.5), 1)
    again = add_tracker_noise(scene, TrackerNoise(DetectorNoise(0.05, 0.1, 0.3), 0.2, 0.5), 1)
    n_in = sum(len(r) for r in scene.boxes["cam1"].values())
    n_out = sum(len(r) for r in noisy.boxes["cam1"].values())
    assert n_out != n_in
    for f in noisy.boxes["cam1"]:
        np.testing.assert_array_equal(noisy.boxes["cam1"][f].ids, again.boxes["cam1"][f].ids)
    paths = write_multicam_scene(tmp_path / "scene", noisy)
    cams = load_ground_cameras(paths["cameras"])
    assert list(cams) == list(scene.cameras)
    back = read_mot_boxes(paths["boxes"] / "cam2.txt")
    assert sum(len(r) for r in back.values()) == sum(
        len(r) for r in noisy.boxes["cam2"].values())
    lines = (paths["ground"]).read_text().splitlines()
    assert lines[0] == "frame,global_id,X,Y" and len(lines) > 60


def test_config_is_checked():
    with pytest.raises(ValueError, match="n_cameras"):
        MulticamConfig(n_cameras=1)
    with pytest.raises(ValueError, match="camera_distance"):
        MulticamConfig(camera_distance=(5.0, 6.0))
