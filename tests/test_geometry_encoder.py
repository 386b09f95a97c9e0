"""The geometry model, fusion heads and matcher: shapes, masking, empty sides, equivariance."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from xvmatch.cues.cost_fusion import ProductFusion, SumFusion
from xvmatch.cues.spatial_features import FeatureConfig, collate_frames, frame_features
from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene
from xvmatch.models.cross_view_matcher import CrossViewMatcher
from xvmatch.models.fusion_heads import LearnedFusionHead, ProductFusionHead, SumFusionHead
from xvmatch.models.geometry_encoder import GeometryEncoder, LogSinkhorn

SIZE = (2688, 1512)
CONFIG = FeatureConfig(n_hypotheses=3, dtheta_deg=4.0)
INPUTS = ("top", "hor", "hyp", "pair", "top_mask", "hor_mask", "hyp_mask")


@pytest.fixture(autouse=True)
def _one_torch_thread():
    """One intra-op thread: tiny tensors gain nothing from more, and on a busy 2-core machine
    more threads spin against each other (a 1 s training run took over a minute)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def frames():
    scene = simulate_box_scene(SceneConfig(n_people=(6, 8)), n_frames=3, seed=5)
    feats = [frame_features(scene.top[f].boxes, scene.hor[f].boxes, SIZE, CONFIG)
             for f in (1, 2, 3)]
    feats.append(frame_features(scene.top[1].boxes[:4], scene.hor[1].boxes[:2], SIZE, CONFIG))
    return feats


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return GeometryEncoder(width=16, layers=1, heads=2, sinkhorn_iterations=10).eval()


def _run(model, feats):
    batch = {k: torch.from_numpy(v) for k, v in collate_frames(feats).items()}
    with torch.no_grad():
        return model(*(batch[k] for k in INPUTS)), batch


def test_shapes_ranges_and_marginals(model, frames):
    out, batch = _run(model, frames)
    b, m, n = batch["pair"].shape[0], batch["top"].shape[1], batch["hor"].shape[1]
    assert out.cost.shape == (b, m, n)
    assert out.log_assignment.shape == (b, m + 1, n + 1)
    assert out.hypothesis_logits.shape == batch["hyp_mask"].shape
    assert out.top_descriptors.shape == (b, m, 16) and out.hor_descriptors.shape == (b, n, 16)
    assert torch.isfinite(out.cost).all() and torch.isfinite(out.log_assignment).all()
    assert (out.cost >= 0).all() and (out.cost <= 1).all()
    prob = out.log_assignment.exp()
    for k, f in enumerate(frames):
        _, mm, nn_ = f.shape
        # Every valid row (dustbin column included) and column sums to one.
        assert torch.allclose(prob[k, :mm, [*range(nn_), n]].sum(dim=1),
                              torch.ones(mm), atol=1e-3)
        assert torch.allclose(prob[k, [*range(mm), m], :nn_].sum(dim=0),
                              torch.ones(nn_), atol=1e-3)
        assert (out.cost[k, mm:] == 1).all() and (out.cost[k, :, nn_:] == 1).all()


def test_padding_does_not_change_a_frame(model, frames):
    alone, _ = _run(model, [frames[3]])
    batched, _ = _run(model, frames)
    _, m, n = frames[3].shape
    assert torch.allclose(alone.cost[0, :m, :n], batched.cost[3, :m, :n], atol=1e-5)


@pytest.mark.parametrize("m, n", [(0, 3), (3, 0), (0, 0)])
def test_empty_sides_are_masked(model, frames, m, n):
    scene = simulate_box_scene(SceneConfig(n_people=(6, 8)), n_frames=1, seed=5)
    empty = frame_features(scene.top[1].boxes[:m], scene.hor[1].boxes[:n], SIZE, CONFIG)
    out, _ = _run(model, [empty, frames[0]])
    assert torch.isfinite(out.log_assignment).all() and torch.isfinite(out.cost).all()
    assert (out.cost[0] == 1).all()
    alone, _ = _run(model, [frames[0]])
    _, mm, nn_ = frames[0].shape
    assert torch.allclose(alone.cost[0, :mm, :nn_], out.cost[1, :mm, :nn_], atol=1e-5)


def test_raw_zero_sized_sets_do_not_fail(model):
    """Without collate's padding: M = 0 or N = 0 as real tensor dimensions."""
    for m, n in ((0, 2), (2, 0)):
        args = (
            torch.zeros(1, m, 5), torch.zeros(1, n, 10), torch.zeros(1, 1, 7),
            torch.zeros(1, 1, m, n, 12), torch.ones(1, m, dtype=torch.bool),
            torch.ones(1, n, dtype=torch.bool), torch.zeros(1, 1, dtype=torch.bool),
        )
        with torch.no_grad():
            out = model(*args)
        assert out.cost.shape == (1, m, n)
        assert torch.isfinite(out.log_assignment).all()


