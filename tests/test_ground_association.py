"""The ground-map association run (issue 67) on a rendered oblique scene, ids scrambled: the top
camera calibrated from its people, the walking horizontal camera registered, pairs consistent
over the clip."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from xvmatch.cues import ground_registration as gr
from xvmatch.datasets.oblique_scenes import ObliqueSceneConfig, make_oblique_scene
from xvmatch.formats.mot_boxes import FrameBoxes, stack_frames
from xvmatch.inference.matching import ground_association
from xvmatch.inference.matching.frame_rate import READ_RATE_SLACK, UNREAD_RATE_SLACK
from xvmatch.inference.matching.ground_association import (
    GroundAssociationOptions,
    run_ground_association,
    top_calibration,
    top_ground_points,
    top_sizes,
)
from xvmatch.metrics.cross_view_metrics import count_sequence, summarize


def _scrambled(frames: dict, offset: int) -> tuple[dict, dict]:
    ids = sorted({int(i) for r in frames.values() for i in r.ids})
    order = np.random.default_rng(offset).permutation(len(ids))  # ids scrambled, one to one
    new = {i: offset + int(order[k]) for k, i in enumerate(ids)}
    back = {v: k for k, v in new.items()}
    return {f: FrameBoxes(f, np.array([new[int(i)] for i in r.ids], dtype=np.int64), r.boxes)
            for f, r in frames.items()}, back


def _prepared(scene) -> tuple[dict, dict, list[int], GroundAssociationOptions, tuple]:
    """The scene's two views with ids scrambled per view, every 3rd frame, the run's options
    (the true image sizes, 10 frames a second) and the ways back to the scene's ids."""
    top, top_back = _scrambled(scene.top, 100)
    hor, hor_back = _scrambled(scene.hor["hor1"], 500)
    frames = [f for f in sorted(set(top) & set(hor)) if f % 3 == 1]
    options = GroundAssociationOptions(scene.top_cameras[0].image_size,
                                       scene.hor_cameras["hor1"][0].image_size, fps=10.0)
    return top, hor, frames, options, (top_back, hor_back)


def _cvidf1(scene, run, frames: list[int], backs: tuple) -> float:
    """CVIDF1 of a run's pairs on ``frames``, its ids taken back to the scene's."""
    back = {f: [(backs[0][a], backs[1][b]) for a, b in p] for f, p in run.pairs.items()}
    return summarize(count_sequence(back, scene.top, scene.hor["hor1"], frames=frames)).cvidf1


@pytest.fixture(scope="module")
def scene():
    config = ObliqueSceneConfig(top_pitch=(25.0, 45.0), overlap=(0.7, 1.0))
    return make_oblique_scene(config, 100, np.random.default_rng(5))


@pytest.mark.slow
def test_oblique_scene_associated_from_boxes_alone(scene) -> None:
    top, hor, frames, options, backs = _prepared(scene)
    calib = top_calibration(top, options.top_size)
    assert calib.kind == "oblique"
    true_tilt = np.degrees(np.arcsin(-scene.top_cameras[0].R[2, 2]))
    assert abs(calib.tilt_deg - true_tilt) < 5.0
    later = top_calibration(top, options.top_size, spread="later")  # as associate asks it
    assert np.isnan(later.tilt_std_deg)
    scores = {}
    for consensus in (False, True):
        run = run_ground_association(top, hor, replace(options, consensus=consensus), frames,
                                     later if consensus else calib)
        scores[consensus] = _cvidf1(scene, run, frames, backs)
    assert run.calibration == calib  # a steady camera's spread measured for the note: the same
    assert run.summary.startswith("top view: oblique, tilt")
    spread = calib.tilt_std_deg  # said to a tenth under a degree, not "+- 0"
    said = f"{spread:.1f}" if spread < 0.95 else f"{spread:.0f}"
    assert f"tilt {calib.tilt_deg:.0f} +- {said} degrees" in run.summary
    assert "+- 0 degrees" not in run.summary
    # Measured 95.7 frame by frame and 100.0 with the consensus along the tracks (71.3 and
    # 94.9 with everyone read at 1.72 m).
    assert scores[False] > 80.0
    assert scores[True] > 90.0


def test_top_points_given_replace_the_calibrations_map(scene, monkeypatch) -> None:
    """``top_points`` (the top view mapped otherwise, e.g. a benchmark's true camera of each
    frame) are the run's top map: the calibration's own map given pairs as without it (where
    the top camera's sights are left out as with a map given: they come from the
    calibration's camera), and a wrong number of rows is refused."""
    top, hor, _, options, _ = _prepared(scene)
    frames = list(range(1, 31, 3))
    options = replace(options, consensus=False)
    calib = top_calibration(top, options.top_size)
    _, _, boxes = stack_frames(top)
    own = top_ground_points(boxes, calib)
    plain = run_ground_association(top, hor, options, frames, calib)
    assert sum(map(len, plain.pairs.values())) > 0
    # Sizes are read as the run reads them; the map of every box is the calibration's.
    monkeypatch.setattr(ground_association, "top_sights", lambda *_: None)
    read = run_ground_association(top, hor, replace(options, top_sizes=False), frames, calib)
    given = run_ground_association(top, hor, replace(options, top_sizes=False), frames, calib,
                                   top_points=own)
    assert given.pairs == read.pairs
    with pytest.raises(ValueError, match=r"top_points must be \(\d+, 2\)"):
        run_ground_association(top, hor, options, frames, calib, top_points=own[:-1])


