"""The trained matcher as one torch file: what training writes and ``xvmatch export`` reads.

One file holds everything the deployed matcher is made of (``torch.save`` of plain containers,
read with ``weights_only=True``)::

    {"format": "xvmatch-matcher", "format_version": 1,
     "feature_version": FEATURE_VERSION, "feature_config": {...},
     "geometry_config": {...GeometryEncoder kwargs...},
     "matcher_config": {"cues": [...], "hidden": int},
     "gamma": float, "meta": {...JSON-able...}, "state_dict": {name: tensor},
     "appearance": None | {...appearance_blob..., "context": float}}

A box-only matcher (``xvmatch fit-geometry``) has no cues and no appearance network. Written
atomically; loading checks every field's presence, type and range, and that every weight is
finite, and says what is wrong in one line naming the file.
"""

from __future__ import annotations

import io
import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from xvmatch.core.atomic_files import atomic_write_bytes
from xvmatch.core.record_fields import typed_field
from xvmatch.cues.spatial_features import FEATURE_VERSION, FeatureConfig
from xvmatch.models.appearance_net import (
    WEIGHTS_FORMAT,
    AppearanceNet,
    AppearanceWeights,
    appearance_blob,
    appearance_from_weights,
)
from xvmatch.models.cross_view_matcher import CrossViewMatcher
from xvmatch.models.geometry_encoder import GeometryEncoder

__all__ = [
    "DEFAULT_MATCHER_PATH",
    "MATCHER_FORMAT",
    "MATCHER_FORMAT_VERSION",
    "LoadedMatcher",
    "MatcherFileError",
    "load_matcher",
    "save_matcher",
]

MATCHER_FORMAT = "xvmatch-matcher"
MATCHER_FORMAT_VERSION = 1
DEFAULT_MATCHER_PATH = Path(__file__).resolve().parent / "default_matcher.pt"
"""The torch file the shipped default bundle is exported from (``training/
make_default_bundle.py`` writes both)."""

_CROP_CONTEXT = 0.1


class MatcherFileError(ValueError):
    """A matcher file that cannot be used; the message names the file and what is wrong."""


@dataclass
class LoadedMatcher:
    """A matcher file in memory (CPU, eval mode).

    Attributes:
        matcher: the :class:`~xvmatch.models.cross_view_matcher.CrossViewMatcher`.
        feature_config: the geometry feature configuration it was trained with.
        gamma: its non-association cost.
        appearance: the appearance network, or None for a matcher without the ``app`` cue.
        crop_context: relative margin of the appearance crops around each box.
        meta: the notes stored with it.
        path: where it was read from.
    """

    matcher: CrossViewMatcher
    feature_config: FeatureConfig
    gamma: float = 0.5
    appearance: AppearanceNet | None = None
    crop_context: float = _CROP_CONTEXT
    meta: dict = field(default_factory=dict)
    path: str = ""


