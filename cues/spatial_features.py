"""Box-only input features of the learned geometry model, built from the spatial-distribution
search (numpy only: no torch, no I/O).

For one frame pair (top-view boxes, horizontal-view boxes) the features describe, without any
id and independently of the order of the boxes:

* the best camera hypotheses of the CVMHAT spatial-distribution search (Section 3.2 of the
  CVMHAT paper, :func:`xvmatch.cues.spatial_search.rank_hypotheses`): by default the best
  orientation theta of every candidate camera location O, the ``n_hypotheses`` lowest-Phi ones
  (O searched), or the best ``n_hypotheses`` distinct orientations of the given O;
* per hypothesis and per (top person i, horizontal person j) pair: the bearing difference, the
  log depth ratio ``log(mu y_top_i / y_hor_j)`` (Eqs. 5-11), whether the hypothesis' DTW matching
  paired them, i's field-of-view / occlusion / is-O flags, how far the pair is from the best
  candidate of its row and column;
* per hypothesis: its cost Phi (Eq. 12), rank, scale mu, matched and in-view counts;
* pose-free box geometry of each person in each view.

Boxes are first put in a canonical order (sorted by their coordinates), so features, and the
model outputs computed from them, do not depend on the input order; ``top_order`` and
``hor_order`` map canonical rows back to input rows. Everything is float32.

Every feature is resolution-free (:data:`FEATURE_VERSION` 2): a view's boxes and image size
scaled by any factor give the same features (the horizontal y of Eq. 9 in reference pixels,
:func:`~xvmatch.cues.spatial_vectors.horizontal_vectors`; top-view lengths over the frame's
median box size; horizontal positions over the image size).

Extraction runs one exact search per candidate O; whole sequences are computed in parallel and
cached on disk by :mod:`xvmatch.datasets.feature_cache`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, fields

import numpy as np

from xvmatch.core import kernel_choice
from xvmatch.core.array_checks import as_boxes
from xvmatch.cues.spatial_matching import SpatialParams
from xvmatch.cues.spatial_search import (
    FrameAssociation,
    _best_per_candidate,
    rank_hypotheses,
)
from xvmatch.cues.spatial_vectors import (
    REFERENCE_SIZE,
    TopGeometry,
    box_centres,
    horizontal_vectors,
    top_geometry,
)

__all__ = [
    "FEATURE_VERSION",
    "HOR_FEATURES",
    "HYP_FEATURES",
    "PAIR_FEATURES",
    "TOP_FEATURES",
    "FeatureConfig",
    "FrameFeatures",
    "camera_labels",
    "collate_frames",
    "frame_features",
    "match_labels",
]

FEATURE_VERSION = 2
"""Bumped whenever a feature's definition changes; stored in caches and model files. Version 2:
resolution-free (y_hor in units of a 2688-pixel-wide image, the border test and the scale mu
relative to the image size); version 1 depended on the horizontal image's pixel count."""

TOP_FEATURES = ("log_w", "log_h", "log_nn_dist", "log_n_top", "log_n_hor")
"""Per top-view person: box size and nearest-neighbour distance over the frame's top box scale
``s_top`` (median sqrt(w h)), and the two set sizes."""

HOR_FEATURES = (
    "x",
    "log_h",
    "bottom",
    "top",
    "log_aspect",
    "at_border",
    "bottom_rel",
    "log_h_rel",
    "log_n_top",
    "log_n_hor",
)
"""Per horizontal-view person: x_hor of Eq. 9, log box height over the image height, box bottom
and top over the image height, log w/h, touching the image border, bottom and log height minus
the frame's median, and the two set sizes."""

HYP_FEATURES = (
    "log_cost",
    "log_cost_gap",
    "rank",
    "matched_fraction",
    "in_view_fraction",
    "log_scale",
    "camera_given",
)
"""Per hypothesis: log Phi (Eq. 12), log Phi minus the best one's, rank / n_hypotheses, matched
pairs over N, people in view over N, log(mu s_top 1512) (mu relates the top view's depths to the
horizontal y of Eq. 9, which is resolution-free, so mu s_top is too; the constant is the reference
height of :data:`~xvmatch.cues.spatial_vectors.REFERENCE_SIZE`), O given."""

