"""DataModules of the box-only geometry model: CVMHAT box files by site, and the box simulator.

Both turn frame pairs into the features of :mod:`xvmatch.cues.spatial_features` (cached on
disk) plus labels. Ids are read once, to build the labels (the same id in both views is a match;
the top-view id ``wearer_id`` is the camera location O), and never reach the features: the model
sees boxes only, in a canonical order, so scrambling ids or shuffling boxes changes nothing.

* :class:`CvmhatBoxDataModule`: the CVMHAT dev sequences; the sites not held out are split in
  time (the last ``val_fraction`` of each sequence validates, for early stopping), the held-out
  site is the test set. Optional detector-noise copies of the training sequences (seeded with
  ``noise_seeds``, which should differ from the evaluation seeds) augment the clean ones. Each
  training sequence is first synchronised as ``associate --offset auto`` would (the same id in
  both views is only the same person at the same moment if the videos are in sync; one CVMHAT
  dev pair is 37 frames off).
* :class:`SimBoxDataModule`: scenes of the box simulator with randomised configurations (domain
  randomisation: crowd size, heights, area, camera altitude and fields of view, pitch, roll, gaze,
  visibility threshold) and random detector-noise levels; whole scenes are held out to validate.
* :class:`MixedBoxDataModule`: the union of a real and a simulated training set, validated on
  the real one.

Every random choice is seeded by ``seed``.
"""

from __future__ import annotations

import json
import zlib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from xvmatch.core.atomic_files import atomic_write_text
from xvmatch.core.worker_pool import worker_pool
from xvmatch.cues.offset_estimation import AUTO_MAX_OFFSET, estimate_offset
from xvmatch.cues.spatial_features import (
    FeatureConfig,
    FrameFeatures,
    camera_labels,
    collate_frames,
    match_labels,
)
from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene
from xvmatch.datasets.detector_noise import DetectorNoise, apply_detector_noise
from xvmatch.datasets.feature_cache import (
    FeatureSet,
    cache_key,
    cached_sequence_features,
    default_cache_dir,
)
from xvmatch.formats.cvmhat import (
    IMAGE_SIZE,
    default_cvmhat_dir,
    read_sequence,
    sequence_names,
    site_of,
)
from xvmatch.formats.mot_boxes import FrameBoxes, scale_frames, shift_frames

__all__ = [
    "CvmhatBoxDataModule",
    "FrameDataModule",
    "LabelledFrames",
    "MixedBoxDataModule",
    "SimBoxDataModule",
    "TrainingOffset",
    "collate_labelled",
    "labelled_sequence",
    "random_image_size",
    "random_scene_config",
    "training_offset",
]


@dataclass(frozen=True, eq=False)
class LabelledFrames:
    """Features of some frames with their labels.

    Attributes:
        features: the :class:`FeatureSet`.
        index: ``(K,)`` rows of ``features`` in this selection.
        matches: per stored frame, ``(M, N)`` bool ground-truth pairs (canonical order).
        cameras: per stored frame, ``(H,)`` bool hypotheses whose O is the wearer.
        name: where the frames come from (sequence and variant), for reports.
    """

    features: FeatureSet
    index: np.ndarray
    matches: list[np.ndarray]
    cameras: list[np.ndarray]
    name: str = ""

    def __len__(self) -> int:
        return int(self.index.shape[0])

    def subset(self, rows: np.ndarray) -> LabelledFrames:
        """The frames ``self.index[rows]``."""
        return replace(self, index=self.index[np.asarray(rows, dtype=np.int64)])

    def item(self, k: int) -> tuple[FrameFeatures, np.ndarray, np.ndarray]:
        """(features, match, camera labels) of the k-th selected frame."""
        i = int(self.index[k])
        return self.features.frame(i), self.matches[i], self.cameras[i]


