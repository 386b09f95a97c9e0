"""An appearance network from ``xvmatch train`` paired with a trained matcher, ready to export.

``xvmatch train --config configs/appearance_*.yaml`` writes an appearance weights file
(``RUN/appearance_weights.pt``: the network, its preprocessing and notes), not a matcher: the
deployed matcher also needs the geometry encoder and the cue fusion that turn boxes, cameras and
the appearance costs into one cost per pair. :func:`pair_appearance` takes a matcher file that
uses the appearance cue (the shipped default by default) and puts the trained network in place
of its own, so that ``xvmatch export --appearance RUN/appearance_weights.pt --out BUNDLE/``
writes a bundle ``associate --model BUNDLE/`` runs. The matcher sees the network only through
the appearance cost of a pair (``|a - b| / 2`` of unit descriptors, in [0, 1]), so any
architecture and descriptor size fits; the matcher's weights are left as they were, which is
why the manifest's ``meta.appearance_pairing`` names both sources (its fusion was learned on the
costs of its own network: compare the bundle with ``xvmatch evaluate`` before relying on it).
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import replace
from pathlib import Path

import torch

from xvmatch.models.appearance_net import (
    WEIGHTS_FORMAT,
    AppearanceWeights,
    appearance_from_weights,
)
from xvmatch.models.matcher_file import (
    MATCHER_FORMAT,
    LoadedMatcher,
    MatcherFileError,
    load_matcher,
)

__all__ = ["DEFAULT_CROP_CONTEXT", "pair_appearance"]

DEFAULT_CROP_CONTEXT = 0.1
"""Relative margin of the crops around each box when a weights file does not record its own
(``ImagePairDataModule``'s default, the one every shipped recipe trains with)."""


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _weights_record(path: Path) -> AppearanceWeights:
    """The record of an appearance weights file; a matcher file or a Lightning checkpoint
    given in its place is named as such, with the option it belongs to."""
    where = os.fspath(path)
    if not path.is_file():
        raise ValueError(f"--appearance {where}: no such appearance weights file (xvmatch "
                         "train writes RUN/appearance_weights.pt)")
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:  # not a torch file at all: from_file below says so in one line
        blob = None
    if isinstance(blob, dict) and blob.get("format") == MATCHER_FORMAT:
        raise ValueError(f"--appearance {where}: a matcher file, not an appearance weights "
                         f"file; export it as it is: xvmatch export --model {where} --out "
                         "BUNDLE/")
    if isinstance(blob, dict) and "pytorch-lightning_version" in blob:
        raise ValueError(f"--appearance {where}: a Lightning checkpoint, not an appearance "
                         "weights file; give the appearance_weights.pt that xvmatch train "
                         "wrote in the same run folder")
    if isinstance(blob, dict) and blob.get("format") != WEIGHTS_FORMAT:
        raise ValueError(f"--appearance {where}: not an appearance weights file (format "
                         f"{WEIGHTS_FORMAT!r}; xvmatch train writes RUN/appearance_weights.pt)")
    try:
        return AppearanceWeights.from_file(path)
    except (OSError, ValueError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ValueError(f"--appearance {first}") from None


def pair_appearance(weights: str | os.PathLike, matcher: str | os.PathLike = "default",
                    ) -> LoadedMatcher:
    """The matcher of ``matcher`` with the appearance network of ``weights`` in place of its
    own, in memory (nothing is written; :func:`~xvmatch.export.onnx_export.export_bundle`
    takes the result).

    Args:
        weights: an appearance weights file (``xvmatch train``'s ``appearance_weights.pt``).
        matcher: a matcher file that takes the appearance cue, or ``"default"`` (the shipped
            one, ``models/default_matcher.pt``).

    Returns:
        The loaded matcher, its ``appearance`` the trained network (eval mode), its crop
        context the one the network was trained with (the weights' ``meta["context"]``, else
        :data:`DEFAULT_CROP_CONTEXT`), and ``meta["appearance_pairing"]`` recording both
        files and their sha256.

    Raises:
        ValueError: ``weights`` is missing, a matcher file, a Lightning checkpoint or not an
            appearance weights file; the matcher file is unusable (:class:`MatcherFileError`)
            or takes no appearance cue (one line each, naming the file and what to do).
    """
    path = Path(weights)
    record = _weights_record(path)
    loaded = load_matcher(matcher)
    if "app" not in loaded.matcher.cues:
        raise MatcherFileError(f"--model {loaded.path}: a box-only matcher (cues "
                               f"{list(loaded.matcher.cues) or 'none'}) has no use for an "
                               "appearance network; pair it with one that takes images, e.g. "
                               "--model default")
    try:
        net = appearance_from_weights(record)
    except ValueError as exc:
        raise ValueError(f"--appearance {str(exc).splitlines()[0]}") from None
    context = record.meta.get("context", DEFAULT_CROP_CONTEXT)
    if isinstance(context, bool) or not isinstance(context, int | float) or \
            not 0.0 <= float(context) <= 1.0:
        raise ValueError(f"--appearance {os.fspath(path)}: meta 'context' must be a number in "
                         f"[0, 1], got {context!r}")
    matcher_path = Path(loaded.path)
    pairing = {
        "appearance": {"file": path.name, "sha256": _sha256(path), "arch": record.arch,
                       "meta": {k: v for k, v in record.meta.items()
                                if k in ("train_data", "val_data", "epochs", "best_score",
                                         "monitor", "context")}},
        "matcher": {"file": matcher_path.name, "sha256": _sha256(matcher_path),
                    "appearance_replaced": (loaded.appearance.arch
                                            if loaded.appearance is not None else None)},
        "note": "the matcher's weights are unchanged: its fusion was trained on the costs of "
                "the network it shipped with",
    }
    return replace(loaded, appearance=net.eval(), crop_context=float(context),
                   meta={**loaded.meta, "appearance_pairing": pairing})
