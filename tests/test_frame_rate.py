"""The frame rate of a box file's frame numbers read from its people's walking (issue 67):
:func:`~xvmatch.inference.matching.frame_rate.frame_rate_from_walkers`, and ``--fps auto`` on a
rendered oblique scene whose sampled frames are numbered 1, 2, 3."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.inference.matching.frame_rate import (
    BRISK_WALK_MPS,
    MIN_WALKERS,
    READ_RATE_SLACK,
    UNREAD_RATE_SLACK,
    frame_rate_from_walkers,
    frame_rate_note,
)


def _walkers(rate: float, seconds: float = 12.0, walking: int = 6, standing: int = 0,
             step: int = 1, seed: int = 0, jitter: float = 0.03
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """People walking straight at 1.0-1.5 m/s (and some standing), a box every ``step``-th
    frame number of a file numbered ``rate`` a second, foot points jittered by ``jitter`` m."""
    rng = np.random.default_rng(seed)
    numbers = np.arange(1, int(seconds * rate) + 1, step)
    frames, ids, points = [], [], []
    for person in range(walking + standing):
        speed = rng.uniform(1.0, 1.5) if person < walking else 0.0
        heading = rng.uniform(0, 2 * np.pi)
        start = rng.uniform(-20, 20, 2)
        t = (numbers - 1) / rate
        path = start + np.outer(t * speed, [np.cos(heading), np.sin(heading)])
        frames.append(numbers)
        ids.append(np.full(len(numbers), 100 + 7 * person))
        points.append(path + rng.normal(0, jitter, path.shape))
    return np.concatenate(frames), np.concatenate(ids), np.concatenate(points)


def test_a_file_numbered_three_a_second_is_read_as_such() -> None:
    rate = frame_rate_from_walkers(*_walkers(3.0, standing=3))
    assert rate.estimated and rate.walkers == 9
    assert 2.0 <= rate.fps <= 4.0
    assert rate.slack == rate.lens_slack == READ_RATE_SLACK > 1.0  # a rate read: looser
    assert not rate.unread
    # Read at 30 a second they would walk ten times too fast; the note says both.
    assert rate.prior_pace > 8 * BRISK_WALK_MPS
    note = frame_rate_note(rate)
    assert note.startswith(f"frame numbers read as {rate.fps:g} a second from the top view's "
                           "walkers") and "give --fps if known" in note


def test_a_video_numbered_at_its_own_rate_keeps_the_prior() -> None:
    # Every 10th frame of a 30 fps video, numbered 1, 11, 21: within a factor 2 of the prior.
    rate = frame_rate_from_walkers(*_walkers(30.0, step=10))
    assert not rate.estimated and rate.fps == 30.0 and rate.walkers == 6
    assert rate.slack == 1.0
    assert 1.0 <= rate.prior_pace <= 1.6
    assert "walkers then walk" in frame_rate_note(rate)
    # Every frame of it too: the pace is measured over a second, not over the jitter of one
    # frame.
    every = frame_rate_from_walkers(*_walkers(30.0, seconds=6.0, jitter=0.05))
    assert every.fps == 30.0 and every.walkers == 6
    # A prior far off is replaced: below it by the walkers' rate (above), above it by at most
    # twice the prior (a strolling crowd reads too high a rate).
    above = frame_rate_from_walkers(*_walkers(30.0, step=10), prior=3.0)
    assert above.estimated and above.fps == 2 * 3.0


def test_people_who_do_not_walk_tell_nothing() -> None:
    standing = frame_rate_from_walkers(*_walkers(3.0, walking=0, standing=8))
    assert not standing.estimated and standing.fps == 30.0 and standing.walkers == 0
    # Nothing says the file is not numbered 1, 2, 3: the camera walks and turns as freely as
    # at a tenth of the prior, where a rate read gets twice and one confirmed or given none.
    assert standing.slack == UNREAD_RATE_SLACK == 10.0 > READ_RATE_SLACK
    assert standing.lens_slack == 1.0  # the lens chosen as before: let move, lenses tie
    assert "too few people walk" in frame_rate_note(standing)
    assert standing.unread and "the camera let move as at 3 a second" in frame_rate_note(standing)
    few = frame_rate_from_walkers(*_walkers(3.0, walking=MIN_WALKERS - 1))
    assert not few.estimated and few.walkers == 0 and few.slack == UNREAD_RATE_SLACK
    # No boxes, one box, no foot on the ground: the prior.
    assert frame_rate_from_walkers(np.zeros(0), np.zeros(0), np.zeros((0, 2))).fps == 30.0
    assert frame_rate_from_walkers([1], [1], [[0.0, 0.0]], prior=25.0).fps == 25.0
    frames, ids, points = _walkers(3.0)
    assert not frame_rate_from_walkers(frames, ids, np.full_like(points, np.nan)).estimated


@settings(max_examples=25, deadline=None)
@given(rate=st.sampled_from([1.0, 2.0, 3.0, 5.0, 10.0]), seed=st.integers(0, 2**16),
       shift=st.integers(0, 10_000), angle=st.floats(0, 2 * np.pi),
       offset=st.tuples(st.floats(-1e3, 1e3), st.floats(-1e3, 1e3)))
def test_estimate_is_near_the_rate_and_blind_to_where_the_map_and_clip_lie(
        rate, seed, shift, angle, offset) -> None:
    frames, ids, points = _walkers(rate, seed=seed)
    first = frame_rate_from_walkers(frames, ids, points)
    assert first.estimated and rate / 1.5 <= first.fps <= rate * 1.5
    turn = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    order = np.random.default_rng(seed).permutation(len(frames))
    moved = frame_rate_from_walkers(frames[order] + shift, ids[order] * 3 + 1,
                                    (points @ turn.T + offset)[order])
    assert moved.fps == pytest.approx(first.fps, rel=0.05)


@pytest.mark.slow
def test_fps_auto_reads_a_renumbered_render(tmp_path, capsys, registration_paces) -> None:
    """``--fps auto`` says the rate it read from the top view's walkers, and the registration
    runs at that rate with the looser walk a rate read gets (``READ_RATE_SLACK``); the same
    rate given runs at the free walk (a rate given is trusted)."""
    from xvmatch.cli import main
    from xvmatch.datasets.oblique_scenes import ObliqueSceneConfig, make_oblique_scene
    from xvmatch.formats.mot_boxes import FrameBoxes, write_mot_boxes

    # Walkers at a pedestrian's pace (the renders' default, 0.3-1.4 m/s with stops, is slower).
    config = ObliqueSceneConfig(top_pitch=(30.0, 40.0), overlap=(0.7, 1.0),
                                walk_speed=(1.0, 1.5), stop_probability=0.0)
    scene = make_oblique_scene(config, 150, np.random.default_rng(3))
    # Every 3rd frame of the 10 fps render, numbered 1, 2, 3: 3.3 frame numbers a second.
    for name, view in (("top", scene.top), ("hor", scene.hor["hor1"])):
        write_mot_boxes(tmp_path / f"{name}.txt", {
            k: FrameBoxes(k, view[f].ids, view[f].boxes)
            for k, f in enumerate(sorted(view)[::3], 1)})
    hor_size = "x".join(map(str, scene.hor_cameras["hor1"][0].image_size))
    base = ["associate", "--top", str(tmp_path / "top.txt"), "--hor", str(tmp_path / "hor.txt"),
            "--image-size", hor_size, "--top-image-size", "1920x1080", "--mode", "video"]
    paces = registration_paces
    assert main([*base, "--out", str(tmp_path / "auto.csv")]) == 0
    said = [line for line in capsys.readouterr().err.splitlines() if "frame numbers" in line]
    assert len(said) == 1 and "from the top view's walkers" in said[0]
    fps = float(said[0].split("read as ")[1].split()[0])
    assert 2.0 <= fps <= 8.0
    assert paces and set(paces) == {(fps, READ_RATE_SLACK)}
    paces.clear()
    assert main([*base, "--fps", f"{fps:g}", "--out", str(tmp_path / "given.csv"),
                 "--quiet"]) == 0
    assert "frame numbers" not in capsys.readouterr().err
    assert paces and set(paces) == {(fps, 1.0)}
