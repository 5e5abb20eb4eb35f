"""Map a pure per-item function over a list of items, in input order, surviving bad items and
dead workers.

Conventions
-----------
* A *batch job* is a module-level (picklable) function ``func(item) -> result`` whose result
  depends on the item alone. It may run more than once for an item (a retry after its worker
  died), so its side effects, if any, must be harmless to repeat.
* Outcomes come back in **input order**, never in completion order: with a deterministic job
  the results are the same objects (the same bytes) whatever the scheduler and the number of
  workers.
* Every item runs with single-threaded BLAS, OpenMP and Numba (in the workers, and for
  ``inline`` in this process as far as those libraries are loaded): the parallelism of a batch
  is its workers, one per core, which is also what Dask's nanny sets up.
* An exception raised by ``func`` fails that item only: it is reported as a :class:`Failure`
  with a one-line message (``"TypeName: first line"``; a ``FormatError``'s own message, which
  names the file and line) and the traceback text, and every other item still runs.
* Local pool: a worker process that dies (killed, out of memory, a crash in C code) fails every
  task then in flight; each of them is charged one attempt and re-run *alone*, so that a second
  death is pinned on the item that causes it. An item is given up, with a message saying its
  worker died, after ``1 + retries`` deaths. With ``retries=0`` every item in flight when a
  worker dies is given up.
* Dask: the Dask scheduler reschedules a task whose worker died on its own, as often as the
  cluster's ``distributed.scheduler.allowed-failures`` allows (3 by default), then reports
  ``KilledWorker``, which fails the task's items; ``retries`` does not add to it.
* ``progress(done, total)`` is called in the calling process: once with ``done == 0`` before
  any work, then each time an item finishes (succeeded or failed), ``done`` counting up to
  ``total``.
* Local pool workers fork from a fork server (safe beside threads; modules imported once) and
  do not re-run the caller's main script unless the batch's first task refers to something
  defined there: a script that calls a batch at its top level, without an
  ``if __name__ == "__main__":`` guard, works (see :mod:`quatmotion.parallel._context`).
* Local pools are kept for the next batch of the same size (warm workers); a worker that
  died takes its pool down and the next batch starts a new one; :func:`shutdown_pools` ends
  them sooner than the process's exit.
* Memory: a stream hands out items at most ``window`` ahead of the oldest one not yet yielded,
  so no more than about ``window`` results wait in memory however long the list is.
"""

from __future__ import annotations

import contextlib
import pickle
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from quatmotion.parallel import _context, _worker
from quatmotion.parallel.scheduler import Scheduler, resolve_scheduler

__all__ = [
    "BatchResult",
    "BatchStats",
    "BatchStream",
    "Failure",
    "Outcome",
    "imap_batch",
    "run_batch",
    "shutdown_pools",
]

T = TypeVar("T")
ProgressCallback = Callable[[int, int], None]

DEFAULT_CONNECT_TIMEOUT = 10.0  # seconds to reach a Dask scheduler


@dataclass(frozen=True)
class Failure:
    """An item that did not complete.

    Attributes
    ----------
    index : int
        Its position in the input list.
    item : object
        The item itself (a path, for clip jobs).
    message : str
        One line: what went wrong.
    detail : str
        The traceback text where there is one (an exception of the job), else ``""``.
    """

    index: int
    item: Any
    message: str
    detail: str = ""

    def __str__(self) -> str:
        # A FormatError's message already starts with the file's name.
        if self.message.startswith(str(self.item)):
            return self.message
        return f"{self.item}: {self.message}"


@dataclass(frozen=True)
class Outcome(Generic[T]):
    """One item's outcome: its value, or its failure.

    Attributes
    ----------
    index : int
    item : object
    value : object or None
        ``func(item)``; ``None`` when the item failed.
    failure : Failure or None
    seconds : float
        Time ``func`` ran for this item, in its worker (0 when it never ran to an end there).
    cpu_seconds : float
        CPU time of the worker thread meanwhile (below ``seconds`` when it waited for a core).
    """

    index: int
    item: Any
    value: T | None
    failure: Failure | None
    seconds: float = 0.0
    cpu_seconds: float = 0.0

    @property
    def ok(self) -> bool:
        """Whether the item succeeded."""
        return self.failure is None


