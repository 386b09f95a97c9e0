"""Tests of the on-disk synthetic dataset, its reader, the CLI and visibility noise."""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from xvmatch.commands.lab.show import add_show_parser
from xvmatch.commands.lab.synth import add_synth_parser
from xvmatch.datasets.detector_noise import DetectorNoise
from xvmatch.datasets.synthetic_io import (
    MANIFEST,
    SchemaError,
    SyntheticDataset,
    draw_pair,
    generate_dataset,
    person_crops,
    read_scene,
)
from xvmatch.datasets.synthetic_scenes import SynthConfig
from xvmatch.datasets.visibility_noise import (
    VisibilityNoise,
    apply_visibility_noise,
    miss_probability,
)

SMALL = (160, 90)
CONFIG = SynthConfig(scenario="drone", top_size=SMALL, ego_size=SMALL, n_people=(4, 8))


def _digest(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*")) if p.is_file()
    }


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("synth") / "data"
    generate_dataset(root, CONFIG, n_scenes=3, n_frames=2, seed=7)
    return root


def test_layout(dataset: Path) -> None:
    assert (dataset / MANIFEST).is_file()
    tops = sorted(p.name for p in (dataset / "images" / "top").glob("*.jpg"))
    egos = sorted(p.name for p in (dataset / "images" / "ego").glob("*.jpg"))
    assert tops == egos == [f"s{s:05d}_{f:06d}.jpg" for s in range(3) for f in (1, 2)]
    assert sorted(p.name for p in (dataset / "annotations").iterdir()) == [
        "s00000.json", "s00001.json", "s00002.json"
    ]
    assert not list(dataset.rglob("*.tmp"))


@pytest.mark.slow
def test_same_seed_same_files_any_workers(dataset: Path, tmp_path: Path) -> None:
    again = tmp_path / "again"
    generate_dataset(again, CONFIG, n_scenes=3, n_frames=2, seed=7, workers=2)
    assert _digest(again) == _digest(dataset)
    other = tmp_path / "other"
    generate_dataset(other, CONFIG, n_scenes=1, n_frames=2, seed=8)
    assert _digest(other)["images/top/s00000_000001.jpg"] != _digest(dataset)[
        "images/top/s00000_000001.jpg"
    ]


def test_reader_pairs_boxes_crops(dataset: Path) -> None:
    data = SyntheticDataset(dataset)
    assert len(data) == 6 and data.scene_names == ["s00000", "s00001", "s00002"]
    pairs = list(data)
    assert [(p.scene, p.frame) for p in pairs][:3] == [("s00000", 1), ("s00000", 2),
                                                       ("s00001", 1)]
    pair = pairs[0]
    assert pair.camera_wearer == 0 and pair.scenario == "drone"
    image = pair.ego.load_image()
    assert image.shape == (SMALL[1], SMALL[0], 3)
    assert pair.top.camera.image_size == SMALL
    assert 0 in pair.top.labels.ids and 0 not in pair.ego.labels.ids
    scene = data.scene("s00001")
    boxes = scene.boxes("top")
    assert sorted(boxes) == [1, 2]
    assert np.array_equal(boxes[1].ids, scene.pairs[0].top.labels.ids)
    assert all(v.shape == (len(boxes[f]),) for f, v in scene.visibility("top").items())
    ids, crops = person_crops(image, pair.ego.labels, size=(16, 32))
    assert crops.shape == (len(ids), 32, 16, 3) and crops.dtype == np.uint8
    ids_vis, _ = person_crops(image, pair.ego.labels, size=(16, 32), min_visible=1.01)
    assert ids_vis.size == 0
    picture = draw_pair(pair)
    assert picture.shape[1] == 2 * SMALL[0] + 4 and picture.shape[0] > SMALL[1]
    with pytest.raises(KeyError, match="no scene 'nope'"):
        data.scene("nope")


def _break(dataset: Path, tmp_path: Path, edit) -> Path:
    copy = tmp_path / "broken"
    shutil.copytree(dataset, copy)
    path = copy / "annotations" / "s00000.json"
    doc = json.loads(path.read_text())
    edit(doc)
    path.write_text(json.dumps(doc))
    return path


