"""Whether a run's cameras can be trusted, judged on the run's own frames (issue 31).

Cameras calibrated wrong (a top camera further off than its refinement reaches, or both cameras
several degrees off) give the learned matcher ray distances (geometric-priors Eq. 6) that lie,
and it trusts them: on rendered videos it then falls up to 35 Eq. 9 points below the boxes alone
(docs/method.md, "the camera check"). Two signs, each weak alone, say so without labels:

* even the best turn of the top camera leaves the head rays apart: the refinement's loss
  (:mod:`xvmatch.inference.matching.camera_refinement`) stays above :data:`DOUBT_LOSS`. Cameras that
  help can also end there (an egocentric camera off anew every frame), so this only opens the check.
  A top camera that changes from frame to frame (a drone in flight, from its telemetry) has at
  most the constant part of its error refined, so nothing vouches for the rest: its check is
  always open;
* the box-only matcher's pseudo-matches, the pairs it is sure of on consecutive frames
  (:func:`~xvmatch.inference.adaptation.adaptation_pairs.mine_pairs`, those the appearance check and
  ``adapt`` use), are mostly right, good cameras keep them, and misleading ones have the
  matcher pair them otherwise. :func:`check_cameras` counts the share kept; below
  :data:`MIN_KEEP` by more than twice its standard error, the run is matched without the
  cameras (:func:`check_run_cameras` scores the frames both ways).

The pseudo-matches judge only where the box-only matcher is shown steady: its sure pairs keep
their partners over :data:`~xvmatch.inference.matching.appearance_check.CONSISTENCY_WINDOW` frames
(:func:`~xvmatch.inference.matching.appearance_check.sure_pair_consistency` at least
:data:`~xvmatch.inference.matching.appearance_check.MIN_CONSISTENCY`). Under an oblique overview
camera it can be sure and wrong, and exact cameras then "lose" its pairs (rendered overview videos:
3 of 35 kept by exact cameras that add 55 points, at a steadiness of 0.6 or more; hence the
fit's loss as well). So cameras that fit the head rays, or that no fit was tried for with
``--refine-top-camera off``, clips too short to measure the steadiness
(under 6 s at 25 fps), single image pairs, and scenes the box-only matcher is rarely sure of or
unsteady on keep their cameras. No identities are used. Numpy only (and the bundle's matcher).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace

import numpy as np

from xvmatch.inference.adaptation.adaptation_pairs import MiningConfig, mine_pairs, plan_bursts
from xvmatch.inference.linking.assignment import assign
from xvmatch.inference.matching.appearance_check import (
    CONSISTENCY_WINDOW,
    MIN_CONSISTENCY,
    MIN_PAIRS,
    sure_pair_consistency,
)
from xvmatch.inference.matching.learned_association import box_only_costs

__all__ = ["DOUBT_LOSS", "MAX_FRAMES", "MIN_KEEP", "CameraCheck", "check_cameras",
           "check_run_cameras"]

MIN_KEEP: float = 0.8
"""Least share of the box-only matcher's pseudo-matches that the matcher with the cameras must
keep for the cameras to be used. Rendered videos (docs/method.md, "the camera check"): exact
cameras keep 0.76 to 1 where the box-only matcher is steady, except on overview videos where it
is sure and wrong (down to 0.09), which :data:`DOUBT_LOSS` guards."""

DOUBT_LOSS: float = 0.65
"""Least loss of the top camera's refinement (its best fit, 0 to 1) for the cameras to be
judged at all. Rendered videos of 160 frames (docs/method.md, "the camera check"): exact
cameras end at 0.05 to 0.20, both cameras 3 to 4 degrees off at 0.38 to 0.68 (and help), those
left out at 0.66 to 1; an overview video whose box-only pseudo-matches condemn right cameras
ends at 0.45 to 0.56 with both cameras off."""

MAX_FRAMES: int = 300
"""Frames the check mines pseudo-matches on (bursts spread over the run), and at most as many
(:data:`~xvmatch.inference.matching.appearance_check.CONSISTENCY_WINDOW` windows) it measures the
box-only matcher's steadiness on: a doubted run is scored on at most 600 frames without the cameras
and 300 with them, whatever the video's length."""

OFF_HINT = "--camera-check off uses them as given"


