"""``quatmotion bench NAME``: run one benchmark of :mod:`quatmotion.bench`."""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from quatmotion.cli._app import app
from quatmotion.cli._common import (
    CliInputError,
    ForceOption,
    at_least,
    check_outputs,
    console,
    say_wrote,
    user_errors,
)


@app.command()
def bench(
    name: Annotated[str, typer.Argument(help="Benchmark: a module of quatmotion.bench.")],
    out: Annotated[Path, typer.Option(help="JSON file to write (figures go beside it).")],
    quick: Annotated[bool, typer.Option(help="A small, fast version.")] = False,
    seed: Annotated[int, typer.Option(help="Random seed (0 or more).")] = 0,
    force: ForceOption = False,
) -> None:
    """Run one benchmark of quatmotion.bench: its JSON result in --out, figures beside it."""
    from quatmotion import bench as bench_package  # (its provenance reads package metadata)

    with user_errors():
        available = bench_package.names()
        if name not in available:
            raise CliInputError(f"unknown benchmark {name!r}; available: {', '.join(available)}")
        if out.suffix.lower() != ".json":
            raise CliInputError(f"{out}: --out names the JSON file to write (*.json)")
        check_outputs([out], force=force)
        at_least("--seed", seed, 0)
        module = importlib.import_module(f"quatmotion.bench.{name}")
        if not callable(getattr(module, "run", None)):
            raise CliInputError(f"quatmotion.bench.{name} has no run() function")
        out.parent.mkdir(parents=True, exist_ok=True)
    # Outside the bad-input guard: an exception inside a benchmark is a bug, shown in full.
    result = module.run(out, quick=quick, seed=seed)
    say_wrote(out, f"benchmark {name}")
    if isinstance(result, dict):
        table = Table(show_header=False)
        for key, value in result.items():
            if isinstance(value, int | float | str | bool):
                table.add_row(str(key), f"{value:.4g}" if isinstance(value, float) else str(value))
        if table.row_count:
            console.print(table)