def _first_person(doc: dict) -> dict:
    return doc["frames"][0]["top"]["people"][0]


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda d: _first_person(d).update(box=[1.0, 2.0, 3.0]),
         r"s00000\.json: frames\[0\]\.top\.people\[0\]\.box: expected numbers of shape \(4,\)"),
        (lambda d: _first_person(d).pop("visible"),
         r"s00000\.json: frames\[0\]\.top\.people\[0\]\.visible: missing field"),
        (lambda d: _first_person(d).update(visible=1.5),
         r"people\[0\]\.visible: expected a number in \[0.0, 1.0\]"),
        (lambda d: d.update(version=99), r"version: unsupported version 99"),
        (lambda d: d["frames"][1]["ego"]["camera"].update(R=[[1, 0, 0], [0, 1, 0], [0, 0, 2]]),
         r"frames\[1\]\.ego\.camera: Camera R must be a proper rotation"),
        (lambda d: d.update(n_frames=5), r"frames: holds 2 frames but n_frames is 5"),
    ],
)
def test_schema_errors_name_file_and_field(dataset: Path, tmp_path: Path, edit, match) -> None:
    path = _break(dataset, tmp_path, edit)
    with pytest.raises(SchemaError, match=match):
        read_scene(path)


def test_unreadable_files(tmp_path: Path) -> None:
    with pytest.raises(SchemaError, match=r"dataset\.json: no such file"):
        SyntheticDataset(tmp_path)
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(SchemaError, match=r"bad\.json: line 1 column 2: not valid JSON"):
        read_scene(bad)


def test_refuses_foreign_folder(tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="not empty and not a synthetic dataset"):
        generate_dataset(tmp_path, CONFIG, n_scenes=1, n_frames=1, seed=0)


def test_refuses_foreign_manifest_and_extra_files(tmp_path: Path) -> None:
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / MANIFEST).write_text('{"name": "someone else\'s dataset"}\n')
    with pytest.raises(ValueError, match=r"foreign.*not a dataset written by xvmatch synth"):
        generate_dataset(foreign, CONFIG, n_scenes=1, n_frames=1, seed=0)
    assert (foreign / MANIFEST).read_text() == '{"name": "someone else\'s dataset"}\n'
    ours = tmp_path / "ours"
    generate_dataset(ours, CONFIG, n_scenes=1, n_frames=1, seed=0)
    (ours / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="not a dataset written by xvmatch synth"):
        generate_dataset(ours, CONFIG, n_scenes=1, n_frames=1, seed=1)
    assert (ours / "notes.txt").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["foreign", "ours"]


def test_rerun_replaces_the_whole_dataset(tmp_path: Path) -> None:
    root = tmp_path / "data"
    generate_dataset(root, CONFIG, n_scenes=3, n_frames=1, seed=0)
    manifest = json.loads((root / MANIFEST).read_text())
    assert manifest["generator"] == "xvmatch synth"
    generate_dataset(root, CONFIG, n_scenes=1, n_frames=1, seed=1)
    assert sorted(p.name for p in (root / "annotations").iterdir()) == ["s00000.json"]
    assert sorted(p.name for p in (root / "images" / "top").iterdir()) == [
        "s00000_000001.jpg"]
    assert len(SyntheticDataset(root)) == 1
    assert [p.name for p in tmp_path.iterdir()] == ["data"]  # no temporary folder left


