"""training/finetune_appearance.py: a matcher file's appearance network trained further."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "training"))

import finetune_appearance  # noqa: E402

from xvmatch.models.matcher_file import load_matcher  # noqa: E402


def test_finetune_changes_only_the_appearance_network(tmp_path, tiny_models, tiny_synth) -> None:
    out = tmp_path / "tuned.pt"
    data = [str(tiny_synth["drone"]), str(tiny_synth["overview"])]
    assert finetune_appearance.main([
        "--base", str(tiny_models["full"]), "--out", str(out), "--train-data", *data,
        "--val-data", data[1], "--epochs", "1", "--learning-rate", "1e-2",
        "--shift-probability", "1", "--shift-max", "3"]) == 0
    base, tuned = load_matcher(tiny_models["full"]), load_matcher(out)
    for key, value in base.matcher.state_dict().items():  # geometry and cue layers as they were
        torch.testing.assert_close(tuned.matcher.state_dict()[key], value)
    assert tuned.gamma == base.gamma and tuned.feature_config == base.feature_config
    changed = [k for k, v in base.appearance.state_dict().items()
               if not torch.equal(tuned.appearance.state_dict()[k], v)]
    assert changed, "the appearance network did not move"
    record = tuned.meta["appearance_finetune"]
    assert record["camera_shift"] == {"probability": 1.0, "max": 3.0}
    assert record["config"] == "appearance_cpu.yaml" and record["epochs"] == 1
    assert set(record["val_rank1"]) == {"before", "after"}
    assert out.with_name("tuned_appearance.pt").is_file()


@pytest.mark.parametrize("args, message", [
    (["--epochs", "0"], "--epochs: expected at least 1"),
    (["--shift-probability", "2"], "--shift-probability: expected a number in [0, 1]"),
    (["--shift-max", "0"], "--shift-max: expected a number in (0, 3]"),
    (["--learning-rate", "-1"], "--learning-rate: expected a positive number"),
])
def test_bad_options_get_one_line(tmp_path, capsys, args, message) -> None:
    with pytest.raises(SystemExit) as info:
        finetune_appearance.main(["--out", str(tmp_path / "x.pt"), *args])
    assert info.value.code == 2 and message in capsys.readouterr().err


def test_an_existing_output_is_never_written_over(tmp_path, capsys) -> None:
    out = tmp_path / "mine.pt"
    out.write_bytes(b"a user's file")
    with pytest.raises(SystemExit):
        finetune_appearance.main(["--out", str(out)])
    assert "exists" in capsys.readouterr().err and out.read_bytes() == b"a user's file"


def test_a_box_only_base_is_refused(tmp_path, capsys, tiny_models) -> None:
    with pytest.raises(SystemExit):
        finetune_appearance.main(["--base", str(tiny_models["boxes"]),
                                  "--out", str(tmp_path / "x.pt"), "--train-data", "a",
                                  "--val-data", "b"])
    assert "a matcher with an appearance network is needed" in capsys.readouterr().err


@pytest.mark.parametrize("beside", ["mine_appearance.pt", "mine.pt.run"])
def test_what_is_written_beside_the_output_is_never_written_over(tmp_path, capsys,
                                                                  beside) -> None:
    kept = tmp_path / beside
    kept.write_bytes(b"a user's file")
    with pytest.raises(SystemExit) as info:
        finetune_appearance.main(["--out", str(tmp_path / "mine.pt")])
    err = capsys.readouterr().err
    assert info.value.code == 2 and f"{kept}, written beside it, exists" in err
    assert kept.read_bytes() == b"a user's file" and not (tmp_path / "mine.pt").exists()


def test_an_output_folder_that_is_a_file_is_refused_before_any_work(tmp_path, capsys) -> None:
    (tmp_path / "notes").write_text("a user's file")
    with pytest.raises(SystemExit) as info:
        finetune_appearance.main(["--out", str(tmp_path / "notes" / "x.pt")])
    err = capsys.readouterr().err
    assert info.value.code == 2 and "--out" in err and "is not a folder" in err
    assert (tmp_path / "notes").read_text() == "a user's file"
