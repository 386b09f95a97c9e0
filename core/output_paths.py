"""The checks every command makes on its output paths, once, before any work starts.

A command lists what it will write (:class:`Output`: a file, or a folder and the names it
writes there) and what it reads (:class:`Input`: a file, a folder, a glob pattern), and calls
:func:`check_outputs` right after parsing. The run is refused with one line naming the option
and the path (:class:`OutputPathError`, a ``ValueError``: exit code 2) when

- a file output exists and is not a regular file (a folder, a FIFO, a device, a socket): the
  writers rename over whatever is there, which would replace a FIFO or a device node;
- a folder output exists and is not a folder;
- the folder an output goes into does not exist (a folder output's nearest existing parent is
  used: commands create their output folders) or is not writable;
- an output is an input of the run (the same file through any symlink or hard link), a file
  output lies in an input folder and already exists there, a folder output is or lies in an
  input folder, or holds an input;
- two outputs of the run are the same path (``--out p.csv --costs p.csv``).

:func:`check_own_folder` / :func:`claim_folder` let a command write into only a folder it made
itself (or a new or empty one): it leaves a marker file naming the command
(:mod:`xvmatch.core.folder_marker`), and refuses any other non-empty folder.
"""

from __future__ import annotations

import argparse
import glob
import os
import re
import stat
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from xvmatch.core.folder_marker import is_own_folder, mark_own_folder
from xvmatch.core.input_files import file_kind

__all__ = [
    "Input",
    "Output",
    "OutputPathError",
    "check_outputs",
    "check_own_folder",
    "check_script_outputs",
    "claim_folder",
    "plain_name",
]

_NAME_CHARS = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.+-]{0,63}")



class OutputPathError(ValueError):
    """An output path that must not be written; the message is one line naming the option."""


@dataclass(frozen=True)
class Output:
    """One output of a command.

    Attributes:
        option: the option that names it, e.g. ``--out`` (used in the error message).
        path: the path given; None: not asked for (skipped).
        folder: a folder the command creates if missing and writes into (else one file).
        files: names the command writes inside the folder, each checked as a file output.
        parents: a file output whose folder the command creates if missing (then the nearest
            existing parent must be a writable folder).
    """

    option: str
    path: str | os.PathLike | None
    folder: bool = False
    files: tuple[str, ...] = ()
    parents: bool = False


@dataclass(frozen=True)
class Input:
    """One input of a command: a file, a folder, or a glob pattern (None or a name that is not
    a path, such as ``default``, is skipped)."""

    option: str
    path: str | os.PathLike | None


_GLOB_CHARS = frozenset("*?[")


def _stat(path: str, option: str) -> os.stat_result | None:
    """``os.stat`` through symlinks; None when nothing (or a dangling link) is there, or a
    parent is not a folder."""
    try:
        return os.stat(path)
    except (FileNotFoundError, NotADirectoryError):  # the folder check names the cause
        return None
    except OSError as exc:
        raise OutputPathError(f"{option} {path}: cannot write ({exc.strerror or exc})") from None


def _inside(path: str, folder: str) -> bool:
    """Whether the real path ``path`` is ``folder`` or lies below it (both real paths)."""
    return path == folder or path.startswith(folder.rstrip(os.sep) + os.sep)


@dataclass(frozen=True)
class _Seen:
    """An input as found on disk: its real path, identity and whether it is a folder."""

    option: str
    given: str
    real: str
    ident: tuple[int, int]
    folder: bool


def _expand(item: Input) -> list[_Seen]:
    """The files and folders an input names: itself, or a glob pattern's matches and their
    folders."""
    if item.path is None:
        return []
    given = os.fspath(item.path)
    names = [given]
    if not os.path.exists(given) and _GLOB_CHARS & set(given):
        matches = sorted(glob.glob(given))
        names = matches + sorted({os.path.dirname(m) or "." for m in matches})
    seen = []
    for name in names:
        try:
            st = os.stat(name)
        except OSError:
            continue
        seen.append(_Seen(item.option, given, os.path.realpath(name), (st.st_dev, st.st_ino),
                          stat.S_ISDIR(st.st_mode)))
    return seen