@dataclass(frozen=True)
class CameraCheck:
    """The outcome of :func:`check_cameras`.

    Attributes:
        judged: whether there were enough pseudo-matches to judge.
        trusted: whether the cameras are used (always when not judged).
        kept: pseudo-matches the matcher with the cameras pairs the same way.
        positives: pseudo-matches (a pair of boxes in one frame each; a tracklet pair counts
            once per frame it was read in).
        bursts: runs of consecutive frames they were mined on (0: none to mine on).
        min_keep: the bar it was held to.
        min_pairs: the fewest pseudo-matches it needed to judge.
        consistency: the box-only matcher's :func:`~xvmatch.inference.matching.appearance_check.
            sure_pair_consistency` (NaN: not measured, the clip is too short); judged only at
            :data:`~xvmatch.inference.matching.appearance_check.MIN_CONSISTENCY` or more.
        fit_loss: the refinement's loss that opened the check (NaN: none given, as for the
            pure :func:`check_cameras`).
        moving: the check was opened by a top camera that changes from frame to frame.
    """

    judged: bool
    trusted: bool
    kept: int
    positives: int
    bursts: int
    min_keep: float = MIN_KEEP
    min_pairs: int = MIN_PAIRS
    consistency: float = math.nan
    fit_loss: float = math.nan
    moving: bool = False

    @property
    def share(self) -> float:
        """Share of the pseudo-matches kept (NaN with none)."""
        return self.kept / self.positives if self.positives else math.nan

    @property
    def error(self) -> float:
        """Standard error of :attr:`share` (binomial; NaN with no pseudo-match)."""
        p = self.share
        return math.sqrt(p * (1.0 - p) / self.positives) if self.positives else math.nan

    def to_tell(self, quiet: bool) -> bool:
        """Whether a command prints :meth:`message`: when there was a run of consecutive
        frames to judge on, and with ``--quiet`` only when the cameras were left out."""
        return (self.judged or self.bursts > 0) and (not quiet or not self.trusted)

    def message(self) -> str:
        """One line for the user."""
        if not self.judged:
            n = self.positives
            if n < self.min_pairs:
                why = (f"the boxes alone are sure of only {n} pair{'s' if n != 1 else ''} over "
                       f"consecutive frames, {self.min_pairs} needed to judge the cameras (a "
                       "longer video gives more)")
            elif math.isnan(self.consistency):
                why = (f"the video is too short ({CONSISTENCY_WINDOW} consecutive frames needed) "
                       "to judge the cameras")
            else:
                why = (f"the pairs the boxes alone are sure of change partners over time (a "
                       f"person's track keeps its most frequent partner in "
                       f"{self.consistency:.2f} of those frames, {MIN_CONSISTENCY:g} needed), "
                       "too unsteady to judge the cameras")
            return f"camera check: {why}; the cameras were used without this check"
        fit = ("the top camera changes from frame to frame and " if self.moving
               else "" if math.isnan(self.fit_loss) else
               f"the top camera fits the people poorly (misfit {self.fit_loss:.3f}) and ")
        head = (f"camera check: {fit}the matcher with the cameras keeps {self.kept} of the "
                f"{self.positives} pairs the boxes alone are sure of ({self.share:.2f} +/- "
                f"{self.error:.2f})")
        if self.trusted:
            return f"{head}; cameras used"
        return (f"{head}; below {self.min_keep:g} by more than twice its standard error, so the "
                f"cameras would drag the boxes down: matched without them ({OFF_HINT})")


