"""``quatmotion demo``: the main job on a built-in generated library (``make demo``)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from quatmotion.cli._app import app
from quatmotion.cli._common import (
    CliInputError,
    ForceOption,
    SkeletonOption,
    UnitsOption,
    at_least,
    check_outputs,
    check_units,
    console,
    require_file,
    user_errors,
)


@app.command()
def demo(
    paths: Annotated[
        list[Path] | None,
        typer.Argument(help="Clips or folders to use instead of the built-in generated library."),
    ] = None,
    out: Annotated[Path, typer.Option(help="Folder for the figure and summary.")] = Path(
        "demo-out"
    ),
    seed: Annotated[int, typer.Option(help="Seed of the generated library and the learners.")] = 0,
    quick: Annotated[bool, typer.Option(help="Fewer clips and iterations.")] = False,
    units: UnitsOption = None,
    skeleton: SkeletonOption = None,
    force: ForceOption = False,
) -> None:
    """Generate (or load) clips, show them, and compress them with QSSD vs K-SVD."""
    from quatmotion.demo import run_demo

    with user_errors():
        if out.exists() and not out.is_dir():
            raise CliInputError(f"{out}: --out names a folder, this is a file")
        at_least("--seed", seed, 0)
        check_units(units)
        if skeleton is not None:
            require_file(skeleton)
        check_outputs([out / "summary.json"], [*(paths or []), skeleton], force=force)
        run_demo(
            paths or [], out_dir=out, seed=seed, quick=quick, console=console, units=units,
            skeleton=skeleton,
        )  # fmt: skip
