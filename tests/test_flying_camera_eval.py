"""benchmarks/flying_camera_eval.py: the per-frame cameras it gives the matcher, and a short run
end to end (refined arms mend a mount bias on a flying render)."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import flying_camera_eval  # noqa: E402

from xvmatch.datasets.synthetic_scenes import SynthConfig  # noqa: E402
from xvmatch.datasets.tracking_video import render_tracking_video  # noqa: E402


def _angle(a, b) -> float:
    return float(np.degrees(Rotation.from_matrix(a.R @ b.R.T).magnitude()))


@pytest.fixture(scope="module")
def cameras():
    video = render_tracking_video(1, 12, SynthConfig(scenario="drone", n_people=(4, 6),
                                                     fps=25.0), flight=(2.0, 5.0))
    return video.cameras


def test_the_biases_and_the_jitter(cameras) -> None:
    bias = np.array([2.0, -1.5, 1.0])
    assert flying_camera_eval.biased(cameras, "exact", bias) is cameras
    for kind in ("mount", "heading"):
        given = flying_camera_eval.biased(cameras, kind, bias)
        assert all(abs(_angle(given[f].top, c.top) - np.linalg.norm(bias)) < 1e-6
                   and given[f].hor is c.hor for f, c in cameras.items())
    # jitter: drawn anew each frame, the same draws for the same seed, others for another
    a = flying_camera_eval.biased(cameras, "exact", bias, 0.5, seed=3)
    b = flying_camera_eval.biased(cameras, "exact", bias, 0.5, seed=3)
    c = flying_camera_eval.biased(cameras, "exact", bias, 0.5, seed=4)
    angles = [_angle(a[f].top, cam.top) for f, cam in cameras.items()]
    assert len(set(np.round(angles, 6))) == len(cameras) and 0.0 < min(angles)
    assert all(np.array_equal(a[f].top.R, b[f].top.R) for f in cameras)
    assert not any(np.array_equal(a[f].top.R, c[f].top.R) for f in cameras)


def test_a_drifting_heading(cameras) -> None:
    # from 0 on the first frame to --drift on the last, about the vertical
    frames = sorted(cameras)
    drifting = flying_camera_eval.biased(cameras, "exact", np.zeros(3), drift_deg=3.0)
    angles = [_angle(drifting[f].top, cameras[f].top) for f in frames]
    assert angles[0] < 1e-9 and abs(angles[-1] - 3.0) < 1e-6
    assert np.all(np.diff(angles) > 0)
    last = drifting[frames[-1]].top.R.T @ cameras[frames[-1]].top.R  # Q of R' = R Q^T
    axis = Rotation.from_matrix(last).as_rotvec()
    assert np.allclose(axis / np.linalg.norm(axis), [0.0, 0.0, 1.0], atol=1e-9)


@pytest.mark.slow
def test_a_short_run_mends_the_biased_cameras(capsys) -> None:
    # Measured: mount 74.6, heading 84.2 as given; 100.0 each refined (turned 2.42 degrees in
    # the camera's frame, 2.30 in the world; the error is 2.69).
    assert flying_camera_eval.main(["--seeds", "1", "--frames", "30"]) == 0
    out = capsys.readouterr().out
    pooled = {k: float(v) for k, v in
              re.findall(r"^\s*(\w+(?: \w+)?)\s+([\d.]+) /", out, re.M)}
    for kind in ("mount", "heading"):
        assert pooled[f"{kind} refined"] > max(99.0, pooled[kind] + 10), out
    assert "mount turned 2.42 deg (camera)" in out and "heading turned 2.30 deg (world)" in out


def test_bad_options_are_refused(capsys) -> None:
    with pytest.raises(SystemExit) as exit_info:
        flying_camera_eval.main(["--jitter", "-1"])
    assert exit_info.value.code == 2
    assert "--jitter: expected degrees, 0 or more, got -1.0" in capsys.readouterr().err
