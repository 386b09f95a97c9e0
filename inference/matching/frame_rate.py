"""The frame rate of a box file's frame numbers, read from how fast its people walk (issue 67).

The ground-map path measures time in seconds: the handheld camera's walk and turn between two
frames are allowed for by their time apart, and the top map's own motion is averaged over a
window of seconds (:mod:`xvmatch.cues.ground_registration`). A file of every 10th frame of a
30 fps video may number its frames 1, 11, 21 (30 a second) or 1, 2, 3 (3 a second), and nothing
in the file says which. Read as 30 a second, a file numbered 1, 2, 3 lets the camera move a
tenth of what it does. On 12 renders (``benchmarks/oblique_association.py --fps N``), CVIDF1
73.6 at the true rate: the same read 1.5 or 3 times too fast, 67.4 at 6 or 9 times, 71.1 and
70.4 at 1.5 and 3 times too slow.

People on the top view's metric ground map tell it: a brisk walker covers about
:data:`BRISK_WALK_MPS` a second. The pace is measured over about a second of each person's
track (the file's own step at first, then the second that step implies), so that box jitter,
which does not grow with time, cannot pass for walking: a crowd that stands still reads ever
slower per frame at longer spans and is refused (:data:`MAX_FPS`), as are too few people
followed. The estimate replaces the prior only where the two are more than
:data:`PRIOR_FACTOR` apart, and never by more than that factor above it: within it the prior
costs nothing on the renders, and a crowd that strolls or stands reads too high a rate.
Where no walker tells the rate, the prior is taken and the registration lets the camera walk
and turn as freely as at a tenth of it (:data:`UNREAD_RATE_SLACK`): nothing says the file is
not numbered 1, 2, 3.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "BRISK_WALK_MPS",
    "MAX_FPS",
    "MIN_FPS",
    "MIN_WALKERS",
    "PRIOR_FACTOR",
    "PRIOR_FPS",
    "READ_RATE_SLACK",
    "UNREAD_RATE_SLACK",
    "FrameRate",
    "frame_rate_from_walkers",
    "frame_rate_note",
]

BRISK_WALK_MPS = 1.3
"""A brisk walker's pace, metres a second: what the :data:`WALKER_QUANTILE` of the people's
paces is read as (pedestrians walk 1.2-1.5 m/s; the renders draw 0.3-1.4)."""

WALKER_QUANTILE = 0.8
"""Which of the people's paces is a brisk walker's: the 80th percentile, so that up to four
in five people may stand, stroll or wait."""

MIN_WALKERS = 3
"""Fewest people followed over three or more spans each that an estimate rests on."""

MIN_FPS, MAX_FPS = 0.2, 240.0
"""Frame rates an estimate may give; outside them it is refused (people who do not walk)."""

PRIOR_FPS = 30.0
"""The frame rate assumed unless the walkers say otherwise: a video's own numbering."""

PRIOR_FACTOR = 2.0
"""How far the walkers' frame rate must lie from the prior (either way, as a factor) to replace
it."""

READ_RATE_SLACK = 2.0
"""How many times its free walk and turn a second the registration allows where the rate was
read from the walkers (:attr:`FrameRate.slack`;
:func:`~xvmatch.cues.ground_registration.register_sequence`): small crowds that stroll and stop
read it too high more often than too low (1.8-13 for a true 3.33 on renders), which shrinks the
time between frames and charges a handheld camera's walk and pan as jumps. A rate read too low
cost little, too high cost 4 CVIDF1 on those clips; twice the walk and turn gained 0.9 over 19
sets of renders, but cost real CVMHAT's forced ground path 0.9 at its true rate (a square,
94.0 -> 85.8), so only a rate read gets it (docs/notes/oblique_top_camera.md)."""

UNREAD_RATE_SLACK = 10.0
"""How many times its free walk and turn a second the registration allows where no walker told
the rate and the prior was taken (:attr:`FrameRate.slack`): as free as a file of every 10th
frame numbered 1, 2, 3 needs. At the prior's own allowance such a file lets the camera move a
tenth of what it does, less than its poses' own wobble from frame to frame, so a steady wrong
run outscores the right one: on a rendered standing crowd the right run, among the
hypotheses in 39 of 40 frames, explained 156 people against the wrong one's 135 and lost.
On six render sets of standing crowds seen by still cameras, + consensus CVIDF1 at the true
lens 70.3 -> 77.9, the lens chosen (at the prior's allowance, :attr:`FrameRate.lens_slack`)
68.0 -> 75.3 (docs/notes/oblique_top_camera.md)."""

_SPANS = 3
"""Rounds of the estimate: each measures the pace over the span the previous one implies."""

_SPAN_S = 1.0
"""The time a pace is measured over, seconds."""


