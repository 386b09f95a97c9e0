"""Spatial-distribution vectors of the CVMHAT paper (Section 3.2.2, Eqs. 5-10).

Each person becomes a vector (x, y): x is the normalised signed position along the horizontal
camera's right direction, in [-1, 1] across its field of view, and y is a depth proxy. In the top
view both come from the geometry of the hypothesised camera location O and view direction theta;
in the horizontal view from the box centre and height.

Angles in the top image are measured counter-clockwise as seen on screen (image y points down),
``phi = atan2(-(v - v_O), u - u_O)``; theta is the direction of the horizontal camera's optical axis
in that convention.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from xvmatch.core import kernel_choice

__all__ = [
    "REFERENCE_SIZE",
    "TopGeometry",
    "TopHypotheses",
    "TopVectors",
    "box_centres",
    "horizontal_vectors",
    "top_geometry",
    "top_hypotheses",
    "top_vectors",
]

TWO_PI = 2.0 * np.pi

REFERENCE_SIZE: tuple[int, int] = (2688, 1512)
"""Width and height (pixels) of the CVMHAT videos, the resolution the paper's parameters were set
at. Horizontal box heights are expressed in pixels of an image this wide (Eq. 9 below), so the
lambda of Eq. 11 keeps its published meaning at any resolution."""


OCCLUSION_BLOCK = 1 << 22
"""(candidate, person, person) triples per block of the occlusion test (about 32 MiB a float
array)."""


def box_centres(boxes: np.ndarray) -> np.ndarray:
    """Centres ``(N, 2)`` of ``(N, 4)`` x, y, w, h boxes."""
    boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)
    return boxes[:, :2] + 0.5 * boxes[:, 2:]


def horizontal_vectors(boxes: np.ndarray, image_width: float) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal-view vectors of Eqs. 9-10, sorted by x ascending.

    Resolution-free: the paper's y_hor = 1 / h is taken with h in pixels of an image
    ``REFERENCE_SIZE[0]`` (2688) pixels wide, ``y_hor = 1 / (h 2688 / W)``, so the same scene at
    another resolution gives the same vectors, and at 2688 pixels they are the paper's exactly.
    The width is the right unit: with the horizontal field of view alpha fixed (Eq. 6), the
    focal length is proportional to W, and 1 / h to depth over focal length.

    Args:
        boxes: ``(Q, 4)`` x, y, w, h boxes in the horizontal image.
        image_width: W, the width of the horizontal image in pixels.

    Returns:
        (vectors, order): ``(Q, 2)`` rows ``(x_hor, y_hor) = ((u - W/2) / (W/2),
        W / (2688 h))`` sorted by x (ties broken by y, so the result does not depend on input
        order), and the indices of the input boxes in that order.
    """
    boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)
    half = 0.5 * float(image_width)
    x = (boxes[:, 0] + 0.5 * boxes[:, 2] - half) / half
    y = (float(image_width) / REFERENCE_SIZE[0]) / boxes[:, 3]
    order = np.lexsort((y, x))
    return np.stack([x[order], y[order]], axis=1), order


@dataclass(frozen=True)
class TopGeometry:
    """Polar layout of the top-view people around each candidate camera location O.

    Attributes:
        phi: ``(C, M)`` angle of person m seen from candidate c (radians, CCW on screen).
        dist: ``(C, M)`` distance |OP| in top-image pixels.
        visible: ``(C, M)`` person m can be seen from candidate c: it is not O itself and no
            strictly nearer person lies within the occlusion tolerance tau of its direction
            (Sec. 3.2.2, "Occlusion Scenario").
    """

    phi: np.ndarray
    dist: np.ndarray
    visible: np.ndarray


