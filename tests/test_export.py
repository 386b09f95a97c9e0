"""Exporting a matcher file to a bundle: the files, their metadata and checksums, the parity
figures, and that a failed or refused export leaves nothing behind."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import stat
import tempfile
from pathlib import Path

import numpy as np
import pytest
import torch

from xvmatch.cli import main
from xvmatch.cues.spatial_features import (
    FEATURE_VERSION,
    HOR_FEATURES,
    HYP_FEATURES,
    PAIR_FEATURES,
    TOP_FEATURES,
)
from xvmatch.export import onnx_export
from xvmatch.export.onnx_export import PARITY_TOLERANCE, ExportError, export_bundle
from xvmatch.inference.matching.bundle import load_bundle, read_manifest
from xvmatch.models.matcher_file import load_matcher

ROOT = Path(__file__).resolve().parents[1]
onnx = pytest.importorskip("onnx")


@pytest.fixture(autouse=True)
def _one_torch_thread():
    """One intra-op thread: tiny graphs gain nothing from more on a busy 2-core machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def exported(tmp_path_factory, tiny_models) -> tuple[Path, dict]:
    """``tiny_models["full"]`` exported into a new folder, with the default parity frames
    (rendered into a temporary folder, which must be gone afterwards); the folder and the
    manifest returned."""
    root = tmp_path_factory.mktemp("export")
    scratch = root / "system_tmp"
    scratch.mkdir()
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(tempfile, "tempdir", os.fspath(scratch))
            manifest = export_bundle(tiny_models["full"], root / "parent" / "bundle")
    finally:
        torch.set_num_threads(threads)
    assert list(scratch.iterdir()) == [], "the rendered parity frames were left behind"
    return root / "parent" / "bundle", manifest


def _metadata(path: Path) -> dict[str, str]:
    return {p.key: p.value for p in onnx.load(os.fspath(path)).metadata_props}


@pytest.mark.slow
def test_export_writes_the_three_files(exported):
    out, manifest = exported
    assert sorted(p.name for p in out.iterdir()) == ["appearance.onnx", "manifest.json",
                                                    "matcher.onnx"]
    assert json.loads((out / "manifest.json").read_text()) == manifest
    assert manifest["format"] == "xvmatch-bundle" and manifest["format_version"] == 1
    assert manifest["feature_version"] == FEATURE_VERSION
    assert manifest["cues"] == ["app", "ray", "cheir"] and manifest["gamma"] == 0.5
    assert manifest["source"]["file"] == "full.pt"


def test_export_leaves_no_temporary_folder(exported):
    out, _ = exported
    assert [p.name for p in out.parent.iterdir()] == [out.name]


@pytest.mark.parametrize("name", ["matcher.onnx", "appearance.onnx"])
def test_onnx_checker_accepts_the_graphs(exported, name):
    onnx.checker.check_model(onnx.load(os.fspath(exported[0] / name)))


def test_appearance_graph_carries_its_preprocessing(exported, tiny_models):
    out, manifest = exported
    meta = _metadata(out / "appearance.onnx")
    assert meta["xvmatch.role"] == "appearance"
    prep = json.loads(meta["xvmatch.preprocessing"])
    net = load_matcher(tiny_models["full"]).appearance
    h, w = net.preprocessing.input_size
    assert prep["crop_size"] == [w, h] == [16, 32]
    assert prep["colour_order"] == "BGR"
    np.testing.assert_allclose(prep["mean"], net.preprocessing.mean)
    np.testing.assert_allclose(prep["std"], net.preprocessing.std)
    app = manifest["appearance"]
    assert (app["crop_size"], app["colour_order"], app["mean"], app["std"]) == (
        prep["crop_size"], "BGR", prep["mean"], prep["std"])
    assert app["embedding_dim"] == net.embedding_dim
    # The second and third outputs, the pooled trunk activations and the unit-scaled pooled
    # stage maps, are what site adaptation fits on.
    graph = onnx.load(os.fspath(out / "appearance.onnx")).graph
    assert [o.name for o in graph.output] == ["descriptors", "features", "stages"]
    assert app["features_dim"] == net.head[0].in_features
    assert app["stages_dim"] == sum(net.stage_channels) == 4 + 8 + 8 + 16
    assert "; stages: " in meta["xvmatch.output"]
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    session = ort.InferenceSession(os.fspath(out / "appearance.onnx"), options,
                                   providers=["CPUExecutionProvider"])
    for k in (1, 3):
        crops = np.random.default_rng(k).integers(0, 256, (k, h, w, 3), dtype=np.uint8)
        got = session.run(None, {"crops": crops})
        with torch.no_grad():
            ref = net.vectors(net.transform(torch.from_numpy(crops)))
        assert [g.shape for g in got] == [(k, 8), (k, 16), (k, 36)]
        for name, g, r in zip(("descriptors", "features", "stages"), got, ref, strict=True):
            np.testing.assert_allclose(g, r.numpy(), atol=1e-5, rtol=1e-4, err_msg=name)
    from onnx import numpy_helper

    # BGR to RGB reverses the 3 channel planes after the transpose to NCHW, not the innermost
    # axis of the NHWC input (a slow strided copy); the shipped files were rewritten to match.
    first = [n for n in graph.node if n.op_type in ("Transpose", "Slice")][:2]
    assert [n.op_type for n in first] == ["Transpose", "Slice"]
    assert first[1].input[0] == first[0].output[0]
    for folder in (out, ROOT / "inference" / "default_bundle"):
        for name in ("appearance.onnx",) + (("appearance_int8.onnx",) if folder != out else ()):
            g = onnx.load(os.fspath(folder / name)).graph
            consts = {i.name: numpy_helper.to_array(i) for i in g.initializer}
            consts.update({n.output[0]: numpy_helper.to_array(n.attribute[0].t)
                           for n in g.node if n.op_type == "Constant"})
            (sl,) = [n for n in g.node if n.op_type == "Slice" and "transform" in n.name]
            assert consts[sl.input[3]].tolist() == [1], f"{folder / name}: slices axis "\
                f"{consts[sl.input[3]].tolist()}"