def check_cameras(
    top: Mapping,
    hor: Mapping,
    box_costs: Mapping[int, np.ndarray],
    camera_costs: Mapping[int, np.ndarray],
    gamma: float,
    config: MiningConfig | None = None,
    min_keep: float = MIN_KEEP,
    min_pairs: int = MIN_PAIRS,
) -> CameraCheck:
    """Judge a run's cameras on its own frames (see the module docstring).

    Args:
        top, hor: ``{frame: FrameBoxes}`` of each view (ids only name boxes).
        box_costs: ``{frame: (M, N)}`` the matcher's costs without the cameras (nor images),
            input order, of frames with boxes in both views: those of ``camera_costs`` and
            the windows :func:`~xvmatch.inference.matching.appearance_check.sure_pair_consistency`
            reads.
        camera_costs: ``{frame: (M, N)}`` its costs with the cameras, of the frames the
            pseudo-matches are mined on (bursts of consecutive frames).
        gamma: the run's non-association cost.
        config: how pseudo-matches are mined (bursts of consecutive frames).
        min_keep: the least share kept for the cameras to be used.
        min_pairs: fewest pseudo-matches to judge.
    """
    config = config or MiningConfig()
    bursts = plan_bursts(camera_costs, config.burst, config.max_frames)
    if not bursts:
        return CameraCheck(False, True, 0, 0, 0, min_keep, min_pairs)
    pos, _ = mine_pairs(top, hor, bursts, box_costs, gamma, config).frame_pairs(top, hor)
    paired: dict[int, set[tuple[int, int]]] = {}
    for f in np.unique(pos[:, 0]).tolist():
        if camera_costs[f].shape != box_costs[f].shape:
            raise ValueError(f"frame {f}: camera costs {camera_costs[f].shape}, box-only costs "
                             f"{box_costs[f].shape}")
        paired[f] = {(int(i), int(j)) for i, j in assign(camera_costs[f], gamma)}
    kept = sum((i, j) in paired[f] for f, i, j in pos.tolist())
    check = CameraCheck(False, True, kept, len(pos), len(bursts), min_keep, min_pairs)
    if len(pos) < min_pairs:
        return check
    check = replace(check, consistency=sure_pair_consistency(top, hor, box_costs, gamma, config))
    if not check.consistency >= MIN_CONSISTENCY:  # NaN too: not measured
        return check
    return replace(check, judged=True, trusted=bool(check.share + 2.0 * check.error >= min_keep))


def check_run_cameras(
    top: Mapping,
    hor: Mapping,
    frames: Iterable[int],
    matcher,
    hor_size: tuple[int, int],
    cameras,
    gamma: float,
    fit_loss: float | None,
    camera_id: int | None = None,
    config: MiningConfig | None = None,
    workers: int = 1,
    min_keep: float = MIN_KEEP,
    moving: bool = False,
) -> CameraCheck:
    """Judge a run's cameras when ``fit_loss`` is above :data:`DOUBT_LOSS` or the top camera
    moves (else they are kept, unjudged and unsaid): score the frames the check reads without
    and with ``cameras`` and judge them (:func:`check_cameras`): bursts of consecutive frames to
    mine (at most ``config.max_frames``) both ways, and windows of
    :data:`~xvmatch.inference.matching.appearance_check.CONSISTENCY_WINDOW` frames (as many)
    without.

    Args:
        top, hor: ``{frame: FrameBoxes}``, the top one re-timed to the horizontal frames.
        frames: the run's frames.
        matcher: a :class:`~xvmatch.inference.matching.learned_association.LearnedMatcher`, or
            several (an ensemble, costs averaged).
        hor_size: ``(W, H)`` of the horizontal images.
        cameras: the run's camera source (``get(frame)``), its top camera refined if it was.
        gamma: the run's non-association cost.
        fit_loss: the loss of the top camera's refinement (its best fit,
            :attr:`~xvmatch.inference.matching.camera_refinement.CameraRefinement.fit_loss`), or
            None when none was tried (the cameras are then kept, unless ``moving``).
        camera_id: the wearer's top-view id, when known.
        config: how pseudo-matches are mined (default: :data:`MAX_FRAMES` frames).
        workers: processes for the geometry features (the result does not depend on it).
        min_keep: the least share kept for the cameras to be used.
        moving: the top camera changes from frame to frame (:attr:`~xvmatch.inference.matching.
            camera_refinement.CameraRefinement.moving`; at most the constant part of its error
            was refined): judged whatever ``fit_loss``.
    """
    loss = math.nan if fit_loss is None else float(fit_loss)
    if not moving and not loss > DOUBT_LOSS:
        return CameraCheck(False, True, 0, 0, 0, min_keep, fit_loss=loss)
    config = config or MiningConfig(max_frames=MAX_FRAMES)
    both = [f for f in frames if len(top.get(f, ())) and len(hor.get(f, ()))]
    mined = [int(f) for b in plan_bursts(both, config.burst, config.max_frames) for f in b]
    steady = [int(f) for b in plan_bursts(both, CONSISTENCY_WINDOW, config.max_frames)
              for f in b]
    if not mined:
        return CameraCheck(False, True, 0, 0, 0, min_keep, fit_loss=loss, moving=moving)
    box = box_only_costs(top, hor, sorted(set(mined) | set(steady)), matcher, hor_size,
                         camera_id=camera_id, workers=workers)
    camera = box_only_costs(top, hor, sorted(mined), matcher, hor_size, cameras=cameras,
                            camera_id=camera_id, workers=workers)
    return replace(check_cameras(top, hor, box, camera, gamma, config, min_keep),
                   fit_loss=loss, moving=moving)
