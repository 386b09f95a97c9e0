"""A deployable matcher bundle: its manifest, checked field by field, and its ONNX sessions.

A bundle is a folder written by ``xvmatch export`` (:mod:`xvmatch.export.onnx_export`)::

    manifest.json      format, versions, feature configuration, gamma, cues, preprocessing,
                       sha256 of every file, the parity figures measured at export
    matcher.onnx       padded geometry features and pair cues -> cost 1 - P
    appearance.onnx    uint8 BGR crops -> unit descriptors (absent for a box-only matcher)
    adaptation.npz     a site bundle's adaptation of the descriptors (``xvmatch adapt``,
                       :mod:`xvmatch.inference.adaptation.site_adaptation`); absent in other bundles

Loading checks the format and its version, every field's type and range, and each file's
sha256 before onnxruntime opens it, and reports any problem in one line naming the file.
Torch-free: numpy and onnxruntime only.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from xvmatch.core.input_files import InputFileError, check_input_file, read_input_text
from xvmatch.core.json_text import json_problem
from xvmatch.core.record_fields import typed_field
from xvmatch.cues.matcher_inputs import CUE_NAMES
from xvmatch.cues.spatial_features import FEATURE_VERSION, FeatureConfig
from xvmatch.inference.adaptation.site_adaptation import (
    ADAPTATION_FORMAT_VERSIONS,
    SiteAdaptation,
    load_adaptation,
)
from xvmatch.inference.matching.frame_check import FrameCheck

__all__ = [
    "APPEARANCE_INPUT",
    "APPEARANCE_OUTPUTS",
    "BUNDLE_FORMAT",
    "BUNDLE_FORMAT_VERSION",
    "DEFAULT_BUNDLE",
    "INT8_MAX_LOSS",
    "INT8_MIN_AGREEMENT",
    "MANIFEST",
    "MATCHER_INPUTS",
    "MATCHER_OUTPUT",
    "OPSET",
    "PRECISIONS",
    "AdaptationRecord",
    "AppearanceSpec",
    "Bundle",
    "BundleError",
    "Manifest",
    "fast_int8_cpu",
    "int8_accuracy_loss",
    "int8_agreement",
    "int8_dot_flags",
    "int8_is_safe",
    "int8_recheck_tolerance",
    "int8_refusal",
    "load_bundle",
    "open_session",
    "read_manifest",
]

MANIFEST = "manifest.json"
BUNDLE_FORMAT = "xvmatch-bundle"
BUNDLE_FORMAT_VERSION = 1
OPSET = 17
"""ONNX opset of the exported graphs."""
MATCHER_INPUTS: tuple[str, ...] = (
    "top", "hor", "hyp", "pair", "top_mask", "hor_mask", "hyp_mask", "cues", "cue_mask",
)
"""Input names of ``matcher.onnx``, in order (a graph may omit the cue inputs it ignores)."""
MATCHER_OUTPUT = "cost"
APPEARANCE_INPUT = "crops"
APPEARANCE_OUTPUTS: tuple[str, ...] = ("descriptors", "features", "stages")
"""Outputs of ``appearance.onnx``: unit descriptors, the trunk's pooled activations, and the
pooled activations of each of its stages, each scaled to unit length (the second only in bundles
exported since site adaptation fits on them, the third since 2026-11-28)."""
DEFAULT_BUNDLE = Path(__file__).resolve().parents[1] / "default_bundle"
"""The shipped default (``training/make_default_bundle.py`` rebuilds it)."""


class BundleError(ValueError):
    """A bundle that cannot be used; the message names the file and what is wrong."""


@dataclass(frozen=True)
class AppearanceSpec:
    """How to feed ``appearance.onnx`` (from the manifest).

    Attributes:
        file: the ONNX file name in the bundle.
        sha256: its checksum.
        crop_size: ``(width, height)`` of the crops.
        context: relative margin cut around each box.
        embedding_dim: descriptor size.
        features_dim: size of the graph's ``features`` output (the trunk's pooled activations),
            or None for a graph with descriptors only (bundles exported before it).
        stages_dim: size of the graph's ``stages`` output (the pooled activations at the end of
            each stage of the trunk, each at unit length, side by side), or None for a graph
            exported before it.
        precision: precision of ``file``, ``"fp32"``.
        int8_file, int8_sha256: the static INT8 network beside it (``xvmatch export --int8``),
            or None.
        int8: what the manifest records of it (calibration, accuracy at export).
        arch: the network's architecture (e.g. ``"small"``, ``"mobilenetv2"``); None in
            bundles written before it was recorded.
        backbone: where the trunk's initial weights came from: ``{"arch", "init"}`` and, for an
            ImageNet initialisation, ``"package"``, ``"version"``, ``"licence"`` of the registry
            package holding them; empty in bundles written before it was recorded.
    """

    file: str
    sha256: str
    crop_size: tuple[int, int]
    context: float
    embedding_dim: int
    precision: str = "fp32"
    int8_file: str | None = None
    int8_sha256: str | None = None
    int8: dict = field(default_factory=dict)
    arch: str | None = None
    backbone: dict = field(default_factory=dict)
    features_dim: int | None = None
    stages_dim: int | None = None

    @property
    def outputs(self) -> tuple[str, ...]:
        """The graph's outputs, in order: a prefix of ``APPEARANCE_OUTPUTS``."""
        return APPEARANCE_OUTPUTS[:1 + (self.features_dim is not None)
                                  + (self.stages_dim is not None)]

    def dim(self, vector: str) -> int | None:
        """The size of the graph's ``vector`` output (one of ``APPEARANCE_OUTPUTS``); None when
        the graph has no such output."""
        return {"descriptors": self.embedding_dim, "features": self.features_dim,
                "stages": self.stages_dim}.get(vector)


