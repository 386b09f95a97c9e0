"""Boxes-only association when the top camera is oblique and the horizontal camera walks
(issue 67), on rendered box scenes (:mod:`xvmatch.datasets.oblique_scenes`), ids scrambled per
view.

Per scene (default settings: top pitch 20-90 degrees, one handheld camera not among the top
view's people, 30-100 % overlap), every ``--step``-th frame of a ``--seconds`` clip, three
methods, scored by the F1 of the cross-view pairs over all frames:

* ``search``: today's ``associate`` (the CVMHAT spatial-distribution search, a nadir top view),
  and ``search, video mode``: the same with ``--mode video`` (the camera location followed by its
  top-view track id, the orientation window);
* ``registered, true cameras``: the ground registration
  (:mod:`xvmatch.inference.matching.ground_association`) with the top camera and the handheld
  field of view known (the ceiling of its frame-by-frame part);
* ``registered, from people``: the same with the top camera calibrated from its boxes
  (:func:`~xvmatch.geometry.people_calibration.calibrate_from_people`) and the handheld field of
  view taken as 70 degrees (``strict=False``: a loose fit rather than none), frame by frame
  without the view's ids (each box its own person, as ``associate --mode frame`` calibrates); a
  refused calibration (too few boxes) scores its frames as misses;
* ``+ tracklet consensus``: those pairs made consistent over the clip with each view's own track
  ids (:func:`~xvmatch.inference.linking.pair_consensus.tracklet_consensus`, video mode).
* ``associate, as it routes``: what ``associate --mode video`` (boxes only) answers: the row
  above where the top view's calibration is oblique (with ``--choose-lens`` the lens chosen, as
  ``associate`` chooses it; else the row's 70 degrees), the search made consistent over the clip
  (:func:`~xvmatch.inference.linking.pair_consensus.consistent_pairs`) where it looks straight
  down or cannot be calibrated (the rows above run the ground path on those scenes too).
* ``associate, its warning followed``: that row, but where it took the search and warned that
  the search's camera location wandered from person to person
  (:mod:`~xvmatch.inference.matching.search_camera`), the ground path as ``--top-view
  oblique`` runs it (the lens chosen with ``--choose-lens``, else the consensus row's).

CVIDF1 pools the frames of all scenes (:mod:`xvmatch.metrics.cross_view_metrics`); a second
table gives it per scenario: per top pitch band (:data:`PITCH_BANDS`) and per overlap band
(:data:`OVERLAP_BANDS`) of each view's share of people the other view sees.

    .venv/bin/python benchmarks/oblique_association.py --scenes 12

``--guess-top-size``: the from-people rows without the top image size, as ``associate`` guesses
it from the boxes; ``--no-scale-search``: the registration at the top map's own scale only (as
before :func:`~xvmatch.cues.ground_registration.register_with_scale`); ``--no-top-motion``: the
tracklet-consensus row without the top map's own motion taken out of the registration (as before
:func:`~xvmatch.cues.ground_registration.map_motion`); ``--no-top-sizes``: every handheld
person read at 1.72 m, not at the height the top view reads for the partner it is compared
with (as before :func:`~xvmatch.inference.matching.ground_association.top_sizes`);
``--box-noise SIGMA``: each box edge of both views moved by a normal draw of SIGMA times the
box's height, then clipped to the image (the renders' boxes are exact; annotations and
detectors are not, and both clip to the image); ``--box-misses RATE S``: each person missed in
both views RATE of the time, in runs of S seconds on average
(:class:`~xvmatch.datasets.detector_noise.DetectorNoise` ``miss_run``: a detector's misses; the
truth counts only the boxes kept).

What the methods take for granted, broken on the same scenes: ``--ground-slope DEG``, the
ground a plane sloping DEG degrees towards a drawn direction
(:func:`~xvmatch.datasets.oblique_scenes.sloped`: a park, a street); ``--top-distortion K1``,
the top camera's lens distorting radially by K1
(:func:`~xvmatch.datasets.oblique_scenes.top_distorted`: a drone's video not undistorted,
about -0.1); ``--top-roll DEG``, the top camera turned DEG degrees about its optical axis
(:func:`~xvmatch.datasets.oblique_scenes.top_rolled`: a building camera mounted askew; the
renders' top cameras are otherwise level); ``--top-hfov LO HI``, the top camera's lens (default
55-85 degrees; 90 120: an action camera on a pole). The methods take a level ground and a
pinhole top camera, and fit the top camera's roll and lens.

    .venv/bin/python benchmarks/oblique_association.py --scenes 12 --ground-slope 3

``--top-pitch LO HI`` and ``--overlap LO HI``: the renders' top pitch (default 20-90 degrees)
and each view's share of people the other sees (default 0.3-1), e.g. a scenario like the
issue's hidden set (a low oblique drone, about half of each view's people in the other):

    .venv/bin/python benchmarks/oblique_association.py --top-pitch 20 45 --overlap 0.35 0.65

``--top-height LO HI``: the top camera's height (default 4-60 m; raised where the people do not
fit its image). By default most top views are far: their people's boxes are 20-100 px tall at
1920x1080; ``--top-height 4 12`` gives 60-270 px, the hidden set's 60-280 (a close, low drone).

``--edge-people LO HI``: LO-HI more people per camera walking across its image's bottom edge
(a close drone's near edge, a handheld camera's passers-by), their boxes cut by it; the renders
otherwise keep everyone inside both images.

``--top-pitch-rate LO HI``: a drone whose gimbal tilts at LO-HI degrees/s where it stands (the
drawn pitch is the clip's middle one). The top camera is still calibrated once for the clip;
the ``true cameras`` row and each scene's printed pitch take the first frame's camera.

``--hor-size assumed|guess``: the from-people rows without the handheld image size, as
``associate`` without ``--image-size`` takes it: ``assumed``, CVMHAT's 2688x1512 where the
boxes fit it (the renders' 1920x1080 views; a 3640x2048 view's boxes do not, and ``associate``
asked for the size: the true size is used), as before the twenty-eighth session; ``guess``,
the size the boxes tell, for every view (where they are cut by the image's borders, else the
smallest common video size holding them: a 3640x2048 view's boxes gave 3840x2160 before the
forty-sixth session; :func:`~xvmatch.formats.box_image_size.ground_path_hor_size`, now).

``--hor-hfov LO HI``: the renders' handheld field of view, drawn per scene in LO-HI degrees
(default 60 80, :class:`~xvmatch.datasets.oblique_scenes.ObliqueSceneConfig`); e.g. 90 120 for an
action camera, 45 55 for a narrow one. The from-people rows still assume 70 degrees.

    .venv/bin/python benchmarks/oblique_association.py --scenes 12 --hor-hfov 90 120

``--distance-errors``: how far the handheld distances read from box heights through the true
lens err from the true ones (median and robust spread, relative), with the bearings' error and
the true distances (why :func:`~xvmatch.cues.ground_registration.ray_distances` stretches the
gate along the ray).

``--choose-lens``: two more rows, both with the tracklet consensus: ``registered, from people,
true lens`` (the handheld field of view known, the top camera from its people) and
``registered, from people, lens chosen`` (``--hor-hfov auto``, as ``associate`` runs it: the
field of view chosen from the people: as this row runs in video mode, the candidate whose
whole run keeps the most pairs along the tracks,
:func:`~xvmatch.cues.hor_lens.pick_along_tracks`); each scene's line gives the true and the
chosen lens with the pairs each candidate kept (``lens:kept/Np``: pair-frames, and the
top-view people they join; then ``made lens:kept``, each lens's run as made with the top
camera's sights, :func:`~xvmatch.inference.matching.ground_association.choose_along_tracks`;
frame by frame the choice would give each candidate's pairing score and chance score,
``lens:in/chance``), and the summary the seconds the choice and its run took.

    .venv/bin/python benchmarks/oblique_association.py --scenes 12 --hor-hfov 90 120 --choose-lens

The methods are given the whole clip's boxes (10 a second) and associate its sampled frames, so
the from-people rows calibrate the top camera from every frame. ``--renumber``: they are given
the sampled frames alone, numbered 1, 2, 3 (a file of every ``--step``-th frame with its own
numbering, as the issue's hidden set gives 3 a second; the rows told the frame rate are told
the renders' rate over the step), and
``--fps auto|N``: the from-people rows take the frame rate ``auto`` (``associate``'s default: 30
unless the top view's walkers say otherwise,
:func:`~xvmatch.inference.matching.ground_association.top_frame_rate`; each scene's line then
gives the rate taken) or ``N`` rather than the true one (``--fps 30 --renumber``: the file read
at a video's rate).

    .venv/bin/python benchmarks/oblique_association.py --scenes 12 --renumber --fps auto
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace

import numpy as np

from xvmatch.cues import ground_registration as gr
from xvmatch.cues.spatial_search import associate_sequence
from xvmatch.datasets.detector_noise import DetectorNoise, apply_detector_noise
from xvmatch.datasets.oblique_scenes import (
    BOX_EXTENTS,
    ObliqueSceneConfig,
    jittered,
    make_oblique_scene,
    pitch_drifted,
    sloped,
    top_distorted,
    top_rolled,
)
from xvmatch.formats.box_image_size import (
    ASSUMED,
    CVMHAT_SIZE,
    UNKNOWN,
    consistent_with,
    ground_path_hor_size,
    guess_image_size,
    runs_past_borders,
)
from xvmatch.formats.mot_boxes import FrameBoxes, stack_frames
from xvmatch.geometry.people_calibration import CalibrationError, PeopleCalibration
from xvmatch.inference.linking.pair_consensus import consistent_pairs
from xvmatch.inference.matching.ground_association import (
    AUTO_FPS,
    AUTO_HFOV,
    GroundAssociationOptions,
    run_ground_association,
    top_calibration,
    top_ground_points,
)
from xvmatch.inference.matching.search_camera import followed_cameras, wandering_camera_note
from xvmatch.metrics.cross_view_metrics import count_sequence, summarize


def _scrambled(frames: dict, rng: np.random.Generator) -> tuple[dict, dict]:
    """The view's records with its ids replaced by a random permutation, and the way back."""
    ids = sorted({int(i) for r in frames.values() for i in r.ids})
    new = rng.permutation(len(ids)) + 100
    forward = dict(zip(ids, new.tolist(), strict=True))
    back = {v: k for k, v in forward.items()}
    return ({f: FrameBoxes(f, np.array([forward[int(i)] for i in r.ids], dtype=np.int64),
                           np.asarray(r.boxes, float).reshape(-1, 4))
             for f, r in frames.items()}, back)


