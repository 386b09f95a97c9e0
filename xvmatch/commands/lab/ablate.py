"""The ``xvmatch ablate`` command: learned against handcrafted fusion, cue by cue, with
uncertainty, as a report with tables and plots (:mod:`xvmatch.evaluation.ablation`).

``add_ablate_parser`` registers the sub-command; its ``func`` returns an exit code. Imports are
lazy, so other commands never load the ablation's modules (or matplotlib). Bad input raises
``ValueError`` with a one-line message, which the main entry point prints as
``xvmatch: error: ...`` with exit code 2, before any work starts.
"""

from __future__ import annotations

import argparse
import shlex
import sys

from xvmatch.commands._options import add_command_parser, progress_bar
from xvmatch.commands._types import int_in, worker_count
from xvmatch.core.output_paths import Input, Output, check_outputs

__all__ = ["EXAMPLE", "add_ablate_parser"]

EXAMPLE = (
    "xvmatch synth --out data/drone --scenario drone --scenes 20 --frames 3 --seed 1000\n"
    "  xvmatch synth --out data/overview --scenario overview --scenes 20 --frames 3 --seed 1000\n"
    "  xvmatch ablate --data data/drone data/overview --model default --out ablation/ "
    "--seeds 3 --sweep noise --workers 2"
)

SWEEP_CHOICES = ("noise", "calibration", "crowd", "lookalike")
"""The sweeps (:data:`xvmatch.evaluation.ablation_settings.SWEEPS`, kept here so ``--help``
needs no import of the evaluation modules; a test checks that they agree)."""

SEEDS_TYPE = int_in(1, 20, "repetitions for the 95% interval; each one recomputes the grid")
CVMHAT_STEP_TYPE = int_in(1, 1000, "every how many frames the CVMHAT sequences are scored")


def add_ablate_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch ablate`` on ``subparsers`` and return its parser."""
    help_text = (
        "Compare learned against handcrafted fusion, cue by cue, on synthetic datasets: every "
        "cue alone, the handcrafted sum and product rules (paper and tuned gammas), the CVMHAT "
        "search and the learned matcher with and without each cue, on ground-truth boxes, "
        "detector noise and one sweep, over several seeds with 95%% intervals. Writes "
        "report.md, results.csv, results.json and PNG plots into the report folder; finished "
        "cells are kept there and reused when the command runs again."
    )
    # the help is %-formatted, the description is not
    p = add_command_parser(subparsers, "ablate", help_text, EXAMPLE,
                           description=help_text.replace("%%", "%"))
    p.add_argument("--data", required=True, nargs="+", metavar="DIR",
                   help="dataset folders written by xvmatch synth, one table each (every 5th "
                   "scene is the validation split, the rest the test split)")
    p.add_argument("--model", default="default", metavar="BUNDLE|default",
                   help="the learned matcher: a bundle folder (xvmatch export) that takes "
                   "images and cameras, or the shipped one (default)")
    p.add_argument("--out", required=True, metavar="REPORT",
                   help="report folder (created; a folder of an earlier run with the same "
                   "options is resumed)")
    p.add_argument("--seeds", type=SEEDS_TYPE, default=3, metavar="N",
                   help="seeds 0..N-1, N in 1..20 (default 3): each changes the detector noise, "
                   "the box shuffling, the calibration error and the sweep's renders")
    p.add_argument("--sweep", choices=SWEEP_CHOICES, default="noise",
                   help="the swept condition (default noise): detector noise x0-2, calibration "
                   "error 0-5 degrees and 0-1 m, crowd of 3-30 people, look-alike rate 0-0.75")
    p.add_argument("--cvmhat", default=None, metavar="DIR",
                   help="also compare the handcrafted search and the learned encoder on the real "
                   "CVMHAT boxes of DIR (NAME_top.txt / NAME_hor.txt), clean and noisy")
    p.add_argument("--cvmhat-step", type=CVMHAT_STEP_TYPE, default=10, metavar="K",
                   help="score every K-th CVMHAT frame, K in 1..1000 (default 10)")
    p.add_argument("--workers", type=worker_count, default=1, metavar="K",
                   help="processes computing cells, 1..64 (default 1); the numbers do not "
                   "depend on it")
    p.add_argument("--quiet", action="store_true",
                   help="no progress bar, and print only where the report is")
    p.set_defaults(func=_cmd_ablate)
    return p


def _command_line(args: argparse.Namespace) -> str:
    """The command as run, options in a fixed order (what the report quotes)."""
    words = ["xvmatch", "ablate", "--data", *args.data, "--model", args.model, "--out",
             args.out, "--seeds", str(args.seeds), "--sweep", args.sweep]
    if args.cvmhat is not None:
        words += ["--cvmhat", args.cvmhat, "--cvmhat-step", str(args.cvmhat_step)]
    words += ["--workers", str(args.workers)]
    return shlex.join(words)


def _cmd_ablate(args: argparse.Namespace) -> int:
    from xvmatch import __version__
    from xvmatch.evaluation.ablation import AblationOptions, run_ablation

    check_outputs([Output("--out", args.out, folder=True)],
                  [*(Input("--data", d) for d in args.data), Input("--cvmhat", args.cvmhat),
                   Input("--model", None if args.model == "default" else args.model)])
    options = AblationOptions(data=tuple(args.data), out=args.out, model=args.model,
                              seeds=args.seeds, sweep=args.sweep, cvmhat=args.cvmhat,
                              cvmhat_step=args.cvmhat_step, workers=args.workers)
    bar = None

    def progress(done: int, total: int) -> None:
        nonlocal bar
        if bar is None:
            bar = progress_bar(total, "ablate", "cell", not args.quiet, leave=True,
                               initial=done)
        else:
            bar.update(done - bar.n)

    try:
        run = run_ablation(options, _command_line(args), progress, version=__version__)
    finally:
        if bar is not None:
            bar.close()
    if not args.quiet:
        print(run.report)
    print(f"xvmatch: ablation: {run.computed} cells computed, {run.reused} reused, "
          f"{run.seconds:.0f} s; wrote {args.out}/report.md and {len(run.files) - 1} more files",
          file=sys.stderr)
    return 0
