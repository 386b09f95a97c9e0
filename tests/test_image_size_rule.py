"""The horizontal image size of box-only runs (issue 29, item 1;
:mod:`xvmatch.commands._box_reading`).

The same scene's horizontal boxes at CVMHAT's 2688x1512, at 1399x787 (the user's camera) and at
half size: without ``--image-size`` the CVMHAT-sized boxes run with a note and the others are
refused in one line naming ``--image-size``; with the right ``--image-size`` every run pairs the
same people as the original (the features are resolution-free). Boxes too far outside the image
are an error naming the line. Run through ``xvmatch.cli.main`` end to end.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.cli import main
from xvmatch.datasets.box_scene import simulate_box_scene
from xvmatch.formats.box_image_size import (
    ASSUMED,
    COMMON_SIZES,
    CVMHAT_SIZE,
    MIN_EXTENT,
    UNKNOWN,
    border_size,
    common_size_holding,
    common_size_started,
    consistent_with,
    ground_path_hor_size,
    ground_path_size_note,
    guess_image_size,
    hor_size_note,
    resolve_size,
    runs_past_borders,
    size_guess_how,
)
from xvmatch.formats.mot_boxes import (
    FrameBoxes,
    read_mot_boxes,
    read_predictions,
    scale_frames,
    write_mot_boxes,
)

SIZES = {"1399x787": 1399 / 2688, "1344x756": 0.5}
"""The user's camera of the issue, and half the CVMHAT size: ``--image-size`` -> scale."""


@pytest.fixture(scope="module")
def boxes(tmp_path_factory):
    """A simulated 2688x1512 scene (boxes reaching past 60% of the width) and its horizontal
    boxes scaled to each of :data:`SIZES`; ``{name: (top, hor)}`` paths, ``cvmhat`` the
    original."""
    folder = tmp_path_factory.mktemp("sizes")
    scene = simulate_box_scene(n_frames=12, seed=1)
    assert consistent_with(scene.hor)
    top = folder / "top.txt"
    write_mot_boxes(top, scene.top)
    out = {"cvmhat": (top, folder / "hor.txt")}
    write_mot_boxes(out["cvmhat"][1], scene.hor)
    for size, factor in SIZES.items():
        out[size] = (top, folder / f"hor_{size}.txt")
        write_mot_boxes(out[size][1], scale_frames(scene.hor, factor))
    return out


def _run(capsys, *argv: str) -> tuple[int, str]:
    capsys.readouterr()
    code = main(list(argv))
    return code, capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.parametrize("model", [[], ["--model", "default"]], ids=["handcrafted", "learned"])
@pytest.mark.parametrize("size", list(SIZES))
def test_boxes_only_needs_the_size_and_then_pairs_as_at_full_size(boxes, tmp_path, capsys,
                                                                  size, model):
    top, hor = boxes["cvmhat"]
    code, err = _run(capsys, "associate", "--top", str(top), "--hor", str(hor), "--out",
                     str(tmp_path / "full.csv"), *model)
    assert code == 0, err
    notes = [line for line in err.splitlines() if line.startswith("xvmatch: note:")
             and "--mode video" not in line]  # the mode auto took is said on its own line
    assert len(notes) == 1 and "2688x1512" in notes[0] and "--image-size" in notes[0], err
    full = read_predictions(tmp_path / "full.csv")
    assert sum(len(p) for p in full.values()) >= 20

    top, hor = boxes[size]
    code, err = _run(capsys, "associate", "--top", str(top), "--hor", str(hor), "--out",
                     str(tmp_path / "refused.csv"), *model)
    assert code == 2 and err.count("\n") == 1 and err.startswith("xvmatch: error: "), err
    assert "--image-size" in err and str(hor) in err
    assert not (tmp_path / "refused.csv").exists()

    code, err = _run(capsys, "associate", "--top", str(top), "--hor", str(hor), "--out",
                     str(tmp_path / "scaled.csv"), "--image-size", size, "--quiet", *model)
    assert code == 0 and err == "", err
    assert read_predictions(tmp_path / "scaled.csv") == full