def labelled_sequence(
    top: Mapping[int, FrameBoxes],
    hor: Mapping[int, FrameBoxes],
    hor_size: tuple[float, float],
    config: FeatureConfig,
    cache_dir: str | Path | None = None,
    workers: int = 1,
    wearer_id: int = 0,
    name: str = "",
    frames: Iterable[int] | None = None,
    camera_given: bool = False,
) -> LabelledFrames:
    """Features (cached) and labels of the frames of a sequence that have boxes in both views.

    O is searched, unless ``camera_given``: then the top box with id ``wearer_id`` is O (the
    "O given" setting, where the user names the wearer); otherwise ``wearer_id`` only labels
    hypotheses.
    """
    both = sorted(f for f in (set(top) & set(hor)) if len(top[f]) and len(hor[f]))
    if frames is not None:
        wanted = {int(f) for f in frames}
        both = [f for f in both if f in wanted]
    feats = cached_sequence_features(
        top, hor, hor_size, config, wearer_id if camera_given else None, both,
        cache_dir=cache_dir, workers=workers,
    )
    matches, cameras = [], []
    for k, f in enumerate(feats.frames.tolist()):
        ff = feats.frame(k)
        matches.append(match_labels(ff, top[f].ids, hor[f].ids))
        cameras.append(camera_labels(ff, top[f].ids, wearer_id))
    return LabelledFrames(feats, np.arange(len(feats)), matches, cameras, name)


@dataclass(frozen=True)
class TrainingOffset:
    """The offset estimate of one training pair, as ``associate --offset auto`` reports it.

    Attributes:
        applied: frames the top view is re-timed by (0: the files' timing is kept).
        offset: the minimum of the clips' mean cost curve.
        status: ``applied``, ``within_tolerance`` or ``unsupported``
            (:class:`~xvmatch.cues.spatial_search.OffsetEstimate`).
        support: fraction of the clips whose own minimum agrees.
        evidence: paired t statistic of the clips' preference for ``offset`` over 0.
    """

    applied: int
    offset: int
    status: str
    support: float
    evidence: float


def training_offset(
    top: Mapping[int, FrameBoxes],
    hor: Mapping[int, FrameBoxes],
    hor_width: float,
    cache_dir: str | Path | None = None,
    workers: int = 1,
    max_offset: int = AUTO_MAX_OFFSET,
) -> TrainingOffset:
    """The ``associate --offset auto`` estimate (O searched, up to ``max_offset`` frames) of a
    training pair, cached under ``offsets/`` in the feature cache: a minute of search per CVMHAT
    pair, done once. Boxes only; ids play no part."""
    folder = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    frames = sorted(set(top) | set(hor))
    key = cache_key(top, hor, (hor_width, 0.0), FeatureConfig(), None, frames)
    path = folder / "offsets" / f"auto{int(max_offset)}_{key}.json"
    if path.exists():
        try:
            return TrainingOffset(**json.loads(path.read_text()))
        except (OSError, ValueError, TypeError, RecursionError):
            pass  # unreadable or stale: estimate again and overwrite
    est = estimate_offset(top, hor, hor_width, max_offset=max_offset, workers=workers)
    found = TrainingOffset(applied=est.applied, offset=est.offset, status=est.status,
                           support=float(est.support), evidence=float(est.evidence))
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps(asdict(found)))
    return found


class _FrameDataset(Dataset):
    """Concatenation of :class:`LabelledFrames` as a map-style dataset of single frames."""

    def __init__(self, parts: Sequence[LabelledFrames]) -> None:
        self.parts = [p for p in parts if len(p)]
        self.bounds = np.cumsum([0] + [len(p) for p in self.parts])

    def __len__(self) -> int:
        return int(self.bounds[-1])

    def __getitem__(self, k: int):
        p = int(np.searchsorted(self.bounds, k, side="right") - 1)
        return self.parts[p].item(int(k - self.bounds[p]))


