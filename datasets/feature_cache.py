"""Features of whole sequences: flat storage, parallel extraction and a disk cache.

The per-frame features of the learned geometry model are built by
:func:`xvmatch.cues.spatial_features.frame_features` (one exact search per candidate camera
location, tens of milliseconds per frame), so training sets are extracted by several processes
and cached on disk, keyed by a hash of the boxes, the image size, the configuration and
:data:`~xvmatch.cues.spatial_features.FEATURE_VERSION`.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import warnings
import zipfile
import zlib
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from xvmatch.core.atomic_files import atomic_write_bytes
from xvmatch.core.worker_pool import worker_pool
from xvmatch.cues.matcher_inputs import matcher_features
from xvmatch.cues.spatial_features import (
    FEATURE_VERSION,
    HOR_FEATURES,
    HYP_FEATURES,
    PAIR_FEATURES,
    TOP_FEATURES,
    FeatureConfig,
    FrameFeatures,
    frame_features,
)
from xvmatch.geometry.camera import FrameCameras

__all__ = [
    "FeatureSet",
    "FrameJob",
    "StaleFeaturesError",
    "cache_key",
    "cached_frame_features",
    "cached_sequence_features",
    "default_cache_dir",
    "sequence_features",
]


_ARRAYS = ("top", "hor", "hyp", "pair", "top_order", "hor_order", "hyp_camera")


@dataclass(frozen=True, eq=False)
class FeatureSet:
    """Features of many frames, stored flat (one concatenated array per field) with offsets.

    Attributes:
        frames: ``(F,)`` frame numbers.
        shapes: ``(F, 3)`` (H, M, N) of each frame.
        arrays: ``{field: concatenated array}`` for the fields of :class:`FrameFeatures`.
    """

    frames: np.ndarray
    shapes: np.ndarray
    arrays: dict[str, np.ndarray]

    def __len__(self) -> int:
        return int(self.frames.shape[0])

    def _offsets(self) -> dict[str, np.ndarray]:
        h, m, n = self.shapes.T.astype(np.int64)
        sizes = {
            "top": m, "hor": n, "hyp": h, "pair": h * m * n,
            "top_order": m, "hor_order": n, "hyp_camera": h,
        }
        return {k: np.concatenate([[0], np.cumsum(v)]) for k, v in sizes.items()}

    def frame(self, index: int) -> FrameFeatures:
        """Features of the ``index``-th stored frame."""
        offsets = self.__dict__.get("_cached_offsets")
        if offsets is None:
            offsets = self._offsets()
            object.__setattr__(self, "_cached_offsets", offsets)
        h, m, n = (int(v) for v in self.shapes[index])
        parts = {}
        for k in _ARRAYS:
            a, b = offsets[k][index], offsets[k][index + 1]
            parts[k] = self.arrays[k][a:b]
        parts["pair"] = parts["pair"].reshape(h, m, n, len(PAIR_FEATURES))
        return FrameFeatures(**parts)

    @classmethod
    def from_frames(cls, frames: Sequence[int], feats: Sequence[FrameFeatures]) -> FeatureSet:
        """Pack per-frame features (in the given order)."""
        shapes = np.array([f.shape for f in feats], dtype=np.int64).reshape(-1, 3)
        dims = {
            "top": (0, len(TOP_FEATURES)), "hor": (0, len(HOR_FEATURES)),
            "hyp": (0, len(HYP_FEATURES)), "pair": (0, len(PAIR_FEATURES)),
        }
        arrays = {}
        for k in _ARRAYS:
            if k == "pair":
                parts = [f.pair.reshape(-1, len(PAIR_FEATURES)) for f in feats]
            else:
                parts = [getattr(f, k) for f in feats]
            empty = np.zeros(dims[k], np.float32) if k in dims else np.zeros(0, np.int64)
            arrays[k] = np.concatenate(parts) if parts else empty
        return cls(np.asarray(frames, dtype=np.int64), shapes, arrays)

    def save(self, path: str | os.PathLike) -> None:
        """Write an ``.npz`` atomically (temporary file in the same folder, then rename)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        buffer = io.BytesIO()
        np.savez(buffer, frames=self.frames, shapes=self.shapes,
                 feature_version=np.array(FEATURE_VERSION), **self.arrays)
        atomic_write_bytes(path, buffer.getvalue(), fsync=False)

    @classmethod
    def load(cls, path: str | os.PathLike) -> FeatureSet:
        """Read a file written by :meth:`save`.

        Raises:
            ValueError: a different feature version, or a truncated or corrupt file (one line
                naming it).
            OSError: the file cannot be opened.
        """
        try:
            with np.load(path, allow_pickle=False) as data:
                version = int(data["feature_version"])
                if version != FEATURE_VERSION:
                    raise StaleFeaturesError(
                        f"{os.fspath(path)}: feature version {version}, this code computes "
                        f"{FEATURE_VERSION}; delete the cache file to recompute"
                    )
                return cls(data["frames"], data["shapes"], {k: data[k] for k in _ARRAYS})
        except (KeyError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
            first = str(exc).splitlines()[0] if str(exc) else ""
            raise ValueError(f"{os.fspath(path)}: not a readable feature cache file "
                             f"({type(exc).__name__}: {first})") from None


def _load_cached(path: Path) -> FeatureSet | None:
    """A cache file's features, or None (with a warning naming it) when it cannot be read."""
    if not path.exists():
        return None
    try:
        return FeatureSet.load(path)
    except StaleFeaturesError:  # written by an earlier xvmatch: expected after an upgrade
        return None
    except (OSError, ValueError) as exc:
        warnings.warn(f"{exc}; rebuilding it", stacklevel=3)
        return None


class StaleFeaturesError(ValueError):
    """A feature file of another feature version (recomputed, never mixed)."""


class _BoxesLike:
    """Structural type of a frame record: ``ids (N,)`` and ``boxes (N, 4)``."""

    ids: np.ndarray
    boxes: np.ndarray


_EMPTY_BOXES = np.zeros((0, 4))


def _frame_inputs(
    top: Mapping[int, _BoxesLike],
    hor: Mapping[int, _BoxesLike],
    frames: Sequence[int],
    camera_id: int | None,
) -> list[tuple[np.ndarray, np.ndarray, int | None]]:
    out = []
    for f in frames:
        t, h = top.get(f), hor.get(f)
        tb = t.boxes if t is not None else _EMPTY_BOXES
        hb = h.boxes if h is not None else _EMPTY_BOXES
        cam = None
        if camera_id is not None and t is not None:
            hits = np.flatnonzero(np.asarray(t.ids) == camera_id)
            cam = int(hits[0]) if hits.size else None
        out.append((tb, hb, cam))
    return out


def _extract_chunk(args) -> list[FrameFeatures]:
    inputs, hor_size, config_dict = args
    config = FeatureConfig.from_dict(config_dict)
    return [frame_features(tb, hb, hor_size, config, cam) for tb, hb, cam in inputs]


def sequence_features(
    top: Mapping[int, _BoxesLike],
    hor: Mapping[int, _BoxesLike],
    hor_size: tuple[float, float],
    config: FeatureConfig | None = None,
    camera_id: int | None = None,
    frames: Iterable[int] | None = None,
    workers: int = 1,
    progress: Callable[[Iterable], Iterable] | None = None,
) -> FeatureSet:
    """Features of every frame of a sequence pair (ids are used only to find ``camera_id``).

    Args:
        top, hor: ``{frame: record}`` with ``ids`` and ``boxes`` (e.g. ``FrameBoxes``).
        hor_size: (width, height) of the horizontal image.
        config: hypothesis generation.
        camera_id: top-view id of the camera wearer (O given); frames where it is absent
            search O.
        frames: frames to extract (default the union of both views' frames, ascending).
        workers: processes to use (1: in this process).
        progress: optional wrapper around the iterator of chunks (each ~64 frames).
    """
    config = config or FeatureConfig()
    order = sorted(set(top) | set(hor)) if frames is None else sorted({int(f) for f in frames})
    inputs = _frame_inputs(top, hor, order, camera_id)
    size = 64
    chunks = [(inputs[i : i + size], tuple(hor_size), config.to_dict())
              for i in range(0, len(inputs), size)]
    if workers > 1 and len(chunks) > 1:
        with worker_pool(workers, None) as pool:
            results = pool.map(_extract_chunk, chunks)
            results = list(progress(results) if progress else results)
    else:
        it = progress(chunks) if progress else chunks
        results = [_extract_chunk(c) for c in it]
    feats = [f for chunk in results for f in chunk]
    return FeatureSet.from_frames(order, feats)


def default_cache_dir() -> Path:
    """``$XVMATCH_CACHE`` if set, else ``~/.cache/xvmatch``."""
    env = os.environ.get("XVMATCH_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "xvmatch"


def cache_key(
    top: Mapping[int, _BoxesLike],
    hor: Mapping[int, _BoxesLike],
    hor_size: tuple[float, float],
    config: FeatureConfig,
    camera_id: int | None,
    frames: Sequence[int],
) -> str:
    """SHA-256 over the boxes of the frames, the image size, the configuration and the feature
    version (ids enter only through the camera row when ``camera_id`` is given)."""
    digest = hashlib.sha256()
    header = {
        "feature_version": FEATURE_VERSION,
        "config": config.to_dict(),
        "hor_size": [float(v) for v in hor_size],
        "camera_id": camera_id,
    }
    digest.update(json.dumps(header, sort_keys=True).encode())
    for tb, hb, cam in _frame_inputs(top, hor, frames, camera_id):
        digest.update(np.ascontiguousarray(tb, dtype=np.float64).tobytes())
        digest.update(b"|")
        digest.update(np.ascontiguousarray(hb, dtype=np.float64).tobytes())
        digest.update(f"|{cam}#".encode())
    digest.update(np.asarray(frames, dtype=np.int64).tobytes())
    return digest.hexdigest()[:32]


def cached_sequence_features(
    top: Mapping[int, _BoxesLike],
    hor: Mapping[int, _BoxesLike],
    hor_size: tuple[float, float],
    config: FeatureConfig | None = None,
    camera_id: int | None = None,
    frames: Iterable[int] | None = None,
    cache_dir: str | os.PathLike | None = None,
    workers: int = 1,
    progress: Callable[[Iterable], Iterable] | None = None,
) -> FeatureSet:
    """:func:`sequence_features`, read from / written to ``cache_dir`` (default
    :func:`default_cache_dir`) under ``geometry_features/<cache_key>.npz``."""
    config = config or FeatureConfig()
    order = sorted(set(top) | set(hor)) if frames is None else sorted({int(f) for f in frames})
    folder = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    key = cache_key(top, hor, hor_size, config, camera_id, order)
    path = folder / "geometry_features" / f"{key}.npz"
    stored = _load_cached(path)  # unreadable or stale: recomputed and overwritten
    if stored is not None:
        return stored
    feats = sequence_features(
        top, hor, hor_size, config, camera_id, order, workers=workers, progress=progress
    )
    feats.save(path)
    return feats


@dataclass(frozen=True, eq=False)
class FrameJob:
    """One frame pair whose matcher features are wanted (:func:`cached_frame_features`).

    Attributes:
        top_boxes, hor_boxes: ``(M, 4)``, ``(N, 4)`` boxes in their images.
        hor_size: (width, height) of the horizontal image.
        camera: input row of the top box that is O, or None.
        cameras: calibrated cameras (features of the rectified boxes), or None.
    """

    top_boxes: np.ndarray
    hor_boxes: np.ndarray
    hor_size: tuple[float, float]
    camera: int | None = None
    cameras: FrameCameras | None = None


def _job_features(args: tuple[list[FrameJob], dict]) -> list[FrameFeatures]:
    jobs, config_dict = args
    config = FeatureConfig.from_dict(config_dict)
    return [matcher_features(j.top_boxes, j.hor_boxes, j.hor_size, config, j.camera, j.cameras)
            for j in jobs]


def _jobs_key(jobs: Sequence[FrameJob], config: FeatureConfig) -> str:
    digest = hashlib.sha256()
    digest.update(json.dumps({"feature_version": FEATURE_VERSION, "config": config.to_dict(),
                              "kind": "frame-jobs-1"}, sort_keys=True).encode())
    for j in jobs:
        for a in (j.top_boxes, j.hor_boxes, np.asarray(j.hor_size, dtype=np.float64)):
            digest.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
            digest.update(b"|")
        digest.update(f"{j.camera}|".encode())
        if j.cameras is not None:
            for cam in (j.cameras.top, j.cameras.hor):
                digest.update(np.concatenate([cam.K.ravel(), cam.R.ravel(), cam.c,
                                              [cam.width, cam.height]]).tobytes())
        digest.update(b"#")
    return digest.hexdigest()[:32]


def cached_frame_features(
    jobs: Sequence[FrameJob],
    config: FeatureConfig,
    cache_dir: str | os.PathLike | None = None,
    workers: int = 1,
    progress: Callable[[Iterable], Iterable] | None = None,
    chunk: int = 32,
) -> list[FrameFeatures]:
    """Matcher features (:func:`~xvmatch.cues.matcher_inputs.matcher_features`) of many
    frame pairs, computed by ``workers`` processes and cached under
    ``frame_features/<key>.npz`` (key: every box, size, camera row and camera, the
    configuration and the feature version). The result is the same for any ``workers``."""
    folder = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    path = folder / "frame_features" / f"{_jobs_key(jobs, config)}.npz"
    stored = _load_cached(path)  # unreadable or stale: recomputed and overwritten
    if stored is not None and len(stored) == len(jobs):
        return [stored.frame(k) for k in range(len(stored))]
    tasks = [(list(jobs[i : i + chunk]), config.to_dict()) for i in range(0, len(jobs), chunk)]
    if workers > 1 and len(tasks) > 1:
        with worker_pool(workers, "spawn") as pool:
            results = pool.map(_job_features, tasks)
            results = list(progress(results) if progress else results)
    else:
        results = [_job_features(t) for t in (progress(tasks) if progress else tasks)]
    feats = [f for part in results for f in part]
    FeatureSet.from_frames(np.arange(len(feats)), feats).save(path)
    return feats
