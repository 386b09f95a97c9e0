"""Frame-level association accuracy on the CVMHAT dev split, beside the authors' MATLAB figures.

Runs the spatial-distribution association frame by frame on all frames of the 10 dev pairs, with
the camera location O searched (mode A) and given (mode B, top-view id 0), on the clean
ground-truth boxes and with detector-like noise (5% box jitter, 10% misses, 0.3 false boxes per
frame and view; mean over ``--noise-seeds`` seeds). Ids are scrambled per view before association
(the method never compares ids across views; scrambling proves it) and mapped back for scoring.

Prints per-sequence CVIDF1 / CVMA for ours on the reference's own frames next to the reference
(``REFERENCE.md``, the authors' code under Octave), and OVERALL rows over all frames.

Usage:
    python benchmarks/cvmhat_accuracy.py [--data ../shared/data/cvmhat] [--noise-seeds 3]
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import numpy as np

from xvmatch.cues.spatial_search import associate_sequence
from xvmatch.datasets.detector_noise import DetectorNoise, apply_detector_noise
from xvmatch.formats.cvmhat import IMAGE_SIZE, default_cvmhat_dir, read_sequence, sequence_names
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.metrics.cross_view_metrics import count_sequence, summarize

SIZE = IMAGE_SIZE
MODES = {"A": None, "B": 0}


def scramble(frames: dict[int, FrameBoxes], rng: np.random.Generator, keep: int | None):
    """Relabel ids with a random permutation (consistent over frames); return frames and inverse."""
    ids = sorted({int(i) for f in frames.values() for i in f.ids})
    new = rng.permutation(len(ids)) + 10_000
    mapping = dict(zip(ids, new.tolist(), strict=True))
    if keep is not None and keep in mapping:
        mapping[keep] = keep  # the wearer id the user passes in the "O given" setting
    inverse = {v: k for k, v in mapping.items()}
    out = {
        k: FrameBoxes(k, np.array([mapping[int(i)] for i in f.ids], dtype=np.int64), f.boxes)
        for k, f in frames.items()
    }
    return out, inverse


def run(top, hor, camera_id, seed: int) -> dict[int, list[tuple[int, int]]]:
    """Associate with ids scrambled per view, return pairs in the original ids."""
    rng = np.random.default_rng([seed, 7])
    s_top, inv_top = scramble(top, rng, camera_id)
    s_hor, inv_hor = scramble(hor, rng, None)
    pred = associate_sequence(s_top, s_hor, SIZE[0], camera_id=camera_id)
    return {f: [(inv_top[a], inv_hor[b]) for a, b in p] for f, p in pred.items()}


def reference_table(path: Path) -> dict[tuple[str, str], tuple[float, float]]:
    """(mode, name or OVERALL) -> (CVIDF1, CVMA) from REFERENCE.md."""
    out, mode = {}, None
    for line in path.read_text().splitlines():
        m = re.match(r"== mode (\w)", line)
        if m:
            mode = m.group(1)
            continue
        m = re.match(r"(\S+)\s+dev\s+frames=\s*\d+.*CVIDF1=([\d.]+) CVMA=([\d.]+)", line)
        if m and mode:
            out[(mode, m.group(1))] = (float(m.group(2)), float(m.group(3)))
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=default_cvmhat_dir(), help="CVMHAT boxes")
    parser.add_argument("--noise-seeds", type=int, default=3, help="noise draws to average")
    args = parser.parse_args()
    if not (args.data / "REFERENCE.md").exists():
        print(f"CVMHAT data not found at {args.data}; nothing to measure (skipped).")
        return 0
    names = sequence_names(args.data)
    ref = reference_table(args.data / "REFERENCE.md")
    data = {n: read_sequence(args.data, n) for n in names}
    noise = DetectorNoise()
    for mode, camera_id in MODES.items():
        print(f"== mode {mode} ({'O given' if camera_id is not None else 'O searched'})")
        header = f"{'sequence':22s} {'ours@ref frames':>16s} {'reference':>12s} {'ours all':>12s}"
        print(f"{header} {'noisy (mean)':>13s}")
        all_counts, noisy_counts = [], [[] for _ in range(args.noise_seeds)]
        for n in names:
            top, hor = data[n]
            pred = run(top, hor, camera_id, seed=0)
            counts = count_sequence(pred, top, hor)
            all_counts += counts
            ref_frames = [
                int(x)
                for x in (args.data / "reference_pred" / mode / f"{n}.frames").read_text().split()
            ]
            on_ref = summarize(count_sequence(pred, top, hor, frames=ref_frames))
            ours = summarize(counts)
            noisy = []
            for s in range(args.noise_seeds):
                keep = (camera_id,) if camera_id is not None else ()
                n_top = apply_detector_noise(top, SIZE, noise, seed=s, view="top", keep_ids=keep)
                n_hor = apply_detector_noise(hor, SIZE, noise, seed=s, view="hor")
                c = count_sequence(run(n_top, n_hor, camera_id, seed=s), n_top, n_hor)
                noisy_counts[s] += c
                noisy.append(summarize(c))
            r = ref[(mode, n)]
            print(
                f"{n:22s} {on_ref.cvidf1:7.1f} {on_ref.cvma:7.1f} {r[0]:6.1f} {r[1]:5.1f} "
                f"{ours.cvidf1:6.1f} {ours.cvma:5.1f} "
                f"{np.mean([x.cvidf1 for x in noisy]):6.1f} {np.mean([x.cvma for x in noisy]):6.1f}"
            )
        ours = summarize(all_counts)
        noisy = [summarize(c) for c in noisy_counts]
        r = ref[(mode, "OVERALL")]
        print(
            f"{'OVERALL (all frames)':22s} {'':>15s} {r[0]:6.1f} {r[1]:5.1f} "
            f"{ours.cvidf1:6.1f} {ours.cvma:5.1f} "
            f"{np.mean([x.cvidf1 for x in noisy]):6.1f} {np.mean([x.cvma for x in noisy]):6.1f}"
        )
        print(
            f"  clean: CVIDP {ours.cvidp:.1f} CVIDR {ours.cvidr:.1f} ACC9 {ours.acc9:.1f}; "
            f"noisy CVIDF1 per seed: {', '.join(f'{x.cvidf1:.1f}' for x in noisy)}"
        )
    print("columns: CVIDF1 CVMA (percent); noisy = 5% jitter, 10% misses, 0.3 false boxes/frame")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
