"""The matcher that appearance cannot drag down (issue 31): the appearance confidence of
``CrossViewMatcher(app_confidence=True)`` and the corrupted appearance of the matcher's
training frames (``training/matcher_datamodule.py``)."""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch

from tests.conftest import TINY_APPEARANCE, TINY_GEOMETRY
from xvmatch.cues.spatial_features import (
    HOR_FEATURES,
    HYP_FEATURES,
    PAIR_FEATURES,
    TOP_FEATURES,
    FeatureConfig,
)
from xvmatch.datasets.pair_trials import TrialConfig, dataset_trials
from xvmatch.models.cross_view_matcher import (
    CONFIDENCE_FEATURES,
    CrossViewMatcher,
    app_confidence_features,
)
from xvmatch.models.geometry_encoder import GeometryEncoder
from xvmatch.training.matcher_datamodule import (
    CORRUPTIONS,
    AppCorruption,
    ShiftedCoster,
    corrupt_app,
    shifted_app_costs,
    trial_frames,
)


def _batch(b: int = 3, m: int = 5, n: int = 6, h: int = 4, seed: int = 0) -> tuple:
    """A padded batch: frame 1 padded in both views, the others full; cue masks (app only,
    all three, none) in turn."""
    g = torch.Generator().manual_seed(seed)
    top_mask = torch.ones(b, m, dtype=torch.bool)
    hor_mask = torch.ones(b, n, dtype=torch.bool)
    top_mask[1, m - 2:] = False
    hor_mask[1, 2:] = False
    cue_mask = torch.tensor([[True, False, False], [True, True, True],
                             [False, False, False]])[torch.arange(b) % 3]
    return (torch.randn(b, m, len(TOP_FEATURES), generator=g),
            torch.randn(b, n, len(HOR_FEATURES), generator=g),
            torch.randn(b, h, len(HYP_FEATURES), generator=g),
            torch.randn(b, h, m, n, len(PAIR_FEATURES), generator=g),
            top_mask, hor_mask, torch.ones(b, h, dtype=torch.bool),
            torch.rand(b, m, n, 3, generator=g), cue_mask)


def _matcher(app_confidence: bool, seed: int = 0) -> CrossViewMatcher:
    """A tiny matcher whose cue layers matter (non-zero weights)."""
    torch.manual_seed(seed)
    matcher = CrossViewMatcher(GeometryEncoder(**TINY_GEOMETRY), app_confidence=app_confidence)
    for layer in (matcher.cue_embed[2], matcher.fusion[2], matcher.fusion_linear):
        torch.nn.init.normal_(layer.weight, std=0.5)
    return matcher.eval()


def _previous_forward(matcher: CrossViewMatcher, *args) -> torch.Tensor:
    """The cost of the matcher as it was computed before the appearance confidence existed."""
    top, hor, hyp, pair, top_mask, hor_mask, hyp_mask, cues, cue_mask = args
    enc = matcher.geometry
    avail = cue_mask.to(top.dtype)[:, None, None, :].expand_as(cues)
    logit = torch.logit(cues.clamp(1e-4, 1.0 - 1e-4)) * avail
    x = torch.cat([logit, avail], dim=-1)
    a, b, pair_emb, _ = enc.encode(top, hor, hyp, pair, top_mask, hor_mask, hyp_mask,
                                   pair_extra=matcher.cue_embed(x))
    scores, _, _ = enc.pair_scores(a, b, pair_emb)
    late = matcher.fusion(torch.cat([x, scores[..., None]], dim=-1)).squeeze(-1)
    scores = scores + late + matcher.fusion_linear(x).squeeze(-1)
    return enc.match(scores, top_mask, hor_mask)[0]


@torch.no_grad()
def test_flag_off_is_bit_identical_to_the_previous_matcher():
    matcher = _matcher(False)
    args = _batch()
    assert "app_confidence" not in matcher.config  # older files' config, unchanged
    assert not any(k.startswith("confidence") for k in matcher.state_dict())
    assert torch.equal(matcher(*args).cost, _previous_forward(matcher, *args))


