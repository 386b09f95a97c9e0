"""Refining a fixed top camera from the head rays of a video (geometry/top_camera_refinement.py)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import Phase, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from xvmatch.geometry.camera import Camera, intrinsics_from_fov, look_rotation
from xvmatch.geometry.top_camera_refinement import (
    MIN_REFINE_FRAMES,
    WIDE_LOSS,
    refine_top_camera,
    turned_camera,
)

TOP_SIZE, HOR_SIZE = (1280, 720), (640, 360)


def _boxes(camera: Camera, heads: np.ndarray) -> np.ndarray:
    """Boxes whose top centre is each head's projection (in the image and in front)."""
    uv, depth = camera.project(heads)
    keep = (depth > 0.5) & camera.in_image(uv)
    uv = uv[keep]
    w = np.full(len(uv), 12.0)
    return np.column_stack([uv[:, 0] - w / 2, uv[:, 1], w, 3 * w])


def _scene(seed: int, frames: int = 24, top_height: float = 18.0):
    """Heads of 14 people walking in a 16 m square, an oblique top camera on a building and
    the egocentric camera of a 15th person, turning as it walks: the exact cameras and the
    boxes of each frame."""
    rng = np.random.default_rng(seed)
    start = rng.uniform(-8, 8, (14, 2))
    velocity = rng.normal(0, 1.2, (14, 2))
    height = rng.uniform(1.55, 1.9, 14)
    top = Camera(K=intrinsics_from_fov(*TOP_SIZE, 70.0),
                 R=look_rotation(np.pi / 2, np.radians(42)),
                 c=np.array([0.0, -22.0, top_height]), width=TOP_SIZE[0], height=TOP_SIZE[1])
    k_hor = intrinsics_from_fov(*HOR_SIZE, 90.0)
    wearer = rng.uniform(-6, -2, 2)
    hors, top_boxes, hor_boxes = [], [], []
    for f in range(frames):
        t = f / 5.0
        xy = start + velocity * t
        heads = np.column_stack([xy, height])
        yaw = np.radians(60.0 + 2.0 * f)
        eye = np.array([*wearer + 0.2 * f * np.array([np.cos(yaw), np.sin(yaw)]), 1.65])
        hor = Camera(K=k_hor, R=look_rotation(yaw, np.radians(5.0)), c=eye,
                     width=HOR_SIZE[0], height=HOR_SIZE[1])
        wearer_head = np.array([[*eye[:2], 1.75]])
        hors.append(hor)
        top_boxes.append(_boxes(top, np.vstack([heads, wearer_head])))
        hor_boxes.append(_boxes(hor, heads))
    return top, hors, top_boxes, hor_boxes


def _turned(camera: Camera, rotvec_deg: np.ndarray) -> Camera:
    return turned_camera(camera, rotvec_deg)


def _angle(a: Camera, b: Camera) -> float:
    return float(np.degrees(Rotation.from_matrix(a.R @ b.R.T).magnitude()))


@pytest.mark.slow
@settings(max_examples=4, phases=(Phase.explicit, Phase.generate))  # seconds each: no shrinking
@given(seed=st.integers(0, 10_000), axis=st.tuples(*[st.floats(-1, 1)] * 3)
       .filter(lambda v: np.linalg.norm(v) > 0.2), degrees=st.floats(1.0, 3.0))
def test_a_turned_top_camera_is_found_again(seed, axis, degrees) -> None:
    top, hors, top_boxes, hor_boxes = _scene(seed)
    axis = np.asarray(axis) / np.linalg.norm(axis)
    wrong = _turned(top, degrees * axis)
    fit = refine_top_camera(wrong, hors, top_boxes, hor_boxes)
    assert _angle(fit.camera, top) < 0.3 < degrees - 0.5 < _angle(wrong, top) + 0.5
    assert fit.loss_after < fit.loss_before


@pytest.mark.slow
def test_an_exact_camera_is_left_about_where_it_was() -> None:
    top, hors, top_boxes, hor_boxes = _scene(7)
    fit = refine_top_camera(top, hors, top_boxes, hor_boxes)
    assert fit.angle_deg < 0.2
    assert fit.loss_before < 0.01