def collate_labelled(items: Sequence[tuple]) -> dict[str, torch.Tensor]:
    """Pad frames and labels into one batch of tensors (``match (B, M, N)``,
    ``camera_correct (B, H)``, and the inputs of :func:`collate_frames`). Items are
    ``(features, match, camera labels)``, or with pair cues ``(..., cues (M, N, K), cue mask
    (K,))``, which adds ``cues (B, M, N, K)`` and ``cue_mask (B, K)``."""
    feats = [it[0] for it in items]
    batch = collate_frames(feats)
    b, m, n = batch["pair"].shape[0], batch["top"].shape[1], batch["hor"].shape[1]
    h = batch["hyp"].shape[1]
    match = np.zeros((b, m, n), bool)
    cams = np.zeros((b, h), bool)
    with_cues = len(items[0]) == 5 if items else False
    if with_cues:
        k_cues = items[0][4].shape[0]
        cues = np.zeros((b, m, n, k_cues), np.float32)
        cue_mask = np.zeros((b, k_cues), bool)
    for k, item in enumerate(items):
        f, mt, cm = item[:3]
        _, mm, nn_ = f.shape
        match[k, :mm, :nn_] = mt
        cams[k, : cm.shape[0]] = cm
        if with_cues:
            cues[k, :mm, :nn_] = item[3]
            cue_mask[k] = item[4]
    batch["match"] = match
    batch["camera_correct"] = cams
    if with_cues:
        batch["cues"], batch["cue_mask"] = cues, cue_mask
    return {k: torch.from_numpy(v) for k, v in batch.items()}


def _loader(parts: Sequence[LabelledFrames], batch_size: int, shuffle: bool, seed: int):
    generator = torch.Generator().manual_seed(seed) if shuffle else None
    return DataLoader(
        _FrameDataset(parts),
        batch_size=batch_size,
        shuffle=shuffle,
        collate_fn=collate_labelled,
        generator=generator,
        num_workers=0,
    )


class FrameDataModule(L.LightningDataModule):
    """Shared loaders of labelled frames; subclasses fill ``self.train_parts``, ``val_parts``
    and ``test_parts`` with parts that have ``len`` and ``item(k)`` (e.g.
    :class:`LabelledFrames`)."""

    def __init__(self, batch_size: int, seed: int) -> None:
        super().__init__()
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        self.batch_size = batch_size
        self.seed = seed
        self.train_parts: list[LabelledFrames] = []
        self.val_parts: list[LabelledFrames] = []
        self.test_parts: list[LabelledFrames] = []

    def train_dataloader(self) -> DataLoader:
        return _loader(self.train_parts, self.batch_size, True, self.seed)

    def val_dataloader(self) -> DataLoader:
        return _loader(self.val_parts, self.batch_size, False, self.seed)

    def test_dataloader(self) -> DataLoader:
        return _loader(self.test_parts, self.batch_size, False, self.seed)


