"""The ablation (``xvmatch ablate``): learned against handcrafted fusion, cue by cue, with
uncertainty, as a report with tables and plots.

The grid is data folders x columns x seeds (:mod:`~xvmatch.evaluation.ablation_settings`), plus
the CVMHAT columns x seeds when a CVMHAT folder is given (:mod:`~xvmatch.evaluation.
ablation_cvmhat`); every cell scores every row (:mod:`~xvmatch.evaluation.ablation_methods`) on
the same frames (:mod:`~xvmatch.evaluation.ablation_cells`). :func:`run_ablation` plans the grid
and checks every input before any work (:func:`plan_ablation`), reuses the cells already stored in
the report folder (refusing cells of other options), computes the others in ``workers`` spawned
processes (each cell on its own, so the numbers do not depend on the number of processes), stores
each as soon as it is done, then writes ``report.md``, ``results.csv``, ``results.json`` and the
pictures (:mod:`~xvmatch.evaluation.ablation_report`, :mod:`~xvmatch.evaluation.ablation_plots`).
"""

from __future__ import annotations

import hashlib
import os
import re
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import as_completed
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from xvmatch.core.atomic_files import atomic_write_text
from xvmatch.core.folder_marker import MARKER, is_own_folder, mark_own_folder
from xvmatch.core.worker_pool import worker_pool
from xvmatch.datasets.pair_trials import open_dataset
from xvmatch.evaluation.ablation_cells import (
    DISTRIBUTION_ROWS,
    CellSpec,
    check_cells,
    compute_cell,
    frame_sample,
    load_cells,
    save_cell,
    validation_mask,
)
from xvmatch.evaluation.ablation_cvmhat import CVMHAT_SETTINGS, CvmhatSpec, compute_cvmhat_cell
from xvmatch.evaluation.ablation_methods import LEARNED_FUSION, ROWS, row_by_key
from xvmatch.evaluation.ablation_plots import (
    Series,
    cost_figure,
    disagreement_figure,
    pick_disagreements,
    require_matplotlib,
    sweep_figure,
)
from xvmatch.evaluation.ablation_report import (
    ReportContext,
    TargetCheck,
    format_report,
    result_rows,
    summarise,
    target_check,
    write_results,
)
from xvmatch.evaluation.ablation_settings import SWEEP_AXES, SWEEPS, Setting, grid_settings
from xvmatch.inference.matching.learned_association import LearnedMatcher, load_matcher_bundle

REPORT_COMMAND = "xvmatch ablate"
"""The command named in the marker (:mod:`xvmatch.core.folder_marker`) that ``ablate``
leaves in a report folder it made; it replaces only such a folder."""

__all__ = [
    "MAX_SEEDS",
    "AblationOptions",
    "AblationPlan",
    "AblationRun",
    "check_matcher",
    "plan_ablation",
    "run_ablation",
]

MAX_SEEDS = 20
"""Most seeds of one run (``--seeds``): beyond that the interval no longer narrows usefully."""


@dataclass(frozen=True)
class AblationOptions:
    """What ``xvmatch ablate`` was asked.

    Attributes:
        data: synthetic dataset folders (``xvmatch synth``), one table each.
        out: the report folder.
        model: the bundle folder or ``"default"``.
        seeds: repetitions, 1..:data:`MAX_SEEDS`; seeds 0 .. seeds - 1.
        sweep: one of :data:`~xvmatch.evaluation.ablation_settings.SWEEPS`.
        cvmhat: a folder of CVMHAT box files, or None.
        cvmhat_step: every how many frames the CVMHAT sequences are scored.
        workers: processes computing cells; the numbers do not depend on it.
    """

    data: tuple[str, ...]
    out: str
    model: str = "default"
    seeds: int = 3
    sweep: str = "noise"
    cvmhat: str | None = None
    cvmhat_step: int = 10
    workers: int = 1


@dataclass(frozen=True, eq=False)
class AblationPlan:
    """The grid of one run, every input checked.

    Attributes:
        options: the run's options.
        record: the options stored in every cell (what the numbers depend on).
        scenarios: per data folder: label, folder, scenario, scenes, test and validation pairs.
        settings: the synthetic columns.
        cells: every cell, synthetic then CVMHAT.
        bundle: what the report says about the bundle.
        cvmhat: the CVMHAT folder, step, sequences and frames, or None.
    """

    options: AblationOptions
    record: dict
    scenarios: list[dict]
    settings: tuple[Setting, ...]
    cells: list[CellSpec | CvmhatSpec]
    bundle: dict
    cvmhat: dict | None = None


