"""The columns of the ablation (``xvmatch ablate``): box settings, sweeps and their perturbations.

Every column is a :class:`Setting`: ground-truth boxes, the default detector noise, and the points
of one sweep:

* ``noise``: the detector noise of :mod:`xvmatch.datasets.visibility_noise` with its jitter,
  misses (base rate and the extra miss of hidden people) and false boxes multiplied by 0, 0.5, 1,
  1.5 and 2 (:func:`scaled_noise`; miss probabilities are capped at 1). Multiplier 1 is the
  detector-noise column itself.
* ``calibration``: both cameras rotated by a random axis-angle of 0, 1, 2.5 or 5 degrees and
  moved by a random direction of 0, 0.25, 0.5 or 1 m (:func:`perturb_camera`), on ground-truth
  boxes; the ray distance, the cheirality cue and the rectified geometry are computed from the
  perturbed cameras, the images and boxes stay as rendered. The point (0, 0) is the
  ground-truth column.
* ``crowd``: scenes rendered with exactly 3, 10, 20 or 30 people, ground-truth boxes.
* ``lookalike``: scenes rendered with a look-alike rate of 0, 0.25, 0.5 or 0.75
  (:class:`~xvmatch.datasets.render.image_render.Difficulty`), ground-truth boxes.

Seeds: seed ``s`` draws the detector noise and the box shuffling (``TrialConfig(noise_seed=s,
scramble_seed=s)``), the calibration error (:func:`calibration_rng`) and, for the rendering
sweeps, the scenes (dataset seed :data:`RENDER_SEED` + ``s``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from xvmatch.datasets.detector_noise import DetectorNoise
from xvmatch.datasets.visibility_noise import VisibilityNoise
from xvmatch.geometry.camera import Camera

__all__ = [
    "RENDER_SEED",
    "SWEEPS",
    "SWEEP_AXES",
    "Setting",
    "calibration_rng",
    "grid_settings",
    "perturb_camera",
    "rotation_angle_deg",
    "scaled_noise",
]

SWEEPS: dict[str, tuple] = {
    "noise": (0.0, 0.5, 1.0, 1.5, 2.0),
    "calibration": ((0.0, 0.0), (1.0, 0.25), (2.5, 0.5), (5.0, 1.0)),
    "crowd": (3, 10, 20, 30),
    "lookalike": (0.0, 0.25, 0.5, 0.75),
}
"""The points of each sweep: noise multipliers, (degrees, metres) of calibration error, people
per scene, look-alike rates."""

SWEEP_AXES: dict[str, str] = {
    "noise": "detector noise (multiple of the default jitter, misses and false boxes)",
    "calibration": "calibration error: rotation (degrees), with position 0 / 0.25 / 0.5 / 1 m",
    "crowd": "people per scene",
    "lookalike": "look-alike rate",
}
"""The x axis of each sweep's plot."""

RENDER_SEED = 3000
"""Dataset seed of the rendering sweeps' scenes, plus the ablation seed (test sets of the
project use 1000, validation sets 2000)."""


@dataclass(frozen=True)
class Setting:
    """One column of the ablation.

    Attributes:
        key: short unique name, used in file names and the results (``gt``, ``det``,
            ``noise1.5``, ``calib2.5``, ``crowd10``, ``lookalike0.5``).
        label: the column header.
        boxes: the boxes associated: ``"gt"`` (ground truth) or ``"det"`` (detector noise).
        noise: multiplier of the default detector noise (``"det"`` boxes only).
        rotation_deg, position_m: calibration error of both cameras.
        people: people per rendered scene (crowd sweep), or None: the data folder's scenes.
        lookalike: look-alike rate of the rendered scenes, or None: the data folder's scenes.
        sweep_value: where the column sits on the sweep's axis, or None when it is not on it.
    """

    key: str
    label: str
    boxes: str = "gt"
    noise: float = 1.0
    rotation_deg: float = 0.0
    position_m: float = 0.0
    people: int | None = None
    lookalike: float | None = None
    sweep_value: float | None = None

    @property
    def renders(self) -> bool:
        """The column is measured on scenes rendered for it (crowd and look-alike sweeps)."""
        return self.people is not None or self.lookalike is not None

    @property
    def perturbs_cameras(self) -> bool:
        """The column's cameras carry a calibration error."""
        return self.rotation_deg > 0 or self.position_m > 0


def _number(value: float) -> str:
    return f"{value:g}"