class CvmhatBoxDataModule(FrameDataModule):
    """CVMHAT dev sequences, leave-one-site-out.

    Args:
        data_dir: folder of the box files (default: ``$XVMATCH_CVMHAT`` or
            ``../shared/data/cvmhat``).
        train_sites: sites to train on (default: every site but ``test_site``).
        test_site: site held out as the test set (None: no test set).
        val_fraction: the last fraction of each training sequence's frames validates.
        clean: include the clean training sequences.
        noise_seeds: seeds of detector-noise copies of the training sequences (default
            setting of :class:`DetectorNoise`); use seeds distinct from the evaluation ones.
        val_noise_seed: seed of a detector-noise copy of the validation frames (None: clean
            validation only).
        frame_step: keep every k-th frame (1: all).
        feature_config: hypothesis generation of the features.
        batch_size: frames per batch.
        cache_dir: feature cache folder (default ``~/.cache/xvmatch``).
        workers: processes for feature extraction.
        seed: seed of the shuffling.
        synchronise: re-time each training sequence's top view by the offset
            :func:`training_offset` applies (0 for synchronised pairs), so that the labels (same
            id, same person) hold for the frame pairs the model sees; ``offsets`` records them.
            The test site keeps the files' timing.
        sync_max_offset: largest |offset| searched (default that of ``--offset auto``).
        rescale: give each detector-noise copy its own resolution per view (boxes scaled by a
            seeded factor in [1/2, 2]; augmentation over resolutions).
    """

    def __init__(
        self,
        data_dir: str | None = None,
        train_sites: list[str] | None = None,
        test_site: str | None = None,
        val_fraction: float = 0.15,
        clean: bool = True,
        noise_seeds: list[int] | None = None,
        val_noise_seed: int | None = None,
        frame_step: int = 1,
        feature_config: FeatureConfig | None = None,
        batch_size: int = 32,
        cache_dir: str | None = None,
        workers: int = 1,
        seed: int = 0,
        synchronise: bool = True,
        sync_max_offset: int = AUTO_MAX_OFFSET,
        rescale: bool = True,
    ) -> None:
        super().__init__(batch_size, seed)
        if not 0.0 <= val_fraction < 1.0:
            raise ValueError(f"val_fraction must be in [0, 1), got {val_fraction}")
        if frame_step < 1:
            raise ValueError(f"frame_step must be >= 1, got {frame_step}")
        self.data_dir = Path(data_dir) if data_dir else default_cvmhat_dir()
        self.train_sites = train_sites
        self.test_site = test_site
        self.val_fraction = val_fraction
        self.clean = clean
        self.noise_seeds = list(noise_seeds or [])
        self.val_noise_seed = val_noise_seed
        self.frame_step = frame_step
        self.feature_config = feature_config or FeatureConfig()
        self.cache_dir = cache_dir
        self.workers = workers
        self.synchronise = synchronise
        self.sync_max_offset = sync_max_offset
        self.rescale = rescale
        self.offsets: dict[str, TrainingOffset] = {}
        if not clean and not self.noise_seeds:
            raise ValueError("nothing to train on: clean=False and no noise_seeds")

    def sequences(self) -> dict[str, list[str]]:
        """``{site: [sequence names]}`` found in ``data_dir``."""
        if not self.data_dir.is_dir():
            raise ValueError(
                f"CVMHAT folder {str(self.data_dir)!r} not found; pass data_dir or set "
                "XVMATCH_CVMHAT"
            )
        out: dict[str, list[str]] = {}
        for name in sequence_names(self.data_dir):
            out.setdefault(site_of(name), []).append(name)
        if not out:
            raise ValueError(f"no NAME_top.txt / NAME_hor.txt pairs in {str(self.data_dir)!r}")
        return out

    def _sites(self) -> tuple[list[str], list[str]]:
        by_site = self.sequences()
        if self.test_site is not None and self.test_site not in by_site:
            raise ValueError(
                f"test_site {self.test_site!r} not among the sites {sorted(by_site)}"
            )
        train = self.train_sites or [s for s in sorted(by_site) if s != self.test_site]
        unknown = sorted(set(train) - set(by_site))
        if unknown:
            raise ValueError(f"train_sites {unknown} not among the sites {sorted(by_site)}")
        if self.test_site in train:
            raise ValueError(f"test_site {self.test_site!r} is also a training site")
        return train, ([self.test_site] if self.test_site else [])

    def training_offsets(self) -> dict[str, TrainingOffset]:
        """``{name: offset estimate}`` of the training sequences (empty unless
        ``synchronise``); estimated once, then read from the cache."""
        if self.synchronise:
            by_site = self.sequences()
            for site in self._sites()[0]:
                for name in by_site[site]:
                    if name not in self.offsets:
                        top, hor = read_sequence(self.data_dir, name)
                        self.offsets[name] = training_offset(
                            top, hor, IMAGE_SIZE[0], self.cache_dir, self.workers,
                            self.sync_max_offset)
        return dict(self.offsets)

    def _variant(self, name, top, hor, seed: int | None, frames) -> LabelledFrames:
        size = IMAGE_SIZE
        if seed is not None:
            noise = DetectorNoise()
            top = apply_detector_noise(top, IMAGE_SIZE, noise, seed=seed, view="top")
            hor = apply_detector_noise(hor, IMAGE_SIZE, noise, seed=seed, view="hor")
            if self.rescale:
                # The same videos at other resolutions (each view its own, log-uniform in
                # [1/2, 2]): the features are resolution-free, and the training data say so.
                rng = np.random.default_rng([seed, zlib.crc32(name.encode())])
                f_top, f_hor = np.exp(rng.uniform(np.log(0.5), np.log(2.0), size=2))
                top, hor = scale_frames(top, f_top), scale_frames(hor, f_hor)
                size = (IMAGE_SIZE[0] * f_hor, IMAGE_SIZE[1] * f_hor)
        tag = "clean" if seed is None else f"noise{seed}"
        return labelled_sequence(
            top, hor, size, self.feature_config, self.cache_dir, self.workers,
            name=f"{name}/{tag}", frames=frames,
        )

    def setup(self, stage: str | None = None) -> None:
        """Read the sequences, extract (or load cached) features, split train / val / test."""
        if self.train_parts or self.test_parts:
            return
        train_sites, test_sites = self._sites()
        by_site = self.sequences()
        offsets = self.training_offsets()
        for site in train_sites:
            for name in by_site[site]:
                top, hor = read_sequence(self.data_dir, name)
                if offsets.get(name) is not None and offsets[name].applied:
                    top = shift_frames(top, offsets[name].applied)
                frames = sorted(set(top) & set(hor))[:: self.frame_step]
                cut = None  # first validation frame: the last val_fraction of the sequence
                if self.val_fraction > 0 and frames:
                    first = round(len(frames) * (1.0 - self.val_fraction))
                    cut = frames[min(len(frames) - 1, first)]
                seeds = ([None] if self.clean else []) + self.noise_seeds
                for seed in seeds:
                    part = self._variant(name, top, hor, seed, frames)
                    is_val = part.features.frames >= cut if cut is not None else np.zeros(
                        len(part), bool)
                    self.train_parts.append(part.subset(np.flatnonzero(~is_val)))
                    if seed is None:
                        self.val_parts.append(part.subset(np.flatnonzero(is_val)))
                if self.val_noise_seed is not None and cut is not None:
                    part = self._variant(name, top, hor, self.val_noise_seed, frames)
                    self.val_parts.append(
                        part.subset(np.flatnonzero(part.features.frames >= cut))
                    )
        for site in test_sites:
            for name in by_site[site]:
                top, hor = read_sequence(self.data_dir, name)
                frames = sorted(set(top) & set(hor))[:: self.frame_step]
                self.test_parts.append(self._variant(name, top, hor, None, frames))


