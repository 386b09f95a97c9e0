"""Tests of the detector-like box corruption (xvmatch.datasets.detector_noise)."""

from __future__ import annotations

import numpy as np
import pytest

from xvmatch.datasets.detector_noise import FALSE_ID_BASE, DetectorNoise, apply_detector_noise
from xvmatch.formats.mot_boxes import FrameBoxes

SIZE = (2688, 1512)


def _frames(n_frames: int = 2000, per_frame: int = 5, seed: int = 0) -> dict[int, FrameBoxes]:
    """Clean frames with ids 0..per_frame-1 and varied box sizes."""
    rng = np.random.default_rng(seed)
    out = {}
    for f in range(1, n_frames + 1):
        wh = rng.uniform([40, 100], [200, 600], size=(per_frame, 2))
        xy = rng.uniform(0, 1, size=(per_frame, 2)) * (np.array(SIZE) - wh)
        out[f] = FrameBoxes(f, np.arange(per_frame), np.concatenate([xy, wh], axis=1))
    return out


def _same(a, b) -> bool:
    return a.keys() == b.keys() and all(
        np.array_equal(a[k].ids, b[k].ids) and np.array_equal(a[k].boxes, b[k].boxes) for k in a
    )


def _split(out):
    ids = np.concatenate([r.ids for r in out.values()])
    boxes = np.concatenate([r.boxes for r in out.values()])
    return ids, boxes


def test_deterministic_and_views_independent():
    frames = _frames(50)
    noise = DetectorNoise()
    a = apply_detector_noise(frames, SIZE, noise, seed=7, view="top")
    assert _same(a, apply_detector_noise(frames, SIZE, noise, seed=7, view="top"))
    assert not _same(a, apply_detector_noise(frames, SIZE, noise, seed=8, view="top"))
    hor = apply_detector_noise(frames, SIZE, noise, seed=7, view="hor")
    top_real = [r.boxes[r.ids < 1_000_000] for r in a.values()]
    hor_real = [r.boxes[r.ids < 1_000_000] for r in hor.values()]
    assert not all(np.array_equal(t, h) for t, h in zip(top_real, hor_real, strict=True))


def test_zero_noise_is_identity():
    frames = _frames(30)
    out = apply_detector_noise(frames, SIZE, DetectorNoise(0.0, 0.0, 0.0), seed=1, view="hor")
    assert _same(out, frames)


def test_rates_as_configured():
    frames = _frames(2000)
    out = apply_detector_noise(frames, SIZE, DetectorNoise(), seed=3, view="top")
    ids, _ = _split(out)
    real = ids < FALSE_ID_BASE["top"]
    n_real = sum(len(r) for r in frames.values())
    assert 1.0 - real.sum() / n_real == pytest.approx(0.10, abs=0.015)
    assert (~real).sum() / len(frames) == pytest.approx(0.3, abs=0.04)


def test_jitter_scale():
    frames = _frames(1000)
    out = apply_detector_noise(frames, SIZE, DetectorNoise(0.05, 0.0, 0.0), seed=2, view="top")
    _, clean = _split(frames)
    _, noisy = _split(out)
    centre = (noisy[:, :2] + noisy[:, 2:] / 2 - clean[:, :2] - clean[:, 2:] / 2) / clean[:, 2:]
    assert centre.std(axis=0) == pytest.approx([0.05, 0.05], abs=0.005)
    assert np.log(noisy[:, 2:] / clean[:, 2:]).std(axis=0) == pytest.approx([0.05, 0.05], abs=0.005)
    assert (noisy[:, 2:] > 0).all()


def test_false_ids_never_collide():
    frames = _frames(500)
    noise = DetectorNoise(false_per_frame=2.0)
    top_ids, _ = _split(apply_detector_noise(frames, SIZE, noise, seed=0, view="top"))
    hor_ids, _ = _split(apply_detector_noise(frames, SIZE, noise, seed=0, view="hor"))
    top_false = top_ids[top_ids >= 1_000_000]
    hor_false = hor_ids[hor_ids >= 1_000_000]
    assert top_false.size > 0 and hor_false.size > 0
    assert np.unique(top_false).size == top_false.size
    assert np.unique(hor_false).size == hor_false.size
    assert ((top_false >= 1_000_000) & (top_false < 2_000_000)).all()
    assert (hor_false >= 2_000_000).all()
    real_ids = np.concatenate([r.ids for r in frames.values()])
    assert not np.isin(np.concatenate([top_false, hor_false]), real_ids).any()


