"""``xvmatch demo``: the deployed matcher on freshly rendered image pairs, beside the baseline.

Renders a handful of drone and overview image pairs (``xvmatch synth``), associates them with
the shipped ONNX matcher from boxes alone, from images, and from images with cameras, and with
the handcrafted rules of the geometric-priors paper on exactly the same boxes (ground truth and
detector noise, ids scrambled), prints the Eq. 9 accuracy of each, and writes one match picture
and a scene laid out as a user's data with the command that matches it. Torch-free.
"""

from __future__ import annotations

import argparse
import os
import shlex
import shutil
import sys
import time
from pathlib import Path

from xvmatch.commands._options import add_command_parser, progress_bar
from xvmatch.commands._types import int_in, seed_value, worker_count
from xvmatch.core.output_paths import (
    Input,
    Output,
    check_outputs,
    check_own_folder,
    claim_folder,
)

__all__ = ["EXAMPLES", "add_demo_parser"]

EXAMPLES = {"demo": "xvmatch demo --out xvmatch-demo --scenes 3 --frames 2"}

DEMO_COMMAND = "xvmatch demo"
"""The owner named in the marker of a demo's folder: the demo writes only into a new or empty
folder or one an earlier demo made (:func:`xvmatch.core.output_paths.claim_folder`)."""

_DEMO_COUNT = int_in(1, 100, "a demonstration holds every pair in memory; for more, xvmatch "
                     "synth + baseline")
"""``--scenes`` and ``--frames`` of the demo: 1..100."""

LEARNED_SETTINGS = (("boxes only", "boxes"), ("images", "images"),
                    ("images + cameras", "images+cameras"))


