"""Pairs kept consistent along each view's tracks (video mode,
:mod:`xvmatch.inference.linking.pair_consensus`)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.inference.linking.pair_consensus import consistent_pairs, tracklet_consensus

PRESENT = {f: (np.array([1, 2, 3]), np.array([7, 8])) for f in range(1, 11)}


def test_the_pairs_found_most_often_hold_in_every_frame() -> None:
    pairs = {f: [(1, 7), (2, 8)] for f in range(1, 11)}
    pairs[4] = [(2, 7), (1, 8)]  # one frame swapped
    pairs[5] = []  # one frame with nothing
    pairs[6] = [(1, 7), (3, 8)]  # one frame's wrong partner
    out = tracklet_consensus(pairs, PRESENT)
    assert all(sorted(out[f]) == [(1, 7), (2, 8)] for f in range(1, 11))


def test_tracks_without_a_stable_pair_keep_their_own() -> None:
    # (1, 7) holds over the clip; tracks 3 and 8 are paired in one frame only and with nobody
    # else: that pair is kept where it was found, not dropped (nor spread to other frames).
    pairs = {f: [(1, 7)] for f in range(1, 11)}
    pairs[2] = [(1, 7), (3, 8)]
    out = tracklet_consensus(pairs, PRESENT)
    assert out[2] == [(1, 7), (3, 8)]
    assert all(out[f] == [(1, 7)] for f in range(1, 11) if f != 2)
    # A frame's pair that contradicts a stable one is replaced by it.
    pairs[3] = [(2, 7)]
    assert tracklet_consensus(pairs, PRESENT)[3] == [(1, 7)]
    # Without keep_free, a pair with no support over time is dropped.
    assert tracklet_consensus({1: [(3, 8)]}, PRESENT, keep_free=False) == {
        f: [] for f in range(1, 11)}
    assert tracklet_consensus({1: [(3, 8)]}, PRESENT)[1] == [(3, 8)]


def test_a_trackers_id_switch_changes_the_partner_where_it_happens() -> None:
    # Top track 1 is hor track 7's person for 60 frames, then (an id switch) hor track 8's;
    # each frame's pairs are right but for one wrong frame in five. The consensus follows the
    # switch and mends the wrong frames; one partner for the whole track cannot (no partner
    # holds over the whole clip, so it keeps the frames' own pairs, wrong one frame in five).
    present = {f: (np.array([1, 2]), np.array([7, 8])) for f in range(1, 121)}
    truth = {f: [(1, 7), (2, 8)] if f <= 60 else [(1, 8), (2, 7)] for f in present}
    pairs = {f: (p if f % 5 else [(a, 15 - b) for a, b in p]) for f, p in truth.items()}
    out = tracklet_consensus(pairs, present)
    wrong = sum(set(out[f]) != set(truth[f]) for f in present)
    assert wrong <= 2, wrong
    whole = tracklet_consensus(pairs, present, switch_cost=np.inf)
    assert sum(set(whole[f]) != set(truth[f]) for f in present) >= 20


def test_consistent_pairs_reads_the_ids_of_the_box_records() -> None:
    box = np.array([[0.0, 0.0, 10.0, 20.0]])
    top = {f: FrameBoxes(f, np.array([1]), box) for f in (1, 2, 3)}
    hor = {f: FrameBoxes(f, np.array([7]), box) for f in (1, 2)}
    out = consistent_pairs({1: [(1, 7)], 2: [(1, 7)]}, top, hor, [1, 2, 3])
    assert out == {1: [(1, 7)], 2: [(1, 7)], 3: []}


@settings(max_examples=60, deadline=None)
@given(st.dictionaries(st.integers(1, 8), st.permutations(range(4)), min_size=1),
       st.integers(0, 4))
def test_each_frame_stays_one_to_one(perms, k) -> None:
    # Any frame-by-frame association (one-to-one per frame) gives one-to-one frames, with ids of
    # that frame only.
    present = {f: (np.arange(4), np.arange(10, 14)) for f in range(1, 9)}
    pairs = {f: [(t, 10 + h) for t, h in enumerate(p[:k])] for f, p in perms.items()}
    out = tracklet_consensus(pairs, present)
    assert set(out) == set(present)
    for f, kept in out.items():
        tops, hors = [t for t, _ in kept], [h for _, h in kept]
        assert len(set(tops)) == len(tops) and len(set(hors)) == len(hors)
        assert set(tops) <= set(present[f][0].tolist())
        assert set(hors) <= set(present[f][1].tolist())
