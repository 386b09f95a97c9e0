"""xvmatch: find the same people in an egocentric/horizontal camera and a top/overview camera.

The top-level folders of the repository are the subpackages of this one import package
(``xvmatch.geometry``, ``xvmatch.datasets``, ...), mapped in ``pyproject.toml``. The names below
are the stable surface: they keep working when modules move (``CHANGELOG.md``), and each is
imported only when first used, so ``import xvmatch`` is instant and never imports torch.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_PUBLIC = {
    # reading and writing the user's files
    "read_mot_boxes": "xvmatch.formats.mot_boxes",
    "write_predictions": "xvmatch.formats.mot_boxes",
    "read_predictions": "xvmatch.formats.mot_boxes",
    "load_cameras": "xvmatch.formats.camera_io",
    "save_cameras": "xvmatch.formats.camera_io",
    # cameras
    "Camera": "xvmatch.geometry.camera",
    "calibrate_from_people": "xvmatch.geometry.people_calibration",
    # associating two views
    "associate_sequence": "xvmatch.cues.spatial_search",
    "load_bundle": "xvmatch.inference.matching.bundle",
    "run_learned_association": "xvmatch.inference.matching.learned_pipeline",
    "LearnedRunOptions": "xvmatch.inference.matching.learned_pipeline",
    "run_ground_association": "xvmatch.inference.matching.ground_association",
    "GroundAssociationOptions": "xvmatch.inference.matching.ground_association",
    # tracking and several cameras
    "track_pair": "xvmatch.inference.tracks.tracking",
    "associate_cameras": "xvmatch.inference.views.multicam",
    # scores
    "count_sequence": "xvmatch.metrics.cross_view_metrics",
    "summarize": "xvmatch.metrics.cross_view_metrics",
}

__all__ = ["__version__", *_PUBLIC]


def __getattr__(name: str) -> Any:
    """Import a public name's module on first use."""
    if name not in _PUBLIC:
        raise AttributeError(f"module 'xvmatch' has no attribute {name!r}")
    value = getattr(importlib.import_module(_PUBLIC[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)
