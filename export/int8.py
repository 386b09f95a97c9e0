"""Static INT8 quantisation of the appearance graph (onnxruntime's QDQ tools), mixed precision
chosen by a per-node sensitivity sweep, with the accuracy it keeps measured on held-out
synthetic frames.

Static QDQ: onnxruntime's pre-processing (shape inference and graph optimisation), then
``quantize_static`` with per-channel INT8 weights and UINT8 activations (the x86 layout) whose
ranges come from calibration crops. Calibration and measurement use disjoint scenes of one
synthetic dataset (``xvmatch synth``): even scenes calibrate, odd scenes measure.

Quantising every node of the shipped MobileNetV2 branch lost 9.1 Eq. 9 points: one 1x1
expansion convolution (block 2) carries BN-folded weights up to 127, so the rounding of its
input is amplified a hundredfold. No calibration method mends that, so the nodes whose
quantisation hurts most stay FP32, found by measuring, not guessed (:func:`node_sensitivity`,
:func:`choose_fp32_nodes`): each node is quantised alone and the descriptors' error against
FP32 on the calibration crops is its sensitivity; nodes are then kept FP32 in that order, each
only if it lowers the whole network's error by :data:`MIN_GAIN` at least, until the error is
at most ``max_error`` or the FP32 share of the multiply-accumulates would pass
``max_fp32_share``.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from xvmatch.inference.linking.assignment import assign
from xvmatch.inference.matching.bundle import APPEARANCE_INPUT, open_session
from xvmatch.models.matcher_file import LoadedMatcher

__all__ = [
    "CALIBRATION_METHODS",
    "MAX_DESCRIPTOR_ERROR",
    "MAX_FP32_SHARE",
    "MIN_GAIN",
    "QUANTISED_OPS",
    "RECHECK_QUANTILE",
    "MixedPrecision",
    "add_int8",
    "calibration_crops",
    "choose_fp32_nodes",
    "descriptor_error",
    "int8_accuracy",
    "int8_measurements",
    "node_macs",
    "node_sensitivity",
    "quantize_appearance",
    "recheck_tolerance",
]

CALIBRATION_METHODS: tuple[str, ...] = ("minmax", "percentile", "entropy")
"""Calibration methods tried, in order of preference on ties."""

QUANTISED_OPS: tuple[str, ...] = ("Conv", "Gemm", "MatMul", "Add")
"""Node types whose quantisation the sweep measures (the ones that carry the compute)."""

MAX_DESCRIPTOR_ERROR = 2.5e-4
"""Mixed precision stops once the INT8 descriptors' mean ``1 - cos`` against FP32 is this low
(the shipped network: 0.105 fully quantised, 3.2e-4 with 9 nodes FP32; FP32 weights rounded to
FP16, 2e-5, already change 0.3% of the matched pairs with images, docs/deployment.md)."""

MAX_FP32_SHARE = 0.3
"""Most share of the network's multiply-accumulates that may stay FP32 (beyond it INT8 is
hardly faster)."""

MIN_GAIN = 0.05
"""Least relative drop of the descriptor error for a node to be kept FP32: the errors of the
layers partly cancel, so a node's exclusion moves the whole error by a few percent either way,
and below this the FP32 node would buy noise, not accuracy."""


def calibration_crops(
    data: str | os.PathLike,
    crop_size: tuple[int, int],
    context: float,
    scenes: Sequence[str] | None = None,
    max_crops: int = 512,
    seed: int = 0,
) -> np.ndarray:
    """Crops of the labelled people of both views of some scenes of a synthetic dataset.

    Args:
        data: dataset folder (``xvmatch synth``).
        crop_size: ``(width, height)`` of the crops.
        context: relative margin around each box.
        scenes: scene names to use (default: all).
        max_crops: at most this many, drawn with ``seed`` when there are more.
        seed: seed of that draw.

    Returns:
        ``(K, H, W, 3)`` uint8 BGR crops.
    """
    from xvmatch.datasets.synthetic_io import SyntheticDataset
    from xvmatch.formats.crops import box_crops

    dataset = SyntheticDataset(data)
    names = list(scenes) if scenes is not None else dataset.scene_names
    crops = []
    for name in names:
        for pair in dataset.scene(name).pairs:
            for view in (pair.top, pair.ego):
                if len(view.labels):
                    crops.append(box_crops(view.load_image(), view.labels.boxes, crop_size,
                                           context))
    if not crops:
        raise ValueError(f"{os.fspath(data)}: no labelled person to calibrate on")
    out = np.concatenate(crops)
    if out.shape[0] > max_crops:
        keep = np.sort(np.random.default_rng(seed).choice(out.shape[0], max_crops,
                                                          replace=False))
        out = out[keep]
    return out


class _CropReader:
    """onnxruntime's calibration data reader over batches of crops."""

    def __init__(self, crops: np.ndarray, input_name: str, batch: int = 32) -> None:
        # Equal batches: the histogram calibrators stack per-batch outputs (a shorter last
        # batch breaks them), so the remainder of a multiple of ``batch`` is left out.
        usable = crops.shape[0] if crops.shape[0] < batch else crops.shape[0] // batch * batch
        self._batches = [{input_name: crops[k : k + batch]} for k in range(0, usable, batch)]
        self._next = 0

    def get_next(self):
        if self._next >= len(self._batches):
            return None
        self._next += 1
        return self._batches[self._next - 1]

    def rewind(self) -> None:
        self._next = 0


