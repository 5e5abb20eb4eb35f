"""``quatmotion index build|add|remove|ls`` and ``quatmotion search``: a searchable clip library.

``index build`` and ``index add`` read every ``.amc``/``.bvh`` under the given folders (AMC
skeletons by the CMU/HDM05 layouts, or from ``--skeleton FILE|DIR``), compute the features of
every retrieval method on all cores and store them in a SQLite ``.qidx`` file
(:meth:`quatmotion.retrieval.ClipIndex.build`, one :class:`IndexSettings` made of the options);
both resume (clips already indexed with the same content hash are skipped, and the command says
so), apply ``--labels`` to every clip it names, and report bad files without stopping.
``index label`` changes labels only.
``search`` ranks the indexed clips for a query file or an indexed clip's name.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from quatmotion.cli._app import app
from quatmotion.cli._common import (
    LABEL_FOLDERS_HELP,
    LABELS_HELP,
    CliInputError,
    JointMapOption,
    JsonOption,
    SchedulerOption,
    SkeletonOption,
    TakeOption,
    UnitsOption,
    WorkersOption,
    at_least,
    check_outputs,
    check_units,
    console,
    doubt_reporter,
    error_console,
    fail,
    joint_map_entries,
    labels_option,
    print_json,
    print_mappings,
    progress_bar,
    read_clip,
    report_skipped,
    require_file,
    require_inputs,
    say_wrote,
    skeleton_mappings,
    user_errors,
)
from quatmotion.retrieval.ranges import DEFAULT_TOP

index_app = typer.Typer(
    help="Build and maintain a clip index (.qidx) for `quatmotion search`.", no_args_is_help=True
)
app.add_typer(index_app, name="index")

_KINDS_HELP = (
    "Feature kinds to compute: motion, qssd, ksvd (comma-separated; qssd and ksvd only for "
    "the paper-qssd and paper-ksvd methods, which cost several times motion alone)."
)
_BUILD_METHOD_HELP = (
    "Also compute the feature kinds this search method needs (paper-qssd: qssd; paper-ksvd: "
    "ksvd); repeat for several."
)


def _kinds(text: str, methods: list[str] | None = None) -> tuple[str, ...]:
    """The kinds asked for, then those the named methods need (each once, in that order)."""
    from quatmotion.retrieval.methods import FEATURE_KINDS, METHODS

    kinds = [k.strip() for k in text.split(",") if k.strip()]
    unknown = [k for k in kinds if k not in FEATURE_KINDS]
    if unknown or not kinds:
        raise CliInputError(
            f"unknown feature kinds {unknown}; choose from {', '.join(FEATURE_KINDS)}"
        )
    for method in methods or ():
        if method not in METHODS:
            raise CliInputError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
        kinds += [k for k in METHODS[method].kinds if k not in kinds]
    return tuple(kinds)


def _settings(
    kinds: str | None,
    skeleton: Path | None,
    skeletons: Path | None,
    units: str | None,
    label_folders: bool | None,
    methods: list[str] | None = None,
    base=None,  # IndexSettings | None
    joint_map: Path | None = None,
    take: str | None = None,
):  # -> IndexSettings
    """The one settings object of a build, from the options given on top of ``base`` (an
    index's stored settings for ``index add``; else :class:`IndexSettings`' defaults), checked
    once by the settings' constraints (the ASF option's file-or-folder checked here for its
    message). An option not given keeps the base's value."""
    from quatmotion.retrieval.index import IndexSettings

    if skeleton is not None and skeletons is not None:
        raise CliInputError(
            "give --skeleton (an ASF or a folder of them) once, not --skeletons too"
        )
    asf = skeleton if skeleton is not None else skeletons
    if asf is not None and not asf.exists():
        raise CliInputError(f"{asf}: no such skeleton file or folder")
    check_units(units)
    if base is None:
        base = IndexSettings()
        base = base.replace(read=base.read.replace(strict=False))
    read = base.read
    if units is not None:
        read = read.replace(units=units)
    if asf is not None:
        read = read.replace(skeleton=str(asf))
    if joint_map is not None:
        read = read.replace(joint_map=joint_map_entries(joint_map))
    if take is not None:
        read = read.replace(take=take)
    given: dict[str, object] = {"read": read}
    if kinds is not None or methods:
        asked = ",".join(base.kinds) if kinds is None else kinds
        given["kinds"] = _kinds(asked, methods)
    if label_folders is not None:
        given["label_folders"] = label_folders
    return base.replace(**given)


