"""Tests of the oblique box-level scenes of issue 67 (xvmatch.datasets.oblique_scenes)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from xvmatch.datasets.oblique_scenes import (
    ObliqueSceneConfig,
    distorted,
    make_oblique_scene,
    pitch_drifted,
    project_view,
    sloped,
    top_distorted,
    top_rolled,
    write_oblique_scene,
)
from xvmatch.formats.camera_frames import open_cameras
from xvmatch.formats.mot_boxes import read_mot_boxes
from xvmatch.geometry.camera import Camera, intrinsics_from_fov, look_rotation, same_camera

CONFIG = ObliqueSceneConfig()
NADIR = ObliqueSceneConfig(top_pitch=(90.0, 90.0), top_height=(30.0, 40.0))
OBLIQUE = ObliqueSceneConfig(top_pitch=(25.0, 35.0), top_height=(8.0, 20.0))


def _scene(config: ObliqueSceneConfig, seed: int, n_frames: int = 30):
    return make_oblique_scene(config, n_frames, np.random.default_rng(seed))


@pytest.fixture(scope="module")
def clips():
    """Three 10 s clips (100 frames at 10 fps) whose groups were all placed."""
    return [_scene(CONFIG, seed, 100) for seed in (0, 6, 9)]


@pytest.fixture(scope="module")
def two_hor():
    return _scene(ObliqueSceneConfig(n_hor=2, top_drift_speed=(0.2, 0.4),
                                     top_yaw_rate=(0.5, 1.0)), 4, 40)


def _views(scene):
    """(records, cameras) of every view, top first."""
    out = [(scene.top, scene.top_cameras)]
    out += [(scene.hor[name], scene.hor_cameras[name]) for name in scene.hor]
    return out


def test_same_seed_same_scene_bit_for_bit():
    a, b = _scene(CONFIG, 11), _scene(CONFIG, 11)
    c = _scene(CONFIG, 12)
    assert a.overlap == b.overlap and a.overlap_target == b.overlap_target
    np.testing.assert_array_equal(a.people.positions, b.people.positions)
    for (ra, ca), (rb, cb) in zip(_views(a), _views(b), strict=True):
        assert sorted(ra) == sorted(rb)
        for f in ra:
            np.testing.assert_array_equal(ra[f].ids, rb[f].ids)
            np.testing.assert_array_equal(ra[f].boxes, rb[f].boxes)
        assert all(np.array_equal(x.R, y.R) and np.array_equal(x.c, y.c)
                   for x, y in zip(ca, cb, strict=True))
    assert not np.array_equal(a.people.positions[0, :3], c.people.positions[0, :3])


def test_layout_names_and_holders(two_hor):
    scene = two_hor
    assert list(scene.hor) == ["hor1", "hor2"] and list(scene.hor_cameras) == ["hor1", "hor2"]
    assert len(scene.top_cameras) == scene.n_frames == 40
    assert all(len(c) == 40 for c in scene.hor_cameras.values())
    assert sorted(scene.top) == list(range(1, 41))
    np.testing.assert_array_equal(scene.people.ids, np.arange(scene.people.n_people))
    np.testing.assert_array_equal(scene.groups["holders"], [0, 1])
    for k, name in enumerate(scene.hor):  # a holder is never in their own view
        assert all(k not in rec.ids for rec in scene.hor[name].values())
        cams = scene.hor_cameras[name]
        assert 1.35 <= cams[0].c[2] <= 1.7
        assert cams[0].image_size in CONFIG.hor_sizes
        yaw = [np.arctan2(c.R[2, 1], c.R[2, 0]) for c in cams]
        assert np.ptp(np.unwrap(yaw)) > np.radians(1.0)  # the camera turns
        assert np.hypot(*(cams[-1].c[:2] - cams[0].c[:2])) > 0.0  # and walks
    # The drifting, yawing drone moves; the default top camera does not.
    top = scene.top_cameras
    assert np.hypot(*(top[-1].c[:2] - top[0].c[:2])) > 0.5
    assert not np.allclose(top[-1].R, top[0].R)
    still = _scene(CONFIG, 3, 5).top_cameras
    assert all(np.array_equal(c.R, still[0].R) and np.array_equal(c.c, still[0].c)
               for c in still)


def _pitch(camera: Camera) -> float:
    return float(np.degrees(np.arcsin(-camera.R[2, 2])))


def test_tilting_gimbal_turns_about_the_middle_pitch():
    """``top_pitch_rate``: the top camera stands still and tilts steadily, the drawn pitch in
    the clip's middle."""
    tilting = _scene(ObliqueSceneConfig(top_pitch=(40.0, 50.0), top_pitch_rate=(1.0, 2.0)),
                     5, 61)
    cams = tilting.top_cameras
    pitches = np.array([_pitch(c) for c in cams])
    rates = np.diff(pitches) * tilting.config.fps
    assert np.allclose(rates, rates[0], atol=1e-6) and 1.0 - 1e-6 <= abs(rates[0]) <= 2.0 + 1e-6
    assert 40.0 - 1e-6 <= pitches[30] <= 50.0 + 1e-6
    assert all(np.array_equal(c.c, cams[0].c) for c in cams)  # it tilts where it stands
    with pytest.raises(ValueError, match="top_pitch_rate"):
        ObliqueSceneConfig(top_pitch_rate=(2.0, 1.0))