def _preprocess(fp32: str | os.PathLike, out: Path) -> None:
    """onnxruntime's quantisation pre-processing (shape inference, graph optimisation)."""
    from onnxruntime.quantization.shape_inference import quant_pre_process

    quant_pre_process(os.fspath(fp32), os.fspath(out), skip_symbolic_shape=True)


def _quantize(pre: Path, out: Path, crops: np.ndarray, method: str, input_name: str,
              cache: Path, exclude: Sequence[str] = (), only: Sequence[str] | None = None,
              ) -> None:
    """``quantize_static`` of the pre-processed graph ``pre``; the calibration ranges are
    computed once per ``cache`` file and reused (the sweep quantises the graph many times)."""
    from onnxruntime.quantization import (
        CalibrationMethod,
        QuantFormat,
        QuantType,
        quantize_static,
    )

    methods = {"minmax": CalibrationMethod.MinMax, "percentile": CalibrationMethod.Percentile,
               "entropy": CalibrationMethod.Entropy}
    if method not in methods:
        raise ValueError(f"method must be one of {', '.join(methods)}, got {method!r}")
    quantize_static(
        os.fspath(pre), os.fspath(out), _CropReader(crops, input_name),
        quant_format=QuantFormat.QDQ, per_channel=True,
        activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8,
        calibrate_method=methods[method],
        extra_options={"CalibPercentile": 99.99} if method == "percentile" else {},
        nodes_to_exclude=list(exclude), nodes_to_quantize=list(only) if only else None,
        calibration_cache_path=cache,
    )


def quantize_appearance(
    fp32: str | os.PathLike,
    out: str | os.PathLike,
    crops: np.ndarray,
    method: str,
    input_name: str = "crops",
    progress: Callable[[str], None] | None = None,
) -> None:
    """Write the static INT8 (QDQ) version of an appearance graph.

    Args:
        fp32: the FP32 ``appearance.onnx``.
        out: the INT8 file to write.
        crops: calibration crops ``(K, H, W, 3)`` uint8.
        method: one of :data:`CALIBRATION_METHODS`.
        input_name: the graph's input.
        progress: called with a line of text.
    """
    if progress:
        progress(f"quantising the appearance network (calibration {method}, "
                 f"{crops.shape[0]} crops)")
    with tempfile.TemporaryDirectory() as tmp:
        pre = Path(tmp) / "pre.onnx"
        _preprocess(fp32, pre)
        _quantize(pre, Path(out), crops, method, input_name, Path(tmp) / "calibration")


def _descriptors(path: Path, crops: np.ndarray, batch: int = 64) -> np.ndarray:
    """``(K, D)`` descriptors of ``crops`` by the graph at ``path`` (one thread)."""
    session = open_session(path, 1)
    name = session.get_inputs()[0].name
    return np.concatenate([session.run(None, {name: crops[k : k + batch]})[0]
                           for k in range(0, crops.shape[0], batch)])