@dataclass(frozen=True)
class AdaptationRecord:
    """A site bundle's adaptation (the manifest's optional ``adaptation`` object).

    Attributes:
        file: ``adaptation.npz`` in the bundle.
        sha256: its checksum.
        rank: the rank of its projection (0: standardisation alone).
        record: the whole object (what it was fitted on, its held-out figures, ...).
        vector: what it maps (``"descriptors"`` when the record, of format 1, does not say).
    """

    file: str
    sha256: str
    rank: int
    record: dict = field(default_factory=dict)
    vector: str = "descriptors"


@dataclass(frozen=True)
class Manifest:
    """A bundle's manifest, validated.

    Attributes:
        folder: the bundle folder.
        feature_config: the geometry feature configuration the matcher expects.
        gamma: non-association cost of the Hungarian assignment.
        cues: the pair cues the matcher takes (a subset of ``CUE_NAMES``, in order).
        margin, beta: depth margin and cost of the cheirality cue (Eq. 7).
        matcher_file, matcher_sha256: ``matcher.onnx`` and its checksum.
        appearance: the appearance graph, or None for a box-only matcher.
        parity: the figures measured at export.
        meta: the training notes of the source model.
        raw: the whole JSON document.
        adaptation: a site bundle's adaptation (``xvmatch adapt``), or None.
        frame_check: the per-frame appearance check fitted for this bundle
            (:mod:`xvmatch.inference.matching.frame_check`), or None.
    """

    folder: Path
    feature_config: FeatureConfig
    gamma: float
    cues: tuple[str, ...]
    margin: float
    beta: float
    matcher_file: str
    matcher_sha256: str
    appearance: AppearanceSpec | None
    parity: dict = field(default_factory=dict)
    meta: dict = field(default_factory=dict)
    raw: dict = field(default_factory=dict, repr=False)
    adaptation: AdaptationRecord | None = None
    frame_check: FrameCheck | None = None

    @property
    def uses_images(self) -> bool:
        """The matcher takes the appearance cue (and the bundle has its network)."""
        return self.appearance is not None

    @property
    def uses_cameras(self) -> bool:
        """The matcher takes the camera cues (ray distance, cheirality)."""
        return "ray" in self.cues or "cheir" in self.cues


def _fail(where: Path | str, what: str) -> BundleError:
    return BundleError(f"{os.fspath(where)}: {what}")


def _get(doc: dict, key: str, kinds: type | tuple[type, ...], where: Path, prefix: str = ""):
    """``doc[key]`` checked to be one of ``kinds`` (bools are not numbers)."""
    return typed_field(doc, key, kinds, os.fspath(where), error=BundleError,
                       document="manifest", prefix=prefix)


def _number(doc: dict, key: str, where: Path, low: float, high: float, prefix: str = ""
            ) -> float:
    value = float(_get(doc, key, (int, float), where, prefix))
    if not (math.isfinite(value) and low <= value <= high):
        raise _fail(where, f"manifest field {prefix}{key!r} must be in [{low:g}, {high:g}], "
                    f"got {value!r}")
    return value


