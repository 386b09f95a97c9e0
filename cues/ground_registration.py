"""Two views' ground maps registered without correspondences, jointly with the association.

Each view's people are put on its own ground map (metres, from its calibration: the top view by
:class:`~xvmatch.geometry.people_calibration.PeopleCalibration`, the horizontal view by the box
heights of people about 1.72 m tall, as the CVMHAT method reads distances). The horizontal
camera's pose on the top map, its position ``c`` and heading ``theta``, is unknown and changes as
its holder walks and turns; it is *not* assumed to be a visible person. Per frame:

* **hypotheses**: every (top person i, horizontal person j, heading) triple puts j on i, which
  fixes ``c``; a hypothesis scores the horizontal people that land within :data:`RADIUS` of a
  top person (soft), minus the top people it puts inside the horizontal camera's field of view
  that nobody there explains (people seen in one view only are expected, so this weighs less);
  the :data:`KEEP` best distinct ones are kept;
* **time**: one hypothesis per frame is chosen by dynamic programming over the frames (Viterbi),
  each step paying for a jump in position or heading faster than a walker turns and walks, so
  the registration is consistent from frame to frame and a frame that alone is ambiguous is
  decided by its neighbours; the whole clip is registered with the top map at a few scales and
  the best kept (:func:`register_with_scale`);
* **association**: under the chosen pose, Hungarian on the ground distances with a
  non-association distance (:data:`RADIUS`).

This generalises the CVMHAT search over the camera location O and orientation theta (Sec. 3 of
the CVMHAT paper) to a camera that is not among the top view's people and a top view that is not
a nadir image.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

__all__ = [
    "KEEP",
    "MAP_SCALES",
    "RADIUS",
    "SCALE_MARGIN",
    "FramePose",
    "associate_on_ground",
    "hor_ground_points",
    "pose_hypotheses",
    "register_sequence",
    "register_with_scale",
]

RADIUS = 1.5
"""Metres: a horizontal person mapped farther than this from every top person explains none."""

KEEP = 24
"""Pose hypotheses kept per frame for the choice over time."""

_HEADINGS = 72
"""Headings tried per (top, horizontal) pair: every 5 degrees."""

_UNSEEN_WEIGHT = 0.3
"""Cost of a top person put in the horizontal camera's view that it does not see, against 1 for
a horizontal person explained: low, as occlusion and partial overlap hide many."""

_DIGITS = 9
"""Scores are rounded to this many decimals: the same choices on every CPU."""

MAP_SCALES = (0.7, 0.85, 1.0, 1.15, 1.3)
"""Scales of the top view's ground map tried against the horizontal view's
(:func:`register_with_scale`)."""

SCALE_MARGIN = 1.05
"""How many times the people explained at scale 1 another scale must explain to replace it."""

_STEP_M = 1.0
"""Metres per second a handheld camera's position may drift between frames at no cost."""

_STEP_DEG = 30.0
"""Degrees per second it may turn at no cost."""

_JUMP_COST = 2.0
"""Score lost per standard step beyond those (a frame's pose can jump where its evidence is
strong: a pan)."""


@dataclass(frozen=True)
class FramePose:
    """The horizontal camera's pose on the top view's ground map for one frame.

    Attributes:
        frame: the frame number.
        centre: (2,) position, metres.
        heading: radians, the direction it looks along.
        score: the frame's evidence for it.
    """

    frame: int
    centre: np.ndarray
    heading: float
    score: float


def hor_ground_points(boxes: np.ndarray, image_size: tuple[int, int], hfov_deg: float,
                      person_height: float = 1.72) -> np.ndarray:
    """Horizontal-view people on the camera's own ground map ``(M, 2)``: x forward, y left.

    Distance from box height (a person of ``person_height`` seen by a level camera,
    ``d = f H / h``), bearing from the box's centre column."""
    boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)
    f = 0.5 * image_size[0] / np.tan(np.radians(hfov_deg) / 2.0)
    distance = f * person_height / np.maximum(boxes[:, 3], 1.0)
    bearing = -np.arctan2(boxes[:, 0] + 0.5 * boxes[:, 2] - 0.5 * image_size[0], f)
    return distance[:, None] * np.column_stack([np.cos(bearing), np.sin(bearing)])


def _rotations(headings: np.ndarray) -> np.ndarray:
    c, s = np.cos(headings), np.sin(headings)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)  # (H, 2, 2)


