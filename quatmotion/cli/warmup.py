"""``quatmotion warm-up``: compile every kernel once (``make demo`` runs it).

What a command says when it compiles, and the kernels a batch compiles first, are
:mod:`quatmotion.cli._kernels`.
"""

from __future__ import annotations

import time
from typing import Annotated

import typer

from quatmotion.cli._app import app
from quatmotion.cli._common import console
from quatmotion.cli._kernels import run_groups, said_already


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

    said_already()  # this command says it itself
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
    reports = run_groups(groups, console, each=True)
    compiled = sum(r.compiled for r in reports)
    console.print(
        f"kernels ready in {time.perf_counter() - start:.1f} s "
        f"({compiled} compiled; later runs load them from the cache)",
        markup=False,
        highlight=False,
    )
