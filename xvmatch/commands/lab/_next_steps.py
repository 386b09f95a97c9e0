"""The commands ``synth`` prints after writing data: the ``track``, ``associate``,
``associate-multi`` and ``evaluate`` lines that run on what it wrote, ready to paste (as ``demo``
prints its own). Imports only the standard library and :mod:`xvmatch.commands.demo`.
"""

from __future__ import annotations

import shlex
import sys
from collections.abc import Sequence
from pathlib import Path

__all__ = ["print_commands", "print_multi_commands"]


def _print(lines: list[str]) -> None:
    """The lines, each indented by two spaces, on stderr (beside the summary line)."""
    print("\n".join(f"  {line}" for line in lines), file=sys.stderr)


def _x() -> str:
    """How to run this xvmatch from a shell (:func:`xvmatch.commands.demo.xvmatch_command`)."""
    from xvmatch.commands.demo import xvmatch_command

    return xvmatch_command()


def print_commands(scene: Path, pred: Path, images: tuple[Path, Path], cameras: Path,
                   track: Sequence | None = None) -> None:
    """The commands that run on a scene written as ``scene/top.txt`` and ``scene/hor.txt``:
    ``track`` with the options ``track`` (if given; its last is the output folder) and
    ``evaluate --tracks``, then ``associate --model default`` on the images (top, horizontal)
    and cameras, and ``evaluate --pred``."""
    x, q = _x(), (lambda path: shlex.quote(str(path)))
    boxes = f"--top {q(scene / 'top.txt')} --hor {q(scene / 'hor.txt')}"
    lines = [] if track is None else [
        f"{x} track {boxes} {shlex.join(map(str, track))}",
        f"{x} evaluate --tracks {q(track[-1])} {boxes}"]
    lines += [f"{x} associate {boxes} --model default --top-images {q(images[0])} --hor-images "
              f"{q(images[1])} --cameras {q(cameras)} --out {q(pred)}",
              f"{x} evaluate --pred {q(pred)} {boxes}"]
    _print(lines)


def print_multi_commands(boxes: Sequence[Path], images: Sequence[Path],
                         cameras: Sequence[Path], out: Path) -> None:
    """The ``associate-multi`` command that runs on a scene of one top and several egocentric
    views (box files, image folders and camera folders, top first for the first two), and the
    ``evaluate`` command that scores its output against the scene's ids, every pair of views."""
    def join(paths: Sequence[Path]) -> str:
        return shlex.join(map(str, paths))

    names = [Path(b).stem for b in boxes]
    pred = join([f"{n}={out / Path(b).name}" for n, b in zip(names, boxes, strict=True)])
    gt = join([f"{n}={b}" for n, b in zip(names, boxes, strict=True)])
    _print([f"{_x()} associate-multi --model default --top {join(boxes[:1])} --hor "
            f"{join(boxes[1:])} --top-images {join(images[:1])} --hor-images {join(images[1:])} "
            f"--cameras {join(cameras)} --out {join([out])}",
            f"{_x()} evaluate --pred {pred} --gt {gt}"])