def _true_calibration(camera, size: tuple[int, int]) -> PeopleCalibration:
    """The scene's top camera as a calibration in its own ground frame (tilt, focal, height;
    the renders' top cameras have no roll)."""
    tilt = float(np.degrees(np.arcsin(-camera.R[2, 2])))
    return PeopleCalibration(kind="oblique", width=size[0], height=size[1],
                             focal=float(camera.K[0, 0]), tilt_deg=tilt, roll_deg=0.0,
                             camera_height=float(camera.c[2]), horizon=(0.0, 0.0),
                             focal_from="given", tilt_std_deg=0.0, horizon_std_px=0.0,
                             focal_rel_std=0.0, n_boxes=0, n_frames=0)


def _true_ground_points(top: dict, cameras: list, size: tuple[int, int]) -> np.ndarray:
    """The top view's people on the ground map of each frame's own true camera (``cameras``,
    one per frame of ``top`` in order; a drone that tilts or moves has one per frame), in
    :func:`~xvmatch.formats.mot_boxes.stack_frames` order: what the "true cameras" row maps."""
    frames, _, boxes = stack_frames(top)
    out = np.full((len(boxes), 2), np.nan)
    for f, camera in zip(sorted(top), cameras, strict=True):
        rows = frames == f
        out[rows] = top_ground_points(boxes[rows], _true_calibration(camera, size))
    return out


