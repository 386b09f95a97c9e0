"""The ablation's results as files: one row per (scenario, column, seed, method), the mean and
95% interval over seeds, and ``report.md`` with a table per data folder.

:func:`result_rows` flattens the cell records; :func:`summarise` gives every (scenario, column,
method) its :class:`~xvmatch.metrics.confidence.MeanInterval` over seeds;
:func:`target_check` compares the learned fusion with the best non-learned row of each column
(paired over seeds: both are measured on the same frames); :func:`format_report` writes the
Markdown and :func:`write_results` the CSV and JSON files.
"""

from __future__ import annotations

import csv
import io
import json
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from xvmatch.core.atomic_files import atomic_write_text
from xvmatch.evaluation.ablation_cvmhat import CVMHAT_ROWS, CVMHAT_SETTINGS
from xvmatch.evaluation.ablation_methods import FAMILIES, LEARNED_FUSION, ROWS, row_by_key
from xvmatch.evaluation.ablation_settings import SWEEP_AXES, Setting
from xvmatch.metrics.confidence import MeanInterval, mean_interval

__all__ = [
    "CSV_COLUMNS",
    "ReportContext",
    "TargetCheck",
    "format_report",
    "result_rows",
    "summarise",
    "target_check",
    "write_results",
]

CSV_COLUMNS: tuple[str, ...] = (
    "scenario", "data", "setting", "setting_label", "sweep_value", "seed", "method",
    "method_label", "family", "gamma", "acc9", "cvidf1", "cvma", "test_pairs", "val_pairs",
)
"""Columns of ``results.csv`` (and keys of each row of ``results.json``); scores in percent,
``cvma`` only on CVMHAT, ``gamma`` empty for the search."""


@dataclass(frozen=True, eq=False)
class ReportContext:
    """What the report says about the run besides the numbers.

    Attributes:
        command: the command line.
        versions: ``{name: version}`` of xvmatch, numpy, onnxruntime, matplotlib.
        bundle: what the bundle's manifest says (name, format, feature version, gamma, cues).
        sweep: the sweep's name.
        seeds: the seeds.
        scenarios: per data folder: label, folder, scenario, scenes, test and validation pairs.
        settings: the columns, in order.
        cvmhat: the CVMHAT folder and frame step, or None.
        cell_seconds: compute time summed over the cells (as stored in them).
        figures: ``{kind: [relative paths]}`` of the pictures written.
    """

    command: str
    versions: Mapping[str, str]
    bundle: Mapping[str, object]
    sweep: str
    seeds: Sequence[int]
    scenarios: Sequence[Mapping[str, object]]
    settings: Sequence[Setting]
    cvmhat: Mapping[str, object] | None
    cell_seconds: float
    figures: Mapping[str, Sequence[str]]


def result_rows(records: Sequence[dict], settings: Sequence[Setting]) -> list[dict]:
    """One row per (scenario, column, seed, method) of the cell records, in the order scenario,
    column (``settings`` order; CVMHAT clean, det), seed, method (table order)."""
    by_key = {s.key: s for s in settings}
    order = {s.key: k for k, s in enumerate(settings)}
    rows = []
    for rec in records:
        cvmhat = rec["scenario"] == "cvmhat"
        setting = by_key.get(rec["setting"])
        keys = list(CVMHAT_ROWS) if cvmhat else [r.key for r in ROWS]
        for key in keys:
            r = rec["rows"][key]
            label = CVMHAT_ROWS[key] if cvmhat else row_by_key(key).label
            family = "learned" if key.startswith("learned") else (
                "cue" if cvmhat else row_by_key(key).family)
            rows.append({
                "scenario": rec["scenario"],
                "data": rec["data"],
                "setting": rec["setting"],
                "setting_label": CVMHAT_SETTINGS[rec["setting"]] if cvmhat else setting.label,
                "sweep_value": None if cvmhat else setting.sweep_value,
                "seed": rec["seed"],
                "method": key,
                "method_label": label,
                "family": family,
                "gamma": r["gamma"],
                "acc9": r["acc9"],
                "cvidf1": r["cvidf1"],
                "cvma": r.get("cvma"),
                "test_pairs": rec["n_frames"] if cvmhat else len(rec["frames"]),
                "val_pairs": None if cvmhat else rec["n_val"],
            })
    method_order = {k: i for i, k in enumerate([*[r.key for r in ROWS], *CVMHAT_ROWS])}
    cv_order = {k: i for i, k in enumerate(CVMHAT_SETTINGS)}
    rows.sort(key=lambda r: (r["scenario"] == "cvmhat", r["scenario"],
                             cv_order.get(r["setting"], order.get(r["setting"], 0)), r["seed"],
                             method_order[r["method"]]))
    return rows


