"""Tests of the box-level scene simulator (xvmatch.datasets.box_scene)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.datasets.box_scene import (
    PeopleState,
    SceneConfig,
    project_boxes,
    project_hor_boxes,
    simulate_box_scene,
    simulate_walks,
    write_box_scene,
)
from xvmatch.formats.mot_boxes import read_mot_boxes
from xvmatch.geometry.camera import Camera, intrinsics_from_fov, look_rotation

CONFIG = SceneConfig()


@pytest.fixture(scope="module")
def scene():
    return simulate_box_scene(n_frames=60, seed=3)


def _state(xy: list[tuple[float, float]], heights: list[float], width: float = 0.45) -> PeopleState:
    """One-frame scene: index 0 is the wearer, the others get ids 1..N-1."""
    n = len(xy)
    return PeopleState(
        positions=np.asarray(xy, dtype=float)[None],
        heights=np.asarray(heights, dtype=float),
        widths=np.full(n, width),
        headings=np.zeros((1, n)),
        ids=np.arange(n),
        wearer=0,
        head_yaw=np.zeros(1),
        head_pitch=np.zeros(1),
        head_roll=np.zeros(1),
    )


def _level_camera(eye: float = 1.7) -> Camera:
    """Ideal head camera at the origin looking along +x (image left is world +y)."""
    width, height = CONFIG.hor_size
    return Camera(
        K=intrinsics_from_fov(width, height, CONFIG.hor_hfov_deg),
        R=look_rotation(0.0),
        c=np.array([0.0, 0.0, eye]),
        width=width,
        height=height,
    )


def _hor(state: PeopleState, config: SceneConfig = CONFIG):
    return project_hor_boxes(state, [_level_camera()], config)[1]


def _same(a, b) -> bool:
    return a.keys() == b.keys() and all(
        np.array_equal(a[k].ids, b[k].ids) and np.array_equal(a[k].boxes, b[k].boxes) for k in a
    )


def test_same_seed_same_scene(scene):
    again = simulate_box_scene(n_frames=60, seed=3)
    assert np.array_equal(again.people.positions, scene.people.positions)
    assert np.array_equal(again.people.head_yaw, scene.people.head_yaw)
    assert _same(again.top, scene.top) and _same(again.hor, scene.hor)


def test_different_seed_different_scene(scene):
    other = simulate_box_scene(n_frames=60, seed=4)
    assert other.people.positions.shape != scene.people.positions.shape or not np.allclose(
        other.people.positions, scene.people.positions
    )
    assert not _same(other.top, scene.top)


def test_shapes_and_frames(scene):
    people = scene.people
    assert people.positions.shape == (60, people.n_people, 2)
    assert CONFIG.n_people[0] <= people.n_people <= CONFIG.n_people[1]
    assert len(scene.hor_cameras) == 60
    assert sorted(scene.top) == sorted(scene.hor) == list(range(1, 61))
    assert np.array_equal(np.sort(people.ids), np.arange(people.n_people))


def test_walks_stay_in_area_and_apart(scene):
    pos = scene.people.positions
    assert np.abs(pos).max() <= 0.5 * CONFIG.area
    dist = np.linalg.norm(pos[:, :, None] - pos[:, None], axis=-1)
    dist[:, np.arange(pos.shape[1]), np.arange(pos.shape[1])] = np.inf
    assert dist.min() >= CONFIG.min_separation - 1e-9
    # Smooth: no one jumps more than a fast walk (plus repulsion) in one frame.
    step = np.linalg.norm(np.diff(pos, axis=0), axis=-1)
    assert step.max() < 3.0 / CONFIG.fps
    assert np.abs(np.angle(np.exp(1j * np.diff(scene.people.head_yaw)))).max() < 0.2


def test_people_stop_sometimes():
    people = simulate_walks(CONFIG, 300, np.random.default_rng(0))
    step = np.linalg.norm(np.diff(people.positions, axis=0), axis=-1)
    assert (step < 1e-9).any() and (step > 0.005).any()


def test_hor_boxes_inside_image(scene):
    width, height = CONFIG.hor_size
    for rec in scene.hor.values():
        b = rec.boxes
        assert (b[:, :2] >= 0).all()
        assert (b[:, 0] + b[:, 2] <= width + 1e-9).all()
        assert (b[:, 1] + b[:, 3] <= height + 1e-9).all()


def test_wearer_in_top_never_in_hor(scene):
    assert all(0 in rec.ids for rec in scene.top.values())
    assert all(0 not in rec.ids for rec in scene.hor.values())
    assert sum(len(rec) for rec in scene.hor.values()) > 0


def test_top_box_centre_is_ground_projection(scene):
    people, cam = scene.people, scene.top_camera
    for frame, rec in scene.top.items():
        ground = np.concatenate([people.positions[frame - 1, rec.ids], np.zeros((len(rec), 1))], 1)
        uv, _ = cam.project(ground)
        np.testing.assert_allclose(rec.boxes[:, :2] + 0.5 * rec.boxes[:, 2:], uv, atol=1e-9)


def test_hor_box_height_is_projected_height():
    state = _state([(0.0, 0.0), (6.0, 0.0)], [1.8, 1.75])
    rec = _hor(state)
    focal = _level_camera().K[0, 0]
    assert list(rec.ids) == [1]
    np.testing.assert_allclose(rec.boxes[0, 3], focal * 1.75 / 6.0, rtol=1e-9)
    np.testing.assert_allclose(rec.boxes[0, 0] + 0.5 * rec.boxes[0, 2], CONFIG.hor_size[0] / 2)


def test_person_hidden_behind_nearer_one_is_dropped():
    state = _state([(0.0, 0.0), (4.0, 0.0), (9.0, 0.0)], [1.8, 1.9, 1.7])
    assert list(_hor(state).ids) == [1]


def test_partly_hidden_person_is_truncated():
    alone = _hor(_state([(0.0, 0.0), (9.0, 0.45)], [1.8, 1.7]))
    both = _hor(_state([(0.0, 0.0), (4.0, 0.0), (9.0, 0.45)], [1.8, 1.9, 1.7]))
    assert list(both.ids) == [1, 2]
    full, cut = alone.boxes[0], both.boxes[1]
    assert cut[2] < full[2] - 1.0  # narrower ...
    assert cut[3] == pytest.approx(full[3])  # ... same height
    assert cut[0] >= full[0] - 1e-9 and cut[0] + cut[2] <= full[0] + full[2] + 1e-9
    # The cut edge is the occluder's edge.
    near = both.boxes[0]
    assert min(abs(cut[0] + cut[2] - near[0]), abs(cut[0] - near[0] - near[2])) < 1e-6


def test_threshold_drops_mostly_hidden_person():
    xy = [(0.0, 0.0), (4.0, 0.0), (9.0, 0.45)]
    strict = replace(CONFIG, min_visible_fraction=0.99)
    assert list(_hor(_state(xy, [1.8, 1.9, 1.7]), strict).ids) == [1]


def test_behind_or_outside_fov_is_absent():
    # (-5, 0) is behind, (1, 5) is 79 degrees off axis (FOV is +-45), (5, 1) is in view.
    state = _state([(0.0, 0.0), (-5.0, 0.0), (1.0, 5.0), (5.0, 1.0)], [1.8, 1.7, 1.7, 1.7])
    assert list(_hor(state).ids) == [3]


def test_border_truncation():
    # Near the edge of the field of view: part of the body is outside the image.
    state = _state([(0.0, 0.0), (4.0, 4.05)], [1.8, 1.7])
    rec = _hor(state)
    assert list(rec.ids) == [1]
    assert rec.boxes[0, 0] == 0.0
    assert rec.boxes[0, 3] > 2.0 * rec.boxes[0, 2]


def test_project_boxes_needs_one_camera_per_frame(scene):
    with pytest.raises(ValueError, match="one camera per frame"):
        project_boxes(scene.people, scene.top_camera, scene.hor_cameras[:-1], CONFIG)


def test_bad_config_is_rejected():
    with pytest.raises(ValueError, match="min_separation"):
        SceneConfig(min_separation=0.3)
    with pytest.raises(ValueError, match="area"):
        SceneConfig(area=2.0)


def test_write_box_scene_round_trip(scene, tmp_path):
    top_path, hor_path = write_box_scene(scene, tmp_path, "sim")
    assert top_path.name == "sim_top.txt" and hor_path.name == "sim_hor.txt"
    for path, frames in ((top_path, scene.top), (hor_path, scene.hor)):
        back = read_mot_boxes(path)
        for frame, rec in frames.items():
            if len(rec):
                assert np.array_equal(back[frame].ids, rec.ids)
                assert np.array_equal(back[frame].boxes, rec.boxes)


@settings(max_examples=15, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    n_people=st.tuples(st.integers(2, 6), st.integers(0, 8)),
    pitch=st.floats(-5.0, 5.0),
    roll=st.floats(-10.0, 10.0),
)
def test_boxes_are_valid(seed, n_people, pitch, roll):
    config = replace(
        CONFIG,
        n_people=(n_people[0], n_people[0] + n_people[1]),
        hor_pitch_deg=pitch,
        hor_roll_deg=roll,
    )
    scene = simulate_box_scene(config, n_frames=8, seed=seed)
    for frames in (scene.top, scene.hor):
        for rec in frames.values():
            assert np.isfinite(rec.boxes).all()
            assert (rec.boxes[:, 2:] > 0).all()
            assert np.unique(rec.ids).size == len(rec)
