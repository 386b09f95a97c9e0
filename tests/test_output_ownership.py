"""Issue 65: a command writes only into a folder it made (or a new or empty one), never outside
``--out`` through a name from the user's data, and never deletes a file it did not write."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from xvmatch.cli import main
from xvmatch.core.folder_marker import (
    files_under,
    own_files,
    record_own_files,
    remove_own_files,
)
from xvmatch.core.output_paths import Output, OutputPathError, check_outputs, plain_name
from xvmatch.datasets.box_scene import simulate_box_scene, write_box_scene
from xvmatch.datasets.multicam_scenes import (
    MulticamConfig,
    simulate_multicam_scene,
    write_multicam_scene,
)


def _refused(capsys, argv: list[str], *words: str) -> str:
    """Run ``argv``: exit code 2 and one error line holding every word of ``words``."""
    assert main(argv) == 2
    _, err = capsys.readouterr()
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("xvmatch: error: "), err
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


def _files(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file()}


@pytest.fixture(scope="module")
def multicam(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("own") / "scene"
    write_multicam_scene(root, simulate_multicam_scene(
        MulticamConfig(n_cameras=2, n_people=(4, 4)), 20, seed=3))
    return root


@pytest.fixture(scope="module")
def pair(tmp_path_factory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("pair")
    return write_box_scene(simulate_box_scene(n_frames=6, seed=2), root, "sim")


# --------------------------------------------------------------------------------------------
# names from the user's data are plain file names

HOSTILE = ["..", ".", "../victim", "../../x", "/abs/name", "a/b", ".hidden", "a\\b", "x y",
           "nul\0x", "é", "a" * 65, "-lead"]


@pytest.mark.parametrize("name", HOSTILE)
def test_a_hostile_name_is_refused(name):
    with pytest.raises(OutputPathError, match="is used as a file name"):
        plain_name(name, "--boxes")


@given(st.from_regex(r"[A-Za-z0-9][A-Za-z0-9_.+-]{0,63}", fullmatch=True))
def test_a_plain_name_stays_one_file_in_the_folder(name):
    assert plain_name(name, "--boxes") == name
    folder = os.path.abspath("out")
    assert os.path.dirname(os.path.abspath(os.path.join(folder, name + ".txt"))) == folder


@pytest.mark.slow
@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(name=st.one_of(st.sampled_from([n for n in HOSTILE if not n.startswith("-")]),
                      st.builds(lambda a, b: f"{a}/{b}", st.text("ab.", min_size=1, max_size=3),
                                st.text("ab", min_size=1, max_size=3)),
                      st.builds(lambda a: f"/{a}", st.text("abc", min_size=1, max_size=4))),
       option=st.sampled_from(["--boxes", "--images", "--image-size"]))
def test_every_name_bearing_option_refuses_a_path(multicam, tmp_path_factory, capsys, name,
                                                  option):
    """multicam's NAME=... options (the camera names become OUT/NAME.txt): a name with ``/``,
    ``..`` or an absolute path is refused before anything is read or written, whatever file
    already stands at the target."""
    capsys.readouterr()
    work = tmp_path_factory.mktemp("names")
    out = work / "out"
    victim = work / "victim.txt"
    victim.write_text("mine\n")
    boxes = [f"{c}={multicam / 'boxes' / (c + '.txt')}" for c in ("cam1", "cam2")]
    value = {"--boxes": f"{name}={multicam / 'boxes' / 'cam1.txt'}",
             "--images": f"{name}={work}", "--image-size": f"{name}=640x360"}[option]
    argv = ["multicam", "--boxes", *boxes, "--cameras", str(multicam / "cameras.json"),
            "--out", str(out), "--quiet"]
    if option == "--boxes":
        argv[2:2] = [value]
    elif option == "--images":
        argv += [option, value]
    else:  # sizes go with --fit-homography (cameras from clicked ground points)
        argv = ["multicam", "--fit-homography", str(multicam / "cameras.json"), option, value,
                "--out", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "file name" in err, err
    assert victim.read_text() == "mine\n" and sorted(p.name for p in work.iterdir()) == [
        "victim.txt"]


def test_multicam_never_writes_outside_out(multicam, tmp_path, capsys):
    out = tmp_path / "sub" / "out"
    (tmp_path / "sub").mkdir()
    victim = tmp_path / "sub" / "victim.txt"
    victim.write_text("mine\n")
    cam2 = f"cam2={multicam / 'boxes' / 'cam2.txt'}"
    for name in ("../victim", str(tmp_path / "abs")):
        _refused(capsys, ["multicam", "--boxes", f"{name}={multicam / 'boxes' / 'cam1.txt'}",
                          cam2, "--cameras", str(multicam / "cameras.json"), "--out", str(out)],
                 "--boxes", "file name")
    assert victim.read_text() == "mine\n" and not out.exists()
    assert not (tmp_path / "abs.txt").exists()


# --------------------------------------------------------------------------------------------
# a folder it did not make is not written into; a second --out with the same path is refused

def test_track_and_associate_multi_leave_a_user_folder_alone(pair, tmp_path, capsys):
    top, hor = pair
    hor2 = tmp_path / "hor2.txt"
    shutil.copy(hor, hor2)
    mine = tmp_path / "mine"
    mine.mkdir()
    for name in ("top.txt", "hor.txt", "hor1.txt"):
        (mine / name).write_text("the user's\n")
    before = _files(mine)
    _refused(capsys, ["track", "--top", str(top), "--hor", str(hor), "--offset", "0",
                      "--out", str(mine), "--quiet"], "--out", "not made by xvmatch track")
    _refused(capsys, ["associate-multi", "--top", str(top), "--hor", str(hor), str(hor2),
                      "--out", str(mine), "--quiet"], "--out",
             "not made by xvmatch associate-multi")
    assert _files(mine) == before
    # its own folder, and a new one, are written (again)
    own = tmp_path / "own"
    for _ in range(2):
        assert main(["track", "--top", str(top), "--hor", str(hor), "--offset", "0",
                     "--out", str(own), "--quiet"]) == 0
    assert (own / "top.txt").is_file() and (own / "hor.txt").is_file()
    capsys.readouterr()


def test_the_same_output_twice_is_refused(tmp_path):
    with pytest.raises(OutputPathError, match="is also --write-cameras"):
        check_outputs([Output("--write-cameras", tmp_path / "c", folder=True),
                       Output("--write-cameras", tmp_path / "c", folder=True)])
    with pytest.raises(OutputPathError, match="is also --out"):
        check_outputs([Output("--out", tmp_path / "p.csv"), Output("--out", tmp_path / "p.csv")])


def test_show_never_writes_over_another_image_of_the_data_set(tmp_path, capsys):
    from xvmatch.datasets.synthetic_io import generate_dataset
    from xvmatch.datasets.synthetic_scenes import SynthConfig

    data = tmp_path / "data"
    generate_dataset(data, SynthConfig(top_size=(64, 36), ego_size=(64, 36), n_people=(2, 3)),
                     n_scenes=1, n_frames=2, seed=0)
    first, second = sorted((data / "images" / "top").iterdir())[:2]
    before = _files(data)
    _refused(capsys, ["show", str(first), "--out", str(second)], "--out",
             "lies in the input folder PAIR")
    assert _files(data) == before


def test_baseline_figures_only_into_its_own_folder(tmp_path, capsys):
    from xvmatch.evaluation.cost_distributions import FIGURE_FILES

    mine = tmp_path / "figs"
    mine.mkdir()
    (mine / next(iter(FIGURE_FILES.values()))).write_text("mine\n")
    _refused(capsys, ["baseline", "--data", str(tmp_path / "nothing"), "--figures", str(mine),
                      "--quiet"], "--figures", "not made by xvmatch baseline --figures")
    assert (mine / next(iter(FIGURE_FILES.values()))).read_text() == "mine\n"


# --------------------------------------------------------------------------------------------
# files a command removes: only those its marker lists as its own

def test_the_marker_lists_what_was_written_and_only_that_is_removed(tmp_path):
    (tmp_path / "a.json").write_text("1")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "b.txt").write_text("2")
    (tmp_path / "user.json").write_text("3")
    record_own_files(tmp_path, "xvmatch x", ["a.json", "sub/b.txt"])
    assert own_files(tmp_path, "xvmatch x") == {"a.json", "sub/b.txt"}
    assert own_files(tmp_path, "xvmatch y") == set()
    assert files_under(tmp_path) == {"a.json", "sub/b.txt", "user.json"}
    remove_own_files(tmp_path, "xvmatch x", keep=["a.json"])
    assert files_under(tmp_path) == {"a.json", "user.json"}


def test_a_forged_marker_cannot_name_files_outside_its_folder(tmp_path):
    folder = tmp_path / "out"
    folder.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("mine\n")
    record_own_files(folder, "xvmatch x", ["../victim.txt", str(victim), "ok.txt"])
    assert own_files(folder, "xvmatch x") == {"ok.txt"}
    remove_own_files(folder, "xvmatch x")
    assert victim.read_text() == "mine\n"


def test_synth_cameras_again_keeps_the_users_files(tmp_path):
    out = tmp_path / "scene"
    args = ["synth", "--cameras", "3", "--boxes-only", "--frames", "10", "--seed", "4",
            "--quiet", "--out", str(out)]
    assert main(args) == 0
    (out / "boxes" / "notes.txt").write_text("mine\n")
    (out / "gt" / "mine.txt").write_text("mine\n")
    assert main(["synth", "--cameras", "2", "--boxes-only", "--frames", "10", "--seed", "4",
                 "--quiet", "--out", str(out)]) == 0
    assert (out / "boxes" / "notes.txt").read_text() == "mine\n"
    assert (out / "gt" / "mine.txt").read_text() == "mine\n"
    assert not (out / "boxes" / "cam3.txt").exists()  # the earlier run's third camera


def test_a_failed_demo_removes_the_folder_it_made(tmp_path, capsys, monkeypatch):
    import xvmatch.datasets.synthetic_io as synthetic_io

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(synthetic_io, "generate_dataset", interrupted)
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--scenes", "1", "--frames", "1"]) == 130
    assert not out.exists()
    out.mkdir()
    (out / "keep.txt").write_text("mine\n")  # not the demo's folder: refused, kept
    assert main(["demo", "--out", str(out), "--scenes", "1", "--frames", "1"]) == 2
    assert (out / "keep.txt").read_text() == "mine\n"
    capsys.readouterr()