def _file_name(doc: dict, where: Path, prefix: str, suffix: str = ".onnx") -> tuple[str, str]:
    name = _get(doc, "file", str, where, prefix)
    if Path(name).name != name or not name.endswith(suffix):
        raise _fail(where, f"manifest field {prefix}file must be an {suffix} file name inside "
                    f"the bundle, got {name!r}")
    sha = _get(doc, "sha256", str, where, prefix)
    if len(sha) != 64 or any(c not in "0123456789abcdef" for c in sha):
        raise _fail(where, f"manifest field {prefix}sha256 must be 64 hex digits, got {sha!r:.70}")
    return name, sha


def _manifest_document(folder: Path) -> tuple[Path, dict]:
    """The manifest's path and its JSON document, checked to be an xvmatch bundle manifest.

    Raises:
        BundleError: no folder or manifest, an unreadable file, malformed JSON or another
            format.
    """
    path = folder / MANIFEST
    if not folder.is_dir():
        raise _fail(folder, "no such bundle folder (xvmatch export writes one)")
    if not path.is_file():
        raise _fail(path, "no manifest: not a bundle folder (xvmatch export writes one)")
    try:
        text = read_input_text(path)
    except InputFileError as exc:  # a FIFO, a device, a NUL byte, a line over a megabyte
        raise BundleError(str(exc)) from None
    except OSError as exc:
        raise _fail(path, f"not a readable JSON manifest ({exc})") from None
    try:
        doc = json.loads(text)
    except (ValueError, RecursionError) as exc:  # syntax, nesting too deep, huge numbers
        raise _fail(path, f"not a readable JSON manifest ({json_problem(exc)})") from None
    if not isinstance(doc, dict) or doc.get("format") != BUNDLE_FORMAT:
        raise _fail(path, f"not an xvmatch bundle manifest (format {BUNDLE_FORMAT!r} expected)")
    return path, doc


def _check_versions(doc: dict, path: Path) -> None:
    """Refuse another bundle format version or feature version than this xvmatch's."""
    version = _get(doc, "format_version", int, path)
    if version != BUNDLE_FORMAT_VERSION:
        raise _fail(path, f"bundle format version {version}, this xvmatch reads "
                    f"{BUNDLE_FORMAT_VERSION}; export the model again with this xvmatch")
    features = _get(doc, "feature_version", int, path)
    if features != FEATURE_VERSION:
        raise _fail(path, f"bundle built for feature version {features}, this xvmatch computes "
                    f"{FEATURE_VERSION}; retrain and export the model again")


def _appearance_spec(app: dict, path: Path) -> AppearanceSpec:
    """The manifest's ``appearance`` record, every field checked."""
    name, sha = _file_name(app, path, "appearance.")
    size = _get(app, "crop_size", list, path, "appearance.")
    if len(size) != 2 or not all(isinstance(v, int) and not isinstance(v, bool)
                                 and 8 <= v <= 1024 for v in size):
        raise _fail(path, "manifest field 'appearance.crop_size' must be [width, height] "
                    f"in 8-1024 pixels, got {size!r}")
    dim = _get(app, "embedding_dim", int, path, "appearance.")
    if not 1 <= dim <= 65536:
        raise _fail(path, f"manifest field 'appearance.embedding_dim' must be in 1-65536, "
                    f"got {dim}")
    if _get(app, "colour_order", str, path, "appearance.") != "BGR":
        raise _fail(path, "manifest field 'appearance.colour_order' must be 'BGR'")
    precision = _get(app, "precision", str, path, "appearance.")
    if precision != "fp32":
        raise _fail(path, f"manifest field 'appearance.precision' must be fp32, got "
                    f"{precision!r}")
    int8, int8_file, int8_sha = _int8_record(app, path)
    arch = app.get("arch")
    if arch is not None and not isinstance(arch, str):
        raise _fail(path, "manifest field 'appearance.arch' must be a string or absent")
    backbone = app.get("backbone") or {}
    if not isinstance(backbone, dict) or not all(
            isinstance(v, str) for k, v in backbone.items()
            if k in ("arch", "init", "package", "version", "licence")):
        raise _fail(path, "manifest field 'appearance.backbone' must be an object of "
                    "strings (arch, init, package, version, licence) or absent")
    features, stages = (_output_dim(app, key, path) for key in ("features_dim",
                                                                 "stages_dim"))
    if stages is not None and features is None:
        raise _fail(path, "manifest field 'appearance.stages_dim' needs "
                    "'appearance.features_dim' (the graph's outputs come in that order)")
    return AppearanceSpec(name, sha, (size[0], size[1]),
                          _number(app, "context", path, 0.0, 1.0, "appearance."), dim,
                          precision, int8_file, int8_sha, dict(int8 or {}), arch,
                          dict(backbone), features, stages)


