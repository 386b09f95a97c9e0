"""The costs file of a learned run (``xvmatch associate --model ... --costs JSON``,
docs/formats.md): each frame's ids and cost matrix, with the run's top camera refinement and its
camera and appearance checks when it had them; written atomically.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping

import numpy as np

from xvmatch.core.atomic_files import atomic_write_text
from xvmatch.inference.matching.appearance_check import AppearanceCheck
from xvmatch.inference.matching.camera_check import CameraCheck
from xvmatch.inference.matching.camera_refinement import CameraRefinement
from xvmatch.inference.matching.site_bundle import json_figure

__all__ = ["costs_record", "write_costs_record"]


def costs_record(top: Mapping, hor: Mapping, costs: Mapping[int, np.ndarray], gamma: float,
                 checked: AppearanceCheck | None = None,
                 camera_checked: CameraCheck | None = None,
                 refinement: CameraRefinement | None = None) -> dict:
    """The costs file's record (version 1): ``gamma`` and, per frame of ``costs``, the top and
    horizontal ids (from ``top`` and ``hor``, ``{frame: FrameBoxes}``) and the cost matrix
    rounded to 6 decimals; then the refinement and the checks, when given."""
    record: dict = {
        "version": 1,
        "gamma": gamma,
        "frames": {
            str(f): {"top_ids": [int(i) for i in top[f].ids],
                     "hor_ids": [int(i) for i in hor[f].ids],
                     "cost": [[round(float(v), 6) for v in row] for row in c]}
            for f, c in sorted(costs.items())
        },
    }
    if refinement is not None:
        fit = refinement.fit
        record["top_camera_refinement"] = {
            "turned": refinement.turned, "moving": refinement.moving,
            "message": refinement.message, "fit": None if fit is None else {
                "frame": fit.frame, "rotation_deg": list(fit.rotation_deg),
                "angle_deg": fit.angle_deg, "frames": fit.frames,
                "loss_before": json_figure(fit.loss_before),
                "loss_after": json_figure(fit.loss_after)}}
    if camera_checked is not None:
        record["camera_check"] = {
            "judged": camera_checked.judged, "cameras_used": camera_checked.trusted,
            "kept": camera_checked.kept, "positives": camera_checked.positives,
            "share": json_figure(camera_checked.share),
            "standard_error": json_figure(camera_checked.error),
            "consistency": json_figure(camera_checked.consistency),
            "fit_loss": json_figure(camera_checked.fit_loss),
            "top_camera_moving": camera_checked.moving,
            "min_keep": camera_checked.min_keep, "min_pairs": camera_checked.min_pairs}
    if checked is not None:
        record["appearance_check"] = {
            "judged": checked.judged, "images_used": checked.trusted,
            "auc": json_figure(checked.auc), "standard_error": json_figure(checked.error),
            "positives": checked.positives, "negatives": checked.negatives,
            "min_auc": checked.min_auc, "min_pairs": checked.min_pairs}
        if checked.frames:
            record["appearance_check"]["frame_check"] = {
                "frames": checked.frames, "from_boxes": checked.frames_dropped}
    return record


def write_costs_record(path: str | os.PathLike, top: Mapping, hor: Mapping,
                       costs: Mapping[int, np.ndarray], gamma: float,
                       checked: AppearanceCheck | None = None,
                       camera_checked: CameraCheck | None = None,
                       refinement: CameraRefinement | None = None) -> None:
    """Write :func:`costs_record` to ``path`` atomically, as one line of JSON."""
    atomic_write_text(path, json.dumps(costs_record(top, hor, costs, gamma, checked,
                                                    camera_checked, refinement)) + "\n")
