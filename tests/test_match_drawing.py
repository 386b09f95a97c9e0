"""Tests of the per-frame association pictures of ``xvmatch associate --draw``."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from xvmatch.viz.match_drawing import (
    GAP_COLOUR,
    UNMATCHED_COLOUR,
    draw_matches,
    frames_to_draw,
    pair_colour,
    picture_path,
    write_match_picture,
)

GAP = 16  # px between the two images (the module's layout)


def _image(height: int, width: int, value: int = 90) -> np.ndarray:
    return np.full((height, width, 3), value, dtype=np.uint8)


def _colour_near(picture: np.ndarray, x: int, y: int, colour: tuple[int, int, int]) -> int:
    """Smallest per-channel distance to ``colour`` among the pixels of column x, rows y-2..y+2."""
    column = picture[max(y - 2, 0):y + 3, x].astype(int)
    return int(np.abs(column - np.array(colour)).max(axis=1).min())


def test_picture_shape_and_dtype_for_images_of_different_sizes() -> None:
    top, hor = _image(200, 300), _image(100, 80)
    picture = draw_matches(top, hor, [[10, 10, 30, 30]], [[5, 5, 20, 40]], [[0, 0]])
    # Common height 200: the hor image is scaled x2 to 160 px wide.
    assert picture.shape == (200, 300 + GAP + 160, 3)
    assert picture.dtype == np.uint8


def test_max_height_caps_the_common_height_and_keeps_aspect() -> None:
    top, hor = _image(400, 600), _image(300, 400)
    picture = draw_matches(top, hor, np.zeros((0, 4)), np.zeros((0, 4)), [], max_height=100)
    assert picture.shape == (100, 150 + GAP + 133, 3)


def test_title_adds_a_header_strip_and_inputs_are_untouched() -> None:
    top, hor = _image(60, 80), _image(60, 80)
    before = top.copy()
    plain = draw_matches(top, hor, [[10, 10, 20, 20]], [[30, 10, 20, 20]], [])
    titled = draw_matches(top, hor, [[10, 10, 20, 20]], [[30, 10, 20, 20]], [],
                          title="seq frame 12")
    assert titled.shape[0] > plain.shape[0]
    assert titled.shape[1] == plain.shape[1]
    np.testing.assert_array_equal(top, before)


def test_matched_line_crosses_the_gap_in_the_pair_colour() -> None:
    top, hor = _image(120, 160), _image(120, 160)
    top_boxes = np.array([[20.0, 20.0, 20.0, 20.0], [100.0, 70.0, 20.0, 30.0]])
    hor_boxes = np.array([[40.0, 60.0, 20.0, 40.0], [10.0, 10.0, 10.0, 10.0]])
    pairs = np.array([[1, 0], [0, 1]])  # sorted: (0, 1) is pair 0, (1, 0) is pair 1
    picture = draw_matches(top, hor, top_boxes, hor_boxes, pairs, costs=np.zeros((2, 2)))
    # Pair (1, 0): centre (109, 84) in the top image, (49 + 176, 79) in the hor image.
    (ax, ay), (bx, by) = (109, 84), (49 + 160 + GAP, 79)
    x = 160 + GAP // 2
    y = round(ay + (by - ay) * (x - ax) / (bx - ax))
    assert tuple(picture[0, x]) == GAP_COLOUR  # the gap's background, away from the lines
    assert _colour_near(picture, x, y, pair_colour(1)) <= 8
    assert _colour_near(picture, x, y, GAP_COLOUR) > 8
    # Both boxes of pair (1, 0) are outlined in its colour (left edge, mid-height).
    assert tuple(picture[85, 100]) == pair_colour(1)
    assert tuple(picture[80, 160 + GAP + 40]) == pair_colour(1)


def test_unmatched_box_outline_is_grey_and_interior_dimmed() -> None:
    rng = np.random.default_rng(0)
    top = rng.integers(0, 256, (100, 120, 3), dtype=np.uint8)
    hor = _image(100, 120, value=200)
    picture = draw_matches(top, hor, [[10, 10, 30, 30], [60, 40, 40, 40]],
                           [[20, 20, 30, 30], [70, 50, 30, 30]], [[0, 0]])
    # Unmatched top box 1 (60..99, 40..79) and hor box 1 (70..99, 50..79), at scale 1.
    assert tuple(picture[60, 60]) == UNMATCHED_COLOUR
    assert tuple(picture[60, 99]) == UNMATCHED_COLOUR
    assert tuple(picture[65, 120 + GAP + 70]) == UNMATCHED_COLOUR
    interior = picture[45:75, 65:95]
    assert (interior[..., 0] == interior[..., 1]).all()  # desaturated
    assert (interior[..., 1] == interior[..., 2]).all()
    assert picture[65, 120 + GAP + 85, 0] < 200  # dimmed
    # A matched box keeps its colour and thickness 2.
    assert tuple(picture[25, 10]) == pair_colour(0)
    assert tuple(picture[25, 11]) == pair_colour(0)


def test_boxes_past_the_image_are_clipped() -> None:
    top, hor = _image(50, 50), _image(50, 50)
    picture = draw_matches(top, hor, [[-20, 30, 200, 100]], [[40, -10, 30, 30]], [[0, 0]])
    assert picture.shape == (50, 50 + GAP + 50, 3)
    assert tuple(picture[40, 0]) == pair_colour(0)  # the clipped left edge


def test_labels_of_boxes_on_top_of_one_another_do_not_overlap() -> None:
    """Issue 29, item 6: two boxes at almost the same place: their ids go to different places
    (the second one's preferred place is taken, it moves to the next free one)."""
    from xvmatch.viz import match_drawing

    placed: list = []
    rects = [np.array([40, 60, 60, 100]), np.array([42, 62, 62, 102])]
    origins = [match_drawing._place_label(
        text, match_drawing._label_candidates(text, rect, 0.5), (0, 300), (0, 200), 0.5, placed)
        for text, rect in zip(["17", "23"], rects, strict=True)]
    assert origins[0] != origins[1]
    assert match_drawing._overlap(placed[1], [placed[0]]) == 0


def test_ids_and_costs_are_printed() -> None:
    top, hor = _image(120, 160, value=0), _image(120, 160, value=0)
    kwargs = dict(top_boxes=[[40, 60, 20, 40]], hor_boxes=[[40, 60, 20, 40]], pairs=[[0, 0]])
    bare = draw_matches(top, hor, **kwargs)
    with_ids = draw_matches(top, hor, top_ids=[7], hor_ids=np.array([12]), **kwargs)
    with_cost = draw_matches(top, hor, costs=np.array([[0.25]]), **kwargs)
    assert (with_ids != bare).any(axis=2)[:60, :].any()  # labels above the boxes
    assert (with_cost != bare).any()


def test_no_pairs_and_empty_box_sets() -> None:
    top, hor = _image(40, 60), _image(30, 30)
    empty = draw_matches(top, hor, np.zeros((0, 4)), [], np.zeros((0, 2), dtype=int),
                         top_ids=[], hor_ids=[], costs=np.zeros((0, 0)))
    assert empty.shape == (40, 60 + GAP + 40, 3)
    one_side = draw_matches(top, hor, [[5, 5, 10, 10]], np.zeros((0, 4)), [],
                            costs=np.zeros((1, 0)))
    assert tuple(one_side[10, 5]) == UNMATCHED_COLOUR


def test_pair_colours_are_distinct_and_not_grey() -> None:
    colours = [pair_colour(k) for k in range(12)]
    assert len(set(colours)) == len(colours)
    assert all(max(c) - min(c) > 100 for c in colours)
    assert pair_colour(3) == pair_colour(3)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(top_image=np.zeros((10, 10), np.uint8)), "top_image must be a non-empty"),
        (dict(hor_image=np.zeros((10, 10, 3), np.float32)), "hor_image must be uint8"),
        (dict(top_boxes=np.zeros((2, 3))), r"top_boxes must have shape \(N, 4\)"),
        (dict(hor_boxes=[[0, 0, -1, 5]]), "hor_boxes has a negative width"),
        (dict(pairs=[[0, 1, 2]]), r"pairs must have shape \(K, 2\)"),
        (dict(pairs=[[0.0, 0.0]]), "pairs must hold integer box indices"),
        (dict(pairs=[[0, 2]]), "out of range for 2 top and 2 hor boxes"),
        (dict(pairs=[[-1, 0]]), "out of range"),
        (dict(pairs=[[0, 0], [1, 0]]), "a box can be matched at most once"),
        (dict(top_ids=[1]), r"top_ids must give one id per box \(2\)"),
        (dict(costs=np.zeros((2, 3))), r"costs must have shape \(M, N\) = \(2, 2\)"),
        (dict(max_height=0), "max_height must be an integer >= 1"),
    ],
)
def test_bad_input_is_rejected(kwargs: dict, match: str) -> None:
    args = dict(top_image=_image(20, 20), hor_image=_image(20, 20),
                top_boxes=np.ones((2, 4)), hor_boxes=np.ones((2, 4)), pairs=[[0, 0]])
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        draw_matches(**args)


