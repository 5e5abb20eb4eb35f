"""The root Typer application every command module registers on."""

from __future__ import annotations

import inspect
from typing import Annotated

import typer

app = typer.Typer(
    name="quatmotion",
    help="Compress and search human motion-capture libraries.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_show_locals=False,
)


def reflow_help(text: str) -> str:
    """A docstring as help text: each paragraph's lines joined into one, so that the help page
    folds sentences to the terminal's width instead of breaking them where the source did
    (Typer's Rich help keeps a docstring's line breaks after its first paragraph). A paragraph
    of list items (``-`` or ``*``) or indented lines keeps its lines."""
    paragraphs = inspect.cleandoc(text).split("\n\n")
    out = []
    for paragraph in paragraphs:
        lines = paragraph.splitlines()
        listed = any(line.lstrip()[:2] in ("- ", "* ") or line.startswith(" ") for line in lines)
        out.append(paragraph if listed else " ".join(line.strip() for line in lines))
    return "\n\n".join(out)


def reflow_all_help(application: typer.Typer) -> None:
    """:func:`reflow_help` on the help of every command and command group of ``application``
    (run once, after every command module has registered its commands)."""
    for info in application.registered_commands:
        text = info.help if info.help is not None else inspect.getdoc(info.callback)
        if text:
            info.help = reflow_help(text)
    for group in application.registered_groups:
        if group.typer_instance is not None:
            reflow_all_help(group.typer_instance)


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
        from quatmotion.cli._kernels import say_when_compiling

        say_when_compiling()


# Commands that run no kernel, spared the import of Numba that listening for compiles costs.
_WITHOUT_KERNELS = ("datasets", "warm-up")
