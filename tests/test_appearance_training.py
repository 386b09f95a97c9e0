"""Tests of the appearance training: crops and splits, the Lightning module, checkpoints, CLI."""

from __future__ import annotations

import argparse
from pathlib import Path

import lightning as L
import numpy as np
import pytest
import torch
from torch import nn

from xvmatch.commands.lab.train import add_train_parser
from xvmatch.datasets.synthetic_io import SyntheticDataset, generate_dataset, person_crops
from xvmatch.datasets.synthetic_scenes import SynthConfig
from xvmatch.formats.crops import box_crops
from xvmatch.models.appearance_net import (
    AppearanceWeights,
    appearance_from_weights,
    appearance_small,
)
from xvmatch.training.appearance_module import AppearanceModule, embed_batch, pair_metrics
from xvmatch.training.image_datamodule import (
    CropPair,
    ImagePairDataModule,
    augment_crops,
    collate_crop_pairs,
    load_crop_pairs,
    split_scenes,
)
from xvmatch.training.train_cli import cli_main

torch.set_num_threads(1)  # one thread: fast and stable on a busy 2-core machine

REPO = Path(__file__).resolve().parents[1]
SIZE = (32, 16)  # (height, width) of the crops in these tests
TINY_NET = {"input_size": SIZE, "widths": (4, 8, 8, 16), "hidden_dim": 16, "embedding_dim": 8}
QUIET = {"logger": False, "enable_progress_bar": False, "enable_model_summary": False}


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory) -> Path:
    """4 overview scenes x 2 frames at 320x180, 3-6 people."""
    root = tmp_path_factory.mktemp("appearance") / "data"
    config = SynthConfig(scenario="overview", top_size=(320, 180), ego_size=(320, 180),
                         n_people=(3, 6))
    generate_dataset(root, config, n_scenes=4, n_frames=2, seed=11)
    return root


def _module(seed: int = 0, **kwargs) -> AppearanceModule:
    torch.manual_seed(seed)
    return AppearanceModule(appearance_small(**TINY_NET), **kwargs)


# ---------------------------------------------------------------------------------------------
# Data


def test_crop_pairs_scrambled_and_labelled_by_id(tiny_data: Path) -> None:
    pairs = load_crop_pairs(tiny_data, None, SIZE, seed=3)
    data = SyntheticDataset(tiny_data)
    assert len(pairs) == len(data) == 8
    pair, record = pairs[0], next(iter(data))
    ids_top, crops_top = person_crops(record.top.load_image(), record.top.labels,
                                      size=(SIZE[1], SIZE[0]), min_pixels=20)
    ids_ego, crops_ego = person_crops(record.ego.load_image(), record.ego.labels,
                                      size=(SIZE[1], SIZE[0]), min_pixels=20)
    assert pair.top.shape == (len(ids_top), *SIZE, 3)
    # Each crop of the pair is one of the person crops; recover its id by pixel equality.
    def ids_of(crops, reference, ids):
        return np.array([ids[[np.array_equal(c, r) for r in reference].index(True)]
                         for c in crops])

    top, ego = ids_of(pair.top, crops_top, ids_top), ids_of(pair.ego, crops_ego, ids_ego)
    np.testing.assert_array_equal(pair.match, top[:, None] == ego[None, :])
    assert sorted(top.tolist()) == sorted(ids_top.tolist())
    # Scrambled: across the dataset, some view is not in ascending id order.
    scrambled = False
    for p, rec in zip(pairs, data, strict=True):
        _, ref = person_crops(rec.top.load_image(), rec.top.labels, size=(SIZE[1], SIZE[0]),
                              min_pixels=20)
        scrambled |= not all(np.array_equal(a, b) for a, b in zip(p.top, ref, strict=True))
    assert scrambled
    # Geometrically hard negatives are false pairs only; with an infinite radius, all of them.
    assert all(not (p.near & p.match).any() for p in pairs)
    assert any(p.near.any() for p in pairs)
    everything = load_crop_pairs(tiny_data, None, SIZE, seed=3, hard_radius=np.inf)
    assert all(np.array_equal(p.near, ~p.match) for p in everything)
    # Deterministic for a seed, whatever the number of threads.
    again = load_crop_pairs(tiny_data, None, SIZE, seed=3, workers=2)
    assert all(np.array_equal(a.top, b.top) and np.array_equal(a.match, b.match)
               for a, b in zip(pairs, again, strict=True))


