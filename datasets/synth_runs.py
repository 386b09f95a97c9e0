"""The runs of ``xvmatch synth`` that write one folder of their own: a scene of several static
cameras (``--cameras N``, the input of ``xvmatch multicam``).

Each run takes one frozen options record and writes into a folder it claims (a marker listing
the files it wrote, :mod:`xvmatch.core.folder_marker`): a later run into the same folder removes
only those, never a file the user put there. The command checks the options' combinations; these
functions render and write.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from xvmatch.core.folder_marker import files_under, record_own_files, remove_own_files
from xvmatch.core.output_paths import claim_folder
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

__all__ = ["SYNTH_CAMERAS", "CamerasSynthOptions", "synth_cameras"]

SYNTH_CAMERAS = "synth --cameras"
"""The command name in the marker of a ``synth --cameras`` folder (it may replace only its own)."""


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
