"""The ``xvmatch evaluate`` command: score predicted pairs (CVIDP, CVIDR, CVIDF1, CVMA, Eq. 9
accuracy), or tracks with ``--tracks``
(:func:`xvmatch.commands.evaluate_tracks.evaluate_tracks_command`), or
a multi-camera association with ``--multicam``
(:func:`xvmatch.commands.evaluate_tracks.evaluate_multicam_command`), or each camera's tracks
with global ids with ``--pred NAME=FILE ... --gt NAME=FILE ...`` (the same scores).

Several prediction CSVs (``--pred A=a.csv B=b.csv``, or ``--pred`` repeated) are scored side by
side against the same ``--top`` and ``--hor``: one table, one row per method, each row re-timed by
its own recorded offset (``PRED.offset.json``) unless ``--offset`` is given."""

from __future__ import annotations

import argparse
import json
import os
import sys

from xvmatch.commands._options import (
    UsageError,
    add_box_inputs,
    add_box_reading_options,
    add_command_parser,
    box_reading,
    read_boxes,
)
from xvmatch.commands._types import frame_offset

__all__ = ["EXAMPLE", "add_evaluate_parser"]

EXAMPLE = "xvmatch evaluate --pred pred.csv --top seq_top.txt --hor seq_hor.txt"