@torch.no_grad()
def test_a_fresh_confidence_head_starts_as_the_loaded_matcher():
    plain = _matcher(False)
    gated = CrossViewMatcher(plain.geometry, plain.cues, app_confidence=True).eval()
    missing, unexpected = gated.load_state_dict(plain.state_dict(), strict=False)
    assert not unexpected and all(k.startswith("confidence.") for k in missing)
    args = _batch()
    x = torch.zeros(3, 5, 6, 6)
    assert torch.equal(gated.app_gates(*args, x), torch.ones(3, 2))
    assert torch.equal(gated(*args).cost, plain(*args).cost)
    assert gated.config["app_confidence"] is True


def test_confidence_needs_the_app_cue():
    with pytest.raises(ValueError, match="app_confidence needs the 'app' cue"):
        CrossViewMatcher(GeometryEncoder(**TINY_GEOMETRY), cues=("ray",), app_confidence=True)
    with pytest.raises(ValueError, match="must be a bool"):
        CrossViewMatcher(GeometryEncoder(**TINY_GEOMETRY), app_confidence=1)


@torch.no_grad()
def test_features_ignore_padding_and_frames_without_the_cue():
    g = torch.Generator().manual_seed(1)
    app, scores = torch.rand(2, 4, 5, generator=g), torch.randn(2, 4, 5, generator=g)
    top = torch.tensor([[True, True, False, False], [True, True, True, True]])
    hor = torch.tensor([[True, True, True, False, False], [True] * 5])
    avail = torch.tensor([True, False])
    feats = app_confidence_features(app, avail, scores, top, hor)
    assert feats.shape == (2, len(CONFIDENCE_FEATURES))
    assert torch.equal(feats[1], torch.zeros(len(CONFIDENCE_FEATURES)))
    garbage = app.clone()
    garbage[0, 2:], garbage[0, :, 3:] = 5.0, -3.0  # padding holds anything
    other = scores.clone()
    other[0, 2:] = 1e3
    again = app_confidence_features(garbage, avail, other, top, hor)
    cropped = app_confidence_features(app[:1, :2, :3], avail[:1], scores[:1, :2, :3],
                                      top[:1, :2], hor[:1, :3])
    torch.testing.assert_close(again[0], feats[0])
    torch.testing.assert_close(cropped[0], feats[0])
    assert torch.isfinite(feats).all()


@torch.no_grad()
def test_corrupted_appearance_lowers_the_confidence_features():
    """Geometry sure of the diagonal; clean appearance agrees, with a clear margin; swapped
    crops and random embeddings do not."""
    n = 6
    mask = torch.ones(1, n, dtype=torch.bool)
    scores = (4.0 * torch.eye(n) - 1.0)[None]
    clean = np.full((n, n), 0.6) - 0.45 * np.eye(n)
    rng = np.random.default_rng(0)
    swapped = corrupt_app(clean, "swap", rng)
    random = corrupt_app(clean, "random", rng)
    names = list(CONFIDENCE_FEATURES)
    feats = {k: app_confidence_features(torch.tensor(v, dtype=torch.float32)[None],
                                        torch.tensor([True]), scores, mask, mask)[0]
             for k, v in (("clean", clean), ("swap", swapped), ("random", random))}
    for kind in ("swap", "random"):
        for name in ("row_agree", "col_agree", "geo_best_gap", "geo_corr"):
            i = names.index(name)
            assert feats[kind][i] < feats["clean"][i], (kind, name)
    assert feats["clean"][names.index("row_agree")] == 1.0
    margin = names.index("row_margin")
    assert feats["random"][margin] < feats["clean"][margin]


