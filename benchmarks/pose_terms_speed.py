"""The oblique registration's pose hypotheses: the compiled pose terms against their numpy form.

Times :func:`xvmatch.cues.ground_registration.pose_hypotheses` on the same random frames in the
same run, once with ``XVMATCH_KERNELS=numpy`` and once compiled (the default wherever numba
imports), and checks that both give the same poses and scores bit for bit. Milliseconds a call
from CPU time (robust to other load), the best of ``--repeats`` passes, and the ratio. Then the
registration of those frames as a sequence with the top camera's sight and without it (video
mode runs both for every lens): two calls of
:func:`~xvmatch.cues.ground_registration.register_scales` against one of
:func:`~xvmatch.cues.ground_registration.register_scales_twice`, which computes each frame's
pose terms once for both, and whether they give the same runs.

Usage:
    python benchmarks/pose_terms_speed.py [--frames 40] [--top 12] [--hor 10] [--repeats 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from xvmatch.core import kernel_choice
from xvmatch.cues import ground_registration as gr
from xvmatch.geometry.people_model import pinhole


def frames(count: int, n_top: int, n_hor: int, seed: int) -> list[tuple]:
    """Random frames: top people within 15 m, handheld people 1-25 m ahead, sizes 0.9-1.1."""
    rng = np.random.default_rng(seed)
    return [(rng.uniform(-15, 15, (n_top, 2)),
             np.column_stack([rng.uniform(1, 25, n_hor), rng.uniform(-8, 8, n_hor)]),
             rng.uniform(0.9, 1.1, n_top)) for _ in range(count)]


def timed(cases: list[tuple], sight: gr.TopSight | None, mode: str, repeats: int
          ) -> tuple[float, list]:
    """The best CPU milliseconds a call over ``repeats`` passes, and the last pass's outputs."""
    best, out = np.inf, []
    with kernel_choice.forced(mode):
        gr.pose_hypotheses(*cases[0][:2], 70.0, cases[0][2], sight)  # compile / warm up
        for _ in range(repeats):
            t = time.process_time()
            out = [gr.pose_hypotheses(top, hor, 70.0, sizes, sight) for top, hor, sizes in cases]
            best = min(best, (time.process_time() - t) / len(cases) * 1e3)
    return best, out


def twice_timed(cases: list[tuple], sight: gr.TopSight, repeats: int
                ) -> tuple[float, float, bool]:
    """CPU milliseconds a frame (best of ``repeats``) of the registration with and without
    the ``sight`` by two calls and by one, and whether the runs are the same."""
    order = list(range(len(cases)))
    args = (order, [c[0] for c in cases], [c[1] for c in cases], 70.0, 3.0, None,
            [c[2] for c in cases])
    sights = [sight] * len(cases)

    def run(call):
        best, out = np.inf, None
        for _ in range(repeats):
            t = time.process_time()
            out = call()
            best = min(best, (time.process_time() - t) / len(cases) * 1e3)
        return best, out

    def flat(runs: dict) -> list:
        return [(s, total, [(p.frame, p.centre.tolist(), p.heading, p.score) for p in poses])
                for s, (total, poses) in sorted(runs.items())]

    two, (made, plain) = run(lambda: (gr.register_scales(*args, sights),
                                      gr.register_scales(*args, None)))
    one, (made1, plain1) = run(lambda: gr.register_scales_twice(*args, sights))
    return two, one, flat(made) == flat(made1) and flat(plain) == flat(plain1)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--top", type=int, default=12, help="top-view people a frame")
    p.add_argument("--hor", type=int, default=10, help="handheld people a frame")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    cases = frames(args.frames, args.top, args.hor, args.seed)
    camera = pinhole(960.0 / np.tan(np.radians(35.0)), np.radians(35.0), 0.0, 8.0, (1920, 1080))
    print(f"{args.frames} frames of {args.top} top and {args.hor} handheld people, "
          "ms a call (CPU time, best of "
          f"{args.repeats})")
    print("| sight | numpy | compiled | ratio | the same bits |")
    print("|---|---|---|---|---|")
    for name, sight in (("none", None), ("the top camera's", gr.TopSight.of(camera, 25.0))):
        slow, expected = timed(cases, sight, "numpy", args.repeats)
        fast, got = timed(cases, sight, "compiled", args.repeats)
        same = all(np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
                   for a, b in zip(expected, got, strict=True))
        print(f"| {name} | {slow:.1f} | {fast:.1f} | {slow / fast:.2f}x | {same} |")
    two, one, same = twice_timed(cases, gr.TopSight.of(camera, 25.0), args.repeats)
    print("\nregistered with the top camera's sight and without, ms a frame (compiled)\n")
    print("| two calls | at once | ratio | the same runs |")
    print("|---|---|---|---|")
    print(f"| {two:.1f} | {one:.1f} | {two / one:.2f}x | {same} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