@pytest.mark.slow
def test_the_same_input_gives_the_same_camera() -> None:
    top, hors, top_boxes, hor_boxes = _scene(3)
    wrong = _turned(top, np.array([1.0, -1.5, 0.5]))
    a = refine_top_camera(wrong, hors, top_boxes, hor_boxes)
    b = refine_top_camera(wrong, hors[::-1][::-1], list(top_boxes), list(hor_boxes))
    assert a.rotation_deg == b.rotation_deg
    assert np.array_equal(a.camera.R, b.camera.R)
    # rounded to 1e-4 degrees: last-bit differences between CPUs do not reach the matcher
    assert all(round(v, 4) == v for v in a.rotation_deg)


def test_too_few_frames_or_mismatched_inputs_are_refused() -> None:
    top, hors, top_boxes, hor_boxes = _scene(1, frames=MIN_REFINE_FRAMES)
    empty = [np.zeros((0, 4)), *top_boxes[1:]]
    with pytest.raises(ValueError, match=f"{MIN_REFINE_FRAMES - 1} frame.*needs "
                       f"{MIN_REFINE_FRAMES}"):
        refine_top_camera(top, hors, empty, hor_boxes)
    with pytest.raises(ValueError, match="differ in length"):
        refine_top_camera(top, hors[:-1], top_boxes, hor_boxes)


def test_the_batched_rays_are_eqs_6_and_7() -> None:
    # The search's batched distances (top camera turned) are ray_priors' Eq. 6 distances where
    # Eq. 7 holds (with the metric margin) on the turned camera, frame by frame.
    from xvmatch.geometry.ray_priors import (
        METRIC_MARGIN,
        box_rays,
        cheirality_mask,
        ray_distances,
    )
    from xvmatch.geometry.top_camera_refinement import _MISS, _RayFrames

    top, hors, top_boxes, hor_boxes = _scene(5, frames=12)
    turn = np.array([0.7, -1.1, 2.0])
    rays = _RayFrames(top, hors, top_boxes, hor_boxes, METRIC_MARGIN)
    batched, _ = rays.distances(turn)
    turned = _turned(top, turn)
    misses = 0
    for k, (hor, tb, hb) in enumerate(zip(hors, top_boxes, hor_boxes, strict=True)):
        rt, rh = box_rays(turned, tb), box_rays(hor, hb)
        ok = cheirality_mask(rt, rh, margin=METRIC_MARGIN)
        want = np.where(ok, ray_distances(rt, rh), _MISS)
        np.testing.assert_allclose(batched[k, :len(tb), :len(hb)], want, rtol=1e-9, atol=1e-9)
        misses += int((~ok).sum())
    assert misses > 0  # the cheirality test did reject some pairs here


@pytest.mark.slow
def test_a_crowd_is_refined_on_fewer_frames() -> None:
    top, hors, top_boxes, hor_boxes = _scene(2)
    pairs = np.median([len(t) * len(h) for t, h in zip(top_boxes, hor_boxes, strict=True)])
    assert refine_top_camera(top, hors, top_boxes, hor_boxes).frames == len(hors)
    fewer = refine_top_camera(top, hors, top_boxes, hor_boxes, max_pairs=int(12 * pairs))
    assert fewer.frames == 12
    least = refine_top_camera(top, hors, top_boxes, hor_boxes, max_pairs=1)
    assert least.frames == MIN_REFINE_FRAMES


@pytest.mark.slow
def test_a_camera_beyond_the_grid_is_found_by_the_wider_search() -> None:
    # 11 degrees off: the fit within the 4-degree grid stays poor (a wrong turn), so the wider
    # 2-degree grid out to 10 is searched and finds it; without it (wide_deg at the grid's own
    # 4 degrees) the camera stays far off.
    top, hors, top_boxes, hor_boxes = _scene(9)
    wrong = _turned(top, 11.0 * np.array([0.0, 1.0, 1.0]) / np.sqrt(2.0))
    fit = refine_top_camera(wrong, hors, top_boxes, hor_boxes)
    assert _angle(fit.camera, top) < 0.3
    narrow = refine_top_camera(wrong, hors, top_boxes, hor_boxes, wide_deg=4.0)
    assert _angle(narrow.camera, top) > 5.0
    assert WIDE_LOSS < narrow.loss_after
    assert fit.loss_after < narrow.loss_after



