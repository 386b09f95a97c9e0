"""Tests of the cross-view metrics (xvmatch.metrics.cross_view_metrics).

Expected values are written as fractions of hand-counted toy frames; the parity test scores the
CVMHAT authors' predictions and must reproduce shared/data/cvmhat/REFERENCE.md to its 0.1.
"""

from __future__ import annotations

import json
import re
import warnings
from dataclasses import replace
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.formats.mot_boxes import FrameBoxes, read_mot_boxes, read_predictions
from xvmatch.metrics.cross_view_metrics import (
    CrossViewScores,
    FrameCounts,
    count_frame,
    count_sequence,
    format_table,
    scores_to_dict,
    summarize,
)

# Frame 1: top {0,1,2,3,4}, horizontal {1,2,3,5,6}, so G = {1,2,3} and U = 7 ids.
# (1,1) is right; (2,3) is a mismatch (hor 3 is in G); (4,5) a false positive (hor 5 is not);
# hor 2 is in no pair: a miss. TN: top-only 0 and hor-only 6 are left unmatched (4 and 5 are
# paired, wrongly, so they are not true negatives).
TOP1, HOR1, PAIRS1 = [0, 1, 2, 3, 4], [1, 2, 3, 5, 6], [(1, 1), (2, 3), (4, 5)]
# Frame 2: perfect, top {1,2}, horizontal {1,2}.
TOP2, HOR2, PAIRS2 = [1, 2], [2, 1], [(2, 2), (1, 1)]


def _pct(x: Fraction | int) -> float:
    return float(100 * Fraction(x))


def _frames() -> list[FrameCounts]:
    return [count_frame(TOP1, HOR1, PAIRS1, frame=1), count_frame(TOP2, HOR2, PAIRS2, frame=2)]


def _approx(scores: CrossViewScores, **expected: float) -> None:
    for name, value in expected.items():
        assert getattr(scores, name) == pytest.approx(value, abs=1e-9), name


# --------------------------------------------------------------------------------------------
# Per-frame counts


def test_count_frame_hand_counted():
    c = count_frame(TOP1, HOR1, PAIRS1, frame=1)
    assert c == FrameCounts(
        frame=1, n_pred=3, n_gt=3, tp=1, fp=1, mismatch=1, miss=1, n_union=7, tn=2
    )


def test_count_frame_accepts_arrays_and_empty_views():
    c = count_frame(np.array([0, 4]), np.array([], dtype=np.int64), [])
    assert c == FrameCounts(0, 0, 0, 0, 0, 0, 0, 2, 2)
    assert count_frame([], [], []) == FrameCounts(0, 0, 0, 0, 0, 0, 0, 0, 0)


def test_wrong_pair_on_a_shared_top_id_but_private_hor_id_is_a_false_positive():
    # top 1 is in G but is paired with hor 9, seen only horizontally: a false positive, and
    # hor 1 (in G, unpaired) is a miss.
    c = count_frame([1], [1, 9], [(1, 9)])
    assert (c.tp, c.fp, c.mismatch, c.miss, c.tn) == (0, 1, 0, 1, 0)


@pytest.mark.parametrize(
    ("top", "hor", "pairs", "match"),
    [
        ([1, 2], [1, 2], [(1, 1), (1, 2)], "one-to-one"),
        ([1, 2], [1, 2], [(1, 1), (2, 1)], "one-to-one"),
        ([1], [1], [(3, 1)], r"top ids \[3\]"),
        ([1], [1], [(1, 4)], r"horizontal ids \[4\]"),
        ([1, 1], [1], [], "lists an id twice"),
        ([1.5], [1], [], "must be integers"),
    ],
)
def test_count_frame_rejects_misuse(top, hor, pairs, match):
    with pytest.raises(ValueError, match=match):
        count_frame(top, hor, pairs, frame=7)


# --------------------------------------------------------------------------------------------
# Scores


