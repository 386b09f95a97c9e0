"""A site bundle: a bundle adapted to one site's cameras from the site's own unlabelled videos.

:func:`adapt_to_site` runs the whole adaptation on opened inputs: bursts of frames
(:func:`~xvmatch.inference.adaptation.adaptation_pairs.plan_bursts`), the box-only matcher's costs
on them, the mined pairs, the appearance network's descriptors of the embedded frames, the reference
costs of the network on renders, and the fit (:func:`~xvmatch.inference.adaptation.site_adaptation.
fit_site_adaptation`). :func:`write_site_bundle` writes the source bundle's files unchanged
(byte-identical ONNX files, same sha256) plus ``adaptation.npz`` and a manifest with an
``adaptation`` record: what it was fitted on, the pair counts, the rank and the held-out
figures. Before any of it, the bundle is judged by the pairs it makes on the last block of
the video, which the fit never saw (:mod:`~xvmatch.inference.matching.site_judgement`): a run
that cannot show a gain there is refused. Every file is written into a temporary folder first
and moved into place, the manifest last, so a crash never leaves a half-written bundle.
Torch-free.
"""

from __future__ import annotations

import datetime
import hashlib
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from xvmatch.inference.adaptation.adaptation_pairs import (
    MinedPairs,
    MiningConfig,
    embed_frames,
    mine_pairs,
    plan_bursts,
    reference_costs,
)
from xvmatch.inference.adaptation.site_adaptation import (
    ADAPTATION_FILE,
    ADAPTATION_FORMAT_VERSION,
    AdaptationFit,
    PairSet,
    adaptation_bytes,
    choose_fit,
    fit_site_adaptation,
)
from xvmatch.inference.matching.bundle import MANIFEST
from xvmatch.inference.matching.learned_association import (
    LearnedMatcher,
    associate_sequence_learned,
    box_only_costs,
)
from xvmatch.inference.matching.site_judgement import (
    PairJudgement,
    judge_pairs,
    split_for_judgement,
)

__all__ = [
    "SiteRun",
    "adapt_to_site",
    "adaptation_record",
    "adapted_vectors",
    "json_figure",
    "judge_site",
    "vector_pair_sets",
    "vectors_embedder",
    "write_site_bundle",
]

Progress = Callable[[Iterable, int, str], Iterable]
"""``progress(items, total, what)``: wraps an iterator (e.g. a progress bar)."""


@dataclass(frozen=True, eq=False)
class SiteRun:
    """What :func:`adapt_to_site` found.

    Attributes:
        fit: the fit kept (accepted or refused, with its held-out figures).
        mined: the mined pairs.
        counts: pairs of each kind.
        frames_scored: frames the box-only matcher scored.
        fits: the fit of each vector tried (:func:`adapted_vectors`), ``fit`` among them.
        judgement: the site bundle's pairs against the source's on the held-out block (None:
            not judged, the fit being refused, or ``judge`` off).
    """

    fit: AdaptationFit
    mined: MinedPairs
    counts: dict[str, int]
    frames_scored: int
    fits: dict[str, AdaptationFit] = field(default_factory=dict)
    judgement: PairJudgement | None = None

    @property
    def accepted(self) -> bool:
        """The fit is accepted on its held-out AUC and, when judged, by its pairs."""
        return self.fit.accepted and (self.judgement is None or self.judgement.accepted)