@dataclass(frozen=True)
class BatchStats:
    """Counts and times of a batch.

    Attributes
    ----------
    n_items : int
    n_done : int
        Items finished, succeeded or failed (``n_items`` once the batch is over).
    n_failed : int
    retried : int or None
        Item runs repeated after a worker died; ``None`` on Dask, whose scheduler reschedules
        without telling the client.
    scheduler : str
        :meth:`Scheduler.describe` of where it ran.
    workers : int
        Items that could run at once (pool processes; Dask: the cluster's threads or the cap).
    wall_seconds : float
        From the start of the batch to its last outcome.
    work_seconds : float
        Sum over items of the time ``func`` ran in its worker.
    startup_seconds : float or None
        From the start of the batch until the first item started in a worker: starting the
        pool, or connecting to Dask and shipping the first task. Read from the workers' clock,
        so meaningful only when they run on this machine; ``None`` if no item ran.
    """

    n_items: int
    n_done: int
    n_failed: int
    retried: int | None
    scheduler: str
    workers: int
    wall_seconds: float
    work_seconds: float
    startup_seconds: float | None = None

    def summary(self, noun: str = "items") -> str:
        """One line, e.g. ``"12 items in 3.1 s on local pool of 2 processes: 11 done, 1 failed"``.

        ``noun`` names the items (``"clips"``).
        """
        text = (
            f"{self.n_items} {noun} in {self.wall_seconds:.1f} s on {self.scheduler}: "
            f"{self.n_done - self.n_failed} done, {self.n_failed} failed"
        )
        if self.retried:
            text += f", {self.retried} re-run after a worker died"
        return text


@dataclass(frozen=True)
class BatchResult(Generic[T]):
    """A finished batch.

    Attributes
    ----------
    results : list
        ``func(item)`` for every item, in input order; ``None`` where the item failed.
    failures : list of Failure
        In input order.
    stats : BatchStats
    """

    results: list[T | None]
    failures: list[Failure]
    stats: BatchStats

    @property
    def ok(self) -> bool:
        """Whether every item succeeded."""
        return not self.failures


@dataclass(frozen=True)
class _Task:
    """Consecutive items sent to a worker together."""

    number: int
    entries: tuple[tuple[int, Any], ...]

    @property
    def first(self) -> int:
        return self.entries[0][0]


class _Collector:
    """Outcomes arriving in any order, handed out in input order; counts and progress."""

    def __init__(self, items: Sequence[Any], progress: ProgressCallback | None) -> None:
        self.items = items
        self.progress = progress
        self.ready: dict[int, Outcome[Any]] = {}
        self.next_index = 0
        self.done = 0
        self.failed = 0
        self.retried = 0
        self.work_seconds = 0.0
        self.first_start: float | None = None

    def _add(self, outcome: Outcome[Any]) -> None:
        if outcome.index in self.ready or outcome.index < self.next_index:
            raise RuntimeError(f"item {outcome.index} finished twice")  # a bug of this module
        self.ready[outcome.index] = outcome
        self.done += 1
        self.failed += not outcome.ok
        self.work_seconds += outcome.seconds
        if self.progress is not None:
            self.progress(self.done, len(self.items))

    def add_records(self, records: Iterable[_worker.Record]) -> None:
        for index, succeeded, value, seconds, cpu, start in records:
            if self.first_start is None or start < self.first_start:
                self.first_start = start
            item = self.items[index]
            if succeeded:
                self._add(Outcome(index, item, value, None, seconds, cpu))
            else:
                failure = Failure(index, item, *value)  # value is (message, detail)
                self._add(Outcome(index, item, None, failure, seconds, cpu))

    def fail(self, task: _Task, message: str) -> None:
        for index, item in task.entries:
            self._add(Outcome(index, item, None, Failure(index, item, message)))

    def pop_ready(self) -> Iterator[Outcome[Any]]:
        while self.next_index in self.ready:
            yield self.ready.pop(self.next_index)
            self.next_index += 1


def _check_picklable(func: Callable[[Any], Any]) -> None:
    try:
        pickle.dumps(func)
    except (pickle.PicklingError, AttributeError, TypeError) as exc:
        raise TypeError(
            f"the job function {func!r} cannot be pickled, so a worker process cannot run it: "
            f"define it at module level ({_worker.one_line(exc)})"
        ) from None


