"""The Dask distributed back end of :mod:`quatmotion.parallel.batch` (imported only when a
batch is sent to a Dask scheduler, so Dask stays an optional dependency)."""

from __future__ import annotations

import asyncio
import uuid
from collections import deque
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

from quatmotion.parallel import _worker
from quatmotion.parallel.scheduler import Scheduler, SchedulerError

if TYPE_CHECKING:
    from quatmotion.parallel.batch import Outcome, _Collector, _Task

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
    func: Callable[[Any], Any],
    tasks: deque[_Task],
    scheduler: Scheduler,
    window: int,
    collector: _Collector,
    connect_timeout: float,
    report_workers: Callable[[int], None],
) -> Iterator[Outcome[Any]]:
    """Submit ``tasks`` to the cluster, at most ``window`` items ahead of the oldest unyielded
    one, and yield outcomes in input order."""
    import distributed

    assert scheduler.address is not None
    client = connect(scheduler.address, connect_timeout)
    try:
        threads = sum(client.nthreads().values())
        capacity = scheduler.workers or 2 * max(1, threads)
        report_workers(scheduler.workers or threads)
        batch = uuid.uuid4().hex[:12]
        finished = distributed.as_completed(loop=client.loop)
        in_flight: dict[str, _Task] = {}

        def fill() -> None:
            horizon = collector.next_index + window
            while tasks and len(in_flight) < capacity and tasks[0].first < horizon:
                task = tasks.popleft()
                future = client.submit(
                    _worker.run_task,
                    func,
                    task.entries,
                    key=f"quatmotion-batch-{batch}-{task.number}",
                    pure=False,
                )
                in_flight[future.key] = task
                finished.add(future)

        fill()
        while in_flight:
            future = next(finished)
            task = in_flight.pop(future.key)
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
        client.close()
