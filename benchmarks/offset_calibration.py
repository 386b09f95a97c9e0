"""Calibrate when ``--offset auto`` may shift the videos, on simulated scenes of known offset.

Each scene is a box-level simulation the length of a CVMHAT pair (780 frames, 30 fps, default
:class:`~xvmatch.datasets.box_scene.SceneConfig`), with the detector noise of the foundation
issue (5% jitter, 10% misses, 0.3 false boxes per frame and view). Even scene numbers are
synchronised; odd ones have the top view re-timed by a drawn offset of 8-55 frames either way.
``--unrelated K`` adds K pairs whose views come from two different scenes (no offset exists).
Each pair's 9 clip curves over every offset in +-60 frames are cached in ``--work`` so that other
thresholds can be judged at once (``--reuse``), and so can the coarse-to-fine search that
``--offset auto`` runs (``--step``, default :data:`~xvmatch.cues.offset_estimation.OFFSET_STEP`:
it reads the cached curve at the offsets it would have searched; ``--step 1``: every offset).

Prints one row per pair (truth, minimum, evidence, agreement, verdict) and the summary the
defaults of :func:`~xvmatch.cues.offset_estimation.estimate_offset` were chosen from: no
synchronised or unrelated pair shifted, and how many true shifts are found. CPU only.
README figures: ``python benchmarks/offset_calibration.py --work runs/offset_cal --clean-scenes 12
--unrelated 6`` (58 pairs, about 40-60 s each per worker on the 2-core development machine; add
``--reuse`` to judge cached curves with other ``--min-evidence`` / ``--alpha`` / ``--tolerance``).
"""

from __future__ import annotations

import argparse
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from xvmatch.cues.offset_estimation import (
    AUTO_MAX_OFFSET,
    MIN_OFFSET_EVIDENCE,
    OFFSET_ALPHA,
    OFFSET_STEP,
    OFFSET_TOLERANCE,
    estimate_offset,
    search_offsets,
)
from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene
from xvmatch.datasets.detector_noise import DetectorNoise, apply_detector_noise
from xvmatch.formats.mot_boxes import shift_frames

N_FRAMES = 780  # a CVMHAT pair's length
CLIPS = 9  # estimate_offset's default


def true_offset(scene: int) -> int:
    """The offset scene ``scene`` is given: 0 for even numbers, else +-8..55 frames."""
    if scene % 2 == 0:
        return 0
    rng = np.random.default_rng([scene, 99])
    return int(rng.choice([-1, 1]) * rng.integers(8, 56))