def _distance_errors(scene, frames: list[int], hfov: float) -> np.ndarray:
    """``(B, 3)`` per handheld box of ``frames``: its distance read from its height through the
    true lens (:func:`~xvmatch.cues.ground_registration.hor_ground_points`) over the true
    distance, minus 1; its bearing's error (degrees); the true distance (metres)."""
    out = []
    for f in frames:
        rec, cam = scene.hor["hor1"][f], scene.hor_cameras["hor1"][f - 1]
        est = gr.hor_ground_points(rec.boxes, cam.image_size, hfov)
        rel = scene.people.positions[f - 1][np.asarray(rec.ids)] - cam.c[:2]
        yaw = np.arctan2(cam.R[2, 1], cam.R[2, 0])
        c, s = np.cos(yaw), np.sin(yaw)
        true = np.column_stack([rel[:, 0] * c + rel[:, 1] * s, -rel[:, 0] * s + rel[:, 1] * c])
        dist = np.hypot(*true.T)
        bearing = np.degrees(np.arctan2(est[:, 1], est[:, 0]) - np.arctan2(true[:, 1], true[:, 0]))
        out.append(np.column_stack([np.hypot(*est.T) / dist - 1.0, bearing, dist]))
    return np.concatenate(out) if out else np.zeros((0, 3))


def _robust_spread(values: np.ndarray) -> float:
    """1.4826 times the median absolute deviation: a standard deviation that outliers do not
    move."""
    return float(1.4826 * np.median(np.abs(values - np.median(values))))


def _score(pred: dict, truth: dict) -> np.ndarray:
    tp = fp = fn = 0
    for f, pairs in truth.items():
        got = set(pred.get(f, []))
        tp, fp, fn = tp + len(got & pairs), fp + len(got - pairs), fn + len(pairs - got)
    return np.array([tp, fp, fn])


PITCH_BANDS = ((20.0, 40.0), (40.0, 60.0), (60.0, 90.1))
"""Top camera pitch bands of the breakdown (degrees): a low oblique drone or building camera,
a steeper one, a near-nadir one."""

OVERLAP_BANDS = ((0.0, 0.5), (0.5, 0.8), (0.8, 1.01))
"""Bands of a view's share of people the other view sees (the scene's target fractions)."""