@dataclass(frozen=True, eq=False)
class AblationRun:
    """What a run did.

    Attributes:
        report: the ``report.md`` text.
        files: every file written (report, results, pictures).
        computed, reused: cells computed now and reused from an earlier run.
        seconds: wall time of the run.
        checks: the learned fusion against the best non-learned row, per column.
    """

    report: str
    files: list[Path]
    computed: int
    reused: int
    seconds: float
    checks: list[TargetCheck] = field(default_factory=list)


def check_matcher(matcher: LearnedMatcher, name: str) -> None:
    """The ablation's learned rows need a bundle that takes the appearance and camera cues.

    Raises:
        ValueError: one line naming the bundle and what it lacks.
    """
    manifest = matcher.bundle.manifest
    missing = []
    if manifest.appearance is None or "app" not in matcher.cues:
        missing.append("an appearance network (the appearance rows and the learned fusion need "
                       "it)")
    if not manifest.uses_cameras:
        missing.append("the camera cues (the learned rows with cameras need them)")
    if missing:
        raise ValueError(f"{name}: the bundle lacks {' and '.join(missing)}; use a bundle that "
                         "takes images and cameras, e.g. --model default")


def _labels(folders: Sequence[Path]) -> list[str]:
    """File-name-safe, distinct labels of the data folders (their names); ``cvmhat`` is
    reserved for the CVMHAT table."""
    labels: list[str] = []
    for folder in folders:
        base = re.sub(r"[^A-Za-z0-9._-]", "_", folder.name) or "data"
        label, k = base, 2
        while label in labels or label == "cvmhat":
            label, k = f"{base}-{k}", k + 1
        labels.append(label)
    return labels


def _data_folders(data: Sequence[str | os.PathLike]) -> list[Path]:
    """The data folders, resolved; refuses one that does not exist."""
    folders = []
    for d in data:
        path = Path(d)
        if not path.is_dir():
            raise ValueError(f"{d}: no such data folder")
        folders.append(path.resolve())
    return folders


def _scenario_records(folders: Sequence[Path]) -> list[dict]:
    """One record per data folder: label, path, scenario, content hash, scenes and pairs.

    Raises:
        ValueError: a folder that is not a dataset (from ``open_dataset``).
    """
    scenarios = []
    for label, folder in zip(_labels(folders), folders, strict=True):
        dataset = open_dataset(folder)
        names = dataset.scene_names
        is_val = validation_mask(len(names))
        frames = [int(e["n_frames"]) for e in dataset.manifest["scenes"]]
        scenarios.append({
            "label": label, "data": os.fspath(folder), "scenario": dataset.scenario,
            "sha256": dataset.content_sha256(),
            "scenes": len(names),
            "test_pairs": int(sum(f for f, v in zip(frames, is_val, strict=True) if not v)),
            "val_pairs": int(sum(f for f, v in zip(frames, is_val, strict=True) if v)),
        })
    return scenarios


def _cvmhat_record(options: AblationOptions) -> dict:
    """The CVMHAT folder's record: path, step, sequences, frames per column and content hash.

    Raises:
        ValueError: a missing folder, or one without sequence pairs.
    """
    from xvmatch.formats.cvmhat import read_sequence, sequence_names

    if not Path(options.cvmhat).is_dir():
        raise ValueError(f"{options.cvmhat}: no such CVMHAT folder")
    names = sequence_names(options.cvmhat)
    if not names:
        raise ValueError(f"{options.cvmhat}: no CVMHAT sequence pairs (NAME_top.txt with "
                         "NAME_hor.txt)")
    n_frames = 0
    for name in names:
        top, hor = read_sequence(options.cvmhat, name)
        n_frames += len(sorted(set(top) | set(hor))[:: int(options.cvmhat_step)])
    return {"folder": os.fspath(Path(options.cvmhat).resolve()),
            "step": int(options.cvmhat_step), "sequences": len(names),
            "frames": n_frames, "sha256": _cvmhat_sha256(options.cvmhat, names)}


