"""The ``xvmatch offset`` command: the temporal offset between the two videos (Fig. 5).

Also what ``associate``, ``associate-multi`` and ``track`` share with it: ``--offset N|auto``
and ``--max-offset`` (:func:`add_offset_options`, :func:`resolve_offset`, :func:`wearer_marked`,
:func:`max_offset_of`, :func:`offset_progress`). ``auto``'s decision and the estimate in words
are the library's (:mod:`xvmatch.cues.auto_offset`,
:func:`~xvmatch.inference.matching.association_run.offset_to_apply`); this module prints them,
and the search's progress bar.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from xvmatch.commands._cameras import line_printer
from xvmatch.commands._options import (
    HOR_IMAGE_SIZE,
    IMAGE_SIZE_HELP,
    UsageError,
    add_box_inputs,
    add_command_parser,
    add_spatial_options,
    check_camera_id,
    progress_bar,
    read_boxes,
    spatial_params,
)
from xvmatch.commands._types import box_id, int_in, offset_value, worker_count
from xvmatch.core.progress import growing_total
from xvmatch.cues.auto_offset import AutoOffsetOptions, estimate_lines, estimate_record
from xvmatch.cues.offset_estimation import (
    AUTO_MAX_OFFSET,
    CLIP_LENGTH,
    CLIPS,
    OFFSET_STEP,
    OFFSET_TOLERANCE,
    clip_start_range,
    estimate_offset,
)

__all__ = ["EXAMPLE", "MAX_OFFSET_LIMIT", "MAX_OFFSET_TYPE", "add_offset_options",
           "add_offset_parser", "check_clip_start", "max_offset_of", "offset_progress",
           "resolve_offset", "wearer_marked"]

EXAMPLE = "xvmatch offset --top seq_top.txt --hor seq_hor.txt"

MAX_OFFSET_LIMIT = 10_000
"""Largest ``--max-offset``: each clip is compared at 2 * max_offset + 1 offsets."""

MAX_OFFSET_TYPE = int_in(0, MAX_OFFSET_LIMIT, "each clip is compared at 2 * max_offset + 1 "
                         "offsets")
"""``--max-offset``: 0..10000 frames (and at most the videos' length: :func:`max_offset_of`)."""

def check_clip_start(clip_start: int | None, hor, clip_length: int) -> None:
    """Refuse a ``--clip-start`` whose clip of ``clip_length`` frames is not inside the
    horizontal video ``hor`` (``{frame: boxes}``): it would score no frame, or a clip cut
    short (:func:`~xvmatch.cues.offset_estimation.clip_start_range`).

    Raises:
        UsageError: one line naming ``--clip-start`` and the valid starts.
    """
    if clip_start is None or not hor:
        return
    first, last = clip_start_range((min(hor), max(hor)), clip_length)
    if not first <= clip_start <= last:
        span = f"{first}" if first == last else f"{first}..{last}"
        raise UsageError(f"--clip-start {clip_start} is outside the horizontal video (frames "
                         f"{min(hor)}..{max(hor)}): a clip of {clip_length} frames starts at "
                         f"{span}")


def max_offset_of(args: argparse.Namespace, top, hor) -> int:
    """``--max-offset``, the default when not given; a given one must not exceed the number of
    frames the two box files span (no larger offset aligns any frame of the two)."""
    if args.max_offset is None:
        return AUTO_MAX_OFFSET
    frames = [*top, *hor]
    if frames:
        first, last = min(frames), max(frames)
        span = last - first + 1
        if args.max_offset > span:
            raise UsageError(
                f"--max-offset {args.max_offset} is more than the videos' length: the box files "
                f"span {span} frames ({first}..{last}) and no larger offset aligns any frame; "
                f"use at most {span}"
            )
    return args.max_offset


def add_offset_options(p: argparse.ArgumentParser, timing: str, several: bool = False,
                       default: int | str = 0) -> None:
    """Add ``--offset N|auto`` and ``--max-offset`` to a command that reads a video pair;
    ``timing`` ends the help of ``--offset``: the frame numbers the command writes. ``several``:
    one value per horizontal view (``--hor H1 H2 ...``), or one for all. ``default``: 0
    (frame-locked videos) or ``"auto"``."""
    what = ("one per --hor file, or one for all: that camera is out of sync with the top "
            "view, top frame = its frame + N" if several else
            "the videos are out of sync: top frame = horizontal frame + N")
    default_text = ("auto: videos long enough for 2 clips are checked" if default == "auto"
                    else f"{default}: frame-locked videos")
    p.add_argument(
        "--offset", type=offset_value, default=[default] if several else default,
        nargs="+" if several else None, metavar="N|auto",
        help=f"{what} (what 'xvmatch offset' prints); 'auto' estimates it first from the boxes "
        "(10-25 s per pair of videos on one core with the default --max-offset; see "
        "--workers) and shifts only when the clips back the estimate and it is more than 5 "
        f"frames from 0. {timing}; |N| <= 100000 (default {default_text})")
    p.add_argument(
        "--max-offset", type=MAX_OFFSET_TYPE, default=None,
        help=f"largest |offset| tried by --offset auto, 0..{MAX_OFFSET_LIMIT} frames and at "
        f"most the frames the box files span (default {AUTO_MAX_OFFSET})")


def wearer_marked(top, positions: dict[int, int] | None):
    """The top view for an offset estimate and the camera wearer's id there: the wearer's box
    (``positions``: ``{frame: its position in the frame's record}``) tagged -1
    (:func:`xvmatch.inference.views.multi_view_costs.with_wearer_tag`); ``(top, None)`` when no
    wearer is given."""
    if positions is None:
        return top, None
    from xvmatch.inference.views.multi_view_costs import with_wearer_tag

    return {f: with_wearer_tag(r, positions.get(f)) for f, r in top.items()}, -1


@contextmanager
def offset_progress(label: str, enabled: bool) -> Iterator[Callable[[int, int], None]]:
    """The offset search's ``progress(done, total)`` on a progress bar (``label``: which pair
    of views), a context manager that closes the bar."""
    with progress_bar(0, f"{label}offset search", "clip", enabled) as bar:
        yield growing_total(bar)


def resolve_offset(args: argparse.Namespace, top, hor, hor_width: float, params,
                   max_offset: int | None, camera_id: int | None = None,
                   value: int | str | None = None, label: str = "",
                   hor_path: str | None = None) -> int:
    """The offset to apply (``track``, ``associate-multi``): ``value`` (default ``--offset``)
    when a number, or with ``auto`` the estimate when the clips back it (0 otherwise, with a
    warning on stderr), reported unless ``--quiet`` after ``label`` (which pair of views);
    ``max_offset``: :func:`max_offset_of`, checked before any work. Views that share no frame
    at the offset are refused, naming both files
    (:func:`~xvmatch.inference.matching.association_run.offset_to_apply`)."""
    from xvmatch.inference.matching.association_run import offset_to_apply

    value = args.offset if value is None else value
    auto = None if value != "auto" else AutoOffsetOptions(
        hor_width=hor_width, max_offset=max_offset, params=params, camera_id=camera_id,
        workers=args.workers, label=label)
    return offset_to_apply(
        top, hor, value, auto, (args.top, hor_path or args.hor),
        lambda: offset_progress(label, not args.quiet),
        line_printer(args.quiet))


def _cmd_offset(args: argparse.Namespace) -> int:
    params = spatial_params(args)
    top = read_boxes(args.top, args.duplicates)
    hor = read_boxes(args.hor, args.duplicates)
    max_offset = max_offset_of(args, top, hor)
    check_camera_id(args.camera_id, top, args.top)
    if args.clip_length < 1:  # before the size note: a refused run prints one line
        raise UsageError(f"--clip-length {args.clip_length}: need clip_length >= 1 (frames per "
                         "clip)")
    check_clip_start(args.clip_start, hor, args.clip_length)
    from xvmatch.commands._box_reading import note_if_assumed
    from xvmatch.formats.box_image_size import resolve_size

    given = [] if args.image_size is None else [(args.image_size, "--image-size")]
    resolved = resolve_size(hor, args.hor, given)
    hor_width = resolved[0][0]
    note_if_assumed(resolved, hor, args.hor)
    from xvmatch.inference.matching.search_camera import upright_top_warning

    if (said := upright_top_warning(top, "the offset search", "its estimate",
                                    "give the offset by hand (--offset N)")) is not None:
        print(said, file=sys.stderr)
    with progress_bar(0, "offset search", "clip", not args.quiet) as bar:
        est = estimate_offset(top, hor, hor_width=hor_width, params=params, step=args.step,
                              clip_start=args.clip_start, clip_length=args.clip_length,
                              max_offset=max_offset, camera_id=args.camera_id, n_clips=args.clips,
                              workers=args.workers, progress=growing_total(bar))
    if args.json:
        print(json.dumps(estimate_record(est)))
    else:
        one_clip = args.clip_start is not None or args.clips == 1
        line, told = estimate_lines(est, max_offset, one_clip)
        print(line)
        if told is not None:
            print(told, file=sys.stderr)
    return 0


def add_offset_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch offset`` on ``subparsers`` and return its parser."""
    p = add_command_parser(
        subparsers,
        "offset",
        "Estimate the temporal offset between the two videos by sliding clips (Fig. 5).",
        EXAMPLE,
    )
    add_box_inputs(p)
    p.add_argument("--camera-id", type=box_id, default=None,
                   help="top-view id of the wearer (|id| <= 2**53)")
    p.add_argument(
        "--clip-start",
        type=int_in(1, 2**53, "a frame number: frames are 1-based, exact to 2**53"),
        default=None,
        help="first horizontal frame of a single clip (the paper's setting), 1..2**53, and "
        "the clip inside the horizontal video; default: --clips clips spread over the video",
    )
    p.add_argument("--clips", default=CLIPS,
                   type=int_in(1, 100, "each clip is one more search over every offset"),
                   help=f"clips to average, 1..100 (default {CLIPS})")
    # clip_length >= 1 is checked by estimate_offset with the other clip settings (one line,
    # exit 2, before any search): the parser bounds only its size.
    p.add_argument("--clip-length", default=CLIP_LENGTH,
                   type=int_in(None, 1000, "frames per clip, in [1, 1000]: each is searched at "
                               "every offset"),
                   help=f"clip length in frames, 1..1000 (default {CLIP_LENGTH})")
    p.add_argument(
        "--max-offset", type=MAX_OFFSET_TYPE, default=None,
        help=f"largest |offset|, 0..{MAX_OFFSET_LIMIT} frames and at most the frames the box "
        f"files span (default {AUTO_MAX_OFFSET}, as associate --offset auto)",
    )
    p.add_argument("--step", default=OFFSET_STEP,
                   type=int_in(1, 2 * OFFSET_TOLERANCE + 1, "every offset needs a coarse one "
                               f"within the estimate's {OFFSET_TOLERANCE}-frame precision"),
                   help=f"coarse step in frames, 1..{2 * OFFSET_TOLERANCE + 1} (default "
                   f"{OFFSET_STEP}, as --offset "
                   "auto): every S-th offset first, then each one near the best; 1 tries "
                   "every offset, as the paper does")
    p.add_argument(
        "--image-size", type=HOR_IMAGE_SIZE, default=None, metavar="WxH",
        help=IMAGE_SIZE_HELP,
    )
    p.add_argument("--json", action="store_true", help="print JSON (offset and cost per offset)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--workers", type=worker_count, default=1, metavar="K",
                   help="processes sharing the clips, 1..64 (default 1; the estimate is the "
                   "same for any K)")
    add_spatial_options(p)
    p.set_defaults(func=_cmd_offset)
    return p
