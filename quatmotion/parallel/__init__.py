"""Batch execution: a pure per-item function mapped over a list of items (clips), on this
machine's cores by default and on a Dask distributed cluster when one is named.

    runner = Runner.local(workers=2)   # or Runner.dask(address_or_client), Runner.resolve(name)
    for outcome in runner.map(encode_clip, paths, context=models):   # encode_clip(path, models)
        ...

Infrastructure: any layer may import it; it imports nothing of quatmotion but
:mod:`quatmotion.errors` (and Dask only when a Dask scheduler is asked for).

    result = run_batch(features_of_clip, paths, progress=bar_update)   # local process pool
    result = run_batch(features_of_clip, paths, scheduler="tcp://head:8786")   # Dask
    for outcome in imap_batch(features_of_clip, paths):    # streamed, input order, bounded
        ...

See :mod:`quatmotion.parallel.batch` for the contract (input order, one-line failures, retry of
an item whose worker died, progress) and :mod:`quatmotion.parallel.scheduler` for the names of
schedulers (``inline``, ``processes``, ``tcp://HOST:PORT``; ``QUATMOTION_SCHEDULER``).
"""

from quatmotion.parallel.batch import (
    BatchResult,
    BatchStats,
    BatchStream,
    Failure,
    Outcome,
    imap_batch,
    run_batch,
    shutdown_pools,
)
from quatmotion.parallel.runner import Runner
from quatmotion.parallel.scheduler import (
    SCHEDULER_ENV,
    Scheduler,
    SchedulerError,
    available_cpus,
    resolve_scheduler,
)

__all__ = [
    "SCHEDULER_ENV",
    "BatchResult",
    "BatchStats",
    "BatchStream",
    "Failure",
    "Outcome",
    "Runner",
    "Scheduler",
    "SchedulerError",
    "available_cpus",
    "imap_batch",
    "resolve_scheduler",
    "run_batch",
    "shutdown_pools",
]