def add_evaluate_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch evaluate`` on ``subparsers`` and return its parser."""
    p = add_command_parser(
        subparsers, "evaluate",
        "Score predicted pairs: CVIDP, CVIDR, CVIDF1, CVMA, Eq. 9 accuracy; or tracks "
        "(--tracks): CVIDF1 and CVMA across views, IDF1, MOTA, MOTP and HOTA per view.",
        EXAMPLE,
    )
    add_box_inputs(p)
    add_box_reading_options(p, min_score=False)  # the boxes are the ground truth
    scored = p.add_mutually_exclusive_group(required=True)
    scored.add_argument("--pred", nargs="+", action="extend", metavar="FILE",
                        help="prediction CSV (frame,top_id,hor_id); several (NAME=FILE or "
                        "FILE, or --pred repeated) are scored side by side, one table row "
                        "each, named NAME or FILE; or, with --gt, each "
                        "camera's boxes as NAME=FILE (MOT format, the id a global person id, "
                        "a tracker's output as it is), scored as --multicam is")
    scored.add_argument("--tracks", metavar="DIR",
                        help="tracks of xvmatch track (DIR/top.txt, DIR/hor.txt); per-view "
                        "metrics need TrackEval (pip install --no-deps trackeval; without it "
                        "the cross-view scores alone, with a note)")
    scored.add_argument("--multicam", metavar="DIR",
                        help="output folder of xvmatch multicam, scored against --gt: the "
                        "trajectory-correspondence paper's P and R (Eqs. 13-14) per camera "
                        "pair, box-pair P/R/F1, global IDF1, CVIDP/CVIDR/CVIDF1/CVMA over "
                        "every camera pair, MOTA/IDF1/HOTA per camera (with TrackEval), "
                        "ground error with --ground-gt")
    p.add_argument("--gt", nargs="+", metavar="NAME=FILE", default=None,
                   help="with --multicam or --pred NAME=FILE: each camera's ground-truth "
                   "boxes, the id a global person id shared across cameras")
    p.add_argument("--ground-gt", metavar="FILE", default=None,
                   help="with --multicam: true ground positions, CSV frame,global_id,X,Y")
    for action in p._actions:  # --top and --hor are not asked for with --multicam
        if action.dest in ("top", "hor"):
            action.required = False
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--name", default=None, help="row label in the table")
    p.add_argument("--offset", type=frame_offset, default=None, metavar="N",
                   help="score predictions made with 'associate --offset N' or tracks made "
                   "with 'track --offset N': the views are re-timed the same way (top frame = "
                   "horizontal frame + N) before scoring, every --pred alike; |N| <= 100000 "
                   "(default: each prediction CSV's recorded PRED.offset.json, else 0; with "
                   "--tracks, the offset that track applied, from DIR/offset.json)")
    p.set_defaults(func=_cmd_evaluate)
    return p


def _cmd_evaluate(args: argparse.Namespace) -> int:
    if args.first_frame != 1 and (args.multicam or args.gt or args.tracks):
        raise UsageError("--first-frame 0 scores prediction CSVs only; renumber the files "
                         "from 1 to score --tracks or --multicam")
    if args.multicam is not None or args.gt is not None:
        if args.multicam is None and args.pred is None:
            raise UsageError("--gt: give --multicam DIR or --pred NAME=FILE ... with it")
        from xvmatch.commands.evaluate_tracks import evaluate_multicam_command

        return evaluate_multicam_command(args)
    if args.top is None or args.hor is None:
        raise UsageError("give --top and --hor (or --multicam DIR --gt NAME=FILE ..., or "
                         "--pred NAME=FILE ... --gt NAME=FILE ...)")
    if args.tracks is not None:
        from xvmatch.commands.evaluate_tracks import evaluate_tracks_command

        return evaluate_tracks_command(args)
    from xvmatch.formats.mot_boxes import check_common_frames, read_predictions, shift_frames
    from xvmatch.metrics.cross_view_metrics import (
        count_sequence,
        format_table,
        scores_to_dict,
        summarize,
    )

    methods = _methods(args.pred, args.name)
    top = read_boxes(args.top, args.duplicates, box_reading(args))
    hor = read_boxes(args.hor, args.duplicates, box_reading(args))
    rows = []
    for name, path in methods:
        pred = read_predictions(path)
        offset = _recorded_offset(path, args.offset)
        what = "nothing to score" if len(methods) == 1 else f"--pred {name}: nothing to score"
        check_common_frames(hor=hor, top=top, offset=offset, names=(args.top, args.hor),
                            what=what)
        try:
            counts = count_sequence(pred, shift_frames(top, offset) if offset else top, hor)
        except ValueError as exc:
            raise UsageError(f"{path}: {exc}") from None
        rows.append((name, summarize(counts)))
    if args.json:
        doc = ({name: scores_to_dict(s) for name, s in rows} if len(rows) > 1
               else scores_to_dict(rows[0][1]))
        print(json.dumps(doc, indent=2))
    else:
        print(format_table(rows))
    return 0


def _methods(values: list[str], label: str | None) -> list[tuple[str, str]]:
    """``(row name, CSV path)`` of each ``--pred``: ``NAME=FILE`` (NAME without a path
    separator) or a plain ``FILE``, named by ``--name`` when alone, else by its path."""
    methods: list[tuple[str, str]] = []
    for text in values:
        name, sep, path = text.partition("=")
        if not (sep and name and path and "/" not in name and os.sep not in name):
            name, path = text, text
        if any(name == seen for seen, _ in methods):
            raise UsageError(f"--pred {text}: the row name {name} is given twice; name each "
                             "method once (NAME=FILE)")
        methods.append((name, path))
    if label is not None:
        if len(methods) > 1:
            raise UsageError(f"--name labels one prediction CSV ({len(methods)} given); name "
                             "each as --pred NAME=FILE instead")
        methods = [(label, methods[0][1])]
    return methods


def _recorded_offset(pred: str, given: int | None) -> int:
    """``given`` (``--offset``) when not None, else the offset ``associate`` recorded beside
    the predictions ``pred`` (``PRED.offset.json``, said in a note), else 0."""
    from xvmatch.commands._types import MAX_FRAME_OFFSET
    from xvmatch.formats.offset_record import predictions_offset_path, read_offset_record

    record = predictions_offset_path(pred)
    if given is not None or not os.path.isfile(record):
        return given or 0
    offset = read_offset_record(record, MAX_FRAME_OFFSET)
    print(f"xvmatch: note: applying the offset {offset} that associate recorded in {record} "
          "(--offset N to override)", file=sys.stderr)
    return offset
