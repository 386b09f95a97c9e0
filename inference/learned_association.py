"""Association with the learned box-only geometry model, and its model file format.

The model replaces the handcrafted cost of the CVMHAT search: per frame, the features of
:mod:`xvmatch.datasets.geometry_features` (which run the search itself for the best hypotheses)
go through the :class:`~xvmatch.models.geometry_encoder.GeometryEncoder` inside a box-only
:class:`~xvmatch.models.cross_view_matcher.CrossViewMatcher`, and its cost matrix in [0, 1] through
the Hungarian assignment with a non-association cost gamma (Eqs. 1-2 of the geometric-priors
paper, :func:`xvmatch.inference.assignment.assign`).

This module imports no torch at import time (the ``xvmatch associate`` command without
``--model`` never loads it); torch is imported when a model is loaded.

Model file (``torch.save`` of plain containers, read with ``weights_only=True``)::

    {"format": "xvmatch-geometry-model", "format_version": 1,
     "feature_version": FEATURE_VERSION, "feature_config": {...}, "model_config": {...},
     "gamma": float, "meta": {...JSON-able...}, "state_dict": {name: tensor}}

Written atomically (temporary file, then rename). Loading checks every key and version and says
what is wrong in one line.
"""

from __future__ import annotations

import io
import json
import math
import os
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from xvmatch.datasets.geometry_features import (
    FEATURE_VERSION,
    FeatureConfig,
    FrameFeatures,
    collate_frames,
    frame_features,
)
from xvmatch.datasets.mot_boxes import atomic_write_bytes
from xvmatch.inference.assignment import assign

__all__ = [
    "DEFAULT_MODEL_PATH",
    "MODEL_FORMAT",
    "MODEL_FORMAT_VERSION",
    "LearnedGeometryModel",
    "associate_sequence_learned",
    "load_geometry_model",
    "save_geometry_model",
]

MODEL_FORMAT = "xvmatch-geometry-model"
MODEL_FORMAT_VERSION = 1
DEFAULT_MODEL_PATH = Path(__file__).resolve().parents[1] / "models" / "default_geometry.pt"
"""The shipped default (trained on the box simulator only, by
``training/make_default_geometry.py``)."""

_KEYS = (
    "format",
    "format_version",
    "feature_version",
    "feature_config",
    "model_config",
    "gamma",
    "meta",
    "state_dict",
)


def save_geometry_model(
    path: str | os.PathLike,
    model,
    feature_config: FeatureConfig,
    gamma: float = 0.5,
    meta: Mapping[str, Any] | None = None,
) -> Path:
    """Write a geometry model file atomically.

    Args:
        path: destination (its folder must exist).
        model: a :class:`~xvmatch.models.geometry_encoder.GeometryEncoder`.
        feature_config: the feature configuration it was trained with.
        gamma: the non-association cost to use with it.
        meta: JSON-able notes (training data, seed, scores); never the training data itself.

    Returns:
        The path written.
    """
    import torch

    path = Path(path)
    if not path.parent.is_dir():
        raise ValueError(f"cannot write {os.fspath(path)!r}: folder {os.fspath(path.parent)!r} "
                         "does not exist")
    meta = dict(meta or {})
    json.dumps(meta)  # must be JSON-able
    if not 0.0 < float(gamma) <= 1.0:
        raise ValueError(f"gamma must be in (0, 1], got {gamma}")
    record = {
        "format": MODEL_FORMAT,
        "format_version": MODEL_FORMAT_VERSION,
        "feature_version": FEATURE_VERSION,
        "feature_config": feature_config.to_dict(),
        "model_config": dict(model.config),
        "gamma": float(gamma),
        "meta": meta,
        "state_dict": {k: v.detach().cpu().clone() for k, v in model.state_dict().items()},
    }
    buffer = io.BytesIO()
    torch.save(record, buffer)
    atomic_write_bytes(path, buffer.getvalue())
    return path