def descriptor_error(reference: np.ndarray, descriptors: np.ndarray) -> float:
    """Mean ``1 - cos`` between each crop's descriptor and its reference (FP32) descriptor."""
    a = reference / np.maximum(np.linalg.norm(reference, axis=1, keepdims=True), 1e-12)
    b = descriptors / np.maximum(np.linalg.norm(descriptors, axis=1, keepdims=True), 1e-12)
    return float(np.mean(1.0 - np.sum(a * b, axis=1)))


def node_macs(model) -> dict[str, int]:
    """Multiply-accumulates per image of each Conv / Gemm / MatMul node of an ONNX model, from
    its inferred shapes (a Conv whose output shape is unknown is left out)."""
    import onnx

    inferred = onnx.shape_inference.infer_shapes(model, data_prop=True)
    shapes = {v.name: [d.dim_value for d in v.type.tensor_type.shape.dim]
              for v in [*inferred.graph.value_info, *inferred.graph.output,
                        *inferred.graph.input]}
    weights = {t.name: list(t.dims) for t in model.graph.initializer}
    out: dict[str, int] = {}
    for node in model.graph.node:
        w = weights.get(node.input[1]) if len(node.input) > 1 else None
        y = shapes.get(node.output[0])
        if node.op_type == "Conv" and w and y and len(y) == 4:
            out[node.name] = int(np.prod(y[1:]) * np.prod(w[1:]))
        elif node.op_type in ("Gemm", "MatMul") and w:
            out[node.name] = int(np.prod(w))
    return out


def _fp32_group(model, name: str) -> list[str]:
    """``name`` and the quantised node that feeds its first input: onnxruntime puts a Q/DQ pair
    on a quantised Conv's output whatever its consumer, so keeping a node's input FP32 needs
    its producer left unquantised too."""
    producers = {o: n for n in model.graph.node for o in n.output}
    node = next(n for n in model.graph.node if n.name == name)
    src = producers.get(node.input[0]) if node.input else None
    return [name] + ([src.name] if src is not None and src.op_type in QUANTISED_OPS else [])


@dataclass(frozen=True)
class MixedPrecision:
    """The nodes an INT8 appearance network keeps FP32 and what that bought.

    Attributes:
        method: calibration method.
        fp32_nodes: nodes left unquantised, in the order chosen.
        error: descriptors' mean ``1 - cos`` against FP32 with them (calibration crops).
        full_error: the same with every node quantised.
        fp32_share: share of the multiply-accumulates that stay FP32.
        sensitivity: each swept node's error when it alone is quantised.
        by_method: each calibration method's ``full_error``.
    """

    method: str
    fp32_nodes: tuple[str, ...]
    error: float
    full_error: float
    fp32_share: float
    sensitivity: dict[str, float]
    by_method: dict[str, float]


def node_sensitivity(pre: Path, crops: np.ndarray, reference: np.ndarray, method: str,
                     input_name: str, cache: Path, work: Path) -> dict[str, float]:
    """Each :data:`QUANTISED_OPS` node's descriptor error when it alone is quantised."""
    import onnx

    model = onnx.load(os.fspath(pre))
    out = {}
    for node in model.graph.node:
        if node.op_type in QUANTISED_OPS:
            path = work / "one.onnx"
            _quantize(pre, path, crops, method, input_name, cache, only=[node.name])
            out[node.name] = descriptor_error(reference, _descriptors(path, crops))
    return out


