"""Ground registration of a walking horizontal camera on the top view's ground map (issue 67):
the pose recovered from people alone, chosen consistently over time, and the pairs under it."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.core import kernel_choice
from xvmatch.cues import ground_registration as gr
from xvmatch.geometry.people_calibration import BODY_WIDTH


def _view(top: np.ndarray, centre: np.ndarray, heading: float) -> np.ndarray:
    """Top-map points in the frame of a camera at ``centre`` looking along ``heading``."""
    c, s = np.cos(heading), np.sin(heading)
    rel = top - centre
    return np.column_stack([rel[:, 0] * c + rel[:, 1] * s, -rel[:, 0] * s + rel[:, 1] * c])


def _in_view(local: np.ndarray, hfov: float = 70.0) -> np.ndarray:
    return (local[:, 0] > 1.0) & (np.abs(np.arctan2(local[:, 1], local[:, 0]))
                                   < np.radians(hfov) / 2)


def _crowd_seen(seed: int, heading: float) -> tuple:
    """Nine top people, a camera about 12 m off looking along ``heading`` at them, and what
    it sees: ``(rng, top, centre, local, seen)``, ``local`` the people in its frame."""
    rng = np.random.default_rng(seed)
    top = rng.uniform(-8, 8, (9, 2))
    centre = -12.0 * np.array([np.cos(heading), np.sin(heading)]) + rng.normal(0, 1, 2)
    local = _view(top, centre, heading)
    return rng, top, centre, local, _in_view(local)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), heading=st.floats(-np.pi, np.pi))
def test_pose_recovered_from_people_alone(seed: int, heading: float) -> None:
    rng, top, centre, local, seen = _crowd_seen(seed, heading)
    if seen.sum() < 4:
        return
    hor = local[seen] + rng.normal(0, 0.1, (int(seen.sum()), 2))
    poses, _ = gr.pose_hypotheses(top, hor, 70.0)
    best = poses[0]
    assert np.hypot(*(best[:2] - centre)) < 1.0
    assert abs(gr._wrap(best[2] - heading)) < np.radians(8.0)
    pairs = gr.associate_on_ground(top, hor, gr.FramePose(1, best[:2], float(best[2]), 0.0))
    assert sorted(map(tuple, pairs.tolist())) == [
        (int(i), k) for k, i in enumerate(np.flatnonzero(seen))]


def test_time_decides_an_ambiguous_frame() -> None:
    """Frame 2 alone prefers a pose far from its neighbours' (a mirror); the choice over time
    keeps the consistent one."""
    near, far = np.array([0.0, 0.0, 0.0]), np.array([20.0, 0.0, np.pi])
    frames = [1, 2, 3]
    cands = [(np.array([near, far]), np.array([5.0, 1.0])),
             (np.array([near, far]), np.array([4.0, 4.5])),
             (np.array([near, far]), np.array([5.0, 1.0]))]
    poses = gr.register_sequence(frames, cands, fps=10.0)
    assert [p.frame for p in poses] == frames
    assert all(np.allclose(p.centre, near[:2]) for p in poses)


def test_slack_lets_a_brisk_walk_pass_free() -> None:
    """A camera walking 1.6 m in a second: at the free 1 m/s it pays for the step and a pose
    that stays wins; with ``slack`` 2 (a rate read from the walkers) the walk is free and the
    better-explained pose moved to is kept. Twice the slack is half the rate, and a slack
    that is not positive is refused."""
    cands = [(np.array([[0.0, 0.0, 0.0]]), np.array([1.0])),
             (np.array([[1.6, 0.0, 0.0], [0.0, 0.0, 0.0]]), np.array([3.0, 2.0]))]

    def second(**kw) -> float:
        return float(gr.register_sequence([1, 2], cands, **kw)[1].centre[0])

    assert second(fps=1.0) == 0.0
    assert second(fps=1.0, slack=2.0) == 1.6
    assert second(fps=0.5) == 1.6
    with pytest.raises(ValueError, match="slack must be positive"):
        gr.register_sequence([1, 2], cands, fps=1.0, slack=0.0)


def test_the_pose_the_choice_holds_is_offered_through_frames_that_rank_it_out() -> None:
    """Frames 2 and 3 lost the true pose from their own hypotheses (people missed there: a
    wrong pose 20 m off explains more). Offered the poses leading the choice at the frame
    before and scored there (``rescore``), the choice keeps the true pose in every frame;
    without, the clip is cheaper wrong throughout than jumping there and back. Poses the
    callback drops are not offered."""
    true, wrong = np.array([0.0, 0.0, 0.0]), np.array([20.0, 0.0, np.pi])
    own = [(np.array([true, wrong]), np.array([3.0, 1.5]))] * 2 + \
        [(np.array([wrong]), np.array([1.5]))] * 2 + [(np.array([true, wrong]),
                                                       np.array([3.0, 1.5]))] * 2
    frames = list(range(6))

    def rescore(k: int, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return poses, np.where(np.hypot(*poses[:, :2].T) < 1.0, 0.5, 1.5)

    held = gr.register_sequence(frames, own, 10.0, rescore=rescore)
    assert all(np.allclose(p.centre, true[:2]) for p in held)
    assert [p.score for p in held] == [3.0, 3.0, 0.5, 0.5, 3.0, 3.0]
    lost = gr.register_sequence(frames, own, 10.0)
    assert all(np.allclose(p.centre, wrong[:2]) for p in lost)
    dropped = gr.register_sequence(frames, own, 10.0,
                                   rescore=lambda k, p: (p[:0], np.zeros(0)))
    assert all(np.allclose(p.centre, wrong[:2]) for p in dropped)


def test_the_missed_share_counts_the_gaps_within_each_track() -> None:
    """Per id, the frames between its first and its last in which it is missing, over all
    those frames: people who come and stay, or leave for good, miss nothing."""
    assert gr.missed_share([]) == 0.0
    assert gr.missed_share([np.array([1, 2]), np.array([2]), np.array([2, 3])]) == 0.0
    assert gr.missed_share([np.array([1, 2]), np.array([2]), np.array([1, 2])]) == \
        pytest.approx(1 / 6)
    assert gr.missed_share([np.array([7]), np.zeros(0, int), np.zeros(0, int),
                            np.array([7])]) == 0.5


def test_the_leading_poses_are_offered_in_video_mode_where_people_are_missed(
        registration_offers) -> None:
    """``register_scales`` offers each frame the poses leading at the one before only with the
    top view's tracks (video mode) and where they show at least :data:`MISSED_SHARE` of their
    people missed: the same boxes with every track whole, or frame by frame, are registered
    as before."""
    rng = np.random.default_rng(5)
    world = rng.uniform(-6, 6, (6, 2))
    local = _view(world, np.array([-12.0, 0.0]), 0.0)
    hor = local[_in_view(local)]
    tops = [world] * 10
    whole = [np.arange(6)] * 10
    gapped = [np.arange(6) if k % 2 else np.arange(3) for k in range(10)]  # 3-5 every other
    tops_gapped = [world if k % 2 else world[:3] for k in range(10)]
    assert gr.missed_share(gapped) >= gr.MISSED_SHARE > gr.missed_share(whole)
    for points, ids, offered in ((tops, None, False), (tops, whole, False),
                                 (tops_gapped, gapped, True)):
        registration_offers.clear()
        gr.register_scales(list(range(10)), points, [hor] * 10, 70.0, 10.0, ids)
        assert registration_offers and set(registration_offers) == {offered}


def test_frames_without_people_split_the_sequence() -> None:
    empty = (np.zeros((0, 3)), np.zeros(0))
    cands = [(np.array([[0.0, 0.0, 0.0]]), np.array([1.0])), empty,
             (np.array([[50.0, 0.0, 1.0]]), np.array([1.0]))]
    poses = gr.register_sequence([1, 2, 3], cands, fps=10.0)
    assert [p.frame for p in poses] == [1, 3]


def test_hor_ground_points_level_camera() -> None:
    # A 1.72 m person 10 m ahead on the optical axis of a 90 degree camera 1000 px wide.
    f = 500.0
    h = f * 1.72 / 10.0
    boxes = np.array([[500 - 10, 300, 20, h], [900 - 10, 300, 20, h]])
    q = gr.hor_ground_points(boxes, (1000, 600), 90.0)
    assert q[0] == pytest.approx([10.0, 0.0])
    assert q[1, 1] < 0  # right of the image is to the camera's right (negative y)
    # As tall in the image, as deep: 10 m ahead, 8 m to the right (400 px at f = 500).
    assert q[1] == pytest.approx([10.0, -8.0])


def test_a_passer_by_cut_by_the_bottom_edge_is_read_from_their_width() -> None:
    """A person 2.5 m from a level camera 1.6 m up, feet out of sight, only their upper 60 %
    in the image: read from their height as if whole they would be put at 4.2 m; read from
    their width (the view's own width over height, from its whole boxes) at 2.5 m."""
    f, size = 500.0, (1000, 600)
    ratio = 0.45 / 1.72
    whole = np.array([[400.0 + 30 * k, 280.0, f * 0.45 / d, f * 1.72 / d]
                      for k, d in enumerate(np.linspace(8.0, 20.0, 24))])
    assert gr.box_width_ratio([whole], size) == pytest.approx(ratio, abs=1e-3)
    assert gr.box_width_ratio([whole[:5]], size) == gr.WIDTH_RATIO  # too few to read
    w, h = f * 0.45 / 2.5, f * 1.72 / 2.5
    cut = np.array([[500.0 - w / 2, 600.0 - 0.6 * h, w, 0.6 * h]])
    q = gr.hor_ground_points(cut, size, 90.0, width_ratio=gr.box_width_ratio([whole], size))
    assert q[0] == pytest.approx([2.5, 0.0], abs=0.05)
    lifted = cut + np.array([0.0, -3.0, 0.0, 0.0])  # the same box inside the image: its height
    assert gr.hor_ground_points(lifted, size, 90.0)[0, 0] == pytest.approx(2.5 / 0.6, rel=1e-6)
    # Cut at a side too (narrow): no farther than where a level camera 1.72 m up sees feet.
    cornered = cut * np.array([1.0, 1.0, 0.2, 1.0])
    assert gr.hor_ground_points(cornered, size, 90.0)[0, 0] == pytest.approx(
        f * 1.72 / 300.0, rel=1e-6)


def test_a_handheld_looking_up_sees_no_feet_near_it() -> None:
    """A camera 1.6 m up looking 12 degrees up sees no feet nearer than about 8 m: a passer-by
    7 m off, cut by its bottom edge, is read from their width at 7 m where its horizon row is
    given, not capped where a level camera would see feet (4.9 m); looking down, the cap is
    nearer."""
    from xvmatch.geometry.people_model import pinhole

    size, f = (1920, 1080), 960.0 / np.tan(np.radians(35.0))
    cam = pinhole(f, np.radians(-12.0), 0.0, 1.6, size)
    (head, side), _ = cam.project(np.array([[7.0, 0.0, 1.72], [7.0, 0.225, 1.72]]))
    w = 2 * (head[0] - side[0])
    cut = np.array([[head[0] - w / 2, head[1], w, size[1] - head[1]]])
    ratio = 0.45 / 1.72
    horizon = 0.5 * size[1] - f * np.tan(np.radians(-12.0))
    level = gr.hor_ground_points(cut, size, 70.0, width_ratio=ratio)
    assert level[0, 0] == pytest.approx(f * 1.72 / 540.0)
    up = gr.hor_ground_points(cut, size, 70.0, width_ratio=ratio, horizon=horizon)
    assert up[0, 0] == pytest.approx(7.0, rel=0.03)
    down = gr.hor_ground_points(cut, size, 70.0, width_ratio=ratio, horizon=size[1] - horizon)
    assert down[0, 0] < 0.7 * level[0, 0]
    assert np.array_equal(gr.hor_ground_points(cut, size, 70.0, width_ratio=ratio,
                                               horizon=None), level)


def test_the_handheld_horizon_is_read_from_its_people() -> None:
    """Heads near the camera's height: the horizon row from a clip's people within 1.5
    degrees of the camera's pitch, for a renderer's handheld pitched 12 degrees up or down
    and one at chest height (1.3 m); too few people: None."""
    from xvmatch.datasets.oblique_scenes import ObliqueSceneConfig, make_oblique_scene
    from xvmatch.geometry.people_model import handheld_horizon

    for pitch, height in ((12.0, (1.4, 1.7)), (-12.0, (1.4, 1.7)), (4.0, (1.3, 1.3))):
        config = ObliqueSceneConfig(top_pitch=(30.0, 40.0), hor_pitch=(pitch, pitch),
                                    hor_height=height)
        scene = make_oblique_scene(config, 90, np.random.default_rng(3))
        cam = scene.hor_cameras["hor1"][0]
        frames = sorted(scene.hor["hor1"])
        boxes = [scene.hor["hor1"][k].boxes for k in frames]
        row = gr.hor_horizon(boxes, cam.image_size)
        read = np.degrees(np.arctan((0.5 * cam.height - row) / cam.K[0, 0]))
        assert read == pytest.approx(pitch, abs=1.5)
        index = np.repeat(frames, [len(b) for b in boxes])
        assert handheld_horizon(index[:10], np.concatenate(boxes)[:10], cam.image_size) is None


def test_a_handheld_reading_is_read_once_for_every_lens() -> None:
    """A view's reading holds its people's width ratio and horizon (as the two functions read
    them) and maps any frame at any lens as :func:`hor_ground_points` given both."""
    from xvmatch.datasets.oblique_scenes import ObliqueSceneConfig, make_oblique_scene

    config = ObliqueSceneConfig(top_pitch=(30.0, 40.0), hor_pitch=(-10.0, -10.0),
                                edge_people=(2, 2))
    scene = make_oblique_scene(config, 60, np.random.default_rng(5))
    size = scene.hor_cameras["hor1"][0].image_size
    boxes = [scene.hor["hor1"][k].boxes for k in sorted(scene.hor["hor1"])]
    reading = gr.HandheldReading.of(boxes, size)
    assert reading.image_size == size
    assert reading.width_ratio == gr.box_width_ratio(boxes, size)
    assert reading.horizon is not None and reading.horizon == gr.hor_horizon(boxes, size)
    for hfov in (60.0, 95.0):
        for frame in boxes:
            assert np.array_equal(reading.points(frame, hfov), gr.hor_ground_points(
                frame, size, hfov, width_ratio=reading.width_ratio, horizon=reading.horizon))
    assert gr.HandheldReading(size).points(boxes[0], 70.0).shape == (len(boxes[0]), 2)


def test_no_people_no_hypotheses() -> None:
    poses, scores = gr.pose_hypotheses(np.zeros((0, 2)), np.ones((2, 2)), 70.0)
    assert poses.shape == (0, 3) and scores.shape == (0,)
    assert gr.associate_on_ground(np.ones((2, 2)), np.zeros((0, 2)),
                                  gr.FramePose(1, np.zeros(2), 0.0, 0.0)).shape == (0, 2)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), angle=st.floats(-np.pi, np.pi),
       shift=st.tuples(st.floats(-30, 30), st.floats(-30, 30)))
