"""Where a batch runs: in this process, in a local process pool, or on a Dask cluster.

Conventions
-----------
* A scheduler is named by a string: ``"inline"`` (this process, one item at a time),
  ``"processes"`` (a local process pool, one worker per available CPU by default), or the
  address of a Dask distributed scheduler, ``tcp://HOST:PORT`` or ``tls://HOST:PORT``
  (``HOST:PORT`` alone means ``tcp://``).
* No name (``None``) means: the environment variable ``QUATMOTION_SCHEDULER`` if it is set and
  not empty, else ``"inline"`` when one worker is asked for, else ``"processes"``.
* Names are checked here, before any work starts; a bad one raises :class:`SchedulerError`
  (a ``ValueError``) whose one-line message quotes it and says what was expected. Whether a
  Dask scheduler answers at that address is checked when a batch connects to it.
"""

from __future__ import annotations

import os
import urllib.parse
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

__all__ = [
    "SCHEDULER_ENV",
    "Scheduler",
    "SchedulerError",
    "available_cpus",
    "resolve_scheduler",
]

SCHEDULER_ENV = "QUATMOTION_SCHEDULER"
_DASK_PROTOCOLS = ("tcp", "tls")

SchedulerKind = Literal["inline", "processes", "dask"]


class SchedulerError(ValueError):
    """A scheduler name or address is invalid, or the scheduler cannot be reached or used."""


def available_cpus() -> int:
    """CPUs this process may run on (its affinity mask where the OS has one), at least 1."""
    count = getattr(os, "process_cpu_count", None)  # Python 3.13+
    if count is not None:
        return max(1, count() or 1)
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # macOS, Windows: no affinity mask
        return max(1, os.cpu_count() or 1)


@dataclass(frozen=True)
class Scheduler:
    """A validated choice of where a batch runs.

    Parameters
    ----------
    kind : {"inline", "processes", "dask"}
    address : str or None
        The Dask scheduler's address (``"tcp://HOST:PORT"``), for ``kind == "dask"`` only.
    workers : int or None
        Worker processes of a local pool; for Dask, the most tasks in flight at once (``None``:
        as many as the cluster has threads); always 1 for ``"inline"``.
    """

    kind: SchedulerKind
    address: str | None = None
    workers: int | None = None

    def __post_init__(self) -> None:
        if self.kind not in ("inline", "processes", "dask"):
            raise SchedulerError(f"unknown scheduler kind {self.kind!r}")
        if (self.kind == "dask") != (self.address is not None):
            raise SchedulerError("a Dask scheduler needs an address, and only it has one")
        if self.workers is not None and (
            isinstance(self.workers, bool) or not isinstance(self.workers, int) or self.workers < 1
        ):
            raise SchedulerError(f"workers must be a positive integer, got {self.workers!r}")
        if self.kind == "inline" and self.workers not in (None, 1):
            raise SchedulerError(
                f"the inline scheduler runs one item at a time; got workers={self.workers}"
            )

    @property
    def n_workers(self) -> int | None:
        """Workers that will run items (``None`` for Dask without a cap: the cluster decides)."""
        if self.kind == "inline":
            return 1
        if self.kind == "processes":
            return self.workers or available_cpus()
        return self.workers

    def describe(self) -> str:
        """One line for a log or a report, e.g. ``"local pool of 2 processes"``."""
        if self.kind == "inline":
            return "inline (this process, one item at a time)"
        if self.kind == "processes":
            n = self.n_workers
            return f"local pool of {n} process{'es' if n != 1 else ''}"
        cap = f", at most {self.workers} tasks at once" if self.workers else ""
        return f"Dask cluster at {self.address}{cap}"


def _parse(text: str, workers: int | None, source: str) -> Scheduler:
    name = text.strip()
    lowered = name.lower()
    if lowered in ("inline", "processes"):
        return Scheduler(lowered, workers=workers)  # type: ignore[arg-type]
    expected = "expected 'processes', 'inline' or a Dask scheduler address such as tcp://HOST:8786"
    if not name:
        raise SchedulerError(f"{source} is empty: {expected}")
    with_scheme = name if "://" in name else f"tcp://{name}"
    try:
        parts = urllib.parse.urlsplit(with_scheme)
        port = parts.port
    except ValueError as exc:
        raise SchedulerError(
            f"{source} {name!r} is not a scheduler address ({exc}); {expected}"
        ) from None
    if parts.scheme not in _DASK_PROTOCOLS:
        raise SchedulerError(
            f"{source} {name!r}: unsupported protocol {parts.scheme!r} "
            f"(use {' or '.join(p + '://' for p in _DASK_PROTOCOLS)}); {expected}"
        )
    if not parts.hostname or port is None or parts.path not in ("", "/") or parts.query:
        raise SchedulerError(f"{source} {name!r} is not HOST:PORT; {expected}")
    if port == 0:
        raise SchedulerError(f"{source} {name!r}: port 0 is not a scheduler's port; {expected}")
    host = f"[{parts.hostname}]" if ":" in parts.hostname else parts.hostname
    return Scheduler("dask", address=f"{parts.scheme}://{host}:{port}", workers=workers)


def resolve_scheduler(
    scheduler: str | Scheduler | None = None,
    *,
    workers: int | None = None,
    environ: Mapping[str, str] | None = None,
) -> Scheduler:
    """The scheduler a batch runs on, from an option, the environment or the defaults.

    Parameters
    ----------
    scheduler : str, Scheduler or None
        ``"inline"``, ``"processes"``, a Dask address (``tcp://HOST:PORT``), an already
        resolved :class:`Scheduler` (returned as is when ``workers`` is None), or ``None``.
    workers : int, optional
        Worker processes of a local pool, or the cap on tasks in flight on Dask.
    environ : mapping, optional
        Where ``QUATMOTION_SCHEDULER`` is looked up when ``scheduler`` is None (default
        ``os.environ``).

    Returns
    -------
    Scheduler

    Raises
    ------
    SchedulerError
        The name or address is malformed, or ``workers`` is not a positive integer (the message
        quotes the offending value and, for the environment variable, names it).
    """
    if isinstance(scheduler, Scheduler):
        if workers is None:
            return scheduler
        return Scheduler(scheduler.kind, address=scheduler.address, workers=workers)
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)):
        raise SchedulerError(f"workers must be a positive integer, got {workers!r}")
    if workers is not None and workers < 1:
        raise SchedulerError(f"workers must be a positive integer, got {workers}")
    if scheduler is not None:
        return _parse(str(scheduler), workers, "scheduler")
    env = os.environ if environ is None else environ
    from_env = env.get(SCHEDULER_ENV, "").strip()
    if from_env:
        return _parse(from_env, workers, SCHEDULER_ENV)
    if workers == 1:
        return Scheduler("inline")
    return Scheduler("processes", workers=workers)
