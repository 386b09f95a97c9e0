"""A nadir top view through ``associate``'s two paths, on the real CVMHAT development pairs.

``associate --top-view auto`` sends a top view that looks straight down to the (O, theta)
search, which assumes the handheld camera stands at a top-view person; ``--top-view oblique``
forces the ground-map path (the top camera calibrated from its people, the handheld camera
registered on its map wherever it stands). Per sequence, boxes only, ``--mode video``, every
``--step``-th frame (``--fps 30``: the frames keep the videos' own numbers, 30 a second), each
view's ids scrambled by a seeded permutation (consistent over time, as track ids): CVIDF1, the
pair-frames kept and the seconds of each path. Used to decide the routing
(docs/notes/oblique_top_camera.md, thirty-seventh session).

    .venv/bin/python benchmarks/nadir_routes.py [--step 5] [--sequences NAME ...] [--seed 0]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from xvmatch.cli import main as cli
from xvmatch.formats.cvmhat import IMAGE_SIZE, default_cvmhat_dir, read_sequence, sequence_names
from xvmatch.formats.mot_boxes import FrameBoxes, read_predictions, write_mot_boxes
from xvmatch.metrics.cross_view_metrics import count_sequence, summarize

ROUTES = {"search (auto)": [], "ground path (oblique)": [
    "--top-view", "oblique", "--top-image-size", "x".join(map(str, IMAGE_SIZE))]}


def scrambled(frames: dict, keep: list[int], rng: np.random.Generator) -> tuple[dict, dict]:
    """The ``keep`` frames with ids permuted (the same permutation over time) and the inverse."""
    ids = sorted({int(i) for f in keep if f in frames for i in frames[f].ids})
    new = dict(zip(ids, (rng.permutation(len(ids)) + 100).tolist(), strict=True))
    out = {f: FrameBoxes(f, np.array([new[int(i)] for i in frames[f].ids], np.int64),
                         frames[f].boxes) for f in keep if f in frames}
    return out, {v: k for k, v in new.items()}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, default=default_cvmhat_dir())
    p.add_argument("--sequences", nargs="+", default=None)
    p.add_argument("--step", type=int, default=5, help="every STEP-th frame (30 a second)")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    if not args.data.is_dir():
        print(f"no CVMHAT boxes at {args.data}", file=sys.stderr)
        return 1
    rng = np.random.default_rng(args.seed)
    scores: dict[str, list[float]] = {name: [] for name in ROUTES}
    print(f"CVMHAT dev pairs, boxes only, --mode video, every {args.step}th frame, ids scrambled")
    print("| sequence | " + " | ".join(f"{n}: CVIDF1, kept, s" for n in ROUTES) + " |")
    print("|---|" + "---|" * len(ROUTES))
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder)
        for name in args.sequences or sequence_names(args.data):
            top, hor = read_sequence(args.data, name)
            keep = sorted(set(top) & set(hor))[::args.step]
            (s_top, back_top), (s_hor, back_hor) = (scrambled(v, keep, rng) for v in (top, hor))
            write_mot_boxes(tmp / "top.txt", s_top)
            write_mot_boxes(tmp / "hor.txt", s_hor)
            cells = []
            for route, extra in ROUTES.items():
                t = time.perf_counter()
                code = cli(["associate", "--top", str(tmp / "top.txt"), "--hor",
                            str(tmp / "hor.txt"), "--mode", "video", "--fps", "30",
                            "--out", str(tmp / "pred.csv"), "--quiet", *extra])
                seconds = time.perf_counter() - t
                pred = read_predictions(tmp / "pred.csv") if code == 0 else {}
                pairs = {f: [(back_top[a], back_hor[b]) for a, b in v] for f, v in pred.items()}
                score = summarize(count_sequence(pairs, {f: top[f] for f in keep if f in top},
                                                 {f: hor[f] for f in keep if f in hor})).cvidf1
                scores[route].append(score)
                kept = sum(len(v) for v in pairs.values())
                cells.append(f"{score:.1f}, {kept}, {seconds:.0f}")
            print(f"| {name} | " + " | ".join(cells) + " |", flush=True)
    print("| mean CVIDF1 | " + " | ".join(f"{np.mean(v):.1f}" for v in scores.values()) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
