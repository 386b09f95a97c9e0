"""The offset estimate as the commands run it: ``--offset auto``'s decision for a pair of views
(:func:`auto_offset`, from a typed :class:`AutoOffsetOptions`), and the estimate in words
(:func:`offset_summary`, :func:`unsupported_reason`, :func:`estimate_lines` and
:func:`estimate_record` for ``xvmatch offset``). Nothing is printed here: the commands print the
lines, so that ``--quiet`` stays theirs.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from xvmatch.cues.offset_estimation import (
    CLIP_LENGTH,
    CLIPS,
    MIN_AGREEING_CLIPS,
    MIN_OFFSET_EVIDENCE,
    OFFSET_ALPHA,
    OFFSET_TOLERANCE,
    OffsetEstimate,
    clip_starts,
    estimate_offset,
)
from xvmatch.cues.spatial_matching import SpatialParams
from xvmatch.cues.spatial_search import FrameLike

__all__ = ["AutoOffset", "AutoOffsetOptions", "auto_offset", "estimate_lines",
           "estimate_record", "offset_summary", "unsupported_reason"]


@dataclass(frozen=True)
class AutoOffsetOptions:
    """How ``--offset auto`` estimates the offset of one pair of views."""

    hor_width: float
    """The horizontal image width (pixels)."""
    max_offset: int
    """``--max-offset``: the largest |offset| tried."""
    params: SpatialParams | None = None
    """The spatial search's parameters (None: the defaults)."""
    camera_id: int | None = None
    """The wearer's top-view id, if known."""
    workers: int = 1
    """Processes sharing the clips (the estimate is the same for any number)."""
    label: str = ""
    """What the messages start with: which pair of views (``associate-multi``), or nothing."""


@dataclass(frozen=True)
class AutoOffset:
    """``--offset auto``'s decision: the offset to apply and what to tell the user."""

    offset: int
    """Frames to add to a horizontal frame number to get its top frame (0: the files' timing)."""
    message: str = ""
    """The line to print on stderr ("" for none)."""
    warning: bool = False
    """The estimate was refused: ``message`` is told even when quiet."""

    def to_tell(self, quiet: bool) -> bool:
        """Whether ``message`` is printed: a warning always, a note unless ``quiet``."""
        return bool(self.message) and (self.warning or not quiet)


def auto_offset(top: Mapping[int, FrameLike], hor: Mapping[int, FrameLike],
                options: AutoOffsetOptions,
                progress: Callable[[int, int], None] | None = None) -> AutoOffset:
    """The offset ``--offset auto`` applies: the estimate (:func:`estimate_offset` with the
    default clips) when the clips back it, else 0 with a warning. Videos too short for
    :data:`MIN_AGREEING_CLIPS` clips are not searched (one clip never backs an offset): 0, with
    a note. A view with no frames is the estimate's own error (``ValueError``).
    ``progress(done, total)``: the search's progress (:func:`estimate_offset`)."""
    label, max_offset = options.label, options.max_offset
    if top and hor:
        starts = clip_starts((min(hor), max(hor)), (min(top), max(top)), CLIP_LENGTH,
                             max_offset, CLIPS)
        if len(starts) < MIN_AGREEING_CLIPS:
            return AutoOffset(0, f"note: {label}videos too short for --offset auto to check "
                              f"their sync with --max-offset {max_offset} (one {CLIP_LENGTH}-"
                              "frame clip fits, and one cannot back an offset); keeping the "
                              "files' timing (pass --offset N, or a smaller --max-offset)")
    est = estimate_offset(top, hor, hor_width=options.hor_width, params=options.params,
                          max_offset=max_offset, camera_id=options.camera_id,
                          workers=options.workers, progress=progress)
    if est.status == "unsupported":
        return AutoOffset(int(est.applied), f"warning: {label}offset {est.offset:+d} not "
                          f"applied ({offset_summary(est)}): "
                          f"{unsupported_reason(est, max_offset)}; keeping the files' timing; "
                          "pass --offset N if you know it", warning=True)
    kept = (f" (within {OFFSET_TOLERANCE} frames of 0: keeping the files' timing)"
            if est.offset and not est.applied else "")
    return AutoOffset(int(est.applied), f"{label}estimated offset {est.offset:+d} frames (top "
                      f"frame = horizontal frame {est.offset:+d}; {offset_summary(est)}){kept}")


def _clips_scored(est: OffsetEstimate) -> int:
    """How many of the estimate's clips matched at some offset."""
    return int(np.isfinite(est.clip_costs).any(axis=1).sum())


def offset_summary(est: OffsetEstimate) -> str:
    """How strongly the clips back an :class:`OffsetEstimate`, in words."""
    n = _clips_scored(est)
    text = f"{round(est.support * n)} of {n} clips agree"
    return text + (f", evidence t = {est.evidence:.1f}" if est.offset and n > 1 else "")


def unsupported_reason(est: OffsetEstimate, max_offset: int,
                       one_clip_asked: bool = False) -> str:
    """Why an :class:`OffsetEstimate` was not applied, in words (``one_clip_asked``: the user
    asked for a single clip with --clips 1 or --clip-start)."""
    n = _clips_scored(est)
    if n < 2 and one_clip_asked:
        return ("one clip (--clips 1 or --clip-start) cannot back an offset: at least 2 clips "
                "must agree; use --clips 3 or more, or pass --offset N if you trust it")
    if n < 2:
        return (f"only {n} clip fits videos this short for --max-offset {max_offset} and one "
                "clip cannot back an offset; try a smaller --max-offset")
    if est.evidence < MIN_OFFSET_EVIDENCE:
        return (f"the clips do not prefer {est.offset:+d} to 0 (evidence t = "
                f"{est.evidence:.1f} < {MIN_OFFSET_EVIDENCE})")
    return (f"too few clips agree on {est.offset:+d} ({round(est.support * n)} of {n}: chance "
            f"{est.chance:.2f} > {OFFSET_ALPHA})")


def estimate_lines(est: OffsetEstimate, max_offset: int,
                   one_clip_asked: bool = False) -> tuple[str, str | None]:
    """``xvmatch offset``'s text: the estimate's line (stdout) and a warning or note on it
    (stderr; None when applied, or at 0): why it is not applied, or that it is within the
    estimate's precision of 0."""
    line = (f"offset {est.offset:+d} frames (top frame = horizontal frame {est.offset:+d}; "
            f"{offset_summary(est)})")
    if est.status == "unsupported":
        return line, (f"warning: {unsupported_reason(est, max_offset, one_clip_asked)}: the "
                      "estimate is unreliable (detector noise, too few people, or an offset "
                      "beyond --max-offset); associate --offset auto keeps the files' timing")
    if est.status == "within_tolerance" and est.offset:
        return line, (f"note: {est.offset:+d} is within the estimate's precision "
                      f"({OFFSET_TOLERANCE} frames) of 0: associate --offset auto keeps the "
                      f"files' timing; pass --offset {est.offset} to apply it")
    return line, None


def estimate_record(est: OffsetEstimate) -> dict:
    """``xvmatch offset --json``'s record: the offset, whether and how it is backed, and the
    cost of each offset tried (infinities as null)."""
    return {
        "offset": est.offset,
        "applied": est.applied,
        "status": est.status,
        "support": est.support,
        "evidence": est.evidence if est.evidence != float("inf") else None,
        "offsets": est.offsets.tolist(),
        "costs": [c if c != float("inf") else None for c in est.costs.tolist()],
    }
