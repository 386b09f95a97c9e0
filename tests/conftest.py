"""Shared pytest fixtures. Keep each fixture small and documented; add new ones below."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

# Property tests draw the same examples on every run (same code, same result: CI cannot turn red
# by chance); HYPOTHESIS_PROFILE=explore searches with fresh random examples instead. No
# deadline: timings are benchmarks' business, and the first call of a compiled kernel (numba,
# cues/search_kernels.py) on a fresh clone includes its compilation.
settings.register_profile("deterministic", derandomize=True, database=None, deadline=None)
settings.register_profile("explore", deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "deterministic"))

CVMHAT_ENV = "XVMATCH_CVMHAT"
"""Environment variable that overrides where the CVMHAT boxes are looked for."""


@pytest.fixture(scope="session")
def cvmhat_dir() -> Path:
    """Folder of the CVMHAT ground-truth boxes (read-only data, never copied into the repo).

    ``$XVMATCH_CVMHAT`` when set, else ``../shared/data/cvmhat`` next to the repository. Tests
    that use it are skipped cleanly when the folder is absent (e.g. on a fresh clone in CI).
    """
    default = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "cvmhat"
    path = Path(os.environ.get(CVMHAT_ENV) or default)
    if not path.is_dir():
        pytest.skip(f"CVMHAT data not found at {path} (set {CVMHAT_ENV} to its folder)")
    return path


TINY_GEOMETRY = {"width": 16, "layers": 1, "heads": 2, "sinkhorn_iterations": 10}
"""A geometry encoder small enough to train and export in a second."""
TINY_APPEARANCE = {"input_size": (32, 16), "widths": (4, 8, 8, 16), "hidden_dim": 16,
                   "embedding_dim": 8}
"""An appearance network small enough to train and export in a second."""


@pytest.fixture(scope="session")
def tiny_synth(tmp_path_factory) -> dict[str, Path]:
    """Tiny synthetic datasets of both scenarios (2 scenes x 2 frames, 320x180, 3-6 people)."""
    from xvmatch.datasets.synthetic_io import generate_dataset
    from xvmatch.datasets.synthetic_scenes import SynthConfig

    root = tmp_path_factory.mktemp("tiny_synth")
    out = {}
    for k, scenario in enumerate(("drone", "overview")):
        config = SynthConfig(scenario=scenario, top_size=(320, 180), ego_size=(320, 180),
                             n_people=(3, 6))
        generate_dataset(root / scenario, config, n_scenes=2, n_frames=2, seed=70 + k)
        out[scenario] = root / scenario
    return out


@pytest.fixture(scope="session")
def tiny_models(tmp_path_factory, tiny_synth) -> dict[str, Path]:
    """Untrained tiny matchers as files and bundles: ``boxes`` (box-only, gamma 0.6, the
    layout of ``fit-geometry`` files) and ``full`` (appearance and camera cues, cue weights
    drawn so the cues matter), each ``.pt`` with its exported bundle folder beside it."""
    import torch

    from xvmatch.cues.spatial_features import FeatureConfig
    from xvmatch.export.onnx_export import export_bundle
    from xvmatch.models.appearance_net import appearance_small
    from xvmatch.models.cross_view_matcher import CrossViewMatcher
    from xvmatch.models.geometry_encoder import GeometryEncoder
    from xvmatch.models.matcher_file import save_matcher

    root = tmp_path_factory.mktemp("tiny_models")
    features = FeatureConfig(n_hypotheses=3, dtheta_deg=4.0)
    torch.manual_seed(0)
    box_only = CrossViewMatcher(GeometryEncoder(**TINY_GEOMETRY), cues=())
    full = CrossViewMatcher(GeometryEncoder(**TINY_GEOMETRY))
    for layer in (full.cue_embed[2], full.fusion[2], full.fusion_linear):
        torch.nn.init.normal_(layer.weight, std=0.5)
    net = appearance_small(**TINY_APPEARANCE).eval()
    out = {}
    for name, matcher, app, gamma in (("boxes", box_only, None, 0.6), ("full", full, net, 0.5)):
        path = root / f"{name}.pt"
        save_matcher(path, matcher.eval(), features, gamma, {"k": 1}, appearance=app)
        export_bundle(path, root / name, parity_data=tiny_synth["overview"])
        out[name] = path
        out[f"{name}_bundle"] = root / name
    return out


@pytest.fixture(scope="session")
def track_files(tmp_path_factory) -> dict[str, Path]:
    """One 30-frame box scene for ``xvmatch track``: ground-truth files (``gt_top``, ``gt_hor``)
    and detection files (``det_top``, ``det_hor``: ids all -1, rows shuffled)."""
    import numpy as np

    from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene
    from xvmatch.formats.mot_boxes import write_mot_boxes

    folder = tmp_path_factory.mktemp("track")
    scene = simulate_box_scene(SceneConfig(head_turn_std_deg=2.0), n_frames=30, seed=5)
    out = {}
    for view, frames in (("top", scene.top), ("hor", scene.hor)):
        gt = folder / f"gt_{view}.txt"
        write_mot_boxes(gt, frames)
        lines = gt.read_text().splitlines()
        rng = np.random.default_rng(7)
        det = [",".join([ln.split(",")[0], "-1", *ln.split(",")[2:]])
               for ln in (lines[k] for k in rng.permutation(len(lines)))]
        (folder / f"det_{view}.txt").write_text("\n".join(det) + "\n")
        out[f"gt_{view}"], out[f"det_{view}"] = gt, folder / f"det_{view}.txt"
    return out


@pytest.fixture(scope="module")
def scene_files(tmp_path_factory) -> tuple[Path, Path]:
    """A 3-frame simulated scene written as ``s_top.txt`` / ``s_hor.txt``."""
    from xvmatch.datasets.box_scene import simulate_box_scene, write_box_scene

    folder = tmp_path_factory.mktemp("scene")
    return write_box_scene(simulate_box_scene(n_frames=3, seed=1), folder, "s")


@pytest.fixture
def close_drone():
    """A 1920x1080 camera 8 m up, 30 degrees down, 70 degrees wide, calibrated as if exactly
    (:class:`~xvmatch.geometry.people_calibration.PeopleCalibration`): a close drone whose
    bottom edge cuts the people walking under it."""
    import numpy as np

    from xvmatch.geometry.people_calibration import PeopleCalibration

    return PeopleCalibration(kind="oblique", width=1920, height=1080,
                             focal=1920 / 2 / np.tan(np.radians(35.0)), tilt_deg=30.0,
                             roll_deg=0.0, camera_height=8.0, horizon=(0.0, 0.0),
                             focal_from="given", tilt_std_deg=0.0, horizon_std_px=0.0,
                             focal_rel_std=0.0, n_boxes=100, n_frames=10)


def _spy_registration(monkeypatch, record) -> None:
    """Replace the ground registration's Viterbi
    (:func:`~xvmatch.cues.ground_registration.register_sequence`) by itself, telling
    ``record(fps, slack, rescore)`` of each call first."""
    from xvmatch.cues import ground_registration as gr

    real = gr.register_sequence

    def spy(frames, candidates, fps, motions=None, slack=1.0, rescore=None):
        record(fps, slack, rescore)
        return real(frames, candidates, fps, motions, slack, rescore)

    monkeypatch.setattr(gr, "register_sequence", spy)


@pytest.fixture
def registration_paces(monkeypatch) -> list[tuple[float, float]]:
    """The ``(fps, slack)`` of every call of the ground registration's Viterbi
    (:func:`~xvmatch.cues.ground_registration.register_sequence`) made during the test, the
    real registration still run: which rate and free walk a command registered at."""
    paces: list[tuple[float, float]] = []
    _spy_registration(monkeypatch, lambda fps, slack, rescore: paces.append((fps, slack)))
    return paces


@pytest.fixture
def registration_offers(monkeypatch) -> list[bool]:
    """Whether each call of the ground registration's Viterbi
    (:func:`~xvmatch.cues.ground_registration.register_sequence`) made during the test was
    given a ``rescore`` (the poses leading at the frame before offered), the real registration
    still run."""
    offers: list[bool] = []
    _spy_registration(monkeypatch, lambda fps, slack, rescore: offers.append(rescore is not None))
    return offers