@pytest.mark.slow
def test_confidence_path_exports_to_onnx_and_matches_torch(tmp_path):
    """The graph ``xvmatch export`` writes (``MatcherGraph``, opset and dynamic axes of every
    ``matcher.onnx``), run by onnxruntime on batches of other sizes than the traced one."""
    import warnings

    import onnxruntime as ort

    from xvmatch.export.onnx_export import MatcherGraph
    from xvmatch.inference.matching.bundle import MATCHER_OUTPUT, OPSET
    from xvmatch.models.appearance_net import appearance_small
    from xvmatch.models.matcher_file import load_matcher, save_matcher

    matcher = _matcher(True)
    torch.nn.init.normal_(matcher.confidence[2].weight, std=1.0)
    torch.nn.init.normal_(matcher.confidence[2].bias, std=1.0)
    args = _batch()
    with torch.no_grad():
        gates = matcher.app_gates(*args, torch.zeros(3, 5, 6, 6))
    assert not torch.allclose(gates[:2], torch.ones(2, 2))  # the gates do something
    path = tmp_path / "robust.pt"
    save_matcher(path, matcher, FeatureConfig(n_hypotheses=3, dtheta_deg=4.0), 0.5,
                 appearance=appearance_small(**TINY_APPEARANCE).eval())
    loaded = load_matcher(path).matcher
    assert loaded.config["app_confidence"] is True
    names = ["top", "hor", "hyp", "pair", "top_mask", "hor_mask", "hyp_mask", "cues",
             "cue_mask"]
    people = {"top": "m", "hor": "n", "hyp": "h", "top_mask": "m", "hor_mask": "n",
              "hyp_mask": "h"}
    dynamic = {k: {0: "b", 1: people[k]} for k in people}
    dynamic |= {"pair": {0: "b", 1: "h", 2: "m", 3: "n"}, "cues": {0: "b", 1: "m", 2: "n"},
                "cue_mask": {0: "b"}, MATCHER_OUTPUT: {0: "b", 1: "m", 2: "n"}}
    onnx_path = tmp_path / "matcher.onnx"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(MatcherGraph(loaded), args, str(onnx_path), dynamo=False,
                          input_names=names, output_names=[MATCHER_OUTPUT],
                          dynamic_axes=dynamic, opset_version=OPSET)
    session = ort.InferenceSession(str(onnx_path))
    for shape in ((3, 5, 6, 4), (2, 7, 3, 2), (4, 1, 1, 1)):
        batch = _batch(*shape, seed=2)
        with torch.no_grad():
            expected = loaded(*batch).cost.numpy()
        got = session.run(None, {k: v.numpy() for k, v in zip(names, batch, strict=True)})[0]
        np.testing.assert_allclose(got, expected, atol=1e-5)


def test_corrupt_app_kinds():
    app = np.random.default_rng(3).uniform(0.2, 0.9, (4, 5))
    swapped = corrupt_app(app, "swap", np.random.default_rng(1))
    rows = sorted(map(tuple, swapped)) == sorted(map(tuple, app))
    cols = sorted(map(tuple, swapped.T)) == sorted(map(tuple, app.T))
    assert rows or cols
    random = corrupt_app(app, "random", np.random.default_rng(1), embedding_dim=128)
    assert random.shape == (4, 5) and 0.6 < random.mean() < 0.8 and random.std() < 0.08
    np.testing.assert_array_equal(random, corrupt_app(app, "random", np.random.default_rng(1)))
    shifted = app[::-1].copy()
    assert corrupt_app(app, "shift", np.random.default_rng(1), shifted) is not None
    np.testing.assert_array_equal(corrupt_app(app, "shift", np.random.default_rng(1), shifted),
                                  shifted)
    with pytest.raises(ValueError, match="needs the shifted images' costs"):
        corrupt_app(app, "shift", np.random.default_rng(1))
    with pytest.raises(ValueError, match="kind must be one of"):
        corrupt_app(app, "blur", np.random.default_rng(1))
    with pytest.raises(ValueError, match="probability must be in"):
        AppCorruption(probability=1.5)
    with pytest.raises(ValueError, match="kinds must be among"):
        AppCorruption(kinds=("blur",), weights=(1.0,))


def _colour_coster(top_image, top_boxes, ego_image, ego_boxes) -> np.ndarray:
    """Appearance costs from the boxes' mean colours (a real, cheap, deterministic coster)."""
    def colours(image, boxes):
        out = []
        for x1, y1, x2, y2 in np.asarray(boxes, dtype=int):
            patch = image[max(y1, 0):max(y2, y1 + 1), max(x1, 0):max(x2, x1 + 1)]
            out.append(patch.reshape(-1, 3).mean(0) if patch.size else np.zeros(3))
        return np.asarray(out, dtype=np.float64).reshape(-1, 3) / 255.0

    a, b = colours(top_image, top_boxes), colours(ego_image, ego_boxes)
    return np.clip(np.linalg.norm(a[:, None] - b[None], axis=-1) / np.sqrt(3.0), 0.0, 1.0)


