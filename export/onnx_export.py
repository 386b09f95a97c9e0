"""Export a trained matcher file to a deployable bundle: two ONNX graphs and a manifest.

``xvmatch export --model M.pt --out BUNDLE/`` writes::

    BUNDLE/manifest.json      format, versions, preprocessing, gamma, sha256, parity figures
    BUNDLE/matcher.onnx       geometry encoder + cue fusion + dustbin + log-Sinkhorn: cost 1 - P
    BUNDLE/appearance.onnx    the Siamese branch: uint8 BGR crops to unit descriptors, pooled
                              trunk features and pooled stages (only when the matcher takes
                              the appearance cue)

What is inside the graphs and what is not: the graphs hold every learned operation (the
appearance network with its input normalisation; the matcher from padded feature tensors to the
cost matrix, Sinkhorn included). Outside them, in numpy (:mod:`xvmatch.cues.matcher_inputs`,
:mod:`xvmatch.formats.crops`): cropping, the spatial-distribution search that builds the
geometry features, the camera cues, the appearance cost of two descriptors, and the Hungarian
assignment with the non-association cost gamma
(:func:`xvmatch.inference.linking.assignment.assign`).

Every axis that varies is dynamic (frames, crops, people in each view, hypotheses), and empty
sets are masks, never branches. The legacy TorchScript-based exporter is used (opset 17): it
needs no extra package, and the parity gate checks its output. Parity at export: the torch
modules and the ONNX graphs (run by onnxruntime) are compared on held-out synthetic frames in
each input setting (boxes only, with images, with images and cameras) plus edge cases (one
person, an empty view in a padded batch); the export fails, writing nothing, unless every cost
agrees within :data:`~xvmatch.export.parity.PARITY_TOLERANCE` and every frame's Hungarian
assignment is identical (:mod:`xvmatch.export.parity`). The licence notice of a pretrained trunk
comes from :mod:`xvmatch.export.licence_notice`, the optional INT8 network from
:mod:`xvmatch.export.int8`.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
import warnings
from collections.abc import Callable
from pathlib import Path

import torch
from torch import Tensor, nn

from xvmatch.cues.spatial_features import (
    FEATURE_VERSION,
    HOR_FEATURES,
    HYP_FEATURES,
    PAIR_FEATURES,
    TOP_FEATURES,
)
from xvmatch.export.int8 import add_int8
from xvmatch.export.licence_notice import NOTICE, backbone_record, notice_text
from xvmatch.export.parity import (
    PARITY_TOLERANCE,
    appearance_parity,
    compare_matcher,
    parity_frames,
)
from xvmatch.geometry.ray_priors import DEFAULT_BETA, METRIC_MARGIN
from xvmatch.inference.matching.bundle import (
    APPEARANCE_INPUT,
    APPEARANCE_OUTPUTS,
    BUNDLE_FORMAT,
    BUNDLE_FORMAT_VERSION,
    MANIFEST,
    MATCHER_INPUTS,
    MATCHER_OUTPUT,
    OPSET,
    open_session,
)
from xvmatch.models.appearance_net import AppearanceNet
from xvmatch.models.cross_view_matcher import CrossViewMatcher
from xvmatch.models.matcher_file import LoadedMatcher, load_matcher

__all__ = ["ExportError", "check_replaceable", "export_bundle"]

class ExportError(ValueError):
    """The export cannot produce a faithful bundle; the message gives the figures."""


class AppearanceGraph(nn.Module):
    """The appearance network with its preprocessing: ``(B, H, W, 3)`` uint8 BGR crops on the
    [0, 255] scale to ``(B, D)`` unit descriptors and, with ``features``, also the ``(B, C)``
    pooled trunk activations and the ``(B, S)`` unit-scaled pooled stage maps
    (:meth:`~xvmatch.models.appearance_net.AppearanceNet.vectors`; what ``appearance.onnx``
    computes, outputs :data:`~xvmatch.inference.matching.bundle.APPEARANCE_OUTPUTS`)."""

    def __init__(self, net: AppearanceNet, features: bool = False) -> None:
        super().__init__()
        self.net = net.eval()
        self.features = bool(features)

    def forward(self, crops: Tensor) -> Tensor | tuple[Tensor, Tensor, Tensor]:
        """Descriptors (and features and stages) of a batch of crops."""
        if self.features:
            return self.net.vectors(self.net.transform(crops))
        return self.net.embed_crops(crops)


class MatcherGraph(nn.Module):
    """The matcher from padded inputs to the ``(B, M, N)`` cost (what ``matcher.onnx``
    computes)."""

    def __init__(self, matcher: CrossViewMatcher) -> None:
        super().__init__()
        self.matcher = matcher.eval()

    def forward(self, top: Tensor, hor: Tensor, hyp: Tensor, pair: Tensor, top_mask: Tensor,
                hor_mask: Tensor, hyp_mask: Tensor, cues: Tensor, cue_mask: Tensor) -> Tensor:
        """Cost ``1 - P`` of a padded batch (1 on padding)."""
        return self.matcher(top, hor, hyp, pair, top_mask, hor_mask, hyp_mask, cues,
                            cue_mask).cost


_DYNAMIC = {
    "top": {0: "frames", 1: "top_people"},
    "hor": {0: "frames", 1: "hor_people"},
    "hyp": {0: "frames", 1: "hypotheses"},
    "pair": {0: "frames", 1: "hypotheses", 2: "top_people", 3: "hor_people"},
    "top_mask": {0: "frames", 1: "top_people"},
    "hor_mask": {0: "frames", 1: "hor_people"},
    "hyp_mask": {0: "frames", 1: "hypotheses"},
    "cues": {0: "frames", 1: "top_people", 2: "hor_people"},
    "cue_mask": {0: "frames"},
    MATCHER_OUTPUT: {0: "frames", 1: "top_people", 2: "hor_people"},
}


def _example_batch(n_cues: int) -> tuple[Tensor, ...]:
    """A batch of 2 frames with unequal sizes and some padding (so no axis is specialised)."""
    g = torch.Generator().manual_seed(0)
    b, m, n, h = 2, 3, 4, 2
    return (
        torch.randn(b, m, len(TOP_FEATURES), generator=g),
        torch.randn(b, n, len(HOR_FEATURES), generator=g),
        torch.randn(b, h, len(HYP_FEATURES), generator=g),
        torch.randn(b, h, m, n, len(PAIR_FEATURES), generator=g),
        torch.tensor([[True, True, True], [True, True, False]]),
        torch.tensor([[True, True, True, True], [True, False, False, False]]),
        torch.tensor([[True, True], [True, False]]),
        torch.rand(b, m, n, n_cues, generator=g),
        torch.ones(b, n_cues, dtype=torch.bool),
    )


def _onnx_export(module: nn.Module, args: tuple[Tensor, ...], path: Path, names: list[str],
                 outputs: list[str], dynamic: dict) -> None:
    """Export an eval-mode module (the exporter restores the module's own mode afterwards, so
    it must already be eval: a wrapper left in training mode would put BatchNorm back in it)."""
    if module.training:
        raise ValueError("export an eval-mode module")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # tracer warnings about Python values are expected
        torch.onnx.export(module, args, os.fspath(path), dynamo=False, input_names=names,
                          output_names=outputs, dynamic_axes=dynamic, opset_version=OPSET,
                          do_constant_folding=True)


def _set_metadata(path: Path, props: dict[str, str]) -> None:
    import onnx

    model = onnx.load(os.fspath(path))
    del model.metadata_props[:]
    for key, value in props.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.checker.check_model(model)
    onnx.save(model, os.fspath(path))


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _versions() -> dict[str, str]:
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for name in ("xvmatch", "torch", "onnx", "onnxruntime"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = "unknown"
    return out


def _write_graphs(loaded: LoadedMatcher, folder: Path) -> dict:
    """Export the graphs into ``folder``; the manifest's file records."""
    matcher = loaded.matcher.eval()
    names = list(MATCHER_INPUTS)
    records: dict = {}
    path = folder / "matcher.onnx"
    _onnx_export(MatcherGraph(matcher).eval(), _example_batch(matcher.n_cues), path, names,
                 [MATCHER_OUTPUT], {k: v for k, v in _DYNAMIC.items() if k in names or
                                    k == MATCHER_OUTPUT})
    layout = {"top": list(TOP_FEATURES), "hor": list(HOR_FEATURES), "hyp": list(HYP_FEATURES),
              "pair": list(PAIR_FEATURES)}
    _set_metadata(path, {
        "xvmatch.role": "matcher",
        "xvmatch.feature_version": str(FEATURE_VERSION),
        "xvmatch.feature_config": json.dumps(loaded.feature_config.to_dict()),
        "xvmatch.feature_layout": json.dumps(layout),
        "xvmatch.cues": json.dumps(list(matcher.cues)),
        "xvmatch.gamma": repr(loaded.gamma),
        "xvmatch.output": "cost = 1 - P (B, M, N); Hungarian with gamma outside the graph",
    })
    records["matcher"] = {"file": path.name, "inputs": names, "output": MATCHER_OUTPUT}
    net = loaded.appearance
    if net is not None:
        path = folder / "appearance.onnx"
        h, w = net.preprocessing.input_size
        example = torch.randint(0, 256, (2, h, w, 3), dtype=torch.uint8,
                                generator=torch.Generator().manual_seed(0))
        _onnx_export(AppearanceGraph(net, features=True).eval(), (example,), path,
                     [APPEARANCE_INPUT], list(APPEARANCE_OUTPUTS),
                     {APPEARANCE_INPUT: {0: "crops"}, **{o: {0: "crops"} for o in
                                                         APPEARANCE_OUTPUTS}})
        prep = {
            "crop_size": [w, h],
            "input": "uint8 NHWC on the [0, 255] scale",
            "colour_order": "BGR",
            "mean": list(net.preprocessing.mean),
            "std": list(net.preprocessing.std),
            "normalisation": "RGB = BGR reversed; (x / 255 - mean) / std, inside the graph",
            "context": loaded.crop_context,
            "resize": "cv2.INTER_AREA when shrinking, cv2.INTER_LINEAR when enlarging",
        }
        _set_metadata(path, {
            "xvmatch.role": "appearance",
            "xvmatch.preprocessing": json.dumps(prep),
            "xvmatch.output": "descriptors: unit descriptors (B, D), cost of a pair "
                              "|a - b| / 2; features: the trunk's average-pooled activations "
                              "(B, C), what site adaptation fits on; stages: the average-pooled "
                              "activations at the end of each stage of the trunk, each scaled "
                              "to unit length, side by side (B, S), what site adaptation fits "
                              "on when present",
        })
        notice = notice_text(net)
        if notice is not None:
            (folder / NOTICE).write_text(notice)
        records["appearance"] = {"file": path.name, "arch": net.arch,
                                 "embedding_dim": net.embedding_dim,
                                 "features_dim": net.head[0].in_features,
                                 "stages_dim": sum(net.stage_channels), "precision": "fp32",
                                 **prep,
                                 "backbone": backbone_record(net)}
    return records


