"""Tests of xvmatch.datasets.render.multicam_render (rendered multi-camera scenes)."""

from __future__ import annotations

import numpy as np
import pytest

from xvmatch.datasets.multicam_scenes import MulticamConfig, simulate_multicam_scene
from xvmatch.datasets.render.multicam_render import (
    MulticamRenderer,
    render_multicam_scene,
    write_rendered_multicam_scene,
)
from xvmatch.formats.camera_io import load_ground_cameras
from xvmatch.formats.frame_sources import open_frames
from xvmatch.formats.mot_boxes import read_mot_boxes

_CFG = MulticamConfig(n_cameras=3, n_people=(5, 5))


def test_render_is_deterministic_and_seeded():
    a = MulticamRenderer(_CFG, 12, seed=4, width=160).render(7)
    b = MulticamRenderer(_CFG, 12, seed=4, width=160).render(7)
    c = MulticamRenderer(_CFG, 12, seed=5, width=160).render(7)
    assert list(a.images) == ["cam1", "cam2", "cam3"]
    for name in a.images:
        np.testing.assert_array_equal(a.images[name], b.images[name])
        np.testing.assert_array_equal(a.gt[name].boxes, b.gt[name].boxes)
    assert any(a.images[n].shape != c.images[n].shape or
               not np.array_equal(a.images[n], c.images[n]) for n in a.images)
    # A frame is the same whatever was rendered before it.
    r = MulticamRenderer(_CFG, 12, seed=4, width=160)
    r.render(3)
    np.testing.assert_array_equal(r.render(7).images["cam2"], a.images["cam2"])


def test_boxes_are_the_visible_pixels_and_each_camera_has_its_own_look():
    r = MulticamRenderer(_CFG, 10, seed=2, width=320)
    assert all(c.image_size == (320, 180) for c in r.cameras.values())
    assert len({p.gains for p in r.photometric.values()}) == 3  # own white balance each
    n_boxes = 0
    for frame in r.frames():
        for name, rec in frame.gt.items():
            ids = frame.id_images[name]
            assert frame.images[name].shape == (180, 320, 3)
            for g, (x, y, w, h) in zip(rec.ids.tolist(), rec.boxes, strict=True):
                rows, cols = np.nonzero(ids == g)  # person index + 1 == global id
                assert (x, y, w, h) == (cols.min(), rows.min(), cols.max() - cols.min() + 1,
                                        rows.max() - rows.min() + 1)
                n_boxes += 1
    assert n_boxes > 20


def test_same_people_and_cameras_as_the_box_simulator():
    boxes = simulate_multicam_scene(_CFG, 10, seed=3)
    rendered = render_multicam_scene(_CFG, 10, seed=3, width=192)
    np.testing.assert_array_equal(boxes.positions, rendered.positions)
    for name, cam in boxes.cameras.items():
        np.testing.assert_allclose(rendered.cameras[name].c, cam.c)
        np.testing.assert_allclose(rendered.cameras[name].R, cam.R)
        assert rendered.cameras[name].width == 192


def test_written_scene_reads_back(tmp_path):
    scene, paths = write_rendered_multicam_scene(tmp_path / "s", _CFG, 6, seed=1, width=160)
    cams = load_ground_cameras(paths["cameras"])
    assert set(cams) == {"cam1", "cam2", "cam3"}
    track_ids = set()
    for name in cams:
        src = open_frames(str(paths["images"] / name))
        assert src.size == (160, 90) and src.frames == list(range(1, 7))
        boxes = read_mot_boxes(paths["boxes"] / f"{name}.txt")
        gt = read_mot_boxes(paths["gt"] / f"{name}.txt")
        for f, rec in gt.items():
            np.testing.assert_array_equal(rec.boxes, boxes[f].boxes)
            np.testing.assert_array_equal(rec.ids, scene.gt[name][f].ids)
        mine = {int(i) for rec in boxes.values() for i in rec.ids}
        assert not mine & track_ids  # track ids scrambled per camera
        track_ids |= mine
    assert (tmp_path / "s" / "ground_gt.csv").read_text().startswith("frame,global_id,X,Y\n")


def test_bad_width():
    with pytest.raises(ValueError, match="width"):
        MulticamRenderer(_CFG, 5, seed=0, width=4)
