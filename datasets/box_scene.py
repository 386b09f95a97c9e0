"""Box-level synthetic scenes for the complementary top / horizontal views (no rendering).

A scene is a group of people walking on flat ground (z = 0, metres, z up), seen by a nadir camera
on a drone above the area centre (the top view) and by a camera worn on the head of one of them
(the horizontal view), as in the CVMHAT dataset. The module keeps two things apart:

* the 3D scene state, :class:`PeopleState`: where every person stands on every frame, their
  size, body heading, and the head pose of the camera wearer. It is the single source of truth a
  renderer (people as upright cylinders of their height and width) or a tracker reuses;
* the box projection, :func:`project_boxes`: the MOTChallenge-style boxes an ideal annotator would
  draw in each view, with the CVMHAT conventions (top-view id 0 is the camera wearer, who is
  never in the horizontal view; the same id is the same person in both views).

Geometry of the boxes, matching what the association method reads from them (Section 3.2 of the
CVMHAT paper): the top-view box centre is the projection of the person's ground position, its size
that of a head-and-shoulders footprint; the horizontal-view box spans the person's upright extent
(feet to head, +- half width), so its height carries depth (h ~ f H / d). Horizontal-view
occlusion is computed exactly on the arrangement of box edges: a nearer person hides the part of
a farther one that its box covers.

The ids are ground truth only: association code must never compare ids across views.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from xvmatch.formats.mot_boxes import FrameBoxes, write_mot_boxes
from xvmatch.geometry.camera import Camera, intrinsics_from_fov, look_rotation

__all__ = [
    "BoxScene",
    "PeopleState",
    "SceneConfig",
    "horizontal_cameras",
    "project_boxes",
    "project_hor_boxes",
    "project_top_boxes",
    "simulate_box_scene",
    "simulate_walks",
    "top_view_camera",
    "write_box_scene",
]

# Depth (m) of the top of a person's shoulders below the top of the head: the top-view footprint
# is scaled at that height, where the head-and-shoulders outline a drone annotator boxes lies.
_SHOULDER_DROP = 0.25
# Range (m) and gain (m/s) of the social repulsion that keeps walkers from bumping into others.
_REPULSION_RANGE = 1.5
_REPULSION_GAIN = 0.6
# Rate (1/s) at which a walker near the edge turns back towards the area centre.
_EDGE_TURN_RATE = 2.0
# Time constant (s) of the low-pass that keeps the wearer's gaze target smooth.
_GAZE_SMOOTHING = 0.5
# Time constant (s) of the pitch / roll wobble of the head-worn camera.
_WOBBLE_TIME = 1.0


@dataclass(frozen=True)
class SceneConfig:
    """Everything that shapes a synthetic scene; defaults mimic the CVMHAT sequences.

    Lengths are metres, angles degrees, times seconds, image sizes ``(width, height)`` pixels.

    Attributes:
        n_people: (min, max) number of people, the camera wearer included, drawn uniformly
            (inclusive) once per scene. CVMHAT has 8-12 people per top-view frame.
        area: side of the square walking area, centred on the world origin. The default 20 m
            fits inside the top view (46 m x 26 m at 40 m altitude and 60 degrees), as in CVMHAT
            where every person is in the top view, and gives the real scenes' spread: their
            top-view extent is 8-17 m by 5-11 m, the median distance to the wearer 5-11 m.
        height_range: (min, max) body height, drawn uniformly per person.
        width_range: (min, max) body width (shoulder breadth of the upright cylinder).
        min_separation: smallest distance between two people's ground positions; must be at
            least ``width_range[1]`` so that two body cylinders never intersect.
        fps: frame rate; speeds and rates below are per second and converted with it.
        walk_speed: (min, max) preferred walking speed, drawn uniformly per person.
        turn_rate_std_deg: stationary standard deviation of the angular velocity of walking
            (an Ornstein-Uhlenbeck process, so headings turn smoothly), degrees per second.
        turn_time: correlation time of that angular velocity.
        stop_probability: probability per second that a walking person stops.
        stop_duration: mean duration of a stop (exponentially distributed).
        edge_margin: distance from the area edge at which walkers start turning back inside.
        gaze_at_group: weight in [0, 1] pulling the wearer's view direction from the walking
            direction towards the other people's centroid; the CVMHAT wearers film the group,
            which is why their horizontal view holds most of the others (4-8 of 7-11).
        head_turn_std_deg: stationary standard deviation of the wearer's head yaw about that
            direction (Ornstein-Uhlenbeck, so the head turns smoothly), degrees.
        head_turn_time: correlation time of the head yaw.
        top_altitude: height of the nadir top-view camera above the ground.
        top_hfov_deg: horizontal field of view of the top-view camera.
        top_size: top-view image size.
        top_yaw_deg: orientation of the top image "up" direction in the world (see
            :func:`~xvmatch.geometry.camera.look_rotation`); ``None`` draws it uniformly.
        top_footprint: (across the shoulders, front to back) size of the head-and-shoulders
            outline boxed in the top view; the box is that ellipse's bounding box in the image.
        hor_size: horizontal-view image size.
        hor_hfov_deg: horizontal field of view of the head-worn camera (CVMHAT code uses 90).
        hor_pitch_deg: mean pitch of the head-worn camera (positive looks down).
        hor_roll_deg: mean roll of the head-worn camera.
        hor_wobble_deg: standard deviation of the smooth pitch and roll wobble about those means
            (0 gives the ideal level camera of the paper).
        eye_below_top: the camera sits this far below the top of the wearer's head.
        hor_near_clip: people whose body comes nearer than this to the horizontal camera's image
            plane (depth) are left out, as a detector would fail on a body filling the frame.
        min_visible_fraction: a horizontal-view person whose visible area (not hidden by nearer
            people, inside the image) is below this fraction of the full box is dropped;
            otherwise the box of the visible part is kept.
    """

    n_people: tuple[int, int] = (6, 12)
    area: float = 20.0
    height_range: tuple[float, float] = (1.5, 1.95)
    width_range: tuple[float, float] = (0.4, 0.5)
    min_separation: float = 0.5
    fps: float = 30.0
    walk_speed: tuple[float, float] = (0.3, 1.2)
    turn_rate_std_deg: float = 30.0
    turn_time: float = 2.0
    stop_probability: float = 0.1
    stop_duration: float = 5.0
    edge_margin: float = 2.0
    gaze_at_group: float = 0.8
    head_turn_std_deg: float = 20.0
    head_turn_time: float = 1.5
    top_altitude: float = 40.0
    top_hfov_deg: float = 60.0
    top_size: tuple[int, int] = (2688, 1512)
    top_yaw_deg: float | None = None
    top_footprint: tuple[float, float] = (0.6, 0.45)
    hor_size: tuple[int, int] = (2688, 1512)
    hor_hfov_deg: float = 90.0
    hor_pitch_deg: float = 0.0
    hor_roll_deg: float = 0.0
    hor_wobble_deg: float = 1.0
    eye_below_top: float = 0.1
    hor_near_clip: float = 0.3
    min_visible_fraction: float = 0.3

    def __post_init__(self) -> None:
        def ordered(name: str, pair: Sequence[float], low: float) -> None:
            if len(pair) != 2 or not low <= pair[0] <= pair[1]:
                raise ValueError(
                    f"SceneConfig.{name} must be (min, max) with {low} <= min <= max, got {pair}"
                )

        ordered("n_people", self.n_people, 1)
        ordered("height_range", self.height_range, 1e-6)
        ordered("width_range", self.width_range, 1e-6)
        ordered("walk_speed", self.walk_speed, 0.0)
        positive = {
            "area": self.area,
            "fps": self.fps,
            "turn_time": self.turn_time,
            "stop_duration": self.stop_duration,
            "head_turn_time": self.head_turn_time,
            "top_altitude": self.top_altitude,
            "hor_near_clip": self.hor_near_clip,
        }
        for name, value in positive.items():
            if not value > 0:
                raise ValueError(f"SceneConfig.{name} must be > 0, got {value}")
        non_negative = {
            "turn_rate_std_deg": self.turn_rate_std_deg,
            "stop_probability": self.stop_probability,
            "edge_margin": self.edge_margin,
            "head_turn_std_deg": self.head_turn_std_deg,
            "hor_wobble_deg": self.hor_wobble_deg,
            "eye_below_top": self.eye_below_top,
        }
        for name, value in non_negative.items():
            if not value >= 0:
                raise ValueError(f"SceneConfig.{name} must be >= 0, got {value}")
        if self.min_separation < self.width_range[1]:
            raise ValueError(
                f"SceneConfig.min_separation ({self.min_separation}) must be >= the largest "
                f"width ({self.width_range[1]}) so that bodies never intersect"
            )
        if self.eye_below_top >= self.height_range[0]:
            raise ValueError("SceneConfig.eye_below_top must be smaller than every height")
        if self.top_altitude <= self.height_range[1]:
            raise ValueError("SceneConfig.top_altitude must be above the tallest person")
        if not 0.0 <= self.gaze_at_group <= 1.0:
            raise ValueError(
                f"SceneConfig.gaze_at_group must be in [0, 1], got {self.gaze_at_group}"
            )
        if not 0.0 <= self.min_visible_fraction <= 1.0:
            raise ValueError(
                "SceneConfig.min_visible_fraction must be in [0, 1], "
                f"got {self.min_visible_fraction}"
            )
        if min(self.top_footprint) <= 0:
            raise ValueError(f"SceneConfig.top_footprint must be > 0, got {self.top_footprint}")
        side = self.area - self.min_separation
        if side <= 0 or (self.n_people[1] * self.min_separation**2 > 0.5 * side**2):
            raise ValueError(
                f"SceneConfig.area ({self.area} m) is too small for {self.n_people[1]} people "
                f"{self.min_separation} m apart; enlarge area or lower n_people"
            )


@dataclass(frozen=True, eq=False)
class PeopleState:
    """The 3D state of a scene over time: what a renderer or a tracker needs, no camera.

    People are upright cylinders of their height and width standing on the ground plane z = 0.
    Equality is identity (the record holds arrays).

    Attributes:
        positions: ``(F, N, 2)`` ground positions (x, y) in metres, frame-major (frame f is
            ``positions[f - 1]``, frames being 1-based in the box records).
        heights: ``(N,)`` body heights in metres.
        widths: ``(N,)`` body widths in metres.
        headings: ``(F, N)`` body (walking) direction, radians counter-clockwise from world x;
            kept while a person stands still.
        ids: ``(N,)`` int64 person ids; ``ids[wearer] == 0``.
        wearer: index (into N) of the horizontal-view camera wearer.
        head_yaw: ``(F,)`` the wearer's view direction (radians, as ``headings``); it differs
            from the walking direction because the head turns.
        head_pitch: ``(F,)`` pitch of the head-worn camera, radians, positive looks down.
        head_roll: ``(F,)`` roll of the head-worn camera, radians.
    """

    positions: np.ndarray
    heights: np.ndarray
    widths: np.ndarray
    headings: np.ndarray
    ids: np.ndarray
    wearer: int
    head_yaw: np.ndarray
    head_pitch: np.ndarray
    head_roll: np.ndarray

    def __post_init__(self) -> None:
        pos = np.asarray(self.positions, dtype=np.float64)
        if pos.ndim != 3 or pos.shape[2] != 2:
            raise ValueError(f"PeopleState.positions must have shape (F, N, 2), got {pos.shape}")
        n_frames, n_people = pos.shape[:2]
        arrays = {
            "heights": ((n_people,), np.float64),
            "widths": ((n_people,), np.float64),
            "headings": ((n_frames, n_people), np.float64),
            "ids": ((n_people,), np.int64),
            "head_yaw": ((n_frames,), np.float64),
            "head_pitch": ((n_frames,), np.float64),
            "head_roll": ((n_frames,), np.float64),
        }
        for name, (shape, dtype) in arrays.items():
            arr = np.asarray(getattr(self, name), dtype=dtype)
            if arr.shape != shape:
                raise ValueError(f"PeopleState.{name} must have shape {shape}, got {arr.shape}")
            object.__setattr__(self, name, arr)
        if not 0 <= int(self.wearer) < n_people:
            raise ValueError(f"PeopleState.wearer must index one of {n_people} people")
        if np.unique(self.ids).size != n_people:
            raise ValueError("PeopleState.ids must be distinct")
        if self.ids[int(self.wearer)] != 0:
            raise ValueError("PeopleState: the wearer must have id 0 (the CVMHAT convention)")
        if not ((self.heights > 0).all() and (self.widths > 0).all()):
            raise ValueError("PeopleState.heights and widths must be > 0")
        object.__setattr__(self, "positions", pos)
        object.__setattr__(self, "wearer", int(self.wearer))

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return int(self.positions.shape[0])

    @property
    def n_people(self) -> int:
        """Number of people N, the wearer included."""
        return int(self.positions.shape[1])


@dataclass(frozen=True, eq=False)
class BoxScene:
    """A simulated scene: its state, its cameras and the boxes of both views.

    Attributes:
        config: the configuration it was drawn from.
        people: the 3D state over all frames.
        top_camera: the nadir drone camera (fixed over the sequence).
        hor_cameras: one head-worn camera per frame (``hor_cameras[f - 1]`` for frame f).
        top: ``{frame: FrameBoxes}`` of the top view, frames 1..F (possibly empty records).
        hor: ``{frame: FrameBoxes}`` of the horizontal view, frames 1..F.
    """

    config: SceneConfig
    people: PeopleState
    top_camera: Camera
    hor_cameras: list[Camera]
    top: dict[int, FrameBoxes]
    hor: dict[int, FrameBoxes]


# --------------------------------------------------------------------------------------------
# Walks


def _wrap(angle: np.ndarray) -> np.ndarray:
    """Angles wrapped to [-pi, pi)."""
    return np.mod(angle + np.pi, 2.0 * np.pi) - np.pi


def _ou_step(value: np.ndarray, std: float, tau: float, dt: float, noise: np.ndarray) -> np.ndarray:
    """One exact Ornstein-Uhlenbeck step with stationary ``std`` and correlation time ``tau``."""
    decay = np.exp(-dt / tau)
    return decay * value + std * np.sqrt(1.0 - decay**2) * noise


def _separate(points: np.ndarray, min_sep: float, bound: float, iters: int = 100) -> np.ndarray:
    """Push ``(N, 2)`` points until all pairs are ``min_sep`` apart, inside ``[-bound, bound]``.

    Each pass moves both members of every too-close pair half their overlap apart along their
    line (pairs at the same spot separate along x, lower index to the left); a few passes settle
    the sparse crowds simulated here.
    """
    pts = np.clip(points, -bound, bound)
    n = pts.shape[0]
    if n < 2:
        return pts
    target = min_sep * (1.0 + 1e-6)
    order = np.sign(np.arange(n)[:, None] - np.arange(n)[None, :]).astype(float)
    for _ in range(iters):
        diff = pts[:, None, :] - pts[None, :, :]
        dist = np.hypot(diff[..., 0], diff[..., 1])
        np.fill_diagonal(dist, np.inf)
        overlap = np.clip(target - dist, 0.0, None)
        if not overlap.any():
            break
        with np.errstate(invalid="ignore", divide="ignore"):
            unit = np.where((dist > 0)[..., None], diff / dist[..., None], 0.0)
        unit[..., 0] = np.where(dist == 0, order, unit[..., 0])
        pts = np.clip(pts + 0.5 * (overlap[..., None] * unit).sum(axis=1), -bound, bound)
    return pts


def _repulsion(pos: np.ndarray, not_self: np.ndarray, min_separation: float) -> np.ndarray:
    """Social push ``(N, 2)`` on every person from the people within :data:`_REPULSION_RANGE`."""
    diff = pos[:, None, :] - pos[None, :, :]
    dist = np.hypot(diff[..., 0], diff[..., 1])
    near = not_self & (dist < _REPULSION_RANGE)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(
            near[..., None],
            diff / dist[..., None]
            * np.exp(-(dist[..., None] - min_separation) / 0.5),
            0.0,
        ).sum(axis=1)


def _step_walkers(
    rng: np.random.Generator, config: SceneConfig, pos: np.ndarray, phi: np.ndarray,
    omega: np.ndarray, stop_left: np.ndarray, speeds: np.ndarray, bound: float,
    not_self: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Advance every walker by one frame: turn, stop or go, avoid others, stay apart.

    Draws, in order: N turn-rate noises, N stop draws and N stop durations.

    Args:
        rng: random generator.
        config: scene configuration.
        pos: ``(N, 2)`` positions, metres.
        phi: ``(N,)`` walking directions, radians.
        omega: ``(N,)`` angular velocities, radians per second.
        stop_left: ``(N,)`` seconds of standing left (<= 0 walks).
        speeds: ``(N,)`` preferred speeds, metres per second.
        bound: half side of the square the positions stay in.
        not_self: ``(N, N)`` mask of the pairs of different people.

    Returns:
        The new ``(pos, phi, omega, stop_left)``.
    """
    n = pos.shape[0]
    dt = 1.0 / config.fps
    turn_std = np.radians(config.turn_rate_std_deg)
    omega = _ou_step(omega, turn_std, config.turn_time, dt, rng.standard_normal(n))
    phi = phi + omega * dt
    # Near the edge, turn back towards the centre, the harder the closer.
    edge = np.clip(1.0 - (bound - np.abs(pos).max(axis=1)) / max(config.edge_margin, 1e-9),
                   0.0, 1.0)
    inward = np.arctan2(-pos[:, 1], -pos[:, 0])
    phi = phi + _wrap(inward - phi) * np.clip(edge * _EDGE_TURN_RATE * dt, 0.0, 1.0)
    # Stops: a walker stops with the configured rate, a stopper counts down.
    starts = (stop_left <= 0) & (rng.random(n) < config.stop_probability * dt)
    durations = rng.exponential(config.stop_duration, size=n)
    stop_left = np.where(starts, durations, stop_left - dt)
    walking = stop_left <= 0
    vel = (speeds * walking)[:, None] * np.stack([np.cos(phi), np.sin(phi)], axis=1)
    # Social repulsion from people within range, for walkers only.
    push = _repulsion(pos, not_self, config.min_separation)
    vel = vel + _REPULSION_GAIN * walking[:, None] * push
    new = _separate(pos + vel * dt, config.min_separation, bound)
    step = new - pos
    moved = walking & (np.hypot(step[:, 0], step[:, 1]) > 0.25 * speeds * dt)
    phi = np.where(moved, np.arctan2(step[:, 1], step[:, 0]), phi)
    return new, phi, omega, stop_left


