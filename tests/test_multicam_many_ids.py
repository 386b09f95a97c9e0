"""``multicam``'s note when the global ids are many more than the people any camera sees at
once (issue 69, item 6: "550 global ids" for 16 people was printed without comment)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from xvmatch.datasets.multicam_scenes import MulticamConfig, simulate_multicam_scene
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.geometry.ground_plane import GroundCamera
from xvmatch.inference.views.multicam_run import MulticamRunOptions, many_ids_note, run_multicam


@pytest.fixture(scope="module")
def scene():
    sc = simulate_multicam_scene(MulticamConfig(n_cameras=2, n_people=(4, 4)), 40, seed=3)
    return sc, {n: GroundCamera.from_camera(c) for n, c in sc.cameras.items()}


def _notes(cams, boxes) -> list[str]:
    said: list[str] = []
    run_multicam(cams, boxes, MulticamRunOptions(), note=said.append)
    return said


def test_clean_tracks_earn_no_note(scene):
    sc, cams = scene
    assert _notes(cams, sc.boxes) == []


def test_broken_tracks_earn_one_note_naming_the_counts(scene):
    sc, cams = scene
    fresh = itertools.count(1000)
    broken = {  # every box a track of its own: a tracker that never keeps an id
        name: {f: FrameBoxes(f, np.array([next(fresh) for _ in rec.ids], np.int64), rec.boxes)
               for f, rec in frames.items()}
        for name, frames in sc.boxes.items()}
    most = max(len(rec.ids) for frames in sc.boxes.values() for rec in frames.values())
    said = _notes(cams, broken)
    assert len(said) == 1
    assert f"while no camera sees more than {most} people at once" in said[0]
    assert "broken tracks" in said[0] and "\n" not in said[0]
    n_ids = int(said[0].split()[0])
    assert n_ids > 2 * most


def test_the_note_counts_short_ids():
    frames = np.arange(1, 4)
    ground = {g: (frames if g < 7 else np.arange(1, 40), np.zeros((0, 2))) for g in range(9)}
    boxes = {"a": {1: FrameBoxes(1, np.array([1, 2]), np.zeros((2, 4)) + 1)}}
    line = many_ids_note(ground, boxes)
    assert line.startswith("9 global ids (7 of them on fewer than 10 frames), while no camera "
                           "sees more than 2 people at once")
    assert many_ids_note({g: ground[g] for g in range(4)}, boxes) == ""
