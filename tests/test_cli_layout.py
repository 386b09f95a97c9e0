"""The command line's modules: the root ``xvmatch/cli.py`` imports the command modules of
``xvmatch/commands/``, never the reverse, and each shared option is defined once, in
``xvmatch/commands/_options.py`` (issue 30, item 2). Every import statement is read from the
source, lazy imports inside functions included.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
COMMANDS = ROOT / "xvmatch" / "commands"
CLI_MODULES = sorted(COMMANDS.rglob("*.py"))
SHARED_OPTIONS = ("--top-images", "--hor-images", "--rho", "--lam", "--tau", "--dtheta", "--fov")
"""Options several commands take, each added by one function of ``commands/_options.py``."""


def _name(path: Path) -> str:
    """A module's path under ``xvmatch/commands/`` (``lab/train.py``), or its name (``cli.py``)."""
    return path.relative_to(COMMANDS).as_posix() if path.is_relative_to(COMMANDS) else path.name


def _imported(path: Path) -> list[tuple[int, str]]:
    """``(line, dotted name)`` of every import of a file; ``from x import y`` gives ``x`` and
    ``x.y``."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append((node.lineno, node.module))
            out += [(node.lineno, f"{node.module}.{alias.name}") for alias in node.names]
    return out


def _string_constants(path: Path) -> list[str]:
    return [node.value for node in ast.walk(ast.parse(path.read_text(), filename=str(path)))
            if isinstance(node, ast.Constant) and isinstance(node.value, str)]


def test_there_are_command_modules() -> None:
    assert {_name(p) for p in CLI_MODULES} >= {"_options.py", "associate.py", "lab/train.py"}


@pytest.mark.parametrize("path", CLI_MODULES, ids=_name)
def test_no_command_module_imports_the_root(path: Path) -> None:
    bad = [f"{_name(path)}:{line}: imports {name}" for line, name in _imported(path)
           if name == "xvmatch.cli" or name.startswith("xvmatch.cli.")]
    assert not bad, "only xvmatch/cli.py imports the command modules:\n" + "\n".join(bad)


@pytest.mark.slow
@pytest.mark.parametrize("option", SHARED_OPTIONS)
def test_shared_option_is_defined_in_one_module(option: str) -> None:
    modules = sorted({_name(p) for p in [ROOT / "xvmatch" / "cli.py", *CLI_MODULES]
                      if option in _string_constants(p)})
    assert modules == ["_options.py"], f"{option} appears as a literal in {modules}"
    calls = [node for node in ast.walk(ast.parse((COMMANDS / "_options.py").read_text()))
             if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
             and node.func.attr == "add_argument" and node.args
             and isinstance(node.args[0], ast.Constant) and node.args[0].value == option]
    assert len(calls) == 1, f"{option} is added {len(calls)} times"


def test_one_progress_bar() -> None:
    """Every command's progress bar comes from ``commands/_options.py``'s ``progress_bar``."""
    users = sorted(_name(p) for p in [ROOT / "xvmatch" / "cli.py", *CLI_MODULES]
                   if any(name.split(".")[0] == "tqdm" for _, name in _imported(p)))
    assert users == ["_options.py"]


@pytest.mark.parametrize(("module", "budget"), [
    ("track.py", "{MIP_MAX_LOOPS} added loops and {MIP_NODE_LIMIT} HiGHS nodes"),
    ("associate_multi.py", "{MIP_MAX_TRIANGLES} added triangles and {MIP_NODE_LIMIT} HiGHS nodes"),
])
def test_time_limit_help_states_the_solvers_budgets(module: str, budget: str) -> None:
    # the command modules import no solver at start-up, so their help spells the budgets out
    from xvmatch.inference.tracks.track_mip import MIP_MAX_LOOPS, MIP_NODE_LIMIT
    from xvmatch.inference.views.multi_view_assignment import MIP_MAX_TRIANGLES

    text = budget.format(MIP_MAX_LOOPS=MIP_MAX_LOOPS, MIP_NODE_LIMIT=MIP_NODE_LIMIT,
                         MIP_MAX_TRIANGLES=MIP_MAX_TRIANGLES)
    assert any(text in s for s in _string_constants(COMMANDS / module)), text
