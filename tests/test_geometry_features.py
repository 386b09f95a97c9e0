"""Box-only features of the learned geometry model: shapes, invariance, labels, cache, batching."""

from __future__ import annotations

import numpy as np
import pytest

from xvmatch.cues.spatial_features import (
    FEATURE_VERSION,
    HOR_FEATURES,
    HYP_FEATURES,
    PAIR_FEATURES,
    TOP_FEATURES,
    FeatureConfig,
    camera_labels,
    collate_frames,
    frame_features,
    match_labels,
)
from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene
from xvmatch.datasets.feature_cache import FeatureSet, cached_sequence_features, sequence_features

SIZE = (2688, 1512)
CONFIG = FeatureConfig(n_hypotheses=4, dtheta_deg=3.0)


@pytest.fixture(scope="module")
def scene():
    return simulate_box_scene(SceneConfig(n_people=(7, 9)), n_frames=6, seed=3)


def _frame(scene, f=2):
    return scene.top[f], scene.hor[f]


def test_shapes_and_names(scene):
    top, hor = _frame(scene)
    f = frame_features(top.boxes, hor.boxes, SIZE, CONFIG)
    m, n = len(top), len(hor)
    h = f.hyp.shape[0]
    assert 1 <= h <= CONFIG.n_hypotheses
    assert f.top.shape == (m, len(TOP_FEATURES))
    assert f.hor.shape == (n, len(HOR_FEATURES))
    assert f.hyp.shape == (h, len(HYP_FEATURES))
    assert f.pair.shape == (h, m, n, len(PAIR_FEATURES))
    assert f.shape == (h, m, n)
    for arr in (f.top, f.hor, f.hyp, f.pair):
        assert arr.dtype == np.float32 and np.isfinite(arr).all()
    # Hypotheses are sorted by cost and have distinct cameras when O is searched.
    assert np.all(np.diff(f.hyp[:, HYP_FEATURES.index("log_cost")]) >= 0)
    assert len(set(f.hyp_camera.tolist())) == h
    # Exactly one is_camera row per hypothesis, and it is that hypothesis' camera.
    is_cam = f.pair[:, :, 0, PAIR_FEATURES.index("is_camera")]
    assert np.array_equal(np.argmax(is_cam, axis=1), f.hyp_camera)


