"""Edge weights of the four-cluster tracking graph (CVMHAT paper, Sec. 3.3-3.5, Eqs. 13-18).

- Cross-view (clusters 3 -> 0 and 1 -> 2): the spatial term of Eq. 13, the fraction of the
  longer tracklet's frames on which the frame-level association (Sec. 3.2) paired the two boxes;
  or its learned counterpart (:func:`learned_similarity`), the same sum over the frames two
  tracklets share of the learned matcher's evidence, read from its cost matrices and its
  non-association cost (the dustbin).
- Over time (clusters 0 -> 1 and 2 -> 3): the constant-velocity motion term of Eqs. 15-16.
- Eqs. 17 and 18 mix each with an appearance term; without images that term does not exist and
  the weight is the other term alone (the mix renormalised over the terms present), so that the
  edge weights keep the [0, 1] range the dummy weight ``c0`` is set against.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from xvmatch.inference.linking.assignment import FrameCosts
from xvmatch.inference.linking.tracklets import Tracklet

__all__ = [
    "DUMMY_WEIGHT",
    "FITTED_CAMERAS_W1",
    "LEARNED_DUMMY_WEIGHT",
    "LEARNED_RULES",
    "MOTION_SIGMA",
    "SOFT_TEMPERATURE",
    "TrackWeights",
    "combine_cross_view",
    "combine_over_time",
    "frame_evidence",
    "learned_similarity",
    "motion_similarity",
    "spatial_similarity",
]

LEARNED_RULES = ("margin", "pairs", "confidence", "soft")
"""How :func:`learned_similarity` turns one frame's costs into evidence (:func:`frame_evidence`);
the first is the default, chosen on the even CVMHAT dev pairs (docs/tracking.md)."""


MOTION_SIGMA = 1.0
"""Default ``sigma`` of Eq. 15, per box height of motion deviation (see :class:`TrackWeights`)."""

DUMMY_WEIGHT = 0.1
"""Default ``c0`` of Eq. 1 (see :class:`TrackWeights`)."""

LEARNED_DUMMY_WEIGHT = 0.02
"""Default ``c0`` of Eq. 1 with the learned cross-view weights (:func:`learned_similarity`),
chosen with them on the even CVMHAT dev pairs: 0.2, 0.15, 0.1, 0.05, 0.02, 0.01, 0 gave 90.5,
91.5, 91.9, 92.0, 92.4, 92.4, 92.2 CVIDF1 clean, and 0.1, 0.05, 0.02 gave 76.9, 78.8, 79.0
with detector noise (docs/tracking.md)."""

FITTED_CAMERAS_W1 = 1.0
"""``w1`` of Eq. 17 when ``track``'s ``--cameras`` fit the video (a fixed top camera turned to
fit its head rays, or kept as given because it already does:
:attr:`~xvmatch.inference.matching.camera_refinement.CameraRefinement.fits`) and ``--w1`` is not
given: the camera-aware spatial term is then nearly right, and the network's similarity across
views, well above zero for two different people, only adds wrong edges; the images still serve over
time (Eq. 18). On rendered videos it gained 0.9 to 2.1 CVIDF1 over 0.3 with exact cameras and
with both cameras 2 or 3 degrees off (docs/tracking.md, "With the cameras")."""


@dataclass(frozen=True)
class TrackWeights:
    """Weights of Eqs. 1, 15, 17 and 18 (``w1``, ``w2``: the paper's, Sec. 4.1; ``c0`` and
    ``sigma`` chosen on half of the CVMHAT dev split, docs/tracking.md).

    Attributes:
        c0: weight of an edge to a dummy node (Eq. 1); a real edge pays off when its weight is
            above ``2 c0`` (it takes one dummy edge off each of its two clusters). The paper
            uses 0.2; 0.1 is ahead on the CVMHAT sequences chosen on (89.3 against 88.0 CVIDF1
            clean, 75.9 against 66.3 with detector noise), with boxes only.
        w1: share of the spatial term in a cross-view weight (Eq. 17).
        w2: share of the appearance term in an over-time weight (Eq. 18).
        sigma: scale of the constant-velocity deviation of Eq. 15, per box height. The paper's
            0.05 per pixel is 3.1 per height of CVMHAT's median top-view box (62 pixels) and
            12.8 per height of its median horizontal box (255 pixels); 1 keeps the tracks
            whole under detector jitter (c0 0.2: top-view IDF1 72.2 at 1, 42.8 at 2, 21.3
            at 3), and the clean scores barely move with it.
    """

    c0: float = DUMMY_WEIGHT
    w1: float = 0.3
    w2: float = 0.6
    sigma: float = MOTION_SIGMA

    def __post_init__(self) -> None:
        for name in ("c0", "w1", "w2"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {value}")
        if not self.sigma > 0 or not np.isfinite(self.sigma):
            raise ValueError(f"sigma must be a positive number, got {self.sigma}")


def _row_index(tracklets: Sequence[Tracklet]) -> dict[int, int]:
    return {int(r): k for k, t in enumerate(tracklets) for r in t.rows.tolist()}


def spatial_similarity(
    top: Sequence[Tracklet],
    hor: Sequence[Tracklet],
    frame_pairs: Mapping[int, Sequence[tuple[int, int]]],
) -> np.ndarray:
    """(len(top), len(hor)) spatial similarity of Eq. 13 from the frame-level association.

    ``frame_pairs[f]`` lists the ``(top row, horizontal row)`` pairs the frame association
    (Sec. 3.2) made on frame ``f``; the similarity of two tracklets is the number of their
    common frames where their boxes were paired, over the length of the longer tracklet.
    """
    out = np.zeros((len(top), len(hor)))
    if not top or not hor:
        return out
    t_of, h_of = _row_index(top), _row_index(hor)
    frames = set().union(*(t.frames.tolist() for t in top))
    hits = [(t_of[a], h_of[b]) for f in frames for a, b in frame_pairs.get(f, ())
            if a in t_of and b in h_of]
    if hits:
        idx = np.array(hits)
        np.add.at(out, (idx[:, 0], idx[:, 1]), 1.0)
    lengths_t = np.array([len(t) for t in top], dtype=float)
    lengths_h = np.array([len(h) for h in hor], dtype=float)
    return out / np.maximum(lengths_t[:, None], lengths_h[None, :])


SOFT_TEMPERATURE = 0.1
"""Temperature of the ``soft`` rule of :func:`frame_evidence`, in cost units."""


def frame_evidence(costs: FrameCosts, gamma: float, rule: str = LEARNED_RULES[0]) -> np.ndarray:
    """(M, N) evidence in [0, 1] that each pair of a frame is one person (:data:`LEARNED_RULES`).

    - ``margin``: ``max(0, gamma - c) / gamma``, how far below the dustbin a pair's cost lies (0
      for every pair the matcher would leave unmatched, 1 for a cost of 0), whether or not the
      frame's assignment took it: the soft evidence, which still counts a pair that lost its
      frame's assignment to a near tie;
    - ``pairs``: 1 for the pairs of the frame's assignment, else 0 (Eq. 13 on the learned pairs);
    - ``confidence``: ``1 - c`` for the pairs of the frame's assignment, else 0;
    - ``soft``: a soft assignment with the dustbin: ``exp(-c / T)`` over the sum of its row's (or
      column's) ``exp(-c / T)`` and the dustbin's ``exp(-gamma / T)``, the smaller of the two,
      ``T`` = :data:`SOFT_TEMPERATURE` (a pair alone far below the dustbin is near 1, two
      close rivals share it).
    """
    if rule == "pairs":
        return costs.paired.astype(float)
    if rule == "confidence":
        return np.where(costs.paired, 1.0 - costs.cost, 0.0)
    if rule == "soft":
        z = np.exp(-(costs.cost - gamma) / SOFT_TEMPERATURE)  # the dustbin's weight is 1
        row = z / (1.0 + z.sum(axis=1, keepdims=True))
        col = z / (1.0 + z.sum(axis=0, keepdims=True))
        return np.minimum(row, col)
    if rule == "margin":
        if not gamma > 0:
            raise ValueError(f"gamma must be > 0, got {gamma}")
        return np.clip((gamma - costs.cost) / gamma, 0.0, 1.0)
    raise ValueError(f"rule must be one of {', '.join(LEARNED_RULES)}, got {rule!r}")


def _frame_members(tracklets: Sequence[Tracklet]) -> dict[int, tuple[list[int], list[int]]]:
    """``{frame: (tracklet indices, their rows on that frame)}``."""
    out: dict[int, tuple[list[int], list[int]]] = {}
    for k, t in enumerate(tracklets):
        for f, r in zip(t.frames.tolist(), t.rows.tolist(), strict=True):
            members = out.setdefault(f, ([], []))
            members[0].append(k)
            members[1].append(r)
    return out


def learned_similarity(
    top: Sequence[Tracklet],
    hor: Sequence[Tracklet],
    frame_costs: Mapping[int, FrameCosts],
    gamma: float,
    rule: str = LEARNED_RULES[0],
) -> np.ndarray:
    """(len(top), len(hor)) cross-view similarity of Eq. 13 from the learned matcher's costs.

    Eq. 13 counts the common frames on which the frame association paired two tracklets' boxes,
    over the length of the longer tracklet; here each common frame adds the matcher's evidence
    for the pair (:func:`frame_evidence`, ``rule``), so a pair seen on every frame of both
    tracklets with cost 0 weighs 1 and a pair the matcher never puts below its dustbin
    ``gamma`` weighs 0, the range the dummy weight ``c0`` is set against. With ``rule="pairs"``
    it equals :func:`spatial_similarity` on the matcher's own pairs.
    """
    out = np.zeros((len(top), len(hor)))
    if not top or not hor:
        return out
    in_top, in_hor = _frame_members(top), _frame_members(hor)
    for f in sorted(in_top.keys() & in_hor.keys()):
        costs = frame_costs.get(f)
        if costs is None:
            continue
        pos_t = {r: i for i, r in enumerate(costs.top_rows.tolist())}
        pos_h = {r: i for i, r in enumerate(costs.hor_rows.tolist())}
        (k_t, r_t), (k_h, r_h) = in_top[f], in_hor[f]
        a = [(k, pos_t[r]) for k, r in zip(k_t, r_t, strict=True) if r in pos_t]
        b = [(k, pos_h[r]) for k, r in zip(k_h, r_h, strict=True) if r in pos_h]
        if not a or not b:
            continue
        (ka, pa), (kb, pb) = zip(*a, strict=True), zip(*b, strict=True)
        out[np.ix_(ka, kb)] += frame_evidence(costs, gamma, rule)[np.ix_(pa, pb)]
    lengths_t = np.array([len(t) for t in top], dtype=float)
    lengths_h = np.array([len(h) for h in hor], dtype=float)
    return out / np.maximum(lengths_t[:, None], lengths_h[None, :])


def _centres(t: Tracklet) -> np.ndarray:
    return t.boxes[:, :2] + 0.5 * t.boxes[:, 2:]


def _velocity(t: Tracklet) -> np.ndarray:
    """Least-squares constant velocity (pixels per frame) of a tracklet's box centres."""
    if len(t) < 2:
        return np.zeros(2)
    f = t.frames.astype(float)
    f = f - f.mean()
    c = _centres(t)
    return (f[:, None] * (c - c.mean(axis=0))).sum(axis=0) / (f @ f)


