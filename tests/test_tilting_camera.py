"""A top camera whose tilt changes over the clip (a gimbal), fitted from its people with a tilt
per window (issue 67): read as tilting where it tilts, as static where it does not, and each
frame of a tilting clip mapped through its own tilt."""

from __future__ import annotations

import numpy as np
import pytest

from xvmatch.datasets.oblique_scenes import ObliqueSceneConfig, make_oblique_scene
from xvmatch.formats.mot_boxes import FrameBoxes, stack_frames
from xvmatch.geometry import tilting_camera
from xvmatch.geometry.people_model import usable_boxes
from xvmatch.geometry.tilting_camera import (
    MIN_TILT_CHANGE_DEG,
    START_BOXES,
    STEADY_DEG,
    TiltTrack,
    fit_tilt_track,
)
from xvmatch.inference.matching.ground_association import (
    GroundAssociationOptions,
    run_ground_association,
    top_calibration,
    top_ground_points,
)

FPS = 10.0 / 3.0  # every 3rd frame of the renders' 10 a second, numbered 1, 2, 3


def _clip(rate: tuple[float, float], seed: int) -> tuple[object, dict, dict, list[int]]:
    """A close drone's clip (every 3rd frame, renumbered) tilting at ``rate`` degrees/s."""
    config = ObliqueSceneConfig(top_pitch=(20.0, 45.0), top_height=(4.0, 12.0),
                                overlap=(0.35, 0.65), top_pitch_rate=rate)
    scene = make_oblique_scene(config, 120, np.random.default_rng([1, seed]))
    frames = [f for f in sorted(set(scene.top) & set(scene.hor["hor1"])) if (f - 1) % 3 == 0]
    top, hor = ({k: FrameBoxes(k, v[f].ids, v[f].boxes) for k, f in enumerate(frames, 1)}
                for v in (scene.top, scene.hor["hor1"]))
    return scene, top, hor, frames


def _true_tilt(scene, frame: int) -> float:
    return float(np.degrees(np.arcsin(-scene.top_cameras[frame - 1].R[2, 2])))


@pytest.fixture(scope="module")
def tilting():
    return _clip((1.0, 2.0), 0)


def test_a_tilting_gimbal_reads_as_tilting_and_a_static_one_does_not(tilting) -> None:
    scene, top, _, frames = tilting
    size = scene.top_cameras[0].image_size
    track = fit_tilt_track(*stack_frames(top), size, FPS)
    assert isinstance(track, TiltTrack) and track.tilting
    first, last = _true_tilt(scene, frames[0]), _true_tilt(scene, frames[-1])
    est = np.diff(track.tilts_deg)
    # Measured: windows 25.0, 29.0, 32.8, 36.8 degrees where the truth went 19.7 -> 37.6.
    assert np.all(np.sign(est) == np.sign(last - first)), track.tilts_deg
    assert 0.4 * abs(last - first) < track.change_deg < 1.5 * abs(last - first)
    assert track.tilt_at([0, 10_000]).tolist() == [track.tilts_deg[0], track.tilts_deg[-1]]
    assert fit_tilt_track(*stack_frames(top), size, FPS) == track  # same input, same track

    static, top_s, _, _ = _clip((0.0, 0.0), 0)
    still = fit_tilt_track(*stack_frames(top_s), static.top_cameras[0].image_size, FPS)
    assert still is not None and not still.tilting
    assert still.change_deg < 0.2 * MIN_TILT_CHANGE_DEG


def test_a_steady_camera_is_told_from_the_one_fit(tilting) -> None:
    """Given the clip's one fit, a static camera's windows are fitted with its lens, roll and
    height held (kept exactly) and returned as steady; a tilting one still gets the whole fit,
    the same as without the one fit."""
    static, top_s, _, _ = _clip((0.0, 0.0), 0)
    size = static.top_cameras[0].image_size
    calib = top_calibration(top_s, size)
    held = fit_tilt_track(*stack_frames(top_s), size, FPS, calib)
    assert held is not None and not held.tilting and held.change_deg <= STEADY_DEG
    np.testing.assert_allclose([held.focal, held.roll_deg, held.camera_height],
                               [calib.focal, calib.roll_deg, calib.camera_height], rtol=1e-12)
    scene, top, _, _ = tilting
    size = scene.top_cameras[0].image_size
    whole = fit_tilt_track(*stack_frames(top), size, FPS)
    assert fit_tilt_track(*stack_frames(top), size, FPS, top_calibration(top, size)) == whole


def test_too_short_a_clip_has_no_track(tilting) -> None:
    scene, top, _, _ = tilting
    short = {f: r for f, r in top.items() if f <= 9}  # 9 frames at 3.3 a second: one window
    assert fit_tilt_track(*stack_frames(short), scene.top_cameras[0].image_size, FPS) is None
    assert fit_tilt_track(*stack_frames({1: top[1]}), scene.top_cameras[0].image_size,
                          FPS) is None  # too few boxes