def test_map_motion_recovers_how_the_top_map_moved(seed: int, angle: float,
                                                    shift: tuple[float, float]) -> None:
    """People standing still while the top map moves rigidly (a drifting, turning drone), seen
    under other row orders in the two frames, one of them walking 3 m away: the motion taking
    the second frame's map onto the first's is recovered."""
    rng = np.random.default_rng(seed)
    before = rng.uniform(-15, 15, (7, 2))
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s], [s, c]])
    walked = before.copy()
    walked[0] += [3.0, 0.0]
    now = (walked - np.asarray(shift)) @ rot  # before = rot @ now + shift for those standing
    order = rng.permutation(7)
    ids_before, ids_now = np.arange(7) + 10, (np.arange(7) + 10)[order]
    motion = gr.map_motion([1, 2], [before, now[order]], [ids_before, ids_now], 10.0)
    assert motion[0] is None
    assert motion[1][:2] == pytest.approx(np.asarray(shift), abs=1e-6)
    assert abs(gr._wrap(motion[1][2] - angle)) < 1e-6


def test_map_motion_needs_three_people_seen_twice() -> None:
    pts = np.array([[0.0, 0.0], [5.0, 0.0], [0.0, 5.0]])
    motion = gr.map_motion([1, 2, 3], [pts, pts + 1, pts],
                           [np.array([1, 2, 3]), np.array([1, 2, 9]), np.array([1, 2, 9])], 10.0)
    assert motion[1] is None
    assert motion[2] == pytest.approx([1.0, 1.0, 0.0])  # frame 2's map onto frame 1's


