"""Site adaptation's fit and its file (inference/adaptation/site_adaptation.py), and how a bundle
reads it (inference/matching/bundle.py): synthetic descriptors with a known camera cast, no network
needed except for the bundle checks (the shipped default's files, copied)."""

from __future__ import annotations

import hashlib
import json
import shutil
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.cues.matcher_inputs import appearance_cost
from xvmatch.inference.adaptation.site_adaptation import (
    ADAPTATION_FILE,
    RIDGE,
    AdaptationFit,
    PairSet,
    SiteAdaptation,
    _log_odds,
    _odds_calibration,
    adaptation_bytes,
    better_than_chance,
    choose_fit,
    fit_site_adaptation,
    load_adaptation,
    pair_auc,
)
from xvmatch.inference.matching.bundle import (
    DEFAULT_BUNDLE,
    BundleError,
    load_bundle,
    read_manifest,
)
from xvmatch.inference.matching.learned_association import LearnedMatcher
from xvmatch.inference.matching.site_bundle import adapted_vectors

DIM = 16


def _unit(x: np.ndarray) -> np.ndarray:
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def _site(seed: int, cast: float = 3.0, signal: float = 1.0, people: int = 12,
          frames: int = 40) -> PairSet:
    """Descriptors of ``people`` identities seen by two cameras over ``frames`` frames: each view
    adds its own strong cast (a fixed offset and per-dimension gains) and noise; every frame's
    people give cross-view positives (same identity) and negatives (another identity of the
    frame), within-view positives (same identity, next frame) and negatives. ``signal`` 0: the
    descriptors carry no identity at all."""
    rng = np.random.default_rng(seed)
    identity = rng.normal(size=(people, DIM))
    casts = {v: (cast * rng.normal(size=DIM), np.exp(rng.normal(0, 0.7, DIM))) for v in "th"}
    desc = {"t": [], "h": []}
    for _ in range(frames):
        for v in "th":
            offset, gain = casts[v]
            x = signal * identity + rng.normal(0, 0.6, (people, DIM))
            desc[v].append(_unit(gain * x + offset))
    top, hor = np.concatenate(desc["t"]), np.concatenate(desc["h"])
    base = np.arange(frames)[:, None] * people
    ids = np.arange(people)[None, :]
    same = np.stack([(base + ids).ravel()] * 2, axis=1)
    other = np.stack([(base + ids).ravel(), (base + (ids + 1) % people).ravel()], axis=1)
    nxt = np.stack([(base[:-1] + ids).ravel(), (base[1:] + ids).ravel()], axis=1)
    group = (np.arange(frames)[:, None] * np.ones((1, people), int)).ravel()
    return PairSet(top, hor, {"top": nxt, "hor": nxt}, {"top": other, "hor": other}, same,
                   other, {"top": group[:len(nxt)], "hor": group[:len(nxt)]},
                   {"top": group, "hor": group}, group, group)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 6), min_size=1, max_size=30),
       st.lists(st.integers(0, 6), min_size=1, max_size=30))
def test_pair_auc_is_the_mann_whitney_statistic(pos: list[int], neg: list[int]) -> None:
    """Ties included (small integers): the share of (positive, negative) pairs where the
    positive costs less, ties half, as scipy's ranks give it."""
    from scipy.stats import rankdata

    p, n = np.array(pos, float) / 3, np.array(neg, float) / 3
    brute = ((p[:, None] < n[None, :]) + 0.5 * (p[:, None] == n[None, :])).mean()
    ranks = rankdata(np.concatenate([p, n]))
    scipy_auc = 1.0 - (ranks[: p.size].sum() - p.size * (p.size + 1) / 2) / (p.size * n.size)
    assert pair_auc(p, n) == pytest.approx(brute, abs=1e-12)
    assert pair_auc(p, n) == pytest.approx(scipy_auc, abs=1e-12)


