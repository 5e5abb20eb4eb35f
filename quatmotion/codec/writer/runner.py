"""Where the per-clip jobs of a build run (:class:`StepRunner`, over
:class:`quatmotion.parallel.Runner`) and how its steps report progress (the runner of the
command line's ``--workers`` and ``--scheduler`` is :meth:`quatmotion.parallel.Runner.of`).
"""

from __future__ import annotations

import warnings
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
    """:meth:`quatmotion.parallel.Runner.of`, its name before 0.5.0 (warns, removed in 0.6.0)."""
    warnings.warn(
        "codec.writer.runner_of is the name before quatmotion 0.5.0 (removed in 0.6.0): use "
        "parallel.Runner.of (docs/migration-0.4.md)",
        DeprecationWarning,
        stacklevel=2,
    )
    return Runner.of(workers, scheduler)


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