def add_demo_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch demo`` on ``subparsers`` and return its parser."""
    help_text = ("Render a few drone and overview image pairs, match them with the shipped "
                 "ONNX matcher (boxes, images, images + cameras) and the handcrafted baseline, "
                 "print the accuracies and write a match picture.")
    p = add_command_parser(subparsers, "demo", help_text, EXAMPLES["demo"])
    p.add_argument("--out", default="xvmatch-demo",
                   help="output folder: new, empty, or an earlier demo's (default xvmatch-demo)")
    p.add_argument("--scenes", type=_DEMO_COUNT, default=3,
                   help="scenes per scenario, 1..100 (default 3)")
    p.add_argument("--frames", type=_DEMO_COUNT, default=2,
                   help="frames per scene, 1..100 (default 2)")
    p.add_argument("--seed", type=seed_value, default=7,
                   help="render seed, 0..2**32-1 (default 7)")
    p.add_argument("--model", default="default", metavar="BUNDLE",
                   help="matcher bundle (default: the shipped one)")
    p.add_argument("--workers", type=worker_count, default=1,
                   help="render processes, 1..64 (default 1)")
    p.add_argument("--quiet", action="store_true",
                   help="no progress bar (it shows only on a terminal)")
    p.set_defaults(func=_cmd_demo)
    return p


def _cmd_demo(args: argparse.Namespace) -> int:
    """``xvmatch demo``; a run that fails or is interrupted removes the folder it made (a
    half-made demo folder would pass for one)."""
    from xvmatch.core.folder_marker import is_own_folder

    made = not os.path.lexists(args.out)
    try:
        return _run_demo(args)
    except BaseException:
        if made and is_own_folder(args.out, DEMO_COMMAND):
            shutil.rmtree(args.out, ignore_errors=True)
        raise


def _score_scenario(folder: Path, scenario: str, matcher, coster, rows: dict,
                    want_picture: bool, progress=None):
    """Score every method on the dataset in ``folder`` (one row per method in ``rows``, one
    column per ``(scenario, setting)``); the match picture of the first overview trial with
    images and cameras when ``want_picture`` (else None). ``progress(n)``: told the pairs of
    each scene whose trials are made."""
    from xvmatch.datasets.pair_trials import SETTINGS, TrialConfig, dataset_trials
    from xvmatch.datasets.synthetic_io import SyntheticDataset
    from xvmatch.evaluation.deployed_matcher_eval import matcher_costs, score_matcher
    from xvmatch.evaluation.handcrafted_baseline import BaselineConfig, score_trial
    from xvmatch.inference.linking.assignment import assign
    from xvmatch.metrics.cross_view_metrics import summarize
    from xvmatch.viz.match_drawing import draw_matches

    config = BaselineConfig()
    picture = None
    trials = dataset_trials(folder, TrialConfig(), SETTINGS, coster, progress=progress)
    for setting in SETTINGS:
        part = [t for t in trials if t.setting == setting]
        for m in config.methods():
            name = f"handcrafted: {m.name.lower()}" + (" + cheirality" if m.cheirality
                                                       else "")
            scores = summarize([score_trial(t, m, config.weights) for t in part])
            rows.setdefault(name, {})[(scenario, setting)] = scores.acc9
        for label, key in LEARNED_SETTINGS:
            costs = matcher_costs(matcher, part, key)
            scores = score_matcher(matcher, part, key, costs=costs)
            rows.setdefault(f"learned (ONNX): {label}", {})[(scenario, setting)] = \
                scores.acc9
            if want_picture and picture is None and scenario == "overview" \
                    and key == "images+cameras":
                t, c = part[0], costs[0]
                pair = SyntheticDataset(folder).scene(t.scene).pairs[t.frame - 1]
                picture = draw_matches(
                    pair.top.load_image(), pair.ego.load_image(), t.top_boxes,
                    t.ego_boxes, assign(c, matcher.gamma), costs=c,
                    title=f"{scenario} {t.scene} frame {t.frame}: images + cameras")
    return picture


def _print_table(rows: dict, n_pairs: int) -> None:
    """The accuracy table: a row per method, a column per scenario and setting, the best of
    each column starred."""
    from xvmatch.datasets.pair_trials import SETTINGS

    columns = [(s, g) for s in ("drone", "overview") for g in SETTINGS]
    width = max(len(r) for r in rows)
    head = "  ".join(f"{s[:5]} {('GT' if g == 'gt' else 'det'):>3}" for s, g in columns)
    print(f"Eq. 9 accuracy (%) on {n_pairs} rendered pairs per scenario, "
          "ids scrambled (GT: ground-truth boxes; det: detector noise)")
    print(f"{'method':<{width}}  {head}")
    best = {c: max(r[c] for r in rows.values()) for c in columns}
    for name, r in rows.items():
        cells = "  ".join(f"{r[c]:8.1f}{'*' if r[c] == best[c] else ' '}"[:9].rjust(9)
                          for c in columns)
        print(f"{name:<{width}}  {cells}")
    print("(* best in the column; handcrafted rows use the paper's gammas, the learned rows the "
          "bundle's)")


def _print_next_steps(args: argparse.Namespace, out: Path, picture_path: Path, start: float
                      ) -> None:
    """The scene's input files written, and the commands that match and score it as a user
    would."""
    from xvmatch.datasets.synthetic_io import SyntheticDataset, write_scene_inputs

    scene = SyntheticDataset(out / "data" / "overview")
    inputs = write_scene_inputs(scene.scene(scene.scene_names[0]), out / "scene")
    print(f"\nwrote {picture_path} ({time.perf_counter() - start:.0f} s). Match a scene as a "
          "user would (boxes from any detector, images, optional cameras):")
    q, xvmatch = shlex.quote, xvmatch_command()
    print(f"  {xvmatch} associate --model {q(str(args.model))} --top {q(str(inputs.top))} "
          f"--hor {q(str(inputs.hor))} --top-images {q(str(inputs.top_images))} --hor-images "
          f"{q(str(inputs.hor_images))} --cameras {q(str(inputs.cameras))} --out "
          f"{q(str(out / 'pred.csv'))} --draw {q(str(out / 'pictures'))}")
    print(f"  {xvmatch} evaluate --pred {q(str(out / 'pred.csv'))} --top {q(str(inputs.top))} "
          f"--hor {q(str(inputs.hor))}", file=sys.stdout)


def _run_demo(args: argparse.Namespace) -> int:
    from xvmatch.datasets.synthetic_io import MANIFEST, SyntheticDataset, generate_dataset
    from xvmatch.datasets.synthetic_scenes import SynthConfig
    from xvmatch.evaluation.deployed_matcher_eval import OnnxAppearanceCoster
    from xvmatch.inference.matching.learned_association import load_matcher_bundle
    from xvmatch.viz.match_drawing import write_match_picture

    start = time.perf_counter()
    out = Path(args.out)
    check_outputs([Output("--out", out, folder=True, files=("match.png",))],
                  [Input("--model", None if args.model == "default" else args.model)])
    check_own_folder(out, DEMO_COMMAND)
    matcher = load_matcher_bundle(args.model)
    claim_folder(out, DEMO_COMMAND)
    coster = OnnxAppearanceCoster(matcher)
    rows: dict[str, dict[tuple[str, str], float]] = {}
    picture = None
    wanted = args.scenes * args.frames
    # Each pair is counted twice: rendered (or found from an earlier demo), then matched.
    with progress_bar(4 * wanted, "demo", "pair", not args.quiet) as bar:
        for k, scenario in enumerate(("drone", "overview")):
            folder = out / "data" / scenario
            bar.set_postfix_str(f"rendering {scenario}")
            if not ((folder / MANIFEST).is_file() and len(SyntheticDataset(folder)) == wanted
                    and SyntheticDataset(folder).seed == args.seed + k):
                generate_dataset(folder, SynthConfig(scenario=scenario), n_scenes=args.scenes,
                                 n_frames=args.frames, seed=args.seed + k,
                                 workers=args.workers, progress=bar.update)
            bar.update((2 * k + 1) * wanted - bar.n)
            bar.set_postfix_str(f"matching {scenario}")
            drawn = _score_scenario(folder, scenario, matcher, coster, rows, picture is None,
                                    bar.update)
            bar.update((2 * k + 2) * wanted - bar.n)
            picture = picture if picture is not None else drawn
    _print_table(rows, args.scenes * args.frames)
    picture_path = out / "match.png"
    if picture is not None:
        write_match_picture(picture_path, picture)
    _print_next_steps(args, out, picture_path, start)
    return 0


def xvmatch_command() -> str:
    """How to run this xvmatch from a shell, as printed commands start (issue 29, item 3):
    ``xvmatch`` when that name on ``PATH`` is the running entry point; else the full path of
    the entry point beside the running interpreter (a virtual environment not activated);
    else ``PYTHON -m xvmatch`` with the running interpreter's path. Quoted for a POSIX shell."""
    here = os.path.join(os.path.dirname(sys.executable), "xvmatch")
    if os.path.isfile(here) and os.access(here, os.X_OK):
        found = shutil.which("xvmatch")
        if found and os.path.realpath(found) == os.path.realpath(here):
            return "xvmatch"
        return shlex.quote(here)
    return f"{shlex.quote(sys.executable)} -m xvmatch"