def test_training_frames_are_corrupted_as_drawn_and_reproducibly(tiny_synth, tmp_path):
    data = tiny_synth["overview"]
    config = TrialConfig()
    trials = dataset_trials(data, config, ("gt", "det"), _colour_coster)
    shifter = ShiftedCoster(_colour_coster, seed=4)
    shifted = shifted_app_costs(data, config, ("gt", "det"), shifter)
    assert [s.shape for s in shifted] == [t.app.shape for t in trials]
    again = shifted_app_costs(data, config, ("gt", "det"), shifter)
    assert all(np.array_equal(a, b) for a, b in zip(shifted, again, strict=True))  # seeded
    assert any(not np.allclose(s, t.app) for s, t in zip(shifted, trials, strict=True))
    features = FeatureConfig(n_hypotheses=3, dtheta_deg=4.0)
    variants = ("boxes", "images")

    def app_of(corruption):
        items = trial_frames(trials, features, variants=variants, cache_dir=tmp_path,
                             corruption=corruption, shifted_app=shifted)
        return [(it[3][..., 0].copy(), bool(it[4][0])) for it in items]

    clean = app_of(None)
    assert [c for _, c in clean] == [False, True] * len(trials)
    assert all(np.array_equal(a, b) for (a, _), (b, _) in
               zip(clean, app_of(AppCorruption(probability=0.0)), strict=True))
    for kind in CORRUPTIONS:
        corruption = AppCorruption(probability=1.0, kinds=(kind,), weights=(1.0,), seed=7)
        got = app_of(corruption)
        assert all(np.array_equal(a, b) for (a, _), (b, _) in
                   zip(got, app_of(corruption), strict=True))  # seeded
        for k, t in enumerate(trials):
            assert np.array_equal(got[2 * k][0], clean[2 * k][0])  # boxes frames untouched
            rng = np.random.default_rng([7, 0, k, 1])
            rng.random(), rng.choice(1, p=[1.0])
            expected = corrupt_app(t.app, kind, rng, shifted[k])
            order = trial_frames([t], features, variants=("images",), cache_dir=tmp_path)[0][0]
            np.testing.assert_allclose(
                got[2 * k + 1][0], expected[order.top_order][:, order.hor_order].astype(
                    np.float32))
    mixed = app_of(AppCorruption(probability=0.5, seed=1))
    changed = sum(not np.array_equal(a, b) for (a, _), (b, _) in zip(mixed, clean, strict=True))
    assert 0 < changed < len(trials)


@pytest.mark.slow
def test_the_data_module_keeps_appearance_costs_between_runs(tiny_synth, tmp_path):
    from xvmatch.models.appearance_net import appearance_small, save_appearance_weights
    from xvmatch.training.matcher_datamodule import SyntheticMatcherDataModule

    torch.manual_seed(0)
    weights = tmp_path / "app.pt"
    save_appearance_weights(appearance_small(**TINY_APPEARANCE).eval(), weights)

    def frames(app_cache):
        dm = SyntheticMatcherDataModule(
            tiny_synth["overview"], tiny_synth["drone"], os.fspath(weights),
            FeatureConfig(n_hypotheses=3, dtheta_deg=4.0), variants=("images",),
            cache_dir=os.fspath(tmp_path / "features"), app_cache=app_cache,
            corruption=AppCorruption(probability=0.5, seed=3), corrupt_val=True)
        dm.setup("fit")
        return [it[3] for part in dm.train_parts + dm.val_parts for it in part.items]

    fresh = frames(None)
    first = frames(tmp_path / "app_costs")
    assert len(list((tmp_path / "app_costs").glob("*.npz"))) == 6  # 3 trial sets x 2 kinds
    again = frames(tmp_path / "app_costs")
    for a, b, c in zip(fresh, first, again, strict=True):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, c)


