"""Calibrated camera rigs of the rendered scenes: a top/overview camera and an egocentric one.

Two scenario families share one walk model, :func:`xvmatch.datasets.box_scene.simulate_walks`
(people with turns and stops over F frames, index 0 = id 0 = the egocentric camera's carrier),
and differ only in their cameras:

* ``"drone"`` (CVMHAT paper): a nadir camera 20-60 m above the area centre and a camera worn on
  the head of one of the walkers. The carrier is visible in the top view (the camera location O).
* ``"overview"`` (geometric-priors paper): a static camera on a building, 8-25 m up and pitched
  25-60 degrees down towards the area, and a camera held at 1.5 m, ``handheld_reach`` in front
  of a pedestrian who is in the overview image but, of course, not in their own.

In both, the egocentric camera turns freely in yaw (it follows the carrier's gaze), and its pitch
and roll stay within +-10 and +-5 degrees; its field of view is drawn per scene in 60-100
degrees. The top/overview camera's field of view is fitted per scene so that the whole walking
area (up to head height) is in its image: every person is in the top view on every frame, as in
CVMHAT. The static buildings around the area (:class:`Building`) belong to the scene too, so the
two views see the same world.

Everything random is drawn from the one generator passed to :func:`make_scene`, in a fixed
order, so a scene is a pure function of its seed.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from xvmatch.datasets.box_scene import (
    PeopleState,
    SceneConfig,
    horizontal_cameras,
    simulate_walks,
    top_view_camera,
)
from xvmatch.geometry.camera import Camera, intrinsics_from_fov, look_rotation

__all__ = [
    "SCENARIOS",
    "Building",
    "SynthConfig",
    "SyntheticScene",
    "fit_hfov",
    "make_scene",
]

SCENARIOS: tuple[str, ...] = ("drone", "overview")
"""The scenario families."""

# Height (m) up to which the walking area must be inside the top/overview image (heads).
_FIT_HEIGHT = 2.0
# Relative margin added to the fitted field of view so nobody touches the image border.
_FIT_MARGIN = 1.08
# Gap (m) between the walking area and the nearest building.
_BUILDING_GAP = 3.0


@dataclass(frozen=True)
class SynthConfig:
    """What shapes a rendered scene; lengths in metres, angles in degrees, sizes in pixels.

    Attributes:
        scenario: ``"drone"`` or ``"overview"`` (see the module docstring).
        n_people: (min, max) people per scene, the camera carrier included, drawn uniformly.
        top_size: (width, height) of the top/overview image.
        ego_size: (width, height) of the egocentric image.
        fps: frame rate of the walks (speeds are per second).
        area: (min, max) side of the square walking area, drawn per scene. The top camera's
            field of view is fitted to it, so it sets the people's size in the top image.
        height_range: (min, max) body height.
        width_range: (min, max) shoulder width.
        min_separation: smallest distance between two people's ground positions; large enough
            that swinging arms and backpacks of neighbours do not interpenetrate.
        walk_speed: (min, max) preferred walking speed, m/s.
        stop_probability: probability per second that a walker stops.
        drone_altitude: (min, max) height of the nadir camera ("drone").
        overview_height: (min, max) height of the building camera ("overview").
        overview_pitch: (min, max) downward pitch of the building camera ("overview").
        top_hfov_limits: (min, max) of the fitted top/overview horizontal field of view; when
            the area does not fit at the maximum, the area is shrunk until it does.
        ego_hfov: (min, max) horizontal field of view of the egocentric camera.
        ego_pitch_limit: the egocentric pitch stays within +- this (positive looks down).
        ego_roll_limit: the egocentric roll stays within +- this.
        ego_wobble: standard deviation of the smooth pitch / roll wobble of the egocentric
            camera about its per-scene mean.
        gaze_at_group: weight in [0, 1] pulling the carrier's view towards the group.
        handheld_height: height of the hand-held camera ("overview").
        handheld_reach: distance of the hand-held camera in front of the carrier's body axis.
        eye_below_top: the head-worn camera sits this far below the top of the head ("drone").
        ego_near_clip: people with a body point nearer than this to the egocentric image plane
            are not rendered (a body filling the frame is no use to either branch).
        buildings: (min, max) number of buildings around the area.
    """

    scenario: str = "drone"
    n_people: tuple[int, int] = (3, 14)
    top_size: tuple[int, int] = (640, 360)
    ego_size: tuple[int, int] = (640, 360)
    fps: float = 10.0
    area: tuple[float, float] = (8.0, 14.0)
    height_range: tuple[float, float] = (1.5, 1.95)
    width_range: tuple[float, float] = (0.4, 0.5)
    min_separation: float = 0.8
    walk_speed: tuple[float, float] = (0.4, 1.4)
    stop_probability: float = 0.1
    drone_altitude: tuple[float, float] = (20.0, 60.0)
    overview_height: tuple[float, float] = (8.0, 25.0)
    overview_pitch: tuple[float, float] = (25.0, 60.0)
    top_hfov_limits: tuple[float, float] = (10.0, 90.0)
    ego_hfov: tuple[float, float] = (60.0, 100.0)
    ego_pitch_limit: float = 10.0
    ego_roll_limit: float = 5.0
    ego_wobble: float = 1.5
    gaze_at_group: float = 0.8
    handheld_height: float = 1.5
    handheld_reach: float = 0.3
    eye_below_top: float = 0.1
    ego_near_clip: float = 0.3
    buildings: tuple[int, int] = (5, 10)

    def __post_init__(self) -> None:
        if self.scenario not in SCENARIOS:
            raise ValueError(
                f"SynthConfig.scenario must be one of {', '.join(SCENARIOS)}, got "
                f"{self.scenario!r}"
            )

        def pair(name: str, low: float, high: float = np.inf) -> None:
            value = getattr(self, name)
            if len(value) != 2 or not low <= value[0] <= value[1] <= high:
                raise ValueError(
                    f"SynthConfig.{name} must be (min, max) with {low} <= min <= max <= {high}, "
                    f"got {value}"
                )

        pair("n_people", 1, 60)
        pair("area", 1.0)
        pair("height_range", 0.5, 2.5)
        pair("width_range", 0.2, 0.8)
        pair("walk_speed", 0.0)
        pair("drone_altitude", 3.0)
        pair("overview_height", 3.0)
        pair("overview_pitch", 5.0, 90.0)
        pair("top_hfov_limits", 1.0, 170.0)
        pair("ego_hfov", 1.0, 170.0)
        pair("buildings", 0, 40)
        for name in ("top_size", "ego_size"):
            size = getattr(self, name)
            if len(size) != 2 or min(size) < 8:
                raise ValueError(f"SynthConfig.{name} must be (width, height) >= 8, got {size}")
        for name in ("fps", "min_separation", "ego_near_clip", "handheld_height"):
            if not getattr(self, name) > 0:
                raise ValueError(f"SynthConfig.{name} must be > 0, got {getattr(self, name)}")
        for name in ("ego_pitch_limit", "ego_roll_limit", "ego_wobble", "handheld_reach"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"SynthConfig.{name} must be >= 0, got {getattr(self, name)}")
        if self.min_separation < self.width_range[1]:
            raise ValueError(
                f"SynthConfig.min_separation ({self.min_separation}) must be >= the largest "
                f"width ({self.width_range[1]})"
            )
        if self.scenario == "overview" and self.handheld_height + 0.05 > self.height_range[1]:
            raise ValueError(
                "SynthConfig.handheld_height must be below the tallest height_range so that a "
                "carrier can hold the camera at eye level"
            )
        if self.scenario == "drone" and self.eye_below_top >= self.height_range[0]:
            raise ValueError("SynthConfig.eye_below_top must be smaller than every height")
        if not 0.0 <= self.gaze_at_group <= 1.0:
            raise ValueError(
                f"SynthConfig.gaze_at_group must be in [0, 1], got {self.gaze_at_group}"
            )


@dataclass(frozen=True)
class Building:
    """An upright box standing on the ground, part of the static scene.

    Attributes:
        centre: (x, y) of the footprint centre, metres.
        half_size: (half length along ``yaw``, half length across), metres.
        height: roof height, metres.
        yaw: orientation of the footprint, radians.
    """

    centre: tuple[float, float]
    half_size: tuple[float, float]
    height: float
    yaw: float

    def corners(self) -> np.ndarray:
        """The 8 corners ``(8, 3)``: the 4 ground corners counter-clockwise, then the roof."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        along, across = np.array([c, s]), np.array([-s, c])
        hx, hy = self.half_size
        signs = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], dtype=float)
        xy = np.asarray(self.centre) + (signs[:, :1] * hx) * along + (signs[:, 1:] * hy) * across
        ground = np.column_stack([xy, np.zeros(4)])
        roof = np.column_stack([xy, np.full(4, self.height)])
        return np.concatenate([ground, roof])

    def to_dict(self) -> dict:
        """JSON-ready record."""
        return {
            "centre": [float(v) for v in self.centre],
            "half_size": [float(v) for v in self.half_size],
            "height": float(self.height),
            "yaw": float(self.yaw),
        }


