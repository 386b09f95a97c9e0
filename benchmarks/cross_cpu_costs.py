"""How much the CPU's SIMD code moves the results (docs/method.md, "Determinism").

NumPy picks its tan, pow, hypot and arctan2 code by the CPU, so costs can differ in the last bits
between machines. ``--save FILE`` writes, for the 10 CVMHAT dev pairs, the handcrafted pairs of
every 5th frame, the best Phi of every 25th and the learned default's pairs and cost matrices of
every 20th; ``--compare A B`` counts what differs between two such files. Run ``--save`` on two
machines, or on one with NumPy's AVX-512 code switched off for the second run::

    python benchmarks/cross_cpu_costs.py --save runs/avx512.pkl
    NPY_DISABLE_CPU_FEATURES="X86_V4 AVX512_ICL" python benchmarks/cross_cpu_costs.py \\
        --save runs/avx2.pkl
    python benchmarks/cross_cpu_costs.py --compare runs/avx512.pkl runs/avx2.pkl
"""

from __future__ import annotations

import argparse
import pickle
from pathlib import Path

import numpy as np

from xvmatch.core.atomic_files import atomic_write_bytes
from xvmatch.core.output_paths import Input, Output, check_script_outputs
from xvmatch.cues.spatial_search import associate_sequence, rank_hypotheses
from xvmatch.formats.cvmhat import IMAGE_SIZE, default_cvmhat_dir, read_sequence, sequence_names
from xvmatch.inference.matching.learned_association import (
    associate_sequence_learned,
    load_matcher_bundle,
)


def save(data: Path, path: Path) -> None:
    """Compute the figures on this machine and write them to ``path``."""
    width = float(IMAGE_SIZE[0])
    model = load_matcher_bundle("default")
    out = {}
    for name in sequence_names(data):
        top, hor = read_sequence(data, name)
        frames = sorted(set(top) & set(hor))
        pairs = associate_sequence(top, hor, width, frames=frames[::5])
        best = [h.cost for f in frames[::25]
                for h in rank_hypotheses(top[f].boxes, hor[f].boxes, width, k=1)]
        costs: dict[int, np.ndarray] = {}
        learned = associate_sequence_learned(top, hor, width, model, frames=frames[::20],
                                             costs_out=costs)
        out[name] = (pairs, best, learned, costs)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, pickle.dumps(out))
    print(f"wrote {path}")


def compare(a_path: Path, b_path: Path) -> None:
    """Print how many pairs and costs differ between two saved runs."""
    a, b = (pickle.loads(p.read_bytes()) for p in (a_path, b_path))
    frames = pairs_diff = n_cost = cost_diff = learned_frames = learned_diff = 0
    n_matrix = matrix_diff = 0
    worst_rel = worst_abs = 0.0
    for name in a:
        (pa, ca, la, ma), (pb, cb, lb, mb) = a[name], b[name]
        frames += len(pa)
        pairs_diff += sum(set(pa[f]) != set(pb[f]) for f in pa)
        for x, y in zip(ca, cb, strict=True):
            n_cost += 1
            cost_diff += x != y
            if np.isfinite(x) and x:
                worst_rel = max(worst_rel, abs(x - y) / abs(x))
        learned_frames += len(la)
        learned_diff += sum(set(la[f]) != set(lb[f]) for f in la)
        for f in ma:
            n_matrix += 1
            d = float(np.abs(ma[f] - mb[f]).max()) if ma[f].size else 0.0
            matrix_diff += d > 0
            worst_abs = max(worst_abs, d)
    print(f"handcrafted: {pairs_diff} of {frames} frames' pairs differ; {cost_diff} of {n_cost} "
          f"best Phi differ, by at most {worst_rel:.2e} relative")
    print(f"learned: {learned_diff} of {learned_frames} frames' pairs differ; {matrix_diff} of "
          f"{n_matrix} cost matrices differ, by at most {worst_abs:.2e}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=default_cvmhat_dir(), help="CVMHAT boxes")
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--save", type=Path, metavar="FILE", help="compute and write the figures")
    group.add_argument("--compare", type=Path, nargs=2, metavar=("A", "B"),
                       help="compare two saved runs")
    args = parser.parse_args()
    check_script_outputs(parser, [Output("--save", args.save)], [Input("--data", args.data)])
    if args.compare:
        compare(*args.compare)
    elif not args.data.is_dir():
        print(f"CVMHAT data not found at {args.data}; nothing to measure (skipped).")
    else:
        save(args.data, args.save)


if __name__ == "__main__":
    main()
