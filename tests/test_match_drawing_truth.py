"""Match pictures as a MOT user reads them (issue 69, item 10): cost labels that never pile up,
right pairs green and wrong ones red when the ground truth is known, the camera wearer marked
in the top view."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from xvmatch.viz import match_drawing
from xvmatch.viz.match_drawing import (
    RIGHT_COLOUR,
    WEARER_COLOUR,
    WRONG_COLOUR,
    draw_matches,
    pair_colour,
    pairs_correct,
)

GAP = 16  # px between the two images (the module's layout)


def _image(height: int, width: int, value: int = 90) -> np.ndarray:
    return np.full((height, width, 3), value, dtype=np.uint8)


def _cost_layout(ends: list[list[tuple[int, int]]], width: int = 336, height: int = 120):
    """The cost labels ``_cost_labels`` draws for lines with these ends: ``(text, rect)``."""
    k = len(ends)
    canvas = _image(height, width)
    drawn = match_drawing._cost_labels(
        canvas, np.linspace(0.01, 0.5, k * k).reshape(k, k), np.array([(i, i) for i in range(k)]),
        ends, (0, height), [pair_colour(i) for i in range(k)], 0.45, [])
    return [(text, match_drawing._text_rect(text, org, 0.45)) for text, org in drawn]


def test_cost_labels_of_lines_crossing_at_one_point_never_overlap() -> None:
    # Ten lines through the picture's centre: every label's first choice is the same place.
    ends = [[(20, 10 + 10 * i), (316, 110 - 10 * i)] for i in range(10)]
    labels = _cost_layout(ends)
    assert 1 <= len(labels) < 10  # crowded: some costs left out rather than piled up
    for (_, a), (_, b) in itertools.combinations(labels, 2):
        assert match_drawing._overlap(a, [b]) == 0, (a, b)


def test_cost_labels_with_room_are_all_drawn() -> None:
    ends = [[(20, 20 + 60 * i), (300, 20 + 60 * i)] for i in range(3)]  # far apart
    labels = _cost_layout(ends, height=200)
    assert [t for t, _ in labels] == ["cost 0.01", "cost 0.26", "cost 0.50"]


def test_pairs_correct_reads_ids_as_ground_truth() -> None:
    got = pairs_correct([5, 7, 9], np.array([9, 7]), [[1, 1], [0, 0], [2, 0]])
    assert got.tolist() == [True, False, True]
    with pytest.raises(ValueError, match="pairs index past the 3 top or 2 hor ids"):
        pairs_correct([5, 7, 9], [9, 7], [[0, 2]])


def test_right_pairs_green_wrong_pairs_red() -> None:
    top, hor = _image(120, 160), _image(120, 160)
    top_boxes = np.array([[20.0, 20.0, 20.0, 20.0], [100.0, 70.0, 20.0, 30.0]])
    hor_boxes = np.array([[40.0, 60.0, 20.0, 40.0], [10.0, 10.0, 10.0, 10.0]])
    pairs = np.array([[1, 0], [0, 1]])  # given unsorted: correct follows this order
    picture = draw_matches(top, hor, top_boxes, hor_boxes, pairs, correct=[False, True])
    # Pair (1, 0), wrong: its boxes red; pair (0, 1), right: green.
    assert tuple(picture[85, 100]) == WRONG_COLOUR
    assert tuple(picture[80, 160 + GAP + 40]) == WRONG_COLOUR
    assert tuple(picture[30, 20]) == RIGHT_COLOUR
    assert tuple(picture[15, 160 + GAP + 10]) == RIGHT_COLOUR
    plain = draw_matches(top, hor, top_boxes, hor_boxes, pairs)
    assert tuple(plain[85, 100]) == pair_colour(1)  # without ground truth: the pair colours


@pytest.mark.parametrize("correct, match", [
    ([True], r"correct must give one bool per pair \(2\)"),
    ([1, 0], "correct must give one bool per pair"),
])
def test_bad_correct_is_refused(correct, match) -> None:
    img = _image(60, 80)
    with pytest.raises(ValueError, match=match):
        draw_matches(img, img, [[1, 1, 5, 5], [20, 20, 5, 5]], [[1, 1, 5, 5], [20, 20, 5, 5]],
                     [[0, 0], [1, 1]], correct=correct)


def test_camera_wearer_is_marked_in_the_top_view() -> None:
    top, hor = _image(120, 160), _image(120, 160)
    boxes = np.array([[20.0, 40.0, 20.0, 20.0], [100.0, 70.0, 20.0, 30.0]])
    bare = draw_matches(top, hor, boxes, boxes[:1], [[1, 0]])
    marked = draw_matches(top, hor, boxes, boxes[:1], [[1, 0]], wearer=0)
    # Box 0 covers x 20..39, y 40..59: a white outline 3 px outside it, on its left edge.
    assert tuple(marked[50, 17]) == WEARER_COLOUR
    assert tuple(bare[50, 17]) != WEARER_COLOUR
    # and the word "camera" by it, in white (anti-aliased: near white): such pixels above or
    # below the box that the bare picture lacks.
    changed = (marked != bare).any(axis=2)
    white = (marked >= 200).all(axis=2)
    assert (changed & white)[:36].any() or (changed & white)[64:].any()
    with pytest.raises(ValueError, match=r"wearer must be the index of a top box, 0\.\.1, got 2"):
        draw_matches(top, hor, boxes, boxes[:1], [[1, 0]], wearer=2)