def choose_fp32_nodes(
    fp32: str | os.PathLike,
    crops: np.ndarray,
    out: str | os.PathLike,
    input_name: str = "crops",
    max_error: float = MAX_DESCRIPTOR_ERROR,
    max_fp32_share: float = MAX_FP32_SHARE,
    max_steps: int = 16,
    progress: Callable[[str], None] | None = None,
) -> MixedPrecision:
    """Calibration method and FP32 nodes of the INT8 appearance network, by measurement.

    The method is the one whose fully quantised network has the lowest descriptor error; then
    nodes are kept FP32 in order of sensitivity (:func:`node_sensitivity`), each with its input's
    producer (:func:`_fp32_group`), only when that lowers the error by :data:`MIN_GAIN` and
    keeps the FP32 share of the multiply-accumulates at most ``max_fp32_share``, until the
    error is at most ``max_error`` or ``max_steps`` nodes were tried. The chosen INT8 network
    is written to ``out`` (the sweep's own file, not quantised again).
    """
    import onnx

    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        pre = work / "pre.onnx"
        _preprocess(fp32, pre)
        reference = _descriptors(Path(fp32), crops)
        full = {}
        for method in CALIBRATION_METHODS:
            path = work / f"full_{method}.onnx"
            _quantize(pre, path, crops, method, input_name, work / f"cache_{method}")
            full[method] = descriptor_error(reference, _descriptors(path, crops))
        method = min(CALIBRATION_METHODS, key=lambda m: (full[m], CALIBRATION_METHODS.index(m)))
        cache = work / f"cache_{method}"
        best = work / f"full_{method}.onnx"
        if progress:
            progress(f"INT8 sensitivity sweep ({method}): every node quantised alone")
        sensitivity = node_sensitivity(pre, crops, reference, method, input_name, cache, work)
        model = onnx.load(os.fspath(pre))
        macs = node_macs(model)
        total = max(sum(macs.values()), 1)
        chosen: list[str] = []
        error = full[method]
        order = sorted(sensitivity, key=lambda n: (-sensitivity[n], n))
        for name in order[:max_steps]:
            if error <= max_error:
                break
            if name in chosen:
                continue
            trial = chosen + [n for n in _fp32_group(model, name) if n not in chosen]
            if sum(macs.get(n, 0) for n in trial) / total > max_fp32_share:
                continue
            path = work / "trial.onnx"
            _quantize(pre, path, crops, method, input_name, cache, exclude=trial)
            e = descriptor_error(reference, _descriptors(path, crops))
            if progress:
                progress(f"  {name} FP32: descriptor error {e:.2e} (was {error:.2e})")
            if e < (1.0 - MIN_GAIN) * error:
                chosen, error = trial, e
                best = path.replace(work / "best.onnx")
        shutil.copyfile(best, out)
        return MixedPrecision(method, tuple(chosen), error, full[method],
                              sum(macs.get(n, 0) for n in chosen) / total,
                              {n: round(v, 8) for n, v in sensitivity.items()},
                              {m: round(v, 8) for m, v in full.items()})


RECHECK_QUANTILE = 0.9
"""The re-check tolerance is this quantile over frames of the largest change INT8 makes to a
frame's matcher costs. The shipped network, on 200 held-out overview trials with images: the
median re-checked 5.5% of the frames and kept 630 of FP32's 635 pairs, not enough to show 99%
with 95% confidence; 0.9 re-checked 18% and kept 634 (docs/deployment.md#int8)."""


def _scene_costs(folder: Path, data: Path, scenes: Sequence[str], files: dict[str, str]
                 ) -> tuple[list, dict[str, dict[str, list[np.ndarray]]]]:
    """The trials of ``scenes`` (ground-truth boxes and detector noise) and, for each
    appearance file of ``files`` ({label: file name}) and each image setting the matcher takes,
    their ``(M, N)`` matcher costs in the input order."""
    from xvmatch.cues.matcher_inputs import INPUT_SETTINGS, matcher_inputs
    from xvmatch.datasets.pair_trials import TrialConfig, scene_trials
    from xvmatch.datasets.synthetic_io import SyntheticDataset
    from xvmatch.geometry.camera import FrameCameras
    from xvmatch.inference.matching.bundle import Bundle, read_manifest
    from xvmatch.inference.matching.learned_association import LearnedMatcher

    spec = read_manifest(folder)
    matcher_session = open_session(folder / spec.matcher_file, 1)
    dataset = SyntheticDataset(data)
    index = {name: k for k, name in enumerate(dataset.scene_names)}
    settings = ["images"] + (["images+cameras"] if "ray" in spec.cues else [])
    trials: list = []
    costs: dict[str, dict[str, list[np.ndarray]]] = {}
    for label, file in files.items():
        matcher = LearnedMatcher(Bundle(spec, matcher_session, open_session(folder / file, 1)))

        def coster(ti, tb, ei, eb, m=matcher):
            return m.crop_cost(m.crops(ti, tb), m.crops(ei, eb))

        trials = [t for name in scenes
                  for t in scene_trials(dataset.scene(name), index[name], TrialConfig(),
                                        coster=coster)]
        costs[label] = {}
        for setting in settings:
            _, rectified = INPUT_SETTINGS[setting]
            inputs = [matcher_inputs(
                t.top_boxes, t.ego_boxes, t.cameras["ego"].image_size, spec.feature_config,
                spec.cues, app=t.app,
                cameras=FrameCameras(t.cameras["top"], t.cameras["ego"]) if rectified else None)
                for t in trials]
            full = []
            for f, c in zip(inputs, matcher.costs(inputs), strict=True):
                out = np.empty_like(c)
                out[np.ix_(f.features.top_order, f.features.hor_order)] = c
                full.append(out)
            costs[label][setting] = full
    return trials, costs