def test_false_boxes_inside_image_with_real_sizes():
    frames = _frames(300)
    out = apply_detector_noise(frames, SIZE, DetectorNoise(0.0, 0.0, 1.5), seed=4, view="hor")
    for frame, rec in out.items():
        fake = rec.boxes[rec.ids >= 1_000_000]
        assert (fake[:, :2] >= 0).all() and (fake[:, :2] + fake[:, 2:] <= SIZE).all()
        real_sizes = frames[frame].boxes[:, 2:]
        assert all((np.all(real_sizes == s, axis=1)).any() for s in fake[:, 2:])


def test_false_boxes_in_empty_frames_use_file_sizes():
    frames = {1: FrameBoxes(1, [0], [[10, 10, 50, 150]]), 2: FrameBoxes(2, [], [])}
    frames.update({f: FrameBoxes(f, [], []) for f in range(3, 200)})
    out = apply_detector_noise(frames, SIZE, DetectorNoise(0.0, 0.0, 1.0), seed=0, view="top")
    fake = np.concatenate([r.boxes for f, r in out.items() if f > 1])
    assert fake.shape[0] > 100
    assert (fake[:, 2:] == [50, 150]).all()


def test_keep_ids_honoured():
    frames = _frames(200)
    out = apply_detector_noise(
        frames, SIZE, DetectorNoise(0.05, 1.0, 0.0), seed=5, view="top", keep_ids={0}
    )
    assert all(list(rec.ids) == [0] for rec in out.values())


def test_bad_input_is_rejected():
    frames = _frames(3)
    with pytest.raises(ValueError, match="view"):
        apply_detector_noise(frames, SIZE, DetectorNoise(), seed=0, view="side")
    with pytest.raises(ValueError, match="reserved"):
        apply_detector_noise(
            {1: FrameBoxes(1, [1_000_000], [[0, 0, 5, 5]])}, SIZE, DetectorNoise(), 0, "top"
        )
    with pytest.raises(ValueError, match="miss_rate"):
        DetectorNoise(miss_rate=1.5)


def test_misses_in_runs_at_the_rate_asked():
    """With ``miss_run`` a person is missed ``miss_rate`` of the time in runs about that many
    frames long (each box on its own: runs of 1 / (1 - rate)); the boxes kept are as given,
    the same seed draws the same misses, and a run shorter than a frame is refused."""
    frames = _frames(2000)
    runs = DetectorNoise(0.0, 0.25, 0.0, miss_run=10.0)
    out = apply_detector_noise(frames, SIZE, runs, seed=3, view="hor")
    assert _same(out, apply_detector_noise(frames, SIZE, runs, seed=3, view="hor"))

    def missed_runs(out) -> tuple[float, float]:
        seen = np.array([[i in out[f].ids for i in range(5)] for f in sorted(frames)])
        starts = (~seen[1:] & seen[:-1]).sum() + (~seen[0]).sum()
        return float((~seen).mean()), float((~seen).sum() / starts)

    rate, length = missed_runs(out)
    assert rate == pytest.approx(0.25, abs=0.04)
    assert length == pytest.approx(10.0, rel=0.25)
    alone = apply_detector_noise(frames, SIZE, DetectorNoise(0.0, 0.25, 0.0), seed=3,
                                 view="hor")
    assert missed_runs(alone)[1] == pytest.approx(1 / 0.75, rel=0.1)
    for f, rec in out.items():
        given = dict(zip(frames[f].ids.tolist(), frames[f].boxes.tolist(), strict=True))
        assert all(given[i] == b for i, b in zip(rec.ids.tolist(), rec.boxes.tolist(),
                                                 strict=True))
    with pytest.raises(ValueError, match="miss_run"):
        DetectorNoise(miss_run=0.5)
