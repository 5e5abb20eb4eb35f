"""What runs inside a worker: a task (a few items) through the job function, errors caught.

Kept apart and small because a worker imports it to unpickle every task.
"""

from __future__ import annotations

import os
import sys
import threading
import time
import traceback
from collections.abc import Callable, Sequence
from typing import Any

# One record per item: (index, succeeded, value or (message, detail), seconds of work, CPU
# seconds of the worker thread, start). The start is time.perf_counter() in the worker:
# CLOCK_MONOTONIC on Linux, shared by every process of the machine, so the caller can tell how
# long workers took to start.
Record = tuple[int, bool, Any, float, float, float]

# Environment read by BLAS and OpenMP when they load: one thread each, as Dask's nanny does for
# its workers, because the parallelism of a batch is its worker processes. Numba is limited by
# numba.set_num_threads(1) instead: its NUMBA_NUM_THREADS must not change once its threads are
# launched (Numba re-reads the environment when it compiles and raises if it differs), and the
# worker may have launched them before this runs.
SINGLE_THREAD_ENV = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
}

_process_limited = False
_thread_state = threading.local()


def one_line(exc: BaseException) -> str:
    """``"TypeName: first line of the message"`` (the message alone for a FormatError, which
    already names its file and line)."""
    text = str(exc).strip()
    first = text.splitlines()[0] if text else ""
    name = type(exc).__name__
    if name == "FormatError" and first:
        return first
    return f"{name}: {first}" if first else name


def start_worker(parent: int) -> None:
    """The initializer of a local pool's worker: one thread (:func:`limit_threads_in_worker`),
    and death with the run that started it (:func:`die_with`)."""
    die_with(parent)
    limit_threads_in_worker()


def die_with(parent: int) -> None:
    """End this process when process ``parent`` ends, however it ends (``kill -9`` too).

    A local pool's worker is a child of the fork server, not of the run, and would otherwise
    live on after the run is killed, holding its memory. On Linux the kernel kills it when its
    parent (the fork server) dies (``PR_SET_PDEATHSIG``), and a thread waits on the run itself
    (a pidfd; elsewhere it asks every second) and ends the process when the run is gone.
    """
    import signal

    if sys.platform.startswith("linux"):
        import ctypes

        with _ignored():
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG
    if parent == os.getpid():
        return

    def watch() -> None:
        import select

        try:
            fd = os.pidfd_open(parent)
        except (AttributeError, OSError):  # no pidfds: ask
            while _alive(parent):
                time.sleep(1.0)
        else:
            select.select([fd], [], [])  # readable when the process has ended
        os.kill(os.getpid(), signal.SIGKILL)

    if not _alive(parent):
        os.kill(os.getpid(), signal.SIGKILL)
    threading.Thread(target=watch, name="quatmotion-parent-watch", daemon=True).start()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _ignored():
    import contextlib

    return contextlib.suppress(OSError, AttributeError)


def limit_threads_in_worker() -> None:
    """Make this worker process (and the calling thread, for Numba) single-threaded.

    Process-wide settings are made once per process; Numba's thread count is per thread, so it
    is set for every thread that runs tasks (Dask runs them in a thread pool).
    """
    global _process_limited
    if not _process_limited:
        for key, value in SINGLE_THREAD_ENV.items():
            os.environ[key] = value
        if "numba" in sys.modules:
            # Numba read its thread count before this process was forked from the server, and
            # its OpenMP layer sets OpenMP's thread count to it when it first starts, undoing a
            # limit set before: start it now, so the limit below is the last word.
            from numba.np.ufunc.parallel import _launch_threads

            _launch_threads()
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=1)
        _process_limited = True
    if "numba" in sys.modules and not getattr(_thread_state, "numba_limited", False):
        import numba

        numba.set_num_threads(1)
        _thread_state.numba_limited = True


# Contexts already read by this worker process, by token (the newest few: a batch's context is
# read once per worker, and a kept pool serves the batches that follow).
_contexts: dict[str, Any] = {}
_CONTEXTS_KEPT = 2


class NoContext:
    """The context of a batch that has none: the job is called ``func(item)``."""

    def __repr__(self) -> str:
        return "NO_CONTEXT"

    def __reduce__(self) -> str:
        return "NO_CONTEXT"  # one instance in every process


NO_CONTEXT = NoContext()


def run_items(
    func: Callable[..., Any], entries: Sequence[tuple[int, Any]], context: Any = NO_CONTEXT
) -> list[Record]:
    """Apply ``func`` to every ``(index, item)`` (``func(item, context)`` when the batch has a
    context); an exception fails that item only."""
    records: list[Record] = []
    with_context = context is not NO_CONTEXT
    for index, item in entries:
        start, cpu_start = time.perf_counter(), time.thread_time()
        try:
            value = func(item, context) if with_context else func(item)
        except Exception as exc:  # any error of the job is this item's failure, no other's
            succeeded, value = False, (one_line(exc), "".join(traceback.format_exception(exc)))
        else:
            succeeded = True
        seconds, cpu = time.perf_counter() - start, time.thread_time() - cpu_start
        records.append((index, succeeded, value, seconds, cpu, start))
    return records


def run_task(
    func: Callable[..., Any], entries: Sequence[tuple[int, Any]], context: Any = NO_CONTEXT
) -> list[Record]:
    """The task a pool or a Dask worker runs: single-threaded, then :func:`run_items`."""
    limit_threads_in_worker()
    return run_items(func, entries, context)


def context_from_file(token: str, path: str) -> Any:
    """The context pickled at ``path`` under ``token``, read once per worker process.

    Raises
    ------
    RuntimeError
        The file cannot be read or unpickled here (one line).
    """
    import pickle

    if token not in _contexts:
        try:
            with open(path, "rb") as file:
                value = pickle.load(file)
        except Exception as exc:  # the task's own failure, told in one line
            raise RuntimeError(
                f"a worker process cannot read the batch's context ({one_line(exc)}): define "
                f"what it uses in an importable module"
            ) from None
        while len(_contexts) >= _CONTEXTS_KEPT:
            del _contexts[next(iter(_contexts))]
        _contexts[token] = value
    return _contexts[token]


def run_pickled_task(payload: bytes, context_ref: tuple[str, str] | None = None) -> list[Record]:
    """:func:`run_task` of a task the caller pickled, ``(func, entries)``; ``context_ref`` is
    ``(token, path)`` of the batch's pickled context, or None when it has none.

    Raises
    ------
    RuntimeError
        The task cannot be unpickled here, e.g. it refers to a class of the caller's main
        script, which this worker did not import (one line, naming what is missing).
    """
    import pickle

    try:
        func, entries = pickle.loads(payload)
    except Exception as exc:  # the task's own failure, told in one line
        raise RuntimeError(
            f"a worker process cannot read the task ({one_line(exc)}): define what the job "
            f"uses in an importable module"
        ) from None
    context = NO_CONTEXT if context_ref is None else context_from_file(*context_ref)
    return run_task(func, entries, context)