@pytest.mark.parametrize("command", ["track", "offset", "associate-multi"])
def test_every_box_command_refuses_an_unknown_size(boxes, tmp_path, capsys, command):
    top, hor = boxes["1399x787"]
    out = [] if command == "offset" else ["--out", str(tmp_path / "out")]
    code, err = _run(capsys, command, "--top", str(top), "--hor", str(hor), *out)
    assert code == 2 and err.count("\n") == 1 and "--image-size" in err, err
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_track_with_the_size_gives_the_tracks_of_the_full_size(boxes, tmp_path, capsys):
    top, hor = boxes["cvmhat"]
    code, err = _run(capsys, "track", "--top", str(top), "--hor", str(hor), "--out",
                     str(tmp_path / "full"), "--quiet")
    assert code == 0, err
    top, hor = boxes["1399x787"]
    code, err = _run(capsys, "track", "--top", str(top), "--hor", str(hor), "--out",
                     str(tmp_path / "scaled"), "--quiet", "--image-size", "1399x787")
    assert code == 0, err
    assert (tmp_path / "scaled" / "top.txt").read_text() == \
        (tmp_path / "full" / "top.txt").read_text()
    full_ids = [ln.split(",")[1] for ln in (tmp_path / "full" / "hor.txt").read_text().split()]
    scaled_ids = [ln.split(",")[1] for ln in
                  (tmp_path / "scaled" / "hor.txt").read_text().split()]
    assert scaled_ids == full_ids


def test_offset_and_multi_take_the_size(boxes, tmp_path, capsys):
    top, hor = boxes["1344x756"]
    code, err = _run(capsys, "offset", "--top", str(top), "--hor", str(hor), "--image-size",
                     "1344x756", "--max-offset", "2", "--clips", "2", "--clip-length", "3")
    assert code == 0, err
    code, err = _run(capsys, "associate-multi", "--top", str(top), "--hor", str(hor), "--out",
                     str(tmp_path / "multi"), "--image-size", "1344x756", "--quiet")
    assert code == 0, err


def test_fit_geometry_refuses_an_unknown_size(boxes, tmp_path, capsys):
    pytest.importorskip("torch")
    data = tmp_path / "data"
    data.mkdir()
    top, hor = boxes["1399x787"]
    (data / "V0-S_a-G_1_top.txt").write_text(top.read_text())
    (data / "V0-S_a-G_1_hor.txt").write_text(hor.read_text())
    code, err = _run(capsys, "fit-geometry", "--cvmhat", str(data), "--out",
                     str(tmp_path / "m.pt"), "--quiet")
    assert code == 2 and err.count("\n") == 1 and "--image-size" in err, err
    assert not (tmp_path / "m.pt").exists()
    code, err = _run(capsys, "fit-geometry", "--cvmhat", str(data), "--out",
                     str(tmp_path / "m.pt"), "--quiet", "--image-size", "1400x600")
    assert code == 2 and "16:9" in err, err
    code, err = _run(capsys, "fit-geometry", "--cvmhat", str(data), "--out",
                     str(tmp_path / "m.pt"), "--quiet", "--image-size", "1399x787", "--epochs",
                     "1", "--noise", "0", "--sim-scenes", "0", "--width", "16", "--layers", "1",
                     "--cache", str(tmp_path / "cache"), "--no-sync")
    assert code == 0, err  # trained on the boxes scaled to 2688 wide
    assert (tmp_path / "m.pt").is_file()


def test_the_rule_separates_a_small_camera_from_cvmhat():
    """A 1399-wide camera's boxes reach at most 1399 plus the margin: below 60% of 2688."""
    assert 1399 * 1.1 < MIN_EXTENT * CVMHAT_SIZE[0]
    edge = {1: FrameBoxes(1, [1, 2], [[0, 0, 50, 100], [1340, 600, 59, 187]])}
    assert not consistent_with(edge)
    wide = {1: FrameBoxes(1, [1], [[2600, 1400, 80, 110]])}
    assert consistent_with(wide)


