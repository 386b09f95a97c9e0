"""The track run as a library call (:mod:`xvmatch.inference.tracks.track_run`): the same tracks as
``xvmatch track``, its options refused where they do not fit, its lines told as they come."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from xvmatch.cli import main
from xvmatch.datasets.oblique_scenes import ObliqueSceneConfig, make_oblique_scene
from xvmatch.datasets.synthetic_scenes import SynthConfig
from xvmatch.datasets.tracking_video import render_tracking_video, write_tracking_video
from xvmatch.formats.detection_rows import read_detection_rows, write_track_rows
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.inference.matching.learned_association import load_matcher_bundle
from xvmatch.inference.matching.search_camera import upright_top_warning
from xvmatch.inference.tracks.track_costs import LEARNED_DUMMY_WEIGHT, TrackWeights
from xvmatch.inference.tracks.track_ground import GroundChoice
from xvmatch.inference.tracks.track_run import (
    TrackRunOptions,
    cross_view_weights,
    open_track_images,
    run_tracking,
    track_weights,
)
from xvmatch.inference.tracks.tracking import TrackConfig


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> dict[str, Path]:
    """A 16-frame rendered drone clip (6 to 8 people): boxes, images and cameras."""
    video = render_tracking_video(5, 16, SynthConfig(n_people=(6, 8), fps=25.0))
    return write_tracking_video(video, tmp_path_factory.mktemp("clip"))


def _library_tracks(clip: dict[str, Path], out: Path, options: TrackRunOptions,
                    opened: bool) -> tuple[bytes, bytes]:
    """The run's tracks written as the command writes them (``opened``: the images opened by
    the caller first, else by the run)."""
    top, hor = read_detection_rows(clip["top"]), read_detection_rows(clip["hor"])
    size = ((640, 360), f"the horizontal images {clip['hor_images']}")
    if opened:
        with open_track_images(top.frames, hor.frames, options) as images:
            assert images.hor_size == (640, 360)
            run = run_tracking(top.frames, hor.frames, options, size, images=images)
    else:
        run = run_tracking(top.frames, hor.frames, options, size)
    out.mkdir()
    write_track_rows(out / "top.txt", top, run.result.top_rows)
    write_track_rows(out / "hor.txt", hor, run.result.hor_rows)
    assert run.warning() is None and run.cameras is None and run.camera_checked is None
    return (out / "top.txt").read_bytes(), (out / "hor.txt").read_bytes()


def test_the_run_gives_the_command_s_tracks(clip, tmp_path) -> None:
    assert main(["track", "--top", str(clip["top"]), "--hor", str(clip["hor"]),
                 "--top-images", str(clip["top_images"]), "--hor-images",
                 str(clip["hor_images"]), "--offset", "0", "--solver", "spectral",
                 "--out", str(tmp_path / "cli"), "--quiet"]) == 0
    command = ((tmp_path / "cli" / "top.txt").read_bytes(),
               (tmp_path / "cli" / "hor.txt").read_bytes())
    options = TrackRunOptions(config=TrackConfig(solver="spectral"),
                              top_images=str(clip["top_images"]),
                              hor_images=str(clip["hor_images"]), top_boxes=str(clip["top"]))
    assert _library_tracks(clip, tmp_path / "opened", options, opened=True) == command
    assert _library_tracks(clip, tmp_path / "by_run", options, opened=False) == command
    assert command[0].count(b"\n") > 50  # tracks written, not an empty answer


@pytest.mark.parametrize(("given", "message"), [
    ({"weights": "learned"}, "--weights learned takes the learned matcher's costs"),
    ({"weights": "other"}, "weights must be one of learned, handcrafted, got 'other'"),
    ({"cameras": "cams"}, "--cameras feeds the learned matcher's cross-view weights: add --model"),
    ({"top_images": "top/"}, "give --top-images and --hor-images together"),
])
def test_options_that_do_not_fit_are_refused(given, message) -> None:
    with pytest.raises(ValueError, match=message):
        TrackRunOptions(**given)


def test_the_weights_and_their_defaults() -> None:
    assert cross_view_weights(None, "default", None, images=False) == "learned"
    assert cross_view_weights(None, None, None, images=True) == "handcrafted"
    with pytest.raises(ValueError, match="needs the images"):
        cross_view_weights("handcrafted", "default", None, images=False)
    with pytest.raises(ValueError, match="drop --weights handcrafted"):
        cross_view_weights("handcrafted", "default", "cams", images=True)
    assert track_weights("learned").c0 == LEARNED_DUMMY_WEIGHT != TrackWeights().c0
    assert track_weights("learned", c0=0.3).c0 == 0.3
    assert track_weights("handcrafted", w2=0.5) == TrackWeights(w2=0.5)


@pytest.mark.slow
def test_the_cameras_lines_are_told_as_they_come(clip) -> None:
    model = load_matcher_bundle("default")
    top, hor = read_detection_rows(clip["top"]), read_detection_rows(clip["hor"])
    options = TrackRunOptions(weights="learned", model=model, model_name="default",
                              cameras=str(clip["cameras"]), top_boxes=str(clip["top"]))
    told: list[tuple[str, bool]] = []
    run = run_tracking(top.frames, hor.frames, options, ((640, 360), "--image-size"),
                       note=lambda line, always: told.append((line, always)))
    assert run.refinement is not None and run.cameras is not None
    assert told[0] == (run.refinement.message, run.refinement.turned)
    assert run.result.top_rows and run.result.hor_rows


def test_an_upright_top_view_takes_the_ground_maps_or_is_warned_of(clip) -> None:
    """track's cross-view search takes the top camera to look straight down: a top view whose
    people stand upright (an oblique drone) takes the ground-map path instead, saying what it
    assumed; forced onto the search (``--top-view nadir``) it is warned of, always, with what
    to give instead; the rendered nadir drone's is not (issue 67: nothing silently assumed)."""
    scene = make_oblique_scene(ObliqueSceneConfig(top_pitch=(25.0, 45.0)), 12,
                               np.random.default_rng(1))
    top, hor = ({f: FrameBoxes(f, 100 * f + np.arange(len(r.ids)), r.boxes)
                 for f, r in v.items()} for v in (scene.top, scene.hor["hor1"]))
    nadir = read_detection_rows(clip["top"]).frames
    assert upright_top_warning(nadir, "s", "w", "i") is None
    assert upright_top_warning({}, "s", "w", "i") is None
    hor_size = (scene.hor_cameras["hor1"][0].image_size, "--image-size")
    for choice in (GroundChoice(), GroundChoice(top_view="nadir")):
        told: list[tuple[str, bool]] = []
        run_tracking(top, hor, TrackRunOptions(ground=choice), hor_size,
                     note=lambda line, always, told=told: told.append((line, always)))
        said = [(line, always) for line, always in told if "stand upright" in line]
        assert len(said) == 1, told
        if choice.top_view == "auto":
            assert said[0] == (said[0][0], False) and "an oblique camera; took" in said[0][0]
            assert any("top view: oblique, tilt" in line for line, _ in told), told
            continue
        assert said[0][1] and not any("top view: oblique" in line for line, _ in told), told
        assert said[0][0].startswith("xvmatch: warning: the top view's people stand upright (")
        assert "--cameras" in said[0][0] and "--top-view oblique" in said[0][0]
        assert "\n" not in said[0][0]
