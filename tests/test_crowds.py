"""Crowds on the learned path (issue 65): a frame over the matcher's limits is refused in one
line before any work, frames under them are scored in batches of bounded size, and ordinary
runs are batched as before."""

from __future__ import annotations

import time

import numpy as np
import pytest

from xvmatch import cli
from xvmatch.cues.matcher_inputs import MatcherInputs
from xvmatch.cues.spatial_features import (
    HOR_FEATURES,
    HYP_FEATURES,
    PAIR_FEATURES,
    TOP_FEATURES,
    FrameFeatures,
)
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.inference.matching.learned_association import (
    EMBED_BATCH,
    MATCHER_BATCH_CELLS,
    MAX_BOX_PAIRS,
    MAX_PEOPLE_PER_VIEW,
    LearnedMatcher,
    check_crowd_size,
)


def _random_frame(rng, frame: int, top: int, hor: int) -> tuple[FrameBoxes, FrameBoxes]:
    """``top`` small top-view boxes over 3840x2160 and ``hor`` people over 1920x1080."""
    side = rng.uniform(20, 40, top)
    t = np.column_stack([rng.uniform(0, 3800, top), rng.uniform(0, 2120, top), side, side])
    height = rng.uniform(40, 400, hor)
    h = np.column_stack([rng.uniform(0, 1900, hor), rng.uniform(0, 680, hor), 0.4 * height,
                         height])
    return (FrameBoxes(frame, np.arange(1, top + 1), t),
            FrameBoxes(frame, np.arange(1, hor + 1), h))


def _write(path, frames: dict[int, FrameBoxes]) -> str:
    lines = [f"{f},{i},{x:.1f},{y:.1f},{w:.1f},{h:.1f},-1,-1,-1,-1"
             for f, rec in sorted(frames.items())
             for i, (x, y, w, h) in zip(rec.ids, rec.boxes, strict=True)]
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def _files(tmp_path, sizes: list[tuple[int, int]], seed: int = 0) -> tuple[str, str]:
    """Box files with one frame of (top, hor) people per entry of ``sizes``."""
    rng = np.random.default_rng(seed)
    top, hor = {}, {}
    for frame, (m, n) in enumerate(sizes, start=1):
        top[frame], hor[frame] = _random_frame(rng, frame, m, n)
    return _write(tmp_path / "t.txt", top), _write(tmp_path / "h.txt", hor)


def _associate(top: str, hor: str, out: str, *extra: str) -> int:
    return cli.main(["associate", "--model", "default", "--top", top, "--hor", hor,
                     "--image-size", "1920x1080", "--out", out, "--quiet", *extra])


def test_a_frame_over_the_pair_limit_is_refused_in_one_line(tmp_path, capsys):
    top, hor = _files(tmp_path, [(20, 10), (20, 10), (400, 300), (300, 300)])
    out = tmp_path / "p.csv"
    start = time.perf_counter()
    assert _associate(top, hor, str(out)) == 2
    seconds = time.perf_counter() - start
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert "frame 3 has 400 x 300 = 120,000 top x horizontal box pairs" in err
    assert top in err and f"{MAX_BOX_PAIRS:,}" in err and "1 more frames" in err
    assert "drop --model" in err
    assert not out.exists()
    assert seconds < 10, f"refused after {seconds:.1f} s: the check must come before any work"


def test_a_frame_over_the_people_limit_is_refused_with_its_file_and_frame(tmp_path, capsys):
    rng = np.random.default_rng(0)
    small_top, small_hor = _random_frame(rng, 1, 20, 10)
    big_top, hor_2 = _random_frame(rng, 2, MAX_PEOPLE_PER_VIEW + 1, 3)
    # --offset 2: horizontal frame f is top frame f + 2, and the message names the top file's
    top = _write(tmp_path / "t.txt", {3: FrameBoxes(3, small_top.ids, small_top.boxes),
                                      4: FrameBoxes(4, big_top.ids, big_top.boxes)})
    hor = _write(tmp_path / "h.txt", {1: small_hor, 2: hor_2})
    assert _associate(top, hor, str(tmp_path / "p.csv"), "--offset", "2") == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert f"frame 4 of {top} has {MAX_PEOPLE_PER_VIEW + 1} boxes" in err
    assert f"at most {MAX_PEOPLE_PER_VIEW} people per view in a frame" in err


def test_check_crowd_size_names_each_files_own_frame():
    rng = np.random.default_rng(1)
    t, h = _random_frame(rng, 5, 300, 300)
    with pytest.raises(ValueError, match=r"^frame 5 has 300 x 300 = 90,000 .*\(frame 7 of T, "
                       r"frame 5 of H\)"):
        check_crowd_size({5: t}, {5: h}, top_name="T", hor_name="H", top_offset=2)
    t, h = _random_frame(rng, 4, 3, MAX_PEOPLE_PER_VIEW + 5)
    with pytest.raises(ValueError, match=f"^frame 4 of H has {MAX_PEOPLE_PER_VIEW + 5} boxes"):
        check_crowd_size({4: t}, {4: h}, top_name="T", hor_name="H")