def plan_ablation(options: AblationOptions, matcher: LearnedMatcher) -> AblationPlan:
    """Check every input and lay out the grid (no work done).

    Raises:
        ValueError: one line: a missing data folder, a folder that is not a dataset or has fewer
            than 2 scenes, an unknown sweep, seeds out of range, a CVMHAT folder without box
            files, or a bundle without the cues the rows need.
    """
    if options.sweep not in SWEEPS:
        raise ValueError(f"unknown sweep {options.sweep!r}; choose one of {', '.join(SWEEPS)}")
    if not 1 <= int(options.seeds) <= MAX_SEEDS:
        raise ValueError(f"seeds must be in 1..{MAX_SEEDS}, got {options.seeds}")
    if not options.data:
        raise ValueError("give at least one data folder (--data DIR)")
    check_matcher(matcher, options.model)
    scenarios = _scenario_records(_data_folders(options.data))
    cvmhat = _cvmhat_record(options) if options.cvmhat is not None else None
    manifest = matcher.bundle.manifest
    model = options.model if options.model == "default" else os.fspath(
        Path(options.model).resolve())
    # The cells are keyed on the data's content, not its path: a folder re-rendered at the
    # same path gives other cells, a copied or moved one the same.
    record = {
        "data": [f"{s['label']} sha256:{s['sha256']}" for s in scenarios],
        "model": model,
        "matcher_sha256": manifest.matcher_sha256,
        "appearance_sha256": manifest.appearance.sha256 if manifest.appearance else None,
        "sweep": options.sweep,
        "seeds": int(options.seeds),
        "cvmhat": f"sha256:{cvmhat['sha256']}" if cvmhat else None,
        "cvmhat_step": cvmhat["step"] if cvmhat else None,
    }
    settings = grid_settings(options.sweep)
    seeds = range(int(options.seeds))
    cells: list[CellSpec | CvmhatSpec] = [
        CellSpec(s["label"], s["data"], setting, seed, model, os.fspath(options.out), record)
        for s in scenarios for seed in seeds for setting in settings
    ]
    if cvmhat:
        cells += [CvmhatSpec(cvmhat["folder"], setting, seed, cvmhat["step"], model, record)
                  for seed in seeds for setting in CVMHAT_SETTINGS]
    raw = manifest.raw
    bundle = {"name": options.model, "format": raw.get("format"),
              "format_version": raw.get("format_version"),
              "feature_version": raw.get("feature_version"), "gamma": matcher.gamma,
              "cues": list(matcher.cues)}
    return AblationPlan(options, record, scenarios, settings, cells, bundle, cvmhat)


def _cvmhat_sha256(folder: str | os.PathLike, names: Sequence[str]) -> str:
    """SHA-256 of the CVMHAT box files the ablation reads (name and bytes of each)."""
    digest = hashlib.sha256()
    for name in names:
        for view in ("top", "hor"):
            path = Path(folder) / f"{name}_{view}.txt"
            data = path.read_bytes()
            digest.update(f"{path.name}\0{len(data)}\0".encode())
            digest.update(data)
    return digest.hexdigest()


def _is_own_report(out: Path) -> bool:
    """Whether ``out`` holds the marker of ``xvmatch ablate`` (or, from before the marker, at
    least one stored cell and nothing but cells in ``cells/``)."""
    if (out / MARKER).exists():
        return is_own_folder(out, REPORT_COMMAND)
    try:
        return bool(load_cells(out))
    except ValueError:
        return False


def _check_out(out: Path) -> None:
    """Refuse a report folder ``ablate`` did not make: it replaces ``report.md`` and more."""
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: exists and is not a folder; give a report folder")
    if out.is_dir() and any(out.iterdir()) and not _is_own_report(out):
        raise ValueError(f"--out {out}: not empty and not an ablation report made by "
                         f"{REPORT_COMMAND} (no {MARKER}); choose an empty or new folder")


def _claim_out(out: Path) -> None:
    """Create the report folder and mark it as ``ablate``'s own."""
    mark_own_folder(out, REPORT_COMMAND)


_MATCHERS: dict[str, LearnedMatcher] = {}


