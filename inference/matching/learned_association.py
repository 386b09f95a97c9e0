"""Association with a deployed matcher bundle on the CPU, without torch.

Per frame pair, in numpy (:mod:`xvmatch.cues.matcher_inputs`): the geometry features of the
spatial-distribution search (on boxes mapped to the ideal setting when the cameras are known),
and the pair cues the frame has: the appearance cost of the two views' crops (embedded by
``appearance.onnx``, all crops of a frame in one batch) and, with cameras, the ray distance and
cheirality cues. Frames go through ``matcher.onnx`` in padded batches; each cost matrix in
[0, 1] goes through the Hungarian assignment with the non-association cost gamma (Eqs. 1-2 of
the geometric-priors paper, :func:`xvmatch.inference.linking.assignment.assign`).

Crowds: the matcher's memory grows with the hypotheses times the box pairs of the frames it
scores at once, and the search for the camera location with the square of the top-view crowd.
A frame over :data:`MAX_PEOPLE_PER_VIEW` people in a view or :data:`MAX_BOX_PAIRS` box pairs is
refused before any work (:func:`check_crowd_size`, one line naming the frame, the view and the
limit); frames under it go through the matcher in batches of at most :data:`MATCHER_BATCH_CELLS`
(hypothesis, pair) cells and crops through the appearance network :data:`EMBED_BATCH` at a
time, so a run's memory stays bounded whatever its length (ordinary frames, tens of people,
are batched as before: the same costs to the bit).

With an INT8 appearance network opened for re-checking (``load_bundle(..., recheck=True)``, as
``associate`` does), a frame whose assignment is not stable within the tolerance the export
measured (how far INT8 moves the costs; :func:`~xvmatch.inference.linking.assignment.
assignment_is_stable`) is scored again with the FP32 network: near ties, where INT8's rounding
could flip a pair, get FP32's answer.

The input settings of one bundle: boxes only (CVMHAT), images and boxes, images, boxes and
cameras (and boxes and cameras). Ids are only used to report pairs, to find O when the user
names the wearer's top-view id, and never reach the matcher.
"""

from __future__ import annotations

import math
import os
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from xvmatch.cues.matcher_inputs import (
    MatcherInputs,
    appearance_cost,
    camera_cues,
    canonical_cues,
    collate_inputs,
    frame_cues,
    matcher_features,
    rectified_boxes,
)
from xvmatch.cues.spatial_features import FeatureConfig, FrameFeatures
from xvmatch.cues.spatial_search import FrameLike
from xvmatch.geometry.camera import FrameCameras
from xvmatch.inference.linking.assignment import assign, assignment_is_stable
from xvmatch.inference.matching.bundle import Bundle, load_bundle

if TYPE_CHECKING:
    from xvmatch.inference.matching.appearance_check import AppearanceCheck

# The crops (OpenCV) and the appearance check (tracklets, pair mining) are imported where a run
# with images uses them: a box-only run starts about a tenth of a second sooner without them.

__all__ = [
    "EMBED_BATCH",
    "MATCHER_BATCH_CELLS",
    "MAX_BOX_PAIRS",
    "MAX_PEOPLE_PER_VIEW",
    "FrameCameraSource",
    "FrameImages",
    "LearnedMatcher",
    "associate_sequence_learned",
    "box_only_costs",
    "check_crowd_size",
    "load_matcher_bundle",
    "non_association_cost",
    "rechecked_costs",
]

MAX_PEOPLE_PER_VIEW = 1000
"""The most boxes of one view in a frame the learned matcher takes. The search for the camera
location O tries every top-view person as O, so a frame's time grows with the square of the
top-view crowd: on one core, 9 s for 500 people and 27-40 s for 1,000 (a few to 65 horizontal
boxes), whose memory the search keeps within about 1 GiB
(:data:`~xvmatch.cues.spatial_search.HYPOTHESIS_BLOCK`); 2,000 would take about four times
as long. The same bound holds for the horizontal view. The matcher was trained on 3-14 people
a frame: far beyond that its costs are an extrapolation, and the handcrafted search takes any
crowd."""

MAX_BOX_PAIRS = 1 << 16
"""The most top x horizontal box pairs (M N) in a frame the learned matcher takes (256 people in
each view). Its graph holds about 1 KB a (hypothesis, pair) cell, with up to
``n_hypotheses`` = 8 hypotheses: about 0.55 GB for a frame at this bound (measured: 256 x 256
people, 0.9 GB resident in all, 1.5 s in the matcher and 3-4 s in the search on one core).
Before this bound, one frame of 1,000 x 600 people took 127 s and 7 GB."""

