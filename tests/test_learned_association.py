"""Association with a learned geometry model: model files, invariance to ids and box order, CLI."""

from __future__ import annotations

import argparse

import numpy as np
import pytest
import torch

from xvmatch import cli_learn
from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene, write_box_scene
from xvmatch.datasets.geometry_features import FeatureConfig
from xvmatch.datasets.mot_boxes import FrameBoxes
from xvmatch.evaluation.cross_view_metrics import count_sequence, summarize
from xvmatch.geometry.spatial_search import associate_sequence
from xvmatch.inference.learned_association import (
    DEFAULT_MODEL_PATH,
    associate_sequence_learned,
    load_geometry_model,
    save_geometry_model,
)
from xvmatch.models.geometry_encoder import GeometryEncoder

FEATURES = FeatureConfig(n_hypotheses=3, dtheta_deg=4.0)
TINY = {"width": 16, "layers": 1, "heads": 2, "sinkhorn_iterations": 10}
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
def model_file(tmp_path_factory):
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("model") / "tiny.pt"
    save_geometry_model(path, GeometryEncoder(**TINY), FEATURES, gamma=0.6, meta={"k": 1})
    return path


def _scramble(frames, rng, shuffle_boxes: bool):
    ids = sorted({int(i) for f in frames.values() for i in f.ids})
    mapping = dict(zip(ids, (rng.permutation(len(ids)) + 500).tolist(), strict=True))
    out = {}
    for k, f in frames.items():
        order = rng.permutation(len(f)) if shuffle_boxes else np.arange(len(f))
        out[k] = FrameBoxes(k, np.array([mapping[int(i)] for i in f.ids[order]], np.int64),
                            f.boxes[order])
    return out, {v: k for k, v in mapping.items()}


def test_save_load_round_trip(model_file):
    model = load_geometry_model(model_file)
    assert model.gamma == 0.6 and model.meta == {"k": 1} and model.feature_config == FEATURES
    assert model.matcher.geometry.config["width"] == 16
    assert not model.matcher.training


def test_invariant_to_id_scrambling_and_box_order(model_file, scene):
    model = load_geometry_model(model_file)
    base = associate_sequence_learned(scene.top, scene.hor, WIDTH, model, gamma=1.0)
    assert sum(len(p) for p in base.values()) > 0
    rng = np.random.default_rng(4)
    top, inv_top = _scramble(scene.top, rng, shuffle_boxes=True)
    hor, inv_hor = _scramble(scene.hor, rng, shuffle_boxes=True)
    again = associate_sequence_learned(top, hor, WIDTH, model, gamma=1.0)
    mapped = {f: sorted((inv_top[a], inv_hor[b]) for a, b in p) for f, p in again.items()}
    assert mapped == {f: sorted(p) for f, p in base.items()}


def test_empty_frames_camera_id_and_gamma(model_file, scene):
    model = load_geometry_model(model_file)
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


def test_load_errors_name_the_file(tmp_path, model_file):
    with pytest.raises(ValueError, match="no such model file"):
        load_geometry_model(tmp_path / "missing.pt")
    text = tmp_path / "text.pt"
    text.write_text("not a model")
    with pytest.raises(ValueError, match=r"text\.pt: not a geometry model file"):
        load_geometry_model(text)
    other = tmp_path / "other.pt"
    torch.save({"weights": torch.zeros(2)}, other)
    with pytest.raises(ValueError, match="not a geometry model file"):
        load_geometry_model(other)
    record = torch.load(model_file, weights_only=True)
    for key, value, message in (
        ("feature_version", 999, "feature version 999"),
        ("format_version", 7, "format version 7"),
        ("model_config", {**TINY, "width": 32}, "does not fit its configuration"),
    ):
        broken = dict(record, **{key: value})
        path = tmp_path / f"{key}.pt"
        torch.save(broken, path)
        with pytest.raises(ValueError, match=message):
            load_geometry_model(path)
    with pytest.raises(ValueError, match="folder"):
        save_geometry_model(tmp_path / "no" / "m.pt", GeometryEncoder(**TINY), FEATURES)


