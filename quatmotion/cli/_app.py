"""The root Typer application every command module registers on."""

from __future__ import annotations

from typing import Annotated

import typer

app = typer.Typer(
    name="quatmotion",
    help="Compress and search human motion-capture libraries.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_show_locals=False,
)


def _print_version(value: bool) -> None:
    if value:
        from quatmotion import __version__

        typer.echo(f"quatmotion {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    ctx: typer.Context,
    version: Annotated[
        bool,
        typer.Option(
            "--version", callback=_print_version, is_eager=True, help="Print the version and exit."
        ),
    ] = False,
) -> None:
    """Compress and search human motion-capture libraries."""
    if ctx.invoked_subcommand not in _WITHOUT_KERNELS:
        from quatmotion.cli.warmup import say_when_compiling

        say_when_compiling()


# Commands that run no kernel, spared the import of Numba that listening for compiles costs.
_WITHOUT_KERNELS = ("datasets", "warm-up")