def adapt_to_site(
    top: Mapping,
    hor: Mapping,
    matcher,
    top_images,
    hor_images,
    hor_size: tuple[int, int],
    cameras=None,
    camera_id: int | None = None,
    config: MiningConfig | None = None,
    progress: Progress | None = None,
    workers: int = 1,
    judge: bool = True,
) -> SiteRun:
    """Mine pairs on a site's videos and fit its adaptation (see the module docstring).

    Args:
        top, hor: ``{frame: FrameBoxes}`` of each view (ids only name boxes).
        matcher: a :class:`~xvmatch.inference.matching.learned_association.LearnedMatcher` with an
            appearance network (its raw descriptors are adapted).
        top_images, hor_images: image sources (``get(frame)``) of the views.
        hor_size: ``(W, H)`` of the horizontal images.
        cameras: a camera source, or None.
        camera_id: the wearer's top-view id, when known.
        config: the mining settings.
        progress: wraps each stage's iterator.
        workers: processes for the geometry features.
        judge: hold out the video's last block (:func:`~xvmatch.inference.matching.
            site_judgement.split_for_judgement`), fit on the frames before it, and judge an
            accepted fit by the pairs it makes there (:func:`judge_site`); False: fit on every
            frame, judged by the held-out AUC alone (the benchmarks' ablation).

    Raises:
        ValueError: a matcher without an appearance network, or no frame with boxes in both
            views.
    """
    if matcher.bundle.manifest.appearance is None:
        raise ValueError(f"{matcher.bundle.name}: a box-only matcher has no appearance network "
                         "to adapt; use a bundle with one (e.g. default)")
    config = config or MiningConfig()
    both = [f for f in sorted(set(top) & set(hor)) if len(top[f].ids) and len(hor[f].ids)]
    fitted, judged = split_for_judgement(both, config.burst) if judge else (both, [])
    bursts = plan_bursts(fitted, config.burst, config.max_frames)
    if not bursts:
        raise ValueError(f"no run of {config.burst} consecutive frames with boxes in both views: "
                         "adapt needs video (consecutive frames), not single frames")
    scored = [int(f) for b in bursts for f in b]

    def stage(what: str, total: int):
        if progress is None:
            return None
        return lambda items: progress(items, total, what)

    costs = box_only_costs(top, hor, scored, matcher, hor_size, cameras, camera_id,
                           stage("boxes", len(scored)), workers)
    mined = mine_pairs(top, hor, bursts, costs, matcher.gamma, config)
    n = len(mined.embed_frames)
    vectors = adapted_vectors(matcher.bundle.manifest.appearance)
    embed = vectors_embedder(matcher, vectors)
    top_all = embed_frames(mined.embed_frames, top, top_images, embed, stage("top crops", n))
    hor_all = embed_frames(mined.embed_frames, hor, hor_images, embed,
                           stage("horizontal crops", n))
    sets = vector_pair_sets(mined, top_all, hor_all, matcher.bundle.manifest.appearance, vectors)
    reference = reference_costs(matcher.descriptors)
    fits = {v: fit_site_adaptation(p, calibration="odds", reference=reference)
            for v, p in sets.items()}
    fit = choose_fit(fits)
    judgement = None
    if judge and fit.accepted:
        judgement = judge_site(top, hor, matcher, fit, judged, top_images, hor_images, hor_size,
                               cameras, camera_id, progress, workers)
    return SiteRun(fit, mined, sets[vectors[0]].counts(), len(scored), fits, judgement)


def judge_site(top: Mapping, hor: Mapping, matcher, fit: AdaptationFit, frames: Sequence[int],
               top_images, hor_images, hor_size: tuple[int, int], cameras=None,
               camera_id: int | None = None, progress: Progress | None = None,
               workers: int = 1) -> PairJudgement:
    """The site bundle of ``fit`` judged by its pairs on the held-out ``frames``: each frame
    matched with the images by ``matcher`` and by the site bundle, the appearance check on as
    ``associate`` runs by default, and the two runs' pairs compared against the box-only
    matcher's sure pairs and each view's tracklets (:func:`~xvmatch.inference.matching.
    site_judgement.judge_pairs`). Labels are never read."""
    site = LearnedMatcher(replace(matcher.bundle, adaptation=fit.adaptation))
    frames = [int(f) for f in frames]

    def stage(what: str):
        return None if progress is None else (lambda items: progress(items, len(frames), what))

    costs = box_only_costs(top, hor, frames, matcher, hor_size, cameras, camera_id,
                           stage("held-out boxes"), workers)
    pairs = {}
    for name, model in (("source", matcher), ("site", site)):
        pairs[name] = associate_sequence_learned(
            top, hor, hor_size[0], model, camera_id=camera_id, hor_height=hor_size[1],
            frames=frames, top_images=top_images, hor_images=hor_images, cameras=cameras,
            appearance_check=True, workers=workers, progress=stage(f"held-out, {name}"))
    return judge_pairs(top, hor, frames, costs, matcher.gamma, pairs["source"], pairs["site"])