def test_box_crops_match_person_crops(tiny_data: Path) -> None:
    record = next(iter(SyntheticDataset(tiny_data)))
    image = record.ego.load_image()
    _, expected = person_crops(image, record.ego.labels, size=(16, 32))
    np.testing.assert_array_equal(box_crops(image, record.ego.labels.boxes, (16, 32)), expected)
    assert box_crops(image, np.zeros((0, 4)), (16, 32)).shape == (0, 32, 16, 3)


def test_split_by_scene() -> None:
    names = [f"s{k:05d}" for k in range(10)]
    train, held = split_scenes(names, 0.2, seed=0)
    assert len(held) == 2 and not set(train) & set(held) and sorted(train + held) == names
    assert split_scenes(names, 0.2, seed=0) == (train, held)
    assert split_scenes(names[:2], 0.9, seed=0)[0]  # at least one scene kept
    with pytest.raises(ValueError, match="val_fraction"):
        split_scenes(names, 1.0, seed=0)


def test_datamodule_splits_scenes_apart(tiny_data: Path) -> None:
    dm = ImagePairDataModule(str(tiny_data), val_fraction=0.25, input_height=SIZE[0],
                             input_width=SIZE[1], batch_size=3, seed=1, workers=1)
    dm.setup("fit")
    train = {p.scene for p in dm.splits["train"]}
    val = {p.scene for p in dm.splits["val"]}
    assert len(val) == 1 and len(train) == 3 and not train & val
    batch = next(iter(dm.train_dataloader()))
    assert batch.top.shape[0] == 3 and batch.top.shape[2:] == (*SIZE, 3)
    assert "train: 6 pairs" in dm.describe()
    with pytest.raises(ValueError, match=r"no dataset\.json"):
        ImagePairDataModule("/nonexistent/folder").setup("fit")


def test_collate_and_masking_with_empty_sides() -> None:
    rng = np.random.default_rng(0)
    crop = lambda k: rng.integers(0, 255, (k, *SIZE, 3), dtype=np.uint8)  # noqa: E731
    items = [
        CropPair("a", 1, crop(3), crop(2), np.array([[1, 0], [0, 0], [0, 1]], bool)),
        CropPair("b", 1, crop(0), crop(2), np.zeros((0, 2), bool)),
        CropPair("c", 1, crop(2), crop(0), np.zeros((2, 0), bool)),
    ]
    batch = collate_crop_pairs(items)
    assert batch.top.shape == (3, 3, *SIZE, 3) and batch.ego.shape == (3, 2, *SIZE, 3)
    assert batch.top_mask.tolist() == [[True] * 3, [False] * 3, [True, True, False]]
    assert batch.ego_mask.tolist() == [[True, True], [True, True], [False, False]]
    assert int(batch.match.sum()) == 2
    module = _module().eval()
    with torch.no_grad():
        top, ego = embed_batch(module.net, batch)
        distance = module(batch)
    assert top.shape == (3, 3, 8) and distance.shape == (3, 3, 2)
    assert (top[~batch.top_mask] == 0).all() and (ego[~batch.ego_mask] == 0).all()
    loss, _, _ = module._step(batch)
    assert torch.isfinite(loss)
    sums = pair_metrics(distance, batch.match, batch.top_mask[:, :, None]
                        & batch.ego_mask[:, None, :])
    assert int(sums["rank1_total"]) == 2
    assert int(sums["neg_count"]) == 4  # only pair "a" has both sides