PAIR_FEATURES = (
    "bearing_diff",
    "abs_bearing_diff",
    "log_depth_ratio",
    "abs_log_depth_ratio",
    "dtw_matched",
    "in_view",
    "visible",
    "is_camera",
    "off_axis",
    "row_gap",
    "col_gap",
    "log_dist",
)
"""Per hypothesis and pair (i, j): bearing of i from the optical axis minus that of j (in units of
half the field of view, clipped to +-3) and its absolute value; log(mu y_top_i / y_hor_j) (clipped
to +-3) and its absolute value; matched by the hypothesis' DTW; i in view, i visible (not occluded,
not O), i is O; |bearing of i| / pi; |bearing diff| minus the smallest of its row (over j) and of
its column (over the visible i); log(|O P_i| / s_top)."""

_CLIP = 3.0
_EPS = 1e-6
_BORDER = 2.0
"""A box within this many reference pixels (2 of 2688 across, 2 of 1512 down) of the image border
touches it; scaled with the image, so the test is the same at any resolution."""


@dataclass(frozen=True)
class FeatureConfig:
    """How hypotheses are generated; JSON-able (stored with caches and model files).

    Attributes:
        n_hypotheses: H, the most hypotheses kept per frame (lowest Phi first).
        modes_per_camera: orientations kept per candidate O when O is searched (distinct modes,
            at least ``mode_separation_deg`` apart); with O given, H modes of that O are kept.
        mode_separation_deg: smallest orientation gap between two kept modes of one O.
        rho, lam, tau_deg, dtheta_deg, fov_deg: :class:`SpatialParams` of the search.
    """

    n_hypotheses: int = 8
    modes_per_camera: int = 1
    mode_separation_deg: float = 10.0
    rho: float = 15.0
    lam: float = 0.003
    tau_deg: float = 2.0
    dtheta_deg: float = 1.0
    fov_deg: float = 90.0

    def __post_init__(self) -> None:
        for name in ("n_hypotheses", "modes_per_camera"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer):
                raise ValueError(f"FeatureConfig.{name} must be an integer, got {value!r}")
        for name in ("mode_separation_deg", "rho", "lam", "tau_deg", "dtheta_deg", "fov_deg"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float | np.floating) or \
                    not math.isfinite(value):
                raise ValueError(f"FeatureConfig.{name} must be a finite number, got {value!r}")
        if self.n_hypotheses > 64 or self.modes_per_camera > 64:
            raise ValueError("FeatureConfig.n_hypotheses and modes_per_camera must be <= 64 "
                             f"(the hypotheses kept per frame), got {self.n_hypotheses} and "
                             f"{self.modes_per_camera}")
        if self.n_hypotheses < 1 or self.modes_per_camera < 1:
            raise ValueError(
                "FeatureConfig.n_hypotheses and modes_per_camera must be >= 1, got "
                f"{self.n_hypotheses} and {self.modes_per_camera}"
            )
        if not self.mode_separation_deg >= 0:
            raise ValueError("FeatureConfig.mode_separation_deg must be >= 0")
        self.spatial_params()  # validates the search parameters

    def spatial_params(self) -> SpatialParams:
        """The search parameters as :class:`SpatialParams`."""
        return SpatialParams(
            rho=self.rho,
            lam=self.lam,
            tau_deg=self.tau_deg,
            dtheta_deg=self.dtheta_deg,
            fov_deg=self.fov_deg,
        )

    def to_dict(self) -> dict[str, float | int]:
        """Plain dict (JSON-able)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> FeatureConfig:
        """Inverse of :meth:`to_dict`; unknown keys are an error naming them."""
        known = {f.name for f in fields(cls)}
        extra = sorted(set(data) - known)
        if extra:
            raise ValueError(f"unknown feature configuration key(s): {', '.join(extra)}")
        return cls(**data)  # type: ignore[arg-type]


@dataclass(frozen=True, eq=False)
class FrameFeatures:
    """Features of one frame pair, rows in canonical order (see the module docstring).

    Attributes:
        top: ``(M, len(TOP_FEATURES))`` float32.
        hor: ``(N, len(HOR_FEATURES))`` float32.
        hyp: ``(H, len(HYP_FEATURES))`` float32, H <= n_hypotheses (0 when nothing matched).
        pair: ``(H, M, N, len(PAIR_FEATURES))`` float32.
        top_order: ``(M,)`` input row of each canonical top row.
        hor_order: ``(N,)`` input row of each canonical horizontal row.
        hyp_camera: ``(H,)`` canonical top row of each hypothesis' O (for labels, not an input).
    """

    top: np.ndarray
    hor: np.ndarray
    hyp: np.ndarray
    pair: np.ndarray
    top_order: np.ndarray
    hor_order: np.ndarray
    hyp_camera: np.ndarray

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(H, M, N)``."""
        return self.pair.shape[0], self.top.shape[0], self.hor.shape[0]


