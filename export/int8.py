"""Static INT8 quantisation of the appearance graph (onnxruntime's QDQ tools), with the accuracy
it keeps measured on held-out synthetic frames.

Static QDQ: onnxruntime's pre-processing (shape inference and graph optimisation), then
``quantize_static`` with per-channel INT8 weights and UINT8 activations (the x86 layout) whose
ranges come from calibration crops. Calibration and measurement use disjoint scenes of one
synthetic dataset (``xvmatch synth``): even scenes calibrate, odd scenes measure. Several
calibration methods are tried; the one whose INT8 network keeps the best geometric-priors Eq. 9
accuracy of the matcher with images on the measurement frames is kept (ties: the first in
:data:`CALIBRATION_METHODS`), and every method's figures are recorded.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from xvmatch.inference.assignment import assign
from xvmatch.inference.bundle import APPEARANCE_INPUT, open_session
from xvmatch.models.matcher_file import LoadedMatcher

__all__ = ["CALIBRATION_METHODS", "add_int8", "calibration_crops", "int8_accuracy",
           "quantize_appearance"]

CALIBRATION_METHODS: tuple[str, ...] = ("minmax", "percentile", "entropy")
"""Calibration methods tried, in order of preference on ties."""


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
    from xvmatch.datasets.crops import box_crops
    from xvmatch.datasets.synthetic_io import SyntheticDataset

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
    from onnxruntime.quantization import (
        CalibrationMethod,
        QuantFormat,
        QuantType,
        quantize_static,
    )
    from onnxruntime.quantization.shape_inference import quant_pre_process

    methods = {"minmax": CalibrationMethod.MinMax, "percentile": CalibrationMethod.Percentile,
                "entropy": CalibrationMethod.Entropy}
    if method not in methods:
        raise ValueError(f"method must be one of {', '.join(methods)}, got {method!r}")
    if progress:
        progress(f"quantising the appearance network (calibration {method}, "
                 f"{crops.shape[0]} crops)")
    with tempfile.TemporaryDirectory() as tmp:
        pre = Path(tmp) / "pre.onnx"
        quant_pre_process(os.fspath(fp32), os.fspath(pre), skip_symbolic_shape=True)
        extra = {"CalibPercentile": 99.99} if method == "percentile" else {}
        quantize_static(
            os.fspath(pre), os.fspath(out), _CropReader(crops, input_name),
            quant_format=QuantFormat.QDQ, per_channel=True,
            activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8,
            calibrate_method=methods[method], extra_options=extra,
            calibration_cache_path=Path(tmp) / "calibration",
        )


def int8_accuracy(folder: Path, manifest: dict, data: Path, scenes: Sequence[str],
                   files: dict[str, str]) -> dict[str, dict]:
    """Geometric-priors Eq. 9 accuracy and CVIDF1 (percent) of the matcher with images (and with
    images and cameras, when it takes camera cues) on ``scenes`` of ``data``, ground-truth boxes
    and detector noise pooled, for each appearance file of ``files`` ({label: file name})."""
    from xvmatch.datasets.pair_trials import TrialConfig, scene_trials
    from xvmatch.datasets.synthetic_io import SyntheticDataset
    from xvmatch.geometry.matcher_inputs import (
        INPUT_SETTINGS,
        FrameCameras,
        appearance_cost,
        matcher_inputs,
    )
    from xvmatch.inference.bundle import Bundle, read_manifest
    from xvmatch.inference.cross_view_metrics import count_pair, summarize
    from xvmatch.inference.learned_association import LearnedMatcher

    spec = read_manifest(folder)
    matcher_session = open_session(folder / manifest["matcher"]["file"], 1)
    dataset = SyntheticDataset(data)
    index = {name: k for k, name in enumerate(dataset.scene_names)}
    settings = ["images"] + (["images+cameras"] if "ray" in spec.cues else [])
    out: dict[str, dict] = {}
    for label, file in files.items():
        matcher = LearnedMatcher(Bundle(spec, matcher_session, open_session(folder / file, 1)))

        def coster(ti, tb, ei, eb, m=matcher):
            return appearance_cost(m.descriptors(ti, tb), m.descriptors(ei, eb))

        trials = [t for name in scenes
                  for t in scene_trials(dataset.scene(name), index[name], TrialConfig(),
                                        coster=coster)]
        record = {}
        for setting in settings:
            _, rectified = INPUT_SETTINGS[setting]
            inputs = [matcher_inputs(
                t.top_boxes, t.ego_boxes, t.cameras["ego"].image_size, spec.feature_config,
                spec.cues, app=t.app,
                cameras=FrameCameras(t.cameras["top"], t.cameras["ego"]) if rectified else None)
                for t in trials]
            counts = []
            for t, f, c in zip(trials, inputs, matcher.costs(inputs), strict=True):
                full = np.empty_like(c)
                full[np.ix_(f.features.top_order, f.features.hor_order)] = c
                counts.append(count_pair(t.gt_top_ids, t.gt_ego_ids, t.det_top_ids,
                                         t.det_ego_ids, assign(full, spec.gamma),
                                         frame=t.frame))
            s = summarize(counts)
            record[setting] = {"acc9": round(s.acc9, 3), "cvidf1": round(s.cvidf1, 3),
                               "trials": len(trials)}
        out[label] = record
    return out


def add_int8(folder: Path, manifest: dict, loaded: LoadedMatcher, data: Path,
              progress: Callable[[str], None] | None) -> None:
    """Quantise the appearance graph (each calibration method), keep the best by measured
    accuracy as ``appearance_int8.onnx`` and record everything in ``manifest``."""
    from xvmatch.datasets.synthetic_io import SyntheticDataset

    names = SyntheticDataset(data).scene_names
    calibrate, measure = names[0::2], names[1::2]
    if not measure:
        raise ValueError(f"{os.fspath(data)}: INT8 calibration needs at least two scenes "
                          "(even ones calibrate, odd ones measure the accuracy)")
    app = manifest["appearance"]
    crops = calibration_crops(data, tuple(app["crop_size"]), loaded.crop_context, calibrate)
    files = {"fp32": app["file"]}
    for method in CALIBRATION_METHODS:
        files[method] = f"appearance_int8_{method}.onnx"
        quantize_appearance(folder / app["file"], folder / files[method], crops, method,
                            APPEARANCE_INPUT, progress)
    if progress:
        progress(f"measuring FP32 and INT8 accuracy on {len(measure)} held-out scenes")
    accuracy = int8_accuracy(folder, manifest, data, measure, files)
    best = max(CALIBRATION_METHODS,
               key=lambda m: (accuracy[m]["images"]["acc9"], -CALIBRATION_METHODS.index(m)))
    final = folder / "appearance_int8.onnx"
    os.replace(folder / files[best], final)
    for method in CALIBRATION_METHODS:
        (folder / files[method]).unlink(missing_ok=True)
    app["int8"] = {
        "file": final.name,
        "sha256": hashlib.sha256(final.read_bytes()).hexdigest(),
        "format": "QDQ, per-channel INT8 weights, UINT8 activations (onnxruntime "
                  "quantize_static after quant_pre_process)",
        "calibration": {"method": best, "methods_tried": list(CALIBRATION_METHODS),
                        "crops": int(crops.shape[0]), "data": os.fspath(data),
                        "scenes": list(calibrate)},
        "accuracy": {"measured_on": {"data": os.fspath(data), "scenes": list(measure),
                                     "settings": "ground-truth boxes and detector noise"},
                     "fp32": accuracy["fp32"], "int8": accuracy[best],
                     "by_method": {m: accuracy[m] for m in CALIBRATION_METHODS}},
    }