def test_default_model_ships_and_works():
    """The shipped simulator-only model beats the handcrafted cost on fresh simulated scenes."""
    assert DEFAULT_MODEL_PATH.is_file(), "run training/make_default_geometry.py"
    assert DEFAULT_MODEL_PATH.stat().st_size < 2_000_000
    model = load_geometry_model("default")
    assert "simulator" in model.meta["trained_on"]
    frames = list(range(1, 41, 4))
    learned, handcrafted = [], []
    for seed in (0, 2):  # seeds the default model was not trained on (its scenes are seeded
        # by default_rng([0, k, 11])), drawn from the default SceneConfig
        scene = simulate_box_scene(SceneConfig(), n_frames=40, seed=seed)
        pred = associate_sequence_learned(scene.top, scene.hor, WIDTH, model, frames=frames)
        learned += count_sequence(pred, scene.top, scene.hor, frames=frames)
        hand = associate_sequence(scene.top, scene.hor, WIDTH, frames=frames)
        handcrafted += count_sequence(hand, scene.top, scene.hor, frames=frames)
    assert summarize(learned).cvidf1 > 85.0
    assert summarize(learned).cvidf1 >= summarize(handcrafted).cvidf1


def test_associate_with_model_cli_helper(model_file, scene):
    args = argparse.Namespace(model=str(model_file), image_size=(2688, 1512), camera_id=None,
                              mode="frame", gamma=None)
    frames = sorted(scene.top)
    pred = cli_learn.associate_with_model(args, scene.top, scene.hor, frames, None)
    direct = associate_sequence_learned(scene.top, scene.hor, WIDTH,
                                        load_geometry_model(model_file))
    assert pred == direct
    mirrored = cli_learn.associate_with_model(argparse.Namespace(**{**vars(args), "mirror": True}),
                                              scene.top, scene.hor, frames, None)
    assert mirrored == associate_sequence_learned(scene.top, scene.hor, WIDTH,
                                                  load_geometry_model(model_file), mirror=True)
    with pytest.raises(ValueError, match="--mode frame"):
        cli_learn.associate_with_model(argparse.Namespace(**{**vars(args), "mode": "video"}),
                                       scene.top, scene.hor, frames, None)
    with pytest.raises(ValueError, match="no such model file"):
        cli_learn.associate_with_model(argparse.Namespace(**{**vars(args), "model": "nope.pt"}),
                                       scene.top, scene.hor, frames, None)


def test_fit_geometry_parser(tmp_path):
    parser = argparse.ArgumentParser(prog="xvmatch")
    sub = parser.add_subparsers(dest="command")
    cli_learn.add_fit_geometry_parser(sub)
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
    cli_learn.add_model_arguments(sub2)
    assert sub2.parse_args(["--model", "default", "--gamma", "0.4"]).gamma == 0.4


def test_fit_geometry_command_end_to_end(tmp_path):
    """``fit-geometry`` on a tiny CVMHAT-layout folder (two sites, a few frames)."""
    data = tmp_path / "data"
    data.mkdir()
    for k, name in enumerate(["V0-S_alpha_0-G_1", "V1-S_beta-G_1"]):
        scene = simulate_box_scene(SceneConfig(n_people=(5, 6)), n_frames=6, seed=20 + k)
        write_box_scene(scene, data, name)
    out = tmp_path / "geo.pt"
    parser = argparse.ArgumentParser(prog="xvmatch")
    cli_learn.add_fit_geometry_parser(parser.add_subparsers())
    args = parser.parse_args(
        ["fit-geometry", "--cvmhat", str(data), "--out", str(out), "--epochs", "1",
         "--noise", "0", "--sim-scenes", "2", "--sites", "alpha", "--cache",
         str(tmp_path / "c"), "--quiet", "--width", "16", "--layers", "1"]
    )
    assert args.func(args) == 0
    model = load_geometry_model(out)
    assert model.meta["sites"] == ["alpha"]
    stored = torch.load(out, map_location="cpu", weights_only=True)["model_config"]
    assert stored["width"] == 16 and stored["layers"] == 1
    with pytest.raises(ValueError, match="--width must be a multiple of 4"):
        args.func(parser.parse_args(["fit-geometry", "--cvmhat", str(data), "--out",
                                     str(tmp_path / "w.pt"), "--width", "10"]))


