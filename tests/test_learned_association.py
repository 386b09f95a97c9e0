"""Association with a deployed matcher bundle: invariance to ids and box order, the input
settings, ensembles, workers, the CLI helper and fit-geometry end to end."""

from __future__ import annotations

import argparse

import numpy as np
import pytest
import torch

from xvmatch.commands import _model as model_command
from xvmatch.commands.lab import fit_geometry
from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene, write_box_scene
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.inference.linking.assignment import assign
from xvmatch.inference.matching.learned_association import (
    associate_sequence_learned,
    load_matcher_bundle,
)
from xvmatch.models.matcher_file import load_matcher

WIDTH = 2688


@pytest.fixture(autouse=True)
def _one_torch_thread():
    """One intra-op thread: tiny tensors gain nothing from more, and on a busy 2-core machine
    more threads spin against each other (a 1 s training run took over a minute)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def scene():
    return simulate_box_scene(SceneConfig(n_people=(6, 9)), n_frames=8, seed=11)


@pytest.fixture(scope="module")
def model(tiny_models):
    return load_matcher_bundle(tiny_models["boxes_bundle"])


def _scramble(frames, rng, shuffle_boxes: bool):
    ids = sorted({int(i) for f in frames.values() for i in f.ids})
    mapping = dict(zip(ids, (rng.permutation(len(ids)) + 500).tolist(), strict=True))
    out = {}
    for k, f in frames.items():
        order = rng.permutation(len(f)) if shuffle_boxes else np.arange(len(f))
        out[k] = FrameBoxes(k, np.array([mapping[int(i)] for i in f.ids[order]], np.int64),
                            f.boxes[order])
    return out, {v: k for k, v in mapping.items()}


def test_bundle_keeps_the_model_files_settings(model, tiny_models):
    source = load_matcher(tiny_models["boxes"])
    assert model.gamma == source.gamma == 0.6
    assert model.feature_config == source.feature_config
    assert model.cues == () and model.bundle.appearance is None
    assert model.bundle.manifest.meta == {"k": 1}


def test_onnx_costs_equal_the_torch_model(model, tiny_models, scene):
    """The runtime's cost matrices are the torch matcher's (the export's parity, end to end)."""
    from xvmatch.cues.matcher_inputs import collate_inputs, matcher_inputs

    source = load_matcher(tiny_models["boxes"])
    frames = [f for f in sorted(scene.top) if len(scene.top[f]) and len(scene.hor[f])]
    inputs = [matcher_inputs(scene.top[f].boxes, scene.hor[f].boxes, (WIDTH, 1512),
                             model.feature_config, ()) for f in frames]
    batch = collate_inputs(inputs)
    with torch.inference_mode():
        ref = source.matcher(*(torch.from_numpy(batch[k]) for k in (
            "top", "hor", "hyp", "pair", "top_mask", "hor_mask", "hyp_mask"))).cost.numpy()
    got = model.costs(inputs)
    for k, c in enumerate(got):
        np.testing.assert_allclose(c, ref[k, : c.shape[0], : c.shape[1]], atol=1e-5)


def test_invariant_to_id_scrambling_and_box_order(model, scene):
    base = associate_sequence_learned(scene.top, scene.hor, WIDTH, model, gamma=1.0)
    assert sum(len(p) for p in base.values()) > 0
    rng = np.random.default_rng(4)
    top, inv_top = _scramble(scene.top, rng, shuffle_boxes=True)
    hor, inv_hor = _scramble(scene.hor, rng, shuffle_boxes=True)
    again = associate_sequence_learned(top, hor, WIDTH, model, gamma=1.0)
    mapped = {f: sorted((inv_top[a], inv_hor[b]) for a, b in p) for f, p in again.items()}
    assert mapped == {f: sorted(p) for f, p in base.items()}


def test_empty_frames_camera_id_and_gamma(model, scene):
    top = dict(scene.top)
    hor = dict(scene.hor)
    hor[2] = FrameBoxes(2, np.zeros(0, np.int64), np.zeros((0, 4)))
    del top[3]
    seen = []
    pred = associate_sequence_learned(top, hor, WIDTH, model, camera_id=0,
                                      progress=lambda it: (seen.append(f) or f for f in it))
    assert pred[2] == [] and pred[3] == []
    assert seen == sorted(set(top) | set(hor))
    nothing = associate_sequence_learned(top, hor, WIDTH, model, gamma=1e-9)
    assert all(p == [] for p in nothing.values())
    with pytest.raises(ValueError, match="hor_width"):
        associate_sequence_learned(top, hor, 0, model)


def test_mirror_augmentation_is_symmetric(model, scene):
    """With ``mirror=True`` a scene and its mirror image give the same pairs (the average of
    the two cost matrices is the same either way)."""
    mirrored_top = {k: FrameBoxes(k, f.ids, np.column_stack([5000 - f.boxes[:, 0] - f.boxes[:, 2],
                                                            f.boxes[:, 1:]]))
                    for k, f in scene.top.items()}
    mirrored_hor = {k: FrameBoxes(k, f.ids, np.column_stack([WIDTH - f.boxes[:, 0] - f.boxes[:, 2],
                                                            f.boxes[:, 1:]]))
                    for k, f in scene.hor.items()}
    a = associate_sequence_learned(scene.top, scene.hor, WIDTH, model, gamma=1.0, mirror=True)
    b = associate_sequence_learned(mirrored_top, mirrored_hor, WIDTH, model, gamma=1.0,
                                   mirror=True)
    assert {f: sorted(p) for f, p in a.items()} == {f: sorted(p) for f, p in b.items()}
    assert sum(len(p) for p in a.values()) > 0


def test_ensemble_averages_the_models_costs(model, tiny_models, scene):
    """Several bundles: the mean of their cost matrices, each with its own feature config."""
    full = load_matcher_bundle(tiny_models["full_bundle"])
    one_costs, two_costs, both_costs = {}, {}, {}
    associate_sequence_learned(scene.top, scene.hor, WIDTH, model, costs_out=one_costs)
    associate_sequence_learned(scene.top, scene.hor, WIDTH, full, costs_out=two_costs)
    pred = associate_sequence_learned(scene.top, scene.hor, WIDTH, [model, full], gamma=1.0,
                                      costs_out=both_costs)
    assert sorted(both_costs) == sorted(one_costs)
    n_pairs = 0
    for f, c in both_costs.items():
        np.testing.assert_allclose(c, (one_costs[f] + two_costs[f]) / 2, atol=1e-12)
        t, h = scene.top[f].ids, scene.hor[f].ids
        assert pred[f] == [(int(t[a]), int(h[b])) for a, b in assign(c, 1.0)]
        n_pairs += len(pred[f])
    assert n_pairs > 0
    assert associate_sequence_learned(scene.top, scene.hor, WIDTH, [model, model]) == (
        associate_sequence_learned(scene.top, scene.hor, WIDTH, model))
    with pytest.raises(ValueError, match="no model"):
        associate_sequence_learned(scene.top, scene.hor, WIDTH, [])


@pytest.mark.slow
def test_workers_give_the_same_pairs_and_costs(model):
    # 70 frames with gaps and an empty frame: more than one 32-frame chunk goes to the two
    # spawned processes, and the pairs and cost matrices must come back in frame order.
    sc = simulate_box_scene(SceneConfig(n_people=(5, 7)), n_frames=70, seed=5)
    top = {f: r for f, r in sc.top.items() if f % 9}
    hor = dict(sc.hor)
    hor[20] = FrameBoxes(20, np.zeros(0, np.int64), np.zeros((0, 4)))
    runs = []
    for workers in (1, 2):
        costs: dict = {}
        pred = associate_sequence_learned(top, hor, WIDTH, model, camera_id=0, gamma=1.0,
                                          mirror=True, costs_out=costs, workers=workers)
        runs.append((pred, costs))
    (one, one_costs), (two, two_costs) = runs
    assert one == two and sum(len(p) for p in one.values()) > 0
    assert sorted(one_costs) == sorted(two_costs)
    for f, c in one_costs.items():
        np.testing.assert_array_equal(c, two_costs[f])
    with pytest.raises(ValueError, match="workers"):
        associate_sequence_learned(top, hor, WIDTH, model, workers=0)


@pytest.mark.slow
def test_association_run_with_learned_matchers(model, tiny_models, scene, tmp_path,
                                               monkeypatch):
    from xvmatch.inference.matching.association_run import (
        AssociationHooks,
        AssociationOptions,
        LearnedChoice,
        run_association,
    )

    def pairs(names, mirror=False):
        options = AssociationOptions(hor_size=((WIDTH, 1512), "--image-size"), top_view="nadir",
                                     learned=LearnedChoice(tuple(names), mirror=mirror))
        run = run_association(scene.top, scene.hor, options,
                              AssociationHooks(export=model_command.export_torch_file))
        return {f: p for f, p in run.pairs.items() if f in scene.top}

    bundle = str(tiny_models["boxes_bundle"])
    pred = pairs([bundle])
    assert pred == associate_sequence_learned(scene.top, scene.hor, WIDTH, model)
    assert pairs([bundle], mirror=True) == associate_sequence_learned(
        scene.top, scene.hor, WIDTH, model, mirror=True)
    # A torch matcher file is exported once into the cache and gives the same pairs.
    monkeypatch.setenv("XVMATCH_CACHE", str(tmp_path / "cache"))
    assert pairs([str(tiny_models["boxes"])]) == pred
    assert len(list((tmp_path / "cache" / "bundles").iterdir())) == 1
    with pytest.raises(ValueError, match="no such bundle folder"):
        pairs(["nope"])


def test_fit_geometry_parser(tmp_path):
    parser = argparse.ArgumentParser(prog="xvmatch")
    sub = parser.add_subparsers(dest="command")
    fit_geometry.add_fit_geometry_parser(sub)
    args = parser.parse_args(["fit-geometry", "--cvmhat", "d", "--out", "m.pt", "--sites", "a",
                              "b", "--epochs", "3", "--noise", "0"])
    assert args.sites == ["a", "b"] and args.epochs == 3 and args.noise == 0
    assert args.func is not None
    with pytest.raises(SystemExit):
        parser.parse_args(["fit-geometry", "--cvmhat", "d", "--out", "m.pt", "--epochs", "0"])
    with pytest.raises(ValueError, match="no such folder"):
        args.func(parser.parse_args(["fit-geometry", "--cvmhat", str(tmp_path / "x"),
                                     "--out", "m.pt"]))
    sub2 = argparse.ArgumentParser()
    model_command.add_model_arguments(sub2)
    assert sub2.parse_args(["--model", "default", "--gamma", "0.4"]).gamma == 0.4


@pytest.mark.slow
def test_fit_geometry_command_end_to_end(tmp_path):
    """``fit-geometry`` on a tiny CVMHAT-layout folder (two sites, a few frames) writes a
    box-only matcher file."""
    data = tmp_path / "data"
    data.mkdir()
    for k, name in enumerate(["V0-S_alpha_0-G_1", "V1-S_beta-G_1"]):
        scene = simulate_box_scene(SceneConfig(n_people=(5, 6)), n_frames=6, seed=20 + k)
        write_box_scene(scene, data, name)
    out = tmp_path / "geo.pt"
    parser = argparse.ArgumentParser(prog="xvmatch")
    fit_geometry.add_fit_geometry_parser(parser.add_subparsers())
    args = parser.parse_args(
        ["fit-geometry", "--cvmhat", str(data), "--out", str(out), "--epochs", "1",
         "--noise", "0", "--sim-scenes", "2", "--sites", "alpha", "--cache",
         str(tmp_path / "c"), "--quiet", "--width", "16", "--layers", "1",
         "--image-size", "2688x1512"]  # the simulator's size: its few boxes reach x 1066 only
    )
    assert args.func(args) == 0
    model = load_matcher(out)
    assert model.meta["sites"] == ["alpha"] and model.matcher.cues == ()
    stored = torch.load(out, map_location="cpu", weights_only=True)["geometry_config"]
    assert stored["width"] == 16 and stored["layers"] == 1
    with pytest.raises(ValueError, match="--width must be a multiple of 4"):
        args.func(parser.parse_args(["fit-geometry", "--cvmhat", str(data), "--out",
                                     str(tmp_path / "w.pt"), "--width", "10"]))
