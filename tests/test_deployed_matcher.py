"""The deployed matcher on the command line: ``xvmatch associate --model BUNDLE`` on image
pairs of a synthetic scene laid out as a user's data (boxes, per-frame cameras, images), its
``--costs`` and ``--draw`` outputs, bad input refused in one line with nothing written, and a
runtime that never imports torch."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import textwrap
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from xvmatch.cli import main
from xvmatch.datasets.synthetic_io import SceneInputs, SyntheticDataset, write_scene_inputs
from xvmatch.formats.mot_boxes import read_mot_boxes, read_predictions
from xvmatch.inference.linking.assignment import assign
from xvmatch.inference.matching.bundle import read_manifest

SCENE = "s00001"
"""The overview scene with the most people (6 in the top view, 2 in the egocentric one)."""


@pytest.fixture(scope="module")
def scene(tmp_path_factory, tiny_synth) -> SceneInputs:
    """Boxes, per-frame cameras and image patterns of one overview scene (2 frames,
    320x180)."""
    record = SyntheticDataset(tiny_synth["overview"]).scene(SCENE)
    return write_scene_inputs(record, tmp_path_factory.mktemp("scene"))


def _associate(capsys, scene: SceneInputs, out: Path, *extra: str, model=None,
               top: Path | None = None, hor: Path | None = None) -> tuple[int, str]:
    """Run ``xvmatch associate`` in-process; (exit code, stderr)."""
    argv = ["associate", "--top", str(top or scene.top), "--hor", str(hor or scene.hor),
            "--out", str(out), "--quiet"]
    if model is not None:
        argv += ["--model", str(model)]
    capsys.readouterr()
    rc = main([*argv, *extra])
    return rc, capsys.readouterr().err


def _images(scene: SceneInputs) -> list[str]:
    return ["--top-images", scene.top_images, "--hor-images", scene.hor_images]


SETTINGS = {
    "images": lambda s: _images(s),
    "images+cameras": lambda s: [*_images(s), "--cameras", str(s.cameras)],
    "boxes": lambda s: ["--image-size", "320x180"],  # boxes only: the camera's size is given
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory, scene, tiny_models) -> dict[str, Path]:
    """The prediction CSV of each input setting, with ``--costs`` (module-scoped: each run is
    shared by the checks on it)."""
    root = tmp_path_factory.mktemp("runs")
    out = {}
    for name, extra in SETTINGS.items():
        pred, costs = root / f"{name}.csv", root / f"{name}.json"
        argv = ["associate", "--top", str(scene.top), "--hor", str(scene.hor), "--out",
                str(pred), "--quiet", "--model", str(tiny_models["full_bundle"]), "--costs",
                str(costs), *extra(scene)]
        assert main(argv) == 0, name
        out[name], out[f"{name} costs"] = pred, costs
    return out


@pytest.mark.parametrize("setting", list(SETTINGS))
def test_each_input_setting_writes_a_prediction_that_evaluate_scores(runs, scene, capsys,
                                                                     setting):
    pred = runs[setting]
    assert pred.read_text().startswith("frame,top_id,hor_id\n")
    read_predictions(pred)
    capsys.readouterr()
    rc = main(["evaluate", "--pred", str(pred), "--top", str(scene.top), "--hor",
               str(scene.hor), "--json"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    scores = json.loads(captured.out)
    assert scores["n_frames"] == 2 and scores["n_gt"] == 4  # 2 people seen in both views x 2


def test_the_settings_give_different_costs(runs):
    """The cues reach the matcher: images and cameras change the cost matrices."""
    costs = {s: json.loads(runs[f"{s} costs"].read_text())["frames"]["1"]["cost"]
             for s in SETTINGS}
    assert not np.allclose(costs["boxes"], costs["images"])
    assert not np.allclose(costs["images"], costs["images+cameras"])


def _check_costs(costs: Path, pred: Path, scene: SceneInputs, gamma: float) -> int:
    """The costs file's matrices solved with ``gamma`` give the CSV's pairs; their count."""
    record = json.loads(costs.read_text())
    assert record["version"] == 1 and record["gamma"] == gamma
    assert sorted(record["frames"]) == ["1", "2"]
    pairs = read_predictions(pred)
    top, hor = read_mot_boxes(scene.top), read_mot_boxes(scene.hor)
    n = 0
    for frame, f in record["frames"].items():
        cost = np.array(f["cost"], dtype=float).reshape(len(f["top_ids"]), len(f["hor_ids"]))
        assert cost.shape == (6, 2) and ((cost >= 0) & (cost <= 1)).all()
        assert f["top_ids"] == top[int(frame)].ids.tolist()
        assert f["hor_ids"] == hor[int(frame)].ids.tolist()
        solved = [(f["top_ids"][a], f["hor_ids"][b]) for a, b in assign(cost, gamma)]
        assert sorted(solved) == sorted(pairs.get(int(frame), [])), frame
        n += len(solved)
    return n


@pytest.mark.parametrize("setting", list(SETTINGS))
def test_costs_solved_with_the_manifests_gamma_give_the_csv(runs, scene, tiny_models, setting):
    gamma = read_manifest(tiny_models["full_bundle"]).gamma
    _check_costs(runs[f"{setting} costs"], runs[setting], scene, gamma)


def test_costs_solved_with_the_gamma_given_give_the_csv(tmp_path, scene, tiny_models, capsys):
    pred, costs = tmp_path / "pred.csv", tmp_path / "c.json"
    rc, err = _associate(capsys, scene, pred, *SETTINGS["images+cameras"](scene), "--costs",
                         str(costs), "--gamma", "0.95", model=tiny_models["full_bundle"])
    assert rc == 0, err
    assert _check_costs(costs, pred, scene, 0.95) > 0  # the untrained matcher pairs someone


def test_draw_writes_one_picture_per_frame(tmp_path, scene, tiny_models, capsys):
    from xvmatch.core.folder_marker import MARKER

    for every, expected in ((1, [MARKER, "frame_000001.jpg", "frame_000002.jpg"]),
                            (2, [MARKER, "frame_000001.jpg"])):
        draw = tmp_path / f"draw{every}"
        rc, err = _associate(capsys, scene, tmp_path / f"p{every}.csv", *_images(scene),
                             "--draw", str(draw), "--draw-every", str(every),
                             model=tiny_models["full_bundle"])
        assert rc == 0, err
        assert sorted(p.name for p in draw.iterdir()) == expected  # no temporary folder left
        assert all(p.stat().st_size > 0 for p in draw.iterdir())


@pytest.mark.parametrize("option", [["--threads", "2"], ["--workers", "2"]])
def test_threads_and_workers_give_the_same_result(tmp_path, runs, scene, tiny_models, capsys,
                                                  option):
    pred, costs = tmp_path / "pred.csv", tmp_path / "c.json"
    rc, err = _associate(capsys, scene, pred, *SETTINGS["images+cameras"](scene), "--costs",
                         str(costs), *option, model=tiny_models["full_bundle"])
    assert rc == 0, err
    assert pred.read_text() == runs["images+cameras"].read_text()
    assert costs.read_text() == runs["images+cameras costs"].read_text()


# --------------------------------------------------------------------------------------------
# Bad input: exit 2, one line naming the file (and frame), nothing written


@dataclass
class Case:
    """A bad invocation: ``make(tmp, scene, models)`` returns the extra arguments, the model
    (or None), the box files to use (or None) and the texts the error line must hold."""

    make: Callable[[Path, SceneInputs, dict], tuple[list[str], object, dict, list[str]]]


def _copy_images(tmp: Path, scene: SceneInputs) -> tuple[Path, str, str]:
    """A copy of the scene's images of both views; (folder, top pattern, hor pattern)."""
    folder = tmp / "images"
    patterns = []
    for view, pattern in (("top", scene.top_images), ("ego", scene.hor_images)):
        (folder / view).mkdir(parents=True)
        for file in sorted(Path(pattern).parent.glob(Path(pattern).name)):
            shutil.copy(file, folder / view / file.name)
        patterns.append(str(folder / view / Path(pattern).name))
    return folder, patterns[0], patterns[1]


