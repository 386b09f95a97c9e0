"""The ``xvmatch export`` command: a trained matcher file to a deployable bundle folder (ONNX
networks and manifest.json), refused unless onnxruntime reproduces the torch costs. With
``--appearance RUN/appearance_weights.pt`` the network ``xvmatch train`` made takes the place of
the matcher's own (the shipped matcher unless ``--model`` names another;
:mod:`xvmatch.export.appearance_pairing`): the step from training to a bundle. Imports are
lazy: only this command's run loads torch and onnx. Bad input raises ``ValueError`` with a
one-line message, which the main entry point prints as ``xvmatch: error: ...``.
"""

from __future__ import annotations

import argparse
import sys

from xvmatch.commands._options import add_command_parser
from xvmatch.core.output_paths import Input, Output, check_outputs

__all__ = ["EXAMPLE", "add_export_parser"]

EXAMPLE = ("xvmatch export --model geometry.pt --out geometry_bundle/\n"
           "  xvmatch export --appearance runs/appearance_cpu/version_0/appearance_weights.pt "
           "--out my_bundle/   # xvmatch train's network with the shipped matcher")


def add_export_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch export`` on ``subparsers`` and return its parser."""
    help_text = (
        "Export a trained matcher file to a deployable bundle folder: the appearance network "
        "and the matcher as ONNX, and manifest.json (preprocessing, gamma, sha256, the parity "
        "figures). Fails, writing nothing, unless onnxruntime reproduces the torch costs within "
        "1e-4 and the same assignments on held-out synthetic frames."
    )
    p = add_command_parser(subparsers, "export", help_text, EXAMPLE)
    p.add_argument("--model", default=None, metavar="MODEL",
                   help="matcher file (.pt from fit-geometry or the matcher training), or "
                   "'default' (models/default_matcher.pt); with --appearance, the matcher to "
                   "pair it with (default: 'default')")
    p.add_argument("--appearance", default=None, metavar="WEIGHTS",
                   help="appearance weights file from xvmatch train (RUN/appearance_weights.pt): "
                   "put it in place of the matcher's own appearance network, so that the "
                   "bundle runs with associate --model BUNDLE")
    p.add_argument("--out", required=True, metavar="BUNDLE", help="bundle folder to write")
    p.add_argument("--parity-data", default=None, metavar="DIR",
                   help="synthetic dataset (xvmatch synth) for the parity check (default: "
                   "render a small held-out one)")
    p.add_argument("--int8", action="store_true",
                   help="also write a static INT8 (QDQ) appearance network, which the runtime "
                   "then uses (needs --calibration)")
    p.add_argument("--calibration", default=None, metavar="DATA",
                   help="with --int8: synthetic dataset (xvmatch synth, 2+ scenes): even "
                   "scenes calibrate, odd scenes measure the accuracy kept")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=_cmd_export)
    return p


def _cmd_export(args: argparse.Namespace) -> int:
    try:
        from xvmatch.export.onnx_export import ExportError, check_replaceable, export_bundle
        from xvmatch.inference.matching.bundle import int8_refusal
    except ImportError as exc:
        raise ValueError(f"xvmatch export needs the learn extra (torch, onnx): {exc}") from None

    def say(line: str) -> None:
        if not args.quiet:
            print(line, file=sys.stderr)

    if args.int8 != (args.calibration is not None):
        raise ValueError("--int8 and --calibration DATA go together")
    if args.model is None and args.appearance is None:
        raise ValueError("give --model MATCHER (a matcher file, or default), or --appearance "
                         "RUN/appearance_weights.pt (a network from xvmatch train, paired "
                         "with the shipped matcher)")
    model = "default" if args.model is None else args.model
    check_outputs(
        [Output("--out", args.out, folder=True)],
        [Input("--model", None if model == "default" else model),
         Input("--appearance", args.appearance),
         Input("--parity-data", args.parity_data), Input("--calibration", args.calibration)],
    )
    try:
        check_replaceable(args.out)  # only a bundle of an earlier export is replaced
    except ExportError as exc:
        raise ValueError(f"--out {exc}") from None
    if args.appearance is not None:
        from xvmatch.export.appearance_pairing import pair_appearance

        say(f"pairing the appearance network of {args.appearance} with the matcher {model}")
        model = pair_appearance(args.appearance, model)
    manifest = export_bundle(model, args.out, parity_data=args.parity_data,
                             int8_calibration=args.calibration, progress=say)
    if not args.quiet:
        for setting, p in manifest["parity"].items():
            if isinstance(p, dict) and "frames" in p:
                say(f"parity {setting}: {p['frames']} frames, max |cost diff| "
                    f"{p['max_abs_cost_diff']:.1e}, identical assignments "
                    f"{p['assignments_identical']}/{p['frames']}")
        int8 = (manifest.get("appearance") or {}).get("int8")
        if int8:
            acc = int8["accuracy"]
            say(f"INT8 appearance ({int8['calibration']['method']} calibration): Eq. 9 accuracy "
                f"with images {acc['int8']['images']['acc9']:.1f} against FP32 "
                f"{acc['fp32']['images']['acc9']:.1f} on held-out scenes")
            kept = [f"{v['kept']}/{v['pairs']} ({s})"
                    for s, v in (int8.get("agreement") or {}).items()]
            if kept:
                say(f"INT8 kept FP32's matched pairs there: {', '.join(kept)}")
            recheck = int8.get("recheck") or {}
            share = {s: v.get("rechecked", 0.0) for s, v in (recheck.get("accuracy") or {}).items()}
            kept = [f"{v['kept']}/{v['pairs']} ({s}, {100 * share.get(s, 0.0):.0f}% of frames "
                    "re-checked)" for s, v in (recheck.get("agreement") or {}).items()]
            if kept:
                say(f"with near ties re-checked in FP32 (associate; cost tolerance "
                    f"{recheck['tolerance']:.3f}): {', '.join(kept)}")
            reason = int8_refusal(int8, recheck=True)
            say("associate picks INT8 by itself on CPUs with 8-bit dot products (VNNI, Arm "
                "dotprod)" if reason is None else
                f"the runtime will not pick INT8 by itself: {reason}; --precision int8 runs it")
        say(f"wrote {args.out} (cues: {', '.join(manifest['cues']) or 'none, box-only'})")
        if args.appearance is not None:
            say("the matcher's fusion was trained with another appearance network: score the "
                "bundle with xvmatch evaluate on your data before relying on it")
        say(f"run it: xvmatch associate --model {args.out} --top TOP.txt --hor HOR.txt "
            "--top-images TOP --hor-images HOR --out pred.csv")
    return 0
