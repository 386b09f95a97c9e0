"""Ground positions from the two most visible views (issue 32; the VRL paper, "paper 003",
``../shared/papers/vrl-visibility-multiview-tracking.txt``).

For every person (a global id of :mod:`xvmatch.inference.multicam`) and frame:

1. **Principal axes along the vertical** (Sec. 3, the vertical reference lines): a calibrated
   camera's vertical vanishing point is ``K R e_z``; a person's axis is the image line through it
   and the box centre (the paper finds the axis from foreground pixels sampled along reference
   lines; we have boxes, so the box centre stands for the axis position). The axis and the camera
   centre span a vertical plane whose trace on the ground is the line from the camera's foot
   along the azimuth of the ray through the box centre. ``axis="column"`` uses the image column
   through the box centre instead, as the methods the paper improves on do: its plane is not
   vertical when the camera rolls or looks down, and its trace is taken where the column's
   ground points lie.
2. **Candidates** (Sec. 2, step 2): the intersection of the traces of each pair of views.
3. **View visibility** (Eq. 3): a distance term (the nearest camera's distance over this
   camera's: Eq. 3's ``D_E(c_f, x) / D_E(c_i, x)`` rescaled to (0, 1], the same ranking) and an
   occlusion term from the other people's previous positions: each person in front of the
   candidate within the camera's field of view is an occluder when its lateral distance from the
   camera-candidate line is below the occlusion width ``W_ks`` (it removes ``T (W_ks - D_P) /
   W_ks``, ``T = N``), else a close neighbour (it adds ``D_P / D_P(I_s)``, its lateral distance
   over the field of view's half-width at its depth); everyone else adds 1; the sum is divided by
   ``N - 1``. ``V = alpha * distance + (1 - alpha) * occlusion``.
4. **MAP choice** (Eqs. 1, 4, 5): the candidate maximising
   ``lambda log(V_j1 V_j2) + (1 - lambda) log exp(-|x - x_prev|)``, with the joint visibility
   of its view pair (Eq. 4) and the smoothness prior on the person's previous estimate (Eq. 5).

``method="all"`` fuses every view instead (least-squares intersection of all traces), the
alternative the paper argues against. People seen by one calibrated view only, or through
``H`` cameras only, keep the association's fused foot point.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from xvmatch.datasets.mot_boxes import FrameBoxes
from xvmatch.geometry.ground_plane import GroundCamera

__all__ = ["LocalisationOptions", "axis_traces", "localise", "view_visibility"]


@dataclass(frozen=True)
class LocalisationOptions:
    """Parameters of the localisation.

    Attributes:
        method: ``"two_best"`` (the paper's MAP choice of two views) or ``"all"``.
        axis: ``"vertical"`` (along the vertical vanishing direction) or ``"column"``.
        alpha: weight of the distance term in Eq. 3.
        lam: weight ``lambda`` of the visibility against the smoothness prior in Eq. 1.
        occlusion_width: ``W_ks`` of Eq. 3, metres (two half body widths).
        min_angle_deg: view pairs whose traces cross at a smaller angle give no candidate.
    """

    method: str = "two_best"
    axis: str = "vertical"
    alpha: float = 0.5
    lam: float = 0.5
    occlusion_width: float = 0.45
    min_angle_deg: float = 15.0

    def __post_init__(self) -> None:
        if self.method not in ("two_best", "all"):
            raise ValueError(f"method must be 'two_best' or 'all', got {self.method!r}")
        if self.axis not in ("vertical", "column"):
            raise ValueError(f"axis must be 'vertical' or 'column', got {self.axis!r}")
        if not (0 <= self.alpha <= 1 and 0 <= self.lam <= 1):
            raise ValueError("alpha and lam must be in [0, 1]")


def axis_traces(camera: GroundCamera, boxes_xywh: np.ndarray, axis: str = "vertical"
                ) -> tuple[np.ndarray, np.ndarray]:
    """Ground traces of the planes through each box's principal axis (step 1 above).

    Args:
        camera: a calibrated camera (``camera.camera`` not None).
        boxes_xywh: ``(N, 4)`` boxes.
        axis: ``"vertical"`` or ``"column"``.

    Returns:
        (origin, direction): ``(N, 2)`` a point of each trace and ``(N, 2)`` its unit direction,
        metres on the ground; NaN where the trace is undefined.
    """
    cam = camera.camera
    b = np.asarray(boxes_xywh, dtype=float).reshape(-1, 4)
    centre = np.stack([b[:, 0] + 0.5 * b[:, 2], b[:, 1] + 0.5 * b[:, 3]], axis=1)
    if axis == "vertical":
        d = cam.ray_directions(centre)[:, :2]
        origin = np.broadcast_to(cam.c[:2], d.shape).copy()
    else:
        # The image column through the centre: its ground points at the box bottom and at a
        # point a box height below (both below the horizon in practice).
        lo = np.stack([centre[:, 0], b[:, 1] + b[:, 3]], axis=1)
        hi = np.stack([centre[:, 0], b[:, 1] + 2.0 * b[:, 3]], axis=1)
        p0, _ = camera.to_ground(lo)
        p1, _ = camera.to_ground(hi)
        origin, d = p0, p1 - p0
    n = np.linalg.norm(d, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return origin, d / n


def _intersect(o1, d1, o2, d2, min_sin: float):
    """Intersections ``(M, 2)`` of lines ``o + t d``; NaN where they cross at a smaller angle
    than ``asin(min_sin)``."""
    cross = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    diff = o2 - o1
    with np.errstate(invalid="ignore", divide="ignore"):
        t = (diff[:, 0] * d2[:, 1] - diff[:, 1] * d2[:, 0]) / cross
    p = o1 + t[:, None] * d1
    return np.where((np.abs(cross) >= min_sin)[:, None], p, np.nan)


def view_visibility(x: np.ndarray, centre: np.ndarray, forward: np.ndarray, half_fov: float,
                    others: np.ndarray, nearest_distance: np.ndarray,
                    opts: LocalisationOptions) -> np.ndarray:
    """Eq. 3 of the VRL paper: the visibility of candidates from one camera each.

    Args:
        x: ``(M, 2)`` candidate positions.
        centre: ``(M, 2)`` the camera's ground position, per candidate.
        forward: ``(M, 2)`` the camera's unit viewing direction on the ground.
        half_fov: ``(M,)`` half the horizontal field of view, radians.
        others: ``(M, S, 2)`` the other people's previous positions (NaN: absent).
        nearest_distance: ``(M,)`` distance from the candidate to the nearest camera (the
            normalised form of ``D_E(c_f, x) / D_E(c_i, x)``; see the module docstring).
        opts: ``alpha`` and the occlusion width.

    Returns:
        ``(M,)`` visibility; below zero when occluders cover the person.
    """
    ray = x - centre
    dist = np.linalg.norm(ray, axis=1)
    u = ray / np.maximum(dist, 1e-9)[:, None]
    distance_term = nearest_distance / np.maximum(dist, 1e-9)
    rel = others - centre[:, None, :]
    along = (rel * u[:, None, :]).sum(-1)  # depth along the camera-candidate line
    lateral = np.abs(rel[..., 0] * u[:, None, 1] - rel[..., 1] * u[:, None, 0])
    present = np.isfinite(along)
    depth_fwd = (rel * forward[:, None, :]).sum(-1)
    bearing = np.arctan2(np.abs(rel[..., 0] * forward[:, None, 1] - rel[..., 1]
                                * forward[:, None, 0]), depth_fwd)
    in_front = present & (along > 0) & (along < dist[:, None]) & (bearing <= half_fov[:, None])
    W = opts.occlusion_width
    occluder = in_front & (lateral < W)
    neighbour = in_front & ~occluder
    n_people = present.sum(1) + 1
    half_width = np.maximum(depth_fwd * np.tan(half_fov)[:, None], 1e-6)
    close = np.where(neighbour, np.clip(lateral / half_width, 0.0, 1.0), 0.0).sum(1)
    cover = np.where(occluder, (W - lateral) / W, 0.0).sum(1)
    free = n_people - in_front.sum(1) - 1
    occlusion = np.where(n_people > 1, (free + close - n_people * cover)
                         / np.maximum(n_people - 1, 1), 1.0)  # alone: fully visible
    return opts.alpha * distance_term + (1.0 - opts.alpha) * occlusion


def _camera_geometry(cam: GroundCamera) -> tuple[np.ndarray, np.ndarray, float]:
    """Ground position, unit ground viewing direction and half horizontal field of view."""
    c = cam.camera
    fwd = c.R[2, :2]
    fwd = fwd / max(np.linalg.norm(fwd), 1e-9)
    half = float(np.arctan(0.5 * c.width / c.K[0, 0]))
    return c.c[:2].copy(), fwd, half


def localise(cameras: Mapping[str, GroundCamera],
             boxes: Mapping[str, Mapping[int, FrameBoxes]],
             fallback: Mapping[int, tuple[np.ndarray, np.ndarray]],
             options: LocalisationOptions | None = None,
             ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Each person's ground position per frame from the principal axes of its boxes.

    Args:
        cameras: ``{name: GroundCamera}``; only those with ``K, R, c`` give axes.
        boxes: ``{name: {frame: FrameBoxes}}`` whose ids are global ids (the association's
            output, :func:`xvmatch.inference.multicam.relabel`).
        fallback: ``{global_id: (frames, xy)}`` used where fewer than two calibrated views
            see a person (the association's fused foot points).
        options: :class:`LocalisationOptions`.

    Returns:
        ``{global_id: (frames, (J, 2) xy)}`` over the frames of ``fallback``.
    """
    opts = options or LocalisationOptions()
    names = [n for n in boxes if cameras[n].camera is not None]
    geo = {n: _camera_geometry(cameras[n]) for n in names}
    centres = np.array([geo[n][0] for n in names]).reshape(-1, 2)
    min_sin = np.sin(np.radians(opts.min_angle_deg))
    # Per frame: every calibrated view's traces, keyed by global id.
    traces: dict[int, dict[int, list[tuple[int, np.ndarray, np.ndarray]]]] = {}
    for v, n in enumerate(names):
        for f, rec in boxes[n].items():
            if not len(rec):
                continue
            o, d = axis_traces(cameras[n], rec.boxes, opts.axis)
            per = traces.setdefault(f, {})
            for g, oo, dd in zip(rec.ids.tolist(), o, d, strict=True):
                if np.isfinite(dd).all():
                    per.setdefault(g, []).append((v, oo, dd))
    out_xy = {g: xy.copy() for g, (_fr, xy) in fallback.items()}
    index = {g: {int(f): i for i, f in enumerate(fr)} for g, (fr, _xy) in fallback.items()}
    previous: dict[int, np.ndarray] = {}
    for f in sorted(traces):
        per = traces[f]
        # The others' previous positions (Eq. 3 uses t - 1), else the fallback at t.
        known = {g: previous.get(g, out_xy[g][index[g][f]] if f in index.get(g, {}) else None)
                 for g in per}
        current: dict[int, np.ndarray] = {}
        for g, views in per.items():
            if g not in index or f not in index[g] or len(views) < 2:
                continue
            v_idx = np.array([v for v, _, _ in views])
            o = np.array([oo for _, oo, _ in views])
            d = np.array([dd for _, _, dd in views])
            if opts.method == "all":
                x = _least_squares(o, d)
            else:
                x = _two_best(g, v_idx, o, d, known, previous.get(g), names, geo, centres,
                              min_sin, opts)
            if x is not None and np.isfinite(x).all():
                current[g] = x
                out_xy[g][index[g][f]] = x
        for g in per:
            if g in index and f in index[g]:
                previous[g] = out_xy[g][index[g][f]]
        del current
    return {g: (fallback[g][0], out_xy[g]) for g in fallback}


def _least_squares(o: np.ndarray, d: np.ndarray) -> np.ndarray | None:
    """The point nearest all lines ``o + t d`` (least squares on their normals)."""
    n = np.stack([-d[:, 1], d[:, 0]], axis=1)
    A = n.T @ n
    if np.linalg.cond(A) > 1e6:
        return None
    return np.linalg.solve(A, n.T @ (n * o).sum(1))


def _two_best(g, v_idx, o, d, known, prev, names, geo, centres, min_sin, opts):
    """Eqs. 1, 4, 5: the candidate of the view pair with the best posterior."""
    i, j = np.triu_indices(len(v_idx), k=1)
    cand = _intersect(o[i], d[i], o[j], d[j], min_sin)
    ok = np.isfinite(cand).all(1)
    if not ok.any():
        return _least_squares(o, d)
    cand, i, j = cand[ok], i[ok], j[ok]
    others = np.array([p for h, p in known.items() if h != g and p is not None]).reshape(-1, 2)
    M = len(cand)
    nearest = np.linalg.norm(cand[:, None, :] - centres[None, :, :], axis=-1).min(1)
    vis = []
    for side in (i, j):
        views = v_idx[side]
        c = np.array([geo[names[v]][0] for v in views])
        fwd = np.array([geo[names[v]][1] for v in views])
        half = np.array([geo[names[v]][2] for v in views])
        vis.append(view_visibility(cand, c, fwd, half,
                                   np.broadcast_to(others, (M, *others.shape)), nearest, opts))
    joint = np.maximum(vis[0], 1e-3) * np.maximum(vis[1], 1e-3)  # Eq. 4
    score = opts.lam * np.log(joint)
    if prev is not None:
        score = score - (1.0 - opts.lam) * np.linalg.norm(cand - prev, axis=1)  # Eq. 5
    return cand[int(np.argmax(score))]