def _breakdown(scenes: list[tuple[float, float, float, dict]], names: tuple[str, ...]) -> None:
    """CVIDF1 of each method per top pitch band and per overlap band (each view's share of
    people seen by the other), pooled over the scenes in the band."""
    bands = [("top pitch", 0, PITCH_BANDS), ("top view's people seen by the handheld", 1,
                                             OVERLAP_BANDS),
             ("handheld view's people seen by the top", 2, OVERLAP_BANDS)]
    print("\n| by | band | scenes | " + " | ".join(names) + " |\n|---|---|---|"
          + "---|" * len(names))
    for title, column, edges in bands:
        for lo, hi in edges:
            sel = [sc for sc in scenes if lo <= sc[column] < hi]
            if not sel:
                continue
            cells = [f"{summarize([c for sc in sel for c in sc[3][n]]).cvidf1:.1f}"
                     for n in names]
            band = f"{lo:g}-{min(hi, 90.0 if column == 0 else 1.0):g}"
            print(f"| {title} | {band} | {len(sel)} | " + " | ".join(cells) + " |")


def add_drone_arguments(p: argparse.ArgumentParser) -> None:
    """The drone's place (``--top-pitch``, ``--top-height``), its motion (``--top-drift``,
    ``--top-yaw-rate``, ``--top-pitch-rate``, ``--no-top-motion``) and the people cut by the
    images' bottom edges (``--edge-people``), the handheld cameras' holders' pace, walk and
    pans (``--holder-speed``, ``--holder-area``, ``--pan-rate``), their lenses' distortion
    (``--hor-distortion``), pitch and height (``--hor-pitch``, ``--hor-wobble``,
    ``--hor-height``), people's heights (``--person-height``), how far apart they stand
    (``--area``, ``--group-area``) and how often and how long they stand still (``--stops``)."""
    p.add_argument("--top-drift", type=float, nargs=2, default=(0.0, 0.0), metavar=("LO", "HI"),
                   help="the top camera drifts at LO-HI m/s (a drone; default static)")
    p.add_argument("--top-yaw-rate", type=float, nargs=2, default=(0.0, 0.0),
                   metavar=("LO", "HI"), help="and turns at LO-HI degrees/s")
    p.add_argument("--top-pitch-rate", type=float, nargs=2, default=(0.0, 0.0),
                   metavar=("LO", "HI"), help="and tilts up or down at LO-HI degrees/s (a "
                   "gimbal; the drawn pitch is the clip's middle one)")
    p.add_argument("--top-pitch", type=float, nargs=2, default=(20.0, 90.0),
                   metavar=("LO", "HI"), help="the top camera's pitch in the renders, LO-HI "
                   "degrees below the horizon (default 20 90)")
    p.add_argument("--top-height", type=float, nargs=2, default=(4.0, 60.0),
                   metavar=("LO", "HI"), help="the top camera's height in the renders, LO-HI "
                   "metres (default 4 60; raised where the people do not fit its image)")
    p.add_argument("--top-hfov", type=float, nargs=2, default=(55.0, 85.0),
                   metavar=("LO", "HI"), help="the top camera's horizontal field of view in the "
                   "renders, LO-HI degrees (default 55 85; 90 120: an action camera on a pole)")
    p.add_argument("--edge-people", type=int, nargs=2, default=(0, 0), metavar=("LO", "HI"),
                   help="LO-HI more people per camera walking across its image's bottom edge, "
                   "their boxes cut by it (default 0 0)")
    p.add_argument("--holder-speed", type=float, nargs=2, default=(0.1, 0.5),
                   metavar=("LO", "HI"), help="each handheld camera's holder walks at LO-HI "
                   "m/s, turning within their square (default 0.1 0.5)")
    p.add_argument("--holder-area", type=float, nargs=2, default=(2.0, 2.0),
                   metavar=("LO", "HI"), help="the side of each holder's square, LO-HI metres "
                   "(default 2 2: turning on the spot; 10: walking past the scene)")
    p.add_argument("--hor-distortion", type=float, nargs=2, default=(0.0, 0.0),
                   metavar=("LO", "HI"), help="each handheld lens's radial distortion k1, drawn "
                   "in LO-HI (default 0 0: a pinhole; -0.25: an action camera's barrel)")
    p.add_argument("--hor-pitch", type=float, nargs=2, default=(-3.0, 5.0),
                   metavar=("LO", "HI"), help="each handheld camera's mean pitch, degrees, "
                   "drawn in LO-HI (positive looks down; default -3 5)")
    p.add_argument("--hor-height", type=float, nargs=2, default=(1.4, 1.7),
                   metavar=("LO", "HI"), help="each handheld camera's height, metres, drawn in "
                   "LO-HI (default 1.4 1.7; at the chest: 1.2 1.4)")
    p.add_argument("--hor-wobble", type=float, default=1.0, metavar="DEG",
                   help="the handheld cameras' smooth pitch and roll wobble about that mean, "
                   "degrees (default 1; a walking hand: 3)")
    p.add_argument("--pan-rate", type=float, default=0.05, metavar="R",
                   help="pans a second of each handheld camera (a turn away and back; default "
                   "0.05)")
    p.add_argument("--area", type=float, nargs=2, default=(5.0, 10.0), metavar=("LO", "HI"),
                   help="the side of the shared people's square, LO-HI metres (default 5 10; "
                   "shrunk to fit the top image: a higher drone spreads them)")
    p.add_argument("--group-area", type=float, nargs=2, default=(3.0, 6.0),
                   metavar=("LO", "HI"), help="the side of each one-view group's square, LO-HI "
                   "metres (default 3 6)")
    p.add_argument("--person-height", type=float, nargs=2, default=(1.5, 1.95),
                   metavar=("LO", "HI"), help="people's heights in the renders, LO-HI metres "
                   "(default 1.5 1.95; lower: children, people sitting)")
    p.add_argument("--stops", type=float, nargs=2, default=(0.1, 5.0), metavar=("RATE", "S"),
                   help="people stop RATE times a second for S seconds on average (default 0.1 "
                   "5: a third stand at any time; 0.5 30, a lingering crowd: 94 %%)")
    p.add_argument("--box-extent", choices=BOX_EXTENTS, default="visible",
                   help="what a person's box covers: visible (default: the visible part, "
                   "clipped to the image), past_border (run on past a border that cuts it, as "
                   "trackers' boxes) or amodal (the whole box, behind others and past the "
                   "border)")
    p.add_argument("--no-top-motion", action="store_true",
                   help="leave the top map's own motion in the registration's jumps (before "
                   "map_motion)")


