"""Short rendered videos for complementary-view tracking: one continuous walk, both views.

:func:`render_tracking_video` draws a drone scene (:func:`xvmatch.datasets.synthetic_scenes.
make_scene`: people walking with turns and stops, frame after frame, the egocentric camera worn by
person 0) and renders every frame of it
(:class:`xvmatch.datasets.render.image_render.SceneRenderer`), so the boxes and images of
consecutive frames show the same people a fraction of a second apart: what ``xvmatch track`` reads.
``xvmatch synth --frames N`` renders the same walks but stores them as training pairs; this keeps
the video in memory and can write it as box files and image folders (:func:`write_tracking_video`).
The walk model turns the worn camera's gaze by several degrees a frame (it is drawn for single
frames; on a 640-pixel image, people's boxes then barely overlap from one frame to the next); a
head-worn video turns far more smoothly, so here the head's yaw, pitch and roll are smoothed over
time (a Gaussian of ``head_smoothing`` seconds) and the egocentric cameras rebuilt from them. Ids
are the ground truth (the same person has the same id in both views); they are for evaluation only.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation

from xvmatch.core.atomic_files import atomic_write_bytes
from xvmatch.datasets.render.image_render import Difficulty, SceneRenderer
from xvmatch.datasets.synthetic_scenes import SynthConfig, SyntheticScene, make_scene
from xvmatch.formats.mot_boxes import FrameBoxes, write_mot_boxes
from xvmatch.geometry.camera import Camera, FrameCameras, look_rotation

__all__ = [
    "TrackingFrame",
    "TrackingVideo",
    "render_tracking_video",
    "tracking_frames",
    "write_tracking_frames",
    "write_tracking_video",
]


@dataclass(frozen=True, eq=False)
class TrackingVideo:
    """A rendered video pair with its ground-truth boxes.

    Attributes:
        top, hor: ``{frame: FrameBoxes}`` (1-based frames, ground-truth ids) of each view.
        top_images, hor_images: ``{frame: (H, W, 3) uint8 BGR}`` images.
        hor_size: ``(width, height)`` of the egocentric image.
        fps: frames per second of the walk.
        cameras: ``{frame: FrameCameras}``, the calibrated cameras each frame was rendered
            with (what ``--cameras`` gives).
    """

    top: dict[int, FrameBoxes]
    hor: dict[int, FrameBoxes]
    top_images: dict[int, np.ndarray]
    hor_images: dict[int, np.ndarray]
    hor_size: tuple[int, int]
    fps: float
    cameras: dict[int, FrameCameras] = field(default_factory=dict)


def _smooth_head(scene: SyntheticScene, seconds: float) -> SyntheticScene:
    """The scene with the wearer's head pose smoothed over ``seconds`` and the egocentric
    cameras rebuilt from it (same centres and intrinsics)."""
    if seconds <= 0:
        return scene
    sigma = seconds * scene.config.fps
    people = scene.people
    yaw, pitch, roll = (gaussian_filter1d(a, sigma, mode="nearest") for a in (
        np.unwrap(people.head_yaw), people.head_pitch, people.head_roll))
    cameras = [Camera(K=c.K, R=look_rotation(y, p, r), c=c.c, width=c.width, height=c.height)
               for c, y, p, r in zip(scene.ego_cameras, yaw.tolist(), pitch.tolist(),
                                     roll.tolist(), strict=True)]
    people = replace(people, head_yaw=yaw, head_pitch=pitch, head_roll=roll)
    return replace(scene, people=people, ego_cameras=cameras)


FLIGHT_HEADING = np.array([1.0, 0.3, 0.0]) / np.hypot(1.0, 0.3)
"""Unit world direction a flying top camera moves along (:func:`render_tracking_video`)."""


def _fly(scene: SyntheticScene, speed: float, yaw_rate: float) -> SyntheticScene:
    """The scene with its top camera in flight: moved ``speed`` m/s along
    :data:`FLIGHT_HEADING`, through its drawn place at the video's middle, and turned
    ``yaw_rate`` degrees/s about the vertical (as a drone's telemetry would give it per frame)."""
    t = np.arange(len(scene.top_cameras)) / scene.config.fps
    cameras = []
    for cam, s in zip(scene.top_cameras, t.tolist(), strict=True):
        turn = Rotation.from_euler("z", yaw_rate * s, degrees=True).as_matrix()
        cameras.append(Camera(K=cam.K, R=cam.R @ turn.T,
                              c=cam.c + speed * (s - t[-1] / 2) * FLIGHT_HEADING,
                              width=cam.width, height=cam.height))
    return replace(scene, top_cameras=cameras)


@dataclass(frozen=True, eq=False)
class TrackingFrame:
    """One rendered frame of a tracking video (:func:`tracking_frames`).

    Attributes:
        frame: the 1-based frame number.
        top, hor: each view's boxes (ground-truth ids).
        top_image, hor_image: ``(H, W, 3)`` uint8 BGR images.
        cameras: the calibrated cameras the frame was rendered with.
    """

    frame: int
    top: FrameBoxes
    hor: FrameBoxes
    top_image: np.ndarray
    hor_image: np.ndarray
    cameras: FrameCameras


def tracking_frames(
    seed: int,
    n_frames: int = 60,
    config: SynthConfig | None = None,
    min_visible: float = 0.3,
    min_pixels: int = 100,
    head_smoothing: float = 1.0,
    flight: tuple[float, float] | None = None,
    difficulty: Difficulty | None = None,
) -> Iterator[TrackingFrame]:
    """The frames of :func:`render_tracking_video` one at a time, rendered as they are asked
    for (a long clip need not be held in memory); the arguments are its own, and
    ``difficulty`` the renderer's (None: medium)."""
    if int(n_frames) < 1:
        raise ValueError(f"n_frames must be >= 1, got {n_frames}")
    config = config or SynthConfig(scenario="drone", n_people=(6, 12), fps=25.0)
    rng = np.random.default_rng([int(seed), 17])
    scene = _smooth_head(make_scene(config, int(n_frames), rng), head_smoothing)
    if flight is not None:
        scene = _fly(scene, *map(float, flight))
    renderer = SceneRenderer(scene, rng, difficulty)
    for f in range(1, int(n_frames) + 1):
        pair = renderer.render(f)
        t, e = pair.top.labels, pair.ego.labels
        keep = (e.visible >= min_visible) & (e.visible_pixels >= min_pixels)
        yield TrackingFrame(f, FrameBoxes(f, t.ids, t.boxes),
                            FrameBoxes(f, e.ids[keep], e.boxes[keep]), pair.top.image,
                            pair.ego.image, FrameCameras(pair.top.camera, pair.ego.camera))


def render_tracking_video(
    seed: int,
    n_frames: int = 60,
    config: SynthConfig | None = None,
    min_visible: float = 0.3,
    min_pixels: int = 100,
    head_smoothing: float = 1.0,
    progress: Callable[[int], None] | None = None,
    flight: tuple[float, float] | None = None,
) -> TrackingVideo:
    """Render ``n_frames`` consecutive frames of one drone scene drawn from ``seed``.

    Args:
        seed: the scene's seed (scene, outfits, world and per-frame noise all come from it).
        n_frames: frames of the video (>= 1).
        config: the scene configuration (default: the drone scenario at 25 fps, 6 to 12 people).
        min_visible: an egocentric person needs this visible fraction to get a box (as a
            detector misses a mostly hidden person).
        min_pixels: and this many visible pixels.
        head_smoothing: seconds (standard deviation) of the head-pose smoothing; 0 keeps the
            walk model's per-frame gaze.
        progress: called with each rendered frame number.
        flight: ``(speed m/s, yaw rate degrees/s)`` of a top camera in flight (a drone; see
            :func:`_fly`; the same people and world, drawn before it), or None: fixed.

    Returns:
        The :class:`TrackingVideo`.
    """
    config = config or SynthConfig(scenario="drone", n_people=(6, 12), fps=25.0)
    top, hor, top_images, hor_images, cameras = {}, {}, {}, {}, {}
    for fr in tracking_frames(seed, n_frames, config, min_visible, min_pixels, head_smoothing,
                              flight):
        f = fr.frame
        top[f], hor[f], cameras[f] = fr.top, fr.hor, fr.cameras
        top_images[f], hor_images[f] = fr.top_image, fr.hor_image
        if progress is not None:
            progress(f)
    return TrackingVideo(top, hor, top_images, hor_images, tuple(config.ego_size), config.fps,
                         cameras)


def _video_paths(folder: Path) -> dict[str, Path]:
    """The files and folders of a written tracking video, by name (the folder created)."""
    folder.mkdir(parents=True, exist_ok=True)
    return {"top": folder / "top.txt", "hor": folder / "hor.txt",
            "top_images": folder / "top", "hor_images": folder / "hor"}


def _write_frame_images(out: dict[str, Path], frame: int, top_image: np.ndarray,
                        hor_image: np.ndarray) -> None:
    """Write one frame's images as ``top/FRAME.png`` and ``hor/FRAME.png`` (``%06d``)."""
    import cv2

    for view, image in (("top_images", top_image), ("hor_images", hor_image)):
        out[view].mkdir(parents=True, exist_ok=True)
        ok, data = cv2.imencode(".png", image)
        if not ok:
            raise ValueError(f"{out[view]}: cannot encode frame {frame} as PNG")
        atomic_write_bytes(out[view] / f"{frame:06d}.png", data.tobytes(), fsync=False)


def _write_frame_cameras(folder: Path, frame: int, cams: FrameCameras) -> None:
    """Write one frame's camera file, ``FRAME.json`` (``%06d``; cameras ``top`` and ``ego``)."""
    from xvmatch.formats.camera_io import save_cameras

    folder.mkdir(parents=True, exist_ok=True)
    save_cameras(folder / f"{frame:06d}.json", {"top": cams.top, "ego": cams.hor})


def write_tracking_video(video: TrackingVideo, folder: str | os.PathLike) -> dict[str, Path]:
    """Write ``top.txt``, ``hor.txt`` (MOT boxes, ground-truth ids), the image folders
    ``top/`` and ``hor/`` (``000001.png`` ...) and, when the video records them, the folder
    ``cameras/`` of per-frame camera files (``000001.json``: ``top`` and ``ego``, the form
    ``--cameras`` reads) into ``folder``; returns their paths by name (``top``, ``hor``,
    ``top_images``, ``hor_images``, and ``cameras`` when written)."""
    out = _video_paths(Path(folder))
    write_mot_boxes(out["top"], video.top)
    write_mot_boxes(out["hor"], video.hor)
    for f in video.top_images:
        _write_frame_images(out, f, video.top_images[f], video.hor_images[f])
    if video.cameras:
        out["cameras"] = Path(folder) / "cameras"
        out["cameras"].mkdir(parents=True, exist_ok=True)
        for f, cams in video.cameras.items():
            _write_frame_cameras(out["cameras"], f, cams)
    return out


def write_tracking_frames(frames: Iterable[TrackingFrame], folder: str | os.PathLike,
                          progress: Callable[[int], None] | None = None) -> dict[str, Path]:
    """Write :func:`tracking_frames` as they come, in the layout of
    :func:`write_tracking_video` (cameras included): each frame's images and cameras at once,
    the box files at the end; ``progress`` is called with each frame number written."""
    out = _video_paths(Path(folder))
    out["cameras"] = Path(folder) / "cameras"
    top, hor = {}, {}
    for fr in frames:
        top[fr.frame], hor[fr.frame] = fr.top, fr.hor
        _write_frame_images(out, fr.frame, fr.top_image, fr.hor_image)
        _write_frame_cameras(out["cameras"], fr.frame, fr.cameras)
        if progress is not None:
            progress(fr.frame)
    write_mot_boxes(out["top"], top)
    write_mot_boxes(out["hor"], hor)
    return out
