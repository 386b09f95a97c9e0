"""Rendering speed of the synthetic image pairs (issue: synthetic image pairs).

Measures, at 640x360 per view:
  1. pairs per second on one core, in-process (OpenCV and BLAS limited to one thread), for each
     scenario: rendering only, and rendering + JPEG encoding + writing files (``write_scene``);
  2. the wall time of a 2,000-pair training set written by ``generate_dataset`` with 2 worker
     processes (process start-up included).
Each line ends with the ratio to its target: >= 30 pairs/s on one core, and 2,000 pairs in
under 120 s with 2 workers (ratio > 1 means the target is met).

Usage:
    python benchmarks/render_speed.py [--scenes 20] [--frames 10] [--pairs 2000] [--skip-set]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from xvmatch.datasets.render.image_render import SceneRenderer  # noqa: E402
from xvmatch.datasets.synthetic_io import generate_dataset, write_scene  # noqa: E402
from xvmatch.datasets.synthetic_scenes import SynthConfig, make_scene  # noqa: E402

SIZE = (640, 360)
TARGET_PAIRS_PER_S = 30.0
TARGET_SET_SECONDS = 120.0


def _render_only(config: SynthConfig, scenes: int, frames: int) -> tuple[float, float, int]:
    """(wall s, CPU s, pairs) of drawing scenes and rendering every pair, no file output."""
    wall, cpu = time.perf_counter(), time.process_time()
    for index in range(scenes):
        rng = np.random.default_rng([0, index])
        renderer = SceneRenderer(make_scene(config, frames, rng), rng)
        for frame in range(1, frames + 1):
            renderer.render(frame)
    return time.perf_counter() - wall, time.process_time() - cpu, scenes * frames


def _render_and_write(config: SynthConfig, scenes: int, frames: int) -> tuple[float, float, int]:
    """Same, plus JPEG encoding and the atomic writes of images and annotations."""
    with tempfile.TemporaryDirectory() as tmp:
        wall, cpu = time.perf_counter(), time.process_time()
        for index in range(scenes):
            write_scene(tmp, config, index, frames, seed=0)
        return time.perf_counter() - wall, time.process_time() - cpu, scenes * frames


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=20, help="scenes per single-core run")
    parser.add_argument("--frames", type=int, default=10, help="frames per scene")
    parser.add_argument("--pairs", type=int, default=2000, help="pairs of the training set")
    parser.add_argument("--workers", type=int, default=2, help="workers for the training set")
    parser.add_argument("--skip-set", action="store_true", help="skip the training-set run")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    print(f"image size {SIZE[0]}x{SIZE[1]} per view, {args.scenes} scenes x {args.frames} "
          f"frames, 3-14 people, one core")
    for scenario in ("drone", "overview"):
        config = SynthConfig(scenario=scenario, top_size=SIZE, ego_size=SIZE)
        _render_only(config, 1, 1)  # warm-up: imports, noise bank
        for name, run in (("render", _render_only), ("render+write", _render_and_write)):
            wall, cpu, pairs = run(config, args.scenes, args.frames)
            rate = pairs / cpu
            print(f"{scenario:9s} {name:13s} {rate:6.1f} pairs/s (CPU), "
                  f"{pairs / wall:6.1f} pairs/s (wall)  target {TARGET_PAIRS_PER_S:.0f}: "
                  f"x{rate / TARGET_PAIRS_PER_S:.2f}")
    if not args.skip_set:
        frames = args.frames
        scenes = -(-args.pairs // frames)
        config = SynthConfig(scenario="drone", top_size=SIZE, ego_size=SIZE)
        with tempfile.TemporaryDirectory() as tmp:
            start = time.perf_counter()
            generate_dataset(tmp, config, n_scenes=scenes, n_frames=frames, seed=0,
                             workers=args.workers)
            elapsed = time.perf_counter() - start
        print(f"training set: {scenes * frames} pairs ({scenes} scenes x {frames} frames) with "
              f"{args.workers} workers in {elapsed:.1f} s  target {TARGET_SET_SECONDS:.0f} s: "
              f"x{TARGET_SET_SECONDS / elapsed:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