def _int8_record(app: dict, path: Path) -> tuple[dict | None, str | None, str | None]:
    """The appearance record's optional ``int8`` object, with its file name and hash (None
    when absent)."""
    int8 = app.get("int8")
    int8_file = int8_sha = None
    if int8 is not None:
        if not isinstance(int8, dict):
            raise _fail(path, "manifest field 'appearance.int8' must be an object or absent")
        int8_file, int8_sha = _file_name(int8, path, "appearance.int8.")
    return int8, int8_file, int8_sha


def read_manifest(folder: str | os.PathLike) -> Manifest:
    """Read and validate ``folder/manifest.json`` (every field's presence, type and range).

    Raises:
        BundleError: no folder or manifest, malformed JSON, another format or version, a field
            missing or out of range (the message names the field).
    """
    folder = Path(folder)
    path, doc = _manifest_document(folder)
    _check_versions(doc, path)
    try:
        config = FeatureConfig.from_dict(_get(doc, "feature_config", dict, path))
    except (TypeError, ValueError) as exc:
        raise _fail(path, f"manifest field 'feature_config': {exc}") from None
    gamma = _number(doc, "gamma", path, 1e-9, 1.0)
    cues = _get(doc, "cues", list, path)
    if not all(isinstance(c, str) for c in cues) or list(cues) != [c for c in CUE_NAMES
                                                                  if c in cues]:
        raise _fail(path, f"manifest field 'cues' must list a subset of {list(CUE_NAMES)} in "
                    f"that order, got {cues!r}")
    camera = _get(doc, "camera_cues", dict, path)
    margin = _number(camera, "margin", path, 0.0, 100.0, "camera_cues.")
    beta = _number(camera, "beta", path, 1.0, 1e12, "camera_cues.")
    matcher = _get(doc, "matcher", dict, path)
    matcher_file, matcher_sha = _file_name(matcher, path, "matcher.")
    app = _get(doc, "appearance", (dict, type(None)), path)
    spec = None if app is None else _appearance_spec(app, path)
    if ("app" in cues) != (spec is not None):
        raise _fail(path, "the appearance graph must be present exactly when 'app' is among "
                    f"the cues (cues {cues})")
    parity = _get(doc, "parity", dict, path)
    meta = _get(doc, "meta", dict, path)
    return Manifest(folder, config, gamma, tuple(cues), margin, beta, matcher_file, matcher_sha,
                    spec, parity, meta, doc, _adaptation_record(doc, path, spec),
                    _frame_check(doc, path, spec))


def _output_dim(app: dict, key: str, path: Path) -> int | None:
    """The optional size of an appearance output (``appearance.KEY``), checked."""
    value = app.get(key)
    if value is not None and (not isinstance(value, int) or isinstance(value, bool)
                              or not 1 <= value <= 65536):
        raise _fail(path, f"manifest field 'appearance.{key}' must be in 1-65536 or absent, "
                    f"got {value!r}")
    return value


def _frame_check(doc: dict, path: Path, spec: AppearanceSpec | None) -> FrameCheck | None:
    """The optional ``frame_check`` object, checked field by field."""
    if doc.get("frame_check") is None:
        return None
    if spec is None:
        raise _fail(path, "manifest field 'frame_check' needs an appearance network")
    try:
        return FrameCheck.from_record(doc["frame_check"])
    except ValueError as exc:
        raise _fail(path, f"manifest field {exc}") from None