def test_map_motion_is_the_steady_rate_around_each_step() -> None:
    """A drone drifting 0.2 m a step, and on one step the crowd walking 0.6 m together: each
    step is given the mean rate of the steps within the window (all of them here), and a step
    twice as long twice the motion."""
    pts = np.array([[0.0, 0.0], [6.0, 1.0], [2.0, 7.0], [-4.0, 3.0]])
    frames = [1, 2, 3, 4, 5, 6, 8]
    shifts = [0.2, 0.2, 0.8, 0.2, 0.2, 0.4]  # frame k's map onto k-1's; the last step is 2 frames
    tops = [pts]
    for d in shifts:
        tops.append(tops[-1] - [d, 0.0])
    motion = gr.map_motion(frames, tops, [np.arange(4)] * len(frames), 10.0)
    steady = 2.0 / 7  # the mean rate per frame: 2 m over 7 frames' time
    assert motion[0] is None
    for k in range(1, 6):
        assert motion[k] == pytest.approx([steady, 0.0, 0.0])
    assert motion[6] == pytest.approx([2 * steady, 0.0, 0.0])


def test_the_top_maps_motion_is_taken_out_of_the_jumps() -> None:
    """The top map turns by 40 degrees between two frames (a drone turning): the camera's true
    pose moves on the map, a decoy stays put. Without the map's motion the decoy is the smooth
    choice; with it the true pose is."""
    true1 = np.array([10.0, 0.0, 0.5])
    motion = np.array([2.0, -1.0, np.radians(40.0)])
    c, s = np.cos(motion[2]), np.sin(motion[2])
    rot = np.array([[c, -s], [s, c]])
    true2 = np.array([*(rot.T @ (true1[:2] - motion[:2])), true1[2] - motion[2]])
    cands = [(np.array([true1]), np.array([5.0])),
             (np.array([true2, true1]), np.array([4.0, 4.5]))]
    still = gr.register_sequence([1, 2], cands, fps=10.0)
    moved = gr.register_sequence([1, 2], cands, fps=10.0, motions=[None, motion])
    assert np.allclose(still[1].centre, true1[:2])
    assert np.allclose(moved[1].centre, true2[:2]) and moved[1].heading == pytest.approx(true2[2])