def test_a_drifting_pitch_keeps_the_scene_and_moves_the_handheld_boxes():
    """:func:`pitch_drifted`: the same people and top view, each handheld camera pitched about
    its own by a slow drift (degrees of spread as asked, frame-to-frame steps far below a
    fresh draw's), its boxes projected again; no drift, the very boxes."""
    scene = _scene(ObliqueSceneConfig(top_pitch=(30.0, 40.0), n_hor=2), 4, 200)
    drifted = pitch_drifted(scene, 5.0, 6.0, np.random.default_rng(0))
    assert drifted.people is scene.people and drifted.top is scene.top
    for name, cams in scene.hor_cameras.items():
        moved = np.array([_pitch(b) - _pitch(a)
                          for a, b in zip(cams, drifted.hor_cameras[name], strict=True)])
        assert 1.0 < np.abs(moved).max() < 25.0
        assert np.std(np.diff(moved)) < 1.5  # a fresh draw a frame: 7 degrees
        assert all(np.array_equal(a.c, b.c)
                   for a, b in zip(cams, drifted.hor_cameras[name], strict=True))
    assert any(not np.array_equal(drifted.hor["hor1"][f].boxes, scene.hor["hor1"][f].boxes)
               for f in scene.hor["hor1"])
    still = pitch_drifted(scene, 0.0, 6.0, np.random.default_rng(0))
    assert all(np.allclose(still.hor[v][f].boxes, scene.hor[v][f].boxes)
               and np.array_equal(still.hor[v][f].ids, scene.hor[v][f].ids)
               for v in scene.hor for f in scene.hor[v])
    with pytest.raises(ValueError, match="time_s"):
        pitch_drifted(scene, 5.0, 0.0, np.random.default_rng(0))


def _plane_error(scene, plane: np.ndarray) -> np.ndarray:
    """How far each top box's bottom centre, cast onto the plane z = a x + b y + c, lands from
    the person's place (frames 1, 30, 60), metres."""
    errors = []
    for f in (1, 30, 60):
        cam, rec = scene.top_cameras[f - 1], scene.top[f]
        uv = np.c_[rec.boxes[:, 0] + 0.5 * rec.boxes[:, 2], rec.boxes[:, 1] + rec.boxes[:, 3]]
        d = cam.ray_directions(uv)
        t = (plane[:2] @ cam.c[:2] + plane[2] - cam.c[2]) / (d[:, 2] - d[:, :2] @ plane[:2])
        place = cam.c[:2] + t[:, None] * d[:, :2]
        errors.append(np.linalg.norm(place - scene.people.positions[f - 1][rec.ids], axis=1))
    return np.concatenate(errors)


