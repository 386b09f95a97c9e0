"""``xvmatch adapt`` end to end on a short rendered video pair (64 frames): the site bundle
(the source's ONNX files byte-identical, ``adaptation.npz``, the manifest's record), its use by
``associate --model SITE/``, and one-line refusals that write nothing (the video being too short
to judge the site bundle's pairs on its held-out frames: issue 69)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from xvmatch.cli import main
from xvmatch.datasets.synthetic_scenes import SynthConfig
from xvmatch.datasets.tracking_video import render_tracking_video, write_tracking_video
from xvmatch.formats.frame_sources import open_frames
from xvmatch.formats.mot_boxes import read_mot_boxes
from xvmatch.inference.adaptation.adaptation_pairs import MiningConfig
from xvmatch.inference.matching.bundle import DEFAULT_BUNDLE, load_bundle
from xvmatch.inference.matching.learned_association import load_matcher_bundle
from xvmatch.inference.matching.site_bundle import adapt_to_site, write_site_bundle


@pytest.fixture(scope="module")
def video(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("video")
    v = render_tracking_video(1, 64, SynthConfig(scenario="drone", n_people=(8, 12), fps=25.0))
    return write_tracking_video(v, folder)


def _args(video: dict[str, Path], out: Path, *extra: str) -> list[str]:
    return ["adapt", "--top", str(video["top"]), "--hor", str(video["hor"]),
            "--top-images", str(video["top_images"]), "--hor-images", str(video["hor_images"]),
            "--out", str(out), "--burst", "8", "--quiet", *extra]


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.slow
def test_adapt_writes_a_site_bundle(video, tmp_path, capsys) -> None:
    """The command refuses this short video: its last 16 frames, held out, are too few to judge
    the site bundle's pairs, and nothing is written. The bundle of a fit accepted on its
    held-out AUC (the library run the command calls, the pairs' judgement off) is written with
    the source's files unchanged, loads, and runs ``associate`` and ``track``."""
    site = tmp_path / "site"
    assert main(_args(video, site)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and ("adaptation refused, nothing written: only 16 held-out frames"
                              in err[0]), err
    assert "give a longer video" in err[0] and not site.exists()
    matcher = load_matcher_bundle("default")
    boxes = {v: read_mot_boxes(video[v]) for v in ("top", "hor")}
    with open_frames(video["top_images"]) as top_images, \
            open_frames(video["hor_images"]) as hor_images:
        run = adapt_to_site(boxes["top"], boxes["hor"], matcher, top_images, hor_images,
                            hor_images.size, config=MiningConfig(burst=8), judge=False)
    assert run.accepted and run.judgement is None
    site.mkdir()
    write_site_bundle(DEFAULT_BUNDLE, site, run, {k: video[k] for k in (
        "top", "hor", "top_images", "hor_images")}, "test")
    for name in ("matcher.onnx", "appearance.onnx"):
        assert _sha(site / name) == _sha(DEFAULT_BUNDLE / name), name
    doc = json.loads((site / "manifest.json").read_text())
    record = doc["adaptation"]
    # The default's frame check was fitted for its unadapted cue: the site bundle drops it.
    assert "frame_check" in json.loads((DEFAULT_BUNDLE / "manifest.json").read_text())
    assert "frame_check" not in doc
    assert record["sha256"] == _sha(site / "adaptation.npz")
    assert record["fitted_on"]["top"]["sha256"] == _sha(video["top"])
    assert record["fitted_on"]["frames_scored"] == 64
    assert record["fitted_on"]["pairs"]["cross_pos"] > 0
    assert record["heldout"]["after"] > record["heldout"]["before"]
    bundle = load_bundle(site)
    assert bundle.adaptation is not None and bundle.adaptation.rank == record["rank"]
    # The default network gives its pooled stages and its descriptors: adapt fits both on the
    # same pairs and keeps the accepted one with the best held-out AUC.
    tried = record["heldout"]["vectors"]
    assert set(tried) == {"stages", "descriptors"}
    best = max((v for v in tried if tried[v]["accepted"]), key=lambda v: tried[v]["after"])
    assert record["vector"] == bundle.adaptation.vector == best
    assert record["heldout"]["after"] == tried[best]["after"]
    assert bundle.adaptation.dim == bundle.manifest.appearance.dim(best)
    pred = tmp_path / "pred.csv"
    short = {}
    for view in ("top", "hor"):  # the first 6 frames are enough to run it
        short[view] = tmp_path / f"{view}.txt"
        short[view].write_text("".join(line + "\n" for line in
                                       video[view].read_text().splitlines()
                                       if int(line.split(",")[0]) <= 6))
    assert main(["associate", "--model", str(site), "--top", str(short["top"]), "--hor",
                 str(short["hor"]), "--top-images", str(video["top_images"]), "--hor-images",
                 str(video["hor_images"]), "--out", str(pred), "--quiet"]) == 0
    assert len(pred.read_text().splitlines()) > 6
    # Tracking takes the site's adapted cross-view appearance cost too.
    tracks = tmp_path / "tracks"
    assert main(["track", "--model", str(site), "--top", str(short["top"]), "--hor",
                 str(short["hor"]), "--top-images", str(video["top_images"]), "--hor-images",
                 str(video["hor_images"]), "--out", str(tracks), "--quiet"]) == 0
    assert (tracks / "top.txt").read_text() and (tracks / "hor.txt").read_text()


@pytest.mark.slow
def test_adapt_refusals_write_nothing(video, tmp_path, capsys) -> None:
    def refused(args: list[str], message: str) -> None:
        assert main(args) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and message in err[0], err
        said.append(err[0])

    said: list[str] = []
    out = tmp_path / "site"
    # a single burst: nothing to hold out, so nothing can be judged
    refused(_args(video, out, "--max-frames", "10", "--burst", "10"),
            "adaptation refused, nothing written: stages: too few confident cross-view "
            "pairs")
    assert "; descriptors: too few confident cross-view pairs" in said[-1]  # both were tried
    assert not out.exists()
    no_images = [a for a in _args(video, out) if a not in ("--top-images",
                                                           str(video["top_images"]))]
    refused(no_images, "give --top-images and --hor-images")
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep")
    refused(_args(video, foreign), "not made by xvmatch adapt")
    assert sorted(p.name for p in foreign.iterdir()) == ["notes.txt"]
    with pytest.raises(SystemExit):  # checked while parsing
        main(_args(video, out, "--burst", "2"))
    assert "--burst: expected an integer in [3, 100]" in capsys.readouterr().err


def test_refusal_advises_boxes_alone_when_the_cue_is_not_above_chance() -> None:
    """A refusal says why for each vector; when the network's own descriptors are not shown
    better than chance on the held-out pairs either, it advises matching from the boxes alone
    (images would only add noise), else keeping the bundle."""
    from xvmatch.commands.adapt import refusal_message
    from xvmatch.inference.adaptation.site_adaptation import AdaptationFit, SiteAdaptation
    from xvmatch.inference.matching.site_bundle import SiteRun

    def run(before: float, pairs: tuple[int, int]) -> SiteRun:
        fits = {v: AdaptationFit(SiteAdaptation.identity(4, v), False, f"{v} did not help",
                                 before, before + 0.01, {}, pairs)
                for v in ("features", "descriptors")}
        return SiteRun(fits["features"], None, {}, 0, fits)

    chance = refusal_message(run(0.505, (40, 400)), "default")
    assert chance.startswith("adaptation refused, nothing written: features: features did not "
                             "help; descriptors: descriptors did not help; nor is the network's")
    assert "held-out AUC 0.505 +/- 0.0" in chance and "without --top-images and --hor-images" \
        in chance
    assert chance.endswith("then score both on a few frames you label")  # the yardstick's caveat
    kept = refusal_message(run(0.8, (40, 400)), "my_bundle")
    assert kept.endswith("; keep using --model my_bundle") and "boxes alone" not in kept
    unjudged = refusal_message(run(float("nan"), (2, 3)), "default")
    assert unjudged.endswith("keep using --model default")
