"""How exact a static top camera is when calibrated from its people (issue 67), on rendered
oblique scenes (:mod:`xvmatch.datasets.oblique_scenes`, default settings: pitch 20-90 degrees,
4-60 m up, field of view 55-85 degrees, 3-12 people, 1920x1080), one ``--seconds`` clip each.

Per scene: the kind found (oblique or nadir), the tilt error, the horizon error in image heights
(where the true horizon is within an image height of the image), whether the strict calibration
(``xvmatch calibrate``) refused and why; then a table per pitch band.

    .venv/bin/python benchmarks/people_calibration_eval.py --scenes 24
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from xvmatch.datasets.oblique_scenes import ObliqueSceneConfig, make_oblique_scene
from xvmatch.formats.mot_boxes import stack_frames
from xvmatch.geometry.people_calibration import (
    CalibrationError,
    calibrate_from_people,
    horizon_line,
)

BANDS = ((20.0, 40.0), (40.0, 60.0), (60.0, 80.0), (80.0, 90.1))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", type=int, default=24)
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    config = ObliqueSceneConfig()
    rows = []
    t0 = time.perf_counter()
    for k in range(args.scenes):
        scene = make_oblique_scene(config, int(args.seconds * config.fps),
                                   np.random.default_rng([args.seed, k]))
        camera = scene.top_cameras[0]
        size = camera.image_size
        pitch = float(np.degrees(np.arcsin(-camera.R[2, 2])))
        true_horizon = float(np.mean(horizon_line(camera)))
        numbers, ids, boxes = stack_frames(scene.top)
        strict = "yes"
        try:
            calibrate_from_people(numbers, boxes, size, ids=ids)
        except CalibrationError as exc:
            strict = "refused: " + str(exc).split(": ", 1)[1].split(";")[0][:60]
        try:
            calib = calibrate_from_people(numbers, boxes, size, ids=ids, strict=False)
        except CalibrationError as exc:
            print(f"scene {k:2d} pitch {pitch:4.1f}: {exc}")
            rows.append((pitch, "none", np.nan, np.nan, strict))
            continue
        tilt = 90.0 if calib.kind == "nadir" else calib.tilt_deg
        near = -size[1] <= true_horizon <= 2 * size[1]
        horizon = (abs(float(np.mean(calib.horizon)) - true_horizon) / size[1]
                   if calib.kind == "oblique" and near else np.nan)
        rows.append((pitch, calib.kind, tilt - pitch, horizon, strict))
        print(f"scene {k:2d} pitch {pitch:4.1f} hfov "
              f"{np.degrees(2 * np.arctan(0.5 * size[0] / camera.K[0, 0])):4.1f}: {calib.kind}, "
              f"tilt error {tilt - pitch:+5.1f}, horizon error {horizon:.3f} H, field of view "
              f"{calib.hfov_deg:4.1f} ({calib.focal_from}); strict: {strict}", flush=True)
    print(f"\n{args.scenes} scenes of {args.seconds:g} s, {time.perf_counter() - t0:.0f} s")
    print("| pitch | scenes | nadir | median abs tilt error | within 3 deg | median horizon "
          "error (H) | strict refused |\n|---|---|---|---|---|---|---|")
    for lo, hi in BANDS:
        sel = [r for r in rows if lo <= r[0] < hi]
        if not sel:
            continue
        tilt = np.abs([r[2] for r in sel])
        hor = np.array([r[3] for r in sel], float)
        hor_text = f"{np.nanmedian(hor):.3f}" if np.isfinite(hor).any() else "-"
        print(f"| {lo:.0f}-{min(hi, 90):.0f} | {len(sel)} | {sum(r[1] == 'nadir' for r in sel)} | "
              f"{np.nanmedian(tilt):.1f} | {int(np.sum(tilt <= 3.0))} | {hor_text} | "
              f"{sum(r[4] != 'yes' for r in sel)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
