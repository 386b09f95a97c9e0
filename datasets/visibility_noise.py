"""Detector noise whose misses depend on how much of a person is visible.

:func:`xvmatch.datasets.detector_noise.apply_detector_noise` drops every box with the same
probability. A real detector misses mostly the people it barely sees; the rendered labels know
the visible fraction ``v`` of every box, so this wrapper raises the miss probability of a box to

    ``p_miss(v) = 1 - (1 - miss_rate) * (1 - hidden_miss * (1 - v) ** power)``

(``miss_rate`` for a fully visible person, ``1 - (1 - miss_rate) (1 - hidden_miss)`` for a fully
hidden one), and delegates jitter and false boxes to the base noise. It is kept apart from the
rendering, so the same noise can be re-drawn with other settings on a fixed dataset.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import dataclass, field

import numpy as np

from xvmatch.datasets.detector_noise import DetectorNoise, apply_detector_noise
from xvmatch.formats.mot_boxes import FrameBoxes

__all__ = ["VisibilityNoise", "apply_visibility_noise", "miss_probability"]

# The base noise names the egocentric view "hor" (horizontal), as CVMHAT does.
_BASE_VIEW = {"top": "top", "ego": "hor", "hor": "hor"}
_STREAM = {"top": 2, "ego": 3, "hor": 3}


@dataclass(frozen=True)
class VisibilityNoise:
    """Detector noise with visibility-dependent misses.

    Attributes:
        base: jitter, miss rate of fully visible boxes, and false boxes per frame.
        hidden_miss: extra miss probability of a fully hidden box, in [0, 1].
        power: how fast the extra miss probability grows as visibility falls (> 0); 2 keeps
            mostly visible people nearly always detected.
    """

    base: DetectorNoise = field(default_factory=DetectorNoise)
    hidden_miss: float = 0.9
    power: float = 2.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.hidden_miss <= 1.0:
            raise ValueError(f"VisibilityNoise.hidden_miss must be in [0, 1], got "
                             f"{self.hidden_miss}")
        if not self.power > 0:
            raise ValueError(f"VisibilityNoise.power must be > 0, got {self.power}")


def miss_probability(visible: np.ndarray, noise: VisibilityNoise) -> np.ndarray:
    """Miss probability of boxes with visible fractions ``visible`` (clipped to [0, 1])."""
    v = np.clip(np.asarray(visible, dtype=float), 0.0, 1.0)
    extra = noise.hidden_miss * (1.0 - v) ** noise.power
    return 1.0 - (1.0 - noise.base.miss_rate) * (1.0 - extra)


def apply_visibility_noise(
    frames: Mapping[int, FrameBoxes],
    visible: Mapping[int, np.ndarray],
    image_size: tuple[int, int],
    noise: VisibilityNoise,
    seed: int,
    view: str,
    keep_ids: Collection[int] = (),
) -> dict[int, FrameBoxes]:
    """Drop boxes according to their visibility, then jitter and add false boxes.

    The drops use the stream ``default_rng([seed, 2])`` (top) or ``default_rng([seed, 3])``
    (ego), independent of the base noise's streams; jitter and false boxes are those of
    :func:`~xvmatch.datasets.detector_noise.apply_detector_noise` with the same ``seed`` and its
    own miss rate set to 0 (misses are decided here).

    Args:
        frames: ``{frame: FrameBoxes}`` of one view.
        visible: ``{frame: (N,) visible fractions}`` aligned with ``frames[frame].ids``
            (e.g. :meth:`xvmatch.datasets.synthetic_io.SceneRecord.visibility`).
        image_size: (width, height) of the view.
        noise: the :class:`VisibilityNoise`.
        seed: random seed.
        view: ``"top"`` or ``"ego"`` (``"hor"`` is accepted as the egocentric view).
        keep_ids: ids never dropped (e.g. the camera wearer in the top view).

    Returns:
        ``{frame: FrameBoxes}`` with the same frames; false boxes get the ids of the base noise
        (``1_000_000 + k`` top, ``2_000_000 + k`` egocentric).
    """
    if view not in _BASE_VIEW:
        raise ValueError(f"view must be 'top' or 'ego', got {view!r}")
    keys = sorted(frames)
    for key in keys:
        if key not in visible:
            raise ValueError(f"apply_visibility_noise: no visibility for frame {key}")
        if np.shape(visible[key]) != (len(frames[key]),):
            raise ValueError(
                f"apply_visibility_noise: frame {key} has {len(frames[key])} boxes but "
                f"visibility of shape {np.shape(visible[key])}"
            )
    rng = np.random.default_rng([int(seed), _STREAM[view]])
    keep = np.fromiter(keep_ids, np.int64)
    kept: dict[int, FrameBoxes] = {}
    for key in keys:
        record = frames[key]
        draw = rng.random(len(record))
        stay = (draw >= miss_probability(visible[key], noise)) | np.isin(record.ids, keep)
        kept[key] = FrameBoxes(record.frame, record.ids[stay], record.boxes[stay])
    base = DetectorNoise(jitter=noise.base.jitter, miss_rate=0.0,
                         false_per_frame=noise.base.false_per_frame)
    return apply_detector_noise(kept, image_size, base, seed, _BASE_VIEW[view], keep_ids)
