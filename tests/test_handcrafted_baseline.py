"""Tests of the handcrafted baseline (Tables I-II of the geometric-priors paper) and its command."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.commands.lab.baseline import add_baseline_parser
from xvmatch.cues.handcrafted_costs import PairCosts, pair_costs
from xvmatch.datasets.detector_noise import DetectorNoise
from xvmatch.datasets.pair_trials import (
    FALSE_POSITIVE,
    SETTINGS,
    match_to_ground_truth,
    scene_trials,
)
from xvmatch.datasets.synthetic_io import SyntheticDataset, generate_dataset
from xvmatch.datasets.synthetic_scenes import SynthConfig
from xvmatch.datasets.visibility_noise import VisibilityNoise
from xvmatch.evaluation.cost_distributions import FIGURE_FILES
from xvmatch.evaluation.handcrafted_baseline import (
    GAMMA_GEO,
    RULE_NAMES,
    RULES,
    BaselineConfig,
    Method,
    evaluate_baseline,
    format_baseline_table,
    fused_cost,
    score_trial,
    tune_gammas,
)
from xvmatch.geometry.box_overlap import box_iou
from xvmatch.geometry.camera import Camera, intrinsics_from_fov, look_rotation
from xvmatch.inference.linking.assignment import GAMMA_GRID
from xvmatch.metrics.cross_view_metrics import count_frame, count_pair, summarize

SMALL = (320, 180)
CONFIG = SynthConfig(scenario="overview", top_size=SMALL, ego_size=SMALL, n_people=(5, 9))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    """4 overview scenes x 3 frames at 320x180 (about 0.6 s to render)."""
    root = tmp_path_factory.mktemp("baseline") / "overview"
    generate_dataset(root, CONFIG, n_scenes=4, n_frames=3, seed=11)
    return root


@pytest.fixture(scope="module")
def result(dataset: Path):
    return evaluate_baseline(dataset)


def _same_scores(a, b) -> bool:
    return a.scores.keys() == b.scores.keys() and all(a.scores[k] == b.scores[k] for k in a.scores)


# --------------------------------------------------------------------------------------------
# The table on a generated dataset


def test_table_has_every_method_and_setting(result) -> None:
    assert len(result.methods) == 8
    assert {(m.rule, m.cheirality) for m in result.methods} == {
        (r, c) for r in RULES for c in (False, True)
    }
    assert set(result.scores) == {(m.key, s) for m in result.methods for s in SETTINGS}
    assert result.n_pairs == 12 and result.n_scenes == 4 and result.scenario == "overview"
    table = format_baseline_table(result)
    lines = table.splitlines()
    for m in result.methods:
        row = [ln for ln in lines if ln.startswith(m.name) and
               ln.split()[len(m.name.split())] == ("Yes" if m.cheirality else "No")]
        assert len(row) == 1, m.key
        acc_gt = result.accuracy(m.key, "gt")
        assert f"{acc_gt:.3f}" in row[0]
    assert "Acc (GT)" in lines[2] and "Acc* (det)" in lines[2]
    # The paper's gammas for the fusion rules (Section IV-A).
    gammas = {m.key: m.gamma for m in result.methods}
    assert gammas["sum"] == gammas["sum+cheirality"] == 0.25
    assert gammas["product"] == gammas["product+cheirality"] == 0.1
    for s in result.scores.values():
        assert 0.0 <= s.acc9 <= 100.0 and s.n_frames == 12


def test_geometry_with_exact_cameras_is_well_above_chance(dataset: Path, result) -> None:
    trials = []
    for index, scene in enumerate(SyntheticDataset(dataset).scenes()):
        trials += scene_trials(scene, index, BaselineConfig(), settings=("gt",))
    rng = np.random.default_rng(0)
    chance = 0.0
    for gamma in (GAMMA_GEO, 0.5, 1.0):  # the best association by costs carrying no information
        counts = []
        for trial in trials:
            noise = rng.random(trial.costs.shape)
            fake = dataclasses.replace(trial, costs=dataclasses.replace(trial.costs, geo=noise))
            counts.append(score_trial(fake, Method("geo", False, gamma)))
        chance = max(chance, summarize(counts).acc9 / 100)
    geo = result.accuracy("geo", "gt")
    assert geo >= 0.85
    assert geo >= chance + 0.3


def test_cheirality_never_lowers_geometric_rows_on_ground_truth(result) -> None:
    for rule in ("geo", "sum", "product"):
        assert result.accuracy(f"{rule}+cheirality", "gt") >= result.accuracy(rule, "gt"), rule


def test_detections_are_harder_than_ground_truth(result) -> None:
    d = result.detection
    for view in ("top", "ego"):
        assert 0 < d.recall(view) < 1 and 0 < d.precision(view) <= 1
    for m in result.methods:
        assert result.accuracy(m.key, "det") <= result.accuracy(m.key, "gt") + 0.05, m.key


def test_scrambling_ids_leaves_results_unchanged(dataset: Path, result) -> None:
    other = evaluate_baseline(dataset, BaselineConfig(scramble_seed=123))
    assert _same_scores(result, other)
    # ... and the scrambling is real: the boxes reach the association in another order.
    scene = SyntheticDataset(dataset).scene("s00001")
    a = scene_trials(scene, 1, BaselineConfig(scramble_seed=0), settings=("gt",))
    b = scene_trials(scene, 1, BaselineConfig(scramble_seed=123), settings=("gt",))
    assert any(not np.array_equal(x.det_top_ids, y.det_top_ids) for x, y in zip(a, b, strict=True))
    for x, y in zip(a, b, strict=True):
        assert sorted(x.det_top_ids.tolist()) == sorted(y.det_top_ids.tolist())


def test_noise_free_detector_reproduces_table_one(dataset: Path, result) -> None:
    clean = VisibilityNoise(base=DetectorNoise(0.0, 0.0, 0.0), hidden_miss=0.0)
    r = evaluate_baseline(dataset, BaselineConfig(noise=clean))
    d = r.detection
    assert d.n_det == d.n_true == d.n_gt
    for m in r.methods:
        assert r.scores[(m.key, "det")] == result.scores[(m.key, "gt")], m.key


def test_noise_seed_changes_only_the_detection_column(dataset: Path, result) -> None:
    other = evaluate_baseline(dataset, BaselineConfig(noise_seed=5))
    assert all(other.scores[(m.key, "gt")] == result.scores[(m.key, "gt")]
               for m in result.methods)
    assert other.detection != result.detection


def test_cost_samples_split_true_and_false_pairs(dataset: Path, result) -> None:
    data = SyntheticDataset(dataset)
    n_true = n_all = 0
    for pair in data:
        top, ego = pair.top.labels.ids, pair.ego.labels.ids
        n_true += len(np.intersect1d(top, ego))
        n_all += len(top) * len(ego)
    s = result.samples
    assert s.geo_true.size == n_true and s.geo_false.size == n_all - n_true
    assert s.hist_true.size == n_true  # ground-truth crops are never empty
    assert np.median(s.geo_true) < np.median(s.geo_false)


def test_tune_gammas_picks_the_best_grid_value(dataset: Path) -> None:
    tuned = tune_gammas(dataset, rules=("geo",))
    curve = tuned.curves["geo"]
    assert list(curve) == sorted(GAMMA_GRID)
    assert tuned.gammas["geo"] in GAMMA_GRID
    assert curve[tuned.gammas["geo"]] == max(curve.values())
    with pytest.raises(ValueError, match="grid must hold finite gammas > 0"):
        tune_gammas(dataset, grid=[0.0, 0.5])


# --------------------------------------------------------------------------------------------
# Ground-truth matching and counting on hand-made cases


def test_box_iou_hand_computed() -> None:
    a = np.array([[0.0, 0.0, 10.0, 10.0]])
    b = np.array([[5.0, 0.0, 10.0, 10.0], [0.0, 0.0, 3.0, 10.0], [20.0, 20.0, 5.0, 5.0],
                  [0.0, 0.0, 0.0, 0.0]])
    np.testing.assert_allclose(box_iou(a, b), [[50 / 150, 30 / 100, 0.0, 0.0]])
    assert box_iou(np.empty((0, 4)), b).shape == (0, 4)
    zero = np.zeros((1, 4))
    assert box_iou(zero, zero)[0, 0] == 0.0  # empty union: 0, not NaN
    with pytest.raises(ValueError, match="boxes_a must have shape"):
        box_iou(np.zeros((2, 3)), b)


def test_match_to_ground_truth_hand_made() -> None:
    gt = np.array([[0.0, 0.0, 10.0, 10.0], [100.0, 0.0, 10.0, 10.0]])
    ids = np.array([7, 3])
    det = np.array([
        [0.0, 0.0, 3.0, 10.0],     # IoU 0.3 exactly with id 7: counts (>= 0.3)
        [100.0, 0.0, 2.0, 10.0],   # IoU 0.2 with id 3: false positive
        [50.0, 50.0, 10.0, 10.0],  # overlaps nothing: false positive
    ])
    assert match_to_ground_truth(det, gt, ids).tolist() == [7, FALSE_POSITIVE, FALSE_POSITIVE]
    # Two detections on one person: the better one keeps the id, the other is a false positive.
    two = np.array([[1.0, 0.0, 10.0, 10.0], [0.0, 0.0, 10.0, 10.0]])
    assert match_to_ground_truth(two, gt, ids).tolist() == [FALSE_POSITIVE, 7]
    # One to one at maximum total IoU, not greedy: A overlaps 7 (0.6) and 3 (0.5), B only 7.
    gt2 = np.array([[0.0, 0.0, 10.0, 10.0], [6.0, 0.0, 10.0, 10.0]])
    a = [2.5, 0.0, 10.0, 10.0]
    iou_a = box_iou(np.array([a]), gt2)[0]
    assert iou_a[0] > iou_a[1] >= 0.3
    b = [-1.0, 0.0, 10.0, 10.0]
    assert match_to_ground_truth(np.array([a, b]), gt2, ids).tolist() == [3, 7]
    assert match_to_ground_truth(np.empty((0, 4)), gt, ids).shape == (0,)
    assert match_to_ground_truth(det, np.empty((0, 4)), []).tolist() == [FALSE_POSITIVE] * 3
    with pytest.raises(ValueError, match="iou_threshold"):
        match_to_ground_truth(det, gt, ids, iou_threshold=0.0)
    with pytest.raises(ValueError, match="distinct"):
        match_to_ground_truth(det, gt, [1, 1])
    with pytest.raises(ValueError, match="2 ids for 1"):
        match_to_ground_truth(det, gt[:1], ids)


def test_count_pair_hand_computed() -> None:
    # Ground truth: top {0, 1, 2, 3}, ego {1, 2, 4}: G = {1, 2}, U = {0..4} (5 persons).
    # Detections: top [1, 2, FP, 0] (3 missed), ego [2, FP, 4] (1 missed).
    top = [0, 1, 2, 3]
    ego = [1, 2, 4]
    det_top = np.array([1, 2, FALSE_POSITIVE, 0])
    det_ego = np.array([2, FALSE_POSITIVE, 4])
    pairs = np.array([[1, 0], [2, 1]])  # (2, 2): TP; (FP, FP): wrong pair, fp
    c = count_pair(top, ego, det_top, det_ego, pairs, frame=4)
    # TN: 0 (top only, detected, unmatched) and 4 (ego only, detected, unmatched); 3 missed.
    assert (c.frame, c.n_pred, c.n_gt, c.tp, c.fp, c.mismatch) == (4, 2, 2, 1, 1, 0)
    assert (c.miss, c.n_union, c.tn) == (1, 5, 2)
    assert summarize([c]).acc9 == pytest.approx(100 * 3 / 5)
    # A false top detection paired with a shared person's ego box is a mismatch.
    c = count_pair(top, ego, det_top, det_ego, np.array([[2, 0]]))
    assert (c.tp, c.mismatch, c.fp, c.miss, c.tn) == (0, 1, 0, 1, 2)
    # Bad input: a detection standing for an id the view does not have, pairs not one-to-one.
    with pytest.raises(ValueError, match="absent from the view's ground truth"):
        count_pair(top, ego, np.array([9]), det_ego, np.empty((0, 2), int))
    with pytest.raises(ValueError, match="one-to-one"):
        count_pair(top, ego, det_top, det_ego, np.array([[0, 0], [1, 0]]))
    with pytest.raises(ValueError, match="out of range"):
        count_pair(top, ego, det_top, det_ego, np.array([[4, 0]]))


@settings(max_examples=40, deadline=None)
@given(st.data())
def test_count_pair_equals_count_frame_on_ground_truth_boxes(data: st.DataObject) -> None:
    top = data.draw(st.lists(st.integers(0, 9), unique=True, max_size=6))
    ego = data.draw(st.lists(st.integers(0, 9), unique=True, max_size=6))
    k = data.draw(st.integers(0, min(len(top), len(ego))))
    rows = data.draw(st.permutations(range(len(top))))[:k]
    cols = data.draw(st.permutations(range(len(ego))))[:k]
    pairs = np.array(list(zip(rows, cols, strict=True)), dtype=np.int64).reshape(-1, 2)
    ours = count_pair(top, ego, np.array(top, np.int64), np.array(ego, np.int64), pairs)
    ref = count_frame(top, ego, [(top[i], ego[j]) for i, j in pairs])
    assert ours == ref


# --------------------------------------------------------------------------------------------
# Costs of one pair: hand-made scenes and bad inputs


def _cameras() -> tuple[Camera, Camera]:
    K = intrinsics_from_fov(160, 90, 70.0)
    top = Camera(K, look_rotation(math.pi / 2, math.radians(45)), [0.0, -8.0, 9.0], 160, 90)
    ego = Camera(K, look_rotation(math.pi / 2, 0.0), [0.5, -2.0, 1.5], 160, 90)
    return top, ego


def _head_box(camera: Camera, head: np.ndarray) -> np.ndarray:
    uv, depth = camera.project(head)
    assert depth > 0
    return np.array([uv[0] - 5.0, uv[1], 10.0, 20.0])


def test_pair_costs_on_a_hand_made_scene() -> None:
    top_cam, ego_cam = _cameras()
    heads = np.array([[0.0, 3.0, 1.7], [2.0, 5.0, 1.8]])
    top_boxes = np.stack([_head_box(top_cam, h) for h in heads])
    ego_boxes = np.stack([_head_box(ego_cam, h) for h in heads[::-1]])  # reversed order
    image = np.zeros((90, 160, 3), np.uint8)
    image[:, :80] = (0, 0, 200)  # red left half, blue right half
    image[:, 80:] = (200, 0, 0)
    costs = pair_costs(top_cam, ego_cam, image, image, top_boxes, ego_boxes)
    assert costs.shape == (2, 2)
    np.testing.assert_allclose(np.diag(costs.geo[:, ::-1]), 0.0, atol=1e-9)  # true pairs meet
    assert (costs.geo[[0, 1], [0, 1]] > 0.1).all()
    assert (costs.cheirality == 0).all()
    norm = costs.normalised()
    np.testing.assert_allclose(norm["geo"], np.tanh(costs.geo))
    np.testing.assert_allclose(norm["hist"], np.tanh(costs.hist))
    for rule in RULES:
        fused = fused_cost(costs, Method(rule, True, 0.5))
        assert np.isfinite(fused).all() and fused.shape == (2, 2)
    prod = fused_cost(costs, Method("product", False, 0.1))
    np.testing.assert_allclose(prod, norm["geo"] * norm["hist"])
    total = fused_cost(costs, Method("sum", False, 0.25), weights=(0.5, 0.5))
    np.testing.assert_allclose(total, 0.5 * norm["geo"] + 0.5 * norm["hist"])


def test_pair_costs_bad_inputs_give_errors_or_finite_costs() -> None:
    top_cam, ego_cam = _cameras()
    image = np.full((90, 160, 3), 128, np.uint8)
    box = np.array([[10.0, 10.0, 20.0, 40.0]])
    # Empty sides: empty matrices, no error.
    costs = pair_costs(top_cam, ego_cam, image, image, np.empty((0, 4)), box)
    assert costs.geo.shape == costs.hist.shape == costs.cheirality.shape == (0, 1)
    # A box outside its image (empty crop): maximal appearance cost 1, never NaN.
    outside = np.array([[500.0, 500.0, 20.0, 40.0], [10.0, 10.0, 0.0, 40.0]])
    costs = pair_costs(top_cam, ego_cam, image, image, outside, box)
    assert not costs.hist_valid.any()
    np.testing.assert_array_equal(costs.normalised()["hist"], 1.0)
    for rule in RULES:
        assert np.isfinite(fused_cost(costs, Method(rule, True, 0.5))).all()
    # Coincident centres (no baseline): geometry carries no cue, but no NaN either.
    same_centre = Camera(ego_cam.K, ego_cam.R, top_cam.c, 160, 90)
    costs = pair_costs(top_cam, same_centre, image, image, box, box)
    assert np.isfinite(costs.geo).all() and np.isfinite(costs.cheirality).all()
    # Singular cameras cannot be built; misuse is a clear error.
    with pytest.raises(ValueError, match="singular"):
        Camera(np.zeros((3, 3)), np.eye(3), np.zeros(3), 160, 90)
    with pytest.raises(TypeError, match="top_camera must be"):
        pair_costs("camera", ego_cam, image, image, box, box)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="is 80x90 but its camera is 160x90"):
        pair_costs(top_cam, ego_cam, image[:, :80], image, box, box)
    with pytest.raises(ValueError, match="NaN or inf"):
        pair_costs(top_cam, ego_cam, image, image, np.array([[np.nan, 0, 1, 1]]), box)
    with pytest.raises(ValueError, match="negative width or height"):
        pair_costs(top_cam, ego_cam, image, image, box, np.array([[0.0, 0.0, -1.0, 4.0]]))


@settings(max_examples=30, deadline=None)
@given(
    st.lists(st.tuples(st.floats(-400, 600), st.floats(-300, 400), st.floats(0, 200),
                       st.floats(0, 200)), max_size=5),
    st.lists(st.tuples(st.floats(-400, 600), st.floats(-300, 400), st.floats(0, 200),
                       st.floats(0, 200)), max_size=5),
)
def test_cost_matrices_are_never_nan(top: list, ego: list) -> None:
    top_cam, ego_cam = _cameras()
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (90, 160, 3), dtype=np.uint8)
    costs = pair_costs(top_cam, ego_cam, image, image, np.array(top).reshape(-1, 4),
                       np.array(ego).reshape(-1, 4))
    for matrix in (costs.geo, costs.hist, costs.cheirality, *costs.normalised().values()):
        assert matrix.shape == (len(top), len(ego)) and np.isfinite(matrix).all()
    for rule in RULES:
        for cheirality in (False, True):
            assert np.isfinite(fused_cost(costs, Method(rule, cheirality, 0.3))).all()


def test_config_and_method_errors() -> None:
    with pytest.raises(ValueError, match="rule must be one of"):
        Method("nn", False, 0.1)
    with pytest.raises(ValueError, match="gamma must be a finite cost > 0"):
        Method("geo", False, float("nan"))
    with pytest.raises(ValueError, match="gamma_sum must be a finite cost > 0"):
        BaselineConfig(gamma_sum=0.0)
    with pytest.raises(ValueError, match="iou_threshold"):
        BaselineConfig(iou_threshold=1.5)
    with pytest.raises(ValueError, match="SumFusion weights"):
        BaselineConfig(weights=(0.0, 0.0))
    assert [m.key for m in BaselineConfig().methods()][:2] == ["geo", "geo+cheirality"]
    assert RULE_NAMES["product"] == "Product combination"


def test_pair_costs_shape_property() -> None:
    costs = PairCosts(np.zeros((2, 3)), np.zeros((2, 3)), np.ones((2, 3), bool), np.zeros((2, 3)))
    assert costs.shape == (2, 3)


# --------------------------------------------------------------------------------------------
# The command


def _cli(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="xvmatch")
    sub = parser.add_subparsers(dest="command", required=True)
    add_baseline_parser(sub)
    args = parser.parse_args(argv)
    return args.func(args)


@pytest.mark.slow
def test_cli_prints_the_table_and_writes_the_figures(dataset: Path, result, tmp_path: Path,
                                                     capsys) -> None:
    figures = tmp_path / "figs"
    assert _cli(["baseline", "--data", str(dataset), "--figures", str(figures)]) == 0
    out, err = capsys.readouterr()
    assert out.strip() == format_baseline_table(result)
    for name in FIGURE_FILES.values():
        path = figures / name
        assert f"wrote {path}" in err
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        assert image is not None and image.shape == (370, 1040, 3)
        assert len(np.unique(image.reshape(-1, 3), axis=0)) > 20  # bars, text and legend
    assert not list(figures.glob("*.tmp"))

    assert _cli(["baseline", "--data", str(dataset), "--json", "--quiet",
                 "--gamma-geo", "0.3"]) == 0
    out, err = capsys.readouterr()
    record = json.loads(out)
    assert err == ""
    assert record["n_pairs"] == 12 and len(record["methods"]) == 8
    assert record["config"]["gamma_geo"] == 0.3
    geo = next(m for m in record["methods"] if m["key"] == "hist")
    assert geo["scores"]["gt"]["acc9"] == pytest.approx(result.scores[("hist", "gt")].acc9)


def test_cli_errors(tmp_path: Path, capsys) -> None:
    with pytest.raises(ValueError, match=r"no dataset\.json; generate a dataset first"):
        _cli(["baseline", "--data", str(tmp_path), "--quiet"])
    with pytest.raises(SystemExit):
        _cli(["baseline", "--data", str(tmp_path), "--gamma-sum", "-1"])
    assert "gamma must be a finite cost > 0" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        _cli(["baseline", "--data", str(tmp_path), "--workers", "0"])
    assert "expected a positive integer" in capsys.readouterr().err
