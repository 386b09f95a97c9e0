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

``--batch-rows`` measures nothing of the runs: it checks, on the first of ``--sequences``,
whether onnxruntime gives a frame's costs the same bits when only the number of frames in its
call changes (each frame alone at its batch's padded shape; its batch in two halves; its batch
with one frame more; the batches of one padded shape stacked into one call), and times the
batches as ``associate`` runs them against the stacked calls (issue 70's third round,
``docs/notes/learned_box_speed.md``).

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
        [--torch-model default] [--runs handcrafted onnx] [--repeat 5] [--batch-rows]
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


def batch_rows(data: Path, name: str, model: str) -> None:
    """The ``--batch-rows`` check (see the module docstring) on one pair, in this process."""
    import numpy as np

    from xvmatch.cues.matcher_inputs import collate_inputs
    from xvmatch.inference.matching.learned_association import (
        _batches,
        _frame_features,
        _has_both,
        load_matcher_bundle,
    )

    matcher = load_matcher_bundle(model, 1)
    top, hor = read_sequence(data, name)
    frames = [f for f in sorted(set(top) | set(hor)) if _has_both(top, hor, f)]
    inputs = [matcher.inputs(_frame_features(top[f].boxes, hor[f].boxes, IMAGE_SIZE,
                                             [matcher.feature_config], None, None, False)[0][0],
                             (len(top[f].ids), len(hor[f].ids))) for f in frames]
    batches = []  # as associate batches them: 64 pending frames, then the cell bound
    for start in range(0, len(inputs), 64):
        pending = inputs[start : start + 64]
        batches += [collate_inputs(pending[part]) for part in _batches(pending, 64)]
    run = matcher.bundle.costs

    def differing(got, want) -> int:
        """Frames (rows) of ``want`` whose costs differ from ``got``'s in any bit."""
        rows = got.view(np.uint32) != want.view(np.uint32)
        return int(rows.reshape(want.shape[0], -1).any(axis=1).sum())

    cpu = time.process_time()
    costs = [run(b) for b in batches]
    as_run = time.process_time() - cpu
    alone = sum(differing(run({k: v[i : i + 1] for k, v in b.items()}), c[i : i + 1])
                for b, c in zip(batches, costs, strict=True) for i in range(c.shape[0]))
    halves = sum(differing(np.concatenate([run({k: v[:h] for k, v in b.items()}),
                                           run({k: v[h:] for k, v in b.items()})]), c)
                 for b, c in zip(batches, costs, strict=True)
                 if (h := c.shape[0] // 2) > 0)
    one_more = sum(differing(run({k: np.concatenate([v, v[:1]]) for k, v in b.items()})[:-1], c)
                   for b, c in zip(batches, costs, strict=True))
    shapes: dict[tuple, list] = {}
    for b, c in zip(batches, costs, strict=True):
        shapes.setdefault(tuple(b[k].shape[1] for k in ("hyp", "top", "hor")), []).append((b, c))
    stacked = [{k: np.concatenate([b[k] for b, _ in group]) for k in group[0][0]}
               for group in shapes.values()]
    cpu = time.process_time()
    stacked_costs = [run(s) for s in stacked]
    as_stacked = time.process_time() - cpu
    in_stacks = sum(differing(s, np.concatenate([c for _, c in group]))
                    for s, group in zip(stacked_costs, shapes.values(), strict=True))
    print(f"{name}: {len(frames)} frames through {model}'s matcher as associate batches them, "
          f"{len(batches)} calls ({len(shapes)} padded shapes); frames whose costs differ in "
          "some bit from that run's:")
    print(f"  each frame alone, at its batch's padded shape: {alone} of {len(frames)}")
    print(f"  its batch split into two calls (halves): {halves} of {len(frames)}")
    print(f"  its batch with a copy of its first frame appended: {one_more} of {len(frames)}")
    print(f"  the batches of one padded shape stacked ({len(stacked)} calls): {in_stacks} of "
          f"{len(frames)}")
    print(f"  CPU of the {len(batches)} calls {as_run:.2f} s, of the {len(stacked)} stacked "
          f"calls {as_stacked:.2f} s")


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
    parser.add_argument("--batch-rows", action="store_true",
                        help="check onnxruntime's bits against the batch's row count instead "
                        "(first sequence; see above)")
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
    if args.batch_rows and args.sequences:
        if (args.data / f"{args.sequences[0]}_top.txt").exists():
            batch_rows(args.data, args.sequences[0], args.model)
            return 0
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
