"""``quatmotion index build|add|remove|ls`` and ``quatmotion search``: a searchable clip library.

``index build`` and ``index add`` read every ``.amc``/``.bvh`` under the given folders (AMC
skeletons by the CMU/HDM05 layouts, or from ``--skeletons DIR``), compute the features of every
retrieval method on all cores and store them in a SQLite ``.qidx`` file; both resume (clips
already indexed with the same content hash are skipped) and report bad files without stopping.
``search`` ranks the indexed clips for a query file or an indexed clip's name.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from quatmotion.cli._app import app
from quatmotion.cli._common import (
    CliInputError,
    SchedulerOption,
    WorkersOption,
    console,
    error_console,
    progress_bar,
    read_clip,
    report_skipped,
    require_file,
    user_errors,
)

index_app = typer.Typer(
    help="Build and maintain a clip index (.qidx) for `quatmotion search`.", no_args_is_help=True
)
app.add_typer(index_app, name="index")

_KINDS_HELP = "Feature kinds to compute: motion, qssd, ksvd (comma-separated)."


def _kinds(text: str) -> tuple[str, ...]:
    from quatmotion.retrieval.methods import FEATURE_KINDS

    kinds = tuple(k.strip() for k in text.split(",") if k.strip())
    unknown = [k for k in kinds if k not in FEATURE_KINDS]
    if unknown or not kinds:
        raise CliInputError(
            f"unknown feature kinds {unknown}; choose from {', '.join(FEATURE_KINDS)}"
        )
    return kinds


def _build(
    paths: list[Path],
    output: Path,
    labels: Path | None,
    skeletons: Path | None,
    kinds: str,
    workers: int | None,
    scheduler: str | None,
) -> None:
    from quatmotion.parallel import resolve_scheduler
    from quatmotion.retrieval.build import build_index, read_labels_csv

    with user_errors():
        label_map = read_labels_csv(require_file(labels)) if labels else None
        if skeletons is not None and not skeletons.is_dir():
            raise CliInputError(f"{skeletons}: --skeletons must be a folder of ASF files")
        kind_tuple = _kinds(kinds)
        from quatmotion.cli.warmup import ensure_kernels

        learn = ("learn",) if {"qssd", "ksvd"} & set(kind_tuple) else ()
        ensure_kernels("read", *learn, "retrieval", workers=workers, scheduler=scheduler)
        with progress_bar(error_console) as bar:
            task = bar.add_task("indexing", total=None)

            def advance(done: int, total: int) -> None:
                bar.update(task, completed=done, total=total)

            report = build_index(
                paths,
                output,
                kinds=kind_tuple,
                labels=label_map,
                skeletons=skeletons,
                workers=workers,
                scheduler=resolve_scheduler(scheduler, workers=workers),
                progress=advance,
            )
    report_skipped(f"{path}: {reason}" for path, reason in report.failed)
    console.print(
        f"{output}: {report.added} clips added, {report.skipped} already indexed, "
        f"{len(report.failed)} failed",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
    if report.failed:
        raise typer.Exit(code=1)


@index_app.command("build")
def build_command(
    paths: Annotated[list[Path], typer.Argument(help="Folders (searched recursively) or clips.")],
    output: Annotated[Path, typer.Option("-o", "--output", help="Index file to write (.qidx).")],
    labels: Annotated[Path | None, typer.Option(help="CSV with columns clip,label.")] = None,
    skeletons: Annotated[
        Path | None, typer.Option(help="Folder of the AMC clips' ASF files.")
    ] = None,
    kinds: Annotated[str, typer.Option(help=_KINDS_HELP)] = "motion,qssd,ksvd",
    workers: WorkersOption = None,
    scheduler: SchedulerOption = None,
) -> None:
    """Index clips (a new file, or resume one: clips already indexed are skipped).

    A file that cannot be read is reported and skipped; the command then exits with code 1
    after committing the others.
    """
    _build(paths, output, labels, skeletons, kinds, workers, scheduler)


@index_app.command("add")
def add_command(
    index: Annotated[Path, typer.Argument(help="Index file (.qidx).")],
    paths: Annotated[list[Path], typer.Argument(help="Folders (searched recursively) or clips.")],
    labels: Annotated[Path | None, typer.Option(help="CSV with columns clip,label.")] = None,
    skeletons: Annotated[
        Path | None, typer.Option(help="Folder of the AMC clips' ASF files.")
    ] = None,
    kinds: Annotated[str, typer.Option(help=_KINDS_HELP)] = "motion,qssd,ksvd",
    workers: WorkersOption = None,
    scheduler: SchedulerOption = None,
) -> None:
    """Add clips to an existing index (skipping those already in it with the same content)."""
    from quatmotion.retrieval.index import ClipIndex

    with user_errors():
        ClipIndex.open(index).close()
    _build(paths, index, labels, skeletons, kinds, workers, scheduler)


@index_app.command("remove")
def remove_command(
    index: Annotated[Path, typer.Argument(help="Index file (.qidx).")],
    clips: Annotated[list[str], typer.Argument(help="Clip names or paths.")],
) -> None:
    """Remove clips from an index."""
    from quatmotion.retrieval.index import ClipIndex

    with user_errors(), ClipIndex.open(index, write=True) as idx:
        removed = idx.remove(clips)
        if not removed:
            raise CliInputError(f"no clip named {', '.join(clips)} in {index}")
    console.print(f"removed {len(removed)} clips", markup=False)


@index_app.command("ls")
def ls_command(
    index: Annotated[Path, typer.Argument(help="Index file (.qidx).")],
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
) -> None:
    """List the clips of an index: name, label, frames, fps, skeleton, path."""
    from quatmotion.retrieval.index import ClipIndex

    with user_errors(), ClipIndex.open(index) as idx:
        rows = idx.clips()
    if as_json:
        print(json.dumps([r.__dict__ for r in rows], indent=1))
        return
    table = Table("clip", "label", "frames", "fps", "skeleton", "path")
    for r in rows:
        table.add_row(r.name, r.label, str(r.frames), f"{r.fps:g}", r.skeleton[:8], r.path)
    console.print(table)
    console.print(f"{len(rows)} clips", markup=False)


@app.command("search")
def search_command(
    query: Annotated[
        str, typer.Argument(help="An .amc/.bvh file, or the name of an indexed clip.")
    ],
    index: Annotated[Path, typer.Option(help="Index file (.qidx).")],
    top: Annotated[int, typer.Option(help="Results to show.")] = 20,
    method: Annotated[
        str | None, typer.Option(help="Retrieval method (default: the best measured).")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
    skeleton: Annotated[Path | None, typer.Option(help="ASF of an AMC query.")] = None,
    within: Annotated[
        bool, typer.Option(help="Find where the query occurs inside longer clips.")
    ] = False,
) -> None:
    """Rank the indexed clips by similarity to the query."""
    from quatmotion.io import MOTION_SUFFIXES
    from quatmotion.retrieval.index import ClipIndex
    from quatmotion.retrieval.methods import DEFAULT_METHOD
    from quatmotion.retrieval.search import search, search_within

    with user_errors():
        name = method or DEFAULT_METHOD
        if within and method not in (None, DEFAULT_METHOD):
            raise CliInputError("--within uses the motion frames; leave out --method")
        path = Path(query)
        is_file = path.suffix.lower() in MOTION_SUFFIXES
        with ClipIndex.open(index) as idx:
            target = read_clip(path, skeleton) if is_file else query
            results = (
                search_within(idx, target, top=top)
                if within
                else search(idx, target, method=name, top=top)
            )
    if as_json:
        doc = {
            "query": query,
            "method": "subsequence-dtw" if within else name,
            "results": [r.as_dict() for r in results],
        }
        print(json.dumps(doc, indent=1))
        return
    cols = ["rank", "clip", "label", "distance"] + (["frames"] if within else [])
    table = Table(*cols)
    for r in results:
        row = [
            str(r.rank),
            r.clip,
            r.label,
            "-" if r.distance != r.distance else f"{r.distance:.4g}",
        ]
        if within:
            row.append(f"{r.start_frame}-{r.stop_frame}")
        table.add_row(*row)
    console.print(table)