MATCHER_BATCH_CELLS = 1 << 20
"""The most (hypothesis, top, horizontal) cells of a padded batch the matcher scores in one
call: frames are batched (up to ``batch_size``) while the batch stays within it, about 1 GB of
the graph's memory. 64 frames of 2,048 pairs (e.g. 45 x 45 people) with 8 hypotheses fill it,
so ordinary runs are batched as they always were; a frame over it alone is scored alone (with
:data:`MAX_BOX_PAIRS` that is at most half of it). Before this bound, 20 frames of 300 x 180
people went in one call that asked onnxruntime for 2.2 GB in one buffer."""

EMBED_BATCH = 256
"""The most crops the appearance network embeds in one call (about 1.6 MB of its memory a
crop: 0.4 GB for a batch); a view with more is embedded in batches of this many."""


def check_crowd_size(
    top: Mapping[int, FrameLike],
    hor: Mapping[int, FrameLike],
    frames: Iterable[int] | None = None,
    top_name: str = "the top-view boxes",
    hor_name: str = "the horizontal-view boxes",
    top_offset: int = 0,
) -> None:
    """Refuse a run with a frame the learned matcher does not take: over
    :data:`MAX_PEOPLE_PER_VIEW` boxes in a view or :data:`MAX_BOX_PAIRS` box pairs. Frames
    without boxes in both views are not scored and not checked.

    Args:
        top, hor: ``{frame: record}`` with ``ids`` of each view, the top one re-timed by
            ``top_offset``.
        frames: the frames to associate (default: those of both views).
        top_name, hor_name: the views' box files (or how to name them), for the message.
        top_offset: top frame = horizontal frame + ``top_offset``; the message gives each file
            its own frame numbers.

    Raises:
        ValueError: one line naming the first such frame, its file, the count, the limit, how
            many more frames are over it, and what to do instead.
    """
    order = sorted(set(top) | set(hor)) if frames is None else sorted({int(f) for f in frames})
    over = []
    for f in order:
        t_rec, h_rec = top.get(f), hor.get(f)
        m = 0 if t_rec is None else len(t_rec.ids)
        n = 0 if h_rec is None else len(h_rec.ids)
        if m and n and (max(m, n) > MAX_PEOPLE_PER_VIEW or m * n > MAX_BOX_PAIRS):
            over.append((f, m, n))
    if not over:
        return
    f, m, n = over[0]
    more = f" ({len(over) - 1} more frames are over a limit)" if len(over) > 1 else ""
    if max(m, n) > MAX_PEOPLE_PER_VIEW:
        where = (f"frame {f + top_offset} of {top_name} has {m} boxes" if m >= n else
                 f"frame {f} of {hor_name} has {n} boxes")
        what = (f"{where}; the learned matcher takes at most {MAX_PEOPLE_PER_VIEW} people per "
                f"view in a frame{more}")
    else:
        files = (f"frame {f + top_offset} of {top_name}, frame {f} of {hor_name}" if top_offset
                 else f"{top_name} and {hor_name}")
        what = (f"frame {f} has {m} x {n} = {m * n:,} top x horizontal box pairs ({files}); the "
                f"learned matcher takes at most {MAX_BOX_PAIRS:,} in a frame (256 people in each "
                f"view){more}")
    raise ValueError(f"{what}: its time and memory grow with the crowd; drop --model to match "
                     "with the handcrafted search, which takes any crowd")


def _batches(frames: Sequence[MatcherInputs], batch_size: int,
             cells: int = MATCHER_BATCH_CELLS) -> Iterator[slice]:
    """Consecutive slices of ``frames`` of at most ``batch_size`` frames whose padded batch
    (:func:`~xvmatch.cues.matcher_inputs.collate_inputs`: every frame at the batch's largest
    H, M and N, each at least 1) holds at most ``cells`` cells; a larger frame goes alone."""
    start, size = 0, [1, 1, 1]
    for k, f in enumerate(frames):
        shape = [max(1, v) for v in f.features.shape]
        grown = [max(a, b) for a, b in zip(size, shape, strict=True)]
        if k > start and (k - start >= batch_size or
                          (k - start + 1) * math.prod(grown) > cells):
            yield slice(start, k)
            start, grown = k, shape
        size = grown
    if start < len(frames):
        yield slice(start, len(frames))