def _matcher(model: str) -> LearnedMatcher:
    """The bundle, opened once per process (one onnxruntime thread: workers share the cores)."""
    if model not in _MATCHERS:
        _MATCHERS[model] = load_matcher_bundle(model, threads=1)
    return _MATCHERS[model]


def _compute(spec: CellSpec | CvmhatSpec) -> tuple[str, dict]:
    if isinstance(spec, CvmhatSpec):
        return spec.name, compute_cvmhat_cell(spec, _matcher(spec.model))
    return spec.name, compute_cell(spec, _matcher(spec.model))


def _worker_init() -> None:
    import cv2

    cv2.setNumThreads(1)


def _run_cells(todo: Sequence[CellSpec | CvmhatSpec], workers: int
               ) -> Iterator[tuple[str, dict]]:
    """``(name, record)`` of each cell as it finishes, in ``workers`` spawned processes."""
    if int(workers) <= 1 or len(todo) <= 1:
        for spec in todo:
            yield _compute(spec)
        return
    # "spawn": a forked child may inherit onnxruntime's or OpenCV's thread pools and hang.
    with worker_pool(min(int(workers), len(todo)), "spawn", _worker_init) as pool:
        futures = [pool.submit(_compute, spec) for spec in todo]
        for future in as_completed(futures):
            yield future.result()


def _name(scenario: dict) -> str:
    """``label`` or ``label (scenario)`` when the folder's name is not its scenario's."""
    label = scenario["label"]
    return label if label == scenario["scenario"] else f"{label} ({scenario['scenario']})"


def _sweep_figures(plan: AblationPlan, rows: list[dict], out: Path) -> list[str]:
    summary = summarise(rows)
    points = sorted((s for s in plan.settings if s.sweep_value is not None),
                    key=lambda s: s.sweep_value)
    x = [s.sweep_value for s in points]
    paths = []
    for sc in plan.scenarios:
        series = []
        for row in ROWS:
            stats = [summary[(sc["label"], s.key, row.key)] for s in points]
            mean = np.array([m.mean for m in stats])
            low = np.array([m.mean if m.low is None else m.low for m in stats])
            high = np.array([m.mean if m.high is None else m.high for m in stats])
            series.append(Series(row.label, row.family, mean, low, high))
        rel = f"sweep_{sc['label']}.png"
        sweep_figure(out / rel, x, series, x_label=SWEEP_AXES[plan.options.sweep],
                     title=f"{_name(sc)}: Eq. 9 accuracy, {len(x)} points x "
                     f"{plan.options.seeds} seed{'s' if plan.options.seeds > 1 else ''}")
        paths.append(rel)
    return paths


_DISTRIBUTION_TITLES = {
    "hist": ("colour histogram", "d'_hist = tanh(chi-square BRD)"),
    "ray": ("ray distance", "d'_geo = tanh(ray distance, m)"),
    "app": ("learned appearance", "appearance cost |a - b| / 2"),
    "learned/boxes": ("learned encoder, boxes", "matcher cost 1 - P"),
    LEARNED_FUSION: ("learned fusion, images + cameras", "matcher cost 1 - P"),
}


def _cost_figures(plan: AblationPlan, records: dict[str, dict], out: Path) -> list[str]:
    paths = []
    for sc in plan.scenarios:
        for setting in plan.settings[:2]:
            cells = [records[c.name] for c in plan.cells if isinstance(c, CellSpec)
                     and c.scenario == sc["label"] and c.setting.key == setting.key]
            panels = []
            for key in DISTRIBUTION_ROWS:
                true = np.sum([c["distributions"][key]["true"] for c in cells], axis=0)
                false = np.sum([c["distributions"][key]["false"] for c in cells], axis=0)
                panels.append((*_DISTRIBUTION_TITLES[key], true, false))
            rel = f"costs_{sc['label']}_{setting.key}.png"
            cost_figure(out / rel, panels, title=f"{sc['label']}, {setting.label}: true / false "
                        "pairs' costs per cue (test pairs, all seeds)")
            paths.append(rel)
    return paths


