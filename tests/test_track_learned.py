"""``xvmatch track --model``: cross-view weights from the learned matcher's costs (issue 33)."""

from __future__ import annotations

import hashlib
import json
import os
import platform
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from xvmatch.cli import main
from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene
from xvmatch.formats.mot_boxes import FrameBoxes, write_mot_boxes
from xvmatch.inference.linking.assignment import FrameCosts
from xvmatch.inference.linking.tracklets import Tracklet
from xvmatch.inference.tracks.track_costs import frame_evidence, learned_similarity
from xvmatch.inference.tracks.tracking import LearnedEvidence, TrackConfig, track_pair


def _track(files, out: Path, *extra: str) -> int:
    return main(["track", "--top", str(files["det_top"]), "--hor", str(files["det_hor"]),
                 "--out", str(out), "--quiet", *extra])


@pytest.mark.slow
def test_track_model_default_from_boxes_only(track_files, tmp_path, capsys):
    out = tmp_path / "tracks"
    assert _track(track_files, out, "--model", "default") == 0
    for view in ("top", "hor"):
        det = track_files[f"det_{view}"].read_text().splitlines()
        written = (out / f"{view}.txt").read_text().splitlines()
        assert [ln.split(",", 2)[::2] for ln in written] == [ln.split(",", 2)[::2] for ln in det]
    capsys.readouterr()
    assert main(["evaluate", "--tracks", str(out), "--top", str(track_files["gt_top"]),
                 "--hor", str(track_files["gt_hor"]), "--json"]) == 0
    scores = json.loads(capsys.readouterr().out)
    # Measured: precision 100.0, CVIDF1 83.3 (the handcrafted weights score the same here): no
    # wrong pair, some pairs missed.
    assert scores["cross_view"]["cvidp"] > 95 and scores["cross_view"]["cvidf1"] > 80


def _digest(folder: Path) -> str:
    return hashlib.sha256((folder / "top.txt").read_bytes()
                          + (folder / "hor.txt").read_bytes()).hexdigest()


def _scores(files, folder: Path, capsys) -> dict:
    capsys.readouterr()
    assert main(["evaluate", "--tracks", str(folder), "--top", str(files["gt_top"]),
                 "--hor", str(files["gt_hor"]), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.mark.slow
def test_handcrafted_weights_reproduce_the_output_before(track_files, tmp_path, capsys):
    """``--weights handcrafted`` is the tracker without ``--model``, byte for byte, and scores
    what the code before the learned weights (commit a4567a4) scored on this scene.

    The bytes themselves are not pinned: the simulated scene's boxes differ in their last bits
    with the CPU's OpenBLAS kernels (``OPENBLAS_CORETYPE=Haswell`` against ``Sandybridge`` on one
    machine), and the tracker writes the boxes it reads (sha256 260e6b7c... on an AVX-512 CPU,
    eb2dcd84... on an AVX2 one); on the same box files its output is the same bytes with every
    kernel (docs/method.md, "Determinism")."""
    assert _track(track_files, tmp_path / "plain") == 0
    assert _track(track_files, tmp_path / "hand", "--weights", "handcrafted") == 0
    for name in ("top.txt", "hor.txt"):
        assert (tmp_path / "plain" / name).read_bytes() == (tmp_path / "hand" / name).read_bytes()
    scores = _scores(track_files, tmp_path / "plain", capsys)
    cross = scores["cross_view"]
    assert (cross["tp"], cross["fp"], cross["mismatch"], cross["miss"]) == (143, 0, 0, 57)
    assert scores["top"]["idsw"] == 0 and scores["top"]["idf1"] == pytest.approx(100.0)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--weights", "learned"], "add --model BUNDLE or --model default"),
        (["--model", "default", "--weights", "handcrafted"], "needs the images"),
        (["--model", "/nonexistent/bundle"], "/nonexistent/bundle"),
    ],
)
def test_weight_option_errors_are_one_line(track_files, tmp_path, capsys, extra, message):
    assert _track(track_files, tmp_path / "x", *extra) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("xvmatch: error:") and message in err[0], err


