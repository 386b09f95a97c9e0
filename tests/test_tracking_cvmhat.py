"""Tracking on real CVMHAT boxes (first frames of one pair); skipped where the data is absent."""

from __future__ import annotations

import numpy as np
import pytest

from xvmatch.formats.cvmhat import IMAGE_SIZE, default_cvmhat_dir, read_sequence
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.inference.tracks.tracking import associate_frames, track_pair
from xvmatch.metrics.cross_view_metrics import count_sequence, summarize
from xvmatch.metrics.track_metrics import track_pair_counts, view_track_scores

NAME = "V1-S_55-G_1"
FRAMES = 60


@pytest.fixture(scope="module")
def sequence():
    folder = default_cvmhat_dir()
    if not (folder / f"{NAME}_top.txt").exists():
        pytest.skip(f"CVMHAT data not found in {folder}")
    top, hor = read_sequence(folder, NAME)
    return ({f: r for f, r in top.items() if f <= FRAMES},
            {f: r for f, r in hor.items() if f <= FRAMES})


def _detections(frames, seed):
    rng = np.random.default_rng(seed)
    out, truth, row = {}, {}, 0
    for f in sorted(frames):
        rec = frames[f]
        order = rng.permutation(len(rec))
        rows = np.arange(row, row + len(rec))
        truth.update(zip(rows.tolist(), rec.ids[order].tolist(), strict=True))
        out[f] = FrameBoxes(f, rows, rec.boxes[order])
        row += len(rec)
    return out, truth


def _tracks(det, rows):
    return {f: FrameBoxes(f, np.array([rows[int(r)] for r in rec.ids]), rec.boxes)
            for f, rec in det.items()}


@pytest.mark.slow
def test_tracking_beats_frame_mode_on_real_boxes(sequence):
    top, hor = sequence
    det_top, truth_top = _detections(top, 1)
    det_hor, truth_hor = _detections(hor, 2)
    pairs = associate_frames(det_top, det_hor, float(IMAGE_SIZE[0]))
    frames = sorted(set(top) | set(hor))
    frame_mode = summarize(count_sequence(
        {f: [(truth_top[a], truth_hor[b]) for a, b in p] for f, p in pairs.items()},
        top, hor, frames))
    res = track_pair(det_top, det_hor, float(IMAGE_SIZE[0]), frame_pairs=pairs)
    tr_top, tr_hor = _tracks(det_top, res.top_rows), _tracks(det_hor, res.hor_rows)
    tracked = summarize(track_pair_counts(tr_top, tr_hor, top, hor, frames))
    assert res.n_fallback == 0
    assert tracked.cvidf1 >= frame_mode.cvidf1
    assert view_track_scores(top, tr_top).idf1 >= 95.0


@pytest.mark.slow
def test_learned_weights_on_real_boxes(sequence):
    from xvmatch.inference.matching.learned_association import load_matcher_bundle
    from xvmatch.inference.tracks.track_costs import LEARNED_DUMMY_WEIGHT, TrackWeights
    from xvmatch.inference.tracks.tracking import TrackConfig, learned_frame_evidence

    top, hor = sequence
    det_top, truth_top = _detections(top, 1)
    det_hor, truth_hor = _detections(hor, 2)
    frames = sorted(set(top) | set(hor))
    evidence = learned_frame_evidence(det_top, det_hor, IMAGE_SIZE, load_matcher_bundle())
    frame_mode = summarize(count_sequence(
        {f: [(truth_top[a], truth_hor[b]) for a, b in p]
         for f, p in evidence.frame_pairs.items()}, top, hor, frames))
    config = TrackConfig(weights=TrackWeights(c0=LEARNED_DUMMY_WEIGHT))
    res = track_pair(det_top, det_hor, float(IMAGE_SIZE[0]), config=config, learned=evidence)
    tr_top, tr_hor = _tracks(det_top, res.top_rows), _tracks(det_hor, res.hor_rows)
    tracked = summarize(track_pair_counts(tr_top, tr_hor, top, hor, frames))
    assert res.n_fallback == 0
    assert tracked.cvidf1 >= max(frame_mode.cvidf1, 95.0)  # measured: 93.2 frame, 95.9 tracked
    assert view_track_scores(top, tr_top).idf1 >= 95.0
