"""``quatmotion compress | decompress | ls | append``: ``.qmz`` motion libraries."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from quatmotion.cli._app import app
from quatmotion.cli._clip_files import Outputs, clip_files, clip_output, write_clip
from quatmotion.cli._common import (
    CliInputError,
    ForceOption,
    ForceUnitsOption,
    JsonOption,
    SchedulerOption,
    SkeletonOption,
    TakeOption,
    UnitsOption,
    WorkersOption,
    bvh_unit_label,
    check_outputs,
    check_units,
    check_writable,
    console,
    doubt_reporter,
    error_console,
    print_json,
    progress_bar,
    report_skipped,
    require_file,
    require_inputs,
    say_wrote,
    unit_label,
    unit_text,
    user_errors,
)
from quatmotion.errors import FormatError

_METHODS = "best, spline, naive, qssd or ksvd"


def _reporter(progress):
    tasks: dict[str, int] = {}

    def report(step: str, done: int, total: int) -> None:
        if step not in tasks:
            for task in tasks.values():  # a new step: the earlier ones are finished
                progress.update(task, completed=progress.tasks[task].total)
            tasks[step] = progress.add_task(step, total=total)
        progress.update(tasks[step], completed=done, total=total)

    return report


def _summary(details: dict, size: int) -> str:
    from quatmotion.codec.metrics import collection_errors

    errors = collection_errors(details["clip_errors"])
    source = sum(details["source_bytes"])
    raw = sum(details["raw_bytes"])
    parts = [f"{size:,} bytes"]
    if source:
        parts.append(f"{source / size:.0f}:1 against the source text")
    parts.append(f"{raw / size:.0f}:1 against float32 channels")
    parts.append(f"ARMS {errors.arms:.3f} cm, max joint error {errors.max_joint:.3f} cm")
    return ", ".join(parts)


def _clip_rows(archive, first: int = 0) -> list[dict[str, object]]:
    """The clips of an open archive from ``first`` on, as ``ls --json`` lists them."""
    rows = []
    units: dict[int, dict[str, object]] = {}  # per skeleton: clips share them
    refs = archive.clips()
    damaged = {d.index: d.reason for d in getattr(archive, "damaged", ())}
    for i, entry in enumerate(archive.entries[first:], start=first):
        size = archive.chunk_bytes(i)
        if entry.skeleton not in units:
            bvh = archive.bvh_unit(entry.skeleton)  # from the header: no record parsed
            try:
                units[entry.skeleton] = (
                    bvh_unit_label(*bvh) if bvh else unit_label(archive.skeleton(entry.skeleton))
                )
            except FormatError:  # its record is lost (a damaged file opened to recover)
                units[entry.skeleton] = {
                    "unit": None, "cm_per_unit": None, "unit_source": "damaged",
                    "unit_guessed": False,
                }  # fmt: skip
        unit = units[entry.skeleton]
        damage = damaged.get(i)
        rows.append(
            {
                "name": entry.name,
                "frames": entry.n_frames,
                "fps": entry.fps,
                "bytes": size,
                "source_bytes": entry.source_bytes,
                "source_format": entry.source_format,
                "ratio": entry.source_bytes / size if entry.source_bytes and size else None,
                "max_error_cm": entry.max_error,
                "arms_cm": entry.arms,
                **unit,
                "damaged": damage,
                "unit_text": "-" if unit["unit_source"] == "damaged" else unit_text(unit),
                "ref": refs[i].to_dict(),
            }
        )
    return rows


def _library_doc(path: Path, archive, rows: list[dict[str, object]]) -> dict[str, object]:
    """One ``.qmz`` as ``ls --json`` and ``compress --json`` print it."""
    source = sum(int(r["source_bytes"]) for r in rows)  # type: ignore[call-overload]
    settings = archive.settings
    return {
        "library": str(path),
        "bytes": archive.size,
        "method": archive.header.method,
        "format_version": archive.version,
        "settings": None if settings is None else settings.to_dict(),
        "source_bytes": source,
        "ratio": source / archive.size if source else None,
        "clips": [{k: v for k, v in r.items() if k != "unit_text"} for r in rows],
    }


def _settings_line(archive) -> str:
    """How the file was made, from the settings it stores (format version 2 on)."""
    settings = archive.settings
    if settings is None:
        return (
            f"made by quatmotion 0.3.0 or earlier (format version {archive.version}): "
            "settings not stored"
        )
    target = (
        f"ratio {settings.ratio:g}"
        if settings.ratio is not None
        else "no bound"
        if settings.max_error is None
        else f"max error {settings.max_error:g} cm on {settings.bound_on}"
    )
    quality = "default" if settings.quality is None else f"{settings.quality:g}"
    read = settings.read
    units = "guessed" if read.units is None else str(read.units)
    return (
        f"made with: method {settings.method}, {target}, quality {quality}, seed {settings.seed}; "
        f"read with units {units}, skeleton {read.skeleton or 'found by name'}, "
        f"translations {read.translations}{', strict' if read.strict else ''}"
    )


def _units_line(rows: list[dict[str, object]], settings) -> str:
    """``length unit: in (guessed) for 3 clips; cm (given) for 1 clip``; where a unit was
    guessed, what hangs on it: the error bound asked for (``settings.max_error``), else the
    errors measured."""
    counts = Counter(str(r["unit_text"]) for r in rows)
    parts = [f"{unit} for {n} clip{'s' if n != 1 else ''}" for unit, n in counts.most_common()]
    guessed = any(r["unit_guessed"] for r in rows)
    held = "the error bound holds" if settings.max_error is not None else "errors are measured"
    note = f" ({held} in this unit; give --units if a guess is wrong)"
    return f"length unit: {'; '.join(parts)}{note if guessed else ''}"


@app.command()
def compress(
    inputs: Annotated[list[Path], typer.Argument(help="AMC/BVH files or folders of them.")],
    out: Annotated[Path, typer.Option("-o", "--out", help="The .qmz file to write.")],
    max_error: Annotated[
        float | None, typer.Option(help="Bound on every joint's position error, cm.")
    ] = None,
    ratio: Annotated[
        float | None, typer.Option(help="Target ratio against the source text instead.")
    ] = None,
    method: Annotated[str, typer.Option(help=f"Codec: {_METHODS}.")] = "best",
    skeleton: SkeletonOption = None,
    units: UnitsOption = None,
    take: TakeOption = None,
    seed: Annotated[int, typer.Option(help="Seed of random choices (same seed, same bytes).")] = 0,
    workers: WorkersOption = None,
    scheduler: SchedulerOption = None,
    force: ForceOption = False,
    force_units: ForceUnitsOption = False,
    as_json: JsonOption = False,
) -> None:
    """Compress clips into one .qmz library (default: every joint within 1 cm).

    Clips are encoded in parallel (--workers, --scheduler) with the same bytes on any
    scheduler; a file that cannot be read is reported and left out, and the command then ends
    with exit code 1.
    """
    from quatmotion.codec import Archive, CompressSettings
    from quatmotion.collection import ReadSettings
    from quatmotion.parallel import Runner

    with user_errors(out):
        check_units(units)
        require_inputs(inputs, skeleton)
        read = ReadSettings(
            units=_units(units), skeleton=None if skeleton is None else str(skeleton), take=take
        )
        # Neither a bound nor a ratio: CompressSettings' default bound.
        bound = {} if max_error is None and ratio is None else {"max_error": max_error}
        settings = CompressSettings(
            **bound, ratio=ratio, method=method, seed=seed, on_error="skip", read=read
        )
        check_outputs([out], [*inputs, skeleton], force=force)
        from quatmotion.cli._kernels import ensure_kernels

        groups = ("read", "codec", "learn") if method in ("qssd", "ksvd") else ("read", "codec")
        ensure_kernels(*groups, workers=workers, scheduler=scheduler)
        with progress_bar(error_console if as_json else console) as progress:
            report = Archive.build(
                inputs, out, settings, runner=Runner.of(workers, scheduler),
                progress=_reporter(progress),
                on_doubt=doubt_reporter(progress, refuse_units=not force_units),
            )  # fmt: skip
        with Archive.open(out) as archive:
            rows = _clip_rows(archive)
            doc = _library_doc(out, archive, rows)
    failed = [(str(f.item), f.message) for f in report.failures]
    report_skipped(f"{name}: {reason}" for name, reason in failed)
    if as_json:
        print_json(
            {
                **doc,
                "max_error_cm": settings.max_error,
                "target_ratio": ratio,
                "failed": [{"input": name, "reason": reason} for name, reason in failed],
            }
        )
    else:
        summary = _summary(report.details, Path(out).stat().st_size)
        console.print(_units_line(rows, settings), markup=False, highlight=False)
        say_wrote(out, f"{len(report.added)} clip(s), {summary}")
        if failed:
            console.print(f"{len(failed)} input(s) failed")
    if failed:
        raise typer.Exit(code=1)


@app.command()
def decompress(
    library: Annotated[Path, typer.Argument(help="A .qmz file.")],
    out: Annotated[Path, typer.Option("-o", "--out", help="Folder for the clips.")],
    format: Annotated[  # noqa: A002 (the option's name)
        str | None, typer.Option("--format", help="amc or bvh (default: each clip's source).")
    ] = None,
    clip: Annotated[
        list[str] | None, typer.Option("--clip", help="Only this clip (repeatable).")
    ] = None,
    force: ForceOption = False,
    skip_damaged: Annotated[
        bool,
        typer.Option(
            "--skip-damaged",
            help="Recover every intact clip of a damaged file; list the damaged ones, exit 1.",
        ),
    ] = False,
) -> None:
    """Write the clips of a .qmz file as AMC (+ASF) or BVH, each under its own name."""
    from quatmotion.codec import Archive

    with user_errors(out):
        require_file(library)
        if format is not None and format.lower().lstrip(".") not in ("amc", "bvh"):
            raise CliInputError(f"--format must be amc or bvh, got {format!r}")
        if out.exists() and not out.is_dir():
            raise CliInputError(f"{out}: exists and is not a folder")
        check_writable(out, folder=True)
        with Archive.open(library, recover=skip_damaged) as archive:
            # A clip named twice (or by name and number) is written once.
            wanted = list(dict.fromkeys(archive.index_of(c) for c in clip or []))
            wanted = wanted or range(len(archive))
            damaged = {d.index: d for d in archive.damaged}
            skipped = [damaged[i] for i in wanted if i in damaged]
            wanted = [i for i in wanted if i not in damaged]
            planned = []  # every clip's files, checked before anything is written
            for i in wanted:
                entry = archive.entries[i]
                skeleton = archive.skeleton(entry.skeleton)
                fmt = (format or entry.source_format or "").lower().lstrip(".")
                if fmt not in ("amc", "bvh"):
                    fmt = "amc" if skeleton.extras.get("format") == "asf" else "bvh"
                planned.append(
                    (i, clip_files(clip_output(out, entry.name, f".{fmt}", library), skeleton))
                )
            from quatmotion.collection.refs import duplicates

            targets = [f for _, files in planned for f in files]
            twice = duplicates(str(f) for f in targets)
            if twice:
                raise CliInputError(
                    f"{library}: several clips would be written to {twice[0]} (their names "
                    "differ only in characters no file name holds)"
                )
            check_outputs(targets, [library], force=force)
            written = 0
            with Outputs() as outputs, progress_bar() as progress:
                outputs.folder(out)
                task = progress.add_task("decompressing", total=len(planned))
                for i, files in planned:
                    try:
                        motion = archive.read(i)
                    except FormatError as error:
                        hint = "" if skip_damaged else " (--skip-damaged recovers the others)"
                        raise FormatError(error.reason + hint, library) from None
                    write_clip(motion, files, outputs)
                    written += 1
                    progress.advance(task)
        console.print(f"wrote {written} clip(s) to {out}")
        if skipped:
            _report_damaged(library, skipped)
            raise typer.Exit(code=1)


def _report_damaged(library: Path, damaged) -> None:
    """One line per damaged clip on stderr: what ``ls`` and ``decompress --skip-damaged`` say."""
    error_console.print(f"{library}: {len(damaged)} damaged clip(s) not recovered:")
    for d in damaged:
        error_console.print(f"  {d.name} (clip {d.index}): {d.reason}", highlight=False)


@app.command("ls")
def list_library(
    library: Annotated[Path, typer.Argument(help="A .qmz file.")],
    as_json: JsonOption = False,
) -> None:
    """List a .qmz file's clips: frames, bytes, ratio, declared max error, ARMS and the length
    unit each was read in, and how the file was made (its settings)."""
    from quatmotion.codec import Archive

    with user_errors():
        require_file(library)
        with Archive.open(library, recover=True) as archive:
            rows = _clip_rows(archive)
            if as_json:
                doc = _library_doc(library, archive, rows)
                doc["damaged"] = [
                    {"index": d.index, "name": d.name, "reason": d.reason} for d in archive.damaged
                ]
                print_json(doc)
                if archive.damaged:
                    raise typer.Exit(code=1)
                return
            table = Table(
                title=f"{library} ({archive.size:,} bytes, method {archive.header.method})",
                title_justify="left",
            )
            columns = ("clip", "frames", "fps", "bytes", "ratio", "max error (cm)", "ARMS (cm)")
            for name in (*columns, "unit"):
                table.add_column(name, justify="left" if name in ("clip", "unit") else "right")
            for r in rows:
                ratio = "-" if r["ratio"] is None else f"{r['ratio']:.0f}"
                label = f"{r['name']} (damaged)" if r["damaged"] else str(r["name"])
                table.add_row(
                    label, str(r["frames"]), f"{r['fps']:g}", f"{r['bytes']:,}", ratio,
                    f"{r['max_error_cm']:.3f}", f"{r['arms_cm']:.3f}", str(r["unit_text"]),
                )  # fmt: skip
            console.print(table)
            source = sum(int(r["source_bytes"]) for r in rows)  # type: ignore[call-overload]
            whole = f"{source / archive.size:.0f}:1" if source else "-"
            console.print(
                f"{len(archive)} clip(s); whole file {archive.size:,} bytes, ratio {whole} "
                "(clip rows count their own chunk only; skeletons and models are shared)"
            )
            console.print(_settings_line(archive), markup=False, highlight=False)
            if archive.damaged:
                _report_damaged(library, archive.damaged)
                raise typer.Exit(code=1)


@app.command()
def append(
    library: Annotated[Path, typer.Argument(help="The .qmz file to extend (rewritten).")],
    inputs: Annotated[list[Path], typer.Argument(help="AMC/BVH files or folders to add.")],
    max_error: Annotated[
        float | None,
        typer.Option(
            help="Bound on every joint's position error of the new clips, cm (default: the "
            "bound the file was made with).",
            show_default=False,
        ),
    ] = None,
    skeleton: SkeletonOption = None,
    units: UnitsOption = None,
    take: TakeOption = None,
    force_units: ForceUnitsOption = False,
    workers: WorkersOption = None,
    scheduler: SchedulerOption = None,
) -> None:
    """Add clips to a .qmz file without re-encoding the clips already in it."""
    from quatmotion.codec import Archive
    from quatmotion.parallel import Runner

    with user_errors(library):
        require_file(library)
        check_units(units)
        require_inputs(inputs, skeleton)
        check_outputs([library], [*inputs, skeleton], replace=True)
        from quatmotion.cli._kernels import ensure_kernels

        with Archive.open(library) as archive:
            made = archive.settings
        settings = _add_settings(made, max_error, units, skeleton, take)
        ensure_kernels("read", "codec", workers=workers, scheduler=scheduler)
        with progress_bar() as progress:
            report = Archive.add(
                library, inputs, settings, runner=Runner.of(workers, scheduler),
                progress=_reporter(progress),
                on_doubt=doubt_reporter(progress, refuse_units=not force_units),
            )  # fmt: skip
        if not report.added:
            console.print(f"added 0 clips to {library}: it already holds all {len(report.skipped)}")
            return
        with Archive.open(library) as archive:
            rows = _clip_rows(archive, len(archive) - len(report.added))
            size = archive.size
    skipped = f" ({len(report.skipped)} already in it)" if report.skipped else ""
    console.print(_units_line(rows, settings), markup=False, highlight=False)
    say_wrote(
        library,
        f"added {len(report.added)} clip(s){skipped}, {_bound_text(settings)}; now {size:,} bytes",
    )


def _units(units):
    """--units as ReadSettings takes it: a unit name, or centimetres per unit as a number."""
    from quatmotion.io import LENGTH_UNITS

    if units is None or units.strip().lower() in LENGTH_UNITS:
        return None if units is None else units.strip().lower()
    return float(units)


def _add_settings(made, max_error, units, skeleton, take=None):
    """The settings new clips are coded with: the file's own (version 2) with what the command
    line gives on top."""
    from quatmotion.codec import CompressSettings

    base = made or CompressSettings()
    read = base.read
    if units is not None:
        read = read.replace(units=_units(units))
    if skeleton is not None:
        read = read.replace(skeleton=str(skeleton))
    if take is not None:
        read = read.replace(take=take)
    if max_error is not None:  # else the file's bound (or its ratio's quality), never a literal
        base = base.replace(max_error=max_error, ratio=None)
    return base.replace(read=read)


def _bound_text(settings) -> str:
    """What bounds the clips just coded, for a success line."""
    if settings.max_error is None:
        return "no error bound"
    return f"every joint within {settings.max_error:g} cm"