@dataclass
class LearnedGeometryModel:
    """A loaded geometry model, ready to associate frames (CPU, eval mode, no gradients).

    Attributes:
        matcher: the box-only :class:`~xvmatch.models.cross_view_matcher.CrossViewMatcher`.
        feature_config: the feature configuration the model expects.
        gamma: non-association cost stored with the model.
        meta: the notes stored with the model.
        path: where it was loaded from.
    """

    matcher: Any
    feature_config: FeatureConfig
    gamma: float = 0.5
    meta: dict = field(default_factory=dict)
    path: str = ""

    def costs(self, feats: list[FrameFeatures], batch_size: int = 64) -> list[np.ndarray]:
        """``(M, N)`` cost matrices in [0, 1] of each frame, rows and columns in canonical
        order (see :class:`FrameFeatures`)."""
        import torch

        out: list[np.ndarray] = []
        with torch.inference_mode():
            for start in range(0, len(feats), batch_size):
                chunk = feats[start : start + batch_size]
                batch = {k: torch.from_numpy(v) for k, v in collate_frames(chunk).items()}
                result = self.matcher(
                    batch["top"], batch["hor"], batch["hyp"], batch["pair"],
                    batch["top_mask"], batch["hor_mask"], batch["hyp_mask"],
                )
                cost = result.cost.numpy().astype(np.float64)
                for k, f in enumerate(chunk):
                    _, m, n = f.shape
                    out.append(cost[k, :m, :n])
        return out

    def associate(self, cost: np.ndarray, gamma: float | None = None) -> np.ndarray:
        """``(K, 2)`` matched (top row, hor row) of an input-order cost matrix (Eq. 2)."""
        return assign(cost, self.gamma if gamma is None else float(gamma))


def _input_order(feats: FrameFeatures, cost: np.ndarray) -> np.ndarray:
    """A canonical-order cost matrix put back in the input order of the frame's boxes."""
    out = np.empty_like(cost)
    out[np.ix_(feats.top_order, feats.hor_order)] = cost
    return out


def _mirrored(boxes: np.ndarray, width: float) -> np.ndarray:
    """Boxes of the image mirrored left-right about x = width / 2."""
    out = np.array(boxes, dtype=float).reshape(-1, 4)
    out[:, 0] = width - out[:, 0] - out[:, 2]
    return out


def _fail(where: str, what: str) -> ValueError:
    return ValueError(f"{where}: {what}")


def load_geometry_model(path_or_default: str | os.PathLike = "default") -> LearnedGeometryModel:
    """Load a geometry model file, or the shipped default with ``"default"``.

    Raises:
        ValueError: missing or unreadable file, another format, a version this code cannot
            read, or weights that do not fit the stored configuration (one line, naming the file).
    """
    import torch

    from xvmatch.models.cross_view_matcher import CrossViewMatcher
    from xvmatch.models.geometry_encoder import GeometryEncoder

    path = DEFAULT_MODEL_PATH if str(path_or_default) == "default" else Path(path_or_default)
    where = os.fspath(path)
    if not path.is_file():
        hint = " (run training/make_default_geometry.py to rebuild it)" if (
            path == DEFAULT_MODEL_PATH) else ""
        raise _fail(where, f"no such model file{hint}")
    try:
        record = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise _fail(where, f"not a geometry model file ({type(exc).__name__}: "
                    f"{str(exc).splitlines()[0] if str(exc) else ''})") from None
    if not isinstance(record, dict) or record.get("format") != MODEL_FORMAT:
        raise _fail(where, f"not a geometry model file (expected format {MODEL_FORMAT!r})")
    missing = [k for k in _KEYS if k not in record]
    if missing:
        raise _fail(where, f"model file lacks {', '.join(missing)}")
    if record["format_version"] != MODEL_FORMAT_VERSION:
        raise _fail(where, f"model format version {record['format_version']}, this xvmatch "
                    f"reads {MODEL_FORMAT_VERSION}")
    if record["feature_version"] != FEATURE_VERSION:
        raise _fail(where, f"model trained on feature version {record['feature_version']}, "
                    f"this xvmatch computes {FEATURE_VERSION}; retrain it (xvmatch fit-geometry)")
    try:
        feature_config = FeatureConfig.from_dict(record["feature_config"])
        model = GeometryEncoder(**record["model_config"])
        model.load_state_dict(record["state_dict"])
    except (TypeError, ValueError, RuntimeError) as exc:
        raise _fail(where, f"model does not fit its configuration: "
                    f"{str(exc).splitlines()[0]}") from None
    gamma = float(record["gamma"])
    if not 0.0 < gamma <= 1.0 or not math.isfinite(gamma):
        raise _fail(where, f"gamma must be in (0, 1], got {gamma}")
    model.eval()
    matcher = CrossViewMatcher(model).eval()
    return LearnedGeometryModel(matcher, feature_config, gamma, dict(record["meta"]), where)


