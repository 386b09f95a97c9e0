"""Tests of the learned-matcher evaluation, the cue DataModule and the fusion module."""

from __future__ import annotations

from pathlib import Path

import lightning as L
import numpy as np
import pytest
import torch

from xvmatch.cues.cost_fusion import ProductFusion, SumFusion
from xvmatch.datasets.pair_trials import dataset_trials, scene_trials
from xvmatch.datasets.synthetic_io import SyntheticDataset, generate_dataset
from xvmatch.datasets.synthetic_scenes import SynthConfig
from xvmatch.evaluation.handcrafted_baseline import (
    BaselineConfig,
    Method,
    score_trial,
)
from xvmatch.evaluation.learned_matcher_eval import (
    CueRule,
    default_rules,
    evaluate_learned_matcher,
    format_learned_table,
    rule_cost,
    score_rule,
    tune_gamma,
)
from xvmatch.metrics.cross_view_metrics import summarize
from xvmatch.models.appearance_net import appearance_small, save_appearance_weights
from xvmatch.models.fusion_heads import LearnedFusionHead
from xvmatch.training.appearance_costs import AppearanceCoster
from xvmatch.training.fusion_datamodule import CuePairDataModule, collate_trials
from xvmatch.training.fusion_module import FusionModule, batch_acc9

torch.set_num_threads(1)  # one thread: fast and stable on a busy 2-core machine

TINY_NET = {"input_size": (32, 16), "widths": (4, 8, 8, 16), "hidden_dim": 16, "embedding_dim": 8}


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory) -> Path:
    """3 overview scenes x 2 frames at 320x180, 3-7 people."""
    root = tmp_path_factory.mktemp("fusion") / "data"
    config = SynthConfig(scenario="overview", top_size=(320, 180), ego_size=(320, 180),
                         n_people=(3, 7))
    generate_dataset(root, config, n_scenes=3, n_frames=2, seed=21)
    return root


@pytest.fixture(scope="module")
def coster() -> AppearanceCoster:
    torch.manual_seed(0)
    return AppearanceCoster(appearance_small(**TINY_NET))


@pytest.fixture(scope="module")
def trials(tiny_data: Path, coster: AppearanceCoster):
    return dataset_trials(tiny_data, BaselineConfig(), coster=coster)


def test_trials_equal_the_baselines(tiny_data: Path, trials) -> None:
    data = SyntheticDataset(tiny_data)
    config = BaselineConfig()
    reference = []
    for index, name in enumerate(data.scene_names):
        reference += scene_trials(data.scene(name), index, config)
    assert len(reference) == len(trials) == 12
    method = Method("product", True, 0.1)
    for ours, theirs in zip(trials, reference, strict=True):
        assert (ours.scene, ours.frame, ours.setting) == (theirs.scene, theirs.frame,
                                                          theirs.setting)
        np.testing.assert_array_equal(ours.det_top_ids, theirs.det_top_ids)
        np.testing.assert_array_equal(ours.det_ego_ids, theirs.det_ego_ids)
        np.testing.assert_array_equal(ours.costs.geo, theirs.costs.geo)
        assert score_trial(theirs, method) == score_rule(ours, method, 0.1)
        assert ours.app.shape == ours.costs.geo.shape
        assert ((ours.app >= 0) & (ours.app <= 1)).all()


def test_cues_and_rules(trials) -> None:
    t = next(t for t in trials if t.costs.geo.size)
    cues = t.cues()
    assert set(cues) == {"app", "geo", "hist", "cheir"}
    assert set(np.unique(cues["cheir"])) <= {0.0, 1.0}
    rules = {r.key: r for r in default_rules()}
    np.testing.assert_allclose(rule_cost(t, rules["app"]), t.app)
    vetoed = rule_cost(t, rules["app+cheirality"])
    np.testing.assert_allclose(vetoed, t.app + t.costs.cheirality)
    summed = rule_cost(t, rules["sum(app,geo)+cheirality"]) - t.costs.cheirality
    np.testing.assert_allclose(summed, SumFusion({"app": 1, "geo": 1})(cues), atol=1e-6)
    product = rule_cost(t, rules["product(app,geo)+cheirality"]) - t.costs.cheirality
    np.testing.assert_allclose(product, ProductFusion(("app", "geo"))(cues), atol=1e-6)
    with pytest.raises(ValueError, match="exactly one of head and cue"):
        CueRule("x", "x")