def random_scene_config(rng: np.random.Generator, base: SceneConfig | None = None) -> SceneConfig:
    """A randomly perturbed :class:`SceneConfig` (domain randomisation of the simulator).

    Crowd size, body heights, walking area, drone altitude and field of view, the head-worn
    camera's field of view, pitch, roll and wobble, the wearer's gaze behaviour and the
    visibility threshold are drawn around the CVMHAT-like defaults; so are both views' image
    sizes (:func:`random_image_size`), which the features must not depend on.
    """
    base = base or SceneConfig()
    low = int(rng.integers(3, 9))
    high = int(rng.integers(max(low, 6), 15))
    h0 = float(rng.uniform(1.45, 1.75))
    area = float(rng.uniform(12.0, 26.0))
    config = replace(
        base,
        n_people=(low, high),
        area=area,
        height_range=(h0, h0 + float(rng.uniform(0.15, 0.45))),
        top_altitude=float(rng.uniform(25.0, 60.0)),
        top_hfov_deg=float(rng.uniform(50.0, 80.0)),
        top_footprint=tuple(float(v) * float(rng.uniform(0.8, 1.3)) for v in base.top_footprint),
        hor_hfov_deg=float(rng.uniform(80.0, 100.0)),
        hor_pitch_deg=float(rng.uniform(-5.0, 15.0)),
        hor_roll_deg=float(rng.uniform(-3.0, 3.0)),
        hor_wobble_deg=float(rng.uniform(0.0, 3.0)),
        gaze_at_group=float(rng.uniform(0.4, 1.0)),
        head_turn_std_deg=float(rng.uniform(10.0, 35.0)),
        min_visible_fraction=float(rng.uniform(0.2, 0.5)),
    )
    return replace(config, top_size=random_image_size(rng), hor_size=random_image_size(rng))


