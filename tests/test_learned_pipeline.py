"""The learned association pipeline as a function
(:mod:`xvmatch.inference.matching.learned_pipeline`): the same pairs as ``xvmatch associate
--model``, the gamma rule in one place, the checks before any work, and the image sources re-timed
and closed."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from xvmatch.cli import main
from xvmatch.datasets.synthetic_io import SceneInputs, SyntheticDataset, write_scene_inputs
from xvmatch.formats.mot_boxes import read_mot_boxes, read_predictions
from xvmatch.inference.matching.learned_association import (
    associate_sequence_learned,
    load_matcher_bundle,
    non_association_cost,
)
from xvmatch.inference.matching.learned_pipeline import (
    LearnedRunOptions,
    open_learned_inputs,
    open_view_images,
    run_learned_association,
)

SIZE = (320, 180)
"""The image size of the tiny synthetic scenes."""


@pytest.fixture(scope="module")
def scene(tmp_path_factory, tiny_synth) -> SceneInputs:
    """Boxes, per-frame cameras and image patterns of one overview scene (2 frames)."""
    record = SyntheticDataset(tiny_synth["overview"]).scene("s00001")
    return write_scene_inputs(record, tmp_path_factory.mktemp("scene"))


@pytest.fixture(scope="module")
def default():
    return load_matcher_bundle("default")


def _boxes(scene: SceneInputs):
    top, hor = read_mot_boxes(scene.top), read_mot_boxes(scene.hor)
    return top, hor, sorted(set(top) | set(hor))


def _cli_pairs(tmp_path: Path, scene: SceneInputs, *extra: str) -> tuple[dict, dict]:
    """Pairs and ``--costs`` record of ``xvmatch associate --model default``."""
    out, costs = tmp_path / "pred.csv", tmp_path / "costs.json"
    argv = ["associate", "--top", str(scene.top), "--hor", str(scene.hor), "--out", str(out),
            "--quiet", "--model", "default", "--costs", str(costs), *extra]
    assert main(argv) == 0
    return read_predictions(out), json.loads(costs.read_text())


def _same_pairs(run_pairs: dict, cli_pairs: dict) -> None:
    assert {f: sorted(p) for f, p in run_pairs.items() if p} == \
        {f: sorted(p) for f, p in cli_pairs.items() if p}


def test_boxes_only_gives_the_pairs_of_the_command_line(tmp_path, scene, default):
    top, hor, frames = _boxes(scene)
    options = LearnedRunOptions((default,), SIZE, "--image-size", keep_costs=True)
    run = run_learned_association(top, hor, frames, options)
    pairs, record = _cli_pairs(tmp_path, scene, "--image-size", "320x180")
    _same_pairs(run.pairs, pairs)
    assert run.pairs == associate_sequence_learned(top, hor, SIZE[0], default,
                                                   hor_height=SIZE[1], frames=frames)
    assert run.hor_size == SIZE and run.hor_size_source == "--image-size"
    assert sorted(run.costs) == sorted(int(f) for f in record["frames"])
    for f, c in run.costs.items():
        np.testing.assert_allclose(c, record["frames"][str(f)]["cost"], atol=1e-6)


def test_images_and_cameras_give_the_pairs_of_the_command_line(tmp_path, scene, default):
    top, hor, frames = _boxes(scene)
    options = LearnedRunOptions((default,), SIZE, "the horizontal images",
                                top_images=scene.top_images, hor_images=scene.hor_images,
                                cameras=str(scene.cameras), keep_costs=True)
    run = run_learned_association(top, hor, frames, options)
    pairs, record = _cli_pairs(tmp_path, scene, "--top-images", scene.top_images,
                               "--hor-images", scene.hor_images, "--cameras", str(scene.cameras))
    _same_pairs(run.pairs, pairs)
    for f, c in run.costs.items():
        np.testing.assert_allclose(c, record["frames"][str(f)]["cost"], atol=1e-6)
    # the cues change the costs: the images and cameras reached the matcher
    boxes_only = run_learned_association(top, hor, frames,
                                         LearnedRunOptions((default,), SIZE, keep_costs=True))
    assert any(not np.allclose(c, boxes_only.costs[f]) for f, c in run.costs.items())


def test_gamma_given_else_the_models_own(scene, default):
    top, hor, frames = _boxes(scene)
    assert non_association_cost([default]) == default.gamma == 0.5
    assert non_association_cost([default], 0.9) == 0.9
    own = run_learned_association(top, hor, frames, LearnedRunOptions((default,), SIZE))
    assert own.gamma == default.gamma and own.costs is None
    given = run_learned_association(top, hor, frames,
                                    LearnedRunOptions((default,), SIZE, gamma=0.01))
    assert given.gamma == 0.01
    assert sum(map(len, given.pairs.values())) <= sum(map(len, own.pairs.values()))
    assert given.pairs == associate_sequence_learned(top, hor, SIZE[0], default, gamma=0.01,
                                                     hor_height=SIZE[1], frames=frames)


def test_a_box_only_bundle_refuses_images(scene, tiny_models):
    top, hor, frames = _boxes(scene)
    boxes_only = load_matcher_bundle(tiny_models["boxes_bundle"])
    options = LearnedRunOptions((boxes_only,), SIZE, names=("mine",),
                                top_images=scene.top_images, hor_images=scene.hor_images)
    with pytest.raises(ValueError, match=r"^mine: a box-only matcher cannot use images; drop "
                       r"--top-images/--hor-images"):
        run_learned_association(top, hor, frames, options)
    with pytest.raises(ValueError, match="this matcher takes no camera cues"):
        run_learned_association(top, hor, frames, LearnedRunOptions(
            (boxes_only,), SIZE, cameras=str(scene.cameras)))


def test_bad_options_are_refused(scene, default):
    with pytest.raises(ValueError, match="no model given"):
        LearnedRunOptions((), SIZE)
    with pytest.raises(ValueError, match="together"):
        LearnedRunOptions((default,), SIZE, top_images=scene.top_images)
    with pytest.raises(ValueError, match="one name per model"):
        LearnedRunOptions((default,), SIZE, names=("a", "b"))


def test_a_camera_size_other_than_the_given_size_is_refused(scene, default):
    top, hor, frames = _boxes(scene)
    options = LearnedRunOptions((default,), (640, 360), "--image-size", cameras=str(scene.cameras))
    with pytest.raises(ValueError, match=r"camera 'ego' is 320x180 but the horizontal image size "
                       r"is 640x360 \(from --image-size\)"):
        run_learned_association(top, hor, frames, options)


def test_images_are_retimed_and_closed(scene, default):
    top, hor, frames = _boxes(scene)
    plain = open_view_images(scene.top_images, top, frames)
    shifted = open_view_images(scene.top_images, {f - 1: top[f] for f in top},
                               [f - 1 for f in frames], shift=1)
    try:
        assert tuple(shifted.size) == tuple(plain.size) == SIZE
        np.testing.assert_array_equal(shifted.get(frames[0] - 1), plain.get(frames[0]))
    finally:
        plain.close()
        shifted.close()
    options = LearnedRunOptions((default,), SIZE, top_images=scene.top_images,
                                hor_images=scene.hor_images)
    with open_learned_inputs(top, hor, frames, options) as inputs:
        assert sorted(inputs.images) == ["hor", "top"]
    assert inputs.images == {}
    with pytest.raises(Exception, match="frame"):
        open_view_images(scene.top_images, top, [max(frames) + 50])


@pytest.mark.slow
def test_int8_near_ties_are_scored_again_with_fp32(scene):
    """associate's INT8 path: a frame whose INT8 assignment is not stable within the tolerance
    gets exactly FP32's costs and pairs, a stable one keeps INT8's."""
    from xvmatch.inference.matching.bundle import int8_recheck_tolerance

    top, hor, frames = _boxes(scene)

    def run(matcher):
        return run_learned_association(top, hor, frames, LearnedRunOptions(
            (matcher,), SIZE, top_images=scene.top_images, hor_images=scene.hor_images,
            keep_costs=True))

    fp32 = run(load_matcher_bundle("default", precision="fp32"))
    int8 = run(load_matcher_bundle("default", precision="int8"))
    assert int8.rechecked == [] and fp32.rechecked == []
    assert any(not np.allclose(c, fp32.costs[f], atol=1e-6) for f, c in int8.costs.items())
    checked = load_matcher_bundle("default", precision="int8", recheck=True)
    spec = checked.bundle.manifest.appearance
    assert checked.bundle.recheck == int8_recheck_tolerance(spec.int8) > 0
    checked.bundle.recheck = 1.0  # every assignment moves within a tolerance of 1
    every = run(checked)
    assert every.rechecked == sorted(every.costs) and every.pairs == fp32.pairs
    for f, c in every.costs.items():
        np.testing.assert_allclose(c, fp32.costs[f], atol=1e-6)
    checked.bundle.recheck = 0.0  # none does within 0
    none = run(checked)
    assert none.rechecked == [] and none.pairs == int8.pairs
    for f, c in none.costs.items():
        np.testing.assert_array_equal(c, int8.costs[f])
