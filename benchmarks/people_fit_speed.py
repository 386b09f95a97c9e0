"""The top camera's calibration from its people: the people model's compiled box heights
against their numpy form (issue 67).

The calibration (:func:`~xvmatch.inference.matching.ground_association.top_calibration`, and
the tilt per window of :func:`~xvmatch.geometry.tilting_camera.fit_tilt_track` on clips whose
one tilt does not hold) asks the model for every box's height a few thousand times a fit, for
the finite differences of its Jacobian. Both sides run here on the same clips in the same run,
``XVMATCH_KERNELS=numpy`` and compiled (the default wherever numba imports), and must give the
same calibration to the bit. The clips are ``tilt_fit_speed.py``'s (``oblique_association.py``'s
scenes, a close low drone: "everything at once" and a tilting gimbal), every 3rd frame of 10 a
second. CPU seconds a clip (the best of ``--repeats``), and the ratio.

Usage:
    python benchmarks/people_fit_speed.py [--seconds 12 36] [--scenes 2] [--repeats 1]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from xvmatch.core import kernel_choice
from xvmatch.geometry import tilting_camera
from xvmatch.inference.matching.ground_association import top_calibration, top_frame_rate

sys.path.insert(0, str(Path(__file__).resolve().parent))

from tilt_fit_speed import CASES, clip


def timed(top: dict, stacked: tuple, size: tuple[int, int], mode: str, repeats: int
          ) -> tuple[float, float, tuple]:
    """The best CPU seconds over ``repeats`` of the clip's calibration and of its tilt track
    (the windows counted at the rate read from the walkers), under the kernel choice ``mode``,
    and what they found."""
    best_calib, best_track, found = np.inf, np.inf, ()
    with kernel_choice.forced(mode):
        for _ in range(repeats):
            t0 = time.process_time()
            calib = top_calibration(top, size)
            t1 = time.process_time()
            fps = top_frame_rate(top, calib).fps  # the rate read, not the people model: untimed
            t2 = time.process_time()
            track = tilting_camera.fit_tilt_track(*stacked, size, fps, calib)
            t3 = time.process_time()
            best_calib, best_track = min(best_calib, t1 - t0), min(best_track, t3 - t2)
            found = (calib, None if track is None else track.tilts_deg)
    return best_calib, best_track, found


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, nargs="+", default=[12.0, 36.0])
    p.add_argument("--scenes", type=int, default=2, help="clips per case and length")
    p.add_argument("--repeats", type=int, default=1)
    args = p.parse_args(argv)
    if kernel_choice.kernels("people") is None:
        print("numba is not installed: no compiled kernel to compare")
        return 1
    print("| clip | s | calibration numpy, s | compiled, s | ratio | tilt track numpy, s "
          "| compiled, s | ratio | same |\n|---|---|---|---|---|---|---|---|---|")
    totals = np.zeros(4)
    for name, case in CASES.items():
        for seconds in args.seconds:
            for k in range(args.scenes):
                stacked, size, top = clip(seconds, case, k)
                if not totals.any():  # numba's import and cached code, once, untimed
                    timed(top, stacked, size, "compiled", 1)
                slow = timed(top, stacked, size, "numpy", args.repeats)
                fast = timed(top, stacked, size, "compiled", args.repeats)
                same = (slow[2][0] == fast[2][0]
                        and np.array_equal(slow[2][1], fast[2][1], equal_nan=True))
                totals += (slow[0], fast[0], slow[1], fast[1])
                print(f"| {name} {k} | {seconds:g} | {slow[0]:.2f} | {fast[0]:.2f} | "
                      f"{slow[0] / max(fast[0], 1e-9):.1f}x | {slow[1]:.2f} | {fast[1]:.2f} | "
                      f"{slow[1] / max(fast[1], 1e-9):.1f}x | {same} |", flush=True)
                if not same:
                    print("the two forms disagree: a bug")
                    return 1
    print(f"\nall clips: calibration {totals[0]:.1f} s numpy, {totals[1]:.1f} s compiled "
          f"({totals[0] / max(totals[1], 1e-9):.1f}x); tilt track {totals[2]:.1f} s, "
          f"{totals[3]:.1f} s ({totals[2] / max(totals[3], 1e-9):.1f}x)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
