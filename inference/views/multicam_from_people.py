"""Several static cameras put in one ground frame from their people alone (issue 68, item 2):
``xvmatch multicam`` without a calibration file.

1. **Each camera from its people** (:func:`~xvmatch.geometry.people_calibration.
   calibrate_from_people`): tilt, roll, focal length and height from the boxes of people about
   1.72 m tall; its foot points then lie on a ground map of its own (metres, the camera above
   the origin looking along +x).
2. **Each pair of cameras registered** by a similarity (rotation, translation, scale near 1)
   between their ground maps, from the people both see at once over time, not single frames:
   every pair of tracks seen together long enough proposes the similarity that lays one's path
   on the other's (Umeyama's least squares); a proposal scores the people of either camera that
   land near one of the other's in the same frame, over the whole clip; the best is refined on
   the pairs it explains. Track ids are compared within a camera only, never across.
3. **One frame for all**: the most trusted registrations (most people-frames explained) form a
   spanning tree from the camera with the most boxes; a camera the tree cannot reach is refused
   by name, with how much it shares with the others.
4. **Refined jointly**: every camera's homography to that frame refitted at once on the people
   that every pair of cameras matches, not only the tree's pairs (:func:`_refine_jointly`): the
   tree places a camera by one link, extrapolated beyond what that pair sees.

The cameras come back as full pinhole cameras in that frame, so today's association, ground
paths and bird's-eye view run on them unchanged. The estimate is as good as the people are
upright, on one flat ground and seen by two cameras at once.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from xvmatch.formats.camera_io import REGISTERED
from xvmatch.formats.mot_boxes import FrameBoxes, stack_frames
from xvmatch.geometry.ground_plane import GroundCamera, ground_from_camera
from xvmatch.geometry.people_calibration import (
    CalibrationError,
    PeopleCalibration,
    calibrate_from_people,
)

__all__ = [
    "MAX_RESIDUAL",
    "MIN_MATCHES",
    "CameraRegistration",
    "EstimatedCameras",
    "GroundSimilarity",
    "RegistrationError",
    "estimate_cameras",
    "fit_similarity",
    "register_pair",
]

MIN_MATCHES = 40
"""People-frames two cameras must explain in each other to be registered, beyond the person
matched most (another person seen by both for 4 s at 10 fps)."""

MAX_RESIDUAL = 0.6
"""Metres: the median distance between the people a registration matches, at most (right ones
measured 0.01-0.5 on renders, with box jitter too; wrong ones 0.77 and more)."""

_SIGMA = 0.5
"""Metres: the softness of "lands near one of the other camera's people"."""

_RADII = (2.0, 1.5, 1.0, 0.75, 0.75)
"""Metres: the refinement's rounds, each on the pairs mutually nearest within the radius: the
similarity's first two, the homography's all but the first."""

_MIN_COMMON = 8
"""Frames two tracks must share to propose a registration."""

_MIN_SPREAD = 0.5
"""Metres: a path must spread this much to fix a rotation (someone standing fixes none)."""

_SCALES = (0.67, 1.5)
"""Scales between two cameras' maps a registration may have, the proposal's and the refined
one's where the people are (each map's metres come from a person's height: a factor 1.5 off is a
wrong one, squeezing many people onto few)."""

_PROPOSALS = 120
"""Track pairs tried per camera pair, those seen together longest first."""

_REFINED = 6
"""Distinct proposals refined per camera pair, the best-scored first."""

_FRAMES = 100
"""Frames scored per proposal, spread evenly over the clip."""

_MIN_HOMOGRAPHY = 60
"""People-frames needed before the registration may bend from a similarity to a homography."""

_MIN_TRACK_BOXES = 10
"""Tracks with fewer boxes take no part in the estimate (a tracker's false boxes and fragments
mislead the calibration and the registration), unless that would leave less than half of a
camera's boxes (a short clip)."""

_CALIBRATION_FRAMES = 48
"""Frames, spread over the clip, each camera is calibrated on (the fit's cost grows with its
boxes; a few dozen frames of a static camera tell it as well as a thousand)."""

_DIGITS = 9
"""Every value compared with a bound or with another to decide (scores, distances, scales,
spreads, residuals) is rounded to this many decimals first (:func:`_settled`): exp, arctan2 and
BLAS differ in their last bits from one CPU to another, the decisions must not."""


class RegistrationError(ValueError):
    """The cameras cannot be put in one frame from their people; the message names the camera
    and what to give instead."""