ASPECTS: tuple[float, ...] = (16 / 9, 4 / 3, 3 / 2, 1.0)
"""Width over height of the image sizes drawn by :func:`random_image_size` (video, GoPro and
phone sensors, square crops)."""


def random_image_size(
    rng: np.random.Generator, widths: tuple[float, float] = (640.0, 5376.0)
) -> tuple[int, int]:
    """A random image size: width log-uniform in ``widths`` (a quarter of the CVMHAT width to
    twice it), height from one of :data:`ASPECTS` (augmentation over resolutions)."""
    width = float(np.exp(rng.uniform(np.log(widths[0]), np.log(widths[1]))))
    aspect = ASPECTS[int(rng.integers(len(ASPECTS)))]
    return round(width), max(1, round(width / aspect))


def random_noise(rng: np.random.Generator) -> DetectorNoise:
    """Random detector-noise levels around the evaluation setting (5% / 10% / 0.3)."""
    return DetectorNoise(
        jitter=float(rng.uniform(0.0, 0.08)),
        miss_rate=float(rng.uniform(0.0, 0.2)),
        false_per_frame=float(rng.uniform(0.0, 0.6)),
    )


class SimBoxDataModule(FrameDataModule):
    """Scenes of the box simulator with randomised configurations (no real data).

    Args:
        n_scenes: scenes to simulate (each with its own random configuration and seed).
        frames_per_scene: frames simulated per scene.
        frame_step: keep every k-th simulated frame (consecutive frames are nearly identical).
        val_scenes: scenes held out (the last ones) for validation.
        noise_probability: probability that a scene gets detector noise of random levels.
        camera_given_probability: probability that a scene's features are extracted with O
            given (the wearer's top box named), so the model also learns that setting.
        feature_config: hypothesis generation of the features.
        batch_size: frames per batch.
        cache_dir: feature cache folder (default ``~/.cache/xvmatch``).
        workers: processes for feature extraction.
        seed: seeds the configurations, the scenes, the noise and the shuffling.
    """

    def __init__(
        self,
        n_scenes: int = 200,
        frames_per_scene: int = 90,
        frame_step: int = 3,
        val_scenes: int = 20,
        noise_probability: float = 0.5,
        camera_given_probability: float = 0.0,
        feature_config: FeatureConfig | None = None,
        batch_size: int = 32,
        cache_dir: str | None = None,
        workers: int = 1,
        seed: int = 0,
    ) -> None:
        super().__init__(batch_size, seed)
        if not 0.0 <= camera_given_probability <= 1.0:
            raise ValueError(
                f"camera_given_probability must be in [0, 1], got {camera_given_probability}"
            )
        self.camera_given_probability = camera_given_probability
        if n_scenes < 1 or frames_per_scene < 1 or frame_step < 1:
            raise ValueError("n_scenes, frames_per_scene and frame_step must be >= 1")
        if not 0 <= val_scenes < n_scenes:
            raise ValueError(f"val_scenes must be in [0, n_scenes), got {val_scenes}")
        if not 0.0 <= noise_probability <= 1.0:
            raise ValueError(f"noise_probability must be in [0, 1], got {noise_probability}")
        self.n_scenes = n_scenes
        self.frames_per_scene = frames_per_scene
        self.frame_step = frame_step
        self.val_scenes = val_scenes
        self.noise_probability = noise_probability
        self.feature_config = feature_config or FeatureConfig()
        self.cache_dir = cache_dir
        self.workers = workers

    def scene(self, k: int) -> tuple[dict[int, FrameBoxes], dict[int, FrameBoxes], SceneConfig]:
        """Boxes (top, hor) and configuration of the k-th scene (deterministic given the seed)."""
        rng = np.random.default_rng([self.seed, k, 11])
        config = random_scene_config(rng)
        scene = simulate_box_scene(config, self.frames_per_scene, seed=int(rng.integers(2**31)))
        top, hor = scene.top, scene.hor
        if rng.random() < self.noise_probability:
            noise = random_noise(rng)
            noise_seed = int(rng.integers(2**31))
            keep = (0,) if self.camera_given(k) else ()  # the named wearer is never missed
            top = apply_detector_noise(
                top, config.top_size, noise, seed=noise_seed, view="top", keep_ids=keep
            )
            hor = apply_detector_noise(hor, config.hor_size, noise, seed=noise_seed, view="hor")
        return top, hor, config

    def camera_given(self, k: int) -> bool:
        """Whether the k-th scene is extracted with O given (deterministic given the seed)."""
        draw = np.random.default_rng([self.seed, k, 12]).random()
        return bool(draw < self.camera_given_probability)

    def setup(self, stage: str | None = None) -> None:
        """Simulate the scenes, extract (or load cached) features, split by scene.

        With ``workers > 1`` whole scenes are simulated and extracted in parallel processes.
        """
        if self.train_parts:
            return
        jobs = [(self, k) for k in range(self.n_scenes)]
        if self.workers > 1 and self.n_scenes > 1:
            with worker_pool(self.workers, None) as pool:
                parts = list(pool.map(_sim_part, jobs, chunksize=4))
        else:
            parts = [_sim_part(job) for job in jobs]
        for k, part in enumerate(parts):
            is_val = k >= self.n_scenes - self.val_scenes
            (self.val_parts if is_val else self.train_parts).append(part)

    def part(self, k: int) -> LabelledFrames:
        """Labelled features of the kept frames of the k-th scene (cached on disk)."""
        top, hor, config = self.scene(k)
        frames = list(range(1, self.frames_per_scene + 1, self.frame_step))
        given = self.camera_given(k)
        return labelled_sequence(
            top, hor, config.hor_size, self.feature_config, self.cache_dir, 1,
            name=f"scene{k}" + ("/O-given" if given else ""), frames=frames, camera_given=given,
        )


