"""The root Typer application every command module registers on."""

from __future__ import annotations

import typer

app = typer.Typer(
    name="quatmotion",
    help="Compress and search human motion-capture libraries.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_show_locals=False,
)
