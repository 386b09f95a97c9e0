"""Property test of every command's outputs (issue 28): whatever lies at an output path (nothing,
a regular file, a FIFO, a folder, a user's folder, an input of the run, another output of the
run), the command ends with exit code 0 or 2, a refusal is one line naming the option, and no
input, no FIFO and no file of the user changes, and no temporary file is left behind.

Commands whose real work is long (the learned matcher, training, export, the demo, the
ablation) are drawn only with at least one refused output: the point is that the check comes
before the work.
"""

from __future__ import annotations

import os
import shutil
import stat
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from xvmatch.cli import main
from xvmatch.core.folder_marker import MARKER
from xvmatch.datasets.box_scene import simulate_box_scene, write_box_scene

KINDS = ("absent", "file", "fifo", "folder", "foreign", "input", "other")
"""What an output path is made to be: nothing, a regular file, a FIFO, an empty folder, a
non-empty folder of the user's, an input of the run, the path of the run's first output."""


@dataclass(frozen=True)
class Command:
    """One command: its output options (option, is a folder), its argv and whether it is heavy."""

    name: str
    outputs: tuple[tuple[str, bool], ...]
    argv: Callable[[Path, list[str]], list[str]]
    heavy: bool = False
    owned: bool = False  # writes only into a new, empty or own folder
    input_file: str = "top"  # the input a file output is made to be (kind "input")
    suffix: str = ""  # of a file output's name
    kinds: tuple[str, ...] = KINDS


def _inputs(ws: Path) -> dict[str, str]:
    i = ws / "in"
    return {"top": str(i / "top.txt"), "hor": str(i / "hor.txt"), "hor2": str(i / "hor2.txt"),
            "data": str(i / "dataset"), "image": str(sorted((i / "dataset" / "images" / "top")
                                                            .iterdir())[0]),
            "top_images": str(i / "dataset" / "images" / "top" / "*.jpg"),
            "hor_images": str(i / "dataset" / "images" / "ego" / "*.jpg"),
            "cvmhat": str(i / "cvmhat"), "model": str(i / "model.pt"),
            "cvmhat_top": str(i / "cvmhat" / "V0-S_x-G_1_top.txt")}


def _c(name, outputs, argv, **kw) -> Command:
    return Command(name, tuple(outputs), argv, **kw)


COMMANDS = [
    _c("associate", [("--out", False)],
       lambda ws, o: ["associate", "--top", _inputs(ws)["top"], "--hor", _inputs(ws)["hor"],
                      "--out", o[0], "--quiet"]),
    _c("noise", [("--out", False)],
       lambda ws, o: ["noise", "--boxes", _inputs(ws)["top"], "--view", "top", "--out", o[0]]),
    _c("track", [("--out", True)],
       lambda ws, o: ["track", "--top", _inputs(ws)["top"], "--hor", _inputs(ws)["hor"],
                      "--out", o[0], "--quiet", "--solver", "spectral"], owned=True),
    _c("associate-multi", [("--out", True)],
       lambda ws, o: ["associate-multi", "--top", _inputs(ws)["top"], "--hor",
                      _inputs(ws)["hor"], _inputs(ws)["hor2"], "--out", o[0], "--quiet",
                      "--solver", "greedy"], owned=True),
    _c("show", [("--out", False)],
       lambda ws, o: ["show", _inputs(ws)["image"], "--out", o[0]], input_file="image",
       suffix=".png"),
    _c("baseline", [("--figures", True)],
       lambda ws, o: ["baseline", "--data", _inputs(ws)["data"], "--figures", o[0], "--quiet",
                      "--json"], owned=True),
    _c("synth", [("--out", True)],
       lambda ws, o: ["synth", "--out", o[0], "--scenes", "1", "--frames", "1", "--size",
                      "32x18", "--quiet"], kinds=("absent", "file", "fifo", "folder")),
    _c("associate --model", [("--out", False), ("--costs", False), ("--draw", True)],
       lambda ws, o: ["associate", "--top", _inputs(ws)["top"], "--hor", _inputs(ws)["hor"],
                      "--model", "default", "--top-images", _inputs(ws)["top_images"],
                      "--hor-images", _inputs(ws)["hor_images"], "--out", o[0], "--costs",
                      o[1], "--draw", o[2], "--quiet"], heavy=True, owned=True),
    _c("fit-geometry", [("--out", False), ("--run-dir", True)],
       lambda ws, o: ["fit-geometry", "--cvmhat", _inputs(ws)["cvmhat"], "--out", o[0],
                      "--run-dir", o[1], "--quiet"], heavy=True, input_file="cvmhat_top"),
    _c("export", [("--out", True)],
       lambda ws, o: ["export", "--model", _inputs(ws)["model"], "--out", o[0], "--quiet"],
       heavy=True, owned=True),
    _c("demo", [("--out", True)],
       lambda ws, o: ["demo", "--out", o[0]], heavy=True, owned=True),
    _c("ablate", [("--out", True)],
       lambda ws, o: ["ablate", "--data", _inputs(ws)["data"], "--out", o[0], "--quiet"],
       heavy=True),
]


