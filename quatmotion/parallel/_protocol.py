"""The execution protocol shared by every back end of :mod:`quatmotion.parallel`: what a back
end is handed (:class:`_Task`, consecutive items), what a worker sends back (records, see
:data:`quatmotion.parallel._worker.Record`), and what the caller gets (:class:`Outcome`, in input
order, through a :class:`_Collector`).

A back end (inline, :mod:`._pool`, :mod:`._dask`) is a generator
``run(func, tasks, collector, context, ...)`` that sends tasks to workers, feeds every record or
task failure to the collector, and yields :meth:`_Collector.pop_ready` as outcomes become ready.
This module imports no back end, and no back end imports another.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from quatmotion.parallel import _worker

__all__ = ["Failure", "Outcome", "ProgressCallback"]

T = TypeVar("T")
ProgressCallback = Callable[[int, int], None]


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
        self.workers = 0  # items that can run at once, as the back end found out

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
