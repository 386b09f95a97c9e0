"""The rule by which ``adapt`` accepts or refuses a site bundle from the pairs it makes on held-out
frames (inference/matching/site_judgement.py), on hand-built scenes: six people walking in both
views, two of them the box-only matcher is sure of, two pairs of look-alikes it is not; runs that
swap the look-alikes for half of each window, against runs that keep everyone steady."""

from __future__ import annotations

import numpy as np
import pytest

from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.inference.matching.site_judgement import (
    MIN_JUDGED,
    judge_pairs,
    judging_windows,
    split_for_judgement,
)

PEOPLE = 6
FRAMES = list(range(1, 101))  # two judging windows of 50 frames
GAMMA = 0.6


def _scene() -> tuple[dict, dict, dict]:
    """Boxes of both views (top ids 1..6, horizontal ids 11..16: nothing shared) moving slowly,
    and box-only costs: people 0 and 1 sure, 2-3 and 4-5 look-alike pairs nobody is sure of."""
    top, hor, costs = {}, {}, {}
    for f in FRAMES:
        x = np.arange(PEOPLE, dtype=np.float64)
        top[f] = FrameBoxes(f, np.arange(1, PEOPLE + 1),
                            np.stack([100 * x + 0.5 * f, np.full(PEOPLE, 100.0),
                                      np.full(PEOPLE, 20.0), np.full(PEOPLE, 20.0)], 1))
        hor[f] = FrameBoxes(f, np.arange(11, 11 + PEOPLE),
                            np.stack([80 * x + 0.3 * f, np.full(PEOPLE, 50.0),
                                      np.full(PEOPLE, 30.0), np.full(PEOPLE, 80.0)], 1))
        c = np.full((PEOPLE, PEOPLE), 0.9)
        c[0, 0] = c[1, 1] = 0.05
        c[2:4, 2:4] = 0.45
        c[4:6, 4:6] = 0.45
        costs[f] = c
    return top, hor, costs


def _pairs(swap_from: int | None = None, drop_sure: bool = False) -> dict:
    """Everyone paired with themselves; from frame ``swap_from`` of each window on, the
    look-alikes swapped (2 with 3's partner, 4 with 5's); ``drop_sure``: person 0 unpaired."""
    out = {}
    for f in FRAMES:
        partner = list(range(PEOPLE))
        if swap_from is not None and (f - 1) % 50 >= swap_from:
            partner[2], partner[3], partner[4], partner[5] = 3, 2, 5, 4
        out[f] = [(p + 1, partner[p] + 11) for p in range(PEOPLE) if not (drop_sure and p == 0)]
    return out


def test_a_site_bundle_that_swaps_look_alikes_is_refused() -> None:
    top, hor, costs = _scene()
    j = judge_pairs(top, hor, FRAMES, costs, GAMMA, source=_pairs(), site=_pairs(swap_from=30))
    assert not j.accepted and j.gain < 0
    assert j.frames == 100 and (j.first, j.last) == (1, 100)
    assert j.source.sure == j.site.sure == 200  # people 0 and 1, every frame
    assert j.source.sure_kept == j.site.sure_kept == 200
    assert j.source.flips == 0 and j.site.flips == 2 * 4 * 20  # 2 windows, 4 people, 20 frames
    assert j.source.score == 600 and j.site.score == 600 - 2 * j.site.flips
    assert "worse" in j.message() and "not used to fit" in j.message()


def test_a_site_bundle_that_stops_the_swaps_is_accepted() -> None:
    top, hor, costs = _scene()
    j = judge_pairs(top, hor, FRAMES, costs, GAMMA, source=_pairs(swap_from=30), site=_pairs())
    assert j.accepted and j.gain == 2 * 4 * 20 * 2
    # 8 clusters (4 people x 2 windows), each +40: gain 320, error sqrt(8) * 40
    assert j.error == pytest.approx(np.sqrt(8) * 40)
    assert "better)" in j.message()


def test_no_difference_no_gain_and_a_dropped_sure_pair_counts_against() -> None:
    top, hor, costs = _scene()
    same = judge_pairs(top, hor, FRAMES, costs, GAMMA, source=_pairs(), site=_pairs())
    assert not same.accepted and same.gain == 0 and same.error == 0
    dropped = judge_pairs(top, hor, FRAMES, costs, GAMMA, source=_pairs(),
                          site=_pairs(drop_sure=True))
    assert not dropped.accepted and dropped.gain == -200  # person 0 unpaired: +1 -> -1, 100 frames
    assert dropped.site.sure_kept == 100


def test_too_few_held_out_frames_are_not_judged() -> None:
    top, hor, costs = _scene()
    few = FRAMES[:MIN_JUDGED - 1]
    j = judge_pairs(top, hor, few, costs, GAMMA, source=_pairs(swap_from=5), site=_pairs())
    assert j.gain > 0 and not j.accepted
    assert "give a longer video" in j.message()


def test_the_split_holds_out_the_last_block_and_windows_cut_runs() -> None:
    fit, judged = split_for_judgement(range(1, 401), burst=10)
    assert fit == list(range(1, 301)) and judged == list(range(301, 401))
    fit, judged = split_for_judgement(range(1, 5001), burst=10)
    assert len(judged) == 300 and judged[-1] == 5000 and fit[-1] == 4700
    assert split_for_judgement(range(1, 21), burst=10)[1] == list(range(11, 21))
    windows = judging_windows([*range(1, 121), *range(200, 202)], 50, 3)
    assert [len(w) for w in windows] == [50, 70]  # the 20-frame piece joins; 2 frames dropped


def _adapt_rendered(seed: int, strength: float):
    """``adapt``'s library run on the first 180 of 240 rendered frames (10-16 people, ids
    scrambled per view, each view through one simulated camera of ``strength``), as
    benchmarks/adapt_gate_eval.py runs it."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from site_adaptation_eval import _Images, _scrambled, _shifted

    from xvmatch.datasets.synthetic_scenes import SynthConfig
    from xvmatch.datasets.tracking_video import render_tracking_video
    from xvmatch.inference.matching.learned_association import load_matcher_bundle
    from xvmatch.inference.matching.site_bundle import adapt_to_site

    video = render_tracking_video(seed, 240, SynthConfig(scenario="drone", n_people=(10, 16),
                                                         fps=25.0))
    rng = np.random.default_rng([seed, 31])
    top = _scrambled(video.top, rng)[0]
    hor = _scrambled(video.hor, rng)[0]
    images = (_Images(_shifted(video.top_images, strength, 100 + seed)),
              _Images(_shifted(video.hor_images, strength, 200 + seed)))
    part = [{f: r for f, r in view.items() if f <= 180} for view in (top, hor)]
    return adapt_to_site(*part, load_matcher_bundle("default"), *images, video.hor_size)


@pytest.mark.slow
def test_a_rendered_video_whose_site_bundle_pairs_better_is_accepted() -> None:
    """Seed 1, unshifted: the site bundle keeps more sure pairs and switches fewer partners on
    the held-out frames 136-180 (and scores +9.2 CVIDF1 on frames 181-240, which adapt never
    saw: benchmarks/adapt_gate_eval.py)."""
    run = _adapt_rendered(1, 0.0)
    j = run.judgement
    assert run.fit.accepted and j is not None and run.accepted
    assert j.frames == 45 and (j.first, j.last) == (136, 180)
    assert j.gain > 2 * j.error > 0
