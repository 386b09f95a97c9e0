"""The frame check's threshold, chosen by cross-validation over scenes (issue 31).

The frame check (:mod:`xvmatch.inference.matching.frame_check`) keeps a frame's images when the
probability that they help is above a threshold. A low one keeps most of what images add where
the cue is good; a high one leaves out more of the frames where a doubtful cue costs accuracy.
The issue asks that images never fall below boxes only in any cell of the shift stress test
(scenario x camera strength x box setting), so :func:`choose_threshold` takes the lowest
threshold whose worst cell, fitted on some scenes and scored on the others
(:func:`cross_validate_thresholds`), is not below boxes only. Numpy only.
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from xvmatch.inference.matching.frame_check import FEATURES, fit_frame_check

__all__ = ["THRESHOLDS", "FrameSamples", "ThresholdScore", "choose_threshold",
           "cross_validate_thresholds", "scene_folds"]

THRESHOLDS = (0.5, 0.55, 0.6, 0.65, 0.7, 0.75, 0.8)
"""The thresholds ``fit_frame_check.py`` cross-validates by default."""


@dataclass(frozen=True)
class FrameSamples:
    """The frames of one cell (one scenario at one camera strength) a frame check learns from.

    Attributes:
        features: ``(F, len(FEATURES))`` each frame's statistics.
        gains: ``(F,)`` Eq. 9 accuracy with images minus from the boxes alone (fractions).
        scenes: ``(F,)`` the scene of each frame (folds keep a scene whole).
        settings: ``(F,)`` the box setting of each frame (``"gt"``, ``"det"``): a cell each.
    """

    features: np.ndarray
    gains: np.ndarray
    scenes: np.ndarray
    settings: np.ndarray


@dataclass(frozen=True)
class ThresholdScore:
    """A threshold's held-out figures, in Eq. 9 points against boxes only, mean over folds.

    Attributes:
        threshold: the probability above which images are used.
        worst: the worst cell (scenario, strength, box setting) of each fold's held-out scenes.
        total: the sum over those cells (what the images add, all cells together).
    """

    threshold: float
    worst: float
    total: float


def scene_folds(scenes: np.ndarray, folds: int) -> np.ndarray:
    """The fold of each scene name, ``(F,)`` int: CRC32 of the name modulo ``folds`` (the same
    on every machine and Python, unlike ``hash``)."""
    return np.asarray([zlib.crc32(str(s).encode()) % folds for s in scenes], dtype=np.int64)


def cross_validate_thresholds(cells: Sequence[FrameSamples],
                              thresholds: Sequence[float] = THRESHOLDS, ridge: float = 1.0,
                              folds: int = 2) -> list[ThresholdScore]:
    """Each threshold's worst and summed held-out cell, fitting on the other folds' scenes.

    Raises:
        ValueError: fewer than two folds, a threshold outside (0, 1), or a fold whose other
            scenes hold no frame of either sign (too few scenes).
    """
    if folds < 2:
        raise ValueError(f"folds must be at least 2, got {folds}")
    if not thresholds or not all(0.0 < t < 1.0 for t in thresholds):
        raise ValueError(f"thresholds must be numbers in (0, 1), got {list(thresholds)}")
    fold_of = [scene_folds(c.scenes, folds) for c in cells]
    worst = np.zeros((folds, len(thresholds)))
    total = np.zeros((folds, len(thresholds)))
    for f in range(folds):
        train = [k != f for k in fold_of]
        check = fit_frame_check(
            np.concatenate([c.features[t] for c, t in zip(cells, train, strict=True)]
                           ).reshape(-1, len(FEATURES)),
            np.concatenate([c.gains[t] for c, t in zip(cells, train, strict=True)]),
            ridge=ridge)
        scores = []  # (cells, thresholds): points each held-out cell keeps over boxes only
        for c, k in zip(cells, fold_of, strict=True):
            p = check.probabilities(c.features)
            for setting in sorted(set(c.settings.tolist())):
                held = (k == f) & (c.settings == setting)
                if held.any():
                    kept = p[held][:, None] > np.asarray(thresholds)[None, :]
                    scores.append(100.0 * np.where(kept, c.gains[held][:, None], 0.0).mean(0))
        scores = np.asarray(scores)
        worst[f], total[f] = scores.min(axis=0), scores.sum(axis=0)
    return [ThresholdScore(float(t), float(w), float(s))
            for t, w, s in zip(thresholds, worst.mean(0), total.mean(0), strict=True)]


def choose_threshold(scores: Sequence[ThresholdScore]) -> ThresholdScore:
    """The lowest threshold whose held-out worst cell is not below boxes only (>= 0 points);
    when none is, the one with the best worst cell (the lowest of equals)."""
    ordered = sorted(scores, key=lambda s: s.threshold)
    for s in ordered:
        if s.worst >= 0.0:
            return s
    return max(ordered, key=lambda s: (s.worst, -s.threshold))
