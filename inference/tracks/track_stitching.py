"""Stitching the windows' short trajectories into long ones (CVMHAT paper, Algorithm 1).

Window ``t`` covers clips ``t`` and ``t + 1``; consecutive windows share a clip, and the ids of
that shared clip carry the trajectories on. Clip 0 takes its ids from window 0: a top and a
horizontal tracklet joined across views (edge set 3) share a new id, the others get their own.
Then, window by window, clip ``t + 1`` (Algorithm 1, lines 12-17):

- a top tracklet continues the id of the top tracklet joined to it over time (edge set 0),
  else it opens a new id;
- a horizontal tracklet joined across views to a top tracklet (edge set 1) takes that id;
- else one joined over time (edge set 2) continues its predecessor's id, unless a tracklet of
  clip ``t + 1`` already holds that id (the pairing would contradict this window's solution),
  in which case, as when it is joined to nothing, it opens a new id.

Ids are therefore unique per view and clip, whatever the solver returned.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from xvmatch.inference.linking.tracklets import Tracklet

__all__ = ["StitchedTracks", "stitch_windows"]


@dataclass(frozen=True)
class StitchedTracks:
    """Track id of every tracklet and every detection row.

    Attributes:
        top_clip_ids: per clip, (N,) the id of each top tracklet.
        hor_clip_ids: per clip, (N,) the id of each horizontal tracklet.
        top_rows: ``{row: track id}`` of the top-view detections.
        hor_rows: ``{row: track id}`` of the horizontal-view detections.
    """

    top_clip_ids: list[np.ndarray]
    hor_clip_ids: list[np.ndarray]
    top_rows: dict[int, int]
    hor_rows: dict[int, int]


def _successor(e: np.ndarray) -> np.ndarray:
    """For each row of a binary matrix, the column of its edge, or -1."""
    out = np.full(e.shape[0], -1)
    r, c = np.nonzero(e)
    out[r] = c
    return out


def _predecessor(e: np.ndarray) -> np.ndarray:
    """For each column of a binary matrix, the row of its edge, or -1."""
    out = np.full(e.shape[1], -1)
    r, c = np.nonzero(e)
    out[c] = r
    return out


def stitch_windows(
    top: Sequence[Sequence[Tracklet]],
    hor: Sequence[Sequence[Tracklet]],
    windows: Sequence[Sequence[np.ndarray]],
) -> StitchedTracks:
    """Give every tracklet a track id from the windows' edges (Algorithm 1).

    Args:
        top, hor: per clip, the tracklets of each view (``T`` clips).
        windows: ``T - 1`` edge tuples (or one, for a single clip padded with an empty one),
            each the four matrices of :class:`xvmatch.inference.tracks.track_mip.ClusterSolution`
            for clips ``t`` (clusters 0 and 3) and ``t + 1`` (clusters 1 and 2).

    Returns:
        The :class:`StitchedTracks`.
    """
    n_clips = len(top)
    if len(hor) != n_clips:
        raise ValueError(f"both views need the same clips, got {n_clips} and {len(hor)}")
    if n_clips == 0:
        return StitchedTracks([], [], {}, {})
    if len(windows) != max(1, n_clips - 1):
        raise ValueError(f"{n_clips} clips need {max(1, n_clips - 1)} windows, got {len(windows)}")
    next_id = 1

    def fresh() -> int:
        nonlocal next_id
        next_id += 1
        return next_id - 1

    top_ids = [np.zeros(len(c), dtype=np.int64) for c in top]
    hor_ids = [np.zeros(len(c), dtype=np.int64) for c in hor]
    # Clip 0 from window 0's cross-view edges (set 3: horizontal q -> top m).
    top_ids[0][:] = [fresh() for _ in range(len(top[0]))]
    match = _successor(np.asarray(windows[0][3]))
    hor_ids[0][:] = [top_ids[0][m] if m >= 0 else fresh() for m in match.tolist()]
    for t in range(n_clips - 1):
        e0, e1, e2, _ = (np.asarray(e) for e in windows[t])
        before = _predecessor(e0)
        top_ids[t + 1][:] = [top_ids[t][m] if m >= 0 else fresh() for m in before.tolist()]
        taken = set(top_ids[t + 1].tolist())
        across = _predecessor(e1)
        over_time = _successor(e2)
        ids = np.zeros(len(hor[t + 1]), dtype=np.int64)
        for p, n in enumerate(across.tolist()):
            if n >= 0:
                ids[p] = top_ids[t + 1][n]
        used = set(ids[across >= 0].tolist())
        for p in np.flatnonzero(across < 0).tolist():
            q = int(over_time[p])
            inherited = int(hor_ids[t][q]) if q >= 0 else None
            if inherited is not None and inherited not in taken and inherited not in used:
                ids[p] = inherited
            else:
                ids[p] = fresh()
            used.add(int(ids[p]))
        hor_ids[t + 1] = ids

    def rows(clips: Sequence[Sequence[Tracklet]], ids: Sequence[np.ndarray]) -> dict[int, int]:
        return {
            int(r): int(i)
            for clip, clip_ids in zip(clips, ids, strict=True)
            for tr, i in zip(clip, clip_ids.tolist(), strict=True)
            for r in tr.rows.tolist()
        }

    return StitchedTracks(top_ids, hor_ids, rows(top, top_ids), rows(hor, hor_ids))