def test_augmentation_keeps_shapes_and_is_seeded(tiny_data: Path) -> None:
    batch = collate_crop_pairs(load_crop_pairs(tiny_data, None, SIZE)[:2])
    a = augment_crops(batch, torch.Generator().manual_seed(0))
    b = augment_crops(batch, torch.Generator().manual_seed(0))
    assert a.top.shape == batch.top.shape and a.top.dtype == torch.float32
    assert float(a.top.min()) >= 0 and float(a.top.max()) <= 255
    torch.testing.assert_close(a.top, b.top)
    assert not torch.equal(a.top, batch.top.float())
    assert torch.equal(a.match, batch.match)


def test_camera_shift_augmentation_is_seeded_and_off_by_default(tiny_data: Path) -> None:
    batch = collate_crop_pairs(load_crop_pairs(tiny_data, None, SIZE)[:2])
    before = batch.top.clone()
    plain = augment_crops(batch, torch.Generator().manual_seed(0))
    off = augment_crops(batch, torch.Generator().manual_seed(0), shift_probability=0.0)
    torch.testing.assert_close(plain.top, off.top)  # 0 draws nothing: the old stream
    a = augment_crops(batch, torch.Generator().manual_seed(0), 1.0, 3.0)
    b = augment_crops(batch, torch.Generator().manual_seed(0), 1.0, 3.0)
    torch.testing.assert_close(a.top, b.top)
    torch.testing.assert_close(a.ego, b.ego)
    assert a.top.shape == batch.top.shape and float(a.top.max()) <= 255
    assert not torch.equal(a.top, plain.top)
    assert torch.equal(batch.top, before)  # the batch's own crops are not written over


def test_camera_shift_gives_one_camera_per_pair_and_view(tiny_data: Path) -> None:
    """All crops of one view of a pair go through the same camera: the shift of a pair's crops
    side by side, crop by crop (sensor noise aside, it is one colour mapping)."""
    batch = collate_crop_pairs(load_crop_pairs(tiny_data, None, SIZE)[:2])
    from xvmatch.training.image_datamodule import _camera_shift_view

    flat = torch.full_like(batch.top, 128)  # grey crops: only the camera changes them
    out = _camera_shift_view(flat, torch.Generator().manual_seed(3), 1.0, 3.0).float()
    assert out.dtype == torch.float32 and out.shape == flat.shape
    for i in range(out.shape[0]):
        means = out[i].mean(dim=(1, 2))  # (K, 3): each crop's mean colour
        assert float((means - means.mean(dim=0)).abs().max()) < 3.0
    assert float((out[0].mean(dim=(0, 1, 2)) - out[1].mean(dim=(0, 1, 2))).abs().max()) > 1.0


@pytest.mark.parametrize("kwargs, message", [
    ({"camera_shift_probability": 1.5}, "camera_shift_probability must be in [0, 1]"),
    ({"camera_shift_max": 0.0}, "camera_shift_max must be in (0, 3]"),
    ({"camera_shift_max": 4.0}, "camera_shift_max must be in (0, 3]"),
])
def test_camera_shift_options_are_checked(tiny_data: Path, kwargs, message) -> None:
    with pytest.raises(ValueError) as info:
        ImagePairDataModule(train_data=str(tiny_data), **kwargs)
    assert message in str(info.value)


# ---------------------------------------------------------------------------------------------
# Loss and training


class _ColourNet(nn.Module):
    """A fixed 'network': the descriptor of a crop is its mean colour, centred and normalised."""

    def embed_crops(self, crops: torch.Tensor) -> torch.Tensor:
        return nn.functional.normalize(crops.float().mean(dim=(1, 2)) - 127.5, dim=1)