def test_a_sloping_ground_raises_the_holders_and_the_feet_on_one_plane():
    """:func:`sloped`: the handheld cameras rise with their holders on one plane of the grade
    asked, and the top view's feet lie on that plane (cast onto it, each lands by its person
    within a body's radius; cast onto the level ground, 1-2 m off); no slope, the very
    boxes."""
    scene = _scene(dataclasses.replace(OBLIQUE, n_hor=2), 4, 60)
    steep = sloped(scene, 8.0, np.random.default_rng(0))
    assert steep.people is scene.people
    xy = np.concatenate([[c.c[:2] for c in cams] for cams in scene.hor_cameras.values()])
    rise = np.concatenate([[b.c[2] - a.c[2] for a, b in zip(cams, steep.hor_cameras[v],
                                                              strict=True)]
                           for v, cams in scene.hor_cameras.items()])
    design = np.c_[xy, np.ones(len(xy))]
    plane = np.linalg.lstsq(design, rise, rcond=None)[0]
    np.testing.assert_allclose(design @ plane, rise, atol=1e-9)
    assert np.degrees(np.arctan(np.hypot(*plane[:2]))) == pytest.approx(8.0)
    assert np.percentile(_plane_error(steep, plane), 90) < 0.5
    assert np.percentile(_plane_error(steep, np.zeros(3)), 90) > 1.0
    level = sloped(scene, 0.0, np.random.default_rng(0))
    assert all(np.allclose(level.hor[v][f].boxes, scene.hor[v][f].boxes)
               and np.allclose(level.top[f].boxes, scene.top[f].boxes)
               for v in scene.hor for f in scene.hor[v])
    with pytest.raises(ValueError, match="grade_deg"):
        sloped(scene, 50.0, np.random.default_rng(0))


def test_a_barrel_top_lens_draws_the_top_boxes_in():
    """:func:`top_distorted`: the top boxes drawn towards the image centre, the farther out
    the more (a few pixels near the middle, tens near the edge); the handheld views kept."""
    scene = _scene(OBLIQUE, 4, 10)
    barrel = top_distorted(scene, -0.1)
    assert barrel.hor is scene.hor
    cam = scene.top_cameras[0]
    before, after = scene.top[1], barrel.top[1]
    assert np.array_equal(before.ids, after.ids)
    radius = [np.linalg.norm(r.boxes[:, :2] + 0.5 * r.boxes[:, 2:] - cam.K[:2, 2], axis=1)
              for r in (before, after)]
    moved = radius[1] - radius[0]
    assert (moved <= 1e-6).all()
    assert moved[np.argmax(radius[0])] == moved.min() < -3.0
    same = top_distorted(scene, 0.0)
    assert all(np.allclose(same.top[f].boxes, scene.top[f].boxes) for f in scene.top)


def test_a_top_camera_mounted_askew_tips_its_horizon():
    """:func:`top_rolled`: the top camera turned about its optical axis (same centre and axis,
    its image's horizon tipped by the roll asked), its boxes projected through it; no roll,
    the very boxes; the handheld views kept."""
    scene = _scene(OBLIQUE, 4, 10)
    askew = top_rolled(scene, 8.0)
    assert askew.hor is scene.hor
    for a, b in zip(scene.top_cameras, askew.top_cameras, strict=True):
        np.testing.assert_allclose(b.c, a.c)
        np.testing.assert_allclose(b.R[2], a.R[2])  # the optical axis kept
        # the world's up seen in each image: turned by the roll
        up_a, up_b = a.R @ np.array([0.0, 0.0, 1.0]), b.R @ np.array([0.0, 0.0, 1.0])
        turn = np.degrees(np.arctan2(up_b[0], -up_b[1]) - np.arctan2(up_a[0], -up_a[1]))
        assert abs(turn) == pytest.approx(8.0)
    assert any(askew.top[f].boxes.shape != scene.top[f].boxes.shape
               or not np.allclose(askew.top[f].boxes, scene.top[f].boxes) for f in scene.top)
    level = top_rolled(scene, 0.0)
    assert all(np.allclose(level.top[f].boxes, scene.top[f].boxes) for f in scene.top)


