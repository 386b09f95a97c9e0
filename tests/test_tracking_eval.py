"""benchmarks/tracking_eval.py --synthetic: the rendered scenario reaches the renderer."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
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


@pytest.mark.slow
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


@pytest.mark.slow
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


@pytest.mark.slow
def test_a_flying_top_camera_gets_one_mount_offset(monkeypatch, capsys) -> None:
    # --flight: each frame's rendered top camera differs; --camera-error puts the same turn
    # in the camera's own frame (and the same step) on every frame's, and the refinement turns
    # the moving camera back.
    from scipy.spatial.transform import Rotation

    from xvmatch.datasets.synthetic_scenes import SynthConfig
    from xvmatch.datasets.tracking_video import render_tracking_video

    video = render_tracking_video(3, 6, SynthConfig(scenario="drone", n_people=(4, 6),
                                                    fps=25.0), flight=(2.0, 5.0))
    given = tracking_eval.with_camera_error(video.cameras, 2.0, 3, ("top",))
    mounts = [given[f].top.R @ video.cameras[f].top.R.T for f in sorted(video.cameras)]
    steps = [given[f].top.c - video.cameras[f].top.c for f in sorted(video.cameras)]
    assert all(np.allclose(m, mounts[0], atol=1e-12) for m in mounts)
    assert all(np.allclose(s, steps[0], atol=1e-12) for s in steps)
    assert abs(np.degrees(Rotation.from_matrix(mounts[0]).magnitude()) - 2.0) < 1e-6
    assert all(given[f].hor is video.cameras[f].hor for f in video.cameras)
    out = _run(monkeypatch, capsys, "--flight", "2", "5", "--cameras", "--camera-error", "2",
               "--error-on", "top", "--arms", "boxes-learned")
    assert "cameras: turned the moving top camera" in out
    monkeypatch.setattr(sys, "argv", ["tracking_eval.py", "--synthetic", "1", "--scenario",
                                      "overview", "--flight", "2", "5"])
    with pytest.raises(SystemExit) as exit_info:
        tracking_eval.main()
    assert exit_info.value.code == 2
    assert "--flight flies the drone's top camera" in capsys.readouterr().err
