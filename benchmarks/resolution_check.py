"""The same CVMHAT videos at other resolutions: CVIDF1 of both methods at 0.5x, 1x and 2x.

Scales every box of the 10 dev pairs (and the horizontal image size) by each factor, as an
export of the same videos at another resolution would, and associates frame by frame with the
handcrafted search (O searched) and the learned default (ONNX runtime, boxes only), ids
scrambled per view. Prints CVIDF1 / CVMA per factor and the difference from 1x (target: within
0.3 CVIDF1 for both methods).

Usage:
    python benchmarks/resolution_check.py [--factors 0.5 1 2] [--model default] [--workers 2]
"""

from __future__ import annotations

import argparse
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from xvmatch.cues.spatial_search import associate_sequence
from xvmatch.formats.cvmhat import IMAGE_SIZE, default_cvmhat_dir, read_sequence, sequence_names
from xvmatch.formats.mot_boxes import FrameBoxes, scale_frames
from xvmatch.inference.matching.learned_association import (
    associate_sequence_learned,
    load_matcher_bundle,
)
from xvmatch.metrics.cross_view_metrics import count_sequence, summarize


def scramble(frames: dict[int, FrameBoxes], rng: np.random.Generator):
    """Relabel ids with a random permutation (consistent over frames); frames and inverse."""
    ids = sorted({int(i) for f in frames.values() for i in f.ids})
    mapping = dict(zip(ids, (rng.permutation(len(ids)) + 10_000).tolist(), strict=True))
    inverse = {v: k for k, v in mapping.items()}
    return {k: FrameBoxes(k, np.array([mapping[int(i)] for i in f.ids], np.int64), f.boxes)
            for k, f in frames.items()}, inverse


def job(args: tuple) -> tuple[str, float, str, list]:
    """Counts of one (method, factor, sequence)."""
    method, factor, data, name, model = args
    top, hor = read_sequence(Path(data), name)
    s_top, inv_top = scramble(scale_frames(top, factor), np.random.default_rng([1, 7]))
    s_hor, inv_hor = scramble(scale_frames(hor, factor), np.random.default_rng([2, 7]))
    width, height = IMAGE_SIZE[0] * factor, IMAGE_SIZE[1] * factor
    if method == "handcrafted":
        pred = associate_sequence(s_top, s_hor, width)
    else:
        pred = associate_sequence_learned(s_top, s_hor, width, load_matcher_bundle(model),
                                          hor_height=height)
    pred = {f: [(inv_top[a], inv_hor[b]) for a, b in p] for f, p in pred.items()}
    return method, factor, name, count_sequence(pred, top, hor)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=default_cvmhat_dir(), help="CVMHAT boxes")
    parser.add_argument("--factors", type=float, nargs="+", default=[0.5, 1.0, 2.0])
    parser.add_argument("--model", default="default", help="bundle of the learned method")
    parser.add_argument("--workers", type=int, default=2, help="processes")
    args = parser.parse_args()
    if not (args.data / "README.md").exists():
        print(f"CVMHAT data not found at {args.data}; nothing to measure (skipped).")
        return 0
    start = time.perf_counter()
    names = sequence_names(args.data)
    jobs = [(m, f, str(args.data), n, args.model) for m in ("learned", "handcrafted")
            for f in args.factors for n in names]
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        results = list(pool.map(job, jobs))
    counts: dict[tuple[str, float], list] = {}
    for method, factor, _, c in results:
        counts.setdefault((method, factor), []).extend(c)
    print(f"CVMHAT dev split ({len(names)} pairs), frame mode, O searched, ids scrambled; "
          "CVIDF1 / CVMA (difference from 1x)")
    for method in ("handcrafted", "learned"):
        base = summarize(counts[(method, 1.0)]) if (method, 1.0) in counts else None
        cells = []
        for f in args.factors:
            s = summarize(counts[(method, f)])
            diff = f" ({s.cvidf1 - base.cvidf1:+.2f})" if base is not None else ""
            cells.append(f"{f:g}x {s.cvidf1:.2f} / {s.cvma:.2f}{diff}")
        print(f"{method:12s} " + "   ".join(cells))
    print(f"{time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