def recheck_tolerance(fp32: Sequence[np.ndarray], int8: Sequence[np.ndarray],
                      quantile: float = RECHECK_QUANTILE) -> float:
    """The ``quantile`` over frames of the largest ``|INT8 - FP32|`` matcher cost of a frame
    (frames with no pair skipped; 0 without any)."""
    change = [float(np.abs(a - b).max()) for a, b in zip(fp32, int8, strict=True) if a.size]
    return float(np.quantile(change, quantile)) if change else 0.0


def int8_accuracy(folder: Path, manifest: dict, data: Path, scenes: Sequence[str],
                  files: dict[str, str], tolerance: float | None = None
                  ) -> tuple[dict[str, dict], dict[str, dict]]:
    """Geometric-priors Eq. 9 accuracy and CVIDF1 (percent) of the matcher with images (and with
    images and cameras, when it takes camera cues) on ``scenes`` of ``data``, ground-truth boxes
    and detector noise pooled, for each appearance file of ``files`` ({label: file name}, the
    first the reference); and for each other file the share of the reference's matched pairs
    it keeps, per setting (what ``associate --precision`` changes for a user). With a
    ``tolerance``, also the label ``"<second>+recheck"``: the second file's near-tie frames
    re-checked with the first (:func:`~xvmatch.inference.matching.learned_association.
    rechecked_costs`), with the share of frames re-checked."""
    from xvmatch.inference.matching.learned_association import rechecked_costs
    from xvmatch.metrics.cross_view_metrics import count_pair, summarize

    gamma = float(manifest["gamma"])
    trials, costs = _scene_costs(folder, data, scenes, files)
    labels = list(files)
    shares: dict[str, float] = {}  # of the re-checked label: frames re-checked per setting
    recheck = None
    if tolerance is not None:
        recheck = f"{labels[1]}+recheck"
        costs[recheck] = {}
        for setting, reference in costs[labels[0]].items():
            costs[recheck][setting], again = rechecked_costs(
                reference, costs[labels[1]][setting], gamma, tolerance)
            shares[setting] = round(again / max(len(reference), 1), 5)
        labels.append(recheck)
    out: dict[str, dict] = {}
    pairs: dict[str, dict[str, list[set]]] = {}
    for label in labels:
        out[label], pairs[label] = {}, {}
        for setting, per_trial in costs[label].items():
            counts, matched = [], []
            for t, c in zip(trials, per_trial, strict=True):
                assignment = assign(c, gamma)
                matched.append(set(map(tuple, np.asarray(assignment).tolist())))
                counts.append(count_pair(t.gt_top_ids, t.gt_ego_ids, t.det_top_ids,
                                         t.det_ego_ids, assignment, frame=t.frame))
            s = summarize(counts)
            out[label][setting] = {"acc9": round(s.acc9, 3), "cvidf1": round(s.cvidf1, 3),
                                   "trials": len(trials)}
            if label == recheck:
                out[label][setting]["rechecked"] = shares[setting]
            pairs[label][setting] = matched
    reference = labels[0]
    agreement = {}
    for label in labels[1:]:
        agreement[label] = {}
        for setting, ref in pairs[reference].items():
            other = pairs[label][setting]
            total = sum(len(a) for a in ref)
            kept = sum(len(a & b) for a, b in zip(ref, other, strict=True))
            agreement[label][setting] = {"pairs": total, "kept": kept,
                                         "share": round(kept / total, 5) if total else 1.0}
    return out, agreement


