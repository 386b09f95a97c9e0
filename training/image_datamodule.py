"""Person crops of both views of synthetic image pairs, for the Siamese appearance branch.

Each item is one image pair (one frame of one scene, ``xvmatch synth``): the crops of every
labelled person of the top view and of the egocentric view, each view in its own seeded random
order ("ids scrambled per view"), and the ``(M, N)`` ground-truth match matrix. Ids are read
once, to build that matrix, and never reach the crops' order or the network.

Hard negatives come from the pairs themselves, two ways:

* the other people of the same frame share the scene, the light and often the clothing palette
  (look-alikes); the contrastive loss keeps the hardest of them per row and column
  (:class:`xvmatch.models.losses.ContrastiveLoss`);
* geometrically hard negatives: false pairs whose projection rays (top centres of the boxes,
  Eq. 6 of the geometric-priors paper, with the pair's cameras) pass within ``hard_radius``
  metres of each other. Geometry cannot tell those apart, so they are where appearance must,
  once the costs are fused; :class:`~xvmatch.training.appearance_module.AppearanceModule` can
  weight them in a second contrastive term.

Crops are cut once, in :meth:`ImagePairDataModule.setup`, at the network's input size and held
in memory as uint8 (about 25 kB per 128x64 crop). Training augmentations run on whole batches
after the transfer to the device (:func:`augment_crops`): per-view camera changes (white
balance, exposure, gamma, as the two rendered cameras differ), per-crop jitter of the box
(scale, shift, mirror), loss of resolution, occluding patches and sensor noise. With
``camera_shift_probability`` > 0 (issue 31, off by default), a share of each view's crops of a
pair first go through one simulated other camera (:func:`xvmatch.datasets.camera_shift.
camera_shift`: white balance, exposure, tone curve, hue and saturation, blur, sensor noise, JPEG)
of a strength drawn up to ``camera_shift_max``.

Splits are by scene: validation scenes are either a separate dataset folder or a seeded
fraction of the training folders' scenes, never frames of a training scene. Nothing is
downloaded: folders come from ``xvmatch synth``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import lightning as L
import numpy as np
import torch
from torch import Tensor
from torch.nn import functional as F
from torch.utils.data import DataLoader, Dataset

from xvmatch.datasets.camera_shift import MAX_STRENGTH, camera_shift
from xvmatch.datasets.synthetic_io import MANIFEST, PairRecord, SyntheticDataset, person_crops
from xvmatch.geometry.ray_priors import box_rays, ray_distances

__all__ = [
    "CropBatch",
    "CropPair",
    "CropPairDataset",
    "ImagePairDataModule",
    "augment_crops",
    "collate_crop_pairs",
    "load_crop_pairs",
    "pair_crops",
    "split_scenes",
]


@dataclass(frozen=True, eq=False)
class CropPair:
    """The crops of both views of one image pair, each view in scrambled order.

    Attributes:
        scene: scene name.
        frame: 1-based frame number.
        top: ``(M, H, W, 3)`` uint8 BGR crops of the top view.
        ego: ``(N, H, W, 3)`` uint8 BGR crops of the egocentric view.
        match: ``(M, N)`` bool, True where both crops show the same person.
        near: ``(M, N)`` bool, False pairs whose rays pass within the hard radius (geometrically
            hard negatives); all False when not computed.
    """

    scene: str
    frame: int
    top: np.ndarray
    ego: np.ndarray
    match: np.ndarray
    near: np.ndarray | None = None


def pair_crops(
    pair: PairRecord,
    input_size: tuple[int, int],
    rng: np.random.Generator,
    *,
    min_pixels: int = 20,
    context: float = 0.1,
    hard_radius: float = 1.0,
) -> CropPair:
    """Crop the labelled people of both views of a pair and scramble each view's order.

    Args:
        pair: the labelled pair.
        input_size: ``(height, width)`` of the crops.
        rng: generator of the per-view permutations.
        min_pixels: leave out people with fewer visible pixels (slivers at the image border).
        context: relative margin around each visible box.
        hard_radius: ray distance (metres) below which a false pair is a geometrically hard
            negative.

    Returns:
        The :class:`CropPair`.
    """
    size = (int(input_size[1]), int(input_size[0]))
    out, ids, rays = {}, {}, {}
    for view in ("top", "ego"):
        record = getattr(pair, view)
        labels = record.labels
        keep = labels.visible_pixels >= min_pixels
        pid, crops = person_crops(record.load_image(), labels, size=size,
                                  min_pixels=min_pixels, context=context)
        order = rng.permutation(len(pid))
        out[view], ids[view] = crops[order], pid[order]
        rays[view] = box_rays(record.camera, labels.boxes[keep][order])
    match = ids["top"][:, None] == ids["ego"][None, :]
    near = (ray_distances(rays["top"], rays["ego"]) < hard_radius) & ~match
    return CropPair(pair.scene, pair.frame, out["top"], out["ego"], match, near)


def split_scenes(names: Sequence[str], fraction: float, seed: int) -> tuple[list[str], list[str]]:
    """Hold out a seeded ``fraction`` of whole scenes: ``(train, held_out)``, each sorted.

    At least one scene is held out when ``fraction > 0`` and at least one is kept.
    """
    if not 0 <= fraction < 1:
        raise ValueError(f"val_fraction must be in [0, 1), got {fraction}")
    names = sorted(names)
    n_out = 0 if fraction == 0 else min(max(1, round(fraction * len(names))), len(names) - 1)
    order = np.random.default_rng([int(seed), 7]).permutation(len(names))
    held = {names[i] for i in order[:n_out]}
    return [n for n in names if n not in held], [n for n in names if n in held]


def _open(root: str | os.PathLike) -> SyntheticDataset:
    root = Path(root)
    if not (root / MANIFEST).is_file():
        raise ValueError(
            f"{os.fspath(root)}: no {MANIFEST}; render a dataset first, e.g. xvmatch synth --out "
            f"{os.fspath(root)} --scenario overview --scenes 200 --frames 5 --seed 1"
        )
    return SyntheticDataset(root)


def load_crop_pairs(
    root: str | os.PathLike,
    scenes: Sequence[str] | None,
    input_size: tuple[int, int],
    *,
    seed: int = 0,
    min_pixels: int = 20,
    context: float = 0.1,
    hard_radius: float = 1.0,
    workers: int = 1,
) -> list[CropPair]:
    """Crops of every pair of the given scenes of a dataset folder, in scene and frame order.

    The permutation of pair ``(scene index i, frame f)`` comes from
    ``default_rng([seed, i, f])`` alone, so the result does not depend on ``workers``.

    Args:
        root: dataset folder written by ``xvmatch synth``.
        scenes: scene names to load; None: all.
        input_size: ``(height, width)`` of the crops.
        seed: seed of the per-view scrambling.
        min_pixels: see :func:`pair_crops`.
        context: see :func:`pair_crops`.
        hard_radius: see :func:`pair_crops`.
        workers: threads decoding images (OpenCV releases the GIL).

    Raises:
        ValueError: no dataset at ``root`` or an unknown scene.
    """
    dataset = _open(root)
    names = dataset.scene_names
    wanted = names if scenes is None else list(scenes)
    unknown = sorted(set(wanted) - set(names))
    if unknown:
        raise ValueError(f"{os.fspath(root)}: no scenes {unknown[:3]}")
    index = {n: i for i, n in enumerate(names)}
    jobs = []
    for name in wanted:
        for pair in dataset.scene(name).pairs:
            jobs.append((pair, np.random.default_rng([int(seed), index[name], pair.frame])))

    def run(job: tuple[PairRecord, np.random.Generator]) -> CropPair:
        return pair_crops(job[0], input_size, job[1], min_pixels=min_pixels, context=context,
                          hard_radius=hard_radius)

    if int(workers) <= 1:
        return [run(j) for j in jobs]
    with ThreadPoolExecutor(max_workers=int(workers)) as pool:
        return list(pool.map(run, jobs))


class CropPairDataset(Dataset):
    """A list of :class:`CropPair` as a map-style dataset."""

    def __init__(self, pairs: Sequence[CropPair]) -> None:
        self.pairs = list(pairs)

    def __len__(self) -> int:
        return len(self.pairs)

    def __getitem__(self, k: int) -> CropPair:
        return self.pairs[k]


class CropBatch(NamedTuple):
    """A padded batch of image pairs.

    Attributes:
        top: ``(B, M, H, W, 3)`` crops of the top views (uint8, or float [0, 255] once
            augmented); padding is zeros.
        ego: ``(B, N, H, W, 3)`` crops of the egocentric views.
        top_mask: ``(B, M)`` bool, real crops.
        ego_mask: ``(B, N)`` bool.
        match: ``(B, M, N)`` bool ground truth (False on padding).
        near: ``(B, M, N)`` bool geometrically hard negatives (False on padding).
    """

    top: Tensor
    ego: Tensor
    top_mask: Tensor
    ego_mask: Tensor
    match: Tensor
    near: Tensor


def collate_crop_pairs(items: Sequence[CropPair]) -> CropBatch:
    """Pad a list of pairs to the largest M and N of the batch (empty sides allowed)."""
    if not items:
        raise ValueError("cannot collate an empty list of pairs")
    b = len(items)
    h, w = items[0].top.shape[1:3] if items[0].top.ndim == 4 else items[0].ego.shape[1:3]
    m = max(1, max(len(p.top) for p in items))
    n = max(1, max(len(p.ego) for p in items))
    top = torch.zeros(b, m, h, w, 3, dtype=torch.uint8)
    ego = torch.zeros(b, n, h, w, 3, dtype=torch.uint8)
    top_mask = torch.zeros(b, m, dtype=torch.bool)
    ego_mask = torch.zeros(b, n, dtype=torch.bool)
    match = torch.zeros(b, m, n, dtype=torch.bool)
    near = torch.zeros(b, m, n, dtype=torch.bool)
    for k, p in enumerate(items):
        mk, nk = len(p.top), len(p.ego)
        if mk:
            top[k, :mk] = torch.from_numpy(np.ascontiguousarray(p.top))
        if nk:
            ego[k, :nk] = torch.from_numpy(np.ascontiguousarray(p.ego))
        top_mask[k, :mk] = True
        ego_mask[k, :nk] = True
        match[k, :mk, :nk] = torch.from_numpy(np.asarray(p.match, dtype=bool).reshape(mk, nk))
        if p.near is not None:
            near[k, :mk, :nk] = torch.from_numpy(np.asarray(p.near, dtype=bool).reshape(mk, nk))
    return CropBatch(top, ego, top_mask, ego_mask, match, near)


# --------------------------------------------------------------------------------------------
# Augmentation


def _uniform(shape: tuple[int, ...], low: float, high: float, g: torch.Generator,
             device: torch.device) -> Tensor:
    return low + (high - low) * torch.rand(shape, generator=g).to(device)


def _normal(shape: tuple[int, ...], std: float, g: torch.Generator,
            device: torch.device) -> Tensor:
    return std * torch.randn(shape, generator=g).to(device)


def _camera_shift_view(crops: Tensor, g: torch.Generator, probability: float,
                       max_strength: float) -> Tensor:
    """``(B, K, H, W, 3)`` crops of one view, each pair's (B) crops with ``probability`` through
    one other camera (:func:`camera_shift` of the pair's crops side by side, one camera for all,
    strength uniform in [0, ``max_strength``]); uint8 [0, 255] on the crops' device (through the
    CPU: :func:`camera_shift` is NumPy and OpenCV)."""
    b, k, h, w, _ = crops.shape
    if crops.dtype != torch.uint8:
        crops = crops.detach().round().clamp(0, 255).to(torch.uint8)
    x = crops.cpu().numpy().copy()
    use = torch.rand(b, generator=g).numpy() < probability
    strength = (max_strength * torch.rand(b, generator=g)).numpy()
    seeds = torch.randint(0, 2**31 - 1, (b,), generator=g).numpy()
    for i in np.flatnonzero(use & (strength > 0)):
        side_by_side = np.ascontiguousarray(x[i].transpose(1, 0, 2, 3).reshape(h, k * w, 3))
        shifted = camera_shift(side_by_side, float(strength[i]), int(seeds[i]), per_image=False)
        x[i] = shifted.reshape(h, k, w, 3).transpose(1, 0, 2, 3)
    return torch.from_numpy(x).to(crops.device)


def _augment_view(crops: Tensor, g: torch.Generator, shift_probability: float = 0.0,
                  shift_max: float = 2.0) -> Tensor:
    """Augment ``(B, K, H, W, 3)`` crops [0, 255]: camera per (B), box and noise per crop
    (first, with ``shift_probability`` > 0, :func:`_camera_shift_view`)."""
    if shift_probability > 0:
        crops = _camera_shift_view(crops, g, shift_probability, shift_max)
    b, k, h, w, _ = crops.shape
    dev = crops.device
    x = crops.reshape(b * k, h, w, 3).permute(0, 3, 1, 2).float() / 255.0
    n = x.shape[0]
    # Box jitter: scale, shift and mirror of each crop (a detector's box is never exact).
    scale = _uniform((n,), 0.85, 1.15, g, dev)
    flip = torch.where(torch.rand(n, generator=g).to(dev) < 0.5, -1.0, 1.0)
    theta = torch.zeros(n, 2, 3, device=dev)
    theta[:, 0, 0] = scale * flip
    theta[:, 1, 1] = scale * _uniform((n,), 0.92, 1.08, g, dev)
    theta[:, 0, 2] = _uniform((n,), -0.1, 0.1, g, dev)
    theta[:, 1, 2] = _uniform((n,), -0.08, 0.08, g, dev)
    grid = F.affine_grid(theta, list(x.shape), align_corners=False)
    x = F.grid_sample(x, grid, mode="bilinear", padding_mode="border", align_corners=False)
    # Loss of resolution (far people, small boxes upsampled): on a random half of the crops.
    factor = float(_uniform((1,), 1.5, 4.0, g, dev))
    small = F.interpolate(x, size=(max(4, round(h / factor)), max(2, round(w / factor))),
                          mode="bilinear", align_corners=False, antialias=True)
    blurred = F.interpolate(small, size=(h, w), mode="bilinear", align_corners=False)
    pick = (torch.rand(n, generator=g) < 0.5).to(dev)[:, None, None, None]
    x = torch.where(pick, blurred, x)
    # Camera of the view (one per pair and view): white balance, exposure, tone curve.
    gains = torch.exp(_normal((b, 3), 0.08, g, dev) + _normal((b, 1), 0.25, g, dev))
    gains = gains.repeat_interleave(k, dim=0)[:, :, None, None]
    gamma = torch.exp(_normal((b,), 0.12, g, dev)).repeat_interleave(k)[:, None, None, None]
    x = (x * gains).clamp(0.0, 1.0) ** gamma
    # Per crop: small brightness and contrast changes (local light, shadows).
    bright = torch.exp(_normal((n, 1, 1, 1), 0.1, g, dev))
    mean = x.mean(dim=(1, 2, 3), keepdim=True)
    contrast = torch.exp(_normal((n, 1, 1, 1), 0.1, g, dev))
    x = ((x - mean) * contrast + mean) * bright
    # Occluding patch on some crops (a nearer person, an object).
    occlude = (torch.rand(n, generator=g) < 0.25).to(dev)
    ph = (_uniform((n,), 0.15, 0.45, g, dev) * h).long()
    pw = (_uniform((n,), 0.3, 0.9, g, dev) * w).long()
    py = (_uniform((n,), 0.0, 1.0, g, dev) * (h - ph)).long()
    px = (_uniform((n,), 0.0, 1.0, g, dev) * (w - pw)).long()
    rows = torch.arange(h, device=dev)[None, :, None]
    cols = torch.arange(w, device=dev)[None, None, :]
    patch = ((rows >= py[:, None, None]) & (rows < (py + ph)[:, None, None])
             & (cols >= px[:, None, None]) & (cols < (px + pw)[:, None, None])
             & occlude[:, None, None])
    fill = _uniform((n, 3, 1, 1), 0.0, 1.0, g, dev).expand(-1, -1, h, w)
    x = torch.where(patch[:, None], fill, x)
    # Sensor noise.
    x = x + _uniform((n, 1, 1, 1), 0.0, 0.02, g, dev) * torch.randn(
        x.shape, generator=g).to(dev)
    x = x.clamp(0.0, 1.0) * 255.0
    return x.permute(0, 2, 3, 1).reshape(b, k, h, w, 3)


def augment_crops(batch: CropBatch, generator: torch.Generator, shift_probability: float = 0.0,
                  shift_max: float = 2.0) -> CropBatch:
    """Training augmentation of a batch, on whatever device it is (see the module docstring).

    Args:
        batch: the batch, crops uint8 or float [0, 255].
        generator: CPU generator of every random draw (so results do not depend on the device).
        shift_probability: share of the pairs whose crops of a view first go through another
            simulated camera (each view its own draw; 0: none, and no draw is made).
        shift_max: the strongest such camera, in (0, 3].

    Returns:
        The batch with float [0, 255] crops; masks and labels unchanged. Padding crops are
        augmented too but stay masked out.
    """
    return batch._replace(top=_augment_view(batch.top, generator, shift_probability, shift_max),
                          ego=_augment_view(batch.ego, generator, shift_probability, shift_max))


# --------------------------------------------------------------------------------------------
# DataModule


def _folders(value: str | Sequence[str] | None) -> list[str]:
    if value is None:
        return []
    return [value] if isinstance(value, str | os.PathLike) else [os.fspath(v) for v in value]


class ImagePairDataModule(L.LightningDataModule):
    """Crops of synthetic image pairs: train, validation and test splits by scene.

    Args:
        train_data: one or more dataset folders (``xvmatch synth``) to train on.
        val_data: dataset folder(s) to validate on (early stopping, checkpoint choice); None:
            hold out ``val_fraction`` of the scenes of each training folder.
        test_data: dataset folder(s) for ``trainer.test``; None: no test split.
        val_fraction: fraction of whole training scenes held out when ``val_data`` is None.
        input_height: crop height in pixels; must equal the network's input size.
        input_width: crop width in pixels.
        batch_size: image pairs per batch (each holds all the people of both views).
        min_pixels: leave out people with fewer visible pixels.
        context: relative margin around each box.
        hard_radius: ray distance (metres) below which a false pair is a geometrically hard
            negative.
        augment: apply :func:`augment_crops` to training batches.
        camera_shift_probability: with ``augment``, the share of the pairs whose crops of a
            view first go through another simulated camera (issue 31; 0, the default: none).
        camera_shift_max: the strongest such camera, in (0, 3] (the stress test's scale).
        seed: seed of the scene split, the scrambling, the batch order and the augmentations.
        workers: threads decoding images in :meth:`setup`.
        num_workers: DataLoader worker processes (0: crops are in memory, batches are cheap).
    """

    def __init__(
        self,
        train_data: str | list[str],
        val_data: str | list[str] | None = None,
        test_data: str | list[str] | None = None,
        val_fraction: float = 0.1,
        input_height: int = 128,
        input_width: int = 64,
        batch_size: int = 8,
        min_pixels: int = 20,
        context: float = 0.1,
        hard_radius: float = 1.0,
        augment: bool = True,
        seed: int = 0,
        workers: int = 2,
        num_workers: int = 0,
        camera_shift_probability: float = 0.0,
        camera_shift_max: float = 2.0,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.train_folders = _folders(train_data)
        if not self.train_folders:
            raise ValueError("train_data must name at least one dataset folder")
        self.val_folders = _folders(val_data)
        self.test_folders = _folders(test_data)
        if not 0 <= val_fraction < 1:
            raise ValueError(f"val_fraction must be in [0, 1), got {val_fraction}")
        if int(batch_size) < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        self.input_size = (int(input_height), int(input_width))
        if min(self.input_size) < 16:
            raise ValueError(f"input_height and input_width must be >= 16, got {self.input_size}")
        self.batch_size = int(batch_size)
        if not 0.0 <= camera_shift_probability <= 1.0:
            raise ValueError("camera_shift_probability must be in [0, 1], got "
                             f"{camera_shift_probability}")
        if not 0.0 < camera_shift_max <= MAX_STRENGTH:
            raise ValueError(f"camera_shift_max must be in (0, {MAX_STRENGTH:g}], got "
                             f"{camera_shift_max}")
        self.seed = int(seed)
        self._generator = torch.Generator().manual_seed(self.seed)
        self.splits: dict[str, list[CropPair]] = {}

    def _load(self, folder: str, scenes: list[str] | None, k: int) -> list[CropPair]:
        hp = self.hparams
        return load_crop_pairs(folder, scenes, self.input_size, seed=self.seed + 1000 * k,
                               min_pixels=hp.min_pixels, context=hp.context,
                               hard_radius=hp.hard_radius, workers=hp.workers)

    def setup(self, stage: str | None = None) -> None:
        """Cut the crops of the splits ``stage`` needs (once; later calls reuse them)."""
        need_fit = stage in (None, "fit", "validate") and "train" not in self.splits
        if need_fit:
            train, val = [], []
            for k, folder in enumerate(self.train_folders):
                names = _open(folder).scene_names
                if self.val_folders:
                    keep, held = names, []
                else:
                    keep, held = split_scenes(names, self.hparams.val_fraction, self.seed + k)
                train += self._load(folder, keep, k)
                if held:
                    val += self._load(folder, held, k)
            for k, folder in enumerate(self.val_folders):
                val += self._load(folder, None, 100 + k)
            self.splits["train"], self.splits["val"] = train, val
        if stage in (None, "test") and "test" not in self.splits and self.test_folders:
            self.splits["test"] = [p for k, folder in enumerate(self.test_folders)
                                   for p in self._load(folder, None, 200 + k)]

    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        if split not in self.splits:
            raise RuntimeError(f"no {split} split: call setup() first, or give the "
                               f"{'test_data' if split == 'test' else 'train_data'} folders")
        generator = torch.Generator().manual_seed(self.seed) if shuffle else None
        return DataLoader(CropPairDataset(self.splits[split]), batch_size=self.batch_size,
                          shuffle=shuffle, generator=generator, collate_fn=collate_crop_pairs,
                          num_workers=self.hparams.num_workers)

    def train_dataloader(self) -> DataLoader:
        """Shuffled training pairs (seeded)."""
        return self._loader("train", True)

    def val_dataloader(self) -> DataLoader:
        """Validation pairs in order."""
        return self._loader("val", False)

    def test_dataloader(self) -> DataLoader:
        """Test pairs in order."""
        return self._loader("test", False)

    def on_after_batch_transfer(self, batch: CropBatch, dataloader_idx: int) -> CropBatch:
        """Augment training batches on the device (validation and test batches untouched)."""
        trainer = getattr(self, "trainer", None)
        if self.hparams.augment and trainer is not None and trainer.training:
            return augment_crops(batch, self._generator,
                                 float(self.hparams.camera_shift_probability),
                                 float(self.hparams.camera_shift_max))
        return batch

    def state_dict(self) -> dict:
        """The augmentation generator's state, so a resumed run continues its random stream."""
        return {"augment_generator": self._generator.get_state()}

    def load_state_dict(self, state_dict: dict) -> None:
        """Restore :meth:`state_dict`."""
        if "augment_generator" in state_dict:
            self._generator.set_state(state_dict["augment_generator"])

    def describe(self) -> str:
        """One line: pairs and crops per split."""
        parts = []
        for name, pairs in self.splits.items():
            crops = sum(len(p.top) + len(p.ego) for p in pairs)
            parts.append(f"{name}: {len(pairs)} pairs, {crops} crops")
        return "; ".join(parts) or "not set up"