def test_write_match_picture_round_trips_atomically(tmp_path: Path) -> None:
    picture = draw_matches(_image(30, 40), _image(30, 40), [[5, 5, 10, 10]], [[5, 5, 10, 10]],
                           [[0, 0]])
    path = picture_path(tmp_path / "draw" / "nested", 7, suffix=".png")
    write_match_picture(path, picture)
    np.testing.assert_array_equal(cv2.imread(str(path), cv2.IMREAD_COLOR), picture)
    second = np.zeros_like(picture)
    write_match_picture(path, second)
    np.testing.assert_array_equal(cv2.imread(str(path), cv2.IMREAD_COLOR), second)
    assert sorted(p.name for p in path.parent.iterdir()) == ["frame_000007.png"]


def _real_looking_frame(height: int, width: int) -> np.ndarray:
    """A camera-like image: smooth shading, texture and sensor noise (seeded)."""
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    base = 120 + 60 * np.sin(x / 97.0) * np.cos(y / 61.0)
    image = base[..., None] + rng.normal(0, 6, (height, width, 3))
    return np.clip(image, 0, 255).astype(np.uint8)


@pytest.mark.slow
def test_pictures_are_jpeg_of_a_few_hundred_kilobytes(tmp_path: Path) -> None:
    """Issue 29, item 6: a real-size frame pair's picture was a 3 MB PNG; it is a JPEG of
    quality 90 now, a fraction of the lossless size, and decodes to nearly the same picture."""
    top, hor = _real_looking_frame(1512, 2688), _real_looking_frame(787, 1399)
    picture = draw_matches(top, hor, [[100, 100, 60, 60], [900, 500, 60, 60]],
                           [[200, 200, 80, 300], [900, 250, 90, 320]], [[0, 0], [1, 1]],
                           top_ids=[1, 2], hor_ids=[11, 12], title="frame 1")
    jpeg = picture_path(tmp_path, 1)
    assert jpeg.name == "frame_000001.jpg"
    write_match_picture(jpeg, picture)
    png = picture_path(tmp_path, 1, suffix=".png")
    write_match_picture(png, picture)
    assert jpeg.stat().st_size < 700_000
    assert jpeg.stat().st_size < png.stat().st_size / 2
    back = cv2.imread(str(jpeg), cv2.IMREAD_COLOR)
    assert back.shape == picture.shape
    assert np.abs(back.astype(int) - picture).mean() < 6


