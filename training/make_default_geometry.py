"""Regenerate the shipped default geometry model, ``models/default_geometry.pt``.

Trained on the box-level simulator only (:class:`~xvmatch.training.box_datamodule.
SimBoxDataModule`: randomised scene configurations and detector-noise levels), never on real
data, so the weights come from our own code and synthetic data alone. Deterministic given
``--seed`` on a given machine and thread count (same scenes, same features, same training).

Usage:
    python training/make_default_geometry.py [--out models/default_geometry.pt] [--seed 0]
        [--scenes 350] [--epochs 8] [--workers 2] [--threads 1]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from xvmatch.datasets.geometry_features import FeatureConfig
from xvmatch.training.box_datamodule import SimBoxDataModule
from xvmatch.training.fit_geometry import fit_geometry

DEFAULT_OUT = Path(__file__).resolve().parents[1] / "models" / "default_geometry.pt"
MODEL_CONFIG = {"width": 64, "layers": 2, "heads": 4}
"""Small enough for a < 2 MB file (about 370k float32 weights)."""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="model file to write")
    parser.add_argument("--seed", type=int, default=0, help="seed of scenes, noise, training")
    parser.add_argument("--scenes", type=int, default=350, help="simulated scenes (default 350)")
    parser.add_argument("--frames", type=int, default=90, help="frames per scene (default 90)")
    parser.add_argument("--frame-step", type=int, default=3, help="keep every k-th frame (3)")
    parser.add_argument("--epochs", type=int, default=8, help="most epochs (default 8)")
    parser.add_argument("--o-given", type=float, default=0.15,
                        help="fraction of scenes extracted with O given (default 0.15)")
    parser.add_argument("--workers", type=int, default=2, help="feature extraction processes")
    parser.add_argument("--cache", default=None, help="feature cache folder")
    parser.add_argument("--run-dir", default=None, help="checkpoints and logs folder")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    feature_config = FeatureConfig()
    dm = SimBoxDataModule(
        n_scenes=args.scenes,
        frames_per_scene=args.frames,
        frame_step=args.frame_step,
        val_scenes=max(1, args.scenes // 10),
        camera_given_probability=args.o_given,
        feature_config=feature_config,
        cache_dir=args.cache,
        workers=args.workers,
        seed=args.seed,
    )
    result = fit_geometry(
        dm,
        args.out,
        feature_config=feature_config,
        model_config=MODEL_CONFIG,
        epochs=args.epochs,
        seed=args.seed,
        run_dir=args.run_dir or Path("runs") / "default_geometry",
        progress=not args.quiet,
        threads=args.threads,
        meta={
            "trained_on": "box simulator only (SimBoxDataModule, domain randomisation)",
            "scenes": args.scenes,
            "frames_per_scene": args.frames,
            "frame_step": args.frame_step,
            "o_given_fraction": args.o_given,
            "script": "training/make_default_geometry.py",
        },
    )
    size = args.out.stat().st_size / 1e6
    print(
        f"wrote {args.out} ({size:.2f} MB; validation CVIDF1 {result.best_score:.1f}, "
        f"{result.epochs} epochs, {result.wall_time_s:.0f} s, "
        f"peak memory {result.peak_memory_mb:.0f} MiB)",
        file=sys.stderr,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
