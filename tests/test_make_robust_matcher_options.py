"""training/make_robust_matcher.py: its outputs are checked before anything is rendered."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture()
def script(monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT / "training"))
    import make_robust_matcher

    return make_robust_matcher


def _refused(script, capsys, argv: list[str], *words: str) -> None:
    with pytest.raises(SystemExit) as info:
        script.main(argv)
    err = capsys.readouterr().err
    assert info.value.code == 2 and "error: " in err
    for word in words:
        assert word in err, err


def test_outputs_are_refused_before_any_work(script, tmp_path, capsys) -> None:
    work = tmp_path / "work"
    (tmp_path / "taken").mkdir()
    _refused(script, capsys, ["--work", str(work), "--out", str(tmp_path / "taken")],
             "--out", "is a folder")
    (tmp_path / "notes").write_text("a user's file")
    _refused(script, capsys, ["--work", str(work), "--out", str(tmp_path / "notes" / "m.pt")],
             "--out", "is not a folder")
    base = tmp_path / "base.pt"
    base.write_bytes(b"a matcher")
    _refused(script, capsys, ["--work", str(work), "--base", str(base), "--out", str(base)],
             "is the input --base")
    _refused(script, capsys, ["--work", str(work), "--out", str(tmp_path / "m.pt"), "--install",
                              "--bundle-out", str(base)], "--bundle-out", "is not a folder")
    assert not work.exists() and base.read_bytes() == b"a matcher"
    assert (tmp_path / "notes").read_text() == "a user's file"
