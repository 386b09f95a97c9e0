"""``--camera-check``: cameras judged on the box-only matcher's pseudo-matches, and a run matched
without them when they fail (inference/matching/camera_check.py)."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from tests.test_appearance_check import PEOPLE, _costs, _still, _wandering
from tests.test_camera_refinement import _right
from xvmatch.cli import main
from xvmatch.datasets.synthetic_scenes import SynthConfig
from xvmatch.datasets.tracking_video import render_tracking_video, write_tracking_video
from xvmatch.formats.camera_frames import CameraFrames
from xvmatch.formats.camera_io import save_cameras
from xvmatch.geometry.top_camera_refinement import turned_camera
from xvmatch.inference.matching.appearance_check import (
    CONSISTENCY_WINDOW,
    MIN_CONSISTENCY,
    MIN_PAIRS,
)
from xvmatch.inference.matching.camera_check import (
    DOUBT_LOSS,
    MIN_KEEP,
    OFF_HINT,
    check_cameras,
    check_run_cameras,
)
from xvmatch.inference.matching.learned_association import load_matcher_bundle
from xvmatch.inference.matching.learned_pipeline import LearnedRunOptions, run_learned_association


def _camera_costs(box: dict, moved: int) -> dict:
    """Costs of a matcher given cameras that agree with the boxes' sure pairs, except that
    they price the first ``moved`` of them above the non-association cost (not paired)."""
    out = {}
    for f, c in box.items():
        cost = c.copy()
        cost[np.arange(moved), np.arange(moved)] = 0.9
        out[f] = cost
    return out


@pytest.mark.parametrize(("moved", "trusted"), [(0, True), (1, True), (3, False), (5, False)])
def test_cameras_are_judged_by_the_pseudo_matches_they_keep(moved: int, trusted: bool) -> None:
    """Cameras that keep every pseudo-match, or 4 of 5 (0.8, at the bar), are used; 2 of 5 or
    none, and they are not."""
    top, hor = _still(200)
    box, _ = _costs(200, "agrees")
    check = check_cameras(top, hor, box, _camera_costs(box, moved), gamma=0.5)
    assert check.judged and check.trusted is trusted
    assert check.positives >= MIN_PAIRS and check.consistency == 1.0
    assert check.kept == check.positives * (PEOPLE - moved) // PEOPLE
    assert check.share == pytest.approx(1 - moved / PEOPLE)
    assert (check.share + 2 * check.error >= MIN_KEEP) is trusted
    assert ("cameras used" in check.message()) is trusted
    assert ("matched without them" in check.message()) is not trusted
    assert (OFF_HINT in check.message()) is not trusted
    assert check.to_tell(quiet=True) is not trusted and check.to_tell(quiet=False)


def test_a_short_clip_or_an_unsteady_matcher_keeps_the_cameras() -> None:
    """Cameras that keep no pseudo-match are not judged on a clip shorter than the steadiness
    window, nor where the box-only matcher changes partners over time (its pairs would condemn
    right cameras), nor on too few pairs, nor without a run of consecutive frames."""
    top, hor = _still(200)
    box, _ = _costs(200, "agrees")
    wrong = _camera_costs(box, PEOPLE)
    short = {f: c for f, c in box.items() if f < CONSISTENCY_WINDOW}
    check = check_cameras(top, hor, short, {f: wrong[f] for f in short}, gamma=0.5)
    assert not check.judged and check.trusted and check.kept == 0
    assert check.positives >= MIN_PAIRS and math.isnan(check.consistency)
    assert "the video is too short (150 consecutive frames needed)" in check.message()
    assert check.to_tell(quiet=False) and not check.to_tell(quiet=True)
    unsteady = check_cameras(top, hor, _wandering(box, 20), wrong, gamma=0.5)
    assert not unsteady.judged and unsteady.trusted
    assert unsteady.consistency < MIN_CONSISTENCY
    assert ("change partners over time (a person's track keeps its most frequent partner in "
            "0.27") in unsteady.message()
    few = check_cameras(top, hor, box, wrong, gamma=0.5, min_pairs=10_000)
    assert not few.judged and few.trusted and "10000 needed to judge the cameras" in few.message()
    top, hor = _still(6)
    box, _ = _costs(6, "agrees")
    single = check_cameras(top, hor, box, _camera_costs(box, PEOPLE), gamma=0.5)
    assert not single.judged and single.bursts == 0 and not single.to_tell(quiet=False)
    with pytest.raises(ValueError, match="frame 1: camera costs"):
        top, hor = _still(200)
        box, _ = _costs(200, "agrees")
        check_cameras(top, hor, box, {f: c[:, :2] for f, c in box.items()}, gamma=0.5)


def _turned_video(folder, frames: int):
    """A rendered drone video of ``frames`` frames, its files, and a camera folder whose top
    camera was calibrated 20 degrees off."""
    config = SynthConfig(scenario="drone", n_people=(8, 12), fps=25.0)
    video = render_tracking_video(2, frames, config)
    files = write_tracking_video(video, folder)
    wrong = turned_camera(video.cameras[1].top, [12.0, -10.0, 11.0])
    turned = folder / "turned"
    turned.mkdir()
    for f, cams in video.cameras.items():
        save_cameras(turned / f"{f:06d}.json", {"top": wrong, "ego": cams.hor})
    return video, files, turned


@pytest.fixture(scope="module")
def drone(tmp_path_factory):
    """Just long enough to judge the cameras (CONSISTENCY_WINDOW frames)."""
    return _turned_video(tmp_path_factory.mktemp("drone"), CONSISTENCY_WINDOW)


@pytest.mark.slow
def test_misleading_cameras_are_left_out_and_exact_ones_kept(drone) -> None:
    """On the shipped bundle: exact cameras are not judged unless doubted, and pass; a top
    camera 20 degrees off (beyond what the refinement searches: its fit stays poor) fails, and
    the run is then exactly the run without cameras, better than with them."""
    video, _, turned = drone
    model = load_matcher_bundle("default")
    frames = sorted(video.hor)
    exact = CameraFrames("rendered", per_frame=video.cameras)
    gamma = float(model.gamma)
    for fit_loss in (None, DOUBT_LOSS):  # no fit, or one good enough: not even scored
        kept = check_run_cameras(video.top, video.hor, frames, model, video.hor_size, exact,
                                 gamma, fit_loss)
        assert not kept.judged and kept.trusted and kept.positives == 0
        assert not kept.to_tell(quiet=False)
    passed = check_run_cameras(video.top, video.hor, frames, model, video.hor_size, exact,
                               gamma, 1.0)  # doubted all the same: they pass
    assert passed.judged and passed.trusted and passed.share > 0.95, passed
    assert "fits the people poorly (misfit 1.000)" in passed.message()
    options = LearnedRunOptions((model,), video.hor_size, refine_top_camera=True)
    none = run_learned_association(video.top, video.hor, frames, options)
    given = run_learned_association(video.top, video.hor, frames,
                                    replace(options, cameras=str(turned)))
    checked = run_learned_association(video.top, video.hor, frames,
                                      replace(options, cameras=str(turned), camera_check=True))
    failed = checked.camera_checked
    assert given.camera_checked is None and failed.judged and not failed.trusted
    assert failed.share < 0.5 and failed.fit_loss > DOUBT_LOSS, failed
    assert checked.pairs == none.pairs and _right(video, none.pairs) > _right(video, given.pairs)


@pytest.mark.slow
def test_a_top_camera_that_moves_is_always_judged(drone, tmp_path) -> None:
    """A top camera that changes from frame to frame (a drone's telemetry) has at most the
    constant part of its error refined, and a fit says little of the rest: the check judges
    it whatever the fit. Exact cameras pass; a constant error of 19 degrees (beyond the
    refinement's search) fails, and the run is then exactly the run without cameras."""
    video, _, _ = drone
    model = load_matcher_bundle("default")
    frames = sorted(video.hor)

    def moving(name: str, error: list[float]) -> str:
        folder = tmp_path / name
        folder.mkdir()
        for f, cams in video.cameras.items():  # a thousandth of a degree more every frame
            top = turned_camera(cams.top, np.add(error, [0.0, 0.0, 1e-3 * f]))
            save_cameras(folder / f"{f:06d}.json", {"top": top, "ego": cams.hor})
        return str(folder)

    options = LearnedRunOptions((model,), video.hor_size, refine_top_camera=True,
                                camera_check=True)
    none = run_learned_association(video.top, video.hor, frames, options)
    exact = run_learned_association(video.top, video.hor, frames,
                                     replace(options, cameras=moving("exact", [0.0, 0.0, 0.0])))
    assert exact.refinement.moving and exact.refinement.fit is not None
    kept = exact.camera_checked
    assert kept.judged and kept.trusted and kept.moving and kept.share > 0.9, kept
    assert kept.message().startswith("camera check: the top camera changes from frame to frame "
                                     "and the matcher with the cameras keeps")
    wrong = moving("wrong", [12.0, -10.0, 11.0])
    failed = run_learned_association(video.top, video.hor, frames,
                                     replace(options, cameras=wrong))
    assert failed.camera_checked.judged and not failed.camera_checked.trusted
    assert failed.pairs == none.pairs
    given = run_learned_association(video.top, video.hor, frames,
                                    replace(options, cameras=wrong, camera_check=False))
    assert _right(video, none.pairs) > _right(video, given.pairs)
    assert _right(video, exact.pairs) > _right(video, none.pairs)


@pytest.mark.slow
def test_associate_matches_without_cameras_that_fail(drone, tmp_path, capsys) -> None:
    video, files, turned = drone
    base = ["associate", "--top", str(files["top"]), "--hor", str(files["hor"]), "--model",
            "default", "--image-size", "x".join(map(str, video.hor_size)), "--quiet"]
    costs = tmp_path / "costs.json"
    assert main([*base, "--cameras", str(turned), "--out", str(tmp_path / "a.txt"), "--costs",
                 str(costs)]) == 0
    said = capsys.readouterr().err
    assert "camera check: the top camera fits the people poorly (misfit 0." in said
    assert "and the matcher with the cameras keeps" in said
    assert "matched without them" in said and OFF_HINT in said
    record = json.loads(costs.read_text())["camera_check"]
    assert record["judged"] and not record["cameras_used"] and record["share"] < 0.5
    assert record["kept"] < record["positives"] and record["min_keep"] == MIN_KEEP
    assert record["fit_loss"] > DOUBT_LOSS
    assert main([*base, "--cameras", str(turned), "--camera-check", "off", "--out",
                 str(tmp_path / "b.txt")]) == 0
    assert "camera check" not in capsys.readouterr().err
    assert (tmp_path / "a.txt").read_bytes() != (tmp_path / "b.txt").read_bytes()


@pytest.mark.slow
def test_track_and_associate_multi_leave_out_cameras_that_fail(drone, tmp_path, capsys) -> None:
    """``track`` then weighs the cross-view edges from the boxes alone, exactly as without
    --cameras; ``associate-multi`` matches that view without them, exactly as without."""
    video, files, turned = drone
    size = "x".join(map(str, video.hor_size))
    track = ["track", "--model", "default", "--top", str(files["top"]), "--hor",
             str(files["hor"]), "--image-size", size, "--offset", "0", "--quiet"]
    assert main([*track, "--out", str(tmp_path / "t_none")]) == 0
    assert main([*[a for a in track if a != "--quiet"], "--cameras", str(turned), "--out",
                 str(tmp_path / "t_cams"), "--write-cameras", str(tmp_path / "refined")]) == 0
    said = capsys.readouterr().err
    assert "camera check:" in said and "matched without them" in said
    # the cameras written are those refined, though the run left them out
    assert f"cameras: wrote {tmp_path / 'refined'} (the top camera turned " in said
    for name in ("top.txt", "hor.txt"):
        assert (tmp_path / "t_none" / name).read_bytes() == (
            tmp_path / "t_cams" / name).read_bytes()
    multi = ["associate-multi", "--model", "default", "--top", str(files["top"]), "--hor",
             str(files["hor"]), "--image-size", size, "--quiet"]
    assert main([*multi, "--out", str(tmp_path / "m_none")]) == 0
    assert main([*multi, "--cameras", str(turned), "--out", str(tmp_path / "m_cams")]) == 0
    assert f"--hor {files['hor']}: camera check:" in capsys.readouterr().err
    for name in ("top.txt", "hor1.txt"):
        assert (tmp_path / "m_none" / name).read_bytes() == (
            tmp_path / "m_cams" / name).read_bytes()


@pytest.mark.slow
def test_adapt_mines_without_cameras_that_fail(tmp_path, capsys) -> None:
    """``adapt`` then mines its pairs from the boxes alone: the site bundle is the one fitted
    without --cameras, byte for byte, and its manifest names no camera file; or, when the site
    bundle's pairs on the held-out frames do not show a gain, both runs refuse with the same
    figures. (240 frames: the check needs 150; the last 60 are held out to judge the pairs.)"""
    video, files, turned = _turned_video(tmp_path, 240)
    base = ["adapt", "--top", str(files["top"]), "--hor", str(files["hor"]), "--top-images",
            str(files["top_images"]), "--hor-images", str(files["hor_images"]), "--image-size",
            "x".join(map(str, video.hor_size)), "--burst", "8", "--quiet"]
    code = main([*base, "--cameras", str(turned), "--out", str(tmp_path / "with")])
    said = capsys.readouterr().err
    assert "camera check: the top camera fits the people poorly" in said
    assert "matched without them" in said
    assert main([*base, "--out", str(tmp_path / "none")]) == code
    if code != 0:  # refused: the same measured figures, nothing written
        assert said.strip().splitlines()[-1] == capsys.readouterr().err.strip().splitlines()[-1]
        assert not (tmp_path / "with").exists() and not (tmp_path / "none").exists()
        return
    fitted = json.loads((tmp_path / "with" / "manifest.json").read_text())["adaptation"]
    assert "cameras" not in fitted["fitted_on"]
    assert fitted["fitted_on"]["frames_scored"] == 176  # 22 bursts of 8 in the first 180
    assert (tmp_path / "with" / "adaptation.npz").read_bytes() == (
        tmp_path / "none" / "adaptation.npz").read_bytes()
