"""benchmarks/tracking_eval.py --synthetic: the rendered scenario reaches the renderer."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import tracking_eval  # noqa: E402

ARMS = ("frame", "frame-learned", *tracking_eval.SYNTHETIC_ARMS)


def _run(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture, *extra: str) -> str:
    monkeypatch.setattr(sys, "argv", ["tracking_eval.py", "--synthetic", "1", "--seed", "3",
                                      "--synthetic-frames", "24", "--people", "4", "6", *extra])
    assert tracking_eval.main() == 0
    return capsys.readouterr().out


def test_synthetic_mode_tracks_the_scenario_asked_for(monkeypatch, capsys) -> None:
    drone = _run(monkeypatch, capsys)
    overview = _run(monkeypatch, capsys, "--scenario", "overview")
    assert "1 rendered drone videos of 24 frames" in drone
    assert "1 rendered overview videos of 24 frames" in overview
    rows = {}
    for name, out in (("drone", drone), ("overview", overview)):
        rows[name] = {line.split()[1]: line for line in out.splitlines()
                      if line.startswith("OVERALL ")}
        assert set(rows[name]) == set(ARMS), name
    # another scene: the frame association of the same seed scores differently
    assert rows["drone"]["frame"] != rows["overview"]["frame"]


def test_cameras_reach_the_learned_rows_only(monkeypatch, capsys) -> None:
    # --cameras gives the learned matcher the rendered cameras, as track --cameras: its rows
    # change, the handcrafted rows do not.
    plain = _run(monkeypatch, capsys, "--scenario", "overview")
    cams = _run(monkeypatch, capsys, "--scenario", "overview", "--cameras")
    assert "the learned weights with the rendered cameras, " in cams
    rows = [{line.split()[1]: line for line in out.splitlines() if line.startswith("OVERALL ")}
            for out in (plain, cams)]
    assert rows[0]["frame"] == rows[1]["frame"] and rows[0]["boxes"] == rows[1]["boxes"]
    assert rows[0]["frame-learned"] != rows[1]["frame-learned"]
