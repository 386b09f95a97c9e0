"""Box-level scenes seen by several static calibrated cameras (issue 32), seeded, no rendering.

People walk on a square floor (:func:`xvmatch.datasets.box_scene.simulate_walks`: turns, stops,
no collisions) watched by 2-8 static cameras placed around it: spread in azimuth (so some are
nearly opposite), at different heights, pitches (oblique to steep), small rolls, fields of view
and image sizes, each aimed at its own point of the floor so that their fields of view overlap
only in part and people walk in and out of each. Every camera's boxes are those an ideal
annotator draws (:func:`xvmatch.datasets.box_scene.project_hor_boxes`: the body's upright extent,
cut by the image border and by nearer people, dropped below 30% visible).

Each camera gets its own **track ids**, as a tracker of that camera alone would give: a new id
whenever a person comes back after more than ``reentry_gap`` frames unseen, then scrambled per
camera. The **global ids** (the same person in every camera) and the **ground positions** are the
ground truth, kept apart for scoring. Tracker-like noise on top (:func:`add_tracker_noise`):
:func:`xvmatch.datasets.detector_noise.apply_detector_noise` (jitter, misses, false boxes, what
``xvmatch noise`` does) and id switches between crossing people and fragments (a track cut into
two ids).

Written by :func:`write_multicam_scene` in today's formats: ``cameras.json`` (version 1),
``boxes/NAME.txt`` (MOT, per-camera track ids: the input), ``gt/NAME.txt`` (MOT, global ids: the
ground truth of the same boxes before noise) and ``ground_gt.csv`` (``frame,global_id,X,Y``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from xvmatch.core.atomic_files import atomic_write_text
from xvmatch.datasets.box_scene import (
    PeopleState,
    SceneConfig,
    project_hor_boxes,
    simulate_walks,
)
from xvmatch.datasets.detector_noise import DetectorNoise, apply_detector_noise
from xvmatch.formats.camera_io import save_cameras
from xvmatch.formats.mot_boxes import FrameBoxes, write_mot_boxes
from xvmatch.geometry.camera import Camera, intrinsics_from_fov, look_rotation

__all__ = [
    "MulticamConfig",
    "MulticamScene",
    "TrackerNoise",
    "add_tracker_noise",
    "multicam_walks",
    "per_camera_track_ids",
    "simulate_multicam_scene",
    "static_cameras",
    "write_multicam_scene",
]

_SIZES = ((1920, 1080), (1280, 720), (1600, 900))


@dataclass(frozen=True)
class MulticamConfig:
    """What shapes a multi-camera scene. Lengths metres, angles degrees, sizes pixels.

    Attributes:
        n_cameras: number of static cameras, 2..8.
        n_people: (min, max) people on the floor, drawn once per scene.
        area: side of the square floor people walk on, centred on the origin.
        camera_distance: (min, max) distance of a camera from the floor's centre.
        camera_height: (min, max) height of a camera above the floor.
        hfov_deg: (min, max) horizontal field of view.
        aim_spread: cameras aim at a point drawn uniformly within this radius of the centre.
        roll_deg: largest |roll| of a camera (its image columns are then not vertical).
        fps: frame rate of the walks.
        walk_speed: (min, max) preferred walking speed, m/s.
        reentry_gap: a person unseen by a camera for more frames than this gets a new track id
            there when seen again.
        min_visible_fraction: a person less visible than this in a camera has no box there.
    """

    n_cameras: int = 4
    n_people: tuple[int, int] = (12, 12)
    area: float = 24.0
    camera_distance: tuple[float, float] = (13.0, 17.0)
    camera_height: tuple[float, float] = (3.0, 8.0)
    hfov_deg: tuple[float, float] = (40.0, 75.0)
    aim_spread: float = 7.0
    roll_deg: float = 3.0
    fps: float = 10.0
    walk_speed: tuple[float, float] = (0.5, 1.5)
    reentry_gap: int = 10
    min_visible_fraction: float = 0.3

    def __post_init__(self) -> None:
        if not 2 <= int(self.n_cameras) <= 8:
            raise ValueError(f"MulticamConfig.n_cameras must be in 2..8, got {self.n_cameras}")
        for name in ("n_people", "camera_distance", "camera_height", "hfov_deg", "walk_speed"):
            lo, hi = getattr(self, name)
            if not 0 < lo <= hi:
                raise ValueError(f"MulticamConfig.{name} must be (min, max), 0 < min <= max")
        if self.camera_distance[0] <= 0.5 * self.area:
            raise ValueError("MulticamConfig.camera_distance must exceed half the floor's side")
        if self.hfov_deg[1] >= 150:
            raise ValueError("MulticamConfig.hfov_deg must stay below 150 degrees")


@dataclass(frozen=True, eq=False)
class MulticamScene:
    """A simulated multi-camera scene.

    Attributes:
        cameras: ``{name: Camera}`` of the static cameras, ``cam1``, ``cam2``, ...
        boxes: ``{name: {frame: FrameBoxes}}`` with per-camera track ids (the input).
        gt: ``{name: {frame: FrameBoxes}}`` the same boxes with global ids (ground truth).
        positions: ``(F, N, 2)`` ground positions of the people, metres; person ``k`` has
            global id ``k + 1``.
        heights: ``(N,)`` body heights, metres.
        fps: frame rate.
    """

    cameras: dict[str, Camera]
    boxes: dict[str, dict[int, FrameBoxes]]
    gt: dict[str, dict[int, FrameBoxes]]
    positions: np.ndarray
    heights: np.ndarray
    fps: float

    @property
    def n_frames(self) -> int:
        """Number of frames F (1..F)."""
        return int(self.positions.shape[0])


def static_cameras(config: MulticamConfig, rng: np.random.Generator) -> dict[str, Camera]:
    """``config.n_cameras`` static cameras around the floor (see the module docstring).

    Camera ``i`` stands at azimuth ``2 pi i / n`` plus up to a quarter step of jitter, so that
    with four or more cameras some face each other nearly head-on.
    """
    n = int(config.n_cameras)
    step = 2.0 * np.pi / n
    cams: dict[str, Camera] = {}
    for i in range(n):
        azimuth = i * step + rng.uniform(-0.25, 0.25) * step
        dist = rng.uniform(*config.camera_distance)
        height = rng.uniform(*config.camera_height)
        centre = np.array([dist * np.cos(azimuth), dist * np.sin(azimuth), height])
        r = config.aim_spread * np.sqrt(rng.random())
        a = rng.uniform(-np.pi, np.pi)
        aim = np.array([r * np.cos(a), r * np.sin(a)])
        to_aim = aim - centre[:2]
        yaw = float(np.arctan2(to_aim[1], to_aim[0]))
        pitch = float(np.arctan2(height - 0.9, np.hypot(*to_aim)))  # aim at waist height
        roll = float(np.radians(rng.uniform(-config.roll_deg, config.roll_deg)))
        width, img_h = _SIZES[int(rng.integers(len(_SIZES)))]
        K = intrinsics_from_fov(width, img_h, rng.uniform(*config.hfov_deg))
        cams[f"cam{i + 1}"] = Camera(K, look_rotation(yaw, pitch, roll), centre, width, img_h)
    return cams


def _track_ids(gt: dict[int, FrameBoxes], gap: int, rng: np.random.Generator
               ) -> dict[int, FrameBoxes]:
    """Per-camera track ids of ground-truth boxes: a new id per (person, visit), a visit ending
    after more than ``gap`` unseen frames; ids scrambled (drawn without replacement)."""
    last_seen: dict[int, int] = {}
    track_of: dict[int, int] = {}
    n_tracks = 0
    raw: dict[int, np.ndarray] = {}
    for f in sorted(gt):
        ids = gt[f].ids
        out = np.empty_like(ids)
        for j, pid in enumerate(ids.tolist()):
            if pid not in track_of or f - last_seen[pid] > gap + 1:
                track_of[pid] = n_tracks
                n_tracks += 1
            last_seen[pid] = f
            out[j] = track_of[pid]
        raw[f] = out
    names = rng.choice(900_000, size=n_tracks, replace=False) + 1
    return {f: FrameBoxes(f, names[raw[f]], gt[f].boxes) for f in sorted(gt)}


def _walk_config(config: MulticamConfig) -> SceneConfig:
    """The walk model's configuration of a multi-camera scene."""
    return SceneConfig(n_people=config.n_people, area=config.area, fps=config.fps,
                       walk_speed=config.walk_speed, min_separation=0.6,
                       min_visible_fraction=config.min_visible_fraction, hor_near_clip=0.5)