def top_geometry(
    centres: np.ndarray, candidates: np.ndarray, tau: float = np.radians(2.0)
) -> TopGeometry:
    """Angles, distances and occlusion of every person around every candidate O.

    Args:
        centres: ``(M, 2)`` top-view box centres (ground positions).
        candidates: ``(C,)`` indices into ``centres`` of the hypothesised camera locations.
        tau: occlusion tolerance (radians): of two people whose directions from O differ by less
            than tau, the farther one is hidden.
    """
    centres = np.asarray(centres, dtype=float).reshape(-1, 2)
    candidates = np.asarray(candidates, dtype=np.intp).reshape(-1)
    d = centres[None, :, :] - centres[candidates][:, None, :]
    dist = np.hypot(d[..., 0], d[..., 1])
    phi = np.mod(np.arctan2(-d[..., 1], d[..., 0]), TWO_PI)
    present = dist > 0.0
    # Pairwise angular gaps per candidate, (C, M, M): person m is hidden by a nearer person n.
    # In blocks of candidates, so that a crowd (1,000 people: 10^9 pairs) stays within memory.
    visible = np.empty_like(present)
    n_people = centres.shape[0]
    step = max(1, OCCLUSION_BLOCK // max(1, n_people * n_people))
    for lo in range(0, candidates.shape[0], step):
        part = slice(lo, lo + step)
        gap = np.abs(phi[part, :, None] - phi[part, None, :])
        gap = np.minimum(gap, TWO_PI - gap)
        # Only a strictly nearer person hides: two people at exactly the same distance both
        # stay, so the result never depends on the order of the boxes.
        nearer = dist[part, None, :] < dist[part, :, None]
        hides = (gap < tau) & nearer & present[part, None, :] & present[part, :, None]
        visible[part] = present[part] & ~hides.any(axis=2)
    return TopGeometry(phi=phi, dist=dist, visible=visible)


@dataclass(frozen=True)
class TopVectors:
    """Top-view vectors of Eqs. 5-8 for a batch of (O, theta) hypotheses.

    Attributes:
        x: ``(B, K)`` normalised x_top (Eq. 7), ascending within each row; padding is +inf.
        y: ``(B, K)`` depth y_top = |OP| sin<OP, V> (Eq. 5), in top-image pixels; padding 0.
        index: ``(B, K)`` index of the top-view person of each entry; padding -1.
        count: ``(B,)`` number of people in the field of view, |K| of Eq. 8.
    """

    x: np.ndarray
    y: np.ndarray
    index: np.ndarray
    count: np.ndarray


@dataclass(frozen=True)
class TopHypotheses:
    """Unsorted top-view x values of every (O, theta) hypothesis, before Eq. 8's sorting.

    Scoring a hypothesis needs its sorted vectors (:meth:`take`), but pruning only needs x and
    the count, so the search sorts just the hypotheses it scores.

    Attributes:
        x: ``(B, M)`` x_top of person m under hypothesis b (Eq. 7); +inf outside the field of
            view, occluded, or O itself. Rows are candidate-major: b = c * T + t.
        count: ``(B,)`` number of people in the field of view.
        delta: ``(B, M)`` signed angle of person m from the optical axis (radians).
        dist: ``(C, M)`` |OP| per candidate.
        n_theta: T, orientations per candidate.
    """

    x: np.ndarray
    count: np.ndarray
    delta: np.ndarray
    dist: np.ndarray
    n_theta: int

    def take(self, rows: np.ndarray) -> TopVectors:
        """Sorted, trimmed vectors (Eq. 8) of the hypotheses ``rows``."""
        rows = np.asarray(rows, dtype=np.intp).reshape(-1)
        count = self.count[rows]
        width = int(count.max()) if count.size else 0
        kernels = kernel_choice.kernels()
        if kernels is None:
            order = np.argsort(self.x[rows], axis=1, kind="stable")[:, :width]
            x = np.take_along_axis(self.x[rows], order, axis=1)
            valid = np.arange(width)[None, :] < count[:, None]
            delta = np.take_along_axis(self.delta[rows], order, axis=1)[valid]
            dist = np.take_along_axis(self.dist[rows // self.n_theta], order, axis=1)[valid]
            where = np.flatnonzero(valid)
            index = np.where(valid, order, -1)
        else:  # the same values in one pass per row, the valid entries' delta and |OP| packed
            shape = (rows.shape[0], width)
            x, index = np.empty(shape), np.empty(shape, dtype=np.intp)
            n_valid = int(count.sum())
            delta, dist = np.empty(n_valid), np.empty(n_valid)
            where = np.empty(n_valid, dtype=np.intp)
            kernels.sorted_rows(self.x, self.delta, self.dist, self.n_theta,
                                rows.astype(np.int64), x, index, delta, dist, where)
        # numpy's cos in both forms, of the valid entries only (elementwise: the same bits).
        y = np.zeros((rows.shape[0], width))
        y.reshape(-1)[where] = dist * np.cos(delta)  # a view: 7 times .flat's speed
        return TopVectors(x=x, y=y, index=index, count=count)


def top_hypotheses(
    geometry: TopGeometry, thetas: np.ndarray, fov: float = np.radians(90.0)
) -> TopHypotheses:
    """x values of the people inside the field of view for every (candidate, theta) pair.

    Eq. 5 gives x_hat = f cot<OP, V> and y_hat = |OP| sin<OP, V> with V the camera's right
    direction; Eqs. 6-7 normalise x by f cot((pi - alpha) / 2) so the field of view spans
    [-1, 1]. With delta = phi - theta (signed angle from the optical axis), <OP, V> = pi/2 + delta,
    hence x_top = -tan(delta) / tan(alpha / 2) and y_top = |OP| cos(delta).

    Args:
        geometry: from :func:`top_geometry`, C candidates and M people.
        thetas: ``(T,)`` view directions (radians), tried for every candidate.
        fov: the horizontal camera's field-of-view angle alpha (radians), in (0, pi).
    """
    phi = np.ascontiguousarray(geometry.phi, dtype=np.float64)
    thetas = np.ascontiguousarray(thetas, dtype=np.float64).reshape(-1)
    n_cand, n_people = phi.shape
    half = 0.5 * fov
    kernels = kernel_choice.kernels()
    if kernels is None:
        delta = np.mod(phi[:, None, :] - thetas[None, :, None] + np.pi, TWO_PI) - np.pi
        delta = delta.reshape(-1, n_people)
        inside = (np.abs(delta) < half) & np.repeat(geometry.visible, thetas.shape[0], axis=0)
        count = inside.sum(axis=1)
        # numpy's tan in both forms (its SIMD tan is not libm's to the last bit on every
        # CPU), of the entries in view only: an elementwise function, so the same bits as over
        # the whole table, at about a quarter of the work (a 90-degree view of the circle).
        seen = np.flatnonzero(inside)
        x = np.full(delta.shape, np.inf)
        x.reshape(-1)[seen] = np.tan(delta.reshape(-1)[seen]) * (-1.0 / np.tan(half))
    else:  # the same table; the kernel packs the in-view entries' delta for numpy's tan
        n_rows = n_cand * thetas.shape[0]
        delta, x = np.empty((n_rows, n_people)), np.empty((n_rows, n_people))
        count = np.empty(n_rows, dtype=np.intp)
        seen = np.empty(n_rows * n_people, dtype=np.intp)
        packed = np.empty(n_rows * n_people)
        n_seen = kernels.hypothesis_table(
            phi, np.ascontiguousarray(geometry.visible, dtype=bool), thetas, half, delta, x,
            count, seen, packed)
        x.reshape(-1)[seen[:n_seen]] = np.tan(packed[:n_seen]) * (-1.0 / np.tan(half))
    return TopHypotheses(x=x, count=count, delta=delta, dist=geometry.dist,
                         n_theta=thetas.shape[0])


def top_vectors(
    geometry: TopGeometry, thetas: np.ndarray, fov: float = np.radians(90.0)
) -> TopVectors:
    """Sorted top-view vectors (Eqs. 5-8) of every (candidate, theta) hypothesis.

    Returns:
        :class:`TopVectors` with B = C * T rows in candidate-major order.
    """
    hyp = top_hypotheses(geometry, thetas, fov)
    return hyp.take(np.arange(hyp.x.shape[0]))
