"""The appearance term of ``xvmatch multicam`` (issue 32, item 5): a constructed case where the
geometry alone picks the wrong pairs and the images put them right, and ``multicam --images``
end to end on a tiny rendered scene (the shipped appearance network, base install)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from xvmatch.cli import main
from xvmatch.datasets.multicam_scenes import MulticamConfig
from xvmatch.datasets.render.multicam_render import write_rendered_multicam_scene
from xvmatch.formats.crops import box_crops
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.geometry.camera import Camera, intrinsics_from_fov, look_rotation
from xvmatch.geometry.ground_plane import GroundCamera
from xvmatch.inference.views.multicam import MulticamOptions, associate_cameras, relabel

_RED, _BLUE = (0, 0, 255), (255, 0, 0)


def _camera(x: float, y: float) -> Camera:
    yaw = float(np.arctan2(-y, -x))
    pitch = float(np.arctan2(5.0 - 0.9, np.hypot(x, y)))
    return Camera(intrinsics_from_fov(1280, 720, 60.0), look_rotation(yaw, pitch, 0.0),
                  np.array([x, y, 5.0]), 1280, 720)


def _boxes_and_image(cam: Camera, xy: np.ndarray, colours) -> tuple[np.ndarray, np.ndarray]:
    """Narrow upright boxes of people standing at ``xy`` (N, 2), and an image with each box
    painted in its colour."""
    foot, _ = cam.project(np.column_stack([xy, np.zeros(len(xy))]))
    head, _ = cam.project(np.column_stack([xy, np.full(len(xy), 1.7)]))
    h = foot[:, 1] - head[:, 1]
    boxes = np.column_stack([foot[:, 0] - 3.0, head[:, 1], np.full(len(xy), 6.0), h])
    image = np.full((cam.height, cam.width, 3), 128, np.uint8)
    for (x, y, w, hh), colour in zip(boxes, colours, strict=True):
        image[int(y):int(y + hh), int(x):int(x + w)] = colour
    return boxes, image


def _mean_colour(images):
    """A colour descriptor: the unit mean BGR of each box's crop (an appearance function of
    the pixels, as the network is)."""
    def embed(frame, boxes):
        crops = box_crops(images[frame], boxes, (8, 16), 0.1).reshape(len(boxes), -1, 3)
        return crops.mean(axis=1)
    return embed


def test_appearance_changes_a_decision_geometry_cannot_make():
    # Two people walk side by side 0.6 m apart. Camera B's boxes put them 0.1 m apart (an
    # ambiguous view): the geometry slightly prefers pairing the left ones; the colours (red
    # on the left in A, blue on the left in B) say the opposite, and win with the images.
    cam_a, cam_b = _camera(-12.0, 0.0), _camera(0.0, -12.0)
    frames = range(1, 21)
    boxes, images = {"A": {}, "B": {}}, {"A": {}, "B": {}}
    for f in frames:
        t = -1.0 + 0.1 * f
        true_xy = np.array([[-0.3, t], [0.3, t]])
        seen_by_b = np.array([[-0.05, t], [0.05, t]])
        ba, ia = _boxes_and_image(cam_a, true_xy, [_RED, _BLUE])
        bb, ib = _boxes_and_image(cam_b, seen_by_b, [_BLUE, _RED])
        boxes["A"][f] = FrameBoxes(f, np.array([11, 12]), ba)
        boxes["B"][f] = FrameBoxes(f, np.array([21, 22]), bb)
        images["A"][f], images["B"][f] = ia, ib
    cams = {"A": GroundCamera.from_camera(cam_a), "B": GroundCamera.from_camera(cam_b)}

    def partner_of_11(result):
        rl = relabel(boxes, result)
        g = int(rl["A"][1].ids[0])
        return int(boxes["B"][1].ids[np.flatnonzero(rl["B"][1].ids == g)[0]])

    geometry = associate_cameras(cams, boxes, MulticamOptions())
    assert partner_of_11(geometry) == 21  # the nearer one on the ground
    embed = {"A": _mean_colour(images["A"]), "B": _mean_colour(images["B"])}
    with_images = associate_cameras(cams, boxes, MulticamOptions(), appearance=embed)
    assert partner_of_11(with_images) == 22  # the one in the same colour
    off = associate_cameras(cams, boxes, MulticamOptions(appearance_weight=0.0),
                            appearance=embed)
    assert partner_of_11(off) == 21
    # Images of one camera only: no pair has the term.
    one = associate_cameras(cams, boxes, MulticamOptions(), appearance={"A": embed["A"]})
    assert partner_of_11(one) == 21


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    root = tmp_path_factory.mktemp("mcr") / "scene"
    write_rendered_multicam_scene(root, MulticamConfig(n_cameras=2, n_people=(6, 6)), 20,
                                  seed=3, width=320)
    return root


def _args(root, out, names=("cam1", "cam2")):
    return ["multicam", "--boxes", *(f"{n}={root / 'boxes' / (n + '.txt')}" for n in names),
            "--cameras", str(root / "cameras.json"), "--out", str(out), "--quiet"]


def test_multicam_with_images_end_to_end(rendered, tmp_path, capsys):
    out = tmp_path / "out"
    images = ["--images", *(f"{n}={rendered / 'images' / n}" for n in ("cam1", "cam2"))]
    assert main([*_args(rendered, out), *images, "--model", "default"]) == 0
    capsys.readouterr()
    gt = [f"{n}={rendered / 'gt' / (n + '.txt')}" for n in ("cam1", "cam2")]
    assert main(["evaluate", "--multicam", str(out), "--gt", *gt, "--json"]) == 0
    scores = json.loads(capsys.readouterr().out)
    assert scores["P"] >= 0.9 and scores["R"] >= 0.9 and scores["idf1"]["IDF1"] >= 0.9


def _refused(argv, out, capsys, match):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and match in err, err
    assert not out.exists()


def test_images_of_a_camera_without_boxes_is_refused(rendered, tmp_path, capsys):
    out = tmp_path / "out"
    _refused([*_args(rendered, out), "--images", f"cam3={rendered / 'images' / 'cam1'}"],
             out, capsys, "--images cam3=")


@pytest.mark.slow
def test_images_of_the_wrong_size_or_missing_frames_are_refused(rendered, tmp_path, capsys):
    out = tmp_path / "out"
    # cam2's images are 320x180; cam1's camera is too, so give a smaller copy of one frame.
    import cv2

    small = tmp_path / "small"
    small.mkdir()
    image = cv2.imread(str(rendered / "images" / "cam1" / "frame_000001.jpg"))
    for f in range(1, 21):
        cv2.imwrite(str(small / f"frame_{f:06d}.jpg"), cv2.resize(image, (160, 90)))
    _refused([*_args(rendered, out), "--images", f"cam1={small}"], out, capsys, "cam1")
    few = tmp_path / "few"
    few.mkdir()
    cv2.imwrite(str(few / "frame_000001.jpg"), image)
    cv2.imwrite(str(few / "frame_000002.jpg"), image)
    _refused([*_args(rendered, out), "--images", f"cam1={few}"], out, capsys, str(few))
    _refused([*_args(rendered, out), "--model", "default"], out, capsys, "--images")
