"""One top view and several handheld views joined on the top view's ground map, for a top camera
that is not a nadir drone (issue 67): the run behind ``associate-multi --top-view oblique`` (and
``auto`` when the top view's boxes say it is oblique).

1. The top camera is calibrated once from its people
   (:func:`~xvmatch.inference.matching.ground_association.top_calibration`): the top view's
   people go on a metric ground map.
2. Each handheld view's people go on its own ground map (distance from box height, bearing from
   column), and its pose on the top map is registered frame by frame and chosen over time
   (:mod:`xvmatch.cues.ground_registration`), as ``associate --top-view oblique`` does for one.
3. Every frame becomes one joint program of
   :mod:`xvmatch.inference.views.multi_view_assignment` (:class:`~xvmatch.inference.views.
   multi_view_costs.FrameProblem`, gamma 0): a top-handheld cost from the ground distance
   between a top person and a registered handheld person (its part along the handheld
   camera's ray shrunk, :func:`~xvmatch.cues.ground_registration.ray_distances`, the handheld
   person read at the top person's height, as ``associate`` pairs and registers,
   :func:`~xvmatch.inference.matching.ground_association.top_sizes`); handheld-handheld pairs
   get no
   evidence by default (:data:`HOR_HOR`: the handheld maps, from box heights, were too loose to
   pair two of them on the renders; a calibration there pairs by ground distance the people the
   top view does not see). The program's cycle consistency keeps the pairs one set of people: two
   handheld people are one when both pair with the same top person. With tracks
   (:class:`~xvmatch.inference.views.multi_view_people.PeopleOptions` ``tracks``) the ids follow
   each view's tracklets, as on the nadir path.

A cost is ``slope (d - threshold)`` nats for a ground distance ``d`` (:data:`TOP_HOR`): a pair
closer than the threshold is worth matching alone (scaled on the registration's own
non-association distance, :data:`~xvmatch.cues.ground_registration.RADIUS`). A view not
registered on a frame gives its pairs no evidence for a match (a positive cost): it is left
unmatched there.

With ``hor_hfov_deg="auto"`` (``--hor-hfov auto``) each handheld view's field of view is chosen
from its people before its registration, one lens per view (:func:`choose_lenses`): in video
mode the lens whose run with the top view keeps the most pairs along the tracks, as
``associate`` chooses; frame by frame, :func:`~xvmatch.cues.hor_lens.choose_hor_hfov`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from functools import partial

import numpy as np

from xvmatch.cues import ground_registration as gr
from xvmatch.cues.hor_lens import NEAR_TIE, LensChoice, choose_hor_hfov
from xvmatch.formats.box_image_size import (
    check_boxes_in_image,
    ground_path_hor_size,
    ground_path_size_note,
    runs_past_borders,
    size_guess_how,
    upright_size_guess,
)
from xvmatch.formats.mot_boxes import FrameBoxes, align_frames, stack_frames
from xvmatch.geometry.people_calibration import (
    PRIOR_HFOV_DEG,
    CalibrationError,
    PeopleCalibration,
    measure_spread,
)
from xvmatch.geometry.tilting_camera import TiltTrack
from xvmatch.inference.linking.tracklets import box_track_ids
from xvmatch.inference.matching.frame_rate import frame_rate_note
from xvmatch.inference.matching.ground_association import (
    AUTO_FPS,
    AUTO_HFOV,
    PRIOR_FPS,
    TOP_VIEWS,
    choose_along_tracks,
    miss_spread,
    run_along_tracks,
    tilting_top,
    top_calibration,
    top_frame_rate,
    top_ground_points,
    top_sights,
    top_sizes,
    top_summary,
)
from xvmatch.inference.views.multi_ego_run import MultiEgoRun
from xvmatch.inference.views.multi_view_assignment import view_pairs
from xvmatch.inference.views.multi_view_costs import FrameProblem, LogisticCalibration
from xvmatch.inference.views.multi_view_people import PeopleOptions, assign_people

__all__ = ["HOR_HOR", "REGISTERED", "TOP_HOR", "MultiGroundOptions", "TopMap", "choose_lenses",
           "ground_options", "ground_problems", "holders_note", "lenses_note", "oblique_top",
           "run_multi_ground", "top_map"]

TOP_HOR = LogisticCalibration(threshold=2.0 * gr.RADIUS, slope=1.0)
"""Top-handheld pairs: minus the evidence (nats) of a ground distance ``d`` (metres), none at
twice the registration's radius, so that a pair within the radius gains at least as much as it
saves the per-view Hungarian of :func:`~xvmatch.cues.ground_registration.associate_on_ground`
(which pays ``2 radius`` for a row left unmatched). On 3 rendered 6 s scenes (two handheld views,
top pitch 25-60 degrees) the top-handheld pair F1 was 0.314 with it against 0.222 with no
evidence at the radius (slope 2)."""

REGISTERED = ("each handheld view registered on its ground map frame by frame and the views "
              "joined there (boxes only: --model and its images not used)")
"""How :func:`run_multi_ground`'s line on the top view ends (:func:`~xvmatch.inference.
matching.ground_association.top_summary`)."""

HOR_HOR: LogisticCalibration | None = None
"""Handheld-handheld pairs from their ground distance, or None: no evidence either way
(:data:`HOR_HOR_COST`), two handheld people paired only when both pair with the same top
person. None by default: the handheld ground maps (distance from box height) are too loose to
pair two of them. Measured with ``benchmarks/oblique_multi_view.py``'s scenes 1-6 (two handheld
views, 12 s, every 3rd frame), pooled pair F1 of the three view pairs: 0.822 with None, 0.777
with threshold ``sqrt(2) RADIUS`` and slope ``sqrt(2)`` (two registrations' errors), 0.808 with
that evidence for a match only (never against), and 0.784 for the per-view runs joined through
the top view."""

HOR_HOR_COST = 0.01
"""Nats against a handheld-handheld pair without evidence: so small that it never stops a
pair the top view closes, so that the program makes none that it does not."""

VIDEO_KEEP_FREE = False
"""In video mode, a top track that no partner holds keeps no pairs (as ``associate --top-view
oblique --mode video``), rather than its frames' own."""

_FAR = 3.0
"""Distances are capped at this many radii: a far pair's cost stays bounded."""


@dataclass(frozen=True)
class MultiGroundOptions:
    """What the run needs besides the boxes and the top camera's calibration.

    Attributes:
        hor_sizes: each handheld view's image size (width, height).
        hor_hfov_deg: the handheld cameras' field of view, degrees (70: a phone's, a
            drone's): one for all, one per handheld view (a tuple), or
            :data:`~xvmatch.inference.matching.ground_association.AUTO_HFOV`: each chosen
            from its people (:func:`choose_lenses`).
        fps: frames per second of the frame numbers (the registration's pace over time), or
            :data:`~xvmatch.inference.matching.ground_association.AUTO_FPS`: from the top
            view's walkers (:func:`~xvmatch.inference.matching.ground_association.
            top_frame_rate`).
        slack: how many times the registration's free walk and turn a second
            (:func:`~xvmatch.cues.ground_registration.register_sequence`): set with the rate
            where it was read from the walkers
            (:attr:`~xvmatch.inference.matching.frame_rate.FrameRate.slack`).
        lens_slack: the same for choosing the handheld lenses, or None: ``slack``
            (:attr:`~xvmatch.inference.matching.frame_rate.FrameRate.lens_slack`).
        workers: processes running a handheld view's candidate lenses side by side in video
            mode (:func:`~xvmatch.inference.matching.ground_association.choose_along_tracks`);
            the same result for any number.
        wearers: per handheld view, ``{frame: row within the top view's record}`` of its
            holder (``--camera-id``, in the top file's frame numbers), or None: they pair
            with nobody of their own view, and in video mode its camera is sought near where
            the top view maps them where that keeps more pairs (:func:`_registered`); None:
            no holder told.
    """

    hor_sizes: tuple[tuple[int, int], ...]
    hor_hfov_deg: float | str | tuple[float, ...] = PRIOR_HFOV_DEG
    fps: float | str = PRIOR_FPS
    slack: float = 1.0
    lens_slack: float | None = None
    workers: int = 1
    wearers: tuple[Mapping[int, int] | None, ...] | None = None

    def __post_init__(self) -> None:
        if isinstance(self.fps, str) and self.fps != AUTO_FPS:
            raise ValueError(f"MultiGroundOptions.fps must be frames a second or "
                             f"{AUTO_FPS!r}, got {self.fps!r}")
        if not self.slack > 0:
            raise ValueError(f"MultiGroundOptions.slack must be positive, got {self.slack!r}")
        if self.lens_slack is not None and not self.lens_slack > 0:
            raise ValueError(f"MultiGroundOptions.lens_slack must be positive or None, got "
                             f"{self.lens_slack!r}")
        hfov = self.hor_hfov_deg
        if isinstance(hfov, str) and hfov != AUTO_HFOV:
            raise ValueError(f"MultiGroundOptions.hor_hfov_deg must be degrees or "
                             f"{AUTO_HFOV!r}, got {hfov!r}")
        if isinstance(hfov, tuple) and len(hfov) != len(self.hor_sizes):
            raise ValueError(f"MultiGroundOptions.hor_hfov_deg: one per handheld view "
                             f"({len(self.hor_sizes)}), got {len(hfov)}")
        if self.wearers is not None and len(self.wearers) != len(self.hor_sizes):
            raise ValueError(f"MultiGroundOptions.wearers: one per handheld view "
                             f"({len(self.hor_sizes)}), got {len(self.wearers)}")

    def wearer(self, k: int, frame: int) -> int | None:
        """Handheld view ``k``'s (1-based) holder's row in the top view's record of ``frame``,
        or None (no holder told, or not in that frame)."""
        rows = None if self.wearers is None else self.wearers[k - 1]
        return None if rows is None else rows.get(frame)

    def hfov(self, k: int) -> float:
        """Handheld view ``k``'s field of view (1-based; not ``auto``)."""
        hfov = self.hor_hfov_deg
        if hfov == AUTO_HFOV:
            raise ValueError("MultiGroundOptions.hor_hfov_deg auto: choose the lenses first "
                             "(choose_lenses)")
        return float(hfov[k - 1] if isinstance(hfov, tuple) else hfov)


def oblique_top(top: Mapping, top_view: str, top_size: tuple[int, int] | None, name: str,
                offsets: Sequence[int | str] = (), seed: int = 0,
                top_tracks: Mapping[int, int] | None = None, hors: Sequence[Mapping] = ()
                ) -> tuple[PeopleCalibration | None, str | None]:
    """``associate-multi --top-view``: the top camera calibrated from its people when it is
    oblique (forced, or found so by ``auto``), else None (the nadir path), and the line to say
    now (None: nothing to say): why the nadir path, or the top view's size where guessed. An
    oblique camera's tilt is said by :func:`run_multi_ground` once it knows whether the camera
    tilts (its spread, measured only for a steady one, is left for later here).

    Args:
        top: the top view's ``{frame: record}``.
        top_view: ``auto``, ``nadir`` or ``oblique`` (``nadir`` also where cameras are given).
        top_size: the top view's image size (``--top-image-size``); None: where the top view's
            people stand upright (``auto``), the size its boxes tell
            (:func:`~xvmatch.formats.box_image_size.guess_image_size`), said in the note;
            else the nadir path.
        name: the top box file (messages).
        offsets: each handheld view's ``--offset``; ``auto`` estimates it with the nadir
            search, so the oblique path refuses it.
        seed: seed of the calibration's resampling.
        top_tracks: the top view's ``{row id: track id}`` in video mode, where ``top``'s ids
            are its rows: each followed person then gets a height of their own in the
            calibration (:func:`~xvmatch.geometry.people_calibration.calibrate_from_people`),
            as ``associate``'s does; None (frame mode): followed by its boxes linked by IoU
            (:func:`~xvmatch.inference.linking.tracklets.box_track_ids`), the ids unread.
        hors: the handheld views' ``{frame: record}``: where any of the run's views runs on
            past its image's borders (:func:`~xvmatch.formats.box_image_size.
            runs_past_borders`), the top view's size is guessed and checked so too.

    Raises:
        ValueError: a top box outside ``top_size``, ``auto`` offsets with an oblique top view,
            too few top boxes to calibrate.
    """
    if top_view not in TOP_VIEWS:
        raise ValueError(f"top_view must be one of {TOP_VIEWS}, got {top_view!r}")
    if top_view == "nadir":
        return None, None
    guessed = ""
    past = runs_past_borders(top, *hors)
    if top_size is None:
        guess = upright_size_guess(top, past) if top_view == "auto" else None
        if guess is None:
            return None, None
        aspect, top_size = guess
        if top_size is None:
            return None, (f"the top view's people stand upright (boxes {aspect:.1f} times as tall "
                          "as wide): an oblique camera, read here as a nadir one; no common video "
                          "size holds its boxes: give --top-image-size WxH to calibrate it from "
                          "its people")
        guessed = (f"top view: its size taken as {top_size[0]}x{top_size[1]}, "
                   f"{size_guess_how(top, top_size, past)} (give --top-image-size WxH if not)")
    check_boxes_in_image(top, tuple(top_size), name, "--top-image-size", ids=False, past=past)
    top = _tracked(top, top_tracks)
    try:
        calib = top_calibration(top, tuple(top_size), seed, name, top_tracks is not None,
                                spread="later")
    except CalibrationError as error:
        if not guessed:
            raise
        return None, ("the top view cannot be calibrated from its people "
                      f"({str(error).split(';')[0]}); associating as over a nadir drone")
    if calib.kind == "nadir" and top_view == "auto":
        return None, ("top view: looking straight down (its boxes are as wide as tall); "
                      "associating as over a nadir drone")
    if "auto" in offsets:
        raise ValueError("--offset auto estimates the offsets with the nadir search; with an "
                         "oblique top view give them as frame numbers (or 0)")
    return calib, guessed or None


def ground_options(views: Sequence[Mapping], resolved: Sequence[tuple[tuple[int, int], str]],
                   paths: Sequence[str], hfov: float | str, fps: float | str,
                   note: Callable[[str], object], workers: int = 1,
                   wearers: Sequence[Mapping[int, int]] | None = None) -> MultiGroundOptions:
    """``associate-multi``'s options of this path: each handheld view's image size as resolved
    (``views[k + 1]``'s ``(size, source)``), except a CVMHAT size assumed for boxes alone (or
    none known: boxes that do not fit it), where the size its boxes tell serves
    (:func:`~xvmatch.formats.box_image_size.ground_path_hor_size`), told to
    ``note`` (``paths``: the box files, top first; the CVMHAT size kept, where the boxes fit
    it, told too); ``--hor-hfov``, ``--fps``, ``--workers`` and the holders' rows
    (``--camera-id``, :attr:`MultiGroundOptions.wearers`)."""
    sizes = []
    past = runs_past_borders(*views)  # the run's files, made by one tracker or tool
    for k, (size, source) in enumerate(resolved, 1):
        guess = ground_path_hor_size(views[k], size, source, past)
        if (said := ground_path_size_note(paths[k], views[k], guess, source, past)) is not None:
            note(said)
        sizes.append(tuple(guess or size))
    return MultiGroundOptions(tuple(sizes), hfov, fps, workers=workers,
                              wearers=None if wearers is None else tuple(wearers))


def _tracked(top: Mapping, top_tracks: Mapping[int, int] | None) -> Mapping:
    """The top view with its track ids for ids (``top_tracks``: ``{row id: track id}``, video
    mode, where its ids are its rows); as it is without them."""
    if top_tracks is None:
        return top
    return {f: FrameBoxes(f, np.array([top_tracks[int(r)] for r in rec.ids], dtype=np.int64),
                          rec.boxes) for f, rec in top.items()}


def _boxes(record) -> np.ndarray:
    return (np.zeros((0, 4)) if record is None
            else np.asarray(record.boxes, float).reshape(-1, 4))


def _paired_frames(hor: Mapping, tops: Mapping[int, np.ndarray]) -> list[int]:
    """The frames where both the top view (on its map) and handheld view ``hor`` have people."""
    return sorted(f for f in set(tops) & set(hor) if len(_boxes(hor[f])) and len(tops[f]))


def _holders(tops: Mapping[int, np.ndarray], order: Sequence[int], options: MultiGroundOptions,
             k: int) -> list[np.ndarray | None] | None:
    """For handheld view ``k`` on ``order``'s frames, where its camera stands about: its
    holder's point on the top map ``tops`` ``{frame: (N, 2)}`` (None where not mapped), or
    None without a holder told (:attr:`MultiGroundOptions.wearers`). The holder stays among
    the top people the registration weighs (see
    :func:`~xvmatch.inference.matching.ground_association.run_ground_association`); only
    their pairs with view ``k`` are left out (:func:`_cost`)."""
    if options.wearers is None or options.wearers[k - 1] is None:
        return None
    rows = [options.wearer(k, f) for f in order]
    return [None if r is None or not np.isfinite(tops[f][r]).all() else tops[f][r]
            for f, r in zip(order, rows, strict=True)]


@dataclass(frozen=True)
class TopMap:
    """The top view's people on its ground map, in each frame's record order.

    Attributes:
        points: ``{frame: (N, 2)}`` where they stand (NaN rows: no ground there).
        sizes: ``{frame: (N,)}`` each one's height over the crowd's
            (:func:`~xvmatch.inference.matching.ground_association.top_sizes`).
        walkers: the whole view stacked, ``(frames, track ids, ground points)`` in
            :func:`~xvmatch.formats.mot_boxes.stack_frames` order (its frame rate's walkers,
            :func:`~xvmatch.inference.matching.ground_association.top_frame_rate`).
        tilt: the top camera's tilt per window where it reads as tilting (each frame mapped
            through its own), else None.
        sights: ``{frame: TopSight}`` where the top camera sees people on its map
            (:func:`~xvmatch.inference.matching.ground_association.top_sights`), or None.
        spread: how far off, in parts of their distance, a top person counts as explained to
            the registration
            (:func:`~xvmatch.inference.matching.ground_association.miss_spread`).
    """

    points: dict[int, np.ndarray]
    sizes: dict[int, np.ndarray]
    walkers: tuple[np.ndarray, np.ndarray, np.ndarray]
    tilt: TiltTrack | None = None
    sights: dict[int, gr.TopSight] | None = None
    spread: float = gr.RANGE_SPREAD


def top_map(views: Sequence[Mapping], frames: Sequence[int], calibration: PeopleCalibration,
            top_tracks: Mapping[int, int] | None = None, fps: float | None = None) -> TopMap:
    """The top view's (``views[0]``) people of ``frames`` on its ground map, as ``associate``
    places them (:func:`~xvmatch.inference.matching.ground_association.top_ground_points`): a
    box cut by the image's bottom edge at its person's own height, each followed by the top
    view's ``top_tracks`` (video mode) or by its boxes linked by IoU (followed once); with the
    frame rate ``fps``, a camera tilting over the clip is read as such and each frame mapped
    through its own tilt (:func:`~xvmatch.inference.matching.ground_association.tilting_top`)."""
    stacked, ids, boxes = stack_frames(_tracked(views[0], top_tracks))
    tracks = ids if top_tracks is not None else box_track_ids(views[0])
    tilt = None if fps is None else tilting_top(stacked, tracks, boxes, calibration, fps)
    read = top_sizes(stacked, boxes, tracks, calibration, tilt)
    ground = top_ground_points(boxes, calibration, read, stacked, tilt)
    keys, starts, counts = np.unique(stacked, return_index=True, return_counts=True)
    at = {int(f): slice(a, a + n) for f, a, n in zip(keys, starts, counts, strict=True)}
    empty = np.zeros((0, 2))
    sights = dict(zip(frames, top_sights(frames, ground, calibration, tilt), strict=True))
    return TopMap({f: ground[at[f]] if f in at else empty for f in frames},
                  {f: read[rows] for f, rows in at.items()}, (stacked, tracks, ground), tilt,
                  sights, miss_spread(calibration))


def choose_lenses(views: Sequence[Mapping], frames: Sequence[int],
                  calibration: PeopleCalibration, options: MultiGroundOptions,
                  tops: TopMap | None = None,
                  tracks: Sequence[Mapping[int, int]] | None = None) -> tuple[LensChoice, ...]:
    """``--hor-hfov auto``: each handheld view's field of view chosen from its people, on the
    frames where it and the top view both have people, each read at its top partner's height,
    in the order of the views (top first, in one timing; ``tops``: the top view's people on its
    map, :func:`top_map`, when built). With ``tracks`` (per view ``{row id: track id}``, video
    mode) as ``associate`` chooses in video mode, the lens whose run with the top view keeps
    the most pairs along the tracks
    (:func:`~xvmatch.inference.matching.ground_association.choose_along_tracks`); without,
    as it chooses frame by frame (:func:`~xvmatch.cues.hor_lens.choose_hor_hfov`)."""
    top_tracks = None if tracks is None else tracks[0]
    top = top_map(views, frames, calibration, top_tracks) if tops is None else tops
    tracked_top = None if tracks is None else _tracked(views[0], tracks[0])  # once, all views
    slack = options.slack if options.lens_slack is None else options.lens_slack
    choices = []
    for k in range(1, len(views)):
        order = _paired_frames(views[k], top.points)
        ok = [np.isfinite(top.points[f]).all(axis=1) for f in order]
        points = [top.points[f][o] for f, o in zip(order, ok, strict=True)]
        sizes = [top.sizes[f][o] for f, o in zip(order, ok, strict=True)]
        size = tuple(options.hor_sizes[k - 1])
        if tracks is None:
            choices.append(choose_hor_hfov(order, points, [_boxes(views[k][f]) for f in order],
                                           size, options.fps, sizes=sizes, spread=top.spread,
                                           slack=slack))
            continue
        pair = (tracked_top, _tracked(views[k], tracks[k]))
        tops_ids = [(p, np.asarray(pair[0][f].ids)[o])
                    for f, p, o in zip(order, points, ok, strict=True)]
        boxes = [(_boxes(pair[1][f]), np.asarray(pair[1][f].ids)) for f in order]
        reading = gr.HandheldReading.of([b for b, _ in boxes], size)
        choices.append(choose_along_tracks(order, tops_ids, boxes, sizes, options.fps, reading,
                                           pair, spread=top.spread, slack=slack,
                                           workers=options.workers)[0])
    return tuple(choices)


def _with_lenses(views: Sequence[Mapping], frames: Sequence[int],
                 calibration: PeopleCalibration, options: MultiGroundOptions,
                 tops: TopMap | None = None,
                 tracks: Sequence[Mapping[int, int]] | None = None
                 ) -> tuple[MultiGroundOptions, tuple[LensChoice, ...]]:
    """``options`` with ``auto`` replaced by each handheld view's chosen lens
    (:func:`choose_lenses`, ``tracks`` in video mode) and the choices; as they are, and none,
    otherwise."""
    if options.hor_hfov_deg != AUTO_HFOV:
        return options, ()
    lenses = choose_lenses(views, frames, calibration, options, tops, tracks)
    return replace(options, hor_hfov_deg=tuple(c.hfov_deg for c in lenses)), lenses


def holders_note(views: Sequence[Mapping], tops: Mapping[int, np.ndarray],
                 options: MultiGroundOptions, kept: Sequence[bool | None]) -> str:
    """The line saying what ``--camera-id`` did: each holder is nobody of their own view's;
    per handheld view, on how many of its frames paired with the top view the top view maps
    its holder, and whether its camera was kept near them (``kept``, per view, as
    :func:`ground_problems` fills it: True near, False anywhere, None frame by frame or no
    holder told)."""
    said = []
    for k in range(1, len(views)):
        order = _paired_frames(views[k], tops)
        holders = _holders(tops, order, options, k)
        seen = sum(h is not None for h in holders or ())
        where = {True: "near them", False: "anywhere (near them kept fewer pairs)",
                 None: "anywhere"}[kept[k - 1]]
        said.append(f"hor{k} mapped on {seen} of {len(order)} frames, sought {where}")
    return (f"--camera-id: each holder left out of their own view's pairs; {', '.join(said)} "
            f"(near: within {gr.HOLDER_RADIUS:g} m, in video mode where its pairs hold along "
            "the tracks more)")


def lenses_note(choices: Sequence[LensChoice]) -> str:
    """The line saying which lens ``--hor-hfov auto`` chose for each handheld view."""
    said = [f"hor{k} {choice.hfov_deg:.0f}"
            + ("" if choice.why_prior is None else f" (the prior: {choice.why_prior})")
            + ("" if choice.measured_from is None else
               f" (measured from a {choice.measured_from:.0f}-degree run's pairs)")
            for k, choice in enumerate(choices, 1)]
    how = ("give --hor-hfov DEG if known" if any(c.why_prior is not None for c in choices)
           else "--hor-hfov DEG fixes them")
    return f"handheld lenses, degrees, chosen from their people: {', '.join(said)} ({how})"


def _registered(views: Sequence[Mapping], k: int, tops: Mapping[int, np.ndarray],
                options: MultiGroundOptions,
                tracks: Sequence[Mapping[int, int]] | None = None,
                sizes: Mapping[int, np.ndarray] | None = None,
                sights: Mapping[int, gr.TopSight] | None = None,
                spread: float = gr.RANGE_SPREAD
                ) -> tuple[dict[int, tuple[np.ndarray, np.ndarray]], bool | None]:
    """``{frame: ((M, 2), (M, 2))}`` handheld view ``k``'s people on the top map and the rays
    from its camera to them there, on the frames where its pose was registered (both views
    have boxes there), and whether its run near its holder was kept (None: no holder told, or
    frame by frame). Frame by frame the top map at the scale whose poses explain the most
    people (:func:`~xvmatch.cues.ground_registration.register_with_scale`); with ``tracks``
    (per view ``{row id: track id}``, video mode) the top map's own motion taken out of the
    registration's jumps and the scale the one whose run with the top view keeps the most
    pairs along both views' tracks, as ``associate`` chooses it
    (:func:`~xvmatch.inference.matching.ground_association.run_along_tracks`), and, with its
    holder told (:attr:`MultiGroundOptions.wearers`), the run seeking the camera near them kept
    where it keeps more than a near tie more pairs, as ``associate`` keeps it. The holder is
    nobody's partner either way. ``sizes``: ``{frame: (N,)}`` each top person's height over
    the crowd's, :attr:`TopMap.sizes`; ``sights``: :attr:`TopMap.sights`; ``spread``:
    :attr:`TopMap.spread`."""
    hor = views[k]
    order = _paired_frames(hor, tops)
    size, hfov = tuple(options.hor_sizes[k - 1]), options.hfov(k)
    every = [_boxes(record) for record in hor.values()]
    reading = gr.HandheldReading.of(every, size)
    local = {f: reading.points(_boxes(hor[f]), hfov) for f in order}
    ok = {f: np.isfinite(tops[f]).all(axis=1) for f in order}
    holders = _holders(tops, order, options, k)
    points = [tops[f][ok[f]] for f in order]
    heights = None if sizes is None else [sizes[f][ok[f]] for f in order]
    seen = None if sights is None else [sights[f] for f in order]
    held = None
    if tracks is None:
        scale, poses = gr.register_with_scale(order, points, [local[f] for f in order], hfov,
                                              options.fps, None, heights, seen, spread,
                                              options.slack)
    else:
        pair = (_tracked(views[0], tracks[0]), _tracked(hor, tracks[k]))
        ids = [np.asarray(pair[0][f].ids)[ok[f]] for f in order]
        run = partial(run_along_tracks, order, list(zip(points, ids, strict=True)),  # as
                      [(local[f], np.asarray(pair[1][f].ids)) for f in order],  # associate
                      heights if heights is not None else [None] * len(order), hfov,
                      options.fps, pair, seen, spread, options.slack)
        scale, poses, pairs = run()
        if holders is not None and any(h is not None for h in holders):
            mine = {f: int(pair[0][f].ids[r]) for f in order  # the holder's track, per frame
                    if (r := options.wearer(k, f)) is not None}
            near = run(holders=holders)
            held = _pairs_but(near[2], mine) > NEAR_TIE * _pairs_but(pairs, mine)
            if held:
                scale, poses, _ = near
    out = {}
    for pose in poses:  # back from the scaled top map to the top map
        placed = gr.on_top_map(local[pose.frame], pose)
        out[pose.frame] = (placed / scale, (placed - pose.centre) / scale)
    return out, held


def _pairs_but(pairs: Mapping[int, list[tuple[int, int]]], holder: Mapping[int, int]) -> int:
    """Pairs kept over the frames, but those of the holder's top id (``holder``, per frame)."""
    return sum(t != holder.get(f) for f, p in pairs.items() for t, _ in p)


def _cost(a: tuple | None, b: tuple | None, n: tuple[int, int],
          calibration: LogisticCalibration | None, sizes: np.ndarray | None = None,
          wearer: int | None = None) -> np.ndarray:
    """``(n_a, n_b)`` costs of two views' people on the top map, each ``(points, rays)`` (None:
    not on the map this frame; NaN rows: no ground), a positive cost where there is no
    distance; without a calibration :data:`HOR_HOR_COST` everywhere. A top view (its rays
    None) and a handheld view are as far apart as
    :func:`~xvmatch.cues.ground_registration.ray_distances` says (the handheld distance errs
    along its ray; each handheld person read at the top person's height, ``sizes`` ``(n_a,)``),
    two handheld views by the plain distance. ``wearer``: the row of view ``a`` (the top
    view) that holds view ``b``'s camera, whose pairs there get no evidence."""
    if calibration is None:
        return np.full(n, HOR_HOR_COST)
    none = calibration.cost(np.full(n, _FAR * gr.RADIUS))
    if a is None or b is None or not n[0] * n[1]:
        return none
    (pa, ra), (pb, rb) = a, b
    if ra is None and rb is not None:
        d = gr.ray_distances(pa, pb, rb, sizes)
    else:
        d = np.hypot(*(pa[:, None, :] - pb[None, :, :]).transpose(2, 0, 1))
    if wearer is not None:  # the holder is not in their own camera's view
        d[wearer] = np.nan
    return np.where(np.isfinite(d), calibration.cost(np.minimum(d, _FAR * gr.RADIUS)), none)


def ground_problems(views: Sequence[Mapping], frames: Sequence[int],
                    calibration: PeopleCalibration, options: MultiGroundOptions,
                    tracks: Sequence[Mapping[int, int]] | None = None,
                    tops: TopMap | None = None, kept: list[bool | None] | None = None
                    ) -> dict[int, FrameProblem]:
    """The :class:`FrameProblem` of every frame of ``frames`` (module docstring).

    Args:
        views: per view, top first, ``{frame: record}`` with ``ids`` and ``boxes``, in one
            timing.
        frames: the frames to build.
        calibration: the top camera's, from its people (:func:`oblique_top`).
        options: the handheld views' image sizes and fields of view (``auto``: chosen here,
            :func:`choose_lenses`, unsaid), the frame rate.
        tracks: per view ``{row id: track id}`` (video mode): the top map's motion is then
            taken out of each registration and its map scale chosen along the tracks
            (:func:`_registered`).
        tops: the top view's people on its map for ``frames`` (:func:`top_map`, with the top
            view's ``tracks``), when already built.
        kept: a list to be given, per handheld view, whether its run near its holder was kept
            (:func:`_registered`; :func:`holders_note`).
    """
    if len(options.hor_sizes) != len(views) - 1:
        raise ValueError(f"MultiGroundOptions.hor_sizes: one per handheld view "
                         f"({len(views) - 1}), got {len(options.hor_sizes)}")
    top_tracks = None if tracks is None else tracks[0]
    top = top_map(views, frames, calibration, top_tracks) if tops is None else tops
    options = _with_lenses(views, frames, calibration, options, top)[0]
    tops, heights = top.points, top.sizes
    runs = [_registered(views, k, tops, options, tracks, heights, top.sights, top.spread)
            for k in range(1, len(views))]
    if kept is not None:
        kept.extend(held for _, held in runs)
    placed = [{f: (p, None) for f, p in tops.items() if len(p)}, *(r for r, _ in runs)]
    problems = {}
    for f in frames:
        sizes = tuple(len(_boxes(v.get(f))) for v in views)
        costs = {(a, b): _cost(placed[a].get(f), placed[b].get(f), (sizes[a], sizes[b]),
                               TOP_HOR if a == 0 else HOR_HOR, heights.get(f) if a == 0 else None,
                               options.wearer(b, f) if a == 0 else None)
                 for a, b in view_pairs(len(views))}
        problems[f] = FrameProblem(sizes, costs, dict.fromkeys(costs, 0.0))
    return problems


def run_multi_ground(views: Sequence[Mapping], offsets: Sequence[int],
                     calibration: PeopleCalibration, options: MultiGroundOptions,
                     people: PeopleOptions, tracks: Sequence[Mapping[int, int]] | None = None,
                     note: Callable[[str], object] | None = None) -> MultiEgoRun:
    """Person ids for every box of ``views`` (top first, each in its own file's timing):
    re-timed by ``offsets`` (top frame ``t + N_k`` shows the moment of handheld view ``k``'s
    frame ``t``), joined on the top view's ground map (:func:`ground_problems`) and solved as
    the nadir path solves (:func:`~xvmatch.inference.views.multi_view_people.assign_people`);
    with ``tracks`` (per view ``{row id: track id}``) in video mode
    (:func:`~xvmatch.inference.views.multi_ego_video.video_people`, :data:`VIDEO_KEEP_FREE`).
    With ``options.hor_hfov_deg`` ``auto`` the lenses are chosen first (:func:`choose_lenses`)
    and told to ``note`` in one line (:func:`lenses_note`); with ``options.fps`` ``auto``, the
    frame rate likewise (:func:`~xvmatch.inference.matching.frame_rate.frame_rate_note`); what
    the top view was read as, once its tilt is read, likewise (:func:`~xvmatch.inference.
    matching.ground_association.top_summary`)."""
    aligned, shifts = align_frames(views, offsets) if any(offsets) else (list(views), [0])
    if options.wearers is not None and shifts[0]:  # the holders' rows, in the views' timing
        options = replace(options, wearers=tuple(
            None if rows is None else {f + shifts[0]: r for f, r in rows.items()}
            for rows in options.wearers))
    frames = sorted(set().union(*aligned))
    top_tracks = None if tracks is None else tracks[0]
    if options.fps == AUTO_FPS:  # the rate from the clip's one fit, then the map at that rate
        first = top_map(aligned, frames, calibration, top_tracks)
        rate = top_frame_rate(aligned[0], calibration, table=first.walkers)
        options = replace(options, fps=rate.fps, slack=rate.slack, lens_slack=rate.lens_slack)
        if note is not None:
            note(frame_rate_note(rate))
    top = top_map(aligned, frames, calibration, top_tracks, options.fps)  # lenses, problems
    if note is not None:  # its tilt's spread measured for a steady camera only
        note(top_summary(calibration if top.tilt else measure_spread(calibration), top.tilt,
                         REGISTERED))
    options, lenses = _with_lenses(aligned, frames, calibration, options, top, tracks)
    if lenses and note is not None:
        note(lenses_note(lenses))
    kept: list[bool | None] = []
    problems = ground_problems(aligned, frames, calibration, options, tracks, top, kept)
    if options.wearers is not None and note is not None:
        note(holders_note(aligned, top.points, options, kept))
    if tracks is not None:
        from xvmatch.inference.views.multi_ego_video import video_people

        found = video_people(aligned, problems, frames, tracks, people, VIDEO_KEEP_FREE)
        return MultiEgoRun(found, frames, None, None)
    return MultiEgoRun(assign_people(aligned, problems, frames, people), frames, None, None)
