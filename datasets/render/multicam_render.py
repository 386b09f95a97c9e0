"""Rendered images of multi-camera scenes (issue 32): every static camera's frames, labelled.

The people and cameras are those of the box simulator's scene of the same seed
(:func:`xvmatch.datasets.multicam_scenes.multicam_walks`): people walking on a square floor,
2-8 static calibrated cameras around it, overlapping in part. Each camera's images are drawn with
the two-view renderer's functions (:mod:`xvmatch.datasets.render.image_render`): outfits
(:func:`~xvmatch.datasets.render.person_render.draw_appearances`), one world for the scene (ground
texture, sky, light, buildings around the floor: :func:`~xvmatch.datasets.render.image_render.
make_world`), each camera's static background drawn once
(:func:`~xvmatch.datasets.render.image_render.render_background`), the people's cast shadows,
then the people far to near (:func:`~xvmatch.datasets.render.image_render.render_people`,
painter's algorithm), then the camera's own photometry
(:func:`~xvmatch.datasets.render.image_render.draw_photometric` per camera: white balance, exposure,
gamma, blur, noise, JPEG quality; per-frame noise from a seed per frame and camera). Cameras are
rendered at ``width`` pixels (default 640; the simulator's 16:9 sizes scaled, so ``K`` is scaled
with them).

Labels come from the pixels: a camera's box of a person is the tight box of its visible pixels,
kept when at least ``min_visible`` of its silhouette and ``min_pixels`` pixels are visible. Each
camera's track ids are its own (a new id when a person comes back after more than
``reentry_gap`` frames unseen), scrambled per camera
(:func:`~xvmatch.datasets.multicam_scenes.per_camera_track_ids`): equality of ids across cameras
means nothing. The global ids (person ``k`` is ``k + 1``) and ground positions are the ground
truth, as in the box simulator.

Seeded and deterministic: everything is drawn from ``seed`` (the walks and cameras from
``[seed, 32]``, outfits, world, photometry and per-frame seeds from ``[seed, 32, 1]``, track ids
from ``[seed, 32, 2]``), so frame ``f`` of camera ``c`` is the same whatever else is rendered.

Written by :func:`write_rendered_multicam_scene` in the box simulator's formats
(:func:`~xvmatch.datasets.multicam_scenes.write_multicam_scene`: ``cameras.json``,
``boxes/NAME.txt``, ``gt/NAME.txt``, ``ground_gt.csv``) plus ``images/NAME/frame_%06d.jpg``, a
folder of frames that ``--images NAME=images/NAME`` reads.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from xvmatch.core.atomic_files import atomic_write_bytes
from xvmatch.datasets.multicam_scenes import (
    MulticamConfig,
    MulticamScene,
    multicam_walks,
    per_camera_track_ids,
    write_multicam_scene,
)
from xvmatch.datasets.render.image_render import (
    Difficulty,
    Photometric,
    _shadows,
    apply_photometric,
    draw_photometric,
    make_world,
    render_background,
    render_people,
)
from xvmatch.datasets.render.person_render import body_frame, draw_appearances, walk_phases
from xvmatch.datasets.synthetic_scenes import Building, _buildings
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.geometry.camera import Camera

__all__ = [
    "MulticamFrame",
    "MulticamRenderer",
    "render_multicam_scene",
    "write_rendered_multicam_scene",
]


@dataclass(frozen=True)
class _Backdrop:
    """What :func:`~xvmatch.datasets.render.image_render.make_world` reads of a scene: its
    buildings."""

    buildings: tuple[Building, ...]


@dataclass(frozen=True, eq=False)
class MulticamFrame:
    """One frame of every camera.

    Attributes:
        frame: the frame number (1-based).
        images: ``{camera: (H, W, 3) uint8 BGR}``, photometry applied (JPEG not yet).
        id_images: ``{camera: (H, W) uint16}`` person index + 1 per pixel (0: background).
        gt: ``{camera: FrameBoxes}`` visible boxes with global ids (ascending).
    """

    frame: int
    images: dict[str, np.ndarray]
    id_images: dict[str, np.ndarray]
    gt: dict[str, FrameBoxes]


def _scaled(camera: Camera, width: int) -> Camera:
    """The camera with its image scaled to ``width`` pixels (height by its aspect ratio)."""
    s = width / camera.width
    height = max(round(camera.height * s), 1)
    K = np.diag([s, height / camera.height, 1.0]) @ camera.K
    return Camera(K, camera.R, camera.c, int(width), height)


class MulticamRenderer:
    """Renders the frames of the multi-camera scene of ``seed`` (see the module docstring).

    Args:
        config: the scene (cameras, people, floor); default :class:`MulticamConfig`.
        n_frames: frames F >= 1.
        seed: the scene's seed.
        width: rendered image width of every camera (8..4096), height by its 16:9 aspect.
        difficulty: outfits and photometry spreads (default: ``Difficulty()``, "medium").
        min_visible: a person less visible than this in a camera (fraction of its
            silhouette) has no box there.
        min_pixels: nor one with fewer visible pixels.
    """

    def __init__(self, config: MulticamConfig | None = None, n_frames: int = 100,
                 seed: int = 0, *, width: int = 640, difficulty: Difficulty | None = None,
                 min_visible: float = 0.3, min_pixels: int = 40) -> None:
        if not 8 <= int(width) <= 4096:
            raise ValueError(f"width must be in 8..4096 pixels, got {width}")
        if not 0.0 <= min_visible <= 1.0:
            raise ValueError(f"min_visible must be in [0, 1], got {min_visible}")
        self.config = config or MulticamConfig()
        self.difficulty = difficulty or Difficulty()
        self.min_visible = float(min_visible)
        self.min_pixels = int(min_pixels)
        self.seed = int(seed)
        walks, cameras, _ = multicam_walks(self.config, int(n_frames), self.seed)
        self.people = walks
        self.cameras = {n: _scaled(c, int(width)) for n, c in cameras.items()}
        rng = np.random.default_rng([self.seed, 32, 1])
        d = self.difficulty
        n = walks.n_people
        self.appearances = draw_appearances(
            n, rng, lookalike=d.lookalike, palette_size=d.palette_size,
            pattern_weights=d.pattern_weights, hat=d.hat, bag=d.bag,
            colour_jitter=d.colour_jitter)
        n_buildings = int(rng.integers(5, 11))
        buildings = tuple(_buildings(rng, self.config.area, n_buildings, None))
        self.world = make_world(_Backdrop(buildings), rng, d)
        self.photometric: dict[str, Photometric] = {
            name: draw_photometric(rng, d, moving=False) for name in self.cameras}
        self._frame_seeds = rng.integers(0, 2**63 - 1, size=(walks.n_frames, len(self.cameras)))
        self._phase, self._amplitude = walk_phases(walks, self.config.fps)
        self._backgrounds = {name: render_background(cam, self.world)
                             for name, cam in self.cameras.items()}
        self.ids = np.arange(1, n + 1, dtype=np.int64)

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return int(self.people.n_frames)

    def render(self, frame: int) -> MulticamFrame:
        """Every camera's image and visible boxes of ``frame`` (1-based)."""
        if not 1 <= frame <= self.n_frames:
            raise ValueError(f"frame must be in 1..{self.n_frames}, got {frame}")
        body = body_frame(self.people, frame, self.appearances, self._phase, self._amplitude)
        images, id_images, gt = {}, {}, {}
        for c, (name, cam) in enumerate(self.cameras.items()):
            image = self._backgrounds[name].copy()
            _shadows(image, cam, body, self.world)
            id_image, labels = render_people(image, cam, body, self.world, self.ids,
                                             near_clip=0.3)
            keep = (labels.visible >= self.min_visible) & \
                (labels.visible_pixels >= self.min_pixels)
            gt[name] = FrameBoxes(frame, labels.ids[keep], labels.boxes[keep])
            rng = np.random.default_rng(int(self._frame_seeds[frame - 1, c]))
            images[name] = apply_photometric(image, self.photometric[name], rng)
            id_images[name] = id_image
        return MulticamFrame(frame, images, id_images, gt)

    def frames(self) -> Iterator[MulticamFrame]:
        """:meth:`render` of frames 1..F in order."""
        for f in range(1, self.n_frames + 1):
            yield self.render(f)

    def scene(self, gt: dict[str, dict[int, FrameBoxes]]) -> MulticamScene:
        """The :class:`MulticamScene` of the rendered boxes ``gt`` (``{camera: {frame:
        FrameBoxes}}``, global ids): per-camera scrambled track ids added."""
        rng = np.random.default_rng([self.seed, 32, 2])
        boxes = {name: per_camera_track_ids(gt[name], self.config.reentry_gap, rng)
                 for name in self.cameras}
        return MulticamScene(dict(self.cameras), boxes, gt, self.people.positions.copy(),
                             self.people.heights.copy(), float(self.config.fps))


