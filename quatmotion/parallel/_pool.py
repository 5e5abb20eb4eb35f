"""The local process pool back end of :mod:`quatmotion.parallel`: kept pools of fork-server
workers, tasks pickled once, a dead worker's tasks re-run alone.

The batch's context, if any, is pickled once into a temporary file named by a token; every task
carries only ``(token, path)``, and each worker process reads the file the first time it sees
the token and keeps the object (see :func:`quatmotion.parallel._worker.context_from_file`).
"""

from __future__ import annotations

import contextlib
import os
import pickle
import tempfile
import threading
import uuid
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from quatmotion.parallel import _context, _worker, scratch
from quatmotion.parallel._protocol import Outcome, _Collector, _Task

__all__ = ["run", "shutdown_pools"]

# Local pools outlive their batches, one per size and kind: a batch after the first (the second
# pass of a pose-library build, a benchmark's repetitions) finds its workers started and warm
# (modules imported, compiled kernels loaded). They end with the process, or with
# shutdown_pools().
_pools: dict[tuple[int, bool], ProcessPoolExecutor] = {}
_pools_lock = threading.Lock()

_MAIN_HINT = (
    "; its workers import the main script first, to find what the job uses from it: keep the "
    'script\'s work under `if __name__ == "__main__":`'
)


def _names_main(payload: bytes) -> bool:
    """Whether a pickled task may refer to something of the main script.

    A pickle names the module of every function and class it refers to, so a task that needs
    the main script contains ``__main__``; a byte string that merely contains those bytes
    costs a worker that imports the script, as ``multiprocessing`` always does.
    """
    return b"__main__" in payload


def _module_of(func: Callable[..., Any]) -> str | None:
    inner = getattr(func, "func", func)  # functools.partial
    return getattr(inner, "__module__", None)


def _shared_pool(n: int, module: str | None, *, import_main: bool) -> ProcessPoolExecutor:
    with _pools_lock:
        pool = _pools.get((n, import_main))
        if pool is None:
            context = _context.context(import_main=import_main)
            # Workers fork from a server process started once, with these modules imported
            # (never __main__ itself: the fork server would run an unguarded script's work).
            preload = ["quatmotion.parallel._worker"]
            if module and module != "__main__":
                preload.append(module)
            context.set_forkserver_preload(preload)
            scratch.use_for_multiprocessing()
            pool = ProcessPoolExecutor(
                max_workers=n,
                mp_context=context,
                initializer=_worker.start_worker,
                initargs=(os.getpid(),),
            )
            _pools[n, import_main] = pool
        return pool


def _discard_pool(n: int, pool: ProcessPoolExecutor) -> None:
    with _pools_lock:
        for key, kept in list(_pools.items()):
            if key[0] == n and kept is pool:
                del _pools[key]
    pool.shutdown(wait=True, cancel_futures=True)


def shutdown_pools() -> None:
    """End the worker processes of every local pool (the next batch starts new ones)."""
    with _pools_lock:
        pools = list(_pools.items())
        _pools.clear()
    for _, pool in pools:
        pool.shutdown(wait=True, cancel_futures=True)


class _ContextFile:
    """A batch's context pickled once into a temporary file, removed when the batch ends."""

    def __init__(self, context: Any) -> None:
        self.ref: tuple[str, str] | None = None
        self.names_main = False
        if context is _worker.NO_CONTEXT:
            return
        data = pickle.dumps(context, protocol=pickle.HIGHEST_PROTOCOL)
        self.names_main = _names_main(data)
        fd, path = tempfile.mkstemp(prefix=scratch.prefix("context"), suffix=".pickle")
        with os.fdopen(fd, "wb") as file:
            file.write(data)
        self.ref = (uuid.uuid4().hex, path)

    def remove(self) -> None:
        if self.ref is not None:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.ref[1])


