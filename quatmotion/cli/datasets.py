"""``quatmotion datasets list | fetch``: the motion-capture data folder."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from quatmotion.cli._app import app
from quatmotion.cli._common import CliInputError, at_least, console, user_errors

datasets_app = typer.Typer(
    help="The motion-capture data folder: list clips, fetch CMU subjects.", no_args_is_help=True
)
app.add_typer(datasets_app, name="datasets")


@datasets_app.command("list")
def datasets_list(
    collection: Annotated[str | None, typer.Option(help="cmu, cmu_bvh, hdm05 or bandai1.")] = None,
    match: Annotated[str | None, typer.Option(help="Text in a label or file name.")] = None,
    limit: Annotated[int, typer.Option(help="Show at most this many rows (0: all).")] = 0,
) -> None:
    """List the clips of the data folder ($QUATMOTION_DATA) with their labels."""
    from quatmotion.datasets import catalogue, data_root

    with user_errors():
        at_least("--limit", limit, 0)
        root = data_root()
        entries = catalogue(root, collection=collection, match=match)
        table = Table(title=f"{len(entries)} clips in {root}", title_justify="left")
        for column in ("collection", "clip", "format", "labels", "skeleton"):
            table.add_column(column, overflow="fold")
        shown = entries if limit <= 0 else entries[:limit]
        for e in shown:
            labels = ", ".join(f"{k}={v}" for k, v in e.labels.items())
            skel = e.skeleton_path.name if e.skeleton_path else "-"
            table.add_row(e.collection, e.name, e.format, labels, skel)
        console.print(table)
        if len(shown) < len(entries):
            console.print(f"... {len(entries) - len(shown)} more (use --limit 0)")


@datasets_app.command("fetch")
def datasets_fetch(
    collection: Annotated[str, typer.Argument(help="Only 'cmu' can be fetched.")],
    subjects: Annotated[str, typer.Option(help="Comma-separated subject numbers, e.g. 1,2.")],
    dest: Annotated[
        Path | None, typer.Option(help="Folder (default: cmu/ in the data folder).")
    ] = None,
    base_url: Annotated[
        str | None, typer.Option(help="Server with the CMU subjects/ layout.")
    ] = None,
    trials: Annotated[
        str | None, typer.Option(help="Comma-separated trials (default: all).")
    ] = None,
    overwrite: Annotated[
        bool, typer.Option("--overwrite", "--force", help="Download files that already exist.")
    ] = False,
) -> None:
    """Download CMU subjects' ASF and AMC files, each written atomically."""
    from quatmotion.datasets import DEFAULT_CMU_BASE_URL, fetch_cmu

    with user_errors():
        if collection != "cmu":
            raise CliInputError(f"only the 'cmu' collection can be fetched, not {collection!r}")
        try:
            subject_list = [int(s) for s in subjects.split(",") if s.strip()]
            trial_list = (
                None if trials is None else [int(t) for t in trials.split(",") if t.strip()]
            )
        except ValueError:
            raise CliInputError("--subjects and --trials take comma-separated numbers") from None
        files = fetch_cmu(
            subject_list,
            dest=dest,
            base_url=base_url or DEFAULT_CMU_BASE_URL,
            trials=trial_list,
            overwrite=overwrite,
            console=console,
        )
        console.print(f"{len(files)} file(s) in {dest or 'the data folder'}")
