"""The deployed matcher (ONNX bundle, no torch) on synthetic trials, in each input setting.

The trials are those every synthetic evaluation uses (:mod:`xvmatch.datasets.pair_trials`:
ground-truth or detector-noise boxes, shuffled per view, ids scrambled), so the learned rows
score exactly the frames the handcrafted baseline scores. Per trial and setting
(:data:`~xvmatch.cues.matcher_inputs.INPUT_SETTINGS`): the matcher's cost matrix from the
boxes, the ONNX appearance cost (with images) and the camera cues and rectified geometry (with
cameras); the Hungarian assignment with gamma; the Eq. 9 accuracy and the cross-view ID scores
of :func:`~xvmatch.metrics.cross_view_metrics.count_pair`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from xvmatch.cues.matcher_inputs import INPUT_SETTINGS, appearance_cost, matcher_inputs
from xvmatch.datasets.pair_trials import PairTrial
from xvmatch.evaluation.frame_check_threshold import FrameSamples
from xvmatch.geometry.camera import FrameCameras
from xvmatch.inference.adaptation.site_adaptation import pair_auc
from xvmatch.inference.linking.assignment import assign
from xvmatch.inference.matching.frame_check import FEATURES, FrameCheck, frame_check_features
from xvmatch.inference.matching.learned_association import LearnedMatcher
from xvmatch.metrics.cross_view_metrics import (
    CrossViewScores,
    FrameCounts,
    count_pair,
    summarize,
)

__all__ = ["OnnxAppearanceCoster", "cue_auc", "frame_accuracy", "frame_check_samples",
           "frame_checked_costs", "frame_count", "matcher_costs", "score_matcher"]


class OnnxAppearanceCoster:
    """Appearance costs of a bundle's ONNX network between the boxes of two images, with the
    call signature of the trials' coster (:func:`xvmatch.datasets.pair_trials.scene_trials`).

    Args:
        matcher: a bundle with an appearance network.
    """

    def __init__(self, matcher: LearnedMatcher) -> None:
        if matcher.bundle.manifest.appearance is None:
            raise ValueError(f"{matcher.bundle.name}: this bundle has no appearance network")
        self.matcher = matcher

    def __call__(self, top_image: np.ndarray, top_boxes: np.ndarray, ego_image: np.ndarray,
                 ego_boxes: np.ndarray) -> np.ndarray:
        """``(M, N)`` appearance costs in [0, 1]."""
        return appearance_cost(self.matcher.descriptors(top_image, top_boxes),
                               self.matcher.descriptors(ego_image, ego_boxes))


def cue_auc(trials: Sequence[PairTrial], setting: str) -> float:
    """Verification AUC of the trials' appearance cue in one box setting: how often a true pair
    (two boxes of one person) costs less than a box against another person's box of the other
    view in its frame, pooled over the frames. It says how much the cue itself still tells,
    apart from how the matcher weighs it (0.5: nothing).

    Raises:
        ValueError: a trial of that setting without appearance costs.
    """
    pos, neg = [], []
    for t in trials:
        if t.setting != setting:
            continue
        if t.app is None:
            raise ValueError(f"{t.scene}/{t.frame}: no appearance costs; build the trials with "
                             "an OnnxAppearanceCoster")
        top, ego = np.asarray(t.det_top_ids), np.asarray(t.det_ego_ids)
        same = (top[:, None] == ego[None, :]) & (top[:, None] >= 0)
        real = (top[:, None] >= 0) & (ego[None, :] >= 0)  # false detections stand for no one
        pos.append(t.app[same])
        neg.append(t.app[real & ~same])
    if not pos:
        return float("nan")
    return pair_auc(np.concatenate(pos), np.concatenate(neg))


def matcher_costs(matcher: LearnedMatcher, trials: Sequence[PairTrial], setting: str,
                  batch_size: int = 64) -> list[np.ndarray]:
    """``(M, N)`` cost matrices (input order) of each trial in one input setting.

    Raises:
        ValueError: an unknown setting, or one whose cues the matcher or the trials lack
            (``app`` needs trials built with an :class:`OnnxAppearanceCoster`).
    """
    if setting not in INPUT_SETTINGS:
        raise ValueError(f"setting must be one of {', '.join(INPUT_SETTINGS)}, got {setting!r}")
    cues, rectified = INPUT_SETTINGS[setting]
    missing = [c for c in cues if c not in matcher.cues]
    if missing:
        raise ValueError(f"{matcher.bundle.name} takes no {', '.join(missing)} cue: it cannot "
                         f"run the {setting!r} setting")
    manifest = matcher.bundle.manifest
    inputs = []
    for t in trials:
        if "app" in cues and t.app is None:
            raise ValueError(f"{t.scene}/{t.frame}: no appearance costs; build the trials with "
                             "an OnnxAppearanceCoster")
        cams = FrameCameras(t.cameras["top"], t.cameras["ego"]) if rectified else None
        inputs.append(matcher_inputs(
            t.top_boxes, t.ego_boxes, t.cameras["ego"].image_size, matcher.feature_config,
            matcher.cues, cameras=cams, app=t.app if "app" in cues else None,
            margin=manifest.margin, beta=manifest.beta))
    out = []
    for f, c in zip(inputs, matcher.costs(inputs, batch_size), strict=True):
        full = np.empty_like(c)
        full[np.ix_(f.features.top_order, f.features.hor_order)] = c
        out.append(full)
    return out


def score_matcher(matcher: LearnedMatcher, trials: Sequence[PairTrial], setting: str,
                  gamma: float | None = None,
                  costs: Sequence[np.ndarray] | None = None) -> CrossViewScores:
    """Eq. 9 accuracy and cross-view ID scores of the matcher on ``trials`` in ``setting``
    (gamma: the bundle's unless given; ``costs``: precomputed :func:`matcher_costs`)."""
    gamma = matcher.gamma if gamma is None else float(gamma)
    costs = matcher_costs(matcher, trials, setting) if costs is None else costs
    counts = [frame_count(t, c, gamma) for t, c in zip(trials, costs, strict=True)]
    return summarize(counts)


def frame_count(trial: PairTrial, cost: np.ndarray, gamma: float) -> FrameCounts:
    """Eq. 9 and cross-view ID counts of one trial's Hungarian assignment under ``gamma``."""
    return count_pair(trial.gt_top_ids, trial.gt_ego_ids, trial.det_top_ids, trial.det_ego_ids,
                      assign(cost, gamma), frame=trial.frame)


def frame_accuracy(trial: PairTrial, cost: np.ndarray, gamma: float) -> float | None:
    """Eq. 9 accuracy (fraction) of one trial's assignment; None for a frame with no one."""
    c = frame_count(trial, cost, gamma)
    return (c.tp + c.tn) / c.n_union if c.n_union > 0 else None


def frame_check_samples(matcher: LearnedMatcher, trials: Sequence[PairTrial]) -> FrameSamples:
    """What :func:`~xvmatch.inference.matching.frame_check.fit_frame_check` learns from: each
    frame's :func:`~xvmatch.inference.matching.frame_check.frame_check_features` (its appearance
    costs against the matcher's boxes-only costs), what the images gained there (Eq. 9 accuracy with
    images minus from the boxes alone, the bundle's gamma), its scene and box setting, over the
    frames with someone in them."""
    images = matcher_costs(matcher, trials, "images")
    boxes = matcher_costs(matcher, trials, "boxes")
    feats, gains, scenes, settings = [], [], [], []
    for t, a, b in zip(trials, images, boxes, strict=True):
        if t.app is None or t.app.size == 0:
            continue
        acc_a, acc_b = frame_accuracy(t, a, matcher.gamma), frame_accuracy(t, b, matcher.gamma)
        if acc_a is None:
            continue
        feats.append(frame_check_features(t.app, b))
        gains.append(acc_a - acc_b)
        scenes.append(t.scene)
        settings.append(t.setting)
    return FrameSamples(np.asarray(feats).reshape(-1, len(FEATURES)),
                        np.asarray(gains, dtype=np.float64), np.asarray(scenes, dtype=str),
                        np.asarray(settings, dtype=str))


def frame_checked_costs(check: FrameCheck, trials: Sequence[PairTrial],
                        images: Sequence[np.ndarray], boxes: Sequence[np.ndarray]
                        ) -> list[np.ndarray]:
    """Each trial's cost matrix as ``associate`` uses it with a frame check and no video to
    judge: the images' costs where the check trusts the frame's cue, else the boxes-only ones."""
    return [a if t.app is None or t.app.size == 0 or check.trusts(t.app, b) else b
            for t, a, b in zip(trials, images, boxes, strict=True)]
