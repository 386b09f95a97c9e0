"""The learned box-only path on real CVMHAT boxes: ONNX runtime against the torch path, and
against the handcrafted search, as whole command-line runs on one core, in one run.

Up to four runs over the same sequences (default ``V1-S_55-G_1``, 1,200 frames), each a fresh
process with one thread (``OMP_NUM_THREADS=1``, onnxruntime ``--threads 1``):

* ``handcrafted``: ``xvmatch associate`` (the exhaustive search of Sec. 3.2.4), as shipped
  (``XVMATCH_KERNELS=auto``: the compiled kernels wherever numba is installed);
* ``hand-numpy``: the same command with ``XVMATCH_KERNELS=numpy``: the search as it ran before
  the compiled kernels, the speed the issue's reference figure (265 frames/s) was measured on;
* ``onnx``: ``xvmatch associate --model BUNDLE`` (the deployed runtime, no torch);
* ``torch``: the path this release replaces, rebuilt here: the features with one exact search
  per candidate camera location (``rank_hypotheses(..., k=1)`` per candidate, as feature
  version 1 did) and the torch matcher (``models.matcher_file``) with the same weights,
  batched 64 frames, Hungarian with the same gamma, the same CSV written.

``--sequences all`` takes every pair of the CVMHAT dev split in ``--data`` (10 pairs, 7,800
frames): ``--sequences all --runs handcrafted onnx`` prints the learned/handcrafted ratio over
the dev pairs in one run. ``--runs`` picks some of them (``--runs handcrafted onnx``: the
learned/handcrafted ratio alone, no torch needed; without torch installed the torch run is left
out with a note) and ``--repeat N`` runs them N times, alternating their order from round to
round (paired runs on a noisy machine); the figures are medians over the rounds, and the
onnx/handcrafted ratio is the median of the rounds' own ratios.

Prints frames per second (CPU time of the child processes, and wall time), the ratios, and the
CVIDF1 of each on those frames (ids as in the files: the learned paths never see them).

Usage:
    python benchmarks/learned_box_path.py [--sequences V1-S_55-G_1 ... | all] [--model default]
        [--torch-model default] [--runs handcrafted onnx] [--repeat 5]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from xvmatch.formats.cvmhat import (  # noqa: E402
    IMAGE_SIZE,
    default_cvmhat_dir,
    read_sequence,
    sequence_names,
)
from xvmatch.formats.mot_boxes import read_predictions  # noqa: E402
from xvmatch.metrics.cross_view_metrics import count_sequence, summarize  # noqa: E402

RUNS = ("handcrafted", "hand-numpy", "onnx", "torch")


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def torch_path(top_file: str, hor_file: str, out: str, model: str) -> None:
    """The replaced pipeline (see the module docstring), run as a command of its own."""
    import numpy as np
    import torch

    import xvmatch.cues.spatial_features as features
    from xvmatch.cues.spatial_features import collate_frames, frame_features
    from xvmatch.cues.spatial_search import rank_hypotheses
    from xvmatch.formats.mot_boxes import read_mot_boxes, write_predictions
    from xvmatch.inference.linking.assignment import assign
    from xvmatch.models.matcher_file import load_matcher

    def per_candidate(top, hor, width, params, candidates, keep=None):
        return [r for c in candidates
                for r in rank_hypotheses(top, hor, width, params, candidates=[c], k=1)], None

    features._best_per_candidate = per_candidate  # feature version 1's search (no geometry)
    torch.set_num_threads(1)
    loaded = load_matcher(model)
    top = read_mot_boxes(top_file, duplicates="first")
    hor = read_mot_boxes(hor_file, duplicates="first")
    frames = [f for f in sorted(set(top) | set(hor))
              if f in top and f in hor and len(top[f]) and len(hor[f])]
    pairs: dict[int, list] = {f: [] for f in sorted(set(top) | set(hor))}
    for start in range(0, len(frames), 64):
        chunk = frames[start : start + 64]
        feats = [frame_features(top[f].boxes, hor[f].boxes, IMAGE_SIZE, loaded.feature_config)
                 for f in chunk]
        batch = {k: torch.from_numpy(v) for k, v in collate_frames(feats).items()}
        with torch.inference_mode():
            cost = loaded.matcher(batch["top"], batch["hor"], batch["hyp"], batch["pair"],
                                  batch["top_mask"], batch["hor_mask"],
                                  batch["hyp_mask"]).cost.numpy().astype(np.float64)
        for k, (f, ff) in enumerate(zip(chunk, feats, strict=True)):
            m, n = ff.shape[1:]
            full = np.empty((m, n))
            full[np.ix_(ff.top_order, ff.hor_order)] = cost[k, :m, :n]
            pairs[f] = [(int(top[f].ids[a]), int(hor[f].ids[b]))
                        for a, b in assign(full, loaded.gamma)]
    write_predictions(out, pairs)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=default_cvmhat_dir(), help="CVMHAT boxes")
    parser.add_argument("--sequences", nargs="+", default=["V1-S_55-G_1"],
                        help="sequence pairs of --data, or 'all' (every dev pair)")
    parser.add_argument("--model", default="default", help="bundle of the ONNX path")
    parser.add_argument("--torch-model", default="default",
                        help="matcher file of the torch path (the bundle's source)")
    parser.add_argument("--runs", nargs="+", choices=RUNS, default=list(RUNS),
                        help="which runs (default all four)")
    parser.add_argument("--repeat", type=int, default=1,
                        help="rounds of the runs, their order alternating (medians reported)")
    parser.add_argument("--torch-path", nargs=3, metavar=("TOP", "HOR", "OUT"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.torch_path:
        torch_path(*args.torch_path, args.torch_model)
        return 0
    if not (args.data / "README.md").exists():
        print(f"CVMHAT data not found at {args.data}; nothing to measure (skipped).")
        return 0
    if args.repeat < 1:
        parser.error(f"--repeat must be >= 1, got {args.repeat}")
    if args.sequences == ["all"]:
        args.sequences = sequence_names(args.data)
    missing = [n for n in args.sequences if not (args.data / f"{n}_top.txt").exists()
               or not (args.data / f"{n}_hor.txt").exists()]
    if missing or not args.sequences:
        print(f"CVMHAT pair(s) {', '.join(missing) or '(none)'} not found in {args.data}; "
              "nothing to measure (skipped).")
        return 0
    if "torch" in args.runs:
        try:
            import torch  # noqa: F401
        except ImportError:
            print("torch is not installed (the learn extra): the torch run is left out")
            args.runs = [r for r in args.runs if r != "torch"]
    exe = [sys.executable, "-m", "xvmatch", "associate", "--quiet"]
    commands = {
        "handcrafted": lambda t, h, o: [*exe, "--top", t, "--hor", h, "--out", o],
        "hand-numpy": lambda t, h, o: [*exe, "--top", t, "--hor", h, "--out", o],
        "onnx": lambda t, h, o: [*exe, "--top", t, "--hor", h, "--out", o, "--model",
                                 args.model, "--threads", "1"],
        "torch": lambda t, h, o: [sys.executable, __file__, "--torch-model", args.torch_model,
                                  "--torch-path", t, h, o],
    }
    labels = [r for r in RUNS if r in args.runs]
    seqs = {n: read_sequence(args.data, n) for n in args.sequences}
    n_frames = sum(len(set(t) | set(h)) for t, h in seqs.values())
    rounds: list[dict[str, tuple[float, float, float]]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.repeat):
            rows = {}
            for label in labels if r % 2 == 0 else labels[::-1]:
                cpu0, wall0 = _children_cpu(), time.perf_counter()
                counts = []
                for n, (top, hor) in seqs.items():
                    out = f"{tmp}/{label}_{n}.csv"
                    env = {**os.environ,
                           "XVMATCH_KERNELS": "numpy" if label == "hand-numpy" else "auto"}
                    subprocess.run(commands[label](str(args.data / f"{n}_top.txt"),
                                                   str(args.data / f"{n}_hor.txt"), out),
                                   check=True, env=env)
                    counts += count_sequence(read_predictions(out), top, hor)
                rows[label] = (_children_cpu() - cpu0, time.perf_counter() - wall0,
                               summarize(counts).cvidf1)
            rounds.append(rows)
    median = {label: tuple(statistics.median(rows[label][k] for rows in rounds)
                           for k in range(3)) for label in labels}
    names = ", ".join(args.sequences) if len(args.sequences) <= 3 else \
        f"{len(args.sequences)} pairs ({args.sequences[0]} ... {args.sequences[-1]})"
    print(f"{names}: {n_frames} frames, whole command per sequence, one "
          f"thread; median of {args.repeat} round(s), order alternating")
    print(f"{'path':12s} {'fps (cpu)':>10s} {'fps (wall)':>11s} {'CVIDF1':>7s}")
    for label, (cpu, wall, f1) in median.items():
        print(f"{label:12s} {n_frames / cpu:10.1f} {n_frames / wall:11.1f} {f1:7.2f}")

    def ratio(num: str, den: str) -> float:
        """Median over the rounds of the CPU time of ``num`` over that of ``den``."""
        return statistics.median(rows[num][0] / rows[den][0] for rows in rounds)

    parts = []
    if {"onnx", "handcrafted"} <= set(labels):
        parts.append(f"onnx / handcrafted: {ratio('handcrafted', 'onnx'):.2f} of its speed "
                     "(target 1.0)")
    if {"onnx", "hand-numpy"} <= set(labels):
        parts.append(f"of the numpy search's: {ratio('hand-numpy', 'onnx'):.2f} (target 200 / "
                     "265 = 0.75)")
    if {"onnx", "torch"} <= set(labels):
        parts.append(f"onnx / torch speed: {ratio('torch', 'onnx'):.2f}x (target >= 3); CVIDF1 "
                     f"onnx - torch: {median['onnx'][2] - median['torch'][2]:+.2f} (target "
                     "within 0.2)")
    if parts:
        print("; ".join(parts))
    return 0

if __name__ == "__main__":
    raise SystemExit(main())