def _build(
    paths: list[Path],
    output: Path,
    settings,  # IndexSettings
    labels: Path | None,
    workers: int | None,
    scheduler: str | None,
    *,
    add: bool,
) -> None:
    from quatmotion.parallel import Runner
    from quatmotion.retrieval.index import ClipIndex

    with user_errors():
        label_map = labels_option(labels)
        require_inputs(paths)
        asf = Path(settings.read.skeleton) if settings.read.skeleton else None
        asf_files = sorted(asf.glob("*.asf")) if asf is not None and asf.is_dir() else [asf]
        check_outputs([output], [*paths, labels, *asf_files], replace=True)
        from quatmotion.cli._kernels import ensure_kernels

        learn = ("learn",) if {"qssd", "ksvd"} & set(settings.kinds) else ()
        ensure_kernels("read", *learn, "retrieval", workers=workers, scheduler=scheduler)
        with progress_bar(error_console) as bar:
            task = bar.add_task("indexing", total=None)

            def advance(done: int, total: int) -> None:
                bar.update(task, completed=done, total=total)

            options = {
                "runner": Runner.of(workers, scheduler),
                "progress": advance,
                "labels": label_map,
                "on_doubt": doubt_reporter(bar),
            }
            if add:
                report = ClipIndex.add(output, paths, settings=settings, **options)
            else:
                report = ClipIndex.build(paths, output, settings, **options)
    report_skipped(report.failures)
    fresh = not add and not report.details.get("resumed")
    if report.failures and not report.added and not report.skipped:
        if fresh:
            output.unlink(missing_ok=True)  # an index of no clip is no result: leave nothing
        raise fail(
            f"{output}: {'not written' if fresh else 'no clip added'}, none of the "
            f"{len(report.failures)} clips could be indexed"
        )
    resumed = " (resumed: the index was there)" if report.details.get("resumed") and not add else ""
    say_wrote(
        output,
        f"{len(report.added)} clips added, {len(report.skipped)} already indexed, "
        f"{len(report.failures)} failed{resumed}",
    )
    if label_map is not None:
        _say_labels(labels, report.labels_changed, report.unmatched_labels)
    if report.failures:
        raise typer.Exit(code=1)


def _say(text: str) -> None:
    console.print(text, markup=False, highlight=False, soft_wrap=True)


def _say_labels(labels: Path | None, changed: int, unmatched: list[str]) -> None:
    """One line on what a label option did, also when it did nothing."""
    missed = (
        f"; {len(unmatched)} keys name no clip ({', '.join(unmatched[:5])})" if unmatched else ""
    )
    if changed:
        _say(f"{labels}: {changed} clips labelled{missed}")
    else:
        _say(f"{labels}: changed no label (every clip it names has that label already){missed}")


_SKELETON_HELP = (
    "ASF of the AMC clips: one file (every AMC's), or a folder of them (each found by its name)."
)
_SKELETONS_HELP = "Same as --skeleton with a folder (kept for older scripts)."
SkeletonPath = Annotated[Path | None, typer.Option("--skeleton", "-s", help=_SKELETON_HELP)]


@index_app.command("build")
def build_command(
    paths: Annotated[list[Path], typer.Argument(help="Folders (searched recursively) or clips.")],
    output: Annotated[Path, typer.Option("-o", "--output", help="Index file to write (.qidx).")],
    labels: Annotated[Path | None, typer.Option(help=LABELS_HELP)] = None,
    skeleton: SkeletonPath = None,
    skeletons: Annotated[Path | None, typer.Option(help=_SKELETONS_HELP, hidden=True)] = None,
    units: UnitsOption = None,
    kinds: Annotated[
        str | None, typer.Option(help=f"{_KINDS_HELP} Default: motion.", show_default=False)
    ] = None,
    method: Annotated[list[str] | None, typer.Option(help=_BUILD_METHOD_HELP)] = None,
    label_folders: Annotated[bool, typer.Option(help=LABEL_FOLDERS_HELP)] = False,
    joint_map: JointMapOption = None,
    take: TakeOption = None,
    workers: WorkersOption = None,
    scheduler: SchedulerOption = None,
) -> None:
    """Index clips (a new file, or resume one: clips already indexed are skipped, and said so).

    --labels applies to every clip named, those already indexed too. A file that cannot be
    read is reported and skipped; the command then exits with code 1 after committing the
    others.
    """
    with user_errors():
        settings = _settings(
            kinds, skeleton, skeletons, units, label_folders, method, joint_map=joint_map,
            take=take,
        )  # fmt: skip
    _build(paths, output, settings, labels, workers, scheduler, add=False)