def _bundle_files(folder: Path) -> set[str] | None:
    """The names of the files an export wrote into ``folder``, from its manifest; None when
    ``folder`` holds no xvmatch bundle manifest."""
    try:
        doc = json.loads((folder / MANIFEST).read_text())
    except (OSError, UnicodeDecodeError, ValueError, RecursionError):  # as json_text sees it
        return None
    if not isinstance(doc, dict) or doc.get("format") != BUNDLE_FORMAT:
        return None
    names = {MANIFEST, NOTICE}
    for key in ("matcher", "appearance"):
        record = doc.get(key)
        if isinstance(record, dict):
            names.add(str(record.get("file")))
            if isinstance(record.get("int8"), dict):
                names.add(str(record["int8"].get("file")))
    return names


def check_replaceable(out: str | os.PathLike) -> None:
    """``out`` may be written by an export: absent, an empty folder, or a bundle an export
    wrote, holding only the files its manifest lists (replacing it deletes nothing else).

    Raises:
        ExportError: a file, or a folder that is not such a bundle (a user's folder that
            happens to hold a ``manifest.json`` included).
    """
    out = Path(out)
    if not out.exists() and not out.is_symlink():
        return
    if out.is_symlink() or not out.is_dir():
        raise ExportError(f"{os.fspath(out)}: exists and is not a bundle folder; choose a new "
                          "folder")
    present = {p.name for p in out.iterdir()}
    if not present:
        return
    known = _bundle_files(out)
    if known is None:
        raise ExportError(f"{os.fspath(out)}: exists and is not a bundle folder (no xvmatch "
                          f"bundle {MANIFEST}); choose a new folder")
    foreign = sorted(present - known)
    if foreign:
        raise ExportError(f"{os.fspath(out)}: exists and is not a bundle folder: it also holds "
                          f"{', '.join(foreign[:3])}{', ...' if len(foreign) > 3 else ''}, "
                          "which xvmatch export did not write; choose a new folder")