@dataclass(frozen=True)
class GroundSimilarity:
    """``x -> scale * R(angle) x + shift`` on the ground plane (metres, radians)."""

    scale: float
    angle: float
    shift: tuple[float, float]

    def apply(self, xy: np.ndarray) -> np.ndarray:
        """Points ``(..., 2)`` mapped."""
        c, s = np.cos(self.angle), np.sin(self.angle)
        rot = np.array([[c, -s], [s, c]])
        return self.scale * np.asarray(xy, float) @ rot.T + np.asarray(self.shift)

    def inverse(self) -> GroundSimilarity:
        back = GroundSimilarity(1.0 / self.scale, -self.angle, (0.0, 0.0))
        shift = -back.apply(np.asarray(self.shift))
        return GroundSimilarity(back.scale, _wrap(back.angle), (float(shift[0]), float(shift[1])))


@dataclass(frozen=True)
class CameraRegistration:
    """How two cameras were put in one frame.

    Attributes:
        source, target: camera names; ``similarity`` maps the source's map onto the target's,
            ``homography`` (3, 3) too, bent where the people say so (:func:`_refine`).
        matches: people-frames mutually nearest within 0.75 m after the refinement.
        beyond: those beyond the pair of tracks matched most (one person seen by both can
            always be laid on itself: only the others are evidence).
        residual: their median distance, metres.
        margin: ``beyond + 1`` of the best refined proposal over that of the best one that
            puts the source's people more than 2 m away; 1 is a tie, not trusted.
    """

    source: str
    target: str
    similarity: GroundSimilarity
    homography: np.ndarray
    matches: int
    beyond: int
    residual: float
    margin: float

    @property
    def trusted(self) -> bool:
        return (self.beyond >= MIN_MATCHES and _settled(self.margin) >= 1.2
                and _settled(self.residual) <= MAX_RESIDUAL)


@dataclass(frozen=True)
class EstimatedCameras:
    """The cameras in one ground frame, and how sure each step was.

    Attributes:
        cameras: ``{name: GroundCamera}`` in the frame of ``reference``: the reference as its
            pinhole camera, the others as image -> ground homographies.
        calibrations: each camera from its own people.
        links: the registrations of the spanning tree, one per camera but the reference.
        reference: the camera whose ground map is the frame.
    """

    cameras: dict[str, GroundCamera]
    calibrations: dict[str, PeopleCalibration]
    links: list[CameraRegistration]
    reference: str

    def summary(self) -> str:
        """One line: how sure the registration is."""
        weakest = min(self.links, key=lambda r: (r.matches, r.source), default=None)
        if weakest is None:
            return f"1 camera ({self.reference}), calibrated from its people"
        return (f"{len(self.cameras)} cameras calibrated and registered from their people "
                f"(frame of {self.reference}); weakest link {weakest.source}-{weakest.target}: "
                f"{weakest.matches} people-frames within {weakest.residual:.2f} m, "
                + (f"{weakest.margin:.1f}x the next explanation" if np.isfinite(weakest.margin)
                   else "no other explanation"))

    def records(self) -> dict[str, dict]:
        """The camera file's ``estimated`` record of each camera (JSON-ready)."""
        out = {}
        by_source = {r.source: r for r in self.links}
        for name, calib in self.calibrations.items():
            rec = {**calib.to_record(), "world": REGISTERED,
                   "reference": self.reference}
            link = by_source.get(name)
            if link is not None:
                rec["registered_to"] = link.target
                rec["matches"] = link.matches
                rec["matches_beyond_one_person"] = link.beyond
                rec["residual_m"] = round(link.residual, 3)
                rec["margin"] = round(link.margin, 3)
            out[name] = rec
        return out


def _settled(value: float) -> float:
    """``value`` rounded to :data:`_DIGITS` decimals, so that comparing it decides the same on
    every CPU."""
    return round(float(value), _DIGITS)


def _wrap(angle: float) -> float:
    return float((angle + np.pi) % (2 * np.pi) - np.pi)


def fit_similarity(src: np.ndarray, dst: np.ndarray) -> GroundSimilarity:
    """The similarity that lays ``src`` ``(N, 2)`` on ``dst`` ``(N, 2)`` in least squares
    (Umeyama 1991, Eqs. 40-42), N >= 2 distinct points."""
    src, dst = np.asarray(src, float), np.asarray(dst, float)
    mu_s, mu_d = src.mean(0), dst.mean(0)
    return _similarity_of_centred(mu_s, mu_d, src - mu_s, dst - mu_d)