@pytest.mark.slow
def test_a_top_map_off_in_scale_pairs_as_the_right_one_in_video_mode() -> None:
    """The top camera's height read 30 % off (its map shrunk or stretched by 1.3): video mode
    keeps the map scale whose run keeps the most pairs along the tracks, which puts the map
    back (0.7 and 1.3 among the scales tried) and pairs as on the right map (seed 2's clip;
    on the module's, seed 5, the map put back by 0.7, which differs from the right one in its
    last bits, pairs otherwise since far and hidden people are not charged: 80.3 CVIDF1
    against 100.0)."""
    scene = make_oblique_scene(ObliqueSceneConfig(top_pitch=(25.0, 45.0), overlap=(0.7, 1.0)),
                               100, np.random.default_rng(2))
    top, hor, frames, options, _ = _prepared(scene)
    frames = frames[:20]
    options = replace(options, consensus=True, top_sizes=False, hor_hfov_deg=70.0)
    calib = top_calibration(top, options.top_size)
    own = top_ground_points(stack_frames(top)[2], calib)
    right = run_ground_association(top, hor, options, frames, calib, top_points=own)
    assert right.scale == 1.0 and sum(map(len, right.pairs.values())) > 50
    for off in (1.3, 0.7):
        run = run_ground_association(top, hor, options, frames, calib, top_points=own / off)
        assert run.scale == off
        assert run.pairs == right.pairs


@pytest.mark.slow
def test_same_input_same_pairs(scene) -> None:
    options = GroundAssociationOptions(scene.top_cameras[0].image_size,
                                       scene.hor_cameras["hor1"][0].image_size, fps=10.0)
    frames = list(range(1, 40, 3))
    a = run_ground_association(scene.top, scene.hor["hor1"], options, frames)
    b = run_ground_association(scene.top, scene.hor["hor1"], options, frames)
    assert a.pairs == b.pairs and a.calibration == b.calibration


@pytest.mark.slow
def test_frame_mode_does_not_read_the_views_track_ids(scene) -> None:
    """Within-view track ids are for video mode only: frame by frame, the top view's ids
    renumbered on every frame (no id persists) give the same calibration and pairs."""
    options = GroundAssociationOptions(scene.top_cameras[0].image_size,
                                       scene.hor_cameras["hor1"][0].image_size, fps=10.0,
                                       consensus=False)
    frames = list(range(1, 60, 3))
    per_frame = {f: FrameBoxes(f, 1000 * f + np.asarray(r.ids, np.int64), r.boxes)
                 for f, r in scene.top.items()}
    a = run_ground_association(scene.top, scene.hor["hor1"], options, frames)
    b = run_ground_association(per_frame, scene.hor["hor1"], options, frames)
    assert a.calibration == b.calibration
    assert a.pairs == {f: [(t % 1000, h) for t, h in p] for f, p in b.pairs.items()}
    assert a.calibration == top_calibration(scene.top, options.top_size, tracks=False)
    # The test would pass vacuously were the file's tracks the same as the boxes' own links.
    assert a.calibration != top_calibration(scene.top, options.top_size)


def test_people_read_at_their_height_register_a_close_drone() -> None:
    """A close, low drone (people 60-270 px tall) and a handheld camera, half of each view's
    people seen by the other: read at 1.72 m the handheld people are off by metres and the
    registration locks on a wrong pose; read at their top-view partner's height (the default)
    it finds the right one. Ids scrambled per view, the handheld lens given (66 degrees);
    measured 22.2 and 100.0 CVIDF1."""
    config = ObliqueSceneConfig(top_pitch=(20.0, 45.0), overlap=(0.35, 0.65),
                                top_height=(4.0, 12.0))
    scene = make_oblique_scene(config, 60, np.random.default_rng(1))
    top, hor, frames, options, backs = _prepared(scene)
    lens = scene.hor_cameras["hor1"][0]
    options = replace(options, hor_hfov_deg=float(
        np.degrees(2.0 * np.arctan(0.5 * lens.width / lens.K[0, 0]))))
    calib = top_calibration(top, options.top_size)
    scores = {}
    for sizes in (False, True):
        run = run_ground_association(top, hor, replace(options, top_sizes=sizes), frames, calib)
        scores[sizes] = _cvidf1(scene, run, frames, backs)
    assert scores[True] > 95.0 > 50.0 > scores[False]


