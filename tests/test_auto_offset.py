"""``--offset auto``'s decision and the estimate in words (cues/auto_offset.py): the typed run the
commands call and print, on a simulated scene whose true shift is known, and on estimates built
by hand where the words are pinned."""

from __future__ import annotations

import json

import numpy as np
import pytest

from xvmatch.cues.auto_offset import (
    AutoOffset,
    AutoOffsetOptions,
    auto_offset,
    estimate_lines,
    estimate_record,
    offset_summary,
    unsupported_reason,
)
from xvmatch.cues.offset_estimation import OFFSET_TOLERANCE, OffsetEstimate
from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene
from xvmatch.formats.mot_boxes import shift_frames


def _estimate(offset: int, status: str, clips: int, support: float = 1.0,
              evidence: float = 3.0, chance: float = 0.01) -> OffsetEstimate:
    """An estimate of ``clips`` clips over offsets -5..5, each clip scored at every offset."""
    offsets = np.arange(-5, 6)
    return OffsetEstimate(offset=offset, offsets=offsets, costs=np.ones(11),
                          clip_costs=np.ones((clips, 11)),
                          applied=offset if status == "applied" else 0, status=status,
                          support=support, chance=chance, evidence=evidence)


def test_words_of_an_applied_estimate() -> None:
    est = _estimate(12, "applied", 9, support=8 / 9, evidence=4.25)
    assert offset_summary(est) == "8 of 9 clips agree, evidence t = 4.2"
    line, told = estimate_lines(est, 60)
    assert line == "offset +12 frames (top frame = horizontal frame +12; 8 of 9 clips agree, " \
                   "evidence t = 4.2)"
    assert told is None


def test_words_of_a_refused_estimate() -> None:
    weak = _estimate(-9, "unsupported", 9, support=3 / 9, evidence=0.9)
    assert unsupported_reason(weak, 30) == "the clips do not prefer -9 to 0 (evidence t = 0.9 " \
                                           "< 2.0)"
    lone = _estimate(8, "unsupported", 1)
    assert unsupported_reason(lone, 60).startswith("only 1 clip fits videos this short")
    assert unsupported_reason(lone, 60, one_clip_asked=True).startswith(
        "one clip (--clips 1 or --clip-start) cannot back an offset")
    _, told = estimate_lines(lone, 60, one_clip_asked=True)
    assert told.startswith("warning: one clip") and told.endswith("keeps the files' timing")
    few = _estimate(7, "unsupported", 9, support=2 / 9, evidence=3.0, chance=0.2)
    assert unsupported_reason(few, 60) == "too few clips agree on +7 (2 of 9: chance 0.20 > 0.05)"


def test_words_of_an_estimate_within_the_tolerance() -> None:
    near = _estimate(-2, "within_tolerance", 9)
    _, told = estimate_lines(near, 60)
    assert told == ("note: -2 is within the estimate's precision (5 frames) of 0: associate "
                    "--offset auto keeps the files' timing; pass --offset -2 to apply it")
    assert estimate_lines(_estimate(0, "within_tolerance", 9), 60)[1] is None


def test_json_record_writes_infinities_as_null() -> None:
    est = _estimate(3, "applied", 9, evidence=float("inf"))
    est = OffsetEstimate(**{**est.__dict__, "costs": np.array([1.0, np.inf] + [0.5] * 9)})
    record = json.loads(json.dumps(estimate_record(est)))
    assert record["evidence"] is None and record["costs"][1] is None
    assert record["offsets"] == list(range(-5, 6)) and record["offset"] == 3


def test_a_warning_is_told_even_when_quiet() -> None:
    assert AutoOffset(0, "warning: x", warning=True).to_tell(quiet=True)
    assert not AutoOffset(0, "note: x").to_tell(quiet=True)
    assert AutoOffset(0, "note: x").to_tell(quiet=False)
    assert not AutoOffset(4).to_tell(quiet=False)


@pytest.fixture(scope="module")
def scene():
    return simulate_box_scene(SceneConfig(n_people=(6, 8)), n_frames=120, seed=5)


@pytest.mark.slow
def test_auto_offset_finds_a_known_shift(scene) -> None:
    top = shift_frames(scene.top, -12)  # top frame = horizontal frame + 12
    decided = auto_offset(top, scene.hor, AutoOffsetOptions(
        hor_width=scene.config.hor_size[0], max_offset=20, label="pair 1: "))
    assert abs(decided.offset - 12) <= OFFSET_TOLERANCE and not decided.warning  # its precision
    assert decided.message.startswith(f"pair 1: estimated offset {decided.offset:+d} frames")


def test_auto_offset_does_not_search_videos_too_short(scene) -> None:
    short = {f: r for f, r in scene.hor.items() if f < min(scene.hor) + 15}
    decided = auto_offset(scene.top, short, AutoOffsetOptions(hor_width=1000.0, max_offset=60))
    assert decided == AutoOffset(0, decided.message)
    assert decided.message.startswith("note: videos too short for --offset auto")
    assert not decided.to_tell(quiet=True)
