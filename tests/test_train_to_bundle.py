"""From ``xvmatch train`` to a bundle ``associate`` runs (issue 69, item 7): ``export
--appearance`` pairs a trained appearance network with a matcher, a wrong file is named for what
it is with the command to use, and the whole path runs on a tiny training run."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from tests.conftest import TINY_APPEARANCE
from xvmatch.cli import main
from xvmatch.export.appearance_pairing import DEFAULT_CROP_CONTEXT, pair_appearance
from xvmatch.formats.crops import box_crops
from xvmatch.inference.matching.bundle import load_bundle
from xvmatch.models.appearance_net import (
    appearance_from_weights,
    appearance_small,
    save_appearance_weights,
)
from xvmatch.models.matcher_file import MatcherFileError, load_matcher

REPO = Path(__file__).resolve().parents[1]
SIZE = (32, 16)  # (height, width) of the trained network's crops, as the training tests use


@pytest.fixture(autouse=True)
def _one_torch_thread():
    """One intra-op thread: tiny networks gain nothing from more on a busy 2-core machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def weights(tmp_path_factory) -> Path:
    """An appearance weights file as ``xvmatch train`` writes it (an untrained tiny network,
    seeded, with a crop context in its notes other than the default)."""
    torch.manual_seed(3)
    net = appearance_small(**TINY_APPEARANCE).eval()
    path = tmp_path_factory.mktemp("weights") / "appearance_weights.pt"
    save_appearance_weights(net, path, {"context": 0.2, "epochs": 1, "train_data": ["d"]})
    return path


def test_pairing_puts_the_trained_network_in_the_matcher(weights, tiny_models) -> None:
    paired = pair_appearance(weights, tiny_models["full"])
    original = load_matcher(tiny_models["full"])
    # the matcher's own weights are untouched; the appearance network is the file's
    for name, value in original.matcher.state_dict().items():
        assert torch.equal(value, paired.matcher.state_dict()[name]), name
    trained = appearance_from_weights(weights)
    for name, value in trained.state_dict().items():
        assert torch.equal(value, paired.appearance.state_dict()[name]), name
    assert paired.crop_context == pytest.approx(0.2) != DEFAULT_CROP_CONTEXT
    record = paired.meta["appearance_pairing"]
    assert record["appearance"]["file"] == "appearance_weights.pt"
    assert record["matcher"]["file"] == tiny_models["full"].name
    assert len(record["appearance"]["sha256"]) == 64 and paired.meta["k"] == 1


def test_an_appearance_file_given_as_a_matcher_says_what_to_do(weights) -> None:
    """What the issue met: ``export --model runs/.../appearance_weights.pt``."""
    with pytest.raises(MatcherFileError, match=r"an appearance weights file \(xvmatch train\), "
                       r"not a matcher file; .*xvmatch export --appearance "):
        load_matcher(weights)