def summarise(rows: Sequence[dict], metric: str = "acc9"
              ) -> dict[tuple[str, str, str], MeanInterval]:
    """``{(scenario, setting, method): mean and 95% interval over seeds of metric}``."""
    values: dict[tuple[str, str, str], list[float]] = {}
    for r in rows:
        values.setdefault((r["scenario"], r["setting"], r["method"]), []).append(r[metric])
    return {k: mean_interval(v) for k, v in values.items()}


@dataclass(frozen=True)
class TargetCheck:
    """The learned fusion against the best non-learned row of one column.

    Attributes:
        scenario, setting: the column.
        learned: the learned fusion's mean Eq. 9 accuracy.
        best_key: the best non-learned row (highest mean).
        best: its mean.
        margin: learned minus best, mean and 95% interval paired over seeds.
    """

    scenario: str
    setting: str
    learned: float
    best_key: str
    best: float
    margin: MeanInterval

    @property
    def above(self) -> bool:
        """The learned fusion's mean is above every non-learned row's."""
        return self.learned > self.best


def target_check(rows: Sequence[dict]) -> list[TargetCheck]:
    """:class:`TargetCheck` of every synthetic column, in the rows' order."""
    summary = summarise(rows)
    per_seed: dict[tuple[str, str, str], dict[int, float]] = {}
    columns: list[tuple[str, str]] = []
    for r in rows:
        if r["scenario"] == "cvmhat":
            continue
        if (r["scenario"], r["setting"]) not in columns:
            columns.append((r["scenario"], r["setting"]))
        per_seed.setdefault((r["scenario"], r["setting"], r["method"]), {})[r["seed"]] = r["acc9"]
    out = []
    for scenario, setting in columns:
        baselines = [row.key for row in ROWS if row.family != "learned"]
        best = max(baselines, key=lambda k: summary[(scenario, setting, k)].mean)
        learned = per_seed[(scenario, setting, LEARNED_FUSION)]
        other = per_seed[(scenario, setting, best)]
        diffs = [learned[s] - other[s] for s in sorted(learned)]
        out.append(TargetCheck(scenario, setting, summary[(scenario, setting, LEARNED_FUSION)].mean,
                               best, summary[(scenario, setting, best)].mean,
                               mean_interval(diffs)))
    return out


def _csv_text(rows: Sequence[dict]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=CSV_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: "" if r[k] is None else (f"{r[k]:.4f}" if isinstance(r[k], float)
                                                      else r[k]) for k in CSV_COLUMNS})
    return buf.getvalue()


def write_results(report: str | os.PathLike, rows: Sequence[dict], context: ReportContext
                  ) -> list[Path]:
    """Write ``results.csv`` and ``results.json`` (the rows, the summary, the run's command,
    versions and bundle) into ``report``, atomically."""
    report = Path(report)
    summary = summarise(rows)
    f1 = summarise(rows, "cvidf1")
    doc = {
        "command": context.command,
        "versions": dict(context.versions),
        "bundle": dict(context.bundle),
        "sweep": context.sweep,
        "seeds": list(context.seeds),
        "confidence": 0.95,
        "rows": list(rows),
        "summary": [
            {"scenario": k[0], "setting": k[1], "method": k[2], "n_seeds": v.n,
             "acc9_mean": v.mean, "acc9_half_width": v.half_width,
             "cvidf1_mean": f1[k].mean, "cvidf1_half_width": f1[k].half_width}
            for k, v in summary.items()
        ],
    }
    paths = [report / "results.csv", report / "results.json"]
    atomic_write_text(paths[0], _csv_text(rows))
    atomic_write_text(paths[1], json.dumps(doc, indent=1) + "\n")
    return paths


def _cell(m: MeanInterval) -> str:
    text = f"{m.mean:.1f}"
    return text if m.half_width is None else f"{text} ± {m.half_width:.1f}"


def _table(scenario: str, settings: Sequence[tuple[str, str]], methods: Sequence[tuple[str, str]],
           summary: Mapping[tuple[str, str, str], MeanInterval]) -> list[str]:
    """A Markdown table: rows ``methods`` (key, label), columns ``settings`` (key, label); the
    best mean of each column (to the shown decimal) in bold."""
    lines = ["| method | " + " | ".join(label for _, label in settings) + " |",
             "|---|" + "---|" * len(settings)]
    best = {s: max(round(summary[(scenario, s, m)].mean, 1) for m, _ in methods)
            for s, _ in settings}
    for key, label in methods:
        cells = []
        for s, _ in settings:
            m = summary[(scenario, s, key)]
            text = _cell(m)
            cells.append(f"**{text}**" if round(m.mean, 1) == best[s] else text)
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return lines