@dataclass(frozen=True, eq=False)
class SyntheticScene:
    """A scene to render: the people over F frames, both cameras per frame, the static world.

    Attributes:
        config: the configuration it was drawn from.
        people: the walks (:class:`~xvmatch.datasets.box_scene.PeopleState`); ``people.wearer``
            (id 0) carries the egocentric camera.
        top_cameras: F top/overview cameras (the same static camera repeated).
        ego_cameras: F egocentric cameras, ``ego_cameras[f - 1]`` for frame f.
        area: side of the square walking area centred on the world origin, metres.
        buildings: the static buildings; in the overview scenario the first one carries the
            overview camera on its roof edge.
        device_offset: (F, 3) position of the egocentric camera relative to the carrier's
            ground position, for drawing the device in the top view.
    """

    config: SynthConfig
    people: PeopleState
    top_cameras: list[Camera]
    ego_cameras: list[Camera]
    area: float
    buildings: tuple[Building, ...]
    device_offset: np.ndarray

    @property
    def scenario(self) -> str:
        """``"drone"`` or ``"overview"``."""
        return self.config.scenario

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return self.people.n_frames


def fit_hfov(
    R: np.ndarray, c: np.ndarray, points: np.ndarray, size: Sequence[int], margin: float = 1.0
) -> float:
    """Smallest horizontal field of view (degrees) whose image holds all ``points``.

    For a camera with rotation ``R``, centre ``c`` and square pixels with the principal point at
    the image centre, a world point is inside the image when ``|x/z| <= tan(hfov / 2)`` and
    ``|y/z| <= tan(hfov / 2) * height / width`` in camera coordinates.

    Args:
        R: (3, 3) world-to-camera rotation.
        c: (3,) camera centre.
        points: (N, 3) world points, all in front of the camera.
        size: (width, height) of the image.
        margin: factor (>= 1) on the tangent, keeping points off the border.

    Returns:
        The field of view in degrees, in (0, 180).

    Raises:
        ValueError: a point is not in front of the camera.
    """
    cam = (np.asarray(points, dtype=float) - np.asarray(c, dtype=float)) @ np.asarray(R).T
    if (cam[:, 2] <= 1e-6).any():
        raise ValueError("fit_hfov: every point must be in front of the camera")
    width, height = size
    tan_half = max(
        float(np.abs(cam[:, 0] / cam[:, 2]).max()),
        float((np.abs(cam[:, 1] / cam[:, 2]) * width / height).max()),
    )
    return float(np.degrees(2.0 * np.arctan(margin * tan_half)))


