"""``xvmatch track`` as a user of MOT tools expects it (issue 69, item 10): the detector's score
column (``--min-score``), 0-based frames (``--first-frame 0``), and pictures of the pairs it
found (``--draw DIR``, ``--draw-video FILE.mp4``), on a blank canvas with boxes only or on the
images, coloured right and wrong with ``--draw-truth`` (the files' ids as ground truth) and the
camera wearer marked; ``--offset``'s help in three lines at most."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from xvmatch.cli import main
from xvmatch.core.folder_marker import MARKER
from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene
from xvmatch.formats.mot_boxes import write_mot_boxes
from xvmatch.viz.box_canvas import CANVAS_COLOUR
from xvmatch.viz.match_drawing import RIGHT_COLOUR, WEARER_COLOUR, WRONG_COLOUR, pair_colour

IMAGE_COLOUR = (70, 110, 90)
"""BGR colour of the test's blank images, far from every pair's colour (those are saturated and
bright)."""


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> dict[str, Path]:
    """A 6-frame box scene whose people walk as in a video (10 top boxes, the wearer id 0
    among them; 6 horizontal), its files' ids the ground truth."""
    folder = tmp_path_factory.mktemp("track_draw")
    boxes = simulate_box_scene(SceneConfig(head_turn_std_deg=2.0), n_frames=6, seed=5)
    out = {"frames": {"top": boxes.top, "hor": boxes.hor}}
    for view in ("top", "hor"):
        out[view] = folder / f"{view}.txt"
        write_mot_boxes(out[view], out["frames"][view])
    return out


def _images(scene: dict, folder: Path) -> dict[str, Path]:
    """Blank images of :data:`IMAGE_COLOUR` for each frame of each view (top 1920x1440,
    horizontal 2688x1512), in a folder per view."""
    out = {}
    for view, size in (("top", (1920, 1440)), ("hor", (2688, 1512))):
        out[view] = folder / f"{view}_images"
        out[view].mkdir()
        picture = np.empty((size[1], size[0], 3), np.uint8)
        picture[:] = IMAGE_COLOUR
        for f in scene["frames"][view]:
            cv2.imwrite(str(out[view] / f"frame_{f:06d}.png"), picture)
    return out


def _track(scene: dict[str, Path], out: Path, *extra: str) -> int:
    return main(["track", "--top", str(scene["top"]), "--hor", str(scene["hor"]), "--out",
                 str(out), "--offset", "0", "--image-size", "2688x1512", "--quiet", *extra])


def _near(picture: np.ndarray, colour: tuple[int, int, int], tol: int = 30) -> int:
    """Pixels of ``picture`` (below its title strip) within ``tol`` of the BGR ``colour``."""
    low = np.clip(np.array(colour) - tol, 0, 255).astype(np.uint8)
    high = np.clip(np.array(colour) + tol, 0, 255).astype(np.uint8)
    return int(cv2.countNonZero(cv2.inRange(picture[30:], low, high)))


@pytest.fixture(scope="module")
def drawn(scene, tmp_path_factory) -> Path:
    """One run with boxes only: --draw, --draw-video and --draw-truth with the wearer's id."""
    folder = tmp_path_factory.mktemp("drawn")
    code = _track(scene, folder / "tracks", "--draw", str(folder / "pictures"), "--draw-every",
                  "2", "--draw-video", str(folder / "pairs.mp4"), "--draw-truth", "--camera-id",
                  "0")
    assert code == 0
    return folder


def test_track_draws_every_kth_frame_on_a_blank_canvas(drawn):
    names = sorted(p.name for p in (drawn / "pictures").iterdir())
    assert names == [MARKER, "frame_000001.jpg", "frame_000003.jpg", "frame_000005.jpg"]
    assert sorted(p.name for p in drawn.iterdir()) == ["pairs.mp4", "pictures", "tracks"]
    picture = cv2.imread(str(drawn / "pictures" / "frame_000003.jpg"))
    assert _near(picture, CANVAS_COLOUR, 8) > picture.size // 6  # no image: a blank canvas


def test_draw_truth_colours_the_pairs_green_and_marks_the_wearer(drawn):
    picture = cv2.imread(str(drawn / "pictures" / "frame_000001.jpg"))
    assert _near(picture, RIGHT_COLOUR) > 200  # ground-truth boxes: the pairs are right
    assert _near(picture, WRONG_COLOUR, 20) == 0
    assert _near(picture, pair_colour(0), 20) == 0  # not the colours of pairs without truth
    assert _near(picture, WEARER_COLOUR, 10) > 20  # the wearer's white outline and label


def test_draw_video_holds_the_same_pictures(drawn):
    video = cv2.VideoCapture(str(drawn / "pairs.mp4"))
    frames = []
    while True:
        ok, frame = video.read()
        if not ok:
            break
        frames.append(frame)
    video.release()
    assert len(frames) == 3
    first = cv2.imread(str(drawn / "pictures" / "frame_000001.jpg"))
    h, w = first.shape[:2]
    assert frames[0].shape[:2] == (h + h % 2, w + w % 2)
    assert cv2.absdiff(frames[0][:h, :w], first).mean() < 8