@pytest.mark.parametrize(("box", "size"), [
    ([100, 100, 40, 90], (640, 360)),
    ([1700, 900, 60, 170], (1920, 1080)),  # a drone's 1080p frame: reaches 1760 x 1070
    ([1900, 1000, 30, 95], (1920, 1080)),  # 2% past the border still holds
    ([3500, 1900, 100, 140], (3840, 2160)),
    ([9000, 100, 10, 10], None),  # wider than every common size
])
def test_the_common_size_holding_boxes_is_the_smallest_that_does(box, size):
    """A size guessed from boxes alone: the smallest common video size holding every box."""
    frames = {1: FrameBoxes(1, [1, 2], [[5, 5, 10, 20], box])}
    assert common_size_holding(frames) == size
    assert common_size_holding({}) is None
    areas = [w * h for w, h in COMMON_SIZES]
    assert areas == sorted(areas)


def test_the_ground_path_guesses_only_a_size_it_assumed():
    """The ground-map path replaces an assumed CVMHAT size by the smallest common size holding
    the boxes; a size given, or boxes that need the CVMHAT size, stay."""
    phone = {1: FrameBoxes(1, [1, 2], [[5, 5, 10, 20], [1700, 600, 60, 170]])}
    assert consistent_with(phone)  # boxes alone would be read as CVMHAT's
    assert ground_path_hor_size(phone, CVMHAT_SIZE, ASSUMED) == (1920, 1080)
    assert ground_path_hor_size(phone, CVMHAT_SIZE, "--image-size") is None
    wide = {1: FrameBoxes(1, [1], [[2640, 600, 40, 170]])}
    assert ground_path_hor_size(wide, CVMHAT_SIZE, ASSUMED) is None  # CVMHAT's own: kept
    assert ground_path_hor_size({}, CVMHAT_SIZE, ASSUMED) is None
    # What the path says: the guess, the CVMHAT size kept, nothing for a size given.
    assert ground_path_size_note("h.txt", phone, (1920, 1080), ASSUMED) == hor_size_note(
        "h.txt", phone, (1920, 1080), ASSUMED)
    assert ground_path_size_note("h.txt", wide, None, ASSUMED).startswith(
        "assuming h.txt's images are 2688x1512 (CVMHAT; its boxes reach x 2680, y 770)")
    assert ground_path_size_note("h.txt", phone, None, "--image-size") is None


def test_boxes_past_cvmhats_size_are_left_to_the_path_only_when_asked():
    """Boxes alone that do not fit 2688x1512 (a 3640x2048 camera's): refused in one line naming
    the file, unless the caller defers (``associate``, whose ground-map path guesses the size);
    boxes no common size holds are refused either way."""
    big = {1: FrameBoxes(1, [1, 2], [[5, 5, 10, 20], [3500, 1500, 120, 500]])}
    with pytest.raises(ValueError, match=r"^h\.txt: the horizontal image size is unknown: pass "
                       r"--image-size WxH .* reach x 3620, y 2000,"):
        resolve_size(big, "h.txt", [])
    assert resolve_size(big, "h.txt", [], defer=True) == ((3840, 2160), UNKNOWN)
    assert ground_path_hor_size(big, (3840, 2160), UNKNOWN) == (3840, 2160)
    assert resolve_size(big, "h.txt", [((3640, 2048), "--image-size")], defer=True) == \
        ((3640, 2048), "--image-size")
    huge = {1: FrameBoxes(1, [1], [[9000, 100, 10, 10]])}
    with pytest.raises(ValueError, match="size is unknown"):
        resolve_size(huge, "h.txt", [], defer=True)
    assert hor_size_note("h.txt", big, (3840, 2160), UNKNOWN) == (
        "h.txt: its images taken as 3840x2160 on this path, the smallest common video size "
        "holding its boxes (give --image-size WxH if not)")


def _clipped(boxes: np.ndarray, size: tuple[int, int]) -> dict:
    """``(x0, y0, x1, y1)`` rows clipped to a ``size`` image as annotation tools clip them, as
    ``(x, y, w, h)`` boxes of one frame (one person each)."""
    b = np.clip(boxes, 0.0, np.tile(np.asarray(size, float), 2))
    return {1: FrameBoxes(1, np.arange(len(b)), np.column_stack([b[:, :2], b[:, 2:] - b[:, :2]]))}


@settings(max_examples=60, deadline=None)
@given(width=st.integers(80, 1000).map(lambda k: 8 * k),
       aspect=st.sampled_from([16 / 9, 4 / 3, 2.0, 1.0]), seed=st.integers(0, 2**31 - 1))
