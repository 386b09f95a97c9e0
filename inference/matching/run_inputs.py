"""What a learned run's command line names, opened and checked before any work: the matchers
(``--model``: a bundle folder, ``default`` for the shipped one, or a torch matcher file, exported
once into the cache, ``$XVMATCH_CACHE/bundles/DIGEST``, and opened from there), and whether
``--precision`` has an appearance network to choose. The export itself needs torch (the learn
extra), so the caller passes it in: this module stays torch-free.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable, Iterable
from pathlib import Path

from xvmatch.datasets.feature_cache import default_cache_dir
from xvmatch.inference.matching.learned_association import LearnedMatcher, load_matcher_bundle

__all__ = ["cached_bundle_folder", "open_matchers", "precision_problem"]


def cached_bundle_folder(path: str | os.PathLike) -> Path:
    """The cache folder of a torch matcher file's bundle, named by the first 20 hex digits of
    the file's sha256 (a changed file gets a new bundle)."""
    digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()[:20]
    return default_cache_dir() / "bundles" / digest


def open_matchers(names: Iterable[str], threads: int = 1, precision: str | None = None,
                  recheck: bool = False,
                  export: Callable[[str, Path], None] | None = None) -> list[LearnedMatcher]:
    """A :class:`~xvmatch.inference.matching.learned_association.LearnedMatcher` for each name.

    Args:
        names: bundle folders, ``default``, or torch matcher files.
        threads, precision, recheck: as
            :func:`~xvmatch.inference.matching.learned_association.load_matcher_bundle`.
        export: ``export(torch_file, folder)`` writes a torch file's bundle into its cache
            folder (:func:`cached_bundle_folder`) when it is not there yet; None: such a file
            is refused.

    Raises:
        ValueError: a torch file not exported yet with no ``export``; an unusable bundle
            (one line naming the file).
    """
    models = []
    for name in names:
        source: str | Path = name
        if name != "default" and os.path.isfile(name):
            source = cached_bundle_folder(name)
            if not (source / "manifest.json").is_file():
                if export is None:
                    raise ValueError(f"{name}: a torch matcher file; export it with 'xvmatch "
                                     "export' and pass the bundle folder")
                export(name, source)
        models.append(load_matcher_bundle(source, threads, precision, recheck))
    return models


def precision_problem(precision: str | None, images: bool,
                      models: Iterable[LearnedMatcher] = (), names: Iterable[str] = ()
                      ) -> str | None:
    """Why ``--precision`` cannot be honoured, in one line, or None: no appearance network runs
    without images (the run matches boxes alone), nor when none of ``models`` (opened from
    ``names``; empty: not opened yet) has one (a box-only bundle)."""
    if precision is None:
        return None
    if not images:
        return (f"--precision {precision} chooses the appearance network, which runs only on "
                "images: give --top-images and --hor-images, or leave --precision out")
    models, names = list(models), list(names)
    if models and all(m.bundle.manifest.appearance is None for m in models):
        which = ", ".join(names) or "the model"
        return (f"--precision {precision}: --model {which} has no appearance network (a "
                "box-only matcher) for it to choose; leave --precision out")
    return None