@pytest.mark.slow
def test_track_draws_on_the_images_when_given(scene, tmp_path):
    images = _images(scene, tmp_path)
    code = _track(scene, tmp_path / "tracks", "--top-images", str(images["top"]),
                  "--hor-images", str(images["hor"]), "--draw", str(tmp_path / "pictures"),
                  "--draw-every", "6", "--no-labels")
    assert code == 0
    picture = cv2.imread(str(tmp_path / "pictures" / "frame_000001.jpg"))
    assert _near(picture, IMAGE_COLOUR) > picture.size // 6  # mostly the images
    tracks = {int(ln.split(",")[1]) for ln in (tmp_path / "tracks" / "hor.txt").read_text()
              .splitlines() if ln.startswith("1,")}
    drawn = [t for t in tracks if _near(picture, pair_colour(t)) > 50]
    assert len(drawn) >= 3  # each pair in its track's colour, without truth


def test_draw_video_must_be_an_mp4_file_refused_before_any_work(scene, tmp_path, capsys):
    assert _track(scene, tmp_path / "tracks", "--draw-video", str(tmp_path / "pairs.avi")) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("xvmatch: error: --draw-video"), err
    assert not (tmp_path / "tracks").exists()


def test_track_reads_detector_scores_and_frames_from_zero(scene, tmp_path, capsys):
    # The ground truth as a detector's file: frames from 0, a score column; the weak rows
    # (score 0.2) are dropped, the others tracked and written with the file's own frames.
    rows = []
    for k, line in enumerate(scene["top"].read_text().splitlines()):
        fields = line.split(",")
        fields[0] = str(int(fields[0]) - 1)
        fields[6] = "0.2" if k % 5 == 0 else "0.9"
        rows.append(",".join(fields))
    hor = tmp_path / "det_hor.txt"
    hor.write_text("".join(f"{int(f) - 1},{i},{x},{y},{w},{h},0.9\n" for f, i, x, y, w, h, *_
                           in (ln.split(",") for ln in scene["hor"].read_text().splitlines())))
    top = tmp_path / "det_top.txt"
    top.write_text("frame,id,x,y,w,h,conf,x,y,z\n" + "\n".join(rows) + "\n")
    capsys.readouterr()
    code = main(["track", "--top", str(top), "--hor", str(hor), "--out",
                 str(tmp_path / "tracks"), "--offset", "0", "--image-size", "2688x1512",
                 "--min-score", "0.5", "--first-frame", "0"])
    err = capsys.readouterr().err
    assert code == 0, err
    notes = [ln for ln in err.splitlines() if ln.startswith("xvmatch: note: ")]
    assert any("header" in ln for ln in notes) and any("0.5" in ln for ln in notes), err
    written = (tmp_path / "tracks" / "top.txt").read_text().splitlines()
    kept = [r for k, r in enumerate(rows) if k % 5]
    assert len(written) == len(kept)
    assert sorted(ln.split(",", 2)[::2] for ln in written) == sorted(
        ln.split(",", 2)[::2] for ln in kept)  # the file's text (frames from 0) but the id
    assert min(int(ln.split(",")[0]) for ln in written) == 0


@pytest.mark.parametrize("command", ["associate", "track"])
def test_offset_help_is_three_lines_at_most(command, capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = capsys.readouterr().out
    lines = text.split("  --offset N|auto", 1)[1].split("  --max-offset", 1)[0].splitlines()
    assert len(lines) <= 3, lines
    assert "|N| <= 100000" in " ".join(" ".join(lines).split())


def test_track_draws_each_moment_under_its_horizontal_frame_with_an_offset(scene, tmp_path):
    # The horizontal file renumbered by 3 (top frame = horizontal frame - 3): the pictures are
    # named by the horizontal frames and pair the boxes of the same moment (all right).
    hor = tmp_path / "late_hor.txt"
    hor.write_text("".join(f"{int(ln.split(',', 1)[0]) + 3},{ln.split(',', 1)[1]}\n"
                           for ln in scene["hor"].read_text().splitlines()))
    code = main(["track", "--top", str(scene["top"]), "--hor", str(hor), "--out",
                 str(tmp_path / "tracks"), "--offset", "-3", "--image-size", "2688x1512",
                 "--quiet", "--draw", str(tmp_path / "pictures"), "--draw-every", "5",
                 "--draw-truth"])
    assert code == 0
    names = sorted(p.name for p in (tmp_path / "pictures").iterdir())
    assert names == [MARKER, "frame_000004.jpg", "frame_000009.jpg"]
    for name in names[1:]:
        picture = cv2.imread(str(tmp_path / "pictures" / name))
        assert _near(picture, RIGHT_COLOUR) > 200 and _near(picture, WRONG_COLOUR, 20) == 0