def test_matcher_graph_carries_the_feature_layout(exported):
    out, manifest = exported
    meta = _metadata(out / "matcher.onnx")
    assert meta["xvmatch.role"] == "matcher"
    assert meta["xvmatch.feature_version"] == str(FEATURE_VERSION)
    assert json.loads(meta["xvmatch.feature_layout"]) == {
        "top": list(TOP_FEATURES), "hor": list(HOR_FEATURES), "hyp": list(HYP_FEATURES),
        "pair": list(PAIR_FEATURES)}
    assert json.loads(meta["xvmatch.feature_config"]) == manifest["feature_config"]
    assert json.loads(meta["xvmatch.cues"]) == manifest["cues"]
    assert float(meta["xvmatch.gamma"]) == manifest["gamma"]


def test_manifest_sha256_match_the_files(exported):
    out, manifest = exported
    for key in ("matcher", "appearance"):
        record = manifest[key]
        assert hashlib.sha256((out / record["file"]).read_bytes()).hexdigest() == \
            record["sha256"]
    loaded = load_bundle(out)  # the loader's own checks agree
    assert loaded.manifest.uses_images and loaded.manifest.uses_cameras


def test_parity_figures_per_setting(exported):
    parity = exported[1]["parity"]
    assert parity["tolerance"] == PARITY_TOLERANCE
    assert set(parity) == {"tolerance", "boxes", "images", "cameras", "edge cases", "appearance"}
    for setting in ("boxes", "images", "cameras", "edge cases"):
        p = parity[setting]
        assert p["frames"] > 0, setting
        assert 0.0 <= p["max_abs_cost_diff"] <= PARITY_TOLERANCE, setting
        assert p["assignments_identical"] == p["frames"], setting
    assert parity["edge cases"]["frames"] == 4
    assert parity["appearance"]["crops"] > 0
    assert 0.0 <= parity["appearance"]["max_abs_descriptor_diff"] <= PARITY_TOLERANCE


@pytest.mark.slow
def test_a_parity_failure_raises_and_leaves_nothing(tmp_path, tiny_models, tiny_synth,
                                                   monkeypatch):
    monkeypatch.setattr(onnx_export, "PARITY_TOLERANCE", -1.0)
    with pytest.raises(ExportError, match=r"ONNX parity failed \(tolerance -1\): boxes: max "
                       r"\|cost diff\| .*, identical assignments \d+/\d+;.*appearance: max "
                       r"\|descriptor diff\|") as info:
        export_bundle(tiny_models["full"], tmp_path / "bundle",
                      parity_data=tiny_synth["overview"])
    for setting in ("boxes", "images", "cameras", "edge cases"):
        assert f"{setting}: max |cost diff|" in str(info.value)
    assert list(tmp_path.iterdir()) == []  # neither the bundle nor the temporary folder