def _wearer_gaze(
    pos: np.ndarray, phi0: float, gaze: float, first: bool, config: SceneConfig
) -> float:
    """The wearer's gaze: a smoothed blend of their walking direction and the group direction.

    Args:
        pos: ``(N, 2)`` positions; index 0 is the wearer.
        phi0: the wearer's walking direction, radians.
        gaze: the previous frame's gaze, radians.
        first: whether this is the first frame (the gaze jumps to its target).
        config: scene configuration.

    Returns:
        The new gaze, radians in [-pi, pi).
    """
    dt = 1.0 / config.fps
    walk_dir = np.array([np.cos(phi0), np.sin(phi0)])
    target_vec = (1.0 - config.gaze_at_group) * walk_dir
    if pos.shape[0] > 1:
        to_group = pos[1:].mean(axis=0) - pos[0]
        norm = np.hypot(*to_group)
        if norm > 1e-9:
            target_vec = target_vec + config.gaze_at_group * to_group / norm
    if np.hypot(*target_vec) > 1e-9:
        target = float(np.arctan2(target_vec[1], target_vec[0]))
        blend = 1.0 if first else 1.0 - np.exp(-dt / _GAZE_SMOOTHING)
        gaze = float(_wrap(gaze + blend * _wrap(target - gaze)))
    return gaze