def _adaptation_record(doc: dict, path: Path, spec: AppearanceSpec | None
                       ) -> AdaptationRecord | None:
    """The optional ``adaptation`` object of a site bundle's manifest, checked field by field."""
    adapt = _get(doc, "adaptation", (dict, type(None)), path) if "adaptation" in doc else None
    if adapt is None:
        return None
    if spec is None:
        raise _fail(path, "manifest field 'adaptation' needs an appearance network (this "
                    "bundle has none)")
    name, sha = _file_name(adapt, path, "adaptation.", ".npz")
    version = _get(adapt, "format_version", int, path, "adaptation.")
    if version not in ADAPTATION_FORMAT_VERSIONS:
        raise _fail(path, f"adaptation format version {version}, this xvmatch reads "
                    f"{', '.join(map(str, ADAPTATION_FORMAT_VERSIONS))}; run xvmatch adapt "
                    "again")
    vector = adapt.get("vector", "descriptors")
    dim = spec.dim(vector) if isinstance(vector, str) else None
    if dim is None:
        raise _fail(path, f"manifest field 'adaptation.vector' must name an output of the "
                    f"appearance network ({', '.join(spec.outputs)}), got {vector!r}")
    rank = _get(adapt, "rank", int, path, "adaptation.")
    if not 0 <= rank <= dim:
        raise _fail(path, f"manifest field 'adaptation.rank' must be in 0-{dim}, got {rank}")
    for key in ("fitted_on", "heldout"):
        _get(adapt, key, dict, path, "adaptation.")
    return AdaptationRecord(name, sha, rank, dict(adapt), vector)


def _checked_file(folder: Path, name: str, sha: str) -> Path:
    path = folder / name
    if not path.is_file():
        raise _fail(path, "missing from the bundle")
    check_input_file(path)  # a regular file within the input bound, never a FIFO
    with open(path, "rb") as handle:  # hashed in chunks: never the whole file in memory
        digest = hashlib.file_digest(handle, "sha256").hexdigest()
    if digest != sha:
        raise _fail(path, f"sha256 {digest[:12]}... does not match the manifest's "
                    f"{sha[:12]}...; the file was changed or corrupted: export the bundle again")
    return path


def open_session(path: Path, threads: int):
    """An onnxruntime CPU session of ``path`` with ``threads`` intra-op threads, sequential;
    a file onnxruntime cannot load is a one-line :class:`BundleError`."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = int(threads)
    options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.log_severity_level = 3
    try:
        return ort.InferenceSession(os.fspath(path), options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own exception types
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise _fail(path, f"onnxruntime cannot load it ({first[:200]})") from None


@dataclass
class Bundle:
    """A loaded bundle: its manifest and onnxruntime sessions (CPU).

    Attributes:
        manifest: the validated manifest.
        matcher: the session of ``matcher.onnx``.
        appearance: the session of the appearance network, or None.
        threads: onnxruntime intra-op threads of each session.
        precision: the appearance network in use, ``"fp32"`` or ``"int8"`` (None without one).
        adaptation: a site bundle's adaptation of the descriptors, or None.
        recheck: with INT8 opened for a caller that re-checks, the cost tolerance within which
            a frame's assignment must be stable to keep its INT8 costs
            (:func:`int8_recheck_tolerance`); None otherwise.
        reference: the FP32 appearance session the re-checked frames run (with ``recheck``).
    """

    manifest: Manifest
    matcher: Any
    appearance: Any = None
    threads: int = 1
    precision: str | None = None
    adaptation: SiteAdaptation | None = None
    recheck: float | None = None
    reference: Any = None

    @property
    def name(self) -> str:
        """The bundle folder, for messages."""
        return os.fspath(self.manifest.folder)

    def embed(self, crops: np.ndarray, vector: str = "descriptors",
              reference: bool = False) -> np.ndarray:
        """``(K, D)`` float32 unit descriptors of ``(K, H, W, 3)`` uint8 BGR crops, in one
        batch (``K`` may be 0); with ``vector="features"``, the ``(K, C)`` pooled trunk
        activations instead, scaled to unit length (onnxruntime then skips the head); with
        ``"stages"``, the ``(K, S)`` pooled stages, scaled to unit length. With
        ``reference``, by the FP32 network that re-checks INT8 frames."""
        return self.embed_vectors(crops, (vector,), reference)[0]

    def embed_vectors(self, crops: np.ndarray, vectors: Sequence[str],
                      reference: bool = False) -> list[np.ndarray]:
        """:meth:`embed` of each of ``APPEARANCE_OUTPUTS`` in ``vectors``, from one
        run of the network."""
        spec = self.manifest.appearance
        if self.appearance is None or spec is None:
            raise BundleError(f"{self.name}: this bundle has no appearance network")
        session = self.appearance
        if reference:
            if self.reference is None:
                raise BundleError(f"{self.name}: opened without an FP32 network to re-check "
                                  "with")
            session = self.reference
        dims = [spec.dim(v) for v in vectors]
        for vector, dim in zip(vectors, dims, strict=True):
            if dim is None:
                raise BundleError(f"{self.name}: the appearance network has no {vector!r} "
                                  f"output (it has {', '.join(spec.outputs)}); export it again")
        if crops.shape[0] == 0:
            return [np.zeros((0, dim), np.float32) for dim in dims]
        import onnxruntime as ort

        # only the nodes the outputs asked for: descriptors skip the stages' pooling, features
        # and stages skip the head (the outputs are the same either way)
        only = ort.RunOptions()
        only.only_execute_path_to_fetches = True
        outs = session.run(list(vectors), {APPEARANCE_INPUT: crops}, only)
        # features and stages at unit length: a crop's overall activation says more about its
        # exposure than about the person
        return [out if vector == "descriptors" else
                out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-12)
                for vector, out in zip(vectors, outs, strict=True)]

    def costs(self, batch: dict[str, np.ndarray]) -> np.ndarray:
        """``(B, M, N)`` costs of a padded batch
        (:func:`~xvmatch.cues.matcher_inputs.collate_inputs`)."""
        wanted = {i.name for i in self.matcher.get_inputs()}
        return self.matcher.run([MATCHER_OUTPUT],
                                {k: batch[k] for k in MATCHER_INPUTS if k in wanted})[0]


PRECISIONS: tuple[str, ...] = ("fp32", "int8")
"""Precisions of the appearance network a bundle can run."""

_INT8_DOT_FLAGS = ("avx512_vnni", "avx_vnni", "amx_int8", "asimddp")
"""CPU flags (``/proc/cpuinfo``) of 8-bit dot-product instructions: x86 VNNI and AMX, Arm's
dot product. Without them onnxruntime's INT8 convolutions are no faster than its FP32 ones."""


