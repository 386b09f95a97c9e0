"""One cell of the ablation grid: a data folder, a column and a seed, computed and stored.

A cell (:class:`CellSpec`) builds the trials of its data folder in its column
(:class:`~xvmatch.evaluation.ablation_settings.Setting`: box setting, noise level, calibration
error, or scenes rendered for the crowd and look-alike sweeps) and seed, splits them into
validation and test scenes (:func:`validation_mask`: every 5th scene is validation), scores every
row of :mod:`xvmatch.evaluation.ablation_methods` on the test scenes and returns a JSON-ready
record: per row the gamma, the Eq. 9 accuracy and CVIDF1 (percent), the per-pair Eq. 9
accuracy and the pairs it chose; and the true/false cost histograms of a few rows (Figs. 2-3).

Records are stored one file per cell under ``REPORT/cells/`` (:func:`save_cell`, atomically),
with the options that produced them; :func:`check_cells` refuses a folder holding cells of other
options, so a finished cell can be reused safely when the command runs again.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from xvmatch.core.atomic_files import atomic_write_text
from xvmatch.core.json_text import json_problem
from xvmatch.cues.matcher_inputs import camera_cues
from xvmatch.datasets.pair_trials import (
    FrameSample,
    PairTrial,
    TrialConfig,
    open_dataset,
    scene_samples,
    scene_trials,
)
from xvmatch.datasets.synthetic_io import MANIFEST, SyntheticDataset, generate_dataset
from xvmatch.evaluation.ablation_methods import LEARNED_FUSION, ROWS, score_rows
from xvmatch.evaluation.ablation_settings import (
    RENDER_SEED,
    Setting,
    calibration_rng,
    perturb_camera,
    scaled_noise,
)
from xvmatch.evaluation.deployed_matcher_eval import OnnxAppearanceCoster
from xvmatch.geometry.camera import FrameCameras
from xvmatch.inference.matching.learned_association import LearnedMatcher
from xvmatch.metrics.cross_view_metrics import summarize

__all__ = [
    "CELL_FORMAT",
    "CELL_VERSION",
    "DISTRIBUTION_BINS",
    "DISTRIBUTION_ROWS",
    "CellSpec",
    "cell_trials",
    "check_cells",
    "compute_cell",
    "frame_sample",
    "load_cells",
    "perturbed_trial",
    "render_setting",
    "save_cell",
    "validation_mask",
]

CELL_FORMAT = "xvmatch.ablation.cell"
CELL_VERSION = 1
"""Format and version of a cell file; a version this code does not write is refused."""
DISTRIBUTION_ROWS: tuple[str, ...] = ("hist", "ray", "app", "learned/boxes", LEARNED_FUSION)
"""Rows whose true/false cost histograms each cell stores (normalised costs in [0, 1])."""
DISTRIBUTION_BINS = 30


@dataclass(frozen=True, eq=False)
class CellSpec:
    """What one cell computes.

    Attributes:
        scenario: the label of its data folder (a file-name-safe name).
        data: the data folder (``xvmatch synth``).
        setting: the column.
        seed: the repetition (noise, shuffling, calibration error, renders).
        model: the bundle folder or ``"default"``.
        report: the report folder (renders of the crowd and look-alike sweeps go to its
            ``data/``).
        options: the run's options, stored in the record.
    """

    scenario: str
    data: str
    setting: Setting
    seed: int
    model: str
    report: str
    options: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        """The cell's file stem: ``SCENARIO__SETTING__seedS``."""
        return f"{self.scenario}__{self.setting.key}__seed{self.seed}"

    @property
    def render_dir(self) -> Path:
        """Where the column's scenes are rendered (crowd and look-alike sweeps)."""
        return Path(self.report) / "data" / f"{self.scenario}-{self.setting.key}-seed{self.seed}"


def validation_mask(n_scenes: int) -> np.ndarray:
    """``(n_scenes,)`` bool: the validation scenes, every 5th (indices 4, 9, 14, ...); with
    fewer than 5 scenes, the last one. The others are the test scenes.

    Raises:
        ValueError: fewer than 2 scenes (no room for both).
    """
    if n_scenes < 2:
        raise ValueError(f"the ablation needs at least 2 scenes per dataset (validation and "
                         f"test), got {n_scenes}")
    mask = np.arange(n_scenes) % 5 == 4
    if not mask.any():
        mask[-1] = True
    return mask