class _FrameLike:
    """Structural type of a frame record: ``ids (N,)`` and ``boxes (N, 4)``."""

    ids: np.ndarray
    boxes: np.ndarray


def associate_sequence_learned(
    top: Mapping[int, _FrameLike],
    hor: Mapping[int, _FrameLike],
    hor_width: float,
    model: LearnedGeometryModel | Sequence[LearnedGeometryModel],
    camera_id: int | None = None,
    gamma: float | None = None,
    progress: Callable[[Iterable[int]], Iterable[int]] | None = None,
    hor_height: float | None = None,
    frames: Iterable[int] | None = None,
    batch_size: int = 64,
    mirror: bool = False,
    costs_out: dict[int, np.ndarray] | None = None,
    workers: int = 1,
) -> dict[int, list[tuple[int, int]]]:
    """Associate every frame on its own with the learned model; ``{frame: [(top_id, hor_id)]}``.

    Ids are only used to report pairs and to find O when ``camera_id`` is given; they never
    enter the model, which sees the boxes only, in a canonical order.

    Args:
        top, hor: ``{frame: record}`` with ``ids`` and ``boxes`` (e.g. ``FrameBoxes``).
        hor_width: width of the horizontal image (pixels).
        model: from :func:`load_geometry_model`, or several: an ensemble whose cost matrices
            are averaged (features are computed once per distinct feature configuration).
        camera_id: top-view id of the camera wearer (O given); frames where it is absent
            search O.
        gamma: non-association cost (default: the (first) model's own).
        progress: optional wrapper around the frame iterator (e.g. a progress bar).
        hor_height: height of the horizontal image (default ``hor_width * 9 / 16``).
        frames: frames to process (default the union of both views' frames).
        batch_size: frames per model call.
        mirror: test-time augmentation: also run the model on both views mirrored left-right
            (the same scene seen in a mirror, which the geometry maps one to one) and average
            the two cost matrices; twice the time.
        costs_out: if given, filled with ``{frame: (M, N) cost matrix}`` (rows and columns in
            the input order of the frame's boxes) of every frame with boxes in both views, e.g.
            to choose gamma on validation frames without running the model again.
        workers: processes computing the features (1: in this process); the result is the same
            for any number.
    """
    if not hor_width > 0:
        raise ValueError(f"hor_width must be > 0, got {hor_width}")
    if int(workers) < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    models = [model] if isinstance(model, LearnedGeometryModel) else list(model)
    if not models:
        raise ValueError("no model given")
    configs: list[FeatureConfig] = []
    for m in models:
        if m.feature_config not in configs:
            configs.append(m.feature_config)
    gamma = models[0].gamma if gamma is None else float(gamma)
    height = float(hor_height) if hor_height is not None else float(hor_width) * 9.0 / 16.0
    size = (float(hor_width), height)
    order = sorted(set(top) | set(hor)) if frames is None else sorted({int(f) for f in frames})
    out: dict[int, list[tuple[int, int]]] = {}
    pending: list[tuple[int, list[list[FrameFeatures]]]] = []

    def flush() -> None:
        per_model = []
        for m in models:
            c = configs.index(m.feature_config)
            views = [f for _, groups in pending for f in groups[c]]
            per_model.append(iter(m.costs(views, batch_size)))
        for frame, groups in pending:
            cost = np.mean([
                _input_order(f, next(costs))
                for m, costs in zip(models, per_model, strict=True)
                for f in groups[configs.index(m.feature_config)]
            ], axis=0)
            if costs_out is not None:
                costs_out[frame] = cost
            pairs = assign(cost, gamma)
            t_ids, h_ids = top[frame].ids, hor[frame].ids
            out[frame] = [(int(t_ids[a]), int(h_ids[b])) for a, b in pairs]
        pending.clear()

    def both(frame: int) -> bool:
        t_rec, h_rec = top.get(frame), hor.get(frame)
        return bool(t_rec is not None and h_rec is not None and len(t_rec.ids) and len(h_rec.ids))

    inputs = []
    for frame in order:
        if both(frame):
            cam = None
            if camera_id is not None:
                hits = np.flatnonzero(np.asarray(top[frame].ids) == camera_id)
                cam = int(hits[0]) if hits.size else None
            inputs.append((top[frame].boxes, hor[frame].boxes, cam))
    stream = _feature_stream(inputs, size, configs, mirror, workers)
    try:
        for frame in progress(order) if progress else order:
            if not both(frame):
                out[frame] = []
                continue
            pending.append((frame, next(stream)))
            if len(pending) >= batch_size:
                flush()
        if pending:
            flush()
    finally:
        stream.close()  # shuts the worker pool down, also on an error or an interrupt
    return {f: out[f] for f in order}


