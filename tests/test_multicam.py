"""Tests of the multi-camera association (xvmatch.inference.views.multicam) and its scores
(xvmatch.metrics.multicam_metrics): tiny scenes whose answer is known, the conflict rule,
id scrambling, and the metrics on hand-built toy sequences."""

from __future__ import annotations

import math

import numpy as np
import pytest

from xvmatch.datasets.detector_noise import DetectorNoise
from xvmatch.datasets.multicam_scenes import (
    MulticamConfig,
    TrackerNoise,
    add_tracker_noise,
    simulate_multicam_scene,
)
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.geometry.camera import Camera, intrinsics_from_fov, look_rotation
from xvmatch.geometry.ground_plane import GroundCamera
from xvmatch.inference.views.multicam import (
    MulticamInputError,
    MulticamOptions,
    associate_cameras,
    dtw_distances,
    relabel,
    trajectory_features,
)
from xvmatch.metrics.multicam_metrics import multicam_scores


def _cam(azimuth: float, height: float = 5.0, dist: float = 12.0) -> Camera:
    c = np.array([dist * math.cos(azimuth), dist * math.sin(azimuth), height])
    yaw = azimuth + math.pi
    pitch = math.atan2(height, dist)
    return Camera(intrinsics_from_fov(1280, 720, 70.0), look_rotation(yaw, pitch), c, 1280, 720)


def _boxes(cam: Camera, paths: np.ndarray, ids: list[int]) -> dict[int, FrameBoxes]:
    """Upright 1.7 m x 0.5 m people at ``paths[f, k]`` as boxes with the given ids."""
    out = {}
    for f in range(paths.shape[0]):
        rows = []
        for xy in paths[f]:
            pts = np.array([[xy[0], xy[1], 0.0], [xy[0], xy[1], 1.7]])
            uv, _ = cam.project(pts)
            h = uv[0, 1] - uv[1, 1]
            rows.append([uv[0, 0] - 0.15 * h, uv[1, 1], 0.3 * h, h])
        out[f + 1] = FrameBoxes(f + 1, np.array(ids), np.array(rows))
    return out


def _two_walkers(n_frames: int = 40) -> np.ndarray:
    t = np.linspace(0.0, 1.0, n_frames)[:, None]
    a = np.concatenate([-3 + 6 * t, -1 + 0 * t], axis=1)
    b = np.concatenate([1 + 0 * t, 3 - 6 * t], axis=1)
    return np.stack([a, b], axis=1)


def test_two_cameras_two_walkers_known_answer():
    paths = _two_walkers()
    cam_a, cam_b = _cam(0.0), _cam(2.0)
    boxes = {"a": _boxes(cam_a, paths, [7, 3]), "b": _boxes(cam_b, paths, [40, 11])}
    cams = {"a": GroundCamera.from_camera(cam_a), "b": GroundCamera.from_camera(cam_b)}
    for method in ("ours", "dtw"):
        res = associate_cameras(cams, boxes, MulticamOptions(method=method))
        assert res.global_ids["a"][7] == res.global_ids["b"][40]
        assert res.global_ids["a"][3] == res.global_ids["b"][11]
        assert res.global_ids["a"][7] != res.global_ids["a"][3]
        g = res.global_ids["a"][7]
        frames, xy = res.ground[g]
        np.testing.assert_array_equal(frames, np.arange(1, 41))
        assert np.abs(xy - paths[:, 0]).max() < 0.05


def test_linkage_across_a_gap_no_camera_covers():
    """A person seen by camera a, then (after 5 unseen frames) by camera b only: linkage joins
    the two segments into one global trajectory (Eq. 12)."""
    t = np.linspace(0.0, 1.0, 50)[:, None]
    path = np.concatenate([-4 + 8 * t, 0 * t], axis=1)[:, None, :]
    cam_a, cam_b = _cam(0.3), _cam(2.5)
    a = {f: r for f, r in _boxes(cam_a, path, [5]).items() if f <= 20}
    b = {f: r for f, r in _boxes(cam_b, path, [9]).items() if f >= 26}
    cams = {"a": GroundCamera.from_camera(cam_a), "b": GroundCamera.from_camera(cam_b)}
    res = associate_cameras(cams, {"a": a, "b": b})
    assert res.global_ids["a"][5] == res.global_ids["b"][9]
    assert res.links == []  # never seen together: linked, not associated


