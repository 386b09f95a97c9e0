"""Cameras put in one ground frame from their people alone (issue 68, item 2):
:mod:`xvmatch.inference.views.multicam_from_people`."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.datasets.multicam_scenes import MulticamConfig, simulate_multicam_scene
from xvmatch.formats.camera_io import load_ground_cameras, save_cameras
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.geometry.ground_plane import GroundCamera, foot_points
from xvmatch.inference.views.multicam import MulticamOptions, associate_cameras, relabel
from xvmatch.inference.views.multicam_from_people import (
    MAX_RESIDUAL,
    GroundSimilarity,
    RegistrationError,
    estimate_cameras,
    fit_plane_homography,
    fit_similarity,
    map_points,
    register_pair,
)
from xvmatch.metrics.multicam_metrics import multicam_scores

similarities = st.builds(GroundSimilarity, st.floats(0.5, 2.0), st.floats(-3.1, 3.1),
                         st.tuples(st.floats(-50, 50), st.floats(-50, 50)))


@settings(max_examples=40, deadline=None)
@given(sim=similarities, seed=st.integers(0, 2**16))
def test_fit_similarity_recovers_a_similarity(sim, seed):
    src = np.random.default_rng(seed).uniform(-10, 10, (12, 2))
    fitted = fit_similarity(src, sim.apply(src))
    np.testing.assert_allclose(fitted.apply(src), sim.apply(src), atol=1e-6)
    assert fitted.scale == pytest.approx(sim.scale)


@settings(max_examples=40, deadline=None)
@given(a=similarities)
def test_a_similarity_inverts(a):
    xy = np.array([[1.0, 2.0], [-3.0, 0.5], [7.0, -4.0]])
    np.testing.assert_allclose(a.inverse().apply(a.apply(xy)), xy, atol=1e-6)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**16))
def test_fit_plane_homography_recovers_a_homography(seed):
    rng = np.random.default_rng(seed)
    H = np.eye(3) + np.diag([0.2, 0.2, 0.0]) * rng.uniform(-1, 1, 3)
    H[:2, 2] = rng.uniform(-20, 20, 2)
    H[2, :2] = rng.uniform(-0.01, 0.01, 2)  # a gentle perspective: points stay in front
    src = rng.uniform(-15, 15, (30, 2))
    np.testing.assert_allclose(map_points(fit_plane_homography(src, map_points(H, src)), src),
                               map_points(H, src), atol=1e-6)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**16))
def test_the_fast_distances_and_scores_are_the_plain_formulas(seed):
    from xvmatch.inference.views.multicam_from_people import _explained, _squared_distances

    rng = np.random.default_rng(seed)
    src = rng.uniform(-5, 5, (3, 6, 4, 2))  # (K, F, A, 2) mapped by three proposals
    dst = rng.uniform(-5, 5, (6, 5, 2))
    src[rng.random(src.shape[:3]) < 0.3] = np.nan  # people absent
    dst[rng.random(dst.shape[:2]) < 0.3] = np.nan
    p, q = src[:, :, :, None, :], dst[None, :, None, :, :]
    plain = ((p - q) ** 2).sum(-1)
    np.testing.assert_array_equal(_squared_distances(p, q), plain)  # bit for bit, NaN too
    near = np.exp(-0.5 * np.where(np.isnan(plain), np.inf, plain) / 0.5**2)
    want = near.max(axis=3).sum(axis=(1, 2)) + near.max(axis=2).sum(axis=(1, 2))
    np.testing.assert_array_equal(np.round(_explained(src, dst), 9), np.round(want, 9))


def _walks(n_people: int, n_frames: int, seed: int) -> np.ndarray:
    """``(F, N, 2)`` people walking about a 12 m square."""
    rng = np.random.default_rng(seed)
    start = rng.uniform(-6, 6, (n_people, 2))
    steps = rng.normal(0.0, 0.15, (n_frames, n_people, 2)) + rng.uniform(-0.1, 0.1,
                                                                          (1, n_people, 2))
    return start + np.cumsum(steps, axis=0)


def test_register_pair_lays_one_map_on_the_other_whoever_else_is_seen():
    world = _walks(7, 80, seed=3)
    truth = GroundSimilarity(1.1, 2.0, (30.0, -12.0))  # the source map -> the target map
    rng = np.random.default_rng(0)
    # The source sees people 0-4, the target 2-6 (a shuffled order: ids mean nothing across).
    src = truth.inverse().apply(world[:, :5]) + rng.normal(0, 0.05, (80, 5, 2))
    dst = world[:, rng.permutation(np.arange(2, 7))] + rng.normal(0, 0.05, (80, 5, 2))
    src[20:30, 1] = np.nan  # a person missed for a while
    reg = register_pair(src, dst, "a", "b")
    assert reg is not None and reg.trusted, reg
    probe = np.array([[0.0, 0.0], [5.0, -3.0]])
    np.testing.assert_allclose(map_points(reg.homography, truth.inverse().apply(probe)), probe,
                               atol=0.3)
    assert reg.matches >= 3 * 80 - 10  # the three people both see, nearly every frame


def test_registration_decisions_near_their_bounds_do_not_hang_on_the_last_bits():
    # Two maps exactly 1.5 apart in scale, the bound a registration may have: every proposal's
    # scale is 1.5 up to the last bits of the fit (which differ between CPUs), the maps
    # perturbed by 1e-12 relative around it. Each is registered the same way, at the bound.
    world = _walks(5, 60, seed=2)
    truth = GroundSimilarity(1.5, 0.7, (4.0, -2.0))  # the source map -> the target map
    src = truth.inverse().apply(world)
    dst = world[:, ::-1].copy()
    decisions = set()
    for eps in (0.0, 1e-12, -1e-12, 3e-12, -3e-12):
        reg = register_pair(src, dst * (1.0 + eps), "a", "b")
        decisions.add(None if reg is None else (reg.matches, reg.beyond, reg.margin,
                                                reg.residual, reg.trusted))
    assert len(decisions) == 1 and None not in decisions, decisions
    base = register_pair(src, dst, "a", "b")
    assert base.trusted
    # The trust's own bounds: a residual or a margin 1e-12 relative off its bound is at it.
    for field, bound in (("residual", MAX_RESIDUAL), ("margin", 1.2)):
        for eps in (1e-12, -1e-12):
            near = dataclasses.replace(base, **{field: bound * (1.0 + eps)})
            assert near.trusted, (field, eps)


def test_the_joint_refinement_pins_a_camera_its_tree_link_placed_off():
    from xvmatch.inference.views.multicam_from_people import _refine_jointly

    world = _walks(8, 80, seed=4)  # every camera sees everyone: each pair matches them all
    rng = np.random.default_rng(1)
    own = {"r": np.eye(3), "a": _similarity_matrix(1.1, 0.5, (3.0, -2.0)),
           "b": _similarity_matrix(0.9, -1.2, (-4.0, 1.0))}  # each map -> the reference's
    paths = {n: map_points(np.linalg.inv(G), world) + rng.normal(0, 0.02, world.shape)
             for n, G in own.items()}
    bent = np.array([[1.03, 0.01, 0.2], [-0.02, 0.98, -0.1], [0.004, -0.003, 1.0]])
    placed = {"r": np.eye(3), "a": own["a"], "b": own["b"] @ bent}  # b's link bent it

    def error(cams):
        return np.median(np.hypot(*(map_points(cams["b"], paths["b"]) - world).reshape(-1, 2).T))

    assert error(placed) > 0.2
    refined = _refine_jointly(paths, placed, "r")
    assert error(refined) < 0.05, error(refined)
    np.testing.assert_allclose(refined["r"], np.eye(3))  # the reference's map is the frame


def _similarity_matrix(scale: float, angle: float, shift: tuple[float, float]) -> np.ndarray:
    c, s = scale * np.cos(angle), scale * np.sin(angle)
    return np.array([[c, -s, shift[0]], [s, c, shift[1]], [0.0, 0.0, 1.0]])


def test_register_pair_without_people_seen_together_proposes_nothing():
    world = _walks(6, 40, seed=1)
    src, dst = world[:, :3].copy(), world[:, 3:].copy()
    src[20:], dst[:20] = np.nan, np.nan  # never in both cameras in the same frame
    assert register_pair(src, dst) is None


def _scene(n_cameras: int, frames: int, people: int, seed: int = 1):
    return simulate_multicam_scene(MulticamConfig(n_cameras=n_cameras,
                                                  n_people=(people, people)), frames, seed)


def _sizes(scene) -> dict:
    return {n: (c.width, c.height) for n, c in scene.cameras.items()}


def test_two_cameras_from_their_people_put_each_person_in_one_place(tmp_path):
    scene = _scene(2, 60, 6)
    est = estimate_cameras(scene.boxes, _sizes(scene))
    assert set(est.cameras) == {"cam1", "cam2"} and len(est.links) == 1
    assert "cameras calibrated and registered from their people" in est.summary()
    # The true people's foot points from both cameras land together (the frame is the
    # reference camera's map: compared between cameras, not with the true ground).
    gaps = []
    for f in sorted(set(scene.gt["cam1"]) & set(scene.gt["cam2"])):
        a, b = scene.gt["cam1"][f], scene.gt["cam2"][f]
        for k, i in enumerate(a.ids.tolist()):
            j = np.nonzero(b.ids == i)[0]
            if len(j):
                pa = est.cameras["cam1"].to_ground(foot_points(a.boxes[k:k + 1]))[0]
                pb = est.cameras["cam2"].to_ground(foot_points(b.boxes[j[:1]]))[0]
                gaps.append(float(np.hypot(*(pa - pb)[0])))
    assert len(gaps) > 50 and np.median(gaps) < 0.5
    # Written as a camera file marked estimated, and read back by multicam's reader.
    save_cameras(tmp_path / "cameras.json", est.cameras, est.records())
    back = load_ground_cameras(tmp_path / "cameras.json")
    for name, cam in est.cameras.items():
        np.testing.assert_allclose(back[name].H, cam.H, rtol=1e-9, atol=1e-12)


def test_a_camera_that_sees_nobody_the_others_see_is_refused_by_name():
    scene = _scene(2, 60, 6)
    # cam2's boxes replaced by cam1's shifted by 20 frames: people, but never cam1's at once.
    late = {f + 200: FrameBoxes(f + 200, r.ids, r.boxes) for f, r in scene.boxes["cam1"].items()}
    boxes = {"cam1": scene.boxes["cam1"], "cam2": late}
    sizes = {"cam1": _sizes(scene)["cam1"], "cam2": _sizes(scene)["cam1"]}
    with pytest.raises(RegistrationError, match=r"camera\(s\) cam2 .*give --cameras"):
        estimate_cameras(boxes, sizes)


@pytest.mark.slow
def test_multicam_on_estimated_cameras_scores_as_on_the_true_ones():
    scene = _scene(3, 80, 8)
    est = estimate_cameras(scene.boxes, _sizes(scene))
    scores = {}
    for label, cams in (("true", {n: GroundCamera.from_camera(c)
                                  for n, c in scene.cameras.items()}),
                        ("estimated", est.cameras)):
        res = associate_cameras(cams, scene.boxes, MulticamOptions())
        scores[label] = multicam_scores(relabel(scene.boxes, res), scene.gt)["box_pairs"]["F1"]
    assert scores["estimated"] >= scores["true"] - 0.02, scores


def test_run_multicam_without_cameras_estimates_them_and_returns_the_estimate():
    from xvmatch.inference.views.multicam_run import MulticamRunOptions, run_multicam

    scene = _scene(2, 60, 6)
    options = MulticamRunOptions(above_horizon="drop", image_sizes=_sizes(scene))
    run = run_multicam(None, scene.boxes, options)
    est = estimate_cameras(scene.boxes, _sizes(scene))
    assert run.estimated is not None and run.estimated.summary() == est.summary()
    assert run.cameras is run.estimated.cameras
    given = run_multicam(est.cameras, scene.boxes, options)  # the same as given those cameras
    assert given.estimated is None
    assert {n: {f: r.ids.tolist() for f, r in fr.items()} for n, fr in run.relabelled.items()} \
        == {n: {f: r.ids.tolist() for f, r in fr.items()} for n, fr in given.relabelled.items()}
    with pytest.raises(ValueError, match="--image-size NAME=WxH for cam2"):
        run_multicam(None, scene.boxes,
                     MulticamRunOptions(image_sizes={"cam1": _sizes(scene)["cam1"]}))


def _cli_scene(tmp_path, n_cameras: int, frames: int, people: int, seed: int):
    from xvmatch.datasets.multicam_scenes import write_multicam_scene

    scene = _scene(n_cameras, frames, people, seed)
    write_multicam_scene(tmp_path / "scene", scene)
    boxes = [f"{n}={tmp_path / 'scene' / 'boxes' / f'{n}.txt'}" for n in scene.cameras]
    sizes = [f"{n}={w}x{h}" for n, (w, h) in _sizes(scene).items()]
    return scene, boxes, sizes


def test_multicam_without_cameras_asks_for_each_camera_image_size(tmp_path, capsys):
    from xvmatch.cli import main

    _, boxes, sizes = _cli_scene(tmp_path, 2, 20, 4, 1)
    assert main(["multicam", "--boxes", *boxes, "--image-size", sizes[0],
                 "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "without --cameras" in err and "--image-size NAME=WxH for cam2" in err
    assert not (tmp_path / "out").exists()


def test_multicam_without_cameras_writes_the_cameras_it_found_and_reads_them_back(tmp_path,
                                                                                 capsys):
    from xvmatch.cli import main

    scene, boxes, sizes = _cli_scene(tmp_path, 2, 60, 6, 1)
    out = tmp_path / "out"
    assert main(["multicam", "--boxes", *boxes, "--image-size", *sizes, "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "2 cameras calibrated and registered from their people" in err
    cams = load_ground_cameras(out / "cameras.json")  # one world: read as any camera file
    assert set(cams) == {"cam1", "cam2"}
    again = tmp_path / "again"
    assert main(["multicam", "--boxes", *boxes, "--cameras", str(out / "cameras.json"),
                 "--out", str(again)]) == 0
    for name in scene.cameras:  # the same global ids from the written cameras
        assert (again / f"{name}.txt").read_text() == (out / f"{name}.txt").read_text()


def test_multicam_without_cameras_claims_no_write_when_the_run_or_the_write_fails(
        tmp_path, capsys, monkeypatch):
    from xvmatch.cli import main
    from xvmatch.formats import multicam_files

    _, boxes, sizes = _cli_scene(tmp_path, 2, 60, 6, 1)
    # The cameras are estimated, the writing fails: no note that they were written.
    def fail(*_args, **_kw):
        raise OSError("disk full")

    monkeypatch.setattr(multicam_files, "write_multicam_outputs", fail)
    assert main(["multicam", "--boxes", *boxes, "--image-size", *sizes,
                 "--out", str(tmp_path / "out")]) == 2
    said = capsys.readouterr()
    assert "disk full" in said.err and "wrote" not in said.err + said.out
    monkeypatch.undo()
    # cam2 never sees cam1's people at once: the estimate refuses, nothing is said written.
    late = tmp_path / "late.txt"
    rows = (tmp_path / "scene" / "boxes" / "cam1.txt").read_text().splitlines()
    late.write_text("".join(f"{int(r.split(',')[0]) + 200},{r.split(',', 1)[1]}\n"
                            for r in rows))
    assert main(["multicam", "--boxes", boxes[0], f"cam2={late}", "--image-size",
                 sizes[0], sizes[0].replace("cam1", "cam2"), "--out",
                 str(tmp_path / "out2")]) == 2
    said = capsys.readouterr()
    assert "cannot put camera(s) cam2" in said.err and "wrote" not in said.err + said.out
    assert not (tmp_path / "out2").exists()


def test_short_tracks_take_no_part_in_the_estimate_unless_they_are_most_boxes() -> None:
    """A tracker's false boxes (tracks of a few boxes) are left out of the estimate; a short clip
    whose tracks are all short keeps them."""
    from xvmatch.inference.views.multicam_from_people import _long_tracks

    box = [10.0, 20.0, 30.0, 80.0]
    frames = {f: FrameBoxes(f, [1, 2] + ([90 + f // 3] if f < 9 else []),
                            [box] * (3 if f < 9 else 2)) for f in range(1, 31)}
    kept = _long_tracks(frames)
    assert sorted({int(i) for r in kept.values() for i in r.ids}) == [1, 2]
    assert all(np.asarray(r.boxes).shape == (len(r.ids), 4) for r in kept.values())
    short = {f: frames[f] for f in range(1, 9)}
    assert _long_tracks(short) is short