def _sim_part(job: tuple[SimBoxDataModule, int]) -> LabelledFrames:
    module, k = job
    return module.part(k)


class MixedBoxDataModule(FrameDataModule):
    """Real box pairs plus simulated scenes: the union of both training sets.

    The simulator's diversity (domain randomisation) regularises a model trained on a few real
    sites, which otherwise learns site-specific shortcuts. Validation and test come from the
    real DataModule only (``sim_validation`` adds the simulated validation scenes).

    Args:
        real: the real-data DataModule (e.g. :class:`CvmhatBoxDataModule`).
        sim: the simulator DataModule (:class:`SimBoxDataModule`).
        sim_validation: also validate on the simulated validation scenes.
        batch_size: frames per batch.
        seed: seed of the shuffling.
    """

    def __init__(
        self,
        real: FrameDataModule,
        sim: SimBoxDataModule,
        sim_validation: bool = False,
        batch_size: int = 32,
        seed: int = 0,
    ) -> None:
        super().__init__(batch_size, seed)
        self.real = real
        self.sim = sim
        self.sim_validation = sim_validation

    def setup(self, stage: str | None = None) -> None:
        """Set both up and merge their splits."""
        if self.train_parts:
            return
        self.real.setup(stage)
        self.sim.setup(stage)
        self.train_parts = [*self.real.train_parts, *self.sim.train_parts]
        self.val_parts = [*self.real.val_parts, *(self.sim.val_parts if self.sim_validation
                                                   else [])]
        self.test_parts = list(self.real.test_parts)