def multicam_walks(config: MulticamConfig, n_frames: int, seed: int
                   ) -> tuple[PeopleState, dict[str, Camera], np.random.Generator]:
    """The people's walks and the static cameras of the scene of ``seed``, and the generator
    they were drawn from (its later draws give the per-camera track ids).

    :func:`simulate_multicam_scene` and the renderer
    (:mod:`xvmatch.datasets.render.multicam_render`) both start here, so a seed gives the same
    people and cameras to the box simulator and to the images. Person ``k`` of the walks has global
    id ``k + 1``.
    """
    rng = np.random.default_rng([int(seed), 32])
    walks = simulate_walks(_walk_config(config), n_frames, rng)
    cameras = static_cameras(config, rng)
    return walks, cameras, rng


def per_camera_track_ids(gt: dict[int, FrameBoxes], gap: int, rng: np.random.Generator
                         ) -> dict[int, FrameBoxes]:
    """One camera's boxes with per-camera track ids instead of global ids: a new id per
    (person, visit), a visit ending after more than ``gap`` unseen frames, scrambled (drawn
    without replacement from 1..900000 with ``rng``)."""
    return _track_ids(gt, gap, rng)


def simulate_multicam_scene(config: MulticamConfig | None = None, n_frames: int = 200,
                            seed: int = 0) -> MulticamScene:
    """A seeded multi-camera scene (deterministic: the same seed gives the same scene).

    Args:
        config: the scene's configuration (defaults: 4 cameras, 12 people, 24 m floor).
        n_frames: number of frames F >= 1.
        seed: random seed.

    Returns:
        The :class:`MulticamScene`, without noise (:func:`add_tracker_noise` adds it).
    """
    config = config or MulticamConfig()
    walks, cameras, rng = multicam_walks(config, n_frames, seed)
    walk_cfg = _walk_config(config)
    n = walks.n_people
    # Global ids 1..N; a placeholder "wearer" (id 0) far off the floor, which
    # project_hor_boxes leaves out of every view, lets us reuse its occlusion model as is.
    far = np.full((walks.n_frames, 1, 2), 1e4)
    people = PeopleState(
        positions=np.concatenate([far, walks.positions], axis=1),
        heights=np.concatenate([[1.7], walks.heights]),
        widths=np.concatenate([[0.45], walks.widths]),
        headings=np.concatenate([np.zeros((walks.n_frames, 1)), walks.headings], axis=1),
        ids=np.arange(n + 1), wearer=0,
        head_yaw=walks.head_yaw, head_pitch=walks.head_pitch, head_roll=walks.head_roll,
    )
    gt, boxes = {}, {}
    for name, cam in cameras.items():
        gt[name] = project_hor_boxes(people, [cam] * walks.n_frames, walk_cfg)
        boxes[name] = _track_ids(gt[name], config.reentry_gap, rng)
    return MulticamScene(cameras, boxes, gt, walks.positions.copy(), walks.heights.copy(),
                         float(config.fps))