def test_a_small_crowd_walking_together_is_not_read_as_a_moving_drone() -> None:
    """A static close drone, five people in its view, walking: their common step reads as the
    top map's motion (0.1 m a step), which, taken out of the registration's jumps, tipped this
    clip to a wrong pose in video mode (0 of 39 pairs right, 91 % frame by frame). The
    registration also runs with the map left still and keeps the better-explained clip.
    Ids scrambled per view; measured 100.0 CVIDF1."""
    config = ObliqueSceneConfig(top_pitch=(20.0, 45.0), overlap=(0.35, 0.65),
                                top_height=(4.0, 12.0))
    scene = make_oblique_scene(config, 120, np.random.default_rng([1, 10]))
    top, hor, frames, options, backs = _prepared(scene)
    # Every 3rd frame numbered 1, 2, 3 (a file of sampled frames), 10/3 a second.
    top, hor = ({k: FrameBoxes(k, v[f].ids, v[f].boxes) for k, f in enumerate(frames, 1)}
                for v in (top, hor))
    run = run_ground_association(top, hor, replace(options, fps=10.0 / 3.0))
    run = replace(run, pairs={frames[k - 1]: p for k, p in run.pairs.items()})
    assert _cvidf1(scene, run, frames, backs) > 95.0


@pytest.mark.slow
def test_associate_top_view_from_the_command_line(scene, tmp_path, capsys) -> None:
    from xvmatch.cli import main
    from xvmatch.datasets.oblique_scenes import write_oblique_scene

    paths = write_oblique_scene(scene, tmp_path, "s")
    hor_size = "x".join(map(str, scene.hor_cameras["hor1"][0].image_size))
    base = ["associate", "--top", str(paths["top"]), "--hor", str(paths["hor1"]),
            "--image-size", hor_size, "--fps", "10"]
    out = tmp_path / "pred.csv"
    assert main([*base, "--top-image-size", "1920x1080", "--mode", "video",
                 "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "note: top view: oblique, tilt" in err and "consistent over the clip" in err
    assert out.read_text().startswith("frame,top_id,hor_id\n")
    # The checks below are of the notes and the top size: one lens, not the choice among
    # three (tests/test_hor_hfov_auto.py), a third of the time.
    base += ["--hor-hfov", "70"]
    # Forced oblique needs the top image size: one line.
    assert main([*base, "--top-view", "oblique", "--out", str(tmp_path / "x.csv")]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "give --top-image-size WxH" in lines[0]
    # Values out of range are refused by the parser, naming the option and its range.
    for extra in (["--hor-hfov", "5"], ["--fps", "0"]):
        with pytest.raises(SystemExit) as stop:
            main([*base, *extra, "--out", str(tmp_path / "x.csv")])
        assert stop.value.code == 2
        assert f"argument {extra[0]}: expected a number in" in capsys.readouterr().err
    # Without the top image size, auto takes the smallest common video size holding the top
    # boxes (here 1280x720: the people fill the frame's upper left), says so, and pairs as with
    # that size given. Options of the nadir search are said to be unused on this path;
    # --camera-id (the holder, id 0 here) places the handheld camera, and says where.
    base += ["--camera-id", "0", "--search", "follow"]
    assert main([*base, "--out", str(tmp_path / "n.csv")]) == 0
    err = capsys.readouterr().err
    assert "people stand upright" in err and "took 1280x720" in err
    assert "note: top view: oblique, tilt" in err
    assert "--camera-id 0: left out of the pairs (not in their own camera's view); the " \
        "handheld camera sought within 2 m of where the top view sees them" in err
    assert "(--search: not used on this path)" in err
    assert main([*base, "--top-image-size", "1280x720", "--out", str(tmp_path / "g.csv"),
                 "--quiet"]) == 0
    assert "top view" not in capsys.readouterr().err  # --quiet: no notes
    assert (tmp_path / "n.csv").read_text() == (tmp_path / "g.csv").read_text()


@pytest.mark.slow
def test_a_nadir_top_view_says_what_its_path_assumes(tmp_path, capsys) -> None:
    """A drone looking straight down goes to the nadir search, whose one line says that it
    takes the wearer to be a top-view person and what to give where they are not."""
    from xvmatch.cli import main
    from xvmatch.datasets.oblique_scenes import write_oblique_scene

    scene = make_oblique_scene(ObliqueSceneConfig(top_pitch=(90.0, 90.0),
                                                  top_height=(30.0, 40.0)), 30,
                               np.random.default_rng(0))
    paths = write_oblique_scene(scene, tmp_path, "n")
    assert main(["associate", "--top", str(paths["top"]), "--hor", str(paths["hor1"]),
                 "--top-image-size", "1920x1080", "--fps", "10", "--out",
                 str(tmp_path / "n.csv")]) == 0
    err = capsys.readouterr().err
    assert "top view: looking straight down" in err
    assert "wearer to be one of its people (if not: --top-view oblique)" in err


@pytest.mark.slow
def test_a_phones_size_is_guessed_on_the_ground_path(tmp_path, capsys) -> None:
    """A 1920x1080 handheld view whose boxes fit CVMHAT's 2688x1512: boxes alone, the ground
    path takes 1920x1080, saying so in one line (not first that it assumes CVMHAT's: that note
    waits for the path), and pairs as with that size given."""
    from xvmatch.cli import main
    from xvmatch.datasets.oblique_scenes import write_oblique_scene

    config = ObliqueSceneConfig(top_pitch=(25.0, 45.0), overlap=(0.7, 1.0))
    scene = make_oblique_scene(config, 100, np.random.default_rng(1))
    assert scene.hor_cameras["hor1"][0].image_size == (1920, 1080)
    paths = write_oblique_scene(scene, tmp_path, "s")
    base = ["associate", "--top", str(paths["top"]), "--hor", str(paths["hor1"]),
            "--top-image-size", "1920x1080", "--fps", "10", "--hor-hfov", "70"]
    assert main([*base, "--out", str(tmp_path / "guess.csv")]) == 0
    err = capsys.readouterr().err
    assert "images are 2688x1512 (CVMHAT" not in err
    assert (f"note: {paths['hor1']}: its images taken as 1920x1080 on this path, the smallest "
            "common video size holding its boxes, not CVMHAT's") in err
    assert main([*base, "--image-size", "1920x1080", "--out", str(tmp_path / "given.csv")]) == 0
    assert "its images taken as" not in capsys.readouterr().err
    assert (tmp_path / "guess.csv").read_text() == (tmp_path / "given.csv").read_text()


def _phone_clip(tmp_path, edge_people: tuple[int, int], seed: int) -> tuple[dict, list[str]]:
    """A 60-frame clip of a 3640x2048 phone under a drone at 25-45 degrees (``edge_people``
    passing across each camera's bottom edge), its box files and ``associate``'s arguments
    for them (frame rate and lens given)."""
    from xvmatch.datasets.oblique_scenes import write_oblique_scene

    config = ObliqueSceneConfig(top_pitch=(25.0, 45.0), overlap=(0.7, 1.0),
                                edge_people=edge_people)
    scene = make_oblique_scene(config, 60, np.random.default_rng(seed))
    assert scene.hor_cameras["hor1"][0].image_size == (3640, 2048)
    paths = write_oblique_scene(scene, tmp_path, "s")
    return paths, ["associate", "--top", str(paths["top"]), "--hor", str(paths["hor1"]),
                   "--fps", "10", "--hor-hfov", "70"]


@pytest.mark.slow
def test_boxes_past_cvmhats_size_take_the_ground_path_with_a_guessed_size(tmp_path,
                                                                          capsys) -> None:
    """A 3640x2048 handheld view, boxes alone: they do not fit CVMHAT's 2688x1512, so the nadir
    search refuses them in one line asking for ``--image-size``, while the ground-map path (an
    oblique top view) takes 3840x2160, the smallest common size holding them, saying so, and
    pairs as with that size given."""
    from xvmatch.cli import main

    paths, base = _phone_clip(tmp_path, (0, 0), 2)
    guess, given = tmp_path / "guess.csv", tmp_path / "given.csv"
    assert main([*base, "--top-image-size", "1920x1080", "--out", str(guess)]) == 0
    err = capsys.readouterr().err
    assert (f"note: {paths['hor1']}: its images taken as 3840x2160 on this path, the smallest "
            "common video size holding its boxes (give --image-size WxH if not)") in err
    assert "2688x1512 (CVMHAT" not in err
    assert main([*base, "--top-image-size", "1920x1080", "--image-size", "3840x2160",
                 "--quiet", "--out", str(given)]) == 0
    assert guess.read_text() == given.read_text()
    refused = tmp_path / "nadir.csv"
    assert main([*base, "--top-view", "nadir", "--out", str(refused)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"xvmatch: error: {paths['hor1']}: the "
                                                   "horizontal image size is unknown: pass "
                                                   "--image-size WxH")
    assert not refused.exists()


@pytest.mark.slow
def test_a_phones_size_is_read_where_its_boxes_are_cut(tmp_path, capsys) -> None:
    """Passers-by cut by a 3640x2048 phone's bottom edge (and by the drone's): boxes alone,
    each view's size is read at the edges where its boxes end (no common size: 3840x2160
    before), said in its note, and the run pairs as with both sizes given."""
    from xvmatch.cli import main

    paths, base = _phone_clip(tmp_path, (3, 3), 3)
    guess, given = tmp_path / "guess.csv", tmp_path / "given.csv"
    assert main([*base, "--out", str(guess)]) == 0
    err = capsys.readouterr().err
    assert "took 1920x1080, where its boxes are cut by the image's borders" in err
    assert (f"note: {paths['hor1']}: its images taken as 3640x2048 on this path, where its "
            "boxes are cut by the image's borders (give --image-size WxH if not)") in err
    assert main([*base, "--top-image-size", "1920x1080", "--image-size", "3640x2048",
                 "--quiet", "--out", str(given)]) == 0
    assert guess.read_text() == given.read_text()


@pytest.mark.parametrize("true_scale", [0.7, 1.0, 1.3])
def test_registration_keeps_the_scale_that_brings_the_maps_together(true_scale) -> None:
    """People on a top map whose metres are ``1 / true_scale`` of the horizontal map's: the
    registration keeps the scale that undoes it, and 1 where it is 1."""
    from xvmatch.cues.ground_registration import register_with_scale

    rng = np.random.default_rng(3)
    order, tops, hors = [], [], []
    for f in range(1, 31, 3):
        people = np.column_stack([rng.uniform(2, 14, 8), rng.uniform(-6, 6, 8)])
        seen = np.abs(np.degrees(np.arctan2(people[:, 1], people[:, 0]))) < 30
        order.append(f)
        tops.append(people / true_scale)
        hors.append(people[seen])
    scale, poses = register_with_scale(order, tops, hors, 70.0, 10.0)
    assert scale == true_scale
    assert len(poses) == len(order)


def test_distinct_pose_hypotheses_are_the_plain_greedy_choice() -> None:
    """The block-wise choice of distinct hypotheses keeps exactly what a plain greedy pass (each
    candidate 1 m or 10 degrees from every one kept before it) keeps, ties and wraps included."""
    from xvmatch.cues.ground_registration import KEEP, _distinct, _wrap

    rng = np.random.default_rng(7)
    for trial in range(40):
        n = int(rng.integers(1, 900))
        poses = np.column_stack([np.round(rng.uniform(-4, 4, (n, 2)), 1),
                                 rng.choice(np.radians(np.arange(0, 360, 5)), n)])
        order = rng.permutation(n)
        plain: list[int] = []
        for k in order:
            if all(np.hypot(*(poses[k, :2] - poses[q, :2])) > 1.0
                   or abs(_wrap(poses[k, 2] - poses[q, 2])) > np.radians(10.0) for q in plain):
                plain.append(int(k))
                if len(plain) == KEEP:
                    break
        assert _distinct(poses, order, block=int(rng.integers(1, 300))) == plain, trial


def test_auto_offset_is_refused_with_an_oblique_top_view(scene, tmp_path, capsys) -> None:
    """``--offset auto`` estimates with the nadir search: with an oblique top view it would be a
    silent guess, so the run refuses it in one line; a given offset runs, and draws."""
    from xvmatch.cli import main
    from xvmatch.datasets.oblique_scenes import write_oblique_scene

    paths = write_oblique_scene(scene, tmp_path, "s")
    base = ["associate", "--top", str(paths["top"]), "--hor", str(paths["hor1"]),
            "--image-size", "x".join(map(str, scene.hor_cameras["hor1"][0].image_size)),
            "--top-image-size", "1920x1080", "--out", str(tmp_path / "p.csv")]
    assert main([*base, "--offset", "auto"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "--offset auto" in lines[0] and "oblique" in lines[0]
    # A given offset runs; --draw draws the ground-map path's pairs too.
    assert main([*base, "--offset", "0", "--quiet", "--draw", str(tmp_path / "d"),
                 "--draw-every", "25", "--hor-hfov", "70"]) == 0  # one lens: no choice
    assert len(list((tmp_path / "d").glob("*.jpg"))) >= 3


def test_the_top_cameras_sight_is_where_its_people_stand(scene) -> None:
    """The top camera's sight on its map (the calibration's camera above the map's origin):
    a person is in sight exactly where their foot pixel lies inside the image off its
    borders and nearer than the farthest of the clip (the reach); that one stands on the
    reach itself, in or out of sight by the last bit of a square root, and is not judged."""
    from xvmatch.inference.matching.ground_association import top_sights

    top, _, frames, options, _ = _prepared(scene)
    calib = top_calibration(top, options.top_size)
    _, _, boxes = stack_frames(top)
    ground = top_ground_points(boxes, calib)
    sight = top_sights(frames, ground, calib)
    assert len(sight) == len(frames) and all(s is sight[0] for s in sight)
    x, y, w, h = boxes.T
    u, v = x + w / 2, y + h
    width, height = options.top_size
    inside = ((u > 0.03 * width) & (u < 0.97 * width) & (v > 0.03 * height)
              & (v < 0.97 * height) & np.isfinite(ground).all(axis=1))
    seen = sight[0].sees(np.nan_to_num(ground, nan=1e9))
    far = np.hypot(*ground.T) >= sight[0].reach
    assert inside.sum() > 100 and far.sum() == 1
    assert np.array_equal(seen[~far], inside[~far])


EVERYTHING = ObliqueSceneConfig(top_pitch=(20.0, 45.0), overlap=(0.35, 0.65),
                                top_height=(4.0, 12.0), hor_hfov=(60.0, 110.0),
                                holder_speed=(1.0, 1.5), pan_rate=0.3,
                                top_drift_speed=(0.3, 1.0), top_yaw_rate=(0.0, 3.0),
                                edge_people=(1, 3))
"""The hidden set's kind: a low drone drifting and turning, a walking, panning holder, about half
of each view's people in the other, people at the top image's edges."""


@pytest.mark.slow
@pytest.mark.parametrize(("seed", "hfov", "sighted"), [(25, 60.0, False), (10, 70.0, True)])
def test_video_mode_keeps_the_run_with_or_without_the_sights_that_keeps_more(
        seed: int, hfov: float, sighted: bool) -> None:
    """A run made with the top camera's sights, or without them where that keeps more pairs
    along the tracks (``fewer_sights``): seed 25 at 60 degrees keeps 88 pair-frames without
    them, 85 with them (CVIDF1 98.6), seed 10 at 70 95 with them, 82 without; the lens chosen
    runs as given, and the lens choice weighs each lens by that run."""
    clip = make_oblique_scene(EVERYTHING, 60, np.random.default_rng(seed))
    top, hor, _, options, backs = _prepared(clip)
    frames = list(range(1, 61, 3))
    options = replace(options, hor_hfov_deg=hfov)
    calib = top_calibration(top, options.top_size)
    run = run_ground_association(top, hor, options, frames, calib)
    assert run.tilt is None  # a steady gimbal: the calibration's map is the run's
    top_frames, tracks, boxes = stack_frames(top)
    plain = run_ground_association(top, hor, options, frames, calib, top_points=top_ground_points(
        boxes, calib, top_sizes(top_frames, boxes, tracks, calib)))  # no sights given
    kept, without = (sum(map(len, r.pairs.values())) for r in (run, plain))
    assert _cvidf1(clip, run, frames, backs) > 90.0  # a percentage
    if sighted:
        assert kept > without and run.pairs != plain.pairs
    else:
        assert run.pairs == plain.pairs
        auto = run_ground_association(top, hor, replace(options, hor_hfov_deg="auto"), frames,
                                      calib)
        assert auto.lens.made[hfov] == kept  # compared as it runs: without the sights
        given = run_ground_association(top, hor, replace(options, hor_hfov_deg=auto.lens.hfov_deg),
                                       frames, calib)
        assert (auto.pairs, auto.scale) == (given.pairs, given.scale)


@pytest.mark.slow
@pytest.mark.parametrize(("seed", "lens", "near_tie", "whole_kept"), [
    (1, 70.0, None, False), (15, 70.0, None, False), (15, 70.0, 0.99, True)])
def test_video_mode_keeps_the_run_on_whole_boxes_where_it_keeps_clearly_more(
        monkeypatch, seed: int, lens: float, near_tie: float | None, whole_kept: bool) -> None:
    """The run registered on the handheld boxes no border cuts (people passing close by, cut
    by the bottom edge, paired under its poses all the same) replaces the run on every box
    where it keeps more than a near tie of its pairs along the tracks: seed 1 keeps 27
    pair-frames so against 104, seed 15 161 against 161, other pairs (kept where the near tie
    is under 1)."""
    clip = make_oblique_scene(EVERYTHING, 60, np.random.default_rng(seed))
    top, hor, _, options, backs = _prepared(clip)
    frames = list(range(1, 61, 3))
    options = replace(options, hor_hfov_deg=lens, consensus=True)
    calib = top_calibration(top, options.top_size)
    made: dict = {}
    on_whole, on_all = ground_association._whole_boxes_run, ground_association.register_and_pair

    def whole(*args, **kwargs):  # the real runs, kept to compare
        made["whole"] = ran = on_whole(*args, **kwargs)
        return ran

    def every(*args, **kwargs):
        made["every"] = ran = on_all(*args, **kwargs)
        return ran

    monkeypatch.setattr(ground_association, "_whole_boxes_run", whole)
    monkeypatch.setattr(ground_association, "register_and_pair", every)
    if near_tie is not None:
        monkeypatch.setattr(ground_association, "NEAR_TIE", near_tie)
    run = run_ground_association(top, hor, options, frames, calib)
    kept = {name: sum(map(len, ran[2].values())) for name, ran in made.items()}
    assert kept == ({"whole": 27, "every": 104} if seed == 1 else {"whole": 161, "every": 161})
    assert run.pairs == made["whole" if whole_kept else "every"][2]
    assert made["whole"][2] != made["every"][2]
    assert _cvidf1(clip, run, frames, backs) > 90.0  # a percentage


def test_far_people_are_excused_by_their_distance_only_under_an_oblique_top_view(
        close_drone) -> None:
    """The registration's tolerance for a far top person left unexplained (a part of their
    distance, :func:`~xvmatch.cues.ground_registration.pose_hypotheses`' ``spread``) is the
    spread of a distance read from a box under an oblique top view, none (the round radius)
    under a nadir one, where it cost the real CVMHAT boxes a person's track."""
    from xvmatch.cues import ground_registration as gr

    assert ground_association.miss_spread(close_drone) == gr.RANGE_SPREAD
    nadir = replace(close_drone, kind="nadir", tilt_deg=90.0)
    assert ground_association.miss_spread(nadir) == 0.0


@pytest.mark.slow
def test_the_holders_id_places_the_handheld_camera(scene) -> None:
    """``--camera-id`` on the ground path: the holder is nobody's partner; in video mode the
    run seeking the camera near where the top view sees them (each pose within a radius of
    their ground point, on the map's scale) is kept where its pairs hold along the tracks
    more than a near tie more than the run seeking it anywhere, and the note says which; frame
    by frame it is sought anywhere; an id the top view never maps changes nothing."""
    clip = make_oblique_scene(EVERYTHING, 60, np.random.default_rng(5))
    top, hor, frames, options, backs = _prepared(clip)
    calib = top_calibration(top, options.top_size)
    holder = next(a for a, b in backs[0].items() if b == int(clip.groups["holders"][0]))
    plain = run_ground_association(top, hor, options, frames, calib)
    told = run_ground_association(top, hor, replace(options, camera_id=holder), frames, calib)
    assert not any(t == holder for p in told.pairs.values() for t, _ in p)
    assert f"--camera-id {holder}: left out of the pairs" in told.summary
    # Measured: CVIDF1 59.7 -> 92.3, 72 pair-frames kept near the holder against 63 anywhere.
    assert "its pairs hold along the tracks more than anywhere's" in told.summary
    assert _cvidf1(clip, told, frames, backs) > _cvidf1(clip, plain, frames, backs) + 20.0
    top_frames, top_ids, boxes = stack_frames(top)
    ground = top_ground_points(boxes, calib, top_sizes(top_frames, boxes, top_ids, calib))
    at = {int(f): g for f, i, g in zip(top_frames, top_ids, ground, strict=True) if i == holder}
    placed = [p for p in told.poses if p.frame in at]
    assert len(placed) > len(told.poses) // 2
    assert all(np.hypot(*(p.centre - told.scale * at[p.frame])) <= gr.HOLDER_RADIUS + 1e-9
               for p in placed)
    # On the module's scene the run anywhere keeps as many (222 pair-frames, 100.0 both ways).
    top, hor, frames, options, backs = _prepared(scene)
    calib = top_calibration(top, options.top_size)
    holder = next(a for a, b in backs[0].items() if b == int(scene.groups["holders"][0]))
    told = run_ground_association(top, hor, replace(options, camera_id=holder), frames, calib)
    assert "kept fewer pairs along the tracks than sought anywhere" in told.summary
    assert _cvidf1(scene, told, frames, backs) > 95.0
    frame = run_ground_association(top, hor, replace(options, camera_id=holder, consensus=False),
                                   frames, calib)
    assert "frame by frame the handheld camera is sought anywhere" in frame.summary
    assert not any(t == holder for p in frame.pairs.values() for t, _ in p)
    plain = run_ground_association(top, hor, options, frames, calib)
    nobody = run_ground_association(top, hor, replace(options, camera_id=10**6), frames, calib)
    assert "not on the top view's ground map on any frame paired" in nobody.summary
    assert nobody.pairs == plain.pairs


def test_the_note_leaves_out_a_spread_not_measured() -> None:
    """A top view calibrated from one stretch of frames has no spread (NaN): the note says its
    tilt alone, neither "+- nan" nor a "+- 0" that reads as exact."""
    from xvmatch.geometry.people_calibration import PeopleCalibration

    calib = PeopleCalibration(
        kind="oblique", width=1920, height=1080, focal=1000.0, tilt_deg=31.2, roll_deg=0.0,
        camera_height=9.6, horizon=(-100.0, -100.0), focal_from="prior",
        tilt_std_deg=float("nan"), horizon_std_px=float("nan"), focal_rel_std=float("nan"),
        n_boxes=60, n_frames=9)
    note = ground_association.oblique_note(calib)
    assert note == "top view: oblique, tilt 31 degrees, about 10 m up (from its people)"
    measured = replace(calib, tilt_std_deg=0.42)
    assert "tilt 31 +- 0.4 degrees" in ground_association.oblique_note(measured)


def _standing_crowd() -> tuple:
    """A crowd standing 94 % of the time seen by a still drone and a still handheld camera
    (its lens 80 degrees), every 3rd frame of the 10 fps render numbered 1, 2, 3: the scene,
    the two views (ids scrambled), ``{scene frame: number}``, video mode's options and the ways
    back to the scene's ids."""
    config = ObliqueSceneConfig(top_pitch=(20.0, 45.0), overlap=(0.35, 0.65),
                                top_height=(4.0, 12.0), stop_probability=0.5,
                                stop_duration=30.0, hor_hfov=(60.0, 110.0))
    clip = make_oblique_scene(config, 120, np.random.default_rng([1, 7]))
    top, hor, frames, options, backs = _prepared(clip)
    number = {f: k for k, f in enumerate(frames, 1)}
    top, hor = ({number[f]: FrameBoxes(number[f], v[f].ids, v[f].boxes) for f in frames if f in v}
                for v in (top, hor))
    return clip, top, hor, number, replace(options, consensus=True), backs


@pytest.mark.slow
@pytest.mark.parametrize("fps", ["auto", 30.0])
def test_a_standing_crowd_whose_frame_rate_no_walker_tells_lets_the_camera_move_freely(
        fps: str | float) -> None:
    """A crowd that stands tells no frame rate, and the prior (30 a second) is taken; on a
    file of every 3rd frame of a 10 fps clip numbered 1, 2, 3 (3.3 a second) the registration
    would then allow a tenth of the camera's true walk and turn, the poses' own wobble would
    cost more than any clip score, and a steady wrong run won (the right one, among the
    hypotheses in 39 of 40 frames, explained 156 against 135). A rate no walker told gets
    ``UNREAD_RATE_SLACK``; the same 30 given is trusted, and loses the clip."""
    clip, top, hor, number, options, backs = _standing_crowd()
    frames = list(number)
    options = replace(options, hor_hfov_deg=70.0, fps=fps)
    run = run_ground_association(top, hor, options, list(number.values()),
                                 top_calibration(top, options.top_size))
    scene_run = replace(run, pairs={f: run.pairs.get(k, []) for f, k in number.items()})
    score = _cvidf1(clip, scene_run, frames, backs)
    if fps == "auto":
        assert run.frame_rate is not None and run.frame_rate.fps == 30.0
        assert not run.frame_rate.estimated and run.frame_rate.walkers == 0
        assert run.frame_rate.slack == UNREAD_RATE_SLACK > READ_RATE_SLACK
        assert score > 95.0  # a percentage
    else:
        assert run.frame_rate is None and score < 5.0


@pytest.mark.slow
def test_where_no_walker_tells_the_rate_the_lens_is_chosen_at_the_priors_own_pace(
        registration_paces) -> None:
    """Let move as at a tenth of the prior, every lens's run keeps as many pairs along a
    standing crowd's tracks and wider lenses won; so the lens is chosen at the prior's own
    free walk and turn (``FrameRate.lens_slack``), and the chosen lens's run then made let
    move: the same run as that lens given."""
    _, top, hor, number, options, _ = _standing_crowd()
    options = replace(options, hor_hfov_deg="auto", fps="auto")
    calib = top_calibration(top, options.top_size)
    run = run_ground_association(top, hor, options, list(number.values()), calib)
    assert run.frame_rate is not None and run.frame_rate.walkers == 0
    assert run.frame_rate.lens_slack == 1.0 and run.frame_rate.slack == UNREAD_RATE_SLACK
    slacks = [slack for _, slack in registration_paces]
    assert set(slacks) == {1.0, UNREAD_RATE_SLACK}
    first = slacks.index(UNREAD_RATE_SLACK)  # the choice, then the chosen lens's run
    assert first > 0 and set(slacks[first:]) == {UNREAD_RATE_SLACK}
    given = run_ground_association(top, hor, replace(options, hor_hfov_deg=run.lens.hfov_deg),
                                   list(number.values()), calib)
    assert given.scale == run.scale and given.pairs == run.pairs


@pytest.mark.slow
@pytest.mark.parametrize("floor", [None, float("-inf")])
def test_a_lingering_crowds_pairs_along_the_tracks_weigh_no_scale_that_explains_less(
        monkeypatch, floor: float | None) -> None:
    """People who stand still keep their pairs along the tracks under a wrong pose too: on a
    crowd standing 94 % of the time (the handheld size guessed 5 % large, as ``associate``
    guessed it) the run at map scale 0.7 kept 280 pair-frames, all wrong, where scale 1's kept
    238, all right, and explained twice the people. Video mode weighs a scale's pairs only
    where its clip score total reaches ``SCALE_FLOOR`` of scale 1's; without that floor, the
    wrong scale."""
    config = ObliqueSceneConfig(top_pitch=(20.0, 45.0), overlap=(0.35, 0.65),
                                top_height=(4.0, 12.0), stop_probability=0.5,
                                stop_duration=30.0)
    clip = make_oblique_scene(config, 120, np.random.default_rng([0, 2]))
    top, hor, frames, options, backs = _prepared(clip)
    options = replace(options, hor_size=(3840, 2160), hor_hfov_deg=70.0, fps="auto",
                      consensus=True)
    if floor is not None:
        monkeypatch.setattr(gr, "SCALE_FLOOR", floor)
    run = run_ground_association(top, hor, options, frames,
                                 top_calibration(top, options.top_size))
    assert run.frame_rate is not None and not run.frame_rate.estimated  # few walk: the prior
    if floor is None:
        assert run.scale == 1.0 and _cvidf1(clip, run, frames, backs) > 95.0  # a percentage
    else:
        assert run.scale == 0.7 and _cvidf1(clip, run, frames, backs) < 5.0
