"""Tests of rendering and pixel labels (xvmatch.datasets.render.image_render, person_render)."""

from __future__ import annotations

import numpy as np
import pytest

from xvmatch.datasets.box_scene import PeopleState
from xvmatch.datasets.render.image_render import (
    Difficulty,
    Photometric,
    SceneRenderer,
    apply_photometric,
    render_people,
)
from xvmatch.datasets.render.person_render import (
    N_SLOTS,
    N_VERTICES,
    body_frame,
    draw_appearances,
    walk_phases,
)
from xvmatch.datasets.synthetic_scenes import SynthConfig, make_scene
from xvmatch.geometry.camera import Camera, intrinsics_from_fov, look_rotation
from xvmatch.geometry.ray_priors import METRIC_MARGIN, cheirality_mask, pixel_rays, ray_distances

SMALL = (160, 90)


def _rendered(scenario: str, seed: int, frames: int = 3, size=SMALL, **kw):
    config = SynthConfig(scenario=scenario, top_size=size, ego_size=size, **kw)
    rng = np.random.default_rng([seed, 0])
    scene = make_scene(config, frames, rng)
    renderer = SceneRenderer(scene, rng)
    return scene, renderer, [renderer.render(f) for f in range(1, frames + 1)]


@pytest.fixture(scope="module", params=["drone", "overview"])
def rendered(request):
    return _rendered(request.param, seed=11, frames=6, size=(320, 180), n_people=(10, 14))


def _state(xy: list[tuple[float, float]], heights: list[float]) -> PeopleState:
    """One frame; index 0 is the camera carrier (id 0) far away, the others ids 1.."""
    n = len(xy)
    return PeopleState(
        positions=np.asarray(xy, dtype=float)[None], heights=np.asarray(heights, dtype=float),
        widths=np.full(n, 0.45), headings=np.full((1, n), np.pi / 2), ids=np.arange(n),
        wearer=0, head_yaw=np.zeros(1), head_pitch=np.zeros(1), head_roll=np.zeros(1),
    )


def _world(scene_like_rng: int = 0):
    scene = make_scene(SynthConfig(top_size=SMALL, ego_size=SMALL), 1,
                       np.random.default_rng(scene_like_rng))
    return SceneRenderer(scene, np.random.default_rng(1)).world


def _level_camera(size=(320, 240)) -> Camera:
    """Camera at (0, 0, 1.6) looking along +x, level."""
    return Camera(intrinsics_from_fov(*size, 60.0), look_rotation(0.0), [0.0, 0.0, 1.6], *size)


def _body(state: PeopleState, seed: int = 0):
    app = draw_appearances(state.n_people, np.random.default_rng(seed))
    phase, amp = walk_phases(state, 10.0)
    return body_frame(state, 1, app, phase, amp)


def test_body_frame_shapes() -> None:
    state = _state([(50.0, 50.0), (4.0, 0.0)], [1.7, 1.8])
    body = _body(state)
    assert body.vertices.shape == (2, N_SLOTS, N_VERTICES, 3)
    norms = np.linalg.norm(body.normals, axis=-1)[body.present]
    assert np.allclose(norms, 1.0)
    # Nobody's body goes below the ground or above their height (hair / hats excepted).
    assert body.vertices[..., 2].min() >= -1e-9
    assert body.head[1, 2] < 1.8 < body.head[1, 2] + 0.2


def test_head_point_inside_box(rendered) -> None:
    _, _, pairs = rendered
    checked = 0
    for pair in pairs:
        for view in (pair.top, pair.ego):
            lab = view.labels
            uv, depth = view.camera.project(lab.head)
            assert (depth > 0).all()
            x, y, w, h = lab.full_boxes.T
            assert ((uv[:, 0] >= x) & (uv[:, 0] <= x + w) & (uv[:, 1] >= y)
                    & (uv[:, 1] <= y + h)).all()
            # Fully visible people: the head is inside the tight box of the visible pixels.
            full = lab.visible > 0.999
            x, y, w, h = lab.boxes[full].T
            u, v = uv[full].T
            assert ((u >= x - 1) & (u <= x + w + 1) & (v >= y - 1) & (v <= y + h + 1)).all()
            checked += int(full.sum())
    assert checked > 10


