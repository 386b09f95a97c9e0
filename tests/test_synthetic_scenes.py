"""Tests of the rendered scenes' camera rigs (xvmatch.datasets.synthetic_scenes)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from xvmatch.datasets.synthetic_scenes import SynthConfig, fit_hfov, make_scene
from xvmatch.geometry.camera import look_rotation

SMALL = (160, 90)


def _scene(scenario: str, seed: int, frames: int = 20, **kw):
    config = SynthConfig(scenario=scenario, top_size=SMALL, ego_size=SMALL, **kw)
    return make_scene(config, frames, np.random.default_rng([seed, 0]))


def _pitch_deg(R: np.ndarray) -> float:
    """Downward pitch of the optical axis (row 2 of R is the axis in world coordinates)."""
    return math.degrees(math.asin(-R[2, 2]))


def _roll_deg(R: np.ndarray) -> float:
    """Roll about the optical axis: angle of the image x axis out of the horizontal plane."""
    return math.degrees(math.asin(np.clip(R[0, 2], -1.0, 1.0)))


def _hfov_deg(camera) -> float:
    return math.degrees(2 * math.atan(camera.width / 2 / camera.K[0, 0]))


@pytest.mark.parametrize("seed", range(4))
def test_drone_rig(seed: int) -> None:
    scene = _scene("drone", seed)
    top = scene.top_cameras[0]
    assert all(cam is top for cam in scene.top_cameras)
    assert 20.0 <= top.c[2] <= 60.0
    assert np.allclose(top.R[2], [0.0, 0.0, -1.0])  # nadir
    people = scene.people
    w = people.wearer
    assert people.ids[w] == 0
    for f, cam in enumerate(scene.ego_cameras):
        # Head-worn: at the carrier's eye, 0.1 m below the top of the head.
        assert np.allclose(cam.c[:2], people.positions[f, w])
        assert cam.c[2] == pytest.approx(people.heights[w] - 0.1)
        assert abs(_pitch_deg(cam.R)) <= 10.0 + 1e-9
        assert abs(_roll_deg(cam.R)) <= 5.0 + 1e-6
        assert 60.0 <= _hfov_deg(cam) <= 100.0
    # The whole walking area is in the top view: every ground point and head on every frame.
    ground = np.concatenate([people.positions, np.zeros((*people.positions.shape[:2], 1))], 2)
    heads = ground + np.array([0.0, 0.0, 1.0]) * people.heights[None, :, None]
    for points in (ground, heads):
        uv, depth = top.project(points)
        assert (depth > 0).all() and top.in_image(uv).all()


@pytest.mark.parametrize("seed", range(4))
def test_overview_rig(seed: int) -> None:
    scene = _scene("overview", seed)
    top = scene.top_cameras[0]
    assert 8.0 <= top.c[2] <= 25.0
    assert 25.0 - 1e-6 <= _pitch_deg(top.R) <= 60.0 + 1e-6
    assert abs(_roll_deg(top.R)) < 1e-9
    people = scene.people
    w = people.wearer
    assert people.heights[w] >= 1.6
    # The overview camera stands on the first building, outside the walking area.
    building = scene.buildings[0]
    assert building.height < top.c[2]
    assert np.hypot(*top.c[:2]) > scene.area / math.sqrt(2)
    for f, cam in enumerate(scene.ego_cameras):
        assert cam.c[2] == pytest.approx(1.5)
        reach = np.hypot(*(cam.c[:2] - people.positions[f, w]))
        assert reach == pytest.approx(0.3)
        assert abs(_pitch_deg(cam.R)) <= 10.0 + 1e-9
        assert abs(_roll_deg(cam.R)) <= 5.0 + 1e-6
    # The carrier is in the overview image on every frame.
    ground = np.concatenate([people.positions[:, w], np.zeros((people.n_frames, 1))], axis=1)
    uv, depth = top.project(ground)
    assert (depth > 0).all() and top.in_image(uv).all()


def test_people_range_and_walks() -> None:
    sizes = [_scene("drone", s, frames=2, n_people=(3, 5)).people.n_people for s in range(12)]
    assert min(sizes) >= 3 and max(sizes) <= 5 and len(set(sizes)) > 1
    scene = _scene("drone", 7, frames=60)
    step = np.hypot(*np.diff(scene.people.positions, axis=0).transpose(2, 0, 1))
    assert step.max() > 0  # people walk
    assert (step.max(axis=0) < 2.5 / scene.config.fps).all()  # at walking speed


def test_same_seed_same_scene() -> None:
    a, b = _scene("overview", 3), _scene("overview", 3)
    assert np.array_equal(a.people.positions, b.people.positions)
    assert all(np.array_equal(x.R, y.R) and np.array_equal(x.c, y.c)
               for x, y in zip(a.ego_cameras, b.ego_cameras, strict=True))
    assert a.buildings == b.buildings
    c = _scene("overview", 4)
    assert not np.array_equal(a.top_cameras[0].c, c.top_cameras[0].c)


def test_fit_hfov_hand_computed() -> None:
    # Camera at the origin looking along +x: points 10 m ahead, 5 m to the side -> tan = 0.5.
    R = look_rotation(0.0)
    points = np.array([[10.0, 5.0, 0.0], [10.0, -5.0, 0.0]])
    assert fit_hfov(R, np.zeros(3), points, (640, 360)) == pytest.approx(
        math.degrees(2 * math.atan(0.5))
    )
    # A vertical offset counts with the aspect ratio: 1 m up at 10 m -> tan 0.1 * 640/360.
    up = np.array([[10.0, 0.0, 1.0]])
    assert fit_hfov(R, np.zeros(3), up, (640, 360)) == pytest.approx(
        math.degrees(2 * math.atan(0.1 * 640 / 360))
    )
    with pytest.raises(ValueError, match="in front of the camera"):
        fit_hfov(R, np.zeros(3), np.array([[-1.0, 0.0, 0.0]]), (640, 360))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"scenario": "satellite"}, "scenario must be one of drone, overview"),
        ({"n_people": (5, 3)}, "n_people must be"),
        ({"ego_hfov": (60.0, 190.0)}, "ego_hfov must be"),
        ({"top_size": (4, 4)}, "top_size must be"),
        ({"min_separation": 0.3}, "min_separation"),
        ({"scenario": "overview", "handheld_height": 2.0}, "handheld_height"),
    ],
)
def test_config_errors(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        SynthConfig(**kwargs)


def test_make_scene_needs_a_frame() -> None:
    with pytest.raises(ValueError, match="n_frames must be >= 1"):
        make_scene(SynthConfig(), 0, np.random.default_rng(0))