def test_associate_names_an_appearance_file_given_as_its_model(weights, tmp_path, capsys,
                                                              monkeypatch) -> None:
    monkeypatch.setenv("XVMATCH_CACHE", str(tmp_path / "cache"))  # a .pt model's export cache
    top, hor = tmp_path / "top.txt", tmp_path / "hor.txt"
    top.write_text("1,1,10,10,5,12\n1,2,30,12,5,12\n")
    hor.write_text("1,1,40,20,20,60\n1,2,100,22,20,60\n")
    assert main(["associate", "--top", str(top), "--hor", str(hor), "--image-size", "320x180",
                 "--model", str(weights), "--out", str(tmp_path / "pred.csv")]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith(f"xvmatch: error: {weights}: an appearance weights file")
    assert f"xvmatch export --appearance {weights} --out BUNDLE/" in err
    assert not (tmp_path / "pred.csv").exists()


def test_wrong_files_given_as_appearance_are_named(weights, tiny_models, tmp_path) -> None:
    with pytest.raises(ValueError, match=r"--appearance .*: a matcher file, not an appearance "
                       r"weights file; export it as it is: xvmatch export --model"):
        pair_appearance(tiny_models["full"])
    checkpoint = tmp_path / "last.ckpt"  # the keys Lightning writes into every checkpoint
    torch.save({"pytorch-lightning_version": "2.6.6", "epoch": 0, "state_dict": {}}, checkpoint)
    with pytest.raises(ValueError, match=r"a Lightning checkpoint, not an appearance weights "
                       r"file; give the appearance_weights.pt"):
        pair_appearance(checkpoint)
    with pytest.raises(ValueError, match=r"--appearance .*none.pt: no such appearance weights "
                       "file"):
        pair_appearance(tmp_path / "none.pt")
    text = tmp_path / "notes.pt"
    text.write_text("not torch")
    with pytest.raises(ValueError, match=r"--appearance .*notes.pt: not a torch file"):
        pair_appearance(text)
    with pytest.raises(MatcherFileError, match=r"a box-only matcher .* has no use for an "
                       r"appearance network; .* --model default"):
        pair_appearance(weights, tiny_models["boxes"])


def test_export_needs_a_model_or_an_appearance_network(tmp_path, capsys) -> None:
    assert main(["export", "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err
    assert "give --model MATCHER" in err and "--appearance" in err
    assert not (tmp_path / "b").exists()


def _train_args(data: Path, root: Path) -> list[str]:
    """``xvmatch train`` on the CPU recipe, shrunk: 32x16 crops, a 4-8-8-16 trunk, one epoch
    of two batches (as tests/test_appearance_training.py runs it)."""
    return [
        "train", "--config", str(REPO / "configs" / "appearance_cpu.yaml"),
        "--data.init_args.train_data", f"[{data}]", "--data.init_args.val_data", str(data),
        "--data.init_args.input_height", str(SIZE[0]),
        "--data.init_args.input_width", str(SIZE[1]), "--data.init_args.workers", "1",
        "--model.init_args.net.init_args.input_size", f"[{SIZE[0]}, {SIZE[1]}]",
        "--model.init_args.net.init_args.widths", "[4, 8, 8, 16]",
        "--trainer.default_root_dir", str(root), "--trainer.max_epochs", "1",
        "--trainer.limit_train_batches", "2", "--trainer.enable_progress_bar", "false",
    ]


@pytest.mark.slow
def test_train_then_export_then_associate(tmp_path, monkeypatch, capsys) -> None:
    """The path a user follows: render, train, run the export command ``train`` printed,
    associate with images and cameras with the bundle; the bundle's appearance network gives
    the torch network's descriptors."""
    monkeypatch.chdir(tmp_path)  # the config's relative runs/ folder lands here
    data = tmp_path / "data"
    assert main(["synth", "--out", str(data), "--scenario", "overview", "--scenes", "3",
                 "--frames", "2", "--seed", "11", "--size", "320x180", "--people", "3:6",
                 "--quiet"]) == 0
    assert main(_train_args(data, tmp_path)) == 0
    out = capsys.readouterr().out
    printed = [line.split() for line in out.splitlines()
               if line.strip().startswith("xvmatch export --appearance")]
    assert len(printed) == 1, out
    weights = Path(printed[0][printed[0].index("--appearance") + 1])
    assert weights.is_file() and weights.name == "appearance_weights.pt"

    bundle = tmp_path / "bundle"
    command = [a if a != "BUNDLE/" else str(bundle) for a in printed[0][1:]]
    assert main([*command, "--parity-data", str(data)]) == 0
    err = capsys.readouterr().err
    assert "pairing the appearance network" in err and f"wrote {bundle}" in err
    assert f"xvmatch associate --model {bundle}" in err

    scene = data / "mot" / "s00000"
    pred = tmp_path / "pred.csv"
    assert main(["associate", "--model", str(bundle), "--top", str(scene / "top.txt"),
                 "--hor", str(scene / "hor.txt"), "--top-images",
                 str(data / "images" / "top" / "s00000_*.jpg"), "--hor-images",
                 str(data / "images" / "ego" / "s00000_*.jpg"), "--cameras",
                 str(scene / "cameras"), "--out", str(pred)]) == 0
    rows = pred.read_text().splitlines()
    assert rows[0] == "frame,top_id,hor_id" and len(rows) > 1, rows
    assert main(["evaluate", "--pred", str(pred), "--top", str(scene / "top.txt"),
                 "--hor", str(scene / "hor.txt")]) == 0

    # The bundle's appearance network against the trained torch network, on real crops.
    opened = load_bundle(bundle)
    spec = opened.manifest.appearance
    assert spec is not None and spec.arch == "small"
    boxes = np.loadtxt(scene / "top.txt", delimiter=",", ndmin=2)
    frame1 = boxes[boxes[:, 0] == 1, 2:6]
    image = cv2.imread(str(data / "images" / "top" / "s00000_000001.jpg"))
    crops = box_crops(image, frame1, (SIZE[1], SIZE[0]), context=DEFAULT_CROP_CONTEXT)
    net = appearance_from_weights(weights)
    with torch.no_grad():
        expected = net.embed_crops(torch.from_numpy(crops)).numpy()
    got = opened.embed(crops)
    assert got.shape == expected.shape == (len(frame1), 128)
    np.testing.assert_allclose(got, expected, atol=1e-4)
    assert not np.allclose(got[0], got[1:], atol=1e-3)  # different people, different vectors