@dataclass
class LearnedMatcher:
    """A bundle ready to score frames (see the module docstring).

    Attributes:
        bundle: the loaded bundle.
    """

    bundle: Bundle

    @property
    def feature_config(self) -> FeatureConfig:
        """The geometry features the matcher expects."""
        return self.bundle.manifest.feature_config

    @property
    def gamma(self) -> float:
        """The bundle's non-association cost."""
        return self.bundle.manifest.gamma

    @property
    def cues(self) -> tuple[str, ...]:
        """The pair cues the matcher takes."""
        return self.bundle.manifest.cues

    def descriptors(self, image: np.ndarray, boxes: np.ndarray,
                    vector: str = "descriptors") -> np.ndarray:
        """``(K, D)`` appearance descriptors of the boxes of one image (one batch); with
        ``vector="features"`` or ``"stages"`` the network's unit pooled features or stages instead
        (:meth:`~xvmatch.inference.matching.bundle.Bundle.embed`)."""
        return self.embed(self.crops(image, boxes), vector)

    def embed(self, crops: np.ndarray, vector: str = "descriptors",
              reference: bool = False) -> np.ndarray:
        """:meth:`~xvmatch.inference.matching.bundle.Bundle.embed` of ``(K, H, W, 3)`` crops,
        :data:`EMBED_BATCH` at a time (one call for an ordinary frame's crops)."""
        if crops.shape[0] <= EMBED_BATCH:
            return self.bundle.embed(crops, vector, reference)
        return np.concatenate([self.bundle.embed(crops[k : k + EMBED_BATCH], vector, reference)
                               for k in range(0, crops.shape[0], EMBED_BATCH)])

    @property
    def cue_vector(self) -> str:
        """What the cross-view appearance cue compares: what a site bundle was adapted on
        (``"stages"``, ``"features"`` or ``"descriptors"``), else ``"descriptors"``."""
        adaptation = self.bundle.adaptation
        return "descriptors" if adaptation is None else adaptation.vector

    def cue_vectors(self, image: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        """The vectors :meth:`appearance_cost` takes, of the boxes of one image."""
        return self.descriptors(image, boxes, self.cue_vector)

    def crops(self, image: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        """``(K, H, W, 3)`` uint8 crops of the boxes of one image, as the network takes them."""
        spec = self.bundle.manifest.appearance
        if spec is None:
            raise ValueError(f"{self.bundle.name}: this bundle has no appearance network")
        from xvmatch.formats.crops import box_crops

        return box_crops(image, boxes, spec.crop_size, spec.context)

    def crop_cost(self, top: np.ndarray, hor: np.ndarray, reference: bool = False
                  ) -> np.ndarray:
        """``(M, N)`` appearance cue of top and horizontal crops (:meth:`crops`); with
        ``reference``, embedded by the FP32 network that re-checks INT8 frames."""
        vector = self.cue_vector
        return self.appearance_cost(self.embed(top, vector, reference),
                                    self.embed(hor, vector, reference))

    def appearance_cost(self, top: np.ndarray, hor: np.ndarray) -> np.ndarray:
        """``(M, N)`` appearance cue of raw top ``(M, D)`` and horizontal ``(N, D)`` vectors
        (:meth:`cue_vectors`): ``|a - b| / 2`` of the descriptors, or a site bundle's adapted
        cost (:meth:`~xvmatch.inference.adaptation.site_adaptation.SiteAdaptation.cost`: each view
        standardised on its own, projected, recalibrated)."""
        if self.bundle.adaptation is not None:
            return self.bundle.adaptation.cost(top, hor)
        return appearance_cost(top, hor)

    def inputs(
        self,
        features: FrameFeatures,
        shape: tuple[int, int],
        app: np.ndarray | None = None,
        ray_distance: np.ndarray | None = None,
        cheirality: np.ndarray | None = None,
    ) -> MatcherInputs:
        """One frame's matcher inputs from its features and raw (input-order) cues; cues the
        matcher does not take are left out."""
        cues, mask = frame_cues(
            shape, self.cues,
            app=app if "app" in self.cues else None,
            ray_distance=ray_distance if "ray" in self.cues else None,
            cheirality=cheirality if "cheir" in self.cues else None,
        )
        return MatcherInputs(features, canonical_cues(cues, features), mask)

    def costs(self, frames: Sequence[MatcherInputs], batch_size: int = 64) -> list[np.ndarray]:
        """``(M, N)`` float64 cost matrices in [0, 1] of each frame, canonical order; frames
        go through the graph ``batch_size`` at a time, fewer when their padded batch would hold
        over :data:`MATCHER_BATCH_CELLS` cells.

        Raises:
            MemoryError: onnxruntime could not allocate the batch's memory.
            ValueError: the graph gave non-finite costs (corrupt weights).
        """
        out: list[np.ndarray] = []
        for part in _batches(frames, batch_size):
            chunk = list(frames[part])
            try:
                cost = self.bundle.costs(collate_inputs(chunk)).astype(np.float64)
            except Exception as exc:  # onnxruntime raises its own exception types
                if "Failed to allocate memory" not in str(exc):
                    raise
                h, m, n = (max(f.features.shape[k] for f in chunk) for k in range(3))
                raise MemoryError(f"{self.bundle.name}: onnxruntime could not allocate the "
                                  f"memory to score {len(chunk)} frame(s) of up to {m} x {n} "
                                  f"people and {h} hypotheses") from None
            if not np.isfinite(cost).all():
                raise ValueError(f"{self.bundle.name}: the matcher gave non-finite costs; its "
                                 "weights are corrupt (NaN or infinite): export it again")
            for k, f in enumerate(chunk):
                m, n = f.features.top.shape[0], f.features.hor.shape[0]
                out.append(cost[k, :m, :n])
        return out


def load_matcher_bundle(path_or_default: str | os.PathLike = "default", threads: int = 1,
                        precision: str | None = None, recheck: bool = False) -> LearnedMatcher:
    """Open a bundle folder (or ``"default"``) as a :class:`LearnedMatcher` (``threads``,
    ``precision`` and ``recheck`` as :func:`~xvmatch.inference.matching.bundle.load_bundle`).

    Raises:
        BundleError: an unusable bundle (one line naming the file).
    """
    return LearnedMatcher(load_bundle(path_or_default, threads, precision, recheck))


def non_association_cost(models: Sequence[LearnedMatcher], gamma: float | None = None) -> float:
    """The non-association cost of a run: ``gamma`` when given, else the (first) model's own.

    The one home of this rule: :func:`associate_sequence_learned` and the pipeline
    (:mod:`xvmatch.inference.matching.learned_pipeline`, which writes it into ``--costs``) both use
    it.
    """
    return models[0].gamma if gamma is None else float(gamma)


class FrameImages:
    """Structural type of an image source (:class:`xvmatch.formats.frame_sources.
    FrameSource`): ``get(frame) -> (H, W, 3) uint8 BGR``."""

    def get(self, frame: int) -> np.ndarray:  # pragma: no cover - a protocol
        raise NotImplementedError


class FrameCameraSource:
    """Structural type of a camera source (:class:`xvmatch.formats.camera_frames.
    CameraFrames`): ``get(frame) -> FrameCameras``."""

    def get(self, frame: int) -> FrameCameras:  # pragma: no cover - a protocol
        raise NotImplementedError


def _input_order(feats: FrameFeatures, cost: np.ndarray) -> np.ndarray:
    """A canonical-order cost matrix put back in the input order of the frame's boxes."""
    out = np.empty_like(cost)
    out[np.ix_(feats.top_order, feats.hor_order)] = cost
    return out


def _mirrored(boxes: np.ndarray, axis: float) -> np.ndarray:
    """Boxes of the image mirrored left-right about ``x = axis / 2``."""
    out = np.array(boxes, dtype=float).reshape(-1, 4)
    out[:, 0] = axis - out[:, 0] - out[:, 2]
    return out


def _frame_features(
    top_boxes: np.ndarray,
    hor_boxes: np.ndarray,
    size: tuple[float, float],
    configs: Sequence[FeatureConfig],
    camera: int | None,
    cameras: FrameCameras | None,
    mirror: bool,
) -> list[list[FrameFeatures]]:
    """Features of one frame pair per configuration: ``[plain]``, or ``[plain, mirrored]``.

    The mirrored copy is the same scene seen in a mirror: the horizontal boxes reflected about
    the image centre, the top boxes about any vertical line (the features do not depend on
    where); with cameras, the boxes are first mapped to the ideal setting and then reflected.
    """
    if cameras is not None:
        top_boxes, hor_boxes, camera = rectified_boxes(top_boxes, hor_boxes, cameras, camera)
    groups = []
    for config in configs:
        group = [matcher_features(top_boxes, hor_boxes, size, config, camera)]
        if mirror:
            group.append(matcher_features(_mirrored(top_boxes, 0.0),
                                          _mirrored(hor_boxes, size[0]), size, config, camera))
        groups.append(group)
    return groups


def _features_of_chunk(inputs, size, configs, mirror) -> list[list[list[FrameFeatures]]]:
    """:func:`_frame_features` of a worker's chunk."""
    return [_frame_features(tb, hb, size, configs, cam, cams, mirror)
            for tb, hb, cam, cams in inputs]


def _feature_stream(
    inputs: Sequence[tuple[np.ndarray, np.ndarray, int | None, FrameCameras | None]],
    size: tuple[float, float],
    configs: Sequence[FeatureConfig],
    mirror: bool,
    workers: int,
    chunk: int = 32,
) -> Iterator[list[list[FrameFeatures]]]:
    """:func:`_frame_features` of each ``(top boxes, hor boxes, camera row, cameras)`` in
    order, computed by ``workers`` processes (the spatial-distribution search dominates)."""
    if workers == 1 or len(inputs) <= chunk:
        for tb, hb, cam, cams in inputs:
            yield _frame_features(tb, hb, size, configs, cam, cams, mirror)
        return
    from xvmatch.core.worker_pool import worker_pool

    chunks = [inputs[i : i + chunk] for i in range(0, len(inputs), chunk)]
    # Spawned workers ("spawn": a forked child may inherit onnxruntime's or OpenCV's thread
    # pools and hang) that ignore Ctrl-C; closing the stream early (an error or an interrupt
    # in the caller raises GeneratorExit here) cancels the rest and stops them at once. At most
    # two chunks per worker are asked for ahead of the caller: finished chunks wait in memory
    # until the caller takes them, and a long crowded run must not hold all of its features.
    workers = min(int(workers), len(chunks))
    with worker_pool(workers) as pool:
        ahead: deque = deque()
        for c in chunks:
            ahead.append(pool.submit(_features_of_chunk, c, size, configs, mirror))
            if len(ahead) >= 2 * workers:
                yield from ahead.popleft().result()
        while ahead:
            yield from ahead.popleft().result()


def _matcher_models(
    model: LearnedMatcher | Sequence[LearnedMatcher],
    hor_width: float,
    workers: int,
    top_images: FrameImages | None,
    hor_images: FrameImages | None,
) -> list[LearnedMatcher]:
    """The list of models of :func:`associate_sequence_learned`, its options checked.

    Raises:
        ValueError: a width or worker count out of range, the images of one view only, no
            model, or images for a bundle without an appearance network.
    """
    if not hor_width > 0:
        raise ValueError(f"hor_width must be > 0, got {hor_width}")
    if int(workers) < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if (top_images is None) != (hor_images is None):
        raise ValueError("give the images of both views or of neither")
    models = [model] if isinstance(model, LearnedMatcher) else list(model)
    if not models:
        raise ValueError("no model given")
    if top_images is not None and any(m.bundle.manifest.appearance is None for m in models):
        raise ValueError("images were given but a bundle has no appearance network")
    return models


def _has_both(top: Mapping[int, FrameLike], hor: Mapping[int, FrameLike], frame: int) -> bool:
    """Whether the frame has at least one box in each view."""
    t_rec, h_rec = top.get(frame), hor.get(frame)
    return bool(t_rec is not None and h_rec is not None and len(t_rec.ids) and len(h_rec.ids))


def _feature_inputs(
    top: Mapping[int, FrameLike],
    hor: Mapping[int, FrameLike],
    order: Sequence[int],
    camera_id: int | None,
    cameras: FrameCameraSource | None,
) -> list[tuple[np.ndarray, np.ndarray, int | None, FrameCameras | None]]:
    """``(top boxes, hor boxes, camera row, cameras)`` of each frame of ``order`` with boxes in
    both views, the inputs of :func:`_feature_stream`; the camera row is the top-view row of
    ``camera_id`` (None where it is absent)."""
    inputs = []
    for frame in order:
        if _has_both(top, hor, frame):
            cam = None
            if camera_id is not None:
                hits = np.flatnonzero(np.asarray(top[frame].ids) == camera_id)
                cam = int(hits[0]) if hits.size else None
            inputs.append((top[frame].boxes, hor[frame].boxes, cam,
                           cameras.get(frame) if cameras is not None else None))
    return inputs


@dataclass
class _SequenceScorer:
    """One run of :func:`associate_sequence_learned`: its frames scored in batches, then
    assigned (at once, or after the appearance check when ``judge``).

    Attributes:
        top, hor: ``{frame: record}`` of both views.
        models: the matchers (an ensemble is averaged).
        configs: their distinct feature configurations.
        gamma: the non-association cost.
        batch_size: frames per matcher call.
        top_images, hor_images: image sources of both views, or None.
        cameras: the camera source, or None.
        tolerance: the near-tie tolerance of INT8 frames re-checked with FP32 (None: none).
        judge: whether the appearance cue is checked before any frame is assigned.
        costs_out: receives ``{frame: cost matrix}`` when given.
        rechecked: receives the frames scored again with FP32 when given.
        searched: receives ``{frame: row of the top record}`` of each frame's best camera
            location O of the geometry features' search (their first hypothesis) when given.
        out: ``{frame: [(top_id, hor_id)]}`` of the frames assigned so far.
        pending: ``(frame, features, cues)`` of the frames waiting to be scored.
        held: ``{frame: (cost, box-only cost, appearance cue)}`` of the scored frames waiting
            for the appearance check.
    """

    top: Mapping[int, FrameLike]
    hor: Mapping[int, FrameLike]
    models: list[LearnedMatcher]
    configs: list[FeatureConfig]
    gamma: float
    batch_size: int
    top_images: FrameImages | None
    hor_images: FrameImages | None
    cameras: FrameCameraSource | None
    tolerance: float | None
    judge: bool
    costs_out: dict[int, np.ndarray] | None
    rechecked: list[int] | None
    searched: dict[int, int] | None = None
    out: dict[int, list[tuple[int, int]]] = field(default_factory=dict)
    pending: list[tuple[int, list[list[FrameFeatures]], dict]] = field(default_factory=list)
    held: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=dict)

    @classmethod
    def for_models(
        cls,
        top: Mapping[int, FrameLike],
        hor: Mapping[int, FrameLike],
        models: list[LearnedMatcher],
        gamma: float | None,
        batch_size: int,
        top_images: FrameImages | None,
        hor_images: FrameImages | None,
        cameras: FrameCameraSource | None,
        appearance_check: bool,
        costs_out: dict[int, np.ndarray] | None,
        rechecked: list[int] | None,
    ) -> _SequenceScorer:
        """The run of :func:`associate_sequence_learned`'s arguments: the models' distinct
        feature configurations, gamma (default: the first model's), the re-check tolerance
        (with images) and whether the appearance cue is judged (with images)."""
        configs: list[FeatureConfig] = []
        for m in models:
            if m.feature_config not in configs:
                configs.append(m.feature_config)
        gamma = non_association_cost(models, gamma)
        tolerance = max((m.bundle.recheck for m in models if m.bundle.recheck is not None),
                        default=None) if top_images is not None else None
        return cls(top=top, hor=hor, models=models, configs=configs, gamma=gamma,
                   batch_size=batch_size, top_images=top_images, hor_images=hor_images,
                   cameras=cameras, tolerance=tolerance,
                   judge=bool(appearance_check) and top_images is not None,
                   costs_out=costs_out, rechecked=rechecked)

    def raw_cues(self, frame: int) -> dict:
        """The frame's cues in input order: appearance cost, ray distance, cheirality; and
        the crops of each model that re-checks INT8 frames."""
        t_boxes, h_boxes = self.top[frame].boxes, self.hor[frame].boxes
        cues: dict = {}
        if self.top_images is not None:
            t_image, h_image = self.top_images.get(frame), self.hor_images.get(frame)
            per_model, crops = [], []
            for m in self.models:
                a, b = m.crops(t_image, t_boxes), m.crops(h_image, h_boxes)
                per_model.append(m.crop_cost(a, b))
                crops.append((a, b) if m.bundle.recheck is not None else None)
            cues["app"] = per_model
            cues["crops"] = crops
        if self.cameras is not None:
            manifest = self.models[0].bundle.manifest
            ray, cheir = camera_cues(self.cameras.get(frame), t_boxes, h_boxes, manifest.margin,
                                     manifest.beta)
            cues["ray_distance"], cues["cheirality"] = ray, cheir
        return cues

    def frame_costs(self, entries: list[tuple[int, list[list[FrameFeatures]], dict]]
                    ) -> list[np.ndarray]:
        """Each entry's cost matrix (input order), averaged over models and mirror copies."""
        models, configs = self.models, self.configs
        per_model = []
        for k, m in enumerate(models):
            c = configs.index(m.feature_config)
            items = []
            for frame, groups, cues in entries:
                shape = (len(self.top[frame].ids), len(self.hor[frame].ids))
                for feats in groups[c]:
                    items.append(m.inputs(feats, shape, cues["app"][k] if "app" in cues else None,
                                          cues.get("ray_distance"), cues.get("cheirality")))
            per_model.append(iter(m.costs(items, self.batch_size)))
        return [np.mean([_input_order(f, next(costs))
                         for m, costs in zip(models, per_model, strict=True)
                         for f in groups[configs.index(m.feature_config)]], axis=0)
                for _, groups, _ in entries]

    def with_reference(self, cues: dict) -> dict:
        """The cues with each re-checking model's appearance cost from its FP32 network."""
        app = [c if kept is None else m.crop_cost(*kept, reference=True)
               for m, c, kept in zip(self.models, cues["app"], cues["crops"], strict=True)]
        return {**cues, "app": app}

    def finish(self, frame: int, cost: np.ndarray) -> None:
        """Assign one frame from its cost matrix (and keep the matrix in ``costs_out``)."""
        if self.costs_out is not None:
            self.costs_out[frame] = cost
        pairs = assign(cost, self.gamma)
        t_ids, h_ids = self.top[frame].ids, self.hor[frame].ids
        self.out[frame] = [(int(t_ids[a]), int(h_ids[b])) for a, b in pairs]

    def flush(self) -> None:
        """Score the pending frames (near ties of INT8 again with FP32); assign them, or hold
        them with their box-only costs for the appearance check."""
        pending = self.pending
        costs = self.frame_costs(pending)
        if self.tolerance is not None:
            near = [k for k, cost in enumerate(costs)
                    if not assignment_is_stable(cost, self.gamma, self.tolerance)]
            again = self.frame_costs([(f, g, self.with_reference(c))
                                      for f, g, c in (pending[k] for k in near)])
            for k, cost in zip(near, again, strict=True):
                costs[k] = cost
            if self.rechecked is not None:
                self.rechecked.extend(pending[k][0] for k in near)
        if self.judge:
            boxes = self.frame_costs([(f, g, {k: v for k, v in c.items()
                                              if k not in ("app", "crops")})
                                      for f, g, c in pending])
            for (frame, _, cues), cost, box_cost in zip(pending, costs, boxes, strict=True):
                self.held[frame] = (cost, box_cost, cues["app"][0])
        else:
            for (frame, _, _), cost in zip(pending, costs, strict=True):
                self.finish(frame, cost)
        pending.clear()

    def score(self, frames: Iterable[int],
              stream: Iterator[list[list[FrameFeatures]]]) -> None:
        """Score ``frames`` in order (their features from ``stream``, one item per frame with
        boxes in both views), in batches of ``batch_size`` frames or of about
        ``4 * MATCHER_BATCH_CELLS`` cells; frames without boxes in a view get no pairs."""
        # (hypothesis, pair) cells of the pending frames' features (48 bytes each): a crowded
        # run is scored before they pass about 200 MB, an ordinary one every batch_size frames
        pending_cells = 0
        for frame in frames:
            if not _has_both(self.top, self.hor, frame):
                self.out[frame] = []
                continue
            self.pending.append((frame, next(stream), self.raw_cues(frame)))
            if self.searched is not None and (first := self.pending[-1][1][0][0]).hyp_camera.size:
                row = first.top_order[first.hyp_camera[0]]
                self.searched[frame] = int(row)
            pending_cells += sum(math.prod(f.shape) for g in self.pending[-1][1] for f in g)
            if len(self.pending) >= self.batch_size or pending_cells >= 4 * MATCHER_BATCH_CELLS:
                self.flush()
                pending_cells = 0
        if self.pending:
            self.flush()

    def finish_judged(self, checked: list[AppearanceCheck] | None) -> None:
        """Judge the appearance cue on the held frames (the check goes to ``checked`` when
        given), then assign each with its cost, or its box-only cost where the cue failed."""
        result, use = self.judge_held()
        if checked is not None:
            checked.append(result)
        for frame in sorted(self.held):
            self.finish(frame, self.held[frame][0 if use[frame] else 1])

    def judge_held(self) -> tuple[AppearanceCheck, dict[int, bool]]:
        """The appearance check of the held frames, and whether each keeps its appearance cue
        (else it is matched from its boxes alone)."""
        from xvmatch.inference.matching.appearance_check import (
            MIN_AUC,
            SITE_MIN_AUC,
            check_appearance,
        )

        held = self.held
        manifest = self.models[0].bundle.manifest
        # a site bundle's cue was fitted on pairs like those it is judged on: a higher bar
        bar = SITE_MIN_AUC if self.models[0].bundle.adaptation is not None else MIN_AUC
        result = check_appearance(self.top, self.hor, {f: h[1] for f, h in held.items()},
                                  {f: h[2] for f, h in held.items()}, self.gamma, min_auc=bar)
        # Fitted on single frames, for one bundle's raw cue against its boxes alone: only
        # where no run of consecutive frames could be mined (a video the box-only matcher
        # is rarely sure of keeps its images, which help most there), not for ensembles,
        # site bundles (another cue) or runs with cameras (other box-only costs).
        veto = (manifest.frame_check if len(self.models) == 1 and manifest.adaptation is None
                and self.cameras is None and result.bursts == 0 else None)
        if veto is not None:  # no burst: nothing was judged over time
            use = {f: veto.trusts(h[2], h[1]) for f, h in held.items()}
            dropped = sum(not u for u in use.values())
            result = replace(result, frames=len(use), frames_dropped=dropped)
        else:
            use = dict.fromkeys(held, result.trusted)
        return result, use


def associate_sequence_learned(
    top: Mapping[int, FrameLike],
    hor: Mapping[int, FrameLike],
    hor_width: float,
    model: LearnedMatcher | Sequence[LearnedMatcher],
    camera_id: int | None = None,
    gamma: float | None = None,
    progress: Callable[[Iterable[int]], Iterable[int]] | None = None,
    hor_height: float | None = None,
    frames: Iterable[int] | None = None,
    batch_size: int = 64,
    mirror: bool = False,
    costs_out: dict[int, np.ndarray] | None = None,
    workers: int = 1,
    top_images: FrameImages | None = None,
    hor_images: FrameImages | None = None,
    cameras: FrameCameraSource | None = None,
    rechecked: list[int] | None = None,
    appearance_check: bool = False,
    checked: list[AppearanceCheck] | None = None,
    searched: dict[int, int] | None = None,
) -> dict[int, list[tuple[int, int]]]:
    """Associate every frame on its own with the learned matcher; ``{frame: [(top_id, hor_id)]}``.

    Args:
        top, hor: ``{frame: record}`` with ``ids`` and ``boxes`` (e.g. ``FrameBoxes``).
        hor_width: width of the horizontal image (pixels).
        model: a :class:`LearnedMatcher`, or several: an ensemble whose cost matrices are
            averaged (features computed once per distinct feature configuration).
        camera_id: top-view id of the camera wearer (O given); frames where it is absent
            search O.
        gamma: non-association cost (default: the (first) model's own).
        progress: optional wrapper around the frame iterator (e.g. a progress bar).
        hor_height: height of the horizontal image (default ``hor_width * 9 / 16``).
        frames: frames to process (default the union of both views' frames).
        batch_size: frames per matcher call (fewer in crowds: :data:`MATCHER_BATCH_CELLS`).
        mirror: test-time augmentation: also score the scene mirrored left-right and average
            the two cost matrices (the cues do not change in a mirror); twice the search.
        costs_out: if given, filled with ``{frame: (M, N) cost matrix}`` (rows and columns in
            the input order of the frame's boxes) of every frame with boxes in both views.
        workers: processes computing the geometry features (1: in this process); the result
            is the same for any number.
        top_images, hor_images: image sources of both views (``get(frame)``), for the
            appearance cue; both or neither.
        cameras: the calibrated cameras of each frame (``get(frame)``), for the camera cues and
            the rectified geometry.
        rechecked: if given, filled with the frames scored again with FP32 because their INT8
            assignment was a near tie (models opened with ``recheck``; see the module
            docstring).
        appearance_check: with images, judge the (first) model's appearance cue on these
            frames' own box-only pseudo-matches
            (:func:`~xvmatch.inference.matching.appearance_check.check_appearance`) and, when it
            fails, match every frame from the boxes alone (each frame is then also scored without
            images, and no frame is assigned before the last one is scored); where there is no run
            of consecutive frames to judge on (single image pairs, clips shorter than a burst), a
            single bundle with a frame check (not a site bundle), without cameras, judges each frame
            on its own (:mod:`xvmatch.inference.matching.frame_check`).
        checked: if given, receives the :class:`~xvmatch.inference.matching.appearance_check.
            AppearanceCheck` of a run with ``appearance_check`` and images.
        searched: if given, filled with ``{frame: O's row in the frame's top record}``: each
            frame's best camera location of the (first) geometry features' search
            (:mod:`~xvmatch.inference.matching.search_camera`).

    Raises:
        ValueError: bad options, or a frame over the crowd limits (:func:`check_crowd_size`),
            before any work.
    """
    models = _matcher_models(model, hor_width, workers, top_images, hor_images)
    check_crowd_size(top, hor, frames)
    run = _SequenceScorer.for_models(top, hor, models, gamma, batch_size, top_images,
                                     hor_images, cameras, appearance_check, costs_out, rechecked)
    run.searched = searched
    height = float(hor_height) if hor_height is not None else float(hor_width) * 9.0 / 16.0
    size = (float(hor_width), height)
    order = sorted(set(top) | set(hor)) if frames is None else sorted({int(f) for f in frames})
    stream = _feature_stream(_feature_inputs(top, hor, order, camera_id, cameras), size,
                             run.configs, mirror, workers)
    try:
        run.score(progress(order) if progress else order, stream)
    finally:
        stream.close()  # shuts the worker pool down, also on an error or an interrupt
    if run.judge:
        run.finish_judged(checked)
    return {f: run.out[f] for f in order}


def rechecked_costs(fp32: Sequence[np.ndarray], int8: Sequence[np.ndarray], gamma: float,
                    tolerance: float) -> tuple[list[np.ndarray], int]:
    """What :func:`associate_sequence_learned` uses with INT8 re-checked, for costs known with
    both networks (evaluation): each frame's INT8 costs when its assignment is stable within
    ``tolerance``, else its FP32 costs; and how many were re-checked."""
    out, again = [], 0
    for a, b in zip(fp32, int8, strict=True):
        stable = assignment_is_stable(b, gamma, tolerance)
        out.append(b if stable else a)
        again += not stable
    return out, again

def box_only_costs(
    top: Mapping,
    hor: Mapping,
    frames: Sequence[int],
    matcher,
    hor_size: tuple[int, int],
    cameras=None,
    camera_id: int | None = None,
    progress: Callable[[Iterable[int]], Iterable[int]] | None = None,
    workers: int = 1,
) -> dict[int, np.ndarray]:
    """``{frame: (M, N) cost}`` (input order) of the matcher without the appearance cue.

    Args:
        top, hor: ``{frame: FrameBoxes}``.
        frames: the frames to score.
        matcher: a :class:`LearnedMatcher`.
        hor_size: ``(W, H)`` of the horizontal images.
        cameras: a camera source (``get(frame)``) or None.
        camera_id: the wearer's top-view id, when known.
        progress: wraps the frame iterator.
        workers: processes for the geometry features.
    """
    costs: dict[int, np.ndarray] = {}
    associate_sequence_learned(top, hor, hor_size[0], matcher, camera_id=camera_id,
                               hor_height=hor_size[1], frames=frames, costs_out=costs,
                               progress=progress, cameras=cameras, workers=workers)
    return costs