def _similarity_of_centred(mu_s: np.ndarray, mu_d: np.ndarray, a: np.ndarray, b: np.ndarray
                           ) -> GroundSimilarity:
    """:func:`fit_similarity` of points ``mu_s + a`` and ``mu_d + b`` (``a``, ``b`` centred)."""
    var = float((a**2).sum()) / len(a)
    cov = b.T @ a / len(a)
    # In 2-D the optimal rotation has a closed form: the angle of the covariance's "complex"
    # part; the scale is its modulus over the source's variance.
    sin = cov[1, 0] - cov[0, 1]
    cos = cov[0, 0] + cov[1, 1]
    angle = float(np.arctan2(sin, cos))
    scale = float(np.hypot(sin, cos) / max(var, 1e-12))
    shift = mu_d - GroundSimilarity(scale, angle, (0.0, 0.0)).apply(mu_s)
    return GroundSimilarity(scale, angle, (float(shift[0]), float(shift[1])))


def _paths(frames: Mapping[int, FrameBoxes], calib: PeopleCalibration, grid: np.ndarray
           ) -> np.ndarray:
    """``(F, T, 2)`` each track's foot point on the camera's ground map at each grid frame
    (NaN where absent or above the horizon), tracks in the order of their ids."""
    f, ids, boxes = stack_frames(frames)
    tracks = np.unique(ids)
    out = np.full((len(grid), len(tracks), 2), np.nan)
    at = np.searchsorted(grid, f)
    on = (at < len(grid)) & (grid[np.minimum(at, len(grid) - 1)] == f)
    feet = np.column_stack([boxes[:, 0] + 0.5 * boxes[:, 2], boxes[:, 1] + boxes[:, 3]])
    ground = calib.ground_points(feet[on]) if on.any() else np.zeros((0, 2))
    out[at[on], np.searchsorted(tracks, ids[on])] = ground
    return out


