"""The Dask distributed back end of :mod:`quatmotion.parallel` (imported only when a batch is
sent to a Dask scheduler, so Dask stays an optional dependency).

The batch's context, if any, is sent to every worker once with
``client.scatter(context, broadcast=True)``; tasks carry the future, which Dask resolves to the
worker's copy.
"""

from __future__ import annotations

import asyncio
import uuid
from collections import deque
from collections.abc import Callable, Iterator
from typing import Any

from quatmotion.parallel import _worker
from quatmotion.parallel._protocol import Outcome, _Collector, _Task
from quatmotion.parallel.scheduler import SchedulerError

__all__ = ["connect", "run"]

_INSTALL_HINT = "pip install 'quatmotion[scale]' (or 'dask[distributed]')"


def connect(address: str, timeout: float) -> Any:
    """A ``distributed.Client`` connected to ``address``.

    Raises
    ------
    SchedulerError
        ``dask.distributed`` is missing, or nothing answers at ``address`` within ``timeout``.
    """
    try:
        import distributed
    except ImportError:
        raise SchedulerError(
            f"scheduler {address} is a Dask cluster, but dask.distributed is not installed: "
            f"{_INSTALL_HINT}"
        ) from None
    try:
        return distributed.Client(address, timeout=timeout, set_as_default=False)
    except (OSError, TimeoutError) as exc:
        raise SchedulerError(
            f"cannot reach the Dask scheduler at {address} within {timeout:g} s "
            f"({_worker.one_line(exc)})"
        ) from None


def run(
    func: Callable[..., Any],
    tasks: deque[_Task],
    collector: _Collector,
    context: Any,
    *,
    client: Any,
    cap: int | None,
    window: int,
) -> Iterator[Outcome[Any]]:
    """Submit ``tasks`` through ``client``, at most ``cap`` in flight (default two per cluster
    thread) and ``window`` items ahead of the oldest unyielded one; yield outcomes in input
    order. The caller owns the client."""
    import distributed

    threads = sum(client.nthreads().values())
    capacity = cap or 2 * max(1, threads)
    collector.workers = cap or threads
    batch = uuid.uuid4().hex[:12]
    if context is not _worker.NO_CONTEXT:
        # hash=False: a fresh key per batch, so a context equal to an older one's is not
        # mistaken for data the cluster may already have dropped.
        context = client.scatter(context, broadcast=True, hash=False)
    finished = distributed.as_completed(loop=client.loop)
    in_flight: dict[str, _Task] = {}
    futures: dict[str, Any] = {}

    def fill() -> None:
        horizon = collector.next_index + window
        while tasks and len(in_flight) < capacity and tasks[0].first < horizon:
            task = tasks.popleft()
            future = client.submit(
                _worker.run_task,
                func,
                task.entries,
                context,
                key=f"quatmotion-batch-{batch}-{task.number}",
                pure=False,
            )
            in_flight[future.key] = task
            futures[future.key] = future
            finished.add(future)

    try:
        fill()
        while in_flight:
            future = next(finished)
            task = in_flight.pop(future.key)
            futures.pop(future.key, None)
            try:
                records = future.result()
            except distributed.KilledWorker as exc:
                collector.fail(
                    task,
                    f"its Dask worker died running it; the scheduler gave up "
                    f"({_worker.one_line(exc)})",
                )
            except (Exception, asyncio.CancelledError) as exc:
                # The task never ran to an end: the job could not be unpickled on the worker,
                # the client lost the scheduler...
                collector.fail(task, _worker.one_line(exc))
            else:
                collector.add_records(records)
            future.release()
            fill()
            yield from collector.pop_ready()
    finally:
        if futures:  # stopped early: what has not finished is cancelled
            client.cancel(list(futures.values()))
        if hasattr(context, "release"):
            context.release()