def test_tune_gamma_takes_the_middle_of_ties(trials) -> None:
    rule = CueRule("geo", "geo", cue="geo")
    gamma, curve = tune_gamma(trials, rule, grid=[0.2, 0.4, 0.6])
    assert set(curve) == {0.2, 0.4, 0.6}
    best = max(curve.values())
    tied = [g for g, a in curve.items() if a == best]
    assert gamma == tied[(len(tied) - 1) // 2]


def test_batch_acc9_equals_count_pair(trials) -> None:
    batch = collate_trials(trials, ("app", "geo", "cheir"))
    rng = np.random.default_rng(0)
    cost = rng.random(batch.match.shape)
    gammas = [0.3, 0.7]
    acc = batch_acc9(cost, batch, gammas)
    for k, g in enumerate(gammas):
        for b, t in enumerate(trials):
            m, n = t.costs.shape
            rule = CueRule("r", "r", cue="geo")
            counts = score_rule(t, rule, g, cost=cost[b, :m, :n])
            expected = summarize([counts]).acc9 / 100
            assert acc[b, k] == pytest.approx(expected)


def test_collate_masks_empty_sides(trials) -> None:
    t = trials[0]
    empty_top = type(t)(t.scene, t.frame, t.setting, t.top_boxes[:0], t.ego_boxes,
                        type(t.costs)(t.costs.geo[:0], t.costs.hist[:0],
                                      t.costs.hist_valid[:0], t.costs.cheirality[:0]),
                        t.app[:0], t.gt_top_ids, t.gt_ego_ids, t.det_top_ids[:0],
                        t.det_ego_ids)
    batch = collate_trials([t, empty_top], ("app", "geo", "cheir"))
    assert not batch.top_mask[1].any() and batch.ego_mask[1].sum() == t.ego_boxes.shape[0]
    module = FusionModule(LearnedFusionHead(("app", "geo", "cheir")))
    fused = module(batch)
    assert fused.shape == batch.match.shape
    assert (fused[1] == 1).all()  # padding and the empty side cost 1
    terms, _ = module.losses(batch)
    assert all(torch.isfinite(v) for v in terms.values())


def test_fusion_steps_reduce_the_loss(trials) -> None:
    torch.manual_seed(0)
    batch = collate_trials(trials, ("app", "geo", "cheir"))
    module = FusionModule(LearnedFusionHead(("app", "geo", "cheir")), lr=0.05)
    optimizer = torch.optim.Adam(module.parameters(), lr=0.05)
    before = float(module.losses(batch)[0]["total"].detach())
    for _ in range(20):
        loss = module.losses(batch)[0]["total"]
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    assert float(module.losses(batch)[0]["total"].detach()) < before


def test_cue_datamodule_and_fusion_fit(tiny_data: Path, coster, tmp_path: Path) -> None:
    weights = save_appearance_weights(coster.net, tmp_path / "app.pt").path
    with pytest.raises(ValueError, match="needs appearance_weights"):
        CuePairDataModule(str(tiny_data), str(tiny_data))
    with pytest.raises(ValueError, match="names must be among"):
        CuePairDataModule(str(tiny_data), str(tiny_data), str(weights), names=["colour"])
    dm = CuePairDataModule(str(tiny_data), str(tiny_data), str(weights), noise_seeds=[3],
                           batch_size=4)
    dm.setup("fit")
    assert dm.describe() == "train: 12 trials; val: 12 trials"
    L.seed_everything(0)
    module = FusionModule(LearnedFusionHead(dm.names))
    trainer = L.Trainer(max_epochs=2, default_root_dir=tmp_path, logger=False,
                        enable_progress_bar=False, enable_model_summary=False,
                        enable_checkpointing=False)
    trainer.fit(module, dm)
    metrics = trainer.callback_metrics
    assert 0 <= float(metrics["val/acc9"]) <= 1
    assert float(metrics["val/gamma"]) in module.gamma_grid


def test_evaluate_and_format(trials) -> None:
    heads = {"fused": LearnedFusionHead(("app", "geo", "cheir"))}
    result = evaluate_learned_matcher(trials, trials, default_rules(heads), grid=[0.1, 0.5],
                                      test_data="t", val_data="v", scenario="overview")
    families = [r.family for r in result.rows]
    assert families.count("handcrafted") == 8 and families.count("handcrafted, tuned") == 8
    assert families.count("learned") == 5
    assert result.n_pairs == 6
    fused = result.row("learned(app,geo,cheir)")
    assert fused.cheirality and fused.gamma in (0.1, 0.5)
    # The published-gamma rows are the baseline's own numbers.
    product = result.row("product+cheirality", "handcrafted")
    assert product.gamma == 0.1
    table = format_learned_table(result)
    assert "Learned head: fused" in table and "Product combination" in table
    assert len(table.splitlines()) == 3 + len(result.rows)
