"""The frame check (inference/matching/frame_check.py): a frame's appearance cue judged from its own
cost statistics, its fit, its manifest record, and its use in ``associate_sequence_learned``."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.datasets.synthetic_scenes import SynthConfig
from xvmatch.datasets.tracking_video import render_tracking_video, write_tracking_video
from xvmatch.formats.mot_boxes import read_mot_boxes
from xvmatch.inference.matching.appearance_check import AppearanceCheck
from xvmatch.inference.matching.bundle import MANIFEST, BundleError, read_manifest
from xvmatch.inference.matching.frame_check import (
    FEATURES,
    FrameCheck,
    fit_frame_check,
    frame_check_features,
)
from xvmatch.inference.matching.learned_association import (
    LearnedMatcher,
    associate_sequence_learned,
    load_matcher_bundle,
)

ROOT = Path(__file__).resolve().parents[1]


def _agreeing(n: int, rng: np.random.Generator, agree: bool) -> tuple[np.ndarray, np.ndarray]:
    """Box-only costs sure of the diagonal, and a cue that agrees with them or is noise."""
    box = np.full((n, n), 0.9)
    np.fill_diagonal(box, 0.1)
    app = rng.uniform(0.3, 0.6, (n, n))
    if agree:
        np.fill_diagonal(app, 0.05)
    return app, box


def test_features_of_a_cue_that_agrees_with_the_boxes() -> None:
    app, box = _agreeing(4, np.random.default_rng(0), True)
    f = dict(zip(FEATURES, frame_check_features(app, box), strict=True))
    assert f["row_agree"] == f["col_agree"] == 1.0
    assert f["rows"] == f["cols"] == 4
    assert f["app_mean"] == pytest.approx(app.mean())
    assert f["best_margin"] == pytest.approx(app.mean() - 0.05)
    assert f["row_gap"] == pytest.approx((np.sort(app, axis=1)[:, 1] - 0.05).mean())
    assert f["box_correlation"] > 0.5
    # the boxes are sure of the diagonal and the cue puts it first: the statistics of the pairs
    assert f["box_assignment_agree"] == 1.0 and f["box_pair_rank"] == 0.0
    assert f["box_row_gap"] == f["box_col_gap"] == pytest.approx(0.8)
    assert f["box_row_min"] == pytest.approx(0.1)
    assert f["box_pair_z"] == pytest.approx((0.05 - app.mean()) / app.std())
    noise = dict(zip(FEATURES, frame_check_features(
        *_agreeing(6, np.random.default_rng(3), False)), strict=True))
    assert noise["box_assignment_agree"] < 1.0 and noise["box_pair_rank"] > 0.0
    # a single column: no second-best to compare with, a constant: no correlation
    one = frame_check_features(np.full((3, 1), 0.4), np.array([[0.1], [0.2], [0.3]]))
    assert one[FEATURES.index("row_gap")] == 0.0
    assert one[FEATURES.index("box_correlation")] == 0.0
    with pytest.raises(ValueError, match="same non-empty"):
        frame_check_features(app, box[:, :3])
    with pytest.raises(ValueError, match="same non-empty"):
        frame_check_features(np.zeros((0, 2)), np.zeros((0, 2)))


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 6), st.integers(1, 6), st.integers(0, 2**31 - 1))
def test_features_do_not_depend_on_the_order_of_the_boxes(m, n, seed) -> None:
    """Rows and columns permuted together in both matrices: the same statistics."""
    rng = np.random.default_rng(seed)
    app, box = rng.uniform(size=(m, n)), rng.uniform(size=(m, n))
    p, q = rng.permutation(m), rng.permutation(n)
    a = frame_check_features(app, box)
    b = frame_check_features(app[p][:, q], box[p][:, q])
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)
    assert a.shape == (len(FEATURES),) and np.all(np.isfinite(a))


def _samples(seed: int = 0, frames: int = 300) -> tuple[np.ndarray, np.ndarray]:
    """Frames whose images help when the cue agrees with the boxes and hurt when it is noise."""
    rng = np.random.default_rng(seed)
    feats, gains = [], []
    for k in range(frames):
        agree = bool(k % 2)
        app, box = _agreeing(int(rng.integers(2, 8)), rng, agree)
        feats.append(frame_check_features(app, box))
        gains.append(rng.uniform(0.05, 0.2) * (1 if agree else -1))
    return np.asarray(feats), np.asarray(gains)


def test_the_fit_learns_which_frames_images_help_and_is_deterministic() -> None:
    feats, gains = _samples()
    check = fit_frame_check(feats, gains, fitted={"data": "test"})
    again = fit_frame_check(feats, gains, fitted={"data": "test"})
    for key in ("mean", "scale", "coef"):
        np.testing.assert_array_equal(getattr(check, key), getattr(again, key))
    assert check.intercept == again.intercept
    rng = np.random.default_rng(1)
    assert all(check.trusts(*_agreeing(5, rng, True)) for _ in range(20))
    assert not any(check.trusts(*_agreeing(5, rng, False)) for _ in range(20))
    p = check.probabilities(feats)
    assert p.shape == gains.shape and np.all((p > 0.5) == (gains > 0))
    np.testing.assert_array_equal(check.trusted(feats), gains > 0)  # the same rule, batched
    with pytest.raises(ValueError, match="gained and frames where they lost"):
        fit_frame_check(feats, np.abs(gains))
    with pytest.raises(ValueError, match="features must be"):
        fit_frame_check(feats[:, :3], gains)
    with pytest.raises(ValueError, match="finite"):
        fit_frame_check(np.where(feats > 0.5, np.nan, feats), gains)


def test_the_record_reads_back_and_names_a_bad_field() -> None:
    check = fit_frame_check(*_samples(), threshold=0.6, fitted={"frames": 300})
    record = json.loads(json.dumps(check.to_record()))
    back = FrameCheck.from_record(record)
    for key in ("mean", "scale", "coef"):
        np.testing.assert_array_equal(getattr(back, key), getattr(check, key))
    assert (back.intercept, back.threshold, back.fitted) == (check.intercept, 0.6,
                                                              {"frames": 300})
    assert record["format_version"] == 2 and record["features"] == list(FEATURES)
    for version in (3, "2", [2], True):
        with pytest.raises(ValueError, match=r"'frame_check\.format_version'"):
            FrameCheck.from_record({**record, "format_version": version})
    bad = {"features": ["x"], "coef": [1.0], "scale": [0.0] * 16,
           "threshold": 1.5, "intercept": "a"}
    for key, value in bad.items():
        with pytest.raises(ValueError, match=f"'frame_check.{key}'"):
            FrameCheck.from_record({**record, key: value})
    with pytest.raises(ValueError, match="finite"):
        FrameCheck.from_record({**record, "mean": [float("nan")] * 16})


def test_a_version_1_record_reads_the_first_ten_statistics() -> None:
    """Checks fitted before the box statistics were added still read and judge frames on the
    ten they were fitted on; a record that mixes the versions is refused."""
    feats, gains = _samples()
    check = fit_frame_check(feats, gains)
    old = {**check.to_record(), "format_version": 1, "features": list(FEATURES[:10])}
    for key in ("mean", "scale", "coef"):
        old[key] = old[key][:10]
    back = FrameCheck.from_record(old)
    assert back.to_record()["format_version"] == 1
    z = (feats[:, :10] - back.mean) / back.scale
    np.testing.assert_allclose(back.probabilities(feats),
                               1.0 / (1.0 + np.exp(-(z @ back.coef + back.intercept))))
    with pytest.raises(ValueError, match=r"'frame_check.features' must be .*\(version 1\)"):
        FrameCheck.from_record({**old, "features": list(FEATURES)})
    with pytest.raises(ValueError, match=r"'frame_check.coef' must be 10 finite numbers"):
        FrameCheck.from_record({**old, "coef": check.to_record()["coef"]})


def test_a_bundle_manifest_with_a_bad_frame_check_names_the_field(tmp_path) -> None:
    folder = tmp_path / "bundle"
    shutil.copytree(ROOT / "inference" / "default_bundle", folder)
    doc = json.loads((folder / MANIFEST).read_text())
    doc["frame_check"] = {**fit_frame_check(*_samples()).to_record(), "threshold": 2}
    (folder / MANIFEST).write_text(json.dumps(doc))
    with pytest.raises(BundleError, match=r"manifest.json: manifest field 'frame_check.threshold"):
        read_manifest(folder)
    del doc["frame_check"]
    (folder / MANIFEST).write_text(json.dumps(doc))
    assert read_manifest(folder).frame_check is None


def test_the_shipped_bundle_carries_a_frame_check() -> None:
    check = read_manifest(ROOT / "inference" / "default_bundle").frame_check
    assert check is not None and check.fitted["frames"] > 1000
    assert "fit_frame_check.py" in check.fitted["command"]
    assert len(check.coef) == len(FEATURES)  # fitted on every statistic
    scores = check.fitted["threshold_choice"]["scores"]
    assert check.threshold in [s[0] for s in scores]  # the cross-validated choice


def _with_check(model: LearnedMatcher, check: FrameCheck | None) -> LearnedMatcher:
    manifest = dataclasses.replace(model.bundle.manifest, frame_check=check)
    return dataclasses.replace(model, bundle=dataclasses.replace(model.bundle, manifest=manifest))


def _constant(trust: bool) -> FrameCheck:
    """A check that trusts every frame or none (all weights 0, the bias alone)."""
    zeros = np.zeros(len(FEATURES))
    return FrameCheck(zeros, np.ones(len(FEATURES)), zeros, 20.0 if trust else -20.0)


@pytest.mark.slow
def test_associate_judges_each_frame_when_the_video_cannot_be_judged(tmp_path) -> None:
    """Three frames, too few to judge over time: a check that trusts no frame gives exactly
    the boxes-only matches and says so; one that trusts every frame, the images' matches;
    with the check off, or with cameras, the frame check is not used."""
    v = render_tracking_video(3, 3, SynthConfig(scenario="drone", n_people=(8, 10), fps=25.0))
    video = write_tracking_video(v, tmp_path)
    top, hor = read_mot_boxes(video["top"]), read_mot_boxes(video["hor"])
    import cv2

    h, w = cv2.imread(str(video["hor_images"] / "000001.png")).shape[:2]

    class Folder:
        def __init__(self, folder: Path) -> None:
            self.folder = folder

        def get(self, frame: int) -> np.ndarray:
            return cv2.imread(str(self.folder / f"{frame:06d}.png"))

    images = {"top_images": Folder(video["top_images"]),
              "hor_images": Folder(video["hor_images"])}
    base = load_matcher_bundle("default")

    def run(check, appearance_check=True, with_images=True):
        checked: list[AppearanceCheck] = []
        pairs = associate_sequence_learned(
            top, hor, w, _with_check(base, check), hor_height=h, checked=checked,
            appearance_check=appearance_check, **(images if with_images else {}))
        return pairs, checked

    boxes, _ = run(None, with_images=False)
    plain, (unjudged,) = run(None)
    assert not unjudged.judged and unjudged.frames == 0 and not unjudged.worth_saying
    never, (dropped,) = run(_constant(False))
    assert never == boxes and never != plain
    assert (dropped.frames, dropped.frames_dropped) == (3, 3) and dropped.trusted
    assert dropped.to_tell(quiet=True)
    assert "judged frame by frame instead, matched 3 of 3 frames from the boxes alone" in \
        dropped.message()
    always, (kept,) = run(_constant(True))
    assert always == plain and (kept.frames, kept.frames_dropped) == (3, 0)
    assert not kept.to_tell(quiet=False)  # single frames, nothing left out: nothing to say
    assert run(_constant(False), appearance_check=False)[0] == plain


@pytest.mark.slow
def test_the_fitting_script_writes_a_record_and_installs_it(tmp_path, monkeypatch, capsys
                                                            ) -> None:
    """benchmarks/fit_frame_check.py on 2 validation scenes per scenario: a record that reads
    back, and --install puts it in a copy of the shipped bundle (its files unchanged)."""
    import sys

    sys.path.insert(0, str(ROOT / "benchmarks"))
    import fit_frame_check

    bundle = tmp_path / "bundle"
    shutil.copytree(ROOT / "inference" / "default_bundle", bundle)
    doc = json.loads((bundle / MANIFEST).read_text())
    doc.pop("frame_check", None)
    (bundle / MANIFEST).write_text(json.dumps(doc))
    onnx_before = {p.name: p.read_bytes() for p in bundle.glob("*.onnx")}
    out = tmp_path / "record.json"
    args = ["fit_frame_check.py", "--bundle", str(bundle), "--scenes", "2", "--shifts", "0", "3",
            "--workers", "1", "--work", str(tmp_path / "work"), "--out", str(out), "--install"]
    monkeypatch.setattr(sys, "argv", args)  # 2 scenes: both in one fold, nothing to fit on
    with pytest.raises(SystemExit):
        fit_frame_check.main()
    assert "--threshold auto:" in capsys.readouterr().err and not out.exists()
    monkeypatch.setattr(sys, "argv", [*args, "--threshold", "0.6"])
    assert fit_frame_check.main() == 0
    printed = capsys.readouterr().out
    assert "drone, strength 3" in printed and "installed in" in printed
    record = FrameCheck.from_record(json.loads(out.read_text()))
    assert record.fitted["shifts"] == [0.0, 3.0] and record.fitted["frames"] > 20
    assert record.threshold == 0.6 and "threshold_choice" not in record.fitted
    installed = read_manifest(bundle).frame_check
    np.testing.assert_array_equal(installed.coef, record.coef)
    assert {p.name: p.read_bytes() for p in bundle.glob("*.onnx")} == onnx_before
    for bad, value, said in (("--out", str(tmp_path), "is a folder"),
                             ("--threshold", "1", "expected a number in (0, 1) (or auto), got"),
                             ("--threshold", "half", "expected a number in (0, 1) (or auto), got")):
        monkeypatch.setattr(sys, "argv", ["fit_frame_check.py", "--bundle", str(bundle),
                                          bad, value])
        with pytest.raises(SystemExit):  # refused before any work
            fit_frame_check.main()
        assert said in capsys.readouterr().err


@pytest.mark.slow
def test_associate_command_says_how_many_frames_came_from_the_boxes(tmp_path, capsys) -> None:
    """The command line with a bundle whose frame check trusts no frame: the line is printed
    even with --quiet, --costs records it, and the matches are the boxes-only ones."""
    from xvmatch.cli import main

    v = render_tracking_video(3, 2, SynthConfig(scenario="drone", n_people=(6, 8), fps=25.0))
    (tmp_path / "video").mkdir()
    video = write_tracking_video(v, tmp_path / "video")
    bundle = tmp_path / "bundle"
    shutil.copytree(ROOT / "inference" / "default_bundle", bundle)
    doc = json.loads((bundle / MANIFEST).read_text())
    doc["frame_check"] = _constant(False).to_record()
    (bundle / MANIFEST).write_text(json.dumps(doc))
    import cv2

    size = "x".join(map(str, cv2.imread(str(video["hor_images"] / "000001.png")).shape[1::-1]))
    args = ["associate", "--model", str(bundle), "--top", str(video["top"]), "--hor",
            str(video["hor"]), "--quiet"]
    assert main([*args, "--image-size", size, "--out", str(tmp_path / "boxes.csv")]) == 0
    capsys.readouterr()
    costs = tmp_path / "costs.json"
    assert main([*args, "--top-images", str(video["top_images"]), "--hor-images",
                 str(video["hor_images"]), "--out", str(tmp_path / "images.csv"),
                 "--costs", str(costs)]) == 0
    assert "matched 2 of 2 frames from the boxes alone" in capsys.readouterr().err
    record = json.loads(costs.read_text())["appearance_check"]
    assert record["frame_check"] == {"frames": 2, "from_boxes": 2} and not record["judged"]
    assert (tmp_path / "images.csv").read_bytes() == (tmp_path / "boxes.csv").read_bytes()