def test_pair_auc_values() -> None:
    assert pair_auc(np.array([0.1, 0.2]), np.array([0.3, 0.4])) == 1.0
    assert pair_auc(np.array([0.5]), np.array([0.5])) == 0.5
    assert pair_auc(np.array([0.9]), np.array([0.1, 0.2])) == 0.0
    assert np.isnan(pair_auc(np.zeros(0), np.array([0.1])))


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 6), st.integers(1, 6))
def test_identity_changes_no_cost(seed: int, m: int, n: int) -> None:
    """The identity adaptation (what a refused fit gives) leaves the appearance cost as it is."""
    rng = np.random.default_rng(seed)
    a, b = _unit(rng.normal(size=(m, DIM))), _unit(rng.normal(size=(n, DIM)))
    assert np.allclose(SiteAdaptation.identity(DIM).cost(a, b), appearance_cost(a, b),
                       atol=1e-12)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000))
def test_transform_follows_a_shifted_camera(seed: int) -> None:
    """Moving a view's descriptors and its mean by the same vector changes nothing (the
    standardisation removes a camera's cast); outputs are unit vectors of the projection's
    rank; the other view is untouched."""
    rng = np.random.default_rng(seed)
    proj = rng.normal(size=(DIM, 5))
    mean, scale = rng.normal(size=DIM), np.exp(rng.normal(size=DIM))
    ad = SiteAdaptation(mean, scale, np.zeros(DIM), np.ones(DIM), proj, np.array([1.0, 0.0]), 5)
    d, shift = rng.normal(size=(7, DIM)), rng.normal(size=DIM)
    moved = SiteAdaptation(mean + shift, scale, np.zeros(DIM), np.ones(DIM), proj,
                           np.array([1.0, 0.0]), 5)
    z = ad.transform(d, "top")
    assert z.shape == (7, 5)
    assert np.allclose(np.linalg.norm(z, axis=1), 1.0)
    assert np.allclose(moved.transform(d + shift, "top"), z, atol=1e-9)
    assert np.allclose(moved.transform(d, "hor"), ad.transform(d, "hor"))


def test_transform_rejects_bad_input() -> None:
    ad = SiteAdaptation.identity(DIM)
    with pytest.raises(ValueError, match="view must be"):
        ad.transform(np.zeros((1, DIM)), "ego")
    with pytest.raises(ValueError, match=r"descriptors must be \(K, 16\)"):
        ad.transform(np.zeros((1, DIM + 1)), "top")


def test_fit_undoes_a_camera_cast() -> None:
    """Under a strong per-view cast the raw cost barely separates identities; the fit accepts,
    beats it on the held-out frames by a wide margin, and its costs rank the held-out pairs
    better too."""
    pairs = _site(0)
    fit = fit_site_adaptation(pairs, calibration="none")
    assert fit.accepted, fit.reason
    assert fit.auc_after > fit.auc_before + 0.1
    assert fit.auc_after > 0.9
    assert set(fit.auc_by_rank) == {0, 2, 4, 8, 16}
    test = pairs.cross_pos_group >= 30
    ad = fit.adaptation
    pos = np.diag(ad.cost(pairs.top[pairs.cross_pos[test, 0]], pairs.hor[pairs.cross_pos[test, 1]]))
    neg = np.diag(ad.cost(pairs.top[pairs.cross_neg[test, 0]], pairs.hor[pairs.cross_neg[test, 1]]))
    assert pair_auc(pos, neg) > 0.9


def test_fit_is_deterministic() -> None:
    pairs = _site(1)
    ref = (np.array([0.1, 0.2, 0.15, 0.05]), np.array([0.4, 0.5, 0.45, 0.35]))
    a = fit_site_adaptation(pairs, calibration="odds", reference=ref)
    b = fit_site_adaptation(_site(1), calibration="odds", reference=ref)
    assert adaptation_bytes(a.adaptation) == adaptation_bytes(b.adaptation)
    assert a.adaptation.calibration[0] > 0


def test_fit_refuses_what_does_not_help() -> None:
    """Descriptors without identity: no rank beats the raw cost on the held-out frames, the fit
    is refused and its adaptation is the identity."""
    fit = fit_site_adaptation(_site(2, signal=0.0))
    assert not fit.accepted
    assert "does not help" in fit.reason
    assert fit.adaptation.rank == 0 and np.array_equal(fit.adaptation.projection, np.eye(DIM))


