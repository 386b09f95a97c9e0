"""Every numeric option of every command has a documented range, checked before any work starts
(issue 22): the known failures end at once with exit code 2 and a message giving the range, and
a property test drives each option with random values and requires a clean exit (0 or 2, never a
traceback) within a bound of time and memory.

The property test runs the commands in one long-lived ``python -c`` worker process that calls
``xvmatch.cli.main`` for each argument list it is sent, under a 4 GiB address-space limit and a
per-call timeout, so the package is imported once rather than once per example. ``train`` is a
LightningCLI passthrough with no numeric option of its own; ``export`` has none.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import select
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.cli import build_parser, main
from xvmatch.datasets.box_scene import simulate_box_scene, write_box_scene
from xvmatch.formats.mot_boxes import read_mot_boxes, write_predictions

CALL_TIMEOUT_S = 60.0
"""Most seconds one command may take in the property test."""
PROMPT_S = 5.0
"""Most seconds a value outside its range may take to be refused."""
MEMORY_LIMIT = 4 << 30
"""Address-space limit of the worker process (RLIMIT_AS), bytes."""


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Path]:
    """Tiny inputs of every command: a 6-frame simulated scene (``top``, ``hor``), its
    ground-truth pairs (``pred``), a 1-scene, 2-frame, 64x36 synthetic dataset (``dataset``),
    a scratch folder (``scratch``) and a path that does not exist (``missing``)."""
    from xvmatch.datasets.synthetic_io import generate_dataset
    from xvmatch.datasets.synthetic_scenes import SynthConfig

    root = tmp_path_factory.mktemp("bounds")
    top, hor = write_box_scene(simulate_box_scene(n_frames=6, seed=1), root, "sim")
    t, h = read_mot_boxes(top), read_mot_boxes(hor)
    pairs = {f: [(int(i), int(i)) for i in sorted(set(t[f].ids) & set(h[f].ids))]
             for f in sorted(set(t) & set(h))}
    write_predictions(root / "pred.csv", pairs)
    config = SynthConfig(top_size=(64, 36), ego_size=(64, 36), n_people=(2, 3))
    generate_dataset(root / "dataset", config, n_scenes=1, n_frames=2, seed=0)
    (root / "scratch").mkdir()
    return {"top": top, "hor": hor, "pred": root / "pred.csv", "dataset": root / "dataset",
            "scratch": root / "scratch", "missing": root / "missing"}


# --------------------------------------------------------------------------------------------
# (a) the failures of the issue: refused at once, with the range and its reason


def _refused(capsys, argv: list[str], option: str) -> str:
    """Run ``argv``; it must stop at argument parsing, quickly, with exit code 2 and an error
    line naming ``option``. Returns that line."""
    start = time.perf_counter()
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert time.perf_counter() - start < PROMPT_S
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    line = err.splitlines()[-1]
    assert line.startswith(f"xvmatch {argv[0]}: error: argument {option}: "), err
    return line


def test_associate_dtheta_too_fine(inputs, capsys):
    argv = ["associate", "--top", str(inputs["top"]), "--hor", str(inputs["hor"]), "--out",
            str(inputs["scratch"] / "p.csv"), "--dtheta", "1e-6"]
    line = _refused(capsys, argv, "--dtheta")
    assert line.endswith("expected a number in [0.01, 360] (the search tries 360 / dtheta "
                         "orientations), got '1e-6'")
    assert not (inputs["scratch"] / "p.csv").exists()


def test_offset_dtheta_too_fine(inputs, capsys):
    argv = ["offset", "--top", str(inputs["top"]), "--hor", str(inputs["hor"]), "--dtheta",
            "1e-6"]
    assert "[0.01, 360] (the search tries 360 / dtheta" in _refused(capsys, argv, "--dtheta")


def test_offset_max_offset_beyond_any_video(inputs, capsys):
    argv = ["offset", "--top", str(inputs["top"]), "--hor", str(inputs["hor"]), "--max-offset",
            "1000000000", "--clips", "1"]
    line = _refused(capsys, argv, "--max-offset")
    assert "expected an integer in [0, 10000] (each clip is compared at 2 * max_offset + 1" in line


@pytest.mark.slow
@pytest.mark.parametrize("command", ["offset", "associate"])
def test_max_offset_beyond_the_videos_length(inputs, capsys, command):
    # Within [0, 10000] but longer than the 6 frames the two files span: refused after reading
    # the box files, before any search. (The default, 60, is not checked: see test_cli.)
    argv = [command, "--top", str(inputs["top"]), "--hor", str(inputs["hor"]),
            "--max-offset", "7"]
    if command == "associate":
        argv += ["--out", str(inputs["scratch"] / "p.csv"), "--offset", "auto"]
    start = time.perf_counter()
    assert main(argv) == 2
    assert time.perf_counter() - start < PROMPT_S
    out, err = capsys.readouterr()
    assert out == ""
    assert err == ("xvmatch: error: --max-offset 7 is more than the videos' length: the box "
                   "files span 6 frames (1..6) and no larger offset aligns any frame; use at "
                   "most 6\n")
    argv[argv.index("7")] = "6"
    assert main([*argv, "--quiet"] if command == "associate" else argv) == 0


def test_noise_false_boxes_per_frame(inputs, capsys):
    out = inputs["scratch"] / "n.txt"
    argv = ["noise", "--boxes", str(inputs["top"]), "--view", "top", "--out", str(out),
            "--false", "1e9"]
    assert "expected a number in [0, 500] (false boxes per frame" in _refused(capsys, argv,
                                                                              "--false")
    assert not out.exists()


def test_synth_image_size(inputs, capsys):
    out = inputs["scratch"] / "synth"
    argv = ["synth", "--out", str(out), "--scenes", "1", "--frames", "1", "--size",
            "100000x100000"]
    line = _refused(capsys, argv, "--size")
    assert "image size must be at least 8x8 and at most 8192x8192 (each image is held" in line
    assert not out.exists()


# --------------------------------------------------------------------------------------------
# (b) every numeric option, random values


def _int(text: str) -> int | None:
    try:
        return int(text)
    except ValueError:
        return None


def _size(text: str) -> tuple[int, int] | None:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        return None
    return w, h


@dataclass(frozen=True)
class Option:
    """A numeric option, its documented range and how to drive it cheaply.

    Attributes:
        command, flag: where it is.
        kind: ``int``, ``float``, ``size`` (WxH, both sides in range), ``people`` (MIN:MAX),
            ``offset`` (an int or ``auto``).
        low, high: the documented range (None: unbounded on that side).
        open_low, open_high: the bound is excluded.
        help: how the option's help text states the range.
        cheap: values inside the range that keep the command small, where some inside values
            would start long work (None: any inside value is cheap with the base arguments).
        extra: arguments the option needs to take effect.
        auto: ``auto`` is also a value (``--hor-hfov``).
    """

    command: str
    flag: str
    kind: str
    low: float | None
    high: float | None
    help: str
    open_low: bool = False
    open_high: bool = False
    cheap: st.SearchStrategy[str] | None = None
    extra: tuple[str, ...] = ()
    auto: bool = False

    def inside(self, text: str) -> bool:
        """Whether ``text`` is a value of the documented range."""
        if (self.kind == "offset" or self.auto) and text.strip().lower() == "auto":
            return True
        if self.kind in ("int", "offset"):
            values = [_int(text)]
        elif self.kind == "size":
            values = list(_size(text) or [None])
        elif self.kind == "people":
            parts = [_int(v) for v in text.split(":")]
            if len(parts) != 2 or None in parts or parts[0] > parts[1]:
                return False
            values = parts
        else:
            try:
                values = [float(text)]
            except ValueError:
                return False
            if not math.isfinite(values[0]):
                return False
        return all(v is not None and self._within(v) for v in values)

    def _within(self, v: float) -> bool:
        above = self.low is None or (v > self.low if self.open_low else v >= self.low)
        below = self.high is None or (v < self.high if self.open_high else v <= self.high)
        return above and below


def _floats(low: float, high: float) -> st.SearchStrategy[str]:
    return st.floats(low, high).map(repr)


SEED, ID = (0, 2**32 - 1), (-(2**53), 2**53)
SPATIAL = [
    ("--rho", 1, 1e6, "in (1, 1e6]", True, False),
    ("--lam", 0, 1e6, "in (0, 1e6]", True, False),
    ("--tau", 0, 90, "in [0, 90]", False, False),
    ("--dtheta", 0.01, 360, "in [0.01, 360]", False, False),
    ("--fov", 0, 180, "in (0, 180)", True, True),
]
OPTIONS = [
    Option("associate", "--camera-id", "int", *ID, "|id| <= 2**53"),
    Option("associate", "--image-size", "size", 8, 65536, "8..65536 a side"),
    Option("associate", "--top-image-size", "size", 8, 65536, "8..65536 a side"),
    Option("associate", "--hor-hfov", "float", 20, 150, "in [20, 150]", auto=True),
    Option("associate", "--fps", "float", 0.1, 1000, "in [0.1, 1000]", auto=True),
    Option("associate", "--offset", "offset", -100_000, 100_000, "|N| <= 100000"),
    Option("associate", "--max-offset", "int", 0, 10_000, "0..10000", extra=("--offset", "auto")),
    Option("associate", "--workers", "int", 1, 64, "1..64"),
    Option("associate", "--draw-every", "int", 1, 100_000, "1..100000"),
    # With --model: the shipped matcher on 6 frames is quick, but up to 64 onnxruntime threads
    # is not: inside values are 1 or 2 threads.
    Option("associate", "--threads", "int", 1, 64, "1..64", extra=("--model", "default"),
           cheap=st.sampled_from(["1", "2"])),
    Option("associate", "--gamma", "float", 0, 1, "in (0, 1]", open_low=True,
           extra=("--model", "default")),
    *(Option("associate", f, "float", lo, hi, h, open_low=ol, open_high=oh)
      for f, lo, hi, h, ol, oh in SPATIAL),
    Option("evaluate", "--offset", "int", -100_000, 100_000, "|N| <= 100000"),
    Option("associate", "--min-score", "float", -1e6, 1e6, "in [-1e6, 1e6]"),
    *(Option(c, "--first-frame", "int", 0, 1, "{0,1}") for c in ("associate", "evaluate")),
    Option("noise", "--seed", "int", *SEED, "0..2**32-1"),
    Option("noise", "--jitter", "float", 0, 1, "in [0, 1]"),
    Option("noise", "--miss", "float", 0, 1, "in [0, 1]"),
    Option("noise", "--false", "float", 0, 500, "in [0, 500]"),
    Option("noise", "--keep-id", "int", *ID, "|id| <= 2**53"),
    Option("noise", "--image-size", "size", 8, 65536, "8..65536 a side"),
    Option("offset", "--camera-id", "int", *ID, "|id| <= 2**53"),
    Option("offset", "--clip-start", "int", 1, 2**53, "1..2**53"),
    Option("offset", "--clips", "int", 1, 100, "1..100"),
    Option("offset", "--clip-length", "int", 1, 1000, "1..1000"),
    Option("offset", "--step", "int", 1, 11, "1..11"),
    Option("offset", "--max-offset", "int", 0, 10_000, "0..10000"),
    Option("offset", "--image-size", "size", 8, 65536, "8..65536 a side"),
    # Up to 64 processes for a 2-frame clip: inside values are 1 or 2 processes.
    Option("offset", "--workers", "int", 1, 64, "1..64", cheap=st.sampled_from(["1", "2"])),
    # --dtheta 0.01 takes seconds per offset search here: inside values are from 0.5 degrees
    # (associate draws the 0.01 edge).
    *(Option("offset", f, "float", lo, hi, h, open_low=ol, open_high=oh,
             cheap=_floats(0.5, 360) if f == "--dtheta" else None)
      for f, lo, hi, h, ol, oh in SPATIAL),
    # demo, baseline and fit-geometry run on a missing model, dataset or folder: values inside
    # the range are parsed and the command stops at that check (their real runs take minutes).
    Option("demo", "--scenes", "int", 1, 100, "1..100"),
    Option("demo", "--frames", "int", 1, 100, "1..100"),
    Option("demo", "--seed", "int", *SEED, "0..2**32-1"),
    Option("demo", "--workers", "int", 1, 64, "1..64"),
    # synth renders: 1 to 3 scenes and frames, small images and 1 or 2 processes inside.
    Option("synth", "--scenes", "int", 1, 100_000, "1..100000", cheap=st.sampled_from("123")),
    Option("synth", "--frames", "int", 1, 10_000, "1..10000", cheap=st.sampled_from("123")),
    Option("synth", "--seed", "int", *SEED, "0..2**32-1"),
    Option("synth", "--people", "people", 1, 60, "MAX <= 60"),
    Option("synth", "--size", "size", 8, 8192, "8..8192 a side",
           cheap=st.tuples(st.integers(8, 160), st.integers(8, 160)).map("{0[0]}x{0[1]}".format)),
    Option("synth", "--fps", "float", 0.1, 1000, "in [0.1, 1000]"),
    Option("synth", "--workers", "int", 1, 64, "1..64", cheap=st.sampled_from(["1", "2"])),
    Option("synth", "--egos", "int", 2, 3, "2..3"),
    Option("synth", "--texture", "float", 0, 1, "in [0, 1]", cheap=st.sampled_from(["0", "0.5"])),
    # --cameras: one rendered 1-frame scene of 64x36 images per inside value.
    Option("synth", "--cameras", "int", 2, 8, "2..8"),
    Option("show", "--frame", "int", 1, 2**53, "1..2**53"),
    Option("show", "--image-size", "size", 8, 65536, "8..65536 a side"),
    Option("show", "--bits", "int", 1, 8, "{1..8}"),
    Option("baseline", "--noise-seed", "int", *SEED, "0..2**32-1"),
    Option("baseline", "--scramble-seed", "int", *SEED, "0..2**32-1"),
    Option("baseline", "--workers", "int", 1, 64, "1..64"),
    *(Option("baseline", f"--gamma-{r}", "float", 0, None, "a finite cost > 0",
             open_low=True)
      for r in ("geo", "hist", "sum", "product")),
    Option("fit-geometry", "--image-size", "size", 8, 65536, "8..65536 a side"),
    Option("fit-geometry", "--epochs", "int", 1, 1000, "1..1000"),
    Option("fit-geometry", "--seed", "int", *SEED, "0..2**32-1"),
    Option("fit-geometry", "--noise", "int", 0, 100, "0..100"),
    Option("fit-geometry", "--sim-scenes", "int", 0, 100_000, "0..100000"),
    Option("fit-geometry", "--width", "int", 4, 1024, "4..1024"),
    Option("fit-geometry", "--layers", "int", 0, 16, "0..16"),
    Option("fit-geometry", "--workers", "int", 1, 64, "1..64"),
    Option("fit-geometry", "--threads", "int", 1, 64, "1..64"),
]
COMMANDS = ("associate", "evaluate", "noise", "offset", "demo", "synth", "show", "baseline",
            "fit-geometry", "export")

_calls = itertools.count()


def _base(command: str, inputs: dict[str, Path]) -> list[str]:
    """Arguments that make ``command`` small (or stop it at a missing input: see OPTIONS)."""
    top, hor, scratch = str(inputs["top"]), str(inputs["hor"]), inputs["scratch"]
    fresh = scratch / f"out{next(_calls)}"
    return {
        "associate": ["associate", "--top", top, "--hor", hor, "--out", f"{fresh}.csv",
                      "--quiet"],
        "evaluate": ["evaluate", "--pred", str(inputs["pred"]), "--top", top, "--hor", hor],
        "noise": ["noise", "--boxes", top, "--view", "top", "--out", f"{fresh}.txt"],
        "offset": ["offset", "--top", top, "--hor", hor, "--max-offset", "2", "--clips", "1",
                   "--clip-length", "2"],
        "demo": ["demo", "--out", str(fresh), "--model", str(inputs["missing"])],
        "synth": ["synth", "--out", str(fresh), "--scenes", "1", "--frames", "1", "--size",
                  "64x36", "--quiet"],
        "show": ["show", str(inputs["dataset"]), "--out", f"{fresh}.png"],
        "baseline": ["baseline", "--data", str(inputs["missing"]), "--quiet"],
        "fit-geometry": ["fit-geometry", "--cvmhat", str(inputs["missing"]), "--out",
                         f"{fresh}.pt", "--quiet"],
    }[command]


def test_every_numeric_option_is_listed_and_documents_its_range():
    # A numeric option added later must join OPTIONS (and so the property test) and say its
    # range in --help.
    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    listed = {(o.command, o.flag): o for o in OPTIONS}
    found = set()
    for name in COMMANDS:
        for action in commands.choices[name]._actions:
            numeric = action.type not in (None, str) and action.option_strings
            if numeric:
                found.add((name, action.option_strings[0]))
                option = listed.get((name, action.option_strings[0]))
                assert option is not None, f"{name} {action.option_strings[0]} not in OPTIONS"
                assert option.help in (action.help or "") or option.help == action.metavar, (
                    f"{name} {option.flag}: help {action.help!r} does not give {option.help!r}")
    assert found == set(listed)


class _Worker:
    """A ``python -c`` process that runs ``xvmatch.cli.main`` on each argument list it is
    sent, under an address-space limit; its stdout and stderr go to ``log``."""

    SCRIPT = (
        "import json, os, sys\n"
        "from xvmatch.cli import main\n"
        "results = os.fdopen(int(sys.argv[1]), 'w')\n"
        "for line in sys.stdin:\n"
        "    try:\n"
        "        code = main(json.loads(line))\n"
        "    except SystemExit as exc:\n"
        "        code = exc.code\n"
        "    sys.stdout.flush(); sys.stderr.flush()\n"
        "    results.write(json.dumps(code) + '\\n'); results.flush()\n"
    )

    def __init__(self, log: Path) -> None:
        self.log, self.proc = log, None

    def _start(self) -> None:
        import resource

        def limit() -> None:
            resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))

        read, write = os.pipe()
        # One BLAS/OpenMP thread: the address space then depends on the command, not on the
        # number of cores of the machine running the tests.
        env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
               "MKL_NUM_THREADS": "1"}
        with open(self.log, "ab") as log:
            self.proc = subprocess.Popen(
                [sys.executable, "-c", self.SCRIPT, str(write)], stdin=subprocess.PIPE,
                stdout=log, stderr=log, pass_fds=(write,), preexec_fn=limit, env=env)
        os.close(write)
        self.results = os.fdopen(read, "r")

    def run(self, argv: list[str]) -> tuple[int | None, str, float]:
        """Exit code (None: the worker died or ran out of time), the output, and seconds."""
        if self.proc is None or self.proc.poll() is not None:
            self._start()
        start_at = self.log.stat().st_size
        start = time.perf_counter()
        self.proc.stdin.write((json.dumps(argv) + "\n").encode())
        self.proc.stdin.flush()
        ready, _, _ = select.select([self.results], [], [], CALL_TIMEOUT_S)
        line = self.results.readline() if ready else ""
        elapsed = time.perf_counter() - start
        if not line:
            self.close()
        with open(self.log, "rb") as log:
            log.seek(start_at)
            output = log.read().decode(errors="replace")
        return (json.loads(line) if line else None), output, elapsed

    def close(self) -> None:
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait()
            self.results.close()
            self.proc = None


@pytest.fixture(scope="module")
def worker(tmp_path_factory):
    w = _Worker(tmp_path_factory.mktemp("worker") / "log.txt")
    yield w
    w.close()


GARBAGE = st.sampled_from(["nan", "-nan", "inf", "-inf", "1e999", "-1e999", "", " ", "abc",
                           "0x10", "1,5", "1e9", "-1e9", "1e-9", "-0", "0", "-1", "3.5",
                           "1_000", "9" * 40, "-" + "9" * 40, "1" * 5000, "٣", "1:2:3", "5x",
                           "x5", "1x2x3", "auto"])


def _edges(o: Option) -> st.SearchStrategy[str]:
    """Values at and just beyond each bound."""
    values = []
    for bound, sign in ((o.low, -1), (o.high, 1)):
        if bound is None:
            continue
        if o.kind in ("int", "offset", "size", "people"):
            near = [int(bound), int(bound) + sign]
        else:
            near = [bound, math.nextafter(bound, sign * math.inf), bound * (1 + sign * 1e-9)]
        for v in near:
            values.append({"size": f"{v}x{v}", "people": f"{max(int(v), 1)}:{v}"}.get(o.kind,
                                                                                      repr(v)))
    return st.sampled_from(values)


def _values(o: Option) -> st.SearchStrategy[str]:
    """Random texts for ``o``: huge, tiny, negative, zero, NaN, infinite, not a number, at
    and just beyond the bounds; inside the range only ``o.cheap`` when given."""
    numbers = st.one_of(st.integers(-(2**70), 2**70).map(str),
                        st.floats(allow_nan=True, allow_infinity=True).map(repr))
    if o.kind == "size":
        side = st.integers(-10, 10**6)
        numbers = st.tuples(side, side).map("{0[0]}x{0[1]}".format)
    elif o.kind == "people":
        numbers = st.tuples(st.integers(-5, 200), st.integers(-5, 200)).map("{0[0]}:{0[1]}".format)
    drawn = st.one_of(GARBAGE, _edges(o), numbers)
    if o.cheap is None:
        return drawn
    return st.one_of(drawn.filter(lambda text: not o.inside(text)), o.cheap)


@pytest.mark.slow
@pytest.mark.parametrize("option", OPTIONS, ids=lambda o: f"{o.command} {o.flag}")
@settings(max_examples=10, deadline=None)
@given(data=st.data())
def test_random_values_exit_cleanly(option, data, inputs, worker):
    text = data.draw(_values(option), label="value")
    argv = [*_base(option.command, inputs), *option.extra, f"{option.flag}={text}"]
    code, output, elapsed = worker.run(argv)
    assert code is not None, f"{argv}: no exit code in {CALL_TIMEOUT_S} s, or died:\n{output}"
    assert "Traceback" not in output, f"{argv}:\n{output}"
    assert code in (0, 2), f"{argv}: exit code {code}:\n{output}"
    if not option.inside(text):
        # Outside the documented range: refused, promptly, by a message naming the option.
        assert code == 2, f"{argv}: a value outside the range was accepted:\n{output}"
        assert elapsed < PROMPT_S, f"{argv}: refused after {elapsed:.1f} s"
        name = option.flag.lstrip("-").replace("-", "_")
        assert name in output.replace("-", "_"), f"{argv}: the error does not name it:\n{output}"