def int8_measurements(folder: Path, manifest: dict, data: Path, int8_file: str,
                      progress: Callable[[str], None] | None = None) -> dict:
    """What the manifest records of an INT8 appearance file against the FP32 one, measured on
    a synthetic dataset (even scenes: the re-check tolerance, :func:`recheck_tolerance`; odd
    scenes: :func:`int8_accuracy`): ``{"accuracy", "agreement", "recheck"}``."""
    from xvmatch.datasets.synthetic_io import SyntheticDataset

    names = SyntheticDataset(data).scene_names
    calibrate, measure = names[0::2], names[1::2]
    files = {"fp32": manifest["appearance"]["file"], "int8": int8_file}
    if progress:
        progress(f"measuring how far INT8 moves the matcher's costs on {len(calibrate)} "
                 "calibration scenes")
    _, moved = _scene_costs(folder, data, calibrate, files)
    tolerance = recheck_tolerance(moved["fp32"]["images"], moved["int8"]["images"])
    if progress:
        progress(f"measuring FP32 and INT8 accuracy on {len(measure)} held-out scenes")
    accuracy, agreement = int8_accuracy(folder, manifest, data, measure, files, tolerance)
    return {
        "accuracy": {"measured_on": {"data": os.fspath(data), "scenes": list(measure),
                                     "settings": "ground-truth boxes and detector noise"},
                     "fp32": accuracy["fp32"], "int8": accuracy["int8"]},
        "agreement": agreement["int8"],
        "recheck": {
            "tolerance": round(tolerance, 6),
            "scenes": list(calibrate),
            "rule": f"quantile {RECHECK_QUANTILE:g} over the frames of these scenes (images) "
                    "of the largest change INT8 makes to a frame's matcher costs; associate "
                    "scores a frame again with FP32 when its INT8 assignment is not stable "
                    "within it",
            "accuracy": accuracy["int8+recheck"],
            "agreement": agreement["int8+recheck"]},
    }


def add_int8(folder: Path, manifest: dict, loaded: LoadedMatcher, data: Path,
             progress: Callable[[str], None] | None) -> None:
    """Quantise the appearance graph (calibration method and FP32 nodes by measurement,
    :func:`choose_fp32_nodes`), write it as ``appearance_int8.onnx`` and record everything in
    ``manifest``: the mixed precision, the Eq. 9 accuracy of FP32 and INT8 on held-out scenes,
    and the share of FP32's matched pairs INT8 keeps there."""
    from xvmatch.datasets.synthetic_io import SyntheticDataset

    names = SyntheticDataset(data).scene_names
    calibrate, measure = names[0::2], names[1::2]
    if not measure:
        raise ValueError(f"{os.fspath(data)}: INT8 calibration needs at least two scenes "
                         "(even ones calibrate, odd ones measure the accuracy)")
    app = manifest["appearance"]
    crops = calibration_crops(data, tuple(app["crop_size"]), loaded.crop_context, calibrate)
    final = folder / "appearance_int8.onnx"
    mixed = choose_fp32_nodes(folder / app["file"], crops, final, APPEARANCE_INPUT,
                              progress=progress)
    app["int8"] = {
        "file": final.name,
        "sha256": hashlib.sha256(final.read_bytes()).hexdigest(),
        "format": "QDQ, per-channel INT8 weights, UINT8 activations (onnxruntime "
                  "quantize_static after quant_pre_process); the nodes of "
                  "mixed_precision.fp32_nodes unquantised",
        "calibration": {"method": mixed.method, "methods_tried": list(CALIBRATION_METHODS),
                        "crops": int(crops.shape[0]), "data": os.fspath(data),
                        "scenes": list(calibrate)},
        "mixed_precision": {
            "fp32_nodes": list(mixed.fp32_nodes),
            "fp32_mac_share": round(mixed.fp32_share, 4),
            "descriptor_error": round(mixed.error, 8),
            "descriptor_error_all_int8": round(mixed.full_error, 8),
            "descriptor_error_all_int8_by_method": mixed.by_method,
            "max_descriptor_error": MAX_DESCRIPTOR_ERROR, "max_fp32_share": MAX_FP32_SHARE,
            "error": "mean 1 - cos of the descriptors against FP32 on the calibration crops",
            "sensitivity": mixed.sensitivity},
        **int8_measurements(folder, manifest, data, final.name, progress),
    }
