"""Frame-mode association on the real CVMHAT dev boxes against the authors' MATLAB results.

``shared/data/cvmhat/REFERENCE.md`` holds the figures of the authors' code (run under Octave on
these ground-truth boxes) and ``reference_pred/{A,B}`` its per-frame pairs on the frames it
processed (``NAME.frames``). To stay fast, mode B (O given: the top-view box with id 0) runs on
every 4th of those frames and mode A (O searched) on every 10th; the reference pairs are scored
on exactly the same frames. Skipped when the data is absent (see ``cvmhat_dir``).
"""

from __future__ import annotations

import re
import warnings

import pytest

from xvmatch.cues.spatial_search import associate_sequence
from xvmatch.formats.mot_boxes import read_mot_boxes, read_predictions
from xvmatch.metrics.cross_view_metrics import count_sequence, summarize

pytestmark = pytest.mark.cvmhat

WIDTH = 2688  # CVMHAT images are 2688 x 1512
MODES = {
    # mode: (camera_id, keep every k-th processed frame)
    "B": (0, 4),
    "A": (None, 10),
}
TOLERANCE = 3.0  # points of CVIDF1 / CVMA
MIN_FRAME_AGREEMENT = 0.95


def _overall(reference_md: str, mode: str) -> tuple[float, float]:
    """(CVIDF1, CVMA) of the OVERALL row of ``mode`` in REFERENCE.md."""
    section = reference_md.split(f"== mode {mode}")[1].split("== mode")[0]
    match = re.search(r"^OVERALL .*CVIDF1=([\d.]+) CVMA=([\d.]+)", section, re.MULTILINE)
    assert match, f"no OVERALL row for mode {mode} in REFERENCE.md"
    return float(match.group(1)), float(match.group(2))


@pytest.fixture(scope="module")
def sequences(cvmhat_dir):
    """``{name: (top, hor)}`` of the 10 dev sequences."""
    listed = (cvmhat_dir / "reference_pred" / "B").glob("*.frames")
    names = sorted(p.name.removesuffix(".frames") for p in listed)
    assert len(names) == 10
    out = {}
    with warnings.catch_warnings():
        # Three files repeat a (frame, id); the first box is kept (see read_mot_boxes).
        warnings.filterwarnings("ignore", message=".*duplicate id.*", category=UserWarning)
        for name in names:
            out[name] = (
                read_mot_boxes(cvmhat_dir / f"{name}_top.txt", duplicates="first"),
                read_mot_boxes(cvmhat_dir / f"{name}_hor.txt", duplicates="first"),
            )
    return out


@pytest.mark.slow
@pytest.mark.parametrize("mode", sorted(MODES))
def test_frame_mode_reproduces_the_authors_code(cvmhat_dir, sequences, mode):
    camera_id, every = MODES[mode]
    ref_dir = cvmhat_dir / "reference_pred" / mode
    ours, theirs, weights = [], [], []
    agree = total = 0
    for name, (top, hor) in sequences.items():
        processed = [int(v) for v in (ref_dir / f"{name}.frames").read_text().split()]
        frames = processed[::every]
        reference = read_predictions(ref_dir / f"{name}.csv")
        pred = associate_sequence(top, hor, WIDTH, camera_id=camera_id, frames=frames)
        ours += count_sequence(pred, top, hor, frames=frames)
        theirs += count_sequence(reference, top, hor, frames=frames)
        # Weight = sequence length / frames scored, as the OVERALL rows of REFERENCE.md pool.
        weights += [len(set(top) | set(hor)) / len(frames)] * len(frames)
        agree += sum(set(pred.get(f, ())) == set(reference.get(f, ())) for f in frames)
        total += len(frames)

    mine, ref = summarize(ours), summarize(theirs)
    # Same frames, same evaluator: our pooled scores are the reference code's, within 3 points.
    assert abs(mine.cvidf1 - ref.cvidf1) <= TOLERANCE, (mine.cvidf1, ref.cvidf1)
    assert abs(mine.cvma - ref.cvma) <= TOLERANCE, (mine.cvma, ref.cvma)
    # And frame by frame: the very same pair sets on at least 95% of the frames.
    assert agree / total >= MIN_FRAME_AGREEMENT, f"{agree}/{total} frames agree"

    # The published OVERALL row (all processed frames, length-weighted) is met within 3 points
    # by the same weighting of our subsample.
    ref_f1, ref_ma = _overall((cvmhat_dir / "REFERENCE.md").read_text(), mode)
    weighted = summarize(ours, weights)
    assert abs(weighted.cvidf1 - ref_f1) <= TOLERANCE, (weighted.cvidf1, ref_f1)
    assert abs(weighted.cvma - ref_ma) <= TOLERANCE, (weighted.cvma, ref_ma)
