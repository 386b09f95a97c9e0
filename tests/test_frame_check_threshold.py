"""The frame check's threshold chosen by cross-validation over scenes
(evaluation/frame_check_threshold.py)."""

from __future__ import annotations

import numpy as np
import pytest

from xvmatch.evaluation.frame_check_threshold import (
    FrameSamples,
    ThresholdScore,
    choose_threshold,
    cross_validate_thresholds,
    scene_folds,
)
from xvmatch.inference.matching.frame_check import frame_check_features


def _cell(seed: int, agree_share: float, scenes: int = 12, frames: int = 10) -> FrameSamples:
    """Frames whose images help (+) when the cue agrees with sure boxes and hurt (-) when it
    is noise; ``agree_share`` of them agree."""
    rng = np.random.default_rng(seed)
    feats, gains, names, settings = [], [], [], []
    for s in range(scenes):
        for k in range(frames):
            n = int(rng.integers(3, 7))
            box = np.full((n, n), 0.9)
            np.fill_diagonal(box, 0.1)
            app = rng.uniform(0.3, 0.6, (n, n))
            agree = rng.uniform() < agree_share
            if agree:
                np.fill_diagonal(app, 0.05)
            feats.append(frame_check_features(app, box))
            gains.append(rng.uniform(0.05, 0.2) * (1 if agree else -1))
            names.append(f"scene_{s:04d}")
            settings.append("gt" if k % 2 else "det")
    return FrameSamples(np.asarray(feats), np.asarray(gains), np.asarray(names),
                        np.asarray(settings))


def test_scene_folds_keep_a_scene_whole_and_use_every_fold() -> None:
    names = np.asarray([f"scene_{i:04d}" for i in range(40)])
    folds = scene_folds(np.r_[names, names[::-1]], 2)
    np.testing.assert_array_equal(folds[:40], folds[40:][::-1])  # a name: one fold
    assert set(folds.tolist()) == {0, 1}
    np.testing.assert_array_equal(scene_folds(names, 3), scene_folds(names.tolist(), 3))


def test_cross_validation_scores_what_each_threshold_keeps() -> None:
    """Keeping every frame scores each held-out cell's mean gain; keeping none, zero; a cue
    the check can read is kept where it helps, so a middle threshold beats both."""
    cells = [_cell(0, 0.8), _cell(1, 0.3)]
    every, middle, none = cross_validate_thresholds(cells, (0.001, 0.5, 0.999))
    assert (none.worst, none.total) == (0.0, 0.0)
    expected_worst, expected_total = [], []
    for f in (0, 1):
        means = [100.0 * c.gains[(scene_folds(c.scenes, 2) == f) & (c.settings == s)].mean()
                 for c in cells for s in ("det", "gt")]
        expected_worst.append(min(means))
        expected_total.append(sum(means))
    assert every.worst == pytest.approx(np.mean(expected_worst))
    assert every.total == pytest.approx(np.mean(expected_total))
    assert every.worst < 0 < middle.worst and middle.total > every.total
    again = cross_validate_thresholds(cells, (0.001, 0.5, 0.999))
    assert again == [every, middle, none]  # deterministic
    with pytest.raises(ValueError, match="folds must be at least 2"):
        cross_validate_thresholds(cells, folds=1)
    with pytest.raises(ValueError, match=r"thresholds must be numbers in \(0, 1\)"):
        cross_validate_thresholds(cells, (0.5, 1.0))


def test_the_lowest_threshold_that_never_falls_below_boxes_is_chosen() -> None:
    scores = [ThresholdScore(0.7, 0.2, 90.0), ThresholdScore(0.5, -0.4, 100.0),
              ThresholdScore(0.6, 0.1, 95.0)]
    assert choose_threshold(scores).threshold == 0.6
    below = [ThresholdScore(0.5, -0.4, 100.0), ThresholdScore(0.6, -0.1, 95.0),
             ThresholdScore(0.7, -0.1, 90.0)]
    assert choose_threshold(below).threshold == 0.6  # the best worst cell, the lower of equals