def test_loss_zero_and_positive_where_it_must_be() -> None:
    module = AppearanceModule(_ColourNet(), margin=0.5)
    colour = lambda c: torch.tensor(c, dtype=torch.uint8).expand(1, *SIZE, 3)  # noqa: E731
    red, blue = colour([0, 0, 255]), colour([255, 0, 0])
    same = CropPair("s", 1, torch.cat([red, blue]).numpy(), torch.cat([red, blue]).numpy(),
                    np.eye(2, dtype=bool))
    loss, distance, _ = module._step(collate_crop_pairs([same]))
    assert float(distance[0, 0, 0]) < 1e-3 and float(distance[0, 0, 1]) > 0.5
    assert float(loss) == pytest.approx(0.0, abs=1e-6)  # partners equal, negatives past margin
    swapped = CropPair("s", 1, same.top, same.ego, ~np.eye(2, dtype=bool))
    loss, _, _ = module._step(collate_crop_pairs([swapped]))
    assert float(loss) > 0.5  # partners far apart, negatives identical
    # The geometric term: zero without hard negatives, positive when one is confused.
    weighted = AppearanceModule(_ColourNet(), margin=0.5, geo_hard_weight=1.0)
    loss, _, _ = weighted._step(collate_crop_pairs([same]))
    assert float(loss) == pytest.approx(0.0, abs=1e-6)
    # Two red people in the egocentric view, one of them a false partner of the red top-view
    # person whose ray passes near: the geometric term adds margin^2 for it.
    confused = CropPair("s", 1, torch.cat([red, blue]).numpy(), torch.cat([red, red]).numpy(),
                        np.array([[True, False], [False, False]]),
                        np.array([[False, True], [False, False]]))
    plain = float(module._step(collate_crop_pairs([confused]))[0])
    assert float(weighted._step(collate_crop_pairs([confused]))[0]) == pytest.approx(
        plain + 0.25, abs=1e-3)
    nobody = CropPair("s", 1, same.top[:0], same.ego, np.zeros((0, 2), bool))
    loss, _, _ = module._step(collate_crop_pairs([nobody]))
    assert float(loss) == 0.0


def test_a_few_steps_reduce_the_loss(tiny_data: Path) -> None:
    pairs = load_crop_pairs(tiny_data, None, SIZE)
    batch = collate_crop_pairs(pairs[:4])
    module = _module(seed=0, lr=3e-3, hard_negatives=0)
    optimizer = torch.optim.Adam(module.parameters(), lr=3e-3)

    def eval_loss() -> float:
        module.eval()
        with torch.no_grad():
            return float(module._step(batch)[0])

    before = eval_loss()
    for _ in range(15):
        module.train()
        loss, _, _ = module._step(batch)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    after = eval_loss()
    assert after < 0.8 * before


def test_input_size_mismatch_is_reported(tiny_data: Path, tmp_path: Path) -> None:
    dm = ImagePairDataModule(str(tiny_data), input_height=64, input_width=32, workers=1)
    trainer = L.Trainer(max_steps=1, default_root_dir=tmp_path, **QUIET)
    with pytest.raises(ValueError, match="the data crops 64x32 but the network expects 32x16"):
        trainer.fit(_module(), dm)


def test_checkpoint_round_trip_and_resume(tiny_data: Path, tmp_path: Path) -> None:
    dm = ImagePairDataModule(str(tiny_data), val_fraction=0.25, input_height=SIZE[0],
                             input_width=SIZE[1], batch_size=2, workers=1)
    L.seed_everything(0)
    module = _module()
    trainer = L.Trainer(max_steps=2, limit_val_batches=1, default_root_dir=tmp_path,
                        enable_checkpointing=False, **QUIET)
    trainer.fit(module, dm)
    path = tmp_path / "two_steps.ckpt"
    trainer.save_checkpoint(path)
    loaded = AppearanceModule.load_from_checkpoint(path, net=appearance_small(**TINY_NET))
    assert loaded.hparams.margin == module.hparams.margin
    batch = collate_crop_pairs(dm.splits["val"][:2])
    module.eval()
    loaded.eval()
    with torch.no_grad():
        torch.testing.assert_close(loaded(batch), module(batch))
    resumed = L.Trainer(max_steps=3, limit_val_batches=1, default_root_dir=tmp_path,
                        enable_checkpointing=False, **QUIET)
    resumed.fit(_module(seed=5), dm, ckpt_path=path)
    assert resumed.global_step == 3


