"""benchmarks/site_adaptation_eval.py: the true-pairs upper bound's pairs."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import site_adaptation_eval  # noqa: E402

from xvmatch.formats.mot_boxes import FrameBoxes  # noqa: E402
from xvmatch.inference.adaptation.adaptation_pairs import MinedPairs  # noqa: E402


def _records(ids_by_frame: dict[int, list[int]]) -> dict[int, FrameBoxes]:
    return {f: FrameBoxes(f, np.array(ids, np.int64), np.tile([0.0, 0.0, 10.0, 20.0],
                                                                (len(ids), 1)))
            for f, ids in ids_by_frame.items()}


def test_true_pairs_are_every_box_pair_of_a_frame_labelled_by_the_true_ids() -> None:
    top = _records({1: [5, 6], 2: [6], 3: [9]})
    hor = _records({1: [6, 7], 2: [6, 5], 3: [1]})
    empty = np.zeros((0, 2), np.int64)
    none = np.zeros(0, np.int64)
    mined = MinedPairs(np.array([1, 2]), {"top": 3, "hor": 4}, {"top": empty, "hor": empty},
                       {"top": empty, "hor": empty}, np.array([[0, 1]]), np.array([[1, 1]]),
                       {"top": none, "hor": none}, {"top": none, "hor": none}, np.array([0]),
                       np.array([0]), 2, 1)
    out = site_adaptation_eval.true_pairs(mined, [np.array([1]), np.array([2, 3])], top, hor)
    # indices run over the embedded frames' boxes (frame 3 is not embedded)
    assert out.cross_pos.tolist() == [[1, 0], [2, 2]]
    assert out.cross_pos_group.tolist() == [0, 1]
    assert out.cross_neg.tolist() == [[0, 0], [0, 1], [1, 1], [2, 3]]
    assert out.cross_neg_group.tolist() == [0, 0, 0, 1]
    # the within-view pairs and the rest are the mined ones
    assert out.embed_frames.tolist() == [1, 2] and out.n_boxes == mined.n_boxes
    assert out.pair_set(np.zeros((3, 4)), np.zeros((4, 4))).counts()["cross_pos"] == 2