@dataclass(frozen=True)
class TrackerNoise:
    """Tracker-like noise on one camera's boxes and track ids.

    Attributes:
        detector: jitter, misses and false boxes (:class:`DetectorNoise`, ``xvmatch noise``).
        switch_per_frame: expected id switches per frame: two tracks whose boxes overlap swap
            ids from that frame on.
        fragment_per_track: expected fragments per track: the track takes a new id from a
            random frame on.
    """

    detector: DetectorNoise = field(default_factory=DetectorNoise)
    switch_per_frame: float = 0.02
    fragment_per_track: float = 0.2


def add_tracker_noise(scene: MulticamScene, noise: TrackerNoise, seed: int) -> MulticamScene:
    """The scene with ``noise`` on every camera's input boxes (``gt`` unchanged), seeded.

    Camera ``i`` (0-based) draws detector noise with seed ``seed * 64 + i`` (view ``"hor"``)
    and its switches and fragments from ``default_rng([seed, i, 7])``. False boxes whose foot
    point lies above the horizon (in the sky of an oblique camera) are dropped: ``xvmatch
    multicam`` refuses such input, and a real detector's false boxes stand on something.
    """
    noisy = {}
    for i, (name, frames) in enumerate(scene.boxes.items()):
        cam = scene.cameras[name]
        det = apply_detector_noise(frames, cam.image_size, noise.detector, seed=seed * 64 + i,
                                   view="hor")
        det = _on_the_floor(det, cam)
        noisy[name] = _switch_and_fragment(det, noise, np.random.default_rng([seed, i, 7]))
    return replace(scene, boxes=noisy)


