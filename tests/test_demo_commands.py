"""The commands ``xvmatch demo`` prints run as printed (issue 29, item 3).

A newcomer runs the demo through the entry point of a virtual environment they have not
activated (``make demo``), then pastes the commands it printed into a shell whose ``PATH`` has
no ``xvmatch``: the commands must name the entry point by its full path, quoted for the shell.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ENTRY = Path(sys.executable).parent / "xvmatch"


def _path_without(folder: Path) -> str:
    """``$PATH`` without ``folder`` and without any other folder holding an ``xvmatch``."""
    keep = [p for p in os.environ.get("PATH", "").split(os.pathsep)
            if p and Path(p).resolve() != folder.resolve() and not (Path(p) / "xvmatch").exists()]
    return os.pathsep.join(keep or ["/usr/bin", "/bin"])


@pytest.mark.slow
@pytest.mark.skipif(not ENTRY.is_file(), reason="no xvmatch entry point beside the interpreter")
def test_the_printed_commands_run_in_a_shell_without_the_environment(tmp_path):
    env = {**os.environ, "PATH": _path_without(ENTRY.parent)}
    assert shutil.which("xvmatch", path=env["PATH"]) is None
    out = tmp_path / "demo folder"  # a space: the paths must be quoted
    demo = subprocess.run([str(ENTRY), "demo", "--out", str(out), "--scenes", "1", "--frames",
                           "2"], env=env, cwd=tmp_path, capture_output=True, text=True,
                          timeout=300)
    assert demo.returncode == 0, demo.stderr
    lines = demo.stdout.splitlines()
    start = next(k for k, line in enumerate(lines) if "Match a scene as a user would" in line)
    commands = [line.strip() for line in lines[start + 1:] if line.startswith("  ")]
    assert [c.split(" ")[1] for c in commands] == ["associate", "evaluate"], commands
    for command in commands:
        assert command.startswith(f"{ENTRY} ") or command.startswith(f"'{ENTRY}' "), command
        run = subprocess.run(["/bin/sh", "-c", command], env=env, cwd=tmp_path,
                             capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, (command, run.stderr)
    assert (out / "pred.csv").is_file()
    assert any((out / "pictures").iterdir())
    assert "CVIDF1" in run.stdout  # the evaluate line printed its scores


def test_the_bare_name_when_it_is_the_running_one(monkeypatch):
    from xvmatch.commands.demo import xvmatch_command

    if not ENTRY.is_file():
        pytest.skip("no xvmatch entry point beside the interpreter")
    monkeypatch.setenv("PATH", str(ENTRY.parent))
    assert xvmatch_command() == "xvmatch"
    monkeypatch.setenv("PATH", _path_without(ENTRY.parent))
    assert xvmatch_command() == str(ENTRY)