@pytest.mark.slow
def test_learned_weights_with_the_wearer_given(track_files, tmp_path):
    gt = {ln.split(",", 2)[2]: ln.split(",")[1]
          for ln in track_files["gt_top"].read_text().splitlines()}
    lines = [ln.replace(",-1,", ",0,", 1) if gt[ln.split(",", 2)[2]] == "0" else ln
             for ln in track_files["det_top"].read_text().splitlines()]
    with_wearer = tmp_path / "top_wearer.txt"
    with_wearer.write_text("\n".join(lines) + "\n")
    files = {**track_files, "det_top": with_wearer}
    assert _track(files, tmp_path / "a", "--model", "default", "--camera-id", "0") == 0
    assert (tmp_path / "a" / "hor.txt").read_text().count("\n") == len(
        track_files["det_hor"].read_text().splitlines())


def _costs(top_rows, hor_rows, cost, gamma=0.5) -> FrameCosts:
    from xvmatch.inference.linking.assignment import assign

    cost = np.asarray(cost, dtype=float)
    paired = np.zeros(cost.shape, dtype=bool)
    pairs = assign(cost, gamma)
    paired[pairs[:, 0], pairs[:, 1]] = True
    return FrameCosts(np.array(top_rows), np.array(hor_rows), cost, paired)


def test_frame_evidence_rules():
    # With gamma 0.5 the assignment takes (0, 0) alone (0.1 + 2 x 0.5 against 0.3 + 2 x 0.5).
    c = _costs([0, 1], [5, 6], [[0.1, 0.7], [0.3, 0.9]])
    assert c.paired.tolist() == [[True, False], [False, False]]
    # margin also counts (1, 0), below the dustbin but lost to (0, 0).
    np.testing.assert_allclose(frame_evidence(c, 0.5, "margin"), [[0.8, 0.0], [0.4, 0.0]])
    np.testing.assert_allclose(frame_evidence(c, 0.5, "pairs"), [[1, 0], [0, 0]])
    np.testing.assert_allclose(frame_evidence(c, 0.5, "confidence"), [[0.9, 0], [0, 0]])
    # soft (T = 0.1, z = exp((0.5 - c) / T)): the smaller of z over 1 + its row's or its
    # column's sum; (0, 0): its column, e^4 / (1 + e^4 + e^2); (1, 1): its row, e^-4 / (1 + e^2
    # + e^-4).
    np.testing.assert_allclose(frame_evidence(c, 0.5, "soft"),
                               [[0.8668, 0.002428], [0.1173, 0.002179]], rtol=1e-3)
    with pytest.raises(ValueError, match="rule must be one of"):
        frame_evidence(c, 0.5, "bogus")


def test_learned_similarity_sums_over_shared_frames_over_the_longer_tracklet():
    def tracklet(frames, rows):
        return Tracklet(0, np.array(frames), np.array(rows), np.zeros((len(frames), 4)))

    top = [tracklet([1, 2, 3, 4], [10, 20, 30, 40]), tracklet([1, 2], [11, 21])]
    hor = [tracklet([2, 3], [50, 60])]
    costs = {
        1: _costs([10, 11], [99], [[0.0], [0.0]]),  # row 99 is in no tracklet
        2: _costs([21, 20], [50], [[0.25], [0.0]]),
        3: _costs([30], [60], [[0.1]]),
    }
    sim = learned_similarity(top, hor, costs, 0.5, "margin")
    # top 0 shares frames 2 and 3: (1.0 + 0.8) / max(4, 2); top 1 shares frame 2: 0.5 / 2.
    np.testing.assert_allclose(sim, [[1.8 / 4], [0.5 / 2]])
    # "pairs" is Eq. 13 on the matcher's pairs: frame 2 pairs (20, 50), frame 3 (30, 60).
    np.testing.assert_allclose(learned_similarity(top, hor, costs, 0.5, "pairs"),
                               [[2 / 4], [0.0]])