def grid_settings(sweep: str) -> tuple[Setting, ...]:
    """The columns for ``sweep``: ground-truth boxes, detector noise, then the sweep's points
    that are not one of those two (noise x0 and calibration error 0 are the ground-truth column,
    noise x1 the detector-noise column; they carry the sweep value).

    Raises:
        ValueError: an unknown sweep.
    """
    if sweep not in SWEEPS:
        raise ValueError(f"unknown sweep {sweep!r}; choose one of {', '.join(SWEEPS)}")
    gt = Setting("gt", "GT boxes", "gt")
    det = Setting("det", "detector noise", "det")
    points: list[Setting] = []
    if sweep == "noise":
        # Noise x0 gives the ground-truth boxes exactly (a test pins it): the GT column is
        # that point, not a second copy of it.
        gt = replace(gt, label="GT boxes (noise x0)", sweep_value=0.0)
        det = replace(det, label="detector noise (x1)", sweep_value=1.0)
        points = [Setting(f"noise{_number(k)}", f"noise x{_number(k)}", "det", noise=float(k),
                          sweep_value=float(k))
                  for k in SWEEPS["noise"] if k not in (0.0, 1.0)]
    elif sweep == "calibration":
        gt = replace(gt, label="GT boxes (calib. 0)", sweep_value=0.0)
        points = [Setting(f"calib{_number(deg)}", f"calib. {_number(deg)} deg / {_number(m)} m",
                          "gt", rotation_deg=float(deg), position_m=float(m),
                          sweep_value=float(deg))
                  for deg, m in SWEEPS["calibration"] if deg > 0 or m > 0]
    elif sweep == "crowd":
        points = [Setting(f"crowd{n}", f"{n} people", "gt", people=int(n),
                          sweep_value=float(n)) for n in SWEEPS["crowd"]]
    else:
        points = [Setting(f"lookalike{_number(r)}", f"look-alike {_number(r)}", "gt",
                          lookalike=float(r), sweep_value=float(r))
                  for r in SWEEPS["lookalike"]]
    return (gt, det, *points)


def scaled_noise(multiplier: float, base: VisibilityNoise | None = None) -> VisibilityNoise:
    """The detector noise with its jitter, miss rates and false-box rate times ``multiplier``.

    The miss rate of fully visible boxes and the extra miss of hidden ones are capped at 1; the
    visibility power is kept. ``multiplier = 0`` leaves the ground-truth boxes unchanged.

    Args:
        multiplier: >= 0.
        base: the default noise (``VisibilityNoise()``: 5% jitter, 10% misses, 0.3 false boxes
            per frame and view, hidden misses 0.9).
    """
    k = float(multiplier)
    if not (np.isfinite(k) and k >= 0):
        raise ValueError(f"the noise multiplier must be a finite number >= 0, got {multiplier}")
    base = VisibilityNoise() if base is None else base
    b = base.base
    return VisibilityNoise(
        base=DetectorNoise(jitter=b.jitter * k, miss_rate=min(1.0, b.miss_rate * k),
                           false_per_frame=b.false_per_frame * k),
        hidden_miss=min(1.0, base.hidden_miss * k),
        power=base.power,
    )


_VIEW_STREAM = {"top": 0, "ego": 1}


def calibration_rng(seed: int, scene_index: int, view: str) -> np.random.Generator:
    """The random stream of one camera's calibration error: one draw per scene and view, so a
    scene's camera keeps the same error on every frame and every sweep point uses the same
    directions (only the magnitudes change)."""
    return np.random.default_rng([int(seed), int(scene_index), _VIEW_STREAM[view], 17])


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.standard_normal(3)
    return v / np.linalg.norm(v)


def perturb_camera(camera: Camera, rotation_deg: float, position_m: float,
                   rng: np.random.Generator) -> Camera:
    """A calibration error: the camera turned by ``rotation_deg`` about a random axis (of its
    own frame) and moved by ``position_m`` metres in a random direction.

    ``R' = R_delta R`` with ``R_delta`` the axis-angle rotation (Rodrigues' formula), so the
    angle of ``R' R^T`` is exactly ``rotation_deg``; ``c' = c + position_m u`` with ``|u| = 1``.
    The intrinsics and the image size are kept. Two directions are drawn from ``rng`` (axis, then
    direction) whatever the magnitudes, so equal streams give equal directions.

    Args:
        camera: the calibrated camera.
        rotation_deg: rotation error in degrees, >= 0.
        position_m: position error in metres, >= 0.
        rng: the stream (e.g. :func:`calibration_rng`).

    Returns:
        The perturbed :class:`~xvmatch.geometry.camera.Camera`.
    """
    if not (np.isfinite(rotation_deg) and rotation_deg >= 0):
        raise ValueError(f"rotation_deg must be a finite angle >= 0, got {rotation_deg}")
    if not (np.isfinite(position_m) and position_m >= 0):
        raise ValueError(f"position_m must be a finite distance >= 0, got {position_m}")
    axis, direction = _unit(rng), _unit(rng)
    angle = np.radians(float(rotation_deg))
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]],
                  [-axis[1], axis[0], 0.0]])
    delta = np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)
    return Camera(K=camera.K, R=delta @ camera.R, c=camera.c + float(position_m) * direction,
                  width=camera.width, height=camera.height)


def rotation_angle_deg(r_a: np.ndarray, r_b: np.ndarray) -> float:
    """Angle in degrees of the rotation taking ``r_b`` to ``r_a`` (of ``r_a r_b^T``)."""
    cos = (np.trace(np.asarray(r_a) @ np.asarray(r_b).T) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