@pytest.mark.slow
def test_exporting_over_a_bundle_replaces_it(tmp_path, tiny_models, tiny_synth):
    out = tmp_path / "bundle"
    shutil.copytree(tiny_models["full_bundle"], out)
    manifest = export_bundle(tiny_models["boxes"], out, parity_data=tiny_synth["overview"])
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json", "matcher.onnx"]
    assert manifest["cues"] == [] and manifest["appearance"] is None
    assert read_manifest(out).raw == manifest
    assert load_bundle(out).manifest.gamma == 0.6
    assert [p.name for p in tmp_path.iterdir()] == ["bundle"]


@pytest.mark.parametrize("kind", ["folder", "file"])
def test_exporting_into_something_else_is_refused(tmp_path, tiny_models, kind):
    if kind == "folder":
        out = tmp_path / "results"
        out.mkdir()
        (out / "notes.txt").write_text("mine\n")
    else:
        out = tmp_path / "results.txt"
        out.write_text("mine\n")
    with pytest.raises(ExportError, match=r"results.*exists and is not a bundle folder"):
        export_bundle(tiny_models["boxes"], out)
    assert (out / "notes.txt" if kind == "folder" else out).read_text() == "mine\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == [out.name]


@pytest.mark.parametrize("case", ["foreign manifest", "deep manifest", "extra file", "symlink"])
def test_exporting_over_a_folder_it_did_not_write_is_refused(tmp_path, tiny_models, case):
    # issue 28: a user's folder holding a manifest.json, or a bundle with a file the export did
    # not write, must not be emptied; only a bundle of exactly its own files is replaced.
    out = tmp_path / "project"
    if case == "foreign manifest":
        out.mkdir()
        (out / "manifest.json").write_text('{"name": "my project"}\n')
        (out / "notes.txt").write_text("mine\n")
    elif case == "deep manifest":  # nested past the JSON reader's recursion limit
        out.mkdir()
        (out / "manifest.json").write_text("[" * 100_000)
    elif case == "extra file":
        shutil.copytree(tiny_models["boxes_bundle"], out)
        (out / "notes.txt").write_text("mine\n")
    else:
        (tmp_path / "real").mkdir()
        out.symlink_to(tmp_path / "real")
    before = sorted((p.relative_to(tmp_path), p.is_file() and p.read_bytes())
                    for p in tmp_path.rglob("*"))
    with pytest.raises(ExportError, match=r"project: exists and is not a bundle folder"):
        export_bundle(tiny_models["boxes"], out)
    assert sorted((p.relative_to(tmp_path), p.is_file() and p.read_bytes())
                  for p in tmp_path.rglob("*")) == before


def test_export_command_refuses_bad_outputs_at_once(tmp_path, tiny_models, capsys):
    os.mkfifo(tmp_path / "pipe")
    model = tmp_path / "m.pt"
    shutil.copy(tiny_models["boxes"], model)
    for out, words in ((tmp_path / "pipe", "exists and is not a folder"),
                       (tmp_path, "holds the input --model"),
                       (tmp_path / "sub", None)):
        if words is None:  # a user's folder with a manifest.json of its own
            out.mkdir()
            (out / "manifest.json").write_text("{}\n")
            words = "exists and is not a bundle folder"
        rc = main(["export", "--model", str(model), "--out", str(out)])
        err = capsys.readouterr().err
        assert rc == 2 and err.count("\n") == 1 and words in err, err
    assert stat.S_ISFIFO((tmp_path / "pipe").lstat().st_mode)
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["m.pt", "manifest.json", "pipe",
                                                           "sub"]


def test_the_bundle_folder_follows_the_umask(exported, tmp_path):
    probe = tmp_path / "probe"
    probe.mkdir()
    assert stat.S_IMODE(exported[0].stat().st_mode) == stat.S_IMODE(probe.stat().st_mode)


@pytest.mark.slow
def test_export_command_end_to_end(tmp_path, tiny_models, tiny_synth, capsys):
    out = tmp_path / "b"
    rc = main(["export", "--model", str(tiny_models["boxes"]), "--out", str(out),
               "--parity-data", str(tiny_synth["overview"])])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert "parity boxes:" in err and f"wrote {out}" in err
    assert load_bundle(out).manifest.cues == ()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b"]


def test_export_command_with_a_missing_model_file(tmp_path, capsys):
    missing = tmp_path / "missing.pt"
    rc = main(["export", "--model", str(missing), "--out", str(tmp_path / "b")])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.count("\n") == 1 and err.startswith("xvmatch: error: ")
    assert str(missing) in err and "no such matcher file" in err
    assert list(tmp_path.iterdir()) == []
