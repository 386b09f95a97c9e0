"""Box files read as detections: every row kept, its text kept, its id column only carried along.

``xvmatch track`` takes MOT-style box files whose id column means nothing (detector output often
has ``-1`` on every row) and writes the same rows back with the id replaced by a track id. So the
rows are read with the validation of :func:`xvmatch.formats.mot_boxes.read_mot_boxes` (same
messages, ``<path>:<line>: ...``) but repeated ids are allowed, and each record's ``ids`` are the
row numbers (0-based, over the non-blank lines) rather than the file's ids.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from xvmatch.core.atomic_files import atomic_write_text
from xvmatch.formats.mot_boxes import FrameBoxes, _read_box_table, _require_rows

__all__ = ["DetectionRows", "read_detection_rows", "write_track_rows"]


@dataclass(frozen=True, eq=False)
class DetectionRows:
    """The rows of one box file, read as detections.

    Attributes:
        path: the file read.
        lines: (R,) the non-blank lines, file order, without their line ends.
        file_ids: (R,) int64 the id column of each row (only used to locate the camera wearer).
        frames: ``{frame: FrameBoxes}`` whose ``ids`` are row numbers into ``lines``, ascending
            frames, file order within a frame.
    """

    path: str
    lines: tuple[str, ...]
    file_ids: np.ndarray
    frames: dict[int, FrameBoxes]

    def rows_with_id(self, file_id: int) -> np.ndarray:
        """Row numbers whose id column equals ``file_id`` (e.g. the wearer's ``--camera-id``)."""
        return np.flatnonzero(self.file_ids == int(file_id))

    def positions_of_id(self, file_id: int) -> dict[int, int]:
        """``{frame: position in the frame's record}`` of the first box whose id column equals
        ``file_id``, on the frames that have one."""
        rows = self.rows_with_id(file_id)
        out = {}
        for frame, record in self.frames.items():
            hits = np.flatnonzero(np.isin(record.ids, rows))
            if hits.size:
                out[frame] = int(hits[0])
        return out


def read_detection_rows(path: str | os.PathLike, *, min_score: float | None = None,
                        first_frame: int = 1) -> DetectionRows:
    """Read a ``frame,id,x,y,w,h[,...]`` file keeping every row; ids may repeat.

    A header line is skipped; ``min_score`` and ``first_frame`` are those of
    :func:`xvmatch.formats.mot_boxes.read_mot_boxes` (the rows dropped are not in ``lines``;
    frames are 1-based in ``frames`` while ``lines`` keep the file's text).

    Raises:
        BoxFileError: as :func:`xvmatch.formats.mot_boxes.read_mot_boxes` (missing file, no
            boxes, bad field, ``w``/``h`` <= 0, ...), naming file and line; line numbers count
            blank lines too, as an editor does.
    """
    all_lines, data = _read_box_table(path, min_score, first_frame)
    _require_rows(path, data)
    lines = [ln for ln in all_lines if ln.strip()]
    frames = data[:, 0].astype(np.int64)
    order = np.argsort(frames, kind="stable")
    sorted_frames = frames[order]
    starts = np.flatnonzero(np.r_[True, sorted_frames[1:] != sorted_frames[:-1]])
    ends = np.r_[starts[1:], sorted_frames.size]
    records = {
        int(sorted_frames[s]): FrameBoxes(
            int(sorted_frames[s]), order[s:e].astype(np.int64), data[order[s:e], 2:6]
        )
        for s, e in zip(starts.tolist(), ends.tolist(), strict=True)
    }
    return DetectionRows(os.fspath(path), tuple(lines), data[:, 1].astype(np.int64), records)


def write_track_rows(
    path: str | os.PathLike, rows: DetectionRows, track_of_row: Mapping[int, int]
) -> int:
    """Write the rows that have a track, file order, text unchanged but the id field; atomic.

    Args:
        path: destination file.
        rows: the detections the tracks were computed from.
        track_of_row: ``{row: track id}``; rows absent here (dropped by the tracker) are absent
            from the output.

    Returns:
        The number of rows written.
    """
    out = []
    for row in sorted(track_of_row):
        fields = rows.lines[row].split(",")
        fields[1] = str(int(track_of_row[row]))
        out.append(",".join(fields) + "\n")
    atomic_write_text(path, "".join(out))
    return len(out)