def test_fit_refuses_too_few_pairs() -> None:
    pairs = _site(3, people=2, frames=6)
    fit = fit_site_adaptation(pairs, min_heldout=10)
    assert not fit.accepted and "too few" in fit.reason


def test_choose_fit_keeps_the_accepted_fit_with_the_best_heldout_auc() -> None:
    def fit(vector: str, accepted: bool, after: float) -> AdaptationFit:
        return AdaptationFit(SiteAdaptation.identity(4, vector), accepted,
                             "" if accepted else "no gain", 0.8, after, {}, (20, 40))

    features, descriptors = fit("features", True, 0.90), fit("descriptors", True, 0.95)
    assert choose_fit({"features": features, "descriptors": descriptors}) is descriptors
    refused = fit("features", False, 0.99)  # a refused fit is never kept, whatever its AUC
    assert choose_fit({"features": refused, "descriptors": descriptors}) is descriptors
    assert choose_fit({"features": refused, "descriptors": fit("descriptors", False, 0.7)}) \
        is refused  # none accepted: the first one's refusal
    tie = fit("features", True, 0.95)
    assert choose_fit({"features": tie, "descriptors": descriptors}) is tie
    with pytest.raises(ValueError, match="no fit"):
        choose_fit({})


def test_adapt_fits_the_richest_vector_the_network_gives() -> None:
    """The stages when the graph gives them, else the features; the descriptors beside them."""
    spec = read_manifest(DEFAULT_BUNDLE).appearance
    assert adapted_vectors(spec) == ("stages", "descriptors")
    assert adapted_vectors(replace(spec, stages_dim=None)) == ("features", "descriptors")
    assert adapted_vectors(replace(spec, stages_dim=None, features_dim=None)) == \
        ("descriptors",)


def test_fit_bad_arguments() -> None:
    with pytest.raises(ValueError, match="calibration must be"):
        fit_site_adaptation(_site(4), calibration="magic")
    with pytest.raises(ValueError, match="needs the reference"):
        fit_site_adaptation(_site(4), calibration="odds")


def test_file_round_trip_and_checks(tmp_path) -> None:
    fit = fit_site_adaptation(_site(5), calibration="none")
    path = tmp_path / ADAPTATION_FILE
    path.write_bytes(adaptation_bytes(fit.adaptation))
    back = load_adaptation(path, {"descriptors": DIM}.get)
    for key, value in fit.adaptation.arrays().items():
        assert np.array_equal(back.arrays()[key], value), key
    with pytest.raises(ValueError, match="'top_mean' must be numbers of shape"):
        load_adaptation(path, {"descriptors": DIM + 1}.get)
    arrays = fit.adaptation.arrays()
    arrays["top_scale"] = -arrays["top_scale"]
    np.savez(path, **arrays)
    with pytest.raises(ValueError, match="must be > 0"):
        load_adaptation(path, {"descriptors": DIM}.get)
    arrays = fit.adaptation.arrays()
    arrays["projection"] = np.array([object()] * 3, dtype=object)
    np.savez(path, **arrays)
    with pytest.raises(ValueError, match=r"not a readable adaptation file|projection"):
        load_adaptation(path, {"descriptors": DIM}.get)
    path.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="not a readable adaptation file"):
        load_adaptation(path, {"descriptors": DIM}.get)


def test_features_take_their_own_ridge_and_vector() -> None:
    """Pairs of the network's features are fitted with :data:`RIDGE` ``["features"]`` and the
    map says what it maps."""
    pairs = replace(_site(6), vector="features")
    fit = fit_site_adaptation(pairs, calibration="none")
    assert fit.accepted and fit.adaptation.vector == "features"
    explicit = fit_site_adaptation(pairs, calibration="none", reg=RIDGE["features"])
    other = fit_site_adaptation(pairs, calibration="none", reg=RIDGE["descriptors"])
    assert np.array_equal(fit.adaptation.projection, explicit.adaptation.projection)
    assert not np.array_equal(fit.adaptation.projection, other.adaptation.projection)
    with pytest.raises(ValueError, match=r"pairs\.vector must be one of"):
        fit_site_adaptation(replace(pairs, vector="colour"))


