"""Compiled (numba) kernel of the people model's box heights
(:func:`~xvmatch.geometry.people_model.centred_heights`): each box's person placed on the
ground, seen as an upright cylinder at the feet and at the head, and its box height read,
one box at a time in one pass.

The calibration asks for these heights a few thousand times a fit (the finite differences of
its Jacobian), and the numpy form spent most of that time in calls on arrays of a few hundred
boxes. The kernel follows the numpy form (``people_model._heights_numpy``) operation by
operation: the rotations as three products summed left to right (never a BLAS call, whose
kernels sum in their own order and fuse multiply-adds on some CPUs), a length as the square
root of its squares (IEEE-exact in both, where NumPy's SIMD ``hypot`` may differ from the C
library's in the last bit), NaN where a ray misses the ground; numba does not contract
multiply-adds without ``fastmath``. So the two are bit-identical on every CPU (tested), and
the choice between them (:mod:`~xvmatch.core.kernel_choice`) only moves time; the camera's
cosines and sines come from numpy, the same for both.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["centred_box_heights"]


@njit(cache=True, error_model="numpy")
def _to_world(x0: float, x1: float, x2: float, R: np.ndarray, j: int) -> float:
    """Component ``j`` of the camera vector ``x`` in world axes (``x R``, ``R`` the
    world-to-camera rotation): the three products summed left to right."""
    return (x0 * R[0, j] + x1 * R[1, j]) + x2 * R[2, j]


@njit(cache=True, error_model="numpy")
def _to_camera(w0: float, w1: float, w2: float, R: np.ndarray, i: int) -> float:
    """Component ``i`` of the world vector ``w`` in camera axes (``R w``), summed as
    :func:`_to_world`."""
    return (w0 * R[i, 0] + w1 * R[i, 1]) + w2 * R[i, 2]


@njit(cache=True, error_model="numpy")
def _depth(z: float) -> float:
    """A camera coordinate's depth, NaN behind the camera."""
    return z if z > 1e-9 else np.nan


@njit(cache=True, error_model="numpy")
def _axis(column: float, ray_row: float, R: np.ndarray, f: float, hc: float, cx: float,
          radius: float) -> tuple[float, float, float, float, float, float]:
    """The body's axis on the ground under the foot pixel at ``column`` (the ray's row term
    ``ray_row``) and the radius along the ray: ``(axis x, y, z, along x, y, z)``."""
    r0 = (column - cx) / f
    d0 = _to_world(r0, ray_row, 1.0, R, 0)
    d1 = _to_world(r0, ray_row, 1.0, R, 1)
    d2 = _to_world(r0, ray_row, 1.0, R, 2)
    s = hc / -d2 if d2 < -1e-9 else np.nan
    rim0, rim1, rim2 = s * d0, s * d1, s * d2
    q = radius / math.sqrt(rim0 * rim0 + rim1 * rim1)
    a0, a1, a2 = rim0 * q, rim1 * q, 0.0 * q
    return rim0 + a0, rim1 + a1, rim2 + a2, a0, a1, a2


@njit(cache=True, error_model="numpy")
def _row(c0: float, c1: float, c2: float, R: np.ndarray, f: float, cy: float) -> float:
    """The image row of the world point ``c`` (the camera above the origin)."""
    return cy + f * _to_camera(c0, c1, c2, R, 1) / _depth(_to_camera(c0, c1, c2, R, 2))


@njit(cache=True, error_model="numpy")
def _height(u: float, v: float, person: float, R: np.ndarray, f: float, hc: float, cx: float,
            cy: float, radius: float, smooth: float) -> float:
    """One box's height with its foot on row ``v`` (``people_model._heights_numpy``): the
    span of its outline's corner rows, each highest and lowest rounded within ``smooth``
    pixels of a tie (``people_model.OUTLINE_SMOOTH_PX``)."""
    ray_row = (v - cy) / f
    p0, p1, p2, _, _, _ = _axis(u, ray_row, R, f, hc, cx, radius)
    h0 = _to_camera(p0 + 0.0, p1 + 0.0, p2 + person, R, 0)
    h2 = _to_camera(p0 + 0.0, p1 + 0.0, p2 + person, R, 2)
    u_head = cx + f * h0 / _depth(h2)
    p0, p1, p2, a0, a1, a2 = _axis(u - 0.5 * (u_head - u), ray_row, R, f, hc, cx, radius)
    s0, s1, s2 = -a1, a0, a2  # across the ray
    q0, q1, q2 = p0 + 0.0, p1 + 0.0, p2 + person  # the head's
    rows = (_row(p0 + s0, p1 + s1, p2 + s2, R, f, cy), _row(p0 - s0, p1 - s1, p2 - s2, R, f, cy),
            _row(p0 + a0, p1 + a1, p2 + a2, R, f, cy), _row(p0 - a0, p1 - a1, p2 - a2, R, f, cy),
            _row(q0 + s0, q1 + s1, q2 + s2, R, f, cy), _row(q0 - s0, q1 - s1, q2 - s2, R, f, cy),
            _row(q0 + a0, q1 + a1, q2 + a2, R, f, cy), _row(q0 - a0, q1 - a1, q2 - a2, R, f, cy))
    hi, lo, missing = rows[0], rows[0], rows[0] != rows[0]
    for k in range(1, 8):  # in the numpy form's order (people_model._smooth_span)
        row = rows[k]
        missing = missing or row != row
        hi = max(hi, row) + _tie(abs(hi - row), smooth)
        lo = min(lo, row) - _tie(abs(lo - row), smooth)
    return np.nan if missing else hi - lo


@njit(cache=True, error_model="numpy")
def _tie(t: float, e: float) -> float:
    """What rounds the higher of two rows ``t`` apart (``people_model._tie``)."""
    if t < e:
        r = 1.0 - t / e
        return -(0.5 * t) * (r * r)
    return 0.0


@njit(cache=True, error_model="numpy")
def centred_box_heights(u: np.ndarray, v: np.ndarray, h: np.ndarray, person: np.ndarray,
                        rotations: np.ndarray, window: np.ndarray, f: float, hc: float,
                        cx: float, cy: float, radius: float, rounds: int,
                        smooth: float) -> np.ndarray:
    """Each box's predicted height (``u``, ``v``: its foot pixel, ``h`` its height, ``person``
    its person's height, ``rotations[window]`` its world-to-camera rotation), the foot row
    moved ``rounds`` times so that the box's centre row is the box's
    (``people_model.centred_heights``; 0: at the box's bottom)."""
    out = np.empty(u.shape[0])
    for i in range(u.shape[0]):
        R = rotations[window[i]]
        pred = _height(u[i], v[i], person[i], R, f, hc, cx, cy, radius, smooth)
        centre = v[i] - 0.5 * h[i]
        for _ in range(rounds):
            at = pred if np.isfinite(pred) else h[i]
            pred = _height(u[i], centre + 0.5 * at, person[i], R, f, hc, cx, cy, radius,
                           smooth)
        out[i] = pred
    return out
