"""Ground-plane trajectory association, fusion and linkage across static cameras (issue 32).

The method of the trajectory-correspondence paper (Anjum and Cavallaro, AVSS 2009; "paper 004",
``../shared/papers/unsupervised-trajectory-correspondence.txt``), on each camera's boxes and
per-camera track ids (ids are never compared across cameras):

1. **Ground projection** (Eq. 1): each box's foot point (bottom centre) goes to the ground z = 0
   through its camera's homography (:mod:`xvmatch.geometry.ground_plane`).
2. **Association** (Sec. 3.2), for every camera pair ``(m, n)`` and every pair of trajectories
   seen at the same frames (their overlap region: the frames both cameras see the person):
   the paper's spatio-temporal features on those frames (Eqs. 2-6: shape, length, average
   velocity, dominant directions, mean, principal axes), normalised, and their correlation as
   the proximity (Eq. 7). A trajectory's candidates are those within ``conflict_margin`` of its
   best correlation (Eq. 8); conflicts among them are resolved by the image-plane distance of
   the reprojected trajectories (Eq. 9), here as one assignment per camera pair
   (``scipy.optimize.linear_sum_assignment``), so that each camera's trajectory joins at most
   one trajectory of every other camera.
3. **Groups**: the pairwise links, strongest first, merge trajectories into groups; a merge that
   would put two trajectories of one camera seen at the same frame into one group is refused,
   so a trajectory is always in exactly one group and one person's group never holds two
   simultaneous trajectories of a camera.
4. **Fusion** (Eqs. 10-11): per frame, the group's ground points averaged with weights
   proportional to each trajectory's number of observations, then a moving average of
   ``smooth_window`` observations (5 in the paper).
5. **Linkage** (Eq. 12): fused segments that follow one another in time (across parts of the
   floor no camera pair shares, or where a track was cut) are chained, one assignment of segment
   ends to segment starts, gated by the distance from the constant-velocity prediction.

With ``split="fixed"`` and ``split_frames=20`` the unit of steps 2-3 is a piece of 20 frames
of a track, not the whole track; each track's pieces are joined again by majority afterwards
(:func:`_rejoin_pieces`), so that a person back in a camera's view under a new track id, or a
tracker's id switch, costs a piece, not the person's whole path (``docs/multicam.md``). By
default (``split="evidence"``) that fixed split is only a probe: each track is cut only where
the other cameras' links show its id switched, and the tracks so cut are grouped by the votes
of their pieces' links; where many tracks are cut (a tracker's output) the fixed pieces are
the answer (:mod:`xvmatch.inference.views.multicam_evidence`).

**Appearance** (optional, issue 32 item 5): with an embedder per camera (``appearance``: e.g.
the deployed bundle's appearance network on that camera's images), each trajectory (piece) that
is a candidate gets the mean of the unit descriptors of ``appearance_boxes`` of its boxes
(first, middle, last), and ``appearance_weight * |a - b| / 2`` of two candidates' descriptors is
added to their reprojection distance where the conflicts are resolved (Eq. 9's assignment) and
the links are ordered; the gates stay geometric.

``method="dtw"`` is the paper's M1 baseline: the same steps with step 2 replaced by dynamic time
warping between the two whole ground trajectories, one assignment per camera pair.

What differs from the paper (see ``docs/multicam.md``): we have boxes and tracks, not foreground
blobs; features are taken on the frames both trajectories share (the paper's overlap region
Omega, found from time rather than drawn by hand); a pair whose median ground distance over those
frames exceeds ``gate_m`` is no candidate (the paper's mean feature, Eq. 4, as a gate); the
reprojection distance is measured in box heights so that one threshold serves every camera.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.geometry.ground_plane import GroundCamera, foot_points, image_to_ground

__all__ = [
    "BoxEmbedder",
    "CameraTracks",
    "MulticamInputError",
    "MulticamOptions",
    "MulticamResult",
    "associate_cameras",
    "camera_tracks",
    "dtw_distances",
    "relabel",
    "trajectory_features",
]

_BIG = 1e9

BoxEmbedder = Callable[[int, np.ndarray], np.ndarray]
"""``embed(frame, boxes (K, 4)) -> (K, D)`` appearance descriptors of one camera's boxes of one
frame (e.g. ``LearnedMatcher.descriptors`` on that camera's image of the frame)."""


class MulticamInputError(ValueError):
    """Input the association cannot use; ``camera`` names the camera (its box file), and
    ``frame`` and ``box`` the box at fault (None when no box is), so a caller can name its line
    (:func:`xvmatch.formats.box_image_size.box_line`)."""

    def __init__(self, camera: str, message: str, frame: int | None = None,
                 box: np.ndarray | None = None):
        super().__init__(message)
        self.camera = camera
        self.frame = frame
        self.box = box


@dataclass(frozen=True)
class MulticamOptions:
    """Parameters of the association (defaults used for every figure in docs/multicam.md).

    Attributes:
        method: ``"ours"`` (paper 004) or ``"dtw"`` (its baseline M1).
        min_length: trajectories with fewer boxes take no part in association (a global id of
            their own); false detections are usually this short.
        min_common: fewest frames two trajectories must share to be compared.
        gate_m: largest median ground distance (metres) over shared frames of a candidate pair.
        conflict_margin: candidates of a trajectory are within this of its best correlation.
        reproj_gate: largest image-plane distance (Eq. 9, in box heights) of an accepted pair.
        dtw_gate_m: largest mean DTW step cost (metres) of an accepted pair (``dtw``).
        smooth_window: observations in the fusion's moving average (the paper's 5).
        link_max_gap: most frames between two segments that linkage may bridge.
        link_radius_m: linkage gate at a gap of one frame, metres.
        link_growth_m: the gate grows by this many metres per frame of gap.
        max_range_m: foot points farther from the origin are at the horizon (refused).
        split_frames: ``L > 0`` (default 20) cuts every track into pieces of ``L`` frames of
            the sequence, associated on their own (each piece joins at most one piece of every
            other camera) and rejoined afterwards unless the other cameras say a piece is
            someone else (a tracker's id switch): a track may then carry several global ids,
            one after the other, never two at once. 0 keeps each track whole, as the paper
            does (one trajectory joins at most one of every other camera).
        split: ``"evidence"`` (default): the pieces of ``split_frames`` are a probe; each
            track is cut only where the probe's global ids along it change for good and the
            pieces so cut are associated whole
            (:func:`~xvmatch.inference.views.multicam_evidence.associate_on_evidence`);
            ``"fixed"``: the pieces of ``split_frames`` are the answer's units. Either way
            ``split_frames=0`` keeps tracks whole.
        evidence_switch_frames: with ``split="evidence"``, the frames of disagreement a
            change of a track's partner in another camera must save to count as a switch.
        evidence_max_cut_share: with ``split="evidence"``, the most tracks cut, as a share of
            all tracks, for the tracks cut on evidence to be the answer; above it (a
            tracker's output) the fixed pieces are.
        appearance_weight: weight of the appearance cost ``|a - b| / 2`` (in [0, 1]) added to
            the reprojection distance (in box heights) of a candidate pair, when both cameras
            have an embedder (``associate_cameras(appearance=...)``); 0 turns it off.
        appearance_boxes: boxes of a trajectory (piece) embedded for its descriptor (evenly
            spread over its frames: first, middle, last for 3).
    """

    method: str = "ours"
    min_length: int = 5
    min_common: int = 5
    gate_m: float = 2.5
    conflict_margin: float = 0.5
    reproj_gate: float = 1.5
    dtw_gate_m: float = 2.0
    smooth_window: int = 5
    link_max_gap: int = 30
    link_radius_m: float = 0.5
    link_growth_m: float = 0.05
    max_range_m: float = 1e4
    split_frames: int = 20
    appearance_weight: float = 4.0
    appearance_boxes: int = 3
    split: str = "evidence"
    evidence_switch_frames: float = 30.0
    evidence_max_cut_share: float = 0.02

    def __post_init__(self) -> None:
        if self.method not in ("ours", "dtw"):
            raise ValueError(f"method must be 'ours' or 'dtw', got {self.method!r}")
        for name in ("min_length", "min_common", "smooth_window", "link_max_gap"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"MulticamOptions.{name} must be >= 1")
        if int(self.split_frames) < 0:
            raise ValueError("MulticamOptions.split_frames must be >= 0")
        if self.split not in ("evidence", "fixed"):
            raise ValueError(f"split must be 'evidence' or 'fixed', got {self.split!r}")
        if not self.evidence_switch_frames >= 0:
            raise ValueError("MulticamOptions.evidence_switch_frames must be >= 0")
        if not 0 <= self.evidence_max_cut_share <= 1:
            raise ValueError("MulticamOptions.evidence_max_cut_share must be in [0, 1]")
        if not self.appearance_weight >= 0:
            raise ValueError("MulticamOptions.appearance_weight must be >= 0")
        if int(self.appearance_boxes) < 1:
            raise ValueError("MulticamOptions.appearance_boxes must be >= 1")
        for name in ("gate_m", "reproj_gate", "dtw_gate_m", "link_radius_m", "max_range_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"MulticamOptions.{name} must be > 0")


@dataclass(frozen=True, eq=False)
class CameraTracks:
    """One camera's trajectories on a common frame axis.

    Attributes:
        name: the camera.
        ids: ``(T,)`` its track ids.
        present: ``(T, F)`` bool, track seen at frame ``frames[f]``.
        ground: ``(T, F, 2)`` foot points on the ground, metres (NaN where absent).
        pixels: ``(T, F, 2)`` foot pixels (NaN where absent).
        heights: ``(T,)`` median box height of each track, pixels.
        frames: ``(F,)`` the common frame numbers.
    """

    name: str
    ids: np.ndarray
    present: np.ndarray
    ground: np.ndarray
    pixels: np.ndarray
    heights: np.ndarray
    frames: np.ndarray

    @property
    def lengths(self) -> np.ndarray:
        """``(T,)`` number of observations of each track."""
        return self.present.sum(axis=1)


def camera_tracks(name: str, camera: GroundCamera, frames: Mapping[int, FrameBoxes],
                  frame_axis: np.ndarray, max_range_m: float = 1e4) -> CameraTracks:
    """Group one camera's boxes by track id and put their foot points on the ground (Eq. 1).

    Raises:
        MulticamInputError: a foot point at or above the horizon (message names frame and id).
    """
    keys = sorted(frames)
    ids = np.concatenate([frames[k].ids for k in keys] or [np.empty(0, np.int64)])
    boxes = np.concatenate([frames[k].boxes for k in keys] or [np.empty((0, 4))])
    fr = np.repeat(np.array(keys, dtype=np.int64), [len(frames[k]) for k in keys])
    uv = foot_points(boxes)
    xy, ok = image_to_ground(camera.H, uv, max_range=max_range_m, strict=False)
    if not ok.all():
        k = int(np.flatnonzero(~ok)[0])
        w = camera.H[2] @ np.array([uv[k, 0], uv[k, 1], 1.0])
        where = "behind the camera (above the horizon)" if w <= 0 else \
            f"to the horizon (farther than {max_range_m:g} m)"
        raise MulticamInputError(name, f"frame {fr[k]}, id {ids[k]}: the box's foot point "
                                       f"({uv[k, 0]:.1f}, {uv[k, 1]:.1f}) projects {where}; "
                                       "check the camera's calibration or drop the box",
                                 frame=int(fr[k]), box=boxes[k])
    uniq, t_idx = np.unique(ids, return_inverse=True)
    f_idx = np.searchsorted(frame_axis, fr)
    T, F = len(uniq), len(frame_axis)
    present = np.zeros((T, F), dtype=bool)
    present[t_idx, f_idx] = True
    ground = np.full((T, F, 2), np.nan)
    ground[t_idx, f_idx] = xy
    pixels = np.full((T, F, 2), np.nan)
    pixels[t_idx, f_idx] = uv
    h = np.full((T, F), np.nan)
    h[t_idx, f_idx] = boxes[:, 3]
    with np.errstate(all="ignore"):
        heights = np.nanmedian(h, axis=1) if T else np.empty(0)
    return CameraTracks(name, uniq, present, ground, pixels, heights, frame_axis)


# --------------------------------------------------------------------------------------------
# Features and proximity (Eqs. 2-7)


def trajectory_features(points: np.ndarray, n_bins: int = 12) -> np.ndarray:
    """The spatio-temporal features of trajectories (Eqs. 2-6 of paper 004).

    Args:
        points: ``(K, J, 2)`` K trajectories of J ground points each (metres, no NaN).
        n_bins: bins of the direction histogram (Eq. 3).

    Returns:
        ``(K, 18)``: shape ``beta`` (quadratic fit of x and y against normalised time, 6),
        length ``d`` (1), average velocity ``v`` (Eq. 2, 2), the three dominant directions of
        the turn histogram ``h`` (Eq. 3, as bin centres over pi, 3), mean ``m`` (Eq. 4, 2),
        and the two principal axes ``p`` of the covariance (Eq. 5, scaled by the square roots
        of their eigenvalues, sign fixed to a non-negative x, 4).
    """
    P = np.asarray(points, dtype=float)
    K, J, _ = P.shape
    s = np.linspace(-1.0, 1.0, J)
    V = np.stack([s**2, s, np.ones_like(s)], axis=1)  # (J, 3)
    beta = np.linalg.lstsq(V, P.transpose(1, 0, 2).reshape(J, -1), rcond=None)[0]  # (3, K*2)
    beta = beta.reshape(3, K, 2).transpose(1, 0, 2).reshape(K, 6)
    step = np.diff(P, axis=1)  # (K, J-1, 2)
    step_len = np.hypot(step[..., 0], step[..., 1])
    length = step_len.sum(axis=1, keepdims=True)
    velocity = step.sum(axis=1) / J  # Eq. 2
    theta = np.arctan2(step[..., 1], step[..., 0])
    bins = np.clip(((theta + np.pi) / (2 * np.pi) * n_bins).astype(int), 0, n_bins - 1)
    hist = np.zeros((K, n_bins))
    np.add.at(hist, (np.repeat(np.arange(K), J - 1), bins.reshape(-1)), step_len.reshape(-1))
    top3 = np.argsort(-hist, axis=1, kind="stable")[:, :3]
    turns = (top3 + 0.5) / n_bins * 2.0 - 1.0  # Eq. 3: the three peaks, in (-1, 1) of pi
    mean = P.mean(axis=1)  # Eq. 4
    centred = P - mean[:, None, :]
    cov = np.einsum("kji,kjl->kil", centred, centred) / J  # Eq. 5
    evals, evecs = np.linalg.eigh(cov)  # ascending
    axes = evecs[:, :, ::-1] * np.sqrt(np.maximum(evals[:, None, ::-1], 0.0))
    sign = np.where(axes[:, 0:1, :] < 0, -1.0, 1.0)
    axes = (axes * sign).transpose(0, 2, 1).reshape(K, 4)
    return np.concatenate([beta, length, velocity, turns, mean, axes], axis=1)


def _correlation(a: np.ndarray, b: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Eq. 7: correlation of the normalised feature vectors, row by row."""
    a, b = a / scale, b / scale
    a = a - a.mean(axis=1, keepdims=True)
    b = b - b.mean(axis=1, keepdims=True)
    den = np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1)
    return np.where(den > 0, (a * b).sum(axis=1) / np.maximum(den, 1e-300), 0.0)


def _resample(points: np.ndarray, mask: np.ndarray, length: int) -> np.ndarray:
    """``(K, length, 2)``: each row's points at ``mask`` resampled to ``length`` evenly."""
    out = np.empty((len(points), length, 2))
    for r in range(len(points)):
        p = points[r][mask[r]]
        t = np.linspace(0, len(p) - 1, length)
        out[r, :, 0] = np.interp(t, np.arange(len(p)), p[:, 0])
        out[r, :, 1] = np.interp(t, np.arange(len(p)), p[:, 1])
    return out


def dtw_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Mean step cost of the dynamic time warping of each pair of trajectories (the paper's
    baseline M1), batched: ``a``, ``b`` are ``(K, L, 2)``; returns ``(K,)`` metres."""
    cost = np.linalg.norm(a[:, :, None, :] - b[:, None, :, :], axis=-1)  # (K, L, L)
    K, L, _ = cost.shape
    D = np.full((K, L + 1, L + 1), np.inf)
    steps = np.zeros((K, L + 1, L + 1))
    D[:, 0, 0] = 0.0
    for i in range(1, L + 1):
        for j in range(1, L + 1):
            opts = np.stack([D[:, i - 1, j], D[:, i - 1, j - 1], D[:, i, j - 1]], axis=1)
            cnt = np.stack([steps[:, i - 1, j], steps[:, i - 1, j - 1], steps[:, i, j - 1]],
                           axis=1)
            k = np.argmin(opts, axis=1)
            D[:, i, j] = cost[:, i - 1, j - 1] + opts[np.arange(K), k]
            steps[:, i, j] = cnt[np.arange(K), k] + 1
    return D[:, L, L] / steps[:, L, L]


# --------------------------------------------------------------------------------------------
# Pairwise association


@dataclass(frozen=True)
class _Link:
    """An accepted pair of trajectories of two cameras and its strength (lower is stronger)."""

    cam_a: int
    track_a: int
    cam_b: int
    track_b: int
    cost: float


def _row_nanmedian(d: np.ndarray) -> np.ndarray:
    """Median of each row over its finite entries (NaN for a row without any); a fast
    ``np.nanmedian(d, axis=1)``."""
    if d.shape[0] == 0:
        return np.empty(0)
    srt = np.sort(np.where(np.isnan(d), np.inf, d), axis=1)
    n = np.isfinite(srt).sum(axis=1)
    rows = np.arange(len(d))
    lo = srt[rows, np.maximum(n - 1, 0) // 2]
    hi = srt[rows, np.maximum(n, 1) // 2 - (n == 0)]
    return np.where(n > 0, 0.5 * (lo + hi), np.nan)


def _pair_candidates(A: CameraTracks, B: CameraTracks, opts: MulticamOptions
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Index pairs sharing >= min_common frames among long enough tracks, their shared-frame
    masks ``(K, F)`` and median ground distances."""
    okA = A.lengths >= opts.min_length
    okB = B.lengths >= opts.min_length
    common = A.present.astype(np.int32) @ B.present.T.astype(np.int32)
    common[~okA] = 0
    common[:, ~okB] = 0
    ia, ib = np.nonzero(common >= opts.min_common)
    mask = A.present[ia] & B.present[ib]
    diff = A.ground[ia] - B.ground[ib]
    d = np.sqrt(diff[..., 0] ** 2 + diff[..., 1] ** 2)
    med = _row_nanmedian(np.where(mask, d, np.nan))
    return ia, ib, mask, med


def _reprojection(A: CameraTracks, B: CameraTracks, cams: tuple[GroundCamera, GroundCamera],
                  ia: np.ndarray, ib: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Eq. 9: image-plane distance of each trajectory to the other's ground points reprojected
    into its image, over the shared frames (median, in box heights), averaged over the two
    cameras."""
    out = np.zeros(len(ia))
    for own, other, cam, idx_own, idx_other in ((A, B, cams[0], ia, ib), (B, A, cams[1], ib, ia)):
        reproj = cam.to_image(other.ground[idx_other])  # (K, F, 2)
        d = np.linalg.norm(reproj - own.pixels[idx_own], axis=-1)
        d = d / np.maximum(own.heights[idx_own], 1.0)[:, None]
        # A point behind the other camera counts as far; the median keeps a few such out.
        d = np.where(mask, np.where(np.isfinite(d), d, 10.0), np.nan)
        out += 0.5 * _row_nanmedian(d)
    return out


def _window(t: CameraTracks, rows: np.ndarray, cols: slice) -> CameraTracks:
    """The tracks ``rows`` restricted to the frames ``cols``."""
    return CameraTracks(t.name, t.ids[rows], t.present[rows, cols], t.ground[rows, cols],
                        t.pixels[rows, cols], t.heights[rows], t.frames[cols])


class _Appearance:
    """Descriptors of the cameras' trajectories (pieces), computed when first asked for and
    kept: the mean of the unit descriptors of ``n_boxes`` of a trajectory's boxes (evenly
    spread over its frames), made unit again; each camera's boxes embedded frame by frame.

    Args:
        tracks: each camera's trajectories (pieces).
        track_ids: each camera's input track id of every trajectory row.
        boxes: each camera's ``{frame: FrameBoxes}`` (input track ids).
        embed: each camera's embedder, or None (no descriptors: no appearance term).
        n_boxes: boxes embedded per trajectory.
    """

    def __init__(self, tracks: list[CameraTracks], track_ids: list[np.ndarray],
                 boxes: list[Mapping[int, FrameBoxes]], embed: list[BoxEmbedder | None],
                 n_boxes: int):
        self.tracks, self.track_ids, self.boxes, self.embed = tracks, track_ids, boxes, embed
        self.n_boxes = int(n_boxes)
        self.cache: list[dict[int, np.ndarray]] = [{} for _ in tracks]

    def get(self, c: int, rows: np.ndarray) -> np.ndarray | None:
        """``(len(rows), D)`` unit descriptors of camera ``c``'s trajectories ``rows``, or None
        when the camera has no embedder."""
        embed = self.embed[c]
        if embed is None:
            return None
        cache, t = self.cache[c], self.tracks[c]
        missing = sorted({int(r) for r in rows} - cache.keys())
        wanted: dict[int, list[tuple[int, np.ndarray]]] = {}
        for r in missing:
            idx = np.flatnonzero(t.present[r])
            pick = np.unique(idx[np.round(np.linspace(0, len(idx) - 1, self.n_boxes))
                                 .astype(int)])
            tid = self.track_ids[c][r]
            for i in pick.tolist():
                f = int(t.frames[i])
                rec = self.boxes[c][f]
                j = int(np.flatnonzero(rec.ids == tid)[0])
                wanted.setdefault(f, []).append((r, rec.boxes[j]))
        sums: dict[int, np.ndarray] = {}
        for f in sorted(wanted):
            who = [r for r, _ in wanted[f]]
            d = np.asarray(embed(f, np.array([b for _, b in wanted[f]])), dtype=np.float64)
            d = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
            for r, v in zip(who, d, strict=True):
                sums[r] = sums[r] + v if r in sums else v.copy()
        for r in missing:
            cache[r] = sums[r] / max(float(np.linalg.norm(sums[r])), 1e-12)
        return np.stack([cache[int(r)] for r in rows]) if len(rows) else None


def _appearance_cost(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(K,)`` appearance cost ``|a - b| / 2`` in [0, 1] of unit descriptors row by row (as
    :func:`xvmatch.cues.matcher_inputs.appearance_cost`, the distance the network is
    trained on)."""
    cosine = (a * b).sum(axis=1)
    return np.clip(0.5 * np.sqrt(np.clip(2.0 - 2.0 * cosine, 0.0, None)), 0.0, 1.0)


_Descriptors = Callable[[int, np.ndarray], "np.ndarray | None"]


def _associate_pieces(a: int, b: int, tracks: list[CameraTracks], numbers: list[np.ndarray],
                      cams: list[GroundCamera], opts: MulticamOptions,
                      appearance: _Appearance | None = None) -> list[_Link]:
    """:func:`_associate_pair` block by block: pieces share frames only within their block of
    ``split_frames`` frames, so each block is associated on its own frames."""
    L = int(opts.split_frames)
    out = []
    for n in np.intersect1d(numbers[a], numbers[b]):
        ra, rb = np.flatnonzero(numbers[a] == n), np.flatnonzero(numbers[b] == n)
        cols = slice(int(n) * L, (int(n) + 1) * L)
        sub = [_window(tracks[a], ra, cols), _window(tracks[b], rb, cols)]
        desc = None
        if appearance is not None:
            def desc(side, rows, ra=ra, rb=rb):
                return appearance.get(a if side == 0 else b, (ra if side == 0 else rb)[rows])
        for lk in _associate_pair(0, 1, sub, [cams[a], cams[b]], opts, desc):
            out.append(_Link(a, int(ra[lk.track_a]), b, int(rb[lk.track_b]), lk.cost))
    return out


def _associate_pair(a: int, b: int, tracks: list[CameraTracks], cams: list[GroundCamera],
                    opts: MulticamOptions, descriptors: _Descriptors | None = None
                    ) -> list[_Link]:
    """The one-to-one trajectory pairs of cameras ``a`` and ``b``; ``descriptors(camera,
    rows)`` gives the trajectories' appearance descriptors (None: no appearance term)."""
    A, B = tracks[a], tracks[b]
    ia, ib, mask, med = _pair_candidates(A, B, opts)
    if opts.method == "dtw":
        if not len(ia):
            return []
        full_a = _resample(A.ground[ia], A.present[ia], 24)
        full_b = _resample(B.ground[ib], B.present[ib], 24)
        cost = dtw_distances(full_a, full_b)
        allowed = cost <= opts.dtw_gate_m
    else:
        keep = med <= opts.gate_m
        ia, ib, mask, med = ia[keep], ib[keep], mask[keep], med[keep]
        if not len(ia):
            return []
        J = 16
        fa = trajectory_features(_resample(A.ground[ia], mask, J))
        fb = trajectory_features(_resample(B.ground[ib], mask, J))
        scale = np.maximum(np.concatenate([fa, fb]).std(axis=0), 1e-3)
        corr = _correlation(fa, fb, scale)
        best_a = np.full(len(A.ids), -np.inf)
        best_b = np.full(len(B.ids), -np.inf)
        np.maximum.at(best_a, ia, corr)
        np.maximum.at(best_b, ib, corr)
        near_best = (corr >= best_a[ia] - opts.conflict_margin) | \
            (corr >= best_b[ib] - opts.conflict_margin)
        cost = _reprojection(A, B, (cams[a], cams[b]), ia, ib, mask)
        allowed = near_best & (cost <= opts.reproj_gate)
    if not allowed.any():
        return []
    ia, ib, cost = ia[allowed], ib[allowed], cost[allowed]
    if descriptors is not None and opts.method == "ours" and opts.appearance_weight > 0:
        ua, inv_a = np.unique(ia, return_inverse=True)
        ub, inv_b = np.unique(ib, return_inverse=True)
        da, db = descriptors(a, ua), descriptors(b, ub)
        if da is not None and db is not None:
            cost = cost + opts.appearance_weight * _appearance_cost(da[inv_a], db[inv_b])
    ua, ra = np.unique(ia, return_inverse=True)
    ub, rb = np.unique(ib, return_inverse=True)
    M = np.full((len(ua), len(ub)), _BIG)
    M[ra, rb] = cost
    rows, cols = linear_sum_assignment(M)
    return [_Link(a, int(ua[r]), b, int(ub[c]), float(M[r, c]))
            for r, c in zip(rows, cols, strict=True) if M[r, c] < _BIG]


# --------------------------------------------------------------------------------------------
# Groups, fusion, linkage


def _split_tracks(t: CameraTracks, length: int) -> tuple[CameraTracks, np.ndarray, np.ndarray]:
    """Cut each track into pieces of ``length`` frames of the frame axis.

    Returns:
        (pieces, parent, number): the pieces as tracks (ids 0..P-1), the row of the track each
        comes from and its piece number (frame position // length).
    """
    F = len(t.frames)
    n_pieces = -(-F // length)
    number = np.arange(F) // length
    has = np.zeros((len(t.ids), n_pieces), dtype=bool)
    rows, cols = np.nonzero(t.present)
    has[rows, number[cols]] = True
    parent, piece = np.nonzero(has)
    present = t.present[parent] & (number[None, :] == piece[:, None])
    keep = present[..., None]
    return (CameraTracks(t.name, np.arange(len(parent)), present,
                         np.where(keep, t.ground[parent], np.nan),
                         np.where(keep, t.pixels[parent], np.nan), t.heights[parent], t.frames),
            parent, piece)


class _Groups:
    """Union-find over (camera, track) with the cannot-link rule: no group holds two
    trajectories of one camera seen at the same frame."""

    def __init__(self, tracks: list[CameraTracks]):
        self.offset = np.cumsum([0] + [len(t.ids) for t in tracks])
        n = int(self.offset[-1])
        self.parent = np.arange(n)
        self.cover: dict[int, dict[int, np.ndarray]] = {}
        for c, t in enumerate(tracks):
            for k in range(len(t.ids)):
                self.cover[int(self.offset[c] + k)] = {c: t.present[k].copy()}

    def find(self, x: int) -> int:
        """The root of ``x``'s group."""
        root = x
        while self.parent[root] != root:
            root = self.parent[root]
        while self.parent[x] != root:
            self.parent[x], x = root, self.parent[x]
        return int(root)

    def union(self, x: int, y: int) -> bool:
        """Merge the groups of ``x`` and ``y`` unless that breaks the cannot-link rule."""
        rx, ry = self.find(x), self.find(y)
        if rx == ry:
            return True
        cx, cy = self.cover[rx], self.cover[ry]
        if any((cx[c] & cy[c]).any() for c in cx.keys() & cy.keys()):
            return False
        for c, m in cy.items():
            cx[c] = cx[c] | m if c in cx else m
        self.parent[ry] = rx
        del self.cover[ry]
        return True


def _rejoin_pieces(groups: _Groups, parents: list[np.ndarray], numbers: list[np.ndarray]
                   ) -> None:
    """Join the groups of consecutive pieces of the cameras' tracks, by majority.

    Every two consecutive pieces of one track are a vote that the group of the first continues
    into the group of the second. Continuations are merged most votes first, under the
    cannot-link rule, so that a single camera's wrong piece link, outvoted by the other
    cameras' tracks, stays one piece's error instead of carrying a person's later history into
    another person's global id; a continuation no other one contradicts is merged whatever its
    votes (a piece another camera missed)."""
    votes: dict[tuple[int, int], int] = {}
    for c in range(len(parents)):
        order = np.lexsort((numbers[c], parents[c]))
        same = parents[c][order[1:]] == parents[c][order[:-1]]
        for p, q in zip(order[:-1][same], order[1:][same], strict=True):
            key = (groups.find(int(groups.offset[c] + p)), groups.find(int(groups.offset[c] + q)))
            if key[0] != key[1]:
                votes[key] = votes.get(key, 0) + 1
    for (a, b), _n in sorted(votes.items(), key=lambda kv: (-kv[1], kv[0])):
        groups.union(a, b)


def _fuse(members: list[tuple[int, int]], tracks: list[CameraTracks], window: int
          ) -> tuple[np.ndarray, np.ndarray]:
    """Eqs. 10-11 and the moving average: the fused ground trajectory of one group.

    Returns:
        (frame_index, xy): ``(J,)`` indices into the frame axis and ``(J, 2)`` metres.
    """
    F = len(tracks[0].frames)
    num = np.zeros((F, 2))
    den = np.zeros(F)
    for c, k in members:
        t = tracks[c]
        w = float(t.lengths[k])  # Eq. 11: weight by the number of observations
        p = t.present[k]
        num[p] += w * t.ground[k][p]
        den[p] += w
    idx = np.flatnonzero(den > 0)
    xy = num[idx] / den[idx, None]
    if window > 1 and len(idx) > 2:
        # Centred moving average over the group's observations (gaps skipped, as in the
        # paper), the window shrunk symmetrically at the ends so that a straight walk at
        # constant speed stays where it is.
        j = np.arange(len(idx))
        half = np.minimum(np.minimum(window // 2, j), len(idx) - 1 - j)
        csum = np.concatenate([np.zeros((1, 2)), np.cumsum(xy, axis=0)])
        xy = (csum[j + half + 1] - csum[j - half]) / (2 * half + 1)[:, None]
    return idx, xy


def _link(segments: list[tuple[np.ndarray, np.ndarray]], frames: np.ndarray,
          opts: MulticamOptions) -> np.ndarray:
    """Eq. 12: chain segments end-to-start; returns each segment's chain index. Gaps and
    velocities are in frames (``frames[idx]``), not positions on the frame axis."""
    n = len(segments)
    segments = [(frames[idx], xy) for idx, xy in segments]
    starts = np.array([s[0][0] for s in segments])
    ends = np.array([s[0][-1] for s in segments])
    p_end = np.array([s[1][-1] for s in segments]).reshape(-1, 2)
    p_start = np.array([s[1][0] for s in segments]).reshape(-1, 2)
    vel = np.zeros((n, 2))
    for i, (idx, xy) in enumerate(segments):
        k = min(len(idx), 6)
        if k >= 2:
            vel[i] = (xy[-1] - xy[-k]) / max(idx[-1] - idx[-k], 1)
    gap = starts[None, :] - ends[:, None]  # (end i, start j)
    pred = p_end[:, None, :] + vel[:, None, :] * np.clip(gap, 0, None)[..., None]
    dist = np.linalg.norm(pred - p_start[None, :, :], axis=-1)
    ok = (gap >= 1) & (gap <= opts.link_max_gap) & \
        (dist <= opts.link_radius_m + opts.link_growth_m * gap)
    chain = np.arange(n)
    if ok.any():
        M = np.where(ok, dist, _BIG)
        rows, cols = linear_sum_assignment(M)
        nxt = np.full(n, -1)
        for r, c in zip(rows, cols, strict=True):
            if ok[r, c]:
                nxt[r] = c
        has_prev = np.zeros(n, dtype=bool)
        has_prev[nxt[nxt >= 0]] = True
        for head in np.flatnonzero(~has_prev):
            cur = head
            while cur >= 0:
                chain[cur] = head
                cur = nxt[cur]
    return chain


@dataclass(frozen=True, eq=False)
class MulticamResult:
    """The answer: one global id per (camera, track) and each global trajectory on the ground.

    Attributes:
        global_ids: ``{camera: {track_id: global_id}}``, every input track (with
            ``split_frames``, the global id of its first piece).
        ground: ``{global_id: (frames, xy)}``: ``(J,)`` frame numbers and ``(J, 2)`` metres.
        links: the accepted pairs ``(camera_a, track_a, camera_b, track_b)``.
        frames: the common frame axis.
        piece_ids: ``{camera: {(track_id, piece): global_id}}``; the piece of a box at frame
            ``f`` is ``position of f in frames // split_frames`` (always 0 without splitting),
            or its piece of ``piece_starts``.
        split_frames: the ``MulticamOptions.split_frames`` of fixed pieces (0: whole tracks or
            ``piece_starts``; with neither, ``global_ids`` alone says everything).
        piece_starts: ``{camera: {track_id: (P,) first frames of its pieces}}`` of tracks cut
            on evidence (empty otherwise): the piece of a box at frame ``f`` is the last one
            starting at or before ``f``.
    """

    global_ids: dict[str, dict[int, int]]
    ground: dict[int, tuple[np.ndarray, np.ndarray]]
    links: list[tuple[str, int, str, int]] = field(default_factory=list)
    frames: np.ndarray = field(default_factory=lambda: np.empty(0, np.int64))
    piece_ids: dict[str, dict[tuple[int, int], int]] = field(default_factory=dict)
    split_frames: int = 0
    piece_starts: dict[str, dict[int, np.ndarray]] = field(default_factory=dict)


def _split_pieces(whole: list[CameraTracks], split_frames: int
                  ) -> tuple[list[CameraTracks], list[np.ndarray], list[np.ndarray]]:
    """Each camera's tracks cut into pieces of ``split_frames`` frames (0: kept whole).

    Returns:
        ``(tracks, parents, numbers)`` per camera: the pieces, the row of each piece's whole
        track and its number within that track.
    """
    if split_frames:
        split = [_split_tracks(t, int(split_frames)) for t in whole]
        return [sp[0] for sp in split], [sp[1] for sp in split], [sp[2] for sp in split]
    return (whole, [np.arange(len(t.ids)) for t in whole],
            [np.zeros(len(t.ids), dtype=np.int64) for t in whole])


def _camera_links(tracks: list[CameraTracks], numbers: list[np.ndarray],
                  cams: list[GroundCamera], opts: MulticamOptions, app: _Appearance | None,
                  progress: Callable[[int], None] | None) -> list[_Link]:
    """The candidate links of every camera pair, cheapest first (ties by cameras and tracks)."""
    links: list[_Link] = []
    for a in range(len(cams)):
        for b in range(a + 1, len(cams)):
            if opts.split_frames:
                links += _associate_pieces(a, b, tracks, numbers, cams, opts, app)
            else:
                links += _associate_pair(a, b, tracks, cams, opts,
                                         None if app is None else app.get)
            if progress is not None:
                progress(1)
    links.sort(key=lambda lk: (lk.cost, lk.cam_a, lk.track_a, lk.cam_b, lk.track_b))
    return links


def _merged_groups(tracks: list[CameraTracks], links: list[_Link], parents: list[np.ndarray],
                   numbers: list[np.ndarray], split_frames: int
                   ) -> tuple[list[list[tuple[int, int]]], list[_Link]]:
    """Tracks joined along the links, cheapest first (a link inside a group is dropped).

    Returns:
        ``(groups, kept)``: each group's ``(camera, track)`` members, and the links kept.
    """
    groups = _Groups(tracks)
    kept = []
    for lk in links:
        if groups.union(int(groups.offset[lk.cam_a] + lk.track_a),
                        int(groups.offset[lk.cam_b] + lk.track_b)):
            kept.append(lk)
    if split_frames:
        _rejoin_pieces(groups, parents, numbers)
    members: dict[int, list[tuple[int, int]]] = {}
    for c, t in enumerate(tracks):
        for k in range(len(t.ids)):
            members.setdefault(groups.find(int(groups.offset[c] + k)), []).append((c, k))
    return list(members.values()), kept


def _chain_ids(group_list: list[list[tuple[int, int]]], segments: list,
               tracks: list[CameraTracks], frame_axis: np.ndarray, opts: MulticamOptions
               ) -> list[int]:
    """Each group's global id: groups linked over time into chains, the chains ordered by
    first frame, then by first position, numbered from 1."""
    # Only segments of associated or long enough tracks take part in linkage.
    linkable = [i for i, m in enumerate(group_list)
                if len(m) > 1 or tracks[m[0][0]].lengths[m[0][1]] >= opts.min_length]
    chain = np.arange(len(group_list))
    if linkable:
        sub = _link([segments[i] for i in linkable], frame_axis, opts)
        for j, i in enumerate(linkable):
            chain[i] = linkable[sub[j]]
    first = {}
    for i, ch in enumerate(chain):
        f0 = (int(segments[i][0][0]), float(segments[i][1][0, 0]), float(segments[i][1][0, 1]))
        first[ch] = min(first.get(ch, f0), f0)
    order = sorted(first, key=lambda ch: first[ch])
    gid_of_chain = {ch: g + 1 for g, ch in enumerate(order)}
    return [gid_of_chain[chain[i]] for i in range(len(group_list))]


def _fused_paths(ground: dict[int, list], frame_axis: np.ndarray
                 ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """``{global id: (frames, (T, 2) ground points)}`` from each id's segments, by id."""
    fused = {}
    for g, segs in ground.items():
        idx = np.concatenate([s[0] for s in segs])
        xy = np.concatenate([s[1] for s in segs])
        order_idx = np.argsort(idx, kind="stable")
        idx, xy = idx[order_idx], xy[order_idx]
        # Unlinked segments never overlap within a chain; keep the first at any repeat.
        uniq = np.concatenate([[True], np.diff(idx) > 0])
        fused[g] = (frame_axis[idx[uniq]], xy[uniq])
    return dict(sorted(fused.items()))


def associate_cameras(cameras: Mapping[str, GroundCamera],
                      boxes: Mapping[str, Mapping[int, FrameBoxes]],
                      options: MulticamOptions | None = None,
                      progress: Callable[[int], None] | None = None,
                      appearance: Mapping[str, BoxEmbedder] | None = None) -> MulticamResult:
    """One global id per person across static cameras, and each person's path on the ground.

    Args:
        cameras: ``{name: GroundCamera}``, at least two, one per box file.
        boxes: ``{name: {frame: FrameBoxes}}`` with per-camera track ids (never compared
            across cameras).
        options: parameters (:class:`MulticamOptions`).
        progress: called with 1 after each camera pair (for a progress bar).
        appearance: ``{name: embedder}`` of the cameras with images (any subset): the
            appearance term of ``options.appearance_weight`` between two of them (``ours``).

    Returns:
        The :class:`MulticamResult`.

    Raises:
        MulticamInputError: a camera without calibration, or a foot point at the horizon.
        ValueError: fewer than two cameras.
    """
    opts = options or MulticamOptions()
    names = list(boxes)
    if len(names) < 2:
        raise ValueError(f"multicam needs boxes of at least two cameras, got {len(names)}")
    for name in names:
        if name not in cameras:
            raise MulticamInputError(name, f"camera {name!r} has boxes but no calibration in "
                                           f"the cameras file (it has {', '.join(cameras)})")
    all_frames = sorted({f for n in names for f, r in boxes[n].items() if len(r)})
    frame_axis = np.array(all_frames or [1], dtype=np.int64)
    whole = [camera_tracks(n, cameras[n], boxes[n], frame_axis, opts.max_range_m)
             for n in names]
    tracks, parents, numbers = _split_pieces(whole, opts.split_frames)
    cams = [cameras[n] for n in names]
    app = None
    if appearance and opts.method == "ours" and opts.appearance_weight > 0:
        for name in appearance:
            if name not in boxes:
                raise MulticamInputError(name, f"camera {name!r} has images but no boxes")
        app = _Appearance(tracks, [w.ids[p] for w, p in zip(whole, parents, strict=True)],
                          [boxes[n] for n in names], [appearance.get(n) for n in names],
                          opts.appearance_boxes)
    links = _camera_links(tracks, numbers, cams, opts, app, progress)
    starts = {}
    if opts.split == "evidence" and opts.split_frames:
        from xvmatch.inference.views.multicam_evidence import evidence_groups

        ev = evidence_groups(whole, tracks, parents, numbers, links, opts)
        if ev is not None:
            tracks, parents, numbers, group_list, kept = ev.tracks, ev.parents, ev.numbers, \
                ev.groups, ev.links
            starts = {n: {int(whole[c].ids[r]): s for r, s in ev.starts[c].items()}
                      for c, n in enumerate(names)}
    if not starts:
        group_list, kept = _merged_groups(tracks, links, parents, numbers, opts.split_frames)
    segments = [_fuse(m, tracks, opts.smooth_window) for m in group_list]
    gids = _chain_ids(group_list, segments, tracks, frame_axis, opts)
    global_ids: dict[str, dict[int, int]] = {n: {} for n in names}
    piece_ids: dict[str, dict[tuple[int, int], int]] = {n: {} for n in names}
    ground: dict[int, list] = {}
    for i, m in enumerate(group_list):
        g = gids[i]
        for c, k in m:
            track = int(whole[c].ids[parents[c][k]])
            piece_ids[names[c]][(track, int(numbers[c][k]))] = g
        ground.setdefault(g, []).append(segments[i])
    for name in names:  # a track's global id: that of its first piece
        for (track, _piece), g in sorted(piece_ids[name].items()):
            global_ids[name].setdefault(track, g)
    pairs = [(names[lk.cam_a], int(whole[lk.cam_a].ids[parents[lk.cam_a][lk.track_a]]),
              names[lk.cam_b], int(whole[lk.cam_b].ids[parents[lk.cam_b][lk.track_b]]))
             for lk in kept if lk.cam_a != lk.cam_b]
    return MulticamResult(global_ids, _fused_paths(ground, frame_axis), pairs, frame_axis,
                          piece_ids, 0 if starts else int(opts.split_frames), starts)


def relabel(boxes: Mapping[str, Mapping[int, FrameBoxes]], result: MulticamResult
            ) -> dict[str, dict[int, FrameBoxes]]:
    """Each camera's boxes, in their order, with the track id replaced by its global id (the
    global id of the track's piece holding the frame, with ``split_frames`` or
    ``piece_starts``)."""
    out: dict[str, dict[int, FrameBoxes]] = {}
    for name, frames in boxes.items():
        if result.piece_starts:
            table, starts = result.piece_ids[name], result.piece_starts[name]
            out[name] = {f: FrameBoxes(f, np.array(
                [table[(int(t), int(np.searchsorted(starts[int(t)], f, side="right")) - 1)]
                 for t in rec.ids], np.int64), rec.boxes) for f, rec in frames.items()}
            continue
        if result.split_frames:
            table = result.piece_ids[name]
            pos = {int(f): i // result.split_frames for i, f in enumerate(result.frames)}
            out[name] = {f: FrameBoxes(f, np.array([table[(int(t), pos.get(f, 0))]
                                                    for t in rec.ids], np.int64), rec.boxes)
                         for f, rec in frames.items()}
            continue
        table = result.global_ids[name]
        out[name] = {f: FrameBoxes(f, np.array([table[int(t)] for t in rec.ids], np.int64),
                                   rec.boxes) for f, rec in frames.items()}
    return out
