"""Tests of the output-path checks (xvmatch.core.output_paths) and of every command's use
of them (issue 28): each refused output gives one line naming the option, exit code 2, before
any work, with no input, no FIFO and no foreign file changed and no partial output left."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from xvmatch.cli import main
from xvmatch.core.folder_marker import MARKER, is_own_folder
from xvmatch.core.output_paths import (
    Input,
    Output,
    OutputPathError,
    check_outputs,
    check_own_folder,
    check_script_outputs,
    claim_folder,
)
from xvmatch.datasets.box_scene import simulate_box_scene, write_box_scene
from xvmatch.formats.mot_boxes import read_mot_boxes, write_predictions

REPO = Path(__file__).resolve().parents[1]
IS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> dict[str, Path]:
    """A 6-frame simulated scene (``top``, ``hor``), its ground-truth pairs (``pred``) and a
    1-scene, 2-frame, 64x36 synthetic dataset (``dataset``)."""
    from xvmatch.datasets.synthetic_io import generate_dataset
    from xvmatch.datasets.synthetic_scenes import SynthConfig

    root = tmp_path_factory.mktemp("outputs")
    top, hor = write_box_scene(simulate_box_scene(n_frames=6, seed=1), root, "sim")
    t, h = read_mot_boxes(top), read_mot_boxes(hor)
    write_predictions(root / "pred.csv", {f: [(int(i), int(i)) for i in
                                              sorted(set(t[f].ids) & set(h[f].ids))]
                                          for f in sorted(set(t) & set(h))})
    config = SynthConfig(top_size=(64, 36), ego_size=(64, 36), n_people=(2, 3))
    generate_dataset(root / "dataset", config, n_scenes=1, n_frames=2, seed=0)
    return {"top": top, "hor": hor, "pred": root / "pred.csv", "dataset": root / "dataset"}


def _snapshot(folder: Path) -> dict[str, tuple[str, bytes | None]]:
    """Every entry under ``folder``: its kind and, for a regular file, its bytes."""
    out = {}
    for path in sorted(folder.rglob("*")):
        mode = path.lstat().st_mode
        kind = ("link" if stat.S_ISLNK(mode) else "fifo" if stat.S_ISFIFO(mode)
                else "dir" if stat.S_ISDIR(mode) else "file")
        out[str(path.relative_to(folder))] = (kind, path.read_bytes() if kind == "file"
                                              else None)
    return out


def _refused(capsys, argv: list[str], *words: str) -> str:
    """Run ``argv``: exit code 2 and one error line holding every word of ``words``."""
    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert out == ""
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("xvmatch: error: "), err
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


# --------------------------------------------------------------------------------------------
# the helper


def test_absent_and_regular_files_pass(tmp_path):
    (tmp_path / "old.csv").write_text("x\n")
    check_outputs([Output("--out", tmp_path / "new.csv"), Output("--costs", tmp_path / "old.csv"),
                   Output("--draw", tmp_path / "pictures", folder=True), Output("--x", None)])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.csv"]  # nothing created


def test_a_fifo_is_refused_and_left_alone(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with pytest.raises(OutputPathError, match=r"^--out .*pipe: is a FIFO, not a regular file"):
        check_outputs([Output("--out", fifo)])
    assert stat.S_ISFIFO(fifo.lstat().st_mode)


def test_a_symlink_to_a_fifo_is_refused(tmp_path):
    os.mkfifo(tmp_path / "pipe")
    (tmp_path / "link").symlink_to(tmp_path / "pipe")
    with pytest.raises(OutputPathError, match="is a FIFO"):
        check_outputs([Output("--out", tmp_path / "link")])


def test_a_device_is_refused():
    with pytest.raises(OutputPathError, match="is a character device"):
        check_outputs([Output("--out", "/dev/null")])


def test_a_folder_where_a_file_goes(tmp_path):
    with pytest.raises(OutputPathError, match=r"^--costs .*: is a folder; give a file name$"):
        check_outputs([Output("--costs", tmp_path)])


def test_a_file_where_a_folder_goes(tmp_path):
    (tmp_path / "f").write_text("mine\n")
    with pytest.raises(OutputPathError, match=r"^--draw .*f: exists and is not a folder$"):
        check_outputs([Output("--draw", tmp_path / "f", folder=True)])


def test_the_folder_must_exist(tmp_path):
    with pytest.raises(OutputPathError, match=r"the folder .*nowhere does not exist"):
        check_outputs([Output("--out", tmp_path / "nowhere" / "p.csv")])
    # a folder output is created with its parents: the nearest existing one must be a folder
    check_outputs([Output("--out", tmp_path / "a" / "b", folder=True)])
    (tmp_path / "file").write_text("")
    with pytest.raises(OutputPathError, match="is not a folder"):
        check_outputs([Output("--out", tmp_path / "file" / "b", folder=True)])


def test_a_file_whose_folder_the_command_creates(tmp_path):
    """``parents=True``: a missing folder passes if its nearest existing parent is a folder;
    an existing one is checked as for any file output (inputs included)."""
    check_outputs([Output("--out", tmp_path / "a" / "b" / "p.pt", parents=True)])
    assert list(tmp_path.iterdir()) == []  # nothing created
    (tmp_path / "file").write_text("")
    with pytest.raises(OutputPathError, match=r"^--out .*p.pt: cannot write: .*file is not a "):
        check_outputs([Output("--out", tmp_path / "file" / "b" / "p.pt", parents=True)])
    with pytest.raises(OutputPathError, match="is the input --base"):
        check_outputs([Output("--out", tmp_path / "file", parents=True)],
                      [Input("--base", tmp_path / "file")])


def test_a_script_refusal_is_its_parsers_usage_error(tmp_path, capsys):
    import argparse

    parser = argparse.ArgumentParser(prog="bench.py")
    with pytest.raises(SystemExit) as info:
        check_script_outputs(parser, [Output("--json", tmp_path)])
    assert info.value.code == 2
    lines = capsys.readouterr().err.splitlines()
    assert lines[-1].startswith("bench.py: error: --json ") and "is a folder" in lines[-1]
    check_script_outputs(parser, [Output("--json", tmp_path / "r.json")])  # passes quietly


@pytest.mark.skipif(IS_ROOT, reason="root may write into any folder")
def test_the_folder_must_be_writable(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    try:
        with pytest.raises(OutputPathError, match="is not writable"):
            check_outputs([Output("--out", locked / "p.csv")])
    finally:
        locked.chmod(0o700)


@pytest.mark.parametrize("how", ["same", "symlink", "hardlink"])
def test_an_output_that_is_an_input(tmp_path, how):
    src = tmp_path / "top.txt"
    src.write_text("1,1,0,0,1,1,-1,-1,-1,-1\n")
    out = {"same": src, "symlink": tmp_path / "l.txt", "hardlink": tmp_path / "h.txt"}[how]
    if how == "symlink":
        out.symlink_to(src)
    elif how == "hardlink":
        os.link(src, out)
    with pytest.raises(OutputPathError, match=r"^--out .*: is the input --top .*top.txt; "):
        check_outputs([Output("--out", out)], [Input("--top", src)])


def test_files_in_input_folders_and_globs(tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    (frames / "0001.png").write_bytes(b"x")
    for given in (frames, frames / "*.png"):
        inputs = [Input("--top-images", given)]
        with pytest.raises(OutputPathError,
                           match=r"(is the input|lies in the input folder) --top-images"):
            check_outputs([Output("--out", frames / "0001.png")], inputs)
        check_outputs([Output("--out", frames / "new.csv")], inputs)  # a new file is fine
        for draw in (frames, frames / "pictures"):
            with pytest.raises(OutputPathError, match="is or lies in the input folder"):
                check_outputs([Output("--draw", draw, folder=True)], inputs)
    with pytest.raises(OutputPathError, match=r"holds the input --top-images"):
        check_outputs([Output("--draw", tmp_path, folder=True)],
                      [Input("--top-images", frames / "*.png")])


def test_a_folder_output_holding_an_input(tmp_path):
    (tmp_path / "top.txt").write_text("")
    with pytest.raises(OutputPathError, match=r"^--out .*: holds the input --top"):
        check_outputs([Output("--out", tmp_path, folder=True, files=("top.txt",))],
                      [Input("--top", tmp_path / "top.txt")])


def test_the_files_of_a_folder_output(tmp_path):
    os.mkfifo(tmp_path / "hor.txt")
    with pytest.raises(OutputPathError, match=r"^--out .*hor.txt: is a FIFO"):
        check_outputs([Output("--out", tmp_path, folder=True, files=("top.txt", "hor.txt"))])


def test_two_outputs_on_one_path(tmp_path):
    with pytest.raises(OutputPathError, match=r"^--costs .*p.csv: is also --out .*p.csv; "):
        check_outputs([Output("--out", tmp_path / "p.csv"), Output("--costs", tmp_path / "p.csv")])
    (tmp_path / "link.csv").symlink_to(tmp_path / "p.csv")
    with pytest.raises(OutputPathError, match="is also --out"):
        check_outputs([Output("--out", tmp_path / "p.csv"),
                       Output("--costs", tmp_path / "link.csv")])
    (tmp_path / "d").mkdir()
    with pytest.raises(OutputPathError, match="is also --out"):
        check_outputs([Output("--out", tmp_path / "d" / "top.txt"),
                       Output("--tracks", tmp_path / "d", folder=True, files=("top.txt",))])


def test_inputs_that_are_not_paths_are_skipped(tmp_path):
    check_outputs([Output("--out", tmp_path / "p.csv")],
                  [Input("--model", "default"), Input("--images", None),
                   Input("--top-images", tmp_path / "none_*.jpg")])


def test_claim_folder_takes_only_new_empty_or_own_folders(tmp_path):
    new = claim_folder(tmp_path / "new", "xvmatch demo")
    assert json.loads((new / MARKER).read_text()) == {"written_by": "xvmatch demo"}
    assert is_own_folder(new, "xvmatch demo") and not is_own_folder(new, "xvmatch other")
    (new / "match.png").write_bytes(b"x")
    assert claim_folder(new, "xvmatch demo") == new  # again: an own folder
    (tmp_path / "empty").mkdir()
    claim_folder(tmp_path / "empty", "xvmatch demo")
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine\n")
    for command in ("xvmatch demo", "xvmatch other"):
        with pytest.raises(OutputPathError, match=r"^--out .*mine: a folder not made by"):
            check_own_folder(mine, command)
    with pytest.raises(OutputPathError, match="not made by xvmatch other"):
        claim_folder(new, "xvmatch other")
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]


# --------------------------------------------------------------------------------------------
# the commands


def test_associate_refuses_bad_outputs_before_the_search(scene, tmp_path, capsys):
    base = ["associate", "--top", str(scene["top"]), "--hor", str(scene["hor"]), "--quiet"]
    os.mkfifo(tmp_path / "pipe")
    before = _snapshot(tmp_path), scene["top"].read_bytes()
    _refused(capsys, [*base, "--out", str(tmp_path / "pipe")], "--out", "FIFO")
    _refused(capsys, [*base, "--out", str(scene["top"])], "--out", "is the input --top")
    _refused(capsys, [*base, "--out", str(tmp_path)], "--out", "is a folder")
    _refused(capsys, [*base, "--out", str(tmp_path / "p.csv"), "--model", "default",
                      "--costs", str(tmp_path / "p.csv")], "--costs", "is also --out")
    _refused(capsys, [*base, "--out", str(tmp_path / "p.csv"), "--model", "default",
                      "--costs", str(tmp_path / "pipe")], "--costs", "FIFO")
    assert (_snapshot(tmp_path), scene["top"].read_bytes()) == before


def test_associate_draw_outputs(scene, tmp_path, capsys):
    images = scene["dataset"] / "images"
    base = ["associate", "--top", str(scene["top"]), "--hor", str(scene["hor"]), "--out",
            str(tmp_path / "p.csv"), "--model", "default", "--top-images",
            str(images / "top" / "*.jpg"), "--hor-images", str(images / "ego" / "*.jpg")]
    (tmp_path / "taken.png").write_bytes(b"mine")
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "frame_000001.png").write_bytes(b"mine")
    before = _snapshot(tmp_path), _snapshot(scene["dataset"])
    _refused(capsys, [*base, "--draw", str(tmp_path / "taken.png")], "--draw",
             "exists and is not a folder")
    _refused(capsys, [*base, "--draw", str(images / "top")], "--draw",
             "is or lies in the input folder --top-images")
    _refused(capsys, [*base, "--draw", str(mine)], "--draw", "not made by xvmatch associate")
    assert (_snapshot(tmp_path), _snapshot(scene["dataset"])) == before


@pytest.mark.parametrize("command", ["associate", "offset"])
def test_an_absent_camera_id_is_refused(scene, tmp_path, capsys, command):
    argv = [command, "--top", str(scene["top"]), "--hor", str(scene["hor"]), "--camera-id",
            "4242"]
    if command == "associate":
        argv += ["--out", str(tmp_path / "p.csv")]
    _refused(capsys, argv, "--camera-id 4242", "no box of", str(scene["top"]))
    assert list(tmp_path.iterdir()) == []


def test_evaluate_with_no_common_frame_has_nothing_to_score(scene, tmp_path, capsys):
    argv = ["evaluate", "--pred", str(scene["pred"]), "--top", str(scene["top"]), "--hor",
            str(scene["hor"])]
    assert main(argv) == 0
    capsys.readouterr()
    _refused(capsys, [*argv[:-4], "--top", str(scene["top"]), "--hor", str(scene["hor"]),
                      "--offset", "100"],
             "nothing to score", "share no frame", "after --offset 100")
    late = tmp_path / "late_hor.txt"
    late.write_text("50,1,10,10,20,40,-1,-1,-1,-1\n")
    empty = tmp_path / "empty.csv"
    empty.write_text("frame,top_id,hor_id\n")
    _refused(capsys, ["evaluate", "--pred", str(empty), "--top", str(scene["top"]), "--hor",
                      str(late)], "nothing to score", "horizontal frames 50..50")


def test_noise_refuses_its_input_and_a_fifo(scene, tmp_path, capsys):
    os.mkfifo(tmp_path / "pipe")
    before = _snapshot(tmp_path), scene["top"].read_bytes()
    base = ["noise", "--boxes", str(scene["top"]), "--view", "top", "--out"]
    _refused(capsys, [*base, str(scene["top"])], "--out", "is the input --boxes")
    _refused(capsys, [*base, str(tmp_path / "pipe")], "--out", "FIFO")
    assert (_snapshot(tmp_path), scene["top"].read_bytes()) == before


def test_track_refuses_a_folder_holding_its_inputs(scene, tmp_path, capsys):
    top = tmp_path / "top.txt"
    top.write_bytes(scene["top"].read_bytes())
    before = _snapshot(tmp_path)
    _refused(capsys, ["track", "--top", str(top), "--hor", str(scene["hor"]), "--out",
                      str(tmp_path)], "--out", "holds the input --top")
    out = tmp_path / "tracks"
    out.mkdir()
    os.mkfifo(out / "hor.txt")
    before = _snapshot(tmp_path)
    _refused(capsys, ["track", "--top", str(scene["top"]), "--hor", str(scene["hor"]), "--out",
                      str(out)], "hor.txt", "FIFO")
    assert _snapshot(tmp_path) == before


def test_associate_multi_checks_each_view_file(scene, tmp_path, capsys):
    other = tmp_path / "hor_b.txt"
    other.write_bytes(scene["hor"].read_bytes())
    out = tmp_path / "people"
    out.mkdir()
    os.mkfifo(out / "hor2.txt")
    before = _snapshot(tmp_path)
    _refused(capsys, ["associate-multi", "--top", str(scene["top"]), "--hor", str(scene["hor"]),
                      str(other), "--out", str(out)], "hor2.txt", "FIFO")
    _refused(capsys, ["associate-multi", "--top", str(scene["top"]), "--hor", str(scene["hor"]),
                      str(other), "--out", str(tmp_path)], "holds the input --hor")
    assert _snapshot(tmp_path) == before


def test_show_writes_no_temporary_file_and_refuses_its_inputs(scene, tmp_path, capsys):
    image = sorted((scene["dataset"] / "images" / "top").iterdir())[0]
    before = _snapshot(scene["dataset"])
    out = tmp_path / "pair.png"
    assert main(["show", str(image), "--out", str(out)]) == 0
    capsys.readouterr()
    assert [p.name for p in tmp_path.iterdir()] == ["pair.png"]
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the former temporary name, a symlink planted there, is neither followed nor left over
    victim = tmp_path / "victim.txt"
    victim.write_text("mine\n")
    (tmp_path / ".pair.png.tmp").symlink_to(victim)
    assert main(["show", str(image), "--out", str(out)]) == 0
    capsys.readouterr()
    assert victim.read_text() == "mine\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == [".pair.png.tmp", "pair.png",
                                                          "victim.txt"]
    jpg = image.with_suffix(".jpg")
    _refused(capsys, ["show", str(image), "--out", str(jpg)], "--out", "is the input PAIR")
    _refused(capsys, ["show", str(scene["dataset"]), "--out",
                      str(sorted((scene["dataset"] / "images" / "ego").iterdir())[0])],
             "--out", "lies in the input folder PAIR")
    os.mkfifo(tmp_path / "pipe.png")
    _refused(capsys, ["show", str(image), "--out", str(tmp_path / "pipe.png")], "FIFO")
    assert stat.S_ISFIFO((tmp_path / "pipe.png").lstat().st_mode)
    assert _snapshot(scene["dataset"]) == before


def test_baseline_refuses_bad_figures_before_the_evaluation(scene, tmp_path, capsys):
    (tmp_path / "figs").write_text("mine\n")
    _refused(capsys, ["baseline", "--data", str(scene["dataset"]), "--figures",
                      str(tmp_path / "figs"), "--quiet"], "--figures", "not a folder")
    _refused(capsys, ["baseline", "--data", str(scene["dataset"]), "--figures",
                      str(scene["dataset"] / "figures"), "--quiet"], "--figures",
             "lies in the input folder --data")
    assert (tmp_path / "figs").read_text() == "mine\n"
    assert not (scene["dataset"] / "figures").exists()


def test_fit_geometry_refuses_bad_outputs_before_training(scene, tmp_path, capsys):
    data = tmp_path / "cvmhat"
    data.mkdir()
    for view in ("top", "hor"):
        (data / f"V0-S_x-G_1_{view}.txt").write_bytes(scene[view].read_bytes())
    os.mkfifo(tmp_path / "pipe.pt")
    before = _snapshot(tmp_path)
    base = ["fit-geometry", "--cvmhat", str(data), "--quiet", "--out"]
    _refused(capsys, [*base, str(tmp_path / "pipe.pt")], "--out", "FIFO")
    _refused(capsys, [*base, str(data / "V0-S_x-G_1_top.txt")], "--out",
             "lies in the input folder --cvmhat")
    _refused(capsys, [*base, str(tmp_path / "m.pt"), "--run-dir", str(tmp_path / "pipe.pt")],
             "--run-dir", "not a folder")
    assert _snapshot(tmp_path) == before


def test_demo_refuses_a_folder_it_did_not_make(tmp_path, capsys):
    out = tmp_path / "project"
    (out / "scene").mkdir(parents=True)
    (out / "scene" / "top.txt").write_text("mine\n")
    (tmp_path / "file").write_text("mine\n")
    before = _snapshot(tmp_path)
    _refused(capsys, ["demo", "--out", str(out)], "--out", "not made by xvmatch demo")
    _refused(capsys, ["demo", "--out", str(tmp_path / "file")], "not a folder")
    assert _snapshot(tmp_path) == before


def test_synth_and_ablate_refuse_a_file_for_a_folder(scene, tmp_path, capsys):
    (tmp_path / "f").write_text("mine\n")
    _refused(capsys, ["synth", "--out", str(tmp_path / "f"), "--quiet"], "--out",
             "not a folder")
    _refused(capsys, ["ablate", "--data", str(scene["dataset"]), "--out", str(tmp_path / "f"),
                      "--quiet"], "--out", "not a folder")
    _refused(capsys, ["ablate", "--data", str(scene["dataset"]), "--out",
                      str(scene["dataset"] / "report"), "--quiet"], "--out",
             "input folder --data")
    assert (tmp_path / "f").read_text() == "mine\n"
    assert not (scene["dataset"] / "report").exists()


@pytest.mark.slow
def test_out_of_memory_is_one_line(tmp_path):
    # A real MemoryError: the address space is capped just above what the process uses, then
    # the search needs far more (360000 orientations per hypothesis).
    script = textwrap.dedent(f"""
        import resource, sys
        from xvmatch.cli import main
        from xvmatch.datasets.box_scene import simulate_box_scene, write_box_scene
        top, hor = write_box_scene(simulate_box_scene(n_frames=2, seed=1), {str(tmp_path)!r},
                                   "s")
        import numpy as np
        np.zeros(1)
        used = int(open("/proc/self/statm").read().split()[0]) * resource.getpagesize()
        resource.setrlimit(resource.RLIMIT_AS, (used + (64 << 20), used + (64 << 20)))
        sys.exit(main(["offset", "--top", str(top), "--hor", str(hor), "--clips", "1",
                       "--clip-length", "2", "--max-offset", "1", "--dtheta", "0.01"]))
    """)
    env = {**os.environ, "XVMATCH_KERNELS": "numpy", "OMP_NUM_THREADS": "1"}
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         env=env, timeout=120)
    assert run.returncode == 2, run.stderr
    lines = run.stderr.strip().splitlines()
    assert lines[-1].startswith("xvmatch: error: out of memory running offset"), run.stderr
    assert "Traceback" not in run.stderr


@pytest.mark.parametrize("script, option", [
    ("deployed_matcher_eval.py", "--json"), ("matcher_comparison.py", "--json"),
    ("pretrained_backbones_eval.py", "--json"), ("learned_matcher_eval.py", "--json"),
    ("cross_cpu_costs.py", "--save"),
])
@pytest.mark.slow
def test_benchmarks_check_their_output_file_before_any_work(tmp_path, script, option):
    """A result file whose folder is missing is refused at once, not after an hour's run."""
    out = tmp_path / "missing" / "r.json"
    work = tmp_path / "work"
    run = subprocess.run([sys.executable, str(REPO / "benchmarks" / script), option, str(out),
                          *(["--work", str(work)] if script != "cross_cpu_costs.py" else [])],
                         capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert run.returncode == 2, run.stderr
    last = run.stderr.strip().splitlines()[-1]
    assert f"error: {option} {out}: cannot write: the folder" in last and "does not exist" in last
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.slow
def test_multicam_benchmark_checks_its_out_folder(tmp_path):
    (tmp_path / "f").write_text("mine\n")
    run = subprocess.run([sys.executable, str(REPO / "benchmarks" / "multicam_eval.py"), "--out",
                          str(tmp_path / "f")], capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "--out" in run.stderr and "not a folder" in run.stderr
    assert (tmp_path / "f").read_text() == "mine\n"
