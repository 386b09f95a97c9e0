"""Shared pytest fixtures. Keep each fixture small and documented; add new ones below."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

# Property tests draw the same examples on every run (same code, same result: CI cannot turn red
# by chance); HYPOTHESIS_PROFILE=explore searches with fresh random examples instead.
settings.register_profile("deterministic", derandomize=True, database=None)
settings.register_profile("explore")
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