@pytest.mark.slow
def test_a_long_clip_tries_its_starts_on_a_few_boxes(monkeypatch) -> None:
    """A clip of more than START_BOXES usable boxes (36 s, 650) has its starts tried on that
    many, and the best and the clip's one fit refined on all: the track of every start on
    every box, to 0.01 degree (benchmarks/tilt_fit_speed.py: a 96 s clip's 47 s in 4)."""
    config = ObliqueSceneConfig(top_pitch=(20.0, 45.0), top_height=(4.0, 12.0),
                                overlap=(0.35, 0.65), top_pitch_rate=(0.3, 0.6),
                                n_people=(9, 12))
    scene = make_oblique_scene(config, 360, np.random.default_rng([2, 1]))
    frames = [f for f in sorted(scene.top) if (f - 1) % 3 == 0]
    top = {k: FrameBoxes(k, scene.top[f].ids, scene.top[f].boxes)
           for k, f in enumerate(frames, 1)}
    stacked, size = stack_frames(top), scene.top_cameras[0].image_size
    assert len(usable_boxes(*stacked, size).h) > START_BOXES
    one = top_calibration(top, size)
    few = fit_tilt_track(*stacked, size, FPS, one)
    monkeypatch.setattr(tilting_camera, "START_BOXES", 10**9)
    every = fit_tilt_track(*stacked, size, FPS, one)
    assert few is not None and every is not None and few.tilting and every.tilting
    assert len(few.tilts_deg) == len(every.tilts_deg) == 12
    np.testing.assert_allclose(few.tilts_deg, every.tilts_deg, atol=0.015)
    first, last = _true_tilt(scene, frames[0]), _true_tilt(scene, frames[-1])
    assert np.all(np.sign(np.diff(few.tilts_deg)) == np.sign(last - first))


@pytest.mark.slow
def test_associate_multi_says_a_tilting_top_camera_in_one_line(tilting, monkeypatch) -> None:
    """associate-multi reads the tilt before it says what the top view is: a tilting camera's
    one line gives its first and last tilts, its one fit's spread neither said nor measured
    (it is not its tilt's)."""
    from xvmatch.inference.views import multi_ground
    from xvmatch.inference.views.multi_view_people import PeopleOptions

    scene, top, hor, _ = tilting
    size, hor_size = scene.top_cameras[0].image_size, scene.hor_cameras["hor1"][0].image_size
    calib, note = multi_ground.oblique_top(top, "oblique", size, "top.txt")
    assert note is None and np.isnan(calib.tilt_std_deg)  # the spread left for later
    measured: list = []
    monkeypatch.setattr(multi_ground, "measure_spread", measured.append)
    said: list[str] = []
    shifted = {f: FrameBoxes(f, np.asarray(r.ids) + 1000, r.boxes) for f, r in hor.items()}
    multi_ground.run_multi_ground([top, shifted], [0], calib, multi_ground.MultiGroundOptions(
        (hor_size,), 70.0, FPS), PeopleOptions(), None, said.append)
    tops = [line for line in said if line.startswith("top view")]
    assert len(tops) == 1 and tops[0].startswith("top view: oblique, tilting from "), said
    assert "+-" not in tops[0] and tops[0].endswith(multi_ground.REGISTERED) and not measured


@pytest.mark.slow
def test_the_run_maps_each_frame_of_a_tilting_clip_through_its_own_tilt(tilting) -> None:
    scene, top, hor, _ = tilting
    size = scene.top_cameras[0].image_size
    options = GroundAssociationOptions(size, scene.hor_cameras["hor1"][0].image_size, fps=FPS)
    calib = top_calibration(top, size, spread="later")  # as associate asks it
    shifted = {f: FrameBoxes(f, np.asarray(r.ids) + 1000, r.boxes) for f, r in hor.items()}
    run = run_ground_association(top, shifted, options, calibration=calib)
    assert run.tilt is not None and run.tilt.tilting
    assert np.isnan(run.calibration.tilt_std_deg)  # the one tilt's spread: not told, not measured
    first, last = run.tilt.tilts_deg[0], run.tilt.tilts_deg[-1]
    assert f"tilting from {first:.0f} to {last:.0f} degrees" in run.summary
    assert 18 < first < 30 and 32 < last < 42  # the truth went 19.7 -> 37.6
    tf, _, boxes = stack_frames(top)
    mapped = top_ground_points(boxes, calib, None, tf, run.tilt)
    calibs = run.tilt.calibrations(calib, tf)
    k = int(np.flatnonzero(tf == tf[-1])[0])
    assert np.allclose(mapped[k], calibs[int(tf[-1])].standing_points(boxes[k:k + 1])[0],
                       equal_nan=True)
    assert not np.allclose(mapped[k], calib.standing_points(boxes[k:k + 1])[0])
    # The handheld view's ids moved by 1000: no id is shared across the views.
    pairs = [(a, b) for p in run.pairs.values() for a, b in p]
    right = sum(a == b - 1000 for a, b in pairs)
    # Measured 1.000 pair F1 (the clip's one fit: 0.000).
    assert pairs and right / len(pairs) > 0.9


@pytest.mark.slow
def test_calibrate_refuses_a_camera_whose_tilt_changes(tmp_path, capsys) -> None:
    """A tilting clip the one fit would pin down wrongly (48 degrees where the truth went from
    about 20 to 40) is refused in one line, nothing written; its static twin is written."""
    from xvmatch.cli import main
    from xvmatch.formats.mot_boxes import write_mot_boxes

    for rate, code in (((1.0, 2.0), 2), ((0.0, 0.0), 0)):
        scene, top, _, _ = _clip(rate, 1)
        boxes, out = tmp_path / f"top{rate[0]:g}.txt", tmp_path / f"cam{rate[0]:g}.json"
        write_mot_boxes(boxes, top)
        size = "x".join(map(str, scene.top_cameras[0].image_size))
        assert main(["calibrate", "--boxes", str(boxes), "--image-size", size, "--hfov", "70",
                     "--out", str(out)]) == code
        err = capsys.readouterr().err.strip().splitlines()
        if code:
            assert len(err) == 1 and "the camera's tilt changes over the clip" in err[0], err
            assert not out.exists()
        else:
            assert out.exists()
    with pytest.raises(SystemExit) as stop:  # the rate is checked as associate's
        main(["calibrate", "--boxes", str(boxes), "--image-size", size, "--fps", "0",
              "--out", str(out)])
    assert stop.value.code == 2
    assert "argument --fps: expected a number in [0.1, 1000]" in capsys.readouterr().err
