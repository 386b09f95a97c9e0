"""Tests of the ablation command (``xvmatch ablate``): every output on tiny datasets, the same
numbers for any number of workers, resumed runs, refused mixes and bad input, the confidence
interval and each sweep's perturbation."""

from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from xvmatch.cli import main
from xvmatch.commands.lab.ablate import SWEEP_CHOICES
from xvmatch.datasets.pair_trials import FALSE_POSITIVE
from xvmatch.datasets.synthetic_io import SyntheticDataset
from xvmatch.datasets.visibility_noise import VisibilityNoise, apply_visibility_noise
from xvmatch.evaluation.ablation_cells import (
    cell_trials,
    render_setting,
    validation_mask,
)
from xvmatch.evaluation.ablation_methods import ROWS, tune_gamma
from xvmatch.evaluation.ablation_plots import require_matplotlib
from xvmatch.evaluation.ablation_settings import (
    SWEEPS,
    Setting,
    calibration_rng,
    grid_settings,
    perturb_camera,
    rotation_angle_deg,
    scaled_noise,
)
from xvmatch.formats.mot_boxes import write_mot_boxes
from xvmatch.geometry.camera import Camera, intrinsics_from_fov, look_rotation
from xvmatch.metrics.confidence import mean_interval


def _ablate(capsys, *argv: str) -> tuple[int, str]:
    """Run ``xvmatch ablate`` in-process; (exit code, stderr)."""
    capsys.readouterr()
    code = main(["ablate", *argv, "--quiet"])
    return code, capsys.readouterr().err


@pytest.fixture(scope="module")
def cvmhat_boxes(tmp_path_factory, tiny_synth) -> Path:
    """A CVMHAT-like folder: one pair of box files made from a tiny overview scene."""
    folder = tmp_path_factory.mktemp("cvmhat")
    scene = SyntheticDataset(tiny_synth["overview"]).scene("s00001")
    write_mot_boxes(folder / "tiny_top.txt", scene.boxes("top"))
    write_mot_boxes(folder / "tiny_hor.txt", scene.boxes("ego"))
    return folder


@pytest.fixture(scope="module")
def args(tiny_synth, tiny_models, cvmhat_boxes) -> list[str]:
    """The options of the end-to-end runs (both tiny scenarios, 2 seeds, CVMHAT every frame)."""
    return ["--data", str(tiny_synth["drone"]), str(tiny_synth["overview"]), "--model",
            str(tiny_models["full_bundle"]), "--seeds", "2", "--cvmhat", str(cvmhat_boxes),
            "--cvmhat-step", "1"]


@pytest.fixture(scope="module")
def report(tmp_path_factory, args) -> Path:
    """One run with one worker."""
    out = tmp_path_factory.mktemp("ablation") / "report"
    assert main(["ablate", *args, "--out", str(out), "--quiet"]) == 0
    return out


def _results(folder: Path) -> list[dict]:
    with open(folder / "results.csv", newline="") as handle:
        return list(csv.DictReader(handle))


# --------------------------------------------------------------------------------------------
# End to end


@pytest.mark.slow
def test_run_writes_every_output(report: Path, args) -> None:
    settings = grid_settings("noise")
    rows = _results(report)
    synthetic = [r for r in rows if r["scenario"] != "cvmhat"]
    assert len(synthetic) == 2 * len(settings) * 2 * len(ROWS)
    assert {r["setting"] for r in synthetic} == {s.key for s in settings}
    assert {r["method"] for r in synthetic} == {r.key for r in ROWS}
    cvmhat = [r for r in rows if r["scenario"] == "cvmhat"]
    assert len(cvmhat) == 2 * 2 * 2 and {r["setting"] for r in cvmhat} == {"clean", "det"}
    for r in rows:
        assert 0.0 <= float(r["acc9"]) <= 100.0 and 0.0 <= float(r["cvidf1"]) <= 100.0
    doc = json.loads((report / "results.json").read_text())
    assert len(doc["rows"]) == len(rows) and doc["seeds"] == [0, 1]
    assert all(s["acc9_half_width"] is not None for s in doc["summary"])
    text = (report / "report.md").read_text()
    for needle in ("xvmatch ablate --data", "numpy", "onnxruntime", "format xvmatch-bundle",
                   "## drone", "## overview", "## Real CVMHAT boxes", "every 5th scene",
                   "**", " ± ", "Learned fusion against the best non-learned row"):
        assert needle in text, needle
    for png in ("sweep_drone.png", "sweep_overview.png", "costs_drone_gt.png",
                "costs_overview_det.png"):
        assert (report / png).stat().st_size > 1000, png
        assert f"]({png})" in text
    examples = sorted((report / "examples").glob("*.png"))
    assert examples and all(f"](examples/{p.name})" in text for p in examples)
    assert len(list((report / "cells").glob("*.json"))) == 2 * len(settings) * 2 + 2 * 2


