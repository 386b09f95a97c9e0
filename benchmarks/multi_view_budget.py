"""The joint multi-view MIP's budget of work on crowded random frames (``associate-multi``).

Each frame: ``--views`` views of ``--people`` people, each view seeing a random half to all of
them; the cost of a true pair is uniform in [0, 0.6], of any other pair in [0.2, 1], both with
Gaussian noise of ``--noise`` and clipped to [0, 1]; gamma 0.5. Such frames are far harder than
the rendered scenes of ``multi_ego_eval.py`` (many near ties), which is what the budget is for.
Per frame (seed ``0..--frames-1``) and budget (``--budgets``, broken triangles; default the
shipped :data:`~xvmatch.inference.views.multi_view_assignment.MIP_MAX_TRIANGLES`), prints the
status, the programs solved, the triangles added, the seconds, the joint objective (lower is better)
and that of pairwise Hungarian made consistent; last, per budget, the slowest frame and the mean
objective. The wall-time guard is set to 600 s, so every figure but the seconds is the same on
any machine.

Usage:
    python benchmarks/multi_view_budget.py [--views 3] [--people 16] [--noise 0.1]
        [--frames 6] [--budgets 64 96 128]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from xvmatch.inference.views.multi_view_assignment import (
    MIP_MAX_TRIANGLES,
    consistent_hungarian,
    objective,
    solve_multi_view,
    view_pairs,
)

GAMMA = 0.5


def crowded_frame(seed: int, views: int, people: int,
                  noise: float) -> tuple[list[int], dict[tuple[int, int], np.ndarray]]:
    """``(sizes, costs)`` of one random crowded frame (the module docstring)."""
    rng = np.random.default_rng(seed)
    seen = [rng.permutation(people)[:rng.integers(people // 2, people + 1)]
            for _ in range(views)]
    costs = {}
    for a, b in view_pairs(views):
        same = seen[a][:, None] == seen[b][None, :]
        c = np.where(same, rng.uniform(0.0, 0.6, same.shape), rng.uniform(0.2, 1.0, same.shape))
        costs[(a, b)] = np.clip(c + rng.normal(0.0, noise, c.shape), 0.0, 1.0)
    return [len(s) for s in seen], costs


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=3)
    parser.add_argument("--people", type=int, default=16)
    parser.add_argument("--noise", type=float, default=0.1)
    parser.add_argument("--frames", type=int, default=6)
    parser.add_argument("--budgets", type=int, nargs="+", default=[MIP_MAX_TRIANGLES])
    args = parser.parse_args(argv)
    print(f"# {args.frames} frames, {args.views} views of {args.people} people, noise "
          f"{args.noise}, gamma {GAMMA}; objective: lower is better")
    print("| budget | frame | status | programs | triangles | seconds | objective | greedy |")
    print("|---|---|---|---|---|---|---|---|")
    summary = []
    for budget in args.budgets:
        seconds, values = [], []
        for seed in range(args.frames):
            sizes, costs = crowded_frame(seed, args.views, args.people, args.noise)
            start = time.perf_counter()
            sol = solve_multi_view(sizes, costs, GAMMA, time_limit=600.0, max_triangles=budget)
            seconds.append(time.perf_counter() - start)
            values.append(objective(costs, GAMMA, sol.pairs))
            greedy = objective(costs, GAMMA, consistent_hungarian(sizes, costs, GAMMA).pairs)
            print(f"| {budget} | {seed} | {sol.status} | {sol.rounds} | {sol.triangles} | "
                  f"{seconds[-1]:.2f} | {values[-1]:.3f} | {greedy:.3f} |", flush=True)
        summary.append((budget, max(seconds), float(np.mean(values))))
    for budget, slowest, mean in summary:
        print(f"budget {budget}: slowest frame {slowest:.2f} s, mean objective {mean:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