def test_summarize_hand_counted_sequence():
    s = summarize(_frames())
    # CVIDP and CVIDR: mean of 1/3 and 1. CVMA: 1 - (miss 1 + fp 1 + 2 * mismatch 1) / (3 + 2).
    # ACC9: mean of (1 + 2)/7 and (2 + 0)/2.
    p = r = Fraction(1, 2) * (Fraction(1, 3) + 1)
    _approx(
        s,
        cvidp=_pct(p),
        cvidr=_pct(r),
        cvidf1=_pct(2 * p * r / (p + r)),
        cvma=_pct(1 - Fraction(4, 5)),
        acc9=_pct(Fraction(1, 2) * (Fraction(3, 7) + 1)),
    )
    assert (s.n_frames, s.n_pred, s.n_gt, s.tp, s.fp, s.mismatch, s.miss) == (2, 5, 5, 3, 1, 1, 1)
    assert (s.n_union, s.tn) == (9, 2)


def test_mismatch_counts_twice_in_cvma_only():
    # Two shared people, both paired crosswise: 2 mismatches, no miss, no fp.
    s = summarize([count_frame([1, 2], [1, 2], [(1, 2), (2, 1)])])
    _approx(s, cvidp=0.0, cvidr=0.0, cvidf1=0.0, cvma=_pct(1 - Fraction(2 * 2, 2)), acc9=0.0)
    assert s.cvma == pytest.approx(-100.0)


def test_precision_and_recall_average_over_their_own_frames():
    frames = [
        count_frame([1, 2], [1, 2], []),  # G = 2, nothing predicted: recall 0, not in precision
        count_frame([1], [5], [(1, 5)]),  # G empty: a false positive, not in recall
        count_frame([3], [3], [(3, 3)]),  # perfect
    ]
    s = summarize(frames)
    _approx(
        s,
        cvidp=_pct(Fraction(0 + 1, 2)),
        cvidr=_pct(Fraction(0 + 1, 2)),
        cvma=_pct(1 - Fraction(2 + 1 + 0, 2 + 1)),
        acc9=_pct(Fraction(0 + 0 + 1, 3)),
    )


def test_empty_cases_are_zero_not_nan():
    s = summarize([])
    assert s == CrossViewScores(0.0, 0.0, 0.0, 0.0, 0.0, 0, 0, 0, 0, 0, 0, 0, 0, 0)
    # Nothing predicted at all: CVIDP is 0 (documented), CVIDR 0, every shared id a miss.
    s = summarize([count_frame([1, 2], [1, 2], [])])
    _approx(s, cvidp=0.0, cvidr=0.0, cvidf1=0.0, cvma=0.0, acc9=0.0)
    # Nobody in both views: CVIDR and CVMA are 0 (documented), unmatched people are TN.
    s = summarize([count_frame([0, 1], [2], [])])
    _approx(s, cvidp=0.0, cvidr=0.0, cvidf1=0.0, cvma=0.0, acc9=100.0)
    # Nobody at all.
    s = summarize([count_frame([], [], [])])
    assert all(np.isfinite(v) for v in scores_to_dict(s).values())


def test_weighted_pooling():
    s = summarize(_frames(), weights=[3.0, 1.0])
    _approx(
        s,
        cvidp=_pct(Fraction(3 * Fraction(1, 3) + 1, 4)),
        cvidr=_pct(Fraction(3 * Fraction(1, 3) + 1, 4)),
        cvma=_pct(1 - Fraction(3 * 4 + 0, 3 * 3 + 1 * 2)),
        acc9=_pct(Fraction(3 * Fraction(3, 7) + 1, 4)),
    )
    assert s.n_frames == 2 and s.tp == 3  # counts stay unweighted


def test_integer_weights_equal_repeated_frames():
    a, b = _frames()
    weighted = summarize([a, b], weights=[2, 1])
    repeated = summarize([a, a, b])
    for name in ("cvidp", "cvidr", "cvidf1", "cvma", "acc9"):
        assert getattr(weighted, name) == pytest.approx(getattr(repeated, name))