def _area_points(area: float) -> np.ndarray:
    """Corners of the walking square at ground and head height, ``(8, 3)``."""
    h = 0.5 * area
    xy = np.array([[h, h], [-h, h], [-h, -h], [h, -h]])
    return np.concatenate(
        [np.column_stack([xy, np.zeros(4)]), np.column_stack([xy, np.full(4, _FIT_HEIGHT)])]
    )


def _fitted_top_camera(
    R: np.ndarray, c: np.ndarray, area: float, config: SynthConfig
) -> tuple[Camera, float]:
    """The top camera with its field of view fitted to the area; the area shrinks if needed."""
    low, high = config.top_hfov_limits
    for _ in range(60):
        hfov = fit_hfov(R, c, _area_points(area), config.top_size, _FIT_MARGIN)
        if hfov <= high:
            break
        area *= 0.95
    else:  # pragma: no cover - the shrinking loop always converges for a forward camera
        raise ValueError("the walking area cannot be fitted into the top camera's image")
    width, height = config.top_size
    K = intrinsics_from_fov(width, height, float(np.clip(hfov, low, high)))
    return Camera(K=K, R=R, c=c, width=width, height=height), area


def _buildings(
    rng: np.random.Generator, area: float, count: int, avoid: float | None
) -> list[Building]:
    """Buildings on a ring around the area, spread in azimuth, none in the ``avoid`` sector."""
    buildings: list[Building] = []
    if count <= 0:
        return buildings
    slots = (rng.permutation(count) + rng.uniform(0.2, 0.8, size=count)) / count * 2 * np.pi
    slots += rng.uniform(-np.pi, np.pi)
    inner = area / np.sqrt(2.0) + _BUILDING_GAP
    for azimuth in slots:
        half = rng.uniform(3.0, 8.0, size=2)
        radius = inner + half.max() + rng.uniform(0.0, 15.0)
        height = float(rng.uniform(5.0, 25.0))
        if avoid is not None and abs(np.angle(np.exp(1j * (azimuth - avoid)))) < np.radians(80):
            continue
        centre = radius * np.array([np.cos(azimuth), np.sin(azimuth)])
        buildings.append(
            Building((float(centre[0]), float(centre[1])), (float(half[0]), float(half[1])),
                     height, float(azimuth))
        )
    return buildings