def _squared_distances(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``|p - q|^2`` of broadcast points ``(..., 2)`` (NaN where either is), as
    ``((p - q) ** 2).sum(-1)`` computes it, without its ``(..., 2)`` temporaries."""
    dx = p[..., 0] - q[..., 0]
    dy = p[..., 1] - q[..., 1]
    dx *= dx
    dy *= dy
    dx += dy
    return dx


def _explained(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Per proposal ``(K,)``: the people of either map within reach of one of the other's in
    the same frame (soft counts), ``src`` ``(K, F, A, 2)`` already mapped, ``dst`` ``(F, B, 2)``.
    The nearest one's closeness is each person's (the closeness falls with the distance: the
    exponential of the nearest, not the nearest of the exponentials)."""
    d2 = _squared_distances(src[:, :, :, None, :], dst[None, :, None, :, :])  # (K, F, A, B)
    d2[np.isnan(d2)] = np.inf
    a_near = np.exp(-0.5 * d2.min(axis=3) / _SIGMA**2)
    b_near = np.exp(-0.5 * d2.min(axis=2) / _SIGMA**2)
    return a_near.sum(axis=(1, 2)) + b_near.sum(axis=(1, 2))


def _mutual(mapped: np.ndarray, dst: np.ndarray, radius: float
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(frame, a, b)`` of the people mutually nearest within ``radius`` in the same frame,
    ``mapped`` ``(F, A, 2)`` and ``dst`` ``(F, B, 2)``."""
    return _within(_mutual_nearest(mapped, dst), radius)


def _within(nearest: tuple, radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(frame, a, b)`` of the mutually nearest people ``(frame, a, b, distance)``
    (:func:`_mutual_nearest`) within ``radius`` of each other."""
    f, a, b, dist = nearest
    keep = dist < radius
    return f[keep], a[keep], b[keep]


def _mutual_nearest(mapped: np.ndarray, dst: np.ndarray) -> tuple:
    """``(frame, a, b, distance)`` of the people mutually nearest in the same frame, ``mapped``
    ``(F, A, 2)`` and ``dst`` ``(F, B, 2)``, the distances settled."""
    d = _squared_distances(mapped[:, :, None, :], dst[:, None, :, :])
    np.sqrt(d, out=d)
    d[np.isnan(d)] = np.inf
    # Nearest and within: settled (np.round's own steps, in place).
    np.multiply(d, 10.0**_DIGITS, out=d)
    np.rint(d, out=d)
    np.divide(d, 10.0**_DIGITS, out=d)
    a_best = d.argmin(axis=2)  # (F, A)
    b_best = d.argmin(axis=1)  # (F, B)
    fa = np.nonzero(np.isfinite(np.take_along_axis(d, a_best[..., None], axis=2)[..., 0]))
    mutual = b_best[fa[0], a_best[fa]] == fa[1]
    f, a = fa[0][mutual], fa[1][mutual]
    b = a_best[f, a]
    return f, a, b, d[f, a, b]


def map_points(H: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Points ``(..., 2)`` through the plane homography ``H`` (NaN stays NaN)."""
    xy = np.asarray(xy, float)
    w = xy @ H[2, :2] + H[2, 2]
    return (xy @ H[:2, :2].T + H[:2, 2]) / w[..., None]


def fit_plane_homography(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """The homography laying ``src`` ``(N, 2)`` on ``dst`` in algebraic least squares, on
    Hartley-normalised points (the DLT), ``H[2, 2] = 1``; N >= 4 points not in one line."""

    def normaliser(p: np.ndarray) -> np.ndarray:
        mu = p.mean(0)
        scale = np.sqrt(2.0) / max(float(np.sqrt(((p - mu) ** 2).sum(1)).mean()), 1e-12)
        return np.array([[scale, 0, -scale * mu[0]], [0, scale, -scale * mu[1]], [0, 0, 1]])

    Ts, Td = normaliser(src), normaliser(dst)
    a = map_points(Ts, src)
    b = map_points(Td, dst)
    zero, one = np.zeros(len(a)), np.ones(len(a))
    rows = np.concatenate([
        np.column_stack([a[:, 0], a[:, 1], one, zero, zero, zero, -b[:, 0] * a[:, 0],
                         -b[:, 0] * a[:, 1], -b[:, 0]]),
        np.column_stack([zero, zero, zero, a[:, 0], a[:, 1], one, -b[:, 1] * a[:, 0],
                         -b[:, 1] * a[:, 1], -b[:, 1]])])
    h = np.linalg.svd(rows, full_matrices=False)[2][-1].reshape(3, 3)
    H = np.linalg.inv(Td) @ h @ Ts
    return H / H[2, 2]


def _local_scale(H: np.ndarray, xy: np.ndarray) -> float:
    """How much ``H`` stretches lengths about the point ``xy`` (the root of its Jacobian's
    determinant there)."""
    step = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]) + xy
    p = map_points(H, step)
    return _settled(np.sqrt(abs(np.linalg.det(np.stack([p[1] - p[0], p[2] - p[0]])))))


def _similarity_matrix(sim: GroundSimilarity) -> np.ndarray:
    c, s = sim.scale * np.cos(sim.angle), sim.scale * np.sin(sim.angle)
    return np.array([[c, -s, sim.shift[0]], [s, c, sim.shift[1]], [0.0, 0.0, 1.0]])


def _packed(paths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each frame's people first: ``(F, K, 2)`` points (NaN-padded) and ``(F, K)`` their track
    index (-1 pad), K the most people of a frame. A camera's tracks over a clip are many more
    than its people at a time; the frame-by-frame comparisons need only these."""
    seen = ~np.isnan(paths[..., 0])
    k = max(1, int(seen.sum(axis=1).max(initial=0)))
    order = np.argsort(~seen, axis=1, kind="stable")[:, :k]
    track = np.where(np.take_along_axis(seen, order, axis=1), order, -1)
    return np.take_along_axis(paths, order[..., None], axis=1), track


def _pair_ids(found: tuple, tracks: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The (source track, target track) of each match ``(frame, a, b)`` as one integer."""
    f, a, b = found
    ta, tb = tracks
    return ta[f, a] * (int(tb.max(initial=0)) + 1) + tb[f, b]


def _refine(sim: GroundSimilarity, src: np.ndarray, dst: np.ndarray,
            tracks: tuple[np.ndarray, np.ndarray]
            ) -> tuple[GroundSimilarity, np.ndarray, tuple, float]:
    """The similarity refitted on the people mutually nearest within each of :data:`_RADII`
    in turn, then a plane homography refitted the same way (the two maps are each the ground
    seen through an estimated camera: a homography apart, not only a similarity) where its
    matches are many and spread, kept only if it explains more; the similarity, the
    homography, the matches ``(frame, a, b)`` and their median distance at the end; ``src``
    and ``dst`` packed (:func:`_packed`), ``tracks`` their track indices."""
    for radius in _RADII[:2]:
        f, a, b = _mutual(sim.apply(src), dst, radius)
        if len(f) < 3:
            return sim, _similarity_matrix(sim), (f, a, b), float("inf")
        sim = fit_similarity(src[f, a], dst[f, b])
        residual = _settled(np.median(np.hypot(*(sim.apply(src[f, a]) - dst[f, b]).T)))
    H, found = _similarity_matrix(sim), (f, a, b)
    if len(f) < _MIN_HOMOGRAPHY or len(np.unique(_pair_ids(found, tracks))) < 3:
        return sim, H, found, residual
    nearest = None  # the people mutually nearest under H, once known
    for radius in _RADII[1:]:
        if nearest is None:
            nearest = _mutual_nearest(map_points(H, src), dst)
        f, a, b = _within(nearest, radius)
        if len(f) < _MIN_HOMOGRAPHY:
            break
        trial = np.round(fit_plane_homography(src[f, a], dst[f, b]), _DIGITS)
        trial_nearest = _mutual_nearest(map_points(trial, src), dst)
        f2, a2, b2 = _within(trial_nearest, radius)
        if len(f2) < 1.05 * len(found[0]) + 5:  # bending must explain clearly more
            break
        H, found, nearest = trial, (f2, a2, b2), trial_nearest
        residual = _settled(np.median(np.hypot(*(map_points(H, src[f2, a2]) - dst[f2, b2]).T)))
    return sim, H, found, residual


def register_pair(src: np.ndarray, dst: np.ndarray, source: str = "A", target: str = "B"
                  ) -> CameraRegistration | None:
    """The similarity laying camera ``source``'s people ``(F, A, 2)`` on ``target``'s
    ``(F, B, 2)`` (the same frames; NaN where a track is absent), or None when no two tracks
    were seen together long enough to propose one (module docstring, step 2)."""
    seen_a, seen_b = ~np.isnan(src[..., 0]), ~np.isnan(dst[..., 0])
    common = seen_a.T.astype(np.int64) @ seen_b.astype(np.int64)  # (A, B)
    a_idx, b_idx = np.nonzero(common >= _MIN_COMMON)
    order = np.lexsort((b_idx, a_idx, -common[a_idx, b_idx]))[:_PROPOSALS]
    proposals = []
    for a, b in zip(a_idx[order], b_idx[order], strict=True):
        both = seen_a[:, a] & seen_b[:, b]
        p, q = src[both, a], dst[both, b]
        mu_p, mu_q = p.mean(0), q.mean(0)
        p, q = p - mu_p, q - mu_q  # centred once, for the spreads and the fit
        if _settled(np.sqrt((p**2).sum(1).mean())) < _MIN_SPREAD or \
                _settled(np.sqrt((q**2).sum(1).mean())) < _MIN_SPREAD:
            continue
        sim = _similarity_of_centred(mu_p, mu_q, p, q)
        if _SCALES[0] <= _settled(sim.scale) <= _SCALES[1]:
            proposals.append(sim)
    if not proposals:
        return None
    centre = np.nanmean(src.reshape(-1, 2), axis=0)  # where the source's people are
    both = seen_a.any(axis=1) & seen_b.any(axis=1)  # frames with people in both
    (src, ta), (dst, tb) = _packed(src[both]), _packed(dst[both])
    rows = np.unique(np.linspace(0, len(src) - 1, min(len(src), _FRAMES)).round().astype(int))
    scores = np.concatenate([
        _explained(np.stack([s.apply(src[rows]) for s in proposals[k:k + 16]]), dst[rows])
        for k in range(0, len(proposals), 16)])
    scores = np.round(scores, _DIGITS)
    # The best few distinct proposals refined, each free to bend into a homography (two maps
    # from estimated cameras are a homography apart), then judged by what they explain beyond
    # one person: a lens misread bends the right proposal more than a wrong one.
    tried: list[tuple[tuple[int, int], np.ndarray, tuple]] = []
    for k in np.argsort(-scores, kind="stable"):
        lands = proposals[k].apply(centre)
        if any(_settled(np.hypot(*(map_points(H, centre) - lands))) < 2.0 for _, H, _ in tried):
            continue
        sim, H, found, residual = _refine(proposals[k], src, dst, (ta, tb))
        per_pair = np.unique(_pair_ids(found, (ta, tb)), return_counts=True)[1]
        beyond = int(len(found[0]) - per_pair.max(initial=0))  # all but the pair matched most
        if not _SCALES[0] <= _local_scale(H, centre) <= _SCALES[1]:
            beyond = 0
        tried.append(((beyond, len(found[0])), H, (sim, residual)))
        if len(tried) == _REFINED:
            break
    order = sorted(range(len(tried)), key=lambda i: (-tried[i][0][0], -tried[i][0][1], i))
    (beyond, matches), H, (sim, residual) = tried[order[0]]
    rival = next((tried[i][0][0] for i in order[1:]
                  if _settled(np.hypot(*(map_points(tried[i][1], centre)
                                         - map_points(H, centre)))) > 2.0),
                 0)
    margin = (beyond + 1.0) / (rival + 1.0)
    return CameraRegistration(source, target, sim, H, matches, beyond, residual, margin)


def _long_tracks(frames: Mapping[int, FrameBoxes]) -> Mapping[int, FrameBoxes]:
    """``frames`` without the tracks of fewer than :data:`_MIN_TRACK_BOXES` boxes, or as given
    when those hold half of its boxes or more."""
    ids = stack_frames(frames)[1]
    tracks, inverse, counts = np.unique(ids, return_inverse=True, return_counts=True)
    keep = counts[inverse] >= _MIN_TRACK_BOXES
    if keep.all() or 2 * int(keep.sum()) < len(ids):
        return frames
    long_tracks = tracks[counts >= _MIN_TRACK_BOXES]
    out = {}
    for frame, rec in frames.items():
        ids_here = np.asarray(rec.ids)
        kept = np.isin(ids_here, long_tracks)
        out[frame] = FrameBoxes(frame, ids_here[kept], np.asarray(rec.boxes)[kept])
    return out


def _calibration(frames: Mapping[int, FrameBoxes], size: tuple[int, int], seed: int,
                 name: str) -> PeopleCalibration:
    """The camera from the people of :data:`_CALIBRATION_FRAMES` frames spread over the clip,
    or of every frame where those are too few; its confidence is not resampled (nothing here
    reads it: the registration judges the cameras)."""
    clip = sorted(frames)
    step = -(-len(clip) // _CALIBRATION_FRAMES)
    for chosen in ([clip[::step], clip] if step > 1 else [clip]):
        f, ids, b = stack_frames({k: frames[k] for k in chosen})
        try:
            return calibrate_from_people(f, b, size, ids=ids, seed=seed, name=name,
                                         strict=False, spread=False)
        except CalibrationError as exc:
            error = exc
    raise RegistrationError(str(error)) from None


def _pair_matches(paths: Mapping[str, np.ndarray], placed: Mapping[str, np.ndarray], a: str,
                  b: str, radius: float) -> tuple[np.ndarray, np.ndarray, int, float] | None:
    """The people cameras ``a`` and ``b`` both see, mutually nearest within ``radius`` in the
    same frame once their maps are laid by ``placed`` (``{camera: homography to the reference
    map}``): their points on each camera's own map ``(M, 2)`` and ``(M, 2)``, how many are
    beyond the pair of tracks matched most, and their median distance (settled); None when
    none."""
    pa, pb = paths[a], paths[b]
    both = ~np.isnan(pa[..., 0]).all(axis=1) & ~np.isnan(pb[..., 0]).all(axis=1)
    (pa, ta), (pb, tb) = _packed(pa[both]), _packed(pb[both])
    f, i, j = _mutual(map_points(placed[a], pa), map_points(placed[b], pb), radius)
    if len(f) == 0:
        return None
    per_pair = np.unique(_pair_ids((f, i, j), (ta, tb)), return_counts=True)[1]
    beyond = len(f) - int(per_pair.max(initial=0))
    gaps = np.hypot(*(map_points(placed[a], pa[f, i]) - map_points(placed[b], pb[f, j])).T)
    return pa[f, i], pb[f, j], beyond, _settled(np.median(gaps))


def _map_jacobian(H: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points ``(M, 2)`` through ``H`` and the derivatives ``(M, 8)`` of their x and of their y
    by ``H``'s first eight entries (``H[2, 2]`` held)."""
    x, y = xy[:, 0], xy[:, 1]
    w = H[2, 0] * x + H[2, 1] * y + H[2, 2]
    u = (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / w
    v = (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / w
    zero, one = np.zeros_like(x), np.ones_like(x)
    ju = np.column_stack([x, y, one, zero, zero, zero, -u * x, -u * y]) / w[:, None]
    jv = np.column_stack([zero, zero, zero, x, y, one, -v * x, -v * y]) / w[:, None]
    return np.column_stack([u, v]), ju, jv


_JOINT_RADII = (1.0, 0.75)
"""Metres: the joint refinement's rounds, each on the people mutually nearest within the radius
under the cameras of the round before."""

_JOINT_SCALE = 0.3
"""Metres: the soft-L1 scale of the joint refinement's distances."""

_JOINT_STEPS = 10
"""Levenberg-Marquardt steps per round of the joint refinement, at most."""

_JOINT_CONVERGED = 1e-4
"""A step that lowers the joint refinement's cost by less than this share ends its round (6-7
steps on the 7-camera scene)."""

Pairs = list[tuple[str, str, np.ndarray, np.ndarray]]


def _joint_cost(pairs: Pairs, placed: Mapping[str, np.ndarray]) -> float:
    """The soft-L1 cost (in units of :data:`_JOINT_SCALE` squared) of the matched people's
    distances, ``pairs`` ``(a, b, points on a's map, points on b's map)``."""
    total = 0.0
    for a, b, p, q in pairs:
        d2 = ((map_points(placed[a], p) - map_points(placed[b], q)) ** 2).sum(1)
        total += float((np.sqrt(1.0 + d2 / _JOINT_SCALE**2) - 1.0).sum())
    return total


def _joint_step(pairs: Pairs, placed: Mapping[str, np.ndarray], names: list[str]
                ) -> tuple[np.ndarray, np.ndarray]:
    """The Gauss-Newton system ``(A, g)`` of the soft-L1 cost (its reweighted least squares)
    in the first eight entries of each homography of ``names`` (the others held)."""
    index = {n: k for k, n in enumerate(names)}
    A, g = np.zeros((8 * len(names),) * 2), np.zeros(8 * len(names))
    for a, b, p, q in pairs:
        ma, ua, va = _map_jacobian(placed[a], p)
        mb, ub, vb = _map_jacobian(placed[b], q)
        r = ma - mb
        w = 1.0 / np.sqrt(1.0 + (r**2).sum(1) / _JOINT_SCALE**2)  # soft-L1's weights
        blocks = [(index[n], ju, jv, sign) for n, ju, jv, sign in
                  ((a, ua, va, 1.0), (b, ub, vb, -1.0)) if n in index]
        for k1, u1, v1, s1 in blocks:
            rows = slice(8 * k1, 8 * k1 + 8)
            g[rows] += s1 * (u1.T @ (w * r[:, 0]) + v1.T @ (w * r[:, 1]))
            for k2, u2, v2, s2 in blocks:
                A[rows, 8 * k2:8 * k2 + 8] += s1 * s2 * ((u1 * w[:, None]).T @ u2
                                                         + (v1 * w[:, None]).T @ v2)
    return A, g


def _refine_jointly(paths: Mapping[str, np.ndarray], placed: Mapping[str, np.ndarray],
                    reference: str) -> dict[str, np.ndarray]:
    """Every camera's homography to the reference map (``placed``) refitted at once on the
    people that every pair of cameras matches, not only the spanning tree's: a pair counts
    when it matches :data:`MIN_MATCHES` people-frames beyond one person within
    :data:`MAX_RESIDUAL` (median) under the cameras so far; Levenberg-Marquardt on the
    soft-L1 cost of their distances, in rounds of :data:`_JOINT_RADII`. A tree places each
    camera by one link, extrapolated beyond what that pair sees; the other pairs pin it
    there."""
    names = [n for n in placed if n != reference]
    current = {n: np.asarray(H, float) / H[2, 2] for n, H in placed.items()}
    keys = list(current)
    for radius in _JOINT_RADII:
        pairs: Pairs = []
        for i, a in enumerate(keys):
            for b in keys[i + 1:]:
                found = _pair_matches(paths, current, a, b, radius)
                if found is not None and found[2] >= MIN_MATCHES and found[3] <= MAX_RESIDUAL:
                    pairs.append((a, b, found[0], found[1]))
        if not pairs or not names:
            break
        cost, damping = _joint_cost(pairs, current), 1e-3
        for _ in range(_JOINT_STEPS):
            A, g = _joint_step(pairs, current, names)
            d = np.sqrt(np.maximum(np.diag(A), 1e-12))  # Jacobi scaling: metres and 1/metres
            while damping < 1e6:
                step = -np.linalg.solve(A / np.outer(d, d) + damping * np.eye(len(d)),
                                        g / d) / d
                trial = dict(current)
                for k, n in enumerate(names):  # settled: the next choices alike on every CPU
                    trial[n] = np.round(current[n] + np.append(step[8 * k:8 * k + 8], 0.0)
                                        .reshape(3, 3), _DIGITS)
                trial_cost = _joint_cost(pairs, trial)
                if _settled(trial_cost) < _settled(cost):
                    gain = _settled((cost - trial_cost) / cost)
                    current, cost, damping = trial, trial_cost, max(damping / 10, 1e-9)
                    break
                damping *= 10
            else:
                break
            if gain < _JOINT_CONVERGED:
                break
    return current


def estimate_cameras(boxes: Mapping[str, Mapping[int, FrameBoxes]],
                     sizes: Mapping[str, tuple[int, int]], seed: int = 0
                     ) -> EstimatedCameras:
    """Every camera of ``boxes`` (``{camera: {frame: FrameBoxes}}``, each camera's own track
    ids) calibrated from its people and registered into one ground frame (module docstring).

    Args:
        boxes: the cameras' boxes, synchronised frames.
        sizes: ``{camera: (width, height)}`` of each camera's images.
        seed: seed of the calibrations' resampling.

    Raises:
        RegistrationError: a camera whose people cannot calibrate it, or that shares too few
            people with the others to be registered; the message names it.
    """
    names = list(boxes)
    boxes = {n: _long_tracks(boxes[n]) for n in names}
    calibrations: dict[str, PeopleCalibration] = {}
    for name in names:
        calibrations[name] = _calibration(boxes[name], sizes[name], seed, f"camera {name}")
    grid = np.array(sorted({int(f) for frames in boxes.values() for f in frames}), np.int64)
    paths = {n: _paths(boxes[n], calibrations[n], grid) for n in names}
    counts = {n: int(sum(len(r.ids) for r in boxes[n].values())) for n in names}
    reference = sorted(names, key=lambda n: (-counts[n], n))[0]
    links: dict[tuple[str, str], CameraRegistration] = {}
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            reg = register_pair(paths[a], paths[b], a, b)
            if reg is not None:
                links[(a, b)] = reg
    # Prim's spanning tree from the reference, over trusted links, most matches first.
    placed = {reference: np.eye(3)}  # each camera's map -> the reference's, a homography
    tree: list[CameraRegistration] = []
    while len(placed) < len(names):
        best: tuple[int, str, CameraRegistration] | None = None
        for (a, b), reg in links.items():
            if not reg.trusted or (a in placed) == (b in placed):
                continue
            new = b if a in placed else a
            if best is None or (reg.beyond, new) > (best[0], best[1]):
                best = (reg.beyond, new, reg)
        if best is None:
            missing = [n for n in names if n not in placed]
            shared = {n: max((r.beyond for (a, b), r in links.items() if n in (a, b)),
                             default=0) for n in missing}
            raise RegistrationError(
                "cannot put camera(s) " + ", ".join(f"{n} ({shared[n]} people-frames shared "
                                                    "at best)" for n in missing)
                + f" in one frame with the others from their people (each needs {MIN_MATCHES} "
                "people-frames shared beyond one person, without ambiguity): their views "
                "overlap too little; give --cameras")
        _, new, reg = best
        if reg.target == new:  # laid the placed source on the new target: turn it round
            back = np.linalg.inv(reg.homography)
            reg = CameraRegistration(new, reg.source, reg.similarity.inverse(), back / back[2, 2],
                                     reg.matches, reg.beyond, reg.residual, reg.margin)
        placed[new] = placed[reg.target] @ reg.homography
        tree.append(reg)
    placed = _refine_jointly(paths, placed, reference)
    cameras = {}
    for n in names:
        own = calibrations[n].camera
        H = np.round(placed[n] @ ground_from_camera(own), _DIGITS + 3)
        cameras[n] = (GroundCamera.from_camera(own) if n == reference
                      else GroundCamera(H, own.width, own.height))
    return EstimatedCameras(cameras, calibrations, tree, reference)