def _tuples(doc: dict) -> dict:
    return {k: tuple(v) if isinstance(v, list) else v for k, v in doc.items()}


def render_setting(source: str | os.PathLike, setting: Setting, seed: int,
                   folder: str | os.PathLike) -> Path:
    """The scenes of a rendering column: the source dataset's scenario, sizes, difficulty,
    scene and frame counts, with ``setting.people`` people per scene or ``setting.lookalike``
    as look-alike rate, dataset seed :data:`RENDER_SEED` + ``seed``. Rendered into ``folder``
    unless a dataset of exactly these settings is already there.

    Returns:
        The dataset folder.
    """
    from xvmatch.datasets.render.image_render import Difficulty
    from xvmatch.datasets.synthetic_scenes import SynthConfig

    manifest = SyntheticDataset(source).manifest
    config = SynthConfig(**_tuples(manifest["config"]))
    difficulty = Difficulty(**_tuples(manifest["difficulty"]))
    if setting.people is not None:
        config = replace(config, n_people=(setting.people, setting.people))
    if setting.lookalike is not None:
        difficulty = replace(difficulty, lookalike=setting.lookalike)
    folder = Path(folder)
    n_scenes, n_frames = int(manifest["n_scenes"]), int(manifest["frames_per_scene"])
    wanted = {"seed": RENDER_SEED + int(seed), "n_scenes": n_scenes,
              "frames_per_scene": n_frames,
              "config": json.loads(json.dumps(asdict(config))),
              "difficulty": json.loads(json.dumps(difficulty.to_dict()))}
    if (folder / MANIFEST).is_file():
        there = SyntheticDataset(folder).manifest
        if all(there.get(k) == v for k, v in wanted.items()):
            return folder
    if folder.exists():
        shutil.rmtree(folder)  # an interrupted or outdated render of this very cell
    generate_dataset(folder, config, n_scenes=n_scenes, n_frames=n_frames,
                     seed=wanted["seed"], difficulty=difficulty)
    return folder


def perturbed_trial(trial: PairTrial, setting: Setting, seed: int, scene_index: int,
                    config: TrialConfig) -> PairTrial:
    """The trial seen through cameras with the column's calibration error
    (:func:`~xvmatch.evaluation.ablation_settings.perturb_camera`, one draw per scene and view):
    the ray distance and cheirality cue recomputed from the perturbed cameras, which the learned
    matcher also gets (camera cues and rectified geometry); boxes, images and the histogram cue
    unchanged."""
    cams = {v: perturb_camera(trial.cameras[v], setting.rotation_deg, setting.position_m,
                              calibration_rng(seed, scene_index, v)) for v in ("top", "ego")}
    geo, cheir = camera_cues(FrameCameras(cams["top"], cams["ego"]), trial.top_boxes,
                             trial.ego_boxes, margin=config.margin, beta=config.beta)
    return replace(trial, costs=replace(trial.costs, geo=geo, cheirality=cheir), cameras=cams)


def cell_trials(data: str | os.PathLike, setting: Setting, seed: int,
                coster: OnnxAppearanceCoster | None) -> tuple[list[PairTrial], list[PairTrial]]:
    """The validation and test trials of a data folder in one column and seed.

    Returns:
        ``(validation trials, test trials)``, scene by scene, frame by frame.
    """
    dataset = open_dataset(data)
    names = dataset.scene_names
    is_val = validation_mask(len(names))
    config = TrialConfig(noise=scaled_noise(setting.noise), noise_seed=seed, scramble_seed=seed)
    val: list[PairTrial] = []
    test: list[PairTrial] = []
    for index, name in enumerate(names):
        trials = scene_trials(dataset.scene(name), index, config, (setting.boxes,), coster)
        if setting.perturbs_cameras:
            trials = [perturbed_trial(t, setting, seed, index, config) for t in trials]
        (val if is_val[index] else test).extend(trials)
    return val, test


def frame_sample(data: str | os.PathLike, setting: Setting, seed: int, scene: str,
                 frame: int) -> FrameSample:
    """One image pair's boxes (shuffled, as the cell's methods saw them), images and ids, for
    drawing a cell's pairs.

    Raises:
        KeyError: no such scene or frame in ``data``.
    """
    dataset = open_dataset(data)
    index = dataset.scene_names.index(scene)
    config = TrialConfig(noise=scaled_noise(setting.noise), noise_seed=seed, scramble_seed=seed)
    for sample in scene_samples(dataset.scene(scene), index, config, (setting.boxes,)):
        if sample.pair.frame == frame:
            return sample
    raise KeyError(f"{os.fspath(data)}: scene {scene} has no frame {frame}")


