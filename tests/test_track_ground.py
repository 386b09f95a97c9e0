"""``track``'s frame association on an oblique top view: ``associate``'s ground-map path frame
by frame on the detection rows (:mod:`xvmatch.inference.tracks.track_ground`)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.datasets.oblique_scenes import ObliqueSceneConfig, make_oblique_scene
from xvmatch.datasets.tracking_video import render_tracking_video
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.inference.tracks.track_ground import (
    GroundChoice,
    ground_frame_pairs,
    oblique_track_top,
    with_wearer,
)

CHOICE = GroundChoice(hor_hfov=70.0, fps=10.0)  # one lens: the choice is tests/test_hor_hfov_auto


def _as_rows(view: dict[int, FrameBoxes], first: int) -> tuple[dict[int, FrameBoxes], dict]:
    """A view with its boxes numbered as rows from ``first`` (``track``'s ids), and each row's
    person."""
    out, person, n = {}, {}, first
    for f, record in sorted(view.items()):
        rows = np.arange(n, n + len(record.ids), dtype=np.int64)
        n += len(rows)
        out[f] = FrameBoxes(f, rows, record.boxes)
        person.update(zip(rows.tolist(), record.ids.tolist(), strict=True))
    return out, person


@pytest.fixture(scope="module")
def oblique():
    """A 40-frame oblique drone render (25-45 degrees down) at 10 frames a second, as rows."""
    scene = make_oblique_scene(ObliqueSceneConfig(top_pitch=(25.0, 45.0), overlap=(0.7, 1.0)),
                               40, np.random.default_rng(0))
    top, top_person = _as_rows(scene.top, 0)
    hor, hor_person = _as_rows(scene.hor["hor1"], 10 ** 6)
    hor_size = (tuple(scene.hor_cameras["hor1"][0].image_size), "--image-size")
    return top, hor, top_person, hor_person, hor_size


def _scores(pairs, top, hor, top_person, hor_person) -> tuple[float, float]:
    """Pair precision and recall against the people both views show each frame."""
    made = [(a, b) for frame_pairs in pairs.values() for a, b in frame_pairs]
    right = sum(top_person[a] == hor_person[b] for a, b in made)
    shared = sum(len({top_person[r] for r in top[f].ids.tolist()}
                     & {hor_person[r] for r in hor[f].ids.tolist()}) for f in hor if f in top)
    return right / max(len(made), 1), right / shared


def test_an_oblique_top_view_pairs_rows_on_the_ground_maps(oblique) -> None:
    # Measured: 151 of 151 pairs right, 310 person-frames shared (associate's video mode on the
    # true track ids pairs 310 of 310; the rows' own pairs carry no track).
    top, hor, top_person, hor_person, hor_size = oblique
    told: list[tuple[str, bool]] = []
    pairs = ground_frame_pairs(top, hor, hor_size, CHOICE,
                               note=lambda line, always: told.append((line, always)))
    assert pairs is not None and set(pairs) <= set(hor)
    for f, frame_pairs in pairs.items():  # each row once a frame, in its own view
        tops, hors = zip(*frame_pairs, strict=True) if frame_pairs else ((), ())
        assert len(set(tops)) == len(tops) and set(tops) <= set(top[f].ids.tolist())
        assert len(set(hors)) == len(hors) and set(hors) <= set(hor[f].ids.tolist())
    precision, recall = _scores(pairs, top, hor, top_person, hor_person)
    assert precision > 0.95 and recall > 0.8, (precision, recall)
    said = " ".join(line for line, _ in told)
    assert "top view: oblique, tilt" in said and "the tracker joining them over time" in said
    assert "--mode video" not in said and oblique_track_top(top, hor, CHOICE)


def test_a_nadir_top_view_is_left_to_the_search(oblique) -> None:
    top, hor, _, _, hor_size = oblique
    assert ground_frame_pairs(top, hor, hor_size, GroundChoice(top_view="nadir")) is None
    assert not oblique_track_top(top, hor, GroundChoice(top_view="nadir"))
    # A rendered nadir drone's squat boxes: none, also with its images' size (a size given
    # makes associate calibrate, and such boxes can fit a tilted camera).
    video = render_tracking_video(2, 20)
    drone, ego = video.top, video.hor
    size = video.top_images[1].shape[1::-1]  # (W, H)
    assert not oblique_track_top(drone, ego, GroundChoice(), size)
    assert ground_frame_pairs(drone, ego, ((640, 360), "--image-size"), GroundChoice(),
                              size) is None


def test_the_holder_named_is_never_paired(oblique) -> None:
    top, hor, top_person, hor_person, hor_size = oblique
    holder = [r for r, p in top_person.items() if p == 0]  # person 0 holds hor1
    assert holder, "the holder is in the top view"
    pairs = ground_frame_pairs(top, hor, hor_size, CHOICE, wearer_rows=holder)
    assert pairs is not None
    assert not {a for frame_pairs in pairs.values() for a, _ in frame_pairs} & set(holder)
    assert _scores(pairs, top, hor, top_person, hor_person)[0] > 0.95


@settings(max_examples=40, deadline=None)
@given(st.lists(st.integers(0, 5), min_size=0, max_size=6), st.data())
def test_the_holders_rows_take_one_id_past_every_row(sizes, data) -> None:
    top, n = {}, 0
    for f, k in enumerate(sizes, start=1):
        top[f] = FrameBoxes(f, np.arange(n, n + k, dtype=np.int64), np.zeros((k, 4)))
        n += k
    rows = data.draw(st.lists(st.integers(0, max(n - 1, 0)), max_size=4, unique=True))
    rows = [r for r in rows if r < n]
    marked, wearer = with_wearer(top, rows)
    if not rows:
        assert marked is top and wearer is None
        return
    assert wearer == n
    for f, record in top.items():
        expected = np.where(np.isin(record.ids, rows), n, record.ids)
        assert np.array_equal(marked[f].ids, expected)
        assert np.array_equal(marked[f].boxes, record.boxes)


def test_track_guesses_the_handheld_size_on_the_ground_maps_only(tmp_path, capsys) -> None:
    """Boxes alone that fit no CVMHAT size: on the ground-map path ``track`` guesses the handheld
    view's size from its boxes and says so, as ``associate`` does; the search refuses, one
    line naming ``--image-size``."""
    from xvmatch.cli import main
    from xvmatch.formats.mot_boxes import write_mot_boxes

    scene = make_oblique_scene(ObliqueSceneConfig(top_pitch=(25.0, 45.0), overlap=(0.7, 1.0),
                                                  hor_sizes=((1920, 1080),)),
                               30, np.random.default_rng(3))
    write_mot_boxes(tmp_path / "top.txt", scene.top)
    write_mot_boxes(tmp_path / "hor.txt", scene.hor["hor1"])
    base = ["track", "--top", str(tmp_path / "top.txt"), "--hor", str(tmp_path / "hor.txt"),
            "--offset", "0", "--hor-hfov", "70", "--fps", "10"]
    capsys.readouterr()
    assert main([*base, "--out", str(tmp_path / "ground")]) == 0
    err = capsys.readouterr().err
    assert "hor.txt: its images taken as" in err and "top view: oblique, tilt" in err, err
    assert (tmp_path / "ground" / "hor.txt").read_text()
    assert main([*base, "--top-view", "nadir", "--out", str(tmp_path / "nadir")]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "--image-size WxH" in lines[0], lines
