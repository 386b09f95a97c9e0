"""Same input, same output: on the real CVMHAT dev pairs, the association, the offset estimate,
the learned matcher's pairs and the tracks do not depend on the kernel choice
(``XVMATCH_KERNELS=numpy|compiled|auto``) nor on the number of worker processes.

The compiled kernels and the numpy forms are bit-identical by construction on every CPU (the
kernels do only IEEE arithmetic; numpy computes every tan, cos and power for both), so costs are
compared exactly here, not within a tolerance. Each check runs on a sample of frames to stay
fast; skipped when the data is absent (see ``cvmhat_dir``).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from xvmatch.core import kernel_choice
from xvmatch.cues.offset_estimation import estimate_offset
from xvmatch.cues.spatial_search import associate_sequence, rank_hypotheses
from xvmatch.formats.mot_boxes import read_mot_boxes

pytestmark = pytest.mark.cvmhat

WIDTH = 2688.0
KERNEL_MODES = ("numpy", "compiled", "auto")


@pytest.fixture(scope="module")
def dev_pairs(cvmhat_dir):
    """``{name: (top, hor)}`` of the 10 dev sequence pairs."""
    names = sorted(p.name.removesuffix("_top.txt") for p in cvmhat_dir.glob("*_top.txt"))
    assert len(names) == 10
    out = {}
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*duplicate id.*", category=UserWarning)
        for name in names:
            out[name] = tuple(read_mot_boxes(cvmhat_dir / f"{name}_{view}.txt",
                                             duplicates="first") for view in ("top", "hor"))
    return out


def _kernels(monkeypatch, mode: str) -> None:
    """This process and the worker processes it spawns run ``mode``."""
    monkeypatch.setenv("XVMATCH_KERNELS", mode)
    kernel_choice.set_mode(mode)


@pytest.fixture(autouse=True)
def _restore_kernel_mode():
    previous = kernel_choice.mode()
    yield
    kernel_choice.set_mode(previous)


@pytest.mark.slow
def test_search_costs_are_identical_under_every_kernel_choice(dev_pairs, monkeypatch):
    # The three best (O, theta) hypotheses of every 40th frame of each pair: costs, scales,
    # cameras, orientations and pairs bit for bit.
    found = {}
    for mode in KERNEL_MODES:
        _kernels(monkeypatch, mode)
        rows = []
        for top, hor in dev_pairs.values():
            for f in sorted(set(top) & set(hor))[::40]:
                for h in rank_hypotheses(top[f].boxes, hor[f].boxes, WIDTH, k=3):
                    rows.append((f, h.camera, h.theta, h.cost, h.scale, h.pairs.tolist()))
        found[mode] = rows
    assert len(found["numpy"]) > 300
    assert found["compiled"] == found["numpy"]
    assert found["auto"] == found["numpy"]


@pytest.mark.slow
def test_sequence_association_is_identical_under_every_kernel_choice(dev_pairs, monkeypatch):
    # Frame mode (O searched) and the follow mode (O and theta carried from frame to frame) on
    # a 40-frame stretch of each pair.
    found = {}
    for mode in KERNEL_MODES:
        _kernels(monkeypatch, mode)
        runs = []
        for top, hor in dev_pairs.values():
            frames = sorted(set(top) & set(hor))[100:140]
            for search in ("exhaustive", "follow"):
                runs.append(associate_sequence(top, hor, WIDTH, search=search, frames=frames))
        found[mode] = runs
    assert found["compiled"] == found["numpy"]
    assert found["auto"] == found["numpy"]


@pytest.mark.slow
def test_offset_estimate_is_identical_for_any_workers_and_kernels(dev_pairs, monkeypatch):
    top, hor = dev_pairs["V1-S_55-G_1"]
    shifted = {f + 4: rec for f, rec in hor.items()}
    found = {}
    for mode in ("numpy", "compiled"):
        _kernels(monkeypatch, mode)
        for workers in (1, 2, 4):
            est = estimate_offset(top, shifted, WIDTH, max_offset=6, clip_length=5, n_clips=3,
                                  camera_id=0, workers=workers)
            found[mode, workers] = (est.offset, est.applied, est.status, est.clip_costs)
    first = found["numpy", 1]
    for key, value in found.items():
        assert value[:3] == first[:3], key
        np.testing.assert_array_equal(value[3], first[3], err_msg=str(key))


@pytest.mark.slow
def test_learned_pairs_and_costs_are_identical_for_any_workers(dev_pairs, monkeypatch):
    from xvmatch.inference.matching.learned_association import (
        associate_sequence_learned,
        load_matcher_bundle,
    )

    model = load_matcher_bundle("default")
    top, hor = dev_pairs["V0-S_canteen_0-G_1"]
    frames = sorted(set(top) & set(hor))[:80:2]
    found = {}
    for mode in ("numpy", "compiled"):
        _kernels(monkeypatch, mode)
        for workers in (1, 2, 4):
            costs: dict[int, np.ndarray] = {}
            pairs = associate_sequence_learned(top, hor, WIDTH, model, frames=frames,
                                               batch_size=16, costs_out=costs, workers=workers)
            found[mode, workers] = (pairs, costs)
    pairs, costs = found["numpy", 1]
    assert sum(len(p) for p in pairs.values()) > 0
    for key, (p, c) in found.items():
        assert p == pairs, key
        assert sorted(c) == sorted(costs)
        for f in costs:
            np.testing.assert_array_equal(c[f], costs[f], err_msg=str(key))


@pytest.mark.slow
def test_tracks_are_identical_for_any_workers(dev_pairs, monkeypatch):
    from xvmatch.inference.tracks.tracking import associate_frames

    top, hor = dev_pairs["V1-S_square-G_1"]
    window = sorted(set(top) & set(hor))[:120]
    top = {f: top[f] for f in window}
    hor = {f: hor[f] for f in window}
    found = {}
    for mode in ("numpy", "compiled"):
        _kernels(monkeypatch, mode)
        for workers in (1, 2, 4):
            found[mode, workers] = associate_frames(top, hor, WIDTH, workers=workers)
    first = found["numpy", 1]
    assert sum(len(p) for p in first.values()) > 0
    for key, value in found.items():
        assert value == first, key