def _canonical_order(boxes: np.ndarray) -> np.ndarray:
    """Row order of boxes sorted by x, then y, w, h: the same for any input permutation."""
    return np.lexsort((boxes[:, 3], boxes[:, 2], boxes[:, 1], boxes[:, 0]))


def _modes(ranked: Sequence[FrameAssociation], keep: int, separation: float) -> list:
    """Greedy non-maximum suppression of hypotheses of one O in orientation (best first)."""
    out: list[FrameAssociation] = []
    for h in ranked:
        gaps = [abs((h.theta - o.theta + math.pi) % (2 * math.pi) - math.pi) for o in out]
        if all(g >= separation for g in gaps):
            out.append(h)
            if len(out) == keep:
                break
    return out


def _hypotheses(
    top: np.ndarray,
    hor: np.ndarray,
    hor_width: float,
    config: FeatureConfig,
    camera: int | None,
) -> tuple[list[FrameAssociation], TopGeometry | None]:
    """Best hypotheses of a frame, lowest Phi first (ties: lower O index, then theta), and the
    search's :class:`TopGeometry` of every top box as O (a row per box) when it searched them
    all at once (None otherwise)."""
    params = config.spatial_params()
    separation = math.radians(config.mode_separation_deg)
    if camera is None:
        candidates, modes = range(top.shape[0]), config.modes_per_camera
    else:
        candidates, modes = [camera], config.n_hypotheses
    # Enough ranked orientations to find `modes` modes `separation` apart on most frames.
    depth = 1 if modes == 1 else max(4 * modes, 2 * math.ceil(
        math.degrees(separation) / config.dtheta_deg) * modes)
    found: list[FrameAssociation] = []
    geometry = None
    if depth == 1:  # one orientation per candidate: one batched search for all of them
        found, geometry = _best_per_candidate(top, hor, hor_width, params,
                                              candidates=candidates, keep=config.n_hypotheses)
        if camera is not None:
            geometry = None  # rows of the given O only
    else:
        for c in candidates:
            ranked = rank_hypotheses(top, hor, hor_width, params, candidates=[c], k=depth)
            found += _modes(ranked, modes, separation)
    found.sort(key=lambda h: (h.cost, h.camera, h.theta))
    return found[: config.n_hypotheses], geometry


def _median(values: np.ndarray) -> float:
    """``np.median`` of a short finite 1-D array, to the bit, without its general machinery
    (three per frame: a tenth of the features' numpy time): the middle value, or the two
    middle ones, each added to 0 as ``np.mean`` sums them (so -0.0 gives 0.0), over 2."""
    ordered = np.sort(values)
    k = ordered.shape[0] // 2
    if ordered.shape[0] % 2:
        return float(0.0 + ordered[k])
    return float((0.0 + ordered[k - 1] + ordered[k]) / 2.0)


def _wrap(angle: np.ndarray) -> np.ndarray:
    return np.mod(angle + np.pi, 2.0 * np.pi) - np.pi