def _missing_image(tmp, scene, models):
    folder, top, hor = _copy_images(tmp, scene)
    (folder / "ego" / f"{SCENE}_000002.jpg").unlink()
    return (["--top-images", top, "--hor-images", hor], models["full_bundle"], {},
            [hor, "no image for frame 2"])


def _undecodable_image(tmp, scene, models):
    folder, top, hor = _copy_images(tmp, scene)
    bad = folder / "top" / f"{SCENE}_000002.jpg"
    bad.write_bytes(b"\x00garbage, not a JPEG\xff" * 20)
    return (["--top-images", top, "--hor-images", hor], models["full_bundle"], {},
            [str(bad), "not a decodable image"])


def _image_size(tmp, scene, models):
    return ([*_images(scene), "--image-size", "640x360"], models["full_bundle"], {},
            ["--image-size 640x360 disagrees", scene.hor_images, "320x180"])


def _camera_size(tmp, scene, models):
    cams = Path(shutil.copytree(scene.cameras, tmp / "cams"))
    path = cams / "000002.json"
    doc = json.loads(path.read_text())
    doc["cameras"]["ego"]["width"], doc["cameras"]["ego"]["height"] = 640, 360
    path.write_text(json.dumps(doc))
    return ([*_images(scene), "--cameras", str(cams)], models["full_bundle"], {},
            [str(cams), "camera 'ego' is 640x360", "320x180"])