def test_file_of_a_feature_map_and_of_version_1(tmp_path) -> None:
    """A features map loads only where the network gives features (of its size); a version 1
    file (before ``vector``) maps the descriptors."""
    fit = fit_site_adaptation(replace(_site(5), vector="features"), calibration="none")
    path = tmp_path / ADAPTATION_FILE
    path.write_bytes(adaptation_bytes(fit.adaptation))
    back = load_adaptation(path, {"descriptors": 128, "features": DIM}.get)
    assert back.vector == "features" and back.dim == DIM
    with pytest.raises(ValueError, match="maps the network's features, which this bundle"):
        load_adaptation(path, {"descriptors": DIM}.get)
    with pytest.raises(ValueError, match="'top_mean' must be numbers of shape"):
        load_adaptation(path, {"descriptors": DIM, "features": DIM + 1}.get)
    arrays = fit.adaptation.arrays()
    arrays["vector"] = np.array("colour")
    np.savez(path, **arrays)
    with pytest.raises(ValueError, match="'vector' must be one of"):
        load_adaptation(path, {"descriptors": 128, "features": DIM}.get)
    old = fit_site_adaptation(_site(5), calibration="none").adaptation.arrays()
    old.pop("vector")
    old["format_version"] = np.array(1)
    np.savez(path, **old)
    back = load_adaptation(path, {"descriptors": DIM}.get)
    assert back.vector == "descriptors" and back.dim == DIM
    old["format_version"] = np.array(3)
    np.savez(path, **old)
    with pytest.raises(ValueError, match="format version 3, this xvmatch reads 1, 2"):
        load_adaptation(path, {"descriptors": DIM}.get)


def _site_bundle(tmp_path, adaptation: SiteAdaptation, **record) -> tuple:
    """The shipped default's files plus ``adaptation`` and its manifest record."""
    folder = tmp_path / "site"
    shutil.copytree(DEFAULT_BUNDLE, folder)
    data = adaptation_bytes(adaptation)
    (folder / ADAPTATION_FILE).write_bytes(data)
    doc = json.loads((folder / "manifest.json").read_text())
    doc["adaptation"] = {"file": ADAPTATION_FILE, "sha256": hashlib.sha256(data).hexdigest(),
                         "format_version": 2, "vector": adaptation.vector,
                         "rank": adaptation.rank, "fitted_on": {},
                         "heldout": {}, **record}
    (folder / "manifest.json").write_text(json.dumps(doc))
    return folder, doc


def test_a_site_bundle_runs_int8_only_when_asked(tmp_path, monkeypatch) -> None:
    """The adaptation was fitted on FP32 vectors and INT8's agreement measured without it: where
    the default would pick INT8 by itself, its site bundle keeps FP32."""
    from xvmatch.inference.matching import bundle

    monkeypatch.setattr(bundle, "fast_int8_cpu", lambda: True)
    assert load_bundle("default", recheck=True).precision == "int8"
    dim = read_manifest(DEFAULT_BUNDLE).appearance.embedding_dim
    folder, _ = _site_bundle(tmp_path, SiteAdaptation.identity(dim))
    assert load_bundle(folder, recheck=True).precision == "fp32"
    assert load_bundle(folder, precision="int8").precision == "int8"


@pytest.mark.slow
def test_bundle_reads_an_adaptation(tmp_path) -> None:
    """A site bundle applies its adaptation to the appearance cue; the identity one gives the
    default's costs; a bundle without the key has none."""
    dim = read_manifest(DEFAULT_BUNDLE).appearance.embedding_dim
    rng = np.random.default_rng(0)
    a, b = _unit(rng.normal(size=(3, dim))), _unit(rng.normal(size=(4, dim)))
    default = LearnedMatcher(load_bundle("default"))
    assert default.bundle.adaptation is None
    folder, _ = _site_bundle(tmp_path, SiteAdaptation.identity(dim))
    site = LearnedMatcher(load_bundle(folder))
    assert site.bundle.adaptation is not None
    assert np.allclose(site.appearance_cost(a, b), default.appearance_cost(a, b), atol=1e-12)
    cast = SiteAdaptation(np.full(dim, 0.1), np.ones(dim), np.zeros(dim), np.ones(dim),
                          np.eye(dim)[:, :8], np.array([1.0, 0.0]), 8)
    other = tmp_path / "other"
    other.mkdir()
    folder2, _ = _site_bundle(other, cast)
    adapted = LearnedMatcher(load_bundle(folder2))
    assert np.allclose(adapted.appearance_cost(a, b), cast.cost(a, b))
    assert not np.allclose(adapted.appearance_cost(a, b), default.appearance_cost(a, b))