# ---------------------------------------------------------------------------------------------
# Configuration and command line


def _overrides(tiny_data: Path, root: Path) -> list[str]:
    return [
        "--data.init_args.train_data", f"[{tiny_data}]",
        "--data.init_args.val_data", str(tiny_data),
        "--data.init_args.input_height", str(SIZE[0]),
        "--data.init_args.input_width", str(SIZE[1]),
        "--data.init_args.workers", "1",
        "--model.init_args.net.init_args.input_size", f"[{SIZE[0]}, {SIZE[1]}]",
        "--model.init_args.net.init_args.widths", "[4, 8, 8, 16]",
        "--trainer.default_root_dir", str(root),
    ]


@pytest.mark.slow
@pytest.mark.parametrize("config", ["appearance_cpu.yaml", "appearance_resnet50.yaml"])
def test_lightning_cli_configs_parse(config: str, tiny_data: Path, tmp_path: Path) -> None:
    args = ["--config", str(REPO / "configs" / config)]
    if config == "appearance_cpu.yaml":
        args += _overrides(tiny_data, tmp_path)
    cli = cli_main(args, run=False)
    assert isinstance(cli.model, AppearanceModule)
    assert isinstance(cli.datamodule, ImagePairDataModule)
    size = cli.model.net.preprocessing.input_size
    assert size == cli.datamodule.input_size
    assert size == (SIZE if config == "appearance_cpu.yaml" else (256, 128))
    assert cli.trainer.max_epochs > 0


def test_camera_shift_options_reach_the_datamodule(tiny_data: Path, tmp_path: Path) -> None:
    """As ``make_default_bundle.py --appearance-shift`` passes them to ``xvmatch train``."""
    args = ["--config", str(REPO / "configs" / "appearance_cpu.yaml"),
            *_overrides(tiny_data, tmp_path), "--data.camera_shift_probability", "0.5",
            "--data.camera_shift_max", "2.5"]
    cli = cli_main(args, run=False)
    assert cli.datamodule.hparams.camera_shift_probability == 0.5
    assert cli.datamodule.hparams.camera_shift_max == 2.5


@pytest.mark.parametrize("args, message", [
    (["--appearance-shift", "1.5"], "--appearance-shift: expected a number in [0, 1]"),
    (["--appearance-shift-max", "3.5"], "--appearance-shift-max: expected a number in (0, 3]"),
])
def test_recipe_refuses_bad_camera_shift_options(tmp_path, capsys, monkeypatch, args,
                                                  message) -> None:
    """``make_default_bundle.py`` stops with one line before it renders anything."""
    monkeypatch.syspath_prepend(str(REPO / "training"))
    import make_default_bundle

    work = tmp_path / "work"
    with pytest.raises(SystemExit) as info:
        make_default_bundle.main(["--work", str(work), *args])
    assert info.value.code == 2 and message in capsys.readouterr().err
    assert not work.exists()


def test_fusion_config_parses() -> None:
    from xvmatch.training.fusion_datamodule import CuePairDataModule
    from xvmatch.training.fusion_module import FusionModule

    cli = cli_main(["--config", str(REPO / "configs" / "fusion_overview.yaml")], run=False)
    assert isinstance(cli.model, FusionModule)
    assert isinstance(cli.datamodule, CuePairDataModule)
    assert tuple(cli.model.head.names) == cli.datamodule.names


