"""Association through the two views' ground maps, for a top camera that is not a nadir drone
(issue 67): the typed run behind ``associate --top-view oblique`` (and ``auto`` when the top
view's boxes say it is oblique).

1. The top camera is calibrated from its people
   (:func:`~xvmatch.geometry.people_calibration.calibrate_from_people`, a loose fit rather than
   none), which puts the top view's people on a metric ground map; a camera whose tilt changes
   over the clip (a gimbal) is read with a tilt per window
   (:func:`~xvmatch.geometry.tilting_camera.fit_tilt_track`, :func:`tilting_top`), each frame
   mapped through its own.
2. The horizontal view's people go on its own ground map (distance from box height, bearing
   from column), and its pose on the top map is registered frame by frame and chosen over time
   (:func:`xvmatch.cues.ground_registration.register_with_scale`: the top map tried at a few
   scales, as the two maps' metres are two estimates that can disagree by a third); pairs by
   Hungarian on the ground distances. Each top person's height is read from their boxes
   through the calibration (:func:`top_sizes`), and a horizontal person compared with them is
   read at that height: a distance from a box height otherwise errs by the spread of people's
   heights (+-13 %, 2 m at 15 m). A pose that puts a horizontal person nobody explains where
   the top camera would see them pays for it (:func:`top_sights`; on a small shared crowd a
   pose with two people swapped explains as many); in video mode the run without that price
   is kept where it keeps more pairs along the tracks (:func:`fewer_sights`).
3. With each view's own track ids (video mode), the top map's own motion (a drifting, turning
   drone) is taken out of the registration's jumps
   (:func:`~xvmatch.cues.ground_registration.map_motion`), the pairs are made consistent
   over the clip (:func:`~xvmatch.inference.linking.pair_consensus.tracklet_consensus`), and
   the map scale kept is the one whose run keeps the most pairs along the tracks
   (:func:`register_and_pair`; the registration's score totals tell it weakly: on a shallow
   tilting render, 0 of 40 pairs right at the scale they kept, 105 of 105 at 1.3), of those
   whose score total is not far below scale 1's (:func:`scale_along_tracks`: standing
   people's pairs hold along the tracks under a wrong pose too). The run
   registered on the handheld boxes no border cuts, every box paired under its poses, replaces
   it where it keeps more than a near tie (:func:`_whole_boxes_run`: a close passer-by cut by
   the bottom edge can hold a wrong pose).

With the holder's top-view id (``camera_id``, ``--camera-id``) their pairs are dropped (they
are not in their own camera's view; they stay among the top people the registration weighs, as
a wrong pose facing them sees them unexplained), and in video mode the whole run is made again
with the camera sought within :data:`~xvmatch.cues.ground_registration.HOLDER_RADIUS` of where
the top view sees them, kept where its pairs hold along the tracks more than a near tie more:
the holder's point strays from where the handheld people put the camera by up to metres, so it
is a candidate, not a given.

``--top-view auto`` takes the calibration's kind: nadir (today's search and learned matcher,
which read the top image as the ground) or oblique (this run).

With ``hor_hfov_deg="auto"`` (``--hor-hfov auto``, the commands' default; these options keep
70 degrees unless told) the handheld camera's field of view is chosen from the clip's people:
in video mode the whole run is made with each candidate lens and the one whose pairs hold
along the tracks most is kept (:func:`~xvmatch.cues.hor_lens.pick_along_tracks`); frame by
frame, before the registration (:func:`~xvmatch.cues.hor_lens.choose_hor_hfov`: 70 unless a
wider lens pairs clearly more people, in all and above chance).

With ``fps="auto"`` (``--fps auto``, the commands' default) the frame numbers' rate is 30 a
second unless the top view's walkers say otherwise
(:func:`~xvmatch.inference.matching.frame_rate.frame_rate_from_walkers`: a file of every 10th
frame numbered 1, 2, 3); a rate read so is registered with twice the free walk and turn
(:attr:`~xvmatch.inference.matching.frame_rate.FrameRate.slack`), as it reads too high more
often than too low; where no walker tells a rate, ten times (the file may be numbered 1, 2, 3).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from functools import partial

import numpy as np

from xvmatch.cues import ground_registration as gr
from xvmatch.cues.hor_lens import (
    HFOV_CANDIDATES,
    MIN_MEASURED_PEOPLE,
    MIN_PEOPLE,
    MIN_REMEASURE_DEG,
    NEAR_TIE,
    LensChoice,
    choose_hor_hfov,
    implied_fit,
    pick_along_tracks,
)
from xvmatch.formats.mot_boxes import stack_frames
from xvmatch.geometry.people_calibration import (
    PRIOR_HFOV_DEG,
    PeopleCalibration,
    calibrate_from_people,
    cut_at_bottom,
    measure_spread,
)
from xvmatch.geometry.tilting_camera import WINDOW_S, TiltTrack, fit_tilt_track
from xvmatch.inference.linking.pair_consensus import consistent_pairs
from xvmatch.inference.linking.tracklets import box_track_ids
from xvmatch.inference.matching.frame_rate import (
    PRIOR_FPS,
    FrameRate,
    frame_rate_from_walkers,
)

__all__ = [
    "AUTO_FPS",
    "AUTO_HFOV",
    "FIXES_LENS",
    "PRIOR_FPS",
    "SIZE_RANGE",
    "TOP_VIEWS",
    "GroundAssociation",
    "GroundAssociationOptions",
    "LensRuns",
    "Registered",
    "choose_along_tracks",
    "fewer_sights",
    "holder_note",
    "lens_note",
    "miss_spread",
    "oblique_note",
    "register_and_pair",
    "replacing",
    "run_along_tracks",
    "run_ground_association",
    "run_top_view",
    "scale_along_tracks",
    "strays_more",
    "tied_with",
    "tilting_top",
    "top_calibration",
    "top_frame_rate",
    "top_ground_points",
    "top_sizes",
    "top_summary",
]

TOP_VIEWS = ("auto", "nadir", "oblique")
"""``--top-view``: let the top view's boxes decide, or force a nadir or an oblique camera."""

AUTO_HFOV = "auto"
"""``--hor-hfov auto``: the handheld field of view chosen from the people
(:func:`~xvmatch.cues.hor_lens.choose_hor_hfov`)."""

AUTO_FPS = "auto"
"""``--fps auto``: 30 a second unless the top view's walkers say otherwise
(:func:`top_frame_rate`)."""

