"""Joint cycle-consistent MIP against pairwise Hungarian on rendered 1 top + K ego scenes.

Per scene (:func:`xvmatch.datasets.multi_ego_scenes.render_multi_ego`, seed ``[--seed, i]``)
and setting (``gt``: ground-truth boxes; ``det``: the visibility-dependent detector noise of
the synthetic evaluations, each detection standing for the ground-truth box it overlaps with
IoU >= 0.3), the boxes of every view are shuffled with a seed (ids scrambled: no method sees
an id), the cost matrices of every view pair are built once per variant
(:func:`xvmatch.inference.views.multi_view_costs.multi_view_costs`; ``learned``: the shipped bundle
with images and cameras for top-ego; ``handcrafted``: the spatial-distribution search from
boxes, O searched; ego-ego: the shipped appearance network in both) and three solvers run on
the same costs: pairwise Hungarian, Hungarian made consistent (greedy), and the joint MIP.
Prints, per variant, setting and solver, the Eq. 9 accuracy and CVIDF1 of each view pair, their
mean, the cycle-inconsistency rate and the solve time.

``--calibrate`` instead fits the calibrations of the ego-ego appearance distance and of the
handcrafted top-ego vote cost (threshold, slope) on scenes of seed ``--seed + 1`` and prints
them (:data:`~xvmatch.inference.views.multi_view_costs.EGO_APPEARANCE`,
:data:`~xvmatch.inference.views.multi_view_costs.SPATIAL_VOTE`).

    python benchmarks/multi_ego_eval.py --scenes 40 --seed 1000

``--tracks`` compares, on scenes of ``--frames`` frames and the learned costs, the
frame-by-frame joint MIP of ``associate-multi`` with ``associate-multi --tracks``
(:func:`xvmatch.inference.views.multi_ego_tracking.track_multi_view`: tracklets per view, the
egocentric ones linked by motion and, for the smoothing, cut where their confident top-view
partner switches, smoothing each frame's costs; the joint program per frame;
ids carried over time) on ground-truth boxes and on boxes with the noise of
``xvmatch noise`` (its defaults: 5% jitter, 10% misses, 0.3 false boxes per frame and view;
one run per ``--noise-seeds`` seed); besides the per-frame pair scores, ``IDF1 over time`` is
the identity F1 of each view's ids over the whole scene (a global id must name one person in
every frame it is used).

    python benchmarks/multi_ego_eval.py --tracks --scenes 16 --frames 20 --n-ego 3
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass

import numpy as np

from xvmatch.cues.matcher_inputs import appearance_cost
from xvmatch.datasets.detector_noise import DetectorNoise, apply_detector_noise
from xvmatch.datasets.multi_ego_scenes import MultiEgoFrame, render_multi_ego, view_names
from xvmatch.datasets.pair_trials import match_to_ground_truth, noise_seed_of
from xvmatch.datasets.visibility_noise import VisibilityNoise, apply_visibility_noise
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.geometry.camera import FrameCameras
from xvmatch.inference.matching.learned_association import load_matcher_bundle
from xvmatch.inference.views.multi_ego_tracking import pairs_from_ids, track_multi_view
from xvmatch.inference.views.multi_view_assignment import (
    MIP_MAX_TRIANGLES,
    consistent_hungarian,
    pairwise_hungarian,
    solve_multi_view,
    view_pairs,
)
from xvmatch.inference.views.multi_view_costs import multi_view_costs, spatial_vote_cost
from xvmatch.metrics.multi_view_metrics import (
    count_views,
    cycle_counts,
    mean_scores,
    summarize_views,
)

SOLVERS = ("hungarian", "greedy", "mip")


@dataclass
class _Images:
    frames: dict[int, np.ndarray]

    def get(self, frame: int) -> np.ndarray:
        return self.frames[frame]


@dataclass
class _Cameras:
    frames: dict[int, FrameCameras]

    def get(self, frame: int) -> FrameCameras:
        return self.frames[frame]


@dataclass
class Sample:
    """One scene in one setting: shuffled boxes per view and what each stands for."""

    frames: list[MultiEgoFrame]
    boxes: list[dict[int, FrameBoxes]]
    stands_for: list[dict[int, np.ndarray]]
    gt_ids: list[dict[int, np.ndarray]]


def make_sample(frames: list[MultiEgoFrame], scene: int, setting: str, seed: int,
                noise_seed: int = 0) -> Sample:
    """Boxes of every view, shuffled, in ``setting`` (``gt``, ``det`` or ``noise``: the
    defaults of ``xvmatch noise`` with seed ``noise_seed``)."""
    n_views = len(frames[0].views)
    boxes, stands, gts = [], [], []
    for v in range(n_views):
        gt = {f.frame: FrameBoxes(f.frame, f.views[v].labels.ids, f.views[v].labels.boxes)
              for f in frames}
        if setting == "det":
            visible = {f.frame: f.views[v].labels.visible for f in frames}
            det = apply_visibility_noise(gt, visible, frames[0].views[v].camera.image_size,
                                         VisibilityNoise(), noise_seed_of(seed, 10 * scene + v),
                                         "top" if v == 0 else "ego")
        elif setting == "noise":
            det = apply_detector_noise(gt, frames[0].views[v].camera.image_size, DetectorNoise(),
                                       noise_seed_of(noise_seed, 10 * scene + v),
                                       "top" if v == 0 else "hor")
        else:
            det = gt
        b_v, s_v = {}, {}
        for f in frames:
            rec = det[f.frame]
            ids = (rec.ids if setting == "gt" else
                   match_to_ground_truth(rec.boxes, gt[f.frame].boxes, gt[f.frame].ids))
            key = [seed, scene, f.frame, v, setting != "gt"]
            key += [noise_seed] if setting == "noise" else []
            order = np.random.default_rng(key).permutation(len(ids))
            b_v[f.frame] = FrameBoxes(f.frame, np.arange(len(ids), dtype=np.int64),
                                      np.asarray(rec.boxes, float)[order].reshape(-1, 4))
            s_v[f.frame] = np.asarray(ids, np.int64)[order]
        boxes.append(b_v)
        stands.append(s_v)
        gts.append({f.frame: gt[f.frame].ids for f in frames})
    return Sample(frames, boxes, stands, gts)


def sample_costs(sample: Sample, variant: str, matcher) -> dict:
    """The :class:`FrameProblem` of every frame of a sample for one cost variant."""
    frames = sample.frames
    n_views = len(frames[0].views)
    images = [_Images({f.frame: f.views[v].image for f in frames}) for v in range(n_views)]
    cameras = [_Cameras({f.frame: FrameCameras(f.views[0].camera, f.views[v].camera)
                         for f in frames}) for v in range(1, n_views)]
    sizes = [frames[0].views[v].camera.image_size for v in range(1, n_views)]
    learned = variant == "learned"
    return multi_view_costs(
        sample.boxes, sizes, [f.frame for f in frames],
        matcher=matcher if learned else None, appearance=matcher, images=images,
        cameras=cameras if learned else None,
    )


def solve(problem, solver: str, time_limit: float):
    """One frame's solution with ``solver``."""
    if solver == "hungarian":
        return pairwise_hungarian(problem.sizes, problem.costs, problem.gamma)
    if solver == "greedy":
        return consistent_hungarian(problem.sizes, problem.costs, problem.gamma)
    return solve_multi_view(problem.sizes, problem.costs, problem.gamma, time_limit)


