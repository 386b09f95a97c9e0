"""Command-line interface: ``xvmatch associate | evaluate | offset | demo | ...``.

This root module only builds the parser from the command modules of :mod:`xvmatch.commands`,
one ``add_<command>_parser`` each (``associate``, ``evaluate``, ``track``, ...; those that make
data and models in :mod:`xvmatch.commands.lab`), and runs the command; the options several
commands share are defined once in :mod:`xvmatch.commands._options`. No command module imports
this one. Each command imports only what it needs, so ``xvmatch associate`` starts fast and never
imports torch. Bad input ends with one line ``xvmatch: error: ...`` naming the file and line,
exit code 2. Every size or count option has a range, given in its help and checked while the
arguments are parsed (:mod:`xvmatch.commands._types`), before any work starts; so is every
output path (:mod:`xvmatch.core.output_paths`: no FIFO, device or folder where a file goes, no
input overwritten, no two outputs on one path, a writable folder).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from xvmatch.commands import associate, evaluate, offset
from xvmatch.commands._options import UsageError
from xvmatch.commands.demo import EXAMPLES as DEMO_EXAMPLES
from xvmatch.commands.lab import noise

__all__ = ["main"]

EXAMPLES = {
    "associate": associate.EXAMPLE,
    "evaluate": evaluate.EXAMPLE,
    "noise": noise.EXAMPLE,
    "offset": offset.EXAMPLE,
    **DEMO_EXAMPLES,
}


def version_text() -> str:
    """``xvmatch --version``: the package and every on-disk format it reads and writes."""
    from xvmatch import __version__
    from xvmatch.cues.spatial_features import FEATURE_VERSION
    from xvmatch.datasets.synthetic_io import SCHEMA_VERSION
    from xvmatch.formats.camera_io import FORMAT_VERSION as CAMERA_VERSION
    from xvmatch.inference.matching.bundle import BUNDLE_FORMAT_VERSION, OPSET

    try:  # the training file format needs torch (the learn extra)
        from xvmatch.models.matcher_file import MATCHER_FORMAT_VERSION as MATCHER
    except ImportError:
        MATCHER = "(needs the learn extra)"
    return (f"xvmatch {__version__}\n"
            f"  geometry features: version {FEATURE_VERSION}\n"
            f"  matcher bundle: format {BUNDLE_FORMAT_VERSION} (ONNX opset {OPSET})\n"
            f"  matcher file (.pt): format {MATCHER}\n"
            f"  camera file: version {CAMERA_VERSION}\n"
            f"  synthetic dataset: schema {SCHEMA_VERSION}")


class _VersionAction(argparse.Action):
    """``--version``, computed only when asked (it may import torch)."""

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        print(version_text())
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every command (also used to render the README's examples)."""
    from xvmatch.commands.adapt import add_adapt_parser
    from xvmatch.commands.associate_multi import add_multi_ego_parser
    from xvmatch.commands.calibrate import add_calibrate_parser
    from xvmatch.commands.demo import add_demo_parser
    from xvmatch.commands.lab.ablate import add_ablate_parser
    from xvmatch.commands.lab.baseline import add_baseline_parser
    from xvmatch.commands.lab.export import add_export_parser
    from xvmatch.commands.lab.fit_geometry import add_fit_geometry_parser
    from xvmatch.commands.lab.show import add_show_parser
    from xvmatch.commands.lab.synth import add_synth_parser
    from xvmatch.commands.lab.train import add_train_parser
    from xvmatch.commands.multicam import add_multicam_parser
    from xvmatch.commands.track import add_track_parser

    parser = argparse.ArgumentParser(
        prog="xvmatch",
        description="Associate the same people across a top/overview view and a horizontal "
        "(egocentric) view.",
    )
    parser.add_argument("--version", action=_VersionAction, nargs=0,
                        help="print the version of xvmatch and of its file formats")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    # In the order a user needs them: try it, match, score, synchronise, data, the baseline,
    # training, deployment, utilities.
    for add_parser in (
        add_demo_parser,
        associate.add_associate_parser,
        evaluate.add_evaluate_parser,
        add_track_parser,
        add_multi_ego_parser,
        add_adapt_parser,
        add_multicam_parser,
        add_calibrate_parser,
        offset.add_offset_parser,
        add_synth_parser,
        add_show_parser,
        add_baseline_parser,
        add_ablate_parser,
        add_fit_geometry_parser,
        add_train_parser,
        add_export_parser,
        noise.add_noise_parser,
    ):
        add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``xvmatch`` command."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except (UsageError, ValueError, OSError) as exc:
        message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"xvmatch: error: {message}", file=sys.stderr)
        return 2
    except MemoryError:
        print(f"xvmatch: error: out of memory running {args.command}: the input or the options "
              "need more memory than this machine has (try smaller inputs or fewer --workers)",
              file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("xvmatch: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
