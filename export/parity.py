"""Parity at export: the torch modules against their ONNX graphs run by onnxruntime.

The matcher is compared on held-out synthetic frames in each input setting (boxes only, with
images, with images and cameras) plus edge cases (one person, an empty view in a padded batch),
by the largest cost difference and whether every frame's Hungarian assignment is the same; the
appearance network by the largest descriptor difference on the crops of those frames.
:func:`~xvmatch.export.onnx_export.export_bundle` refuses an export beyond
:data:`PARITY_TOLERANCE`.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import torch

from xvmatch.cues.matcher_inputs import MatcherInputs, collate_inputs
from xvmatch.inference.linking.assignment import assign
from xvmatch.inference.matching.bundle import APPEARANCE_INPUT, MATCHER_INPUTS, MATCHER_OUTPUT
from xvmatch.models.appearance_net import AppearanceNet
from xvmatch.models.cross_view_matcher import CrossViewMatcher
from xvmatch.models.matcher_file import LoadedMatcher

__all__ = ["PARITY_TOLERANCE", "appearance_parity", "compare_matcher", "parity_frames"]

PARITY_TOLERANCE: float = 1e-4
"""Largest |cost_torch - cost_onnx| accepted at export."""


def _matcher_costs_torch(matcher: CrossViewMatcher, batch: dict[str, np.ndarray]) -> np.ndarray:
    with torch.inference_mode():
        out = matcher(*(torch.from_numpy(batch[k]) for k in MATCHER_INPUTS))
    return out.cost.numpy()


def _matcher_costs_onnx(session, batch: dict[str, np.ndarray]) -> np.ndarray:
    wanted = {i.name for i in session.get_inputs()}
    return session.run([MATCHER_OUTPUT], {k: batch[k] for k in MATCHER_INPUTS if k in wanted})[0]


def compare_matcher(matcher: CrossViewMatcher, session, frames: Sequence[MatcherInputs],
                     gamma: float, batch_size: int = 16) -> dict:
    """Parity figures of one input setting."""
    worst, same, n_pairs = 0.0, 0, 0
    for start in range(0, len(frames), batch_size):
        chunk = list(frames[start : start + batch_size])
        batch = collate_inputs(chunk)
        ref = _matcher_costs_torch(matcher, batch)
        got = _matcher_costs_onnx(session, batch)
        if got.shape != ref.shape or not np.isfinite(got).all():
            return {"frames": len(frames), "max_abs_cost_diff": float("inf"),
                    "assignments_identical": 0, "error": f"shape {got.shape} / non-finite"}
        for k, f in enumerate(chunk):
            m, n = f.features.top.shape[0], f.features.hor.shape[0]
            a, b = ref[k, :m, :n].astype(np.float64), got[k, :m, :n].astype(np.float64)
            if a.size:
                worst = max(worst, float(np.abs(a - b).max()))
            same += int(np.array_equal(assign(a, gamma), assign(b, gamma)))
            n_pairs += int(assign(a, gamma).shape[0])
    return {"frames": len(frames), "max_abs_cost_diff": worst, "assignments_identical": same,
            "pairs": n_pairs}


def _render_parity_data(folder: Path, seed: int) -> list[Path]:
    """Render a small dataset of each scenario (2 scenes of 2 frames, seeds ``seed + k``)
    into ``folder``; their folders."""
    from xvmatch.datasets.synthetic_io import generate_dataset
    from xvmatch.datasets.synthetic_scenes import SynthConfig

    folders = []
    for k, scenario in enumerate(("drone", "overview")):
        scenario_folder = folder / scenario
        config = SynthConfig(scenario=scenario, n_people=(2, 12))
        generate_dataset(scenario_folder, config, n_scenes=2, n_frames=2, seed=seed + k)
        folders.append(scenario_folder)
    return folders


def _crop_coster(loaded: LoadedMatcher, crops_all: list[np.ndarray]
                 ) -> Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray], np.ndarray]:
    """The trials' appearance coster: the matcher's network on the two views' crops, each
    crop kept in ``crops_all`` (for the appearance parity)."""
    from xvmatch.cues.matcher_inputs import appearance_cost
    from xvmatch.formats.crops import box_crops

    net = loaded.appearance

    def coster(top_image, top_boxes, hor_image, hor_boxes):
        size = net.preprocessing.crop_size
        a = box_crops(top_image, top_boxes, size, loaded.crop_context)
        b = box_crops(hor_image, hor_boxes, size, loaded.crop_context)
        crops_all.extend([a, b])
        with torch.inference_mode():
            da = net.embed_crops(torch.from_numpy(a)).numpy() if len(a) else np.zeros(
                (0, net.embedding_dim), np.float32)
            db = net.embed_crops(torch.from_numpy(b)).numpy() if len(b) else np.zeros(
                (0, net.embedding_dim), np.float32)
        return appearance_cost(da, db)

    return coster


def _setting_frames(trials: list, loaded: LoadedMatcher) -> dict[str, list[MatcherInputs]]:
    """The trials' matcher inputs in each input setting the matcher takes: ``boxes``,
    ``images`` (with ``app``) and ``cameras`` (with ``ray`` or ``cheir``)."""
    from xvmatch.cues.matcher_inputs import matcher_inputs
    from xvmatch.geometry.camera import FrameCameras

    names = tuple(loaded.matcher.cues)
    settings: dict[str, list[MatcherInputs]] = {"boxes": []}
    if "app" in names:
        settings["images"] = []
    if "ray" in names or "cheir" in names:
        settings["cameras"] = []
    config = loaded.feature_config
    for t in trials:
        size = t.cameras["ego"].image_size
        cams = FrameCameras(t.cameras["top"], t.cameras["ego"])
        plain = matcher_inputs(t.top_boxes, t.ego_boxes, size, config, names)
        settings["boxes"].append(plain)
        if "images" in settings:
            settings["images"].append(matcher_inputs(t.top_boxes, t.ego_boxes, size, config,
                                                     names, app=t.app))
        if "cameras" in settings:
            settings["cameras"].append(matcher_inputs(t.top_boxes, t.ego_boxes, size, config,
                                                      names, cameras=cams, app=t.app))
    return settings


def _edge_cases(trials: list, loaded: LoadedMatcher) -> list[MatcherInputs]:
    """Edge cases from the most crowded trial: one person per view, an empty view (either
    one), and the whole frame beside them in a batch."""
    from xvmatch.cues.matcher_inputs import matcher_inputs

    names, config = tuple(loaded.matcher.cues), loaded.feature_config
    t = max(trials, key=lambda t: len(t.top_boxes) * len(t.ego_boxes))
    size = t.cameras["ego"].image_size
    return [
        matcher_inputs(t.top_boxes[:1], t.ego_boxes[:1], size, config, names),
        matcher_inputs(t.top_boxes, t.ego_boxes[:0], size, config, names),
        matcher_inputs(t.top_boxes[:0], t.ego_boxes, size, config, names),
        matcher_inputs(t.top_boxes, t.ego_boxes, size, config, names),
    ]


def parity_frames(
    loaded: LoadedMatcher,
    data: str | os.PathLike | None = None,
    *,
    seed: int = 424242,
    progress: Callable[[str], None] | None = None,
) -> tuple[dict[str, list[MatcherInputs]], np.ndarray]:
    """Held-out synthetic frames in each input setting, and the crops they were cut from.

    Args:
        loaded: the matcher (its feature configuration, cues and appearance network).
        data: synthetic dataset folder(s) to draw from (``xvmatch synth``); None renders a small
            one of each scenario (seed ``seed``, never a training seed) in a temporary folder.
        seed: seed of the rendered scenes.
        progress: called with a line of text at each stage.

    Returns:
        ``({setting: frames}, crops (C, H, W, 3) uint8)``; settings ``boxes`` always,
        ``images`` and ``cameras`` when the matcher takes those cues.
    """
    from xvmatch.datasets.pair_trials import TrialConfig, dataset_trials

    tmp = None
    folders: list[Path]
    if data is None:
        tmp = Path(tempfile.mkdtemp(prefix="xvmatch-parity-"))
        folders = _render_parity_data(tmp, seed)
    else:
        folders = [Path(data)]
    try:
        if progress:
            progress(f"parity frames from {', '.join(map(str, folders))}")
        crops_all: list[np.ndarray] = []
        coster = _crop_coster(loaded, crops_all) if loaded.appearance is not None else None
        trials = []
        for folder in folders:
            trials += dataset_trials(folder, TrialConfig(), coster=coster)
        settings = _setting_frames(trials, loaded)
        # Edge cases: one person per view, and an empty view padded in a batch.
        settings["edge cases"] = _edge_cases(trials, loaded)
        crops = np.concatenate(crops_all) if crops_all else np.zeros((0, 1, 1, 3), np.uint8)
        return settings, crops
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


def appearance_parity(net: AppearanceNet, session, crops: np.ndarray) -> dict:
    """The largest descriptor difference between the torch network and its ONNX graph on
    ``crops``."""
    if crops.shape[0] == 0:
        return {"crops": 0, "max_abs_descriptor_diff": 0.0}
    with torch.inference_mode():
        ref = net.embed_crops(torch.from_numpy(crops)).numpy()
    got = np.concatenate([session.run(None, {APPEARANCE_INPUT: crops[k : k + 64]})[0]
                          for k in range(0, crops.shape[0], 64)])
    return {"crops": int(crops.shape[0]),
            "max_abs_descriptor_diff": float(np.abs(ref - got).max())}
