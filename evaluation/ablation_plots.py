"""The ablation's pictures: accuracy along the sweep, cost distributions and disagreements.

* :func:`sweep_figure`: Eq. 9 accuracy against the sweep variable, one line per method with its
  95% interval band (matplotlib, the ``plots`` extra, imported only here and only when drawing;
  :func:`require_matplotlib` checks it up front with a one-line error).
* :func:`cost_figure`: true and false pairs' costs per cue, the panels of Figs. 2-3 of the
  geometric-priors paper (:mod:`xvmatch.evaluation.cost_distributions`, OpenCV).
* :func:`pick_disagreements` and :func:`disagreement_figure`: frames where two rows chose
  different pairs, drawn one above the other with :func:`~xvmatch.viz.match_drawing.
  draw_matches`.

Every file is written atomically.
"""

from __future__ import annotations

import io
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from xvmatch.core.atomic_files import atomic_write_bytes
from xvmatch.evaluation.cost_distributions import (
    CostHistogram,
    draw_cost_histograms,
    encode_png,
)

__all__ = [
    "Disagreement",
    "Series",
    "cost_figure",
    "disagreement_figure",
    "pick_disagreements",
    "require_matplotlib",
    "sweep_figure",
]

_STYLES = {"learned": ("-", 2.2), "handcrafted": ("--", 1.3), "cue": (":", 1.3)}


def require_matplotlib() -> None:
    """Fail early, in one line, when matplotlib (the ``plots`` extra) is missing.

    Raises:
        ValueError: matplotlib cannot be imported.
    """
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise ValueError("the ablation draws its plots with matplotlib, which is not "
                         "installed: pip install 'xvmatch[plots]'") from None


@dataclass(frozen=True)
class Series:
    """One method's line on a sweep plot.

    Attributes:
        label: the legend entry.
        family: ``"learned"``, ``"handcrafted"`` or ``"cue"`` (the line style).
        mean: (P,) mean accuracy at each point.
        low, high: (P,) interval ends (equal to ``mean`` without an interval).
    """

    label: str
    family: str
    mean: np.ndarray
    low: np.ndarray
    high: np.ndarray


def sweep_figure(path: str | os.PathLike, x: Sequence[float], series: Sequence[Series], *,
                 title: str, x_label: str, y_label: str = "Eq. 9 accuracy (%)") -> Path:
    """Draw accuracy against the sweep variable, one line and band per method, as a PNG.

    Args:
        path: the PNG file.
        x: (P,) the sweep's points, increasing.
        series: the lines.
        title, x_label, y_label: captions.

    Returns:
        The path written.
    """
    require_matplotlib()
    import matplotlib

    matplotlib.use("Agg", force=True)
    from matplotlib import pyplot as plt

    colours = plt.get_cmap("tab20")
    fig, ax = plt.subplots(figsize=(11.0, 6.0), dpi=110)
    try:
        for k, s in enumerate(series):
            style, width = _STYLES.get(s.family, ("-", 1.3))
            colour = colours(k % 20)
            ax.plot(x, s.mean, style, color=colour, linewidth=width, marker="o",
                    markersize=3.5, label=s.label)
            ax.fill_between(x, s.low, s.high, color=colour, alpha=0.12, linewidth=0)
        ax.set_xticks(list(x))
        ax.set_xlabel(x_label)
        ax.set_ylabel(y_label)
        ax.set_title(title)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=8, frameon=False)
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png", metadata={"Software": None})
    finally:
        plt.close(fig)
    path = Path(path)
    atomic_write_bytes(path, buf.getvalue())
    return path