def test_write_match_picture_rejects_bad_input(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"path must end in \.jpg, \.jpeg or \.png"):
        write_match_picture(tmp_path / "frame.gif", _image(4, 4))
    with pytest.raises(ValueError, match="picture must be uint8"):
        write_match_picture(tmp_path / "frame.png", np.zeros((4, 4, 3), np.float64))
    assert list(tmp_path.iterdir()) == []


def test_write_match_picture_never_replaces_a_fifo_or_a_folder(tmp_path: Path) -> None:
    import os
    import stat

    os.mkfifo(tmp_path / "pipe.png")
    (tmp_path / "dir.png").mkdir()
    for name in ("pipe.png", "dir.png"):
        with pytest.raises(ValueError, match=f"{name}: exists and is not a regular file"):
            write_match_picture(tmp_path / name, _image(4, 4))
    assert stat.S_ISFIFO((tmp_path / "pipe.png").lstat().st_mode)
    assert (tmp_path / "dir.png").is_dir()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dir.png", "pipe.png"]


def test_picture_path() -> None:
    assert picture_path(Path("out"), 12) == Path("out/frame_000012.jpg")
    assert picture_path("out", 0, suffix=".png").name == "frame_000000.png"
    with pytest.raises(ValueError, match="frame must be an integer >= 0"):
        picture_path("out", -1)
    with pytest.raises(ValueError, match="suffix"):
        picture_path("out", 1, suffix=".gif")


def test_frames_to_draw() -> None:
    assert frames_to_draw([5, 1, 2, 3, 4, 6], every=2) == [1, 3, 5]
    assert frames_to_draw([3, 1, 2], every=1) == [1, 2, 3]
    assert frames_to_draw([10, 20, 30, 40], every=3) == [10, 40]
    assert frames_to_draw([4, 4, 2], every=1) == [2, 4]
    assert frames_to_draw([], every=5) == []
    for every in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="every must be an integer >= 1"):
            frames_to_draw([1, 2], every=every)
