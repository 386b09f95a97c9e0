"""How exact a static top camera is when calibrated from its people (issue 67), on rendered
oblique scenes (:mod:`xvmatch.datasets.oblique_scenes`, default settings: pitch 20-90 degrees,
4-60 m up, field of view 55-85 degrees, 3-12 people, 1920x1080), one ``--seconds`` clip each.

Per scene: the kind found (oblique or nadir) by the loose calibration (``strict=False``, what
the association uses), its tilt error (a nadir call counts as a tilt of 90) and horizon error in
image heights; then what the strict calibration (``xvmatch calibrate``) answers, without the
lens and with the true one given (``--hfov``): ``ok`` (tilt within 3 degrees), ``refused`` (and
why) or ``WRONG`` (an answer off by more than 3 degrees: what the target forbids). Then a table
per pitch band (a horizon column: the median error and, in brackets, how many scenes it
counts). The horizon error is counted where the true horizon is within half an image
height of the image (rows -0.5 H to 1.5 H): farther off, a tenth of a degree of tilt or a few
per cent of focal length moves it by more than the target's 3 % and the tilt says it all.
``--box-noise`` loosens each box's edges as a tracker's or annotator's are, ``--edge-people``
adds people walking across the image's bottom edge (their boxes cut by it), ``--top-pitch`` and
``--top-hfov`` draw the cameras from other ranges (a low drone, a wide lens).

    .venv/bin/python benchmarks/people_calibration_eval.py --scenes 24
    .venv/bin/python benchmarks/people_calibration_eval.py --top-pitch 20 45 --box-noise 0.03 \
        --edge-people 1 3
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from xvmatch.datasets.oblique_scenes import ObliqueSceneConfig, jittered, make_oblique_scene
from xvmatch.formats.mot_boxes import stack_frames
from xvmatch.geometry.people_calibration import (
    CalibrationError,
    calibrate_from_people,
    horizon_line,
)

BANDS = ((20.0, 40.0), (40.0, 60.0), (60.0, 80.0), (80.0, 90.1))
TILT_TARGET = 3.0
"""Degrees: the target's tilt error."""
HORIZON_WINDOW = (-0.5, 1.5)
"""True horizon rows (image heights) where its error is counted."""


def _tilt(calib) -> float:
    return 90.0 if calib.kind == "nadir" else calib.tilt_deg


def _horizon_error(calib, true_horizon: float, height: int) -> float:
    """Horizon error in image heights where the true horizon is within
    :data:`HORIZON_WINDOW` (NaN elsewhere, and for a nadir call)."""
    lo, hi = HORIZON_WINDOW
    if calib.kind != "oblique" or not lo * height <= true_horizon <= hi * height:
        return np.nan
    return abs(float(np.mean(calib.horizon)) - true_horizon) / height