def test_interrupted_run_leaves_the_target_as_it_was(tmp_path: Path) -> None:
    def interrupt(_: int) -> None:
        raise KeyboardInterrupt

    new = tmp_path / "new"
    with pytest.raises(KeyboardInterrupt):
        generate_dataset(new, CONFIG, n_scenes=2, n_frames=1, seed=0, progress=interrupt)
    assert list(tmp_path.iterdir()) == []  # neither the target nor a temporary folder
    old = tmp_path / "old"
    generate_dataset(old, CONFIG, n_scenes=2, n_frames=1, seed=0)
    before = _digest(old)
    with pytest.raises(KeyboardInterrupt):
        generate_dataset(old, CONFIG, n_scenes=3, n_frames=1, seed=5, progress=interrupt)
    assert _digest(old) == before
    assert [p.name for p in tmp_path.iterdir()] == ["old"]
    generate_dataset(old, CONFIG, n_scenes=1, n_frames=1, seed=5)  # and the next run works
    assert len(SyntheticDataset(old)) == 1


def _cli(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="xvmatch")
    sub = parser.add_subparsers(dest="command", required=True)
    add_synth_parser(sub)
    add_show_parser(sub)
    args = parser.parse_args(argv)
    return args.func(args)


def test_cli_synth_and_show(tmp_path: Path) -> None:
    out = tmp_path / "cli"
    code = _cli(["synth", "--out", str(out), "--scenario", "overview", "--scenes", "2",
                 "--frames", "1", "--seed", "3", "--people", "3:5", "--size", "160x90",
                 "--workers", "1", "--quiet"])
    assert code == 0
    data = SyntheticDataset(out)
    assert data.scenario == "overview" and len(data) == 2
    picture = tmp_path / "pair.png"
    assert _cli(["show", str(out / "images" / "ego" / "s00001_000001.jpg"),
                 "--out", str(picture)]) == 0
    assert picture.stat().st_size > 1000
    assert _cli(["show", str(out), "--scene", "s00000", "--out", str(picture)]) == 0
    with pytest.raises(ValueError, match=r"frame 4 out of range 1\.\.1"):
        _cli(["show", str(out), "--frame", "4", "--out", str(picture)])
    with pytest.raises(ValueError, match="no such file or folder"):
        _cli(["show", str(tmp_path / "missing.jpg")])


def test_cli_rejects_bad_arguments(capsys) -> None:
    with pytest.raises(SystemExit):
        _cli(["synth", "--out", "x", "--people", "5:3"])
    assert "need 1 <= MIN <= MAX" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        _cli(["synth", "--out", "x", "--size", "640"])
    assert "expected WIDTHxHEIGHT" in capsys.readouterr().err


def test_visibility_noise(dataset: Path) -> None:
    noise = VisibilityNoise(base=DetectorNoise(jitter=0.0, miss_rate=0.0, false_per_frame=0.0),
                            hidden_miss=1.0, power=1.0)
    assert miss_probability(np.array([1.0, 0.5, 0.0]), noise).tolist() == [0.0, 0.5, 1.0]
    scene = SyntheticDataset(dataset).scene("s00000")
    frames, visible = scene.boxes("ego"), scene.visibility("ego")
    fully = {f: np.ones(len(b)) for f, b in frames.items()}
    kept = apply_visibility_noise(frames, fully, SMALL, noise, seed=1, view="ego")
    assert all(np.array_equal(kept[f].ids, frames[f].ids) for f in frames)
    hidden = {f: np.zeros(len(b)) for f, b in frames.items()}
    gone = apply_visibility_noise(frames, hidden, SMALL, noise, seed=1, view="ego")
    assert all(len(gone[f]) == 0 for f in frames)
    a = apply_visibility_noise(frames, visible, SMALL, VisibilityNoise(), seed=4, view="ego")
    b = apply_visibility_noise(frames, visible, SMALL, VisibilityNoise(), seed=4, view="ego")
    assert all(np.array_equal(a[f].boxes, b[f].boxes) for f in frames)
    top = scene.boxes("top")
    kept_top = apply_visibility_noise(top, {f: np.zeros(len(b)) for f, b in top.items()},
                                      SMALL, noise, seed=1, view="top", keep_ids=(0,))
    assert all(kept_top[f].ids.tolist() == [0] for f in top)
    with pytest.raises(ValueError, match="visibility of shape"):
        apply_visibility_noise(frames, {f: np.ones(1) for f in frames} | {1: np.ones(99)},
                               SMALL, noise, seed=1, view="ego")