def test_a_site_bundle_written_before_features_still_loads(tmp_path) -> None:
    """A site bundle of format 1 (no ``vector`` in its file or manifest) maps the descriptors."""
    dim = read_manifest(DEFAULT_BUNDLE).appearance.embedding_dim
    folder, doc = _site_bundle(tmp_path, SiteAdaptation.identity(dim))
    arrays = SiteAdaptation.identity(dim).arrays()
    arrays.pop("vector")
    arrays["format_version"] = np.array(1)
    np.savez(folder / ADAPTATION_FILE, **arrays)
    doc["adaptation"].pop("vector")
    doc["adaptation"].update(format_version=1, sha256=hashlib.sha256(
        (folder / ADAPTATION_FILE).read_bytes()).hexdigest())
    (folder / "manifest.json").write_text(json.dumps(doc))
    site = LearnedMatcher(load_bundle(folder))
    assert site.bundle.adaptation.vector == "descriptors" and site.cue_vector == "descriptors"


@pytest.mark.slow
@pytest.mark.parametrize("vector", ["features", "stages"])
def test_bundle_reads_a_feature_adaptation(tmp_path, vector: str) -> None:
    """A site adapted on the network's features (or stages): the cross-view cue takes those of
    the boxes (``cue_vectors``), the descriptors stay the descriptors."""
    spec = read_manifest(DEFAULT_BUNDLE).appearance
    rng = np.random.default_rng(1)
    dim = spec.dim(vector)
    cast = SiteAdaptation(np.full(dim, 0.01), np.ones(dim), np.zeros(dim), np.ones(dim),
                          np.eye(dim)[:, :8], np.array([1.0, 0.0]), 8, vector)
    folder, _ = _site_bundle(tmp_path, cast)
    site = LearnedMatcher(load_bundle(folder))
    assert site.cue_vector == vector
    assert LearnedMatcher(load_bundle("default")).cue_vector == "descriptors"
    image = rng.integers(0, 256, (120, 160, 3), dtype=np.uint8)
    boxes = np.array([[10.0, 10.0, 30.0, 60.0], [60.0, 20.0, 25.0, 70.0]])
    vectors = site.cue_vectors(image, boxes)
    assert vectors.shape == (2, dim)
    assert site.descriptors(image, boxes).shape == (2, spec.embedding_dim)
    assert np.allclose(site.appearance_cost(vectors, vectors), cast.cost(vectors, vectors))


@pytest.mark.slow
def test_track_embeds_a_feature_site_once_per_box(tmp_path, monkeypatch) -> None:
    """``track --model SITE/`` with a site adapted on the features: each tracklet's middle box
    goes through the network once for both its descriptor and its features."""
    from xvmatch.cli import main
    from xvmatch.datasets.synthetic_scenes import SynthConfig
    from xvmatch.datasets.tracking_video import render_tracking_video, write_tracking_video
    from xvmatch.inference.matching.bundle import Bundle

    dim = read_manifest(DEFAULT_BUNDLE).appearance.features_dim
    cast = SiteAdaptation(np.full(dim, 0.01), np.ones(dim), np.zeros(dim), np.ones(dim),
                          np.eye(dim)[:, :8], np.array([1.0, 0.0]), 8, "features")
    folder, _ = _site_bundle(tmp_path, cast)
    video = write_tracking_video(render_tracking_video(2, 12, SynthConfig(
        scenario="drone", n_people=(4, 6), fps=25.0)), tmp_path)
    runs = []
    original = Bundle.embed_vectors

    def counted(self, crops, vectors, reference=False):
        runs.append(tuple(vectors))
        return original(self, crops, vectors, reference)

    monkeypatch.setattr(Bundle, "embed_vectors", counted)
    assert main(["track", "--model", str(folder), "--top", str(video["top"]), "--hor",
                 str(video["hor"]), "--top-images", str(video["top_images"]), "--hor-images",
                 str(video["hor_images"]), "--out", str(tmp_path / "tracks"), "--quiet"]) == 0
    assert runs and set(runs) == {("descriptors", "features")}
    assert (tmp_path / "tracks" / "hor.txt").read_text()