def simulate_walks(config: SceneConfig, n_frames: int, rng: np.random.Generator) -> PeopleState:
    """Smooth random walks with turns and stops, inside the area, never overlapping.

    Every person has a preferred speed; the walking direction turns with an Ornstein-Uhlenbeck
    angular velocity, people stop (probability ``stop_probability`` per second) for an
    exponential time, turn back inside near the area edge, and are steered away from nearby
    people; a final projection enforces ``min_separation`` exactly. Index 0 is the camera wearer
    (id 0); the others have ids 1..N-1. The wearer's head looks along a smoothed blend of the
    walking direction and the direction of the group centroid, plus a smooth random head turn.

    Args:
        config: scene configuration.
        n_frames: number of frames F >= 1.
        rng: the only source of randomness (seeded by the caller).

    Returns:
        The :class:`PeopleState` of F frames.
    """
    if int(n_frames) < 1:
        raise ValueError(f"n_frames must be >= 1, got {n_frames}")
    n_frames = int(n_frames)
    dt = 1.0 / config.fps
    n = int(rng.integers(config.n_people[0], config.n_people[1] + 1))
    heights = rng.uniform(*config.height_range, size=n)
    widths = rng.uniform(*config.width_range, size=n)
    speeds = rng.uniform(*config.walk_speed, size=n)
    bound = 0.5 * config.area - 0.5 * config.min_separation
    turn_std = np.radians(config.turn_rate_std_deg)
    head_std = np.radians(config.head_turn_std_deg)
    wobble_std = np.radians(config.hor_wobble_deg)

    pos = _separate(rng.uniform(-bound, bound, size=(n, 2)), config.min_separation, bound)
    phi = rng.uniform(-np.pi, np.pi, size=n)
    omega = turn_std * rng.standard_normal(n)
    # Start in the stationary mix of walking and standing people.
    stop_rate = config.stop_probability * config.stop_duration
    standing = rng.random(n) < stop_rate / (1.0 + stop_rate)
    stop_left = np.where(standing, rng.exponential(config.stop_duration, size=n), 0.0)
    head_turn = head_std * rng.standard_normal()
    wobble = wobble_std * rng.standard_normal(2)
    gaze = float(phi[0])

    positions = np.empty((n_frames, n, 2))
    headings = np.empty((n_frames, n))
    head = np.empty((n_frames, 3))
    not_self = ~np.eye(n, dtype=bool)
    for t in range(n_frames):
        if t > 0:
            pos, phi, omega, stop_left = _step_walkers(rng, config, pos, phi, omega, stop_left,
                                                       speeds, bound, not_self)
            head_turn = _ou_step(head_turn, head_std, config.head_turn_time, dt,
                                 rng.standard_normal())
            wobble = _ou_step(wobble, wobble_std, _WOBBLE_TIME, dt, rng.standard_normal(2))
        gaze = _wearer_gaze(pos, phi[0], gaze, t == 0, config)
        positions[t] = pos
        headings[t] = _wrap(phi)
        head[t] = (
            _wrap(gaze + head_turn),
            np.radians(config.hor_pitch_deg) + wobble[0],
            np.radians(config.hor_roll_deg) + wobble[1],
        )
    return PeopleState(
        positions=positions,
        heights=heights,
        widths=widths,
        headings=headings,
        ids=np.arange(n, dtype=np.int64),
        wearer=0,
        head_yaw=head[:, 0],
        head_pitch=head[:, 1],
        head_roll=head[:, 2],
    )


