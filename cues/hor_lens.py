"""The horizontal (handheld) camera's field of view chosen from the people, for the ground
registration (:mod:`xvmatch.cues.ground_registration`).

The horizontal view's ground map reads distance from box height and bearing from column, both
through the focal length, which comes from an *assumed* field of view (70 degrees,
:data:`~xvmatch.geometry.people_calibration.PRIOR_HFOV_DEG`). A wrong lens does not just scale
that map: a person's sideways offset stays about the same while the distance ahead scales with
the focal length, so the map is stretched along the camera's axis only, which the top map's
isotropic scale search (:data:`~xvmatch.cues.ground_registration.MAP_SCALES`) cannot undo. An
action camera (90-120 degrees) read as 70 puts its people about twice as far as they are.

:func:`choose_hor_hfov` registers the clip (a subsample of its frames) with each of a few
candidate lenses (:data:`HFOV_CANDIDATES`) and keeps the one whose registration pairs the most
people over the clip, one to one (:func:`~xvmatch.cues.ground_registration.associate_on_ground`
under each frame's chosen pose, each pair counted by how close it lands, the same Gaussian of
:data:`~xvmatch.cues.ground_registration.RADIUS` as the pose scores). Not the registration's own
score: that counts a horizontal person near *any* top person, so a map squeezed by too wide a
lens lands many people near a few and scores higher (on the rendered scenes it favoured the
widest lens tried even for 60-80 degree cameras). As with the map scale
(:data:`~xvmatch.cues.ground_registration.SCALE_MARGIN`), another lens replaces the prior only
where it pairs :data:`LENS_MARGIN` times as much, and only where it pairs somebody
(:data:`MIN_PAIRING`). That margin is wide: even this score leans
towards wider lenses (on the rendered scenes, 90 or 110 degrees pair 1.1-1.3 times as well as
70 on many 45-55 and 60-80 degree cameras, more where no lens registers, and the wider lens then
often fails), while an action camera's lead is mostly 1.15-1.7, over 1.3 in about half the
scenes. So the choice serves clearly wide cameras only, and where no lens registers (a near-nadir
top view) a switch adds false pairs; a narrow camera keeps 70 degrees, whose error the top map's
scale search mostly absorbs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from xvmatch.cues import ground_registration as gr
from xvmatch.geometry.people_calibration import PRIOR_HFOV_DEG

__all__ = [
    "HFOV_CANDIDATES",
    "LENS_MARGIN",
    "MAX_FRAMES",
    "MIN_PAIRING",
    "LensChoice",
    "choose_hor_hfov",
    "pairing_score",
]

HFOV_CANDIDATES = (70.0, 90.0, 110.0)
"""Horizontal fields of view tried, degrees: a phone's, a wide and an action camera's (focal
lengths about 1.4 times apart). No narrower one: 50 degrees never paired much better than 70 on
45-55 degree cameras (the top map's scale search takes up most of that error)."""

LENS_MARGIN = 1.3
"""How many times the prior lens's pairing score another lens must exceed to replace it (module
docstring: wide, as wider lenses often pair up to 1.3 times as well on cameras that are not
wide)."""

MIN_PAIRING = 1.0
"""The least clip pairing score (:func:`pairing_score`, about one person paired closely on one
frame) a lens other than the prior needs to be chosen: where no candidate's registration pairs
anybody (a near-nadir top view), a score above the prior's nothing is no evidence."""

MAX_FRAMES = 20
"""Frames registered per candidate lens at most (evenly spread over the clip)."""

_DIGITS = 6
"""Clip scores are rounded to this many decimals before they are compared: the same choice on
every CPU."""


@dataclass(frozen=True)
class LensChoice:
    """The chosen field of view and what each candidate explained.

    Attributes:
        hfov_deg: the field of view chosen, degrees.
        scores: ``{candidate hfov: the clip's pairing score}`` (:func:`pairing_score`,
            rounded).
        scales: ``{candidate hfov: the top map's scale its registration kept}``.
        frames: the frames registered.
    """

    hfov_deg: float
    scores: dict[float, float]
    scales: dict[float, float]
    frames: list[int]

    @property
    def registered(self) -> bool:
        """Whether any candidate's registration paired somebody (:data:`MIN_PAIRING`)."""
        return max(self.scores.values(), default=0.0) >= MIN_PAIRING


def _subsample(n: int, max_frames: int) -> list[int]:
    """Indices of at most ``max_frames`` of ``n`` frames, evenly spread, first and last kept."""
    if n <= max_frames:
        return list(range(n))
    return sorted({int(k) for k in np.round(np.linspace(0, n - 1, max_frames))})


def pairing_score(tops: list[np.ndarray], hors: list[np.ndarray], frames: list[int],
                  poses: list[gr.FramePose]) -> float:
    """How well the poses pair the two views' people, one to one: per frame with a pose, the
    Hungarian pairs under it (:func:`~xvmatch.cues.ground_registration.associate_on_ground`),
    each counted ``exp(-d^2 / (2 (RADIUS / 2)^2))`` for its ground distance ``d`` (metres), as
    the pose scores count a person explained; summed over the frames.

    Args:
        tops: per frame, the top view's people ``(N, 2)`` on its map (at the registration's
            scale).
        hors: per frame, the horizontal view's people ``(M, 2)`` on its own map.
        frames: the frame numbers of ``tops`` and ``hors``.
        poses: the registration's poses (frames without one count nothing).
    """
    by_frame = {p.frame: p for p in poses}
    total = 0.0
    for f, top, hor in zip(frames, tops, hors, strict=True):
        pose = by_frame.get(f)
        if pose is None:
            continue
        pairs = gr.associate_on_ground(top, hor, pose)
        if not len(pairs):
            continue
        mapped = gr.on_top_map(hor[pairs[:, 1]], pose)
        d2 = ((top[pairs[:, 0]] - mapped) ** 2).sum(axis=1)
        total += float(np.exp(-0.5 * d2 / (0.5 * gr.RADIUS) ** 2).sum())
    return total


def choose_hor_hfov(frames: list[int], tops: list[np.ndarray], hor_boxes: list[np.ndarray],
                    hor_size: tuple[int, int], fps: float,
                    candidates: tuple[float, ...] = HFOV_CANDIDATES,
                    prior_deg: float = PRIOR_HFOV_DEG, margin: float = LENS_MARGIN,
                    max_frames: int = MAX_FRAMES) -> LensChoice:
    """The horizontal camera's field of view that best registers its people on the top map
    (module docstring).

    Args:
        frames: the frame numbers, in order.
        tops: per frame, the top view's people ``(N, 2)`` on its ground map, metres (finite
            rows, as :func:`~xvmatch.inference.matching.ground_association.run_ground_association`
            builds them).
        hor_boxes: per frame, the horizontal view's boxes ``(M, 4)`` (x, y, w, h), pixels.
        hor_size: the horizontal view's image size (width, height).
        fps: frames per second of the frame numbers.
        candidates: fields of view tried, degrees; the prior is added when missing.
        prior_deg: the field of view kept unless another pairs ``margin`` times as much.
        margin: see :data:`LENS_MARGIN`.
        max_frames: frames registered per candidate at most (:data:`MAX_FRAMES`).
    Returns:
        The choice; the prior when no frame has people in both views.
    """
    if not len(frames) == len(tops) == len(hor_boxes):
        raise ValueError(f"frames, tops and hor_boxes must have one entry per frame, got "
                         f"{len(frames)}, {len(tops)} and {len(hor_boxes)}")
    if max_frames < 1:
        raise ValueError(f"max_frames must be at least 1, got {max_frames}")
    lenses = sorted({float(c) for c in candidates} | {float(prior_deg)})
    keep = _subsample(len(frames), max_frames)
    sub = [frames[k] for k in keep]
    sub_tops = [np.asarray(tops[k], float).reshape(-1, 2) for k in keep]
    sub_boxes = [np.asarray(hor_boxes[k], float).reshape(-1, 4) for k in keep]
    scores: dict[float, float] = {}
    scales: dict[float, float] = {}
    for hfov in lenses:
        hors = [gr.hor_ground_points(b, hor_size, hfov) for b in sub_boxes]
        scale, poses = gr.register_with_scale(sub, sub_tops, hors, hfov, fps)
        scores[hfov] = round(pairing_score([scale * t for t in sub_tops], hors, sub, poses),
                             _DIGITS)
        scales[hfov] = scale
    return LensChoice(hfov_deg=_pick(scores, float(prior_deg), margin), scores=scores,
                      scales=scales, frames=sub)


def _pick(scores: dict[float, float], prior: float, margin: float) -> float:
    """The lens chosen from the candidates' rounded pairing scores (``prior`` among them): the
    best (a tie: the nearest the prior, then the narrower), unless it does not exceed ``margin``
    times the prior's score or pairs next to nobody (:data:`MIN_PAIRING`)."""
    best = max(scores, key=lambda h: (scores[h], -abs(h - prior), -h))
    return (best if scores[best] > round(margin * scores[prior], _DIGITS)
            and scores[best] >= MIN_PAIRING else prior)
