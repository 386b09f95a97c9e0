"""The appearance check frame by frame, for frames the video check cannot judge (issue 31).

The video check (:mod:`xvmatch.inference.matching.appearance_check`) judges the cue on pairs the
box-only matcher is sure of over consecutive frames; single image pairs and clips shorter than a
burst have none. A frame still says something about its cue: how its appearance costs spread, how
clearly each box prefers one partner, and whether those preferences agree with the box-only
matcher's (a cue near chance disagrees with it at random). :class:`FrameCheck` is a logistic
model of those statistics (:data:`FEATURES`), fitted on renders seen through simulated cameras
(``benchmarks/fit_frame_check.py``: frames weighted by how much images gained or lost there),
that says whether the images are more likely to help than to hurt a frame; when not, the frame
is matched from the boxes alone. Its coefficients live in the bundle's manifest
(``frame_check``, docs/formats.md), fitted for that bundle's network and matcher. Numpy and
SciPy only.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment, minimize

__all__ = ["FEATURES", "FORMAT_VERSION", "FrameCheck", "fit_frame_check",
           "frame_check_features"]

FEATURES = ("app_mean", "app_std", "row_gap", "row_agree", "col_gap", "col_agree",
            "best_margin", "box_correlation", "rows", "cols", "box_assignment_agree",
            "box_row_gap", "box_col_gap", "box_pair_z", "box_pair_rank", "box_row_min")
"""The statistics of a frame's ``(M, N)`` appearance costs ``a`` and box-only matcher costs
``b`` (:func:`frame_check_features`): the mean and spread of ``a``; the mean gap between each
row's cheapest and second-cheapest cost and the share of rows whose cheapest partner is the
box-only matcher's (then the same for columns); the mean of ``a`` minus its mean at the box-only
matcher's best partner of each row; the correlation of ``a`` with ``b``; ``M`` and ``N``. Then
how sure the boxes are and where the cue puts their choice: the share of the box-only optimal
assignment's pairs that the optimal assignment of ``a`` also makes; the mean gap between each
row's (column's) cheapest and second-cheapest box-only cost, and the mean cheapest one of each
row; at the box-only assignment's pairs, ``a`` standardised within the frame and the share of
the column's other rows that ``a`` finds cheaper. Version-1 records use the first ten."""
FORMAT_VERSION = 2
"""Version of the manifest's ``frame_check`` record written (version 1, with the first ten
:data:`FEATURES`, is still read)."""
_VERSION_FEATURES = {1: FEATURES[:10], 2: FEATURES}


def frame_check_features(app: np.ndarray, box_cost: np.ndarray) -> np.ndarray:
    """The :data:`FEATURES` of one frame, ``(len(FEATURES),)`` float64.

    Args:
        app: ``(M, N)`` appearance costs in [0, 1] (the cue the matcher receives).
        box_cost: ``(M, N)`` the matcher's costs from the boxes alone, same order.

    Raises:
        ValueError: shapes that differ, or an empty frame.
    """
    a, b = np.asarray(app, dtype=np.float64), np.asarray(box_cost, dtype=np.float64)
    if a.ndim != 2 or a.shape != b.shape or a.size == 0:
        raise ValueError(f"app and box_cost must be the same non-empty (M, N), got {a.shape} "
                         f"and {b.shape}")
    m, n = a.shape
    mean, std = a.mean(), a.std()
    out = [mean, std]
    for x, y in ((a, b), (a.T, b.T)):
        out.append(_second_gap(x))
        out.append(float((x.argmin(axis=1) == y.argmin(axis=1)).mean()))
    out.append(mean - a[np.arange(m), b.argmin(axis=1)].mean())
    corr = 0.0
    if a.size > 2 and np.ptp(a) > 0 and np.ptp(b) > 0:
        corr = float(np.corrcoef(a.ravel(), b.ravel())[0, 1])
    out.append(corr)
    out += [float(m), float(n)]
    rows, cols = linear_sum_assignment(b)
    a_rows, a_cols = linear_sum_assignment(a)
    agree = np.zeros((m, n), dtype=bool)
    agree[a_rows, a_cols] = True
    out.append(float(agree[rows, cols].mean()))
    cheaper = (a[:, cols] < a[rows, cols][None, :]).sum(axis=0)
    out += [_second_gap(b), _second_gap(b.T),
            float(((a[rows, cols] - mean) / (std if std > 0 else 1.0)).mean()),
            float((cheaper / max(m - 1, 1)).mean()), float(b.min(axis=1).mean())]
    return np.asarray(out, dtype=np.float64)


def _second_gap(x: np.ndarray) -> float:
    """Mean gap between each row's cheapest and second-cheapest entry (0 with one column)."""
    if x.shape[1] < 2:
        return 0.0
    two = np.partition(x, 1, axis=1)[:, :2]
    return float((two[:, 1] - two[:, 0]).mean())