def _frame_groups(
    top_boxes: np.ndarray,
    hor_boxes: np.ndarray,
    size: tuple[float, float],
    configs: Sequence[FeatureConfig],
    camera: int | None,
    mirror: bool,
) -> list[list[FrameFeatures]]:
    """Features of one frame pair for each feature configuration: ``[plain]``, or
    ``[plain, mirrored]`` with ``mirror``."""
    groups = []
    for config in configs:
        group = [frame_features(top_boxes, hor_boxes, size, config, camera)]
        if mirror:
            top_width = float(np.max(top_boxes[:, 0] + top_boxes[:, 2]))
            group.append(frame_features(_mirrored(top_boxes, top_width),
                                        _mirrored(hor_boxes, size[0]), size, config, camera))
        groups.append(group)
    return groups


def _groups_of_chunk(
    inputs: Sequence[tuple[np.ndarray, np.ndarray, int | None]],
    size: tuple[float, float],
    configs: Sequence[FeatureConfig],
    mirror: bool,
) -> list[list[list[FrameFeatures]]]:
    return [_frame_groups(tb, hb, size, configs, cam, mirror) for tb, hb, cam in inputs]


def _feature_stream(
    inputs: Sequence[tuple[np.ndarray, np.ndarray, int | None]],
    size: tuple[float, float],
    configs: Sequence[FeatureConfig],
    mirror: bool,
    workers: int,
    chunk: int = 32,
) -> Iterator[list[list[FrameFeatures]]]:
    """:func:`_frame_groups` of each ``(top boxes, hor boxes, camera row)`` in order, computed
    by ``workers`` processes (the k-best hypothesis search dominates the learned path)."""
    if workers == 1 or len(inputs) <= chunk:
        for tb, hb, cam in inputs:
            yield _frame_groups(tb, hb, size, configs, cam, mirror)
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    chunks = [inputs[i : i + chunk] for i in range(0, len(inputs), chunk)]
    # "spawn": the parent has torch (and its thread pools) loaded; a forked child may hang.
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=min(int(workers), len(chunks)),
                             mp_context=context) as pool:
        futures = [pool.submit(_groups_of_chunk, c, size, configs, mirror) for c in chunks]
        try:
            for future in futures:
                yield from future.result()
        finally:
            for future in futures:
                future.cancel()
