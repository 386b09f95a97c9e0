"""Hostile and corrupt input files (issue 28, item 6): each is one line naming the file, exit code
2 through the command line, never a traceback; a corrupt cache file is rebuilt with a warning."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

from xvmatch.cli import main
from xvmatch.core.json_text import parse_json
from xvmatch.datasets.feature_cache import FeatureSet, cached_sequence_features
from xvmatch.datasets.synthetic_io import SchemaError, SyntheticDataset, read_scene
from xvmatch.evaluation.ablation_cells import load_cells
from xvmatch.formats.camera_io import CameraFileError, load_cameras
from xvmatch.formats.frame_sources import FrameSourceError, _decode, open_frames
from xvmatch.formats.image_size import (
    MAX_IMAGE_PIXELS,
    ImageTooLargeError,
    check_image_size,
    declared_image_size,
)
from xvmatch.inference.matching.bundle import MANIFEST, BundleError, read_manifest

DEEP = "[" * 100_000  # nesting deeper than any JSON reader follows by recursion


def _one_line(exc: BaseException, path: Path) -> None:
    text = str(exc)
    assert "\n" not in text and text.startswith(str(path)), text


def _cli(capsys, *argv: str) -> tuple[int, str]:
    capsys.readouterr()
    code = main(list(argv))
    return code, capsys.readouterr().err


def _png(width: int, height: int) -> bytes:
    """A tiny PNG whose header declares ``width`` x ``height`` grey pixels."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        crc = zlib.crc32(kind + data) & 0xFFFFFFFF
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)

    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header)
            + chunk(b"IDAT", zlib.compress(b"\x00" * 64)) + chunk(b"IEND", b""))


# --------------------------------------------------------------------------------------------
# Deeply nested JSON


def test_parse_json_turns_every_failure_into_one_line() -> None:
    with pytest.raises(SchemaError, match=r"^f\.json: not valid JSON here \(nested too deeply"):
        parse_json(DEEP, "f.json", SchemaError)
    with pytest.raises(ValueError, match=r"^f\.json: line 1 column 2: not valid JSON"):
        parse_json("{x", "f.json")
    with pytest.raises(ValueError, match=r"^f\.json: not valid JSON here \(.*digits"):
        parse_json("1" * 10_000, "f.json")
    assert parse_json('{"a": [1]}', "f.json") == {"a": [1]}


def test_deep_json_camera_file(tmp_path: Path) -> None:
    path = tmp_path / "cams.json"
    path.write_text(DEEP)
    with pytest.raises(CameraFileError, match="nested too deeply") as info:
        load_cameras(path)
    _one_line(info.value, path)


def test_deep_json_bundle_manifest(tmp_path: Path) -> None:
    (tmp_path / MANIFEST).write_text(DEEP)
    with pytest.raises(BundleError, match=r"not a readable JSON manifest .*nested too deep"
                       ) as info:
        read_manifest(tmp_path)
    _one_line(info.value, tmp_path / MANIFEST)


def test_deep_json_dataset_and_scene_files(tmp_path: Path, capsys) -> None:
    (tmp_path / "dataset.json").write_text(DEEP)
    with pytest.raises(SchemaError, match="nested too deeply") as info:
        SyntheticDataset(tmp_path)
    _one_line(info.value, tmp_path / "dataset.json")
    scene = tmp_path / "s00000.json"
    scene.write_text(DEEP)
    with pytest.raises(SchemaError, match="nested too deeply") as info:
        read_scene(scene)
    _one_line(info.value, scene)
    code, err = _cli(capsys, "show", str(tmp_path), "--out", str(tmp_path / "pair.png"))
    assert code == 2 and err.count("\n") == 1 and "dataset.json" in err, err
    assert "Traceback" not in err


def test_deep_json_cell_file(tmp_path: Path) -> None:
    (tmp_path / "cells").mkdir()
    cell = tmp_path / "cells" / "drone__gt__seed0.json"
    cell.write_text(DEEP)
    with pytest.raises(ValueError, match=r"not a readable cell file .*nested too deeply") as info:
        load_cells(tmp_path)
    _one_line(info.value, cell)


# --------------------------------------------------------------------------------------------
# A truncated feature cache


def test_a_truncated_feature_cache_is_rebuilt_with_a_warning(tmp_path: Path) -> None:
    from xvmatch.cues.spatial_features import FeatureConfig
    from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene

    scene = simulate_box_scene(SceneConfig(n_people=(3, 4)), n_frames=2, seed=3)
    config = FeatureConfig(n_hypotheses=2)
    first = cached_sequence_features(scene.top, scene.hor, (1920.0, 1080.0), config,
                                     cache_dir=tmp_path)
    (path,) = (tmp_path / "geometry_features").glob("*.npz")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])  # as a killed writer or a full disk leaves it
    with pytest.raises(ValueError, match="not a readable feature cache file") as info:
        FeatureSet.load(path)
    _one_line(info.value, path)
    with pytest.warns(UserWarning, match=rf"{path.name}: not a readable feature cache file.*"
                                         "rebuilding it"):
        again = cached_sequence_features(scene.top, scene.hor, (1920.0, 1080.0), config,
                                         cache_dir=tmp_path)
    assert np.array_equal(again.arrays["pair"], first.arrays["pair"])
    assert path.read_bytes() == data  # rewritten whole


# --------------------------------------------------------------------------------------------
# Images and videos


@pytest.mark.parametrize("ext", [".png", ".jpg", ".bmp", ".tif", ".webp"])
def test_declared_size_of_each_format(ext: str) -> None:
    import cv2

    ok, buf = cv2.imencode(ext, np.zeros((30, 40, 3), np.uint8))
    assert ok and declared_image_size(buf.tobytes()) == (40, 30)


