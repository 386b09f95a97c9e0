"""Detector-like corruption of box records: jitter, missed boxes and false boxes.

Ground-truth boxes (real CVMHAT annotations or :mod:`xvmatch.datasets.box_scene` output) are too
clean to stand for a detector. :func:`apply_detector_noise` degrades them the way the evaluation
protocol describes: "5% jitter of box size in position and scale, 10% of boxes missed, 0.3 false
boxes per frame and view". It is kept apart from the scene simulator so the very same noise
applies to real and synthetic boxes.

False boxes get ids no real person has: ``1_000_000 + k`` in the top view and ``2_000_000 + k`` in
the horizontal view (k = 0, 1, ... over the sequence, one new id per false box), so they never
match across views nor collide with a real id; real ids must therefore stay below 1_000_000.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import dataclass

import numpy as np

from xvmatch.formats.mot_boxes import FrameBoxes

__all__ = ["FALSE_ID_BASE", "DetectorNoise", "apply_detector_noise"]

FALSE_ID_BASE: dict[str, int] = {"top": 1_000_000, "hor": 2_000_000}
"""First id of the false boxes of each view; real ids must be below the smallest."""

_VIEW_STREAM = {"top": 0, "hor": 1}


@dataclass(frozen=True)
class DetectorNoise:
    """How much a simulated detector departs from the ground-truth boxes.

    Attributes:
        jitter: standard deviation of the box perturbation as a fraction of the box size: the
            centre moves by ``N(0, jitter) * (w, h)`` and each side length is scaled by
            ``exp(N(0, jitter))`` (log-normal, so sizes stay positive; ~``1 +- jitter``).
        miss_rate: probability that a box is dropped, independently per box.
        false_per_frame: Poisson mean of the false boxes added per frame (and view).
        miss_run: None (the default), each box missed on its own; else the mean length, in
            frames, of a run in which one person is missed (behind a passer-by, blurred,
            turned away), each id's frames a two-state chain missed ``miss_rate`` of the time
            on average, its runs of geometric length.
    """

    jitter: float = 0.05
    miss_rate: float = 0.10
    false_per_frame: float = 0.3
    miss_run: float | None = None

    def __post_init__(self) -> None:
        if not self.jitter >= 0:
            raise ValueError(f"DetectorNoise.jitter must be >= 0, got {self.jitter}")
        if not 0.0 <= self.miss_rate <= 1.0:
            raise ValueError(f"DetectorNoise.miss_rate must be in [0, 1], got {self.miss_rate}")
        if not self.false_per_frame >= 0:
            raise ValueError(
                f"DetectorNoise.false_per_frame must be >= 0, got {self.false_per_frame}"
            )
        if self.miss_run is not None and not self.miss_run >= 1:
            raise ValueError(f"DetectorNoise.miss_run must be None or >= 1 frame, got "
                             f"{self.miss_run}")


def _missed(draws: np.ndarray, ids: np.ndarray, noise: DetectorNoise) -> np.ndarray:
    """``(M,)`` the boxes a detector misses, from one uniform draw each (boxes frame after
    frame): each with probability ``miss_rate``, or, with ``miss_run``, each id's a two-state
    chain that leaves a miss with probability ``1 / miss_run`` a frame and enters one so that
    ``miss_rate`` of its frames are missed (a new id starts in that steady state)."""
    if noise.miss_run is None or noise.miss_rate >= 1.0:
        return draws < noise.miss_rate
    leave = 1.0 / noise.miss_run
    enter = min(1.0, noise.miss_rate / (1.0 - noise.miss_rate) * leave)
    state: dict[int, bool] = {}
    out = np.empty(len(draws), bool)
    for k, (i, d) in enumerate(zip(ids.tolist(), draws.tolist(), strict=True)):
        was = state.get(i)
        out[k] = state[i] = (d < noise.miss_rate if was is None else
                             d >= leave if was else d < enter)
    return out


def _jitter_and_drop(
    rng: np.random.Generator, boxes: np.ndarray, ids: np.ndarray, noise: DetectorNoise,
    keep_ids: Collection[int],
) -> tuple[np.ndarray, np.ndarray]:
    """Jitter every real box, then pick the ones a detector misses.

    Draws, in order: ``(M, 2)`` shifts, ``(M, 2)`` log-scales and M miss draws.

    Args:
        rng: the view's random stream.
        boxes: ``(M, 4)`` real boxes ``(x, y, w, h)``, pixels.
        ids: ``(M,)`` their ids.
        noise: the noise levels.
        keep_ids: ids that are never dropped.

    Returns:
        The ``(M, 4)`` jittered boxes and the ``(M,)`` mask of the kept ones.
    """
    n_real = ids.size
    shift = noise.jitter * rng.standard_normal((n_real, 2))
    scale = np.exp(noise.jitter * rng.standard_normal((n_real, 2)))
    size = boxes[:, 2:] * scale
    # x' = (x + w/2 + shift w) - w'/2, written so that zero jitter returns x exactly.
    corner = boxes[:, :2] + 0.5 * boxes[:, 2:] * (1.0 - scale) + shift * boxes[:, 2:]
    noisy = np.concatenate([corner, size], axis=1)
    kept = ~_missed(rng.random(n_real), ids, noise) | np.isin(ids, np.fromiter(keep_ids,
                                                                              np.int64))
    return noisy, kept


def _false_boxes(
    rng: np.random.Generator, boxes: np.ndarray, counts: np.ndarray, noise: DetectorNoise,
    width: float, height: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Draw the false boxes: a Poisson count per frame, each the size of a random real box.

    The size comes from a real box of the same frame, or of any frame when that one has none;
    the box lies inside the image. Draws, in order: the counts, one pick per false box, and
    ``(K, 2)`` positions.

    Args:
        rng: the view's random stream.
        boxes: ``(M, 4)`` real boxes of all frames, frame after frame.
        counts: ``(F,)`` real boxes per frame.
        noise: the noise levels.
        width, height: image size, pixels.

    Returns:
        The ``(K, 4)`` false boxes, frame after frame, and the ``(F,)`` count per frame.
    """
    n_real, n_frames = boxes.shape[0], counts.size
    starts = np.concatenate([[0], np.cumsum(counts)])
    n_false = rng.poisson(noise.false_per_frame, size=n_frames) if n_real else np.zeros(
        n_frames, dtype=np.int64
    )
    owner = np.repeat(np.arange(n_frames), n_false)
    pick = rng.random(owner.size)
    own_count = counts[owner]
    source = np.where(
        own_count > 0,
        starts[owner] + np.minimum((pick * own_count).astype(np.int64), own_count - 1),
        np.minimum((pick * n_real).astype(np.int64), max(n_real - 1, 0)),
    )
    false_size = boxes[source, 2:] if n_real else np.empty((0, 2))
    room = np.maximum(np.array([width, height]) - false_size, 0.0)
    false_corner = rng.random((owner.size, 2)) * room
    return np.concatenate([false_corner, false_size], axis=1), n_false