def vectors_embedder(matcher, vectors: Sequence[str]) -> Callable:
    """``embed(image, boxes) -> (K, sum of sizes)``: every one of ``vectors`` of the boxes,
    side by side, from one run of ``matcher``'s network (for :func:`~xvmatch.inference.adaptation.
    adaptation_pairs.embed_frames`; :func:`vector_pair_sets` splits them)."""
    def embed(image, boxes):
        return np.concatenate(matcher.bundle.embed_vectors(matcher.crops(image, boxes),
                                                           vectors), axis=1)

    return embed


def vector_pair_sets(mined: MinedPairs, top: np.ndarray, hor: np.ndarray, spec,
                     vectors: Sequence[str]) -> dict[str, PairSet]:
    """``{vector: PairSet}`` of the mined pairs from :func:`vectors_embedder`'s side-by-side
    columns (``spec``: the network's :class:`~xvmatch.inference.matching.bundle.AppearanceSpec`)."""
    sets, start = {}, 0
    for vector in vectors:
        cols = slice(start, start + spec.dim(vector))
        start = cols.stop
        sets[vector] = replace(mined.pair_set(top[:, cols], hor[:, cols]), vector=vector)
    return sets


def adapted_vectors(spec) -> tuple[str, ...]:
    """What ``adapt`` fits on for a network with this :class:`~xvmatch.inference.matching.bundle.
    AppearanceSpec`, in order of preference: its pooled stages (else its pooled features) and
    its descriptors when the graph gives them (the stages recover more of a camera change than
    the features, the features more than the descriptors, but each is sometimes refused where
    the descriptors help; :func:`~xvmatch.inference.adaptation.site_adaptation.choose_fit` keeps
    one), else its descriptors alone."""
    for vector in ("stages", "features"):
        if spec.dim(vector) is not None:
            return (vector, "descriptors")
    return ("descriptors",)


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def json_figure(value: float) -> float | None:
    """A measured figure for a JSON record: rounded to 6 decimals, None for NaN (too few pairs
    to judge)."""
    return round(float(value), 6) if np.isfinite(value) else None


def adaptation_record(run: SiteRun, inputs: Mapping[str, str | os.PathLike], sha256: str,
                      version: str) -> dict:
    """The manifest's ``adaptation`` object of an accepted run.

    Args:
        run: the accepted :class:`SiteRun`.
        inputs: ``{role: path}`` of what it was fitted on (box files, images, cameras): each
            recorded by name with its sha256 (files) or size in entries (folders, videos too).
        sha256: the checksum of ``adaptation.npz``.
        version: the xvmatch version.
    """
    fitted = {}
    for role, path in inputs.items():
        p = Path(path)
        if p.is_file():
            fitted[role] = {"name": p.name, "sha256": _sha256(p), "bytes": p.stat().st_size}
        elif p.is_dir():
            fitted[role] = {"name": p.name, "entries": sum(1 for _ in p.iterdir())}
        else:
            fitted[role] = {"name": p.name}
    fit = run.fit
    return {
        "file": ADAPTATION_FILE,
        "sha256": sha256,
        "format_version": ADAPTATION_FORMAT_VERSION,
        "vector": fit.adaptation.vector,
        "rank": int(fit.adaptation.rank),
        "calibration": [float(v) for v in fit.adaptation.calibration],
        "fitted_on": {**fitted, "frames_scored": run.frames_scored,
                      "frames_embedded": len(run.mined.embed_frames),
                      "bursts": run.mined.bursts, "pairs": run.counts},
        "heldout": {"metric": "cross-view verification AUC of pseudo-pairs, last 25% of bursts",
                    "before": round(fit.auc_before, 6), "after": round(fit.auc_after, 6),
                    "by_rank": {str(k): round(v, 6) for k, v in fit.auc_by_rank.items()},
                    "pairs": list(fit.heldout_pairs),
                    "vectors": {v: {"accepted": f.accepted, "before": json_figure(f.auc_before),
                                    "after": json_figure(f.auc_after)}
                                for v, f in run.fits.items()}},
        **({"judged": _judgement_record(run.judgement)} if run.judgement is not None else {}),
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "xvmatch": version,
    }