def _flying_scene(seed: int, frames: int = 24):
    """The walking scene seen from a drone in flight: its camera 25 degrees off nadir, 20 m up,
    moving 1 m and turning 2 degrees about the vertical every frame; each frame's exact top
    camera, the egocentric cameras and the boxes."""
    _, hors, _, hor_boxes = _scene(seed, frames)
    rng = np.random.default_rng(seed)
    start = rng.uniform(-8, 8, (14, 2))
    velocity = rng.normal(0, 1.2, (14, 2))
    height = rng.uniform(1.55, 1.9, 14)
    tops, top_boxes = [], []
    for f, hor in enumerate(hors):
        xy = start + velocity * f / 5.0
        heads = np.vstack([np.column_stack([xy, height]), [[*hor.c[:2], 1.75]]])
        yaw = np.radians(90.0 + 2.0 * f)
        top = Camera(K=intrinsics_from_fov(*TOP_SIZE, 70.0), R=look_rotation(yaw, np.radians(65)),
                     c=np.array([-12.0 + 1.0 * f, -9.0, 20.0]), width=TOP_SIZE[0],
                     height=TOP_SIZE[1])
        tops.append(top)
        top_boxes.append(_boxes(top, heads))
    return tops, hors, top_boxes, hor_boxes


def _mounted(camera: Camera, rotvec_deg: np.ndarray) -> Camera:
    """``camera`` turned by ``rotvec_deg`` in its own frame (a mount offset: ``R' = B R``)."""
    b = Rotation.from_rotvec(np.radians(rotvec_deg)).as_matrix()
    return Camera(K=camera.K, R=b @ camera.R, c=camera.c, width=camera.width,
                  height=camera.height)


@pytest.mark.slow
@pytest.mark.parametrize("frame", ["camera", "world"])
def test_a_flying_camera_has_its_constant_error_found(frame) -> None:
    # A drone's telemetry with a 2.5-degree error that stays the same in the camera's frame
    # (its mount) or in the world (its heading and level): each frame's camera is turned back,
    # and the turn is read in the right frame (the camera turns 46 degrees over the clip, so
    # the other reading misses by degrees at its ends).
    tops, hors, top_boxes, hor_boxes = _flying_scene(4)
    bias = np.array([1.5, -1.6, 1.2])
    wrong = [_mounted(t, bias) if frame == "camera" else _turned(t, bias) for t in tops]
    assert all(_angle(w, t) > 2.0 for w, t in zip(wrong, tops, strict=True))
    fit = refine_top_camera(wrong, hors, top_boxes, hor_boxes)
    assert fit.frame == frame and fit.reference is wrong[0]
    assert max(_angle(fit.turn(w), t) for w, t in zip(wrong, tops, strict=True)) < 0.3
    assert _angle(fit.camera, tops[0]) < 0.3 and fit.loss_after < fit.loss_before
    assert f"in {'its own frame' if frame == 'camera' else 'the world'}" in fit.describe()


@pytest.mark.slow
def test_an_exact_flying_camera_is_left_about_where_it_was() -> None:
    tops, hors, top_boxes, hor_boxes = _flying_scene(6)
    fit = refine_top_camera(tops, hors, top_boxes, hor_boxes)
    assert fit.frame in ("camera", "world") and fit.angle_deg < 0.2
    assert fit.loss_after <= fit.loss_before  # not 0: some heads leave the drone's view
    # equal cameras in a sequence are one fixed camera, and its search is the fixed one's
    n = MIN_REFINE_FRAMES
    fixed = refine_top_camera([tops[0]] * n, [hors[0]] * n, [top_boxes[0]] * n,
                              [hor_boxes[0]] * n)
    assert fixed.frame == "fixed" and fixed.reference is None


