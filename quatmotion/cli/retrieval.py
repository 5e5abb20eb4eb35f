"""``quatmotion index build|add|remove|ls`` and ``quatmotion search``: a searchable clip library.

``index build`` and ``index add`` read every ``.amc``/``.bvh`` under the given folders (AMC
skeletons by the CMU/HDM05 layouts, or from ``--skeletons DIR``), compute the features of every
retrieval method on all cores and store them in a SQLite ``.qidx`` file; both resume (clips
already indexed with the same content hash are skipped) and report bad files without stopping.
``search`` ranks the indexed clips for a query file or an indexed clip's name.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from quatmotion.cli._app import app
from quatmotion.cli._common import (
    CliInputError,
    JsonOption,
    SchedulerOption,
    SkeletonOption,
    UnitsOption,
    WorkersOption,
    check_outputs,
    check_units,
    console,
    doubt_reporter,
    error_console,
    print_json,
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

_KINDS_HELP = (
    "Feature kinds to compute: motion, qssd, ksvd (comma-separated; qssd and ksvd only for "
    "the paper-qssd and paper-ksvd methods, which cost several times motion alone)."
)


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
    skeleton: Path | None = None,
    units: str | None = None,
) -> None:
    from quatmotion.parallel import resolve_scheduler
    from quatmotion.retrieval.build import build_index, read_labels_csv

    with user_errors():
        label_map = read_labels_csv(require_file(labels)) if labels else None
        if skeletons is not None and not skeletons.is_dir():
            raise CliInputError(f"{skeletons}: --skeletons must be a folder of ASF files")
        if skeleton is not None and skeletons is not None:
            raise CliInputError("give --skeleton (one ASF) or --skeletons (a folder), not both")
        if skeleton is not None:
            require_file(skeleton)
        check_units(units)
        kind_tuple = _kinds(kinds)
        for path in paths:
            if not path.exists():
                raise CliInputError(f"{path}: no such file or folder")
        asf_files = sorted(skeletons.glob("*.asf")) if skeletons is not None else []
        check_outputs([output], [*paths, labels, skeleton, *asf_files], replace=True)
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
                skeletons=skeleton or skeletons,
                units=units,
                workers=workers,
                scheduler=resolve_scheduler(scheduler, workers=workers),
                progress=advance,
                on_doubt=doubt_reporter(bar),
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


_SKELETONS_HELP = "Folder of the AMC clips' ASF files (each found by its name)."


@index_app.command("build")
def build_command(
    paths: Annotated[list[Path], typer.Argument(help="Folders (searched recursively) or clips.")],
    output: Annotated[Path, typer.Option("-o", "--output", help="Index file to write (.qidx).")],
    labels: Annotated[Path | None, typer.Option(help="CSV with columns clip,label.")] = None,
    skeleton: SkeletonOption = None,
    skeletons: Annotated[Path | None, typer.Option(help=_SKELETONS_HELP)] = None,
    units: UnitsOption = None,
    kinds: Annotated[str, typer.Option(help=_KINDS_HELP)] = "motion",
    workers: WorkersOption = None,
    scheduler: SchedulerOption = None,
) -> None:
    """Index clips (a new file, or resume one: clips already indexed are skipped).

    A file that cannot be read is reported and skipped; the command then exits with code 1
    after committing the others.
    """
    _build(paths, output, labels, skeletons, kinds, workers, scheduler, skeleton, units)


@index_app.command("add")
def add_command(
    index: Annotated[Path, typer.Argument(help="Index file (.qidx).")],
    paths: Annotated[list[Path], typer.Argument(help="Folders (searched recursively) or clips.")],
    labels: Annotated[Path | None, typer.Option(help="CSV with columns clip,label.")] = None,
    skeleton: SkeletonOption = None,
    skeletons: Annotated[Path | None, typer.Option(help=_SKELETONS_HELP)] = None,
    units: UnitsOption = None,
    kinds: Annotated[str, typer.Option(help=_KINDS_HELP)] = "motion",
    workers: WorkersOption = None,
    scheduler: SchedulerOption = None,
) -> None:
    """Add clips to an existing index (skipping those already in it with the same content)."""
    from quatmotion.retrieval.index import ClipIndex

    with user_errors():
        check_units(units)  # the options first, as build checks them
        if skeleton is not None:
            require_file(skeleton)
        ClipIndex.open(index).close()
    _build(paths, index, labels, skeletons, kinds, workers, scheduler, skeleton, units)


@index_app.command("remove")
def remove_command(
    index: Annotated[Path, typer.Argument(help="Index file (.qidx).")],
    clips: Annotated[list[str], typer.Argument(help="Clip names or paths.")],
) -> None:
    """Remove clips from an index."""
    from quatmotion.retrieval.index import ClipIndex

    with user_errors():
        require_file(index)
        check_outputs([index], replace=True)
        with ClipIndex.open(index, write=True) as idx:
            removed = idx.remove(clips)
    console.print(f"removed {len(removed)} clips", markup=False)


@index_app.command("ls")
def ls_command(
    index: Annotated[Path, typer.Argument(help="Index file (.qidx).")],
    as_json: JsonOption = False,
) -> None:
    """List the clips of an index: name, label, frames, fps, skeleton, path."""
    from quatmotion.retrieval.index import ClipIndex

    with user_errors(), ClipIndex.open(index) as idx:
        rows = idx.clips()
    if as_json:
        print_json([r.__dict__ for r in rows])
        return
    table = Table("clip", "label", "frames", "fps", "skeleton", "path")
    for r in rows:
        table.add_row(r.name, r.label, str(r.frames), f"{r.fps:g}", r.skeleton[:8], r.path)
    console.print(table)
    console.print(f"{len(rows)} clips", markup=False)


@app.command("search")
def search_command(
    index: Annotated[Path, typer.Option(help="Index file (.qidx).")],
    query: Annotated[
        str | None,
        typer.Argument(help="An .amc/.bvh file, or an indexed clip's name, file name or stem."),
    ] = None,
    queries: Annotated[
        Path | None,
        typer.Option(
            help="Many queries in one process: a folder of motion files (searched recursively) "
            "or a text file of queries, one a line (files or indexed clip names)."
        ),
    ] = None,
    top: Annotated[int, typer.Option(help="Results to show.")] = 20,
    method: Annotated[
        str | None, typer.Option(help="Retrieval method (default: the best measured).")
    ] = None,
    as_json: JsonOption = False,
    skeleton: SkeletonOption = None,
    units: UnitsOption = None,
    within: Annotated[
        bool, typer.Option(help="Find where the query occurs inside longer clips.")
    ] = False,
) -> None:
    """Rank the indexed clips by similarity to the query.

    With --within, each result names the frames of the clip that match, first to last (from
    0); the JSON's stop_frame is one past the last.
    """
    from quatmotion.errors import ClipNameError
    from quatmotion.io import MOTION_SUFFIXES
    from quatmotion.retrieval.index import ClipIndex
    from quatmotion.retrieval.methods import DEFAULT_METHOD
    from quatmotion.retrieval.search import search, search_within

    with user_errors():
        name = method or DEFAULT_METHOD
        if within and method not in (None, DEFAULT_METHOD):
            raise CliInputError("--within uses the motion frames; leave out --method")
        if (query is None) == (queries is None):
            raise CliInputError("give one query, or --queries, not both")
        check_units(units)
        if skeleton is not None:
            require_file(skeleton)
        if queries is not None:
            if queries.is_dir():
                texts = [
                    str(p)
                    for p in sorted(queries.rglob("*"))
                    if p.is_file() and p.suffix.lower() in MOTION_SUFFIXES
                ]
            else:
                require_file(queries)
                lines = queries.read_text(encoding="utf-8").splitlines()
                texts = [t.strip() for t in lines if t.strip() and not t.startswith("#")]
            if not texts:
                raise CliInputError(f"{queries}: no queries in it")
        else:
            texts = [str(query)]
        answers = []
        with ClipIndex.open(index) as idx:
            for text in texts:
                path = Path(text)
                # A motion file if there is one; else an indexed clip's name (walk.bvh too).
                is_file = path.suffix.lower() in MOTION_SUFFIXES and path.exists()
                if not is_file and (skeleton is not None or units is not None):
                    raise CliInputError("--skeleton and --units apply to a query file")
                target = read_clip(path, skeleton, units) if is_file else text
                try:
                    answers.append(
                        search_within(idx, target, top=top)
                        if within
                        else search(idx, target, method=name, top=top)
                    )
                except ClipNameError as error:
                    looks_like_file = path.suffix.lower() in MOTION_SUFFIXES
                    raise CliInputError(
                        f"{text}: no such file, and {error}" if looks_like_file else str(error)
                    ) from None
    method_name = "subsequence-dtw" if within else name
    if as_json:
        docs = [
            {"query": t, "method": method_name, "results": [r.as_dict() for r in rs]}
            for t, rs in zip(texts, answers, strict=True)
        ]
        print_json(docs[0] if queries is None else {"method": method_name, "queries": docs})
        return
    for text, results in zip(texts, answers, strict=True):
        if queries is not None:
            console.print(f"query {text}")
        _print_results(results, within)


def _print_results(results: list, within: bool) -> None:
    cols = ["rank", "clip", "label", "distance"] + (["frames (first-last)"] if within else [])
    table = Table(*cols)
    for r in results:
        row = [
            str(r.rank),
            r.clip,
            r.label,
            "-" if r.distance != r.distance else f"{r.distance:.4g}",
        ]
        if within:
            row.append(f"{r.start_frame}-{max(r.start_frame, r.stop_frame - 1)}")
        table.add_row(*row)
    console.print(table)
