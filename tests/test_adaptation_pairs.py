"""Mining site-adaptation pairs (inference/adaptation/adaptation_pairs.py) on hand-built boxes and
costs: bursts, confident pairs with the dustbin, tracklet agreement, 'no match' for a person seen in
one view only, and the order of the embedded boxes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.inference.adaptation.adaptation_pairs import (
    MiningConfig,
    agreed_pairs,
    confident_pairs,
    embed_frames,
    mine_pairs,
    plan_bursts,
)


def test_plan_bursts_runs_and_budget() -> None:
    frames = [*range(1, 36), *range(50, 58), *range(100, 121)]
    bursts = plan_bursts(frames, 10, 10_000)
    assert [b.tolist()[0] for b in bursts] == [1, 11, 21, 100, 110]  # 50..57 is too short
    assert all(np.array_equal(b, np.arange(b[0], b[0] + 10)) for b in bursts)
    few = plan_bursts(frames, 10, 20)
    assert [b.tolist()[0] for b in few] == [1, 110]  # two, first and last: spread in time
    assert plan_bursts([], 10, 100) == []


def test_confident_pairs_margin_and_dustbin() -> None:
    cost = np.array([[0.05, 0.90, 0.95],
                     [0.90, 0.30, 0.35],
                     [0.97, 0.96, 0.92]])
    # row 0: sure; row 1: matched (0.30 < gamma) but its column holds 0.35 nearby; row 2: above
    # gamma, the dustbin wins
    assert confident_pairs(cost, 0.5, 0.3) == [(0, 0)]
    assert confident_pairs(cost, 0.5, 0.04) == [(0, 0), (1, 1)]
    # the dustbin is an alternative too: 0.40 is only 0.10 below gamma 0.5
    assert confident_pairs(np.array([[0.40]]), 0.5, 0.3) == []
    assert confident_pairs(np.array([[0.10]]), 0.5, 0.3) == [(0, 0)]
    assert confident_pairs(np.zeros((0, 3)), 0.5, 0.3) == []


def _walk(frames: int, people: int, wearer: bool = True):
    """People walking slowly to the right in both views (boxes overlap frame to frame); ids in
    the two views differ (+100 in the horizontal one); the top view also holds the wearer
    (id 99), whom the horizontal view cannot see. Costs: 0.05 for the same person, 0.95 else."""
    top, hor, costs = {}, {}, {}
    for f in range(1, frames + 1):
        xs = np.arange(people) * 80.0 + f
        t_ids = np.arange(people)
        t_boxes = np.stack([xs, np.full(people, 50.0), np.full(people, 30.0),
                            np.full(people, 60.0)], 1)
        if wearer:
            t_ids = np.r_[t_ids, 99]
            t_boxes = np.vstack([t_boxes, [900.0, 500.0, 30.0, 60.0]])
        h_ids = np.arange(people)[::-1] + 100  # another order
        h_boxes = np.stack([xs[::-1] * 1.5, np.full(people, 100.0), np.full(people, 40.0),
                            np.full(people, 90.0)], 1)
        top[f] = FrameBoxes(f, t_ids.astype(np.int64), t_boxes)
        hor[f] = FrameBoxes(f, h_ids.astype(np.int64), h_boxes)
        costs[f] = np.where(t_ids[:, None] + 100 == h_ids[None, :], 0.05, 0.95)
    return top, hor, costs


def _ids(records, frames) -> np.ndarray:
    return np.concatenate([records[f].ids for f in frames])


def test_mine_pairs_on_a_clear_scene() -> None:
    top, hor, costs = _walk(20, 4)
    bursts = plan_bursts(range(1, 21), 10, 1000)
    mined = mine_pairs(top, hor, bursts, costs, 0.5, MiningConfig(burst=10, shots=3))
    assert mined.embed_frames.tolist() == [1, 5, 10, 11, 15, 20]
    assert mined.n_boxes == {"top": 6 * 5, "hor": 6 * 4}
    t, h = _ids(top, mined.embed_frames), _ids(hor, mined.embed_frames)
    # every person seen in both views, in every embedded frame; never the wearer
    assert len(mined.cross_pos) == 6 * 4
    assert np.all(t[mined.cross_pos[:, 0]] + 100 == h[mined.cross_pos[:, 1]])
    assert not np.any(t[mined.cross_neg[:, 0]] + 100 == h[mined.cross_neg[:, 1]])
    assert not np.any(t[mined.cross_pos[:, 0]] == 99)
    # within a view: the same person in two frames of a burst, or two people of one frame
    for view, ids in (("top", t), ("hor", h)):
        pos, neg = mined.within_pos[view], mined.within_neg[view]
        assert len(pos) and np.all(ids[pos[:, 0]] == ids[pos[:, 1]])
        assert len(neg) and np.all(ids[neg[:, 0]] != ids[neg[:, 1]])
    assert set(mined.cross_pos_group.tolist()) == {0, 1}


def test_no_pseudo_match_without_agreement() -> None:
    """Confident in isolated frames only (never ``agree`` frames in a row): no pseudo-match."""
    top, hor, costs = _walk(10, 3, wearer=False)
    for f in costs:
        if f % 2 == 0:
            costs[f] = np.full_like(costs[f], 0.45)  # unsure frames
    bursts = plan_bursts(range(1, 11), 10, 1000)
    mined = mine_pairs(top, hor, bursts, costs, 0.5, MiningConfig(burst=10, agree=3))
    assert len(mined.cross_pos) == 0 and len(mined.cross_neg) == 0
    loose = mine_pairs(top, hor, bursts, costs, 0.5, MiningConfig(burst=10, agree=1))
    assert len(loose.cross_pos) > 0


def test_mining_config_checks() -> None:
    with pytest.raises(ValueError, match="agree must be in"):
        MiningConfig(burst=3, agree=4, shots=3)
    with pytest.raises(ValueError, match="shots must be in"):
        MiningConfig(burst=4, shots=5)
    with pytest.raises(ValueError, match="max_frames"):
        MiningConfig(burst=10, max_frames=5)


def test_embed_frames_order() -> None:
    """Descriptors come in frame order, then record order (the indices of the mined pairs)."""
    top, _, _ = _walk(3, 2)

    class Images:
        def get(self, frame: int) -> np.ndarray:
            return np.full((4, 4, 3), frame, np.uint8)

    def embed(image: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        return np.stack([np.full(len(boxes), image[0, 0, 0], float), boxes[:, 0]], 1)

    d = embed_frames([3, 1], top, Images(), embed)
    assert d[:, 0].tolist() == [3, 3, 3, 1, 1, 1]
    assert d[:, 1].tolist() == [*top[3].boxes[:, 0], *top[1].boxes[:, 0]]


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(st.dictionaries(st.tuples(st.integers(0, 4), st.integers(0, 4)),
                       st.lists(st.integers(0, 30), min_size=1, max_size=12, unique=True)
                       .map(sorted), max_size=12),
       st.integers(1, 5))
def test_agreed_pairs_against_their_definition(seen: dict, agree: int) -> None:
    """A pseudo-match: sure on ``agree`` consecutive frames, and neither tracklet sure of any
    other partner (brute force over the pairs)."""
    def consecutive(frames: list[int]) -> int:
        # ascending unique frames: n of them in a row span n - 1
        return max(n for n in range(1, len(frames) + 1)
                   if any(frames[i + n - 1] - frames[i] == n - 1
                          for i in range(len(frames) - n + 1)))

    expected = {p for p, frames in seen.items() if consecutive(frames) >= agree
                and all(q == p or (q[0] != p[0] and q[1] != p[1]) for q in seen)}
    assert agreed_pairs(seen, agree) == expected