def _hypothesis_features(
    hyps: Sequence[FrameAssociation],
    hyp_camera: np.ndarray,
    geometry: TopGeometry,
    x_hor: np.ndarray,
    y_hor: np.ndarray,
    s_top: float,
    n: int,
    config: FeatureConfig,
    camera_given: bool,
    hyp_f: np.ndarray,
    pair_f: np.ndarray,
) -> None:
    """The ``HYP_FEATURES`` into ``hyp_f`` ``(H, 7)`` and the ``PAIR_FEATURES`` into ``pair_f``
    ``(H, M, N, 12)`` (float32, zeroed) of the hypotheses ``hyps`` (see :func:`frame_features`;
    ``geometry``: the :class:`TopGeometry` of each hypothesis' O, a row each):
    every hypothesis at once, (H, M) per top person and (H, M, N) per pair, each feature computed
    in float64 and written into its slice. The (H, M, N) part runs in one compiled pass where
    the kernels are loaded (:mod:`~xvmatch.core.kernel_choice`): the same arithmetic on numpy's
    log, cos and arctan, so the same bits (tested)."""
    n_hyp, m = pair_f.shape[:2]
    half_fov = 0.5 * math.radians(config.fov_deg)
    bearing_hor = np.arctan(x_hor * math.tan(half_fov))  # (N,) right of the axis, radians
    log_y_hor = np.log(y_hor)
    thetas = np.array([h.theta for h in hyps])
    scales = np.array([h.scale for h in hyps])
    dist, visible = geometry.dist, geometry.visible
    delta = _wrap(geometry.phi - thetas[:, None])  # signed angle from the optical axis
    in_view = (np.abs(delta) < half_fov) & visible  # inside the field of view (Eqs. 5-7)
    y_top = dist * np.cos(delta)  # Eq. 5 depth
    bearing_top = -delta  # Eq. 7: x_top = -tan(delta) / tan(alpha / 2)
    depth = np.maximum(y_top, 0.05 * dist) * scales[:, None]
    log_depth = np.log(np.maximum(depth, 1e-12))
    log_dist = np.clip(np.log(np.maximum(dist, _EPS) / s_top), -_CLIP, 2 * _CLIP)
    is_cam = np.arange(m)[None, :] == hyp_camera[:, None]
    kernels = kernel_choice.kernels()
    if kernels is not None:  # the same values in one pass (numpy's log, cos, arctan above)
        per_top = np.stack([in_view, visible, is_cam, np.abs(bearing_top) / math.pi], axis=2)
        kernels.pair_features(bearing_top, log_depth, visible, per_top.astype(np.float64),
                              log_dist, bearing_hor, log_y_hor, half_fov, _CLIP, pair_f)
    else:
        diff = _wrap(bearing_top[:, :, None] - bearing_hor[None, None, :]) / half_fov
        diff = np.clip(diff, -_CLIP, _CLIP)
        absdiff = np.abs(diff)
        pair_f[..., 0] = diff
        pair_f[..., 1] = absdiff
        ratio = np.clip(log_depth[:, :, None] - log_y_hor[None, None, :], -_CLIP, _CLIP)
        pair_f[..., 2] = ratio
        pair_f[..., 3] = np.abs(ratio)
        pair_f[..., 5] = in_view[:, :, None]
        pair_f[..., 6] = visible[:, :, None]
        pair_f[..., 7] = is_cam[:, :, None]
        pair_f[..., 8] = (np.abs(bearing_top) / math.pi)[:, :, None]
        pair_f[..., 9] = absdiff - absdiff.min(axis=2, keepdims=True)
        col_ref = np.where(visible[:, :, None], absdiff, np.inf).min(axis=1, keepdims=True)
        pair_f[..., 10] = np.clip(absdiff - np.where(np.isfinite(col_ref), col_ref, 0.0), 0,
                                  _CLIP)
        pair_f[..., 11] = log_dist[:, :, None]
    sizes = [h.pairs.shape[0] for h in hyps]
    if sum(sizes):  # matched by the hypothesis' DTW
        pairs = np.concatenate([h.pairs for h in hyps])
        pair_f[np.repeat(np.arange(n_hyp), sizes), pairs[:, 0], pairs[:, 1], 4] = 1.0
    costs = np.array([max(h.cost, 1e-12) for h in hyps])
    log_cost = np.log(costs)
    hyp_f[:, 0] = np.clip(log_cost / 5.0, -_CLIP, _CLIP)
    hyp_f[:, 1] = np.minimum(log_cost - log_cost[0], 10.0) / 5.0
    hyp_f[:, 2] = np.arange(n_hyp) / config.n_hypotheses
    hyp_f[:, 3] = np.array(sizes) / n
    hyp_f[:, 4] = in_view.sum(axis=1) / n
    hyp_f[:, 5] = np.clip(np.log(np.maximum(scales * s_top * REFERENCE_SIZE[1], 1e-12)),
                          -10, 10) / 5.0
    hyp_f[:, 6] = float(camera_given)