@index_app.command("add")
def add_command(
    index: Annotated[Path, typer.Argument(help="Index file (.qidx).")],
    paths: Annotated[list[Path], typer.Argument(help="Folders (searched recursively) or clips.")],
    labels: Annotated[Path | None, typer.Option(help=LABELS_HELP)] = None,
    skeleton: SkeletonPath = None,
    skeletons: Annotated[Path | None, typer.Option(help=_SKELETONS_HELP, hidden=True)] = None,
    units: UnitsOption = None,
    kinds: Annotated[
        str | None, typer.Option(help=f"{_KINDS_HELP} Default: the index's.", show_default=False)
    ] = None,
    method: Annotated[list[str] | None, typer.Option(help=_BUILD_METHOD_HELP)] = None,
    label_folders: Annotated[
        bool | None,
        typer.Option(help=f"{LABEL_FOLDERS_HELP} Default: the index's.", show_default=False),
    ] = None,
    joint_map: JointMapOption = None,
    take: TakeOption = None,
    workers: WorkersOption = None,
    scheduler: SchedulerOption = None,
) -> None:
    """Add clips to an existing index (skipping those already in it with the same content;
    --labels relabels those too). The clips are read and indexed with the settings the index
    was built with (unit, skeleton, feature kinds); an option given replaces its setting."""
    from quatmotion.retrieval.index import ClipIndex

    with user_errors():
        options = (kinds, skeleton, skeletons, units, label_folders, method)
        _settings(*options, joint_map=joint_map, take=take)  # the options' errors first
        with ClipIndex.open(index) as idx:
            stored = idx.settings
        settings = _settings(*options, base=stored, joint_map=joint_map, take=take)
    _build(paths, index, settings, labels, workers, scheduler, add=True)


@index_app.command("label")
def label_command(
    index: Annotated[Path, typer.Argument(help="Index file (.qidx).")],
    labels: Annotated[Path, typer.Option(help=LABELS_HELP)],
) -> None:
    """Set or change the labels of indexed clips (by name, file name, stem or path), without
    reading the clips again."""
    from quatmotion.collection import ClipSource, match_keys
    from quatmotion.retrieval.index import ClipIndex

    with user_errors():
        given = labels_option(labels) or {}
        require_file(index)
        check_outputs([index], [labels], replace=True)
        with ClipIndex.open(index, write=True) as idx:
            sources = [
                ClipSource(r.name, r.sha256, Path(r.ref.path) if r.ref.path else None)
                for r in idx.rows()
            ]
            assignment = match_keys(given, sources)
            changed = idx.set_labels(assignment.labels)

    _say_labels(labels, changed, assignment.unmatched)


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
    """List the clips of an index (name, label, frames, fps, skeleton, path) and the settings
    it was built with."""
    from quatmotion.retrieval.index import ClipIndex

    with user_errors(), ClipIndex.open(index) as idx:
        rows = idx.rows()
        settings, version = idx.settings, idx.version
        mappings = skeleton_mappings(idx.clips(), settings.read)
    if as_json:
        print_json(
            {
                "format": {"name": idx.format.name, "version": version},
                "settings": settings.to_dict(),
                "clips": [r.as_dict() for r in rows],
                "skeletons": mappings,
            }
        )
        return
    table = Table("clip", "label", "frames", "fps", "skeleton", "path")
    for r in rows:
        table.add_row(r.name, r.label, str(r.frames), f"{r.fps:g}", r.skeleton[:8], r.path)
    console.print(table)
    read = settings.read
    _say(
        f"{len(rows)} clips; index version {version}; features {', '.join(settings.kinds)}; "
        f"units {read.units or 'guessed'}; skeleton {read.skeleton or 'found by name'}"
        + (f"; joint map {', '.join(read.joint_map)}" if read.joint_map else "")
    )
    print_mappings(mappings)