def _judgement_record(judgement: PairJudgement) -> dict:
    """The manifest's record of the pairs' judgement on the held-out block."""
    def figures(f) -> dict:
        return {"sure_pairs": f.sure, "sure_kept": f.sure_kept, "steady": f.steady,
                "flips": f.flips, "score": f.score}

    return {"metric": "pairs on held-out frames: the box-only matcher's sure pairs kept and "
                      "pairs steady along tracklets (+1), broken or flipped (-1)",
            "frames": judgement.frames, "first": judgement.first, "last": judgement.last,
            "source": figures(judgement.source), "site": figures(judgement.site),
            "gain": judgement.gain, "error": round(judgement.error, 6)}


def _source_files(manifest: Mapping) -> list[str]:
    """The files of a bundle its manifest names, and its licence notice."""
    names = [manifest["matcher"]["file"]]
    app = manifest.get("appearance") or {}
    if app:
        names.append(app["file"])
        if isinstance(app.get("int8"), dict):
            names.append(app["int8"]["file"])
    return names


def write_site_bundle(source: str | os.PathLike, out: str | os.PathLike, run: SiteRun,
                      inputs: Mapping[str, str | os.PathLike], version: str) -> Path:
    """Write the site bundle into the folder ``out`` (which must exist).

    Args:
        source: the source bundle folder (its files are copied unchanged, its manifest less
            its ``frame_check``, fitted for the unadapted cue).
        out: the site bundle folder.
        run: an accepted :class:`SiteRun`.
        inputs: what it was fitted on (:func:`adaptation_record`).
        version: the xvmatch version.

    Returns:
        The path of the written manifest.

    Raises:
        ValueError: a refused run.
    """
    if not run.accepted:
        raise ValueError("adaptation refused: " + (run.fit.reason or run.judgement.message()))
    from xvmatch.core.input_files import read_input_text

    source, out = Path(source), Path(out)
    manifest = json.loads(read_input_text(source / MANIFEST))  # never blocks, bounded lines
    names = _source_files(manifest)
    if (source / "NOTICE.txt").is_file():
        names.append("NOTICE.txt")
    tmp = Path(tempfile.mkdtemp(prefix=".adapt-", dir=out))
    try:
        for name in names:
            shutil.copyfile(source / name, tmp / name)
        data = adaptation_bytes(run.fit.adaptation)
        (tmp / ADAPTATION_FILE).write_bytes(data)
        # The source's frame check judges its unadapted cue; the site's cue is another one.
        manifest.pop("frame_check", None)
        manifest["adaptation"] = adaptation_record(run, inputs,
                                                   hashlib.sha256(data).hexdigest(), version)
        (tmp / MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n", encoding="utf-8")
        stale = out / MANIFEST
        if stale.exists():
            stale.unlink()  # no manifest naming files that are being replaced
        for name in [*names, ADAPTATION_FILE, MANIFEST]:
            os.replace(tmp / name, out / name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out / MANIFEST