def _graph_parity(loaded: LoadedMatcher, folder: Path, records: dict, frames: dict,
                  crops) -> dict:
    """Torch against onnxruntime on the parity frames (per input setting) and, with an
    appearance network, on the parity crops: ``{setting or "appearance": figures}``."""
    parity: dict = {}
    session = open_session(folder / records["matcher"]["file"], 1)
    for setting, items in frames.items():
        parity[setting] = compare_matcher(loaded.matcher, session, items, loaded.gamma)
    if loaded.appearance is not None:
        app_session = open_session(folder / records["appearance"]["file"], 1)
        parity["appearance"] = appearance_parity(loaded.appearance, app_session, crops)
    return parity


def _check_parity(parity: dict) -> None:
    """Raise :class:`ExportError` naming every setting over :data:`PARITY_TOLERANCE` or with
    an assignment that differs, and the appearance network if over it."""
    failed = [
        f"{s}: max |cost diff| {p['max_abs_cost_diff']:.2e}, identical assignments "
        f"{p['assignments_identical']}/{p['frames']}"
        for s, p in parity.items()
        if "frames" in p and (p["max_abs_cost_diff"] > PARITY_TOLERANCE
                              or p["assignments_identical"] != p["frames"])
    ]
    if "appearance" in parity and parity["appearance"]["max_abs_descriptor_diff"] > \
            PARITY_TOLERANCE:
        failed.append(f"appearance: max |descriptor diff| "
                      f"{parity['appearance']['max_abs_descriptor_diff']:.2e}")
    if failed:
        raise ExportError("ONNX parity failed (tolerance "
                          f"{PARITY_TOLERANCE:g}): " + "; ".join(failed))