@pytest.mark.slow
def test_xvmatch_train_end_to_end(tiny_data: Path, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)  # the config's relative runs/ folder lands here
    parser = argparse.ArgumentParser()
    add_train_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args([
        "train", "--config", str(REPO / "configs" / "appearance_cpu.yaml"),
        *_overrides(tiny_data, tmp_path), "--trainer.max_epochs", "1",
        "--trainer.limit_train_batches", "2", "--trainer.enable_progress_bar", "false",
    ])
    assert args.func(args) == 0
    run = tmp_path / "runs" / "appearance_cpu" / "version_0"
    config = (run / "config.yaml").read_text()
    assert "appearance_small" in config and str(tiny_data) in config
    assert (run / "metrics.csv").is_file() and (run / "checkpoints" / "last.ckpt").is_file()
    record = AppearanceWeights.from_file(run / "appearance_weights.pt")
    assert record.preprocessing.input_size == SIZE
    assert record.meta["train_data"] == [str(tiny_data)]
    assert appearance_from_weights(record).embedding_dim == 128
    # The CLI-written checkpoint rebuilds its module without being given the network.
    loaded = AppearanceModule.load_from_checkpoint(run / "checkpoints" / "last.ckpt")
    assert loaded.net.preprocessing.input_size == SIZE


def test_xvmatch_train_rejects_a_missing_config(tmp_path: Path) -> None:
    parser = argparse.ArgumentParser()
    add_train_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["train", "--config", str(tmp_path / "none.yaml")])
    with pytest.raises(ValueError, match="no such configuration file"):
        args.func(args)


# ---------------------------------------------------------------------------------------------
# Untrusted checkpoints (issue 28, item 2a)


class _Marker:
    """A pickled object that, once unpickled, creates a file: stands for code execution."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def __reduce__(self):
        return (open, (str(self.path), "w"))


def _fit_with_best_checkpoint(data: Path, root: Path, max_steps: int, ckpt_path=None):
    from lightning.pytorch.callbacks import ModelCheckpoint

    from xvmatch.training.appearance_module import SaveAppearanceWeights

    dm = ImagePairDataModule(str(data), val_fraction=0.25, input_height=SIZE[0],
                             input_width=SIZE[1], batch_size=2, workers=1)
    save = SaveAppearanceWeights(path=str(root / "weights.pt"))
    trainer = L.Trainer(max_steps=max_steps, limit_val_batches=1, default_root_dir=root,
                        callbacks=[ModelCheckpoint(dirpath=root / "checkpoints",
                                                   monitor="val/loss", save_last=True), save],
                        **QUIET)
    trainer.fit(_module(), dm, ckpt_path=ckpt_path)
    return save


def _crafted_resume(root: Path, best: Path) -> Path:
    """The run's last checkpoint with its stored best-model path replaced by ``best``."""
    blob = torch.load(root / "checkpoints" / "last.ckpt", weights_only=True)
    for key, state in blob["callbacks"].items():
        if key.startswith("ModelCheckpoint"):
            state["best_model_path"] = str(best)
    crafted = root / "crafted.ckpt"
    torch.save(blob, crafted)
    return crafted


def test_best_checkpoint_outside_the_run_folder_is_refused(tiny_data: Path,
                                                            tmp_path: Path) -> None:
    root = tmp_path / "run"
    assert _fit_with_best_checkpoint(tiny_data, root, max_steps=1).written is not None
    marker = tmp_path / "marker"
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    torch.save({"state_dict": _Marker(marker)}, elsewhere / "evil.ckpt")
    crafted = _crafted_resume(root, elsewhere / "evil.ckpt")
    with pytest.raises(ValueError, match=r"refusing best checkpoint .*evil\.ckpt: outside"):
        _fit_with_best_checkpoint(tiny_data, root, max_steps=2, ckpt_path=crafted)
    assert not marker.exists()


def test_best_checkpoint_with_pickled_code_is_refused(tiny_data: Path, tmp_path: Path) -> None:
    root = tmp_path / "run"
    _fit_with_best_checkpoint(tiny_data, root, max_steps=1)
    marker = tmp_path / "marker"
    evil = root / "checkpoints" / "evil.ckpt"  # inside the run folder: read weights-only
    torch.save({"state_dict": _Marker(marker)}, evil)
    crafted = _crafted_resume(root, evil)
    with pytest.raises(ValueError, match=r"evil\.ckpt: not a readable checkpoint") as info:
        _fit_with_best_checkpoint(tiny_data, root, max_steps=2, ckpt_path=crafted)
    assert "\n" not in str(info.value)
    assert not marker.exists()
