"""Tests of the photographic person textures (xvmatch.datasets.render.person_textures)."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from xvmatch.datasets.render.image_render import Difficulty, SceneRenderer
from xvmatch.datasets.render.person_textures import (
    TEXTURE_SIZE,
    TEXTURE_SOURCES,
    PersonTextures,
    apply_person_textures,
    draw_person_textures,
    load_textures,
)
from xvmatch.datasets.synthetic_scenes import SynthConfig, make_scene

needs_images = pytest.mark.skipif(
    importlib.util.find_spec("skimage") is None,
    reason="the scikit-image wheel's images are not installed (pip install --no-deps "
    "scikit-image; make test does)")


def test_difficulty_records_a_texture_only_when_set():
    assert "texture" not in Difficulty().to_dict()  # older manifests unchanged
    assert Difficulty(texture=0.5).to_dict()["texture"] == 0.5
    with pytest.raises(ValueError, match=r"Difficulty\.texture must be in \[0, 1\]"):
        Difficulty(texture=1.5)


@needs_images
def test_textures_are_normalised_and_read_only():
    textures = load_textures()
    assert textures.shape == (len(TEXTURE_SOURCES), TEXTURE_SIZE, TEXTURE_SIZE)
    assert np.allclose(textures.mean(axis=(1, 2)), 0.0, atol=1e-4)
    assert np.allclose(textures.std(axis=(1, 2)), 1.0, atol=1e-3)
    with pytest.raises(ValueError):
        textures[0, 0, 0] = 1.0


def _one_person(top: int, left: int, height: int, width: int, shape=(120, 160)):
    image = np.full((*shape, 3), 128, np.uint8)
    ids = np.zeros(shape, np.uint16)
    ids[top:top + height, left:left + width] = 1
    return image, ids


@needs_images
def test_a_person_keeps_the_texture_wherever_they_stand():
    textures = PersonTextures(np.array([3]), np.array([[17.0, 40.0]]), np.array([200.0]))
    image, ids = _one_person(10, 20, 60, 25)
    out = apply_person_textures(image, ids, textures, 1.0)
    assert np.array_equal(out[ids == 0], image[ids == 0])  # the background is untouched
    person = out[10:70, 20:45].astype(int)
    assert person.std() > 5  # textured, not flat
    moved_image, moved_ids = _one_person(50, 100, 60, 25)
    moved = apply_person_textures(moved_image, moved_ids, textures, 1.0)
    assert np.array_equal(moved[50:110, 100:125], out[10:70, 20:45])
    assert apply_person_textures(image, ids, textures, 0.0) is image
    weaker = apply_person_textures(image, ids, textures, 0.3)[10:70, 20:45].astype(int)
    assert 0 < np.abs(weaker - 128).mean() < np.abs(person - 128).mean()
    with pytest.raises(ValueError, match="texture depth must be in"):
        apply_person_textures(image, ids, textures, 1.2)


@needs_images
def test_textured_scene_is_the_same_scene_with_textured_people():
    config = SynthConfig(scenario="drone", top_size=(320, 180), ego_size=(320, 180),
                         n_people=(6, 8))

    def render(texture: float):
        rng = np.random.default_rng([7, 0])
        scene = make_scene(config, 2, rng)
        return SceneRenderer(scene, rng, Difficulty(texture=texture)).render(2)

    plain, textured, again = render(0.0), render(1.0), render(1.0)
    for view in ("top", "ego"):
        a, b = getattr(plain, view), getattr(textured, view)
        assert np.array_equal(a.labels.ids, b.labels.ids)
        assert np.array_equal(a.labels.boxes, b.labels.boxes)
        assert np.array_equal(a.id_image, b.id_image)
        assert np.array_equal(getattr(again, view).image, b.image)  # deterministic
    people = textured.ego.id_image > 0
    diff = np.abs(plain.ego.image.astype(int) - textured.ego.image.astype(int)).sum(axis=2)
    assert diff[people].mean() > 3 * max(diff[~people].mean(), 0.1)


def test_draw_person_textures_is_seeded():
    a = draw_person_textures(np.random.default_rng(4), 5)
    b = draw_person_textures(np.random.default_rng(4), 5)
    assert np.array_equal(a.index, b.index) and np.array_equal(a.offset, b.offset)
    assert a.index.min() >= 0 and a.index.max() < len(TEXTURE_SOURCES)
    assert np.all((a.scale >= 0.5 * TEXTURE_SIZE) & (a.scale <= 1.5 * TEXTURE_SIZE))


@needs_images
def test_synth_texture_renders_the_same_scenes_with_textured_people(tmp_path):
    from xvmatch.cli import main
    from xvmatch.datasets.synthetic_io import SyntheticDataset

    base = ["synth", "--scenes", "1", "--frames", "1", "--size", "160x90", "--seed", "2",
            "--quiet"]
    assert main([*base, "--out", str(tmp_path / "plain")]) == 0
    assert main([*base, "--out", str(tmp_path / "tex"), "--texture", "1"]) == 0
    plain, tex = SyntheticDataset(tmp_path / "plain"), SyntheticDataset(tmp_path / "tex")
    a, b = next(iter(plain)), next(iter(tex))
    for view in ("top", "ego"):
        la, lb = getattr(a, view).labels, getattr(b, view).labels
        assert np.array_equal(la.ids, lb.ids) and np.array_equal(la.boxes, lb.boxes)
    assert not np.array_equal(a.ego.load_image(), b.ego.load_image())
    assert main(["synth", "--cameras", "2", "--frames", "1", "--size", "64x36", "--texture",
                 "0.5", "--out", str(tmp_path / "cams"), "--quiet"]) == 2