def test_boxes_cut_by_the_borders_tell_the_size(width, aspect, seed):
    """People leaving a clip's frame, their boxes clipped by its right and bottom borders, give
    the image size exactly, any size of whole 8-pixel blocks (a 3640x2048 phone is no common
    video size) but one within 1% of a common size, which is that size; people who never reach
    a border leave it to the common sizes."""
    height = 8 * round(width / aspect / 8)
    rng = np.random.default_rng(seed)
    x0 = rng.uniform(0.0, 0.9 * width, 40)
    y0 = rng.uniform(0.0, 0.5 * height, 40)
    w, h = rng.uniform(0.05, 0.15, (2, 40)) * height
    boxes = np.column_stack([x0, y0, x0 + w, y0 + 2.0 * h])
    boxes[:3, 1] = [0.0, 0.25 * height, 0.5 * height]  # three people cut at the right
    boxes[:3, 2] = width + rng.uniform(1.0, 50.0, 3)
    boxes[3:6, 0] = [0.1 * width, 0.4 * width, 0.7 * width]  # three at the bottom
    boxes[3:6, 3] = height + rng.uniform(1.0, 50.0, 3)
    near = [c for c in COMMON_SIZES if abs(width - c[0]) <= 0.01 * c[0]
            and abs(height - c[1]) <= 0.01 * c[1]]
    assert border_size(_clipped(boxes, (width, height))) == (near[0] if near else (width, height))
    inside = np.column_stack([x0, y0, x0 + w, y0 + h])[6:] * 0.5
    assert border_size(_clipped(inside, (width, height))) is None


@pytest.mark.parametrize(("cut", "size"), [
    ("bottom", (3640, 2048)),  # 2048 * 16 / 9 = 3640.9, to a multiple of 8: 3640
    ("right", (3640, 2048)),  # 3640 * 9 / 16 = 2047.5
])
def test_one_border_gives_the_other_side_from_the_frames_aspect(cut, size):
    """A phone's passers-by cut only by its bottom edge (or people leaving by its right edge
    only): the other side from 16:9, the first of the frame aspects holding every box."""
    bottom = [[100.0, 200.0, 900.0, 2500.0], [1500.0, 900.0, 2100.0, 2600.0],
              [2200.0, 1200.0, 2700.0, 2900.0], [3000.0, 300.0, 3300.0, 1100.0]]
    right = [[3300.0, 200.0, 3900.0, 1500.0], [3500.0, 900.0, 3800.0, 1700.0],
             [3100.0, 500.0, 3700.0, 2040.0], [300.0, 300.0, 500.0, 1100.0]]
    boxes = np.array(bottom if cut == "bottom" else right)
    assert border_size(_clipped(boxes, size)) == size
    assert guess_image_size(_clipped(boxes, size)) == size


def test_a_person_standing_at_the_far_edge_is_no_border():
    """The boxes of one person at the farthest edge (standing still, boxes interpolated, walking
    slowly far away or along that edge), however many, are not a border; boxes past the border (a
    detector's, not clipped) show none: the smallest common size holding them is guessed."""
    still = {f: FrameBoxes(f, [1, 2], [[3500.0, 1500.0, 120.0, 500.0], [10.0, 10.0, 40.0, 90.0]])
             for f in range(1, 6)}
    assert border_size(still) is None
    slow = {f: FrameBoxes(f, [1], [[3500.0 + 0.1 * f, 1500.0 - 0.3 * f, 120.0, 500.0]])
            for f in range(1, 6)}  # far away, walking towards the camera: edges within 1 px
    assert border_size(slow) is None
    along = {f: FrameBoxes(f, [1, 2], [[1155.0 + 0.1 * f, 200.0 + 15.0 * f, 28.4, 72.0],
                                       [10.0, 10.0, 40.0, 90.0]])
             for f in range(1, 9)}  # one person walking down a column of the image
    assert border_size(along) is None
    assert guess_image_size(still) == (3840, 2160)
    past = {f: FrameBoxes(f, [1], [[3600.0, 1900.0, 60.0 + f, 200.0 + f]]) for f in range(1, 6)}
    assert border_size(past) is None
    cut = {f: FrameBoxes(f, [1], [[3500.0 + 10 * f, 1900.0 - 200 * f, 140.0 - 10 * f, 148.0]])
           for f in range(1, 6)}  # people leaving by the right edge, one a frame
    assert border_size(cut) == (3640, 2048)
    assert hor_size_note("h.txt", cut, (3640, 2048), UNKNOWN) == (
        "h.txt: its images taken as 3640x2048 on this path, where its boxes are cut by the "
        "image's borders (give --image-size WxH if not)")