@pytest.mark.slow
def test_numbers_do_not_depend_on_workers(report: Path, args, tmp_path: Path) -> None:
    out = tmp_path / "report"
    assert main(["ablate", *args, "--out", str(out), "--workers", "2", "--quiet"]) == 0
    assert (out / "results.csv").read_text() == (report / "results.csv").read_text()


@pytest.mark.slow
def test_second_run_reuses_every_cell(report: Path, args, capsys) -> None:
    cells = sorted((report / "cells").glob("*.json"))
    before = {p: p.stat().st_mtime_ns for p in cells}
    text = (report / "report.md").read_text()
    code, err = _ablate(capsys, *args, "--out", str(report))
    assert code == 0
    assert f"0 cells computed, {len(cells)} reused" in err
    assert {p: p.stat().st_mtime_ns for p in cells} == before
    assert (report / "report.md").read_text() == text


@pytest.mark.slow
def test_other_options_in_the_report_folder_are_refused(report: Path, args, capsys) -> None:
    before = sorted(p.name for p in (report / "cells").iterdir())
    code, err = _ablate(capsys, *args, "--out", str(report), "--sweep", "calibration")
    assert code == 2
    assert err.count("\n") == 1 and "holds cells of other options" in err and "sweep" in err
    assert sorted(p.name for p in (report / "cells").iterdir()) == before


@pytest.mark.slow
def test_calibration_sweep_runs_and_zero_error_is_the_ground_truth_column(
        tiny_synth, tiny_models, tmp_path, capsys) -> None:
    out = tmp_path / "calib"
    code, err = _ablate(capsys, "--data", str(tiny_synth["overview"]), "--model",
                        str(tiny_models["full_bundle"]), "--seeds", "1", "--sweep",
                        "calibration", "--out", str(out))
    assert code == 0, err
    rows = _results(out)
    assert {r["setting"] for r in rows} == {s.key for s in grid_settings("calibration")}
    assert {r["sweep_value"] for r in rows if r["setting"] == "gt"} == {"0.0000"}
    assert "one seed: single values, no interval" in (out / "report.md").read_text()


# --------------------------------------------------------------------------------------------
# Bad input: one line, exit code 2


def test_missing_data_folder(tiny_models, tmp_path, capsys) -> None:
    code, err = _ablate(capsys, "--data", str(tmp_path / "nope"), "--out", str(tmp_path / "r"))
    assert code == 2 and err.count("\n") == 1 and "no such data folder" in err
    assert not (tmp_path / "r").exists()


def test_folder_that_is_not_a_dataset(tmp_path, capsys) -> None:
    (tmp_path / "empty").mkdir()
    code, err = _ablate(capsys, "--data", str(tmp_path / "empty"), "--out", str(tmp_path / "r"))
    assert code == 2 and err.count("\n") == 1 and "no dataset.json" in err


def test_bundle_without_appearance(tiny_synth, tiny_models, tmp_path, capsys) -> None:
    code, err = _ablate(capsys, "--data", str(tiny_synth["drone"]), "--model",
                        str(tiny_models["boxes_bundle"]), "--out", str(tmp_path / "r"))
    assert code == 2 and err.count("\n") == 1
    assert "lacks an appearance network" in err and "--model default" in err