def save_matcher(
    path: str | os.PathLike,
    matcher: CrossViewMatcher,
    feature_config: FeatureConfig,
    gamma: float = 0.5,
    meta: Mapping[str, Any] | None = None,
    appearance: AppearanceNet | None = None,
    crop_context: float = _CROP_CONTEXT,
) -> Path:
    """Write a matcher file atomically.

    Args:
        path: destination (its folder must exist).
        matcher: the trained matcher.
        feature_config: the feature configuration it was trained with.
        gamma: the non-association cost to use with it, in (0, 1].
        meta: JSON-able notes (training data, seed, scores); never the training data itself.
        appearance: the appearance network giving its ``app`` cue (required when the matcher
            takes ``app``, refused otherwise).
        crop_context: relative margin of the crops the appearance network was trained on.

    Returns:
        The path written.
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise ValueError(f"cannot write {os.fspath(path)!r}: folder {os.fspath(path.parent)!r} "
                         "does not exist")
    meta = dict(meta or {})
    json.dumps(meta)  # must be JSON-able
    if not 0.0 < float(gamma) <= 1.0:
        raise ValueError(f"gamma must be in (0, 1], got {gamma}")
    if ("app" in matcher.cues) != (appearance is not None):
        raise ValueError("an appearance network is needed exactly when the matcher takes the "
                         f"'app' cue (cues {list(matcher.cues)})")
    record = {
        "format": MATCHER_FORMAT,
        "format_version": MATCHER_FORMAT_VERSION,
        "feature_version": FEATURE_VERSION,
        "feature_config": feature_config.to_dict(),
        "geometry_config": dict(matcher.geometry.config),
        "matcher_config": dict(matcher.config),
        "gamma": float(gamma),
        "meta": meta,
        "state_dict": {k: v.detach().cpu().clone() for k, v in matcher.state_dict().items()},
        "appearance": None if appearance is None else {
            **appearance_blob(appearance), "context": float(crop_context)},
    }
    buffer = io.BytesIO()
    torch.save(record, buffer)
    atomic_write_bytes(path, buffer.getvalue())
    return path


def _fail(where: str, what: str) -> MatcherFileError:
    return MatcherFileError(f"{where}: {what}")


def _field(record: Mapping, key: str, kinds: type | tuple[type, ...], where: str):
    """``record[key]``, checked to be one of ``kinds`` (a bool is not a number here)."""
    return typed_field(record, key, kinds, where, error=MatcherFileError,
                       document="matcher file")


def _finite_weights(state: Mapping, where: str, what: str) -> None:
    for name, tensor in state.items():
        if not isinstance(tensor, torch.Tensor):
            raise _fail(where, f"{what} entry {name!r} is not a tensor")
        if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
            raise _fail(where, f"{what} weight {name!r} holds NaN or infinite values; the file "
                        "is corrupt or the training diverged")


def load_matcher(path_or_default: str | os.PathLike = "default") -> LoadedMatcher:
    """Read a matcher file, or the shipped default's with ``"default"``.

    Raises:
        MatcherFileError: missing or unreadable file, another format, a version this code
            cannot read, a field of the wrong type or range, non-finite weights, or weights
            that do not fit the stored configuration (one line naming the file).
    """
    path = DEFAULT_MATCHER_PATH if str(path_or_default) == "default" else Path(path_or_default)
    where = os.fspath(path)
    if not path.is_file():
        raise _fail(where, "no such matcher file")
    try:
        record = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # pickle, zip and weights-only errors all mean "not ours"
        first = str(exc).splitlines()[0] if str(exc) else ""
        raise _fail(where, f"not a matcher file ({type(exc).__name__}: {first})") from None
    if not isinstance(record, dict):
        raise _fail(where, "not a matcher file (expected a dict record)")
    if record.get("format") == "xvmatch-geometry-model":
        raise _fail(where, "a geometry model of an earlier xvmatch (its features depend on the "
                    "image resolution); retrain it with xvmatch fit-geometry")
    if record.get("format") == WEIGHTS_FORMAT:
        raise _fail(where, "an appearance weights file (xvmatch train), not a matcher file; "
                    "pair it with the shipped matcher into a bundle: xvmatch export "
                    f"--appearance {where} --out BUNDLE/, then associate --model BUNDLE/")
    if "pytorch-lightning_version" in record:
        raise _fail(where, "a Lightning checkpoint of xvmatch train, not a matcher file; its "
                    "run folder's appearance_weights.pt makes a bundle: xvmatch export "
                    "--appearance RUN/appearance_weights.pt --out BUNDLE/")
    if record.get("format") != MATCHER_FORMAT:
        raise _fail(where, f"not a matcher file (expected format {MATCHER_FORMAT!r})")
    version = _field(record, "format_version", int, where)
    if version != MATCHER_FORMAT_VERSION:
        raise _fail(where, f"matcher format version {version}, this xvmatch reads "
                    f"{MATCHER_FORMAT_VERSION}")
    features = _field(record, "feature_version", int, where)
    if features != FEATURE_VERSION:
        raise _fail(where, f"matcher trained on feature version {features}, this xvmatch "
                    f"computes {FEATURE_VERSION}; retrain it")
    feature_config = _field(record, "feature_config", dict, where)
    geometry_config = _field(record, "geometry_config", dict, where)
    matcher_config = _field(record, "matcher_config", dict, where)
    gamma = float(_field(record, "gamma", (int, float), where))
    if not (math.isfinite(gamma) and 0.0 < gamma <= 1.0):
        raise _fail(where, f"field 'gamma' must be in (0, 1], got {gamma}")
    meta = _field(record, "meta", dict, where)
    state = _field(record, "state_dict", dict, where)
    _finite_weights(state, where, "state_dict")
    try:
        config = FeatureConfig.from_dict(feature_config)
        geometry = GeometryEncoder(**geometry_config)
        matcher = CrossViewMatcher(geometry, **matcher_config)
        matcher.load_state_dict(state)
    except (TypeError, ValueError, RuntimeError) as exc:
        raise _fail(where, "matcher does not fit its configuration: "
                    f"{str(exc).splitlines()[0]}") from None
    appearance = None
    context = _CROP_CONTEXT
    if "appearance" not in record:
        raise _fail(where, "matcher file lacks the field 'appearance'")
    blob = record["appearance"]
    if blob is not None:
        if not isinstance(blob, dict):
            raise _fail(where, f"field 'appearance' must be a dict or None, got "
                        f"{type(blob).__name__}")
        _finite_weights(_field(blob, "state_dict", dict, where), where, "appearance")
        context = float(_field(blob, "context", (int, float), where))
        if not (math.isfinite(context) and 0.0 <= context <= 1.0):
            raise _fail(where, f"appearance 'context' must be in [0, 1], got {context}")
        try:
            appearance = appearance_from_weights(AppearanceWeights.from_blob(blob, path))
        except (TypeError, ValueError, RuntimeError) as exc:
            raise _fail(where, f"appearance network: {str(exc).splitlines()[0]}") from None
    if ("app" in matcher.cues) != (appearance is not None):
        raise _fail(where, "the appearance network must be present exactly when the matcher "
                    f"takes the 'app' cue (cues {list(matcher.cues)})")
    return LoadedMatcher(matcher.eval(), config, gamma, appearance, context, dict(meta), where)