def _height(t: Tracklet) -> float:
    """Mean box height of a tracklet (pixels), the unit of its motion deviations; at least
    one pixel, so that a degenerate box cannot divide by zero."""
    return max(float(t.boxes[:, 3].mean()), 1.0)


def motion_similarity(
    earlier: Sequence[Tracklet], later: Sequence[Tracklet], sigma: float = MOTION_SIGMA
) -> np.ndarray:
    """(len(earlier), len(later)) motion consistency of Eqs. 15-16, ``exp(-sigma (d_f + d_b))``.

    ``d_f`` is the distance between the later tracklet's first centre and the earlier one's
    last centre carried forward at its constant velocity, in units of the later tracklet's
    mean box height; ``d_b`` the same backwards, in units of the earlier tracklet's. The paper
    measures them in pixels, so that one ``sigma`` means another thing at every image size and
    in each view (a 250-pixel horizontal box against a 60-pixel top-view one on CVMHAT);
    relative to the box they are resolution-free, as Eq. 9's features are
    (:mod:`xvmatch.cues.spatial_features`). A pair where the later tracklet does not start
    after the earlier one ends gets 0.
    """
    if not earlier or not later:
        return np.zeros((len(earlier), len(later)))
    last = np.array([_centres(t)[-1] for t in earlier])
    first = np.array([_centres(t)[0] for t in later])
    v_e = np.array([_velocity(t) for t in earlier])
    v_l = np.array([_velocity(t) for t in later])
    h_e = np.array([_height(t) for t in earlier])
    h_l = np.array([_height(t) for t in later])
    end = np.array([t.frames[-1] for t in earlier], dtype=float)
    start = np.array([t.frames[0] for t in later], dtype=float)
    gap = start[None, :] - end[:, None]
    forward = last[:, None, :] + v_e[:, None, :] * gap[..., None]
    backward = first[None, :, :] - v_l[None, :, :] * gap[..., None]
    d_f = np.linalg.norm(forward - first[None, :, :], axis=-1) / h_l[None, :]
    d_b = np.linalg.norm(backward - last[:, None, :], axis=-1) / h_e[:, None]
    return np.where(gap > 0, np.exp(-sigma * (d_f + d_b)), 0.0)


def combine_cross_view(
    spatial: np.ndarray, appearance: np.ndarray | None, weights: TrackWeights
) -> np.ndarray:
    """Cross-view edge weight of Eq. 17, ``w1 spatial + (1 - w1) appearance``; spatial alone
    without an appearance term."""
    if appearance is None:
        return np.asarray(spatial, dtype=float)
    return weights.w1 * spatial + (1.0 - weights.w1) * appearance


def combine_over_time(
    motion: np.ndarray, appearance: np.ndarray | None, weights: TrackWeights
) -> np.ndarray:
    """Over-time edge weight of Eq. 18, ``w2 appearance + (1 - w2) motion``; motion alone
    without an appearance term."""
    if appearance is None:
        return np.asarray(motion, dtype=float)
    return weights.w2 * appearance + (1.0 - weights.w2) * motion