def _writable_folder(folder: str, what: str) -> None:
    """``folder`` must be an existing, writable folder (``what`` opens the message)."""
    try:
        st = os.stat(folder)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise OutputPathError(f"{what}: cannot write ({exc.strerror or exc})") from None
    if st is None:
        raise OutputPathError(f"{what}: cannot write: the folder {folder} does not exist")
    if not stat.S_ISDIR(st.st_mode):
        raise OutputPathError(f"{what}: cannot write: {folder} is not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputPathError(f"{what}: cannot write: the folder {folder} is not writable")


def _real_target(path: str) -> str:
    """The real path a write to ``path`` lands on (the path need not exist)."""
    return os.path.realpath(path)


def _writable_parent(path: str, what: str, option: str) -> None:
    """A folder to be created at ``path`` (if missing): its nearest existing parent must be a
    writable folder."""
    parent = os.path.dirname(os.path.abspath(path))
    while parent != os.path.dirname(parent) and _stat(parent, option) is None:
        parent = os.path.dirname(parent)
    _writable_folder(parent, what)


def _check_file(option: str, path: str, inputs: list[_Seen], parents: bool = False) -> None:
    """One file output: regular or absent, in a writable folder (or one to be created, with
    ``parents``), not an input."""
    what = f"{option} {path}"
    folder = os.path.dirname(os.path.abspath(path))
    if parents and _stat(folder, option) is None:
        _writable_parent(folder, what, option)  # nothing there yet: no file, no input
        return
    st = _stat(path, option)
    if st is not None and stat.S_ISDIR(st.st_mode):
        raise OutputPathError(f"{what}: is a folder; give a file name")
    if st is not None and not stat.S_ISREG(st.st_mode):
        raise OutputPathError(f"{what}: is {file_kind(st.st_mode)}, not a regular file; refusing "
                              "to write over it")
    _writable_folder(folder, what)
    if st is None:
        return
    real = _real_target(path)
    for seen in inputs:
        if not seen.folder and seen.ident == (st.st_dev, st.st_ino):
            raise OutputPathError(f"{what}: is the input {seen.option} {seen.given}; choose "
                                  "another file")
        if seen.folder and _inside(real, seen.real):
            raise OutputPathError(f"{what}: lies in the input folder {seen.option} "
                                  f"{seen.given}; choose another file")


def _check_folder(out: Output, inputs: list[_Seen]) -> None:
    """One folder output: a folder or absent under a writable folder, apart from the inputs."""
    path = os.fspath(out.path)
    what = f"{out.option} {path}"
    st = _stat(path, out.option)
    if st is not None and not stat.S_ISDIR(st.st_mode):
        raise OutputPathError(f"{what}: exists and is not a folder")
    if st is None:
        _writable_parent(path, what, out.option)
    else:
        _writable_folder(path, what)
    real = _real_target(path)
    for seen in inputs:
        if seen.folder and _inside(real, seen.real):
            raise OutputPathError(f"{what}: is or lies in the input folder {seen.option} "
                                  f"{seen.given}; choose another folder")
    for seen in inputs:
        if _inside(seen.real, real):
            raise OutputPathError(f"{what}: holds the input {seen.option} {seen.given}; choose "
                                  "another folder")
    if st is not None:
        for name in out.files:
            _check_file(out.option, os.path.join(path, name), inputs)


def check_outputs(outputs: Sequence[Output], inputs: Sequence[Input] = ()) -> None:
    """Refuse, before any work, outputs that must not be written (see the module docstring).

    Args:
        outputs: every output of the run; those whose path is None are skipped.
        inputs: every input of the run (files, folders, glob patterns).

    Raises:
        OutputPathError: one line naming the option and the path.
    """
    seen = [s for item in inputs for s in _expand(item)]
    targets: dict[str, tuple[int, str]] = {}
    for index, out in enumerate(outputs):
        if out.path is None:
            continue
        path = os.fspath(out.path)
        if out.folder:
            _check_folder(out, seen)
            names = [(out.option, path, os.path.join(path, n)) for n in out.files]
            names.append((out.option, path, path))
        else:
            _check_file(out.option, path, seen, out.parents)
            names = [(out.option, path, path)]
        for option, given, name in names:
            real = _real_target(name)
            if real in targets and targets[real][0] != index:
                raise OutputPathError(f"{option} {given}: is also {targets[real][1]}; give each "
                                      "output its own path")
            targets[real] = (index, f"{option} {given}")


def check_script_outputs(parser: argparse.ArgumentParser, outputs: Sequence[Output],
                         inputs: Sequence[Input] = ()) -> None:
    """:func:`check_outputs` for a script with its own parser (``benchmarks/``,
    ``training/``): a refusal is the parser's one-line usage error (exit code 2)."""
    try:
        check_outputs(outputs, inputs)
    except OutputPathError as exc:
        parser.error(str(exc))


def check_own_folder(folder: str | os.PathLike, command: str, option: str = "--out") -> None:
    """Refuse a folder ``command`` may not write into: one that exists and is not a folder, or
    a non-empty folder without ``command``'s marker (a user's folder, or another command's).
    Nothing is created; an absent or empty folder passes.

    Raises:
        OutputPathError: one line naming ``option`` and the folder.
    """
    out = Path(folder)
    if out.exists() and not out.is_dir():
        raise OutputPathError(f"{option} {os.fspath(out)}: exists and is not a folder")
    if out.is_dir() and not is_own_folder(out, command) and any(out.iterdir()):
        raise OutputPathError(f"{option} {os.fspath(out)}: a folder not made by {command} and "
                              "not empty; choose a new or empty folder (nothing was written)")


def claim_folder(folder: str | os.PathLike, command: str, option: str = "--out") -> Path:
    """Make ``folder`` the command's own (after :func:`check_own_folder`): create it if missing
    and leave the marker naming ``command``; a folder already marked is kept as it is."""
    check_own_folder(folder, command, option)
    return mark_own_folder(folder, command)


def plain_name(name: str, what: str) -> str:
    """``name`` if it may name a file: a name from the user's data (a camera, a scene) becomes
    a file name in an output folder, so it must never be a path. Allowed: 1-64 characters of
    letters, digits and ``_ . + -``, starting with a letter or a digit (no ``/``, ``..``,
    absolute path, hidden file, space or control character, the same on every system).

    Raises:
        OutputPathError: one line naming ``what`` (e.g. ``--boxes ../x=cam.txt``) and the rule.
    """
    if not _NAME_CHARS.fullmatch(name):
        raise OutputPathError(f"{what}: the name {name!r} is used as a file name, so it must be "
                              "1-64 letters, digits, '_', '.', '+' or '-', starting with a "
                              "letter or a digit (no '/', no '..')")
    return name

