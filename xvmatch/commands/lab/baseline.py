"""The ``xvmatch baseline`` command: Tables I-II of the geometric-priors paper on synthetic pairs.

``add_baseline_parser`` registers the sub-command on the ``subparsers`` of the main parser; its
``func`` takes the parsed arguments and returns an exit code. Imports are lazy so other commands
never load OpenCV or scipy through it. Bad input raises ``ValueError`` with a one-line message,
which the main entry point prints as ``xvmatch: error: ...``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from xvmatch.commands._options import add_command_parser, progress_bar
from xvmatch.commands._types import seed_value, worker_count
from xvmatch.core.output_paths import (
    Input,
    Output,
    check_outputs,
    check_own_folder,
    claim_folder,
)

__all__ = ["EXAMPLE", "add_baseline_parser"]

FIGURES_COMMAND = "xvmatch baseline --figures"
"""The marker name of a ``--figures`` folder (the command writes only into a folder it made)."""

EXAMPLE = (
    "xvmatch synth --out data/ov_test --scenario overview --scenes 20 --frames 5 --seed 1000\n"
    "  xvmatch baseline --data data/ov_test --figures figures/"
)


def _gamma(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"gamma must be a finite cost > 0, got {text!r}")
    return value


def add_baseline_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch baseline`` on ``subparsers`` and return its parser."""
    help_text = (
        "Handcrafted association baseline of the geometric-priors paper on a synthetic dataset: "
        "Eq. 9 accuracy of geometry only, histogram only, sum and product fusion, each with and "
        "without cheirality, on ground-truth boxes (Table I) and with detector noise matched to "
        "ground truth at IoU 0.3 (Table II)."
    )
    p = add_command_parser(subparsers, "baseline", help_text, EXAMPLE)
    p.add_argument("--data", required=True, metavar="DIR",
                   help="dataset folder written by xvmatch synth (the paper's setting: "
                   "--scenario overview)")
    p.add_argument("--noise-seed", type=seed_value, default=0, metavar="S",
                   help="seed of the detector noise of the Table II setting, 0..2**32-1 "
                   "(default 0)")
    p.add_argument("--scramble-seed", type=seed_value, default=0, metavar="S",
                   help="seed of the per-view shuffling of the boxes, 0..2**32-1 (default 0); "
                   "the table does not depend on it")
    p.add_argument("--figures", default=None, metavar="DIR",
                   help="also write the true/false cost distributions before and after "
                   "normalisation (Figs. 2-3) as PNG files into DIR")
    p.add_argument("--json", action="store_true", help="print JSON instead of the table")
    p.add_argument("--workers", type=worker_count, default=1, metavar="K",
                   help="processes computing the costs, 1..64 (default 1); the result does not "
                   "depend on it")
    g = p.add_argument_group(
        "non-association costs gamma (Eq. 2); the table's gamma column shows those used"
    )
    g.add_argument("--gamma-geo", type=_gamma, default=None, metavar="G",
                   help="geometry only, a finite cost > 0 (default: tuned on the validation seed "
                   "2000, see xvmatch.evaluation.handcrafted_baseline.GAMMA_GEO)")
    g.add_argument("--gamma-hist", type=_gamma, default=None, metavar="G",
                   help="histogram only, a finite cost > 0 (default: tuned on the validation seed "
                   "2000, GAMMA_HIST)")
    g.add_argument("--gamma-sum", type=_gamma, default=None, metavar="G",
                   help="sum combination, w = 0.5, a finite cost > 0 (default: the paper's 0.25)")
    g.add_argument("--gamma-product", type=_gamma, default=None, metavar="G",
                   help="product combination of Eq. 8, a finite cost > 0 (default: the paper's "
                   "0.1)")
    p.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    p.set_defaults(func=_cmd_baseline)
    return p


def _cmd_baseline(args: argparse.Namespace) -> int:
    from xvmatch.datasets.pair_trials import open_dataset
    from xvmatch.evaluation.cost_distributions import FIGURE_FILES, save_cost_figures
    from xvmatch.evaluation.handcrafted_baseline import (
        BaselineConfig,
        evaluate_baseline,
        format_baseline_table,
    )

    gammas = {f"gamma_{rule}": getattr(args, f"gamma_{rule}")
              for rule in ("geo", "hist", "sum", "product")}
    config = BaselineConfig(
        **{k: v for k, v in gammas.items() if v is not None},
        noise_seed=args.noise_seed, scramble_seed=args.scramble_seed,
    )
    check_outputs([Output("--figures", args.figures, folder=True,
                          files=tuple(FIGURE_FILES.values()))], [Input("--data", args.data)])
    if args.figures:
        check_own_folder(args.figures, FIGURES_COMMAND, "--figures")
    dataset = open_dataset(args.data)
    start = time.perf_counter()
    with progress_bar(len(dataset), "baseline", "pair", not args.quiet) as bar:
        result = evaluate_baseline(args.data, config, workers=args.workers,
                                   progress=bar.update)
    elapsed = time.perf_counter() - start
    figures = (save_cost_figures(result.samples, claim_folder(args.figures, FIGURES_COMMAND,
                                                              "--figures"))
               if args.figures else [])
    if args.json:
        record = result.to_dict()
        record["figures"] = [str(f) for f in figures]
        print(json.dumps(record, indent=2))
    else:
        print(format_baseline_table(result))
    if not args.quiet:
        if result.scenario != "overview":
            print(f"xvmatch: note: {args.data} is a {result.scenario!r} dataset; the paper's "
                  "setting is --scenario overview", file=sys.stderr)
        for f in figures:
            print(f"wrote {f}", file=sys.stderr)
        print(f"evaluated {result.n_pairs} pairs x 2 settings x {len(result.methods)} methods "
              f"in {elapsed:.1f} s", file=sys.stderr)
    return 0