# --------------------------------------------------------------------------------------------
# Cameras


def top_view_camera(config: SceneConfig, yaw: float = 0.0) -> Camera:
    """The nadir drone camera at ``top_altitude`` above the area centre.

    Args:
        config: scene configuration (altitude, field of view, image size).
        yaw: radians; the world direction the top image's "up" points to.
    """
    width, height = config.top_size
    return Camera(
        K=intrinsics_from_fov(width, height, config.top_hfov_deg),
        R=look_rotation(yaw, np.pi / 2.0),
        c=np.array([0.0, 0.0, config.top_altitude]),
        width=width,
        height=height,
    )


def horizontal_cameras(people: PeopleState, config: SceneConfig) -> list[Camera]:
    """The head-worn camera of every frame: at the wearer's eye, along the head pose.

    The centre is above the wearer's ground position at ``height - eye_below_top``; the
    orientation is ``look_rotation(head_yaw, head_pitch, head_roll)``.
    """
    width, height = config.hor_size
    K = intrinsics_from_fov(width, height, config.hor_hfov_deg)
    eye = people.heights[people.wearer] - config.eye_below_top
    xy = people.positions[:, people.wearer]
    return [
        Camera(
            K=K,
            R=look_rotation(yaw, pitch, roll),
            c=np.array([x, y, eye]),
            width=width,
            height=height,
        )
        for (x, y), yaw, pitch, roll in zip(
            xy.tolist(),
            people.head_yaw.tolist(),
            people.head_pitch.tolist(),
            people.head_roll.tolist(),
            strict=True,
        )
    ]