@dataclass(frozen=True)
class FrameCheck:
    """A fitted logistic model of :data:`FEATURES`: the probability that a frame's images help.

    Attributes:
        mean, scale: standardisation of each feature (all :data:`FEATURES`, or the first ten
            of a version-1 record).
        coef: the weight of each standardised feature.
        intercept: the bias.
        threshold: the images are used when the probability is above it.
        fitted: what it was fitted on (free-form notes kept in the manifest).
    """

    mean: np.ndarray
    scale: np.ndarray
    coef: np.ndarray
    intercept: float
    threshold: float = 0.5
    fitted: dict = field(default_factory=dict)

    def probabilities(self, features: np.ndarray) -> np.ndarray:
        """Probability that the images help, for ``(F, len(FEATURES))`` frames' features (a
        version-1 check reads the first ten)."""
        x = np.asarray(features, dtype=np.float64)[:, :len(self.coef)]
        z = (x - self.mean) / self.scale
        return 1.0 / (1.0 + np.exp(-(z @ self.coef + self.intercept)))

    def trusted(self, features: np.ndarray) -> np.ndarray:
        """Whether each of ``(F, len(FEATURES))`` frames is matched with its images: the one
        decision rule (probability above :attr:`threshold`)."""
        return self.probabilities(features) > self.threshold

    def probability(self, app: np.ndarray, box_cost: np.ndarray) -> float:
        """Probability that the images help this frame."""
        return float(self.probabilities(frame_check_features(app, box_cost)[None])[0])

    def trusts(self, app: np.ndarray, box_cost: np.ndarray) -> bool:
        """Whether this frame is matched with its images."""
        return bool(self.trusted(frame_check_features(app, box_cost)[None])[0])

    def to_record(self) -> dict:
        """The manifest's ``frame_check`` object."""
        version = 1 if len(self.coef) == len(_VERSION_FEATURES[1]) else FORMAT_VERSION
        return {"format_version": version, "features": list(_VERSION_FEATURES[version]),
                "mean": self.mean.tolist(), "scale": self.scale.tolist(),
                "coef": self.coef.tolist(), "intercept": float(self.intercept),
                "threshold": float(self.threshold), "fitted": dict(self.fitted)}

    @classmethod
    def from_record(cls, doc: Mapping) -> FrameCheck:
        """Read a manifest's ``frame_check`` object.

        Raises:
            ValueError: naming the field that is missing or wrong.
        """
        if not isinstance(doc, Mapping):
            raise ValueError("'frame_check' must be an object")
        version = doc.get("format_version")
        if type(version) is not int or version not in _VERSION_FEATURES:
            raise ValueError(f"'frame_check.format_version' is {version!r}, this xvmatch reads "
                             f"{', '.join(map(str, _VERSION_FEATURES))}")
        names = _VERSION_FEATURES[version]
        if list(doc.get("features", [])) != list(names):
            raise ValueError(f"'frame_check.features' must be {list(names)} (version {version})")
        vectors = {}
        for key in ("mean", "scale", "coef"):
            v = doc.get(key)
            ok = (isinstance(v, list) and len(v) == len(names)
                  and all(isinstance(x, int | float) and not isinstance(x, bool) for x in v))
            if not ok or not np.all(np.isfinite(np.asarray(v, dtype=np.float64))):
                raise ValueError(f"'frame_check.{key}' must be {len(names)} finite numbers")
            vectors[key] = np.asarray(v, dtype=np.float64)
        if not np.all(vectors["scale"] > 0):
            raise ValueError("'frame_check.scale' must be positive")
        numbers = {}
        for key, low, high in (("intercept", -np.inf, np.inf), ("threshold", 0.0, 1.0)):
            x = doc.get(key)
            if (not isinstance(x, int | float) or isinstance(x, bool) or not np.isfinite(x)
                    or not low <= x <= high):
                raise ValueError(f"'frame_check.{key}' must be a number in [{low}, {high}], "
                                 f"got {x!r}")
            numbers[key] = float(x)
        fitted = doc.get("fitted", {})
        if not isinstance(fitted, Mapping):
            raise ValueError("'frame_check.fitted' must be an object")
        return cls(vectors["mean"], vectors["scale"], vectors["coef"], numbers["intercept"],
                   numbers["threshold"], dict(fitted))


def fit_frame_check(features: np.ndarray, gains: np.ndarray, threshold: float = 0.5,
                    ridge: float = 1.0, fitted: Mapping | None = None) -> FrameCheck:
    """Fit :class:`FrameCheck` on frames whose gain from images is known (renders).

    Each frame with a nonzero gain (images minus boxes, e.g. in Eq. 9 accuracy) is a sample
    labelled by its sign and weighted by its size: the model learns where images are likely to
    pay more than they cost. L2 penalty ``ridge`` on the standardised weights (not the bias);
    deterministic L-BFGS from zero.

    Args:
        features: ``(F, len(FEATURES))`` from :func:`frame_check_features`.
        gains: ``(F,)`` what the images gained on each frame (negative: lost).
        threshold: the probability above which images are used.
        ridge: the penalty.
        fitted: notes kept in the record.

    Raises:
        ValueError: shapes that differ, non-finite values, or no frame of either sign.
    """
    x = np.asarray(features, dtype=np.float64)
    g = np.asarray(gains, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != len(FEATURES) or g.shape != (x.shape[0],):
        raise ValueError(f"features must be (F, {len(FEATURES)}) and gains (F,), got {x.shape} "
                         f"and {g.shape}")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(g))):
        raise ValueError("features and gains must be finite")
    keep = g != 0
    x, g = x[keep], g[keep]
    if not (np.any(g > 0) and np.any(g < 0)):
        raise ValueError("need frames where the images gained and frames where they lost")
    mean, scale = x.mean(axis=0), x.std(axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    z = np.c_[(x - mean) / scale, np.ones(len(x))]
    sign, weight = np.where(g > 0, 1.0, -1.0), np.abs(g)

    def loss(beta: np.ndarray) -> tuple[float, np.ndarray]:
        margin = sign * (z @ beta)
        value = float(weight @ np.logaddexp(0.0, -margin))
        grad = -(weight * sign * np.exp(-np.logaddexp(0.0, margin))) @ z
        penalty = np.r_[beta[:-1], 0.0]
        return value + 0.5 * ridge * float(penalty @ penalty), grad + ridge * penalty

    beta = minimize(loss, np.zeros(z.shape[1]), jac=True, method="L-BFGS-B").x
    return FrameCheck(mean, scale, beta[:-1].copy(), float(beta[-1]), float(threshold),
                      dict(fitted or {}))