def int8_dot_flags(cpuinfo: str | None = None) -> list[str]:
    """This CPU's 8-bit dot-product flags (read from ``/proc/cpuinfo``; none where that cannot
    be read). ``cpuinfo``: the file's text, for tests."""
    if cpuinfo is None:
        try:
            with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as handle:
                cpuinfo = handle.read()
        except OSError:
            return []
    flags = set()
    for line in cpuinfo.splitlines():
        key, _, value = line.partition(":")
        if key.strip() in ("flags", "Features"):
            flags.update(value.split())
    return [f for f in _INT8_DOT_FLAGS if f in flags]


def fast_int8_cpu(cpuinfo: str | None = None) -> bool:
    """Whether this CPU has 8-bit dot-product instructions (:func:`int8_dot_flags`)."""
    return bool(int8_dot_flags(cpuinfo))


INT8_MAX_LOSS = 1.0
"""Most Eq. 9 points the INT8 appearance network may lose against FP32 (matcher with images, the
held-out scenes measured at export) for the runtime to pick it on its own."""


def int8_accuracy_loss(int8: dict) -> float | None:
    """FP32 minus INT8 Eq. 9 accuracy with images, as the manifest's ``appearance.int8`` records
    it at export; None when it records no such figures."""
    try:
        acc = int8["accuracy"]
        return float(acc["fp32"]["images"]["acc9"]) - float(acc["int8"]["images"]["acc9"])
    except (KeyError, TypeError, ValueError):
        return None


INT8_MIN_AGREEMENT = 0.99
"""Least share of FP32's matched pairs the INT8 network must keep, in every setting measured at
export, for the runtime to pick it on its own: choosing INT8 by CPU must not change a user's
matches beyond that. The share must clear it with 95% confidence (:func:`int8_agreement`), not
by the luck of a few hundred pairs (an export measured 213 of 215 pairs, 99.1%, for an INT8
network that kept 98.7% of 716 on the deployed benchmark)."""


def int8_recheck_tolerance(int8: dict) -> float | None:
    """The manifest's ``appearance.int8.recheck.tolerance``: how far INT8 moved the matcher's
    costs at export (a high quantile over frames of a frame's largest change, the export's
    ``RECHECK_QUANTILE``). A frame whose INT8 assignment is not stable within it
    (:func:`~xvmatch.inference.linking.assignment.assignment_is_stable`) is run again with FP32;
    None when the manifest records none (or an unusable one)."""
    try:
        tolerance = float(int8["recheck"]["tolerance"])
    except (KeyError, TypeError, ValueError):
        return None
    return tolerance if math.isfinite(tolerance) and 0.0 <= tolerance <= 1.0 else None


