"""The word every command says when it compiles kernels, and the kernels a batch compiles first.

Numba compiles quatmotion's kernels the first time they run, for minutes on a new install, and
caches them (:mod:`quatmotion._jit`). A command that compiles says so once on stderr
(:func:`say_when_compiling`, installed for every command by the root application); a command
that runs a batch on a process pool first compiles, in this process, the kernel groups it needs
(:func:`ensure_kernels`), so that its workers load them from the cache instead of each
compiling them at once. ``quatmotion warm-up`` (:mod:`quatmotion.cli.warmup`) compiles all of
them.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from quatmotion.cli._common import error_console

if TYPE_CHECKING:
    from rich.console import Console

    from quatmotion.warmup import GroupReport

__all__ = ["ensure_kernels", "run_groups", "said_already", "say_when_compiling"]

_said = False


def _compiling_message() -> str:
    from quatmotion import _jit

    return (
        f"compiling kernels, once: later runs load them from the cache "
        f"({_jit.cache_location()}); `quatmotion warm-up` compiles all of them ahead"
    )


def _say_compiling() -> None:
    global _said
    if not _said:
        _said = True
        error_console.print(_compiling_message(), markup=False, highlight=False, soft_wrap=True)


def said_already() -> None:
    """Say nothing more about compiling in this process (a command that says it itself)."""
    global _said
    _said = True


def say_when_compiling() -> None:
    """Say once, on stderr, when this process starts compiling a kernel."""
    from quatmotion import _jit

    _jit.on_first_compile(_say_compiling)


def run_groups(groups: list[str], target: Console, *, each: bool) -> list[GroupReport]:
    from quatmotion.warmup import GROUPS, warm_up

    width = max(len(text) for text in GROUPS.values())

    def report(done: GroupReport) -> None:
        if each:
            how = f"{done.compiled} compiled" if done.compiled else "all from the cache"
            target.print(
                f"  {GROUPS[done.group]:<{width}} {done.seconds:6.1f} s  ({how})",
                markup=False,
                highlight=False,
            )

    with target.status("compiling kernels", spinner="dots"):
        return warm_up(groups, report=report)


def ensure_kernels(*groups: str, workers: int | None = None, scheduler: str | None = None) -> None:
    """Before a batch on a local process pool: compile the kernels of ``groups``
    (:data:`quatmotion.warmup.GROUPS`) in this process if they may not be in the cache, saying
    so once on stderr, so that the workers load them instead of each compiling them at once.

    Nothing when they are cached, or when the batch runs in this process (``--workers 1``: it
    compiles what it uses, and says so) or on Dask (the cluster's workers have caches of their
    own).
    """
    from quatmotion.parallel import resolve_scheduler
    from quatmotion.warmup import stale_groups

    if resolve_scheduler(scheduler, workers=workers).kind != "processes":
        return
    stale = stale_groups(groups)
    if not stale:
        return
    start = time.perf_counter()
    _say_compiling()
    run_groups(stale, error_console, each=False)
    error_console.print(
        f"kernels compiled in {time.perf_counter() - start:.0f} s", markup=False, highlight=False
    )