def cost_figure(path: str | os.PathLike, panels: Sequence[tuple[str, str, Sequence[int],
                                                                 Sequence[int]]],
                *, title: str) -> Path:
    """Draw per-cue true/false cost histograms on [0, 1] (Figs. 2-3 style) as a PNG.

    Args:
        path: the PNG file.
        panels: ``(title, x label, true counts, false counts)`` per cue, equal bins on [0, 1].
        title: caption above the panels.

    Returns:
        The path written.
    """
    hists = []
    for name, x_label, true_counts, false_counts in panels:
        t = np.asarray(true_counts, np.int64)
        hists.append(CostHistogram(title=name, x_label=x_label,
                                   edges=np.linspace(0.0, 1.0, t.size + 1), true_counts=t,
                                   false_counts=np.asarray(false_counts, np.int64),
                                   true_overflow=0, false_overflow=0))
    image = draw_cost_histograms(hists, title=title, panel_size=(420, 300))
    path = Path(path)
    atomic_write_bytes(path, encode_png(image))
    return path


@dataclass(frozen=True)
class Disagreement:
    """A frame of a cell where two rows' pairs differ.

    Attributes:
        cell: the cell's name.
        index: the frame's position among the cell's test frames.
        scene, frame: which image pair.
        acc_a, acc_b: the two rows' Eq. 9 accuracy on it (fractions).
    """

    cell: str
    index: int
    scene: str
    frame: int
    acc_a: float
    acc_b: float


def pick_disagreements(cells: Sequence[tuple[str, dict]], row_a: str, row_b: str | Sequence[str],
                       n: int = 4) -> list[Disagreement]:
    """Frames where ``row_a`` and ``row_b`` chose different pairs, the largest accuracy gaps
    first, alternating frames where ``row_a`` is better and where ``row_b`` is, as far as each
    side has them.

    Args:
        cells: ``(name, record)`` of the cells to look in.
        row_a: a row key.
        row_b: a row key, or one per cell (the best other row of that cell's column).
        n: how many frames at most.
    """
    wins: list[Disagreement] = []
    losses: list[Disagreement] = []
    for k, (name, rec) in enumerate(cells):
        other = row_b if isinstance(row_b, str) else row_b[k]
        a, b = rec["rows"][row_a], rec["rows"][other]
        for i, (scene, frame) in enumerate(rec["frames"]):
            if sorted(map(tuple, a["pairs"][i])) == sorted(map(tuple, b["pairs"][i])):
                continue
            d = Disagreement(name, i, scene, int(frame), a["frame_acc9"][i], b["frame_acc9"][i])
            (wins if d.acc_a >= d.acc_b else losses).append(d)
    wins.sort(key=lambda d: (d.acc_b - d.acc_a, d.cell, d.index))
    losses.sort(key=lambda d: (d.acc_a - d.acc_b, d.cell, d.index))
    out: list[Disagreement] = []
    while len(out) < n and (wins or losses):
        for side in (wins, losses):
            if side and len(out) < n:
                out.append(side.pop(0))
    return out


def disagreement_figure(path: str | os.PathLike, images: dict[str, np.ndarray],
                        boxes: dict[str, np.ndarray], ids: dict[str, np.ndarray],
                        pairs: Sequence[np.ndarray], titles: Sequence[str]) -> Path:
    """Draw the same frame once per method (one above the other) with their pairs.

    Args:
        path: the PNG file.
        images, boxes, ids: per view (``"top"``, ``"ego"``): image, ``(K, 4)`` boxes and the
            label printed by each box.
        pairs: per method, ``(P, 2)`` (top row, ego column) pairs.
        titles: per method, the header line.

    Returns:
        The path written.
    """
    from xvmatch.viz.match_drawing import draw_matches

    panels = [draw_matches(images["top"], images["ego"], boxes["top"], boxes["ego"],
                           np.asarray(p, np.int64).reshape(-1, 2), ids["top"], ids["ego"],
                           title=t, max_height=360) for p, t in zip(pairs, titles, strict=True)]
    width = max(p.shape[1] for p in panels)
    padded = [np.pad(p, ((0, 8), (0, width - p.shape[1]), (0, 0)), constant_values=255)
              for p in panels]
    path = Path(path)
    atomic_write_bytes(path, encode_png(np.concatenate(padded, axis=0)))
    return path
