"""Locating and reading the CVMHAT dev split (box files only; never shipped with the project)."""

from __future__ import annotations

import os
import re
import warnings
from pathlib import Path

from xvmatch.formats.mot_boxes import FrameBoxes, read_mot_boxes

__all__ = ["IMAGE_SIZE", "default_cvmhat_dir", "read_sequence", "sequence_names", "site_of"]

IMAGE_SIZE = (2688, 1512)
"""Width and height of both CVMHAT views, in pixels."""


def default_cvmhat_dir() -> Path:
    """``$XVMATCH_CVMHAT`` if set, else ``../shared/data/cvmhat`` beside the repository."""
    env = os.environ.get("XVMATCH_CVMHAT")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2] / "shared" / "data" / "cvmhat"


def sequence_names(folder: str | os.PathLike) -> list[str]:
    """Names of the sequence pairs in ``folder`` (files ``NAME_top.txt`` with ``NAME_hor.txt``)."""
    folder = Path(folder)
    return sorted(
        p.name[: -len("_top.txt")]
        for p in folder.glob("*_top.txt")
        if (folder / p.name.replace("_top.txt", "_hor.txt")).exists()
    )


def site_of(name: str) -> str:
    """Site of a CVMHAT sequence name: ``V0-S_canteen_0-G_1`` -> ``canteen``."""
    match = re.search(r"S_([A-Za-z0-9]+)", name)
    if not match:
        raise ValueError(f"cannot read the site of sequence {name!r} (expected '...S_<site>...')")
    return match.group(1)


def read_sequence(
    folder: str | os.PathLike, name: str, quiet: bool = True
) -> tuple[dict[int, FrameBoxes], dict[int, FrameBoxes]]:
    """Top and horizontal boxes of one sequence pair.

    A repeated (frame, id) keeps its first box (three real files have one); ``quiet`` silences
    the warning that names it.
    """
    folder = Path(folder)
    with warnings.catch_warnings():
        if quiet:
            warnings.simplefilter("ignore")
        top = read_mot_boxes(folder / f"{name}_top.txt", duplicates="first")
        hor = read_mot_boxes(folder / f"{name}_hor.txt", duplicates="first")
    return top, hor
