"""Training frames of the one cross-view matcher: synthetic image pairs in every input setting.

Each synthetic image pair (``xvmatch synth``, both scenarios) becomes trials
(:mod:`xvmatch.datasets.pair_trials`: ground-truth boxes and detector-noise boxes, shuffled per
view) and each trial becomes one training frame per input setting the deployed matcher meets
(:data:`VARIANTS`):

* ``boxes``: the spatial-distribution features of the raw boxes, no cue (the CVMHAT case);
* ``images``: the same features, plus the appearance cost of a frozen appearance network;
* ``cameras``: features of the boxes mapped to the ideal setting with the cameras (CVMHAT paper
  Sec. 5.1; O taken as the person carrying the horizontal camera), plus the ray-distance and
  cheirality cues;
* ``images+cameras``: both.

Box-simulator scenes (:class:`~xvmatch.training.box_datamodule.SimBoxDataModule`, CVMHAT-like
drone views at random resolutions) can join the training set in the ``boxes`` setting, so the
matcher keeps what the box-only model learnt. Ids only build the labels: the same id in both
views is a match; the top-view id 0 (the camera wearer) labels the hypotheses. Geometry
features are cached on disk (:func:`~xvmatch.datasets.feature_cache.cached_frame_features`).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from xvmatch.datasets.feature_cache import FrameJob, cached_frame_features
from xvmatch.datasets.pair_trials import PairTrial, TrialConfig, dataset_trials
from xvmatch.geometry.matcher_inputs import (
    CUE_NAMES,
    INPUT_SETTINGS,
    FrameCameras,
    canonical_cues,
    frame_cues,
)
from xvmatch.geometry.spatial_features import (
    FeatureConfig,
    FrameFeatures,
    camera_labels,
)
from xvmatch.models.appearance_net import appearance_from_weights
from xvmatch.training.appearance_costs import AppearanceCoster
from xvmatch.training.box_datamodule import FrameDataModule, LabelledFrames, SimBoxDataModule

__all__ = ["VARIANTS", "FrameItems", "SyntheticMatcherDataModule", "trial_frames"]

VARIANTS = INPUT_SETTINGS
"""Input settings trained on (:data:`~xvmatch.geometry.matcher_inputs.INPUT_SETTINGS`)."""

Item = tuple[FrameFeatures, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


@dataclass(frozen=True, eq=False)
class FrameItems:
    """Training frames held in memory, with the interface of
    :class:`~xvmatch.training.box_datamodule.LabelledFrames` (``len``, ``item``).

    Attributes:
        items: ``(features, match, camera labels, cues (M, N, K), cue mask (K,))`` per frame.
        name: where they come from.
    """

    items: list[Item]
    name: str = ""

    def __len__(self) -> int:
        return len(self.items)

    def item(self, k: int) -> Item:
        """The k-th frame."""
        return self.items[k]


@dataclass(frozen=True, eq=False)
class _BoxOnly:
    """Box-only labelled frames with empty cues, so they batch with cue frames."""

    part: LabelledFrames
    n_cues: int

    def __len__(self) -> int:
        return len(self.part)

    def item(self, k: int) -> Item:
        feats, match, cams = self.part.item(k)
        m, n = match.shape
        return (feats, match, cams, np.zeros((m, n, self.n_cues), np.float32),
                np.zeros(self.n_cues, bool))


def trial_frames(
    trials: Sequence[PairTrial],
    config: FeatureConfig,
    names: tuple[str, ...] = CUE_NAMES,
    variants: Sequence[str] = tuple(VARIANTS),
    cache_dir: str | os.PathLike | None = None,
    workers: int = 1,
    wearer_id: int = 0,
) -> list[Item]:
    """Training frames of trials in each of ``variants`` (see the module docstring).

    Args:
        trials: the trials (with appearance costs when a variant uses ``app``).
        config: geometry feature configuration.
        names: the cues the matcher takes.
        variants: keys of :data:`VARIANTS`.
        cache_dir: feature cache folder.
        workers: processes computing the features.
        wearer_id: top-view id of the camera wearer (labels only).
    """
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        raise ValueError(f"variants must be among {', '.join(VARIANTS)}, got {unknown}")
    rectified = any(VARIANTS[v][1] for v in variants)
    plain = any(not VARIANTS[v][1] for v in variants)
    jobs = {}
    for key, use in (("plain", plain), ("rectified", rectified)):
        if use:
            jobs[key] = cached_frame_features(
                [FrameJob(t.top_boxes, t.ego_boxes, t.cameras["ego"].image_size, None,
                          FrameCameras(t.cameras["top"], t.cameras["ego"])
                          if key == "rectified" else None) for t in trials],
                config, cache_dir, workers)
    out: list[Item] = []
    for k, t in enumerate(trials):
        match_input = t.match()
        m, n = match_input.shape
        for variant in variants:
            cues_of, rect = VARIANTS[variant]
            feats = jobs["rectified" if rect else "plain"][k]
            wanted = [c for c in cues_of if c in names]
            if "app" in wanted and t.app is None:
                raise ValueError(f"{t.scene}/{t.frame}: the {variant!r} setting needs "
                                 "appearance costs; build the trials with a coster")
            cues, mask = frame_cues(
                (m, n), names,
                app=t.app if "app" in wanted else None,
                ray_distance=t.costs.geo if "ray" in wanted else None,
                cheirality=t.costs.cheirality if "cheir" in wanted else None,
            )
            match = match_input[feats.top_order][:, feats.hor_order]
            cams = camera_labels(feats, t.det_top_ids, wearer_id)
            out.append((feats, match, cams, canonical_cues(cues, feats), mask))
    return out


def _folders(value: str | Sequence[str]) -> list[str]:
    return [value] if isinstance(value, str | os.PathLike) else [os.fspath(v) for v in value]


class SyntheticMatcherDataModule(FrameDataModule):
    """Synthetic image pairs in every input setting, optionally with box-simulator scenes.

    Args:
        train_data: synthetic dataset folder(s) for training.
        val_data: synthetic dataset folder(s) for validation (other scenes, other seeds).
        appearance_weights: the frozen appearance network's weights file (for the ``app``
            cue); None: no appearance cue.
        feature_config: geometry feature configuration.
        cues: the cues the matcher takes.
        variants: input settings to train on (keys of :data:`VARIANTS`).
        noise_seeds: detector-noise seeds of the training ``det`` trials (keep them apart from
            the evaluation's 0).
        scramble_seed: box-shuffling seed of the training trials.
        sim: box-simulator frames added to training in the ``boxes`` setting, or None.
        batch_size: frames per batch.
        cache_dir: feature cache folder.
        workers: processes computing the features.
        seed: seed of the batch order.
    """

    def __init__(
        self,
        train_data: str | Sequence[str],
        val_data: str | Sequence[str],
        appearance_weights: str | None = None,
        feature_config: FeatureConfig | None = None,
        cues: Sequence[str] = CUE_NAMES,
        variants: Sequence[str] = tuple(VARIANTS),
        noise_seeds: Sequence[int] = (11,),
        scramble_seed: int = 5,
        sim: SimBoxDataModule | None = None,
        batch_size: int = 32,
        cache_dir: str | None = None,
        workers: int = 1,
        seed: int = 0,
    ) -> None:
        super().__init__(batch_size, seed)
        self.train_folders = _folders(train_data)
        self.val_folders = _folders(val_data)
        self.cues = tuple(cues)
        self.variants = tuple(variants)
        if "app" in self.cues and appearance_weights is None:
            raise ValueError("the 'app' cue needs appearance_weights")
        self.appearance_weights = appearance_weights
        self.feature_config = feature_config or FeatureConfig()
        self.noise_seeds = tuple(int(s) for s in noise_seeds)
        self.scramble_seed = int(scramble_seed)
        self.sim = sim
        self.cache_dir = cache_dir
        self.workers = workers

    def _frames(self, folder: str, config: TrialConfig, settings: tuple[str, ...], coster,
                name: str) -> FrameItems:
        trials = dataset_trials(folder, config, settings, coster)
        items = trial_frames(trials, self.feature_config, self.cues, self.variants,
                             self.cache_dir, self.workers)
        return FrameItems(items, name)

    def setup(self, stage: str | None = None) -> None:
        """Build the trials and their features (once); add the simulator's frames."""
        if self.train_parts:
            return
        coster = None
        if "app" in self.cues:
            coster = AppearanceCoster(appearance_from_weights(self.appearance_weights))
        for folder in self.train_folders:
            gt = TrialConfig(scramble_seed=self.scramble_seed)
            self.train_parts.append(self._frames(folder, gt, ("gt",), coster, f"{folder}/gt"))
            for s in self.noise_seeds:
                det = TrialConfig(noise_seed=s, scramble_seed=self.scramble_seed)
                self.train_parts.append(
                    self._frames(folder, det, ("det",), coster, f"{folder}/noise{s}"))
        for folder in self.val_folders:
            self.val_parts.append(
                self._frames(folder, TrialConfig(), ("gt", "det"), coster, f"{folder}/val"))
        if self.sim is not None:
            self.sim.setup(stage)
            self.train_parts += [_BoxOnly(p, len(self.cues)) for p in self.sim.train_parts]

    def describe(self) -> str:
        """One line: frames per split."""
        return (f"train {sum(len(p) for p in self.train_parts)} frames, "
                f"val {sum(len(p) for p in self.val_parts)} frames")
