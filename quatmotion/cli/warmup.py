"""``quatmotion warm-up``, and the word every command says when it compiles kernels.

Numba compiles quatmotion's kernels the first time they run, for minutes on a new install, and
caches them (:mod:`quatmotion._jit`). A command that compiles says so once on stderr
(:func:`say_when_compiling`, installed for every command); a command that runs a batch on a
process pool first compiles, in this process, the kernel groups it needs
(:func:`ensure_kernels`), so that its workers load them from the cache instead of each
compiling them at once. ``quatmotion warm-up`` compiles all of them (``make demo`` runs it).
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Annotated

import typer

from quatmotion.cli._app import app
from quatmotion.cli._common import console, error_console

if TYPE_CHECKING:
    from rich.console import Console

    from quatmotion.warmup import GroupReport

__all__ = ["ensure_kernels", "say_when_compiling"]

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


def say_when_compiling() -> None:
    """Say once, on stderr, when this process starts compiling a kernel."""
    from quatmotion import _jit

    _jit.on_first_compile(_say_compiling)


def _run(groups: list[str], target: Console, *, each: bool) -> list[GroupReport]:
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
    _run(stale, error_console, each=False)
    error_console.print(
        f"kernels compiled in {time.perf_counter() - start:.0f} s", markup=False, highlight=False
    )


@app.command("warm-up")
def warm_up_command(
    again: Annotated[
        bool, typer.Option("--again", help="Run every group, even those already compiled.")
    ] = False,
) -> None:
    """Compile every kernel once (minutes on a new install; later runs load them from the
    cache, in seconds)."""
    from quatmotion import _jit
    from quatmotion.warmup import GROUPS, stale_groups

    global _said
    _said = True  # this command says it itself
    groups = list(GROUPS) if again else stale_groups()
    where = _jit.cache_location()
    if not groups:
        console.print(
            f"kernels compiled already (cache: {where})", markup=False, highlight=False,
            soft_wrap=True,
        )  # fmt: skip
        return
    console.print(
        f"compiling kernels, once, into the cache ({where})",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
    start = time.perf_counter()
    reports = _run(groups, console, each=True)
    compiled = sum(r.compiled for r in reports)
    console.print(
        f"kernels ready in {time.perf_counter() - start:.1f} s "
        f"({compiled} compiled; later runs load them from the cache)",
        markup=False,
        highlight=False,
    )
