"""How often ``xvmatch adapt`` refuses, helps and hurts, scored with ground truth on renders.

For each seed, one rendered video (:func:`xvmatch.datasets.tracking_video.render_tracking_video`,
``--frames`` frames at 25 fps, ``--people`` people, ``--scenario``), ids scrambled per view (the
box files' ids only name boxes), each view's images through ONE fixed simulated camera
(:func:`xvmatch.datasets.camera_shift.camera_shift`, ``per_image=False``) whose strength cycles
through ``--strengths`` over the seeds. ``adapt`` runs as the command runs it
(:func:`xvmatch.inference.matching.site_bundle.adapt_to_site`: it holds out the last block of what
it is given, fits on the rest and judges the site bundle by its pairs there, with no labels) on
the first ``--adapt-fraction`` of the video. Then ``associate`` with the images (its appearance
check on, the default) scores the rest of the video, which ``adapt`` never saw, with the source
bundle and with the site bundle; CVIDF1 (%) against the render's ids.

Each video is one of: **refused** by the held-out AUC (as before issue 69), **refused** by the
pairs (the new judgement; the CVIDF1 change the refused bundle would have made is printed, to
show what the refusal avoided), or **accepted**: helped (CVIDF1 up by more than ``--tolerance``),
within the tolerance, or hurt. The target (issue 69): no accepted adaptation hurts.

Rows go to ``--json`` (one file per process, so several processes can share the seeds);
``--summary FILE ...`` prints the table of several such files.

Usage:
    python benchmarks/adapt_gate_eval.py --seeds 1 2 3 --json runs/adapt_gate/a.json
    python benchmarks/adapt_gate_eval.py --summary runs/adapt_gate/*.json
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from site_adaptation_eval import _Images, _score, _shifted, _video

from xvmatch.datasets.synthetic_scenes import SCENARIOS
from xvmatch.inference.adaptation.adaptation_pairs import MiningConfig
from xvmatch.inference.matching.learned_association import (
    LearnedMatcher,
    associate_sequence_learned,
    load_matcher_bundle,
)
from xvmatch.inference.matching.site_bundle import adapt_to_site


def run_seed(seed: int, strength: float, args, matcher: LearnedMatcher) -> dict:
    """One video: adapt on its first part, score both bundles on the rest."""
    t0 = time.perf_counter()
    video, top, hor, back_top, back_hor, cut = _video(seed, args)
    frames = sorted(top)
    images = (_Images(_shifted(video.top_images, strength, 100 + seed)),
              _Images(_shifted(video.hor_images, strength, 200 + seed)))
    part = {f: top[f] for f in frames if f < cut}, {f: hor[f] for f in frames if f < cut}
    run = adapt_to_site(*part, matcher, *images, video.hor_size, config=MiningConfig())
    test = [f for f in frames if f >= cut]

    def cvidf1(model: LearnedMatcher) -> float:
        pred = associate_sequence_learned(
            top, hor, video.hor_size[0], model, hor_height=video.hor_size[1], frames=test,
            top_images=images[0], hor_images=images[1], appearance_check=True)
        return _score(pred, top, hor, back_top, back_hor, video.top, video.hor, test)[1]

    row = {"seed": seed, "strength": strength, "auc_accepted": run.fit.accepted,
           "auc_before": run.fit.auc_before, "auc_after": run.fit.auc_after,
           "source": cvidf1(matcher)}
    if run.fit.accepted:
        site = LearnedMatcher(replace(matcher.bundle, adaptation=run.fit.adaptation))
        row["site"] = cvidf1(site)
        j = run.judgement
        row.update(pairs_accepted=j.accepted, gain=j.gain, error=j.error, frames=j.frames,
                   message=j.message(), pairs_source=vars(j.source), pairs_site=vars(j.site))
    row["seconds"] = time.perf_counter() - t0
    return row


def _verdict(row: dict, tolerance: float) -> str:
    if not row["auc_accepted"]:
        return "refused (AUC)"
    if not row["pairs_accepted"]:
        return "refused (pairs)"
    delta = row["site"] - row["source"]
    return "helped" if delta > tolerance else "hurt" if delta < -tolerance else "within"


def summary(rows: list[dict], tolerance: float) -> None:
    """Print each video and the counts of each verdict."""
    rows = sorted(rows, key=lambda r: r["seed"])
    print(f"seed strength | CVIDF1 source -> site (change) | held-out AUC before -> after | "
          f"pair gain +/- error | verdict (tolerance {tolerance:g})")
    counts: dict[str, list[float]] = {}
    for r in rows:
        verdict = _verdict(r, tolerance)
        change = r["site"] - r["source"] if "site" in r else float("nan")
        counts.setdefault(verdict, []).append(change)
        pairs = f"{r['gain']:+d} +/- {r['error']:.1f}" if "gain" in r else "-"
        site = f"{r['site']:.1f} ({change:+.1f})" if "site" in r else "-"
        print(f"{r['seed']} {r['strength']:g} | {r['source']:.1f} -> {site} | "
              f"{r['auc_before']:.3f} -> {r['auc_after']:.3f} | {pairs} | {verdict}")
    print(f"\n{len(rows)} videos:")
    for verdict in ("refused (AUC)", "refused (pairs)", "helped", "within", "hurt"):
        changes = counts.get(verdict, [])
        extra = ""
        if changes and verdict != "refused (AUC)":
            extra = (f"; CVIDF1 change {min(changes):+.1f} to {max(changes):+.1f}, mean "
                     f"{np.mean(changes):+.2f}"
                     + (" (had it been kept)" if verdict == "refused (pairs)" else ""))
        print(f"  {verdict}: {len(changes)}{extra}")
    kept = [r["site"] - r["source"] for r in rows if "site" in r]
    if kept:
        print(f"  had every AUC-accepted bundle been kept (before issue 69): {len(kept)}, "
              f"CVIDF1 change {min(kept):+.1f} to {max(kept):+.1f}, "
              f"{sum(k < -tolerance for k in kept)} hurt")


def main() -> int:
    """Run the benchmark (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=list(range(1, 21)))
    parser.add_argument("--strengths", type=float, nargs="+", default=[0.0, 1.0, 2.0, 3.0],
                        help="camera-change strengths, cycled over the seeds (seed s gets "
                        "strengths[(s - 1) %% len])")
    parser.add_argument("--frames", type=int, default=240)
    parser.add_argument("--people", type=int, nargs=2, default=[10, 16])
    parser.add_argument("--scenario", choices=SCENARIOS, default="drone")
    parser.add_argument("--adapt-fraction", type=float, default=0.75)
    parser.add_argument("--tolerance", type=float, default=0.5,
                        help="CVIDF1 points an accepted adaptation may lose and still count")
    parser.add_argument("--json", default=None, help="write the rows here")
    parser.add_argument("--summary", nargs="+", default=None,
                        help="print the table of these --json files and stop")
    args = parser.parse_args()
    if args.summary:
        rows = [r for f in args.summary for r in json.loads(Path(f).read_text())]
        summary(rows, args.tolerance)
        return 0
    print("$ python " + shlex.join(sys.argv))
    t0 = time.perf_counter()
    matcher = load_matcher_bundle("default")
    rows = []
    for seed in args.seeds:
        strength = args.strengths[(seed - 1) % len(args.strengths)]
        rows.append(run_seed(seed, strength, args, matcher))
        print(f"seed {seed}: {rows[-1]['seconds']:.0f} s", file=sys.stderr, flush=True)
        if args.json:
            Path(args.json).parent.mkdir(parents=True, exist_ok=True)
            tmp = Path(args.json + ".tmp")
            tmp.write_text(json.dumps(rows, indent=1))
            os.replace(tmp, args.json)
    summary(rows, args.tolerance)
    print(f"wall time {time.perf_counter() - t0:.0f} s ({os.cpu_count()} CPUs)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
