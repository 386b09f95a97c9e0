"""Tests of the Siamese appearance network, its builders and its weights files."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torchvision

from xvmatch.models.appearance_net import (
    IMAGENET_MEAN,
    IMAGENET_STD,
    AppearanceNet,
    AppearanceWeights,
    CompactTrunk,
    CropTransform,
    Preprocessing,
    ResNetTrunk,
    appearance_distance,
    appearance_efficientnet_lite0,
    appearance_from_weights,
    appearance_mobilenetv2,
    appearance_resnet18,
    appearance_resnet50,
    appearance_small,
    save_appearance_weights,
)

torch.set_num_threads(1)  # one thread: fast and stable on a busy 2-core machine

TINY = {"input_size": (32, 16), "widths": (4, 8, 8, 16), "hidden_dim": 8, "embedding_dim": 6}


def _crops(k: int, size: tuple[int, int], seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.randint(0, 256, (k, *size, 3), generator=g, dtype=torch.uint8)


def test_small_shapes_unit_norm_and_distance_range() -> None:
    torch.manual_seed(0)
    net = appearance_small(**TINY).eval()
    emb = net.embed_crops(_crops(5, (32, 16)))
    assert emb.shape == (5, 6)
    torch.testing.assert_close(emb.norm(dim=1), torch.ones(5))
    d = appearance_distance(emb[:3], emb[3:])
    assert d.shape == (3, 2)
    assert ((d >= 0) & (d <= 1)).all()
    # Identical descriptors: 0 up to float32 round-off of the cosine form.
    torch.testing.assert_close(appearance_distance(emb, emb).diagonal(), torch.zeros(5),
                               atol=1e-3, rtol=0)
    # Opposite descriptors are at distance 1.
    torch.testing.assert_close(appearance_distance(emb[:1], -emb[:1]), torch.ones(1, 1))


def test_distance_with_empty_sides() -> None:
    a, b = torch.zeros(2, 0, 6), torch.nn.functional.normalize(torch.ones(2, 3, 6), dim=-1)
    assert appearance_distance(a, b).shape == (2, 0, 3)
    assert appearance_distance(b, a).shape == (2, 3, 0)


def test_siamese_one_set_of_weights() -> None:
    torch.manual_seed(0)
    net = appearance_small(**TINY).eval()
    crops = _crops(2, (32, 16))
    # The same crop seen "from either view" has the same descriptor: one network, shared.
    both = net.embed_crops(torch.cat([crops, crops]))
    torch.testing.assert_close(both[:2], both[2:])


@pytest.mark.slow
def test_resnet50_is_the_papers_branch() -> None:
    net = appearance_resnet50()
    assert net.preprocessing.input_size == (256, 128)
    assert isinstance(net.trunk, ResNetTrunk) and net.trunk.depth == 50
    assert net.stage_channels == net.trunk.stage_channels == (256, 512, 1024, 2048)
    fc1, bn, relu, drop, fc2 = net.head
    assert (fc1.in_features, fc1.out_features) == (2048, 1024)
    assert isinstance(bn, torch.nn.BatchNorm1d) and isinstance(relu, torch.nn.ReLU)
    assert isinstance(drop, torch.nn.Dropout) and drop.p == 0.5
    assert (fc2.in_features, fc2.out_features) == (1024, 128)
    with torch.no_grad():
        emb = net.eval().embed_crops(_crops(1, (256, 128)))
    assert emb.shape == (1, 128)


def test_crop_transform_bgr_to_normalised_rgb() -> None:
    t = CropTransform(Preprocessing((16, 16)))
    crops = torch.zeros(1, 16, 16, 3, dtype=torch.uint8)
    crops[..., 0] = 255  # blue in BGR
    x = t(crops)
    assert x.shape == (1, 3, 16, 16)
    expected_blue = (1.0 - IMAGENET_MEAN[2]) / IMAGENET_STD[2]
    expected_red = (0.0 - IMAGENET_MEAN[0]) / IMAGENET_STD[0]
    assert x[0, 2, 0, 0].item() == pytest.approx(expected_blue, rel=1e-5)
    assert x[0, 0, 0, 0].item() == pytest.approx(expected_red, rel=1e-5)
    with pytest.raises(ValueError, match=r"crops must be \(B, 16, 16, 3\)"):
        t(torch.zeros(1, 8, 16, 3))


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="input_size must be"):
        Preprocessing((8, 4))
    with pytest.raises(ValueError, match="out_channels"):
        AppearanceNet(torch.nn.Identity())
    with pytest.raises(ValueError, match="dropout"):
        AppearanceNet(CompactTrunk((4, 4, 4, 4)), dropout=1.0)
    with pytest.raises(ValueError, match="depth must be one of"):
        ResNetTrunk(depth=20)


def test_weights_file_round_trip(tmp_path) -> None:
    torch.manual_seed(0)
    net = appearance_small(**TINY).eval()
    record = save_appearance_weights(net, tmp_path / "w.pt", {"train_data": ["x"]})
    assert isinstance(record, AppearanceWeights)
    assert record.arch == "small" and record.preprocessing == net.preprocessing
    assert record.meta == {"train_data": ["x"]}
    again = appearance_from_weights(tmp_path / "w.pt")
    assert again.preprocessing.input_size == (32, 16) and not again.training
    crops = _crops(3, (32, 16))
    with torch.no_grad():
        torch.testing.assert_close(again.embed_crops(crops), net.embed_crops(crops))
    with pytest.raises(ValueError, match="holds an appearance_small network"):
        appearance_resnet18(weights=record)


def test_weights_file_errors(tmp_path) -> None:
    with pytest.raises(FileNotFoundError, match="no such appearance weights file"):
        appearance_from_weights(tmp_path / "missing.pt")
    torch.save({"conv1.weight": torch.zeros(1)}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="not an xvmatch appearance weights file"):
        appearance_from_weights(tmp_path / "other.pt")


@pytest.mark.slow
def test_local_torchvision_backbone_weights(tmp_path) -> None:
    torch.manual_seed(0)
    reference = torchvision.models.resnet18(weights=None)
    path = tmp_path / "resnet18.pth"
    torch.save(reference.state_dict(), path)
    net = appearance_resnet18(backbone_weights=path)
    torch.testing.assert_close(net.trunk.conv1.weight, reference.conv1.weight)
    torch.testing.assert_close(net.trunk.layer4[1].bn2.running_var,
                               reference.layer4[1].bn2.running_var)
    with pytest.raises(FileNotFoundError, match="no such torchvision weights file"):
        appearance_resnet18(backbone_weights=tmp_path / "absent.pth")
    bad = dict(reference.state_dict())
    bad["conv1.weight"] = torch.zeros(3, 3, 3, 3)
    torch.save(bad, tmp_path / "bad.pth")
    with pytest.raises(ValueError, match=r"not torchvision resnet18 weights \(shape mismatch: "
                                         r"conv1.weight"):
        appearance_resnet18(backbone_weights=tmp_path / "bad.pth")
    (tmp_path / "junk.pth").write_bytes(b"not a torch file")
    with pytest.raises(ValueError, match="not a torch weights file"):
        appearance_resnet18(backbone_weights=tmp_path / "junk.pth")


def test_compact_trunk_downsamples_by_32() -> None:
    trunk = CompactTrunk((4, 8, 8, 16))
    out = trunk(torch.zeros(2, 3, 64, 32))
    assert out.shape == (2, 16, 2, 1)
    assert np.isclose(trunk.out_channels, 16)


# Stage maps: the end of each group of equal-width blocks from stride 4 on, the last the
# trunk's output. Widths and strides by architecture, random initialisation (no file read).
STAGES = {
    "small": (lambda **kw: appearance_small(widths=(4, 8, 8, 16), **kw), (4, 8, 8, 16),
              (4, 8, 16, 32)),
    "resnet18": (appearance_resnet18, (64, 128, 256, 512), (4, 8, 16, 32)),
    "mobilenetv2": (appearance_mobilenetv2, (24, 32, 64, 96, 160, 320, 1280),
                    (4, 8, 16, 16, 32, 32, 32)),
    "efficientnet_lite0": (appearance_efficientnet_lite0, (24, 40, 80, 112, 192, 320, 1280),
                           (4, 8, 16, 16, 32, 32, 32)),
}


@pytest.mark.parametrize("arch", sorted(STAGES))
def test_vectors_pool_each_stage_to_unit_length(arch) -> None:
    build, widths, strides = STAGES[arch]
    torch.manual_seed(0)
    net = build(input_size=(64, 32), hidden_dim=8, embedding_dim=6).eval()
    assert net.arch == arch
    assert net.stage_channels == net.trunk.stage_channels == widths
    assert widths[-1] == net.trunk.out_channels
    images = net.transform(_crops(3, (64, 32)))
    with torch.no_grad():
        maps = net.trunk.stage_maps(images)
        descriptors, features, stages = net.vectors(images)
        trunk_out, alone = net.trunk(images), net(images)
    assert [tuple(m.shape[1:]) for m in maps] == [(c, 64 // s, 32 // s)
                                                  for c, s in zip(widths, strides, strict=True)]
    torch.testing.assert_close(maps[-1], trunk_out, rtol=0, atol=0)
    assert stages.shape == (3, sum(widths)) and features.shape == (3, widths[-1])
    torch.testing.assert_close(descriptors, alone)  # one code path for the descriptors
    torch.testing.assert_close(features, trunk_out.mean((2, 3)))
    blocks = stages.split(list(widths), dim=1)
    for block, m in zip(blocks, maps, strict=True):
        torch.testing.assert_close(block.norm(dim=1), torch.ones(3))
        torch.testing.assert_close(block, torch.nn.functional.normalize(m.mean((2, 3)), dim=1))
    torch.testing.assert_close(blocks[-1], torch.nn.functional.normalize(features, dim=1))


class _PlainTrunk(torch.nn.Module):
    """A user's trunk: ``out_channels`` only, no stage maps."""

    out_channels = 5

    def __init__(self) -> None:
        super().__init__()
        self.conv = torch.nn.Conv2d(3, 5, 3, stride=4)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv(x)


def test_a_trunk_without_stage_maps_is_one_stage() -> None:
    torch.manual_seed(0)
    net = AppearanceNet(_PlainTrunk(), input_size=(32, 16), hidden_dim=8, embedding_dim=6)
    net.eval()
    assert net.stage_channels == (5,)
    images = net.transform(_crops(2, (32, 16)))
    with torch.no_grad():
        descriptors, features, stages = net.vectors(images)
    torch.testing.assert_close(descriptors, net(images))
    torch.testing.assert_close(stages, torch.nn.functional.normalize(features, dim=1))


def test_a_trunk_with_stage_maps_needs_their_widths() -> None:
    trunk = CompactTrunk((4, 4, 4, 8))
    trunk.stage_channels = (4, 4, 4, 4)  # does not end with out_channels
    with pytest.raises(ValueError, match=r"stage_channels.*ending with out_channels \(8\)"):
        AppearanceNet(trunk)
    del trunk.stage_channels
    with pytest.raises(ValueError, match="a trunk with stage_maps needs stage_channels"):
        AppearanceNet(trunk)
