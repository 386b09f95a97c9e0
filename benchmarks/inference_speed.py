"""CPU speed of the appearance branch: torch eager FP32, ONNX FP32 and ONNX INT8, in one run.

For the paper's ResNet-50 branch (256x128 crops), the compact trunk of the shipped default
(128x64) and the ImageNet-initialisable MobileNetV2 and EfficientNet-Lite0 trunks (128x64,
:mod:`xvmatch.models.pretrained_backbones`), with 1 and 2 threads, on the same crops: crops per
second (batches of 64) and milliseconds per image pair with 10 + 10 people (one batch of 20
crops, what the runtime sends per frame). The INT8 networks are static QDQ ones
(:mod:`xvmatch.export.int8`, MinMax calibration on rendered crops); speed does not depend on the
weights, so untrained networks are timed. Also: the ResNet-50's FP32 GFLOP/s (its multiply-adds
counted from the ONNX graph's convolutions and matrix products) beside the machine's
single-precision matrix-product peak measured in the same run (numpy sgemm, 2048x2048, in a
process with one, then two BLAS threads).

It first prints the CPU's 8-bit dot-product features (VNNI, AMX, Arm's dot product: where the
runtime picks INT8 on its own, :func:`xvmatch.inference.matching.bundle.fast_int8_cpu`), then, for a
bundle (``--bundle``, the shipped default unless ``--bundle none``), its own FP32 and INT8
appearance files (the INT8 one mixed precision, as exported) with their ratio.

Usage:
    python benchmarks/inference_speed.py [--repeats 5] [--bundle default|BUNDLE|none]
        [--archs resnet50 small mobilenetv2 efficientnet_lite0]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np


def _timed(fn, repeats: int) -> float:
    """Best wall time of ``repeats`` calls (after one warm-up)."""
    fn()
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def sgemm_gflops(threads: int, n: int = 2048, repeats: int = 5) -> float:
    """Measured float32 matrix-product speed of numpy's BLAS with ``threads`` threads, in a
    fresh process (BLAS reads its thread count when it loads)."""
    import subprocess
    import sys

    code = (
        "import time, numpy as np\n"
        f"a = np.random.default_rng(0).standard_normal(({n}, {n})).astype(np.float32)\n"
        "b = a.T.copy(); a @ b\n"
        f"best = min((lambda t: (a @ b, time.perf_counter() - t)[1])(time.perf_counter()) "
        f"for _ in range({repeats}))\n"
        f"print(2.0 * {n}**3 / best / 1e9)\n"
    )
    env = {**os.environ, **{v: str(threads) for v in
                            ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, check=True)
    return float(out.stdout.strip())


def graph_gflop(path: Path, batch: int) -> float:
    """Multiply-add FLOPs (x2) of the Conv, Gemm and MatMul nodes of an ONNX graph for one
    batch, from shape inference (:func:`xvmatch.export.int8.node_macs`)."""
    import onnx
    import onnxruntime as ort

    from xvmatch.export.int8 import node_macs

    # onnxruntime's basic optimisations first: they fold the traced padding arithmetic of
    # EfficientNet's "same" padding into the convolutions, so every shape can be inferred.
    with tempfile.TemporaryDirectory() as tmp:
        options = ort.SessionOptions()
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_BASIC
        options.optimized_model_filepath = os.fspath(Path(tmp) / "basic.onnx")
        options.intra_op_num_threads = 1
        ort.InferenceSession(os.fspath(path), options, providers=["CPUExecutionProvider"])
        model = onnx.load(options.optimized_model_filepath)
    for v in model.graph.input:  # the batch axis made concrete
        for d in v.type.tensor_type.shape.dim:
            if d.dim_value <= 0:
                d.dim_value = batch
    return 2.0 * batch * sum(node_macs(model).values()) / 1e9


def time_bundle(bundle: str, crops: np.ndarray, repeats: int) -> None:
    """Crops per second of a bundle's FP32 and INT8 appearance files, 1 and 2 threads (loaded
    and checked as the runtime loads them)."""
    import cv2

    from xvmatch.inference.matching.bundle import load_bundle

    spec = load_bundle(bundle).manifest.appearance
    if spec is None or spec.int8_file is None:
        print(f"\nbundle {bundle}: no INT8 appearance network")
        return
    w, h = spec.crop_size
    batch = np.resize(np.stack([cv2.resize(c, (w, h)) for c in crops]), (64, h, w, 3))
    mixed = spec.int8.get("mixed_precision", {})
    print(f"\nbundle {bundle}: {spec.arch} {h}x{w} crops; INT8 keeps "
          f"{len(mixed.get('fp32_nodes', []))} nodes FP32 "
          f"({100 * mixed.get('fp32_mac_share', 0.0):.0f}% of the multiply-adds)")
    for threads in (1, 2):
        speed = {}
        for precision in ("fp32", "int8"):
            loaded = load_bundle(bundle, threads, precision)
            speed[precision] = 64 / _timed(lambda b=loaded: b.embed(batch), repeats)
        print(f"  {threads} thread(s): FP32 {speed['fp32']:.1f} crops/s, INT8 "
              f"{speed['int8']:.1f} crops/s, INT8/FP32 {speed['int8'] / speed['fp32']:.2f}x")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--archs", nargs="+",
                        default=["resnet50", "small", "mobilenetv2", "efficientnet_lite0"])
    parser.add_argument("--bundle", default="default",
                        help="bundle whose own FP32 and INT8 files are timed (none: skip)")
    args = parser.parse_args()
    from xvmatch.inference.matching.bundle import int8_dot_flags

    found = int8_dot_flags()
    print(f"CPU 8-bit dot products: {', '.join(found) if found else 'none'} (the runtime "
          f"{'may pick' if found else 'never picks'} INT8 on its own here)")

    import onnxruntime as ort
    import torch

    from xvmatch.datasets.synthetic_io import generate_dataset
    from xvmatch.datasets.synthetic_scenes import SynthConfig
    from xvmatch.export.int8 import calibration_crops, quantize_appearance
    from xvmatch.export.onnx_export import AppearanceGraph, _onnx_export
    from xvmatch.models.appearance_net import (
        appearance_efficientnet_lite0,
        appearance_mobilenetv2,
        appearance_resnet50,
        appearance_small,
    )

    builders = {"resnet50": appearance_resnet50, "small": appearance_small,
                "mobilenetv2": appearance_mobilenetv2,
                "efficientnet_lite0": appearance_efficientnet_lite0}
    peak = {t: sgemm_gflops(t) for t in (1, 2)}
    print(f"numpy sgemm peak: {peak[1]:.1f} GFLOP/s on 1 thread, {peak[2]:.1f} on 2")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        data = tmp / "data"
        generate_dataset(data, SynthConfig(scenario="overview", n_people=(8, 12)), n_scenes=4,
                         n_frames=2, seed=31)
        if args.bundle != "none":
            time_bundle(args.bundle, calibration_crops(data, (64, 128), 0.1, max_crops=128),
                        args.repeats)
        for arch in args.archs:
            torch.manual_seed(0)
            net = builders[arch]().eval()
            h, w = net.preprocessing.input_size
            crops = calibration_crops(data, (w, h), 0.1, max_crops=128)
            batch = np.resize(crops, (64, h, w, 3))
            pair = np.resize(crops, (20, h, w, 3))
            fp32 = tmp / f"{arch}.onnx"
            _onnx_export(AppearanceGraph(net).eval(),
                         (torch.from_numpy(batch[:2]),), fp32, ["crops"], ["descriptors"],
                         {"crops": {0: "n"}, "descriptors": {0: "n"}})
            int8 = tmp / f"{arch}_int8.onnx"
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                quantize_appearance(fp32, int8, crops, "minmax")
            gflop = graph_gflop(fp32, 64)
            print(f"\n{arch}: {h}x{w} crops, {gflop / 64:.2f} GFLOP per crop")
            print(f"{'runtime':18s} {'threads':>7s} {'crops/s':>9s} {'ms/pair':>8s} "
                  f"{'vs torch':>8s} {'vs onnx':>8s}")
            for threads in (1, 2):
                rows = {}
                torch.set_num_threads(threads)
                with torch.inference_mode():
                    tb, tp = torch.from_numpy(batch), torch.from_numpy(pair)
                    rows["torch eager fp32"] = (
                        _timed(lambda n=net, x=tb: n.embed_crops(x), args.repeats),
                        _timed(lambda n=net, x=tp: n.embed_crops(x), args.repeats))
                for label, path in (("onnx fp32", fp32), ("onnx int8", int8)):
                    options = ort.SessionOptions()
                    options.intra_op_num_threads = threads
                    options.inter_op_num_threads = 1
                    s = ort.InferenceSession(os.fspath(path), options,
                                             providers=["CPUExecutionProvider"])
                    rows[label] = (
                        _timed(lambda s=s, x=batch: s.run(None, {"crops": x}), args.repeats),
                        _timed(lambda s=s, x=pair: s.run(None, {"crops": x}), args.repeats))
                for label, (tb_s, tp_s) in rows.items():
                    print(f"{label:18s} {threads:7d} {64 / tb_s:9.1f} {1000 * tp_s:8.1f} "
                          f"{rows['torch eager fp32'][0] / tb_s:7.2f}x "
                          f"{rows['onnx fp32'][0] / tb_s:7.2f}x")
                if arch == "resnet50":
                    achieved = gflop / rows["onnx fp32"][0]
                    print(f"  ResNet-50 ONNX FP32: {achieved:.1f} GFLOP/s = "
                          f"{100 * achieved / peak[threads]:.0f}% of the sgemm peak "
                          f"({peak[threads]:.1f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