@dataclass(frozen=True)
class FrameRate:
    """A frame rate and where it came from.

    Attributes:
        fps: frames per second of the frame numbers.
        estimated: read from the people's walking (:func:`frame_rate_from_walkers`);
            False: the prior (or what the user gave).
        prior: the frame rate assumed without the walkers.
        walkers: people whose pace was measured (0: none could be).
        prior_pace: the brisk walkers' pace were the frames ``prior`` a second, metres a
            second (NaN: not measured).
    """

    fps: float
    estimated: bool
    prior: float
    walkers: int = 0
    prior_pace: float = float("nan")

    @property
    def slack(self) -> float:
        """The registration's free walk and turn a second, as a factor: :data:`READ_RATE_SLACK`
        for a rate read from the walkers, :data:`UNREAD_RATE_SLACK` for the prior where no
        walker could tell one, 1 for one given or the walkers confirm."""
        if self.estimated:
            return READ_RATE_SLACK
        return UNREAD_RATE_SLACK if self.unread else 1.0

    @property
    def unread(self) -> bool:
        """The prior taken because no walker could tell a rate (neither read nor confirmed)."""
        return not self.estimated and not self.walkers

    @property
    def lens_slack(self) -> float:
        """The free walk and turn the handheld lens is chosen with: :attr:`slack`, but 1 where
        no walker told the rate: let move so, on a standing crowd each lens's run keeps as many
        pairs along the tracks and a wider lens than the true one was chosen more often."""
        return 1.0 if self.unread else self.slack


def _paces(frames: np.ndarray, ids: np.ndarray, points: np.ndarray, span: float) -> np.ndarray:
    """Each person's median pace, metres per frame number, over steps about ``span`` frame
    numbers long (from each box to the person's first box at least ``span`` later, at most
    twice that); only people with :data:`_SPANS` or more such steps. The rows come sorted by
    person, then frame."""
    f, i, p = frames.astype(float), ids, points
    ends = np.searchsorted(i, i, side="right")
    # Within each person's rows (frames ascending), the first row at least `span` later.
    key = np.unique(i, return_inverse=True)[1] * (np.ptp(f) + 4 * span + 1) + (f - f.min())
    later = np.minimum(np.searchsorted(key, key + span, side="left"), len(f) - 1)
    ok = (later < ends) & (f[later] - f >= span) & (f[later] - f <= 2 * span)
    step = np.hypot(*(p[later] - p).T) / np.maximum(f[later] - f, 1e-9)
    first = np.unique(i[ok], return_index=True)[1]
    return np.array([np.median(mine) for mine in np.split(step[ok], first[1:])
                     if len(mine) >= _SPANS])


def frame_rate_from_walkers(frames: np.ndarray, ids: np.ndarray, points: np.ndarray,
                            prior: float = PRIOR_FPS) -> FrameRate:
    """The frame rate of ``frames`` from the people's walking (module docstring); the
    ``prior`` where they cannot tell one or where theirs is within :data:`PRIOR_FACTOR` of it,
    and at most that factor above it.

    Args:
        frames: ``(N,)`` frame number of each box.
        ids: ``(N,)`` the person each box is, followed over time (the view's track ids, or
            boxes linked by IoU).
        points: ``(N, 2)`` their foot points on a metric ground map (NaN: none).
        prior: the frame rate kept where the walkers cannot tell one.
    """
    frames = np.asarray(frames, np.int64).ravel()
    ids = np.asarray(ids, np.int64).ravel()
    points = np.asarray(points, float).reshape(-1, 2)
    ok = np.isfinite(points).all(axis=1)
    frames, ids, points = frames[ok], ids[ok], points[ok]
    kept = FrameRate(float(prior), False, float(prior))
    if len(frames) < 2:
        return kept
    order = np.lexsort((frames, ids))  # by person, then frame: once, for every round
    frames, ids, points = frames[order], ids[order], points[order]
    gaps = np.diff(frames)[np.diff(ids) == 0]
    gaps = gaps[gaps > 0]
    if not len(gaps):
        return kept
    span = float(np.median(gaps))
    fps, paces = float("nan"), np.zeros(0)
    for _ in range(_SPANS):
        paces = _paces(frames, ids, points, span)
        if len(paces) < MIN_WALKERS:
            return kept
        brisk = float(np.quantile(paces, WALKER_QUANTILE))
        if brisk <= 0 or not MIN_FPS <= BRISK_WALK_MPS / brisk <= MAX_FPS:
            return kept
        fps = BRISK_WALK_MPS / brisk
        span = max(float(np.median(gaps)), round(fps * _SPAN_S))
    pace = float(np.quantile(paces, WALKER_QUANTILE)) * prior
    if prior / PRIOR_FACTOR <= fps <= prior * PRIOR_FACTOR:
        return FrameRate(float(prior), False, float(prior), len(paces), pace)
    return FrameRate(min(float(f"{fps:.2g}"), prior * PRIOR_FACTOR), True, float(prior),
                     len(paces), pace)


def frame_rate_note(rate: FrameRate) -> str:
    """One line saying what frame rate the run took and why."""
    if rate.estimated:
        return (f"frame numbers read as {rate.fps:g} a second from the top view's walkers "
                f"({rate.walkers} followed; at {rate.prior:g} a second they would walk "
                f"{rate.prior_pace:.1f} m/s); give --fps if known")
    if rate.walkers:
        return (f"frame numbers read as {rate.fps:g} a second (the top view's {rate.walkers} "
                f"walkers then walk {rate.prior_pace:.1f} m/s); give --fps if known")
    return (f"frame numbers read as {rate.fps:g} a second, the default (too few people walk "
            f"in the top view to tell; the camera let move as at "
            f"{rate.fps / UNREAD_RATE_SLACK:g} a second; give --fps if known)")