def _noisy_scene(seed: int = 2):
    scene = simulate_multicam_scene(MulticamConfig(n_cameras=4, n_people=(10, 10)), 80, seed)
    return add_tracker_noise(scene, TrackerNoise(DetectorNoise(0.05, 0.1, 0.3), 0.05, 0.3), 1)


@pytest.mark.parametrize("split", [0, 20])
def test_conflicts_never_put_a_trajectory_in_two_places(split):
    scene = _noisy_scene()
    cams = {n: GroundCamera.from_camera(c) for n, c in scene.cameras.items()}
    res = associate_cameras(cams, scene.boxes, MulticamOptions(split_frames=split))
    # Every input track has a global id.
    for name, frames in scene.boxes.items():
        tracks = {int(t) for rec in frames.values() for t in rec.ids}
        assert set(res.global_ids[name]) == tracks
    if split == 0:  # whole tracks: one joins at most one trajectory of every other camera
        seen = set()
        for a, ta, b, tb in res.links:
            assert (a, ta, b) not in seen and (b, tb, a) not in seen
            seen |= {(a, ta, b), (b, tb, a)}
    # No global id holds two boxes of one camera at one frame, and a track keeps its global
    # id within a piece.
    relabelled = relabel(scene.boxes, res)
    for name, frames in relabelled.items():
        owner: dict[tuple[int, int], int] = {}
        for f, rec in frames.items():
            assert len(np.unique(rec.ids)) == len(rec.ids)
            piece = 0 if split == 0 else int(np.searchsorted(res.frames, f)) // split
            for t, g in zip(scene.boxes[name][f].ids.tolist(), rec.ids.tolist(), strict=True):
                assert owner.setdefault((t, piece), g) == g


def test_answer_does_not_depend_on_the_ids():
    scene = simulate_multicam_scene(MulticamConfig(n_cameras=3, n_people=(8, 8)), 60, 5)
    cams = {n: GroundCamera.from_camera(c) for n, c in scene.cameras.items()}
    rng = np.random.default_rng(0)
    renamed = {}
    for name, frames in scene.boxes.items():
        ids = np.unique(np.concatenate([r.ids for r in frames.values()]))
        new = dict(zip(ids.tolist(), rng.permutation(5000)[: len(ids)].tolist(), strict=True))
        renamed[name] = {f: FrameBoxes(f, np.array([new[int(i)] for i in r.ids], np.int64),
                                       r.boxes) for f, r in frames.items()}
    a = relabel(scene.boxes, associate_cameras(cams, scene.boxes))
    b = relabel(renamed, associate_cameras(cams, renamed))
    # The same partition of the boxes (global ids may be numbered alike or not).
    pairs = {(x, y) for n in a for f in a[n] for x, y in zip(a[n][f].ids, b[n][f].ids,
                                                             strict=True)}
    assert len({x for x, _ in pairs}) == len(pairs) == len({y for _, y in pairs})


@pytest.mark.slow
def test_simulated_scene_scores_well_and_beats_dtw():
    scene = simulate_multicam_scene(MulticamConfig(n_cameras=4, n_people=(12, 12)), 150, 1)
    cams = {n: GroundCamera.from_camera(c) for n, c in scene.cameras.items()}
    ours = multicam_scores(relabel(scene.boxes, associate_cameras(cams, scene.boxes)), scene.gt)
    assert ours["P"] >= 0.95 and ours["R"] >= 0.9 and ours["idf1"]["IDF1"] >= 0.9
    dtw = multicam_scores(relabel(scene.boxes, associate_cameras(
        cams, scene.boxes, MulticamOptions(method="dtw"))), scene.gt)
    assert ours["R"] >= dtw["R"]


