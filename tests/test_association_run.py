"""The association run (:mod:`xvmatch.inference.matching.association_run`): ``xvmatch associate``'s
pipeline in one call, its options in one typed record, its notes and pictures told to hooks."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from xvmatch.cues.auto_offset import AutoOffsetOptions
from xvmatch.cues.spatial_search import associate_sequence
from xvmatch.datasets.box_scene import simulate_box_scene
from xvmatch.formats.mot_boxes import FrameBoxes, shift_frames
from xvmatch.inference.linking.pair_consensus import consistent_pairs
from xvmatch.inference.matching.association_run import (
    AUTO_VIDEO,
    AssociationHooks,
    AssociationOptions,
    guessed_top_size,
    oblique_pairs,
    offset_to_apply,
    run_association,
)

SIZE = ((2688, 1512), "--image-size")


@pytest.fixture(scope="module")
def scene():
    return simulate_box_scene(n_frames=12, seed=3)


def _said() -> tuple[list[tuple[str, bool]], AssociationHooks, list]:
    notes: list[tuple[str, bool]] = []
    shown: list = []
    hooks = AssociationHooks(note=lambda line, always: notes.append((line, always)),
                             size_assumed=lambda: notes.append(("size", False)),
                             pictures=shown.append)
    return notes, hooks, shown


def test_the_handcrafted_run_is_the_search_then_the_consensus(scene) -> None:
    options = AssociationOptions(hor_size=SIZE, top_view="nadir", video=True,
                                 video_by_auto=True)
    notes, hooks, shown = _said()
    run = run_association(scene.top, scene.hor, options, hooks)
    frames = sorted(set(scene.top) | set(scene.hor))
    found = associate_sequence(scene.top, scene.hor, hor_width=2688, frames=frames)
    assert run.pairs == consistent_pairs(found, scene.top, scene.hor, frames)
    assert run.frames == frames and run.offset == 0 and run.note == AUTO_VIDEO
    assert run.learned is None and notes == [("size", False)]  # said as the work starts
    assert len(shown) == 1 and shown[0].pairs == run.pairs and shown[0].images is None
    # Frame mode: the search's own pairs, no note with the summary; no hooks: said nowhere.
    alone = run_association(scene.top, scene.hor, AssociationOptions(hor_size=SIZE,
                                                                     top_view="nadir"))
    assert alone.pairs == found and alone.note is None


def test_a_given_offset_retimes_the_top_view(scene) -> None:
    late = {f + 5: FrameBoxes(f + 5, r.ids, r.boxes) for f, r in scene.hor.items()}
    options = AssociationOptions(hor_size=SIZE, top_view="nadir", offset=-5)
    run = run_association(scene.top, late, options)
    top = shift_frames(scene.top, -5)
    assert run.offset == -5 and sorted(run.top) == sorted(top)
    frames = sorted(set(top) | set(late))
    assert run.pairs == associate_sequence(top, late, hor_width=2688, frames=frames)


def test_views_sharing_no_frame_are_refused_naming_both(scene) -> None:
    with pytest.raises(ValueError, match=r"nothing to match.*t\.txt.*h\.txt"):
        offset_to_apply(scene.top, scene.hor, 1000, names=("t.txt", "h.txt"))
    assert offset_to_apply(scene.top, scene.hor, "3", names=("t.txt", "h.txt")) == 3


def test_auto_offset_is_said_after_its_search(scene) -> None:
    # Videos too short for two clips are not searched: 0, with a note (not a warning).
    notes: list = []
    opened: list = []

    def clips():
        from contextlib import nullcontext

        opened.append(True)
        return nullcontext(lambda done, total: None)

    auto = AutoOffsetOptions(hor_width=2688, max_offset=60)
    offset = offset_to_apply(scene.top, scene.hor, "auto", auto, clips=clips,
                             note=lambda line, always: notes.append((line, always)))
    assert offset == 0 and opened == [True]
    assert len(notes) == 1 and "too short" in notes[0][0] and notes[0][1] is False
    with pytest.raises(ValueError, match="max_offset"):
        AssociationOptions(hor_size=SIZE, offset="auto")


def test_the_top_size_is_guessed_only_for_upright_people(scene) -> None:
    notes: list = []
    assert guessed_top_size(scene.top, lambda line, always: notes.append(line)) is None
    upright = {1: FrameBoxes(1, np.array([1, 2]), np.array([[100.0, 100, 40, 120],
                                                             [500, 200, 30, 100]]))}
    assert guessed_top_size(upright, lambda line, always: notes.append(line)) == (640, 360)
    assert len(notes) == 1 and "took 640x360" in notes[0]


def test_search_modes_that_read_previous_frames_need_video() -> None:
    with pytest.raises(ValueError, match="needs video"):
        AssociationOptions(hor_size=SIZE, search="follow")
    AssociationOptions(hor_size=SIZE, search="exhaustive")


def test_a_guessed_top_view_too_few_to_calibrate_takes_the_nadir_path(scene) -> None:
    """Upright people too few to calibrate from: with a guessed size the nadir path, said in one
    line; with the size given, the calibration's error."""
    upright = {1: FrameBoxes(1, np.array([1, 2]), np.array([[100.0, 100, 40, 120],
                                                             [500, 200, 30, 100]]))}
    notes: list = []
    options = AssociationOptions(hor_size=SIZE)
    assert oblique_pairs(upright, upright, options, lambda line, always: notes.append(line)) is None
    assert "cannot be calibrated from its people" in notes[-1]
    with pytest.raises(ValueError, match="the calibration needs"):
        oblique_pairs(upright, upright, replace(options, top_image_size=(640, 360)))


