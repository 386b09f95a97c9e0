"""Every file the project's commands, training scripts and benchmarks write is written
atomically (``xvmatch.core.atomic_files``) or inside a fresh temporary folder that is moved
into place whole: a direct ``Path.write_text`` / ``write_bytes`` on a user's path would leave a
half-written file behind an interrupted run."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("xvmatch", "geometry", "datasets", "models", "training", "export", "inference",
           "evaluation", "benchmarks")
DIRECT_WRITES = {"write_text", "write_bytes"}
IN_TEMPORARY_FOLDER = {
    # the export writes the whole bundle into a temporary folder, then renames it
    ("export/onnx_export.py", "folder / NOTICE"),
}
"""(file, receiver) of direct writes into a folder created for the run and moved whole."""


def direct_writes(path: Path) -> list[tuple[int, str]]:
    """(line, receiver source) of each ``X.write_text(...)`` / ``X.write_bytes(...)`` call."""
    text = path.read_text(encoding="utf-8")
    out = []
    for node in ast.walk(ast.parse(text, filename=str(path))):
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                and node.func.attr in DIRECT_WRITES):
            out.append((node.lineno, ast.get_source_segment(text, node.func.value) or ""))
    return out


def receiver_is_temporary(receiver: str) -> bool:
    """A path under a folder named ``tmp`` (the project's name for a run's temporary folder)."""
    return receiver.lstrip("(").split()[0] == "tmp"


@pytest.mark.parametrize("folder", SOURCES)
def test_outputs_are_written_atomically(folder: str) -> None:
    offenders = []
    for path in sorted((ROOT / folder).rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        for line, receiver in direct_writes(path):
            if not receiver_is_temporary(receiver) and (rel, receiver) not in IN_TEMPORARY_FOLDER:
                offenders.append(f"{rel}:{line}: {receiver}.write_...")
    assert not offenders, "use xvmatch.core.atomic_files: " + ", ".join(offenders)


def test_the_scan_finds_a_direct_write(tmp_path: Path) -> None:
    source = tmp_path / "example.py"
    source.write_text("from pathlib import Path\n\nPath('out.json').write_text('{}')\n"
                      "(tmp / 'a').write_bytes(b'')\n")
    found = direct_writes(source)
    assert [line for line, _ in found] == [3, 4]
    assert [receiver_is_temporary(r) for _, r in found] == [False, True]