@pytest.mark.parametrize(("box", "ok"), [
    ("1380,700,60,100", True),     # 41 px past the right border of 1399: within 10%
    ("1500,300,60,100", False),    # past the border by 161 px > 139.9
    ("-100,300,60,100", False),    # entirely left of the image
    ("-130,300,200,100", True),    # 130 px past the left border, but inside by 70 px
])
def test_a_box_outside_the_stated_image_is_an_error_naming_the_line(tmp_path, capsys, box, ok):
    top, hor = tmp_path / "top.txt", tmp_path / "hor.txt"
    top.write_text("1,1,10,10,20,40\n1,2,60,10,20,40\n")
    hor.write_text(f"1,1,100,200,50,120\n1,2,{box}\n")
    code, err = _run(capsys, "associate", "--top", str(top), "--hor", str(hor), "--out",
                     str(tmp_path / "p.csv"), "--image-size", "1399x787", "--quiet")
    if ok:
        assert code == 0, err
        return
    assert code == 2 and err.count("\n") == 1, err
    assert f"{hor}:2: frame 1: box of id 2" in err and "outside the 1399x787 image" in err


@pytest.mark.cvmhat
def test_a_cvmhat_pair_at_two_resolutions(cvmhat_dir, tmp_path, capsys):
    """A real CVMHAT dev pair (its first 40 frames), the horizontal boxes scaled to 1399x787
    and to half size: refused without --image-size, the original's pairs with it."""
    name = "V0-S_canteen_0-G_1"
    top = {f: r for f, r in read_mot_boxes(cvmhat_dir / f"{name}_top.txt",
                                           duplicates="first").items() if f <= 40}
    hor = {f: r for f, r in read_mot_boxes(cvmhat_dir / f"{name}_hor.txt",
                                           duplicates="first").items() if f <= 40}
    write_mot_boxes(tmp_path / "top.txt", top)
    write_mot_boxes(tmp_path / "hor.txt", hor)
    code, err = _run(capsys, "associate", "--top", str(tmp_path / "top.txt"), "--hor",
                     str(tmp_path / "hor.txt"), "--out", str(tmp_path / "full.csv"), "--quiet")
    assert code == 0, err
    full = read_predictions(tmp_path / "full.csv")
    for size, factor in SIZES.items():
        path = tmp_path / f"hor_{size}.txt"
        write_mot_boxes(path, scale_frames(hor, factor))
        argv = ["associate", "--top", str(tmp_path / "top.txt"), "--hor", str(path), "--out",
                str(tmp_path / f"{size}.csv"), "--quiet"]
        code, err = _run(capsys, *argv)
        assert code == 2 and "--image-size" in err, err
        code, err = _run(capsys, *argv, "--image-size", size)
        assert code == 0, err
        assert read_predictions(tmp_path / f"{size}.csv") == full
    assert sum(len(p) for p in full.values()) > 0


def test_noise_places_false_boxes_in_the_horizontal_image(boxes, tmp_path, capsys):
    """``noise --view hor`` takes the size by the same rule: its false boxes land inside the
    user's 1399x787 image, so that associate accepts the noisy file."""
    top, hor = boxes["1399x787"]
    out = tmp_path / "noisy.txt"
    code, err = _run(capsys, "noise", "--boxes", str(hor), "--view", "hor", "--out", str(out))
    assert code == 2 and "--image-size" in err and not out.exists(), err
    code, err = _run(capsys, "noise", "--boxes", str(hor), "--view", "hor", "--out", str(out),
                     "--image-size", "1399x787", "--false", "3")
    assert code == 0, err
    noisy = read_mot_boxes(out)
    assert any(i >= 2_000_000 for rec in noisy.values() for i in rec.ids)  # false boxes
    code, err = _run(capsys, "associate", "--top", str(top), "--hor", str(out), "--out",
                     str(tmp_path / "p.csv"), "--image-size", "1399x787", "--quiet")
    assert code == 0, err