def test_a_png_decompression_bomb_is_refused_before_decoding(tmp_path: Path) -> None:
    bomb = tmp_path / "bomb.png"
    bomb.write_bytes(_png(100_000, 100_000))
    assert bomb.stat().st_size < 200
    with pytest.raises(ImageTooLargeError, match=r"declares 100000x100000 pixels"):
        check_image_size(bomb.read_bytes(), bomb)
    check_image_size(_png(8192, 8192), "ok.png")  # 67 million pixels: fine
    assert 8192 * 8192 <= MAX_IMAGE_PIXELS < 100_000 * 100_000
    with pytest.raises(FrameSourceError, match="declares 100000x100000 pixels") as info:
        with open_frames(bomb) as source:
            source.get(1)
    _one_line(info.value, bomb)
    folder = tmp_path / "frames"
    folder.mkdir()
    (folder / "000001.png").write_bytes(_png(100_000, 100_000))
    with pytest.raises(FrameSourceError, match="declares 100000x100000 pixels") as info:
        with open_frames(folder) as source:
            source.get(1)
    _one_line(info.value, folder / "000001.png")


def test_opencv_s_own_pixel_limit_is_one_line_too(tmp_path: Path) -> None:
    # A format the header check does not read (PPM): OpenCV's CV_IO_MAX_IMAGE_PIXELS refuses it.
    path = tmp_path / "big.pgm"
    path.write_bytes(b"P5\n100000 100000\n255\n" + bytes(64))
    assert declared_image_size(path.read_bytes()) is None
    with pytest.raises(FrameSourceError, match="not a decodable image") as info:
        _decode(str(path))
    _one_line(info.value, path)


def _boxes(tmp_path: Path) -> tuple[Path, Path]:
    top, hor = tmp_path / "top.txt", tmp_path / "hor.txt"
    top.write_text("1,1,10,10,20,40\n1,2,60,10,20,40\n")
    hor.write_text("1,1,15,12,20,40\n1,2,70,12,20,40\n")
    return top, hor


@pytest.mark.parametrize("kind", ["text", "bomb"])
def test_bad_images_through_the_command_line(tmp_path: Path, capsys, kind: str) -> None:
    top, hor = _boxes(tmp_path)
    if kind == "text":
        bad = tmp_path / "top.mp4"  # a video's name, a text file's content
        bad.write_text("frame,id,x,y,w,h\n" * 100)
        what = "no known video container"
    else:
        bad = tmp_path / "top.png"
        bad.write_bytes(_png(100_000, 100_000))
        what = "declares 100000x100000 pixels"
    good = tmp_path / "hor.png"
    import cv2

    cv2.imwrite(str(good), np.zeros((90, 160, 3), np.uint8))
    code, err = _cli(capsys, "associate", "--model", "default", "--top", str(top), "--hor",
                     str(hor), "--top-images", str(bad), "--hor-images", str(good), "--out",
                     str(tmp_path / "pred.csv"))
    assert code == 2 and err.count("\n") == 1, err
    assert str(bad) in err and what in err and "Traceback" not in err
    assert not (tmp_path / "pred.csv").exists()


# --------------------------------------------------------------------------------------------
# Weights files holding pickled code


class _Marker:
    """Unpickled, creates a file: stands for code a crafted weights file would run."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def __reduce__(self):
        return (open, (str(self.path), "w"))


@pytest.mark.parametrize("reader", ["matcher", "appearance", "backbone", "pretrained",
                                    "checkpoint"])
def test_weights_files_with_pickled_code_are_refused(tmp_path: Path, reader: str) -> None:
    torch = pytest.importorskip("torch")
    marker = tmp_path / "ran"
    evil = tmp_path / "evil.pt"
    torch.save({"format": "x", "weight": torch.zeros(2), "payload": _Marker(marker)}, evil)
    with pytest.raises(ValueError) as info:
        if reader == "matcher":
            from xvmatch.models.matcher_file import load_matcher

            load_matcher(evil)
        elif reader == "appearance":
            from xvmatch.models.appearance_net import AppearanceWeights

            AppearanceWeights.from_file(evil)
        elif reader == "backbone":
            from xvmatch.models.appearance_net import ResNetTrunk, load_backbone_weights

            load_backbone_weights(ResNetTrunk(18), evil)
        elif reader == "pretrained":
            from xvmatch.models.pretrained_backbones import MobileNetV2Trunk, load_pretrained_trunk

            load_pretrained_trunk(MobileNetV2Trunk(), "mobilenetv2", evil)
        else:
            from xvmatch.training.checkpoint_files import load_checkpoint_state

            load_checkpoint_state(evil)
    assert "\n" not in str(info.value) and str(evil) in str(info.value)
    assert not marker.exists()


def test_a_corrupt_fit_geometry_resume_checkpoint_through_the_command_line(tmp_path: Path,
                                                                         capsys) -> None:
    pytest.importorskip("lightning")
    cvmhat = tmp_path / "cvmhat"
    cvmhat.mkdir()
    for view in ("top", "hor"):
        (cvmhat / f"S_a_1_{view}.txt").write_text("1,1,2000,10,20,40\n")
    last = tmp_path / "m.pt.run" / "checkpoints" / "last.ckpt"
    last.parent.mkdir(parents=True)
    last.write_bytes(b"PK\x03\x04 cut short")
    code, err = _cli(capsys, "fit-geometry", "--cvmhat", str(cvmhat), "--out",
                     str(tmp_path / "m.pt"), "--resume", "--quiet", "--sim-scenes", "0",
                     "--cache", str(tmp_path / "cache"))
    assert code == 2 and err.count("\n") == 1, err
    assert f"{last}: not a readable checkpoint" in err and "Traceback" not in err
    assert not (tmp_path / "m.pt").exists()