def _agreement_counts(int8: dict, recheck: bool = False) -> dict[str, tuple[int, int]] | None:
    """``{setting: (kept, pairs)}`` of the manifest's ``appearance.int8.agreement`` (with
    ``recheck``, of ``appearance.int8.recheck.agreement`` when it records a tolerance); None
    when it records none or a count is impossible."""
    try:
        record = int8["agreement"]
        if recheck and int8_recheck_tolerance(int8) is not None:
            record = int8["recheck"]["agreement"]
        counts = {str(s): (int(v["kept"]), int(v["pairs"])) for s, v in record.items()}
    except (KeyError, TypeError, ValueError, AttributeError):
        return None
    if not counts or any(n <= 0 or not 0 <= kept <= n for kept, n in counts.values()):
        return None
    return counts


def _wilson_lower(kept: int, n: int, z: float) -> float:
    """One-sided Wilson score lower bound of the share ``kept / n``."""
    p = kept / n
    centre = p + z * z / (2 * n)
    spread = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return (centre - spread) / (1 + z * z / n)


def int8_agreement(int8: dict, z: float = 1.645, recheck: bool = False) -> float | None:
    """The smallest one-sided lower confidence bound (Wilson score, ``z`` 1.645: 95%) of the
    share of FP32's matched pairs INT8 kept (with ``recheck``: INT8 with its near-tie frames
    re-checked in FP32), over the settings the manifest records; None when it records none."""
    counts = _agreement_counts(int8, recheck)
    if counts is None:
        return None
    return min(_wilson_lower(kept, n, z) for kept, n in counts.values())


def int8_refusal(int8: dict, z: float = 1.645, recheck: bool = False) -> str | None:
    """Why the runtime will not pick the INT8 network on its own (a clause for a message), or
    None when it kept the FP32 accuracy at export (within :data:`INT8_MAX_LOSS`) and FP32's
    matches (at least :data:`INT8_MIN_AGREEMENT` of the pairs, with confidence; with
    ``recheck``, the pairs INT8 kept with its near-tie frames re-checked in FP32, for a caller
    that re-checks them); unknown counts as not kept."""
    loss = int8_accuracy_loss(int8)
    if loss is None:
        return "the manifest records no INT8 accuracy"
    if loss > INT8_MAX_LOSS:
        return (f"it lost {loss:.1f} Eq. 9 points against FP32 at export (at most "
                f"{INT8_MAX_LOSS:g})")
    counts = _agreement_counts(int8, recheck)
    if counts is None:
        return "the manifest records no agreement with FP32's matched pairs"
    setting, (kept, n) = min(counts.items(), key=lambda c: _wilson_lower(*c[1], z))
    if _wilson_lower(kept, n, z) >= INT8_MIN_AGREEMENT:
        return None
    share = f"{100 * INT8_MIN_AGREEMENT:g}%"
    if kept == n:  # all kept: n / (n + z^2) is the bound, so this many pairs are needed
        needed = math.ceil(INT8_MIN_AGREEMENT * z * z / (1 - INT8_MIN_AGREEMENT))
        return (f"it kept all {n} of FP32's matched pairs ({setting}), too few to show "
                f"{share} with 95% confidence (at least {needed} are needed: calibrate on a "
                "dataset with more scenes)")
    return (f"it kept {kept} of FP32's {n} matched pairs ({setting}, {100 * kept / n:.1f}%), "
            f"not shown to be {share} or more with 95% confidence")


def int8_is_safe(int8: dict, recheck: bool = False) -> bool:
    """Whether the runtime may pick the INT8 network on its own (:func:`int8_refusal`)."""
    return int8_refusal(int8, recheck=recheck) is None


