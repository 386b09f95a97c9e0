"""The pictures' ground truth and video (issue 69, item 10): ``write_match_pictures`` colours
right pairs green and wrong ones red and marks the camera wearer when given the true ids
(:func:`~xvmatch.viz.match_pictures.truth_marks`, ``--draw-truth``), draws exactly what it drew
before when not, and writes the same pictures as an mp4 video (:class:`MatchVideo`);
``associate --draw-truth`` and ``--draw-video`` wire them on the command line."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from xvmatch.cli import main
from xvmatch.datasets.box_scene import simulate_box_scene
from xvmatch.formats.mot_boxes import FrameBoxes, write_mot_boxes
from xvmatch.viz.box_canvas import blank_view, top_plan
from xvmatch.viz.match_drawing import (
    RIGHT_COLOUR,
    WEARER_COLOUR,
    WRONG_COLOUR,
    draw_matches,
    pair_colour,
    write_match_picture,
)
from xvmatch.viz.match_pictures import MatchVideo, truth_marks, write_match_pictures

OWNER = "test --draw"


def _near(picture: np.ndarray, colour: tuple[int, int, int], tol: int = 25) -> int:
    """Pixels of ``picture`` (below its title strip) within ``tol`` of the BGR ``colour``."""
    low = np.clip(np.array(colour) - tol, 0, 255).astype(np.uint8)
    high = np.clip(np.array(colour) + tol, 0, 255).astype(np.uint8)
    return int(cv2.countNonZero(cv2.inRange(picture[30:], low, high)))


def _views():
    """One frame (7): four top people (ids 1, 2, 3 and the wearer 5) and three horizontal ones
    (1, 2, 3); pairs (1, 1) right, (2, 3) wrong."""
    top = {7: FrameBoxes(7, np.array([1, 2, 3, 5]), np.array(
        [[100, 100, 40, 40], [300, 120, 40, 40], [500, 300, 40, 40], [200, 400, 40, 40]],
        float))}
    hor = {7: FrameBoxes(7, np.array([1, 2, 3]), np.array(
        [[100, 200, 80, 200], [400, 220, 80, 200], [700, 210, 80, 200]], float))}
    return top, hor, {7: [(1, 1), (2, 3)]}


def test_truth_colours_right_pairs_green_wrong_ones_red_and_marks_the_wearer(tmp_path):
    top, hor, pairs = _views()
    marks = truth_marks(top, hor, camera_id=5)
    assert marks["wearer"] == {7: 3}
    write_match_pictures(tmp_path / "draw", 1, top, hor, pairs, [7], None, (960, 540),
                         owner=OWNER, option="--draw", **marks)
    picture = cv2.imread(str(tmp_path / "draw" / "frame_000007.jpg"))
    assert _near(picture, RIGHT_COLOUR) > 100 and _near(picture, WRONG_COLOUR) > 100
    assert _near(picture, pair_colour(0), 10) == 0
    assert _near(picture, WEARER_COLOUR, 5) > 30


def test_truth_of_a_detection_file_reads_the_rows_true_ids(tmp_path):
    # track's records hold row numbers; the truth is each row's id in the file
    top = {1: FrameBoxes(1, np.array([0, 1]), np.zeros((2, 4)) + 10)}
    hor = {1: FrameBoxes(1, np.array([2, 3]), np.zeros((2, 4)) + 10)}
    marks = truth_marks(top, hor, 9, np.array([4, 9]), np.array([-1, -1, 4, 7]))
    assert [ids.tolist() for ids in (marks["truth"][0][1], marks["truth"][1][1])] == [[4, 9],
                                                                                      [4, 7]]
    assert marks["wearer"] == {1: 1}


def test_without_truth_the_pictures_are_those_drawn_before(tmp_path):
    # what write_match_pictures drew before the truth and video options: the same bytes
    top, hor, pairs = _views()
    write_match_pictures(tmp_path / "draw", 1, top, hor, pairs, [7], None, (960, 540),
                         owner=OWNER, option="--draw")
    plan = top_plan(top)
    rows = np.array([[0, 0], [1, 2]])  # (1, 1) and (2, 3) as box indices
    legend = ("same colour: same person; grey: unmatched; boxes only: top view as a plan, "
              "horizontal view blank")
    picture = draw_matches(plan.image, blank_view((960, 540)), plan.place(top[7].boxes),
                           hor[7].boxes, rows, top[7].ids, hor[7].ids,
                           title=f"frame 7: 2 matches ({legend})")
    write_match_picture(tmp_path / "expected.jpg", picture)
    assert ((tmp_path / "draw" / "frame_000007.jpg").read_bytes()
            == (tmp_path / "expected.jpg").read_bytes())


def test_a_track_keeps_its_colour_from_frame_to_frame(tmp_path):
    # Frame 8 is frame 7 with its pairs listed the other way round; with the tracks, each pair
    # is drawn in its track's colour (tracks 40 and 41), not by its place in the frame.
    top, hor, pairs = _views()
    top[8], hor[8] = FrameBoxes(8, top[7].ids, top[7].boxes), FrameBoxes(8, hor[7].ids,
                                                                          hor[7].boxes)
    pairs[8] = pairs[7][::-1]
    tracks = ({1: 40, 2: 41, 3: 42}, {1: 40, 3: 41})
    write_match_pictures(tmp_path / "draw", 1, top, hor, pairs, [7, 8], None, (960, 540),
                         owner=OWNER, option="--draw", tracks=tracks)
    first, second = (cv2.imread(str(tmp_path / "draw" / f"frame_00000{f}.jpg")) for f in (7, 8))
    for picture in (first, second):
        assert _near(picture, pair_colour(40)) > 100 and _near(picture, pair_colour(41)) > 100
        assert _near(picture, pair_colour(0), 10) == 0
    assert cv2.absdiff(first[30:], second[30:]).mean() < 1  # the same but the title
    with pytest.raises(ValueError, match="keys must give one integer per pair"):
        draw_matches(first, first, top[7].boxes, hor[7].boxes, [[0, 0]], keys=[0.5])


def test_the_video_holds_every_picture_and_appears_only_when_complete(tmp_path):
    top, hor, pairs = _views()
    video = tmp_path / "out" / "pairs.mp4"
    write_match_pictures(None, 1, top, hor, pairs, [7], None, (961, 541), owner=OWNER,
                         option="--draw", video=video)
    assert sorted(p.name for p in video.parent.iterdir()) == ["pairs.mp4"]
    capture = cv2.VideoCapture(str(video))
    ok, frame = capture.read()
    capture.release()
    assert ok and frame.shape[0] % 2 == 0 and frame.shape[1] % 2 == 0  # odd sides padded
    with pytest.raises(ValueError, match=r"ends in \.mp4"):
        MatchVideo(tmp_path / "pairs.avi")
    top[8] = FrameBoxes(8, top[7].ids, top[7].boxes)
    hor[8] = FrameBoxes(8, hor[7].ids, -hor[7].boxes)
    with pytest.raises(ValueError, match="negative width"):  # a bad frame after a good one
        write_match_pictures(None, 1, top, hor, pairs, [7, 8], None, (960, 540), owner=OWNER,
                             option="--draw", video=tmp_path / "broken.mp4")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


@pytest.fixture(scope="module")
def boxes(tmp_path_factory):
    folder = tmp_path_factory.mktemp("truth")
    scene = simulate_box_scene(n_frames=2, seed=1)
    write_mot_boxes(folder / "top.txt", scene.top)
    write_mot_boxes(folder / "hor.txt", scene.hor)
    return folder / "top.txt", folder / "hor.txt"


@pytest.mark.slow
@pytest.mark.parametrize("model", [[], ["--model", "default"]], ids=["handcrafted", "learned"])
def test_associate_draw_truth_colours_by_the_files_ids(boxes, tmp_path, capsys, model):
    top, hor = boxes
    code = main(["associate", "--top", str(top), "--hor", str(hor), "--out",
                 str(tmp_path / "p.csv"), "--image-size", "2688x1512", "--quiet", "--draw",
                 str(tmp_path / "draw"), "--draw-truth", "--camera-id", "0", "--mode", "frame",
                 "--draw-video", str(tmp_path / "pairs.mp4"), *model])
    assert code == 0, capsys.readouterr().err
    picture = cv2.imread(str(tmp_path / "draw" / "frame_000001.jpg"))
    assert _near(picture, RIGHT_COLOUR) > 100
    assert _near(picture, pair_colour(0), 10) == 0
    assert _near(picture, WEARER_COLOUR, 5) > 30
    video = cv2.VideoCapture(str(tmp_path / "pairs.mp4"))
    assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == 2  # the two frames' pictures
    video.release()


def test_associate_draw_video_must_be_an_mp4_file(boxes, tmp_path, capsys):
    top, hor = boxes
    code = main(["associate", "--top", str(top), "--hor", str(hor), "--out",
                 str(tmp_path / "p.csv"), "--draw-video", str(tmp_path / "pairs.avi")])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("xvmatch: error: --draw-video"), err
    assert sorted(p.name for p in tmp_path.iterdir()) == []