def curves(job: tuple) -> tuple[str, int | None, np.ndarray, np.ndarray]:
    """Clip curves of one pair: ``("sim", scene, noisy)`` or ``("unrelated", k, True)``; the
    truth is None for unrelated views. Cached as an .npz in the work folder."""
    kind, k, noisy, work = job
    name = f"sim_{k}_{'n' if noisy else 'c'}" if kind == "sim" else f"unrelated_{k}"
    path = work / f"{name}.npz"
    truth = true_offset(k) if kind == "sim" else None
    if not path.exists():
        scene = simulate_box_scene(SceneConfig(), n_frames=N_FRAMES, seed=1000 + k)
        top = scene.top
        hor = scene.hor if kind == "sim" else simulate_box_scene(
            SceneConfig(), n_frames=N_FRAMES, seed=2000 + k).hor
        size = scene.config.top_size
        if noisy:
            top = apply_detector_noise(top, size, DetectorNoise(), seed=k, view="top")
            hor = apply_detector_noise(hor, size, DetectorNoise(), seed=k, view="hor")
        if truth:
            top = shift_frames(top, -truth)  # horizontal frame f now shows top frame f + truth
        est = estimate_offset(top, hor, scene.config.hor_size[0], max_offset=AUTO_MAX_OFFSET,
                              n_clips=CLIPS, step=1)
        tmp = path.with_suffix(".tmp.npz")
        np.savez(tmp, clip_costs=est.clip_costs, offsets=est.offsets)
        tmp.replace(path)
    z = np.load(path)
    return path.stem, truth, z["clip_costs"], z["offsets"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", type=Path, required=True, help="folder for the cached curves")
    parser.add_argument("--scenes", type=int, default=40, help="noisy simulated scenes")
    parser.add_argument("--clean-scenes", type=int, default=0,
                        help="the first K scenes also without detector noise")
    parser.add_argument("--unrelated", type=int, default=0, help="noisy pairs of two scenes")
    parser.add_argument("--reuse", action="store_true", help="keep cached curves")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--tolerance", type=int, default=OFFSET_TOLERANCE)
    parser.add_argument("--min-evidence", type=float, default=MIN_OFFSET_EVIDENCE)
    parser.add_argument("--alpha", type=float, default=OFFSET_ALPHA)
    parser.add_argument("--step", type=int, default=OFFSET_STEP,
                        help="coarse step of the search judged (1: every offset)")
    args = parser.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    if not args.reuse:
        for old in args.work.glob("*.npz"):
            old.unlink()
    jobs = ([("sim", k, True, args.work) for k in range(args.scenes)]
            + [("sim", k, False, args.work) for k in range(args.clean_scenes)]
            + [("unrelated", k, True, args.work) for k in range(args.unrelated)])
    start = time.perf_counter()
    groups: dict[str, list[tuple[int | None, object]]] = {}
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        for name, truth, clip_costs, offsets in pool.map(curves, jobs):
            column = {int(o): i for i, o in enumerate(offsets)}
            est = search_offsets(
                lambda tried, c=clip_costs, col=column: c[:, [col[int(o)] for o in tried]],
                AUTO_MAX_OFFSET, args.step, tolerance=args.tolerance,
                min_evidence=args.min_evidence, alpha=args.alpha)
            n = int(np.isfinite(clip_costs).any(axis=1).sum())
            print(f"{name:14s} truth {'-' if truth is None else f'{truth:+d}':>4s}  minimum "
                  f"{est.offset:+4d}  evidence t {est.evidence:6.2f}  "
                  f"{round(est.support * n)}/{n} clips agree (chance {est.chance:.3f})  "
                  f"{est.status} -> {est.applied:+d}", flush=True)
            noise = "clean" if name.endswith("_c") else "noisy"
            kind = ("unrelated" if truth is None else
                    f"{noise} {'synchronised' if truth == 0 else 'shifted'}")
            groups.setdefault(kind, []).append((truth, est))
    print(f"\nstep {args.step}, tolerance {args.tolerance}, min evidence {args.min_evidence}, "
          f"alpha {args.alpha}; "
          f"{len(jobs)} pairs in {time.perf_counter() - start:.0f} s")
    for kind, rows in groups.items():
        if kind.endswith("shifted"):
            found = [(t, e) for t, e in rows if e.applied]
            errors = [abs(e.applied - t) for t, e in found]
            near = [e.evidence for t, e in rows if abs(e.offset - t) <= args.tolerance]
            print(f"{kind}: {len(found)} of {len(rows)} shifts applied, |error| "
                  f"{'-' if not errors else f'mean {np.mean(errors):.1f}, max {max(errors)}'} "
                  f"frames, {sum(abs(e.applied - t) > args.tolerance for t, e in found)} applied "
                  f"more than {args.tolerance} off; smallest evidence of a minimum within "
                  f"{args.tolerance} of the truth "
                  f"{'-' if not near else f'{min(near):.2f}'}")
        else:
            wrong = sum(e.applied != 0 for _, e in rows)
            far = [e.evidence for _, e in rows if abs(e.offset) > args.tolerance]
            print(f"{kind}: {wrong} of {len(rows)} shifted; {len(far)} minima beyond "
                  f"{args.tolerance} frames, largest evidence "
                  f"{'-' if not far else f'{max(far):.2f}'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