def test_gate_cap_only_down_weights_and_is_stored_only_when_on(tmp_path):
    from xvmatch.models.appearance_net import appearance_small
    from xvmatch.models.matcher_file import load_matcher, save_matcher

    with pytest.raises(ValueError, match="app_gate_cap needs app_confidence"):
        CrossViewMatcher(GeometryEncoder(**TINY_GEOMETRY), app_gate_cap=True)
    with pytest.raises(ValueError, match="app_gate_cap must be a bool"):
        CrossViewMatcher(GeometryEncoder(**TINY_GEOMETRY), app_confidence=True, app_gate_cap=1)
    assert "app_gate_cap" not in _matcher(True).config  # off: files as before
    fresh = CrossViewMatcher(GeometryEncoder(**TINY_GEOMETRY), app_confidence=True,
                             app_gate_cap=True)
    (-fresh.app_gates(*_batch(), torch.zeros(3, 5, 6, 6)).sum()).backward()
    assert fresh.confidence[2].bias.grad.abs().sum() > 0  # a fresh capped head can learn
    free = _matcher(True)
    torch.nn.init.normal_(free.confidence[2].weight, std=1.0)
    torch.nn.init.normal_(free.confidence[2].bias, std=1.0)
    capped = CrossViewMatcher(free.geometry, free.cues, app_confidence=True,
                              app_gate_cap=True).eval()
    capped.load_state_dict(free.state_dict())
    args = _batch()
    x = torch.zeros(3, 5, 6, 6)
    with torch.no_grad():
        g_free, g_cap = free.app_gates(*args, x), capped.app_gates(*args, x)
        assert (g_free > 1).any() and (g_free < 1).any()
        assert torch.equal(g_cap, g_free.clamp(max=1.0))
        expected = capped(*args).cost
    path = tmp_path / "capped.pt"
    save_matcher(path, capped, FeatureConfig(n_hypotheses=3, dtheta_deg=4.0), 0.5,
                 appearance=appearance_small(**TINY_APPEARANCE).eval())
    loaded = load_matcher(path).matcher.eval()
    assert loaded.config["app_gate_cap"] is True and loaded.app_gate_cap
    with torch.no_grad():
        assert torch.equal(loaded(*args).cost, expected)


def test_clean_frame_term_pulls_only_the_gates_of_clean_frames():
    from xvmatch.models.losses import GeometryMatchingLoss
    from xvmatch.training.geometry_module import GeometryMatchingModule

    loss = GeometryMatchingLoss(gate_weight=2.0)
    gates = torch.tensor([[0.5, 1.0], [1.5, 0.0], [0.0, 0.0]])
    clean = torch.tensor([True, True, False])
    assert torch.isclose(loss.gate_term(gates, clean), torch.tensor((0.25 + 0.25 + 1.0) / 2))
    assert loss.gate_term(gates, torch.zeros(3, dtype=torch.bool)) == 0
    with pytest.raises(ValueError, match="gate_weight must be >= 0"):
        GeometryMatchingLoss(gate_weight=-1.0)

    top, hor, hyp, pair, top_mask, hor_mask, hyp_mask, cues, cue_mask = _batch()
    batch = {"top": top, "hor": hor, "hyp": hyp, "pair": pair, "top_mask": top_mask,
             "hor_mask": hor_mask, "hyp_mask": hyp_mask, "cues": cues, "cue_mask": cue_mask,
             "match": torch.zeros(3, 5, 6, dtype=torch.bool),
             "camera_correct": torch.zeros(3, 4, dtype=torch.bool)}
    batch["match"][:, 0, 0] = True
    matcher = _matcher(True).train()
    torch.nn.init.normal_(matcher.confidence[2].weight, std=1.0)
    plain = GeometryMatchingModule(matcher, GeometryMatchingLoss())
    weighted = GeometryMatchingModule(matcher, GeometryMatchingLoss(gate_weight=2.0))
    base, _ = plain._step(batch, "train")
    same, _ = weighted._step(batch, "train")  # no app_corrupted in the batch: no term
    assert torch.equal(base, same)
    flagged = dict(batch, app_corrupted=torch.tensor([False, True, False]))
    assert torch.equal(plain._step(flagged, "train")[0], base)  # weight 0: no term
    total, _ = weighted._step(flagged, "train")
    gates = matcher.last_gates
    # frame 0 (app, clean) only: frame 1 is corrupted and frame 2 has no app cue
    expected = base + 2.0 * ((gates[0] - 1.0) ** 2).sum()
    assert torch.allclose(total, expected)
    matcher.zero_grad()
    (total - base).backward()
    assert matcher.confidence[0].weight.grad.abs().sum() > 0