@pytest.mark.parametrize("weights", [[1.0], [1.0, -1.0], [1.0, np.nan], [[1.0, 1.0]] * 2])
def test_bad_weights(weights):
    with pytest.raises(ValueError, match="weights must be 2"):
        summarize(_frames(), weights=weights)


# --------------------------------------------------------------------------------------------
# Sequences


def _boxes(frames: dict[int, list[int]]) -> dict[int, FrameBoxes]:
    return {t: FrameBoxes(t, ids, np.ones((len(ids), 4))) for t, ids in frames.items()}


def test_count_sequence_union_of_frames_and_subset():
    top = _boxes({1: TOP1, 2: TOP2})
    hor = _boxes({1: HOR1, 3: [4]})
    pred = {1: PAIRS1, 3: []}
    counts = count_sequence(pred, top, hor)
    assert [c.frame for c in counts] == [1, 2, 3]
    assert counts[0] == count_frame(TOP1, HOR1, PAIRS1, frame=1)
    assert counts[1] == FrameCounts(2, 0, 0, 0, 0, 0, 0, 2, 2)  # no horizontal boxes
    assert counts[2] == FrameCounts(3, 0, 0, 0, 0, 0, 0, 1, 1)  # no top boxes
    subset = count_sequence({1: PAIRS1, 2: [(1, 2)]}, top, hor, frames=[3, 1, 1])
    assert [c.frame for c in subset] == [1, 3]  # predictions of frame 2 are not evaluated


def test_count_sequence_rejects_predictions_on_unknown_frames():
    top, hor = _boxes({1: [1]}), _boxes({1: [1]})
    with pytest.raises(ValueError, match=r"no box in either view: \[9\]"):
        count_sequence({1: [(1, 1)], 9: [(1, 1)]}, top, hor)
    with pytest.raises(ValueError, match="frame 1: pairs name ids"):
        count_sequence({1: [(2, 1)]}, top, hor)


@pytest.mark.slow
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_scores_invariant_under_consistent_id_relabelling(data):
    universe = list(range(12))
    frames = []
    for _ in range(data.draw(st.integers(1, 4))):
        top = data.draw(st.sets(st.sampled_from(universe), max_size=8))
        hor = data.draw(st.sets(st.sampled_from(universe), max_size=8))
        tops = data.draw(st.permutations(sorted(top)))
        hors = data.draw(st.permutations(sorted(hor)))
        k = data.draw(st.integers(0, min(len(tops), len(hors))))
        frames.append((sorted(top), sorted(hor), list(zip(tops[:k], hors[:k], strict=True))))
    perm = data.draw(st.permutations(universe))
    relabel = dict(zip(universe, perm, strict=True))
    weights = data.draw(st.lists(st.floats(0.1, 10.0), min_size=len(frames), max_size=len(frames)))

    before = [count_frame(t, h, p, frame=i) for i, (t, h, p) in enumerate(frames)]
    after = [
        count_frame(
            [relabel[i] for i in t],
            [relabel[i] for i in h],
            [(relabel[a], relabel[b]) for a, b in p],
            frame=i,
        )
        for i, (t, h, p) in enumerate(frames)
    ]
    assert before == after
    assert summarize(before, weights) == summarize(after, weights)


# --------------------------------------------------------------------------------------------
# Reports


def test_format_table_is_aligned_and_rounds_ties_to_even():
    a = summarize(_frames())
    tie = replace(a, acc9=96.65, cvma=-0.04)
    table = format_table([("seq-a", a), ("a-much-longer-name", tie)])
    lines = table.splitlines()
    assert len(lines) == 3
    assert lines[0].split() == ["name", "frames", "CVIDP", "CVIDR", "CVIDF1", "CVMA", "ACC9"]
    assert len({len(line) for line in lines}) == 1
    assert lines[2].split()[1:] == ["2", "66.7", "66.7", "66.7", "0.0", "96.6"]
    assert lines[1].split()[-2:] == [f"{a.cvma:.1f}", f"{a.acc9:.1f}"]