def frame_features(
    top_boxes: np.ndarray,
    hor_boxes: np.ndarray,
    hor_size: tuple[float, float],
    config: FeatureConfig | None = None,
    camera: int | None = None,
) -> FrameFeatures:
    """Features of one frame pair (see the module docstring and the ``*_FEATURES`` names).

    Args:
        top_boxes: ``(M, 4)`` top-view boxes x, y, w, h (pixels), any order.
        hor_boxes: ``(N, 4)`` horizontal-view boxes, any order.
        hor_size: (width, height) of the horizontal image in pixels.
        config: hypothesis generation; defaults when None.
        camera: input row of the top box that is the camera location O when it is known (O
            given); None searches every top box.

    Returns:
        :class:`FrameFeatures`; M or N may be 0 (then H = 0).

    Raises:
        ValueError: malformed boxes (shape, NaN, non-positive size), image size or camera row.
    """
    config = config or FeatureConfig()
    top_boxes = as_boxes(top_boxes, "top_boxes")
    hor_boxes = as_boxes(hor_boxes, "hor_boxes")
    for name, b in (("top_boxes", top_boxes), ("hor_boxes", hor_boxes)):
        if (b[:, 2:] <= 0).any():
            raise ValueError(f"{name} has a box of zero width or height; drop it first")
    width, height = (float(v) for v in hor_size)
    if not (width > 0 and height > 0):
        raise ValueError(f"hor_size must be (width, height) > 0, got {hor_size}")
    m, n = top_boxes.shape[0], hor_boxes.shape[0]
    if camera is not None and not 0 <= int(camera) < m:
        raise ValueError(f"camera must index one of the {m} top boxes, got {camera}")
    top_order = _canonical_order(top_boxes)
    hor_order = _canonical_order(hor_boxes)
    top = top_boxes[top_order]
    hor = hor_boxes[hor_order]
    cam = None if camera is None else int(np.flatnonzero(top_order == int(camera))[0])

    # Pose-free box geometry.
    s_top = _median(np.sqrt(top[:, 2] * top[:, 3])) if m else 1.0
    centres = box_centres(top)
    log_counts = [math.log1p(m), math.log1p(n)]
    if m > 1:
        gaps = np.hypot(*(centres[:, None, :] - centres[None, :, :]).transpose(2, 0, 1))
        np.fill_diagonal(gaps, np.inf)
        nn_dist = gaps.min(axis=1)
    else:
        nn_dist = np.full(m, 100.0 * s_top)
    top_f = np.column_stack(
        [
            np.log(top[:, 2] / s_top),
            np.log(top[:, 3] / s_top),
            np.log(np.maximum(nn_dist, _EPS) / s_top),
            np.full(m, log_counts[0]),
            np.full(m, log_counts[1]),
        ]
    ).reshape(m, len(TOP_FEATURES))
    vectors, sorted_rows = horizontal_vectors(hor, width)  # Eq. 9, sorted by x
    x_hor, y_hor = np.empty(n), np.empty(n)
    x_hor[sorted_rows], y_hor[sorted_rows] = vectors[:, 0], vectors[:, 1]
    log_h = np.log(hor[:, 3] / height)
    bottom = (hor[:, 1] + hor[:, 3]) / height
    margin_x = _BORDER * width / REFERENCE_SIZE[0]
    margin_y = _BORDER * height / REFERENCE_SIZE[1]
    border = (
        (hor[:, 0] <= margin_x) | (hor[:, 0] + hor[:, 2] >= width - margin_x)
        | (hor[:, 1] + hor[:, 3] >= height - margin_y)
    )
    hor_f = np.column_stack(
        [
            x_hor,
            log_h,
            bottom,
            hor[:, 1] / height,
            np.log(hor[:, 2] / hor[:, 3]),
            border.astype(float),
            bottom - (_median(bottom) if n else 0.0),
            log_h - (_median(log_h) if n else 0.0),
            np.full(n, log_counts[0]),
            np.full(n, log_counts[1]),
        ]
    ).reshape(n, len(HOR_FEATURES))

    hyps, searched = _hypotheses(top, hor, width, config, cam) if m and n else ([], None)
    n_hyp = len(hyps)
    hyp_camera = np.array([h.camera for h in hyps], dtype=np.int64)
    # Written straight into the float32 arrays (a float64 value assigned to a float32 array
    # rounds as astype does: the same bits as building them in float64 and casting).
    hyp_f = np.zeros((n_hyp, len(HYP_FEATURES)), np.float32)
    pair_f = np.zeros((n_hyp, m, n, len(PAIR_FEATURES)), np.float32)
    if n_hyp:
        if searched is None:
            geometry = top_geometry(centres, hyp_camera, math.radians(config.tau_deg))
        else:  # the search's rows of these O (each row depends on its O alone: the same bits)
            geometry = TopGeometry(searched.phi[hyp_camera], searched.dist[hyp_camera],
                                   searched.visible[hyp_camera])
        _hypothesis_features(hyps, hyp_camera, geometry, x_hor, y_hor, s_top, n, config,
                             camera is not None, hyp_f, pair_f)
    return FrameFeatures(
        top=top_f.astype(np.float32),
        hor=hor_f.astype(np.float32),
        hyp=hyp_f,
        pair=pair_f,
        top_order=top_order.astype(np.int64),
        hor_order=hor_order.astype(np.int64),
        hyp_camera=hyp_camera,
    )