def test_given_gates_open_and_close_the_appearance_cue():
    args = _batch()
    cue_mask = args[-1]
    matcher = _matcher(True)
    torch.nn.init.normal_(matcher.confidence[2].weight, std=1.0)
    with torch.no_grad():
        matcher(*args)
        head = matcher.last_gates
        opened = matcher(*args, gates=torch.ones(3, 2)).cost
        closed = matcher(*args, gates=torch.zeros(3, 2)).cost
        assert matcher.last_gates is head  # given gates are not the head's
        # open: the cue as without the confidence; closed: the frame without the app cue
        assert torch.allclose(opened, _previous_forward(matcher, *args), atol=1e-6)
        no_app = cue_mask.clone()
        no_app[:, 0] = False
        assert torch.allclose(closed, _previous_forward(matcher, *args[:-1], no_app),
                              atol=1e-6)
        assert not torch.allclose(opened[0], closed[0], atol=1e-3)  # frame 0 has app only
    with pytest.raises(ValueError, match="app_confidence"):
        _matcher(False)(*args, gates=torch.ones(3, 2))


def test_frame_nll_is_the_assignment_loss_of_each_frame():
    from xvmatch.models.losses import AssignmentNLLLoss, frame_nll

    g = torch.Generator().manual_seed(3)
    log_assignment = torch.log_softmax(torch.randn(3, 5, 6, generator=g), dim=-1)
    top, hor = torch.ones(3, 4, dtype=torch.bool), torch.ones(3, 5, dtype=torch.bool)
    top[1, 2:] = False
    hor[2] = False  # no horizontal person: every top person in the dustbin
    match = torch.zeros(3, 4, 5, dtype=torch.bool)
    match[0, 0, 1] = match[1, 1, 0] = True
    per_frame = frame_nll(log_assignment, match, top, hor)
    loss = AssignmentNLLLoss()
    for k in range(3):
        one = loss(log_assignment[k:k + 1], match[k:k + 1], top[k:k + 1], hor[k:k + 1])
        assert torch.isclose(per_frame[k], one)
    empty = frame_nll(log_assignment, match, torch.zeros_like(top), torch.zeros_like(hor))
    assert torch.equal(empty, torch.zeros(3))


def test_gate_target_pulls_each_frame_towards_its_better_end():
    from xvmatch.models.losses import GeometryMatchingLoss

    loss = GeometryMatchingLoss(gate_target_weight=1.0)
    gates = torch.tensor([[0.5, 1.0], [0.5, 0.0], [1.0, 1.0], [0.2, 0.2]], requires_grad=True)
    nll_open = torch.tensor([0.2, 0.9, 0.4, 0.1])
    nll_closed = torch.tensor([0.6, 0.3, 0.4, 5.0])
    has_app = torch.tensor([True, True, True, False])
    term = loss.gate_target_term(gates, nll_open, nll_closed, has_app)
    # frame 0: images better by 0.4, target 1; frame 1: boxes better by 0.6, target 0;
    # frame 2: a tie weighs nothing; frame 3 has no images
    expected = (0.4 * (0.25 + 0.0) + 0.6 * (0.25 + 0.0) + 0.0) / 3
    assert torch.isclose(term, torch.tensor(expected))
    term.backward()
    assert gates.grad[0, 0] < 0 and gates.grad[1, 0] > 0  # open frame 0, close frame 1
    assert torch.equal(gates.grad[2:], torch.zeros(2, 2))
    none = loss.gate_target_term(gates, nll_open, nll_closed, torch.zeros(4, dtype=torch.bool))
    assert none == 0
    with pytest.raises(ValueError, match="gate_target_weight must be >= 0"):
        GeometryMatchingLoss(gate_target_weight=-1.0)