def test_bad_input_is_named():
    paths = _two_walkers(10)
    cam = _cam(0.0)
    boxes = {"a": _boxes(cam, paths, [1, 2]), "b": _boxes(cam, paths, [1, 2])}
    with pytest.raises(MulticamInputError, match="camera 'b' has boxes but no calibration"):
        associate_cameras({"a": GroundCamera.from_camera(cam)}, boxes)
    with pytest.raises(ValueError, match="at least two cameras"):
        associate_cameras({"a": GroundCamera.from_camera(cam)}, {"a": boxes["a"]})
    low = _cam(0.0, height=3.0, dist=30.0)  # looks nearly level: the sky is in its image
    sky = _boxes(low, paths, [1, 2])
    sky[3] = FrameBoxes(3, np.array([9]), np.array([[600.0, 0.0, 20.0, 10.0]]))
    with pytest.raises(MulticamInputError, match=r"frame 3, id 9: .* behind the camera"):
        associate_cameras({"a": GroundCamera.from_camera(cam),
                           "b": GroundCamera.from_camera(low)}, {"a": boxes["a"], "b": sky})


def test_features_and_dtw():
    t = np.linspace(0, 1, 16)[:, None]
    line = np.concatenate([t, 0 * t], axis=1)[None]
    f = trajectory_features(np.concatenate([line, line + np.array([5.0, 0.0]), 2 * line]))
    assert f.shape == (3, 18)
    np.testing.assert_allclose(f[1, 12:14] - f[0, 12:14], [5.0, 0.0])  # the mean, Eq. 4
    np.testing.assert_allclose(f[2, 7:9], 2 * f[0, 7:9])  # average velocity, Eq. 2
    np.testing.assert_allclose(f[0, 6], 1.0)  # length
    up = line + np.array([0.0, 1.0])
    d = dtw_distances(np.concatenate([line, line]), np.concatenate([line, up]))
    np.testing.assert_allclose(d, [0.0, 1.0])


def _fb(frame, ids, n=None):
    ids = np.array(ids, dtype=np.int64)
    boxes = np.array([[10.0 * k, 0, 5, 10] for k in range(len(ids))]).reshape(-1, 4)
    return FrameBoxes(frame, ids, boxes)


def test_metrics_on_a_toy_sequence():
    """Two cameras, two frames; person 1 right, person 2 split into two predicted ids in
    camera b at frame 2."""
    gt = {"a": {1: _fb(1, [1, 2]), 2: _fb(2, [1, 2])}, "b": {1: _fb(1, [1, 2]),
                                                          2: _fb(2, [1, 2])}}
    pred = {"a": {1: _fb(1, [10, 20]), 2: _fb(2, [10, 20])},
            "b": {1: _fb(1, [10, 20]), 2: _fb(2, [10, 30])}}
    s = multicam_scores(pred, gt)
    # Trajectories: xi = {1, 2}; E = {10, 20} (30 is only in b) and both correct.
    assert (s["P"], s["R"]) == (1.0, 1.0)
    # Box pairs: true 4 (2 per frame), predicted 3 (10 and 20 at frame 1, 10 at frame 2).
    assert s["box_pairs"]["P"] == 1.0 and s["box_pairs"]["R"] == pytest.approx(3 / 4)
    # IDF1: 8 boxes each side; 10->1 (4), 20->2 (3), 30 unmatched: IDTP 7.
    assert s["idf1"]["IDF1"] == pytest.approx(7 / 8)
    ground = {1: (np.array([1, 2]), np.array([[0.0, 0], [1, 0]]))}
    s = multicam_scores(pred, gt, {10: (np.array([1, 2]), np.array([[0.0, 0.5], [1, 0]]))},
                        ground)
    assert s["ground"]["median"] == pytest.approx(0.25) and s["ground"]["count"] == 2


def test_row_nanmedian_matches_numpy():
    from xvmatch.inference.views.multicam import _row_nanmedian

    rng = np.random.default_rng(0)
    d = rng.random((50, 9))
    d[rng.random(d.shape) < 0.4] = np.nan
    d[3] = np.nan
    with np.errstate(all="ignore"), pytest.warns(RuntimeWarning):
        want = np.nanmedian(d, axis=1)
    np.testing.assert_allclose(_row_nanmedian(d), want)