def _example_figures(plan: AblationPlan, records: dict[str, dict], rows: list[dict],
                     out: Path, per_scenario: int = 4) -> list[str]:
    summary = summarise(rows)
    baselines = [r.key for r in ROWS if r.family != "learned"]
    paths = []
    (out / "examples").mkdir(exist_ok=True)
    for sc in plan.scenarios:
        cells, best = [], []
        for setting in plan.settings[:2]:
            spec = next(c for c in plan.cells if isinstance(c, CellSpec) and c.seed == 0
                        and c.scenario == sc["label"] and c.setting.key == setting.key)
            cells.append((spec.name, records[spec.name]))
            best.append(max(baselines, key=lambda k, s=setting.key:
                            summary[(sc["label"], s, k)].mean))
        picked = pick_disagreements(cells, LEARNED_FUSION, best, per_scenario)
        for k, d in enumerate(picked):
            position = [name for name, _ in cells].index(d.cell)
            setting, other = plan.settings[position], best[position]
            rec = cells[position][1]
            spec = next(c for c in plan.cells if isinstance(c, CellSpec) and c.name == d.cell)
            data = os.fspath(spec.render_dir) if setting.renders else spec.data  # not rec's
            sample = frame_sample(data, setting, 0, d.scene, d.frame)
            where = f"{sc['label']}, {setting.label}, {d.scene} frame {d.frame}"
            titles = [f"{where}: learned fusion (images + cameras), Eq. 9 {d.acc_a:.2f}",
                      f"{where}: {row_by_key(other).label}, Eq. 9 {d.acc_b:.2f}"]
            pairs = [rec["rows"][LEARNED_FUSION]["pairs"][d.index],
                     rec["rows"][other]["pairs"][d.index]]
            rel = f"examples/{sc['label']}_{k + 1}.png"
            disagreement_figure(out / rel, sample.images, sample.boxes, sample.stands_for,
                                pairs, titles)
            paths.append(rel)
    return paths


def _versions(package: str) -> dict[str, str]:
    import matplotlib
    import onnxruntime

    return {"xvmatch": package, "numpy": np.__version__,
            "onnxruntime": onnxruntime.__version__, "matplotlib": matplotlib.__version__}


def run_ablation(options: AblationOptions, command: str,
                 progress: Callable[[int, int], object] | None = None, *,
                 version: str = "unknown") -> AblationRun:
    """Run (or resume) the ablation and write its report.

    Args:
        options: what to run.
        command: the command line, quoted in the report.
        progress: called as ``progress(done, total)`` (cells) before the first cell is computed
            and after each one.
        version: the version of xvmatch, quoted in the report (the command line passes it).

    Returns:
        The :class:`AblationRun`.

    Raises:
        ValueError: bad input (one line, before any work), or a report folder holding cells of
            other options.
    """
    start = time.perf_counter()
    require_matplotlib()
    if not 1 <= int(options.workers):
        raise ValueError(f"workers must be >= 1, got {options.workers}")
    out = Path(options.out)
    _check_out(out)  # before the matcher loads and the data are hashed
    plan = plan_ablation(options, _matcher(options.model))
    stored = load_cells(out)
    check_cells(out, stored, plan.record)
    names = {c.name for c in plan.cells}
    records = {k: v for k, v in stored.items() if k in names}
    todo = [c for c in plan.cells if c.name not in records]
    _claim_out(out)
    done = len(plan.cells) - len(todo)
    if progress is not None:
        progress(done, len(plan.cells))
    for name, record in _run_cells(todo, options.workers):
        save_cell(out, name, record)
        records[name] = record
        done += 1
        if progress is not None:
            progress(done, len(plan.cells))
    ordered = [records[c.name] for c in plan.cells]
    rows = result_rows(ordered, plan.settings)
    figures = {"sweep": _sweep_figures(plan, rows, out),
               "costs": _cost_figures(plan, records, out),
               "examples": _example_figures(plan, records, rows, out)}
    context = ReportContext(
        command=command, versions=_versions(version), bundle=plan.bundle, sweep=options.sweep,
        seeds=list(range(int(options.seeds))), scenarios=plan.scenarios,
        settings=plan.settings, cvmhat=plan.cvmhat,
        cell_seconds=float(sum(r["seconds"] for r in ordered)), figures=figures)
    files = write_results(out, rows, context)
    text = format_report(rows, context)
    atomic_write_text(out / "report.md", text)
    files = [out / "report.md", *files, *(out / p for ps in figures.values() for p in ps)]
    return AblationRun(text, files, len(todo), len(plan.cells) - len(todo),
                       time.perf_counter() - start, target_check(rows))