def test_the_batched_rays_of_a_flying_camera_are_eqs_6_and_7() -> None:
    # Each frame's turn A_f^T Q A_f: the batched distances are those of fit.turn's camera.
    from xvmatch.geometry.ray_priors import (
        METRIC_MARGIN,
        box_rays,
        cheirality_mask,
        ray_distances,
    )
    from xvmatch.geometry.top_camera_refinement import (
        _MISS,
        TopCameraRefinement,
        _RayFrames,
    )

    tops, hors, top_boxes, hor_boxes = _flying_scene(5, frames=12)
    rotvec = (0.7, -1.1, 2.0)
    relative = np.stack([tops[0].R.T @ t.R for t in tops])
    rays = _RayFrames(tops, hors, top_boxes, hor_boxes, METRIC_MARGIN, turns=relative)
    batched, _ = rays.distances(np.array(rotvec))
    fit = TopCameraRefinement(tops[0], rotvec, float(np.linalg.norm(rotvec)), 12, 1.0, 1.0,
                              frame="camera", reference=tops[0])
    for k, (top, hor, tb, hb) in enumerate(zip(tops, hors, top_boxes, hor_boxes, strict=True)):
        rt, rh = box_rays(fit.turn(top), tb), box_rays(hor, hb)
        ok = cheirality_mask(rt, rh, margin=METRIC_MARGIN)
        want = np.where(ok, ray_distances(rt, rh), _MISS)
        np.testing.assert_allclose(batched[k, :len(tb), :len(hb)], want, rtol=1e-9, atol=1e-9)
    assert fit.turn(tops[0]).R.tolist() == _turned(tops[0], rotvec).R.tolist()


def _rays(seed: int = 5):
    """The search's frames of a scene whose top view sees only two people every other frame."""
    from xvmatch.geometry.ray_priors import METRIC_MARGIN
    from xvmatch.geometry.top_camera_refinement import _RayFrames

    top, hors, top_boxes, hor_boxes = _scene(seed, frames=12)
    top_boxes = [b[:2] if k % 2 else b for k, b in enumerate(top_boxes)]
    return _RayFrames(top, hors, top_boxes, hor_boxes, METRIC_MARGIN)


@settings(max_examples=30, deadline=None, phases=[Phase.generate])
@given(st.integers(0, 2**32 - 1), st.sampled_from([(0.1, 0.5, 0.9), (0.2, 0.2, 0.7), None]))
def test_the_least_pairing_is_the_hungarian_ones(seed: int, levels) -> None:
    # Each frame's least one-to-one sum (every head of the smaller view paired) is the
    # Hungarian method's, ties included (few levels), the unpaired heads priced 1 each.
    from scipy.optimize import linear_sum_assignment

    rays = _rays()
    rng = np.random.default_rng(seed)
    shape = (3, *rays.top_mask.shape, rays.hor_mask.shape[1])
    rho = rng.uniform(0, 1, shape) if levels is None else rng.choice(levels, shape)
    want = np.zeros(3)
    for g in range(3):
        for k, (m, n) in enumerate(rays.sizes):
            r, c = linear_sum_assignment(rho[g, k, :m, :n])
            want[g] += rho[g, k, r, c].sum() + n - len(r)
    np.testing.assert_allclose(rays._assigned(rho), want, rtol=1e-12)
    assert {m <= n for m, n in rays.sizes} == {True, False}  # both kinds of frame


def test_the_grids_losses_are_the_searchs() -> None:
    # The grid's batched losses, taken a few turns at a time, are the search's one by one.
    from xvmatch.geometry import top_camera_refinement as refinement

    rays = _rays()
    turns = np.random.default_rng(0).normal(0, 3, (7, 3))
    one_by_one = [rays.loss(x, 0.5) for x in turns]
    assert rays.losses(turns, 0.5).tolist() == one_by_one
    small = refinement._CHUNK
    try:
        refinement._CHUNK = 1
        assert rays.losses(turns, 0.5).tolist() == one_by_one
    finally:
        refinement._CHUNK = small
