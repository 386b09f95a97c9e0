"""The runs of ``xvmatch synth`` that write one folder of their own: a scene of several static
cameras (``--cameras N``, the input of ``xvmatch multicam``), a smooth video clip (``--video``,
the input of ``xvmatch track`` and ``associate --mode video``) and a scene of several egocentric
cameras (``--egos K``, the input of ``xvmatch associate-multi``).

Each run takes one frozen options record and writes into a folder it claims (a marker listing
the files it wrote, :mod:`xvmatch.core.folder_marker`): a later run into the same folder removes
only those, never a file the user put there. The command checks the options' combinations; these
functions render and write.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

from xvmatch.core.folder_marker import files_under, record_own_files, remove_own_files
from xvmatch.core.output_paths import claim_folder
from xvmatch.datasets.multi_ego_scenes import (
    MultiEgoInputs,
    multi_ego_config,
    render_multi_ego,
    write_multi_ego_inputs,
)
from xvmatch.datasets.multicam_scenes import (
    MulticamConfig,
    MulticamScene,
    TrackerNoise,
    add_tracker_noise,
    simulate_multicam_scene,
    write_multicam_scene,
)
from xvmatch.datasets.render.image_render import Difficulty
from xvmatch.datasets.render.multicam_render import write_rendered_multicam_scene
from xvmatch.datasets.render.person_textures import load_textures
from xvmatch.datasets.synthetic_scenes import SynthConfig
from xvmatch.datasets.tracking_video import tracking_frames, write_tracking_frames

__all__ = [
    "SYNTH_CAMERAS",
    "SYNTH_EGOS",
    "SYNTH_VIDEO",
    "CamerasSynthOptions",
    "EgosSynthOptions",
    "VideoSynthOptions",
    "synth_cameras",
    "synth_difficulty",
    "synth_egos",
    "synth_video",
]

SYNTH_CAMERAS = "synth --cameras"
"""The command name in the marker of a ``synth --cameras`` folder (it may replace only its own)."""
SYNTH_VIDEO = "synth --video"
"""The command name in the marker of a ``synth --video`` folder."""
SYNTH_EGOS = "synth --egos"
"""The command name in the marker of a ``synth --egos`` folder."""


def synth_difficulty(preset: str, texture: float = 0.0) -> Difficulty:
    """The renderer's difficulty ``preset`` (``easy``, ``medium``, ``hard``) with photographic
    textures of depth ``texture`` over the people (0: none). The textures are loaded here, so a
    missing package is one error before rendering, not one in each worker."""
    difficulty = Difficulty.preset(preset)
    if texture:
        load_textures()
        difficulty = replace(difficulty, texture=texture)
    return difficulty


@dataclass(frozen=True)
class CamerasSynthOptions:
    """One scene of several static cameras, as ``synth --cameras N`` writes it.

    Attributes:
        out: the folder to write (new, empty, or an earlier ``synth --cameras`` output).
        config: the scene's cameras, people and frame rate.
        n_frames: frames of the walk.
        seed: the scene's seed (walks, cameras, rendering, noise).
        width: rendered image width in pixels (16:9 images); unused with ``boxes_only``.
        difficulty: rendering difficulty preset name (``easy``, ``medium``, ``hard``).
        boxes_only: the box simulator only, no images.
        tracker_noise: tracker-like noise on ``boxes/`` (``gt/`` stays clean).
    """

    out: str | os.PathLike
    config: MulticamConfig
    n_frames: int
    seed: int
    width: int = 640
    difficulty: str = "medium"
    boxes_only: bool = False
    tracker_noise: bool = False


def synth_cameras(options: CamerasSynthOptions,
                  progress: Callable[[int], None] | None = None) -> tuple[Path, MulticamScene]:
    """Write the scene of ``options`` (issue 32): rendered, or box-only from the simulator,
    optionally with tracker-like noise; ``progress(1)`` once the rendered scene is written.

    Returns:
        (folder, scene): the claimed output folder and the scene written there.
    """
    root = claim_folder(options.out, SYNTH_CAMERAS)
    remove_own_files(root, SYNTH_CAMERAS)  # an earlier scene of this command: no stale camera
    kept = files_under(root)  # the user's: never removed, and not listed as written
    if options.boxes_only:
        scene = simulate_multicam_scene(options.config, options.n_frames, options.seed)
    else:
        scene, _ = write_rendered_multicam_scene(
            root, options.config, options.n_frames, options.seed, width=options.width,
            difficulty=Difficulty.preset(options.difficulty))
        if progress is not None:
            progress(1)
    if options.tracker_noise:
        scene = add_tracker_noise(scene, TrackerNoise(), options.seed)
    if options.boxes_only or options.tracker_noise:
        write_multicam_scene(root, scene)
    record_own_files(root, SYNTH_CAMERAS, files_under(root) - kept)
    return root, scene


@dataclass(frozen=True)
class VideoSynthOptions:
    """One smooth video clip, as ``synth --video`` writes it.

    Attributes:
        out: the folder to write (new, empty, or an earlier ``synth --video`` output).
        config: the scene's scenario, people, image sizes and frame rate.
        n_frames: consecutive frames of the clip.
        seed: the clip's seed (scene, outfits, world, per-frame noise).
        difficulty: the renderer's difficulty (None: medium).
    """

    out: str | os.PathLike
    config: SynthConfig
    n_frames: int
    seed: int
    difficulty: Difficulty | None = None


def synth_video(options: VideoSynthOptions,
                progress: Callable[[int], None] | None = None) -> dict[str, Path]:
    """Render and write the clip of ``options`` frame by frame
    (:func:`~xvmatch.datasets.tracking_video.tracking_frames`: one walk, the worn camera's head
    pose smoothed over a second, so boxes move a few pixels a frame) as a user's data:
    ``top.txt``, ``hor.txt`` (MOT, ground-truth ids), ``top/``, ``hor/`` (PNG frames) and
    ``cameras/``; ``progress`` is called with each frame written.

    Returns:
        The paths written, by name (``top``, ``hor``, ``top_images``, ``hor_images``,
        ``cameras``), under the claimed output folder.
    """
    root = claim_folder(options.out, SYNTH_VIDEO)
    remove_own_files(root, SYNTH_VIDEO)  # an earlier, longer clip: no stale frame
    kept = files_under(root)
    frames = tracking_frames(options.seed, options.n_frames, options.config,
                             difficulty=options.difficulty)
    paths = write_tracking_frames(frames, root, progress)
    record_own_files(root, SYNTH_VIDEO, files_under(root) - kept)
    return paths


@dataclass(frozen=True)
class EgosSynthOptions:
    """One scene seen by the top camera and several head-worn cameras, as ``synth --egos K``
    writes it.

    Attributes:
        out: the folder to write (new, empty, or an earlier ``synth --egos`` output).
        n_ego: head-worn cameras, 1..3 (:data:`~xvmatch.datasets.multi_ego_scenes.MAX_EGO`).
        n_frames: frames of the scene (held in memory while rendered).
        seed: the scene's seed.
        image_size: ``(width, height)`` of every view.
        fps: frame rate of the walk.
        people: ``(min, max)`` people, or None: 6 to 12 (at least ``n_ego + 3``).
        difficulty: the renderer's difficulty (None: medium).
    """

    out: str | os.PathLike
    n_ego: int
    n_frames: int
    seed: int
    image_size: tuple[int, int] = (640, 360)
    fps: float = 10.0
    people: tuple[int, int] | None = None
    difficulty: Difficulty | None = None


def synth_egos(options: EgosSynthOptions) -> MultiEgoInputs:
    """Render the drone scene of ``options`` in every view
    (:func:`~xvmatch.datasets.multi_ego_scenes.render_multi_ego`) and write it as a user's data
    (:func:`~xvmatch.datasets.multi_ego_scenes.write_multi_ego_inputs`): ``top.txt``,
    ``hor1.txt`` ... (MOT, ground-truth ids), ``images/VIEW/`` and ``cameras/horK/``.

    Returns:
        The files written, per view.
    """
    changes = {"top_size": options.image_size, "ego_size": options.image_size,
               "fps": options.fps}
    if options.people is not None:
        changes["n_people"] = options.people
    config = multi_ego_config(options.n_ego, **changes)
    root = claim_folder(options.out, SYNTH_EGOS)
    remove_own_files(root, SYNTH_EGOS)
    kept = files_under(root)
    frames = render_multi_ego(options.seed, options.n_ego, options.n_frames, config,
                              options.difficulty)
    inputs = write_multi_ego_inputs(frames, root, options.seed)
    record_own_files(root, SYNTH_EGOS, files_under(root) - kept)
    return inputs
