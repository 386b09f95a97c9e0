"""Pictures of box-only results (issue 29, item 5): ``xvmatch associate --draw`` without images,
for the handcrafted search and the learned matcher: the horizontal boxes on a blank canvas of
the horizontal image size, the top view as a plan; ``--no-labels`` leaves the ids out."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from xvmatch.cli import main
from xvmatch.core.folder_marker import MARKER
from xvmatch.datasets.box_scene import simulate_box_scene
from xvmatch.formats.mot_boxes import read_predictions, write_mot_boxes
from xvmatch.viz.box_canvas import CANVAS_COLOUR, blank_view, top_plan
from xvmatch.viz.match_drawing import pair_colour


@pytest.fixture(scope="module")
def boxes(tmp_path_factory):
    folder = tmp_path_factory.mktemp("boxes_only")
    scene = simulate_box_scene(n_frames=4, seed=1)
    write_mot_boxes(folder / "top.txt", scene.top)
    write_mot_boxes(folder / "hor.txt", scene.hor)
    return folder / "top.txt", folder / "hor.txt"


def _associate(capsys, boxes, out, *extra):
    top, hor = boxes
    capsys.readouterr()
    code = main(["associate", "--top", str(top), "--hor", str(hor), "--out", str(out / "p.csv"),
                 "--image-size", "2688x1512", "--quiet", *extra])
    return code, capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.parametrize("model", [[], ["--model", "default"]], ids=["handcrafted", "learned"])
def test_both_methods_draw_box_only_results(boxes, tmp_path, capsys, model):
    code, err = _associate(capsys, boxes, tmp_path, "--draw", str(tmp_path / "draw"),
                           "--draw-every", "2", *model)
    assert code == 0, err
    names = sorted(p.name for p in (tmp_path / "draw").iterdir())
    assert names == [MARKER, "frame_000001.jpg", "frame_000003.jpg"]
    picture = cv2.imread(str(tmp_path / "draw" / "frame_000001.jpg"), cv2.IMREAD_COLOR)
    assert picture is not None and picture.shape[0] > 300
    body = picture[40:].reshape(-1, 3).astype(int)
    blank = np.abs(body - np.array(CANVAS_COLOUR)).max(axis=1) <= 8
    assert blank.mean() > 0.5  # mostly the blank canvases
    pairs = read_predictions(tmp_path / "p.csv")
    if pairs.get(1):  # the first pair's colour is on the picture
        near = np.abs(body - np.array(pair_colour(0))).max(axis=1) <= 40
        assert near.sum() > 50


def test_no_labels_leaves_the_ids_out(boxes, tmp_path, capsys):
    pictures = []
    for name, extra in (("labels", []), ("bare", ["--no-labels"])):
        out = tmp_path / name
        out.mkdir()
        code, err = _associate(capsys, boxes, out, "--draw", str(out / "draw"), *extra)
        assert code == 0, err
        pictures.append(cv2.imread(str(out / "draw" / "frame_000001.jpg"), cv2.IMREAD_COLOR))
    assert pictures[0].shape == pictures[1].shape
    assert np.abs(pictures[0].astype(int) - pictures[1]).max() > 100  # the ids' text


def test_the_plan_frames_every_top_box_and_keeps_their_shape():
    scene = simulate_box_scene(n_frames=3, seed=2)
    plan = top_plan(scene.top)
    h, w = plan.image.shape[:2]
    for rec in scene.top.values():
        placed = plan.place(rec.boxes)
        assert (placed[:, 0] >= 0).all() and (placed[:, 1] >= 0).all()
        assert (placed[:, 0] + placed[:, 2] <= w).all() and (placed[:, 1] + placed[:, 3] <= h).all()
        np.testing.assert_allclose(placed[:, 2:] / plan.scale, rec.boxes[:, 2:])
    assert blank_view((40, 30)).shape == (30, 40, 3)
    with pytest.raises(ValueError, match="size"):
        blank_view((0, 30))


def test_show_draws_a_frame_of_box_files(boxes, tmp_path, capsys):
    """``show --top --hor``: the ground-truth pairs (same id in both views) or a prediction
    CSV's, on the same canvases as --draw; a frame without boxes in both views is refused."""
    top, hor = boxes
    code, err = _associate(capsys, boxes, tmp_path)
    assert code == 0, err
    capsys.readouterr()
    for extra, name in (([], "gt.png"), (["--pred", str(tmp_path / "p.csv")], "pred.jpg")):
        assert main(["show", "--top", str(top), "--hor", str(hor), "--frame", "2",
                     "--image-size", "2688x1512", "--out", str(tmp_path / name), *extra]) == 0
        picture = cv2.imread(str(tmp_path / name), cv2.IMREAD_COLOR)
        body = picture[40:].reshape(-1, 3).astype(int)
        near = np.abs(body - np.array(pair_colour(0))).max(axis=1) <= 40
        assert near.sum() > 50  # at least one pair drawn in the first pair colour
    capsys.readouterr()
    assert main(["show", "--top", str(top), "--hor", str(hor), "--frame", "99", "--image-size",
                 "2688x1512", "--out", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--frame 99" in err and not (tmp_path / "x.png").exists()
    assert main(["show", "--out", str(tmp_path / "x.png")]) == 2
    assert "PAIR" in capsys.readouterr().err
