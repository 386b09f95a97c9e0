"""Ground positions from the two most visible views (issue 32; the VRL paper, "paper 003",
``../shared/papers/vrl-visibility-multiview-tracking.txt``).

For every person (a global id of :mod:`xvmatch.inference.views.multicam`) and frame:

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

from xvmatch.formats.mot_boxes import FrameBoxes
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
            output, :func:`xvmatch.inference.views.multicam.relabel`).
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
    cam_c = np.array([geo[n][0] for n in names]).reshape(-1, 2)
    cam_fwd = np.array([geo[n][1] for n in names]).reshape(-1, 2)
    cam_half = np.array([geo[n][2] for n in names])
    previous: dict[int, np.ndarray] = {}
    for f in sorted(traces):
        per = {g: v for g, v in traces[f].items() if f in index.get(g, {})}
        people = list(per)
        if opts.method == "all":
            found = {g: _least_squares(np.array([o for _, o, _ in per[g]]),
                                       np.array([d for _, _, d in per[g]]))
                     for g in people if len(per[g]) >= 2}
        else:
            # The others' previous positions (Eq. 3 uses t - 1), else the fallback at t.
            known = np.array([previous.get(g, out_xy[g][index[g][f]]) for g in people])
            found = _two_best_frame(people, per, known, previous, cam_c, cam_fwd, cam_half,
                                    centres, min_sin, opts)
        for g, x in found.items():
            if x is not None and np.isfinite(x).all():
                out_xy[g][index[g][f]] = x
        for g in people:
            previous[g] = out_xy[g][index[g][f]]
    return {g: (fallback[g][0], out_xy[g]) for g in fallback}


def _two_best_frame(people, per, known, previous, cam_c, cam_fwd, cam_half, centres, min_sin,
                    opts) -> dict:
    """Eqs. 1, 4, 5 for every person of one frame at once: the candidate of the view pair with
    the best posterior (least squares over all views where no pair crosses well enough)."""
    rows = []  # (person k, view a, view b, o_a, d_a, o_b, d_b)
    for k, g in enumerate(people):
        views = per[g]
        for a in range(len(views)):
            for b in range(a + 1, len(views)):
                rows.append((k, views[a][0], views[b][0], views[a][1], views[a][2],
                             views[b][1], views[b][2]))
    found: dict[int, np.ndarray | None] = {}
    if not rows:
        return found
    k = np.array([r[0] for r in rows])
    va = np.array([r[1] for r in rows])
    vb = np.array([r[2] for r in rows])
    cand = _intersect(np.array([r[3] for r in rows]), np.array([r[4] for r in rows]),
                      np.array([r[5] for r in rows]), np.array([r[6] for r in rows]), min_sin)
    valid = np.isfinite(cand).all(1)
    M, S = len(rows), len(people)
    others = np.broadcast_to(known, (M, S, 2)).copy()
    others[np.arange(M), k] = np.nan  # a person does not hide itself
    nearest = np.linalg.norm(cand[:, None, :] - centres[None, :, :], axis=-1).min(1)
    vis = [view_visibility(cand, cam_c[v], cam_fwd[v], cam_half[v], others, nearest, opts)
           for v in (va, vb)]
    joint = np.maximum(vis[0], 1e-3) * np.maximum(vis[1], 1e-3)  # Eq. 4
    score = opts.lam * np.log(joint)
    prev = np.array([previous.get(g, np.full(2, np.nan)) for g in people])[k]
    step = np.linalg.norm(cand - prev, axis=1)
    score = score - (1.0 - opts.lam) * np.where(np.isfinite(step), step, 0.0)  # Eq. 5
    score = np.where(valid, score, -np.inf)
    order = np.lexsort((-score, k))
    first = order[np.concatenate([[True], k[order][1:] != k[order][:-1]])]
    for r in first:
        g = people[k[r]]
        if np.isfinite(score[r]):
            found[g] = cand[r]
        else:
            views = per[g]
            found[g] = _least_squares(np.array([o for _, o, _ in views]),
                                      np.array([d for _, _, d in views]))
    return found


def _least_squares(o: np.ndarray, d: np.ndarray) -> np.ndarray | None:
    """The point nearest all lines ``o + t d`` (least squares on their normals)."""
    n = np.stack([-d[:, 1], d[:, 0]], axis=1)
    A = n.T @ n
    if np.linalg.cond(A) > 1e6:
        return None
    return np.linalg.solve(A, n.T @ (n * o).sum(1))
