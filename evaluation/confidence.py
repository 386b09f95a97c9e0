"""Confidence intervals of a mean over a few independent repetitions (seeds).

The ablation repeats every measurement with a handful of seeds; the interval of their mean is
Student's t interval, ``mean +- t_{(1 + c) / 2, n - 1} s / sqrt(n)`` with ``s`` the sample
standard deviation (``ddof = 1``). With one repetition there is no spread to estimate and no
interval (None), never a zero-width one.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["MeanInterval", "mean_interval"]


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
