"""A fixed top camera's orientation refined from the video itself.

A top camera calibrated a degree or two off moves its head rays (geometric-priors Eq. 5) by a
metre or more at the scene, and the learned matcher, trained with exact cameras, trusts the ray
distance (Eq. 6): on rendered videos a 2-degree error of the fixed top camera brings per-frame
association below the boxes alone, while the same error of the egocentric camera, frame by
frame, costs next to nothing (docs/method.md, "How exact they must be"). A fixed top camera
has one orientation for the whole video, so the video can correct it:

* every horizontal head ray should meet the head ray of a different top box (Eq. 6 distance,
  robust loss ``d^2 / (d^2 + s^2)``, one-to-one by the Hungarian method; pairs that fail the
  cheirality test of Eq. 7 count as missing);
* one top head ray should pass through the egocentric camera or just above it (its wearer
  is in the top view; :data:`WEARER_HEAD`).

The rotation of the top camera about its centre that minimises the mean loss over a sample of
frames, plus a small price per squared degree (of two fits alike, the smaller turn), is searched
on a grid within ``max_deg``, then by Nelder-Mead from the best grid points and the given
orientation at shrinking scales ``s`` (the best two go on to the finest); the lowest final loss
wins. When that fit stays poor (loss above :data:`WIDE_LOSS`: a camera further off than the
grid, or both cameras off), a coarser grid out to ``wide_deg`` is searched the same way (ranked
at a scale as much coarser as its step), and its fit is kept if its loss is
:data:`WIDE_GAIN` lower; a good fit within ``max_deg`` is never searched further.
Only the orientation is refined: a centre a few decimetres off moves the rays by as much, a
turn of 2 degrees by metres.

A top camera that moves (a drone in flight, its camera per frame from telemetry) is refined the
same way for the error that stays constant while it flies: either a turn in the camera's own
frame (its mount, or a gimbal's offset: frame ``f``'s world directions turned by
``A_f^T Q A_f`` with ``A_f = R_0^T R_f``, frame 0 the first sampled one) or one in the world
(a heading or levelling bias: ``Q`` on every frame). Both are searched, the lower loss wins;
for a fixed camera the two are the same turn.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import linear_sum_assignment, minimize
from scipy.spatial.transform import Rotation

from xvmatch.core.array_checks import as_boxes
from xvmatch.geometry.camera import Camera, same_camera
from xvmatch.geometry.ray_priors import METRIC_MARGIN, box_rays

__all__ = ["MAX_PAIRS", "MIN_REFINE_FRAMES", "WEARER_HEAD", "WIDE_GAIN", "WIDE_LOSS",
           "TopCameraRefinement", "refine_top_camera", "turned_camera"]

MIN_REFINE_FRAMES: int = 10
"""Fewest frames with boxes in both views to refine on: a few frames hold too few people to
tell a turn of the camera from a chance alignment of unrelated heads."""

WEARER_HEAD: float = 0.5
"""Metres from the egocentric camera up to its wearer's head top, at most (a camera worn at the
eyes: about 0.1; on the chest: about 0.4)."""

MAX_PAIRS: int = 20_000
"""Top x horizontal box pairs the search holds at once (over its frames), by default: 30 frames
of 30 x 20 people; a crowd is refined on fewer frames."""

WIDE_LOSS: float = 0.3
"""Loss (with its price per squared degree) above which the fit within ``max_deg`` is not taken
as final and the wider grid is searched too. Rendered videos (docs/method.md): a top camera
off alone ends at 0.09 to 0.38 when its turn is found, at 0.49 to 0.81 when the grid does not
reach it; with both cameras 2 degrees or more off it stays above 0.3 however good the fit,
hence also :data:`WIDE_GAIN`."""

WIDE_GAIN: float = 0.05
"""Least drop of the loss for the wider grid's fit to replace the one within ``max_deg``: a
camera far off drops it by 0.2 and more, while both cameras a few degrees off leave a rough
loss whose other dips, a few thousandths lower, lie degrees away (renders, docs/method.md)."""

_SCALES = (1.0, 0.5, 0.25, 0.12)  # metres, the robust loss's scale s, coarse to fine
_STARTS = 4  # best grid points refined (and the given orientation)
_FINE = 2  # of those, the best taken on to the fine scales
_MISS = 10.0  # metres: a pair behind a camera (Eq. 7) or padding, beyond any scale
_GRID_SCALE = 0.5  # metres per degree of the grid's step: the scale a grid is ranked at
_PRIOR = 0.002  # loss per squared degree of turn: of two fits alike, the smaller turn
_CHUNK = 1 << 20  # (turn, frame, top, horizontal) entries the grid's losses hold at once


@dataclass(frozen=True)
class TopCameraRefinement:
    """What :func:`refine_top_camera` found.

    Attributes:
        camera: the top camera turned by ``rotation_deg`` (the given one when ``angle_deg`` is 0);
            for a moving one, the first sampled frame's (:meth:`turn` turns any frame's).
        rotation_deg: ``(3,)`` rotation vector, degrees, that turns the top camera's world ray
            directions (``R' = R Q^T`` with ``Q`` this rotation; a moving camera's ``camera``
            frame: on the first sampled frame).
        angle_deg: its angle, degrees.
        frames: the frames it was fitted on.
        loss_before, loss_after: mean robust loss at the finest scale, given and refined
            (0: every head ray meets its partner; 1: none does).
        frame: ``"fixed"`` (one top camera), or for a moving one the frame the turn is
            constant in: ``"camera"`` (its mount) or ``"world"`` (its heading or levelling).
        reference: the first sampled frame's top camera (``"camera"`` turns are relative to
            it), or None.
    """

    camera: Camera
    rotation_deg: tuple[float, float, float]
    angle_deg: float
    frames: int
    loss_before: float
    loss_after: float
    frame: str = "fixed"
    reference: Camera | None = None

    def turn(self, top: Camera) -> Camera:
        """``top``, a frame's top camera as given, turned as the fit says (``A_f^T Q A_f``
        with ``A_f = R_0^T R_f`` in the camera's frame; ``Q`` otherwise); itself when the
        fit did not turn."""
        if self.angle_deg == 0.0:
            return top
        rotvec = np.asarray(self.rotation_deg, dtype=float)
        if self.frame == "camera":
            rotvec = (self.reference.R.T @ top.R).T @ rotvec  # the rotation vector of A^T Q A
        return turned_camera(top, rotvec)

    def fitted_on(self, usable: int | None = None) -> str:
        """The frames it was fitted on, in words: ``30 of the 60 frames with people in both
        views, evenly spread`` when only a sample of the ``usable`` ones was fitted."""
        if usable is None or usable <= self.frames:
            return f"{self.frames} frames with people in both views"
        return f"{self.frames} of the {usable} frames with people in both views, evenly spread"

    def describe(self, usable: int | None = None) -> str:
        """One line for the user; ``usable``: the frames with people in both views, of which
        the fit sampled :attr:`frames`."""
        what = {"fixed": "the top camera",
                "camera": "the moving top camera in its own frame (a mount offset)",
                "world": "the moving top camera in the world (a heading or level offset)"}
        return (f"turned {what[self.frame]} {self.angle_deg:.2f} degrees so the people of both "
                f"views line up, fitted on {self.fitted_on(usable)} (misfit "
                f"{self.loss_before:.3f} -> {self.loss_after:.3f})")


class _RayFrames:
    """The sampled frames' head rays, padded to ``(F, M, 3)`` and ``(F, N, 3)``.

    ``top`` is one fixed camera, or each frame's with ``turns`` ``(F, 3, 3)``: the ``A_f`` of
    the module docstring (identities for a turn constant in the world)."""

    def __init__(self, top: Camera | Sequence[Camera], hor_cameras: Sequence[Camera],
                 top_boxes: Sequence[np.ndarray], hor_boxes: Sequence[np.ndarray],
                 margin: float, turns: np.ndarray | None = None) -> None:
        f = len(hor_cameras)
        tops = [top] * f if isinstance(top, Camera) else list(top)
        self.turns = turns
        m = max(len(b) for b in top_boxes)
        n = max(len(b) for b in hor_boxes)
        self.top_dirs = np.zeros((f, m, 3))
        self.hor_dirs = np.zeros((f, n, 3))
        self.top_mask = np.zeros((f, m), bool)
        self.hor_mask = np.zeros((f, n), bool)
        self.baseline = np.zeros((f, 3))
        self.hor_axis = np.zeros((f, 3))  # optical axes in the world (depth = axis . (X - c))
        # one optical axis for a fixed camera, (F, 3) for a moving one
        self.top_axis = tops[0].R[2].copy() if turns is None else np.stack([t.R[2] for t in tops])
        self.sizes = []
        for k, (cam, tb, hb, tc) in enumerate(zip(hor_cameras, top_boxes, hor_boxes, tops,
                                                  strict=True)):
            self.top_dirs[k, :len(tb)] = box_rays(tc, tb).directions
            self.hor_dirs[k, :len(hb)] = box_rays(cam, hb).directions
            self.top_mask[k, :len(tb)] = True
            self.hor_mask[k, :len(hb)] = True
            self.baseline[k] = cam.c - tc.c
            self.hor_axis[k] = cam.R[2]
            self.sizes.append((len(tb), len(hb)))
        self.margin = margin
        # the parts of Eqs. 6-7 that the turn of the top camera leaves alone
        self.hor_cross_b = np.cross(self.hor_dirs, self.baseline[:, None, :])   # n_j x c1c2
        self.hor_b = np.einsum("fnk,fk->fn", self.hor_dirs, self.baseline)
        self.hor_depth = np.einsum("fnk,fk->fn", self.hor_dirs, self.hor_axis)
        self.b_hor = np.einsum("fk,fk->f", self.baseline, self.hor_axis)
        # a turn keeps a top ray's angle to the top camera's own axis
        self.top_depth = np.einsum("fmk,fk->fm", self.top_dirs,
                                   np.broadcast_to(self.top_axis, (f, 3)))
        self.b_sq = np.einsum("fk,fk->f", self.baseline, self.baseline)
        self.pair_mask = self.top_mask[:, :, None] & self.hor_mask[:, None, :]
        self.rows_fewer = np.array([m <= n for m, n in self.sizes])     # pair every top head
        self.unpaired = float(sum(n - min(m, n) for m, n in self.sizes))  # 1 per head left

    def _turned(self, rotvecs_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The top directions turned by each of ``rotvecs_deg`` ``(G, 3)``: ``(G, F, M, 3)``,
        and the top camera's turned optical axis, ``(G, F, 3)`` (``(G, 1, 3)`` when fixed)."""
        q = Rotation.from_rotvec(np.radians(rotvecs_deg)).as_matrix()       # (G, 3, 3)
        if self.turns is not None:  # each frame's turn A_f^T Q A_f
            q = np.einsum("fji,gjk,fkl->gfil", self.turns, q, self.turns)   # (G, F, 3, 3)
            axis = np.einsum("gfij,fj->gfi", q, self.top_axis)
        else:
            q = q[:, None]                                                   # (G, 1, 3, 3)
            axis = np.einsum("gfij,j->gfi", q, self.top_axis)
        return self.top_dirs[None] @ np.swapaxes(q, -1, -2), axis

    def _pairs(self, nt: np.ndarray, axis_top: np.ndarray) -> np.ndarray:
        """``(G, F, M, N)`` Eq. 6 distances of the turned top rays ``nt`` with the horizontal
        ones, :data:`_MISS` where Eq. 7 fails: :func:`~xvmatch.geometry.ray_priors.ray_distances`
        and :func:`~xvmatch.geometry.ray_priors.cheirality_mask` batched, each product of Eq. 6
        rewritten on unit directions (``|c1c2 . (n_i x n_j)| = |n_i . (n_j x c1c2)|``,
        ``||n_i x n_j||^2 = 1 - cos^2``) so that no ``(M, N, 3)`` array is made."""
        nh = self.hor_dirs
        cos = nt @ np.swapaxes(nh, -1, -2)[None]                             # (G, F, M, N)
        triple = nt @ np.swapaxes(self.hor_cross_b, -1, -2)[None]
        sin_sq = 1.0 - cos ** 2
        sin = np.sqrt(np.maximum(sin_sq, 0.0))
        dist = np.abs(triple) / np.maximum(sin, 1e-9)
        bt = np.einsum("gfmk,fk->gfm", nt, self.baseline)[..., None]
        bh = self.hor_b[None, :, None, :]
        den = np.maximum(sin_sq, 1e-9)
        along_top = (bt - cos * bh) / den          # the closest points, along the top ray
        along_hor = (cos * bt - bh) / den          # and along the horizontal one
        # their midpoint (Eq. 7), its depth in each camera; a point's depth along an axis is
        # linear in it, so each ray's depth is taken once: (u . a) and (v . a)
        hor_top = np.einsum("fnk,gfk->gfn", nh, axis_top)[:, :, None, :]
        b_top = np.einsum("fk,gfk->gf", self.baseline, axis_top)[..., None, None]
        depth_top = 0.5 * (along_top * self.top_depth[None, :, :, None] + along_hor * hor_top
                           + b_top)
        top_hor = np.einsum("gfmk,fk->gfm", nt, self.hor_axis)[..., None]
        depth_hor = 0.5 * (along_top * top_hor + along_hor * self.hor_depth[None, :, None, :]
                           - self.b_hor[None, :, None, None])
        ok = (depth_top > self.margin) & (depth_hor > self.margin) & (sin >= 1e-9)
        ok &= self.top_mask[None, :, :, None] & self.hor_mask[None, :, None, :]
        return np.where(ok, dist, _MISS)

    def distances(self, rotvec_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(F, M, N)`` Eq. 6 distances of every frame's head rays with the top ones turned by
        ``rotvec_deg``, :data:`_MISS` where Eq. 7 fails, and the turned top directions
        ``(F, M, 3)``."""
        nt, axis = self._turned(np.asarray(rotvec_deg, float)[None])
        return self._pairs(nt, axis)[0], nt[0]

    def losses(self, rotvecs_deg: np.ndarray, scale: float) -> np.ndarray:
        """``(G,)`` :meth:`loss` of each of ``rotvecs_deg`` ``(G, 3)``, a few at a time."""
        rotvecs_deg = np.asarray(rotvecs_deg, float).reshape(-1, 3)
        f, m, n = self.top_dirs.shape[0], self.top_dirs.shape[1], self.hor_dirs.shape[1]
        chunk = max(1, _CHUNK // (f * m * n))
        return np.concatenate([self._losses(rotvecs_deg[i:i + chunk], scale)
                               for i in range(0, len(rotvecs_deg), chunk)])

    def loss(self, rotvec_deg: np.ndarray, scale: float) -> float:
        """Mean robust loss of the one-to-one head-ray pairs and the wearer term."""
        return float(self._losses(np.asarray(rotvec_deg, float)[None], scale)[0])

    def _assigned(self, rho: np.ndarray) -> np.ndarray:
        """``(G,)`` sums over the frames of the one-to-one pairs' ``rho`` (``(G, F, M, N)``) at
        their least, plus 1 per horizontal head left unpaired. Where the smaller view's heads
        each have their least ``rho`` with a different head of the other, those least values
        are the optimum (no assignment does better than each head's best); the Hungarian
        method solves the rest."""
        pairs = np.where(self.pair_mask[None], rho, np.inf)
        best_col = pairs.argmin(axis=3)                                   # (G, F, M)
        best_row = pairs.argmin(axis=2)                                   # (G, F, N)
        col_hit = np.where(self.top_mask[None], best_col, -1 - np.arange(best_col.shape[2]))
        row_hit = np.where(self.hor_mask[None], best_row, -1 - np.arange(best_row.shape[2]))
        col_sorted, row_sorted = np.sort(col_hit, axis=2), np.sort(row_hit, axis=2)
        clash = np.where(self.rows_fewer[None],
                         (col_sorted[..., 1:] == col_sorted[..., :-1]).any(axis=2),
                         (row_sorted[..., 1:] == row_sorted[..., :-1]).any(axis=2))
        least = np.where(self.rows_fewer[None],
                         np.where(self.top_mask[None], pairs.min(axis=3), 0.0).sum(axis=2),
                         np.where(self.hor_mask[None], pairs.min(axis=2), 0.0).sum(axis=2))
        for g, k in zip(*np.nonzero(clash), strict=True):
            m, n = self.sizes[k]
            r, c = linear_sum_assignment(rho[g, k, :m, :n])
            least[g, k] = rho[g, k, r, c].sum()
        return least.sum(axis=1) + self.unpaired

    def _losses(self, rotvecs_deg: np.ndarray, scale: float) -> np.ndarray:
        nt, axis = self._turned(rotvecs_deg)
        dist = self._pairs(nt, axis)
        rho = dist ** 2 / (dist ** 2 + scale ** 2)
        total = self._assigned(rho)
        # the wearer: one top head ray passes through the egocentric camera or up to
        # WEARER_HEAD metres above it (worn at the eyes or on the chest); the closest point of
        # that vertical segment to each ray (its squared distance is convex in the height).
        # With p_b = b - (b . n) n and p_up = z - n_z n off the unit ray n:
        along_b = np.einsum("fk,gfmk->gfm", self.baseline, nt)
        nz = nt[..., 2]
        b_up = self.baseline[None, :, None, 2] - along_b * nz             # p_b . p_up
        up_sq = 1.0 - nz ** 2                                             # |p_up|^2
        height = np.clip(-b_up / np.maximum(up_sq, 1e-12), 0.0, WEARER_HEAD)
        perp_sq = (self.b_sq[None, :, None] - along_b ** 2 + 2.0 * height * b_up
                   + height ** 2 * up_sq)
        perp = np.sqrt(np.maximum(perp_sq, 0.0))
        along = along_b + height * nz
        perp = np.where((along > 0) & self.top_mask[None], perp, _MISS).min(axis=2)
        total += np.sum(perp ** 2 / (perp ** 2 + scale ** 2), axis=1)
        count = sum(n for _, n in self.sizes) + len(self.sizes)
        return total / count + _PRIOR * np.sum(np.square(rotvecs_deg), axis=1)


def _grid(half_width: float, step: float) -> np.ndarray:
    """``(G, 3)`` rotation vectors, degrees: a cubic grid of ``step`` within ``half_width``."""
    axis = np.arange(-half_width, half_width + 1e-9, step)
    return np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)


def _grid_starts(rays: _RayFrames, grid: np.ndarray, step: float) -> list[np.ndarray]:
    """The :data:`_STARTS` points of ``grid`` with the lowest loss at the scale
    ``_GRID_SCALE * step``: a coarser grid's points lie further from the best turn, so their
    rays miss by more."""
    grid_loss = rays.losses(grid, _GRID_SCALE * step)
    return [grid[i] for i in np.argsort(grid_loss, kind="stable")[:_STARTS]]


def _search(rays: _RayFrames, starts: list[np.ndarray]) -> tuple[np.ndarray, float]:
    """The best fit from ``starts`` and its loss at the finest scale: every start descended by
    Nelder-Mead at the coarse scales, the best :data:`_FINE` of them on to the fine ones,
    rounded to 1e-4 degrees."""

    def descend(x: np.ndarray, scales: tuple[float, ...]) -> np.ndarray:
        for scale in scales:
            x = minimize(rays.loss, x, args=(scale,), method="Nelder-Mead",
                         options={"xatol": 0.01, "fatol": 1e-7, "maxiter": 400}).x
        return x

    half = len(_SCALES) // 2
    coarse = [descend(x, _SCALES[:half]) for x in starts]
    order = np.argsort([rays.loss(x, _SCALES[half - 1]) for x in coarse], kind="stable")
    fits = [np.round(descend(coarse[i], _SCALES[half:]), 4) for i in order[:_FINE]]
    losses = [rays.loss(x, _SCALES[-1]) for x in fits]
    best = int(np.argmin(losses))  # the first of equals
    return fits[best], losses[best]


def turned_camera(camera: Camera, rotvec_deg) -> Camera:
    """``camera`` turned about its centre by the rotation vector ``rotvec_deg`` (degrees), which
    turns its world ray directions: ``R' = R Q^T``."""
    q = Rotation.from_rotvec(np.radians(rotvec_deg)).as_matrix()
    return Camera(K=camera.K, R=camera.R @ q.T, c=camera.c, width=camera.width,
                  height=camera.height)


def _sample(n: int, most: int) -> np.ndarray:
    """``most`` indices spread evenly over ``range(n)`` (all of them when ``n <= most``)."""
    if n <= most:
        return np.arange(n)
    return np.unique(np.round(np.linspace(0, n - 1, most)).astype(int))


def _fit(rays: _RayFrames, max_deg: float, grid_step_deg: float, wide_deg: float,
         wide_step_deg: float) -> tuple[np.ndarray, float, float]:
    """The search of the module docstring on ``rays``: ``(rotation vector, degrees; loss
    given; loss refined)``, the zero vector and the given loss when nothing fits better."""
    before = rays.loss(np.zeros(3), _SCALES[-1])
    starts = [np.zeros(3), *_grid_starts(rays, _grid(max_deg, grid_step_deg), grid_step_deg)]
    best_x, best_loss = np.zeros(3), before
    x, value = _search(rays, starts)
    if value < best_loss:
        best_x, best_loss = x, value
    if best_loss > WIDE_LOSS and wide_deg > max_deg:
        wide = _grid(wide_deg, wide_step_deg)
        wide = wide[np.abs(wide).max(axis=1) > max_deg + 1e-9]  # the inner grid is done
        x, value = _search(rays, _grid_starts(rays, wide, wide_step_deg))
        if value < best_loss - WIDE_GAIN:
            best_x, best_loss = x, value
    return best_x, before, best_loss


def refine_top_camera(
    top: Camera | Sequence[Camera],
    hor_cameras: Sequence[Camera],
    top_boxes: Sequence[np.ndarray],
    hor_boxes: Sequence[np.ndarray],
    *,
    max_deg: float = 4.0,
    grid_step_deg: float = 1.0,
    wide_deg: float = 10.0,
    wide_step_deg: float = 2.0,
    max_frames: int = 30,
    max_pairs: int = MAX_PAIRS,
    margin: float = METRIC_MARGIN,
) -> TopCameraRefinement:
    """Refine the orientation of a top camera fixed over a video, or the constant part of a
    moving one's error (see the module docstring).

    Args:
        top: the fixed top camera as calibrated, or each frame's (a moving camera; a sequence
            of cameras all the same (:func:`~xvmatch.geometry.camera.same_camera`) is a fixed
            one).
        hor_cameras: the egocentric camera of each frame.
        top_boxes, hor_boxes: ``(M, 4)`` and ``(N, 4)`` x, y, w, h boxes of each frame, pixels.
        max_deg: the largest turn searched (grid half-width), degrees.
        grid_step_deg: the grid's step, degrees.
        wide_deg, wide_step_deg: the wider, coarser grid searched when the fit within
            ``max_deg`` has a loss above :data:`WIDE_LOSS` (its points beyond ``max_deg``; its
            fit kept when :data:`WIDE_GAIN` lower); ``wide_deg <= max_deg``: none.
        max_frames: frames sampled, evenly spread (the result is the same on any machine).
        max_pairs: fewer frames (down to :data:`MIN_REFINE_FRAMES`) when a frame's top x
            horizontal box pairs (the median) times ``max_frames`` exceed this: the search's
            time and memory grow with the pairs.
        margin: the cheirality test's depth margin, metres (Eq. 7).

    Returns:
        The refinement; the rotation is rounded to 1e-4 degrees so that last-bit differences
        between machines do not reach the matcher.

    Raises:
        ValueError: fewer than :data:`MIN_REFINE_FRAMES` frames with boxes in both views, or
            inputs of different lengths.
    """
    tops = [top] * len(hor_cameras) if isinstance(top, Camera) else list(top)
    if not len(hor_cameras) == len(top_boxes) == len(hor_boxes) == len(tops):
        raise ValueError(f"top, hor_cameras, top_boxes and hor_boxes differ in length: "
                         f"{len(tops)}, {len(hor_cameras)}, {len(top_boxes)}, {len(hor_boxes)}")
    keep = [k for k in range(len(hor_cameras)) if len(top_boxes[k]) and len(hor_boxes[k])]
    if len(keep) < MIN_REFINE_FRAMES:
        raise ValueError(f"{len(keep)} frame(s) with boxes in both views; refining the top "
                         f"camera needs {MIN_REFINE_FRAMES}")
    pairs = float(np.median([len(top_boxes[k]) * len(hor_boxes[k]) for k in keep]))
    most = int(np.clip(max_pairs // max(pairs, 1.0), MIN_REFINE_FRAMES, max_frames))
    keep = [keep[i] for i in _sample(len(keep), most)]
    args = ([hor_cameras[k] for k in keep], [as_boxes(top_boxes[k], "top_boxes") for k in keep],
            [as_boxes(hor_boxes[k], "hor_boxes") for k in keep], margin)
    search = (max_deg, grid_step_deg, wide_deg, wide_step_deg)
    first = tops[keep[0]]
    if all(same_camera(t, first) for t in tops):
        best_x, before, best_loss = _fit(_RayFrames(first, *args), *search)
        camera = first if not best_x.any() else turned_camera(first, best_x)
        return TopCameraRefinement(camera, tuple(float(v) for v in best_x),
                                   float(np.linalg.norm(best_x)), len(keep), before, best_loss)
    sampled = [tops[k] for k in keep]
    relative = np.stack([first.R.T @ t.R for t in sampled])  # A_f = R_0^T R_f
    world = np.broadcast_to(np.eye(3), relative.shape)
    fits = {name: _fit(_RayFrames(sampled, *args, turns=turns), *search)
            for name, turns in (("camera", relative), ("world", world))}
    # the lower loss; on a tie to 1e-6 the camera's frame (last-bit differences between CPUs
    # must not choose the frame, which turns every frame's camera differently)
    name = min(fits, key=lambda n: round(fits[n][2], 6))
    best_x, before, best_loss = fits[name]
    fit = TopCameraRefinement(first, tuple(float(v) for v in best_x),
                              float(np.linalg.norm(best_x)), len(keep), before, best_loss,
                              frame=name, reference=first)
    return replace(fit, camera=fit.turn(first))
