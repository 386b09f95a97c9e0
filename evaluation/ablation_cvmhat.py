"""The box-only part of the ablation on real CVMHAT boxes (``xvmatch ablate --cvmhat DIR``).

Every sequence pair ``NAME_top.txt`` / ``NAME_hor.txt`` of the folder
(:func:`~xvmatch.formats.cvmhat.sequence_names`), every ``step``-th frame (frames of either
file, ascending, from the first), in two settings: the clean boxes, and the detector noise of
:mod:`xvmatch.datasets.detector_noise` (5% jitter, 10% misses, 0.3 false boxes per frame and
view; seeded per seed and sequence). Per frame and view the boxes are shuffled (ids scrambled)
before association; the ids are used only to score. Two rows, both from the boxes alone: the
handcrafted spatial-distribution search (:func:`~xvmatch.cues.spatial_search.
associate_frame`, the paper's parameters, O searched) and the learned geometry encoder (the
bundle's ONNX matcher, boxes only, the bundle's gamma). Scores pooled over all sequences:
CVIDF1 (the CVMHAT paper's metric), CVMA and the Eq. 9 accuracy.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from xvmatch.cues.matcher_inputs import matcher_inputs
from xvmatch.cues.spatial_search import associate_frame
from xvmatch.datasets.detector_noise import FALSE_ID_BASE, DetectorNoise, apply_detector_noise
from xvmatch.evaluation.ablation_cells import CELL_FORMAT, CELL_VERSION
from xvmatch.formats.cvmhat import IMAGE_SIZE, read_sequence, sequence_names
from xvmatch.formats.mot_boxes import FALSE_POSITIVE
from xvmatch.inference.linking.assignment import assign
from xvmatch.inference.matching.learned_association import LearnedMatcher
from xvmatch.metrics.cross_view_metrics import count_pair, summarize

__all__ = [
    "CVMHAT_ROWS",
    "CVMHAT_SETTINGS",
    "BoxFrame",
    "CvmhatSpec",
    "compute_cvmhat_cell",
    "cvmhat_frames",
]

CVMHAT_SETTINGS: dict[str, str] = {"clean": "clean boxes", "det": "detector noise"}
"""The CVMHAT columns."""
CVMHAT_ROWS: dict[str, str] = {
    "search": "CVMHAT spatial search (handcrafted)",
    "learned/boxes": "learned encoder: boxes (ONNX)",
}
"""The CVMHAT rows."""


@dataclass(frozen=True, eq=False)
class CvmhatSpec:
    """One CVMHAT cell: the folder, a setting of :data:`CVMHAT_SETTINGS`, a seed and the frame
    step; ``model`` and ``options`` as :class:`~xvmatch.evaluation.ablation_cells.CellSpec`."""

    folder: str
    setting: str
    seed: int
    step: int
    model: str
    options: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        """The cell's file stem: ``cvmhat__SETTING__seedS``."""
        return f"cvmhat__{self.setting}__seed{self.seed}"


@dataclass(frozen=True, eq=False)
class BoxFrame:
    """One frame pair of boxes, shuffled per view, with the ids to score it.

    Attributes:
        sequence: the sequence name.
        frame: the frame number.
        top_boxes, hor_boxes: ``(M, 4)`` and ``(N, 4)`` shuffled boxes.
        gt_top_ids, gt_hor_ids: the clean ids of the frame.
        det_top_ids, det_hor_ids: the id each shuffled box stands for (-1: a false box).
    """

    sequence: str
    frame: int
    top_boxes: np.ndarray
    hor_boxes: np.ndarray
    gt_top_ids: np.ndarray
    gt_hor_ids: np.ndarray
    det_top_ids: np.ndarray
    det_hor_ids: np.ndarray


def _stands_for(ids: np.ndarray) -> np.ndarray:
    ids = np.asarray(ids, np.int64)
    return np.where(ids >= min(FALSE_ID_BASE.values()), FALSE_POSITIVE, ids)