_QUERIES_HELP = (
    "Many queries in one process: a folder of motion files (searched recursively) or a text "
    "file of queries, one a line (files or indexed clip names; # starts a comment)."
)


@app.command("search")
def search_command(
    index: Annotated[Path, typer.Option(help="Index file (.qidx).")],
    query: Annotated[
        str | None,
        typer.Argument(help="An .amc/.bvh file, or an indexed clip's name, file name or stem."),
    ] = None,
    queries: Annotated[Path | None, typer.Option(help=_QUERIES_HELP)] = None,
    top: Annotated[int, typer.Option(help="Results to show (at least 1).")] = DEFAULT_TOP,
    method: Annotated[
        str | None, typer.Option(help="Retrieval method (default: the best measured).")
    ] = None,
    as_json: JsonOption = False,
    skeleton: SkeletonOption = None,
    units: UnitsOption = None,
    within: Annotated[
        bool, typer.Option(help="Find where the query occurs inside longer clips.")
    ] = False,
    joint_map: JointMapOption = None,
    take: TakeOption = None,
) -> None:
    """Rank the indexed clips by similarity to the query (or to each of --queries).

    With --within, each result names the frames of the clip that match, first to last (from
    0); the JSON's stop_frame is one past the last. With --queries and --json, one document
    lists every query's results, in the order given.
    """
    with user_errors():
        at_least("--top", top, 1)
        _check_search_options(query, queries, method, within, skeleton, units)
        entries = joint_map_entries(joint_map)
        quick = None
        if not entries and take is None:
            quick = _quick_answer(index, query, top, method, within, skeleton, units)
        if quick is not None:  # a single query by clip name, without Numba
            method_name, own, results = quick
            if as_json:
                print_json(
                    {"query": query, "method": method_name, "left_out": own, "results": results}
                )
            else:
                _say_left_out(own)
                _print_results([_Result(**r) for r in results], within)
            return
        texts = _query_texts(query, queries)
        method_name, answers = _answer(
            index, texts, top, method, within, skeleton, units, entries, take
        )
    _show_answers(texts, answers, method_name, as_json, batch=queries is not None, within=within)


def _check_search_options(
    query: str | None,
    queries: Path | None,
    method: str | None,
    within: bool,
    skeleton: Path | None,
    units: str | None,
) -> None:
    """Step 1: the options agree (one query or --queries; --within without another method)."""
    from quatmotion.retrieval.quick import METHOD as DEFAULT_METHOD  # no Numba

    if within and method not in (None, DEFAULT_METHOD):
        raise CliInputError("--within uses the motion frames; leave out --method")
    if (query is None) == (queries is None):
        raise CliInputError("give one query, or --queries, not both")
    if units is not None:  # (quatmotion.io imports Numba)
        check_units(units)
    if skeleton is not None:
        require_file(skeleton)


def _query_texts(query: str | None, queries: Path | None) -> list[str]:
    """Step 2: the queries as given (file paths or clip names), in order."""
    from quatmotion.io import MOTION_SUFFIXES

    if queries is None:
        return [str(query)]
    if queries.is_dir():
        texts = [
            str(p)
            for p in sorted(queries.rglob("*"))
            if p.is_file() and p.suffix.lower() in MOTION_SUFFIXES
        ]
    else:
        require_file(queries)
        lines = queries.read_text(encoding="utf-8").splitlines()
        texts = [t.strip() for t in lines if t.strip() and not t.strip().startswith("#")]
    if not texts:
        raise CliInputError(f"{queries}: no queries in it")
    return texts


class _Result:
    """A result of the quick path, shown like a ``SearchResult``."""

    def __init__(self, rank: int, clip: str, path: str, label: str, distance: float | None):
        self.rank, self.clip, self.path, self.label = rank, clip, path, label
        self.distance = float("nan") if distance is None else distance


