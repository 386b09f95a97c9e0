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
candidate lenses (:data:`HFOV_CANDIDATES`) and scores how many people each registration pairs
over the clip, one to one (:func:`pairing_score`:
:func:`~xvmatch.cues.ground_registration.associate_on_ground` under each frame's chosen pose,
each pair counted by how close it lands, the same Gaussian of
:data:`~xvmatch.cues.ground_registration.RADIUS` as the pose scores). Not the registration's own
score: that counts a horizontal person near *any* top person, so a map squeezed by too wide a
lens lands many people near a few and scores higher. Even the one-to-one pairing leans towards
wider lenses: a squeezed crowd pairs more people by chance. So each lens is also registered
with its handheld maps mirrored (:func:`chance_score`: the same distances and spread, not the
same arrangement), which pairs what chance pairs, and the lens chosen is the one that pairs the
most *above* that. Another lens replaces the prior only where it pairs :data:`LENS_MARGIN`
times as much as the prior, both in all and above chance, and somebody above chance
(:data:`MIN_PAIRING`).

That is the choice frame by frame. In video mode (each view's track ids read) the commands
make the whole run with each candidate lens instead and keep the one whose pairs hold along
the tracks most (:func:`pick_along_tracks`): a wrong lens's pairs change partner along a track
and the consensus drops them, a test of the arrangement over the whole clip that needs no
chance score and no margin. Those runs leave out where the top camera would see people (a term
that steadies a wrong lens's poses on a small crowd too); each lens's run is then made with it,
and another lens's replaces the chosen one's where it keeps more than :data:`NEAR_TIE` times
its pairs.

The four candidates are guesses, 10-20 degrees apart; the pairs a run keeps measure the lens
(:func:`implied_hfov`): a wrong focal length stretches the handheld map along the camera's
axis only, so the top map's distances between paired people, against the handheld map's ahead
and across, give the stretch, and the lens, without any pose. Where the lens each run's pairs
imply differs from the run's by :data:`MIN_REMEASURE_DEG` or more (and is not a candidate nor
one measured already), the whole run is made with it too and kept where its pairs hold along
the tracks more often (than the chosen lens's run, measured from it; more than a near tie,
measured from another lens's; a tie keeps the candidate: where every lens keeps the same
pairs, the pairs are no measure of it). Candidates that tie with the chosen lens exactly
measure it together: of the lenses their pairs imply, the one they fit best
(:func:`implied_fit`), kept where its run keeps as many pairs. All told eight to eleven runs.

Measured on rendered scenes (``benchmarks/oblique_association.py --choose-lens``,
docs/notes/oblique_top_camera.md): without the chance check the choice lost up to 4 CVIDF1 on
ordinary lenses, picking a wide lens where no lens registered; scored above chance alone (no
margin in all) it lost 7 on one set of ordinary lenses, as a prior that pairs little above
chance is beaten by any noise; both together kept the prior on the ordinary lenses tried and
won back most of a wide lens. Each handheld person is read at their top partner's height
(``sizes``, as the run after the choice reads them): under a close drone, read at 1.72 m, no
lens registered well and a 90-120 degree camera kept 70 on 8 of 12 scenes (+ consensus CVIDF1
79.4 against 95.1 with the heights, 100.0 with the true lens; another seed 95.6 against 90.5).
Along the tracks (video mode) the same three wide rows reach 100.0 (95.1, 90.5 and 95.7 with
the 20-frame choice; 100.0, 99.3 and 97.9 with the true lens), the ordinary lenses' as before.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from xvmatch.cues import ground_registration as gr
from xvmatch.geometry.people_calibration import PRIOR_HFOV_DEG

__all__ = [
    "HFOV_CANDIDATES",
    "LENS_MARGIN",
    "MAX_FRAMES",
    "MEASURED_RANGE",
    "MIN_MEASURED_PEOPLE",
    "MIN_PAIRING",
    "MIN_PEOPLE",
    "MIN_REMEASURE_DEG",
    "NEAR_TIE",
    "LensChoice",
    "chance_score",
    "choose_hor_hfov",
    "implied_fit",
    "implied_hfov",
    "pairing_score",
    "pick_along_tracks",
]

HFOV_CANDIDATES = (60.0, 70.0, 90.0, 110.0)
"""Horizontal fields of view tried, degrees: a narrow and a phone's, a wide and an action
camera's (focal lengths about 1.4 times apart from 70 up). 60 for people far off (a holder
walking 15-50 m from them): there a lens 9 degrees wide of a 61-degree one stretched the
handheld map by metres, and on renders video mode's choice with 60 gained clips without losing
any (docs/notes/oblique_top_camera.md, forty-second session). No narrower one: 50 degrees
never paired much better than 70 on 45-55 degree cameras (the top map's scale search takes up
most of that error)."""

LENS_MARGIN = 1.3
"""How many times the prior lens's pairing score another lens must exceed to replace it, in all
and above chance (module docstring: wide, as wider lenses often pair up to 1.3 times as well on
cameras that are not wide)."""

MIN_PAIRING = 1.0
"""The least clip pairing score above chance (:func:`pairing_score` less :func:`chance_score`,
about one person paired closely on one frame) a lens other than the prior needs to be chosen:
where no candidate's registration pairs anybody above chance (a near-nadir top view), a score
above the prior's nothing is no evidence."""

MIN_PEOPLE = 2
"""Top-view people the pairs kept along the tracks must join for a lens other than the prior to
be chosen in video mode (:func:`pick_along_tracks`). On 12 rendered clips of 60-80 degree
lenses (``benchmarks/oblique_association.py --scenes 12 --choose-lens``) one clip's 70 kept no
pair and 90 kept one wrong pair over 39 frames (+ consensus CVIDF1 87.0 -> 83.4 without this
bound)."""

NEAR_TIE = 1.1
"""Along the tracks, another lens than the prior keeping at most this many times the prior's
pair-frames replaces it only where its pairs also join more top-view people
(:func:`pick_along_tracks`). On a tilting close drone (``benchmarks/oblique_association.py
--top-pitch-rate 1 2``) a 110 degree run kept 117 pair-frames of three people, all wrong,
against the prior's 110 of the same three, all right; in the three other near ties (within
10 %) among the clips measured with it, where the wider lens paired slightly better (0.989
against 0.986, 1.000 against 0.990 and 0.985), it joined more people (6 against 5, 8 against
7, 10 against 8). Then another lens's run made with the top camera's sights, or a lens
measured from another lens's pairs, replaces the chosen run only where it keeps more than this
many times its pairs
(:func:`~xvmatch.inference.matching.ground_association.choose_along_tracks`)."""

MEASURED_RANGE = (45.0, 130.0)
"""The fields of view, degrees, a lens measured from a run's pairs (:func:`implied_hfov`) is
held to: wider than an action camera's pinhole reading nothing is sure (pairs that imply more
are wrong pairs or a fisheye)."""

MIN_MEASURED_PEOPLE = 3
"""Top-view people a run's pairs must join for the lens they imply (:func:`implied_hfov`) to
be tried: two people give one distance, which a depth stretch and a scale share."""

MIN_REMEASURE_DEG = 3.0
"""Degrees the lens a run's pairs imply must differ from the run's own for another run to be
made at it (:func:`~xvmatch.inference.matching.ground_association.choose_along_tracks`)."""

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
        chance: ``{candidate hfov: the pairing score of the mirrored registration}``
            (:func:`chance_score`), rounded.
        along_tracks: chosen by :func:`pick_along_tracks` (video mode): ``scores`` are the
            pairs each lens's whole run kept along the tracks, ``chance`` is empty.
        people: along the tracks, ``{candidate hfov: the top-view people its pairs join}``.
        measured_from: where ``hfov_deg`` is the lens a candidate's pairs imply
            (:func:`implied_hfov`), that candidate (``scores``, ``scales`` and ``people``
            then hold the measured lens's run too, as made); None: a candidate.
        made: along the tracks, ``{candidate hfov: the pair-frames of its run as made}``
            (with the top camera's sights where given; ``scores`` are those of the runs the
            lens is first chosen on, without them).
    """

    hfov_deg: float
    scores: dict[float, float]
    scales: dict[float, float]
    frames: list[int]
    chance: dict[float, float] = field(default_factory=dict)
    along_tracks: bool = False
    people: dict[float, int] = field(default_factory=dict)
    measured_from: float | None = None
    made: dict[float, float] = field(default_factory=dict)

    @property
    def registered(self) -> bool:
        """Whether any candidate's registration paired somebody above chance
        (:data:`MIN_PAIRING`; along the tracks: kept a pair)."""
        if self.along_tracks:
            return max(self.scores.values(), default=0.0) > 0.0
        return max(_above(self.scores, self.chance).values(), default=0.0) >= MIN_PAIRING

    @property
    def why_prior(self) -> str | None:
        """Why the prior (:data:`~xvmatch.geometry.people_calibration.PRIOR_HFOV_DEG`) was
        kept, in a few words the commands' notes share; None where the lens was chosen from
        the people."""
        if not self.registered:
            return ("no lens tried kept a pair along the tracks" if self.along_tracks else
                    "no lens tried registered its people")
        if self.hfov_deg == PRIOR_HFOV_DEG:
            return ("no other lens kept more pairs along the tracks" if self.along_tracks else
                    "no other lens paired clearly more of its people")
        return None


def implied_hfov(hfov_deg: float, tops: list[np.ndarray], hors: list[np.ndarray]
                 ) -> float | None:
    """The horizontal field of view, whole degrees within :data:`MEASURED_RANGE`, that a run's
    pairs imply; None where they cannot tell (:func:`implied_fit`, its lens)."""
    fit = implied_fit(hfov_deg, tops, hors)
    return None if fit is None else fit[0]


def implied_fit(hfov_deg: float, tops: list[np.ndarray], hors: list[np.ndarray]
                ) -> tuple[float, float] | None:
    """The horizontal field of view, whole degrees within :data:`MEASURED_RANGE`, that a run's
    pairs imply, and how far they stray from it: the median over the pairs of pairs of the
    fit's residual over the top map's squared distance (4 decimals; a run that swaps people
    strays more); None where they cannot tell (fewer than three distances, or a degenerate fit).

    A lens of the wrong focal length stretches the handheld map along the camera's axis only:
    a person's distance ahead is ``f H / h`` while the offset across is ``H (u - c) / h``, free
    of ``f``. So between two paired people, the top map's squared distance is
    ``s^2 (k^2 da^2 + dc^2)`` for the handheld map's ``da`` (ahead) and ``dc`` (across), ``s``
    the maps' scale and ``k`` the true over the used focal length: linear in ``s^2 k^2`` and
    ``s^2``, fitted by least squares over every pair of pairs of every frame (no pose needed).
    The two-by-two normal equations are solved by hand and the answer rounded: the same lens
    on every CPU.

    Args:
        hfov_deg: the field of view the handheld map was read with, degrees.
        tops: per frame, the paired people on the top map ``(P, 2)``.
        hors: per frame, the same people, row for row, on the handheld map ``(P, 2)`` (x ahead,
            y across; read at their top partner's height where the run reads them so).
    """
    rows = []
    for top, hor in zip(tops, hors, strict=True):
        top = np.asarray(top, float).reshape(-1, 2)
        hor = np.asarray(hor, float).reshape(-1, 2)
        if len(top) != len(hor):
            raise ValueError(f"each frame's tops and hors must pair row for row, got "
                             f"{len(top)} and {len(hor)}")
        i, j = np.triu_indices(len(top), 1)
        d_top = ((top[i] - top[j]) ** 2).sum(axis=1)
        rows.append(np.column_stack([(hor[i] - hor[j]) ** 2, d_top]))
    table = np.vstack(rows) if rows else np.zeros((0, 3))
    if len(table) < 3:
        return None
    a, c, y = table.T
    # The normal equations of y = alpha a + beta c, by Cramer's rule.
    aa, ac, cc, ay, cy = (float(np.sum(v)) for v in (a * a, a * c, c * c, a * y, c * y))
    det = aa * cc - ac * ac
    if not det > 1e-9 * aa * cc:
        return None
    alpha, beta = (ay * cc - cy * ac) / det, (aa * cy - ac * ay) / det
    if not (alpha > 0 and beta > 0):
        return None
    k = math.sqrt(alpha / beta)  # the math module's: the same on every CPU
    hfov = math.degrees(2 * math.atan(math.tan(math.radians(hfov_deg) / 2) / k))
    stray = np.abs(y - alpha * a - beta * c) / np.maximum(y, 1e-12)
    return (float(min(max(round(hfov), MEASURED_RANGE[0]), MEASURED_RANGE[1])),
            round(float(np.median(stray)), 4))


def _subsample(n: int, max_frames: int) -> list[int]:
    """Indices of at most ``max_frames`` of ``n`` frames, evenly spread, first and last kept."""
    if n <= max_frames:
        return list(range(n))
    return sorted({int(k) for k in np.round(np.linspace(0, n - 1, max_frames))})


def pairing_score(tops: list[np.ndarray], hors: list[np.ndarray], frames: list[int],
                  poses: list[gr.FramePose], sizes: list[np.ndarray] | None = None) -> float:
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
        sizes: per frame, each top person's height over the crowd's ``(N,)``, at which a
            horizontal person is read against them (None: all 1).
    """
    by_frame = {p.frame: p for p in poses}
    total = 0.0
    for k, (f, top, hor) in enumerate(zip(frames, tops, hors, strict=True)):
        pose = by_frame.get(f)
        if pose is None:
            continue
        pairs = gr.associate_on_ground(top, hor, pose, None if sizes is None else sizes[k])
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
                    max_frames: int = MAX_FRAMES,
                    sizes: list[np.ndarray] | None = None,
                    spread: float = gr.RANGE_SPREAD, slack: float = 1.0,
                    holders: list[np.ndarray | None] | None = None) -> LensChoice:
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
        sizes: per frame, each top person's height over the crowd's ``(N,)``
            (:func:`~xvmatch.inference.matching.ground_association.top_sizes`): each
            registration reads a handheld person at their top partner's height, as the run
            after the choice does (None: everyone at the crowd's).
        spread: as the registration's
            (:func:`~xvmatch.cues.ground_registration.pose_hypotheses`).
        slack: the registration's free walk and turn, as
            :func:`~xvmatch.cues.ground_registration.register_sequence`'s.
        holders: per frame, where the camera stands on the top map, or None
            (:func:`~xvmatch.cues.ground_registration.register_with_scale`'s).
    Returns:
        The choice; the prior when no frame has people in both views.
    """
    if not len(frames) == len(tops) == len(hor_boxes):
        raise ValueError(f"frames, tops and hor_boxes must have one entry per frame, got "
                         f"{len(frames)}, {len(tops)} and {len(hor_boxes)}")
    if sizes is not None and len(sizes) != len(frames):
        raise ValueError(f"sizes must have one entry per frame, got {len(sizes)} for "
                         f"{len(frames)} frames")
    if max_frames < 1:
        raise ValueError(f"max_frames must be at least 1, got {max_frames}")
    lenses = sorted({float(c) for c in candidates} | {float(prior_deg)})
    keep = _subsample(len(frames), max_frames)
    sub = [frames[k] for k in keep]
    sub_tops = [np.asarray(tops[k], float).reshape(-1, 2) for k in keep]
    sub_boxes = [np.asarray(hor_boxes[k], float).reshape(-1, 4) for k in keep]
    sub_sizes = None if sizes is None else [np.asarray(sizes[k], float).reshape(-1)
                                            for k in keep]
    sub_holders = None if holders is None else [holders[k] for k in keep]
    scores: dict[float, float] = {}
    scales: dict[float, float] = {}
    chance: dict[float, float] = {}
    reading = gr.HandheldReading.of(sub_boxes, hor_size)
    for hfov in lenses:
        hors = [reading.points(b, hfov) for b in sub_boxes]
        scale, poses = gr.register_with_scale(sub, sub_tops, hors, hfov, fps,
                                              top_sizes=sub_sizes, spread=spread, slack=slack,
                                              holders=sub_holders)
        scores[hfov] = round(pairing_score([scale * t for t in sub_tops], hors, sub, poses,
                                           sub_sizes), _DIGITS)
        chance[hfov] = round(chance_score(sub, sub_tops, hors, hfov, fps, sub_sizes, spread,
                                          slack, sub_holders), _DIGITS)
        scales[hfov] = scale
    return LensChoice(hfov_deg=_pick(scores, chance, float(prior_deg), margin), scores=scores,
                      scales=scales, frames=sub, chance=chance)


def chance_score(frames: list[int], tops: list[np.ndarray], hors: list[np.ndarray],
                 hfov_deg: float, fps: float, sizes: list[np.ndarray] | None = None,
                 spread: float = gr.RANGE_SPREAD, slack: float = 1.0,
                 holders: list[np.ndarray | None] | None = None) -> float:
    """The pairing score (:func:`pairing_score`) of the same registration with the horizontal
    view's ground maps mirrored (left and right swapped): what a lens pairs by chance. The
    mirrored crowd keeps its distances, its spread and the squeeze of the lens, but not its
    arrangement, so it matches the top map no better than chance, whether people walk or
    stand. A wide lens squeezes the handheld map and pairs more people by chance alone; the
    choice compares the lenses on what they pair above that (``sizes``: as
    :func:`pairing_score`'s; ``spread``, ``slack`` and ``holders``: as the registration's)."""
    mirrored = [np.asarray(h, float).reshape(-1, 2) * np.array([1.0, -1.0]) for h in hors]
    scale, poses = gr.register_with_scale(frames, tops, mirrored, hfov_deg, fps,
                                          top_sizes=sizes, spread=spread, slack=slack,
                                          holders=holders)
    return pairing_score([scale * t for t in tops], mirrored, frames, poses, sizes)


def pick_along_tracks(kept: dict[float, int], people: dict[float, int] | None = None,
                      prior: float = PRIOR_HFOV_DEG) -> float:
    """Video mode's lens (and, with ``prior`` 1, the top map's scale of a lens's run,
    :func:`~xvmatch.inference.matching.ground_association.register_and_pair`): the candidate
    whose whole run (registration, pairs, consensus along both views' tracks) keeps the most
    pairs, counted over the frames (a tie: the nearest the prior, then the smaller); the prior
    where none keeps any. Another lens than the prior
    only where its pairs join :data:`MIN_PEOPLE` top-view people (``people``: how many each
    run's pairs join; None: not checked): a pose can put any one person on any other, so one
    pair held says nothing of the lens; nor where it keeps at most :data:`NEAR_TIE` times the
    prior's pairs and joins no more people. A wrong lens stretches the handheld map along the
    camera's axis, so its poses drift from frame to frame and its pairs change partner along a
    track, which the consensus drops. On 72 rendered clips (lenses of 60-80 and 90-120
    degrees, a close and a far drone) its pick paired as well as the best of the then three
    candidates on every clip (docs/notes/oblique_top_camera.md)."""
    if prior not in kept:
        raise ValueError(f"the prior lens {prior} must be among the candidates {sorted(kept)}")
    if people is not None and set(people) != set(kept):
        raise ValueError(f"people must have the candidates of kept, {sorted(kept)}; got "
                         f"{sorted(people)}")
    able = [h for h in kept if h == prior or people is None or people[h] >= MIN_PEOPLE]
    best = max(able, key=lambda h: (kept[h], -abs(h - prior), -h))
    if (people is not None and best != prior and kept[best] <= NEAR_TIE * kept[prior]
            and people[best] <= people[prior]):
        return prior  # a near tie joining no more people: no evidence against the prior
    return best if kept[best] > 0 else prior


def _above(scores: dict[float, float], chance: dict[float, float]) -> dict[float, float]:
    """Each lens's pairing score above chance (:func:`chance_score`; none recorded: 0), rounded
    as the scores are."""
    return {h: round(v - chance.get(h, 0.0), _DIGITS) for h, v in scores.items()}


def _pick(scores: dict[float, float], chance: dict[float, float], prior: float,
          margin: float) -> float:
    """The lens chosen from the candidates' rounded pairing scores and chance scores
    (``prior`` among them): the one that pairs the most above chance (a tie: the nearest the
    prior, then the narrower), where it pairs more than ``margin`` times what the prior pairs,
    both in all and above chance (where the prior pairs anything above chance), and somebody
    above chance (:data:`MIN_PAIRING`); else the prior."""
    above = _above(scores, chance)
    best = max(above, key=lambda h: (above[h], -abs(h - prior), -h))
    return (best if scores[best] > round(margin * scores[prior], _DIGITS)
            and above[best] > round(margin * max(above[prior], 0.0), _DIGITS)
            and above[best] >= MIN_PAIRING else prior)