def _positive(name: str, value: Any, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return value


def _module_of(func: Callable[[Any], Any]) -> str | None:
    inner = getattr(func, "func", func)  # functools.partial
    return getattr(inner, "__module__", None)


class BatchStream(Generic[T]):
    """An iterator of :class:`Outcome`, in input order, over a running batch.

    Made by :func:`imap_batch`. Close it (or use it as a context manager) to stop early:
    queued work is cancelled. :meth:`stats` gives the counts at any time.
    """

    def __init__(
        self,
        func: Callable[[Any], T],
        items: Sequence[Any],
        scheduler: Scheduler,
        *,
        retries: int,
        chunk_size: int,
        window: int,
        progress: ProgressCallback | None,
        connect_timeout: float,
    ) -> None:
        self._func = func
        self._items = items
        self._scheduler = scheduler
        self._retries = retries
        self._chunk_size = chunk_size
        self._window = window
        self._connect_timeout = connect_timeout
        self._collector = _Collector(items, progress)
        self._workers = scheduler.n_workers or 0
        self._start: float | None = None
        self._end: float | None = None
        self._generator = self._generate()

    def __iter__(self) -> BatchStream[T]:
        return self

    def __next__(self) -> Outcome[T]:
        return next(self._generator)

    def close(self) -> None:
        """Stop the batch: cancel what has not started (the local pool is kept for reuse)."""
        self._generator.close()

    def __enter__(self) -> BatchStream[T]:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def stats(self) -> BatchStats:
        """Counts and times so far (final once the stream is exhausted)."""
        c = self._collector
        wall = 0.0 if self._start is None else (self._end or time.perf_counter()) - self._start
        return BatchStats(
            n_items=len(self._items),
            n_done=c.done,
            n_failed=c.failed,
            retried=None if self._scheduler.kind == "dask" else c.retried,
            scheduler=self._scheduler.describe(),
            workers=self._workers,
            wall_seconds=wall,
            work_seconds=c.work_seconds,
            startup_seconds=(
                None
                if c.first_start is None or self._start is None
                else max(0.0, c.first_start - self._start)
            ),
        )

    def _tasks(self) -> deque[_Task]:
        entries = list(enumerate(self._items))
        size = self._chunk_size
        return deque(
            _Task(k, tuple(entries[s : s + size]))
            for k, s in enumerate(range(0, len(entries), size))
        )

    def _generate(self) -> Iterator[Outcome[T]]:
        self._start = time.perf_counter()
        collector = self._collector
        if collector.progress is not None:
            collector.progress(0, len(self._items))
        tasks = self._tasks()
        kind = self._scheduler.kind
        if not tasks:
            runner: Iterator[Outcome[Any]] = iter(())
        elif kind == "inline":
            runner = self._run_inline(tasks)
        elif kind == "processes":
            runner = self._run_pool(tasks)
        else:
            from quatmotion.parallel import _dask

            runner = _dask.run(
                self._func,
                tasks,
                self._scheduler,
                self._window,
                collector,
                self._connect_timeout,
                self._set_workers,
            )
        try:
            yield from runner
        finally:
            self._end = time.perf_counter()
            close = getattr(runner, "close", None)
            if close is not None:
                close()

    def _set_workers(self, n: int) -> None:
        self._workers = n

    def _run_inline(self, tasks: deque[_Task]) -> Iterator[Outcome[Any]]:
        from threadpoolctl import threadpool_limits

        with threadpool_limits(limits=1), _numba_single_thread():
            for task in tasks:
                self._collector.add_records(_worker.run_items(self._func, task.entries))
                yield from self._collector.pop_ready()

    def _run_pool(self, tasks: deque[_Task]) -> Iterator[Outcome[Any]]:
        collector = self._collector
        n = self._workers
        # The executor itself queues one call beyond its workers; more in flight would only
        # widen the set of tasks a dead worker takes down with it.
        capacity = n + 1
        suspects: deque[_Task] = deque()
        deaths: dict[int, int] = {}
        in_flight: dict[Future[list[_worker.Record]], _Task] = {}
        pool: ProcessPoolExecutor | None = None

        def submit(task: _Task, payload: bytes) -> None:
            assert pool is not None
            in_flight[pool.submit(_worker.run_pickled_task, payload)] = task

        def settle(future: Future[list[_worker.Record]], task: _Task, crashed: list[_Task]) -> None:
            try:
                records = future.result()
            except BrokenProcessPool:
                crashed.append(task)
                return
            except Exception as exc:  # the task never ran: the worker could not read it
                collector.fail(task, _worker.one_line(exc))
            else:
                collector.add_records(records)
            payloads.pop(task.number, None)

        # Each task is pickled here, once (the pool sends the bytes): whether they name the main
        # script tells which workers the batch needs (see _context), and a task that cannot be
        # pickled fails alone, at once. Kept until the task is settled, for a re-run.
        payloads: dict[int, bytes] = {}

        def payload_of(task: _Task) -> bytes | None:
            if task.number not in payloads:
                try:
                    payloads[task.number] = pickle.dumps(
                        (self._func, task.entries), protocol=pickle.HIGHEST_PROTOCOL
                    )
                except Exception as exc:  # an item that cannot be sent fails alone
                    message = f"cannot be sent to a worker process: {_worker.one_line(exc)}"
                    collector.fail(task, message)
                    return None
            return payloads[task.number]

        def drop_unsendable() -> None:
            """Fail and drop the tasks at the head of ``tasks`` that cannot be pickled."""
            while tasks and payload_of(tasks[0]) is None:
                tasks.popleft()

        import_main: bool | None = None  # the first task sent decides, for the whole batch
        try:
            while tasks or suspects or in_flight:
                if pool is None:
                    if import_main is None:
                        drop_unsendable()
                        if not tasks:
                            yield from collector.pop_ready()
                            continue
                        import_main = _names_main(payloads[tasks[0].number])
                    pool = _shared_pool(n, _module_of(self._func), import_main=import_main)
                try:
                    if suspects:
                        if not in_flight:
                            submit(suspects[0], payloads[suspects[0].number])
                            suspects.popleft()
                    else:
                        horizon = collector.next_index + self._window
                        drop_unsendable()
                        while tasks and len(in_flight) < capacity and tasks[0].first < horizon:
                            submit(tasks[0], payloads[tasks[0].number])
                            tasks.popleft()
                            drop_unsendable()
                except BrokenProcessPool:
                    # A worker died since the last look: while the kept pool was idle (start
                    # afresh), or under a task in flight (found below, like any death).
                    if not in_flight:
                        _discard_pool(n, pool, wait=True)
                        pool = None
                        continue
                done, _ = wait(in_flight, return_when=FIRST_COMPLETED)
                crashed: list[_Task] = []
                for future in done:
                    settle(future, in_flight.pop(future), crashed)
                if crashed:
                    # The pool is broken: every task still in flight fails the same way.
                    for future, task in list(in_flight.items()):
                        settle(future, task, crashed)
                    in_flight.clear()
                    _discard_pool(n, pool, wait=True)
                    pool = None
                    for task in sorted(crashed, key=lambda t: t.number):
                        deaths[task.number] = deaths.get(task.number, 0) + 1
                        if deaths[task.number] > self._retries:
                            times = deaths[task.number]
                            message = (
                                f"its worker process died running it "
                                f"({times} time{'s' if times > 1 else ''}; gave up)"
                            )
                            if import_main and collector.done == collector.failed:
                                message += _MAIN_HINT
                            collector.fail(task, message)
                            payloads.pop(task.number, None)
                        else:
                            collector.retried += len(task.entries)
                            suspects.append(task)
                yield from collector.pop_ready()
        finally:
            # Stopped early: what has not started is cancelled; the few tasks already running
            # (at most workers + 1) finish unread, and the warm pool stays for the next batch.
            for future in in_flight:
                future.cancel()


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
            pool = ProcessPoolExecutor(
                max_workers=n, mp_context=context, initializer=_worker.limit_threads_in_worker
            )
            _pools[n, import_main] = pool
        return pool


def _discard_pool(n: int, pool: ProcessPoolExecutor, *, wait: bool) -> None:
    with _pools_lock:
        for key, kept in list(_pools.items()):
            if key[0] == n and kept is pool:
                del _pools[key]
    pool.shutdown(wait=wait, cancel_futures=True)


def shutdown_pools() -> None:
    """End the worker processes of every local pool (the next batch starts new ones)."""
    with _pools_lock:
        pools = list(_pools.items())
        _pools.clear()
    for _, pool in pools:
        pool.shutdown(wait=True, cancel_futures=True)


@contextlib.contextmanager
def _numba_single_thread() -> Iterator[None]:
    """Numba's thread count set to 1 for the calling thread while inside, if Numba is loaded."""
    numba = sys.modules.get("numba")
    if numba is None:
        yield
        return
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(before)


def imap_batch(
    func: Callable[[Any], T],
    items: Iterable[Any],
    *,
    workers: int | None = None,
    scheduler: str | Scheduler | None = None,
    retries: int = 1,
    chunk_size: int = 1,
    window: int | None = None,
    progress: ProgressCallback | None = None,
    connect_timeout: float = DEFAULT_CONNECT_TIMEOUT,
) -> BatchStream[T]:
    """Run ``func`` over ``items`` and stream the outcomes in input order.

    Parameters
    ----------
    func : callable
        ``func(item) -> result``, module-level (picklable); see the module's conventions.
    items : iterable
        Read into a list at once (items are small: paths, seeds).
    workers : int, optional
        Local pool processes (default: the CPUs available); on Dask the most tasks in flight
        (default: two per cluster thread). ``1`` without a scheduler runs inline.
    scheduler : str or Scheduler, optional
        ``"inline"``, ``"processes"`` or a Dask address; see
        :func:`quatmotion.parallel.resolve_scheduler` (``QUATMOTION_SCHEDULER`` when None).
    retries : int
        Re-runs of an item whose local worker process died (Dask: the cluster's policy).
    chunk_size : int
        Consecutive items per task: raise it when items are so small that sending them one by
        one costs a noticeable share of the work.
    window : int, optional
        Most items handed out beyond the oldest one not yet yielded (bounds the results held
        while waiting for a slow item); default ``4 * chunk_size * (workers + 1)``.
    progress : callable, optional
        ``progress(done, total)``, see the module's conventions.
    connect_timeout : float
        Seconds to wait for a Dask scheduler to answer.

    Returns
    -------
    BatchStream
        Iterator of :class:`Outcome`, one per item, ``index`` 0, 1, 2...

    Raises
    ------
    TypeError
        ``func`` is not callable or cannot be pickled.
    ValueError
        ``retries``, ``chunk_size`` or ``window`` out of range.
    SchedulerError
        The scheduler is malformed (here), or, when iteration starts, a Dask scheduler cannot
        be reached or ``dask.distributed`` is not installed.
    """
    if not callable(func):
        raise TypeError(f"func must be callable, got {type(func).__name__}")
    _check_picklable(func)
    sched = resolve_scheduler(scheduler, workers=workers)
    items = list(items)
    _positive("retries", retries, minimum=0)
    _positive("chunk_size", chunk_size)
    if window is None:
        window = 4 * chunk_size * ((sched.n_workers or 2) + 1)
    _positive("window", window)
    window = max(window, chunk_size)
    if progress is not None and not callable(progress):
        raise TypeError(f"progress must be callable, got {type(progress).__name__}")
    return BatchStream(
        func,
        items,
        sched,
        retries=retries,
        chunk_size=chunk_size,
        window=window,
        progress=progress,
        connect_timeout=float(connect_timeout),
    )


def run_batch(
    func: Callable[[Any], T],
    items: Iterable[Any],
    *,
    workers: int | None = None,
    scheduler: str | Scheduler | None = None,
    retries: int = 1,
    chunk_size: int = 1,
    progress: ProgressCallback | None = None,
    connect_timeout: float = DEFAULT_CONNECT_TIMEOUT,
) -> BatchResult[T]:
    """Run ``func`` over every item and collect the results in input order.

    Parameters are those of :func:`imap_batch` (without ``window``: every result is kept, so
    items are handed out as fast as the workers take them).

    Returns
    -------
    BatchResult
        ``results[i]`` is ``func(items[i])``, or ``None`` if item ``i`` failed; ``failures`` lists
        the failed items with one-line messages; ``stats`` counts and times.
    """
    items = list(items)
    stream = imap_batch(
        func,
        items,
        workers=workers,
        scheduler=scheduler,
        retries=retries,
        chunk_size=chunk_size,
        window=max(1, len(items)),
        progress=progress,
        connect_timeout=connect_timeout,
    )
    results: list[T | None] = [None] * len(items)
    failures: list[Failure] = []
    with stream:
        for outcome in stream:
            if outcome.failure is None:
                results[outcome.index] = outcome.value
            else:
                failures.append(outcome.failure)
    return BatchResult(results, failures, stream.stats())
