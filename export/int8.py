"""Static INT8 quantisation of the appearance graph (onnxruntime's QDQ tools), with the accuracy
it keeps measured on held-out synthetic frames.

Static QDQ: onnxruntime's pre-processing (shape inference and graph optimisation), then
``quantize_static`` with per-channel INT8 weights and UINT8 activations (the x86 layout) whose
ranges come from calibration crops. Calibration and measurement use disjoint scenes of one
synthetic dataset (``xvmatch synth``): even scenes calibrate, odd scenes measure. Several
calibration methods are tried; the one whose INT8 network keeps the best Eq. 9 accuracy of the
matcher with images on the measurement frames is kept (ties: the first in
:data:`CALIBRATION_METHODS`), and every method's figures are recorded.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

__all__ = ["CALIBRATION_METHODS", "calibration_crops", "quantize_appearance"]

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