def test_missing_cvmhat_folder(tiny_synth, tiny_models, tmp_path, capsys) -> None:
    code, err = _ablate(capsys, "--data", str(tiny_synth["drone"]), "--model",
                        str(tiny_models["full_bundle"]), "--cvmhat", str(tmp_path / "none"),
                        "--out", str(tmp_path / "r"))
    assert code == 2 and err.count("\n") == 1 and "no such CVMHAT folder" in err


def test_foreign_output_folder(tiny_synth, tiny_models, tmp_path, capsys) -> None:
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "notes.txt").write_text("mine\n")
    code, err = _ablate(capsys, "--data", str(tiny_synth["drone"]), "--model",
                        str(tiny_models["full_bundle"]), "--out", str(tmp_path / "r"))
    assert code == 2 and "not an ablation report" in err


def test_a_foreign_report_md_is_not_replaced(tiny_synth, tiny_models, tmp_path, capsys) -> None:
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "report.md").write_text("my own report\n")
    code, err = _ablate(capsys, "--data", str(tiny_synth["drone"]), "--model",
                        str(tiny_models["full_bundle"]), "--out", str(tmp_path / "r"))
    assert code == 2 and err.count("\n") == 1 and "not an ablation report" in err
    assert (tmp_path / "r" / "report.md").read_text() == "my own report\n"
    assert [p.name for p in (tmp_path / "r").iterdir()] == ["report.md"]


def test_the_report_folder_is_checked_before_the_data_is_read(tmp_path, capsys) -> None:
    # A refused --out is said first, before the matcher loads or any dataset is opened.
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "report.md").write_text("my own report\n")
    code, err = _ablate(capsys, "--data", str(tmp_path / "no_data"), "--model", "default",
                        "--out", str(tmp_path / "r"))
    assert code == 2 and err.count("\n") == 1 and "--out" in err and "not an ablation" in err


@pytest.mark.slow
def test_the_report_folder_is_marked_as_ablate_s_own(report: Path) -> None:
    marker = json.loads((report / ".xvmatch-output.json").read_text())
    assert marker == {"written_by": "xvmatch ablate"}


def test_cells_are_keyed_on_the_data_content_not_its_path(tiny_synth, tiny_models,
                                                          tmp_path) -> None:
    import shutil

    from xvmatch.datasets.synthetic_io import generate_dataset
    from xvmatch.datasets.synthetic_scenes import SynthConfig
    from xvmatch.evaluation.ablation import AblationOptions, plan_ablation
    from xvmatch.evaluation.ablation_cells import check_cells
    from xvmatch.inference.matching.learned_association import load_matcher_bundle

    matcher = load_matcher_bundle(str(tiny_models["full_bundle"]), threads=1)
    data = tmp_path / "a" / "drone"
    shutil.copytree(tiny_synth["drone"], data)

    def record(folder: Path) -> dict:
        options = AblationOptions(data=(str(folder),), model=str(tiny_models["full_bundle"]),
                                  out=str(tmp_path / "r"))
        return plan_ablation(options, matcher).record

    first = record(data)
    moved = tmp_path / "b" / "drone"
    shutil.copytree(data, moved)
    assert record(moved) == first  # same content elsewhere: the same cells
    cells = {"drone__gt__seed0": {"options": first}}
    check_cells(tmp_path / "r", cells, record(moved))
    # Re-rendered at the same path: other cells, and the stored ones are refused.
    source = SyntheticDataset(data).manifest
    config = SynthConfig(scenario="drone", top_size=tuple(source["config"]["top_size"]),
                         ego_size=tuple(source["config"]["ego_size"]))
    generate_dataset(data, config, n_scenes=2, n_frames=1, seed=99)
    again = record(data)
    assert again["data"] != first["data"]
    with pytest.raises(ValueError, match=r"holds cells of other options \(data "):
        check_cells(tmp_path / "r", cells, again)


@pytest.mark.parametrize("option", [("--sweep", "weather"), ("--seeds", "0"), ("--seeds", "21"),
                                    ("--workers", "0"), ("--cvmhat-step", "0")])