def drone_config(args: argparse.Namespace, **settings) -> ObliqueSceneConfig:
    """The scenes' settings with the drone and the edge people of :func:`add_drone_arguments`; with
    ``--no-top-motion`` the registration leaves the top map's motion in (as before
    :func:`~xvmatch.cues.ground_registration.map_motion`)."""
    if args.no_top_motion:
        gr.map_motion = lambda frames, tops, ids, fps: [None] * len(tops)
    return ObliqueSceneConfig(top_drift_speed=tuple(args.top_drift),
                              top_yaw_rate=tuple(args.top_yaw_rate),
                              top_pitch_rate=tuple(args.top_pitch_rate),
                              top_pitch=tuple(args.top_pitch), top_height=tuple(args.top_height),
                              top_hfov=tuple(args.top_hfov),
                              edge_people=tuple(args.edge_people),
                              holder_speed=tuple(args.holder_speed),
                              holder_area=tuple(args.holder_area), pan_rate=args.pan_rate,
                              hor_distortion=tuple(args.hor_distortion),
                              hor_pitch=tuple(args.hor_pitch), hor_wobble=args.hor_wobble,
                              hor_height=tuple(args.hor_height),
                              height_range=tuple(args.person_height), area=tuple(args.area),
                              group_area=tuple(args.group_area),
                              stop_probability=args.stops[0], stop_duration=args.stops[1],
                              box_extent=args.box_extent, **settings)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", type=int, default=12)
    p.add_argument("--seconds", type=float, default=12.0)
    p.add_argument("--step", type=int, default=3, help="every N-th frame (10 fps scenes)")
    p.add_argument("--seed", type=int, default=0)
    add_drone_arguments(p)
    p.add_argument("--guess-top-size", action="store_true",
                   help="the from-people rows take the top size guessed from the boxes "
                   "(associate without --top-image-size), not the true one")
    p.add_argument("--hor-drift", type=float, nargs=2, default=None, metavar=("DEG", "S"),
                   help="each handheld camera's pitch drifts DEG degrees about its own, over S "
                   "seconds, on the same scenes (a holder who reframes; e.g. 5 6)")
    p.add_argument("--ground-slope", type=float, default=None, metavar="DEG",
                   help="the same scenes on a ground sloping DEG degrees, rising towards a "
                   "drawn direction (a park, a street; the methods take it to be level)")
    p.add_argument("--top-distortion", type=float, default=None, metavar="K1",
                   help="the same scenes with the top camera's lens distorting radially by K1 "
                   "(a drone's video not undistorted: about -0.1; the methods take a pinhole)")
    p.add_argument("--top-roll", type=float, default=None, metavar="DEG",
                   help="the same scenes with the top camera rolled DEG degrees about its axis "
                   "(a building camera mounted askew; the calibration fits the roll)")
    p.add_argument("--box-noise", type=float, default=0.0, metavar="SIGMA",
                   help="move each box edge, in both views, by a normal draw of SIGMA times "
                   "the box's height, clipped to the image (default 0: the renders' exact "
                   "boxes)")
    p.add_argument("--box-misses", type=float, nargs=2, default=None, metavar=("RATE", "S"),
                   help="miss each person, in both views, RATE of the time in runs of S "
                   "seconds on average, as a detector misses (default: none missed)")
    p.add_argument("--camera-id", action="store_true",
                   help="the from-people rows are told the top-view id of the handheld camera's "
                   "holder, as associate --camera-id ID (the camera placed where the top view "
                   "sees them)")
    p.add_argument("--no-top-sizes", action="store_true",
                   help="read every handheld person at 1.72 m, not at their top-view partner's "
                   "height (before)")
    p.add_argument("--no-scale-search", action="store_true",
                   help="register at the top map's own scale only (before the scale search)")
    p.add_argument("--hor-hfov", type=float, nargs=2, default=(60.0, 80.0), metavar=("LO", "HI"),
                   help="the handheld camera's horizontal field of view in the renders, LO-HI "
                   "degrees (default 60 80)")
    p.add_argument("--overlap", type=float, nargs=2, default=(0.3, 1.0), metavar=("LO", "HI"),
                   help="each view's share of people the other sees, drawn in LO-HI (default "
                   "0.3 1)")
    p.add_argument("--distance-errors", action="store_true",
                   help="also print how far the handheld distances read from box heights (the "
                   "true lens) err from the true ones, and their bearings")
    p.add_argument("--choose-lens", action="store_true",
                   help="add the rows with the true and the chosen handheld lens (from people, "
                   "tracklet consensus)")
    p.add_argument("--workers", type=int, default=1, metavar="K",
                   help="with --choose-lens: processes running the candidate lenses side by "
                   "side in the lens-chosen run, as associate --workers (default 1; the same "
                   "pairs)")
    p.add_argument("--hor-size", choices=("true", "assumed", "guess"), default="true",
                   help="the from-people rows' handheld image size: true (default), or as "
                   "associate takes it without --image-size: assumed (CVMHAT's 2688x1512, "
                   "before) or guess (the size the boxes tell, now)")
    p.add_argument("--renumber", action="store_true",
                   help="number the sampled frames 1, 2, 3 (a file of every --step-th frame "
                   "with its own numbering)")
    p.add_argument("--fps", default="true",
                   help="the from-people rows' frame rate: true (default: the renders', over "
                   "the step with --renumber), auto (associate's default) or frames a second")
    args = p.parse_args(argv)
    if args.no_scale_search:
        gr.MAP_SCALES = (1.0,)
    config = drone_config(args, hor_hfov=tuple(args.hor_hfov), overlap=tuple(args.overlap))
    names = ("search", "search, video mode", "registered, true cameras",
             "registered, from people", "registered, from people, tracklet consensus",
             "associate, as it routes")
    if args.choose_lens:
        names += ("registered, from people, true lens, tracklet consensus",
                  "registered, from people, lens chosen, tracklet consensus")
    names += ("associate, its warning followed",)
    choice_s = voted_s = 0.0
    totals = {name: np.zeros(3) for name in names}
    counts: dict[str, list] = {name: [] for name in names}
    refused = 0
    per_scene: list[tuple[float, float, float, dict]] = []
    errors: list[np.ndarray] = []
    t0 = time.perf_counter()
    for k in range(args.scenes):
        scene = make_oblique_scene(config, int(args.seconds * config.fps),
                                   np.random.default_rng([args.seed, k]))
        if args.hor_drift is not None:  # the same scene, its handheld pitch drifting
            scene = pitch_drifted(scene, *args.hor_drift, np.random.default_rng([args.seed, k, 3]))
        if args.ground_slope is not None:  # the same scene on a sloping ground
            scene = sloped(scene, args.ground_slope, np.random.default_rng([args.seed, k, 4]))
        if args.top_distortion is not None:  # the same scene through a drone's barrel lens
            scene = top_distorted(scene, args.top_distortion)
        if args.top_roll is not None:  # the same scene from a camera mounted askew
            scene = top_rolled(scene, args.top_roll)
        rng = np.random.default_rng([args.seed, k, 1])
        top, top_back = _scrambled(scene.top, rng)
        hor, hor_back = _scrambled(scene.hor["hor1"], rng)
        if args.box_noise > 0:  # from a generator of its own: the scenes' draws stay
            noise = np.random.default_rng([args.seed, k, 2])
            top, hor = (jittered(v, args.box_noise, noise, c.image_size,
                                 clip=args.box_extent == "visible") for v, c in
                        ((top, scene.top_cameras[0]), (hor, scene.hor_cameras["hor1"][0])))
        if args.box_misses is not None:  # its own draws, as the noise's
            misses = DetectorNoise(0.0, args.box_misses[0], 0.0,
                                   max(1.0, args.box_misses[1] * config.fps))
            top, hor = (apply_detector_noise(v, c.image_size, misses, 1000 * args.seed + k, n)
                        for v, c, n in ((top, scene.top_cameras[0], "top"),
                                        (hor, scene.hor_cameras["hor1"][0], "hor")))
        seen = tuple(  # the boxes the methods see, the scene's ids: what CVIDF1 scores
            {f: FrameBoxes(f, np.array([way[int(i)] for i in r.ids], np.int64), r.boxes)
             for f, r in v.items()} for v, way in ((top, top_back), (hor, hor_back)))
        frames = [f for f in sorted(set(top) & set(hor)) if (f - 1) % args.step == 0]
        holder = int(scene.groups["holders"][0])  # its scrambled id, where the top view has one
        camera_id = next((a for a, b in top_back.items() if b == holder), None) if \
            args.camera_id else None
        truth = {f: {(int(a), int(b)) for a in top[f].ids for b in hor[f].ids
                     if top_back[int(a)] == hor_back[int(b)]} for f in frames}
        hor_cam = scene.hor_cameras["hor1"][0]
        hor_size = hor_cam.image_size
        true_hfov = float(np.degrees(2 * np.arctan(0.5 * hor_size[0] / hor_cam.K[0, 0])))
        fps = config.fps
        if args.distance_errors:
            errors.append(_distance_errors(scene, frames, true_hfov))
        sampled = frames
        if args.renumber:  # the methods see frames 1, 2, 3; their pairs go back to `sampled`
            top, hor = ({k: FrameBoxes(k, v[f].ids, v[f].boxes) for k, f in
                         enumerate(sampled, 1)} for v in (top, hor))
            frames, fps = list(range(1, len(sampled) + 1)), config.fps / args.step
        people_fps = fps if args.fps == "true" else (
            AUTO_FPS if args.fps == AUTO_FPS else float(args.fps))
        cameras: dict[int, int] = {}  # the search's O per frame (search_camera's warning)
        search = associate_sequence(top, hor, float(hor_size[0]), frames=frames, cameras=cameras)
        follow = associate_sequence(top, hor, float(hor_size[0]), frames=frames, search="follow")
        top_size = scene.top_cameras[0].image_size
        known = GroundAssociationOptions(top_size, hor_size, true_hfov, fps, consensus=False,
                                         top_sizes=not args.no_top_sizes)
        original = dict(zip(frames, sampled, strict=True))  # the methods' frame -> the scene's
        true = run_ground_association(
            top, hor, known, frames, _true_calibration(scene.top_cameras[0], top_size),
            _true_ground_points(top, [scene.top_cameras[original.get(f, f) - 1]
                                      for f in sorted(top)], top_size)).pairs
        past = runs_past_borders(top, hor)  # as the commands read the run's two files
        if args.guess_top_size:
            top_size = guess_image_size(top, past) or top_size
        people_hor = hor_size
        if args.hor_size != "true" and consistent_with(hor):
            people_hor = (CVMHAT_SIZE if args.hor_size == "assumed" else
                          ground_path_hor_size(hor, CVMHAT_SIZE, ASSUMED, past) or CVMHAT_SIZE)
        elif args.hor_size == "guess":  # boxes that do not fit CVMHAT's ("assumed": refused):
            # as resolve_size(defer=True) settles them for the command, not the true size
            people_hor = ground_path_hor_size(hor, guess_image_size(hor, past) or hor_size,
                                              UNKNOWN) or hor_size
        options = GroundAssociationOptions(top_size, people_hor, fps=people_fps, consensus=False,
                                           top_sizes=not args.no_top_sizes, camera_id=camera_id)
        try:  # frame by frame the calibration reads no ids; the consensus rows, the tracks
            calib = top_calibration(top, top_size)
            frame_calib = top_calibration(top, top_size, tracks=False)
        except CalibrationError:
            refused += 1
            calib = None
            people = voted = true_lens = chosen = {}
            lens, lens_scores, rate = float("nan"), "", None
        else:
            people = run_ground_association(top, hor, options, frames, frame_calib).pairs
            t1 = time.perf_counter()
            voted_run = run_ground_association(top, hor, replace(options, consensus=True),
                                               frames, calib)
            voted = voted_run.pairs
            rate = voted_run.frame_rate
            voted_s += time.perf_counter() - t1
            if args.choose_lens:
                voting = replace(options, consensus=True)
                true_lens = run_ground_association(
                    top, hor, replace(voting, hor_hfov_deg=true_hfov), frames, calib).pairs
                t1 = time.perf_counter()  # as associate runs: the lens chosen, then the run
                chosen_run = run_ground_association(
                    top, hor, replace(voting, hor_hfov_deg=AUTO_HFOV, workers=args.workers),
                    frames, calib)
                choice_s += time.perf_counter() - t1
                chosen, choice = chosen_run.pairs, chosen_run.lens
                lens = choice.hfov_deg
                lens_scores = " ".join(  # video mode: pairs kept along the tracks
                    f"{h:.0f}:{v:.0f}/{choice.people[h]}p" if h not in choice.chance else
                    f"{h:.0f}:{v:.1f}/{choice.chance[h]:.1f}" for h, v in choice.scores.items())
                if choice.made:  # each lens's run as made, with the top camera's sights
                    lens_scores += "; made " + " ".join(f"{h:.0f}:{v:.0f}"
                                                        for h, v in choice.made.items())
        routed = ((chosen if args.choose_lens else voted)  # associate chooses the lens
                  if calib is not None and calib.kind == "oblique" else
                  consistent_pairs(search, top, hor, frames))
        preds = (search, follow, true, people, voted, routed)
        if args.choose_lens:
            preds += (true_lens, chosen)
        # associate warns where the search's O wandered; --top-view oblique then runs the
        # ground path (the lens chosen, as associate; else the 70-degree consensus run)
        warned = (calib is not None and calib.kind != "oblique" and wandering_camera_note(
            followed_cameras(top, cameras, video=True)) is not None)
        preds += ((chosen if args.choose_lens else voted) if warned else routed,)
        if args.renumber:
            preds = tuple({sampled[f - 1]: v for f, v in pred.items()} for pred in preds)
        frames = sampled
        line = []
        pitch = float(np.degrees(np.arcsin(-scene.top_cameras[0].R[2, 2])))
        per_scene.append((pitch, scene.overlap_target["top"], scene.overlap_target["hor1"], {}))
        for name, pred in zip(names, preds, strict=True):
            s = _score(pred, truth)
            totals[name] += s
            back = {f: [(top_back[a], hor_back[b]) for a, b in pred.get(f, [])] for f in frames}
            per_scene[-1][3][name] = count_sequence(back, *seen,
                                                    frames=frames)
            counts[name] += per_scene[-1][3][name]
            line.append(f"{2 * s[0] / max(1, 2 * s[0] + s[1] + s[2]):.3f}")
        print(f"scene {k:2d} top pitch {pitch:4.1f} overlap top "
              f"{scene.overlap_target['top']:.2f} hor {scene.overlap_target['hor1']:.2f}: "
              f"pair F1 search {line[0]} (video {line[1]}), registered (true) {line[2]}, "
              f"(from people) {line[3]}, (+ consensus) {line[4]}, (as associate routes: "
              f"{'ground' if calib is not None and calib.kind == 'oblique' else 'search'}) "
              f"{line[5]}{' (warned: --top-view oblique ' + line[-1] + ')' if warned else ''}"
              + (f"; lens {true_hfov:.0f}, chosen {lens:.0f} ({lens_scores}): (true lens) "
                 f"{line[6]}, (lens chosen) {line[7]}" if args.choose_lens else "")
              + (f"; frame rate {rate.fps:g}{' (walkers)' if rate.estimated else ''}, true "
                 f"{fps:.3g}" if args.fps == AUTO_FPS and rate is not None else "")
              + (f"; sizes taken: top {'x'.join(map(str, top_size))}, handheld "
                 f"{'x'.join(map(str, people_hor))} (true "
                 f"{'x'.join(map(str, hor_size))})" if args.guess_top_size
                 or args.hor_size != "true" else ""), flush=True)
    print(f"\n{args.scenes} scenes, every {args.step}th frame of {args.seconds:g} s, "
          f"{time.perf_counter() - t0:.0f} s; top calibration refused in {refused}"
          + (f"; the lens choice and its run took {choice_s:.0f} s (the consensus run at 70 "
             "degrees "
             f"{voted_s:.0f} s)" if args.choose_lens else ""))
    print("| method | CVIDF1 | pair F1 | TP | FP | FN |\n|---|---|---|---|---|---|")
    for name, (tp, fp, fn) in totals.items():
        cvidf1 = summarize(counts[name]).cvidf1
        print(f"| {name} | {cvidf1:.1f} | {2 * tp / max(1, 2 * tp + fp + fn):.3f} | {tp:.0f} | "
              f"{fp:.0f} | {fn:.0f} |")
    _breakdown(per_scene, names)
    if errors:
        e = np.concatenate(errors)
        lo, mid, hi = np.percentile(e[:, 2], [10, 50, 90])
        print(f"\nhandheld distances from box heights (true lens), {len(e)} boxes: error median "
              f"{100 * np.median(e[:, 0]):.1f} %, robust spread {100 * _robust_spread(e[:, 0]):.1f}"
              f" %; bearing error robust spread {_robust_spread(e[:, 1]):.2f} degrees; true "
              f"distances {lo:.1f} / {mid:.1f} / {hi:.1f} m (10th / 50th / 90th percentile)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