def test_a_far_person_pairs_along_their_ray_not_across_it() -> None:
    """A distance from a box height errs along the camera's ray: 30 m away, a person mapped
    2.5 m short of their top-view partner still pairs, one 2.5 m to the side does not; near
    the camera the round :data:`RADIUS` holds both ways."""
    pose = gr.FramePose(1, np.array([0.0, 0.0]), 0.0, 0.0)  # at the origin, looking along +x
    top = np.array([[30.0, 0.0]])
    assert gr.associate_on_ground(top, np.array([[27.5, 0.0]]), pose).tolist() == [[0, 0]]
    assert gr.associate_on_ground(top, np.array([[30.0, 2.5]]), pose).tolist() == []
    near = np.array([[5.0, 0.0]])
    assert gr.associate_on_ground(near, np.array([[3.6, 0.0]]), pose).tolist() == [[0, 0]]
    assert gr.associate_on_ground(near, np.array([[3.4, 0.0]]), pose).tolist() == []
    assert gr.associate_on_ground(near, np.array([[5.0, 1.6]]), pose).tolist() == []
    # Two people along one ray: each goes to the partner nearest along it.
    tops = np.array([[20.0, 0.0], [24.0, 0.3]])
    hors = np.array([[22.9, 0.2], [19.5, 0.1]])
    assert sorted(gr.associate_on_ground(tops, hors, pose).tolist()) == [[0, 1], [1, 0]]


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), angle=st.floats(-np.pi, np.pi))
def test_ray_distances_shrink_only_along_far_rays(seed: int, angle: float) -> None:
    """Never more than the plain distance; the plain one within 7.5 m of the camera (the
    spread's floor) and across a ray; unchanged by turning and moving the whole map."""
    rng = np.random.default_rng(seed)
    top, camera = rng.uniform(-40, 40, (5, 2)), rng.uniform(-40, 40, 2)
    mapped = rng.uniform(-40, 40, (4, 2))
    rays = mapped - camera
    d = gr.ray_distances(top, mapped, rays)
    plain = np.hypot(*(top[:, None, :] - mapped[None]).transpose(2, 0, 1))
    assert d.shape == (5, 4) and (d <= plain + 1e-9).all()
    near = np.hypot(*rays.T) <= 0.5 * gr.RADIUS / gr.RANGE_SPREAD
    np.testing.assert_allclose(d[:, near], plain[:, near], atol=1e-9)
    across = mapped + 3.0 * np.column_stack([-rays[:, 1], rays[:, 0]]) / np.hypot(*rays.T)[:, None]
    np.testing.assert_allclose(np.diag(gr.ray_distances(across, mapped, rays)), 3.0, atol=1e-9)
    turn = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    shift = rng.uniform(-5, 5, 2)
    moved = gr.ray_distances(top @ turn.T + shift, mapped @ turn.T + shift, rays @ turn.T)
    np.testing.assert_allclose(moved, d, atol=1e-8)
    still = gr.ray_distances(top, mapped, np.zeros_like(rays))  # at the camera: plain
    np.testing.assert_allclose(still, plain, atol=1e-9)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), step=st.integers(0, 71))
def test_people_read_at_their_partners_height_land_on_them(seed: int, step: int) -> None:
    """Far people 1.5-1.95 m tall, their distances read as if 1.72 m: read at their top-view
    partner's height (``sizes``) the true pose (a heading the hypotheses try, every 5 degrees)
    explains every one of them exactly and wins; with all sizes 1 the hypotheses are those
    without sizes, bit for bit."""
    heading = np.radians(5.0 * step)
    rng = np.random.default_rng(seed)
    top = rng.uniform(-6, 6, (7, 2))
    heights = rng.uniform(1.5, 1.95, len(top))
    centre = -25.0 * np.array([np.cos(heading), np.sin(heading)])
    local = _view(top, centre, heading)
    seen = _in_view(local)
    if seen.sum() < 3:
        return
    sizes = heights / 1.72
    hor = local[seen] / sizes[seen, None]  # each distance read through 1.72 m
    poses, scores = gr.pose_hypotheses(top, hor, 70.0, sizes)
    assert np.hypot(*(poses[0][:2] - centre)) < 1e-6
    assert abs(gr._wrap(poses[0][2] - heading)) < 1e-6
    assert scores[0] == pytest.approx(seen.sum())
    pose = gr.FramePose(1, poses[0][:2], float(poses[0][2]), 0.0)
    pairs = gr.associate_on_ground(top, hor, pose, sizes)
    assert sorted(map(tuple, pairs.tolist())) == [
        (int(i), k) for k, i in enumerate(np.flatnonzero(seen))]
    for a, b in zip(gr.pose_hypotheses(top, hor, 70.0, np.ones(len(top))),
                    gr.pose_hypotheses(top, hor, 70.0), strict=True):
        assert np.array_equal(a, b)