def _missing_camera_file(tmp, scene, models):
    cams = Path(shutil.copytree(scene.cameras, tmp / "cams"))
    (cams / "000002.json").unlink()
    return ([*_images(scene), "--cameras", str(cams)], models["full_bundle"], {},
            [str(cams), "no camera file for frame 2"])


def _box_outside(tmp, scene, models):
    hor = tmp / "hor.txt"
    hor.write_text(scene.hor.read_text() + "2,9,1000,20,10,30,-1,-1,-1,-1\n")
    return (_images(scene), models["full_bundle"], {"hor": hor},
            [str(hor), "frame 2", "id 9", "outside the 320x180 image"])


def _top_without_hor(tmp, scene, models):
    return (["--top-images", scene.top_images], models["full_bundle"], {},
            ["--top-images and --hor-images together"])


def _cameras_with_box_only(tmp, scene, models):
    return (["--cameras", str(scene.cameras)], models["boxes_bundle"], {},
            [str(models["boxes_bundle"]), "takes no camera cues"])


def _images_with_box_only(tmp, scene, models):
    return (_images(scene), models["boxes_bundle"], {},
            [str(models["boxes_bundle"]), "box-only matcher cannot use images"])


def _images_without_model(tmp, scene, models):
    return (_images(scene), None, {}, ["--top-images", "add --model"])


def _tampered_bundle(tmp, scene, models):
    bundle = Path(shutil.copytree(models["full_bundle"], tmp / "bundle"))
    path = bundle / "matcher.onnx"
    data = bytearray(path.read_bytes())
    data[-10] ^= 0xFF
    path.write_bytes(bytes(data))
    return (_images(scene), bundle, {}, [str(path), "sha256", "does not match"])


def _other_format_version(tmp, scene, models):
    bundle = Path(shutil.copytree(models["full_bundle"], tmp / "bundle"))
    path = bundle / "manifest.json"
    doc = json.loads(path.read_text())
    doc["format_version"] = 2
    path.write_text(json.dumps(doc))
    return (_images(scene), bundle, {}, [str(path), "format version 2"])