def apply_detector_noise(
    frames: Mapping[int, FrameBoxes],
    image_size: tuple[int, int],
    noise: DetectorNoise,
    seed: int,
    view: str,
    keep_ids: Collection[int] = (),
) -> dict[int, FrameBoxes]:
    """Jitter, drop and add boxes like a detector would, deterministically.

    Per box: the centre and both side lengths are perturbed (:class:`DetectorNoise`), then the box
    is dropped with probability ``miss_rate`` (or in runs, ``miss_run``) unless its id is in
    ``keep_ids`` (e.g. the top-view wearer box, id 0, which is an input when the camera location
    is given). Per frame:
    ``Poisson(false_per_frame)`` false boxes are added after the real ones; their sizes are those
    of real boxes of the same frame drawn at random (of the whole input when the frame has none),
    and they lie entirely inside the image at a uniformly drawn position. Noise is applied to the
    frames present in ``frames`` only: give empty records for frames that should still receive
    false boxes. If the input holds no box at all there is no size to draw from, and no false box
    is added.

    The random stream is ``default_rng([seed, 0])`` for ``view="top"`` and
    ``default_rng([seed, 1])`` for ``"hor"``: the same seed gives the same output, and the two
    views of a sequence get independent noise. Jittered boxes are not clipped to the image.

    Args:
        frames: ``{frame: FrameBoxes}`` of one view; real ids must be below 1_000_000.
        image_size: (width, height) of the images in pixels.
        noise: the noise levels; ``DetectorNoise(0, 0, 0)`` returns copies of the input.
        seed: random seed.
        view: ``"top"`` or ``"hor"``; selects the random stream and the false-id range
            (``FALSE_ID_BASE[view] + k``).
        keep_ids: ids that are never dropped (they are still jittered).

    Returns:
        ``{frame: FrameBoxes}`` with the same frames, in ascending order.

    Raises:
        ValueError: unknown ``view``, non-positive ``image_size``, or a real id >= 1_000_000.
    """
    if view not in _VIEW_STREAM:
        raise ValueError(f"view must be 'top' or 'hor', got {view!r}")
    width, height = (float(v) for v in image_size)
    if not (width > 0 and height > 0):
        raise ValueError(f"image_size must be (width, height) > 0, got {image_size}")
    keys = sorted(frames)
    counts = np.array([len(frames[k]) for k in keys], dtype=np.int64)
    ids = np.concatenate([frames[k].ids for k in keys] or [np.empty(0, np.int64)])
    boxes = np.concatenate([frames[k].boxes for k in keys] or [np.empty((0, 4))])
    if ids.size and ids.max() >= min(FALSE_ID_BASE.values()):
        raise ValueError(
            f"apply_detector_noise: real ids must be < {min(FALSE_ID_BASE.values())} (that range "
            f"is reserved for false boxes), got id {int(ids.max())}"
        )
    rng = np.random.default_rng([int(seed), _VIEW_STREAM[view]])
    n_frames = len(keys)
    noisy, kept = _jitter_and_drop(rng, boxes, ids, noise, keep_ids)
    false_boxes, n_false = _false_boxes(rng, boxes, counts, noise, width, height)
    false_ids = FALSE_ID_BASE[view] + np.arange(false_boxes.shape[0], dtype=np.int64)

    frame_of_real = np.repeat(np.arange(n_frames), counts)
    real_bounds = np.searchsorted(frame_of_real[kept], np.arange(n_frames + 1))
    false_bounds = np.concatenate([[0], np.cumsum(n_false)])
    out_ids, out_boxes = ids[kept], noisy[kept]
    result: dict[int, FrameBoxes] = {}
    for i, key in enumerate(keys):
        r0, r1 = real_bounds[i], real_bounds[i + 1]
        f0, f1 = false_bounds[i], false_bounds[i + 1]
        result[key] = FrameBoxes(
            frames[key].frame,
            np.concatenate([out_ids[r0:r1], false_ids[f0:f1]]),
            np.concatenate([out_boxes[r0:r1], false_boxes[f0:f1]]),
        )
    return result
