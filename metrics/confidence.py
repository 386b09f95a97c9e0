"""Confidence intervals: of a mean over a few independent repetitions (seeds), and of a paired
difference over frames that come in groups (scenes).

The ablation repeats every measurement with a handful of seeds; the interval of their mean is
Student's t interval, ``mean +- t_{(1 + c) / 2, n - 1} s / sqrt(n)`` with ``s`` the sample
standard deviation (``ddof = 1``). With one repetition there is no spread to estimate and no
interval (None), never a zero-width one.

Two settings scored on the same frames (e.g. a matcher with and without images) differ by the
mean of per-frame differences; frames of one rendered scene share its people and cameras, so
:func:`grouped_difference_interval` resamples whole scenes (a cluster bootstrap, percentile
interval, scipy's ``bootstrap``), not frames.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["DifferenceInterval", "MeanInterval", "grouped_difference_interval", "mean_interval"]


@dataclass(frozen=True)
class MeanInterval:
    """The mean of ``n`` values and the half-width of its confidence interval.

    Attributes:
        mean: the sample mean.
        half_width: ``t s / sqrt(n)``, or None when ``n < 2``.
        n: the number of values.
        confidence: the interval's confidence level, e.g. 0.95.
    """

    mean: float
    half_width: float | None
    n: int
    confidence: float

    @property
    def low(self) -> float | None:
        """Lower end of the interval (None without one)."""
        return None if self.half_width is None else self.mean - self.half_width

    @property
    def high(self) -> float | None:
        """Upper end of the interval (None without one)."""
        return None if self.half_width is None else self.mean + self.half_width


@functools.lru_cache(maxsize=256)
def _t_quantile(probability: float, dof: int) -> float:
    from scipy.stats import t as student_t

    return float(student_t.ppf(probability, dof))


def mean_interval(values: Sequence[float] | np.ndarray, confidence: float = 0.95
                  ) -> MeanInterval:
    """Student's t confidence interval of the mean of independent repetitions.

    Args:
        values: (n,) finite values, n >= 1 (e.g. one accuracy per seed).
        confidence: level in (0, 1).

    Returns:
        The :class:`MeanInterval`; ``half_width`` None for a single value.

    Raises:
        ValueError: no values, a non-finite value, or a level outside (0, 1).

    Example:
        >>> r = mean_interval([1.0, 2.0, 3.0])  # s = 1, t_{0.975, 2} = 4.3027
        >>> round(r.mean, 3), round(r.half_width, 3)
        (2.0, 2.484)
    """
    x = np.asarray(values, dtype=float).reshape(-1)
    if x.size == 0:
        raise ValueError("mean_interval needs at least one value")
    if not np.isfinite(x).all():
        raise ValueError(f"mean_interval needs finite values, got {x.tolist()}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    mean = float(x.mean())
    if x.size < 2:
        return MeanInterval(mean, None, 1, float(confidence))
    half = _t_quantile(0.5 + confidence / 2.0, int(x.size) - 1) * float(x.std(ddof=1)) / float(
        np.sqrt(x.size))
    return MeanInterval(mean, half, int(x.size), float(confidence))


@dataclass(frozen=True)
class DifferenceInterval:
    """A paired difference of means and its group-bootstrap confidence interval.

    Attributes:
        difference: ``mean(a) - mean(b)`` over the items.
        low, high: ends of the interval, or None with fewer than two groups.
        n_groups: the number of groups resampled.
        confidence: the interval's level, e.g. 0.95.
    """

    difference: float
    low: float | None
    high: float | None
    n_groups: int
    confidence: float


def grouped_difference_interval(a: Sequence[float] | np.ndarray, b: Sequence[float] | np.ndarray,
                                groups: Sequence, confidence: float = 0.95,
                                n_resamples: int = 2000, seed: int = 0) -> DifferenceInterval:
    """Percentile bootstrap interval of ``mean(a) - mean(b)`` for paired per-item values,
    resampling whole groups with replacement (items of a group are not independent).

    Args:
        a, b: ``(n,)`` finite values of the same items (e.g. one accuracy per frame).
        groups: ``(n,)`` the group of each item (e.g. its scene).
        confidence: level in (0, 1).
        n_resamples: bootstrap resamples.
        seed: seed of the resampling (same seed, same interval).

    Raises:
        ValueError: no items, lengths that differ, a non-finite value, or a level outside
            (0, 1).
    """
    x = np.asarray(a, dtype=float).reshape(-1)
    y = np.asarray(b, dtype=float).reshape(-1)
    labels = np.asarray(groups).reshape(-1)
    if x.size == 0 or x.shape != y.shape or labels.shape != x.shape:
        raise ValueError(f"grouped_difference_interval needs a, b and groups of one non-zero "
                         f"length, got {x.size}, {y.size}, {labels.size}")
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise ValueError("grouped_difference_interval needs finite values")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    _, index = np.unique(labels, return_inverse=True)
    sums = np.stack([np.bincount(index, weights=v) for v in (x, y, np.ones_like(x))])
    difference = float(x.mean() - y.mean())
    if sums.shape[1] < 2:
        return DifferenceInterval(difference, None, None, int(sums.shape[1]), float(confidence))
    from scipy.stats import bootstrap

    def statistic(sa, sb, count, axis=-1):
        return (sa.sum(axis) - sb.sum(axis)) / count.sum(axis)

    result = bootstrap(tuple(sums), statistic, paired=True, vectorized=True, method="percentile",
                       n_resamples=int(n_resamples), confidence_level=float(confidence),
                       rng=np.random.default_rng(seed))
    interval = result.confidence_interval
    return DifferenceInterval(difference, float(interval.low), float(interval.high),
                              int(sums.shape[1]), float(confidence))