def test_learned_weights_give_the_right_tracks_on_a_known_case():
    # Two people walk apart in both views over 20 frames (two clips); the horizontal rows are
    # listed in the other order. The learned costs say top person k is horizontal person k;
    # top and horizontal rows never share a number, so only the costs link the views.
    top, hor, costs = {}, {}, {}
    for f in range(1, 21):
        t_rows, h_rows = np.array([2 * f, 2 * f + 1]), np.array([1001 + 2 * f, 1000 + 2 * f])
        top[f] = FrameBoxes(f, t_rows, np.array([[100 + f, 100, 20, 40], [400 - f, 300, 20, 40]],
                                                dtype=float))
        hor[f] = FrameBoxes(f, h_rows, np.array([[900 - 2 * f, 200, 60, 150],
                                                 [200 + 2 * f, 210, 60, 150]], dtype=float))
        # cost rows: top person 0, 1; columns: hor rows in file order (person 1, person 0).
        costs[f] = _costs(t_rows, h_rows, [[0.9, 0.05], [0.1, 0.8]])
    res = track_pair(top, hor, 1280.0, config=TrackConfig(),
                     learned=LearnedEvidence(costs, 0.5))
    for f in range(1, 21):
        assert res.top_rows[2 * f] == res.hor_rows[1000 + 2 * f]
        assert res.top_rows[2 * f + 1] == res.hor_rows[1001 + 2 * f]
        assert res.top_rows[2 * f] != res.top_rows[2 * f + 1]
        assert res.frame_pairs[f] == [(2 * f, 1000 + 2 * f), (2 * f + 1, 1001 + 2 * f)]
    assert len(set(res.top_rows.values())) == 2
    # The same boxes with the costs swapped: the other pairing, still one id per person.
    swapped = {f: _costs(c.top_rows, c.hor_rows, c.cost[:, ::-1]) for f, c in costs.items()}
    res = track_pair(top, hor, 1280.0, learned=LearnedEvidence(swapped, 0.5))
    assert all(res.top_rows[2 * f] == res.hor_rows[1001 + 2 * f] for f in range(1, 21))


@pytest.mark.slow
def test_learned_tracks_do_not_depend_on_workers(tmp_path):
    # 40 frames: more than one chunk of the learned association's feature pool (32 frames), so
    # that --workers 2 really shares them between processes.
    scene = simulate_box_scene(SceneConfig(), n_frames=40, seed=11)
    files = {}
    for view, frames in (("top", scene.top), ("hor", scene.hor)):
        write_mot_boxes(tmp_path / f"gt_{view}.txt", frames)
        lines = (tmp_path / f"gt_{view}.txt").read_text().splitlines()
        det = [",".join([ln.split(",")[0], "-1", *ln.split(",")[2:]]) for ln in lines]
        files[f"det_{view}"] = tmp_path / f"det_{view}.txt"
        files[f"det_{view}"].write_text("\n".join(det) + "\n")
    assert _track(files, tmp_path / "one", "--model", "default") == 0
    assert _track(files, tmp_path / "two", "--model", "default", "--workers", "2") == 0
    assert _digest(tmp_path / "one") == _digest(tmp_path / "two")


@pytest.mark.slow
@pytest.mark.skipif(platform.machine().lower() not in ("x86_64", "amd64"),
                    reason="OPENBLAS_CORETYPE names x86 kernels")
@pytest.mark.parametrize("extra", [[], ["--model", "default"]], ids=["handcrafted", "learned"])
def test_track_output_does_not_depend_on_the_blas_kernels(track_files, tmp_path, extra):
    """The same box files give the same bytes whichever matrix kernels OpenBLAS picks for the
    CPU (AVX2 Haswell against SSE3 Prescott here; an AVX-512 CPU picks a third)."""
    digests = set()
    for core in ("Haswell", "Prescott"):
        out = tmp_path / core
        env = {**os.environ, "OPENBLAS_CORETYPE": core, "OMP_NUM_THREADS": "1"}
        subprocess.run([sys.executable, "-m", "xvmatch", "track", "--top",
                        str(track_files["det_top"]), "--hor", str(track_files["det_hor"]),
                        "--out", str(out), "--quiet", *extra], env=env, check=True)
        digests.add(_digest(out))
    assert len(digests) == 1
