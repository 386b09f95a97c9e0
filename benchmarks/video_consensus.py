"""Video mode's pairs kept consistent along each view's tracks, on the real CVMHAT development
pairs, boxes only: with the ground-truth tracks and with a tracker's id switches.

Per sequence, ``xvmatch associate --mode frame`` (handcrafted search, and ``--model default``)
gives each frame's pairs; the consensus (:mod:`xvmatch.inference.linking.pair_consensus`) then
reads each view's ids as track ids. Three kinds of ids, each view's ids scrambled:

* ``tracks``: the files' own ids, whole tracks (ground truth);
* ``switch 150`` / ``switch 300``: a tracker's ids, two tracks of a view swapping ids about every
  150 (300) frames per track (seeded), in both views; scored on the true ids.

Columns: ``frame`` (each frame on its own), ``consensus`` (the default switch cost) and
``whole track`` (no change of partner along a track: one partner per track or none, the rule
before the switch cost). CVIDF1, the mean over the sequences.

    .venv/bin/python benchmarks/video_consensus.py [--sequences NAME ...] [--seed 0]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from xvmatch.formats.cvmhat import default_cvmhat_dir, read_sequence, sequence_names
from xvmatch.formats.mot_boxes import read_predictions
from xvmatch.inference.linking.pair_consensus import tracklet_consensus
from xvmatch.metrics.cross_view_metrics import count_sequence, summarize

KINDS = {"tracks": None, "switch 150": 300, "switch 300": 600}
"""Each kind of ids and its ``every``: a view swaps two tracks' ids with probability
``n / every`` a frame (``n`` its people), so each track about every ``every / 2`` frames."""


def tracker_ids(frames: dict, every: int | None, rng: np.random.Generator) -> dict:
    """``{(frame, true id): tracker id}``: ids scrambled, and with ``every``, two tracks present
    swapping ids with probability ``n / every`` a frame (``n`` people present; each track
    about every ``every / 2`` frames: an id switch)."""
    current: dict[int, int] = {}
    out = {}
    for f in sorted(frames):
        ids = [int(i) for i in frames[f].ids]
        for i in ids:
            current.setdefault(i, 1000 + 7919 * len(current) % 100003)
        if every and len(ids) >= 2 and rng.random() < len(ids) / every:
            a, b = rng.choice(ids, 2, replace=False)
            current[a], current[b] = current[b], current[a]
        out.update({(f, i): current[i] for i in ids})
    return out


def score(pairs: dict, top: dict, hor: dict, every: int | None, seed: int) -> tuple[float, ...]:
    """CVIDF1 of the frame pairs, the consensus and the whole-track rule, on tracker ids."""
    rng = np.random.default_rng(seed)
    to_t, to_h = tracker_ids(top, every, rng), tracker_ids(hor, every, rng)
    back_t = {(f, t): i for (f, i), t in to_t.items()}
    back_h = {(f, h): i for (f, i), h in to_h.items()}
    frames = sorted(set(top) | set(hor))
    seen = {f: [(to_t[f, a], to_h[f, b]) for a, b in p] for f, p in pairs.items()}
    present = {f: (np.array([to_t[f, int(i)] for i in top[f].ids] if f in top else [], np.int64),
                   np.array([to_h[f, int(i)] for i in hor[f].ids] if f in hor else [], np.int64))
               for f in frames}
    out = [summarize(count_sequence(pairs, top, hor)).cvidf1]
    for cost in (None, np.inf):
        kept = (tracklet_consensus(seen, present) if cost is None
                else tracklet_consensus(seen, present, switch_cost=cost))
        true = {f: [(back_t[f, a], back_h[f, b]) for a, b in p] for f, p in kept.items()}
        out.append(summarize(count_sequence(true, top, hor)).cvidf1)
    return tuple(out)


def frame_pairs(data: Path, name: str, model: bool, folder: str) -> dict:
    """Each frame's pairs from the command line, ``--mode frame``."""
    out = os.path.join(folder, f"{name}{'.learned' if model else ''}.csv")
    cmd = [sys.executable, "-m", "xvmatch.cli", "associate", "--top",
           str(data / f"{name}_top.txt"), "--hor", str(data / f"{name}_hor.txt"), "--mode",
           "frame", "--out", out, "--quiet", *(["--model", "default"] if model else [])]
    subprocess.run(cmd, check=True)
    return read_predictions(out)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=default_cvmhat_dir())
    parser.add_argument("--sequences", nargs="+", default=None)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if not args.data.is_dir():
        print(f"no CVMHAT boxes at {args.data}", file=sys.stderr)
        return 1
    names = args.sequences or sequence_names(args.data)
    rows: dict[tuple[str, str], list] = {}
    with tempfile.TemporaryDirectory() as folder:
        for name in names:
            top, hor = read_sequence(args.data, name)
            for method, model in (("handcrafted", False), ("learned", True)):
                pairs = frame_pairs(args.data, name, model, folder)
                for kind, every in KINDS.items():
                    rows.setdefault((method, kind), []).append(
                        score(pairs, top, hor, every, args.seed))
    print(f"{len(names)} CVMHAT sequences, boxes only, mean CVIDF1 (seed {args.seed})")
    print("| matcher | ids | frame | consensus | whole track |")
    print("|---|---|---|---|---|")
    for (method, kind), values in rows.items():
        mean = np.mean(np.array(values), axis=0)
        print(f"| {method} | {kind} | " + " | ".join(f"{v:.1f}" for v in mean) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