def pose_hypotheses(top: np.ndarray, hor: np.ndarray, hfov_deg: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The best poses ``(K, 3)`` (x, y, heading) of the horizontal camera on the top map for
    one frame, and their scores ``(K,)``, best first (module docstring).

    Args:
        top: ``(N, 2)`` top-view people on its ground map.
        hor: ``(M, 2)`` horizontal-view people on the camera's ground map (x forward).
        hfov_deg: the horizontal camera's field of view.
    """
    top, hor = np.asarray(top, float).reshape(-1, 2), np.asarray(hor, float).reshape(-1, 2)
    if not len(top) or not len(hor):
        return np.zeros((0, 3)), np.zeros(0)
    headings = np.arange(_HEADINGS) * (2 * np.pi / _HEADINGS)
    rot = _rotations(headings)  # (H, 2, 2)
    turned = np.einsum("hab,mb->hma", rot, hor)  # (H, M, 2)
    # c = top_i - turned_j for every (heading, i, j).
    centres = top[None, :, None, :] - turned[:, None, :, :]  # (H, N, M, 2)
    centres = centres.reshape(-1, 2)
    h_idx = np.repeat(np.arange(len(headings)), len(top) * len(hor))  # heading of each row
    mapped = centres[:, None, :] + turned[h_idx]  # (P, M, 2)
    dx = mapped[:, :, None, 0] - top[None, None, :, 0]  # (P, M, N), one coordinate at a time:
    dy = mapped[:, :, None, 1] - top[None, None, :, 1]  # no (P, M, N, 2) temporary
    d2 = dx * dx + dy * dy
    explained = np.exp(-0.5 * d2.min(axis=2) / (0.5 * RADIUS) ** 2).sum(axis=1)
    # Top people in the horizontal camera's view (bearing within the half field of view, as far
    # as its people reach) that no horizontal person explains.
    rel = top[None, :, :] - centres[:, None, :]  # (P, N, 2)
    heading = headings[h_idx]
    forward = rel[..., 0] * np.cos(heading)[:, None] + rel[..., 1] * np.sin(heading)[:, None]
    side = -rel[..., 0] * np.sin(heading)[:, None] + rel[..., 1] * np.cos(heading)[:, None]
    reach = 1.2 * float(np.max(np.hypot(hor[:, 0], hor[:, 1])))
    in_view = ((forward > 0.5) & (np.abs(np.arctan2(side, forward)) < np.radians(hfov_deg) / 2)
               & (np.hypot(forward, side) < reach))
    unseen = in_view & (d2.min(axis=1) > RADIUS**2)
    # Rounded so that a last-bit difference of exp() between CPUs cannot reorder near-ties.
    score = np.round(explained - _UNSEEN_WEIGHT * unseen.sum(axis=1), _DIGITS)
    poses = np.column_stack([centres, heading])
    keep = _distinct(poses, np.argsort(-score, kind="stable"))
    return poses[keep], score[keep]


def _distinct(poses: np.ndarray, order: np.ndarray, block: int = 256) -> list[int]:
    """The first :data:`KEEP` of ``order`` (indices into ``poses`` ``(P, 3)``) each 1 m or 10
    degrees away from every one kept before it (greedy, in order); a block of candidates at a
    time, its distances to the kept ones and to each other computed at once."""
    keep: list[int] = []
    limit = np.radians(10.0)
    for start in range(0, len(order), block):
        cand = order[start:start + block]
        xy, th = poses[cand, :2], poses[cand, 2]
        apart = ((np.hypot(xy[:, None, 0] - xy[None, :, 0], xy[:, None, 1] - xy[None, :, 1])
                  > 1.0) | (np.abs(_wrap(th[:, None] - th[None, :])) > limit))
        if keep:
            kx, kt = poses[keep, :2], poses[keep, 2]
            free = (((np.hypot(xy[:, None, 0] - kx[None, :, 0], xy[:, None, 1] - kx[None, :, 1])
                      > 1.0) | (np.abs(_wrap(th[:, None] - kt[None, :])) > limit)).all(axis=1))
        else:
            free = np.ones(len(cand), bool)
        taken: list[int] = []
        for i in np.flatnonzero(free):
            if apart[i, taken].all():
                taken.append(int(i))
                keep.append(int(cand[i]))
                if len(keep) == KEEP:
                    return keep
    return keep


def _wrap(angle: np.ndarray | float) -> np.ndarray | float:
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


def register_sequence(frames: list[int], candidates: list[tuple[np.ndarray, np.ndarray]],
                      fps: float) -> list[FramePose]:
    """One pose per frame from each frame's hypotheses (``(poses, scores)``), chosen by Viterbi
    over the frames with a cost on fast jumps (module docstring); frames without hypotheses
    split the sequence into runs, each chosen on its own."""
    totals: list[np.ndarray] = []
    back: list[np.ndarray] = []
    for k, (poses, scores) in enumerate(candidates):
        if not len(poses) or k == 0 or not len(candidates[k - 1][0]):
            totals.append(np.asarray(scores, float).copy())
            back.append(np.full(len(poses), -1))
            continue
        gap = max(1, frames[k] - frames[k - 1]) / fps
        prev = candidates[k - 1][0]
        step = np.hypot(*(poses[:, None, :2] - prev[None, :, :2]).transpose(2, 0, 1))
        turn = np.abs(_wrap(poses[:, None, 2] - prev[None, :, 2]))
        cost = _JUMP_COST * (np.maximum(step / (_STEP_M * gap) - 1.0, 0.0)
                             + np.maximum(turn / (np.radians(_STEP_DEG) * gap) - 1.0, 0.0))
        via = np.round(totals[k - 1][None, :] - cost, _DIGITS)
        best = np.argmax(via, axis=1)
        totals.append(np.round(scores + via[np.arange(len(poses)), best], _DIGITS))
        back.append(best)
    choice = [-1] * len(candidates)
    k = len(candidates) - 1
    while k >= 0:
        if not len(candidates[k][0]):
            k -= 1
            continue
        j = int(np.argmax(totals[k]))
        while k >= 0 and j >= 0:
            choice[k] = j
            j = int(back[k][j])
            k -= 1
    out = []
    for k, (poses, scores) in enumerate(candidates):
        if choice[k] >= 0:
            p = poses[choice[k]]
            out.append(FramePose(frames[k], p[:2].copy(), float(p[2]),
                                 float(scores[choice[k]])))
    return out


def register_with_scale(frames: list[int], tops: list[np.ndarray], hors: list[np.ndarray],
                        hfov_deg: float, fps: float) -> tuple[float, list[FramePose]]:
    """The horizontal camera's pose per frame (:func:`register_sequence`) on the top map
    scaled by each of :data:`MAP_SCALES`, and the scale kept: the two maps' metres come from
    two estimates (the top camera's height from its people, each distance from a box height)
    that can disagree by a third, so another scale replaces 1 where its chosen poses explain
    :data:`SCALE_MARGIN` times as many people over the clip (a small lead is noise).

    Args:
        frames: the frame numbers, in order.
        tops: per frame, the top view's people ``(N, 2)`` on its ground map (finite rows).
        hors: per frame, the horizontal view's people ``(M, 2)`` on its own map.
        hfov_deg: the horizontal camera's field of view.
        fps: frames per second of the frame numbers.
    Returns:
        ``(scale, poses)``: the poses lie on the top map multiplied by ``scale``.
    """
    runs: dict[float, tuple[float, list[FramePose]]] = {}
    for scale in MAP_SCALES:
        cands = [pose_hypotheses(scale * p, q, hfov_deg) for p, q in zip(tops, hors, strict=True)]
        poses = register_sequence(frames, cands, fps)
        runs[scale] = (round(sum(p.score for p in poses), 6), poses)
    best = max(MAP_SCALES, key=lambda s: (runs[s][0], -abs(s - 1.0)))
    if runs[best][0] <= round(SCALE_MARGIN * runs[1.0][0], 6):
        best = 1.0
    return best, runs[best][1]


def associate_on_ground(top: np.ndarray, hor: np.ndarray, pose: FramePose) -> np.ndarray:
    """Pairs ``(P, 2)`` (top index, horizontal index) under the pose: Hungarian on the ground
    distances, pairs farther than :data:`RADIUS` left unmatched."""
    top, hor = np.asarray(top, float).reshape(-1, 2), np.asarray(hor, float).reshape(-1, 2)
    if not len(top) or not len(hor):
        return np.zeros((0, 2), dtype=np.int64)
    rot = _rotations(np.array([pose.heading]))[0]
    mapped = pose.centre + hor @ rot.T
    d = np.hypot(*(top[:, None, :] - mapped[None, :, :]).transpose(2, 0, 1))
    cost = np.where(d < RADIUS, d, 2 * RADIUS)
    rows, cols = linear_sum_assignment(cost)
    ok = d[rows, cols] < RADIUS
    return np.column_stack([rows[ok], cols[ok]]).astype(np.int64)