def load_bundle(path_or_default: str | os.PathLike = "default", threads: int = 1,
                precision: str | None = None, recheck: bool = False) -> Bundle:
    """Open a bundle folder, or the shipped default with ``"default"``.

    Args:
        path_or_default: the bundle folder or ``"default"``.
        threads: onnxruntime intra-op threads per session (>= 1).
        precision: the appearance network to run: ``"int8"`` (needs one), ``"fp32"``, or None:
            the INT8 one when the bundle has it, the CPU has 8-bit dot-product instructions
            (:func:`fast_int8_cpu`; measured on an AVX2-only CPU, INT8 was 0.76x the speed of
            FP32 for the compact network) and it kept the FP32 accuracy and matches at export
            (:func:`int8_is_safe`) and the bundle is not a site bundle (``adapt``), else FP32.
        recheck: the caller re-checks INT8's near-tie frames in FP32 (``associate``): INT8 is
            then judged by the agreement measured that way, and the bundle carries the
            tolerance and the FP32 session (:attr:`Bundle.recheck`, :attr:`Bundle.reference`)
            when the manifest records a tolerance.

    Raises:
        BundleError: anything wrong with the manifest or a file (one line naming the file).
    """
    if int(threads) < 1:
        raise ValueError(f"threads must be >= 1, got {threads}")
    if precision is not None and precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    folder = DEFAULT_BUNDLE if str(path_or_default) == "default" else Path(path_or_default)
    manifest = read_manifest(folder)
    matcher_path = _checked_file(folder, manifest.matcher_file, manifest.matcher_sha256)
    matcher = open_session(matcher_path, threads)
    names = [i.name for i in matcher.get_inputs()]
    missing = [n for n in MATCHER_INPUTS[:7] if n not in names]
    if missing or [i.name for i in matcher.get_outputs()][:1] != [MATCHER_OUTPUT]:
        raise _fail(matcher_path, f"not a matcher graph (inputs {names}, expected "
                    f"{list(MATCHER_INPUTS)})")
    appearance = reference = tolerance = None
    used = None
    if precision is not None and manifest.appearance is None:
        raise _fail(folder, f"precision {precision!r} chooses the appearance network, and this "
                    "bundle has none (a box-only bundle)")
    if manifest.appearance is not None:
        spec = manifest.appearance
        # A site bundle's adaptation was fitted on FP32 vectors, and the agreement measured
        # without it: INT8 there only when asked for.
        auto = (precision is None and manifest.adaptation is None
                and int8_is_safe(spec.int8, recheck) and fast_int8_cpu())
        used = "int8" if spec.int8_file is not None and (precision == "int8" or auto) else "fp32"
        if precision == "int8" and spec.int8_file is None:
            raise _fail(folder, "this bundle has no INT8 appearance network (export it with "
                        "xvmatch export --int8 --calibration DATA)")
        if used == "int8":
            app_path = _checked_file(folder, spec.int8_file, spec.int8_sha256)
        else:
            app_path = _checked_file(folder, spec.file, spec.sha256)
        appearance = _appearance_session(app_path, spec, threads)
        tolerance = int8_recheck_tolerance(spec.int8) if recheck and used == "int8" else None
        if tolerance is not None:
            reference = _appearance_session(_checked_file(folder, spec.file, spec.sha256), spec,
                                            threads)
    adaptation = None
    record = manifest.adaptation
    if record is not None and manifest.appearance is not None:
        adapt_path = _checked_file(folder, record.file, record.sha256)
        try:
            adaptation = load_adaptation(adapt_path, manifest.appearance.dim)
        except ValueError as exc:
            raise _fail(adapt_path, str(exc)) from None
        if adaptation.vector != record.vector:
            raise _fail(adapt_path, f"it maps the {adaptation.vector} but the manifest says "
                        f"{record.vector}; run xvmatch adapt again")
        if adaptation.rank != record.rank:
            raise _fail(adapt_path, f"rank {adaptation.rank} but the manifest says "
                        f"{record.rank}; run xvmatch adapt again")
    return Bundle(manifest, matcher, appearance, int(threads), used, adaptation, tolerance,
                  reference)


def _appearance_session(path: Path, spec: AppearanceSpec, threads: int):
    """An onnxruntime session of an appearance graph, checked against the manifest."""
    session = open_session(path, threads)
    inputs = session.get_inputs()
    if [i.name for i in inputs] != [APPEARANCE_INPUT]:
        raise _fail(path, f"not an appearance graph (inputs {[i.name for i in inputs]})")
    outputs = [o.name for o in session.get_outputs()]
    if outputs[:len(spec.outputs)] != list(spec.outputs):
        raise _fail(path, f"the graph's outputs are {outputs}, the manifest expects "
                    f"{list(spec.outputs)}")
    return session