def _plain_score(top: np.ndarray, hor: np.ndarray, sizes: np.ndarray, pose: np.ndarray,
                 hfov: float, sight: tuple | None = None) -> float:
    """One pose's score as the module docstring defines it, person by person: each horizontal
    person explained by their nearest top person (read at that person's height), less 0.3 for
    each top person in the camera's view within its people's reach whom nobody is near (within
    the radius, nor a tenth of their distance from the camera) and no nearer horizontal person
    hides (their bearing within half a body's width of theirs); with
    ``sight`` (the top camera, its reach), less 0.3 for each horizontal person nobody explains
    standing where the top camera would see them (projected inside its image, 3 % off its
    borders, within the reach of the map's origin)."""
    c, s = np.cos(pose[2]), np.sin(pose[2])
    turned = hor @ np.array([[c, -s], [s, c]]).T
    near = np.array([[np.hypot(*(pose[:2] + size * t - p))
                      for p, size in zip(top, sizes, strict=True)] for t in turned])  # (M, N)
    explained = float(np.exp(-0.5 * (near.min(axis=1) / (0.5 * gr.RADIUS)) ** 2).sum())
    local = _view(top, pose[:2], pose[2])
    reach = 1.2 * np.hypot(hor[:, 0], hor[:, 1]).max()
    in_view = ((local[:, 0] > 0.5) & (np.abs(np.arctan2(local[:, 1], local[:, 0]))
                                      < np.radians(hfov) / 2)
               & (np.hypot(local[:, 0], local[:, 1]) < reach))
    lone = 0
    if sight is not None:
        camera, reach_top = sight
        for t, d in zip(turned, near.min(axis=1), strict=True):
            at = pose[:2] + t
            uv, depth = camera.project(np.array([at[0], at[1], 0.0]))
            inside = (depth > 0 and 0.03 * camera.width < uv[0] < 0.97 * camera.width
                      and 0.03 * camera.height < uv[1] < 0.97 * camera.height)
            lone += int(d > gr.RADIUS and inside and np.hypot(*at) < reach_top)
    far = np.maximum(gr.RADIUS, gr.RANGE_SPREAD * np.hypot(local[:, 0], local[:, 1]))
    hidden = np.array([any(h[0] < ahead and abs(across / ahead - h[1] / h[0])
                           < 0.5 * BODY_WIDTH / h[0] for h in hor) for ahead, across in local])
    return explained - 0.3 * float((in_view & ~hidden & (near.min(axis=0) > far)).sum() + lone)


def _top_camera(tilt_deg: float = 35.0, height: float = 8.0):
    """An oblique top camera above the map's origin looking along +x, 1920x1080, 70 degrees."""
    from xvmatch.geometry.people_model import pinhole

    return pinhole(960.0 / np.tan(np.radians(35.0)), np.radians(tilt_deg), 0.0, height,
                   (1920, 1080))


def _small_frame(rng: np.random.Generator, n: int, m: int, with_sight: bool) -> tuple:
    """``n`` top people, ``m`` horizontal ones ahead, their sizes, and the top camera's sight
    (as ``_plain_score`` takes it, and as a :class:`TopSight`) or None."""
    top = rng.uniform(-8, 8, (n, 2))
    hor = np.column_stack([rng.uniform(2, 15, m), rng.uniform(-4, 4, m)])
    sizes = rng.uniform(0.9, 1.1, n)
    plain_sight = (_top_camera(), 14.0) if with_sight else None
    sight = gr.TopSight.of(*plain_sight) if with_sight else None
    return top, hor, sizes, plain_sight, sight


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 4), m=st.integers(1, 3),
       hfov=st.floats(40.0, 120.0), with_sight=st.booleans())
def test_hypotheses_are_the_best_distinct_poses_scored_as_defined(seed: int, n: int, m: int,
                                                                  hfov: float,
                                                                  with_sight: bool) -> None:
    """Against every candidate pose (a heading every 5 degrees, each horizontal person on each
    top person) scored person by person: the kept poses' scores are theirs, best first, each
    1 m or 10 degrees from the others, and no candidate scoring above the last kept (any, where
    fewer than :data:`KEEP` are) is apart from all of them; with the top camera's sight too."""
    rng = np.random.default_rng(seed)
    top, hor, sizes, plain_sight, sight = _small_frame(rng, n, m, with_sight)
    poses, scores = gr.pose_hypotheses(top, hor, hfov, sizes, sight)
    plain = [_plain_score(top, hor, sizes, p, hfov, plain_sight) for p in poses]
    np.testing.assert_allclose(scores, plain, atol=2e-9)
    assert len(poses) <= gr.KEEP and np.all(np.diff(scores) <= 0)

    def apart(a: np.ndarray, b: np.ndarray, slack: float) -> bool:  # within rounding
        return bool(np.hypot(*(a[:2] - b[:2])) > 1.0 + slack
                    or abs(gr._wrap(a[2] - b[2])) > np.radians(10.0) + slack)

    assert all(apart(a, b, -1e-9) for k, a in enumerate(poses) for b in poses[:k])
    for h in np.arange(72) * (2 * np.pi / 72):
        turned = hor @ np.array([[np.cos(h), -np.sin(h)], [np.sin(h), np.cos(h)]]).T
        for p, size in zip(top, sizes, strict=True):
            for t in turned:
                pose = np.array([*(p - size * t), h])
                if (len(poses) < gr.KEEP
                        or _plain_score(top, hor, sizes, pose, hfov, plain_sight)
                        > scores[-1] + 1e-6):
                    assert not all(apart(pose, q, 1e-9) for q in poses)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 14), m=st.integers(1, 13),
       hfov=st.floats(40.0, 170.0), with_sight=st.booleans(), with_sizes=st.booleans())