def _draw_top_camera(
    config: SynthConfig, rng: np.random.Generator, area: float, top_yaw: float
) -> tuple[Camera, float, float, float | None]:
    """Draw the top (drone) or overview camera and fit its field of view to the area.

    Args:
        config: scenario configuration.
        rng: random generator (draws the altitude, or the overview height and pitch).
        area: drawn side of the walking square, metres.
        top_yaw: drawn yaw of the top camera, radians.

    Returns:
        The camera, the (possibly shrunk) area, the yaw (snapped near the image axes for a
        drone) and the azimuth where no building may stand (the overview camera's), or None.
    """
    if config.scenario == "drone":
        altitude = float(rng.uniform(*config.drone_altitude))
        # Square area roughly aligned with the image axes: it fills more of a wide image.
        top_yaw = float(np.round(top_yaw / (np.pi / 2)) * (np.pi / 2) + 0.15 * np.sin(top_yaw))
        R = look_rotation(top_yaw, np.pi / 2.0)
        c = np.array([0.0, 0.0, altitude])
        top, area = _fitted_top_camera(R, c, area, config)
        return top, area, top_yaw, None
    height = float(rng.uniform(*config.overview_height))
    pitch = np.radians(rng.uniform(*config.overview_pitch))
    # Aim at the area centre from far enough that the camera's building is outside the area.
    distance = max(height / np.tan(pitch), area / np.sqrt(2.0) + _BUILDING_GAP)
    pitch = float(np.arctan2(height, distance))
    toward = np.array([np.cos(top_yaw), np.sin(top_yaw)])
    c = np.array([*(-distance * toward), height])
    top, area = _fitted_top_camera(look_rotation(top_yaw, pitch), c, area, config)
    return top, area, top_yaw, top_yaw + np.pi  # azimuth of the camera seen from the centre


def _walk_config(
    config: SynthConfig, area: float, top: Camera, ego_hfov: float, pitch_mean: float
) -> SceneConfig:
    """The walk simulator's configuration for a scene of this area, top camera and ego view."""
    return SceneConfig(
        n_people=config.n_people,
        area=area,
        height_range=config.height_range,
        width_range=config.width_range,
        min_separation=config.min_separation,
        fps=config.fps,
        walk_speed=config.walk_speed,
        stop_probability=config.stop_probability,
        edge_margin=min(2.0, 0.2 * area),
        gaze_at_group=config.gaze_at_group,
        top_altitude=max(float(top.c[2]), config.height_range[1] + 1.0),
        hor_size=config.ego_size,
        hor_hfov_deg=ego_hfov,
        hor_pitch_deg=pitch_mean,
        hor_roll_deg=0.0,
        hor_wobble_deg=config.ego_wobble,
        eye_below_top=config.eye_below_top,
    )