def render_multicam_scene(
    config: MulticamConfig | None = None,
    n_frames: int = 100,
    seed: int = 0,
    *,
    width: int = 640,
    difficulty: Difficulty | None = None,
    on_frame: Callable[[MulticamFrame, MulticamRenderer], None] | None = None,
) -> MulticamScene:
    """Render every frame of the scene of ``seed`` and return its boxes as a scene.

    Args:
        config, n_frames, seed, width, difficulty: as :class:`MulticamRenderer`.
        on_frame: called with each rendered frame (in order) and the renderer, e.g. to write
            the images; the images are not kept.

    Returns:
        The :class:`MulticamScene` (cameras at the rendered size, per-camera track ids,
        global-id ground truth, ground positions).
    """
    renderer = MulticamRenderer(config, n_frames, seed, width=width, difficulty=difficulty)
    gt: dict[str, dict[int, FrameBoxes]] = {name: {} for name in renderer.cameras}
    for frame in renderer.frames():
        for name, rec in frame.gt.items():
            gt[name][frame.frame] = rec
        if on_frame is not None:
            on_frame(frame, renderer)
    return renderer.scene(gt)


def write_rendered_multicam_scene(
    root: str | os.PathLike,
    config: MulticamConfig | None = None,
    n_frames: int = 100,
    seed: int = 0,
    *,
    width: int = 640,
    difficulty: Difficulty | None = None,
) -> tuple[MulticamScene, dict[str, Path]]:
    """Render the scene of ``seed`` and write it under ``root`` (created if missing).

    Files: those of :func:`~xvmatch.datasets.multicam_scenes.write_multicam_scene` and
    ``images/NAME/frame_%06d.jpg`` (each camera at its JPEG quality), each written atomically.

    Returns:
        (scene, paths): the scene, and ``{"cameras", "boxes", "gt", "ground", "images"}``.
    """
    root = Path(root)
    folders: dict[str, Path] = {}

    def write(frame: MulticamFrame, renderer: MulticamRenderer) -> None:
        for name, image in frame.images.items():
            if name not in folders:
                folders[name] = root / "images" / name
                folders[name].mkdir(parents=True, exist_ok=True)
            quality = renderer.photometric[name].jpeg_quality
            ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
            if not ok:
                raise OSError(f"{folders[name]}: cannot encode frame {frame.frame} as JPEG")
            atomic_write_bytes(folders[name] / f"frame_{frame.frame:06d}.jpg", data.tobytes(),
                               fsync=False)

    scene = render_multicam_scene(config, n_frames, seed, width=width, difficulty=difficulty,
                                  on_frame=write)
    paths = write_multicam_scene(root, scene)
    return scene, {**paths, "images": root / "images"}