@pytest.fixture(scope="module")
def source(tmp_path_factory) -> Path:
    """The inputs every example copies: a 6-frame scene, a second horizontal view, a 1-scene
    64x36 dataset, a CVMHAT-like folder and a (not loadable) model file."""
    from xvmatch.datasets.synthetic_io import generate_dataset
    from xvmatch.datasets.synthetic_scenes import SynthConfig

    root = tmp_path_factory.mktemp("property") / "in"
    root.mkdir()
    scene = simulate_box_scene(n_frames=6, seed=1)
    top, hor = write_box_scene(scene, root, "sim")
    top.rename(root / "top.txt")
    hor.rename(root / "hor.txt")
    shutil.copy(root / "hor.txt", root / "hor2.txt")
    config = SynthConfig(top_size=(64, 36), ego_size=(64, 36), n_people=(2, 3))
    generate_dataset(root / "dataset", config, n_scenes=1, n_frames=2, seed=0)
    (root / "cvmhat").mkdir()
    for view in ("top", "hor"):
        shutil.copy(root / f"{view}.txt", root / "cvmhat" / f"V0-S_x-G_1_{view}.txt")
    (root / "model.pt").write_bytes(b"not a matcher file\n")
    return root


def _bad(kind: str, folder: bool, owned: bool) -> bool:
    """Whether an output of this kind must be refused."""
    if kind in ("fifo", "input", "other"):
        return True
    if kind == "foreign":
        return (not folder) or owned
    if kind == "file":
        return folder
    if kind == "folder":
        return not folder
    return False  # absent


def _make(ws: Path, k: int, kind: str, folder: bool, first: str | None,
          command: Command) -> str:
    """Make output ``k`` of ``kind`` in the workspace and return its path."""
    if kind == "other" and first is not None:
        return first
    if kind in ("input", "other"):  # "other" for the first output: an input too
        return str(ws / "in") if folder else _inputs(ws)[command.input_file]
    path = ws / f"out{k}{'' if folder else command.suffix}"
    if kind == "file":
        path.write_bytes(b"the user's\n")
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "folder":
        path.mkdir()
    elif kind == "foreign":
        path.mkdir()
        (path / "notes.txt").write_bytes(b"the user's\n")
    return str(path)


def _state(ws: Path) -> dict[str, tuple[str, bytes | None]]:
    out = {}
    for path in sorted(ws.rglob("*")):
        mode = path.lstat().st_mode
        kind = ("fifo" if stat.S_ISFIFO(mode) else "dir" if stat.S_ISDIR(mode)
                else "link" if stat.S_ISLNK(mode) else "file")
        out[str(path.relative_to(ws))] = (kind, path.read_bytes() if kind == "file" else None)
    return out


@pytest.mark.parametrize("command", COMMANDS, ids=[c.name for c in COMMANDS])
@settings(max_examples=8, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_outputs_of_every_command(source, command, data, capsys):
    kinds = [data.draw(st.sampled_from([x for x in command.kinds if k or x != "other"]),
                       label=opt) for k, (opt, _) in enumerate(command.outputs)]
    if command.heavy and not any(_bad(kind, f, command.owned)
                                 for kind, (_, f) in zip(kinds, command.outputs, strict=True)):
        kinds[0] = "fifo"  # heavy commands: only runs refused before the work
    with tempfile.TemporaryDirectory() as tmp:
        ws = Path(tmp)
        shutil.copytree(source, ws / "in", symlinks=True)
        paths: list[str] = []
        for k, (kind, (_, folder)) in enumerate(zip(kinds, command.outputs, strict=True)):
            paths.append(_make(ws, k, kind, folder, paths[0] if paths else None, command))
        argv = command.argv(ws, paths)
        before = _state(ws)
        capsys.readouterr()
        rc = main(argv)
        err = capsys.readouterr().err
        after = _state(ws)
        bad = [opt for kind, (opt, folder) in zip(kinds, command.outputs, strict=True)
               if _bad(kind, folder, command.owned)]
        assert rc in (0, 2), err
        if bad:
            assert rc == 2, (kinds, err)
            lines = err.strip().splitlines()
            assert len(lines) == 1 and lines[0].startswith("xvmatch: error: "), err
            assert any(opt in lines[0] for opt in bad), (kinds, lines[0])
        elif command.name not in ("synth",):  # synth may refuse a foreign folder (its own rule)
            assert rc == 0, (kinds, err)
        # inputs, FIFOs and the user's files are as they were
        for name, (kind, content) in before.items():
            if name.startswith("in") or kind == "fifo" or "notes.txt" in name:
                assert after.get(name) == (kind, content), (kinds, name)
            if kind == "file" and content == b"the user's\n" and rc == 2:
                assert after.get(name) == (kind, content), (kinds, name)
        if rc == 2:  # nothing written
            assert set(after) == set(before), (kinds, sorted(set(after) ^ set(before)))
        stray = [n for n in after if (Path(n).name.startswith(".") and Path(n).name != MARKER)
                 or n.endswith(".tmp")]
        assert stray == [], (kinds, stray)