@pytest.mark.parametrize(("change", "message"), [
    ({"vector": "descriptors"}, "it maps the features but the manifest says descriptors"),
    ({"vector": "colour"}, "'adaptation.vector' must name an output"),
    ({"rank": 2000}, "'adaptation.rank' must be in 0-1280"),
])
def test_bundle_refuses_a_bad_feature_adaptation(tmp_path, change: dict, message: str) -> None:
    dim = read_manifest(DEFAULT_BUNDLE).appearance.features_dim
    folder, _ = _site_bundle(tmp_path, SiteAdaptation.identity(dim, "features"), **change)
    with pytest.raises(BundleError, match=message) as info:
        load_bundle(folder)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(("change", "message"), [
    ({"rank": 999}, "'adaptation.rank' must be in"),
    ({"file": "../x.npz"}, "adaptation.file must be an .npz file name"),
    ({"format_version": 7}, "adaptation format version 7"),
    ({"sha256": "0" * 64}, "sha256 .* does not match"),
    ({"rank": 3}, "rank 0 but the manifest says 3"),
    ({"heldout": 1}, "heldout"),
])
def test_bundle_refuses_a_bad_adaptation(tmp_path, change: dict, message: str) -> None:
    dim = read_manifest(DEFAULT_BUNDLE).appearance.embedding_dim
    folder, _ = _site_bundle(tmp_path, SiteAdaptation.identity(dim), **change)
    with pytest.raises(BundleError, match=message) as info:
        load_bundle(folder)
    assert "\n" not in str(info.value)


def test_better_than_chance_needs_twice_the_standard_error() -> None:
    assert better_than_chance(0.9, (100, 1000))
    assert not better_than_chance(0.55, (20, 200))  # 0.05 above chance, SE about 0.07
    assert better_than_chance(0.55, (20_000, 200_000))
    assert not better_than_chance(0.3, (1000, 1000))  # below chance is not above it
    assert not better_than_chance(float("nan"), (100, 100))
    assert not better_than_chance(0.9, (0, 100))


def test_odds_calibration_sends_a_cue_without_evidence_to_the_neutral_cost() -> None:
    """A site cue whose held-out positives cost no less than its negatives gets a calibration
    that maps every cost to about the reference's likelihood-ratio-1 cost, not the identity
    (which would pass the cue on at full strength)."""
    rng = np.random.default_rng(0)
    ref = (rng.uniform(0.05, 0.3, 400), rng.uniform(0.25, 0.6, 400))
    inverted = (rng.uniform(0.3, 0.5, 200), rng.uniform(0.2, 0.4, 200))
    cal = _odds_calibration(*ref, *inverted)
    assert 0 < cal[0] < 0.01
    mapped = SiteAdaptation.identity(DIM)
    mapped = SiteAdaptation(mapped.top_mean, mapped.top_scale, mapped.hor_mean, mapped.hor_scale,
                            mapped.projection, cal, 0)
    costs = mapped.calibrate(np.linspace(0.05, 0.6, 12))
    assert np.ptp(costs) < 0.01
    alpha_ref, beta_ref = _log_odds(*ref)
    logit = np.log(costs) - np.log1p(-costs)
    assert np.allclose(alpha_ref * logit + beta_ref, 0.0, atol=0.02)  # likelihood ratio 1
    informative = (rng.uniform(0.05, 0.3, 200), rng.uniform(0.25, 0.6, 200))
    assert _odds_calibration(*ref, *informative)[0] > 0.5
