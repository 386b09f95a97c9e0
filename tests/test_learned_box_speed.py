"""The learned box path's speed-ups keep every bit (issue 70): each faster form against the
definition it replaces, on the same inputs, in numpy and in the compiled kernels."""

from __future__ import annotations

import math

import numpy as np
import pytest

from xvmatch.core import kernel_choice
from xvmatch.cues.spatial_features import FeatureConfig, _hypotheses, _wrap, frame_features
from xvmatch.cues.spatial_search import _group_seeds
from xvmatch.cues.spatial_vectors import REFERENCE_SIZE, box_centres, top_geometry
from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene


def _seeds_by_sort(loose: np.ndarray, n_theta: int) -> np.ndarray:
    """The definition: a sort by (bound, index), each group's first row, finite ones."""
    order = np.lexsort((np.arange(loose.shape[0]), loose))
    _, first = np.unique(order // n_theta, return_index=True)
    seed = np.sort(order[first])
    return seed[np.isfinite(loose[seed])]


@pytest.mark.parametrize("special", ["none", "ties", "inf", "nan"])
def test_group_seeds_are_the_sorts_first_rows(special):
    rng = np.random.default_rng(7)
    for n_theta, n_groups in ((1, 5), (3, 1), (360, 9), (7, 13)):
        loose = rng.random(n_groups * n_theta)
        if special == "ties":
            loose = np.round(loose * 3) / 3  # many equal bounds in a group
        elif special == "inf":
            loose[rng.random(loose.shape) < 0.5] = np.inf
            loose[:n_theta] = np.inf  # a group with no finite bound
        elif special == "nan":
            loose[rng.random(loose.shape) < 0.2] = np.nan
        np.testing.assert_array_equal(_group_seeds(loose, n_theta),
                                      _seeds_by_sort(loose, n_theta))


def _pair_features_in_float64(top, hor, size, config, camera):
    """The pair and hypothesis features as they were built before issue 70: in float64, one
    concatenation, cast to float32 at the end (the reference of the direct float32 writes)."""
    from xvmatch.cues.spatial_vectors import horizontal_vectors

    width = size[0]
    m, n = top.shape[0], hor.shape[0]
    s_top = float(np.median(np.sqrt(top[:, 2] * top[:, 3])))
    centres = box_centres(top)
    vectors, rows = horizontal_vectors(hor, width)
    x_hor, y_hor = np.empty(n), np.empty(n)
    x_hor[rows], y_hor[rows] = vectors[:, 0], vectors[:, 1]
    hyps, _ = _hypotheses(top, hor, width, config, camera)
    n_hyp = len(hyps)
    half_fov = 0.5 * math.radians(config.fov_deg)
    hyp_camera = np.array([h.camera for h in hyps], dtype=np.int64)
    bearing_hor = np.arctan(x_hor * math.tan(half_fov))
    log_y_hor = np.log(y_hor)
    thetas = np.array([h.theta for h in hyps])
    scales = np.array([h.scale for h in hyps])
    geometry = top_geometry(centres, hyp_camera, math.radians(config.tau_deg))
    dist, visible = geometry.dist, geometry.visible
    delta = _wrap(geometry.phi - thetas[:, None])
    in_view = (np.abs(delta) < half_fov) & visible
    y_top = dist * np.cos(delta)
    bearing_top = -delta
    diff = np.clip(_wrap(bearing_top[:, :, None] - bearing_hor[None, None, :]) / half_fov, -3, 3)
    depth = np.maximum(y_top, 0.05 * dist) * scales[:, None]
    ratio = np.clip(np.log(np.maximum(depth, 1e-12))[:, :, None] - log_y_hor[None, None, :],
                    -3, 3)
    matched = np.zeros((n_hyp, m, n))
    for h, hyp in enumerate(hyps):
        if hyp.pairs.size:
            matched[h, hyp.pairs[:, 0], hyp.pairs[:, 1]] = 1.0
    absdiff = np.abs(diff)
    row_gap = absdiff - absdiff.min(axis=2, keepdims=True)
    col_ref = np.where(visible[:, :, None], absdiff, np.inf).min(axis=1, keepdims=True)
    col_gap = np.clip(absdiff - np.where(np.isfinite(col_ref), col_ref, 0.0), 0, 3)
    is_cam = np.arange(m)[None, :] == hyp_camera[:, None]
    per_top = np.stack([in_view, visible, is_cam, np.abs(bearing_top) / math.pi],
                       axis=2).astype(float)
    log_dist = np.clip(np.log(np.maximum(dist, 1e-6) / s_top), -3, 6)
    pair = np.concatenate([diff[..., None], absdiff[..., None], ratio[..., None],
                           np.abs(ratio)[..., None], matched[..., None],
                           np.broadcast_to(per_top[:, :, None, :], (n_hyp, m, n, 4)),
                           row_gap[..., None], col_gap[..., None],
                           np.broadcast_to(log_dist[:, :, None, None], (n_hyp, m, n, 1))],
                          axis=3)
    log_cost = np.log(np.array([max(h.cost, 1e-12) for h in hyps]))
    hyp = np.column_stack([
        np.clip(log_cost / 5.0, -3, 3),
        np.minimum(log_cost - log_cost[0], 10.0) / 5.0,
        np.arange(n_hyp) / config.n_hypotheses,
        np.array([h.pairs.shape[0] for h in hyps]) / n,
        in_view.sum(axis=1) / n,
        np.clip(np.log(np.maximum(scales * s_top * REFERENCE_SIZE[1], 1e-12)), -10, 10) / 5.0,
        np.full(n_hyp, float(camera is not None)),
    ])
    return pair.astype(np.float32), hyp.astype(np.float32)


@pytest.mark.parametrize("kernels", ["numpy", "compiled"])
@pytest.mark.parametrize("camera", [None, 0])
def test_features_written_in_float32_are_the_float64_ones_cast(kernels, camera):
    if kernels == "compiled":
        pytest.importorskip("numba")
    scene = simulate_box_scene(SceneConfig(n_people=(7, 9)), n_frames=3, seed=3)
    size = (2688.0, 1512.0)
    with kernel_choice.forced(kernels):
        for frame in sorted(scene.top)[:3]:
            top, hor = scene.top[frame].boxes, scene.hor[frame].boxes
            feats = frame_features(top, hor, size, FeatureConfig(), camera)
            order_top, order_hor = feats.top_order, feats.hor_order
            cam = None if camera is None else int(np.flatnonzero(order_top == camera)[0])
            pair, hyp = _pair_features_in_float64(top[order_top], hor[order_hor], size,
                                                  FeatureConfig(), cam)
            assert feats.pair.dtype == np.float32 and feats.hyp.dtype == np.float32
            assert feats.pair.shape[0] > 0
            assert feats.pair.tobytes() == pair.tobytes()
            assert feats.hyp.tobytes() == hyp.tobytes()


def test_the_searchs_geometry_is_top_geometrys_in_blocks_too(monkeypatch):
    # The features read the search's geometry of each hypothesis' O instead of computing it
    # again: each row depends on its O alone, so it is top_geometry's to the bit, whatever the
    # blocks of candidates the search ran in.
    from xvmatch.cues import spatial_search

    rng = np.random.default_rng(5)
    top = np.column_stack([rng.uniform(0, 800, (14, 2)), np.full((14, 2), 20.0)])
    hor = np.column_stack([rng.uniform(0, 2400, 5), np.full(5, 400.0), np.full(5, 60.0),
                           rng.uniform(150, 400, 5)])
    expected = top_geometry(box_centres(top), np.arange(14), math.radians(2.0))
    size = (2688.0, 1512.0)
    whole = frame_features(top, hor, size)
    for block in (None, 3 * 360 * 14):  # one block; blocks of 3 candidates
        if block is not None:
            monkeypatch.setattr(spatial_search, "HYPOTHESIS_BLOCK", block)
        found, geometry = spatial_search._best_per_candidate(top, hor, size[0], keep=8)
        assert found and len(found) == 8
        for name in ("phi", "dist", "visible"):
            assert getattr(geometry, name).tobytes() == getattr(expected, name).tobytes()
        again = frame_features(top, hor, size)
        assert again.pair.tobytes() == whole.pair.tobytes()
        assert again.hyp.tobytes() == whole.hyp.tobytes()


def _sparse_cases(rng, n_cases):
    """Arrays of +0.0 with a few entries (ascending positions), of lengths around NumPy's
    pairwise blocks (8, 128 and the halvings above), with ties, infinities and -0.0 (which
    the sparse sum must leave to the whole array's sum)."""
    for case in range(n_cases):
        n_total = int(rng.choice([rng.integers(1, 9), rng.integers(1, 130), rng.integers(1, 70),
                                  rng.integers(120, 600), rng.integers(1, 3000)]))
        m = int(rng.integers(1, min(n_total, 40) + 1))
        pos = np.sort(rng.choice(n_total, m, replace=False)).astype(np.int64)
        val = rng.random(m) * 10.0 ** rng.uniform(-6, 6, m)
        if case % 4 == 1:
            val = np.round(rng.random(m), 1)  # ties and exact zeros
        if case % 9 == 2:
            val = val * rng.choice([-1.0, 1.0], m)
        if case % 13 == 3:
            val[rng.integers(0, m)] = -0.0
        if case % 17 == 4:
            val[rng.integers(0, m)] = np.inf
        yield pos, val, n_total


def test_kept_pairs_sum_is_numpys_sum_of_the_whole_grid():
    # match_batch adds only the kept pairs' terms (at most one per column) where the numpy form
    # sums the whole padded (rows, columns) grid, zeros elsewhere: the same bits.
    kernels = pytest.importorskip("xvmatch.cues.search_kernels")
    rng = np.random.default_rng(70)
    stack, results = np.empty((64, 4), np.int64), np.empty(64)
    for pos, val, n_total in _sparse_cases(rng, 4000):
        dense = np.zeros(n_total)
        dense[pos] = val
        got = kernels._kept_sum(pos, val, pos.shape[0], n_total, stack, results,
                                np.empty(n_total))
        assert np.float64(got).tobytes() == np.add.reduce(dense).tobytes()
        assert np.float64(got).tobytes() == np.float64(kernels._pairwise_sum(dense)).tobytes()
    # positions out of order: the whole grid is summed instead
    pos, val = np.array([5, 2], np.int64), np.array([0.1, 0.7])
    dense = np.zeros(9)
    dense[pos] = val
    got = kernels._kept_sum(pos, val, 2, 9, stack, results, np.empty(9))
    assert np.float64(got).tobytes() == np.add.reduce(dense).tobytes()


def _scenes_for_the_compiled_search():
    """Frames of simulated scenes, a crowded one (batches past 128 grid cells), and frames on
    a coarse grid (equal costs: the merge's tie rule)."""
    out = []
    for seed, people in ((1, (5, 8)), (2, (9, 14)), (3, (24, 30))):
        scene = simulate_box_scene(SceneConfig(n_people=people), n_frames=3, seed=seed)
        out += [(scene.top[f].boxes, scene.hor[f].boxes) for f in sorted(scene.top)[:3]
                if len(scene.top[f].boxes) > 1 and len(scene.hor[f].boxes)]
    rng = np.random.default_rng(11)
    for _ in range(4):
        top = np.column_stack([np.round(rng.uniform(0, 400, (9, 2)), -2), np.full((9, 2), 20.0)])
        hor = np.column_stack([np.round(rng.uniform(0, 2400, 4), -2), np.full(4, 400.0),
                               np.full(4, 60.0), np.full(4, 300.0)])
        out.append((top, hor))
    return out


@pytest.mark.parametrize("keep", [None, 8, 2])
@pytest.mark.parametrize("block", [None, 3 * 360 * 30])
def test_compiled_best_per_candidate_is_the_numpy_form(keep, block, monkeypatch):
    # The kernels score, merge and keep each batch in one call (the y of Eq. 5 taken once per
    # block): the same hypotheses, costs, scales and pairs as the numpy form, to the bit, also
    # in blocks of candidates.
    pytest.importorskip("numba")
    from xvmatch.cues import spatial_search

    if block is not None:
        monkeypatch.setattr(spatial_search, "HYPOTHESIS_BLOCK", block)
    for top, hor in _scenes_for_the_compiled_search():
        found = {}
        for mode in ("numpy", "compiled"):
            with kernel_choice.forced(mode):
                found[mode] = spatial_search.best_per_candidate(top, hor, 2688.0, keep=keep)
        assert found["compiled"], "nothing matched: the case tests nothing"
        assert len(found["numpy"]) == len(found["compiled"])
        for a, b in zip(found["numpy"], found["compiled"], strict=True):
            assert (a.camera, a.theta) == (b.camera, b.theta)
            assert np.float64(a.cost).tobytes() == np.float64(b.cost).tobytes()
            assert np.float64(a.scale).tobytes() == np.float64(b.scale).tobytes()
            assert a.pairs.dtype == b.pairs.dtype
            np.testing.assert_array_equal(a.pairs, b.pairs)


def test_compiled_features_are_the_numpy_ones_on_a_crowd():
    pytest.importorskip("numba")
    scene = simulate_box_scene(SceneConfig(n_people=(24, 30)), n_frames=2, seed=4)
    for frame in sorted(scene.top)[:2]:
        feats = {}
        for mode in ("numpy", "compiled"):
            with kernel_choice.forced(mode):
                feats[mode] = frame_features(scene.top[frame].boxes, scene.hor[frame].boxes,
                                             (2688.0, 1512.0))
        for name in ("top", "hor", "hyp", "pair", "hyp_camera"):
            assert getattr(feats["numpy"], name).tobytes() == \
                getattr(feats["compiled"], name).tobytes()
