"""``xvmatch track`` on rendered oblique top views: the ground-map path against the nadir search.

Each scene is an oblique drone or building camera (``ObliqueSceneConfig``, top pitch
``--top-pitch``) and one handheld camera, rendered at ``--fps`` for ``--frames`` frames and
written as detection files (ids scrambled per view; ``track`` does not read them) beside the
truth. ``track`` runs from the boxes alone (``--image-size`` given, the top size guessed), as it
routes (``--top-view auto``: the top camera calibrated from its people, the frame association
on the ground maps) and forced onto the search (``--top-view nadir``, the route before);
The views are in sync (``--offset 0``, as the warning of an oblique top view asks).
``evaluate --tracks`` scores both: CVIDF1 and the handheld view's IDF1 (its tracks, which the
tracker links by IoU). The handheld camera's shake is off by default (``--hor-wobble 0``,
``--head-turn-std 2``, ``--pan-rate 0``): the renderer's own (1, 8, 0.05) draws a camera seen
about three times a second, whose boxes jump too far between frames for the tracker's IoU
links (``associate --mode video`` on a tracker's ids is the command there).

    .venv/bin/python benchmarks/oblique_tracking.py [--scenes 6] [--frames 240] [--seed 1]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from xvmatch.cli import main as cli
from xvmatch.datasets.oblique_scenes import ObliqueSceneConfig, make_oblique_scene
from xvmatch.formats.mot_boxes import FrameBoxes, write_mot_boxes

ROUTES = {"as routed (auto)": [], "search (--top-view nadir)": ["--top-view", "nadir"]}


def _scores(out: Path, truth: dict[str, Path]) -> tuple[float, float | None]:
    """``(CVIDF1, handheld IDF1 or None without TrackEval)`` of a track run's folder."""
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        cli(["evaluate", "--tracks", str(out), "--top", str(truth["top"]), "--hor",
             str(truth["hor"]), "--json"])
    scores = json.loads(text.getvalue())
    return scores["cross_view"]["cvidf1"], (scores.get("hor") or {}).get("idf1")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", type=int, default=6)
    p.add_argument("--frames", type=int, default=240)
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--top-pitch", type=float, nargs=2, default=(20.0, 45.0))
    p.add_argument("--hor-wobble", type=float, default=0.0)
    p.add_argument("--head-turn-std", type=float, default=2.0)
    p.add_argument("--pan-rate", type=float, default=0.0)
    p.add_argument("--seed", type=int, default=1)
    args = p.parse_args(argv)
    config = ObliqueSceneConfig(top_pitch=tuple(args.top_pitch), fps=args.fps,
                                hor_wobble=args.hor_wobble, head_turn_std=args.head_turn_std,
                                pan_rate=args.pan_rate)
    rng = np.random.default_rng(args.seed)
    print(f"oblique renders, {args.frames} frames at {args.fps:g} a second, top pitch "
          f"{args.top_pitch[0]:g}-{args.top_pitch[1]:g}, boxes only, ids scrambled, seed "
          f"{args.seed}")
    print("| scene | " + " | ".join(f"{n}: CVIDF1, handheld IDF1, s" for n in ROUTES) + " |")
    print("|---|" + "---|" * len(ROUTES))
    means: dict[str, list[float]] = {name: [] for name in ROUTES}
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder)
        for k in range(args.scenes):
            scene = make_oblique_scene(config, args.frames, rng)
            views = {"top": scene.top, "hor": scene.hor["hor1"]}
            truth = {name: tmp / f"{name}_truth.txt" for name in views}
            for name, view in views.items():
                write_mot_boxes(truth[name], view)
                new = rng.permutation(10 ** 4)
                write_mot_boxes(tmp / f"{name}.txt", {f: FrameBoxes(f, new[r.ids], r.boxes)
                                                      for f, r in view.items()})
            size = "x".join(map(str, scene.hor_cameras["hor1"][0].image_size))
            cells = []
            for route, extra in ROUTES.items():
                out = tmp / f"tracks{k}_{len(cells)}"
                start = time.perf_counter()
                code = cli(["track", "--top", str(tmp / "top.txt"), "--hor", str(tmp / "hor.txt"),
                            "--image-size", size, "--offset", "0", "--out", str(out), "--quiet",
                            *extra])
                seconds = time.perf_counter() - start
                if code:
                    cells.append(f"failed ({code})")
                    continue
                cvidf1, hor_idf1 = _scores(out, truth)
                means[route].append(cvidf1)
                hor_text = "-" if hor_idf1 is None else f"{hor_idf1:.1f}"
                cells.append(f"{cvidf1:.1f}, {hor_text}, {seconds:.0f}")
            print(f"| {k} | " + " | ".join(cells) + " |", flush=True)
    print("| mean CVIDF1 | " + " | ".join(f"{np.mean(v):.1f}" if v else "-"
                                         for v in means.values()) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
