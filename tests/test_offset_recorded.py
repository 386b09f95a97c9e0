"""``associate --offset`` records the offset it applied beside its predictions and ``evaluate``
applies it (issue 69, item 3): a plain ``evaluate`` of re-timed predictions scores them right."""

from __future__ import annotations

import pytest

from xvmatch.cli import main
from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene, write_box_scene
from xvmatch.formats.mot_boxes import read_mot_boxes, shift_frames, write_mot_boxes


@pytest.fixture(scope="module")
def shifted(tmp_path_factory):
    folder = tmp_path_factory.mktemp("offset")
    scene = simulate_box_scene(SceneConfig(n_people=(6, 8)), n_frames=30, seed=3)
    top, hor = write_box_scene(scene, folder, "s")
    late = folder / "s_hor_late.txt"
    write_mot_boxes(late, shift_frames(read_mot_boxes(hor), 4))  # hor frame = top frame + 4
    return folder, str(top), str(hor), str(late)


def _f1(capsys) -> float:
    lines = capsys.readouterr().out.strip().splitlines()
    return float(lines[-1].split()[-3])


def test_recorded_offset_is_applied_by_evaluate(shifted, capsys) -> None:
    folder, top, _, late = shifted
    pred = folder / "pred.csv"
    assert main(["associate", "--top", top, "--hor", late, "--offset", "-4", "--out", str(pred),
                 "--quiet", "--image-size", "2688x1512"]) == 0
    record = folder / "pred.csv.offset.json"
    assert record.read_text() == '{"offset": -4}\n'
    assert main(["evaluate", "--pred", str(pred), "--top", top, "--hor", late]) == 0
    recorded = _f1(capsys)
    assert main(["evaluate", "--pred", str(pred), "--top", top, "--hor", late,
                 "--offset", "-4"]) == 0
    assert _f1(capsys) == recorded
    assert main(["evaluate", "--pred", str(pred), "--top", top, "--hor", late,
                 "--offset", "0"]) == 0
    assert recorded > _f1(capsys)  # scored against the wrong frames without it


def test_note_names_the_record_and_a_run_without_offset_removes_it(shifted, capsys) -> None:
    folder, top, hor, late = shifted
    pred = folder / "pred2.csv"
    assert main(["associate", "--top", top, "--hor", late, "--offset", "-4", "--out", str(pred),
                 "--quiet", "--image-size", "2688x1512"]) == 0
    capsys.readouterr()
    assert main(["evaluate", "--pred", str(pred), "--top", top, "--hor", late]) == 0
    err = capsys.readouterr().err
    assert f"applying the offset -4 that associate recorded in {pred}.offset.json" in err
    # The same predictions file rewritten by a run without an offset: no stale record.
    assert main(["associate", "--top", top, "--hor", hor, "--out", str(pred), "--quiet",
                 "--image-size", "2688x1512"]) == 0
    assert not (folder / "pred2.csv.offset.json").exists()