def test_scores_to_dict_is_json_ready():
    d = scores_to_dict(summarize(_frames()))
    assert json.loads(json.dumps(d)) == d
    assert type(d["n_frames"]) is int and type(d["cvma"]) is float
    assert set(d) == {
        "cvidp", "cvidr", "cvidf1", "cvma", "acc9", "n_frames", "n_pred", "n_gt", "tp",
        "fp", "mismatch", "miss", "n_union", "tn",
    }  # fmt: skip


# --------------------------------------------------------------------------------------------
# Parity with the CVMHAT reference figures

_REF_ROW = re.compile(
    r"^(?P<name>\S+)\s+\S+\s+frames=\s*(?P<frames>\d+)\s+"
    r"CVIDP=(?P<cvidp>\S+)\s+CVIDR=(?P<cvidr>\S+)\s+CVIDF1=(?P<cvidf1>\S+)\s+"
    r"CVMA=(?P<cvma>\S+)\s+ACC9=(?P<acc9>\S+)\s*$"
)
_METRICS = ("cvidp", "cvidr", "cvidf1", "cvma", "acc9")


def _reference_table(path: Path) -> dict[str, dict[str, dict[str, str]]]:
    """``{mode: {sequence or "OVERALL": {column: printed value}}}`` from REFERENCE.md."""
    table: dict[str, dict[str, dict[str, str]]] = {}
    mode = None
    for line in path.read_text(encoding="utf-8").splitlines():
        header = re.match(r"^== mode (\w+)", line)
        if header:
            mode = header.group(1)
            table[mode] = {}
            continue
        row = _REF_ROW.match(line)
        if row and mode is not None:
            table[mode][row.group("name")] = row.groupdict()
    return table


def _printed(value: float) -> str:
    """As the reference prints: to 0.1, ties to even."""
    return f"{float(np.round(value, 1)) + 0.0:.1f}"


@pytest.mark.cvmhat
@pytest.mark.parametrize("mode", ["A", "B"])
def test_parity_with_reference(cvmhat_dir, mode):
    reference = _reference_table(cvmhat_dir / "REFERENCE.md")
    assert mode in reference, f"REFERENCE.md has no '== mode {mode}' table"
    rows = reference[mode]
    names = sorted(n for n in rows if n != "OVERALL")
    assert len(names) == 10 and "OVERALL" in rows, sorted(rows)

    pooled, weights, failures = [], [], []
    for name in names:
        with warnings.catch_warnings():  # three files hold one stray duplicate box each
            warnings.simplefilter("ignore", UserWarning)
            top = read_mot_boxes(cvmhat_dir / f"{name}_top.txt", duplicates="first")
            hor = read_mot_boxes(cvmhat_dir / f"{name}_hor.txt", duplicates="first")
        pred_dir = cvmhat_dir / "reference_pred" / mode
        pred = read_predictions(pred_dir / f"{name}.csv")
        frames = [int(f) for f in (pred_dir / f"{name}.frames").read_text().split()]
        counts = count_sequence(pred, top, hor, frames)
        scores = summarize(counts)
        got = {m: _printed(getattr(scores, m)) for m in _METRICS}
        got["frames"] = str(scores.n_frames)
        want = {k: rows[name][k] for k in got}
        if got != want:
            failures.append(f"{mode} {name}: got {got}, reference {want}")
        pooled += counts
        weights += [len(set(top) | set(hor)) / len(frames)] * len(counts)

    scores = summarize(pooled, weights)
    got = {m: _printed(getattr(scores, m)) for m in _METRICS}
    got["frames"] = str(scores.n_frames)
    want = {k: rows["OVERALL"][k] for k in got}
    if got != want:
        failures.append(f"{mode} OVERALL: got {got}, reference {want}")
    assert not failures, "\n".join(failures)