def test_labels_match_id_image(rendered) -> None:
    scene, _, pairs = rendered
    for pair in pairs:
        for view in (pair.top, pair.ego):
            lab = view.labels
            counts = np.bincount(view.id_image.ravel(), minlength=scene.people.n_people + 1)
            index = {int(pid): k for k, pid in enumerate(scene.people.ids)}
            for k, pid in enumerate(lab.ids):
                mask = view.id_image == index[int(pid)] + 1
                assert counts[index[int(pid)] + 1] == lab.visible_pixels[k]
                rows, cols = np.nonzero(mask)
                assert lab.boxes[k].tolist() == [cols.min(), rows.min(),
                                                 cols.max() - cols.min() + 1,
                                                 rows.max() - rows.min() + 1]
            assert np.all(np.diff(lab.ids) > 0)
            assert ((lab.visible > 0) & (lab.visible <= 1)).all()
    # The carrier is in every top view and in no egocentric view.
    assert all(0 in p.top.labels.ids and 0 not in p.ego.labels.ids for p in pairs)


def test_visible_fraction_agrees_with_occlusion() -> None:
    """A person behind another: visible fraction = own pixels not covered by the nearer one."""
    state = _state([(60.0, 60.0), (5.0, 0.05), (9.0, -0.3)], [1.6, 1.75, 1.85])
    body = _body(state, seed=2)
    world = _world()
    cam = _level_camera()

    def alone(index: int) -> np.ndarray:
        allowed = np.zeros(3, bool)
        allowed[index] = True
        image = np.zeros((cam.height, cam.width, 3), np.uint8)
        ids, _ = render_people(image, cam, body, world, state.ids, allowed=allowed)
        return ids == index + 1

    near, far = alone(1), alone(2)
    image = np.zeros((cam.height, cam.width, 3), np.uint8)
    ids, labels = render_people(image, cam, body, world, state.ids,
                                allowed=np.array([False, True, True]))
    expected = np.count_nonzero(far & ~near) / np.count_nonzero(far)
    assert 0.05 < expected < 0.95  # a real partial occlusion
    k_far, k_near = list(labels.ids).index(2), list(labels.ids).index(1)
    assert labels.visible[k_far] == pytest.approx(expected, abs=0.01)
    assert labels.visible[k_near] == pytest.approx(1.0)
    assert not labels.truncated.any()
    assert np.count_nonzero(ids == 3) == labels.visible_pixels[k_far]


def test_truncated_person() -> None:
    # Near the right image border: part of the body is outside.
    cam = _level_camera()
    state = _state([(60.0, 60.0), (5.0, -2.8)], [1.6, 1.75])
    body = _body(state)
    image = np.zeros((cam.height, cam.width, 3), np.uint8)
    _, labels = render_people(image, cam, body, _world(), state.ids,
                              allowed=np.array([False, True]))
    assert labels.ids.tolist() == [1]
    assert labels.truncated[0]
    assert 0.05 < labels.visible[0] < 0.95
    assert labels.full_boxes[0, 0] + labels.full_boxes[0, 2] > cam.width
    assert labels.boxes[0, 0] + labels.boxes[0, 2] <= cam.width


def test_people_too_near_are_left_out() -> None:
    cam = _level_camera()
    state = _state([(60.0, 60.0), (0.25, 0.0)], [1.6, 1.75])
    image = np.zeros((cam.height, cam.width, 3), np.uint8)
    ids, labels = render_people(image, cam, _body(state), _world(), state.ids,
                                allowed=np.array([False, True]), near_clip=0.3)
    assert len(labels) == 0 and not ids.any()


