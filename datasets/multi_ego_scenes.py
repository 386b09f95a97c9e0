"""Rendered scenes with one top camera and several egocentric cameras at the same instants.

A drone scene of :func:`xvmatch.datasets.synthetic_scenes.make_scene` (nadir top camera, one
head-worn camera on person index 0) gets ``n_ego - 1`` more head-worn cameras, worn by other
walkers drawn from the same generator. Each extra wearer looks towards the centroid of the
others, turned by a per-wearer offset (normal, ``gaze_spread`` degrees), with the pitch and
roll limits and a field of view drawn from the scene's :class:`SynthConfig`; so the egocentric
views overlap, each with its own part of the crowd.

Every view is drawn by :class:`~xvmatch.datasets.render.image_render.SceneRenderer`: one
renderer per egocentric camera, built from the same seed (so the people wear the same outfits and
the world is the same), with that camera's wearer left out of its own view and a photometry of its
own. Only the first wearer's device is drawn in the top view. Labels keep the scene's person ids
(the same person has the same id in every view); the ids are for evaluation only.

:func:`write_multi_ego_inputs` lays a scene out as a user's data: one MOT box file per view
(rows shuffled per frame, seeded), one image folder per view, and per egocentric camera a
folder of camera files with cameras ``top`` and ``ego``: what ``xvmatch associate-multi``
reads. Everything is a pure function of the seed.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from xvmatch.datasets.render.image_render import (
    Difficulty,
    SceneRenderer,
    ViewLabels,
    draw_photometric,
)
from xvmatch.datasets.synthetic_scenes import SynthConfig, SyntheticScene, make_scene
from xvmatch.geometry.camera import Camera, intrinsics_from_fov, look_rotation

__all__ = [
    "MAX_EGO",
    "MultiEgoFrame",
    "MultiEgoInputs",
    "MultiEgoView",
    "multi_ego_config",
    "render_multi_ego",
    "view_names",
    "write_multi_ego_inputs",
]

MAX_EGO = 3
"""Most egocentric cameras per scene (issue 17: one top view and two or three horizontal)."""


def view_names(n_ego: int) -> tuple[str, ...]:
    """``("top", "hor1", ..., "horK")``: the names of the views, top first."""
    return ("top", *(f"hor{k}" for k in range(1, int(n_ego) + 1)))


@dataclass(frozen=True, eq=False)
class MultiEgoView:
    """One view of one frame.

    Attributes:
        name: ``"top"`` or ``"horK"``.
        image: ``(H, W, 3)`` uint8 BGR image.
        camera: the view's calibrated camera.
        labels: the people visible in it (scene person ids: evaluation only).
        jpeg_quality: quality the view is saved with.
    """

    name: str
    image: np.ndarray
    camera: Camera
    labels: ViewLabels
    jpeg_quality: int


@dataclass(frozen=True, eq=False)
class MultiEgoFrame:
    """All views of one frame: the top view first, then the egocentric ones.

    Attributes:
        frame: 1-based frame number.
        views: ``(top, hor1, ..., horK)``.
        wearers: person id of each egocentric camera's wearer.
    """

    frame: int
    views: tuple[MultiEgoView, ...]
    wearers: tuple[int, ...]


def multi_ego_config(n_ego: int, **changes) -> SynthConfig:
    """The drone configuration of the multi-egocentric scenes: 6 to 12 people (at least
    ``n_ego + 3``), other fields as :class:`SynthConfig` unless given in ``changes``."""
    low = max(6, int(n_ego) + 3)
    return SynthConfig(scenario="drone", **{"n_people": (low, max(low, 12)), **changes})


def _extra_cameras(scene: SyntheticScene, wearer: int, rng: np.random.Generator,
                   gaze_spread: float) -> list[Camera]:
    """Head-worn cameras of ``wearer`` (person index) over the frames, towards the group."""
    config, people = scene.config, scene.people
    width, height = config.ego_size
    K = intrinsics_from_fov(width, height, float(rng.uniform(*config.ego_hfov)))
    offset = np.radians(gaze_spread) * rng.standard_normal()
    pitch = np.radians(rng.uniform(-0.5, 0.5) * config.ego_pitch_limit)
    roll = np.radians(rng.uniform(-0.5, 0.5) * config.ego_roll_limit)
    eye = people.heights[wearer] - config.eye_below_top
    others = np.arange(people.n_people) != wearer
    out = []
    for f in range(people.n_frames):
        here = people.positions[f, wearer]
        to_group = people.positions[f, others].mean(axis=0) - here
        yaw = float(np.arctan2(to_group[1], to_group[0]) + offset)
        out.append(Camera(K=K, R=look_rotation(yaw, pitch, roll), c=np.array([*here, eye]),
                          width=width, height=height))
    return out


def _as_wearer(scene: SyntheticScene, wearer: int, cameras: list[Camera]) -> SyntheticScene:
    """The scene as seen by ``wearer``'s camera: ids 0 and the wearer's swapped (the renderer
    leaves id 0, the wearer, out of the egocentric view) and the cameras replaced."""
    people = scene.people
    ids = people.ids.copy()
    ids[[people.wearer, wearer]] = ids[[wearer, people.wearer]]
    yaw = np.array([np.arctan2(c.R[2, 1], c.R[2, 0]) for c in cameras])
    worn = replace(people, ids=ids, wearer=wearer, head_yaw=yaw)
    offset = np.stack([c.c for c in cameras]) - np.column_stack(
        [people.positions[:, wearer], np.zeros(people.n_frames)])
    return replace(scene, people=worn, ego_cameras=cameras, device_offset=offset)


def _relabelled(labels: ViewLabels, swap: dict[int, int]) -> ViewLabels:
    """Labels with ids mapped back through ``swap``, rows in ascending id order again."""
    ids = np.array([swap.get(int(i), int(i)) for i in labels.ids], dtype=np.int64)
    order = np.argsort(ids, kind="stable")
    return replace(labels.select(order), ids=ids[order])


def render_multi_ego(
    seed: int | Sequence[int],
    n_ego: int = 3,
    n_frames: int = 1,
    config: SynthConfig | None = None,
    difficulty: Difficulty | None = None,
    gaze_spread: float = 25.0,
) -> list[MultiEgoFrame]:
    """Draw and render one scene seen by a top camera and ``n_ego`` egocentric cameras.

    Args:
        seed: the scene's seed (an int or a sequence, e.g. ``[dataset seed, scene index]``).
        n_ego: egocentric cameras, 1..:data:`MAX_EGO`.
        n_frames: frames F >= 1.
        config: a drone configuration (default :func:`multi_ego_config`); it needs at least
            ``n_ego + 1`` people.
        difficulty: rendering difficulty (None: medium).
        gaze_spread: standard deviation (degrees) of each extra wearer's gaze offset from the
            group centroid.

    Returns:
        F :class:`MultiEgoFrame`, frame 1 first.

    Raises:
        ValueError: ``n_ego`` out of range, a non-drone configuration, or too few people.
    """
    if not 1 <= int(n_ego) <= MAX_EGO:
        raise ValueError(f"n_ego must be in 1..{MAX_EGO}, got {n_ego}")
    n_ego = int(n_ego)
    config = multi_ego_config(n_ego) if config is None else config
    if config.scenario != "drone":
        raise ValueError("render_multi_ego needs a drone configuration (head-worn cameras)")
    if config.n_people[0] < n_ego + 1:
        raise ValueError(f"config.n_people must be at least {n_ego + 1} for {n_ego} "
                         f"egocentric cameras, got {config.n_people}")
    root = [int(seed)] if np.isscalar(seed) else [int(s) for s in seed]
    rng = np.random.default_rng([*root, 0])
    scene = make_scene(config, n_frames, rng)
    people = scene.people
    others = np.flatnonzero(np.arange(people.n_people) != people.wearer)
    extra = rng.choice(others, size=n_ego - 1, replace=False).tolist()
    renderers = [SceneRenderer(scene, np.random.default_rng([*root, 1]), difficulty)]
    swaps: list[dict[int, int]] = [{}]
    for k, wearer in enumerate(extra, start=2):
        cams = _extra_cameras(scene, wearer, rng, gaze_spread)
        worn = _as_wearer(scene, wearer, cams)
        renderer = SceneRenderer(worn, np.random.default_rng([*root, 1]), difficulty)
        renderer.photometric["ego"] = draw_photometric(
            np.random.default_rng([*root, k]), renderer.difficulty, moving=True)
        renderers.append(renderer)
        a, b = int(worn.people.ids[people.wearer]), int(worn.people.ids[wearer])
        swaps.append({a: b, b: a})
    wearers = (int(people.ids[people.wearer]), *(int(people.ids[w]) for w in extra))
    names = view_names(n_ego)
    out = []
    for frame in range(1, n_frames + 1):
        views = []
        top = renderers[0].render_view(frame, "top")
        views.append(MultiEgoView(names[0], top.image, top.camera, top.labels, top.jpeg_quality))
        for k, (renderer, swap) in enumerate(zip(renderers, swaps, strict=True), start=1):
            ego = renderer.render_view(frame, "ego")
            views.append(MultiEgoView(names[k], ego.image, ego.camera,
                                      _relabelled(ego.labels, swap), ego.jpeg_quality))
        out.append(MultiEgoFrame(frame, tuple(views), wearers))
    return out


@dataclass(frozen=True)
class MultiEgoInputs:
    """A multi-egocentric scene laid out as a user's data (:func:`write_multi_ego_inputs`).

    Attributes:
        boxes: one MOT box file per view, top first (ground-truth ids, evaluation only).
        images: one image folder per view, top first (``000001.jpg``, ...).
        cameras: one camera folder per egocentric view (``000001.json``: ``top``, ``ego``).
    """

    boxes: tuple[Path, ...]
    images: tuple[Path, ...]
    cameras: tuple[Path, ...]


def write_multi_ego_inputs(frames: Sequence[MultiEgoFrame], out: str | os.PathLike,
                           seed: int = 0) -> MultiEgoInputs:
    """Write the frames as box files, images and camera files under ``out``.

    The rows of each view and frame are shuffled with ``default_rng([seed, frame, view])``;
    every file is written atomically.
    """
    import cv2

    from xvmatch.core.atomic_files import atomic_write_bytes
    from xvmatch.formats.camera_io import save_cameras
    from xvmatch.formats.mot_boxes import FrameBoxes, write_mot_boxes

    if not frames:
        raise ValueError("no frames to write")
    out = Path(out)
    names = [v.name for v in frames[0].views]
    boxes, images, cameras = [], [], []
    for v, name in enumerate(names):
        folder = out / "images" / name
        folder.mkdir(parents=True, exist_ok=True)
        records = {}
        for f in frames:
            view = f.views[v]
            order = np.random.default_rng([int(seed), f.frame, v]).permutation(len(view.labels))
            records[f.frame] = FrameBoxes(f.frame, view.labels.ids[order],
                                          view.labels.boxes[order])
            ok, buf = cv2.imencode(".jpg", view.image,
                                   [cv2.IMWRITE_JPEG_QUALITY, view.jpeg_quality])
            if not ok:  # pragma: no cover - OpenCV always encodes a valid uint8 image
                raise OSError(f"could not encode view {name} of frame {f.frame}")
            atomic_write_bytes(folder / f"{f.frame:06d}.jpg", buf.tobytes(), fsync=False)
        write_mot_boxes(out / f"{name}.txt", records)
        boxes.append(out / f"{name}.txt")
        images.append(folder)
        if v:
            cam_folder = out / "cameras" / name
            cam_folder.mkdir(parents=True, exist_ok=True)
            for f in frames:
                save_cameras(cam_folder / f"{f.frame:06d}.json",
                             {"top": f.views[0].camera, "ego": f.views[v].camera})
            cameras.append(cam_folder)
    return MultiEgoInputs(tuple(boxes), tuple(images), tuple(cameras))