class _PoolRun:
    """One batch on a kept local pool: tasks pickled once (whether they name the main script
    tells which workers the batch needs, see :mod:`._context`; a task that cannot be pickled
    fails alone, at once), at most ``window`` items ahead, a dead worker's tasks re-run alone
    until ``retries`` deaths."""

    def __init__(
        self,
        func: Callable[..., Any],
        tasks: deque[_Task],
        collector: _Collector,
        context: _ContextFile,
        *,
        workers: int,
        retries: int,
        window: int,
    ) -> None:
        self.func = func
        self.tasks = tasks
        self.collector = collector
        self.context = context
        self.n = workers
        self.retries = retries
        self.window = window
        # The executor itself queues one call beyond its workers; more in flight would only
        # widen the set of tasks a dead worker takes down with it.
        self.capacity = workers + 1
        self.suspects: deque[_Task] = deque()  # tasks in flight when a worker died: run alone
        self.deaths: dict[int, int] = {}
        self.in_flight: dict[Future[list[_worker.Record]], _Task] = {}
        self.payloads: dict[int, bytes] = {}  # kept until the task is settled, for a re-run
        self.pool: ProcessPoolExecutor | None = None
        self.import_main: bool | None = None  # the first task sent decides, for the whole batch

    # -- steps -------------------------------------------------------------------------------

    def payload_of(self, task: _Task) -> bytes | None:
        if task.number not in self.payloads:
            try:
                self.payloads[task.number] = pickle.dumps(
                    (self.func, task.entries), protocol=pickle.HIGHEST_PROTOCOL
                )
            except Exception as exc:  # an item that cannot be sent fails alone
                message = f"cannot be sent to a worker process: {_worker.one_line(exc)}"
                self.collector.fail(task, message)
                return None
        return self.payloads[task.number]

    def drop_unsendable(self) -> None:
        """Fail and drop the tasks at the head of the queue that cannot be pickled."""
        while self.tasks and self.payload_of(self.tasks[0]) is None:
            self.tasks.popleft()

    def start_pool(self) -> bool:
        """Get a pool for the batch; False when no task is left to send."""
        if self.import_main is None:
            self.drop_unsendable()
            if not self.tasks:
                return False
            payload = self.payloads[self.tasks[0].number]
            self.import_main = _names_main(payload) or self.context.names_main
        self.pool = _shared_pool(self.n, _module_of(self.func), import_main=self.import_main)
        return True

    def submit(self, task: _Task) -> None:
        assert self.pool is not None
        future = self.pool.submit(
            _worker.run_pickled_task, self.payloads[task.number], self.context.ref
        )
        self.in_flight[future] = task

    def fill(self) -> None:
        """Send suspects alone, else tasks up to the capacity and the window."""
        if self.suspects:
            if not self.in_flight:
                self.submit(self.suspects.popleft())
            return
        horizon = self.collector.next_index + self.window
        self.drop_unsendable()
        while self.tasks and len(self.in_flight) < self.capacity and self.tasks[0].first < horizon:
            self.submit(self.tasks.popleft())
            self.drop_unsendable()

    def settle(
        self, future: Future[list[_worker.Record]], task: _Task, crashed: list[_Task]
    ) -> None:
        try:
            records = future.result()
        except BrokenProcessPool:
            crashed.append(task)
            return
        except Exception as exc:  # the task never ran: the worker could not read it
            self.collector.fail(task, _worker.one_line(exc))
        else:
            self.collector.add_records(records)
        self.payloads.pop(task.number, None)

    def charge_deaths(self, crashed: list[_Task]) -> None:
        """The pool is broken: every task in flight failed with it; charge each one death and
        queue it to run alone, or give it up."""
        for future, task in list(self.in_flight.items()):
            self.settle(future, task, crashed)
        self.in_flight.clear()
        assert self.pool is not None
        _discard_pool(self.n, self.pool)
        self.pool = None
        collector = self.collector
        for task in sorted(crashed, key=lambda t: t.number):
            self.deaths[task.number] = self.deaths.get(task.number, 0) + 1
            times = self.deaths[task.number]
            if times > self.retries:
                message = (
                    f"its worker process died running it ({times} time{'s' if times > 1 else ''}; "
                    f"gave up)"
                )
                if self.import_main and collector.done == collector.failed:
                    message += _MAIN_HINT
                collector.fail(task, message)
                self.payloads.pop(task.number, None)
            else:
                collector.retried += len(task.entries)
                self.suspects.append(task)

    # -- the loop ----------------------------------------------------------------------------

    def __iter__(self) -> Iterator[Outcome[Any]]:
        try:
            while self.tasks or self.suspects or self.in_flight:
                if self.pool is None and not self.start_pool():
                    yield from self.collector.pop_ready()
                    continue
                try:
                    self.fill()
                except BrokenProcessPool:
                    # A worker died since the last look: while the kept pool was idle (start
                    # afresh), or under a task in flight (found below, like any death).
                    if not self.in_flight:
                        assert self.pool is not None
                        _discard_pool(self.n, self.pool)
                        self.pool = None
                        continue
                done, _ = wait(self.in_flight, return_when=FIRST_COMPLETED)
                crashed: list[_Task] = []
                for future in done:
                    self.settle(future, self.in_flight.pop(future), crashed)
                if crashed:
                    self.charge_deaths(crashed)
                yield from self.collector.pop_ready()
        finally:
            # Stopped early: what has not started is cancelled; the few tasks already running
            # (at most workers + 1) finish unread, and the warm pool stays for the next batch.
            for future in self.in_flight:
                future.cancel()


def run(
    func: Callable[..., Any],
    tasks: deque[_Task],
    collector: _Collector,
    context: Any,
    *,
    workers: int,
    retries: int,
    window: int,
) -> Iterator[Outcome[Any]]:
    """Run ``tasks`` on a kept pool of ``workers`` processes and yield outcomes in input order."""
    try:
        context_file = _ContextFile(context)
    except Exception as exc:  # a context that cannot be sent fails every item, in one line
        for task in tasks:
            collector.fail(task, f"the batch's context cannot be sent: {_worker.one_line(exc)}")
        yield from collector.pop_ready()
        return
    try:
        yield from _PoolRun(
            func, tasks, collector, context_file, workers=workers, retries=retries, window=window
        )
    finally:
        context_file.remove()
