"""``xvmatch track`` and ``xvmatch evaluate --tracks`` end to end, on a small synthetic scene."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from xvmatch.cli import main
from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene
from xvmatch.formats.mot_boxes import FrameBoxes, read_mot_boxes, write_mot_boxes


def _track(files, out: Path, *extra: str) -> int:
    return main(["track", "--top", str(files["det_top"]), "--hor", str(files["det_hor"]),
                 "--out", str(out), "--quiet", *extra])


def test_track_writes_the_input_rows_with_track_ids(track_files, tmp_path):
    out = tmp_path / "tracks"
    assert _track(track_files, out) == 0
    for view in ("top", "hor"):
        det = track_files[f"det_{view}"].read_text().splitlines()
        written = (out / f"{view}.txt").read_text().splitlines()
        assert len(written) == len(det)  # ground-truth boxes: no row is dropped
        strip = [ln.split(",", 2)[::2] for ln in written]
        assert strip == [ln.split(",", 2)[::2] for ln in det]  # same text but the id
        frames = read_mot_boxes(out / f"{view}.txt")  # one box per track id and frame
        assert all(len(r) for r in frames.values())


def test_evaluate_tracks_scores_them(track_files, tmp_path, capsys):
    out = tmp_path / "tracks"
    assert _track(track_files, out) == 0
    capsys.readouterr()
    argv = ["evaluate", "--tracks", str(out), "--top", str(track_files["gt_top"]), "--hor",
            str(track_files["gt_hor"]), "--json"]
    assert main(argv) == 0
    scores = json.loads(capsys.readouterr().out)
    assert scores["top"]["idf1"] > 90 and scores["top"]["mota"] > 99
    assert scores["top"]["motp"] == pytest.approx(100.0)  # the boxes are the ground truth's
    assert scores["cross_view"]["cvidp"] > 80
    assert main(argv[:-1]) == 0
    assert "CVIDF1" in capsys.readouterr().out


def test_evaluate_tracks_with_an_empty_view_scores_it_as_missed(track_files, tmp_path, capsys):
    # A tracker that kept no horizontal track wrote an empty hor.txt: a poor result to score,
    # not a bad input file.
    folder = tmp_path / "no_hor"
    folder.mkdir()
    (folder / "top.txt").write_text(track_files["gt_top"].read_text())
    (folder / "hor.txt").write_text("")
    assert main(["evaluate", "--tracks", str(folder), "--top", str(track_files["gt_top"]),
                 "--hor", str(track_files["gt_hor"]), "--json"]) == 0
    scores = json.loads(capsys.readouterr().out)
    assert scores["cross_view"]["cvidr"] == pytest.approx(0.0)
    assert scores["top"]["idf1"] == pytest.approx(100.0)


def test_evaluate_the_ground_truth_as_tracks_is_perfect(track_files, tmp_path, capsys):
    folder = tmp_path / "perfect"
    folder.mkdir()
    (folder / "top.txt").write_text(track_files["gt_top"].read_text())
    (folder / "hor.txt").write_text(track_files["gt_hor"].read_text())
    assert main(["evaluate", "--tracks", str(folder), "--top", str(track_files["gt_top"]),
                 "--hor", str(track_files["gt_hor"]), "--json"]) == 0
    scores = json.loads(capsys.readouterr().out)
    for key in ("cvidp", "cvidr", "cvidf1", "cvma"):
        assert scores["cross_view"][key] == pytest.approx(100.0)
    for view in ("top", "hor"):
        for key in ("idf1", "mota", "motp", "hota"):
            assert scores[view][key] == pytest.approx(100.0)


def test_spectral_and_camera_id(track_files, tmp_path):
    det_top = track_files["det_top"]
    # Give the wearer (ground-truth id 0) its id back in the detection file.
    gt = {ln.split(",", 2)[2]: ln.split(",")[1]
          for ln in track_files["gt_top"].read_text().splitlines()}
    lines = [ln.replace(",-1,", ",0,", 1) if gt[ln.split(",", 2)[2]] == "0" else ln
             for ln in det_top.read_text().splitlines()]
    with_wearer = tmp_path / "top_wearer.txt"
    with_wearer.write_text("\n".join(lines) + "\n")
    files = {**track_files, "det_top": with_wearer}
    assert _track(files, tmp_path / "a", "--camera-id", "0") == 0
    assert _track(track_files, tmp_path / "b", "--solver", "spectral", "--seed", "3") == 0


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--camera-id", "12345"], "no box has the --camera-id 12345"),
        (["--top", "/nonexistent/top.txt"], "no such file"),
    ],
)
def test_track_errors_are_one_line(track_files, tmp_path, capsys, extra, message):
    assert _track(track_files, tmp_path / "x", *extra) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("xvmatch: error:") and message in err[0]


def test_track_out_must_be_a_folder(track_files, tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert _track(track_files, blocker) == 2
    assert "not a folder" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("flag", "value"),
    [("--clip-length", "0"), ("--clip-length", "1001"), ("--max-gap", "-1"),
     ("--min-iou", "0"), ("--c0", "1.5"),
     ("--sigma", "0"), ("--time-limit", "0"), ("--time-limit", "nan"), ("--workers", "65"),
     ("--seed", "-1"), ("--image-size", "4x4"), ("--w1", "1.5"), ("--w2", "-0.1"),
     ("--min-colour", "2")],
)
def test_track_numeric_options_are_bounded(track_files, tmp_path, capsys, flag, value):
    with pytest.raises(SystemExit) as exc:
        _track(track_files, tmp_path / "x", flag, value)
    assert exc.value.code == 2
    assert f"argument {flag}" in capsys.readouterr().err


def test_evaluate_needs_pred_or_tracks(track_files, tmp_path, capsys):
    base = ["evaluate", "--top", str(track_files["gt_top"]), "--hor", str(track_files["gt_hor"])]
    with pytest.raises(SystemExit):
        main(base)
    assert "one of the arguments --pred --tracks" in capsys.readouterr().err
    assert main([*base, "--tracks", str(tmp_path / "missing")]) == 2
    assert "not a folder" in capsys.readouterr().err


@pytest.mark.slow
def test_track_output_does_not_depend_on_workers(track_files, tmp_path):
    assert _track(track_files, tmp_path / "one") == 0
    assert _track(track_files, tmp_path / "two", "--workers", "2") == 0
    for view in ("top.txt", "hor.txt"):
        assert (tmp_path / "one" / view).read_bytes() == (tmp_path / "two" / view).read_bytes()


@pytest.fixture(scope="module")
def video_files(tmp_path_factory) -> dict[str, Path]:
    """A tiny rendered clip: ground-truth files, detection files (ids -1) and image folders."""
    from xvmatch.datasets.tracking_video import render_tracking_video, write_tracking_video

    folder = tmp_path_factory.mktemp("track_video")
    out = write_tracking_video(render_tracking_video(2, n_frames=20), folder)
    files = {"folder": folder, "top_images": out["top_images"], "hor_images": out["hor_images"]}
    for view in ("top", "hor"):
        lines = out[view].read_text().splitlines()
        det = [",".join([ln.split(",")[0], "-1", *ln.split(",")[2:]]) for ln in lines]
        (folder / f"det_{view}.txt").write_text("\n".join(det) + "\n")
        files[f"gt_{view}"], files[f"det_{view}"] = out[view], folder / f"det_{view}.txt"
    return files


def _track_video(files, out: Path, *extra: str) -> int:
    return _track(files, out, "--top-images", str(files["top_images"]),
                  "--hor-images", str(files["hor_images"]), *extra)


@pytest.mark.slow
def test_track_with_images_end_to_end(video_files, tmp_path, capsys):
    out = tmp_path / "tracks"
    assert _track_video(video_files, out, "--model", "default") == 0
    for view in ("top", "hor"):
        det = video_files[f"det_{view}"].read_text().splitlines()
        written = (out / f"{view}.txt").read_text().splitlines()
        assert [ln.split(",", 2)[::2] for ln in written] == [ln.split(",", 2)[::2] for ln in det]
    capsys.readouterr()
    assert main(["evaluate", "--tracks", str(out), "--top", str(video_files["gt_top"]),
                 "--hor", str(video_files["gt_hor"]), "--json"]) == 0
    scores = json.loads(capsys.readouterr().out)
    assert scores["cross_view"]["cvidf1"] > 80 and scores["top"]["idf1"] > 80
    # Colour terms only (no network), and colour over time with the network: both run.
    assert _track_video(video_files, tmp_path / "colour") == 0
    assert _track_video(video_files, tmp_path / "net", "--model", "default",
                        "--time-appearance", "colour", "--w1", "0.5", "--w2", "0.5",
                        "--min-colour", "0.2") == 0


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--top-images", "IMAGES"], "give --top-images and --hor-images together"),
        (["--model", "default", "--weights", "handcrafted"], "needs the images"),
        (["--top-images", "IMAGES", "--hor-images", "IMAGES", "--image-size", "320x180"],
         "disagrees with the horizontal images"),
        (["--top-images", "IMAGES", "--hor-images", "/nonexistent/hor"], "no such file"),
    ],
)
def test_track_image_errors_are_one_line(video_files, tmp_path, capsys, extra, message):
    extra = [str(video_files["top_images"]) if e == "IMAGES" else e for e in extra]
    argv = ["track", "--top", str(video_files["det_top"]), "--hor", str(video_files["det_hor"]),
            "--out", str(tmp_path / "x"), "--quiet", *extra]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("xvmatch: error:") and message in err[0], err


def test_track_help_states_the_library_defaults(capsys):
    from xvmatch.inference.tracks.track_costs import TrackWeights
    from xvmatch.inference.tracks.tracking import TrackConfig

    with pytest.raises(SystemExit):
        main(["track", "--help"])
    options = " ".join(capsys.readouterr().out.split()).split("options:", 1)[1]
    w, c = TrackWeights(), TrackConfig()
    for flag, value in (("--c0", w.c0), ("--sigma", w.sigma), ("--w1", w.w1), ("--w2", w.w2),
                        ("--min-colour", c.min_colour)):
        assert f"(default {value:g}" in options.split(f" {flag} ", 1)[1].split(" --", 1)[0], flag


def _columns(path: Path, frame_shift: int = 0) -> list[tuple[int, str, str]]:
    """(frame - frame_shift, track id, the rest of the row) of each row of a track file."""
    rows = [ln.split(",", 2) for ln in path.read_text().splitlines()]
    return [(int(f) - frame_shift, i, rest) for f, i, rest in rows]


@pytest.mark.slow
def test_track_with_an_offset_tracks_as_if_the_videos_were_in_sync(tmp_path, capsys):
    # The idealised walk of test_associate_with_an_offset_re_times_the_top_view: horizontal
    # frames renumbered by 8, so top frame = horizontal frame - 8. Tracked with --offset auto
    # (which finds -8) the pair is the synchronised one renumbered as a whole: the same tracks,
    # written in each file's own frame numbers, and the same scores with evaluate --tracks
    # --offset -8.
    config = SceneConfig(fps=5.0, height_range=(1.7, 1.7), hor_wobble_deg=0.0)
    scene = simulate_box_scene(config, n_frames=60, seed=3)
    files = {v: tmp_path / f"{v}.txt" for v in ("top", "hor", "late_hor")}
    write_mot_boxes(files["top"], scene.top)
    write_mot_boxes(files["hor"], scene.hor)
    write_mot_boxes(files["late_hor"], {f + 8: FrameBoxes(f + 8, r.ids, r.boxes)
                                        for f, r in scene.hor.items()})
    # O given; the spectral solver: this walk's windows are slow for the MIP (time limits)
    base = ["track", "--top", str(files["top"]), "--camera-id", "0", "--solver", "spectral"]
    assert main([*base, "--hor", str(files["hor"]), "--out", str(tmp_path / "sync"),
                 "--quiet"]) == 0
    # auto is track's default; --offset 0 keeps the files' timing.
    for tag, extra in [("auto", ["--offset", "auto", "--max-offset", "10", "--workers", "2"]),
                       ("default", ["--max-offset", "10", "--quiet"]),
                       ("none", ["--offset", "0", "--quiet"])]:
        out = tmp_path / tag
        assert main([*base, "--hor", str(files["late_hor"]), "--out", str(out), *extra]) == 0
        if tag == "auto":
            assert "estimated offset -8 frames" in capsys.readouterr().err
        same = (_columns(out / "top.txt") == _columns(tmp_path / "sync" / "top.txt")
                and _columns(out / "hor.txt", 8) == _columns(tmp_path / "sync" / "hor.txt"))
        assert same == (tag != "none"), tag
        # The offset applied is written beside the tracks.
        recorded = json.loads((out / "offset.json").read_text())
        assert recorded == {"offset": 0 if tag == "none" else -8}
    capsys.readouterr()
    scores = []
    for folder, hor, extra in [("sync", "hor", []), ("auto", "late_hor", ["--offset", "-8"]),
                               ("auto", "late_hor", []), ("auto", "late_hor", ["--offset", "0"])]:
        assert main(["evaluate", "--tracks", str(tmp_path / folder), "--top", str(files["top"]),
                     "--hor", str(files[hor]), "--json", *extra]) == 0
        scores.append(json.loads(capsys.readouterr().out)["cross_view"])
    assert scores[1] == scores[0]
    assert scores[2] == scores[0]  # without --offset: the one track recorded
    assert scores[3] != scores[0], scores  # scored out of sync


def test_track_on_videos_too_short_for_the_sync_check_says_so(track_files, tmp_path, capsys):
    # 30 frames: with the default --max-offset 60 one clip fits, so auto (the default) keeps
    # the files' timing without a search, and says why.
    out = tmp_path / "tracks"
    argv = ["track", "--top", str(track_files["det_top"]), "--hor", str(track_files["det_hor"]),
            "--out", str(out)]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "videos too short for --offset auto to check their sync with --max-offset 60" in err
    assert "estimated offset" not in err
    assert json.loads((out / "offset.json").read_text()) == {"offset": 0}


@pytest.mark.slow
@pytest.mark.parametrize("record", ['{"offset": "soon"}', "{", '{"shift": 3}', '{"offset": true}'])
def test_evaluate_tracks_refuses_a_broken_offset_record(track_files, tmp_path, capsys, record):
    out = tmp_path / "tracks"
    assert _track(track_files, out) == 0
    (out / "offset.json").write_text(record)
    argv = ["evaluate", "--tracks", str(out), "--top", str(track_files["gt_top"]), "--hor",
            str(track_files["gt_hor"])]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{out / 'offset.json'}:" in err[0] and "--offset N" in err[0], err
    assert main([*argv, "--offset", "0"]) == 0  # a given offset does not read it


@pytest.mark.slow
def test_track_with_an_offset_re_times_the_images(video_files, tmp_path):
    # The rendered clip with its top view (boxes and image files) 5 frames later: top frame =
    # horizontal frame + 5. With --offset 5 and the network, the tracks are those of the clip.
    late = tmp_path / "late_top"
    late.mkdir()
    for image in sorted(Path(video_files["top_images"]).iterdir()):
        frame = int("".join(c for c in image.stem if c.isdigit()))
        (late / f"{frame + 5:06d}{image.suffix}").write_bytes(image.read_bytes())
    rows = video_files["det_top"].read_text().splitlines()
    late_top = tmp_path / "late_top.txt"
    late_top.write_text("\n".join(f"{int(ln.split(',', 1)[0]) + 5},{ln.split(',', 1)[1]}"
                                   for ln in rows) + "\n")
    # A generous MIP time limit: both runs solve every window, whatever the CPU's speed.
    assert _track_video(video_files, tmp_path / "sync", "--model", "default",
                        "--time-limit", "600") == 0
    assert main(["track", "--top", str(late_top), "--hor", str(video_files["det_hor"]),
                 "--top-images", str(late), "--hor-images", str(video_files["hor_images"]),
                 "--model", "default", "--offset", "5", "--time-limit", "600",
                 "--out", str(tmp_path / "late"),
                 "--quiet"]) == 0
    assert _columns(tmp_path / "late" / "top.txt", 5) == _columns(tmp_path / "sync" / "top.txt")
    assert _columns(tmp_path / "late" / "hor.txt") == _columns(tmp_path / "sync" / "hor.txt")