def _gammas(rows: Sequence[dict], scenario: str, setting: str) -> str:
    """The tuned gammas of a column, per row, across seeds (``0.6`` or ``0.55-0.7``)."""
    found: dict[str, list[float]] = {}
    for r in rows:
        if r["scenario"] == scenario and r["setting"] == setting and r["gamma"] is not None:
            if row_by_key(r["method"]).gamma == "tuned":
                found.setdefault(r["method"], []).append(r["gamma"])
    parts = []
    for key, values in found.items():
        low, high = min(values), max(values)
        parts.append(f"{key} {low:g}" if low == high else f"{key} {low:g}-{high:g}")
    return "; ".join(parts)


def _run_lines(context: ReportContext, interval: str) -> list[str]:
    """The report's title, the command and versions that made it, and the protocol."""
    v = context.versions
    b = context.bundle
    return [
        "# Ablation: learned against handcrafted fusion",
        "",
        "Made by",
        "",
        "```",
        context.command,
        "```",
        "",
        f"xvmatch {v['xvmatch']}, numpy {v['numpy']}, onnxruntime {v['onnxruntime']}, "
        f"matplotlib {v['matplotlib']}; bundle `{b['name']}` (format {b['format']} version "
        f"{b['format_version']}, geometry feature version {b['feature_version']}, gamma "
        f"{b['gamma']:g}, cues {', '.join(b['cues'])}). Compute time of the cells: "
        f"{context.cell_seconds:.0f} s (summed over cells; the wall time of a run is printed "
        "at its end).",
        "",
        "## Protocol",
        "",
        "* Data: each folder's scenes; every 5th scene (s00004, s00009, ...; the last scene of a "
        "folder with fewer than 5) is the validation split, the others the test split. Every "
        "number is on the test split; tuned gammas are chosen on the validation split of the "
        "same column and seed (grid 0.05, 0.10, ..., 1.0, best mean Eq. 9 accuracy, middle of "
        "ties). The learned rows use the bundle's gamma.",
        "* Columns: ground-truth boxes (GT), the default detector noise (5% box jitter, 10% "
        "misses growing with occlusion, 0.3 false boxes per frame and view; detections take "
        "the id of the ground-truth box with IoU >= 0.3), and the sweep "
        f"`{context.sweep}`: {SWEEP_AXES[context.sweep]}"
        + {"noise": "; x0 (no jitter, misses or false boxes) is the GT column, x1 the "
                    "detector-noise column.",
           "calibration": "; both cameras, a random rotation axis and direction per scene "
                          "and camera, on GT boxes; 0 is the GT column.",
           "crowd": "; scenes rendered for each point with the folder's settings (into "
                    "REPORT/data/), GT boxes.",
           "lookalike": "; scenes rendered for each point with the folder's settings (into "
                        "REPORT/data/), GT boxes."}[context.sweep],
        f"* Seeds: {', '.join(str(s) for s in context.seeds)}. A seed changes the detector "
        "noise, the shuffling of the boxes (ids scrambled per frame and view: no method sees an "
        "id), the calibration error and the rendered scenes of the crowd and look-alike sweeps. "
        f"Every method of a column is measured on the same frames. Cells: {interval}.",
        "* Scores: the Eq. 9 accuracy of the geometric-priors paper (percent, mean over image "
        "pairs) and CVIDF1 (percent); the best mean of each column in bold. `results.csv` and "
        "`results.json` hold every (method, column, seed).",
        "",
    ]


def _scenario_lines(rows: Sequence[dict], context: ReportContext, interval: str,
                    summary: dict[tuple[str, str, str], MeanInterval],
                    f1: dict[tuple[str, str, str], MeanInterval]) -> list[str]:
    """One section per data folder: its Eq. 9 and CVIDF1 tables and the tuned gammas."""
    lines: list[str] = []
    col_sets = [(s.key, s.label) for s in context.settings]
    methods = [(r.key, r.label) for r in ROWS]
    for sc in context.scenarios:
        label = str(sc["label"])
        lines += [
            f"## {label}",
            "",
            f"`{sc['data']}`: {sc['scenario']} scenario, {sc['scenes']} scenes, "
            f"{sc['test_pairs']} test pairs and {sc['val_pairs']} validation pairs per column "
            "and seed.",
            "",
            f"Eq. 9 accuracy (%), {interval}:",
            "",
            *_table(label, col_sets, methods, summary),
            "",
            "CVIDF1 (%):",
            "",
            *_table(label, col_sets, methods, f1),
            "",
            "Tuned gammas (min-max over seeds), "
            + "; ".join(f"{s.label}: {_gammas(rows, label, s.key)}"
                        for s in context.settings[:2]) + ".",
            "",
        ]
    return lines