def test_borders_a_few_pixels_short_of_a_common_size_are_that_size():
    """Hand annotations stopping short of the border (CVMHAT's: boxes cut at x 2682 and
    y 1507 of its 2688x1512 frames) read as the common size within 1% of them."""
    boxes = np.array([[2500.0, 300.0, 2682.0, 900.0], [2400.0, 800.0, 2682.0, 1300.0],
                      [2600.0, 100.0, 2682.0, 500.0], [100.0, 900.0, 400.0, 1507.0],
                      [900.0, 700.0, 1200.0, 1507.0], [1600.0, 1000.0, 1900.0, 1507.0]])
    assert border_size(_clipped(boxes, (2682, 1507))) == CVMHAT_SIZE


def _spilled(size: tuple[int, int], seed: int) -> dict:
    """A clip's boxes in a ``size`` image as trackers give them: people inside, one leaving by
    the left border and three passers-by cut by the bottom one, whose boxes run on past them
    (one 1.9 times the image's height past its foot)."""
    width, height = size
    rng = np.random.default_rng(seed)
    x0 = rng.uniform(0.05, 0.9, 12) * width
    y0 = rng.uniform(0.05, 0.6, 12) * height
    boxes = np.column_stack([x0, y0, np.full(12, 0.04 * width), np.full(12, 0.2 * height)])
    run_on = [[-0.03 * width, 0.3 * height, 0.05 * width, 0.25 * height],
              [0.2 * width, 0.8 * height, 0.2 * width, 1.9 * height],
              [0.5 * width, 0.7 * height, 0.1 * width, 0.5 * height],
              [0.96 * width, 0.75 * height, 0.08 * width, 0.3 * height]]
    return {k: FrameBoxes(k, [k], [box]) for k, box in enumerate([*boxes, *run_on], start=1)}


@pytest.mark.parametrize("size", [(1280, 720), (1920, 1080), (3840, 2160)])
def test_boxes_running_past_the_borders_start_inside_the_image(size):
    """Boxes that run on past the borders (a tracker's; one starts well before the left
    border, which no image size explains) tell the smallest common size they all start inside,
    not the larger one holding them; clipped boxes, and hand annotations a few pixels before
    the border (CVMHAT's -4 for a person 38 px wide), are read as before."""
    spilled = _spilled(size, 0)
    assert runs_past_borders(spilled)
    assert common_size_holding(spilled) != size
    assert common_size_started(spilled) == size
    assert guess_image_size(spilled) == size
    assert "start inside" in size_guess_how(spilled, size)
    clipped = {f: FrameBoxes(f, r.ids, np.column_stack([
        np.clip(r.boxes[:, :2], 0, size), np.clip(r.boxes[:, :2] + r.boxes[:, 2:], 0, size)
        - np.clip(r.boxes[:, :2], 0, size)])) for f, r in spilled.items()}
    assert not runs_past_borders(clipped)
    sloppy = {1: FrameBoxes(1, [1, 2], [[-4.0, 536.0, 38.0, 153.0], [500.0, -3.0, 20.0, 60.0]])}
    assert not runs_past_borders(sloppy)
    far = {1: FrameBoxes(1, [1], [[-5.4, 441.4, 12.4, 31.7]])}  # a small, far person leaving
    assert runs_past_borders(far)
    cut = {f: FrameBoxes(f, [f], [[3500.0 + 10 * f, 1900.0 - 200 * f, 140.0 - 10 * f, 148.0]])
           for f in range(1, 6)}  # people leaving by the right edge, clipped there
    cut[6] = FrameBoxes(6, [6], [[-30.0, 500.0, 100.0, 300.0]])  # one box before the left
    assert runs_past_borders(cut) and guess_image_size(cut) == (3640, 2048)  # borders first