def _on_the_floor(frames: dict[int, FrameBoxes], camera: Camera) -> dict[int, FrameBoxes]:
    """Drop boxes whose foot point lies above the camera's horizon (false boxes drawn in the
    sky of an oblique camera: no person stands there, and multicam refuses such input)."""
    from xvmatch.geometry.ground_plane import GroundCamera, foot_points

    ground = GroundCamera.from_camera(camera)
    out = {}
    for f, rec in frames.items():
        _, ok = ground.to_ground(foot_points(rec.boxes))
        out[f] = FrameBoxes(f, rec.ids[ok], rec.boxes[ok])
    return out


def _switch_and_fragment(frames: dict[int, FrameBoxes], noise: TrackerNoise,
                         rng: np.random.Generator) -> dict[int, FrameBoxes]:
    """Id switches between overlapping boxes and fragments of tracks, in frame order."""
    from xvmatch.geometry.box_overlap import box_iou

    keys = sorted(frames)
    ids = {f: frames[f].ids.copy() for f in keys}
    all_ids = np.unique(np.concatenate([ids[f] for f in keys] or [np.empty(0, np.int64)]))
    next_id = 900_001  # above the scrambled track ids, below the false boxes' ids
    rename: dict[int, int] = {}
    # Fragments: each track is cut with probability fragment_per_track at a random frame.
    cut_at = {int(t): int(rng.choice(keys)) for t in all_ids
              if rng.random() < noise.fragment_per_track}
    for f in keys:
        for t in ids[f]:
            if cut_at.get(int(t)) == f:
                rename[int(t)] = next_id
                next_id += 1
        cur = np.array([rename.get(int(t), int(t)) for t in ids[f]], dtype=np.int64)
        if len(cur) >= 2 and rng.random() < noise.switch_per_frame:
            iou = box_iou(frames[f].boxes, frames[f].boxes)
            np.fill_diagonal(iou, 0.0)
            a, b = np.unravel_index(np.argmax(iou), iou.shape)
            if iou[a, b] > 0:
                ta, tb = int(ids[f][a]), int(ids[f][b])
                ra, rb = rename.get(ta, ta), rename.get(tb, tb)
                rename[ta], rename[tb] = rb, ra
                cur[a], cur[b] = rb, ra
        ids[f] = cur
    return {f: FrameBoxes(f, ids[f], frames[f].boxes) for f in keys}


def write_multicam_scene(root: str | os.PathLike, scene: MulticamScene) -> dict[str, Path]:
    """Write the scene in today's formats under ``root`` (created if missing).

    Files: ``cameras.json``, ``boxes/NAME.txt`` (per-camera track ids), ``gt/NAME.txt``
    (global ids) and ``ground_gt.csv`` (``frame,global_id,X,Y``, every person on every frame
    some camera sees them), each written atomically.

    Returns:
        ``{"cameras": path, "boxes": folder, "gt": folder, "ground": path}``.
    """
    root = Path(root)
    (root / "boxes").mkdir(parents=True, exist_ok=True)
    (root / "gt").mkdir(exist_ok=True)
    save_cameras(root / "cameras.json", scene.cameras)
    for name in scene.cameras:
        write_mot_boxes(root / "boxes" / f"{name}.txt", scene.boxes[name])
        write_mot_boxes(root / "gt" / f"{name}.txt", scene.gt[name])
    seen = np.zeros(scene.positions.shape[:2], dtype=bool)
    for frames in scene.gt.values():
        for f, rec in frames.items():
            seen[f - 1, rec.ids - 1] = True
    f_idx, p_idx = np.nonzero(seen)
    xy = scene.positions[f_idx, p_idx]
    lines = ["frame,global_id,X,Y"] + [
        f"{f + 1},{p + 1},{x:.4f},{y:.4f}" for f, p, (x, y) in zip(f_idx, p_idx, xy, strict=True)
    ]
    atomic_write_text(root / "ground_gt.csv", "\n".join(lines) + "\n")
    return {"cameras": root / "cameras.json", "boxes": root / "boxes", "gt": root / "gt",
            "ground": root / "ground_gt.csv"}