@pytest.mark.slow
def test_the_top_size_takes_the_runs_boxes_past_the_borders() -> None:
    """Boxes that run on past the borders (a tracker's), shown by the handheld view only (its
    people leave by the left; the drone's by its near, lowest edge): the top view's size is
    the one its boxes start inside, as the run's files share their making, and its boxes past
    the bottom are no error; alone its boxes would tell a larger image."""
    from xvmatch.datasets.oblique_scenes import ObliqueSceneConfig, make_oblique_scene
    from xvmatch.formats.box_image_size import runs_past_borders

    config = ObliqueSceneConfig(top_pitch=(20.0, 45.0), top_height=(4.0, 12.0),
                                edge_people=(1, 3), box_extent="past_border")
    scene = make_oblique_scene(config, 60, np.random.default_rng(1))
    top, hor = scene.top, scene.hor["hor1"]
    assert not runs_past_borders(top) and runs_past_borders(hor)
    assert guessed_top_size(top) == (2560, 1440)
    hor_size = (tuple(scene.hor_cameras["hor1"][0].image_size), "--image-size")
    notes: list = []
    options = AssociationOptions(hor_size=hor_size, hor_hfov=70.0, fps=10.0)
    pairs = oblique_pairs(top, hor, options, lambda line, always: notes.append(line))
    assert pairs is not None and sum(map(len, pairs.values())) > 0
    assert any("took 1920x1080, the smallest common video size its boxes, run on past the "
               "borders, start inside" in line for line in notes), notes
    from xvmatch.inference.views.multi_ground import oblique_top  # associate-multi's too

    calib, note = oblique_top(top, "auto", None, "top.txt", hors=[hor])
    assert calib is not None and "its size taken as 1920x1080" in note


def test_the_assumed_size_is_said_only_on_the_path_that_reads_it() -> None:
    """Boxes alone that fit CVMHAT's size: the nadir path says it assumes that size, once, as
    its work starts; the ground-map path (an oblique drone) guesses the handheld's size from
    its boxes instead and says only that, not first an assumption it then drops."""
    from xvmatch.datasets.oblique_scenes import ObliqueSceneConfig, make_oblique_scene
    from xvmatch.formats.box_image_size import ASSUMED, CVMHAT_SIZE

    config = ObliqueSceneConfig(top_pitch=(25.0, 45.0), overlap=(0.7, 1.0))
    scene = make_oblique_scene(config, 40, np.random.default_rng(1))
    top, hor = scene.top, scene.hor["hor1"]
    options = AssociationOptions(hor_size=(CVMHAT_SIZE, ASSUMED), hor_hfov=70.0, fps=10.0,
                                 top_image_size=(1920, 1080))
    notes, hooks, _ = _said()
    run_association(top, hor, options, hooks)
    assert ("size", False) not in notes
    assert sum("its images taken as 1920x1080 on this path" in line and "not CVMHAT's" in line
               for line, _ in notes) == 1, notes
    notes, hooks, _ = _said()
    run_association(top, hor, replace(options, top_view="nadir"), hooks)
    assert notes.count(("size", False)) == 1
    assert not any("its images taken as" in line for line, _ in notes)
