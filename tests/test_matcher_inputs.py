"""The learned matcher's numpy inputs: pair cues, the appearance cost, canonical order, the
camera wearer found from calibrated cameras, order invariance with cameras, and batching."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from xvmatch.cues.matcher_inputs import (
    CUE_NAMES,
    appearance_cost,
    canonical_cues,
    collate_inputs,
    frame_cues,
    matcher_inputs,
    wearer_row,
)
from xvmatch.cues.spatial_features import FeatureConfig, frame_features
from xvmatch.datasets.synthetic_io import SyntheticDataset
from xvmatch.geometry.camera import FrameCameras

CONFIG = FeatureConfig(n_hypotheses=3, dtheta_deg=4.0)
"""Few hypotheses on a coarse orientation grid: fast, and every code path still runs."""

TOP = np.array([[40.0, 30.0, 10.0, 10.0], [10.0, 50.0, 12.0, 11.0], [80.0, 20.0, 9.0, 10.0],
                [60.0, 70.0, 10.0, 12.0]])
HOR = np.array([[300.0, 200.0, 60.0, 180.0], [50.0, 220.0, 50.0, 150.0],
                [900.0, 210.0, 40.0, 120.0]])
SIZE = (1280.0, 720.0)


def test_cue_names_are_the_models_cues():
    from xvmatch.models.cross_view_matcher import CUES

    assert CUE_NAMES == CUES


# --------------------------------------------------------------------------------------------
# frame_cues


def test_frame_cues_in_the_order_asked_with_masks():
    rng = np.random.default_rng(0)
    app = rng.uniform(0, 1, (3, 2))
    ray = rng.uniform(0, 4, (3, 2))
    cheir = np.where(rng.uniform(size=(3, 2)) > 0.5, 1000.0, 0.0)
    cues, mask = frame_cues((3, 2), app=app, ray_distance=ray, cheirality=cheir)
    assert cues.shape == (3, 2, 3) and cues.dtype == np.float32
    assert mask.dtype == bool and mask.tolist() == [True, True, True]
    np.testing.assert_allclose(cues[..., 0], app, rtol=1e-6)
    np.testing.assert_allclose(cues[..., 1], np.tanh(ray), rtol=1e-6)
    np.testing.assert_array_equal(cues[..., 2], (cheir > 0).astype(np.float32))
    # A subset, in the order of CUE_NAMES: cheirality comes second here.
    sub, sub_mask = frame_cues((3, 2), ("app", "cheir"), app=app, ray_distance=ray,
                               cheirality=cheir)
    assert sub.shape == (3, 2, 2) and sub_mask.tolist() == [True, True]
    np.testing.assert_array_equal(sub, cues[..., [0, 2]])


def test_missing_cues_are_zero_and_masked_out():
    app = np.full((2, 4), 0.25)
    cues, mask = frame_cues((2, 4), app=app)
    assert mask.tolist() == [True, False, False]
    assert (cues[..., 0] == 0.25).all() and (cues[..., 1:] == 0).all()
    cues, mask = frame_cues((2, 4), ray_distance=np.full((2, 4), np.inf))
    assert mask.tolist() == [False, True, False]
    assert (cues[..., 0] == 0).all() and (cues[..., 1] == 1).all() and (cues[..., 2] == 0).all()
    cues, mask = frame_cues((2, 4))
    assert not mask.any() and not cues.any()
    cues, mask = frame_cues((0, 3), app=np.zeros((0, 3)))
    assert cues.shape == (0, 3, 3) and mask.tolist() == [True, False, False]


def test_frame_cues_are_clipped_to_the_unit_interval():
    cues, _ = frame_cues((1, 3), ("app",), app=np.array([[-0.5, 0.5, 1.5]]))
    np.testing.assert_array_equal(cues[0, :, 0], [0.0, 0.5, 1.0])


@pytest.mark.parametrize("cue", ["app", "ray_distance", "cheirality"])
def test_frame_cues_reject_a_cue_of_the_wrong_shape(cue):
    name = {"app": "app", "ray_distance": "ray", "cheirality": "cheir"}[cue]
    with pytest.raises(ValueError, match=rf"cue '{name}' has shape \(2, 3\), expected \(3, 2\)"):
        frame_cues((3, 2), **{cue: np.zeros((2, 3))})


def test_frame_cues_reject_an_unknown_cue():
    with pytest.raises(ValueError, match="unknown cue 'depth'"):
        frame_cues((2, 2), ("app", "depth"), app=np.zeros((2, 2)))


# --------------------------------------------------------------------------------------------
# appearance_cost


def test_appearance_cost_of_identical_and_opposite_unit_vectors():
    a = np.eye(4)[:3]
    cost = appearance_cost(a, np.concatenate([a, -a]))
    np.testing.assert_allclose(np.diag(cost[:, :3]), 0.0, atol=1e-7)
    np.testing.assert_allclose(np.diag(cost[:, 3:]), 1.0)
    np.testing.assert_allclose(cost[0, 1], np.sqrt(2.0) / 2)  # orthogonal: |a - b| / 2
    assert appearance_cost(np.zeros((0, 4)), a).shape == (0, 3)


_vectors = hnp.arrays(np.float64, st.tuples(st.integers(1, 5), st.just(6)),
                      elements=st.floats(-1.0, 1.0)).filter(
    lambda v: (np.linalg.norm(v, axis=1) > 1e-3).all())


@settings(max_examples=30, deadline=None)
@given(top=_vectors, hor=_vectors)
def test_appearance_cost_is_half_the_distance_of_unit_vectors_in_0_1(top, hor):
    top = top / np.linalg.norm(top, axis=1, keepdims=True)
    hor = hor / np.linalg.norm(hor, axis=1, keepdims=True)
    cost = appearance_cost(top, hor)
    assert cost.shape == (len(top), len(hor))
    assert ((cost >= 0) & (cost <= 1)).all()
    expected = np.linalg.norm(top[:, None] - hor[None], axis=-1) / 2
    np.testing.assert_allclose(cost, expected, atol=1e-6)
    np.testing.assert_allclose(appearance_cost(hor, top), cost.T, atol=1e-12)


# --------------------------------------------------------------------------------------------
# canonical_cues


def _coded_cues(m: int, n: int, k: int = 3) -> np.ndarray:
    """Cues whose value tells the input row, column and cue: 100 i + 10 j + k."""
    i, j, c = np.meshgrid(np.arange(m), np.arange(n), np.arange(k), indexing="ij")
    return (100 * i + 10 * j + c).astype(np.float32)


def test_canonical_cues_follow_the_features_canonical_order():
    feats = frame_features(TOP, HOR, SIZE, CONFIG)
    cues = _coded_cues(4, 3)
    canon = canonical_cues(cues, feats)
    assert canon.shape == cues.shape
    for a, i in enumerate(feats.top_order):
        for b, j in enumerate(feats.hor_order):
            np.testing.assert_array_equal(canon[a, b], cues[i, j])
    # The canonical order sorts the boxes by x (here all x differ).
    assert (np.diff(TOP[feats.top_order, 0]) > 0).all()
    assert (np.diff(HOR[feats.hor_order, 0]) > 0).all()


def test_canonical_cues_do_not_depend_on_the_input_order():
    cues = _coded_cues(4, 3)
    p, q = np.array([2, 0, 3, 1]), np.array([1, 2, 0])
    a = canonical_cues(cues, frame_features(TOP, HOR, SIZE, CONFIG))
    b = canonical_cues(cues[p][:, q], frame_features(TOP[p], HOR[q], SIZE, CONFIG))
    np.testing.assert_array_equal(a, b)


# --------------------------------------------------------------------------------------------
# wearer_row on synthetic frames


def _frames(root):
    for scene in SyntheticDataset(root).scenes():
        yield from scene.pairs


@pytest.mark.parametrize("scenario", ["drone", "overview"])
def test_wearer_row_finds_the_carrier_of_the_egocentric_camera(tiny_synth, scenario):
    rng = np.random.default_rng(1)
    n = 0
    for pair in _frames(tiny_synth[scenario]):
        labels = pair.top.labels
        assert pair.camera_wearer == 0 and 0 in labels.ids.tolist()
        order = rng.permutation(len(labels.ids))
        order = np.roll(order, -int(np.argmax(labels.ids[order] == 0)) - 1)  # wearer not first
        cams = FrameCameras(pair.top.camera, pair.ego.camera)
        row = wearer_row(cams, labels.boxes[order])
        assert row is not None and labels.ids[order][row] == 0
        n += 1
    assert n == 4


@pytest.mark.parametrize("scenario", ["drone", "overview"])
def test_wearer_row_is_none_when_nobody_is_near_the_camera(tiny_synth, scenario):
    for pair in _frames(tiny_synth[scenario]):
        labels = pair.top.labels
        cams = FrameCameras(pair.top.camera, pair.ego.camera)
        others = labels.boxes[labels.ids != 0]
        assert wearer_row(cams, others) is None
        assert wearer_row(cams, labels.boxes, radius=1e-4) is None
        assert wearer_row(cams, np.zeros((0, 4))) is None


# --------------------------------------------------------------------------------------------
# matcher_inputs and collate_inputs


def _input_order(cues: np.ndarray, feats) -> np.ndarray:
    out = np.empty_like(cues)
    out[np.ix_(feats.top_order, feats.hor_order)] = cues
    return out


@pytest.mark.parametrize("scenario", ["drone", "overview"])
def test_matcher_inputs_with_cameras_do_not_depend_on_the_box_order(tiny_synth, scenario):
    rng = np.random.default_rng(7)
    pair = next(_frames(tiny_synth[scenario]))
    top, hor = pair.top.labels.boxes, pair.ego.labels.boxes
    cams = FrameCameras(pair.top.camera, pair.ego.camera)
    size = pair.ego.camera.image_size
    app = rng.uniform(0, 1, (len(top), len(hor)))
    ref = matcher_inputs(top, hor, size, CONFIG, cameras=cams, app=app)
    assert ref.cue_mask.tolist() == [True, True, True]
    assert ref.cues[..., 1:].any()  # the camera cues are there
    for _ in range(3):
        p, q = rng.permutation(len(top)), rng.permutation(len(hor))
        got = matcher_inputs(top[p], hor[q], size, CONFIG, cameras=cams, app=app[p][:, q])
        for name in ("top", "hor", "hyp", "pair", "hyp_camera"):
            np.testing.assert_array_equal(getattr(got.features, name),
                                          getattr(ref.features, name), err_msg=name)
        np.testing.assert_array_equal(got.cues, ref.cues)
        np.testing.assert_array_equal(got.cue_mask, ref.cue_mask)
        # Back in input order, the cues are the reference's rows and columns reordered.
        np.testing.assert_array_equal(_input_order(got.cues, got.features),
                                      _input_order(ref.cues, ref.features)[p][:, q])


def test_collate_inputs_pads_with_zeros_and_masks():
    a = matcher_inputs(TOP, HOR[:2], SIZE, CONFIG, app=np.full((4, 2), 0.5))
    b = matcher_inputs(TOP[:1], HOR, SIZE, CONFIG, ("app", "ray"))
    b = type(b)(b.features, np.full((1, 3, 3), 0.75, np.float32), np.array([True, False, True]))
    batch = collate_inputs([a, b])
    assert batch["cues"].shape == (2, 4, 3, 3) and batch["cues"].dtype == np.float32
    np.testing.assert_array_equal(batch["cues"][0, :4, :2], a.cues)
    np.testing.assert_array_equal(batch["cues"][1, :1, :3], b.cues)
    assert not batch["cues"][0, :, 2:].any() and not batch["cues"][1, 1:].any()
    assert batch["cue_mask"].dtype == bool
    assert batch["cue_mask"].tolist() == [[True, False, False], [True, False, True]]
    assert batch["top_mask"].tolist() == [[True] * 4, [True, False, False, False]]
    assert batch["hor_mask"].tolist() == [[True, True, False], [True, True, True]]
    assert batch["top"].shape[:2] == (2, 4) and batch["hor"].shape[:2] == (2, 3)
    h = batch["hyp"].shape[1]
    assert batch["pair"].shape[:4] == (2, h, 4, 3)
    assert batch["hyp_mask"].sum(axis=1).tolist() == [a.features.hyp.shape[0],
                                                       b.features.hyp.shape[0]]
    wide = collate_inputs([a, b], n_hypotheses=5)
    assert wide["hyp"].shape[1] == 5 and wide["pair"].shape[1] == 5
    np.testing.assert_array_equal(wide["cues"], batch["cues"])


def test_collate_inputs_of_an_empty_view():
    empty = matcher_inputs(TOP, HOR[:0], SIZE, CONFIG, app=np.zeros((4, 0)))
    full = matcher_inputs(TOP[:2], HOR, SIZE, CONFIG)
    batch = collate_inputs([empty, full])
    assert batch["cues"].shape == (2, 4, 3, 3)
    assert not batch["hor_mask"][0].any() and batch["hor_mask"][1].all()
    assert batch["cue_mask"].tolist() == [[True, False, False], [False, False, False]]
    assert not batch["cues"].any()