def test_the_compiled_pose_terms_are_numpys_bit_for_bit(seed: int, n: int, m: int, hfov: float,
                                                         with_sight: bool,
                                                         with_sizes: bool) -> None:
    """The numba kernel of the pose terms and their numpy form give the same poses and scores,
    bit for bit (the same arithmetic and comparisons), with and without sizes and the sight."""
    rng = np.random.default_rng(seed)
    top = rng.uniform(-15, 15, (n, 2))
    hor = np.column_stack([rng.uniform(1, 25, m), rng.uniform(-8, 8, m)])
    sizes = rng.uniform(0.9, 1.1, n) if with_sizes else None
    sight = gr.TopSight.of(_top_camera(), 14.0) if with_sight else None
    with kernel_choice.forced("compiled"):
        compiled = gr.pose_hypotheses(top, hor, hfov, sizes, sight)
    with kernel_choice.forced("numpy"):
        plain = gr.pose_hypotheses(top, hor, hfov, sizes, sight)
    assert np.array_equal(compiled[0], plain[0]) and np.array_equal(compiled[1], plain[1])


def test_ray_distances_read_at_the_top_persons_height() -> None:
    """A person 1.9 m tall, 20 m away, read as 1.72 m: mapped 20 * 1.72 / 1.9 m away, at
    their size of 1.9 / 1.72 they are where their partner stands; the size only moves along
    the ray."""
    top = np.array([[20.0, 0.0], [20.0, 3.0]])
    mapped = np.array([[20.0 * 1.72 / 1.9, 0.0]])
    sizes = np.array([1.9 / 1.72, 1.0])
    d = gr.ray_distances(top, mapped, mapped, sizes)
    assert d[0, 0] == pytest.approx(0.0, abs=1e-12)
    assert d[1, 0] == pytest.approx(gr.ray_distances(top[1:], mapped, mapped)[0, 0])


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), tilt=st.floats(15.0, 85.0), height=st.floats(3.0, 60.0),
       scale=st.sampled_from(gr.MAP_SCALES))
def test_the_top_cameras_sight_is_its_image_within_its_reach(seed: int, tilt: float,
                                                            height: float, scale: float) -> None:
    """A point is in sight where it projects inside the top image, 3 % off its borders, within
    the reach; on the map multiplied by a scale, its point multiplied by it is."""
    camera = _top_camera(tilt, height)
    points = np.random.default_rng(seed).uniform(-20, 80, (400, 2))
    reach = 60.0
    uv, depth = camera.project(np.column_stack([points, np.zeros(len(points))]))
    want = ((depth > 0) & (uv[:, 0] > 0.03 * 1920) & (uv[:, 0] < 0.97 * 1920)
            & (uv[:, 1] > 0.03 * 1080) & (uv[:, 1] < 0.97 * 1080)
            & (np.hypot(points[:, 0], points[:, 1]) < reach))
    sight = gr.TopSight.of(camera, reach)
    assert np.array_equal(sight.sees(points), want)
    assert np.array_equal(sight.scaled(scale).sees(scale * points), want)


def test_where_a_pose_puts_the_people_the_top_view_misses_tells_a_swap() -> None:
    """Two people seen by both views and a third only by the handheld camera: the pose with
    the two swapped (a half turn about their midpoint) explains as many, and ties with the
    right one; it puts the third where the top camera would see them, the right one does not,
    so with the top camera's sight the right pose comes first."""
    both = np.array([[15.0, -2.0], [15.0, 2.0]])
    third = np.array([[11.0, -10.0]])  # beside the top camera's view: only the handheld's
    centre, heading = np.array([14.0, -16.0]), np.pi / 2
    hor = _view(np.vstack([both, third]), centre, heading)
    assert _in_view(hor).all()
    sight = gr.TopSight.of(_top_camera(), 30.0)
    assert not sight.sees(third).any() and sight.sees(2 * both.mean(axis=0) - third).all()
    swapped = np.array([*(2 * both.mean(axis=0) - centre), heading - np.pi])
    poses, scores = gr.pose_hypotheses(both, hor, 70.0)
    assert scores[0] == scores[1]
    assert {int(np.hypot(*(p[:2] - centre)) < 0.5) + 2 * int(
        np.hypot(*(p[:2] - swapped[:2])) < 0.5) for p in poses[:2]} == {1, 2}
    poses, scores = gr.pose_hypotheses(both, hor, 70.0, sight=sight)
    assert np.hypot(*(poses[0][:2] - centre)) < 0.5
    assert abs(gr._wrap(poses[0][2] - heading)) < np.radians(3.0)
    at_swap = [s for p, s in zip(poses, scores, strict=True)
               if np.hypot(*(p[:2] - swapped[:2])) < 0.5]
    assert len(at_swap) == 1 and scores[0] - at_swap[0] == pytest.approx(0.3, abs=1e-6)


@pytest.mark.parametrize("kernels", ["compiled", "numpy"])
def test_a_far_top_person_is_charged_only_beyond_the_spread_of_their_distance(
        kernels: str) -> None:
    """A top person in the handheld camera's view costs a pose :data:`_UNSEEN_WEIGHT` where no
    handheld person lands near: within the radius, or, farther off, within
    :data:`RANGE_SPREAD` of their distance (30 m: 3 m), as a distance read from a box errs."""
    pose = np.array([[0.0, 0.0, 0.0]])
    reach = [40.0, 20.0]  # a handheld person far aside, explaining nobody: the view's reach

    def cost(top_x: float, hor_x: float) -> float:
        # the handheld person 1 m aside: not in front of the top person (who is not hidden)
        top, hor = np.array([[top_x, 0.0]]), np.array([[hor_x, 1.0], reach])
        with kernel_choice.forced(kernels):
            score = gr.score_poses(pose, top, hor, 70.0)[0]
        explained = np.exp(-0.5 * (np.hypot(top_x - hor_x, 1.0) / (0.5 * gr.RADIUS)) ** 2)
        return round(float(explained - score), 6)

    assert cost(30.0, 27.5) == 0.0  # 2.7 m off at 30 m: within a tenth of it
    assert cost(30.0, 32.5) == 0.0
    assert cost(30.0, 26.5) == gr._UNSEEN_WEIGHT  # 3.6 m off: beyond it
    assert cost(8.0, 6.0) == gr._UNSEEN_WEIGHT  # 2.2 m off at 8 m: beyond the radius
    assert cost(8.0, 7.2) == 0.0


