"""benchmarks/matcher_comparison.py: bundles compared on the same shifted frames, paired."""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import deployed_matcher_eval  # noqa: E402
import matcher_comparison  # noqa: E402

from xvmatch.datasets.pair_trials import SETTINGS, TrialConfig, dataset_trials  # noqa: E402
from xvmatch.evaluation.deployed_matcher_eval import (  # noqa: E402
    OnnxAppearanceCoster,
    cue_auc,
    frame_checked_costs,
    matcher_costs,
)
from xvmatch.inference.matching.learned_association import load_matcher_bundle  # noqa: E402

DEFAULT_FOLDER = str(ROOT / "inference" / "default_bundle")


def run(monkeypatch, *args: str) -> int:
    monkeypatch.setattr(sys, "argv", ["matcher_comparison.py", *args])
    return matcher_comparison.main()


@pytest.mark.slow
def test_bundles_are_compared_on_the_same_frames(tmp_path, monkeypatch, tiny_models) -> None:
    out = tmp_path / "out.json"
    tiny = str(tiny_models["full_bundle"])  # another appearance network: its own trials
    assert run(monkeypatch, "--models", "default", tiny, DEFAULT_FOLDER, "--scenes", "2",
               "--scenarios", "overview", "--shifts", "0", "1", "--workers", "1",
               "--work", str(tmp_path / "work"), "--json", str(out)) == 0
    rows = json.loads(out.read_text())
    cell = {(r["shift"], r["setting"], r["model"]): r for r in rows}
    assert len(cell) == len(rows) == 2 * len(SETTINGS) * 3
    for strength in (0.0, 1.0):
        for s in SETTINGS:
            first, same = cell[strength, s, "default"], cell[strength, s, DEFAULT_FOLDER]
            # The default named by its folder is the same matcher on the same frames.
            assert (same["images"], same["boxes"]) == (first["images"], first["boxes"])
            for key in ("images vs default", "boxes vs default"):
                assert (same[key]["points"], same[key]["low"], same[key]["high"]) == (0, 0, 0)
            other = cell[strength, s, tiny]
            assert other["images vs default"]["points"] == pytest.approx(
                other["images"] - first["images"])
            assert other["images vs default"]["scenes"] == 2
            assert first["images - boxes"]["points"] == pytest.approx(
                first["images"] - first["boxes"])
            # Boxes never see the images: the shift moves only the images rows.
            assert cell[1.0, s, "default"]["boxes"] == cell[0.0, s, "default"]["boxes"]
    assert any(cell[1.0, s, "default"]["images"] != cell[0.0, s, "default"]["images"]
               for s in SETTINGS)
    # The unshifted default row is the deployed benchmark's own Eq. 9 figure on these frames.
    matcher = load_matcher_bundle("default")
    trials = dataset_trials(Path(rows[0]["data"]), TrialConfig(), SETTINGS,
                            OnnxAppearanceCoster(matcher))
    scores = deployed_matcher_eval.scores(trials, matcher_costs(matcher, trials, "images"),
                                          matcher.gamma)
    for s in SETTINGS:
        assert cell[0.0, s, "default"]["images"] == pytest.approx(100 * scores[s], abs=1e-9)
        # the cue's own AUC: the trials' costs, true pairs against the frame's other people
        assert cell[0.0, s, "default"]["cue AUC"] == cue_auc(trials, s) > 0.75
        assert cell[0.0, s, DEFAULT_FOLDER]["cue AUC"] == cell[0.0, s, "default"]["cue AUC"]
        assert 0.0 <= cell[1.0, s, "default"]["cue AUC"] <= 1.0
    # "checked": the shipped bundle's frame check, frame by frame images or boxes alone
    checked = frame_checked_costs(matcher.bundle.manifest.frame_check, trials,
                                  matcher_costs(matcher, trials, "images"),
                                  matcher_costs(matcher, trials, "boxes"))
    for s in SETTINGS:
        acc, _ = deployed_matcher_eval.frame_accuracies(trials, checked, matcher.gamma, s)
        row = cell[0.0, s, "default"]
        assert row["checked"] == pytest.approx(100 * acc.mean(), abs=1e-9)
        assert row["checked - boxes"]["points"] == pytest.approx(row["checked"] - row["boxes"])
        assert "checked" not in cell[0.0, s, tiny]  # no frame check in that bundle


def _with_cue(trials, cue):
    return [dataclasses.replace(t, app=cue(t)) for t in trials]


def test_cue_auc_counts_true_pairs_against_the_other_people(tmp_path) -> None:
    path = deployed_matcher_eval.render(tmp_path, "overview", "test", 1, 2)
    trials = dataset_trials(path, TrialConfig(), SETTINGS)

    def same(t):
        top, ego = np.asarray(t.det_top_ids), np.asarray(t.det_ego_ids)
        return (top[:, None] == ego[None, :]) & (top[:, None] >= 0)

    for s in SETTINGS:
        assert cue_auc(_with_cue(trials, lambda t: 1.0 - same(t)), s) == 1.0
        assert cue_auc(_with_cue(trials, lambda t: same(t) + 0.0), s) == 0.0
        assert cue_auc(_with_cue(trials, lambda t: np.zeros(same(t).shape)), s) == 0.5
    with pytest.raises(ValueError, match="no appearance costs"):
        cue_auc(trials, "gt")


@pytest.mark.parametrize("args, message", [
    (["--scenes", "1"], "--scenes: expected at least 2, got 1"),
    (["--shifts", "0", "3.5"], "--shifts: expected numbers in [0, 3], got 3.5"),
    (["--models", "default", "default"], "a bundle is named twice"),
    (["--models", "no/such/bundle"], "no/such/bundle"),
])
def test_bad_arguments_get_one_line(monkeypatch, capsys, args, message) -> None:
    with pytest.raises(SystemExit) as exit_info:
        run(monkeypatch, *args)
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err


def test_a_bundle_without_appearance_is_refused(monkeypatch, capsys, tiny_models) -> None:
    with pytest.raises(SystemExit):
        run(monkeypatch, "--models", str(tiny_models["boxes_bundle"]))
    assert "this bundle has no appearance network" in capsys.readouterr().err
