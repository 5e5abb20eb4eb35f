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
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from quatmotion.parallel import _pool, _worker
from quatmotion.parallel._pool import shutdown_pools
from quatmotion.parallel._protocol import Failure, Outcome, ProgressCallback, _Collector, _Task
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

DEFAULT_CONNECT_TIMEOUT = 10.0  # seconds to reach a Dask scheduler


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
        context: Any = _worker.NO_CONTEXT,
        client: Any = None,
    ) -> None:
        self._func = func
        self._context = context
        self._client = client
        self._items = items
        self._scheduler = scheduler
        self._retries = retries
        self._chunk_size = chunk_size
        self._window = window
        self._connect_timeout = connect_timeout
        self._collector = _Collector(items, progress)
        self._collector.workers = scheduler.n_workers or 0
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
            workers=c.workers,
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
        try:
            if not tasks:
                return
            if kind == "inline":
                yield from self._run_inline(tasks)
            elif kind == "processes":
                yield from _pool.run(
                    self._func,
                    tasks,
                    collector,
                    self._context,
                    workers=collector.workers,
                    retries=self._retries,
                    window=self._window,
                )
            else:
                yield from self._run_dask(tasks)
        finally:
            self._end = time.perf_counter()

    def _run_inline(self, tasks: deque[_Task]) -> Iterator[Outcome[Any]]:
        from threadpoolctl import threadpool_limits

        with threadpool_limits(limits=1), _numba_single_thread():
            for task in tasks:
                records = _worker.run_items(self._func, task.entries, self._context)
                self._collector.add_records(records)
                yield from self._collector.pop_ready()

    def _run_dask(self, tasks: deque[_Task]) -> Iterator[Outcome[Any]]:
        from quatmotion.parallel import _dask

        client = self._client
        if client is None:
            assert self._scheduler.address is not None
            client = _dask.connect(self._scheduler.address, self._connect_timeout)
        try:
            yield from _dask.run(
                self._func,
                tasks,
                self._collector,
                self._context,
                client=client,
                cap=self._scheduler.workers,
                window=self._window,
            )
        finally:
            if self._client is None:  # connected here: closed here; a caller's client stays
                client.close()


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
    return open_stream(
        func,
        items,
        resolve_scheduler(scheduler, workers=workers),
        retries=retries,
        chunk_size=chunk_size,
        window=window,
        progress=progress,
        connect_timeout=connect_timeout,
    )


def open_stream(
    func: Callable[..., T],
    items: Iterable[Any],
    scheduler: Scheduler,
    *,
    retries: int = 1,
    chunk_size: int = 1,
    window: int | None = None,
    progress: ProgressCallback | None = None,
    connect_timeout: float = DEFAULT_CONNECT_TIMEOUT,
    context: Any = _worker.NO_CONTEXT,
    client: Any = None,
) -> BatchStream[T]:
    """:func:`imap_batch` on a resolved scheduler, with a batch context (``func(item,
    context)``) and, for Dask, a caller's ``distributed.Client``; what
    :meth:`quatmotion.parallel.Runner.map` calls. Checks the arguments as :func:`imap_batch`
    documents."""
    if not callable(func):
        raise TypeError(f"func must be callable, got {type(func).__name__}")
    _check_picklable(func)
    items = list(items)
    _positive("retries", retries, minimum=0)
    _positive("chunk_size", chunk_size)
    if window is None:
        window = 4 * chunk_size * ((scheduler.n_workers or 2) + 1)
    _positive("window", window)
    window = max(window, chunk_size)
    if progress is not None and not callable(progress):
        raise TypeError(f"progress must be callable, got {type(progress).__name__}")
    return BatchStream(
        func,
        items,
        scheduler,
        retries=retries,
        chunk_size=chunk_size,
        window=window,
        progress=progress,
        connect_timeout=float(connect_timeout),
        context=context,
        client=client,
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
    return collect(stream, len(items))


def collect(stream: BatchStream[T], n_items: int) -> BatchResult[T]:
    """Every outcome of ``stream`` (a batch of ``n_items`` items) collected in input order:
    ``results[i]`` the value of item ``i`` (``None`` where it failed), the failures, the
    stats; the stream closed."""
    results: list[T | None] = [None] * n_items
    failures: list[Failure] = []
    with stream:
        for outcome in stream:
            if outcome.failure is None:
                results[outcome.index] = outcome.value
            else:
                failures.append(outcome.failure)
    return BatchResult(results, failures, stream.stats())
