"""Where a batch runs, as one value: :class:`Runner`.

    runner = Runner.local(workers=2)                  # or Runner.dask("tcp://head:8786")
    for outcome in runner.map(encode_clip, paths, context=models):
        ...                                           # encode_clip(path, models), input order

The ``context`` is one shared read-only object of the batch (models, layouts): it is sent to
each worker once per batch, not with every item (local pool: pickled once, read once per worker
process; Dask: ``client.scatter(context, broadcast=True)``). The conventions of
:mod:`quatmotion.parallel.batch` hold (input order, one-line failures, retries, progress).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, TypeVar

from quatmotion.parallel import _worker
from quatmotion.parallel.batch import (
    DEFAULT_CONNECT_TIMEOUT,
    BatchResult,
    BatchStream,
    ProgressCallback,
    collect,
    open_stream,
)
from quatmotion.parallel.scheduler import Scheduler, SchedulerError, resolve_scheduler

__all__ = ["Runner"]

T = TypeVar("T")


@dataclass(frozen=True)
class Runner:
    """Where and how a batch runs: a scheduler and the batch options, validated once.

    Attributes
    ----------
    scheduler : Scheduler
        Inline, a local pool, or a Dask address (see :func:`resolve_scheduler`).
    retries : int
        Re-runs of an item whose local worker process died (Dask: the cluster's policy).
    chunk_size : int
        Consecutive items per task.
    window : int or None
        Most items handed out beyond the oldest not yet yielded (default
        ``4 * chunk_size * (workers + 1)``).
    connect_timeout : float
        Seconds to wait for a Dask scheduler.
    client : distributed.Client or None
        A Dask client of the caller's, used instead of connecting to ``scheduler.address``
        (and left open).
    """

    scheduler: Scheduler = field(default_factory=lambda: resolve_scheduler(None))
    retries: int = 1
    chunk_size: int = 1
    window: int | None = None
    connect_timeout: float = DEFAULT_CONNECT_TIMEOUT
    client: Any = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        if not isinstance(self.scheduler, Scheduler):
            raise TypeError(f"scheduler must be a Scheduler, got {type(self.scheduler).__name__}")
        if self.client is not None and self.scheduler.kind != "dask":
            raise SchedulerError("a Dask client needs a Dask scheduler")

    @classmethod
    def local(cls, workers: int | None = None, **options: Any) -> Runner:
        """A local process pool of ``workers`` processes (default: the CPUs available)."""
        return cls(Scheduler("processes", workers=workers), **options)

    @classmethod
    def inline(cls, **options: Any) -> Runner:
        """Every item in this process, one at a time."""
        return cls(Scheduler("inline"), **options)

    @classmethod
    def dask(cls, target: Any, *, workers: int | None = None, **options: Any) -> Runner:
        """A Dask cluster: ``target`` is a scheduler address (``tcp://HOST:PORT``) or a
        ``distributed.Client`` (used, not closed). ``workers`` caps the tasks in flight."""
        if isinstance(target, str):
            scheduler = resolve_scheduler(target, workers=workers)
            if scheduler.kind != "dask":
                raise SchedulerError(f"{target!r} is not a Dask scheduler address")
            return cls(scheduler, **options)
        address = getattr(target, "scheduler", None) and target.scheduler.address
        if not address:
            raise SchedulerError(f"not a Dask address or a connected Client: {target!r}")
        return cls(resolve_scheduler(address, workers=workers), client=target, **options)

    @classmethod
    def resolve(
        cls, scheduler: str | Scheduler | None = None, *, workers: int | None = None, **options: Any
    ) -> Runner:
        """The runner of a scheduler name as :func:`resolve_scheduler` reads it (``None``: the
        ``QUATMOTION_SCHEDULER`` environment variable, else a local pool; ``workers=1``
        inline)."""
        return cls(resolve_scheduler(scheduler, workers=workers), **options)

    @classmethod
    def of(
        cls, workers: int | None = None, scheduler: str | Scheduler | None = None
    ) -> Runner | None:
        """The runner of the command line's ``--workers`` and ``--scheduler``: None when
        neither is given (the caller's default, as a rule :meth:`resolve`'s), a
        :class:`Scheduler` used as it is, else :meth:`resolve` of the name."""
        if workers is None and scheduler is None:
            return None
        if isinstance(scheduler, Scheduler):
            return cls(scheduler)
        return cls.resolve(scheduler, workers=workers)

    def describe(self) -> str:
        """Where batches run, in words (:meth:`Scheduler.describe`)."""
        return self.scheduler.describe()

    def map(
        self,
        func: Callable[..., T],
        items: Iterable[Any],
        *,
        context: Any = None,
        progress: ProgressCallback | None = None,
    ) -> BatchStream[T]:
        """Stream ``func(item)`` (``func(item, context)`` when ``context`` is not None) over
        ``items`` as :class:`Outcome` values in input order.

        Raises
        ------
        TypeError
            ``func`` is not callable or cannot be pickled.
        SchedulerError
            When iteration starts: a Dask scheduler cannot be reached.
        """
        return open_stream(
            func,
            items,
            self.scheduler,
            retries=self.retries,
            chunk_size=self.chunk_size,
            window=self.window,
            progress=progress,
            connect_timeout=self.connect_timeout,
            context=_worker.NO_CONTEXT if context is None else context,
            client=self.client,
        )

    def run(
        self,
        func: Callable[..., T],
        items: Iterable[Any],
        *,
        context: Any = None,
        progress: ProgressCallback | None = None,
    ) -> BatchResult[T]:
        """:meth:`map` collected: every result in input order (``None`` where the item
        failed), the failures, the stats. Items are handed out as fast as workers take them."""
        items = list(items)
        runner = self if self.window is not None else _with_window(self, max(1, len(items)))
        return collect(runner.map(func, items, context=context, progress=progress), len(items))


def _with_window(runner: Runner, window: int) -> Runner:
    from dataclasses import replace

    return replace(runner, window=window)