def cvmhat_frames(folder: str | os.PathLike, setting: str, seed: int, step: int
                  ) -> list[BoxFrame]:
    """The frames of every sequence of ``folder`` in one setting and seed (module docstring).

    Raises:
        ValueError: an unknown setting, a step < 1, or no sequence pair in the folder.
    """
    if setting not in CVMHAT_SETTINGS:
        raise ValueError(f"setting must be one of {', '.join(CVMHAT_SETTINGS)}, got {setting!r}")
    if int(step) < 1:
        raise ValueError(f"step must be >= 1, got {step}")
    names = sequence_names(folder)
    if not names:
        raise ValueError(f"{os.fspath(folder)}: no CVMHAT sequence pairs (NAME_top.txt with "
                         "NAME_hor.txt)")
    out: list[BoxFrame] = []
    for index, name in enumerate(names):
        top, hor = read_sequence(folder, name)
        boxes = {"top": top, "hor": hor}
        if setting == "det":
            noise_seed = int(np.random.SeedSequence([int(seed), index]).generate_state(1)[0])
            boxes = {v: apply_detector_noise(b, IMAGE_SIZE, DetectorNoise(), noise_seed, v)
                     for v, b in boxes.items()}
        frames = sorted(set(top) | set(hor))[:: int(step)]
        for frame in frames:
            rng = np.random.default_rng([int(seed), index, frame])
            gt, shuffled, ids = {}, {}, {}
            for v, clean in (("top", top), ("hor", hor)):
                gt[v] = clean[frame].ids if frame in clean else np.zeros(0, np.int64)
                record = boxes[v].get(frame)
                b = record.boxes if record is not None else np.zeros((0, 4))
                i = record.ids if record is not None else np.zeros(0, np.int64)
                order = rng.permutation(len(i))
                shuffled[v], ids[v] = b[order], _stands_for(i[order])
            out.append(BoxFrame(name, frame, shuffled["top"], shuffled["hor"], gt["top"],
                                gt["hor"], ids["top"], ids["hor"]))
    return out


def _learned_pairs(matcher: LearnedMatcher, frames: list[BoxFrame],
                   batch_size: int = 64) -> list[np.ndarray]:
    """The learned matcher's pairs (input order) of each frame, boxes only."""
    pairs: list[np.ndarray] = [np.zeros((0, 2), np.int64)] * len(frames)
    todo = [k for k, f in enumerate(frames) if len(f.top_boxes) and len(f.hor_boxes)]
    inputs = [matcher_inputs(frames[k].top_boxes, frames[k].hor_boxes, IMAGE_SIZE,
                             matcher.feature_config, matcher.cues) for k in todo]
    for k, f, c in zip(todo, inputs, matcher.costs(inputs, batch_size), strict=True):
        full = np.empty_like(c)
        full[np.ix_(f.features.top_order, f.features.hor_order)] = c
        pairs[k] = assign(full, matcher.gamma)
    return pairs


def compute_cvmhat_cell(spec: CvmhatSpec, matcher: LearnedMatcher) -> dict:
    """Both rows on one CVMHAT cell; a JSON-ready record like a synthetic cell's (rows with
    their Eq. 9 accuracy, CVIDF1 and CVMA, no per-frame data)."""
    start = time.perf_counter()
    frames = cvmhat_frames(spec.folder, spec.setting, spec.seed, spec.step)
    found = {
        "search": [associate_frame(f.top_boxes, f.hor_boxes, IMAGE_SIZE[0]).pairs
                   for f in frames],
        "learned/boxes": _learned_pairs(matcher, frames),
    }
    rows = {}
    for key, pairs in found.items():
        scores = summarize([count_pair(f.gt_top_ids, f.gt_hor_ids, f.det_top_ids,
                                       f.det_hor_ids, p, frame=f.frame)
                            for f, p in zip(frames, pairs, strict=True)])
        rows[key] = {"gamma": matcher.gamma if key.startswith("learned") else None,
                     "acc9": scores.acc9, "cvidf1": scores.cvidf1, "cvma": scores.cvma}
    return {
        "format": CELL_FORMAT,
        "version": CELL_VERSION,
        "options": spec.options,
        "scenario": "cvmhat",
        "data": os.fspath(Path(spec.folder)),
        "setting": spec.setting,
        "seed": spec.seed,
        "n_frames": len(frames),
        "n_sequences": len({f.sequence for f in frames}),
        "rows": rows,
        "seconds": round(time.perf_counter() - start, 3),
    }