@settings(max_examples=60, deadline=None)
@given(size=st.sampled_from(COMMON_SIZES), seed=st.integers(0, 2**31 - 1))
def test_boxes_running_past_any_common_size_tell_it(size, seed):
    """Any common size: boxes starting anywhere in it and running on past its borders by up to
    twice their size (one leaving by the left, one starting in its last pixels, the corner)
    show their convention and give the size; the same boxes clipped to it show none."""
    width, height = size
    rng = np.random.default_rng(seed)
    x0, y0 = rng.uniform(0.0, width, 20), rng.uniform(0.0, height, 20)
    w, h = rng.uniform(0.01, 0.1, 20) * width, rng.uniform(0.02, 0.3, 20) * height
    w, h = w * rng.uniform(1.0, 3.0, 20), h * rng.uniform(1.0, 3.0, 20)
    x0[0], y0[1] = -0.5 * w[0], rng.uniform(0.995, 1.0) * height - 1e-6
    x0[1] = rng.uniform(0.995, 1.0) * width - 1e-6
    boxes = np.column_stack([x0, y0, w, h])
    spilled = {k: FrameBoxes(k, [k], [box]) for k, box in enumerate(boxes, start=1)}
    assert runs_past_borders(spilled)
    assert guess_image_size(spilled) == size
    corners = np.column_stack([x0, y0, x0 + w, y0 + h])
    assert not runs_past_borders(_clipped(corners, size))


def test_boxes_running_past_the_borders_are_no_error_while_inside_it(tmp_path, capsys):
    """Rule 3 for boxes that run on past the borders: a passer-by's box 1.9 times the image's
    height past its foot is accepted with the right ``--image-size``, a box entirely outside is
    still an error naming its line; in a clipped file the passer-by's box is an error, unless
    the run's other file shows its boxes run on past the borders."""
    top, hor = tmp_path / "top.txt", tmp_path / "hor.txt"
    top.write_text("1,1,10,10,20,40\n1,2,60,10,20,40\n")
    spilled = _spilled((1920, 1080), 1)
    write_mot_boxes(hor, spilled)
    argv = ["associate", "--top", str(top), "--hor", str(hor), "--out", str(tmp_path / "p.csv"),
            "--image-size", "1920x1080", "--quiet"]
    code, err = _run(capsys, *argv)
    assert code == 0, err
    outside = dict(spilled)
    outside[99] = FrameBoxes(99, [99], [[1930.0, 300.0, 60.0, 150.0]])
    write_mot_boxes(hor, outside)
    code, err = _run(capsys, *argv)
    assert code == 2 and f"{hor}:" in err and "frame 99" in err, err
    inside = {f: r for f, r in spilled.items() if r.boxes[0, 0] >= 0}  # nobody leaving by the left
    write_mot_boxes(hor, inside)
    code, err = _run(capsys, *argv)
    assert code == 2 and "outside the 1920x1080 image" in err and "clip them" in err, err
    top.write_text("1,1,-30,10,60,40\n1,2,60,10,20,40\n")  # the run's other file shows it
    code, err = _run(capsys, *argv)
    assert code == 0, err


def test_a_runs_files_share_whether_their_boxes_run_past_the_borders():
    """A handheld view whose boxes run past its lowest border only shows no sign of it (read
    as a larger image's, the one holding them); told by the run's other file (``past``), its
    size is the one its boxes start inside, said so, and its boxes past the border are no
    error with the size given."""
    spilled = _spilled((1920, 1080), 2)
    lower = {f: r for f, r in spilled.items() if r.boxes[0, 0] >= 0}  # nobody leaving left
    assert not runs_past_borders(lower) and runs_past_borders(spilled, lower)
    assert resolve_size(lower, "h.txt", [], defer=True)[0] != (1920, 1080)
    assert resolve_size(lower, "h.txt", [], defer=True, past=True) == ((1920, 1080), UNKNOWN)
    assert "run on past the borders" in hor_size_note("h.txt", lower, (1920, 1080), UNKNOWN,
                                                      past=True)
    given = [((1920, 1080), "--image-size")]
    with pytest.raises(ValueError, match="clip them"):
        resolve_size(lower, "h.txt", given)
    assert resolve_size(lower, "h.txt", given, past=True) == ((1920, 1080), "--image-size")