def test_check_crowd_size_takes_frames_at_the_limits_and_skips_unscored_frames():
    rng = np.random.default_rng(2)
    at_pairs = _random_frame(rng, 1, 256, 256)
    at_people = _random_frame(rng, 2, MAX_PEOPLE_PER_VIEW, MAX_BOX_PAIRS // MAX_PEOPLE_PER_VIEW)
    alone, _ = _random_frame(rng, 3, MAX_PEOPLE_PER_VIEW + 1, 1)  # no horizontal boxes
    empty = FrameBoxes(3, np.zeros(0, np.int64), np.zeros((0, 4)))
    top = {1: at_pairs[0], 2: at_people[0], 3: alone}
    hor = {1: at_pairs[1], 2: at_people[1], 3: empty}
    check_crowd_size(top, hor)
    big, small = _random_frame(rng, 9, 400, 400)
    check_crowd_size({**top, 9: big}, {**hor, 9: small}, frames=[1, 2, 3])  # 9 not asked for


class _RecordingBundle:
    """A stand-in for a bundle: records the padded shape of each matcher call and the size of
    each embedding call."""

    name = "recording"

    def __init__(self, fail: str | None = None) -> None:
        self.calls: list[tuple[int, ...]] = []
        self.embedded: list[int] = []
        self.fail = fail

    def costs(self, batch: dict[str, np.ndarray]) -> np.ndarray:
        if self.fail is not None:
            raise RuntimeError(self.fail)
        self.calls.append(batch["pair"].shape[:4])
        b, _, m, n = batch["pair"].shape[:4]
        return np.zeros((b, m, n), np.float32)

    def embed(self, crops: np.ndarray, vector: str = "descriptors",
              reference: bool = False) -> np.ndarray:
        self.embedded.append(crops.shape[0])
        return np.tile(crops.reshape(crops.shape[0], -1)[:, :2].astype(np.float32), (1, 2))


def _inputs(h: int, m: int, n: int) -> MatcherInputs:
    features = FrameFeatures(
        top=np.zeros((m, len(TOP_FEATURES)), np.float32),
        hor=np.zeros((n, len(HOR_FEATURES)), np.float32),
        hyp=np.zeros((h, len(HYP_FEATURES)), np.float32),
        pair=np.zeros((h, m, n, len(PAIR_FEATURES)), np.float32),
        top_order=np.arange(m), hor_order=np.arange(n), hyp_camera=np.zeros(h, np.int64))
    return MatcherInputs(features, np.zeros((m, n, 0), np.float32), np.zeros(0, bool))


def test_ordinary_frames_are_batched_as_before():
    bundle = _RecordingBundle()
    frames = [_inputs(8, 12 + k % 5, 8 + k % 3) for k in range(150)]
    costs = LearnedMatcher(bundle).costs(frames, batch_size=64)
    assert [c[0] for c in bundle.calls] == [64, 64, 22]
    assert [c.shape for c in costs] == [(f.features.shape[1], f.features.shape[2])
                                        for f in frames]


def test_crowded_frames_are_batched_within_the_cell_budget():
    bundle = _RecordingBundle()
    frames = [_inputs(8, 256, 256), _inputs(8, 200, 100), _inputs(8, 20, 10),
              _inputs(8, 256, 256), _inputs(8, 256, 256), _inputs(1, 2, 2)]
    costs = LearnedMatcher(bundle).costs(frames, batch_size=64)
    assert all(b * h * m * n <= MATCHER_BATCH_CELLS for b, h, m, n in bundle.calls), bundle.calls
    assert sum(c[0] for c in bundle.calls) == len(frames)
    assert [c.shape for c in costs] == [(256, 256), (200, 100), (20, 10), (256, 256),
                                        (256, 256), (2, 2)]


def test_a_frame_over_the_cell_budget_is_scored_alone():
    bundle = _RecordingBundle()
    LearnedMatcher(bundle).costs([_inputs(1, 2, 2), _inputs(8, 400, 400), _inputs(1, 2, 2)])
    assert [c[0] for c in bundle.calls] == [1, 1, 1]


def test_onnxruntime_out_of_memory_is_a_memory_error():
    bundle = _RecordingBundle(fail="Failed to allocate memory for requested buffer of size 9")
    with pytest.raises(MemoryError, match="could not allocate the memory to score 1 frame"):
        LearnedMatcher(bundle).costs([_inputs(8, 30, 20)])
    with pytest.raises(RuntimeError, match="something else"):
        LearnedMatcher(_RecordingBundle(fail="something else")).costs([_inputs(8, 30, 20)])


def test_crowds_are_embedded_in_batches_with_the_same_vectors():
    bundle = _RecordingBundle()
    crops = np.random.default_rng(3).integers(0, 255, (2 * EMBED_BATCH + 7, 4, 2, 3), np.uint8)
    out = LearnedMatcher(bundle).embed(crops)
    assert bundle.embedded == [EMBED_BATCH, EMBED_BATCH, 7]
    np.testing.assert_array_equal(out, _RecordingBundle().embed(crops))
    bundle.embedded.clear()
    LearnedMatcher(bundle).embed(crops[:EMBED_BATCH])
    assert bundle.embedded == [EMBED_BATCH]


def test_a_crowd_under_the_limits_is_matched(tmp_path, capsys):
    top, hor = _files(tmp_path, [(60, 40), (60, 40)], seed=4)
    out = tmp_path / "p.csv"
    assert _associate(top, hor, str(out)) == 0, capsys.readouterr().err
    assert out.read_text().splitlines()[0] == "frame,top_id,hor_id"


@pytest.mark.slow
def test_a_frame_at_the_pair_limit_is_matched(tmp_path, capsys):
    m = 64
    top, hor = _files(tmp_path, [(m, MAX_BOX_PAIRS // m - 24)], seed=5)  # 64 x 1000
    out = tmp_path / "p.csv"
    assert _associate(top, hor, str(out)) == 0, capsys.readouterr().err
    assert out.read_text().splitlines()[0] == "frame,top_id,hor_id"