@dataclass(frozen=True)
class GroundAssociationOptions:
    """What the run needs besides the boxes.

    Attributes:
        top_size: the top view's image size (width, height).
        hor_size: the horizontal view's image size.
        hor_hfov_deg: the horizontal camera's field of view, degrees (70: a phone's, a
            drone's), or :data:`AUTO_HFOV`: chosen from the people
            (:func:`~xvmatch.cues.hor_lens.choose_hor_hfov`).
        fps: frames per second of the frame numbers (the registration's pace over time), or
            :data:`AUTO_FPS`: from the top view's walkers (:func:`top_frame_rate`).
        consensus: video mode: each view's track ids are used, to make the pairs consistent
            over the clip and to take the top map's own motion out of the registration.
        seed: seed of the calibration's resampling.
        top_sizes: read each top person's height from their boxes (:func:`top_sizes`) and
            each horizontal person's distance at their partner's height; False: everyone
            of the crowd's height (before; a benchmark's comparison).
        workers: processes that run the candidate lenses' whole runs side by side (``auto``
            in video mode, :func:`choose_along_tracks`); the same result for any number.
        camera_id: the top-view id of the horizontal camera's holder (``--camera-id``), or
            None: their pairs are dropped (not in their own camera's view), and in video mode
            the run with the camera sought near where the top view sees them
            (:data:`~xvmatch.cues.ground_registration.HOLDER_RADIUS`) is kept where its pairs
            hold along the tracks more than a near tie more (:func:`run_ground_association`).
    """

    top_size: tuple[int, int]
    hor_size: tuple[int, int]
    hor_hfov_deg: float | str = PRIOR_HFOV_DEG
    fps: float | str = PRIOR_FPS
    consensus: bool = True
    seed: int = 0
    top_sizes: bool = True
    workers: int = 1
    camera_id: int | None = None

    def __post_init__(self) -> None:
        if isinstance(self.hor_hfov_deg, str) and self.hor_hfov_deg != AUTO_HFOV:
            raise ValueError(f"hor_hfov_deg must be degrees or {AUTO_HFOV!r}, got "
                             f"{self.hor_hfov_deg!r}")
        if isinstance(self.fps, str) and self.fps != AUTO_FPS:
            raise ValueError(f"fps must be frames a second or {AUTO_FPS!r}, got {self.fps!r}")
        if int(self.workers) < 1:
            raise ValueError(f"workers must be at least 1, got {self.workers}")


@dataclass(frozen=True)
class GroundAssociation:
    """The run's result: ``pairs`` ``{frame: [(top id, hor id), ...]}``, the top camera's
    calibration, the horizontal camera's pose per frame (on the top map scaled by ``scale``,
    :func:`~xvmatch.cues.ground_registration.register_with_scale`), and one line saying what
    was assumed; with ``--hor-hfov auto``, the lens chosen (``lens``, its line
    :func:`lens_note`), else None; with ``fps`` ``auto``, the frame rate taken
    (:func:`~xvmatch.inference.matching.frame_rate.frame_rate_note`), else None; ``tilt``:
    the top camera's tilt per window where it reads as tilting
    (:mod:`~xvmatch.geometry.tilting_camera`; each frame mapped through its own), else None."""

    pairs: dict[int, list[tuple[int, int]]]
    calibration: PeopleCalibration
    poses: list[gr.FramePose]
    summary: str
    scale: float = 1.0
    lens: LensChoice | None = None
    frame_rate: FrameRate | None = None
    tilt: TiltTrack | None = None


def top_calibration(top: Mapping, top_size: tuple[int, int], seed: int = 0,
                    name: str = "the top view", tracks: bool = True,
                    spread: bool | str = True) -> PeopleCalibration:
    """The top camera from its people, loose rather than refused (see the module docstring);
    raises :class:`~xvmatch.geometry.people_calibration.CalibrationError` only for too few
    boxes. Each person followed gives a height of their own: ``tracks``, by the view's own
    track ids (video mode); False (frame mode), by its boxes linked by IoU
    (:func:`~xvmatch.inference.linking.tracklets.box_track_ids`), the ids unread. ``spread``:
    the fit's spread over resamples measured (True), not (False) or left for
    :func:`~xvmatch.geometry.people_calibration.measure_spread` (``"later"``)."""
    frames, ids, boxes = stack_frames(top)
    return calibrate_from_people(frames, boxes, top_size,
                                 ids=ids if tracks else box_track_ids(top), seed=seed,
                                 name=name, strict=False, spread=spread)