# --------------------------------------------------------------------------------------------
# Boxes


def _frame_records(
    n_frames: int, frame_index: np.ndarray, ids: np.ndarray, boxes: np.ndarray
) -> dict[int, FrameBoxes]:
    """Split flat rows (sorted by frame then id) into ``{frame: FrameBoxes}`` for frames 1..F."""
    bounds = np.searchsorted(frame_index, np.arange(n_frames + 1))
    return {
        f + 1: FrameBoxes(f + 1, ids[bounds[f] : bounds[f + 1]], boxes[bounds[f] : bounds[f + 1]])
        for f in range(n_frames)
    }


def project_top_boxes(
    people: PeopleState, camera: Camera, config: SceneConfig
) -> dict[int, FrameBoxes]:
    """Top-view boxes of every frame: head-and-shoulders outlines centred on the ground position.

    The box centre is the projection of the ground position (x, y, 0), the quantity the CVMHAT
    method reads from the top view. Its size is the image bounding box of the
    ``top_footprint`` ellipse (across the shoulders x front to back, oriented by the body
    heading) at shoulder height. A person is kept when the box centre is inside the image; the
    box itself is not clipped (real top-view boxes also run slightly past the border).

    Returns:
        ``{frame: FrameBoxes}`` for frames 1..F, ids ascending within a frame.
    """
    n_frames, n = people.n_frames, people.n_people
    ground = np.concatenate([people.positions, np.zeros((n_frames, n, 1))], axis=2)
    centre, _ = camera.project(ground)
    shoulder_z = np.broadcast_to(people.heights - _SHOULDER_DROP, (n_frames, n))[..., None]
    shoulders = np.concatenate([people.positions, shoulder_z], axis=2)
    depth = camera.depth(shoulders)
    # Image axes as world ground directions, and the ellipse half-axes along them.
    axes = camera.R[:2, :2]  # rows: image x and y directions, world (x, y) components
    fwd = np.stack([np.cos(people.headings), np.sin(people.headings)], axis=-1)
    across = np.stack([-fwd[..., 1], fwd[..., 0]], axis=-1)
    half_across, half_fwd = 0.5 * config.top_footprint[0], 0.5 * config.top_footprint[1]
    half_m = np.hypot(half_across * (across @ axes.T), half_fwd * (fwd @ axes.T))  # (F, N, 2)
    focal = np.array([camera.K[0, 0], camera.K[1, 1]])
    with np.errstate(divide="ignore", invalid="ignore"):
        half_px = half_m * focal / depth[..., None]
    keep = camera.in_image(np.nan_to_num(centre, nan=-1.0)) & (depth > 0)
    frame_index, person = np.nonzero(keep)  # frame-major, ids ascending (ids == index order)
    order = np.lexsort((people.ids[person], frame_index))
    frame_index, person = frame_index[order], person[order]
    c = centre[frame_index, person]
    hp = half_px[frame_index, person]
    boxes = np.concatenate([c - hp, 2.0 * hp], axis=1)
    return _frame_records(n_frames, frame_index, people.ids[person], boxes)


