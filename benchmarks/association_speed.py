"""Association speed on the CVMHAT dev split: frames per second, single thread.

Measures, on the same frames in the same run:
  * exhaustive search (every O, every theta; frame mode, the paper's Table 3 first column),
  * reduced theta (damped window S_t, every O),
  * reduced theta + O followed (video mode),
each in-process, and the whole ``xvmatch associate`` CLI (process start, file parsing, writing)
in frame mode, in video mode (its default: the exhaustive search, then the tracklet consensus)
and in video mode with ``--search follow`` (the video default before issue 67). Prints
frames/s from CPU time (robust to other load on the machine) and from wall time, and the
speed-up of each mode over the exhaustive search.

Targets (issue 2): exhaustive >= 200 frames/s with the CLI included; video >= 1000 frames/s.
The paper reports 3.1 / 26.3 / 44.8 frames/s in MATLAB on an i9 (Table 3).

Usage:
    python benchmarks/association_speed.py [--data ../shared/data/cvmhat] [--sequences N]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from xvmatch.cues.spatial_search import associate_sequence  # noqa: E402
from xvmatch.formats.cvmhat import (  # noqa: E402
    IMAGE_SIZE,
    default_cvmhat_dir,
    read_sequence,
    sequence_names,
)

WIDTH = IMAGE_SIZE[0]


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=default_cvmhat_dir(), help="CVMHAT boxes")
    parser.add_argument("--sequences", type=int, default=0, help="use only the first N (0 = all)")
    parser.add_argument("--no-cli", action="store_true", help="skip the whole-CLI timing")
    args = parser.parse_args()
    if not (args.data / "README.md").exists():
        print(f"CVMHAT data not found at {args.data}; nothing to measure (skipped).")
        return 0
    names = sequence_names(args.data)
    if args.sequences:
        names = names[: args.sequences]
    pairs = {n: read_sequence(args.data, n) for n in names}
    n_frames = sum(len(set(t) | set(h)) for t, h in pairs.values())

    rows = []
    for mode in ("exhaustive", "reduced", "follow"):
        cpu0, wall0 = time.process_time(), time.perf_counter()
        for top, hor in pairs.values():
            associate_sequence(top, hor, WIDTH, search=mode)
        cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
        rows.append((f"in-process, {mode}", cpu, wall))

    if not args.no_cli:
        exe = [sys.executable, "-m", "xvmatch"]
        for label, extra in (
            ("CLI, frame (exhaustive)", []),
            ("CLI, video (exhaustive, consensus)", ["--mode", "video"]),
            ("CLI, video, --search follow", ["--mode", "video", "--search", "follow"]),
        ):
            cpu0, wall0 = _children_cpu(), time.perf_counter()
            with tempfile.TemporaryDirectory() as tmp:
                for n in names:
                    cmd = [
                        *exe,
                        "associate",
                        "--quiet",
                        "--top",
                        str(args.data / f"{n}_top.txt"),
                        "--hor",
                        str(args.data / f"{n}_hor.txt"),
                        "--out",
                        f"{tmp}/{n}.csv",
                        *extra,
                    ]
                    subprocess.run(cmd, check=True, stderr=subprocess.DEVNULL)
            rows.append((label, _children_cpu() - cpu0, time.perf_counter() - wall0))

    base_cpu = rows[0][1]
    print(f"CVMHAT dev split: {len(names)} sequences, {n_frames} frames, single thread")
    print(f"{'mode':34s} {'fps (cpu)':>10s} {'fps (wall)':>11s} {'speed-up':>9s}")
    for label, cpu, wall in rows:
        print(f"{label:34s} {n_frames / cpu:10.0f} {n_frames / wall:11.0f} {base_cpu / cpu:8.1f}x")
    print("targets: CLI frame >= 200 fps, CLI video >= 1000 fps (paper, MATLAB: 3.1 / 26.3 / 44.8)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
