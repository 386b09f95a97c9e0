"""Reading Lightning checkpoint files safely: weights only, and only from the run's own folder.

A checkpoint given to resume a run is trusted (Lightning itself unpickles it), but the paths
stored inside it are not: a resumed ``ModelCheckpoint`` takes its ``best_model_path`` from the
file, so a crafted checkpoint could point the end-of-training reload anywhere. Every reload
here goes through PyTorch's weights-only unpickler, and a best-model path outside the
callback's own ``dirpath`` is refused.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch

__all__ = [
    "best_checkpoint_path",
    "check_checkpoint_file",
    "load_checkpoint_file",
    "load_checkpoint_state",
]


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return f"{type(exc).__name__}: {text.splitlines()[0]}" if text else type(exc).__name__


def load_checkpoint_file(path: str | os.PathLike) -> dict[str, Any]:
    """The dict stored in a checkpoint file, read with ``weights_only=True``.

    Raises:
        ValueError: missing, truncated or corrupt file, or one holding pickled objects other
            than tensors and plain containers (one line naming the file).
    """
    where = os.fspath(path)
    if not Path(path).is_file():
        raise ValueError(f"{where}: no such checkpoint file")
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # zip, pickle and weights-only errors: not a checkpoint we read
        raise ValueError(f"{where}: not a readable checkpoint ({_first_line(exc)})") from None
    if not isinstance(blob, dict):
        raise ValueError(f"{where}: not a Lightning checkpoint (expected a dict)")
    return blob


def check_checkpoint_file(path: str | os.PathLike) -> None:
    """Refuse a checkpoint that cannot be read before a run resumes from it (one line)."""
    blob = load_checkpoint_file(path)
    if not isinstance(blob.get("state_dict"), dict):
        raise ValueError(f"{os.fspath(path)}: not a Lightning checkpoint (no state_dict); "
                         "delete it to start the run afresh")


def load_checkpoint_state(path: str | os.PathLike) -> dict[str, torch.Tensor]:
    """The ``state_dict`` of a Lightning checkpoint, read with ``weights_only=True``."""
    blob = load_checkpoint_file(path)
    state = blob.get("state_dict")
    if not isinstance(state, dict):
        raise ValueError(f"{os.fspath(path)}: not a Lightning checkpoint (no state_dict)")
    return state


def best_checkpoint_path(callback: Any) -> Path | None:
    """The best checkpoint of a ``ModelCheckpoint``, None without one.

    Raises:
        ValueError: the stored path lies outside the callback's own ``dirpath`` (a path read
            back from a resumed checkpoint is not trusted).
    """
    best = getattr(callback, "best_model_path", "") if callback is not None else ""
    if not best:
        return None
    path = Path(best)
    dirpath = getattr(callback, "dirpath", None)
    if dirpath is None:
        raise ValueError(f"refusing best checkpoint {os.fspath(path)}: the checkpoint callback "
                         "has no folder of its own")
    folder = Path(dirpath).resolve()
    if not path.resolve().is_relative_to(folder):
        raise ValueError(f"refusing best checkpoint {os.fspath(path)}: outside the run's "
                         f"checkpoint folder {os.fspath(folder)}")
    return path