def match_labels(
    features: FrameFeatures, top_ids: np.ndarray, hor_ids: np.ndarray
) -> np.ndarray:
    """``(M, N)`` bool ground truth in canonical order: the same id in both views (labels only).

    Ids never enter the features; this is for training and evaluation targets.
    """
    t = np.asarray(top_ids)[features.top_order]
    h = np.asarray(hor_ids)[features.hor_order]
    return t[:, None] == h[None, :]


def camera_labels(features: FrameFeatures, top_ids: np.ndarray, wearer_id: int = 0) -> np.ndarray:
    """``(H,)`` bool: the hypothesis' O is the wearer (top-view id ``wearer_id``; labels only)."""
    t = np.asarray(top_ids)[features.top_order]
    return t[features.hyp_camera] == wearer_id if features.hyp_camera.size else np.zeros(0, bool)


def collate_frames(
    feats: Sequence[FrameFeatures],
    n_hypotheses: int | None = None,
) -> dict[str, np.ndarray]:
    """Pad a batch of frames to common sizes, with masks (numpy, ready for ``torch.from_numpy``).

    Args:
        feats: B frames.
        n_hypotheses: pad H to this size (default the batch maximum, at least 1).

    Returns:
        ``top (B, M, Ft)``, ``hor (B, N, Fh)``, ``hyp (B, H, Fy)``, ``pair (B, H, M, N, Fp)``
        float32 and ``top_mask (B, M)``, ``hor_mask (B, N)``, ``hyp_mask (B, H)`` bool; padded
        entries are zero and masked out. M and N are at least 1 so no dimension is empty.
    """
    b = len(feats)
    m = max([f.top.shape[0] for f in feats] + [1])
    n = max([f.hor.shape[0] for f in feats] + [1])
    h = max([f.hyp.shape[0] for f in feats] + [1]) if n_hypotheses is None else n_hypotheses
    out = {
        "top": np.zeros((b, m, len(TOP_FEATURES)), np.float32),
        "hor": np.zeros((b, n, len(HOR_FEATURES)), np.float32),
        "hyp": np.zeros((b, h, len(HYP_FEATURES)), np.float32),
        "pair": np.zeros((b, h, m, n, len(PAIR_FEATURES)), np.float32),
        "top_mask": np.zeros((b, m), bool),
        "hor_mask": np.zeros((b, n), bool),
        "hyp_mask": np.zeros((b, h), bool),
    }
    for k, f in enumerate(feats):
        hh, mm, nn = f.shape
        if hh > h:
            raise ValueError(f"frame {k} has {hh} hypotheses, more than n_hypotheses={h}")
        out["top"][k, :mm] = f.top
        out["hor"][k, :nn] = f.hor
        out["hyp"][k, :hh] = f.hyp
        out["pair"][k, :hh, :mm, :nn] = f.pair
        out["top_mask"][k, :mm] = True
        out["hor_mask"][k, :nn] = True
        out["hyp_mask"][k, :hh] = True
    return out