def test_training_step_adds_the_gate_target_from_open_and_closed_passes():
    from xvmatch.models.losses import GeometryMatchingLoss, frame_nll
    from xvmatch.training.geometry_module import GeometryMatchingModule

    top, hor, hyp, pair, top_mask, hor_mask, hyp_mask, cues, cue_mask = _batch()
    batch = {"top": top, "hor": hor, "hyp": hyp, "pair": pair, "top_mask": top_mask,
             "hor_mask": hor_mask, "hyp_mask": hyp_mask, "cues": cues, "cue_mask": cue_mask,
             "match": torch.zeros(3, 5, 6, dtype=torch.bool),
             "camera_correct": torch.zeros(3, 4, dtype=torch.bool)}
    batch["match"][:, 0, 0] = batch["match"][:, 1, 1] = True
    matcher = _matcher(True)
    torch.nn.init.normal_(matcher.confidence[2].weight, std=1.0)
    plain = GeometryMatchingModule(matcher, GeometryMatchingLoss())
    targeted = GeometryMatchingModule(matcher, GeometryMatchingLoss(gate_target_weight=3.0))
    base, _ = plain._step(batch, "train")
    total, _ = targeted._step(batch, "train")
    gates = matcher.last_gates
    inputs = (top, hor, hyp, pair, top_mask, hor_mask, hyp_mask, cues, cue_mask)
    with torch.no_grad():
        nll_open, nll_closed = (frame_nll(matcher(*inputs, gates=torch.full((3, 2), v))
                                          .log_assignment, batch["match"], top_mask, hor_mask)
                                for v in (1.0, 0.0))
    gap = nll_closed - nll_open
    assert gap[2] == 0 and gap[0] != 0  # frame 2 has no app cue: open is closed
    per_frame = gap.abs() * ((gates - (gap > 0).float()[:, None]) ** 2).sum(-1)
    expected = base + 3.0 * per_frame[:2].sum() / 2  # frames 0 and 1 have the app cue
    assert torch.allclose(total, expected, atol=1e-6)
    matcher.zero_grad()
    targeted._gate_target(batch, gates).backward()
    assert matcher.confidence[0].weight.grad.abs().sum() > 0
    # the open and closed passes carry no gradient: only the head learns from the target
    assert all(p.grad is None or not p.grad.any() for name, p in matcher.named_parameters()
               if not name.startswith("confidence."))


def test_training_frames_can_carry_their_corruption_flag(tiny_synth, tmp_path):
    from xvmatch.training.box_datamodule import collate_labelled
    from xvmatch.training.matcher_datamodule import collate_flagged

    data = tiny_synth["overview"]
    trials = dataset_trials(data, TrialConfig(), ("gt",), _colour_coster)
    features = FeatureConfig(n_hypotheses=3, dtheta_deg=4.0)
    corruption = AppCorruption(probability=0.5, kinds=("random",), weights=(1.0,), seed=1)
    kwargs = dict(variants=("boxes", "images"), cache_dir=tmp_path, corruption=corruption)
    plain = trial_frames(trials, features, **kwargs)
    flagged = trial_frames(trials, features, **kwargs, flag_corrupted=True)
    assert all(len(it) == 5 for it in plain) and all(len(it) == 6 for it in flagged)
    clean = trial_frames(trials, features, variants=("boxes", "images"), cache_dir=tmp_path)
    for a, b, c in zip(plain, flagged, clean, strict=True):
        np.testing.assert_array_equal(a[3], b[3])
        assert bool(b[5]) == (not np.array_equal(b[3], c[3]))
    assert 0 < sum(bool(it[5]) for it in flagged) < len(trials)
    batch = collate_flagged(flagged[:4])
    reference = collate_labelled(plain[:4])
    assert set(batch) == set(reference) | {"app_corrupted"}
    assert all(torch.equal(batch[k], reference[k]) for k in reference)
    assert batch["app_corrupted"].tolist() == [bool(it[5]) for it in flagged[:4]]