def test_equivariant_to_row_and_column_permutations(model, frames):
    out, batch = _run(model, frames[:1])
    _, m, n = frames[0].shape
    pt, ph = torch.randperm(m, generator=torch.Generator().manual_seed(1)), torch.randperm(n)
    perm = dict(batch)
    perm["top"] = batch["top"][:, pt]
    perm["hor"] = batch["hor"][:, ph]
    perm["pair"] = batch["pair"][:, :, pt][:, :, :, ph]
    with torch.no_grad():
        again = model(*(perm[k] for k in INPUTS))
    assert torch.allclose(again.cost, out.cost[:, pt][:, :, ph], atol=1e-5)


def test_sinkhorn_rejects_zero_iterations():
    with pytest.raises(ValueError, match="iterations"):
        LogSinkhorn(0)


def test_fusion_heads_match_the_numpy_rules():
    rng = np.random.default_rng(0)
    geo, app = rng.random((3, 4)), rng.random((3, 4))
    costs_np = {"geo": geo, "app": app}
    costs_t = {k: torch.from_numpy(v).float().unsqueeze(0) for k, v in costs_np.items()}
    w = {"geo": 0.7, "app": 0.3}
    assert np.allclose(SumFusionHead(w)(costs_t)[0].numpy(), SumFusion(w)(costs_np), atol=1e-6)
    assert np.allclose(ProductFusionHead(("geo", "app"))(costs_t)[0].numpy(),
                       ProductFusion(("geo", "app"))(costs_np), atol=1e-6)
    learned = LearnedFusionHead(("geo", "app"))
    fused = learned(costs_t)
    assert fused.shape == (1, 3, 4) and (fused >= 0).all() and (fused <= 1).all()
    # Untrained, it is the sigmoid of the mean logit: monotone in every cost.
    assert torch.all(learned({"geo": costs_t["geo"] + 0.0, "app": costs_t["app"] * 0 + 0.9})
                     >= learned({"geo": costs_t["geo"], "app": costs_t["app"] * 0 + 0.1}))
    with pytest.raises(ValueError, match="costs lack app"):
        learned({"geo": costs_t["geo"]})
    with pytest.raises(TypeError, match="sequence of names"):
        ProductFusionHead("geo")
    with pytest.raises(ValueError, match="weights must be finite"):
        SumFusionHead({"geo": -1.0})


def test_matcher_starts_as_the_geometry_model_and_masks_missing_cues(model, frames):
    matcher = CrossViewMatcher(model).eval()
    batch = {k: torch.from_numpy(v) for k, v in collate_frames(frames).items()}
    args = [batch[k] for k in INPUTS]
    b, m, n = batch["top"].shape[0], batch["top"].shape[1], batch["hor"].shape[1]
    cues = torch.rand(b, m, n, 3, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        geo = model(*args)
        box_only = matcher(*args)
        untrained = matcher(*args, cues, torch.ones(b, 3, dtype=torch.bool))
        # Cue modules start at zero: an untrained matcher is the geometry model.
        assert torch.allclose(box_only.cost, geo.cost) and torch.allclose(untrained.cost,
                                                                           geo.cost)
        for layer in (matcher.cue_embed[2], matcher.fusion[2], matcher.fusion_linear):
            torch.nn.init.normal_(layer.weight, std=0.5)
        fused = matcher(*args, cues, torch.ones(b, 3, dtype=torch.bool))
        assert not torch.allclose(fused.cost, geo.cost)
        # An unavailable cue is ignored whatever its values.
        none = torch.zeros(b, 3, dtype=torch.bool)
        a = matcher(*args, cues, none).cost
        c = matcher(*args, torch.rand_like(cues), none).cost
        assert torch.allclose(a, c)
        assert torch.isfinite(fused.cost).all()
    with pytest.raises(ValueError, match="subset of"):
        CrossViewMatcher(model, cues=("ray", "app"))
    assert CrossViewMatcher(model, cues=()).n_cues == 0


@pytest.mark.slow
def test_exports_to_onnx_with_dynamic_sizes(model, frames, tmp_path):
    """No data-dependent branch: one export serves other batch, set and hypothesis sizes."""
    ort = pytest.importorskip("onnxruntime")
    import warnings

    batch = collate_frames(frames[:2])
    path = tmp_path / "geometry.onnx"
    axes = {"top": {0: "B", 1: "M"}, "top_mask": {0: "B", 1: "M"}, "hor": {0: "B", 1: "N"},
            "hor_mask": {0: "B", 1: "N"}, "hyp": {0: "B", 1: "H"}, "hyp_mask": {0: "B", 1: "H"},
            "pair": {0: "B", 1: "H", 2: "M", 3: "N"}}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(model, tuple(torch.from_numpy(batch[k]) for k in INPUTS), path,
                          input_names=list(INPUTS), output_names=["cost"], dynamo=False,
                          dynamic_axes=axes, opset_version=17)
    session = ort.InferenceSession(str(path))
    other = collate_frames([frames[3], frames[2], frames[1]])
    (cost, *_) = session.run(None, {k: other[k] for k in INPUTS})
    expected, _ = _run(model, [frames[3], frames[2], frames[1]])
    assert np.allclose(cost, expected.cost.numpy(), atol=1e-5)
