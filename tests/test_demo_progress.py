"""``xvmatch demo``'s progress (issue 69, item 9: the demo was silent for about a minute): a bar
over the pairs rendered and matched, on a terminal only, none with ``--quiet``."""

from __future__ import annotations

import io
import sys

import pytest

from xvmatch.cli import main


class _Terminal(io.StringIO):
    """A stderr that says it is a terminal, so that the bar (tqdm) is drawn into it."""

    def isatty(self) -> bool:
        return True


@pytest.mark.slow
def test_demo_shows_its_pairs_on_a_terminal_and_nothing_when_quiet(tmp_path, monkeypatch,
                                                                  capsys, tiny_models):
    argv = ["demo", "--scenes", "1", "--frames", "2", "--model",
            str(tiny_models["full_bundle"])]
    terminal = _Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    assert main([*argv, "--out", str(tmp_path / "a")]) == 0
    drawn = terminal.getvalue()
    # 2 pairs per scenario, each counted rendered and matched: 8 in all, each step named. A
    # step's name redraws the bar at once; a count alone only every 0.1 s (tqdm), so the
    # last step is checked with the count it was named at, 6 of 8, and never "8/8".
    assert "demo" in drawn and "0/8" in drawn and "rendering drone" in drawn
    assert "6/8" in drawn and "matching overview" in drawn
    quiet = _Terminal()
    monkeypatch.setattr(sys, "stderr", quiet)
    assert main([*argv, "--out", str(tmp_path / "b"), "--quiet"]) == 0
    assert quiet.getvalue() == ""
    assert "wrote" in capsys.readouterr().out  # the summary line stays