def _same_boxes(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(
        np.array_equal(a[f].ids, b[f].ids) and np.allclose(a[f].boxes, b[f].boxes) for f in a)


def test_the_transforms_compose_in_any_order():
    """A slope, the top lens's barrel, its roll and the handheld drift each keep what the
    others did (the scene carries its ground and top lens): sloping then distorting gives the
    boxes of distorting then sloping, and neither those of the barrel on a level ground; the
    handheld drift keeps the slope under its people."""
    scene = _scene(dataclasses.replace(OBLIQUE, n_hor=2), 4, 30)
    a = top_distorted(sloped(scene, 5.0, np.random.default_rng(0)), -0.1)
    b = sloped(top_distorted(scene, -0.1), 5.0, np.random.default_rng(0))
    assert _same_boxes(a.top, b.top) and all(_same_boxes(a.hor[v], b.hor[v]) for v in a.hor)
    assert not _same_boxes(a.top, top_distorted(scene, -0.1).top)
    rolled = top_rolled(a, 3.0)
    assert rolled.ground is a.ground and rolled.top_distortion == -0.1
    drifted = pitch_drifted(a, 0.0, 6.0, np.random.default_rng(0))
    assert all(_same_boxes(drifted.hor[v], a.hor[v]) for v in a.hor)


def test_a_turning_drone_stays_low_and_keeps_the_people_in_view():
    """A low drone that drifts and turns fast (36 degrees over the clip, about its own axis):
    rising cannot keep the shared square in a turning image, so past the highest drone asked
    for it drifts and turns less (seed [2, 6] rose to 67 km before, its boxes 0 px at one
    point); a slow one drifts and turns as drawn."""
    fast = ObliqueSceneConfig(top_pitch=(20.0, 45.0), top_height=(4.0, 12.0),
                              top_drift_speed=(0.3, 1.0), top_yaw_rate=(0.0, 3.0),
                              overlap=(0.35, 0.65), hor_hfov=(60.0, 110.0))
    scene = make_oblique_scene(fast, 120, np.random.default_rng([2, 6]))
    cams = scene.top_cameras
    assert all(c.c[2] <= 12.0 * 1.05 + 1e-9 for c in cams)
    heights = np.concatenate([r.boxes[:, 3] for r in scene.top.values()])
    assert len(heights) > 100 and np.median(heights) > 60.0  # people, not points
    drift = np.hypot(*(cams[-1].c[:2] - cams[0].c[:2]))
    rising = make_oblique_scene(dataclasses.replace(fast, top_height=(4.0, 1e6)), 120,
                                np.random.default_rng([2, 6]))  # the same draws, free to rise
    assert rising.top_cameras[0].c[2] > 1000.0
    drawn = np.hypot(*(rising.top_cameras[-1].c[:2] - rising.top_cameras[0].c[:2]))
    assert 0.0 < drift < 0.5 * drawn  # it still drifts, slower
    slow = make_oblique_scene(dataclasses.replace(fast, top_drift_speed=(0.3, 0.3),
                                                  top_yaw_rate=(0.0, 0.0)), 120,
                              np.random.default_rng([2, 6]))
    drift = np.hypot(*(slow.top_cameras[-1].c[:2] - slow.top_cameras[0].c[:2]))
    assert drift == pytest.approx(0.3 * 11.9)


def test_a_holder_given_a_wide_square_walks_past_the_scene():
    """``holder_area``: a holder walking a 10 m square at 1.2-1.5 m/s covers metres over the
    clip (2 m, the default, turns on the spot), stands farther from the shared group, and still
    films it; a fixed side draws nothing, so the default scene is the same draw for draw."""
    fast = dataclasses.replace(CONFIG, holder_speed=(1.2, 1.5))
    near = _scene(fast, 2, 100)
    far = _scene(dataclasses.replace(fast, holder_area=(10.0, 10.0)), 2, 100)
    twin = _scene(dataclasses.replace(CONFIG, holder_area=(2.0, 2.0)), 3, 100)
    np.testing.assert_array_equal(twin.people.positions, _scene(CONFIG, 3, 100).people.positions)

    def reach(scene):  # the camera's farthest place from its first, and its distance to the
        c = np.array([cam.c[:2] for cam in scene.hor_cameras["hor1"]])  # shared group
        shared = scene.people.positions[:, scene.groups["shared"]].mean(axis=1)
        return np.hypot(*(c - c[0]).T).max(), np.hypot(*(c - shared).T).mean()

    (walked_near, away_near), (walked_far, away_far) = reach(near), reach(far)
    assert walked_near < 3.0 < 5.0 < walked_far and away_far > away_near + 3.0
    shared = set(far.groups["shared"].tolist())
    seen = [set(r.ids.tolist()) & shared for r in far.hor["hor1"].values()]
    assert np.mean([len(s) for s in seen]) >= 0.7 * len(shared)
    with pytest.raises(ValueError, match="holder_area"):
        ObliqueSceneConfig(holder_area=(0.5, 2.0))


def test_a_barrel_lens_pulls_the_handheld_boxes_toward_the_centre():
    """``hor_distortion``: Brown's k1 on the handheld views only; a fixed value draws nothing
    (the same people, the same top boxes); barrel (k1 < 0) moves a box's corners toward the
    image centre, more the farther out, and a ray far out of view stays out."""
    K = intrinsics_from_fov(1920, 1080, 100.0)
    uv = np.array([[960.0, 540.0], [1400.0, 540.0], [1900.0, 1000.0], [60000.0, 540.0]])
    out = distorted(uv, K, -0.25)
    assert np.array_equal(out[0], uv[0])  # the centre stays
    r_in, r_out = np.hypot(*(uv - uv[0]).T), np.hypot(*(out - uv[0]).T)
    assert (r_out[1:] < r_in[1:]).all() and np.all(np.diff(r_out[1:]) > 0)
    assert r_out[2] / r_in[2] < r_out[1] / r_in[1] and out[3, 0] > 1920  # out of view still
    config = dataclasses.replace(CONFIG, hor_hfov=(100.0, 110.0))
    pinhole = _scene(config, 5, 30)
    barrel = _scene(dataclasses.replace(config, hor_distortion=(-0.25, -0.25)), 5, 30)
    np.testing.assert_array_equal(barrel.people.positions, pinhole.people.positions)
    assert all(np.array_equal(barrel.top[f].boxes, pinhole.top[f].boxes) for f in pinhole.top)
    moved = 0
    for f, rec in pinhole.hor["hor1"].items():
        other = barrel.hor["hor1"][f]
        shared = np.intersect1d(rec.ids, other.ids)
        a = rec.boxes[np.isin(rec.ids, shared)]
        b = other.boxes[np.isin(other.ids, shared)]
        assert (b[:, 3] <= a[:, 3] + 1e-9).all()  # heights shrink toward the edges
        moved += int((np.abs(a - b) > 1.0).any())
    assert moved > 0
    with pytest.raises(ValueError, match="hor_distortion"):
        ObliqueSceneConfig(hor_distortion=(-0.8, 0.0))


def test_edge_people_are_cut_by_each_images_bottom_edge():
    """``edge_people``: more people walk across each camera's bottom edge, whose boxes it cuts
    (the renders otherwise keep everyone inside both images); everyone else is the same scene's,
    bit for bit."""
    config = ObliqueSceneConfig(top_pitch=(20.0, 45.0), top_height=(4.0, 12.0))
    plain = _scene(config, 3, 60)
    edged = _scene(dataclasses.replace(config, edge_people=(2, 3)), 3, 60)
    n = plain.people.n_people
    np.testing.assert_array_equal(edged.people.positions[:, :n], plain.people.positions)
    assert {"top_edge", "hor1_edge"} <= set(edged.groups)
    assert all(2 <= len(edged.groups[g]) <= 3 for g in ("top_edge", "hor1_edge"))
    assert edged.overlap_target == plain.overlap_target
    for scene, want in ((plain, False), (edged, True)):
        for records, cams in _views(scene):
            rows = np.concatenate([r.boxes[:, 1] + r.boxes[:, 3] for r in records.values()])
            assert (rows >= cams[0].height - 1.0).any() == want
    with pytest.raises(ValueError, match="edge_people"):
        ObliqueSceneConfig(edge_people=(3, 2))


def test_boxes_past_the_border_and_amodal_boxes():
    """``box_extent``: ``past_border``, a box the image's border cuts runs on past it (trackers'
    boxes): the same people in the same frames, every box the border does not cut the same, and
    the part inside each cut box the clipped box; ``amodal``, every kept person's whole box
    (behind nearer people too), the visible box inside it."""
    config = ObliqueSceneConfig(top_pitch=(20.0, 45.0), top_height=(4.0, 12.0),
                                edge_people=(2, 3))
    clipped = _scene(config, 3, 60)
    spilled = _scene(dataclasses.replace(config, box_extent="past_border"), 3, 60)
    whole = _scene(dataclasses.replace(config, box_extent="amodal"), 3, 60)
    for (plain, cams), (past, _), (full, _) in zip(_views(clipped), _views(spilled),
                                                   _views(whole), strict=True):
        ran_on = grown = 0
        for f, rec in plain.items():
            np.testing.assert_array_equal(past[f].ids, rec.ids)
            np.testing.assert_array_equal(full[f].ids, rec.ids)
            a, b, c = rec.boxes, past[f].boxes, full[f].boxes
            a1, b1, c1 = a[:, :2] + a[:, 2:], b[:, :2] + b[:, 2:], c[:, :2] + c[:, 2:]
            size = np.array([cams[f - 1].width, cams[f - 1].height], dtype=float)
            np.testing.assert_allclose(np.clip(b[:, :2], 0.0, size), a[:, :2])
            np.testing.assert_allclose(np.clip(b1, 0.0, size), a1)
            ran_on += int(((b[:, :2] < 0) | (b1 > size)).any(axis=1).sum())
            assert (c[:, :2] <= b[:, :2] + 1e-9).all() and (c1 >= b1 - 1e-9).all()
            grown += int(((c[:, :2] < b[:, :2] - 1e-6) | (c1 > b1 + 1e-6)).any(axis=1).sum())
        assert ran_on > 0 and grown > 0  # amodal: the parts nearer people hide too
    with pytest.raises(ValueError, match="box_extent"):
        ObliqueSceneConfig(box_extent="whole")
    with pytest.raises(ValueError, match="extent must be one of"):
        project_view(np.zeros((1, 2)), [1.7], [0.4], clipped.top_cameras[0], extent="whole")


def test_boxes_inside_the_image(clips, two_hor):
    for scene in [*clips, two_hor]:
        for records, cams in _views(scene):
            for f, rec in records.items():
                cam = cams[f - 1]
                b = rec.boxes
                assert (b[:, 2:] > 0).all()
                assert (b[:, :2] >= 0).all()
                assert (b[:, 0] + b[:, 2] <= cam.width + 1e-9).all()
                assert (b[:, 1] + b[:, 3] <= cam.height + 1e-9).all()
                assert np.unique(rec.ids).size == len(rec)


def _isolated_untruncated(rec, cam):
    """Indices of boxes off the image border that overlap no other box of the frame."""
    b = rec.boxes
    x0, y0, x1, y1 = b[:, 0], b[:, 1], b[:, 0] + b[:, 2], b[:, 1] + b[:, 3]
    ox = (np.minimum(x1[:, None], x1[None]) > np.maximum(x0[:, None], x0[None]))
    oy = (np.minimum(y1[:, None], y1[None]) > np.maximum(y0[:, None], y0[None]))
    overlap = ox & oy
    np.fill_diagonal(overlap, False)
    inner = (x0 > 1) & (y0 > 1) & (x1 < cam.width - 1) & (y1 < cam.height - 1)
    return np.flatnonzero(inner & ~overlap.any(axis=1))


def test_box_height_is_the_projected_person(clips):
    """An isolated box spans head to foot: at least |v(head) - v(foot)|, at most that plus the
    body's width seen from above (f w / depth), in every view."""
    checked = 0
    for scene in clips:
        people = scene.people
        for records, cams in _views(scene):
            for f in range(1, scene.n_frames + 1, 5):
                rec, cam = records[f], cams[f - 1]
                for i in _isolated_untruncated(rec, cam):
                    p = int(rec.ids[i])
                    x, y = people.positions[f - 1, p]
                    uv, depth = cam.project(np.array([[x, y, 0.0], [x, y, people.heights[p]]]))
                    span = abs(uv[1, 1] - uv[0, 1])
                    width_px = cam.K[1, 1] * people.widths[p] / depth.min()
                    h = rec.boxes[i, 3]
                    assert span - 0.5 <= h <= span + 1.05 * width_px + 0.5, (f, p, h, span)
                    checked += 1
    assert checked > 200


def _fractions(scene, view):
    """(per-frame, per-person) fraction of the top's and of the view's people seen by both."""
    both = top_n = hor_n = 0
    top_ids, hor_ids = set(), set()
    for f in scene.top:
        t, h = set(scene.top[f].ids.tolist()), set(scene.hor[view][f].ids.tolist())
        both += len(t & h)
        top_n += len(t)
        hor_n += len(h)
        top_ids |= t
        hor_ids |= h
    shared = len(top_ids & hor_ids)
    return (both / top_n, both / hor_n), (shared / len(top_ids), shared / len(hor_ids))


def test_overlap_close_to_the_drawn_fraction(clips):
    for scene in clips:
        n_top = len(scene.groups["shared"]) + len(scene.groups["top_only"])
        n_hor = len(scene.groups["shared"]) + len(scene.groups["hor1_only"])
        # The groups placed realise the drawn fractions up to rounding a count.
        assert abs(scene.overlap_target["top"] - scene.overlap["top"]) <= 1.0 / n_top
        assert abs(scene.overlap_target["hor1"] - scene.overlap["hor1"]) <= 1.0 / n_hor
        (frame_top, frame_hor), (person_top, person_hor) = _fractions(scene, "hor1")
        # Over the clip, whoever is in a view at some time: the target.
        assert abs(person_top - scene.overlap_target["top"]) <= 0.1
        assert abs(person_hor - scene.overlap_target["hor1"]) <= 0.1
        # Frame by frame, lower: near people hide shared ones from the handheld camera.
        assert scene.overlap_target["top"] - 0.2 <= frame_top <= scene.overlap_target["top"] + 0.05
        assert abs(frame_hor - scene.overlap_target["hor1"]) <= 0.15
    drawn = [s.overlap["top"] for s in clips]
    assert min(drawn) >= 0.3 and max(drawn) <= 1.0


def test_nadir_blobs_and_oblique_upright_people():
    ratios = {}
    for label, config in (("nadir", NADIR), ("oblique", OBLIQUE)):
        r = []
        for seed in (0, 1):
            scene = _scene(config, seed, 20)
            for f, rec in scene.top.items():
                idx = _isolated_untruncated(rec, scene.top_cameras[f - 1])
                r.extend((rec.boxes[idx, 3] / rec.boxes[idx, 2]).tolist())
        ratios[label] = np.asarray(r)
        assert len(r) > 20
    assert 0.5 <= np.median(ratios["nadir"]) <= 1.6
    assert np.median(ratios["oblique"]) > 2.0
    assert (ratios["oblique"] > 1.0).mean() > 0.95


def test_occlusion_and_truncation():
    # Two people on the optical axis of a level camera, the far one shifted a little sideways:
    # the near one hides most of its box, which shrinks to the visible strip.
    cam = Camera(K=intrinsics_from_fov(1920, 1080, 70.0), R=look_rotation(0.0),
                 c=np.array([0.0, 0.0, 1.6]), width=1920, height=1080)
    xy = np.array([[6.0, 0.0], [12.0, -0.5], [3.0, 2.0]])
    heights, widths = np.array([1.7, 1.8, 1.7]), np.full(3, 0.45)
    idx, boxes = project_view(xy, heights, widths, cam, min_visible_fraction=0.0)
    _, full = project_view(xy[1:2], heights[1:2], widths[1:2], cam)
    np.testing.assert_array_equal(idx, [0, 1, 2])
    assert boxes[1, 2] < 0.8 * full[0, 2]  # the far one: only its visible part
    assert boxes[2, 0] == 0.0 and boxes[2, 1] >= 0.0  # the near one, cut by the left border
    idx, _ = project_view(xy, heights, widths, cam, min_visible_fraction=0.9)
    assert 1 not in idx and 2 not in idx  # mostly hidden or mostly outside: dropped
    idx, _ = project_view(xy, heights, widths, cam, present=np.array([False, True, True]))
    assert 0 not in idx
    # In scenes: boxes cut by the border, and people dropped for being mostly hidden.
    scene = _scene(CONFIG, 0, 100)
    cut = dropped = 0
    for name, records in scene.hor.items():
        for f, rec in records.items():
            cam = scene.hor_cameras[name][f - 1]
            b = rec.boxes
            cut += int(((b[:, 0] <= 0) | (b[:, 0] + b[:, 2] >= cam.width)).sum())
            present = np.arange(scene.people.n_people) != int(name[3:]) - 1
            all_idx, _ = project_view(scene.people.positions[f - 1], scene.people.heights,
                                      scene.people.widths, cam, min_visible_fraction=0.0,
                                      present=present)
            dropped += len(all_idx) - len(rec)
    assert cut > 0 and dropped > 0


def test_written_files_read_back(tmp_path, two_hor):
    scene = two_hor
    paths = write_oblique_scene(scene, tmp_path, "s1")
    assert sorted(paths) == ["cameras_hor1", "cameras_hor2", "hor1", "hor2", "top"]
    assert paths["top"].name == "s1_top.txt" and paths["hor2"].name == "s1_hor2.txt"
    for view, records in [("top", scene.top), *scene.hor.items()]:
        back = read_mot_boxes(paths[view])
        assert sorted(back) == [f for f, rec in records.items() if len(rec)]
        for f, rec in back.items():
            np.testing.assert_array_equal(rec.ids, records[f].ids)
            np.testing.assert_array_equal(rec.boxes, records[f].boxes)
    for view in scene.hor:
        cams = open_cameras(paths[f"cameras_{view}"], frames=range(1, scene.n_frames + 1))
        for f in range(1, scene.n_frames + 1):
            assert same_camera(cams.get(f).top, scene.top_cameras[f - 1])
            assert same_camera(cams.get(f).hor, scene.hor_cameras[view][f - 1])
    with pytest.raises(ValueError, match="does not exist"):
        write_oblique_scene(scene, tmp_path / "missing", "s1")


def test_a_lingering_crowd_stands_still():
    """``stop_probability`` and ``stop_duration``: people who stop half a second's chance a
    second for 30 s on average stand nearly all the time (``p d / (1 + p d)``, 94 %), for 5 s
    about two thirds of it, and the default crowd a third; the default duration is the walks'
    own (5 s), so the default scene is the same draw for draw."""
    def standing(stops):  # the share of person-frames slower than 5 cm/s, seed 2
        config = dataclasses.replace(CONFIG, stop_probability=stops[0], stop_duration=stops[1])
        steps = np.diff(_scene(config, 2, 100).people.positions, axis=0)
        return float(np.mean(np.hypot(*steps.transpose(2, 0, 1)) * config.fps < 0.05))

    assert standing((0.1, 5.0)) < 0.4 < standing((0.5, 5.0)) < 0.8 < standing((0.5, 30.0))
    np.testing.assert_array_equal(
        _scene(dataclasses.replace(CONFIG, stop_duration=5.0), 3, 40).people.positions,
        _scene(CONFIG, 3, 40).people.positions)
    with pytest.raises(ValueError, match="stop_duration"):
        ObliqueSceneConfig(stop_duration=0.0)


def test_bad_input():
    with pytest.raises(ValueError, match="top_pitch"):
        ObliqueSceneConfig(top_pitch=(20.0, 100.0))
    with pytest.raises(ValueError, match="min_separation"):
        ObliqueSceneConfig(width_range=(0.4, 0.7))
    with pytest.raises(ValueError, match="n_hor"):
        ObliqueSceneConfig(n_hor=0)
    with pytest.raises(ValueError, match="n_frames"):
        make_oblique_scene(CONFIG, 0, np.random.default_rng(0))


def test_the_benchmarks_render_options_default_to_the_configs_own() -> None:
    """``benchmarks/oblique_association.py``'s render options (the drone's, the holders', the
    people's squares), left out, draw the scenes of the config's defaults: figures measured
    before an option was added are measured again without it."""
    import argparse
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from oblique_association import add_drone_arguments, drone_config

    parser = argparse.ArgumentParser()
    add_drone_arguments(parser)
    assert drone_config(parser.parse_args([])) == ObliqueSceneConfig()
    spread = drone_config(parser.parse_args(["--area", "20", "40", "--group-area", "6", "12"]))
    assert (spread.area, spread.group_area) == ((20.0, 40.0), (6.0, 12.0))
    wide = drone_config(parser.parse_args(["--top-hfov", "90", "120"]))
    assert wide.top_hfov == (90.0, 120.0)
    lingering = drone_config(parser.parse_args(["--stops", "0.5", "30"]))
    assert (lingering.stop_probability, lingering.stop_duration) == (0.5, 30.0)