def test_invariant_to_box_order(scene):
    top, hor = _frame(scene)
    rng = np.random.default_rng(0)
    pt, ph = rng.permutation(len(top)), rng.permutation(len(hor))
    a = frame_features(top.boxes, hor.boxes, SIZE, CONFIG)
    b = frame_features(top.boxes[pt], hor.boxes[ph], SIZE, CONFIG)
    for name in ("top", "hor", "hyp", "pair", "hyp_camera"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    # The orders point at the same boxes.
    assert np.array_equal(top.boxes[a.top_order], top.boxes[pt][b.top_order])
    assert np.array_equal(hor.boxes[a.hor_order], hor.boxes[ph][b.hor_order])


def test_labels_follow_ids(scene):
    top, hor = _frame(scene)
    f = frame_features(top.boxes, hor.boxes, SIZE, CONFIG)
    match = match_labels(f, top.ids, hor.ids)
    assert match.shape == (len(top), len(hor))
    assert match.sum() == len(set(top.ids.tolist()) & set(hor.ids.tolist()))
    rows, cols = np.nonzero(match)
    assert np.array_equal(top.ids[f.top_order[rows]], hor.ids[f.hor_order[cols]])
    cams = camera_labels(f, top.ids, wearer_id=0)
    assert cams.shape == (f.shape[0],)
    assert np.array_equal(cams, top.ids[f.top_order[f.hyp_camera]] == 0)


def test_camera_given(scene):
    top, hor = _frame(scene)
    wearer = int(np.flatnonzero(top.ids == 0)[0])
    f = frame_features(top.boxes, hor.boxes, SIZE, CONFIG, camera=wearer)
    assert f.shape[0] >= 1
    assert np.all(f.top_order[f.hyp_camera] == wearer)
    assert np.all(f.hyp[:, HYP_FEATURES.index("camera_given")] == 1.0)
    assert camera_labels(f, top.ids).all()


@pytest.mark.parametrize("m, n", [(0, 3), (4, 0), (0, 0), (1, 3)])
def test_empty_or_tiny_sides(scene, m, n):
    top, hor = _frame(scene)
    f = frame_features(top.boxes[:m], hor.boxes[:n], SIZE, CONFIG)
    assert f.shape == (0, m, n)  # no hypothesis without two top boxes and one horizontal box
    assert f.top.shape == (m, len(TOP_FEATURES)) and f.hor.shape == (n, len(HOR_FEATURES))
    assert np.isfinite(f.top).all() and np.isfinite(f.hor).all()


def test_bad_input(scene):
    top, hor = _frame(scene)
    bad = hor.boxes.copy()
    bad[0, 3] = 0.0
    with pytest.raises(ValueError, match="hor_boxes has a box of zero"):
        frame_features(top.boxes, bad, SIZE, CONFIG)
    with pytest.raises(ValueError, match=r"hor_size must be \(width, height\)"):
        frame_features(top.boxes, hor.boxes, (0, 10), CONFIG)
    with pytest.raises(ValueError, match="camera must index"):
        frame_features(top.boxes, hor.boxes, SIZE, CONFIG, camera=99)
    with pytest.raises(ValueError, match=r"top_boxes must have shape \(N, 4\)"):
        frame_features(np.zeros((3, 3)), hor.boxes, SIZE, CONFIG)
    with pytest.raises(ValueError, match="unknown feature configuration key"):
        FeatureConfig.from_dict({"n_hypotheses": 2, "bogus": 1})
    with pytest.raises(ValueError, match="n_hypotheses"):
        FeatureConfig(n_hypotheses=0)


def test_feature_set_round_trip_and_cache(scene, tmp_path, monkeypatch):
    feats = sequence_features(scene.top, scene.hor, SIZE, CONFIG, frames=[1, 3, 5])
    assert feats.frames.tolist() == [1, 3, 5]
    single = frame_features(scene.top[3].boxes, scene.hor[3].boxes, SIZE, CONFIG)
    assert np.array_equal(feats.frame(1).pair, single.pair)
    path = tmp_path / "f.npz"
    feats.save(path)
    loaded = FeatureSet.load(path)
    for k in range(len(feats)):
        a, b = feats.frame(k), loaded.frame(k)
        assert np.array_equal(a.pair, b.pair) and np.array_equal(a.top_order, b.top_order)

    first = cached_sequence_features(scene.top, scene.hor, SIZE, CONFIG, frames=[1, 3],
                                     cache_dir=tmp_path)
    stored = list((tmp_path / "geometry_features").glob("*.npz"))
    assert len(stored) == 1

    def fail(*args, **kwargs):
        raise AssertionError("the cache should have been used")

    monkeypatch.setattr("xvmatch.datasets.feature_cache.sequence_features", fail)
    again = cached_sequence_features(scene.top, scene.hor, SIZE, CONFIG, frames=[1, 3],
                                     cache_dir=tmp_path)
    assert np.array_equal(first.arrays["pair"], again.arrays["pair"])
    with pytest.raises(AssertionError, match="cache"):  # another configuration: another key
        cached_sequence_features(scene.top, scene.hor, SIZE, FeatureConfig(n_hypotheses=2),
                                 frames=[1, 3], cache_dir=tmp_path)


def test_stale_cache_version_is_reported(tmp_path, scene):
    feats = sequence_features(scene.top, scene.hor, SIZE, CONFIG, frames=[1])
    path = tmp_path / "f.npz"
    feats.save(path)
    data = dict(np.load(path))
    data["feature_version"] = np.array(FEATURE_VERSION + 1)
    np.savez(path, **data)
    with pytest.raises(ValueError, match="feature version"):
        FeatureSet.load(path)


def test_collate_pads_with_masks(scene):
    a = frame_features(scene.top[1].boxes, scene.hor[1].boxes, SIZE, CONFIG)
    b = frame_features(scene.top[2].boxes[:3], scene.hor[2].boxes[:1], SIZE, CONFIG)
    empty = frame_features(np.zeros((0, 4)), np.zeros((0, 4)), SIZE, CONFIG)
    batch = collate_frames([a, b, empty])
    h, m, n = a.shape
    assert batch["pair"].shape[:4] == (3, max(h, b.shape[0]), m, n)
    assert batch["top_mask"].sum(axis=1).tolist() == [m, 3, 0]
    assert batch["hor_mask"].sum(axis=1).tolist() == [n, 1, 0]
    assert batch["hyp_mask"].sum(axis=1).tolist() == [h, b.shape[0], 0]
    assert np.array_equal(batch["pair"][0, :h, :m, :n], a.pair)
    assert not batch["pair"][1, :, 3:].any() and not batch["pair"][2].any()
    one = collate_frames([empty])
    assert one["pair"].shape[:4] == (1, 1, 1, 1)  # never an empty dimension


def test_frame_median_is_numpys_to_the_bit():
    # The features' median (three per frame) replaces np.median for speed (issue 70): the same
    # bits on odd and even lengths, ties, signed zeros and huge values.
    from xvmatch.cues.spatial_features import _median

    rng = np.random.default_rng(7)
    for n in range(1, 30):
        for scale in (1e-3, 1.0, 1e300):
            for values in (rng.normal(size=n) * scale, np.round(rng.normal(size=n), 1),
                           rng.choice([0.0, -0.0, 1.0, -1.0], size=n)):
                assert np.float64(_median(values)).tobytes() == \
                    np.float64(np.median(values)).tobytes(), values
