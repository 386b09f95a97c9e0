"""``xvmatch evaluate --tracks DIR``: the tracking scores of the folder ``xvmatch track`` wrote;
and ``evaluate --multicam DIR`` / ``--gt NAME=FILE``: those of several cameras' global ids.

Reads ``DIR/top.txt`` and ``DIR/hor.txt`` and the offset ``track`` applied (``DIR/offset.json``,
or ``--offset N``), re-times the tracks and the ground truth the same way, and prints the
cross-view scores with TrackEval's per-view IDF1, MOTA, MOTP and HOTA
(:func:`xvmatch.metrics.track_metrics.evaluate_tracks`), or the cross-view scores alone with a
note when TrackEval is not installed. Bad input raises ``ValueError`` with a one-line message.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from xvmatch.commands._options import UsageError, read_boxes
from xvmatch.commands.multicam import named_paths
from xvmatch.commands.track import OFFSET_FILE

__all__ = ["TRACKEVAL_MISSING", "evaluate_multicam_command", "evaluate_tracks_command",
           "tracked_offset"]

TRACKEVAL_MISSING = ("xvmatch: note: per-view IDF1, MOTA, MOTP and HOTA need the TrackEval "
                     "package: pip install --no-deps trackeval")
"""The line ``evaluate --tracks`` prints on stderr when TrackEval is not installed."""


def _trackeval_installed() -> bool:
    """Whether TrackEval's metrics import (its optional dataset readers' messages hidden)."""
    import contextlib
    import io

    try:
        with contextlib.redirect_stdout(io.StringIO()):
            import trackeval.metrics  # noqa: F401
    except ImportError:
        return False
    return True


def tracked_offset(folder: Path) -> int:
    """The offset ``track`` applied to the tracks in ``folder`` (its :data:`OFFSET_FILE`,
    checked as ``--offset`` is: :func:`~xvmatch.formats.offset_record.read_offset_record`; 0
    when absent, as in folders written before it existed)."""
    from xvmatch.commands._types import MAX_FRAME_OFFSET
    from xvmatch.formats.offset_record import read_offset_record

    path = folder / OFFSET_FILE
    if not path.exists():
        return 0
    return read_offset_record(path, MAX_FRAME_OFFSET)


def evaluate_tracks_command(args: argparse.Namespace) -> int:
    """``xvmatch evaluate --tracks DIR``: print the tracking scores of DIR/top.txt, DIR/hor.txt.

    Without TrackEval the cross-view scores are printed alone (JSON: ``top`` and ``hor`` are
    null), then one line on stderr naming the package the per-view metrics need; exit 0, as the
    cross-view scores asked for are given (issue 29, item 4)."""
    from dataclasses import asdict

    from xvmatch.formats.mot_boxes import read_mot_boxes
    from xvmatch.metrics.cross_view_metrics import format_table, summarize
    from xvmatch.metrics.track_metrics import (
        evaluate_tracks,
        format_track_table,
        track_pair_counts,
        track_scores_to_dict,
    )

    folder = Path(args.tracks)
    if not folder.is_dir():
        raise ValueError(f"--tracks {args.tracks}: not a folder (expected the --out of "
                         "xvmatch track, with top.txt and hor.txt)")
    tracks_top = read_mot_boxes(folder / "top.txt", allow_empty=True)
    tracks_hor = read_mot_boxes(folder / "hor.txt", allow_empty=True)
    gt_top = read_boxes(args.top, args.duplicates)
    gt_hor = read_boxes(args.hor, args.duplicates)
    offset = args.offset if args.offset is not None else tracked_offset(folder)
    if offset:  # tracked with --offset N: both files in their own videos' timing
        from xvmatch.formats.mot_boxes import align_views

        tracks_top, tracks_hor = align_views(tracks_top, tracks_hor, offset)
        gt_top, gt_hor = align_views(gt_top, gt_hor, offset)
    name = args.name or args.tracks
    if not _trackeval_installed():
        cross = summarize(track_pair_counts(tracks_top, tracks_hor, gt_top, gt_hor))
        if args.json:
            print(json.dumps({"cross_view": asdict(cross), "top": None, "hor": None}, indent=2))
        else:
            print(format_table([(name, cross)]))
        print(TRACKEVAL_MISSING, file=sys.stderr)
        return 0
    scores = evaluate_tracks(tracks_top, tracks_hor, gt_top, gt_hor)
    if args.json:
        print(json.dumps(track_scores_to_dict(scores), indent=2))
    else:
        print(format_track_table([(name, scores)]))
    return 0


def evaluate_multicam_command(args: argparse.Namespace) -> int:
    """``xvmatch evaluate --multicam OUT --gt NAME=FILE ... [--ground-gt FILE]``, or with
    ``--pred NAME=FILE ...`` (one MOT box file per camera, ids global) instead of ``--multicam``:
    trajectory P/R, box pairs, global IDF1, CVIDP/CVIDR/CVIDF1/CVMA over every camera pair and,
    with TrackEval, MOTA/IDF1/HOTA per camera."""
    import json
    from pathlib import Path

    from xvmatch.formats.multicam_files import multicam_box_files, read_ground_csv
    from xvmatch.metrics.multicam_cross_view import (
        cross_view_scores,
        format_cross_view,
        view_tracking_scores,
    )
    from xvmatch.metrics.multicam_metrics import format_multicam, multicam_scores

    gt_files = named_paths(args.gt, "--gt")
    if len(gt_files) < 2:
        raise UsageError("--gt: give the ground truth of at least two cameras, NAME=FILE")
    folder = None if args.multicam is None else os.fspath(Path(args.multicam))
    if args.multicam is None:
        pred_files = named_paths(args.pred, "--pred")
        if set(pred_files) != set(gt_files):
            raise UsageError(f"--pred names the cameras {', '.join(pred_files)} but --gt "
                             f"{', '.join(gt_files)}; give both for the same cameras")
        pred_files = {name: pred_files[name] for name in gt_files}
    else:
        pred_files = multicam_box_files(args.multicam, gt_files)
    pred = {name: read_boxes(path, args.duplicates) for name, path in pred_files.items()}
    gt = {name: read_boxes(path, args.duplicates) for name, path in gt_files.items()}
    ground_pred = ground_gt = None
    if args.ground_gt is not None:
        if folder is None:
            raise UsageError("--ground-gt: needs --multicam DIR (its ground.csv); with --pred "
                             "there are no predicted ground positions")
        ground_gt = read_ground_csv(args.ground_gt)
        ground_pred = read_ground_csv(os.path.join(folder, "ground.csv"))
    scores = {**multicam_scores(pred, gt, ground_pred, ground_gt),
              "cross_view": cross_view_scores(pred, gt), "views": view_tracking_scores(pred, gt)}
    if args.json:
        print(json.dumps(scores, indent=2))
    else:
        print(format_multicam(scores, args.name or folder or "multicam tracks"))
        print(format_cross_view(scores["cross_view"], scores["views"]))
    return 0
