"""The files of ``xvmatch multicam`` beside its box files: ground positions (``ground.csv``, a
true-positions CSV), image/ground point pairs for ``--fit-homography``, and the whole output
folder written atomically (docs/formats.md, multicam outputs).

Bad input raises ``ValueError`` with one line naming the file and the line.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from xvmatch.core.atomic_files import atomic_write_bytes, atomic_write_text
from xvmatch.core.input_files import read_input_text
from xvmatch.formats.mot_boxes import FrameBoxes, write_mot_boxes

__all__ = ["multicam_box_files", "read_ground_csv", "read_point_pairs",
           "write_multicam_outputs"]

GroundPaths = Mapping[int, tuple[np.ndarray, np.ndarray]]
"""``{global_id: (frames (J,), (J, 2) ground xy in metres)}``."""


def read_ground_csv(path: str | os.PathLike) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """``{global_id: (frames, (J, 2) xy)}`` of a CSV ``frame,global_id,X,Y`` (ground.csv or
    true positions), each id's rows sorted by frame; a bad line is an error naming the file and
    the line."""
    try:
        with open(path, encoding="utf-8") as fh:
            lines = fh.read().split("\n")
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not UTF-8 text") from None
    if not lines or [h.strip() for h in lines[0].split(",")] != ["frame", "global_id", "X",
                                                                   "Y"]:
        raise ValueError(f"{path}:1: expected the header frame,global_id,X,Y")
    rows: dict[int, list[tuple[int, float, float]]] = {}
    for lineno, line in enumerate(lines[1:], 2):
        if not line.strip():
            continue
        fields = line.split(",")
        try:
            if len(fields) != 4:
                raise ValueError
            frame, gid = int(fields[0]), int(fields[1])
            x, y = float(fields[2]), float(fields[3])
            if not (np.isfinite(x) and np.isfinite(y)):
                raise ValueError
        except ValueError:
            raise ValueError(f"{path}:{lineno}: expected frame,global_id,X,Y (integers, then "
                             "finite numbers)") from None
        rows.setdefault(gid, []).append((frame, x, y))
    out = {}
    for gid, pts in rows.items():
        pts.sort()
        arr = np.array(pts, dtype=float)
        out[gid] = (arr[:, 0].astype(np.int64), arr[:, 1:])
    return out


def read_point_pairs(path: str | os.PathLike, option: str = "--fit-homography"
                     ) -> dict[str, np.ndarray]:
    """``{camera: (N, 4) u, v, X, Y}`` of a CSV ``camera,u,v,X,Y`` (pixels, ground metres), in
    the order of the file; ``option`` names the file in a read error."""
    points: dict[str, list[tuple[float, ...]]] = {}
    lines = read_input_text(path, option).split("\n")
    header = [h.strip() for h in lines[0].split(",")] if lines else []
    if header != ["camera", "u", "v", "X", "Y"]:
        raise ValueError(f"{path}:1: expected the header camera,u,v,X,Y")
    for lineno, line in enumerate(lines[1:], 2):
        if not line.strip():
            continue
        fields = [f.strip() for f in line.split(",")]
        if len(fields) != 5:
            raise ValueError(f"{path}:{lineno}: expected 5 fields camera,u,v,X,Y")
        try:
            values = tuple(float(v) for v in fields[1:])
        except ValueError:
            raise ValueError(f"{path}:{lineno}: u, v, X, Y must be numbers") from None
        if not np.isfinite(values).all():
            raise ValueError(f"{path}:{lineno}: u, v, X, Y must be finite")
        points.setdefault(fields[0], []).append(values)
    if not points:
        raise ValueError(f"{path}: no point pairs")
    return {name: np.array(rows) for name, rows in points.items()}


def multicam_box_files(folder: str | os.PathLike, cameras: Mapping[str, str]) -> dict[str, str]:
    """Each camera's box file in a multicam output folder (``--multicam``), in the order of
    ``cameras`` (``{camera: its ground-truth file}``, named when the folder lacks its file)."""
    where = Path(folder)
    if not where.is_dir():
        raise ValueError(f"--multicam {folder}: no such folder (the --out of xvmatch multicam)")
    written = sorted(p.stem for p in where.glob("*.txt"))
    out = {}
    for name, path in cameras.items():
        mine = where / f"{name}.txt"
        if not mine.is_file():
            raise ValueError(f"--gt {name}={path}: {mine} does not exist (multicam wrote "
                             f"{', '.join(written) or 'no box file'} there)")
        out[name] = str(mine)
    return out


def write_multicam_outputs(out: Path, boxes: Mapping[str, Mapping[int, FrameBoxes]],
                           relabelled: Mapping[str, Mapping[int, FrameBoxes]],
                           ground: GroundPaths, picture: bytes) -> None:
    """Every file of a multicam output folder, each atomically: ``NAME.txt`` (the boxes with
    global ids), ``tracks.csv`` (one line per stretch of a track under one global id),
    ``ground.csv`` and ``birdseye.png``. ``boxes`` are the input boxes (their track ids),
    ``relabelled`` the same boxes with global ids."""
    for name, frames in relabelled.items():
        write_mot_boxes(out / f"{name}.txt", frames)
    atomic_write_text(out / "tracks.csv", _tracks_csv(boxes, relabelled))
    lines = ["frame,global_id,X,Y"]
    points = [(int(f), g, x, y) for g, (fr, xy) in ground.items()
              for f, (x, y) in zip(fr.tolist(), xy.tolist(), strict=True)]
    points.sort()
    lines += [f"{f},{g},{x:.4f},{y:.4f}" for f, g, x, y in points]
    atomic_write_text(out / "ground.csv", "\n".join(lines) + "\n")
    atomic_write_bytes(out / "birdseye.png", picture)


def _tracks_csv(boxes: Mapping[str, Mapping[int, FrameBoxes]],
                relabelled: Mapping[str, Mapping[int, FrameBoxes]]) -> str:
    """``tracks.csv``: ``camera,track_id,first_frame,last_frame,global_id``, one line per
    stretch of a track under one global id."""
    rows = ["camera,track_id,first_frame,last_frame,global_id"]
    for name, frames in relabelled.items():
        spans: list[list[int]] = []
        open_span: dict[int, list[int]] = {}
        for f in sorted(frames):
            for t, g in zip(boxes[name][f].ids.tolist(), frames[f].ids.tolist(), strict=True):
                span = open_span.get(t)
                if span is None or span[3] != g:
                    span = [t, f, f, g]
                    open_span[t] = span
                    spans.append(span)
                span[2] = f
        rows += [f"{name},{t},{a},{b},{g}" for t, a, b, g in sorted(spans)]
    return "\n".join(rows) + "\n"
