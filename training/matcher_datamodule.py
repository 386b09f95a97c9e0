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

**Corrupted appearance** (:class:`AppCorruption`, issue 31; off by default): a frame that uses
the ``app`` cue is given, with a seeded probability, appearance costs that cannot be trusted, so
a matcher with an appearance confidence learns when to ignore them. The kinds
(:data:`CORRUPTIONS`):

* ``"shift"``: the costs of the same boxes on camera-shifted images
  (:func:`~xvmatch.datasets.camera_shift.camera_shift`, both views, a strength drawn per frame
  up to 3, one camera per image or per view; computed once per trial by
  :class:`ShiftedCoster`);
* ``"swap"``: the crops of one view swapped among its people (a random permutation of the
  cost matrix's rows or columns);
* ``"random"``: the costs of random unit embeddings (``|a - b| / 2`` of Gaussian directions).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader

from xvmatch.cues.matcher_inputs import CUE_NAMES, INPUT_SETTINGS, canonical_cues, frame_cues
from xvmatch.cues.spatial_features import (
    FeatureConfig,
    FrameFeatures,
    camera_labels,
)
from xvmatch.datasets.camera_shift import MAX_STRENGTH, camera_shift
from xvmatch.datasets.feature_cache import FrameJob, cached_frame_features
from xvmatch.datasets.pair_trials import (
    PairTrial,
    TrialConfig,
    dataset_trials,
    open_dataset,
    scene_samples,
)
from xvmatch.geometry.camera import FrameCameras
from xvmatch.models.appearance_net import AppearanceNet, appearance_from_weights
from xvmatch.training.appearance_costs import AppearanceCoster
from xvmatch.training.box_datamodule import (
    FrameDataModule,
    LabelledFrames,
    SimBoxDataModule,
    _FrameDataset,
    collate_labelled,
)

__all__ = [
    "CORRUPTIONS",
    "VARIANTS",
    "AppCorruption",
    "FrameItems",
    "ShiftedCoster",
    "SyntheticMatcherDataModule",
    "collate_flagged",
    "corrupt_app",
    "shifted_app_costs",
    "trial_frames",
]

VARIANTS = INPUT_SETTINGS
"""Input settings trained on (:data:`~xvmatch.cues.matcher_inputs.INPUT_SETTINGS`)."""

Item = tuple[FrameFeatures, np.ndarray, np.ndarray, np.ndarray, np.ndarray]

CORRUPTIONS: tuple[str, ...] = ("shift", "swap", "random")
"""The kinds of corrupted appearance costs (module docstring)."""


@dataclass(frozen=True)
class AppCorruption:
    """How often and how frames with the ``app`` cue get corrupted appearance costs.

    Attributes:
        probability: chance that one such frame is corrupted (0: never, the default).
        kinds: which of :data:`CORRUPTIONS` to draw from.
        weights: relative chance of each kind (same length as ``kinds``).
        max_strength: strongest camera shift of ``"shift"`` (at most 3).
        min_strength: weakest camera shift of ``"shift"``.
        embedding_dim: dimension of the random unit embeddings of ``"random"``.
        seed: seed of every draw (which frames, which kind, the permutations, the embeddings,
            the shifted cameras).
    """

    probability: float = 0.0
    kinds: tuple[str, ...] = CORRUPTIONS
    weights: tuple[float, ...] = (0.7, 0.1, 0.2)
    max_strength: float = MAX_STRENGTH
    min_strength: float = 1.0
    embedding_dim: int = 128
    seed: int = 0

    def __post_init__(self) -> None:
        if not 0.0 <= float(self.probability) <= 1.0:
            raise ValueError(f"probability must be in [0, 1], got {self.probability}")
        unknown = [k for k in self.kinds if k not in CORRUPTIONS]
        if unknown or not self.kinds:
            raise ValueError(f"kinds must be among {', '.join(CORRUPTIONS)}, got "
                             f"{list(self.kinds)}")
        if len(self.weights) != len(self.kinds) or min(self.weights) < 0 or sum(
                self.weights) <= 0:
            raise ValueError(f"weights must be {len(self.kinds)} non-negative numbers with a "
                             f"positive sum, got {list(self.weights)}")
        if not 0.0 < self.min_strength <= self.max_strength <= MAX_STRENGTH:
            raise ValueError("strengths must satisfy 0 < min_strength <= max_strength <= "
                             f"{MAX_STRENGTH:g}, got {self.min_strength}, {self.max_strength}")
        if int(self.embedding_dim) < 2:
            raise ValueError(f"embedding_dim must be >= 2, got {self.embedding_dim}")


def corrupt_app(app: np.ndarray, kind: str, rng: np.random.Generator,
                shifted: np.ndarray | None = None, embedding_dim: int = 128) -> np.ndarray:
    """Corrupted ``(M, N)`` appearance costs of one frame (module docstring).

    Args:
        app: the clean costs.
        kind: one of :data:`CORRUPTIONS`.
        rng: the frame's random generator.
        shifted: the costs of the camera-shifted images (needed by ``"shift"``).
        embedding_dim: dimension of the random unit embeddings (``"random"``).
    """
    app = np.asarray(app, dtype=np.float64)
    m, n = app.shape
    if kind == "shift":
        if shifted is None or np.shape(shifted) != (m, n):
            raise ValueError("the 'shift' corruption needs the shifted images' costs of the "
                             f"same shape {(m, n)}")
        return np.asarray(shifted, dtype=np.float64)
    if kind == "swap":
        if rng.random() < 0.5:
            return app[rng.permutation(m)]
        return app[:, rng.permutation(n)]
    if kind == "random":
        a = rng.standard_normal((m, embedding_dim))
        b = rng.standard_normal((n, embedding_dim))
        a /= np.linalg.norm(a, axis=1, keepdims=True)
        b /= np.linalg.norm(b, axis=1, keepdims=True)
        return np.linalg.norm(a[:, None] - b[None], axis=-1) / 2.0
    raise ValueError(f"kind must be one of {', '.join(CORRUPTIONS)}, got {kind!r}")


class ShiftedCoster:
    """An appearance coster whose images first go through :func:`camera_shift`.

    The strength (uniform in ``[min_strength, max_strength]``), whether each image or each
    view draws its own camera (``per_image``, half the frames each) and the cameras' seeds come
    from ``seed`` and the two images' bytes, so a frame's ground-truth and detector-noise trials
    see the same pictures, and every run the same.

    Args:
        coster: ``coster(top_image, top_boxes, ego_image, ego_boxes) -> (M, N)``.
        seed: seed of the draws.
        min_strength, max_strength: range of the strength.
    """

    def __init__(self, coster: Callable[..., np.ndarray], seed: int = 0,
                 min_strength: float = 0.5, max_strength: float = MAX_STRENGTH) -> None:
        self.coster = coster
        self.seed = int(seed)
        self.min_strength, self.max_strength = float(min_strength), float(max_strength)

    def __call__(self, top_image: np.ndarray, top_boxes: np.ndarray, ego_image: np.ndarray,
                 ego_boxes: np.ndarray) -> np.ndarray:
        """``(M, N)`` costs of the boxes on the shifted images."""
        crc = [zlib.crc32(np.ascontiguousarray(im).tobytes()) for im in (top_image, ego_image)]
        rng = np.random.default_rng([self.seed, *crc])
        strength = float(rng.uniform(self.min_strength, self.max_strength))
        per_image = bool(rng.random() < 0.5)
        seeds = rng.integers(0, 2**31, size=2)
        return self.coster(camera_shift(top_image, strength, int(seeds[0]), per_image),
                           top_boxes,
                           camera_shift(ego_image, strength, int(seeds[1]), per_image),
                           ego_boxes)


def shifted_app_costs(data: str | os.PathLike, config: TrialConfig, settings: Sequence[str],
                      coster: Callable[..., np.ndarray]) -> list[np.ndarray]:
    """The appearance costs of :func:`~xvmatch.datasets.pair_trials.dataset_trials`'s trials
    (same order, same boxes) through another ``coster`` (e.g. a :class:`ShiftedCoster`),
    without the handcrafted cues."""
    dataset = open_dataset(data)
    out = []
    for index, name in enumerate(dataset.scene_names):
        for fs in scene_samples(dataset.scene(name), index, config, settings):
            out.append(coster(fs.images["top"], fs.boxes["top"], fs.images["ego"],
                              fs.boxes["ego"]))
    return out


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


def _variant_features(
    trials: Sequence[PairTrial], variants: Sequence[str], config: FeatureConfig,
    cache_dir: str | os.PathLike | None, workers: int,
) -> dict[str, list]:
    """Geometry features of every trial, ``"plain"`` and/or ``"rectified"`` as variants need."""
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
    return jobs


def _maybe_corrupt(
    app: np.ndarray, corruption: AppCorruption, kind_p: np.ndarray,
    stream: tuple[int, int, int], shifted: np.ndarray | None,
) -> tuple[np.ndarray, bool]:
    """Corrupt one frame's appearance costs with probability ``corruption.probability``.

    Args:
        app: ``(M, N)`` appearance costs.
        corruption: the corruption settings.
        kind_p: probability of each of ``corruption.kinds``.
        stream: (corruption stream, trial index, variant index); with ``corruption.seed`` it
            seeds the frame's own generator.
        shifted: the costs on shifted images (the ``"shift"`` kind), or None.

    Returns:
        The (possibly corrupted) costs and whether they were corrupted.
    """
    rng = np.random.default_rng([int(corruption.seed), *stream])
    if rng.random() < corruption.probability:
        kind = corruption.kinds[int(rng.choice(len(corruption.kinds), p=kind_p))]
        return corrupt_app(app, kind, rng, shifted, corruption.embedding_dim), True
    return app, False


def trial_frames(
    trials: Sequence[PairTrial],
    config: FeatureConfig,
    names: tuple[str, ...] = CUE_NAMES,
    variants: Sequence[str] = tuple(VARIANTS),
    cache_dir: str | os.PathLike | None = None,
    workers: int = 1,
    wearer_id: int = 0,
    corruption: AppCorruption | None = None,
    shifted_app: Sequence[np.ndarray] | None = None,
    corruption_stream: int = 0,
    flag_corrupted: bool = False,
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
        corruption: corrupted appearance of frames with ``app`` (None or probability 0: none).
            Each frame and variant draws from its own generator, seeded by (``corruption.
            seed``, ``corruption_stream``, trial index, variant index).
        shifted_app: per trial, the costs on shifted images (needed by the ``"shift"`` kind).
        corruption_stream: keeps the draws of different trial lists apart (e.g. one per
            dataset folder and setting).
        flag_corrupted: append to each item a sixth element, a bool array of shape ``()``:
            whether its appearance costs were corrupted (default False: five elements).
    """
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        raise ValueError(f"variants must be among {', '.join(VARIANTS)}, got {unknown}")
    corrupting = corruption is not None and corruption.probability > 0
    if corrupting and "shift" in corruption.kinds and (
            shifted_app is None or len(shifted_app) != len(trials)):
        raise ValueError("the 'shift' corruption needs shifted_app, one cost matrix per trial")
    if corrupting:
        kind_p = np.asarray(corruption.weights, dtype=np.float64)
        kind_p = kind_p / kind_p.sum()
    jobs = _variant_features(trials, variants, config, cache_dir, workers)
    out: list[Item] = []
    for k, t in enumerate(trials):
        match_input = t.match()
        m, n = match_input.shape
        for v_index, variant in enumerate(variants):
            cues_of, rect = VARIANTS[variant]
            feats = jobs["rectified" if rect else "plain"][k]
            wanted = [c for c in cues_of if c in names]
            if "app" in wanted and t.app is None:
                raise ValueError(f"{t.scene}/{t.frame}: the {variant!r} setting needs "
                                 "appearance costs; build the trials with a coster")
            app = t.app if "app" in wanted else None
            corrupted = False
            if app is not None and corrupting:
                app, corrupted = _maybe_corrupt(
                    app, corruption, kind_p, (int(corruption_stream), k, v_index),
                    None if shifted_app is None else shifted_app[k])
            cues, mask = frame_cues(
                (m, n), names,
                app=app,
                ray_distance=t.costs.geo if "ray" in wanted else None,
                cheirality=t.costs.cheirality if "cheir" in wanted else None,
            )
            match = match_input[feats.top_order][:, feats.hor_order]
            cams = camera_labels(feats, t.det_top_ids, wearer_id)
            item = (feats, match, cams, canonical_cues(cues, feats), mask)
            out.append((*item, np.asarray(corrupted)) if flag_corrupted else item)
    return out


def collate_flagged(items: Sequence[tuple]) -> dict[str, torch.Tensor]:
    """:func:`~xvmatch.training.box_datamodule.collate_labelled` of items with the sixth
    element of ``trial_frames(..., flag_corrupted=True)`` (box-only items: not corrupted),
    which adds ``app_corrupted (B,)`` bool."""
    flags = [bool(it[5]) if len(it) == 6 else False for it in items]
    batch = collate_labelled([it[:5] for it in items])
    batch["app_corrupted"] = torch.tensor(flags, dtype=torch.bool)
    return batch


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
        corruption: corrupted appearance costs of training frames (None: none, the default).
        corrupt_val: corrupt the validation frames too (with ``corruption``'s probability and
            kinds, other draws), so the best epoch is the best on clean and corrupted frames.
        app_cache: folder keeping the appearance costs (clean and shifted) between runs, keyed
            by the dataset's content, the trials' configuration, the network's weights and the
            shift's draws; None: computed every time.
        flag_corrupted: batches carry ``app_corrupted (B,)``, which frames have corrupted
            appearance costs (for a loss's clean-frame term); default False: batches as before.
    """

    def __init__(
        self,
        train_data: str | Sequence[str],
        val_data: str | Sequence[str],
        appearance_weights: str | AppearanceNet | None = None,
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
        corruption: AppCorruption | None = None,
        corrupt_val: bool = False,
        app_cache: str | os.PathLike | None = None,
        flag_corrupted: bool = False,
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
        self.corruption = corruption
        self.corrupt_val = bool(corrupt_val)
        self.app_cache = None if app_cache is None else os.fspath(app_cache)
        self._net_digest = ""
        self.flag_corrupted = bool(flag_corrupted)

    def _app_costs(self, folder: str, config: TrialConfig, settings: tuple[str, ...], coster,
                   what: str) -> list[np.ndarray]:
        """:func:`shifted_app_costs` through ``coster``, read from or written to
        ``app_cache``."""
        if self.app_cache is None:
            return shifted_app_costs(folder, config, settings, coster)
        key = hashlib.sha256(json.dumps([
            open_dataset(folder).content_sha256(), repr(config), list(settings),
            self._net_digest, what]).encode()).hexdigest()[:32]
        path = Path(self.app_cache) / f"{key}.npz"
        if path.is_file():
            with np.load(path) as stored:
                return [stored[str(i)] for i in range(len(stored.files))]
        costs = shifted_app_costs(folder, config, settings, coster)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f"{key}.tmp.npz")
        np.savez(tmp, **{str(i): c for i, c in enumerate(costs)})
        os.replace(tmp, path)
        return costs

    def _frames(self, folder: str, config: TrialConfig, settings: tuple[str, ...], coster,
                name: str, corrupt: bool = False) -> FrameItems:
        trials = dataset_trials(folder, config, settings, None)
        if coster is not None:
            apps = self._app_costs(folder, config, settings, coster, "clean")
            trials = [dataclasses.replace(t, app=a) for t, a in zip(trials, apps, strict=True)]
        corruption = self.corruption if corrupt and coster is not None else None
        shifted = None
        stream = len(self.train_parts) + 1000 * len(self.val_parts) + (
            10**6 if name.endswith("/val") else 0)
        if corruption is not None and corruption.probability > 0 and (
                "shift" in corruption.kinds):
            shifter = ShiftedCoster(coster, seed=corruption.seed + stream,
                                    min_strength=corruption.min_strength,
                                    max_strength=corruption.max_strength)
            shifted = self._app_costs(folder, config, settings, shifter, json.dumps(
                ["shift", shifter.seed, shifter.min_strength, shifter.max_strength]))
        items = trial_frames(trials, self.feature_config, self.cues, self.variants,
                             self.cache_dir, self.workers, corruption=corruption,
                             shifted_app=shifted, corruption_stream=stream,
                             flag_corrupted=self.flag_corrupted)
        return FrameItems(items, name)

    def setup(self, stage: str | None = None) -> None:
        """Build the trials and their features (once); add the simulator's frames."""
        if self.train_parts:
            return
        coster = None
        if "app" in self.cues:
            net = self.appearance_weights
            net = net if isinstance(net, AppearanceNet) else appearance_from_weights(net)
            coster = AppearanceCoster(net)
            digest = hashlib.sha256()
            for name, tensor in net.state_dict().items():
                digest.update(name.encode())
                digest.update(tensor.detach().cpu().contiguous().numpy().tobytes())
            self._net_digest = digest.hexdigest()
        for folder in self.train_folders:
            gt = TrialConfig(scramble_seed=self.scramble_seed)
            self.train_parts.append(
                self._frames(folder, gt, ("gt",), coster, f"{folder}/gt", corrupt=True))
            for s in self.noise_seeds:
                det = TrialConfig(noise_seed=s, scramble_seed=self.scramble_seed)
                self.train_parts.append(self._frames(folder, det, ("det",), coster,
                                                     f"{folder}/noise{s}", corrupt=True))
        for folder in self.val_folders:
            self.val_parts.append(self._frames(folder, TrialConfig(), ("gt", "det"), coster,
                                               f"{folder}/val", corrupt=self.corrupt_val))
        if self.sim is not None:
            self.sim.setup(stage)
            self.train_parts += [_BoxOnly(p, len(self.cues)) for p in self.sim.train_parts]

    def _flagged_loader(self, parts, shuffle: bool) -> DataLoader:
        generator = torch.Generator().manual_seed(self.seed) if shuffle else None
        return DataLoader(_FrameDataset(parts), batch_size=self.batch_size, shuffle=shuffle,
                          collate_fn=collate_flagged, generator=generator, num_workers=0)

    def train_dataloader(self) -> DataLoader:
        """Training batches (with ``app_corrupted`` when ``flag_corrupted``)."""
        if not self.flag_corrupted:
            return super().train_dataloader()
        return self._flagged_loader(self.train_parts, True)

    def val_dataloader(self) -> DataLoader:
        """Validation batches (with ``app_corrupted`` when ``flag_corrupted``)."""
        if not self.flag_corrupted:
            return super().val_dataloader()
        return self._flagged_loader(self.val_parts, False)

    def describe(self) -> str:
        """One line: frames per split."""
        return (f"train {sum(len(p) for p in self.train_parts)} frames, "
                f"val {sum(len(p) for p in self.val_parts)} frames")