def _handheld_views(
    config: SynthConfig, people: PeopleState, rng: np.random.Generator, ego_hfov: float
) -> tuple[PeopleState, list[Camera]]:
    """Overview scenario: the carrier films with a phone held in front of them.

    The carrier is redrawn taller than the phone's height, and their body turns with the
    camera (a person filming faces where they film).

    Args:
        config: scenario configuration.
        people: the simulated walks.
        rng: random generator (draws the carrier's height).
        ego_hfov: horizontal field of view of the phone, degrees.

    Returns:
        The updated walks and one egocentric camera per frame.
    """
    w = people.wearer
    n_frames = people.n_frames
    low = max(config.height_range[0], config.handheld_height + 0.1)
    heights = people.heights.copy()
    heights[w] = rng.uniform(low, max(low, config.height_range[1]))
    headings = people.headings.copy()
    headings[:, w] = people.head_yaw
    people = replace(people, heights=heights, headings=headings)
    K = intrinsics_from_fov(*config.ego_size, ego_hfov)
    look = np.stack([np.cos(people.head_yaw), np.sin(people.head_yaw)], axis=1)
    centres = np.column_stack(
        [people.positions[:, w] + config.handheld_reach * look,
         np.full(n_frames, config.handheld_height)]
    )
    ego_cameras = [
        Camera(K=K, R=look_rotation(yaw, pitch, roll), c=centre, width=config.ego_size[0],
               height=config.ego_size[1])
        for yaw, pitch, roll, centre in zip(
            people.head_yaw.tolist(), people.head_pitch.tolist(),
            people.head_roll.tolist(), centres, strict=True,
        )
    ]
    return people, ego_cameras


def _overview_building(rng: np.random.Generator, top: Camera) -> Building:
    """The building whose roof's front edge the overview camera stands on."""
    depth, half_width = rng.uniform(4.0, 7.0), rng.uniform(4.0, 8.0)
    toward = -top.c[:2] / np.linalg.norm(top.c[:2])
    centre = top.c[:2] - (depth + 0.3) * toward
    yaw = float(np.arctan2(toward[1], toward[0]))
    return Building((float(centre[0]), float(centre[1])), (float(depth), float(half_width)),
                    float(top.c[2] - 0.5), yaw)


def make_scene(config: SynthConfig, n_frames: int, rng: np.random.Generator) -> SyntheticScene:
    """Draw one scene: area, cameras, walks and buildings, in that order, from ``rng``.

    Args:
        config: scenario configuration.
        n_frames: number of frames F >= 1.
        rng: the only source of randomness, e.g. ``np.random.default_rng([seed, scene])``.

    Returns:
        The :class:`SyntheticScene`.
    """
    if int(n_frames) < 1:
        raise ValueError(f"n_frames must be >= 1, got {n_frames}")
    n_frames = int(n_frames)
    area = float(rng.uniform(*config.area))
    top_yaw = float(rng.uniform(-np.pi, np.pi))
    ego_hfov = float(rng.uniform(*config.ego_hfov))
    pitch_mean = float(rng.uniform(-0.5, 0.5) * config.ego_pitch_limit)
    n_buildings = int(rng.integers(config.buildings[0], config.buildings[1] + 1))
    top, area, top_yaw, avoid = _draw_top_camera(config, rng, area, top_yaw)
    walk_config = _walk_config(config, area, top, ego_hfov, pitch_mean)
    people = simulate_walks(walk_config, n_frames, rng)
    pitch_lim, roll_lim = np.radians(config.ego_pitch_limit), np.radians(config.ego_roll_limit)
    people = replace(
        people,
        head_pitch=np.clip(people.head_pitch, -pitch_lim, pitch_lim),
        head_roll=np.clip(people.head_roll, -roll_lim, roll_lim),
    )
    w = people.wearer
    if config.scenario == "drone":
        top_cameras = [top_view_camera(replace(walk_config, top_altitude=float(top.c[2]),
                                               top_size=config.top_size,
                                               top_hfov_deg=_hfov_of(top)), top_yaw)] * n_frames
        ego_cameras = horizontal_cameras(people, walk_config)
    else:
        people, ego_cameras = _handheld_views(config, people, rng, ego_hfov)
        top_cameras = [top] * n_frames
    device_offset = np.stack([cam.c for cam in ego_cameras]) - np.column_stack(
        [people.positions[:, w], np.zeros(n_frames)]
    )
    buildings = _buildings(rng, area, n_buildings, avoid)
    if config.scenario == "overview":
        buildings.insert(0, _overview_building(rng, top))
    return SyntheticScene(
        config=config,
        people=people,
        top_cameras=top_cameras,
        ego_cameras=ego_cameras,
        area=area,
        buildings=tuple(buildings),
        device_offset=device_offset,
    )


def _hfov_of(camera: Camera) -> float:
    """Horizontal field of view (degrees) of a camera with a centred principal point."""
    return float(np.degrees(2.0 * np.arctan(0.5 * camera.width / camera.K[0, 0])))