def top_frame_rate(top: Mapping, calib: PeopleCalibration, tracks: bool = True,
                   prior: float = PRIOR_FPS,
                   table: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> FrameRate:
    """The frame rate of the top view's frame numbers from how fast its people walk on its
    ground map (:func:`~xvmatch.inference.matching.frame_rate.frame_rate_from_walkers`), each
    followed by the view's track ids (``tracks``, video mode) or by its boxes linked by IoU;
    ``table``: the view already stacked and mapped, ``(frames, ids, ground points)`` in
    :func:`~xvmatch.formats.mot_boxes.stack_frames` order (with the tracks to follow for ids,
    ``tracks`` True)."""
    if table is None:
        frames, ids, boxes = stack_frames(top)
        table = (frames, ids, top_ground_points(boxes, calib))
    frames, ids, ground = table
    return frame_rate_from_walkers(frames, ids if tracks else box_track_ids(top), ground, prior)


SIZE_RANGE = (0.85, 1.15)
"""Bounds of a top person's height over the crowd's as :func:`top_sizes` reads it: people are
1.5-1.95 m tall, about 1.72 times 0.87-1.13; a box cut by a border or a nearer person reads
beyond, and its person is read as no taller or shorter than these."""


def _per_frame(frames: np.ndarray, calib: PeopleCalibration, tilt: TiltTrack | None
               ) -> Iterator[tuple[PeopleCalibration, np.ndarray]]:
    """``(calibration, rows)`` for each of ``frames``' distinct frames, through its own tilt
    (``tilt``), or once for all rows (None)."""
    if tilt is None:
        yield calib, np.arange(len(frames))
        return
    order = np.argsort(frames, kind="stable")
    starts = np.flatnonzero(np.r_[True, frames[order][1:] != frames[order][:-1]])
    calibs = tilt.calibrations(calib, frames)
    for rows in np.split(order, starts[1:]):
        yield calibs[int(frames[rows[0]])], rows


def top_sizes(frames: np.ndarray, boxes: np.ndarray, tracks: np.ndarray,
              calib: PeopleCalibration, tilt: TiltTrack | None = None) -> np.ndarray:
    """``(N,)`` each top-view box's person's height over the crowd's, the boxes ``(N, 4)`` and
    their frames ``(N,)`` as :func:`~xvmatch.formats.mot_boxes.stack_frames` gives them (who
    stands behind whom is read per frame): each box's height read through the
    calibration (:meth:`~xvmatch.geometry.people_calibration.PeopleCalibration.person_heights`),
    the median along its track (``tracks`` ``(N,)``, the boxes' track numbers) over the median of
    every box read, within :data:`SIZE_RANGE`, rounded to 4 decimals; 1 for a track none of
    whose boxes tells (a nadir view, people seen steeply from above, boxes cut or hidden). A
    horizontal person read at their partner's height lands where the partner stands
    (:func:`~xvmatch.cues.ground_registration.pose_hypotheses`). ``tilt``: each frame read
    through its own tilt (a tilting camera)."""
    tracks = np.asarray(tracks).reshape(-1)
    sizes = np.ones(len(tracks))
    frames = np.asarray(frames).reshape(-1)
    boxes = np.asarray(boxes, float).reshape(-1, 4)
    read = np.full(len(tracks), np.nan)
    for c, rows in _per_frame(frames, calib, tilt):
        read[rows] = c.person_heights(frames[rows], boxes[rows])
    if not np.isfinite(read).any():
        return sizes
    crowd = float(np.nanmedian(read))
    order = np.argsort(tracks, kind="stable")
    starts = np.flatnonzero(np.r_[True, tracks[order][1:] != tracks[order][:-1]])
    for rows in np.split(order, starts[1:]):
        values = read[rows][np.isfinite(read[rows])]
        if len(values):
            sizes[rows] = np.clip(np.median(values) / crowd, *SIZE_RANGE)
    return np.round(sizes, 4)


def top_ground_points(boxes: np.ndarray, calib: PeopleCalibration,
                      sizes: np.ndarray | None = None, frames: np.ndarray | None = None,
                      tilt: TiltTrack | None = None) -> np.ndarray:
    """The top view's people ``(N, 2)`` on its ground map (metres), from their boxes'
    ``(N, 4)`` foot points through the calibration, or, for a box cut by the image's bottom
    edge, from its top at its person's height (``sizes`` ``(N,)``, :func:`top_sizes`;
    :meth:`~xvmatch.geometry.people_calibration.PeopleCalibration.standing_points`); NaN where
    a foot has no ground (above the horizon). ``tilt`` (with each box's ``frames``): each
    frame mapped through its own tilt (a tilting camera)."""
    boxes = np.asarray(boxes, float).reshape(-1, 4)
    if tilt is None or not len(boxes):
        return calib.standing_points(boxes, sizes) if len(boxes) else np.zeros((0, 2))
    frames = np.asarray(frames).reshape(-1)
    out = np.full((len(boxes), 2), np.nan)
    for c, rows in _per_frame(frames, calib, tilt):
        out[rows] = c.standing_points(boxes[rows], None if sizes is None else sizes[rows])
    return out


def top_sights(order: Sequence[int], ground: np.ndarray, calib: PeopleCalibration,
               tilt: TiltTrack | None = None) -> list[gr.TopSight]:
    """Per frame of ``order``, where the top camera sees people on its map
    (:class:`~xvmatch.cues.ground_registration.TopSight`): out as far as any of its people
    ``ground`` ``(N, 2)`` stand over the clip; through each frame's own tilt (``tilt``)."""
    finite = np.isfinite(ground).all(axis=1)
    reach = float(np.hypot(*ground[finite].T).max()) if finite.any() else 0.0
    if tilt is None:
        return [gr.TopSight.of(calib.camera, reach)] * len(order)
    calibs = tilt.calibrations(calib, np.asarray(order))
    return [gr.TopSight.of(calibs[int(f)].camera, reach) for f in order]


def tilting_top(frames: np.ndarray, tracks: np.ndarray, boxes: np.ndarray,
                calib: PeopleCalibration, fps: float) -> TiltTrack | None:
    """The top camera's tilt per window (:func:`~xvmatch.geometry.tilting_camera.fit_tilt_track`,
    the view stacked: each box's frame, track and box) where an oblique camera reads as
    tilting over the clip; None for a nadir or a steady camera, whose one fit ``calib``
    stands (and starts the windows' fit: a steady camera is told at a twentieth of its cost)."""
    if calib.kind != "oblique":
        return None
    track = fit_tilt_track(frames, tracks, boxes, (calib.width, calib.height), fps, calib)
    return track if track is not None and track.tilting else None


def top_summary(calib: PeopleCalibration, tilt: TiltTrack | None = None,
                registered: str = "the horizontal camera registered on its ground map frame by "
                                  "frame") -> str:
    """The one line saying what the top view was read as, once its tilt is known: nadir; a
    steady oblique camera's tilt with its spread (:func:`oblique_note`); a tilting one's first
    and last tilts (its one fit's spread is not its tilt's, and is not said); then how the
    other views were ``registered``."""
    if calib.kind == "nadir":
        return "top view: looking straight down (its boxes are as wide as tall)"
    if tilt is not None:
        return (f"top view: oblique, tilting from {tilt.tilts_deg[0]:.0f} to "
                f"{tilt.tilts_deg[-1]:.0f} degrees over the clip, about "
                f"{tilt.camera_height:.0f} m up (from its people, a tilt per "
                f"{WINDOW_S:g} s); {registered}")
    return f"{oblique_note(calib)}; {registered}"


def holder_note(camera_id: int, holders: Sequence[np.ndarray | None], video: bool,
                held: tuple | None) -> str:
    """What ``--camera-id`` did on the ground path: the holder is nobody's partner; in video
    mode (``video``) the camera was also sought within
    :data:`~xvmatch.cues.ground_registration.HOLDER_RADIUS` of where the top view sees them
    (``holders``, per frame, or None), that run kept (``held`` not None) where its pairs held
    along the tracks more than a near tie more than the run seeking it anywhere."""
    seen = sum(h is not None for h in holders)
    out = f"--camera-id {camera_id}: left out of the pairs (not in their own camera's view)"
    if not video:
        return out + ("; frame by frame the handheld camera is sought anywhere (in video mode "
                      "also near them)")
    if not seen:
        return out + "; not on the top view's ground map on any frame paired"
    near = (f"the handheld camera sought within {gr.HOLDER_RADIUS:g} m of where the top view "
            f"sees them ({seen} of {len(holders)} frames)")
    if held is not None:
        return f"{out}; {near}: its pairs hold along the tracks more than anywhere's"
    return f"{out}; {near} kept fewer pairs along the tracks than sought anywhere"


def oblique_note(calib: PeopleCalibration) -> str:
    """What a top view calibrated from its people is: its tilt, the tilt's spread (to a tenth
    under a degree: "+- 0" reads as no measure; none where not measured: a clip of one stretch)
    and its height."""
    spread = calib.tilt_std_deg
    measured = "" if np.isnan(spread) else f" +- {spread:.{1 if spread < 0.95 else 0}f}"
    return (f"top view: oblique, tilt {calib.tilt_deg:.0f}{measured} degrees, about "
            f"{calib.camera_height:.0f} m up (from its people)")


FIXES_LENS = "--hor-hfov DEG fixes it"
"""What a lens note says of a lens chosen: not "give it if known", as the lens chosen is the one
the pairs hold best under and takes up other errors of the handheld map (19 render sets: 97.7
CVIDF1 with the lens chosen, 96.9 with the true lens given; docs/notes/oblique_top_camera.md,
fifty-second session). Where the prior was taken, too few people to choose, it says to give it."""


def lens_note(choice: LensChoice, view: str = "handheld lens") -> str:
    """The line saying which lens ``--hor-hfov auto`` chose (``view``: whose)."""
    if choice.measured_from is not None:
        return (f"{view}: {choice.hfov_deg:.0f} degrees, chosen from its people (measured "
                f"from the pairs of a {choice.measured_from:.0f}-degree run; {FIXES_LENS})")
    if choice.why_prior is None:
        return f"{view}: {choice.hfov_deg:.0f} degrees, chosen from its people ({FIXES_LENS})"
    return (f"{view}: {choice.hfov_deg:.0f} degrees, the prior ({choice.why_prior}; give "
            "--hor-hfov DEG if known)")


def miss_spread(calib: PeopleCalibration) -> float:
    """How far off, in parts of their distance from the handheld camera, a top person still
    counts as explained to the registration, which then also hides those behind a nearer
    handheld person (:func:`~xvmatch.cues.ground_registration.pose_hypotheses`): the spread of
    a distance read from a box (:data:`~xvmatch.cues.ground_registration.RANGE_SPREAD`) for an
    oblique top view; 0 (the round radius alone, nobody hidden) for a nadir one, forced
    through the ground maps (``--top-view oblique``), where either cost the real CVMHAT boxes
    a person's track and the spread a rendered three-view nadir scene 0.94 -> 0.52 pair F1
    (docs/notes/oblique_top_camera.md)."""
    return gr.RANGE_SPREAD if calib.kind == "oblique" else 0.0


def run_ground_association(top: Mapping, hor: Mapping, options: GroundAssociationOptions,
                           frames: list[int] | None = None,
                           calibration: PeopleCalibration | None = None,
                           top_points: np.ndarray | None = None) -> GroundAssociation:
    """Associate every frame of ``frames`` (default: those with boxes in both views) through the
    ground maps (module docstring).

    Args:
        top, hor: ``{frame: record}`` with ``ids`` and ``boxes`` (``FrameBoxes``).
        options: image sizes, the horizontal field of view (or ``auto``: in video mode the
            candidate whose whole run keeps the most pairs along the tracks,
            :func:`~xvmatch.cues.hor_lens.pick_along_tracks`; frame by frame chosen first,
            :func:`~xvmatch.cues.hor_lens.choose_hor_hfov`), the frame rate.
        frames: the frames to associate.
        calibration: the top camera's, when already estimated (:func:`top_calibration`).
        top_points: the top view's people on its ground map ``(N, 2)``, in
            :func:`~xvmatch.formats.mot_boxes.stack_frames` order, where they are mapped
            otherwise than through ``calibration`` (a benchmark's true camera of each frame);
            ``calibration`` still reads their heights (:func:`top_sizes`).
    """
    calib = calibration or top_calibration(top, options.top_size, options.seed,
                                           tracks=options.consensus)
    order = sorted(set(frames) if frames is not None else set(top) & set(hor))
    spread = miss_spread(calib)
    # The top view stacked and mapped once, for the frames, the sizes and the rate.
    top_frames, top_ids, top_boxes = stack_frames(top)
    starts = np.searchsorted(top_frames, order, side="left")
    ends = np.searchsorted(top_frames, order, side="right")
    tracks = top_ids if options.consensus else box_track_ids(top)  # frame mode: by IoU
    read = (top_sizes(top_frames, top_boxes, tracks, calib) if options.top_sizes
            else np.ones(len(top_frames)))
    if top_points is None:
        top_ground = top_ground_points(top_boxes, calib, read)
    else:
        top_ground = np.asarray(top_points, float)
        if top_ground.shape != (len(top_boxes), 2):
            raise ValueError(f"top_points must be ({len(top_boxes)}, 2), one row per top-view "
                             f"box, got {top_ground.shape}")
    rate = (top_frame_rate(top, calib, table=(top_frames, tracks, top_ground))  # followed once
            if options.fps == AUTO_FPS else None)
    fps = float(options.fps) if rate is None else rate.fps
    slack = 1.0 if rate is None else rate.slack  # a rate read, or none told: a looser walk
    lens_slack = 1.0 if rate is None else rate.lens_slack  # none told: the lens as at 1
    tilt = None if top_points is not None else tilting_top(top_frames, tracks, top_boxes,
                                                             calib, fps)
    if tilt is not None:  # a gimbal tilting over the clip: each frame through its own tilt
        if options.top_sizes:
            read = top_sizes(top_frames, top_boxes, tracks, calib, tilt)
        top_ground = top_ground_points(top_boxes, calib, read, top_frames, tilt)
    sights = None if top_points is not None else top_sights(order, top_ground, calib, tilt)
    tops, boxes, sizes = [], [], []
    holders: list[np.ndarray | None] | None = None if options.camera_id is None else []
    for f, a, b in zip(order, starts, ends, strict=True):
        h = hor.get(f)
        hb = np.zeros((0, 4)) if h is None else np.asarray(h.boxes, float).reshape(-1, 4)
        h_ids = np.zeros(0, np.int64) if h is None else np.asarray(h.ids)
        ground, t_ids = top_ground[a:b], top_ids[a:b]
        ok = np.isfinite(ground).all(axis=1)
        if holders is not None:  # the holder: about where the camera stands
            wearer = (t_ids == options.camera_id) & ok
            holders.append(ground[wearer][0] if wearer.any() else None)
        tops.append((ground[ok], t_ids[ok]))
        sizes.append(read[a:b][ok])
        boxes.append((hb, h_ids))

    run = partial(_lens_and_pairs, order, tops, boxes, sizes, options, fps,
                  gr.HandheldReading.of([b for b, _ in boxes], options.hor_size), (top, hor),
                  sights, spread, (lens_slack, slack))
    lens, (scale, poses, pairs) = run(None)
    if tilt is None:  # its tilt's spread told (a tilting camera's one tilt is not)
        calib = measure_spread(calib)
    summary, held = top_summary(calib, tilt), None
    if options.camera_id is not None:  # the holder is not in their own camera's view
        pairs = _without(pairs, options.camera_id)
    if holders is not None and options.consensus and any(h is not None for h in holders):
        # near the holder, kept where its pairs hold along the tracks more than a near tie
        held = run(holders)
        near = _without(held[1][2], options.camera_id)
        if _count(near)[0] > NEAR_TIE * _count(pairs)[0]:
            lens, (scale, poses, pairs) = held[0], (*held[1][:2], near)
        else:
            held = None
    if holders is not None:
        summary += f"; {holder_note(options.camera_id, holders, options.consensus, held)}"
    return GroundAssociation(pairs=pairs, calibration=calib, poses=poses,
                             summary=summary, scale=scale, lens=lens,
                             frame_rate=rate, tilt=tilt)


Registered = tuple[float, list[gr.FramePose], dict[int, list[tuple[int, int]]]]
"""A registration's top map scale, its poses and the pairs under them."""


def _without(pairs: Mapping[int, list[tuple[int, int]]], top_id: int
             ) -> dict[int, list[tuple[int, int]]]:
    """``pairs`` without those of top person ``top_id`` (the handheld camera's holder, not in
    its view): dropped after the run, as the holder stays among the top people the
    registration weighs (a wrong pose facing them sees them unexplained; left out, on a
    rendered nadir clip a pose turned half round won, 0.553 -> 0.000 pair F1)."""
    return {f: [(t, h) for t, h in p if t != top_id] for f, p in pairs.items()}


def _lens_and_pairs(order: list[int], tops: list, boxes: list, sizes: list,
                    options: GroundAssociationOptions, fps: float, reading: gr.HandheldReading,
                    views: tuple[Mapping, Mapping], sights: list[gr.TopSight] | None,
                    spread: float, slacks: tuple[float, float],
                    holders: list[np.ndarray | None] | None
                    ) -> tuple[LensChoice | None, Registered]:
    """:func:`run_ground_association`'s lens (chosen where ``auto``, else None) and run, with
    the camera sought near its ``holders`` or anywhere (None): in video mode
    (``options.consensus``) each lens's whole run (:func:`choose_along_tracks`), else the lens
    chosen first (:func:`~xvmatch.cues.hor_lens.choose_hor_hfov`); then the run on the boxes
    no border cuts where it keeps more than a near tie (:func:`_whole_boxes_run`). ``slacks``:
    the registration's free walk and turn for the lens choice and for the runs
    (:attr:`~xvmatch.inference.matching.frame_rate.FrameRate.lens_slack`, ``slack``); where
    they differ, the chosen lens's run is made again. Other arguments as
    :func:`register_and_pair`'s."""
    lens, hfov = None, options.hor_hfov_deg
    lens_slack, slack = slacks
    if hfov == AUTO_HFOV and options.consensus:  # each lens's whole run, along the tracks
        lens, (scale, poses, pairs) = choose_along_tracks(order, tops, boxes, sizes, fps,
                                                          reading, views, sights, spread,
                                                          lens_slack, options.workers, holders)
        if lens_slack != slack:
            scale, poses, pairs = register_and_pair(order, tops, boxes, sizes, lens.hfov_deg,
                                                    fps, reading, views, sights, spread, slack,
                                                    holders)
    else:
        if hfov == AUTO_HFOV:
            lens = choose_hor_hfov(order, [p for p, _ in tops], [b for b, _ in boxes],
                                   options.hor_size, fps, sizes=sizes, spread=spread,
                                   slack=lens_slack, holders=holders)
            hfov = lens.hfov_deg
        scale, poses, pairs = register_and_pair(order, tops, boxes, sizes, hfov, fps, reading,
                                                views if options.consensus else None, sights,
                                                spread, slack, holders)
    if options.consensus:  # the run on the boxes no border cuts, where it keeps clearly more
        whole = _whole_boxes_run(order, tops, boxes, sizes, hfov if lens is None else
                                 lens.hfov_deg, fps, reading, views, sights, spread, slack,
                                 holders)
        if whole is not None and _count(whole[2])[0] > NEAR_TIE * _count(pairs)[0]:
            scale, poses, pairs = whole
    return lens, (scale, poses, pairs)


def choose_along_tracks(order: list[int], tops: list, boxes: list, sizes: list, fps: float,
                        reading: gr.HandheldReading, views: tuple[Mapping, Mapping],
                        sights: list[gr.TopSight] | None = None,
                        spread: float = gr.RANGE_SPREAD, slack: float = 1.0, workers: int = 1,
                        holders: list[np.ndarray | None] | None = None
                        ) -> tuple[LensChoice, Registered]:
    """Video mode's ``--hor-hfov auto``: the whole run (the pairs made consistent along the
    tracks, each lens's map scale as :func:`~xvmatch.cues.ground_registration.register_with_scale`
    keeps it) with each candidate lens (:data:`~xvmatch.cues.hor_lens.HFOV_CANDIDATES`), the
    one keeping the most pairs chosen (:func:`~xvmatch.cues.hor_lens.pick_along_tracks`). The
    lens is chosen on runs without the top camera's ``sights``: they steady a wrong lens's
    poses on a small crowd too. Then each lens's run as :func:`register_and_pair` makes it
    (with them, or without them where that keeps more: :func:`fewer_sights`; its map scale
    chosen along the tracks too: the lens is chosen first, as a scale chosen per lens lets a
    wrong lens's run keep more pairs on a small crowd), another lens's run replacing the
    chosen one's where it keeps more than :data:`~xvmatch.cues.hor_lens.NEAR_TIE` times its
    pairs, where its run without them joined :data:`~xvmatch.cues.hor_lens.MIN_PEOPLE` people
    (a 65 degree lens: without the sights 110 degrees kept 122 pair-frames, a third wrong, 70
    kept 51, all right; with them, 130 and 190), and none where the runs without them all keep
    as many pairs, nor where its pairs stray from the lens they imply more than
    :data:`STRAY_RATIO` times as far as the chosen one's (:func:`replacing`). Each compared as
    it would run: with the
    sights alone a 65 degree clip's 60-degree run kept nothing, so every other lens's wrong run
    replaced the one that, without them, kept 200 pair-frames of nine people, right. Then the
    lens each run's pairs imply (:func:`~xvmatch.cues.hor_lens.implied_fit`: a measurement,
    not one of four guesses) is run too where it differs, and kept where its pairs hold along
    the tracks more often (the chosen lens's; another lens's, more than a near tie; the
    choice's ``measured_from`` says so; a tie keeps the candidate: on tilting close drones,
    whose runs kept as many pairs at any lens, the lens measured was up to 54 degrees off).
    But where candidates' runs keep as many pairs as the chosen lens's, or more by no more
    than a near tie (:func:`tied_with`), and nothing replaced it, the lens their pairs imply
    that they fit best is kept where its run keeps as many (:func:`_tie_measured`: several
    measurements, the best taken). The run kept is the one
    :func:`register_and_pair` makes: the same lens, given or chosen, runs the same.
    Arguments as :func:`register_and_pair`'s (``workers``: processes running the candidates'
    runs side by side, :func:`_each_lens`); returns the choice and the chosen lens's run."""
    # each lens's runs with the sights and without, the nearest the prior first: a run of
    # another lens replaces the chosen one's only where it keeps more than a near tie of the
    # best before it, so a tie keeps the lens nearer the prior
    lenses = sorted(HFOV_CANDIDATES, key=lambda h: (abs(h - PRIOR_HFOV_DEG), h))
    each = dict(zip(lenses, _each_lens(partial(
        _lens_runs, order, tops, boxes, sizes, fps=fps, reading=reading, views=views,
        sights=sights, spread=spread, slack=slack, holders=holders), lenses, workers),
        strict=True))
    scales = {h: runs.scale for h, runs in each.items()}
    pairs = {h: runs.pairs for h, runs in each.items()}
    kept, people = _kept(pairs)
    hfov = pick_along_tracks(kept, people)
    choice = LensChoice(hfov, {h: float(n) for h, n in kept.items()}, scales, list(order),
                        along_tracks=True, people=people)
    # each lens's run as register_and_pair makes it (with the sights, or without them where
    # that keeps more), the chosen one's first
    made = {h: each[h].made for h in (hfov, *(h for h in each if h != hfov))}
    made_kept = {h: _count(m[2])[0] for h, m in made.items()}
    implied_by = {source: _implied(order, tops, each[source].scale_runs[0], sizes, source,
                                   made[source][2]) for source in made}
    best = replacing(hfov, kept, people, made_kept, implied_by)
    run, run_kept = made[best], made_kept[best]

    def run_at(lens: float) -> Registered:  # a measured lens's run, as register_and_pair's
        return run_along_tracks(order, tops, _hor_people(boxes, reading, lens), sizes, lens,
                                fps, views, sights, spread, slack, holders)

    measured_from, measured = None, dict(made)
    for source in made:  # then the lens each run's pairs imply, the chosen one's first
        fit = implied_by[source]
        implied = None if fit is None else fit[0]
        if (implied is None or implied in measured or abs(implied - source) < MIN_REMEASURE_DEG
                or any(abs(implied - t) < MIN_REMEASURE_DEG for t in measured if t not in made)):
            continue  # nothing told, a lens already run, or too near to matter
        measured[implied] = run_at(implied)
        kept_here = _count(measured[implied][2])[0]
        # a tie tells nothing; another lens's measurement needs more than a near tie
        if kept_here > run_kept * (1.0 if source == hfov else NEAR_TIE):
            best, measured_from, run, run_kept = implied, source, measured[implied], kept_here
    if best == hfov:  # candidates tied with the chosen lens measure it together
        best, measured_from, run = _tie_measured(
            hfov, run, {h: implied_by[h] for h in tied_with(run_kept, made_kept)},
            measured, run_at)
        run_kept = _count(run[2])[0]
    choice = replace(choice, made={h: float(n) for h, n in made_kept.items()})
    if best != hfov:
        choice = replace(choice, hfov_deg=best, scales={**choice.scales, best: run[0]})
    if measured_from is not None:
        choice = replace(choice, measured_from=measured_from,
                         scores={**choice.scores, best: float(run_kept)},
                         people={**choice.people, best: _count(run[2])[1]})
    return choice, run


def replacing(hfov: float, kept: Mapping[float, int], people: Mapping[float, int],
              made_kept: Mapping[float, int],
              fits: Mapping[float, tuple[float, float] | None] | None = None) -> float:
    """The lens whose run as made (with the top camera's sights) replaces the chosen ``hfov``'s
    in :func:`choose_along_tracks`: in the order of ``made_kept`` (pairs each lens's run as
    made keeps), the first to keep more than :data:`~xvmatch.cues.hor_lens.NEAR_TIE` times the
    best before it whose run without the sights joined
    :data:`~xvmatch.cues.hor_lens.MIN_PEOPLE` people (``kept``, ``people``: those runs' pairs
    and people); none where the runs without the sights all keep as many pairs, so tell no
    lens: on two-person renders with the handheld pitch drifting every lens kept 75-79
    pair-frames without them and 110 degrees' run with them 91-119, all wrong (still drone s0
    and s1, scene 10: 0.000, 1.000 when kept; docs/notes/oblique_top_camera.md). Nor where
    that run's pairs stray from the lens they imply more than :data:`STRAY_RATIO` times as far
    as the chosen lens's run's (``fits``: each run's :func:`~xvmatch.cues.hor_lens.implied_fit`,
    None where it tells nothing; None: not checked): a run that swaps people fits no lens well,
    however many pairs it holds (a standing crowd, a 61-degree lens: 90 degrees' run kept 280
    pair-frames to the others' 238, straying 0.199 to 0.088, and paired 0.155 to 1.000; with
    the boxes moved in their last digits, or another CPU's arithmetic, it kept 238 too)."""
    best = hfov
    if len(set(kept.values())) <= 1:
        return best
    for h, n in made_kept.items():  # more than a near tie, and pairs of two people or more
        # without the sights (which steady any lens's poses)
        if people[h] >= MIN_PEOPLE and n > NEAR_TIE * made_kept[best]:
            best = h
    if fits is not None and best != hfov and strays_more(fits[best], fits[hfov], STRAY_RATIO):
        return hfov
    return best


STRAY_RATIO = 2.0
"""How many times as far from the lens they imply the pairs of a run replacing the chosen
lens's may stray as that run's (:func:`replacing`): on renders a swapping run strayed 2.3
times as far as the right one (its docstring's clip), and a right run of seven people 1.6
times as far as the chosen lens's right run of six (a 114-degree lens, 110 replacing 90)."""


MIN_TIE_TOLD = 3
"""Tied candidates whose pairs must each imply a lens for the best fitting of those lenses to
be tried (:func:`_tie_measured`; with the middle of two told, on renders of a 100-degree lens
with 90 and 110 tied, the lower, 80 degrees, paired 0.69 against 110's 0.83)."""


def tied_with(kept: int, made_kept: Mapping[float, int]) -> list[float]:
    """The lenses whose runs as made keep as many pairs as the chosen lens's (``kept``), or
    more by no more than a near tie (:data:`~xvmatch.cues.hor_lens.NEAR_TIE`), which the
    choice's leaning to the prior beat: no measure of the lens either (:func:`_tie_measured`).
    Renders: a 92-degree lens, 70 chosen with 128 pair-frames, 30 % of them a swap; 90 and
    110 kept 131, all right."""
    return [h for h, n in made_kept.items() if kept <= n <= NEAR_TIE * kept]


def _tie_measured(hfov: float, run: Registered,
                  implied_by: Mapping[float, tuple[float, float] | None],
                  measured: Mapping[float, Registered], make: Callable[[float], Registered]
                  ) -> tuple[float, float | None, Registered]:
    """The lens, where it came from and its run, where candidate lenses' runs keep as many
    pairs as the chosen lens ``hfov``'s (``run``): of the lenses their pairs imply
    (``implied_by``, per tied candidate, ``hfov`` among them: each lens and how far its pairs
    stray from it, :func:`~xvmatch.cues.hor_lens.implied_fit`), the one whose pairs stray
    least, run (from ``measured``, the runs made so far by lens, or ``make``) and kept where
    it keeps as many pairs: the tie says the candidates are no measure, and a run that swaps
    people fits no lens well (renders of an 82-degree lens: the 60 and 70 degree runs swapped
    two of four people and implied 75, straying 0.159; 90's implied 78, straying 0.094, and
    78's run paired all four right; every run kept 133 pair-frames). Where fewer than
    :data:`MIN_TIE_TOLD` lenses are told, or that lens is ``hfov`` or within
    :data:`~xvmatch.cues.hor_lens.MIN_REMEASURE_DEG` of it, the chosen lens and its run."""
    told = sorted((fit[1], fit[0], h) for h, fit in implied_by.items() if fit is not None)
    if len(told) < MIN_TIE_TOLD:
        return hfov, None, run
    _, lens, source = told[0]
    if abs(lens - hfov) < MIN_REMEASURE_DEG:
        return hfov, None, run
    other = measured[lens] if lens in measured else make(lens)
    if _count(other[2])[0] < _count(run[2])[0]:
        return hfov, None, run
    return lens, None if lens in implied_by else source, other  # a tied candidate's own


@dataclass(frozen=True)
class LensRuns:
    """One candidate lens's part of :func:`choose_along_tracks` (:func:`_lens_runs`).

    Attributes:
        scale_runs: its people on the handheld map and its registrations at each map scale,
            with the sights and without (:func:`_scale_runs`).
        scale: the map scale of its run without the sights by the clip's score totals.
        pairs: that run's pairs along the tracks at that scale.
        made: its run as :func:`register_and_pair` makes it (:func:`_made`).
    """

    scale_runs: tuple[list, list]
    scale: float
    pairs: dict[int, list[tuple[int, int]]]
    made: Registered


def _lens_runs(order: list[int], tops: list, boxes: list, sizes: list, hfov: float, fps: float,
               reading: gr.HandheldReading, views: tuple[Mapping, Mapping],
               sights: list[gr.TopSight] | None, spread: float, slack: float,
               holders: list[np.ndarray | None] | None = None) -> LensRuns:
    """One candidate lens's part of :func:`choose_along_tracks`: its :func:`_scale_runs`, the
    map scale of its run without the sights (the last) by the clip's score totals
    (:func:`~xvmatch.cues.ground_registration.margin_scale`) and that run's pairs along the
    tracks, and its run as :func:`register_and_pair` makes it (:func:`_made`)."""
    runs = _scale_runs(order, tops, boxes, sizes, hfov, fps, reading, views, sights, spread,
                       slack, holders)
    hors, plain = runs[0], runs[1][-1]
    scale = gr.margin_scale(plain)
    pairs = _consistent(order, tops, hors, sizes, scale, plain[scale][1], views)
    return LensRuns(runs, scale, pairs, _made(order, tops, runs, sizes, views, hfov))


def _each_lens(run: Callable[[float], object], lenses: list[float], workers: int) -> list:
    """``run(lens)`` for each of ``lenses``, in order: in ``workers`` processes where more than
    one (:func:`~xvmatch.core.worker_pool.worker_pool`; each lens's run is the same
    arithmetic wherever it runs, so the result is the same for any number)."""
    if workers <= 1 or len(lenses) < 2:
        return [run(h) for h in lenses]
    from xvmatch.core.worker_pool import worker_pool

    with worker_pool(min(int(workers), len(lenses))) as pool:
        return list(pool.map(run, lenses))


def _made(order: list[int], tops: list, scale_runs: tuple[list, list], sizes: list,
          views: tuple[Mapping, Mapping], hfov: float) -> Registered:
    """One lens's run along the tracks from its :func:`_scale_runs` (its people and its
    registrations at each map scale, with the sights and without, or the one): as
    :func:`run_along_tracks` makes it, without registering again."""
    hors, by_scale = scale_runs
    run = scale_along_tracks(order, tops, hors, by_scale[0], sizes, views)
    if len(by_scale) == 1:
        return run
    return fewer_sights(run, order, tops, hors, sizes, by_scale[-1], views, hfov)


def _implied(order: list[int], tops: list, hors: list, sizes: list, hfov: float,
             pairs: Mapping[int, list[tuple[int, int]]]) -> tuple[float, float] | None:
    """The lens a run's ``pairs`` imply and how far they stray from it
    (:func:`~xvmatch.cues.hor_lens.implied_fit`), each handheld person read at their top
    partner's height as the run reads them; None where they join fewer than
    :data:`~xvmatch.cues.hor_lens.MIN_MEASURED_PEOPLE` top-view people."""
    if _count(pairs)[1] < MIN_MEASURED_PEOPLE:
        return None
    paired_top, paired_hor = [], []
    for f, (top, t_ids), (hor, h_ids), size in zip(order, tops, hors, sizes, strict=True):
        if len(pairs.get(f, ())) < 2:
            continue
        at_top = {int(t): k for k, t in enumerate(t_ids)}
        at_hor = {int(h): k for k, h in enumerate(h_ids)}
        rows = np.array([at_top[t] for t, _ in pairs[f]])
        paired_top.append(top[rows])
        paired_hor.append(hor[[at_hor[h] for _, h in pairs[f]]] * size[rows, None])
    return implied_fit(hfov, paired_top, paired_hor)


def register_and_pair(order: list[int], tops: list, boxes: list, sizes: list, hfov: float,
                      fps: float, reading: gr.HandheldReading,
                      views: tuple[Mapping, Mapping] | None,
                      sights: list[gr.TopSight] | None = None,
                      spread: float = gr.RANGE_SPREAD, slack: float = 1.0,
                      holders: list[np.ndarray | None] | None = None) -> Registered:
    """The handheld view registered on the top map with a lens of ``hfov`` degrees and each
    frame's pairs under its pose; with ``views`` (the top and horizontal ``{frame: record}``,
    their ids the tracks: video mode) the top map's motion taken out, the pairs made
    consistent along the tracks, and the map scale the one whose run keeps the most pairs
    there (:func:`scale_along_tracks`, scale 1 the prior: the clip's score totals tell the
    scale weakly, :func:`~xvmatch.cues.ground_registration.margin_scale`, and only bar a
    scale far below scale 1's) and, with ``sights``, the run without them where it keeps more
    (:func:`fewer_sights`); frame by frame the scale those totals keep.

    Args:
        order: the frames.
        tops: per frame, the top view's people on its map ``(N, 2)`` and their ids.
        boxes: per frame, the horizontal view's boxes ``(M, 4)`` and their ids.
        sizes: per frame, each top person's height over the crowd's ``(N,)``.
        hfov: the horizontal camera's field of view, degrees.
        fps: frames per second of the frame numbers.
        reading: what the horizontal view's people tell of it, whatever its lens
            (:class:`~xvmatch.cues.ground_registration.HandheldReading`: its image size, their
            width over height, its horizon).
        views: see above; None: frame by frame.
        sights: per frame, where the top camera sees people on its map
            (:class:`~xvmatch.cues.ground_registration.TopSight`, :func:`top_sights`), or None.
        spread: how far off, in parts of their distance, a top person counts as explained
            (:func:`~xvmatch.cues.ground_registration.pose_hypotheses`; :func:`miss_spread`).
        slack: how many times the registration's free walk and turn a second
            (:func:`~xvmatch.cues.ground_registration.register_sequence`; a rate read,
            :attr:`~xvmatch.inference.matching.frame_rate.FrameRate.slack`).
        holders: per frame, where the top view sees the handheld camera's holder on its map
            (``--camera-id``), or None
            (:func:`~xvmatch.cues.ground_registration.register_with_scale`).
    Returns:
        The top map's scale, the poses and ``{frame: [(top id, hor id), ...]}``.
    """
    hors = _hor_people(boxes, reading, hfov)
    if views is not None:
        return run_along_tracks(order, tops, hors, sizes, hfov, fps, views, sights, spread,
                                slack, holders)
    runs = _registrations(order, tops, hors, sizes, hfov, fps, False, sights, spread, slack,
                          holders)
    scale = gr.margin_scale(runs)
    return scale, runs[scale][1], _pairs_under(order, tops, hors, sizes, scale, runs[scale][1])


def _whole_boxes_run(order: list[int], tops: list, boxes: list, sizes: list, hfov: float,
                     fps: float, reading: gr.HandheldReading, views: tuple[Mapping, Mapping],
                     sights: list[gr.TopSight] | None, spread: float, slack: float = 1.0,
                     holders: list[np.ndarray | None] | None = None) -> Registered | None:
    """Video mode's run registered on the handheld boxes no border cuts and paired with every
    box under its poses (None where the bottom edge cuts none): a close passer-by's depth, read
    from a cut box's width, can hold a wrong pose. Arguments as :func:`register_and_pair`'s."""
    cut = [cut_at_bottom(b, reading.image_size[1]) for b, _ in boxes]
    if not any(c.any() for c in cut):
        return None
    hors = _hor_people(boxes, reading, hfov)
    whole = [(q[~c], i[~c]) for (q, i), c in zip(hors, cut, strict=True)]
    by_scale = _by_scale(order, tops, whole, sizes, hfov, fps, True, sights, spread, slack,
                         holders)
    return _made(order, tops, (hors, by_scale), sizes, views, hfov)


def run_along_tracks(order: list[int], tops: list, hors: list, sizes: list, hfov: float,
                     fps: float, views: tuple[Mapping, Mapping],
                     sights: list[gr.TopSight] | None = None,
                     spread: float = gr.RANGE_SPREAD, slack: float = 1.0,
                     holders: list[np.ndarray | None] | None = None) -> Registered:
    """Video mode's run of one lens on the handheld view's people (``hors``, on its map with
    their ids): the map scale along the tracks (:func:`scale_along_tracks`) of the run made
    with the ``sights``, or of the run without them where that keeps more
    (:func:`fewer_sights`). Arguments as :func:`register_and_pair`'s."""
    by_scale = _by_scale(order, tops, hors, sizes, hfov, fps, True, sights, spread, slack,
                         holders)
    return _made(order, tops, (hors, by_scale), sizes, views, hfov)


def fewer_sights(made: Registered, order: list[int], tops: list, hors: list, sizes: list,
                 plain: dict[float, tuple[float, list[gr.FramePose]]],
                 views: tuple[Mapping, Mapping], hfov: float) -> Registered:
    """A run made with the top camera's sights (video mode), or the run without them
    (``plain``: its registration at each map scale without them) where that keeps more pairs
    along the tracks: the sights steady poses, but where the top camera's view of the holder
    misleads them they cost the right ones (a 110-degree run: 69 pair-frames with them, all
    wrong; 152 without, all right). But not the one keeping more where its pairs stray from
    the lens they imply more than :data:`SIGHTS_STRAY_RATIO` times as far as the other's
    (:func:`~xvmatch.cues.hor_lens.implied_fit`; the lens ``hfov``): a run that swaps people
    fits no lens well. A tie keeps the run as made (the stray alone decided ties on the
    renders as often wrongly as rightly). Arguments as :func:`scale_along_tracks`'."""
    other = scale_along_tracks(order, tops, hors, plain, sizes, views)
    kept, kept_other = _count(made[2])[0], _count(other[2])[0]
    if kept == kept_other:  # a tie keeps the run as made
        return made
    more, fewer = (other, made) if kept_other > kept else (made, other)
    fits = [_implied(order, tops, hors, sizes, hfov, run[2]) for run in (more, fewer)]
    return fewer if strays_more(*fits, SIGHTS_STRAY_RATIO) else more


SIGHTS_STRAY_RATIO = 1.5
"""How many times as far from the lens they imply the pairs of one lens's run with the top
camera's sights (or without them) may stray as the other run's, and be kept for keeping more
pairs (:func:`fewer_sights`). The two read the same people through the same lens, so a lower
bar than :data:`STRAY_RATIO`'s between lenses: on renders of a 66-degree lens run at 70, the run
with the sights kept 140 pair-frames straying 0.272, the one without 127 straying 0.146, right
(pair F1 0.689 -> 1.000; docs/notes/oblique_top_camera.md)."""


def strays_more(fit: tuple[float, float] | None, other: tuple[float, float] | None,
                ratio: float) -> bool:
    """Whether pairs whose implied lens fit is ``fit`` (lens, how far they stray:
    :func:`~xvmatch.cues.hor_lens.implied_fit`) stray more than ``ratio`` times as far as
    ``other``'s; False where either tells nothing (None)."""
    return fit is not None and other is not None and fit[1] > ratio * other[1]


def _scale_runs(order: list[int], tops: list, boxes: list, sizes: list, hfov: float, fps: float,
                reading: gr.HandheldReading, views: tuple[Mapping, Mapping] | None,
                sights: list[gr.TopSight] | None = None, spread: float = gr.RANGE_SPREAD,
                slack: float = 1.0, holders: list[np.ndarray | None] | None = None
                ) -> tuple[list, list[dict[float, tuple[float, list[gr.FramePose]]]]]:
    """The handheld view's people on its own map (with their ids) and its registrations at
    each map scale (:func:`~xvmatch.cues.ground_registration.register_scales`; the top map's
    motion taken out in video mode): with the ``sights`` and without them, or, without
    sights, the one."""
    hors = _hor_people(boxes, reading, hfov)
    return hors, _by_scale(order, tops, hors, sizes, hfov, fps, views is not None, sights,
                           spread, slack, holders)


def _by_scale(order: list[int], tops: list, hors: list, sizes: list, hfov: float, fps: float,
              video: bool, sights: list[gr.TopSight] | None, spread: float,
              slack: float = 1.0, holders: list[np.ndarray | None] | None = None
              ) -> list[dict[float, tuple[float, list[gr.FramePose]]]]:
    """The registrations at each map scale of the handheld people ``hors``: with the
    ``sights`` and without them (:func:`_registrations_twice`), or, without sights, the one
    (:func:`_registrations`)."""
    if sights is None:
        return [_registrations(order, tops, hors, sizes, hfov, fps, video, spread=spread,
                               slack=slack, holders=holders)]
    return list(_registrations_twice(order, tops, hors, sizes, hfov, fps, video, sights,
                                     spread, slack, holders))


def _hor_people(boxes: list, reading: gr.HandheldReading, hfov: float) -> list:
    """Per frame, the handheld view's people on its own map (a lens of ``hfov`` degrees, the
    view's ``reading``: people cut by its bottom edge read as far as its pitch lets it see no
    feet) and their ids, from its boxes and ids."""
    return [(reading.points(hb, hfov), h_ids) for hb, h_ids in boxes]


def _registrations(order: list[int], tops: list, hors: list, sizes: list, hfov: float,
                   fps: float, video: bool, sights: list[gr.TopSight] | None = None,
                   spread: float = gr.RANGE_SPREAD, slack: float = 1.0,
                   holders: list[np.ndarray | None] | None = None
                   ) -> dict[float, tuple[float, list[gr.FramePose]]]:
    """The handheld view's registration at each map scale
    (:func:`~xvmatch.cues.ground_registration.register_scales`), the top map's motion taken
    out in ``video`` mode (its ids the tracks)."""
    return gr.register_scales(order, [p for p, _ in tops], [q for q, _ in hors], hfov, fps,
                              [i for _, i in tops] if video else None, sizes, sights, spread,
                              slack, holders)


def _registrations_twice(order: list[int], tops: list, hors: list, sizes: list, hfov: float,
                         fps: float, video: bool, sights: list[gr.TopSight],
                         spread: float = gr.RANGE_SPREAD, slack: float = 1.0,
                         holders: list[np.ndarray | None] | None = None
                         ) -> tuple[dict[float, tuple[float, list[gr.FramePose]]],
                                    dict[float, tuple[float, list[gr.FramePose]]]]:
    """:func:`_registrations` with the ``sights`` and without them, in one pass
    (:func:`~xvmatch.cues.ground_registration.register_scales_twice`)."""
    return gr.register_scales_twice(order, [p for p, _ in tops], [q for q, _ in hors], hfov,
                                    fps, [i for _, i in tops] if video else None, sizes, sights,
                                    spread, slack, holders)


def scale_along_tracks(order: list[int], tops: list, hors: list,
                  runs: dict[float, tuple[float, list[gr.FramePose]]], sizes: list,
                  views: tuple[Mapping, Mapping]) -> Registered:
    """The map scale whose run keeps the most pairs along the tracks (scale 1 the prior,
    :func:`~xvmatch.cues.hor_lens.pick_along_tracks`), its poses and pairs; of the scales
    whose clip score total is at least :data:`~xvmatch.cues.ground_registration.SCALE_FLOOR`
    of scale 1's (:func:`~xvmatch.cues.ground_registration.fitting_scales`: people who stand
    still keep their pairs along the tracks under any pose)."""
    pairs = {s: _consistent(order, tops, hors, sizes, s, runs[s][1], views)
             for s in gr.fitting_scales(runs)}
    scale = pick_along_tracks(*_kept(pairs), prior=1.0)
    return scale, runs[scale][1], pairs[scale]


def _kept(runs: Mapping[float, Mapping[int, list[tuple[int, int]]]]
          ) -> tuple[dict[float, int], dict[float, int]]:
    """Per candidate run (a lens, a map scale), the pairs it kept over the frames and the
    top-view people they join (:func:`~xvmatch.cues.hor_lens.pick_along_tracks`' counts)."""
    counts = {c: _count(p) for c, p in runs.items()}
    return {c: n for c, (n, _) in counts.items()}, {c: m for c, (_, m) in counts.items()}


def _count(pairs: Mapping[int, list[tuple[int, int]]]) -> tuple[int, int]:
    """One run's pairs kept over the frames and the top-view people they join."""
    return sum(map(len, pairs.values())), len({t for frame in pairs.values() for t, _ in frame})


def _consistent(order: list[int], tops: list, hors: list, sizes: list, scale: float,
                poses: list[gr.FramePose], views: tuple[Mapping, Mapping]
                ) -> dict[int, list[tuple[int, int]]]:
    """The pairs under the poses (:func:`_pairs_under`) made consistent along both views'
    tracks."""
    return consistent_pairs(_pairs_under(order, tops, hors, sizes, scale, poses), *views, order,
                            keep_free=False)


def _pairs_under(order: list[int], tops: list, hors: list, sizes: list, scale: float,
                 poses: list[gr.FramePose]) -> dict[int, list[tuple[int, int]]]:
    """Each frame's pairs (top id, horizontal id) under its pose on the top map multiplied by
    ``scale`` (:func:`~xvmatch.cues.ground_registration.associate_on_ground`)."""
    by_frame = {p.frame: p for p in poses}
    return {f: [(int(ti[a]), int(hi[b]))
                for a, b in gr.associate_on_ground(scale * p, q, by_frame[f], z)]
            for f, (p, ti), (q, hi), z in zip(order, tops, hors, sizes, strict=True)
            if f in by_frame}


def run_top_view(top: Mapping, hor: Mapping, options: GroundAssociationOptions,
                 top_view: str = "auto", name: str = "the top view",
                 calibration: PeopleCalibration | None = None) -> GroundAssociation | None:
    """``--top-view auto|oblique``: the top camera calibrated from its people (or
    ``calibration``, made so by the caller on the same boxes), then this run; None when
    ``auto`` finds the top view looking straight down (today's nadir path serves it)."""
    if top_view not in ("auto", "oblique"):
        raise ValueError(f"top_view must be auto or oblique here, got {top_view!r}")
    calib = calibration or top_calibration(top, options.top_size, options.seed, name,
                                           options.consensus, spread="later")  # told: measured
    if calib.kind == "nadir" and top_view == "auto":
        return None
    return run_ground_association(top, hor, options, calibration=calib)