def _target_lines(rows: Sequence[dict], context: ReportContext) -> list[str]:
    """The learned fusion against the best non-learned row of each column (none: no lines)."""
    lines: list[str] = []
    checks = target_check(rows)
    if checks:
        lines += [
            "## Learned fusion against the best non-learned row",
            "",
            "The learned fusion (images + cameras) against the best non-learned row of each "
            "column (single cues, the CVMHAT search and the handcrafted rules, tuned gammas "
            "included); margin in Eq. 9 points, paired over seeds.",
            "",
            "| data | column | learned fusion | best non-learned row | its accuracy | margin | "
            "above? |",
            "|---|---|---|---|---|---|---|",
        ]
        labels = {s.key: s.label for s in context.settings}
        for c in checks:
            lines.append(f"| {c.scenario} | {labels[c.setting]} | {c.learned:.1f} | "
                         f"{row_by_key(c.best_key).label} | {c.best:.1f} | {_cell(c.margin)} | "
                         f"{'yes' if c.above else '**no**'} |")
        below = [c for c in checks if not c.above]
        lines += ["", (f"The learned fusion is above every non-learned row in all "
                       f"{len(checks)} columns." if not below else
                       f"The learned fusion is not above every non-learned row in "
                       f"{len(below)} of {len(checks)} columns: "
                       + "; ".join(f"{c.scenario} {labels[c.setting]} "
                                   f"({row_by_key(c.best_key).label})" for c in below) + "."),
                  ""]
        fam = ", ".join(f"{k}: {v}" for k, v in FAMILIES.items())
        lines += [f"Row families ({fam}).", ""]
    return lines


def _cvmhat_lines(context: ReportContext, interval: str,
                  summary: dict[tuple[str, str, str], MeanInterval],
                  f1: dict[tuple[str, str, str], MeanInterval]) -> list[str]:
    """The real CVMHAT boxes' tables (no lines when the run had none)."""
    lines: list[str] = []
    if context.cvmhat is not None:
        cv = context.cvmhat
        cv_sets = list(CVMHAT_SETTINGS.items())
        cv_methods = list(CVMHAT_ROWS.items())
        lines += [
            "## Real CVMHAT boxes (boxes only)",
            "",
            f"`{cv['folder']}`: {cv['sequences']} sequence "
            f"pair{'s' if cv['sequences'] != 1 else ''}, "
            + ("every frame" if cv["step"] == 1 else f"one frame in {cv['step']}")
            + f" ({cv['frames']} frames per column and seed; `--cvmhat-step`), frame mode, O "
            "searched, ids scrambled per view; detector noise as above (uniform misses). "
            f"CVIDF1 (%), {interval}:",
            "",
            *_table("cvmhat", cv_sets, cv_methods, f1),
            "",
            "Eq. 9 accuracy (%):",
            "",
            *_table("cvmhat", cv_sets, cv_methods, summary),
            "",
        ]
    return lines


def _figure_lines(context: ReportContext) -> list[str]:
    """The pictures, under one caption per kind (no lines when there are none)."""
    lines: list[str] = []
    figures = context.figures
    if any(figures.values()):
        lines += ["## Pictures", ""]
        titles = {"sweep": "Eq. 9 accuracy along the sweep (band: 95% interval over seeds)",
                  "costs": "True and false pairs' costs per cue (Figs. 2-3 of the "
                           "geometric-priors paper; normalised costs, test pairs, all seeds)",
                  "examples": "Frames where the learned fusion and the best non-learned row "
                              "disagree (seed 0; box labels: the ground-truth id each box "
                              "stands for, -1 a false box)"}
        for kind, paths in figures.items():
            if paths:
                lines += [f"{titles[kind]}:", ""]
                lines += [f"![{Path(p).stem}]({p})" for p in paths]
                lines.append("")
    return lines


def format_report(rows: Sequence[dict], context: ReportContext) -> str:
    """``report.md``: the run, the protocol, a table per data folder (Eq. 9 accuracy and
    CVIDF1), the target check, the CVMHAT table and the pictures."""
    summary = summarise(rows)
    f1 = summarise(rows, "cvidf1")
    n_seeds = len(context.seeds)
    interval = ("mean ± half-width of the 95% Student t interval over the "
                f"{n_seeds} seeds" if n_seeds > 1 else
                "one seed: single values, no interval (run with --seeds 2 or more for one)")
    lines = [*_run_lines(context, interval),
             *_scenario_lines(rows, context, interval, summary, f1),
             *_target_lines(rows, context),
             *_cvmhat_lines(context, interval, summary, f1),
             *_figure_lines(context)]
    return "\n".join(lines).rstrip() + "\n"