@pytest.mark.parametrize("kernels", ["compiled", "numpy"])
def test_a_top_person_behind_a_nearer_handheld_person_is_hidden_not_missed(
        kernels: str) -> None:
    """A top person whose bearing from the camera lies within half a body's width of a nearer
    handheld person's (:func:`shade`) may be hidden behind them: not charged as missed; beside
    them, charged; under a nadir top view (``spread`` 0) charged either way."""
    pose = np.array([[0.0, 0.0, 0.0]])
    hor = np.array([[4.0, 0.0], [20.0, 6.0]])  # one near, straight ahead; one far aside

    def cost(top_y: float, spread: float = gr.RANGE_SPREAD) -> float:
        top = np.array([[12.0, top_y]])  # 12 m ahead, nobody mapped near
        with kernel_choice.forced(kernels):
            score = gr.score_poses(pose, top, hor, 70.0, spread=spread)[0]
        mapped = hor - top[0]
        explained = np.exp(-0.5 * (np.hypot(*mapped.T) / (0.5 * gr.RADIUS)) ** 2).sum()
        return round(float(explained - score), 6)

    half = 0.5 * BODY_WIDTH / 4.0  # the near person's half span, as a bearing's tangent
    assert cost(12.0 * 0.9 * half) == 0.0  # behind them
    assert cost(12.0 * 1.1 * half) == gr._UNSEEN_WEIGHT  # beside them
    assert cost(12.0 * 0.9 * half, spread=0.0) == gr._UNSEEN_WEIGHT


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 3000), count=st.integers(1, 3000),
       levels=st.integers(1, 50))
def test_the_best_first_prefix_is_the_stable_sorts(seed: int, n: int, count: int,
                                                   levels: int) -> None:
    """The pose hypotheses' leading candidates, partitioned then sorted, are exactly the
    stable sort's first ``count`` (ties in index order, many ties where few score levels)."""
    score = np.random.default_rng(seed).integers(0, levels, n) / 7.0
    want = np.argsort(-score, kind="stable")[:count]
    np.testing.assert_array_equal(gr._best_first(score, count), want)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 6), m=st.integers(1, 4),
       hfov=st.floats(40.0, 120.0), with_sight=st.booleans())
def test_any_pose_is_scored_as_the_hypotheses_are(seed: int, n: int, m: int, hfov: float,
                                                  with_sight: bool) -> None:
    """A pose off the hypotheses' grid (another frame's, carried) is scored as the module
    docstring defines it; the hypotheses' own poses rescored keep their scores bit for bit."""
    rng = np.random.default_rng(seed)
    top, hor, sizes, plain_sight, sight = _small_frame(rng, n, m, with_sight)
    poses = np.column_stack([rng.uniform(-20, 20, (5, 2)), rng.uniform(-7, 7, 5)])
    np.testing.assert_allclose(gr.score_poses(poses, top, hor, hfov, sizes, sight),
                               [_plain_score(top, hor, sizes, p, hfov, plain_sight)
                                for p in poses], atol=2e-9)
    own, scores = gr.pose_hypotheses(top, hor, hfov, sizes, sight)
    assert np.array_equal(gr.score_poses(own, top, hor, hfov, sizes, sight), scores)


def test_a_pose_a_frame_dropped_is_carried_in_from_its_neighbours() -> None:
    """A drifting, turning top map; the handheld camera stands still. Frame 1 lost the true
    pose from its hypotheses (a near-duplicate kept in its place): its neighbours' carry it in
    on frame 1's map, scored there, and the choice over time keeps it in all three frames."""
    rng = np.random.default_rng(3)
    world = rng.uniform(-6, 6, (7, 2))
    pose = np.array([-14.0, 1.0, np.radians(10.0)])  # on the 5-degree grid in frame 0
    local = _view(world, pose[:2], pose[2])
    hor = local[_in_view(local)]
    assert len(hor) >= 3

    def on_map(k: int, xy: np.ndarray) -> np.ndarray:  # frame k's map: the world moved
        a, t = 0.04 * k, np.array([0.3, -0.2]) * k
        return xy @ gr._rotations(np.array([a]))[0].T + t

    tops = [on_map(k, world) for k in range(3)]
    truth = [np.array([*on_map(k, pose[None, :2])[0], pose[2] + 0.04 * k]) for k in range(3)]
    # Frame k's map onto frame k-1's, R(angle) x + t: R(-0.04) x + t (k-1) - R(-0.04) t k.
    back, step = gr._rotations(np.array([-0.04]))[0], np.array([0.3, -0.2])
    motions = [None] + [np.array([*(step * (k - 1) - back @ (step * k)), -0.04])
                        for k in (1, 2)]
    for k in (1, 2):  # the motion takes frame k's people onto frame k-1's
        np.testing.assert_allclose(gr._moved(np.column_stack([tops[k], np.zeros(7)]),
                                             motions[k])[:, :2], tops[k - 1], atol=1e-9)
    cands = [gr.pose_hypotheses(t, hor, 70.0) for t in tops]
    for k in (0, 2):
        assert np.hypot(*(cands[k][0][0, :2] - truth[k][:2])) < 0.5
    poses, scores = cands[1]
    lost = np.hypot(*(poses[:, :2] - truth[1][:2]).T) > 2.0
    cands[1] = (poses[lost], scores[lost])
    offered = gr.carried(cands, tops, [hor] * 3, 70.0, [None] * 3, [None] * 3, motions)
    assert np.array_equal(offered[1][0][:lost.sum()], cands[1][0])  # its own, first
    near = np.hypot(*(offered[1][0][:, :2] - truth[1][:2]).T) < 1e-6
    assert near.any()
    assert offered[1][1][near][0] == gr.score_poses(truth[1][None], tops[1], hor, 70.0)[0]
    chosen = gr.register_sequence([0, 1, 2], offered, 3.0, motions)
    assert all(np.hypot(*(p.centre - t[:2])) < 0.5 for p, t in zip(chosen, truth, strict=True))
    without = gr.register_sequence([0, 1, 2], cands, 3.0, motions)
    assert np.hypot(*(without[1].centre - truth[1][:2])) > 2.0


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(0, 300), limit=st.integers(1, 40),
       spread=st.sampled_from([0.5, 3.0, 20.0]))