def _strict(numbers, boxes, size, ids, pitch: float, hfov: float | None,
            true_horizon: float) -> tuple[str, str, float]:
    """The strict calibration's outcome (ok, refused, WRONG), its line and horizon error."""
    try:
        calib = calibrate_from_people(numbers, boxes, size, ids=ids, hfov_deg=hfov)
    except CalibrationError as exc:
        return "refused", "refused: " + str(exc).split(": ", 1)[1].split(";")[0][:70], np.nan
    error = _tilt(calib) - pitch
    horizon = _horizon_error(calib, true_horizon, size[1])
    return (("ok" if abs(error) <= TILT_TARGET else "WRONG"), f"{calib.kind} {error:+.1f}",
            horizon)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", type=int, default=24)
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--box-noise", type=float, default=0.0, metavar="SIGMA",
                   help="each box edge moved by a normal draw of SIGMA times the box's height, "
                        "then clipped to the image (default 0: exact boxes)")
    p.add_argument("--edge-people", type=int, nargs=2, metavar=("LO", "HI"), default=(0, 0),
                   help="LO-HI more people walking across the image's bottom edge")
    p.add_argument("--top-pitch", type=float, nargs=2, metavar=("LO", "HI"),
                   default=ObliqueSceneConfig.top_pitch, help="the top camera's pitch (degrees)")
    p.add_argument("--top-hfov", type=float, nargs=2, metavar=("LO", "HI"),
                   default=ObliqueSceneConfig.top_hfov,
                   help="the top camera's horizontal field of view (degrees)")
    args = p.parse_args(argv)
    config = ObliqueSceneConfig(top_pitch=tuple(args.top_pitch), top_hfov=tuple(args.top_hfov),
                                edge_people=tuple(args.edge_people))
    rows = []
    t0 = time.perf_counter()
    for k in range(args.scenes):
        scene = make_oblique_scene(config, int(args.seconds * config.fps),
                                   np.random.default_rng([args.seed, k]))
        camera = scene.top_cameras[0]
        size = camera.image_size
        pitch = float(np.degrees(np.arcsin(-camera.R[2, 2])))
        hfov = float(np.degrees(2 * np.arctan(0.5 * size[0] / camera.K[0, 0])))
        true_horizon = float(np.mean(horizon_line(camera)))
        top = scene.top
        if args.box_noise > 0:  # a generator of its own: the scenes drawn stay the same
            top = jittered(top, args.box_noise, np.random.default_rng([args.seed, k, 3]), size)
        numbers, ids, boxes = stack_frames(top)
        strict, strict_text, _ = _strict(numbers, boxes, size, ids, pitch, None, true_horizon)
        given, given_text, given_horizon = _strict(numbers, boxes, size, ids, pitch, hfov,
                                                   true_horizon)
        try:
            calib = calibrate_from_people(numbers, boxes, size, ids=ids, strict=False)
        except CalibrationError as exc:
            print(f"scene {k:2d} pitch {pitch:4.1f}: {exc}")
            rows.append((pitch, "none", np.nan, np.nan, strict, given, given_horizon))
            continue
        tilt = _tilt(calib)
        horizon = _horizon_error(calib, true_horizon, size[1])
        rows.append((pitch, calib.kind, tilt - pitch, horizon, strict, given, given_horizon))
        print(f"scene {k:2d} pitch {pitch:4.1f} hfov {hfov:4.1f}: {calib.kind}, tilt error "
              f"{tilt - pitch:+5.1f}, horizon error {horizon:.3f} H, field of view "
              f"{calib.hfov_deg:4.1f} ({calib.focal_from}); strict: {strict_text}; strict "
              f"--hfov: {given_text}", flush=True)
    print(f"\n{args.scenes} scenes of {args.seconds:g} s, {time.perf_counter() - t0:.0f} s")
    print("| pitch | scenes | loose: nadir | loose: median abs tilt error | loose: within 3 deg "
          "| loose: median horizon error (H) | strict: within 3 / refused / wrong | strict "
          "--hfov: within 3 / refused / wrong | strict --hfov: median horizon error (H) |\n"
          "|---|---|---|---|---|---|---|---|---|")
    for lo, hi in BANDS:
        sel = [r for r in rows if lo <= r[0] < hi]
        if not sel:
            continue
        tilt = np.abs([r[2] for r in sel])
        hor_text, given_hor_text = (
            f"{np.nanmedian(hor):.3f} ({int(np.isfinite(hor).sum())})"
            if np.isfinite(hor).any() else "-"
            for hor in (np.array([r[col] for r in sel], float) for col in (3, 6)))
        counts = [" / ".join(str(sum(r[col] == what for r in sel))
                             for what in ("ok", "refused", "WRONG")) for col in (4, 5)]
        print(f"| {lo:.0f}-{min(hi, 90):.0f} | {len(sel)} | {sum(r[1] == 'nadir' for r in sel)} | "
              f"{np.nanmedian(tilt):.1f} | {int(np.sum(tilt <= TILT_TARGET))} | {hor_text} | "
              f"{counts[0]} | {counts[1]} | {given_hor_text} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