def _quick_answer(
    index: Path,
    query: str | None,
    top: int,
    method: str | None,
    within: bool,
    skeleton: Path | None,
    units: str | None,
) -> tuple[str, list[dict[str, object]]] | None:
    """A single query of the default method by an indexed clip's name, answered without Numba
    (:mod:`quatmotion.retrieval.quick`: importing Numba and loading its kernels costs more than
    one search); None when that path does not answer (a file, another method, --within...)."""
    if query is None or within or skeleton is not None or units is not None:
        return None
    from quatmotion.retrieval.quick import METHOD, quick_query

    if method not in (None, METHOD) or Path(query).exists():
        return None
    answer = quick_query(index, query, k=top)
    return None if answer is None else (METHOD, *answer)


_TAKE_SUFFIXES = (".fbx", ".glb", ".gltf")
"""Query files ``--take`` applies to (:data:`quatmotion.io.fbx.FBX_SUFFIXES`, glTF's)."""


def _answer(
    index: Path,
    texts: list[str],
    top: int,
    method: str | None,
    within: bool,
    skeleton: Path | None,
    units: str | None,
    joint_map: tuple[str, ...] = (),
    take: str | None = None,
) -> tuple[str, list[list]]:
    """Step 3: every query answered on the index opened once (a motion file is read, mapped
    by ``joint_map``, else by the index's stored map where its skeleton has those joints; any
    other text names an indexed clip; ``take`` the take of an FBX or glTF query file). Returns
    the method's name and each query's answer: the indexed clip it is, left out of its results
    (None: none), and its results."""
    from quatmotion.collection.reading import file_hash
    from quatmotion.errors import ClipNameError
    from quatmotion.io import MOTION_SUFFIXES
    from quatmotion.retrieval.index import ClipIndex
    from quatmotion.retrieval.search import default_method, query_row, search, search_within

    answers = []
    with ClipIndex.open(index) as idx:
        # an index of 0.3.0 has no features of the default: default_method says which it has
        name = "subsequence-dtw" if within else (method or default_method(idx))
        for text in texts:
            path = Path(text)
            looks_like_file = path.suffix.lower() in MOTION_SUFFIXES
            is_file = looks_like_file and path.exists()  # else a clip's name (walk.bvh too)
            if not is_file and (skeleton is not None or units is not None):
                raise CliInputError("--skeleton and --units apply to a query file")
            its_take = take if path.suffix.lower() in _TAKE_SUFFIXES else None
            target = (
                read_clip(path, skeleton, units, joint_map=joint_map, take=its_take)
                if is_file
                else text
            )
            if is_file and not joint_map and idx.settings.read.joint_map:
                from quatmotion.collection import with_joint_map

                target = with_joint_map(target, idx.settings.read.joint_map, if_fits=True)
            sha256 = file_hash(path, skeleton, its_take) if is_file else None
            where = path if is_file else None
            try:
                own = query_row(idx, target, sha256=sha256, path=where)
                found = (
                    search_within(idx, target, k=top, sha256=sha256, path=where)
                    if within
                    else search(idx, target, method=name, k=top, sha256=sha256, path=where)
                )
                answers.append((None if own is None else own.name, found))
            except ClipNameError as error:
                raise CliInputError(
                    f"{text}: no such file, and {error}" if looks_like_file else str(error)
                ) from None
    return name, answers


def _show_answers(
    texts: list[str], answers: list[list], method: str, as_json: bool, *, batch: bool, within: bool
) -> None:
    """Step 4: the results as JSON (one document) or a table per query."""
    if as_json:
        docs = [
            {"query": t, "method": method, "left_out": own, "results": [r.as_dict() for r in rs]}
            for t, (own, rs) in zip(texts, answers, strict=True)
        ]
        print_json({"method": method, "queries": docs} if batch else docs[0])
        return
    for text, (own, results) in zip(texts, answers, strict=True):
        if batch:
            console.print(f"query {text}", markup=False, highlight=False)
        _say_left_out(own)
        _print_results(results, within)


def _say_left_out(own: str | None) -> None:
    """The one line that says a query is an indexed clip, left out of its own results."""
    if own is not None:
        console.print(
            f"left out {own}: the query itself (an indexed clip)", markup=False, highlight=False
        )


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
