"""Where the per-clip jobs of a build run (:class:`StepRunner`, over
:class:`quatmotion.parallel.Runner`) and how its steps report progress; :func:`runner_of`,
the runner of the command line's ``--workers`` and ``--scheduler``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from quatmotion.io import Doubt
from quatmotion.parallel import Runner, Scheduler

Progress = Callable[[str, int, int], None]
OnDoubt = Callable[[str, Doubt], None]


def runner_of(
    workers: int | None = None, scheduler: str | Scheduler | None = None
) -> Runner | None:
    """The :class:`~quatmotion.parallel.Runner` of the command line's ``--workers`` and
    ``--scheduler`` (None for neither: the default, :meth:`Runner.resolve`)."""
    if workers is None and scheduler is None:
        return None
    if isinstance(scheduler, Scheduler):
        return Runner(scheduler)
    return Runner.resolve(scheduler, workers=workers)


@dataclass(frozen=True)
class StepRunner:
    """Where per-clip jobs run (:mod:`quatmotion.parallel`) and how progress is reported."""

    runner: Runner | None
    report: Progress

    def each(
        self, step: str, func: Callable[..., Any], items: Sequence[Any], context: Any
    ) -> Iterator[Any]:
        """``func(item, context)`` of every item, streamed in input order.

        Raises
        ------
        ValueError
            Naming the first item whose job failed (nothing is written then).
        """
        runner = self.runner
        if runner is None:
            # one clip: a process pool would only add its start-up
            runner = Runner.inline() if len(items) < 2 else Runner.resolve(None)
        self.report(step, 0, len(items))
        progress = lambda done, total: self.report(step, done, total)  # noqa: E731
        with runner.map(func, items, context=context, progress=progress) as stream:
            for outcome in stream:
                if outcome.failure is not None:
                    raise ValueError(str(outcome.failure))
                yield outcome.value