def test_the_compiled_distinct_poses_are_numpys(seed: int, n: int, limit: int,
                                                spread: float) -> None:
    """The numba kernel of the greedy choice of distinct poses keeps numpy's (its blocks, its
    wrapped headings, headings past a full turn and exactly 1 m apart included), in order."""
    rng = np.random.default_rng(seed)
    poses = np.column_stack([rng.uniform(-spread, spread, (n, 2)),
                             rng.uniform(-3 * np.pi, 3 * np.pi, n)])
    if n > 1:  # an exact tie of distance and of heading
        poses[1] = poses[0] + np.array([1.0, 0.0, 2 * np.pi + np.radians(10.0)])
    order = rng.permutation(n)
    with kernel_choice.forced("compiled"):
        compiled = gr._distinct(poses, order, block=64, limit=limit)
    with kernel_choice.forced("numpy"):
        plain = gr._distinct(poses, order, block=64, limit=limit)
    assert compiled == plain and len(plain) <= limit
    kept = poses[plain]
    apart = gr._apart(kept, kept)
    assert apart[~np.eye(len(kept), dtype=bool)].all()


def test_registered_with_and_without_the_sights_at_once_as_one_by_one() -> None:
    """``register_scales_twice`` gives the runs two calls of ``register_scales`` give, with
    the top camera's sights and without, bit for bit (the pose terms computed once)."""
    rng = np.random.default_rng(4)
    world = rng.uniform(-6, 6, (6, 2))
    frames = list(range(5))
    tops = [world + 0.1 * k for k in frames]
    hor = _view(world, np.array([-12.0, 0.5]), 0.1)
    hor = hor[_in_view(hor)]
    sight = gr.TopSight.of(_top_camera(), 14.0)
    args = (frames, tops, [hor + rng.normal(0, 0.05, hor.shape) for _ in frames], 70.0, 3.0,
            [np.arange(6)] * 5, [rng.uniform(0.9, 1.1, 6) for _ in frames])
    made, plain = gr.register_scales_twice(*args, [sight] * 5)
    for twice, once in ((made, gr.register_scales(*args, [sight] * 5)),
                        (plain, gr.register_scales(*args, None))):
        assert twice.keys() == once.keys()
        for scale in once:
            assert twice[scale][0] == once[scale][0]
            assert [(p.frame, p.centre.tolist(), p.heading, p.score) for p in twice[scale][1]] \
                == [(p.frame, p.centre.tolist(), p.heading, p.score) for p in once[scale][1]]
    # the sight weighs here: some scale's total differs with it
    assert any(made[s][0] != plain[s][0] for s in made)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), heading=st.floats(-np.pi, np.pi))
def test_a_camera_standing_where_its_holder_is_seen_is_found_by_its_heading(
        seed: int, heading: float) -> None:
    """Told where the camera stands (``--camera-id``): the poses standing there, one heading
    per pair of people, the true one among them; every hypothesis within
    :data:`HOLDER_RADIUS` of there, the best the true pose; and a registration over frames
    keeps the camera near each frame's holder (scaled with the map), free where not told."""
    _, top, centre, local, seen = _crowd_seen(seed, heading)
    if seen.sum() < 3:
        return
    hor = local[seen]
    poses = gr.anchored_poses(top, hor, centre)
    assert poses.shape == (len(top) * len(hor), 3)
    assert np.array_equal(poses[:, :2], np.tile(centre, (len(poses), 1)))
    assert ((poses[:, 2] >= 0) & (poses[:, 2] <= 2 * np.pi)).all()
    assert np.abs(gr._wrap(poses[:, 2] - heading)).min() < 1e-6
    (best, scores), = gr._hypotheses(top, hor, 70.0, None, None, False, at=centre)
    assert (np.hypot(*(best[:, :2] - centre).T) <= gr.HOLDER_RADIUS).all()
    assert np.allclose(best[0, :2], centre) and abs(gr._wrap(best[0, 2] - heading)) < 1e-6
    assert np.array_equal(scores, gr.score_poses(best, top, hor, 70.0))  # scored as any pose
    far = centre + np.array([3 * gr.HOLDER_RADIUS, 0.0])  # told wrong: nothing near the truth
    (wrong, _), = gr._hypotheses(top, hor, 70.0, None, None, False, at=far)
    assert (np.hypot(*(wrong[:, :2] - far).T) <= gr.HOLDER_RADIUS).all()
    holders = [centre, None, far]
    scale, run = gr.register_with_scale([1, 2, 3], [top] * 3, [hor] * 3, 70.0, 10.0,
                                        holders=holders)
    assert np.hypot(*(run[0].centre - scale * centre)) <= gr.HOLDER_RADIUS + 1e-9
    assert np.hypot(*(run[2].centre - scale * far)) <= gr.HOLDER_RADIUS + 1e-9
