"""The offset search's progress (issue 69, item 9: ``offset`` and ``--offset auto`` were silent
for 15-50 s): ``estimate_offset`` tells ``progress(done, total)`` as its clip costs are known,
the bar (``core/progress.growing_total``) follows it, and the estimate does not depend on it."""

from __future__ import annotations

import io

import numpy as np
import pytest
from tqdm import tqdm

from xvmatch.cli import main
from xvmatch.core.progress import growing_total
from xvmatch.cues.auto_offset import AutoOffsetOptions, auto_offset
from xvmatch.cues.offset_estimation import estimate_offset
from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene
from xvmatch.formats.mot_boxes import shift_frames, write_mot_boxes


@pytest.fixture(scope="module")
def pair():
    scene = simulate_box_scene(SceneConfig(n_people=(4, 5)), n_frames=70, seed=7)
    return shift_frames(scene.top, -8), scene.hor, float(scene.config.hor_size[0])


def test_progress_counts_every_clip_cost_and_changes_nothing(pair) -> None:
    top, hor, width = pair
    told: list[tuple[int, int]] = []
    est = estimate_offset(top, hor, width, max_offset=10, n_clips=4,
                          progress=lambda d, t: told.append((d, t)))
    plain = estimate_offset(top, hor, width, max_offset=10, n_clips=4)
    assert (est.offset, est.applied, est.status) == (plain.offset, plain.applied, plain.status)
    np.testing.assert_array_equal(est.clip_costs, plain.clip_costs)
    done = [d for d, _ in told]
    assert done == sorted(done) and all(d <= t for d, t in told)
    # One cost per clip and offset tried, coarse pass and fine pass: the last call is complete.
    assert told[-1] == (4 * est.offsets.size, 4 * est.offsets.size)
    assert told[0][1] < told[-1][1]  # the fine pass grew the total


@pytest.mark.slow
def test_auto_offset_passes_progress_on(pair) -> None:
    top, hor, width = pair
    told: list[tuple[int, int]] = []
    decided = auto_offset(top, hor, AutoOffsetOptions(hor_width=width, max_offset=10),
                          progress=lambda d, t: told.append((d, t)))
    assert told and told[-1][0] == told[-1][1] > 0
    assert decided == auto_offset(top, hor, AutoOffsetOptions(hor_width=width, max_offset=10))


@pytest.mark.parametrize("disable", [False, True])
def test_a_bar_follows_a_growing_total(disable: bool) -> None:
    out = io.StringIO()
    with tqdm(total=0, file=out, disable=disable) as bar:
        tell = growing_total(bar)
        tell(10, 40)
        tell(40, 40)
        tell(55, 60)
        assert bar.total == 60 and (disable or bar.n == 55)
    assert ("55/60" in out.getvalue()) != disable


def test_offset_command_is_silent_but_for_its_line_off_a_terminal(pair, tmp_path,
                                                                  capsys) -> None:
    top, hor, _width = pair
    write_mot_boxes(tmp_path / "top.txt", top)
    write_mot_boxes(tmp_path / "hor.txt", hor)
    argv = ["offset", "--top", str(tmp_path / "top.txt"), "--hor", str(tmp_path / "hor.txt"),
            "--max-offset", "10", "--clips", "4", "--image-size", "2688x1512"]
    assert main(argv) == 0
    first = capsys.readouterr()
    assert main([*argv, "--quiet"]) == 0
    quiet = capsys.readouterr()
    assert first.out == quiet.out and first.out.startswith("offset ")
    assert "offset search" not in first.err  # stderr is not a terminal here: no bar
    assert "stand upright" not in first.err  # a nadir drone's view: nothing to warn of


def test_a_top_frames_hypotheses_built_once_give_associate_frames_cost(pair) -> None:
    """The offset search builds each top frame's hypotheses once for the clip frames that read it
    (``spatial_search.top_search`` and ``best_cost``): the same costs, bit for bit."""
    from xvmatch.cues.spatial_search import associate_frame, best_cost, top_search

    top, hor, width = pair
    frames = sorted(set(hor) & set(top))[:12]
    for t in frames[::3]:
        for candidates in (None, [0]):
            search = top_search(top[t].boxes, candidates=candidates)
            for f in frames:
                expected = associate_frame(top[t].boxes, hor[f].boxes, width,
                                           candidates=candidates).cost
                assert best_cost(search, hor[f].boxes, width) == expected
    assert best_cost(top_search(top[frames[0]].boxes[:1]), hor[frames[0]].boxes, width) \
        == float("inf")
