"""Ctrl-C with worker processes: the command stops at once, exit 130, and writes nothing.

A real ``python -m xvmatch`` runs on a synthetic box file long enough to keep two workers busy
for tens of seconds; SIGINT goes to its whole process group, as a terminal's Ctrl-C does. The
bounds are hang checks (the old pool waited for every queued task: 16-25 s), not timings.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from concurrent.futures import process as futures_process
from pathlib import Path

import pytest

from xvmatch.core.worker_pool import worker_pool
from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene
from xvmatch.formats.mot_boxes import write_mot_boxes

pytestmark = pytest.mark.skipif(not Path("/proc/self/task").is_dir(),
                                reason="finds the worker processes through /proc (Linux)")

HANG = 5.0  # seconds: far beyond the ~0.1 s an interrupt takes, far below the old wait


@pytest.fixture(scope="module")
def long_scene(tmp_path_factory) -> tuple[Path, Path]:
    """Top and horizontal box files of 200 frames, 8 people: the offset search takes ~30 s."""
    folder = tmp_path_factory.mktemp("long_scene")
    scene = simulate_box_scene(SceneConfig(n_people=(8, 8)), n_frames=200, seed=1)
    top, hor = folder / "top.txt", folder / "hor.txt"
    write_mot_boxes(top, scene.top)
    write_mot_boxes(hor, scene.hor)
    return top, hor


def _workers(pid: int) -> int:
    """How many of ``pid``'s children are spawned multiprocessing workers."""
    try:
        children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        return 0
    count = 0
    for child in children:
        try:
            count += b"spawn_main" in Path(f"/proc/{child}/cmdline").read_bytes()
        except OSError:
            pass
    return count


def _sigint_default() -> None:
    """In the child before it runs: Ctrl-C at its default, as in a terminal. A test run
    started in the background by a non-interactive shell (``make test &``) inherits SIGINT
    ignored, and Python then never turns it into KeyboardInterrupt."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _interrupt(args: list[str], cwd: Path, times: int = 1, group: bool = True,
               pause: float = 0.5) -> tuple[int, str]:
    """Run ``xvmatch ARGS``, Ctrl-C it (``times`` times) ``pause`` seconds after its two workers
    started (0.5: busy with their tasks; 0: still importing); returns the exit code and stderr,
    failing if it does not end within :data:`HANG` seconds. SIGINT goes to the process group
    (a terminal's Ctrl-C) or, unless ``group``, to xvmatch alone (``kill -INT``: the workers are
    then left to the parent to stop)."""
    proc = subprocess.Popen([sys.executable, "-m", "xvmatch", *args], cwd=cwd,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=_sigint_default)
    try:
        deadline = time.monotonic() + 60.0
        while _workers(proc.pid) < 2:
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "the workers never started"
            time.sleep(0.02)
        time.sleep(pause)
        assert proc.poll() is None, "finished before the interrupt: make the scene longer"
        for k in range(times):
            (os.killpg if group else os.kill)(proc.pid, signal.SIGINT)
            time.sleep(0.05 * (k < times - 1))
        try:
            _, err = proc.communicate(timeout=HANG)
        except subprocess.TimeoutExpired:
            pytest.fail(f"xvmatch {args[0]} still running {HANG} s after Ctrl-C")
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    return proc.returncode, err


@pytest.mark.parametrize("group", [True, False], ids=["ctrl-c", "kill-int"])
def test_offset_with_workers_stops_at_once_on_ctrl_c(long_scene, tmp_path, group):
    top, hor = long_scene
    code, err = _interrupt(["offset", "--top", str(top), "--hor", str(hor), "--workers", "2"],
                           tmp_path, group=group)
    assert code == 130, err
    # No worker traceback: the last line says so, and no other line is an error.
    assert err.strip().splitlines()[-1] == "xvmatch: interrupted"
    assert "Traceback" not in err and "error" not in err


@pytest.mark.slow
@pytest.mark.parametrize("extra", [["--offset", "auto"], ["--model", "default"]],
                         ids=["offset-auto", "learned"])
def test_associate_with_workers_stops_at_once_and_writes_nothing(long_scene, tmp_path, extra):
    top, hor = long_scene
    out = tmp_path / "pred.csv"
    code, err = _interrupt(["associate", "--top", str(top), "--hor", str(hor), "--workers", "2",
                            "--out", str(out), *extra], tmp_path)
    assert code == 130, err
    assert "Traceback" not in err
    assert list(tmp_path.iterdir()) == []  # neither the output nor a temporary file


@pytest.mark.parametrize("pause", [0.0, 0.05, 0.1])
def test_ctrl_c_while_the_workers_start_prints_no_traceback(long_scene, tmp_path, pause):
    # A worker imports for a second or more before it can ignore SIGINT: a Ctrl-C then printed
    # its KeyboardInterrupt traceback (CI, on a loaded machine), or, landing in the parent half-way
    # through starting one, left it reading a closed pipe (EOFError). A race: before the fix,
    # a few tries in a dozen at these pauses showed it.
    top, hor = long_scene
    code, err = _interrupt(["offset", "--top", str(top), "--hor", str(hor), "--workers", "2"],
                           tmp_path, pause=pause)
    assert code == 130, err
    assert err.strip().splitlines()[-1] == "xvmatch: interrupted"
    assert "Traceback" not in err


def test_a_second_ctrl_c_does_not_hang(long_scene, tmp_path):
    top, hor = long_scene
    code, err = _interrupt(["offset", "--top", str(top), "--hor", str(hor), "--workers", "2"],
                           tmp_path, times=2)
    # 130 from xvmatch, or -SIGINT when the second one lands after main() returned.
    assert code in (130, -signal.SIGINT), err
    assert "Traceback" not in err


def _running(pid: int) -> bool:
    """The process ``pid`` exists and is not a zombie (asked of the OS: ``Process.is_alive`` can
    stay True when the executor's own thread reaped the child first)."""
    stat = Path(f"/proc/{pid}/stat")
    if stat.parent.parent.is_dir() and Path("/proc/self").exists():
        try:
            return stat.read_text().rsplit(")", 1)[1].split()[0] != "Z"
        except OSError:
            return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_worker_pool_stops_its_workers_when_the_block_raises():
    start = time.monotonic()
    with pytest.raises(KeyboardInterrupt), worker_pool(2) as pool:
        for _ in range(4):
            pool.submit(time.sleep, 60)
        processes = list(pool._processes.values())
        manager = pool._executor_manager_thread
        raise KeyboardInterrupt
    assert time.monotonic() - start < HANG  # not waiting for the sleeping tasks
    assert len(processes) == 2 and not any(_running(p.pid) for p in processes)
    # Its manager thread has ended and is off the exit hook's list, which would otherwise
    # write to the wake-up pipe that thread closes (a traceback at exit, now and then).
    assert not manager.is_alive() and manager not in futures_process._threads_wakeups