def _frame_acc9(counts) -> list[float]:
    return [(c.tp + c.tn) / c.n_union if c.n_union else 0.0 for c in counts]


def _histograms(test: list[PairTrial], costs: list[np.ndarray]) -> dict[str, list[int]]:
    edges = np.linspace(0.0, 1.0, DISTRIBUTION_BINS + 1)
    same = np.concatenate([t.match().reshape(-1) for t in test] or [np.zeros(0, bool)])
    values = np.concatenate([np.clip(c, 0.0, 1.0).reshape(-1) for c in costs] or [np.zeros(0)])
    return {"true": np.histogram(values[same], edges)[0].tolist(),
            "false": np.histogram(values[~same], edges)[0].tolist()}


def compute_cell(spec: CellSpec, matcher: LearnedMatcher) -> dict:
    """Compute one cell (rendering its scenes first for the crowd and look-alike sweeps).

    Returns:
        The JSON-ready record (module docstring).
    """
    start = time.perf_counter()
    data = spec.data
    if spec.setting.renders:
        data = os.fspath(render_setting(spec.data, spec.setting, spec.seed, spec.render_dir))
    val, test = cell_trials(data, spec.setting, spec.seed, OnnxAppearanceCoster(matcher))
    results = score_rows(val, test, matcher)
    rows = {}
    for row in ROWS:
        r = results[row.key]
        scores = summarize(r.counts)
        rows[row.key] = {"gamma": r.gamma, "acc9": scores.acc9, "cvidf1": scores.cvidf1,
                         "frame_acc9": _frame_acc9(r.counts),
                         "pairs": [np.asarray(p).reshape(-1, 2).tolist() for p in r.pairs]}
    return {
        "format": CELL_FORMAT,
        "version": CELL_VERSION,
        "options": spec.options,
        "scenario": spec.scenario,
        "data": data,
        "setting": spec.setting.key,
        "seed": spec.seed,
        "n_val": len(val),
        "frames": [[t.scene, t.frame] for t in test],
        "rows": rows,
        "distributions": {k: _histograms(test, results[k].costs) for k in DISTRIBUTION_ROWS},
        "seconds": round(time.perf_counter() - start, 3),
    }


def save_cell(report: str | os.PathLike, name: str, record: dict) -> Path:
    """Write a cell's record to ``REPORT/cells/NAME.json`` atomically."""
    path = Path(report) / "cells" / f"{name}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps(record, separators=(",", ":")) + "\n")
    return path


def load_cells(report: str | os.PathLike) -> dict[str, dict]:
    """Every stored cell record of a report folder, ``{name: record}``.

    Raises:
        ValueError: a cell file that is not valid JSON or not a cell of this version.
    """
    out = {}
    folder = Path(report) / "cells"
    for path in sorted(folder.glob("*.json")) if folder.is_dir() else []:
        try:
            record = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError) as exc:
            raise ValueError(f"{path}: not a readable cell file ({exc}); delete it to "
                             "recompute that cell") from None
        except (ValueError, RecursionError) as exc:  # syntax, nesting too deep
            raise ValueError(f"{path}: not a readable cell file ({json_problem(exc)}); delete "
                             "it to recompute that cell") from None
        if (not isinstance(record, dict) or record.get("format") != CELL_FORMAT
                or record.get("version") != CELL_VERSION):
            raise ValueError(f"{path}: not a cell of this xvmatch (format {CELL_FORMAT} "
                             f"version {CELL_VERSION}); delete it to recompute that cell")
        out[path.stem] = record
    return out


def check_cells(report: str | os.PathLike, cells: dict[str, dict], options: dict) -> None:
    """Refuse to mix: every stored cell must come from ``options``.

    Raises:
        ValueError: one line naming the report folder and the options that differ.
    """
    for name, record in cells.items():
        theirs = record.get("options", {})
        if theirs != options:
            keys = sorted(k for k in set(theirs) | set(options) if theirs.get(k) != options.get(k))
            shown = ", ".join(f"{k} {theirs.get(k)!r} there, {options.get(k)!r} now"
                              for k in keys)
            raise ValueError(f"{os.fspath(report)} holds cells of other options ({shown}; cell "
                             f"{name}): use another --out, or delete {os.fspath(report)}/cells")

