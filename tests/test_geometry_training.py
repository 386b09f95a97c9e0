"""Training the geometry model: loss goes down, fit/checkpoint/resume round trip, DataModules."""

from __future__ import annotations

import json
import warnings
from dataclasses import replace

import lightning as L
import numpy as np
import pytest
import torch

from xvmatch.cues.spatial_features import FeatureConfig
from xvmatch.datasets.box_scene import write_box_scene
from xvmatch.formats.cvmhat import site_of
from xvmatch.models.geometry_encoder import GeometryEncoder
from xvmatch.models.matcher_file import load_matcher
from xvmatch.training.box_datamodule import (
    CvmhatBoxDataModule,
    SimBoxDataModule,
    random_scene_config,
)
from xvmatch.training.fit_geometry import fit_geometry
from xvmatch.training.geometry_module import GeometryMatchingModule

FEATURES = FeatureConfig(n_hypotheses=3, dtheta_deg=4.0)
TINY = {"width": 16, "layers": 1, "heads": 2, "sinkhorn_iterations": 10}
INPUTS = ("top", "hor", "hyp", "pair", "top_mask", "hor_mask", "hyp_mask")

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning", "ignore::DeprecationWarning")


@pytest.fixture(autouse=True)
def _one_torch_thread():
    """One intra-op thread: tiny tensors gain nothing from more, and on a busy 2-core machine
    more threads spin against each other (a 1 s training run took over a minute)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def sim_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("cache")


def _sim(cache, **kwargs) -> SimBoxDataModule:
    options = {"n_scenes": 4, "frames_per_scene": 16, "frame_step": 2, "val_scenes": 1,
               "feature_config": FEATURES, "batch_size": 8, "cache_dir": str(cache), "seed": 1}
    options.update(kwargs)
    return SimBoxDataModule(**options)


def _mean_loss(module: GeometryMatchingModule, batches) -> float:
    module.eval()
    with torch.no_grad():
        values = [
            module.loss(module(b), b["match"], b["camera_correct"], b["top_mask"],
                        b["hor_mask"], b["hyp_mask"])["total"].item()
            for b in batches
        ]
    module.train()
    return float(np.mean(values))


@pytest.mark.slow
def test_a_few_training_steps_reduce_the_loss(sim_dir):
    dm = _sim(sim_dir)
    dm.setup("fit")
    assert len(dm.train_parts) == 3 and len(dm.val_parts) == 1
    batches = list(dm.train_dataloader())
    L.seed_everything(0, verbose=False)
    module = GeometryMatchingModule(GeometryEncoder(**TINY), learning_rate=5e-3)
    before = _mean_loss(module, batches)
    trainer = L.Trainer(max_epochs=12, accelerator="cpu", logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, enable_model_summary=False,
                        num_sanity_val_steps=0, limit_val_batches=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        trainer.fit(module, train_dataloaders=dm.train_dataloader())
    after = _mean_loss(module, batches)
    assert after < 0.7 * before, (before, after)


@pytest.mark.slow
def test_fit_checkpoint_resume_round_trip(sim_dir, tmp_path):
    out = tmp_path / "geo.pt"
    run = tmp_path / "run"
    result = fit_geometry(_sim(sim_dir), out, feature_config=FEATURES, model_config=TINY,
                          epochs=1, seed=0, run_dir=run, progress=False, meta={"note": "test"})
    assert result.model_path == out and out.is_file()
    assert result.epochs == 1 and result.best_score is not None
    assert result.wall_time_s > 0 and result.peak_memory_mb > 0
    assert (run / "checkpoints" / "last.ckpt").is_file()
    assert list((run / "csv").rglob("metrics.csv"))
    assert list((run / "tensorboard").rglob("*tfevents*"))
    config = json.loads((run / "config.json").read_text())
    assert config["model_config"]["width"] == 16 and config["seed"] == 0

    # The model file round-trips: same weights, same costs.
    loaded = load_matcher(out)
    assert loaded.meta["note"] == "test" and loaded.feature_config == FEATURES
    best = torch.load(next((run / "checkpoints").glob("best-*.ckpt")), weights_only=True)
    weights = {k.removeprefix("model."): v for k, v in best["state_dict"].items()
               if k.startswith("model.")}
    for name, value in loaded.matcher.state_dict().items():
        assert torch.equal(value, weights[name]), name
    dm = _sim(sim_dir)
    dm.setup("fit")
    batch = next(iter(dm.val_dataloader()))
    reference = GeometryEncoder(**TINY)
    reference.load_state_dict({k.removeprefix("geometry."): v for k, v in weights.items()})
    reference.eval()
    with torch.no_grad():
        expected = reference(*(batch[k] for k in INPUTS)).cost
        got = loaded.matcher(*(batch[k] for k in INPUTS)).cost
    assert torch.equal(expected, got)

    # Resume continues from the last checkpoint up to the new epoch budget.
    again = fit_geometry(_sim(sim_dir), out, feature_config=FEATURES, model_config=TINY,
                         epochs=2, seed=0, run_dir=run, resume=True, progress=False)
    assert again.epochs == 2


def test_a_corrupt_resume_checkpoint_is_one_line_naming_it(sim_dir, tmp_path):
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    last = run / "checkpoints" / "last.ckpt"
    last.write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(ValueError, match=r"last\.ckpt: not a readable checkpoint") as info:
        fit_geometry(_sim(sim_dir), tmp_path / "m.pt", feature_config=FEATURES,
                     model_config=TINY, epochs=1, run_dir=run, resume=True, progress=False)
    assert "\n" not in str(info.value)
    assert not (tmp_path / "m.pt").exists()


@pytest.mark.slow
def test_a_resumed_best_path_outside_the_run_is_refused(sim_dir, tmp_path):
    run = tmp_path / "run"
    fit_geometry(_sim(sim_dir), tmp_path / "m.pt", feature_config=FEATURES, model_config=TINY,
                 epochs=1, seed=0, run_dir=run, progress=False)
    last = run / "checkpoints" / "last.ckpt"
    blob = torch.load(last, weights_only=True)
    outside = tmp_path / "outside.ckpt"
    outside.write_bytes(last.read_bytes())
    for key, state in blob["callbacks"].items():
        if key.startswith("ModelCheckpoint"):
            state["best_model_path"] = str(outside)
            state["best_model_score"] = torch.tensor(1e9)  # no later epoch replaces it
    torch.save(blob, last)
    with pytest.raises(ValueError, match=r"refusing best checkpoint .*outside\.ckpt"):
        fit_geometry(_sim(sim_dir), tmp_path / "m2.pt", feature_config=FEATURES,
                     model_config=TINY, epochs=2, seed=0, run_dir=run, resume=True,
                     progress=False)


def test_fit_rejects_bad_arguments(sim_dir, tmp_path):
    with pytest.raises(ValueError, match="epochs must be >= 1"):
        fit_geometry(_sim(sim_dir), tmp_path / "m.pt", feature_config=FEATURES, epochs=0)
    with pytest.raises(ValueError, match="does not exist"):
        fit_geometry(_sim(sim_dir), tmp_path / "nope" / "m.pt", feature_config=FEATURES)


def test_sim_datamodule_is_deterministic(sim_dir):
    a, b = _sim(sim_dir, n_scenes=2, val_scenes=0), _sim(sim_dir, n_scenes=2, val_scenes=0)
    for k in range(2):
        ta, _, ca = a.scene(k)
        tb, _, cb = b.scene(k)
        assert ca == cb
        assert all(np.array_equal(ta[f].boxes, tb[f].boxes) for f in ta)
    rng = np.random.default_rng(3)
    configs = [random_scene_config(rng) for _ in range(20)]  # all valid SceneConfigs
    assert len({c.top_altitude for c in configs}) == 20


def test_cvmhat_datamodule_on_box_files(tmp_path, sim_dir):
    """Leave-one-site-out splits on a tiny CVMHAT-layout folder written from simulated scenes."""
    sim = _sim(sim_dir, n_scenes=3, frames_per_scene=8, noise_probability=0.0)
    from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene

    for k, name in enumerate(["V0-S_alpha_0-G_1", "V0-S_alpha_1-G_1", "V1-S_beta-G_2"]):
        scene = simulate_box_scene(SceneConfig(n_people=(5, 7)), n_frames=8, seed=k)
        write_box_scene(scene, tmp_path, name)
    del sim
    assert site_of("V1-S_beta-G_2") == "beta"
    dm = CvmhatBoxDataModule(data_dir=str(tmp_path), test_site="beta", val_fraction=0.25,
                             noise_seeds=[1000], feature_config=FEATURES,
                             cache_dir=str(sim_dir), batch_size=4)
    dm.setup("fit")
    n_train = sum(len(p) for p in dm.train_parts)
    n_val = sum(len(p) for p in dm.val_parts)
    n_test = sum(len(p) for p in dm.test_parts)
    assert n_val > 0 and n_test > 0
    assert n_train >= 2 * n_val  # clean + noisy copy of the first 75% of frames
    assert {p.name.split("/")[0] for p in dm.test_parts} == {"V1-S_beta-G_2"}
    batch = next(iter(dm.train_dataloader()))
    assert batch["match"].dtype == torch.bool and batch["match"].any()
    with pytest.raises(ValueError, match="not among the sites"):
        CvmhatBoxDataModule(data_dir=str(tmp_path), test_site="gamma").setup()
    with pytest.raises(ValueError, match="nothing to train on"):
        CvmhatBoxDataModule(data_dir=str(tmp_path), clean=False)


@pytest.mark.slow
def test_cvmhat_datamodule_re_times_an_out_of_sync_training_pair(tmp_path):
    """One training pair is the other with its horizontal frames renumbered by 8: synchronised,
    its frames carry the very features and labels of the original; the test site is untouched."""
    from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene
    from xvmatch.formats.mot_boxes import FrameBoxes

    config = SceneConfig(n_people=(5, 6), fps=5.0, height_range=(1.7, 1.7), hor_wobble_deg=0.0)
    scene = simulate_box_scene(config, n_frames=60, seed=3)
    write_box_scene(scene, tmp_path, "V0-S_alpha_0-G_1")
    shifted = replace(scene, hor={f + 8: FrameBoxes(f + 8, r.ids, r.boxes)
                                  for f, r in scene.hor.items()})
    write_box_scene(shifted, tmp_path, "V0-S_alpha_1-G_1")
    write_box_scene(shifted, tmp_path, "V1-S_beta-G_1")
    options = dict(data_dir=str(tmp_path), test_site="beta", val_fraction=0.0,
                   feature_config=FEATURES, cache_dir=str(tmp_path / "cache"), sync_max_offset=10)
    dm = CvmhatBoxDataModule(**options)
    dm.setup("fit")
    assert {n: o.applied for n, o in dm.offsets.items()} == {
        "V0-S_alpha_0-G_1": 0, "V0-S_alpha_1-G_1": -8}
    orig, moved = dm.train_parts
    f0, f1 = orig.features.frames, moved.features.frames
    common = np.intersect1d(f0, f1 - 8)
    assert common.size > 40
    for f in common[:: 7]:
        a = orig.features.frame(int(np.flatnonzero(f0 == f)[0]))
        b = moved.features.frame(int(np.flatnonzero(f1 == f + 8)[0]))
        for field in ("top", "hor", "hyp", "pair"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    # The same labels: with the files' timing the moved pair's labels are the wrong ones.
    labels = {int(f): m for f, m in zip(f0, orig.matches, strict=True)}
    assert all(np.array_equal(m, labels[int(f) - 8])
               for f, m in zip(f1, moved.matches, strict=True) if int(f) - 8 in labels)
    (test,) = dm.test_parts
    assert test.features.frames.min() == min(shifted.hor)  # files' timing: no re-timing
    plain = CvmhatBoxDataModule(**options, synchronise=False)
    plain.setup("fit")
    assert plain.offsets == {}
    assert not np.array_equal(plain.train_parts[1].features.frames, f1)


def test_training_is_deterministic_given_the_seed(sim_dir, tmp_path):
    """Same seed, same data: bit-identical weights (what make_default_bundle.py relies on)."""
    weights = []
    for k in range(2):
        out = tmp_path / f"m{k}.pt"
        fit_geometry(_sim(sim_dir), out, feature_config=FEATURES, model_config=TINY, epochs=1,
                     seed=3, run_dir=tmp_path / f"run{k}", progress=False)
        weights.append(torch.load(out, weights_only=True)["state_dict"])
    assert weights[0].keys() == weights[1].keys()
    assert all(torch.equal(weights[0][k], weights[1][k]) for k in weights[0])
