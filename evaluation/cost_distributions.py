"""Distributions of true and false association costs, before and after normalisation.

Figs. 2 and 3 of the geometric-priors paper show, for every cue, how the costs of the true
associations (same person in both views) and of the false ones are distributed: before
normalisation (Fig. 2: the chi-square BRD of Eq. 3 and the ray distance of Eq. 6 in metres) and
after it (Fig. 3: ``d' = tanh(d)``, Section III-C). The shapes are what the paper uses to choose
the fusion rule (Eq. 8) and the non-association costs gamma (Eq. 2).

This module turns cost samples into per-class histograms (:func:`cost_histogram`, counts a test
can check by hand) and draws them with OpenCV alone (:func:`draw_cost_histograms`: bars, axes,
ticks, a legend), then writes the PNG files atomically (:func:`save_cost_figures`). Bars are the
fraction of each class's pairs per bin, so the rare true pairs stay visible beside the many false
ones; values beyond the drawn range are counted in the end bin and reported in the legend.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from xvmatch.core.atomic_files import atomic_write_bytes

__all__ = [
    "FIGURE_FILES",
    "CostHistogram",
    "CostSamples",
    "cost_figures",
    "cost_histogram",
    "draw_cost_histograms",
    "encode_png",
    "save_cost_figures",
]

FIGURE_FILES: dict[str, str] = {
    "before": "fig2_costs_before_normalisation.png",
    "after": "fig3_costs_after_normalisation.png",
}
"""File names of the two figures written by :func:`save_cost_figures`."""

_TRUE_BGR = (60, 160, 40)  # green
_FALSE_BGR = (40, 40, 210)  # red
_BAR_ALPHA = 0.55
_FONT = 0  # cv2.FONT_HERSHEY_SIMPLEX, without importing cv2 at module import time
_PANEL_SIZE = (520, 340)  # (width, height) of one panel in pixels
_MARGINS = (72, 18, 34, 52)  # left, right, top, bottom of the plot area inside a panel


def _as_costs(values: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(values, dtype=float).reshape(-1)
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} contains NaN or inf; costs must be finite to be histogrammed")
    return arr


@dataclass(frozen=True, eq=False)
class CostSamples:
    """Raw (unnormalised) costs of true and false associations, pooled over image pairs.

    Attributes:
        geo_true: (T,) ray distances of Eq. 6 (world units, metres) of true pairs.
        geo_false: (F,) ray distances of false pairs.
        hist_true: (T',) chi-square BRD distances of Eq. 3 of true pairs (both crops non-empty).
        hist_false: (F',) chi-square BRD distances of false pairs (both crops non-empty).
    """

    geo_true: np.ndarray
    geo_false: np.ndarray
    hist_true: np.ndarray
    hist_false: np.ndarray

    def __post_init__(self) -> None:
        for name in ("geo_true", "geo_false", "hist_true", "hist_false"):
            arr = _as_costs(getattr(self, name), f"CostSamples.{name}")
            if (arr < 0).any():
                raise ValueError(f"CostSamples.{name} has negative distances")
            object.__setattr__(self, name, arr)

    @classmethod
    def from_matrices(
        cls,
        geo: np.ndarray,
        hist: np.ndarray,
        same_person: np.ndarray,
        hist_valid: np.ndarray | None = None,
    ) -> CostSamples:
        """Split the (M, N) raw cost matrices of one image pair into true and false samples.

        Args:
            geo: (M, N) ray distances (Eq. 6).
            hist: (M, N) histogram distances (Eq. 3).
            same_person: (M, N) bool, True where row i and column j are the same person.
            hist_valid: (M, N) bool, False where a crop was empty (its histogram distance is
                meaningless and left out); default all True.

        Returns:
            The samples of this pair.
        """
        geo = np.asarray(geo, dtype=float)
        hist = np.asarray(hist, dtype=float)
        same = np.asarray(same_person, dtype=bool)
        valid = np.ones(same.shape, bool) if hist_valid is None else np.asarray(hist_valid, bool)
        if not geo.shape == hist.shape == same.shape == valid.shape or geo.ndim != 2:
            raise ValueError(
                "geo, hist, same_person and hist_valid must be (M, N) matrices of one shape, got "
                f"{geo.shape}, {hist.shape}, {same.shape}, {valid.shape}"
            )
        return cls(geo[same], geo[~same], hist[same & valid], hist[~same & valid])

    @classmethod
    def concatenate(cls, parts: Sequence[CostSamples]) -> CostSamples:
        """Pool the samples of several image pairs (an empty sequence gives empty samples)."""
        def join(name: str) -> np.ndarray:
            return np.concatenate([getattr(p, name) for p in parts] or [np.empty(0)])

        return cls(join("geo_true"), join("geo_false"), join("hist_true"), join("hist_false"))


@dataclass(frozen=True, eq=False)
class CostHistogram:
    """Per-class histogram of one cost, as drawn in one panel of Figs. 2-3.

    Attributes:
        title: panel title.
        x_label: what the cost is, with its unit.
        edges: (B + 1,) increasing bin edges; bin b is ``[edges[b], edges[b + 1])``, the last
            bin closed.
        true_counts: (B,) number of true pairs per bin.
        false_counts: (B,) number of false pairs per bin.
        true_overflow: true pairs above ``edges[-1]``, already counted in the last bin.
        false_overflow: false pairs above ``edges[-1]``, already counted in the last bin.
    """

    title: str
    x_label: str
    edges: np.ndarray
    true_counts: np.ndarray
    false_counts: np.ndarray
    true_overflow: int
    false_overflow: int

    @property
    def n_true(self) -> int:
        """Number of true pairs."""
        return int(self.true_counts.sum())

    @property
    def n_false(self) -> int:
        """Number of false pairs."""
        return int(self.false_counts.sum())

    def fractions(self) -> tuple[np.ndarray, np.ndarray]:
        """(true, false) fraction of each class's pairs per bin; zeros for an empty class."""
        def frac(counts: np.ndarray) -> np.ndarray:
            total = counts.sum()
            return counts / total if total > 0 else np.zeros(counts.shape)

        return frac(self.true_counts), frac(self.false_counts)


def _nice_step(span: float, target: int) -> float:
    """A 1-2-5 step giving about ``target`` intervals over ``span`` (> 0)."""
    raw = span / max(target, 1)
    power = 10.0 ** math.floor(math.log10(raw))
    for mult in (1.0, 2.0, 2.5, 5.0, 10.0):
        if mult * power >= raw * (1 - 1e-9):
            return mult * power
    return 10.0 * power  # pragma: no cover - the loop always returns


def _nice_upper(value: float) -> float:
    """Smallest 1-2-2.5-5 x 10^k number >= value (> 0)."""
    return _nice_step(value, 1)


def cost_histogram(
    true_costs: np.ndarray,
    false_costs: np.ndarray,
    *,
    bins: int = 30,
    value_range: tuple[float, float] | None = None,
    percentile: float = 99.0,
    title: str = "",
    x_label: str = "cost",
) -> CostHistogram:
    """Histogram the costs of true and false pairs on shared bins (one panel of Figs. 2-3).

    Values outside ``value_range`` are clipped into the end bins (and counted as overflow when
    above it), so every sample is counted exactly once.

    Args:
        true_costs: costs of the true associations, any shape.
        false_costs: costs of the false associations, any shape.
        bins: number of equal-width bins, >= 1.
        value_range: (low, high) of the bins, ``low < high``. Default: from 0 (or the smallest
            value, if negative) to the ``percentile`` of all costs rounded up to a 1-2-2.5-5
            number, so a long tail does not squash the picture; ``(0, 1)`` is the natural range
            of normalised costs.
        percentile: upper percentile used by the default range, in (0, 100].
        title: panel title.
        x_label: axis label, with the unit.

    Returns:
        The :class:`CostHistogram`.

    Raises:
        ValueError: NaN or inf costs, ``bins < 1``, or an empty or reversed ``value_range``.

    Example:
        >>> h = cost_histogram([0.1, 0.2], [0.7, 3.0], bins=2, value_range=(0.0, 1.0))
        >>> h.true_counts.tolist(), h.false_counts.tolist(), h.false_overflow
        ([2, 0], [0, 2], 1)
    """
    t = _as_costs(true_costs, "true_costs")
    f = _as_costs(false_costs, "false_costs")
    if int(bins) < 1:
        raise ValueError(f"bins must be >= 1, got {bins}")
    if value_range is None:
        pooled = np.concatenate([t, f])
        if not 0 < percentile <= 100:
            raise ValueError(f"percentile must be in (0, 100], got {percentile}")
        low = min(0.0, float(pooled.min())) if pooled.size else 0.0
        top = float(np.percentile(pooled, percentile)) if pooled.size else 1.0
        span = top - low
        high = low + (_nice_upper(span) if span > 0 else 1.0)
    else:
        low, high = (float(v) for v in value_range)
        if not (np.isfinite(low) and np.isfinite(high) and low < high):
            raise ValueError(f"value_range must be finite (low, high) with low < high, "
                             f"got {value_range}")
    edges = np.linspace(low, high, int(bins) + 1)

    def counts(values: np.ndarray) -> np.ndarray:
        hist, _ = np.histogram(np.clip(values, low, high), bins=edges)
        return hist.astype(np.int64)

    return CostHistogram(
        title=title,
        x_label=x_label,
        edges=edges,
        true_counts=counts(t),
        false_counts=counts(f),
        true_overflow=int((t > high).sum()),
        false_overflow=int((f > high).sum()),
    )


def _fmt_tick(value: float, step: float) -> str:
    decimals = 0
    while decimals < 6 and abs(step * 10**decimals - round(step * 10**decimals)) > 1e-6:
        decimals += 1
    text = f"{value:.{decimals}f}"
    return "0" if float(text) == 0 else text


def _ticks(low: float, high: float, target: int) -> tuple[np.ndarray, float]:
    step = _nice_step(high - low, target)
    start = math.ceil(low / step - 1e-9) * step
    ticks = np.arange(start, high + step * 1e-6, step)
    return ticks, step


def _put_text(img: np.ndarray, text: str, org: tuple[int, int], scale: float,
              colour=(0, 0, 0), thickness: int = 1, align: str = "left") -> None:
    """Draw ``text`` with its baseline at ``org``; ``align`` left, centre or right of org[0]."""
    import cv2

    (w, _), _ = cv2.getTextSize(text, _FONT, scale, thickness)
    x = org[0] - (w if align == "right" else w // 2 if align == "centre" else 0)
    cv2.putText(img, text, (int(x), int(org[1])), _FONT, scale, colour, thickness, cv2.LINE_AA)


def _vertical_label(img: np.ndarray, text: str, centre: tuple[int, int], scale: float) -> None:
    """Draw ``text`` rotated 90 degrees counter-clockwise, centred on ``centre``."""
    import cv2

    (w, h), base = cv2.getTextSize(text, _FONT, scale, 1)
    strip = np.full((h + base + 4, w + 4, 3), 255, np.uint8)
    cv2.putText(strip, text, (2, h + 2), _FONT, scale, (0, 0, 0), 1, cv2.LINE_AA)
    strip = cv2.rotate(strip, cv2.ROTATE_90_COUNTERCLOCKWISE)
    sh, sw = strip.shape[:2]
    y0 = max(0, min(img.shape[0] - sh, centre[1] - sh // 2))
    x0 = max(0, min(img.shape[1] - sw, centre[0] - sw // 2))
    region = img[y0 : y0 + sh, x0 : x0 + sw]
    np.minimum(region, strip, out=region)  # dark text over the white background


def _blend_bars(img: np.ndarray, rects: list[tuple[int, int, int, int]], colour) -> None:
    """Alpha-blend filled rectangles ``(x0, y0, x1, y1)`` (inclusive) and outline them."""
    import cv2

    mask = np.zeros(img.shape[:2], bool)
    for x0, y0, x1, y1 in rects:
        if y1 >= y0:
            mask[y0 : y1 + 1, x0 : x1 + 1] = True
    tint = np.asarray(colour, float)
    img[mask] = (_BAR_ALPHA * tint + (1 - _BAR_ALPHA) * img[mask]).astype(np.uint8)
    dark = tuple(int(c * 0.6) for c in colour)
    for x0, y0, x1, y1 in rects:
        if y1 > y0:
            cv2.rectangle(img, (x0, y0), (x1, y1), dark, 1)


def _draw_legend(img: np.ndarray, box: tuple[int, int, int, int],
                 lines: list[tuple[str, tuple[int, int, int]]], note: str) -> None:
    """Draw the legend in place: a framed white box, a swatch and text per line, a grey note.

    Args:
        img: the panel, BGR uint8.
        box: ``(x0, y0, x1, y1)`` of the legend box, pixels.
        lines: ``(text, BGR colour)`` of each series.
        note: a last line in grey; empty for none.
    """
    import cv2

    bx0, by0, bx1, by1 = box
    cv2.rectangle(img, (bx0, by0), (bx1, by1), (255, 255, 255), -1)
    cv2.rectangle(img, (bx0, by0), (bx1, by1), (150, 150, 150), 1)
    for k, (text, colour) in enumerate(lines):
        y = by0 + 8 + 20 * k
        swatch = img[y : y + 12, bx0 + 8 : bx0 + 24]
        swatch[:] = (_BAR_ALPHA * np.asarray(colour, float) + (1 - _BAR_ALPHA) * 255).astype(
            np.uint8
        )
        _put_text(img, text, (bx0 + 30, y + 11), 0.42)
    if note:
        _put_text(img, note, (bx0 + 8, by0 + 8 + 20 * len(lines) + 10), 0.38, (90, 90, 90))


def _draw_panel(hist: CostHistogram, size: tuple[int, int]) -> np.ndarray:
    import cv2

    width, height = size
    left, right, top, bottom = _MARGINS
    img = np.full((height, width, 3), 255, np.uint8)
    px0, px1, py0, py1 = left, width - right, top, height - bottom
    low, high = float(hist.edges[0]), float(hist.edges[-1])
    true_frac, false_frac = hist.fractions()
    tallest = np.maximum(true_frac, false_frac)
    x_ticks, x_step = _ticks(low, high, 5)

    def x_px(v: float) -> int:
        return round(float(px0 + (v - low) / (high - low) * (px1 - px0)))

    # Legend: in the top corner whose bars are lowest, with headroom so no bar runs under it.
    lines = [(f"true pairs (n={hist.n_true})", _TRUE_BGR),
             (f"false pairs (n={hist.n_false})", _FALSE_BGR)]
    overflow = hist.true_overflow + hist.false_overflow
    plural = "value" if overflow == 1 else "values"
    note = f"{overflow} {plural} > {_fmt_tick(high, x_step)} in last bin" if overflow else ""
    text_w = max(cv2.getTextSize(t, _FONT, 0.42, 1)[0][0] for t, _ in [*lines, (note, None)])
    box_w, box_h = text_w + 34, 20 * len(lines) + (18 if note else 0) + 8
    bin_x0 = np.array([x_px(e) for e in hist.edges[:-1]])
    bin_x1 = np.array([x_px(e) for e in hist.edges[1:]])
    corners = {"right": (px1 - 6 - box_w, px1 - 6), "left": (px0 + 6, px0 + 6 + box_w)}
    under = {
        side: float(tallest[(bin_x1 > x0) & (bin_x0 < x1)].max(initial=0.0))
        for side, (x0, x1) in corners.items()
    }
    side = min(corners, key=lambda k: (under[k], k != "right"))
    bx0, bx1 = corners[side]
    by0 = py0 + 6
    plot_h = py1 - py0
    free = max(plot_h - (box_h + 16), plot_h // 3)
    y_max = float(tallest.max(initial=0.0))
    need = max(y_max, under[side] * plot_h / free)
    y_ticks, y_step = _ticks(0.0, need if need > 0 else 1.0, 5)
    y_top = float(y_ticks[-1])
    if y_top < need * (1 - 1e-9):
        y_top += y_step
        y_ticks = np.append(y_ticks, y_top)

    def y_px(v: float) -> int:
        return round(float(py1 - v / y_top * plot_h))

    # Grid, then bars (false below true), then axes on top.
    for v in y_ticks:
        cv2.line(img, (px0, y_px(v)), (px1, y_px(v)), (232, 232, 232), 1)
    for frac, colour in ((false_frac, _FALSE_BGR), (true_frac, _TRUE_BGR)):
        rects = [
            (int(bin_x0[b]), y_px(frac[b]), max(int(bin_x1[b]) - 1, int(bin_x0[b])), py1)
            for b in range(frac.size) if frac[b] > 0
        ]
        _blend_bars(img, rects, colour)
    cv2.line(img, (px0, py1), (px1, py1), (0, 0, 0), 1)
    cv2.line(img, (px0, py0), (px0, py1), (0, 0, 0), 1)
    for v in x_ticks:
        x = x_px(v)
        cv2.line(img, (x, py1), (x, py1 + 4), (0, 0, 0), 1)
        _put_text(img, _fmt_tick(v, x_step), (x, py1 + 17), 0.4, align="centre")
    for v in y_ticks:
        y = y_px(v)
        cv2.line(img, (px0 - 4, y), (px0, y), (0, 0, 0), 1)
        _put_text(img, _fmt_tick(v, y_step), (px0 - 7, y + 4), 0.4, align="right")
    _put_text(img, hist.x_label, ((px0 + px1) // 2, height - 10), 0.45, align="centre")
    _vertical_label(img, "fraction of pairs per bin", (16, (py0 + py1) // 2), 0.45)
    _put_text(img, hist.title, ((px0 + px1) // 2, 22), 0.5, thickness=1, align="centre")

    _draw_legend(img, (bx0, by0, bx1, by0 + box_h), lines, note)
    return img


def draw_cost_histograms(
    histograms: Sequence[CostHistogram],
    *,
    title: str = "",
    panel_size: tuple[int, int] = _PANEL_SIZE,
) -> np.ndarray:
    """Draw the panels side by side under a title strip, with OpenCV only.

    Each panel shows the fraction of true (green) and false (red) pairs per bin as translucent
    overlapping bars, x and y axes with ticks and labels, and a legend with the pair counts (and
    the overflow, if any).

    Args:
        histograms: one :class:`CostHistogram` per panel, at least one.
        title: caption drawn above the panels.
        panel_size: (width, height) of each panel in pixels, at least (240, 180).

    Returns:
        (H, W, 3) uint8 BGR picture, ``W = len(histograms) * panel_size[0]``,
        ``H = panel_size[1] + 30`` (the title strip).
    """
    if not histograms:
        raise ValueError("draw_cost_histograms needs at least one histogram")
    width, height = (int(v) for v in panel_size)
    if width < 240 or height < 180:
        raise ValueError(f"panel_size must be at least (240, 180), got {panel_size}")
    panels = [_draw_panel(h, (width, height)) for h in histograms]
    body = np.concatenate(panels, axis=1)
    strip = np.full((30, body.shape[1], 3), 255, np.uint8)
    _put_text(strip, title, (body.shape[1] // 2, 21), 0.55, align="centre")
    return np.concatenate([strip, body], axis=0)


def encode_png(image: np.ndarray) -> bytes:
    """PNG bytes of an (H, W, 3) uint8 BGR image."""
    import cv2

    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.dtype != np.uint8:
        raise ValueError(f"image must be (H, W, 3) uint8, got {arr.shape} {arr.dtype}")
    ok, buf = cv2.imencode(".png", arr, [cv2.IMWRITE_PNG_COMPRESSION, 6])
    if not ok:  # pragma: no cover - OpenCV always encodes a valid uint8 image
        raise OSError("could not encode the PNG")
    return buf.tobytes()


def cost_figures(samples: CostSamples, *, bins: int = 30) -> dict[str, np.ndarray]:
    """The pictures of Figs. 2 and 3 for the histogram and geometric costs.

    ``"before"`` (Fig. 2): raw chi-square BRD (Eq. 3) and ray distance (Eq. 6, metres), each on
    0 .. its 99th percentile; ``"after"`` (Fig. 3): ``tanh`` of both (Section III-C) on [0, 1].

    Args:
        samples: pooled true/false costs.
        bins: bins per panel.

    Returns:
        ``{"before": image, "after": image}``, BGR uint8.
    """
    before = [
        cost_histogram(samples.hist_true, samples.hist_false, bins=bins,
                       title="(a) appearance: colour histogram",
                       x_label="chi-square BRD distance d_hist (Eq. 3)"),
        cost_histogram(samples.geo_true, samples.geo_false, bins=bins,
                       title="(b) geometry: distance between head rays",
                       x_label="ray distance d_geo (Eq. 6), metres"),
    ]
    after = [
        cost_histogram(np.tanh(samples.hist_true), np.tanh(samples.hist_false), bins=bins,
                       value_range=(0.0, 1.0), title="(a) appearance: colour histogram",
                       x_label="d'_hist = tanh(d_hist)"),
        cost_histogram(np.tanh(samples.geo_true), np.tanh(samples.geo_false), bins=bins,
                       value_range=(0.0, 1.0), title="(b) geometry: distance between head rays",
                       x_label="d'_geo = tanh(d_geo)"),
    ]
    return {
        "before": draw_cost_histograms(
            before, title="Fig. 2: true / false association costs before normalisation"),
        "after": draw_cost_histograms(
            after, title="Fig. 3: true / false association costs after normalisation (tanh)"),
    }


def save_cost_figures(
    samples: CostSamples, out_dir: str | os.PathLike, *, bins: int = 30
) -> list[Path]:
    """Write Figs. 2 and 3 as PNG files into ``out_dir`` (created if missing), atomically.

    Args:
        samples: pooled true/false costs.
        out_dir: destination folder.
        bins: bins per panel.

    Returns:
        The written paths, ``out_dir / FIGURE_FILES[key]`` for ``"before"`` then ``"after"``.
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{os.fspath(out)}: exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for key, image in cost_figures(samples, bins=bins).items():
        path = out / FIGURE_FILES[key]
        atomic_write_bytes(path, encode_png(image))
        paths.append(path)
    return paths