BAD = {f.__name__.lstrip("_"): Case(f) for f in (
    _missing_image, _undecodable_image, _image_size, _camera_size, _missing_camera_file,
    _box_outside, _top_without_hor, _cameras_with_box_only,
    _images_with_box_only, _images_without_model, _tampered_bundle, _other_format_version,
)}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_is_one_line_and_writes_nothing(tmp_path, scene, tiny_models, capsys, case):
    extra, model, boxes, texts = BAD[case].make(tmp_path, scene, tiny_models)
    out = tmp_path / "out"
    out.mkdir(exist_ok=True)
    outputs = ["--costs", str(out / "costs.json")]
    if "--top-images" in extra and "--hor-images" in extra:
        outputs += ["--draw", str(out / "draw")]
    rc, err = _associate(capsys, scene, out / "pred.csv", *extra, *outputs, model=model,
                         **boxes)
    assert rc == 2, err
    assert err.count("\n") == 1 and err.startswith("xvmatch: error: "), err
    for text in texts:
        assert text in err, (text, err)
    assert sorted(out.rglob("*")) == [], "output left behind"


@pytest.mark.parametrize("missing", ["out", "costs"])
def test_an_unwritable_destination_fails_before_writing_anything(tmp_path, scene, tiny_models,
                                                                 capsys, missing):
    out = tmp_path / "out"
    out.mkdir()
    paths = {"out": out / "pred.csv", "costs": out / "c.json"}
    paths[missing] = tmp_path / "no_such_folder" / paths[missing].name
    rc, err = _associate(capsys, scene, paths["out"], *_images(scene), "--costs",
                         str(paths["costs"]), "--draw", str(out / "draw"),
                         model=tiny_models["full_bundle"])
    assert rc == 2 and err.count("\n") == 1
    assert f"{paths[missing]}:" in err, err
    assert sorted(out.rglob("*")) == [], "output left behind"


def test_a_camera_size_error_names_the_frames_file(tmp_path, scene, tiny_models, capsys):
    extra, model, _, _ = _camera_size(tmp_path, scene, tiny_models)
    rc, err = _associate(capsys, scene, tmp_path / "pred.csv", *extra, model=model)
    assert rc == 2
    assert "000002.json" in err or "frame 2" in err, err


def test_cameras_without_images_take_the_size_or_ask_for_it(tmp_path, scene, tiny_models,
                                                           capsys):
    rc, err = _associate(capsys, scene, tmp_path / "pred.csv", "--cameras", str(scene.cameras),
                         model=tiny_models["full_bundle"])
    assert rc == 0 or ("--image-size" in err and "images are" not in err), err


def test_cameras_without_images_with_the_image_size(tmp_path, scene, tiny_models, capsys):
    rc, err = _associate(capsys, scene, tmp_path / "pred.csv", "--cameras", str(scene.cameras),
                         "--image-size", "320x180", model=tiny_models["full_bundle"])
    assert rc == 0, err
    read_predictions(tmp_path / "pred.csv")


# --------------------------------------------------------------------------------------------
# The deployed runtime is torch-free


@pytest.mark.slow
def test_the_deployed_runtime_never_imports_torch(tmp_path, scene, tiny_models):
    argv = ["associate", "--top", str(scene.top), "--hor", str(scene.hor), "--out",
            str(tmp_path / "pred.csv"), "--quiet", "--model", str(tiny_models["full_bundle"]),
            *SETTINGS["images+cameras"](scene), "--costs", str(tmp_path / "c.json"), "--draw",
            str(tmp_path / "draw")]
    code = textwrap.dedent("""
        import json, sys
        from xvmatch.cli import main
        rc = main(json.loads(sys.argv[1]))
        assert rc == 0, f"exit code {rc}"
        loaded = [m for m in ("torch", "lightning") if m in sys.modules]
        assert not loaded, f"the deployed runtime imported {loaded}"
    """)
    done = subprocess.run([sys.executable, "-c", code, json.dumps(argv)], capture_output=True,
                          text=True, timeout=120, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "pred.csv").is_file() and (tmp_path / "c.json").is_file()
    assert len(list((tmp_path / "draw").glob("*.jpg"))) == 2