def test_mirror_augmentation_is_symmetric(model_file, scene):
    """With ``mirror=True`` a scene and its mirror image give the same pairs (the average of
    the two cost matrices is the same either way)."""
    model = load_geometry_model(model_file)
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


def test_ensemble_averages_the_models_costs(model_file, tmp_path, scene):
    """Several models: the mean of their cost matrices, each with its own feature config."""
    from xvmatch.datasets.geometry_features import frame_features
    from xvmatch.inference.assignment import assign
    from xvmatch.inference.learned_association import _input_order

    tiny = load_geometry_model(model_file)
    torch.manual_seed(1)
    other_features = FeatureConfig(n_hypotheses=2, dtheta_deg=6.0)
    other_path = tmp_path / "other.pt"
    save_geometry_model(other_path, GeometryEncoder(**TINY), other_features, gamma=0.3)
    other = load_geometry_model(other_path)
    assert associate_sequence_learned(scene.top, scene.hor, WIDTH, [tiny, tiny]) == (
        associate_sequence_learned(scene.top, scene.hor, WIDTH, tiny))
    pred = associate_sequence_learned(scene.top, scene.hor, WIDTH, [tiny, other], gamma=1.0)
    size = (WIDTH, WIDTH * 9 / 16)
    n_pairs = 0
    for frame, pairs in pred.items():
        t, h = scene.top[frame], scene.hor[frame]
        if not len(t) or not len(h):
            continue
        costs = []
        for m in (tiny, other):
            f = frame_features(t.boxes, h.boxes, size, m.feature_config)
            costs.append(_input_order(f, m.costs([f])[0]))
        expected = assign((costs[0] + costs[1]) / 2, 1.0)
        assert pairs == [(int(t.ids[a]), int(h.ids[b])) for a, b in expected]
        n_pairs += len(pairs)
    assert n_pairs > 0
    args = argparse.Namespace(model=[str(model_file), str(other_path)], image_size=(2688, 1512),
                              camera_id=None, mode="frame", gamma=1.0)
    assert cli_learn.associate_with_model(args, scene.top, scene.hor, sorted(scene.top),
                                          None) == pred
    assert associate_sequence_learned(scene.top, scene.hor, WIDTH, [tiny, other]) == (
        associate_sequence_learned(scene.top, scene.hor, WIDTH, [tiny, other], gamma=0.6))
    with pytest.raises(ValueError, match="no model"):
        associate_sequence_learned(scene.top, scene.hor, WIDTH, [])


def test_costs_out_holds_the_matrices_behind_the_pairs(model_file, scene):
    from xvmatch.inference.assignment import assign

    model = load_geometry_model(model_file)
    costs: dict = {}
    pred = associate_sequence_learned(scene.top, scene.hor, WIDTH, model, gamma=1.0,
                                      costs_out=costs)
    with_boxes = [f for f in pred if len(scene.top[f]) and len(scene.hor[f])]
    assert sorted(costs) == with_boxes
    for f in with_boxes:
        assert costs[f].shape == (len(scene.top[f]), len(scene.hor[f]))
        t, h = scene.top[f].ids, scene.hor[f].ids
        assert pred[f] == [(int(t[a]), int(h[b])) for a, b in assign(costs[f], 1.0)]
    assert sum(len(p) for p in pred.values()) > 0


def test_workers_give_the_same_pairs_and_costs(model_file):
    # 70 frames with gaps and an empty frame: more than one 32-frame chunk goes to the two
    # spawned processes, and the pairs and cost matrices must come back in frame order.
    model = load_geometry_model(model_file)
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