def test_ray_distance_and_cheirality_of_true_pairs(rendered) -> None:
    """Eq. 6 ~ 0 for true pairs with exact cameras, clearly > 0 for wrong ones; Eq. 7 holds."""
    _, _, pairs = rendered
    wrong = []
    for pair in pairs:
        top, ego = pair.top, pair.ego
        common = np.intersect1d(top.labels.ids, ego.labels.ids)
        if common.size < 2:
            continue
        ti = np.searchsorted(top.labels.ids, common)
        ei = np.searchsorted(ego.labels.ids, common)
        rays_t = pixel_rays(top.camera, top.camera.project(top.labels.head[ti])[0])
        rays_e = pixel_rays(ego.camera, ego.camera.project(ego.labels.head[ei])[0])
        d = ray_distances(rays_t, rays_e)
        assert np.diag(d).max() < 1e-6
        wrong.extend(d[~np.eye(len(common), dtype=bool)].tolist())
        ok = cheirality_mask(rays_t, rays_e)
        assert np.diag(ok).all()
        far = ego.camera.depth(ego.labels.head[ei]) > METRIC_MARGIN + 0.1
        assert np.diag(cheirality_mask(rays_t, rays_e, margin=METRIC_MARGIN))[far].all()
    wrong = np.asarray(wrong)
    assert wrong.size > 10
    assert np.median(wrong) > 0.3
    assert np.mean(wrong > 0.05) > 0.9


def test_same_seed_same_images_in_any_order() -> None:
    _, _, pairs = _rendered("overview", seed=5, frames=3)
    _, renderer, _ = _rendered("overview", seed=5, frames=3)
    again = renderer.render(3)  # a fresh renderer, frames 1-2 of the first one not re-rendered
    assert np.array_equal(again.top.image, pairs[2].top.image)
    assert np.array_equal(again.ego.image, pairs[2].ego.image)
    assert np.array_equal(again.ego.labels.boxes, pairs[2].ego.labels.boxes)


def test_photometric_is_deterministic_and_bounded() -> None:
    image = np.full((40, 60, 3), 120, np.uint8)
    params = Photometric(gains=(1.1, 1.0, 0.9), gamma=1.05, blur_sigma=0.8, noise_sigma=4.0,
                         motion_blur=5.0, jpeg_quality=80)
    a = apply_photometric(image, params, np.random.default_rng(3))
    b = apply_photometric(image, params, np.random.default_rng(3))
    assert np.array_equal(a, b) and a.dtype == np.uint8 and a.shape == image.shape
    assert not np.array_equal(a, image)
    assert np.array_equal(image, np.full((40, 60, 3), 120, np.uint8))  # input untouched
    assert a[..., 0].mean() > a[..., 2].mean()  # the blue gain is above the red one


def test_difficulty_presets_and_errors() -> None:
    assert Difficulty.preset("medium") == Difficulty()
    assert Difficulty.preset("hard").lookalike > Difficulty.preset("easy").lookalike
    with pytest.raises(ValueError, match="unknown difficulty 'extreme'"):
        Difficulty.preset("extreme")
    with pytest.raises(ValueError, match=r"Difficulty\.lookalike must be in"):
        Difficulty(lookalike=1.5)
    with pytest.raises(ValueError, match="jpeg_quality"):
        Difficulty(jpeg_quality=(90, 80))


def test_lookalikes_share_pattern() -> None:
    app = draw_appearances(30, np.random.default_rng(0), lookalike=1.0)
    copies = np.flatnonzero(app.lookalike_of >= 0)
    assert copies.size == 29
    assert (app.pattern[copies] == app.pattern[app.lookalike_of[copies]]).all()
    plain = draw_appearances(30, np.random.default_rng(0), lookalike=0.0)
    assert (plain.lookalike_of == -1).all()
    with pytest.raises(ValueError, match="palette_size"):
        draw_appearances(3, np.random.default_rng(0), palette_size=1)