def test_bad_options_exit_2_before_any_work(tiny_synth, tmp_path, capsys, option) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["ablate", "--data", str(tiny_synth["drone"]), "--out", str(tmp_path / "r"),
              *option])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("xvmatch ablate: error: argument " + option[0])
    assert not (tmp_path / "r").exists()


def test_sweep_choices_match_the_sweeps() -> None:
    assert set(SWEEP_CHOICES) == set(SWEEPS)


def test_missing_matplotlib_is_one_line_naming_the_extra(monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(ValueError, match=r"pip install 'xvmatch\[plots\]'"):
        require_matplotlib()


# --------------------------------------------------------------------------------------------
# The confidence interval


def test_mean_interval_hand_computed() -> None:
    # s = 1, t_{0.975, 2} = 4.302653 (tables), half = 4.302653 / sqrt(3) = 2.484138.
    r = mean_interval([1.0, 2.0, 3.0])
    assert r.mean == 2.0 and r.n == 3
    assert math.isclose(r.half_width, 2.484138, abs_tol=1e-6)
    # Two values 90, 92: s = sqrt(2), t_{0.975, 1} = 12.706205, half = 12.706205 * sqrt(2) /
    # sqrt(2).
    r = mean_interval([90.0, 92.0])
    assert math.isclose(r.half_width, 12.706205, abs_tol=1e-6) and r.low < 80 < 100 < r.high


def test_one_value_has_no_interval() -> None:
    r = mean_interval([97.5])
    assert r.mean == 97.5 and r.half_width is None and r.low is None


def test_mean_interval_bad_input() -> None:
    with pytest.raises(ValueError, match="at least one value"):
        mean_interval([])
    with pytest.raises(ValueError, match="finite"):
        mean_interval([1.0, float("nan")])


# --------------------------------------------------------------------------------------------
# The sweeps' perturbations


def _camera() -> Camera:
    return Camera(K=intrinsics_from_fov(640, 360, 70.0), R=look_rotation(0.4, 0.3, 0.05),
                  c=np.array([2.0, -1.0, 1.6]), width=640, height=360)


@pytest.mark.parametrize(("degrees", "metres"), SWEEPS["calibration"])
def test_calibration_error_has_the_given_angle_and_distance(degrees, metres) -> None:
    camera = _camera()
    moved = perturb_camera(camera, degrees, metres, calibration_rng(3, 1, "ego"))
    assert math.isclose(rotation_angle_deg(moved.R, camera.R), degrees, abs_tol=1e-6)
    assert math.isclose(float(np.linalg.norm(moved.c - camera.c)), metres, abs_tol=1e-9)
    assert np.array_equal(moved.K, camera.K) and moved.image_size == camera.image_size


def test_calibration_error_is_seeded_and_the_same_direction_at_every_point() -> None:
    camera = _camera()
    a = perturb_camera(camera, 1.0, 0.25, calibration_rng(0, 2, "top"))
    b = perturb_camera(camera, 5.0, 1.0, calibration_rng(0, 2, "top"))
    c = perturb_camera(camera, 1.0, 0.25, calibration_rng(1, 2, "top"))
    assert np.allclose((b.c - camera.c) / 1.0, (a.c - camera.c) / 0.25)
    assert not np.allclose(a.c, c.c)


def test_calibrated_trials_use_the_perturbed_cameras(tiny_synth) -> None:
    setting = next(s for s in grid_settings("calibration") if s.rotation_deg == 5.0)
    _, clean = cell_trials(tiny_synth["overview"], Setting("gt", "GT"), 0, None)
    _, moved = cell_trials(tiny_synth["overview"], setting, 0, None)
    for a, b in zip(clean, moved, strict=True):
        assert np.array_equal(a.top_boxes, b.top_boxes) and np.array_equal(a.costs.hist,
                                                                          b.costs.hist)
        assert math.isclose(rotation_angle_deg(b.cameras["top"].R, a.cameras["top"].R), 5.0,
                            abs_tol=1e-6)
    assert any(not np.allclose(a.costs.geo, b.costs.geo) for a, b in zip(clean, moved,
                                                                          strict=True))


def test_noise_multiplier_zero_gives_the_ground_truth_boxes(tiny_synth) -> None:
    scene = SyntheticDataset(tiny_synth["drone"]).scene("s00000")
    gt = scene.boxes("ego")
    noisy = apply_visibility_noise(gt, scene.visibility("ego"), (320, 180), scaled_noise(0.0),
                                   seed=5, view="ego")
    for frame, record in gt.items():
        assert np.array_equal(noisy[frame].ids, record.ids)
        assert np.array_equal(noisy[frame].boxes, record.boxes)
    _, trials = cell_trials(tiny_synth["drone"], Setting("noise0", "x0", "det", noise=0.0), 0,
                            None)
    assert all((t.det_top_ids != FALSE_POSITIVE).all() and len(t.ego_boxes) == len(t.gt_ego_ids)
               for t in trials)


def test_noise_multiplier_scales_every_rate() -> None:
    base = VisibilityNoise()
    double = scaled_noise(2.0)
    assert math.isclose(double.base.jitter, 2 * base.base.jitter)
    assert math.isclose(double.base.miss_rate, 2 * base.base.miss_rate)
    assert math.isclose(double.base.false_per_frame, 2 * base.base.false_per_frame)
    assert double.hidden_miss == 1.0  # 2 x 0.9, capped
    assert scaled_noise(1.0) == base
    with pytest.raises(ValueError, match="multiplier"):
        scaled_noise(-1.0)


@pytest.mark.parametrize("sweep", ["crowd", "lookalike"])
def test_rendering_sweeps_render_what_they_say(tiny_synth, tmp_path, sweep) -> None:
    setting = grid_settings(sweep)[3]
    folder = render_setting(tiny_synth["drone"], setting, 0, tmp_path / "render")
    data = SyntheticDataset(folder)
    source = SyntheticDataset(tiny_synth["drone"])
    assert len(data) == len(source) and data.scenario == source.scenario
    if sweep == "crowd":
        assert all(len(s.people) == setting.people for s in data.scenes())
    else:
        assert data.manifest["difficulty"]["lookalike"] == setting.lookalike
    stamp = (folder / "dataset.json").stat().st_mtime_ns
    render_setting(tiny_synth["drone"], setting, 0, folder)  # already there: kept
    assert (folder / "dataset.json").stat().st_mtime_ns == stamp


# --------------------------------------------------------------------------------------------
# Splits, grids and tuning


def test_validation_split_is_every_fifth_scene() -> None:
    assert np.flatnonzero(validation_mask(20)).tolist() == [4, 9, 14, 19]
    assert validation_mask(2).tolist() == [False, True]
    with pytest.raises(ValueError, match="at least 2 scenes"):
        validation_mask(1)


def test_grids_have_distinct_columns_with_the_sweep_values() -> None:
    for sweep, points in SWEEPS.items():
        settings = grid_settings(sweep)
        assert [s.key for s in settings[:2]] == ["gt", "det"]
        assert len({s.key for s in settings}) == len(settings)
        values = sorted(s.sweep_value for s in settings if s.sweep_value is not None)
        expected = [p[0] if isinstance(p, tuple) else p for p in points]
        assert values == sorted(float(v) for v in expected)
    with pytest.raises(ValueError, match="unknown sweep"):
        grid_settings("weather")


def test_tune_gamma_takes_the_middle_of_ties(tiny_synth) -> None:
    _, trials = cell_trials(tiny_synth["overview"], Setting("gt", "GT"), 0, None)
    # A zero cost on the true pairs and one elsewhere: every gamma in (0, 1) is perfect.
    costs = [np.where(t.match(), 0.0, 1.0) for t in trials]
    assert tune_gamma(trials, costs, grid=(0.2, 0.4, 0.6, 0.8)) == 0.4
    assert tune_gamma(trials, costs, grid=(0.2, 0.4, 0.6)) == 0.4