def _bundle_manifest(loaded: LoadedMatcher, records: dict, parity: dict,
                     source: Path | None) -> dict:
    """The manifest of a bundle of the graphs ``records`` (with their hashes), exported from
    ``loaded`` (its file ``source``, if any), with its parity figures."""
    return {
        "format": BUNDLE_FORMAT,
        "format_version": BUNDLE_FORMAT_VERSION,
        "opset": OPSET,
        "created_by": _versions(),
        "feature_version": FEATURE_VERSION,
        "feature_config": loaded.feature_config.to_dict(),
        "gamma": loaded.gamma,
        "cues": list(loaded.matcher.cues),
        "camera_cues": {"margin": METRIC_MARGIN, "beta": DEFAULT_BETA},
        "matcher": records["matcher"],
        "appearance": records.get("appearance"),
        "parity": {"tolerance": PARITY_TOLERANCE, **parity},
        "source": {"file": source.name if source else None,
                   "sha256": _sha256(source) if source and source.is_file() else None},
        "meta": loaded.meta,
    }


def _write_int8(tmp: Path, manifest: dict, loaded: LoadedMatcher,
                calibration: str | os.PathLike,
                progress: Callable[[str], None] | None) -> None:
    """Add the INT8 appearance network (:func:`~xvmatch.export.int8.add_int8`) to the bundle
    being written in the temporary folder ``tmp`` and rewrite its manifest; unusable
    calibration data, or no appearance network, is an :class:`ExportError`."""
    if loaded.appearance is None:
        raise ExportError("--int8 quantises the appearance network, and this matcher "
                          "has none")
    try:
        add_int8(tmp, manifest, loaded, Path(calibration), progress)
    except ValueError as exc:  # unusable calibration data: this export's error
        raise ExportError(str(exc)) from None
    (tmp / MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n")


def _publish(folder: Path, out: Path) -> None:
    """Move the finished bundle ``folder`` to ``out`` (replacing the bundle there, checked
    again), with the permissions ``mkdir`` would give it."""
    umask = os.umask(0o022)
    os.umask(umask)
    os.chmod(folder, 0o777 & ~umask)  # as mkdir would make it (mkdtemp's is 0700)
    if out.exists():
        check_replaceable(out)  # again: the folder may have changed during the export
        shutil.rmtree(out)
    os.replace(folder, out)


def export_bundle(
    model: str | os.PathLike | LoadedMatcher,
    out: str | os.PathLike,
    *,
    parity_data: str | os.PathLike | None = None,
    int8_calibration: str | os.PathLike | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict:
    """Export a matcher file to a bundle folder, checking parity first (see the module
    docstring); nothing is left at ``out`` when the export fails.

    Args:
        model: a matcher file (``xvmatch fit-geometry`` or the matcher training), ``"default"``,
            or a loaded one.
        out: the bundle folder to write (created; a bundle an export wrote there is
            replaced, anything else refused: :func:`check_replaceable`).
        parity_data: synthetic dataset folder for the parity check (default: render a small
            held-out one).
        int8_calibration: synthetic dataset folder: also write a static INT8 appearance
            network, calibrated on its even scenes, its accuracy measured on the odd ones
            (:mod:`xvmatch.export.int8`); the runtime uses it unless asked for FP32.
        progress: called with a line of text at each stage.

    Returns:
        The manifest written.

    Raises:
        ExportError: parity not reached (the figures are in the message), or ``out`` is a
            file or a non-empty folder that is not a bundle holding only its own files.
        MatcherFileError: an unusable matcher file.
    """
    out = Path(out)
    check_replaceable(out)
    loaded = model if isinstance(model, LoadedMatcher) else load_matcher(model)
    source = Path(loaded.path) if loaded.path else None
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        if progress:
            progress("exporting the ONNX graphs")
        records = _write_graphs(loaded, tmp)
        frames, crops = parity_frames(loaded, parity_data, progress=progress)
        if progress:
            progress("checking parity (torch against onnxruntime)")
        parity = _graph_parity(loaded, tmp, records, frames, crops)
        _check_parity(parity)
        for record in records.values():
            record["sha256"] = _sha256(tmp / record["file"])
        manifest = _bundle_manifest(loaded, records, parity, source)
        (tmp / MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n")
        if int8_calibration is not None:
            _write_int8(tmp, manifest, loaded, int8_calibration, progress)
        _publish(tmp, out)
        return manifest
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
