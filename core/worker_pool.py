"""Process pools that stop at once on Ctrl-C: the one way the package starts worker processes.

``with ProcessPoolExecutor(...)`` waits on exit for every task already queued, so a Ctrl-C
during a long search took tens of seconds, and a second Ctrl-C inside that wait could deadlock
the interpreter's exit. :func:`worker_pool` gives the same executor, but its workers ignore
SIGINT (the terminal sends it to the whole process group; only the parent should act on it)
and, when the ``with`` block is left by any exception (``KeyboardInterrupt`` included), the
pending tasks are cancelled and the workers terminated before the exception goes on.
"""

from __future__ import annotations

import multiprocessing
import signal
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures import process as futures_process
from contextlib import contextmanager

__all__ = ["stop_pool", "worker_pool"]


_CAN_BLOCK = hasattr(signal, "pthread_sigmask")


@contextmanager
def _sigint_held() -> Iterator[None]:
    """Ctrl-C held back for the block and delivered when it ends. A process started inside
    inherits SIGINT blocked (fork and exec keep the thread's mask); and the parent is not
    interrupted half-way through starting one (a signal caught by another of its threads
    still raises in the main thread) and left with a worker it never recorded."""
    caught: list[int] = []
    main = threading.current_thread() is threading.main_thread()
    previous = signal.getsignal(signal.SIGINT) if main else None
    main = previous is not None  # None: a handler not set from Python, left alone
    if main:
        signal.signal(signal.SIGINT, lambda number, frame: caught.append(number))
    if _CAN_BLOCK:
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        if main:
            signal.signal(signal.SIGINT, previous)
            if caught:
                signal.raise_signal(signal.SIGINT)  # to the handler now restored
        if _CAN_BLOCK:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


class _Pool(ProcessPoolExecutor):
    """A ``ProcessPoolExecutor`` whose workers are started with SIGINT blocked. A worker
    otherwise takes a second or more (importing numpy, the task's modules) before its
    initializer can ignore SIGINT, and a Ctrl-C in that window printed its traceback."""

    def submit(self, fn, /, *args, **kwargs):
        # The executor starts its workers inside submit(), in the calling thread.
        with _sigint_held():
            return super().submit(fn, *args, **kwargs)


def _start_worker(initializer: Callable[[], object] | None) -> None:
    """Worker initializer: leave Ctrl-C to the parent, which stops the workers itself, then run
    the caller's own ``initializer`` (e.g. one thread per worker). Ignoring SIGINT before
    unblocking it drops a Ctrl-C that came while the worker was starting."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if _CAN_BLOCK:
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    if initializer is not None:
        initializer()


def stop_pool(pool: ProcessPoolExecutor) -> None:
    """Cancel ``pool``'s pending tasks and terminate its workers now, without waiting for the
    tasks they are running (their results are dropped)."""
    # The executor has no public handle on its processes nor on its manager thread; these
    # are the only ones, and shutdown() below sets both to None: read them first.
    processes = list((getattr(pool, "_processes", None) or {}).values())
    manager = getattr(pool, "_executor_manager_thread", None)
    # Terminate first: a second Ctrl-C arriving during what follows then finds no worker left
    # that the interpreter's exit would wait for.
    for process in processes:
        if process.is_alive():
            process.terminate()
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        process.join(timeout=1.0)
        if process.is_alive():
            process.kill()
            process.join(timeout=1.0)
    # Let the executor's manager thread see its dead workers and close its wake-up pipe: left
    # running, it can close that pipe while the interpreter's exit hook writes to it (Python
    # 3.11's ProcessPoolExecutor checks, then writes, without a lock), which printed an
    # "Exception ignored ... Bad file descriptor" traceback after a Ctrl-C.
    if manager is not None and manager.is_alive():
        manager.join(timeout=2.0)
    # The join is bounded, and a loaded machine can outlast it (the traceback came back in a
    # fresh-clone `make test`), so also take the thread off the exit hook's list: the hook then
    # never writes to that pipe, and the thread still ends by itself, its workers being dead.
    if manager is not None:
        getattr(futures_process, "_threads_wakeups", {}).pop(manager, None)


@contextmanager
def worker_pool(workers: int, start_method: str | None = "spawn",
                initializer: Callable[[], object] | None = None,
                ) -> Iterator[ProcessPoolExecutor]:
    """A ``ProcessPoolExecutor`` of ``workers`` processes that ignore SIGINT, stopped at once
    (:func:`stop_pool`) when the block raises, and shut down normally when it completes.

    Args:
        workers: number of worker processes (>= 1).
        start_method: ``"spawn"`` (default: a forked child may inherit the parent's thread
            pools, e.g. onnxruntime's or OpenCV's, and hang), ``"fork"``, or None for the
            platform's default.
        initializer: run in each worker after it starts (a module-level function).
    """
    if int(workers) < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    context = multiprocessing.get_context(start_method)
    pool = _Pool(max_workers=int(workers), mp_context=context,
                 initializer=_start_worker, initargs=(initializer,))
    try:
        yield pool
        # Inside the try: a Ctrl-C during this wait must stop the pool too, or its manager
        # thread stays on the exit hook's list (the traceback stop_pool describes).
        pool.shutdown(wait=True)
    except BaseException:
        stop_pool(pool)
        raise