def _fit(d: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Logistic fit ``P(same) = sigmoid(slope (threshold - d))``: (threshold, slope, log-loss)."""
    from scipy.optimize import minimize

    def loss(theta: np.ndarray) -> float:
        z = theta[1] * (theta[0] - d)
        return float(np.mean(np.logaddexp(0.0, z) - y * z))

    fit = minimize(loss, np.array([0.3, 10.0]), method="Nelder-Mead")
    return float(fit.x[0]), float(fit.x[1]), float(fit.fun)


def calibrate(args: argparse.Namespace, matcher) -> None:
    """Fit the ego-ego appearance and the handcrafted top-ego vote calibrations on scenes of
    seed ``--seed + 1`` (ground-truth boxes)."""
    found: dict[str, tuple[list, list]] = {"ego-ego": ([], []), "top-ego vote": ([], [])}
    for i in range(args.scenes):
        for f in render_multi_ego([args.seed + 1, i], args.n_ego, args.frames):
            desc = [matcher.descriptors(v.image, v.labels.boxes) if len(v.labels) else None
                    for v in f.views]
            for a, b in view_pairs(len(f.views)):
                la, lb = f.views[a].labels, f.views[b].labels
                if not len(la) or not len(lb):
                    continue
                if a == 0:
                    d = spatial_vote_cost(la.boxes, lb.boxes, f.views[b].camera.width)
                    key = "top-ego vote"
                else:
                    d, key = appearance_cost(desc[a], desc[b]), "ego-ego"
                found[key][0].append(d.ravel())
                found[key][1].append((la.ids[:, None] == lb.ids[None, :]).ravel())
    print(f"# calibration on {args.scenes} scenes, seed {args.seed + 1}, ground-truth boxes")
    for key, (dist, same) in found.items():
        d, y = np.concatenate(dist), np.concatenate(same).astype(float)
        threshold, slope, loss = _fit(d, y)
        prior = float(y.mean())
        neutral = threshold - np.log(prior / (1.0 - prior)) / slope
        print(f"{key}: {len(d)} pairs, {int(y.sum())} same person; P = 1/2 at {threshold:.3f}, "
              f"slope {slope:.1f}, log-loss {loss:.4f}; prior odds removed: threshold "
              f"{neutral:.3f}")


def _print_header(header: list[str]) -> None:
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))


def _pair_cells(per_frame: list, status: dict[str, int],
                triangles: int | None = None) -> tuple[list[str], str]:
    """The cells of one row: per view pair ACC9 / CVIDF1, the two means; and the statuses,
    with the most triangles one frame's program added (MIP rows)."""
    scores = summarize_views(per_frame)
    mean = mean_scores(scores)
    cells = [f"{scores[p].acc9:.1f} / {scores[p].cvidf1:.1f}" for p in sorted(scores)]
    cells += [f"{mean['acc9']:.1f}", f"{mean['cvidf1']:.1f}"]
    stat = ", ".join(f"{k} {v}" for k, v in sorted(status.items()))
    if triangles is not None:
        stat += f"; triangles <= {triangles} (budget {MIP_MAX_TRIANGLES})"
    return cells, stat


def identity_f1(pred: list[np.ndarray], truth: list[np.ndarray], n_truth: int) -> tuple[int, int]:
    """``(IDTP, IDTP denominator)`` of one view over a scene: predicted and true ids of its
    boxes frame by frame (true id < 0: a false box), matched one-to-one over the scene
    (Hungarian on co-occurrence counts); IDF1 = 2 IDTP / (predicted boxes + true boxes)."""
    from scipy.optimize import linear_sum_assignment

    p, t = np.concatenate(pred), np.concatenate(truth)
    real = t >= 0
    if not real.any():
        return 0, p.size + n_truth
    pu, pi = np.unique(p[real], return_inverse=True)
    tu, ti = np.unique(t[real], return_inverse=True)
    counts = np.zeros((pu.size, tu.size))
    np.add.at(counts, (pi, ti), 1.0)
    r, c = linear_sum_assignment(-counts)
    return int(counts[r, c].sum()), p.size + n_truth


def run_tracks(args: argparse.Namespace, matcher) -> None:
    """Frame-by-frame joint MIP against ``associate-multi --tracks`` (the module docstring)."""
    names = view_names(args.n_ego)
    settings = [("gt", 0)] + [("noise", s) for s in args.noise_seeds]
    methods = ("frame-by-frame MIP", "tracks")
    counts = {(s, m): [] for s, _ in settings for m in methods}
    cycles = {k: [0, 0] for k in counts}
    seconds = {k: 0.0 for k in counts}
    idf = {k: [0, 0] for k in counts}
    status: dict[tuple, dict[str, int]] = {k: {} for k in counts}
    triangles = dict.fromkeys(counts, 0)
    start = time.perf_counter()
    for i in range(args.scenes):
        frames = render_multi_ego([args.seed, i], args.n_ego, args.frames)
        for setting, noise_seed in settings:
            sample = make_sample(frames, i, setting, args.seed, noise_seed)
            problems = sample_costs(sample, "learned", matcher)
            order = sorted(problems)
            answers = {}
            t0 = time.perf_counter()
            per_frame = {f: solve(problems[f], "mip", args.time_limit) for f in order}
            seconds[(setting, methods[0])] += time.perf_counter() - t0
            for sol in per_frame.values():
                status[(setting, methods[0])][sol.status] = (
                    status[(setting, methods[0])].get(sol.status, 0) + 1)
                triangles[(setting, methods[0])] = max(triangles[(setting, methods[0])],
                                                       sol.triangles)
            offset = np.cumsum([0, *(max((int(p.max()) + 1 for p in per_frame[f].person
                                          if p.size), default=0) for f in order)])
            answers[methods[0]] = {f: [p + 1 + offset[k] for p in per_frame[f].person]
                                   for k, f in enumerate(order)}
            t0 = time.perf_counter()
            tracks = track_multi_view(sample.boxes, problems, args.clip_length,
                                      time_limit=args.time_limit)
            seconds[(setting, methods[1])] += time.perf_counter() - t0
            for st in tracks.statuses:
                status[(setting, methods[1])][st] = status[(setting, methods[1])].get(st, 0) + 1
            triangles[(setting, methods[1])] = max(triangles[(setting, methods[1])],
                                                   tracks.max_triangles)
            answers[methods[1]] = {f: [tracks.person[v][f] for v in range(len(names))]
                                   for f in order}
            for method, ids in answers.items():
                key = (setting, method)
                for f in order:
                    pairs = pairs_from_ids(ids[f])
                    views = range(len(names))
                    counts[key].append(count_views([sample.gt_ids[v][f] for v in views],
                                                   [sample.stands_for[v][f] for v in views],
                                                   pairs, f))
                    broken, closed = cycle_counts(pairs, problems[f].sizes)
                    cycles[key][0] += broken
                    cycles[key][1] += closed
                for v in range(len(names)):
                    tp, den = identity_f1([ids[f][v] for f in order],
                                          [sample.stands_for[v][f] for f in order],
                                          sum(len(sample.gt_ids[v][f]) for f in order))
                    idf[key][0] += tp
                    idf[key][1] += den
        print(f"scene {i + 1}/{args.scenes} ({time.perf_counter() - start:.0f} s)",
              file=sys.stderr)
    pair_names = [f"{names[a]}-{names[b]}" for a, b in view_pairs(len(names))]
    print(f"# {args.scenes} scenes x {args.frames} frames, 1 top + {args.n_ego} ego, seed "
          f"{args.seed}, learned costs, clips of {args.clip_length}; noise: xvmatch noise "
          f"defaults, seeds {args.noise_seeds}; Eq. 9 accuracy / CVIDF1 (%) per view pair")
    _print_header(["boxes", "method", *pair_names, "mean ACC9", "mean CVIDF1",
                   "IDF1 over time", "inconsistent triples", "ms/frame", "status"])
    for key, per_frame in counts.items():
        cells, stat = _pair_cells(per_frame, status[key], triangles[key])
        print("| " + " | ".join([*key, *cells,
                                 f"{200.0 * idf[key][0] / max(idf[key][1], 1):.1f}",
                                 str(cycles[key][0]),
                                 f"{1000 * seconds[key] / len(per_frame):.1f}", stat]) + " |")
    print(f"# total {time.perf_counter() - start:.0f} s")


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=40)
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--n-ego", type=int, default=3)
    parser.add_argument("--frames", type=int, default=1, help="frames per scene")
    parser.add_argument("--settings", nargs="+", default=["gt", "det"], choices=("gt", "det"))
    parser.add_argument("--variants", nargs="+", default=["learned", "handcrafted"],
                        choices=("learned", "handcrafted"))
    parser.add_argument("--time-limit", type=float, default=10.0)
    parser.add_argument("--calibrate", action="store_true")
    parser.add_argument("--tracks", action="store_true",
                        help="frame-by-frame MIP against associate-multi --tracks")
    parser.add_argument("--clip-length", type=int, default=10)
    parser.add_argument("--noise-seeds", type=int, nargs="+", default=[1, 2, 3])
    args = parser.parse_args(argv)
    matcher = load_matcher_bundle("default")
    if args.calibrate:
        calibrate(args, matcher)
        return 0
    if args.tracks:
        run_tracks(args, matcher)
        return 0
    names = view_names(args.n_ego)
    pair_names = [f"{names[a]}-{names[b]}" for a, b in view_pairs(len(names))]
    counts = {(v, s, m): [] for v in args.variants for s in args.settings for m in SOLVERS}
    cycles = {k: [0, 0] for k in counts}
    seconds = {k: 0.0 for k in counts}
    status: dict[tuple, dict[str, int]] = {k: {} for k in counts}
    triangles = dict.fromkeys(counts, 0)
    start = time.perf_counter()
    for i in range(args.scenes):
        frames = render_multi_ego([args.seed, i], args.n_ego, args.frames)
        for setting in args.settings:
            sample = make_sample(frames, i, setting, args.seed)
            for variant in args.variants:
                problems = sample_costs(sample, variant, matcher)
                for solver in SOLVERS:
                    key = (variant, setting, solver)
                    for f, problem in problems.items():
                        t0 = time.perf_counter()
                        sol = solve(problem, solver, args.time_limit)
                        seconds[key] += time.perf_counter() - t0
                        status[key][sol.status] = status[key].get(sol.status, 0) + 1
                        triangles[key] = max(triangles[key], sol.triangles)
                        views = range(len(names))
                        counts[key].append(count_views([sample.gt_ids[v][f] for v in views],
                                                       [sample.stands_for[v][f] for v in views],
                                                       sol.pairs, f))
                        broken, closed = cycle_counts(sol.pairs, problem.sizes)
                        cycles[key][0] += broken
                        cycles[key][1] += closed
        print(f"scene {i + 1}/{args.scenes} ({time.perf_counter() - start:.0f} s)",
              file=sys.stderr)
    n_frames = args.scenes * args.frames
    print(f"# {args.scenes} scenes x {args.frames} frame(s), 1 top + {args.n_ego} ego, seed "
          f"{args.seed}; Eq. 9 accuracy / CVIDF1 (%) per view pair")
    _print_header(["variant", "setting", "solver", *pair_names, "mean ACC9", "mean CVIDF1",
                   "inconsistent %", "ms/frame", "status"])
    for key, per_frame in counts.items():
        broken, closed = cycles[key]
        rate = 100.0 * broken / (broken + closed) if broken + closed else 0.0
        cells, stat = _pair_cells(per_frame, status[key],
                                  triangles[key] if key[2] == "mip" else None)
        print("| " + " | ".join([*key, *cells, f"{rate:.1f}",
                                 f"{1000 * seconds[key] / n_frames:.1f}", stat]) + " |")
    print(f"# total {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
