"""Memory and time of one crowded top frame: the search's blocks of candidates (issue 28).

One frame of ``--people`` top-view people (default 1,000: a crowd the search once asked 7.45 GiB
for) and ``--hor`` horizontal boxes, drawn with ``--seed``, associated by the handcrafted search
(``associate_frame``, every O) and by the learned default (``--model``, boxes only), each in a
fresh process so that its peak resident memory is its own. A frame of ``--baseline`` people is
measured the same way in the same run, and the ratios printed.

Usage:
    python benchmarks/crowd_memory.py [--people 1000] [--hor 12] [--baseline 30] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

_CHILD = r"""
import json, resource, sys, time
import numpy as np
people, hor_n, seed, method, model = json.loads(sys.argv[1])
rng = np.random.default_rng(seed)
top = np.c_[rng.uniform(0, 2600, (people, 2)), np.full((people, 2), 20.0)]
hor = np.c_[rng.uniform(0, 2600, (hor_n, 1)), rng.uniform(300, 900, (hor_n, 1)),
            np.full((hor_n, 1), 60.0), rng.uniform(100, 400, (hor_n, 1))]
start = time.perf_counter()
if method == "handcrafted":
    from xvmatch.cues.spatial_search import associate_frame
    pairs = len(associate_frame(top, hor, 2688.0).pairs)
else:
    from xvmatch.formats.mot_boxes import FrameBoxes
    from xvmatch.inference.matching.learned_association import (associate_sequence_learned,
                                                        load_matcher_bundle)
    top_f = {1: FrameBoxes(1, np.arange(people), top)}
    hor_f = {1: FrameBoxes(1, np.arange(hor_n), hor)}
    found = associate_sequence_learned(top_f, hor_f, 2688.0, load_matcher_bundle(model))
    pairs = len(found[1])
seconds = time.perf_counter() - start
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
print(json.dumps({"seconds": seconds, "peak_mb": peak, "pairs": pairs}))
"""


def _run(people: int, hor: int, seed: int, method: str, model: str) -> dict:
    out = subprocess.run([sys.executable, "-c", _CHILD,
                          json.dumps([people, hor, seed, method, model])],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--people", type=int, default=1000, help="top-view people (1000)")
    parser.add_argument("--hor", type=int, default=12, help="horizontal boxes (12)")
    parser.add_argument("--baseline", type=int, default=30, help="people of the baseline (30)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the boxes (0)")
    parser.add_argument("--model", default="default", help="bundle of the learned row")
    args = parser.parse_args()
    print(f"{'method':<12} {'people':>6} {'seconds':>8} {'peak MB':>8} {'pairs':>5}  "
          "(ratio to the baseline frame)")
    for method in ("handcrafted", "learned"):
        base = _run(args.baseline, args.hor, args.seed, method, args.model)
        crowd = _run(args.people, args.hor, args.seed, method, args.model)
        for n, r in ((args.baseline, base), (args.people, crowd)):
            ratio = (f"  x{r['seconds'] / base['seconds']:.0f} time, "
                     f"x{r['peak_mb'] / base['peak_mb']:.1f} memory" if r is crowd else "")
            print(f"{method:<12} {n:>6} {r['seconds']:>8.1f} {r['peak_mb']:>8.0f} "
                  f"{r['pairs']:>5}{ratio}")


if __name__ == "__main__":
    main()