def _visible_parts(
    boxes: np.ndarray, depth: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Visible area and visible-part bounding box of overlapping boxes, nearest in front.

    The distinct box edges cut the image into cells on which the set of covering boxes is
    constant; each cell belongs to its nearest covering box. This is exact and vectorised, with
    ``(2Q + 1)^2`` cells for Q boxes.

    Args:
        boxes: ``(Q, 4)`` x0, y0, x1, y1 (already clipped to the image), positive size.
        depth: ``(Q,)`` occlusion depth of each box (smaller is nearer).

    Returns:
        (area, visible): ``(Q,)`` visible areas in square pixels and ``(Q, 4)`` x0, y0, x1, y1 of
        the bounding box of each visible part (NaN where nothing is visible).
    """
    q = boxes.shape[0]
    xs = np.unique(boxes[:, [0, 2]])
    ys = np.unique(boxes[:, [1, 3]])
    cx, cy = 0.5 * (xs[:-1] + xs[1:]), 0.5 * (ys[:-1] + ys[1:])
    in_x = (boxes[:, 0:1] <= cx) & (cx < boxes[:, 2:3])  # (Q, Cx)
    in_y = (boxes[:, 1:2] <= cy) & (cy < boxes[:, 3:4])  # (Q, Cy)
    cover = in_y[:, :, None] & in_x[:, None, :]  # (Q, Cy, Cx)
    owner = np.argmin(np.where(cover, depth[:, None, None], np.inf), axis=0)
    visible = cover & (owner[None] == np.arange(q)[:, None, None])
    cell_area = np.diff(ys)[:, None] * np.diff(xs)[None, :]
    area = (visible * cell_area).sum(axis=(1, 2))
    cols, rows = visible.any(axis=1), visible.any(axis=2)
    with np.errstate(invalid="ignore"):
        part = np.stack(
            [
                np.where(cols, xs[:-1], np.inf).min(axis=1),
                np.where(rows, ys[:-1], np.inf).min(axis=1),
                np.where(cols, xs[1:], -np.inf).max(axis=1),
                np.where(rows, ys[1:], -np.inf).max(axis=1),
            ],
            axis=1,
        )
    part[area <= 0] = np.nan
    return area, part


def project_hor_boxes(
    people: PeopleState, cameras: Sequence[Camera], config: SceneConfig
) -> dict[int, FrameBoxes]:
    """Horizontal-view boxes of every frame, with occlusion and image-border truncation.

    Each person but the wearer is an upright body ``widths`` wide from the ground to ``heights``:
    its full box is the image bounding box of the four corners of the vertical rectangle through
    its axis, facing the camera. A person with any corner nearer than ``hor_near_clip`` (or
    behind the camera) is absent, as is one entirely outside the image. Nearer people hide what
    their (clipped) boxes cover of farther ones (:func:`_visible_parts`, depth of the body axis).
    The visible fraction is the visible area over the full, unclipped box area; people below
    ``min_visible_fraction`` are dropped, the others keep the bounding box of their visible part,
    which lies inside the image.

    Args:
        people: scene state of F frames.
        cameras: F cameras, ``cameras[f - 1]`` seeing frame f.
        config: scene configuration (near clip, visibility threshold).

    Returns:
        ``{frame: FrameBoxes}`` for frames 1..F, ids ascending within a frame.
    """
    if len(cameras) != people.n_frames:
        raise ValueError(
            f"project_hor_boxes needs one camera per frame: {people.n_frames} frames, "
            f"{len(cameras)} cameras"
        )
    others = np.flatnonzero(np.arange(people.n_people) != people.wearer)
    others = others[np.argsort(people.ids[others], kind="stable")]
    heights, half_w, ids = people.heights[others], 0.5 * people.widths[others], people.ids[others]
    z = np.stack([np.zeros_like(heights), heights], axis=1)  # (Q, 2) feet and head
    records: dict[int, FrameBoxes] = {}
    for f, cam in enumerate(cameras):
        ground = people.positions[f, others]  # (Q, 2)
        ray = ground - cam.c[:2]
        dist = np.maximum(np.hypot(ray[:, 0], ray[:, 1]), 1e-12)
        side = np.stack([-ray[:, 1], ray[:, 0]], axis=1) / dist[:, None] * half_w[:, None]
        lateral = np.stack([ground - side, ground + side], axis=1)  # (Q, 2, 2)
        corners = np.concatenate(
            [
                np.broadcast_to(lateral[:, :, None, :], (len(ids), 2, 2, 2)),
                np.broadcast_to(z[:, None, :, None], (len(ids), 2, 2, 1)),
            ],
            axis=3,
        ).reshape(len(ids), 4, 3)
        uv, depth = cam.project(corners)
        front = (depth > config.hor_near_clip).all(axis=1)
        uv = np.where(front[:, None, None], uv, 0.0)
        full = np.concatenate([uv.min(axis=1), uv.max(axis=1)], axis=1)  # x0, y0, x1, y1
        full_area = (full[:, 2] - full[:, 0]) * (full[:, 3] - full[:, 1])
        size = np.array([cam.width, cam.height, cam.width, cam.height], dtype=float)
        clipped = np.clip(full, 0.0, size)
        present = (
            front & (clipped[:, 2] > clipped[:, 0]) & (clipped[:, 3] > clipped[:, 1])
            & (full_area > 0)
        )
        idx = np.flatnonzero(present)
        kept_ids = np.empty(0, dtype=np.int64)
        kept_boxes = np.empty((0, 4))
        if idx.size:
            axis_mid = np.concatenate([ground[idx], 0.5 * heights[idx, None]], axis=1)
            area, part = _visible_parts(clipped[idx], cam.depth(axis_mid))
            keep = (area > 0) & (area >= config.min_visible_fraction * full_area[idx])
            kept_ids = ids[idx[keep]]
            part = part[keep]
            kept_boxes = np.concatenate([part[:, :2], part[:, 2:] - part[:, :2]], axis=1)
        records[f + 1] = FrameBoxes(f + 1, kept_ids, kept_boxes)
    return records


def project_boxes(
    people: PeopleState,
    top_camera: Camera,
    hor_cameras: Sequence[Camera],
    config: SceneConfig,
) -> tuple[dict[int, FrameBoxes], dict[int, FrameBoxes]]:
    """Boxes of both views: ``(top, hor)``, each ``{frame: FrameBoxes}`` for frames 1..F.

    See :func:`project_top_boxes` and :func:`project_hor_boxes`. The wearer (id 0) is in the top
    view wherever its centre is inside the image, and never in the horizontal view.
    """
    return (
        project_top_boxes(people, top_camera, config),
        project_hor_boxes(people, hor_cameras, config),
    )


def simulate_box_scene(
    config: SceneConfig | None = None, n_frames: int = 100, seed: int = 0
) -> BoxScene:
    """Draw a scene (walks, cameras) and project its boxes in both views.

    Deterministic: the walks use the stream ``default_rng([seed, 0])`` and the top-camera yaw
    (when ``config.top_yaw_deg`` is None) ``default_rng([seed, 1])``, so changing one does not
    shift the other.

    Args:
        config: scene configuration; ``None`` uses the defaults.
        n_frames: number of frames F >= 1.
        seed: random seed.

    Returns:
        The :class:`BoxScene`.
    """
    config = SceneConfig() if config is None else config
    people = simulate_walks(config, n_frames, np.random.default_rng([seed, 0]))
    if config.top_yaw_deg is None:
        yaw = float(np.random.default_rng([seed, 1]).uniform(-np.pi, np.pi))
    else:
        yaw = float(np.radians(config.top_yaw_deg))
    top_camera = top_view_camera(config, yaw)
    hor_cameras = horizontal_cameras(people, config)
    top, hor = project_boxes(people, top_camera, hor_cameras, config)
    return BoxScene(
        config=config,
        people=people,
        top_camera=top_camera,
        hor_cameras=hor_cameras,
        top=top,
        hor=hor,
    )


def write_box_scene(
    scene: BoxScene, directory: str | os.PathLike, name: str
) -> tuple[Path, Path]:
    """Write ``NAME_top.txt`` and ``NAME_hor.txt`` (CVMHAT / MOTChallenge format) in ``directory``.

    Frames with no box leave no line, as in the real files. Writes are atomic.

    Returns:
        The paths of the top-view and horizontal-view files.
    """
    folder = Path(directory)
    if not folder.is_dir():
        raise ValueError(f"write_box_scene: directory {os.fspath(folder)!r} does not exist")
    top_path, hor_path = folder / f"{name}_top.txt", folder / f"{name}_hor.txt"
    write_mot_boxes(top_path, scene.top)
    write_mot_boxes(hor_path, scene.hor)
    return top_path, hor_path
