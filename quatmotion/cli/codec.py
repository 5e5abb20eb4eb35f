"""``quatmotion compress | decompress | ls | append``: ``.qmz`` motion libraries."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from quatmotion.cli._app import app
from quatmotion.cli._common import (
    CliInputError,
    ForceOption,
    Outputs,
    SchedulerOption,
    WorkersOption,
    check_outputs,
    clip_files,
    console,
    progress_bar,
    report_skipped,
    require_file,
    user_errors,
    write_clip,
)

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


def _summary(result) -> str:
    from quatmotion.codec.metrics import collection_errors

    errors = collection_errors(result.clip_errors)
    source = sum(result.source_bytes)
    raw = sum(result.raw_bytes)
    parts = [f"{result.size:,} bytes"]
    if source:
        parts.append(f"{source / result.size:.0f}:1 against the source text")
    parts.append(f"{raw / result.size:.0f}:1 against float32 channels")
    parts.append(f"ARMS {errors.arms:.3f} cm, max joint error {errors.max_joint:.3f} cm")
    return ", ".join(parts)


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
    skeleton: Annotated[
        Path | None, typer.Option("--skeleton", "-s", help="ASF of AMC inputs (else by name).")
    ] = None,
    seed: Annotated[int, typer.Option(help="Seed of random choices (same seed, same bytes).")] = 0,
    workers: WorkersOption = None,
    scheduler: SchedulerOption = None,
    force: ForceOption = False,
) -> None:
    """Compress clips into one .qmz library (default: every joint within 1 cm).

    Clips are encoded in parallel (--workers, --scheduler) with the same bytes on any
    scheduler; a file that cannot be read is reported and left out, and the command then ends
    with exit code 1.
    """
    from quatmotion.codec import DEFAULT_MAX_ERROR_CM
    from quatmotion.codec import compress as run_compress

    with user_errors():
        if max_error is not None and ratio is not None:
            raise CliInputError("give --max-error or --ratio, not both")
        if max_error is None and ratio is None:
            max_error = DEFAULT_MAX_ERROR_CM
        if skeleton is not None:
            require_file(skeleton)
        for path in inputs:
            if not path.exists():
                raise CliInputError(f"{path}: no such file or folder")
        check_outputs([out], [p for p in inputs if p.is_file()], force=force)
        from quatmotion.cli.warmup import ensure_kernels

        groups = ("read", "codec", "learn") if method in ("qssd", "ksvd") else ("read", "codec")
        ensure_kernels(*groups, workers=workers, scheduler=scheduler)
        with progress_bar() as progress:
            result = run_compress(
                inputs, out, max_error=max_error, ratio=ratio, method=method,
                skeleton=skeleton, seed=seed, progress=_reporter(progress), workers=workers,
                scheduler=scheduler, on_error="skip",
            )  # fmt: skip
    report_skipped(f"{name}: {reason}" for name, reason in result.failed)
    console.print(f"wrote {out}: {len(result.clip_errors)} clip(s), {_summary(result)}")
    if result.failed:
        console.print(f"{len(result.failed)} input(s) failed")
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
) -> None:
    """Write the clips of a .qmz file as AMC (+ASF) or BVH, each under its own name."""
    from quatmotion.codec import open_archive

    with user_errors():
        require_file(library)
        if format is not None and format.lower().lstrip(".") not in ("amc", "bvh"):
            raise CliInputError(f"--format must be amc or bvh, got {format!r}")
        if out.exists() and not out.is_dir():
            raise CliInputError(f"{out}: exists and is not a folder")
        with open_archive(library) as archive:
            wanted = [archive.index_of(c) for c in clip] if clip else range(len(archive))
            planned = []  # every clip's files, checked before anything is written
            for i in wanted:
                entry = archive.clips[i]
                skeleton = archive.skeleton(entry.skeleton)
                fmt = (format or entry.source_format or "").lower().lstrip(".")
                if fmt not in ("amc", "bvh"):
                    fmt = "amc" if skeleton.extras.get("format") == "asf" else "bvh"
                planned.append((i, clip_files(out / f"{entry.name}.{fmt}", skeleton)))
            check_outputs([f for _, files in planned for f in files], [library], force=force)
            written = 0
            with Outputs() as outputs, progress_bar() as progress:
                outputs.folder(out)
                task = progress.add_task("decompressing", total=len(planned))
                for i, files in planned:
                    write_clip(archive.read(i), files, outputs)
                    written += 1
                    progress.advance(task)
        console.print(f"wrote {written} clip(s) to {out}")


@app.command("ls")
def list_library(
    library: Annotated[Path, typer.Argument(help="A .qmz file.")],
) -> None:
    """List a .qmz file's clips: frames, bytes, ratio, declared max error and ARMS."""
    from quatmotion.codec import open_archive

    with user_errors():
        require_file(library)
        with open_archive(library) as archive:
            table = Table(
                title=f"{library} ({archive.size:,} bytes, method {archive.header.method})",
                title_justify="left",
            )
            for name in ("clip", "frames", "fps", "bytes", "ratio", "max error (cm)", "ARMS (cm)"):
                table.add_column(name, justify="left" if name == "clip" else "right")
            source = 0
            for i, entry in enumerate(archive.clips):
                size = archive.chunk_bytes(i)
                ratio = f"{entry.source_bytes / size:.0f}" if entry.source_bytes and size else "-"
                source += entry.source_bytes
                table.add_row(
                    entry.name, str(entry.n_frames), f"{entry.fps:g}", f"{size:,}", ratio,
                    f"{entry.max_error:.3f}", f"{entry.arms:.3f}",
                )  # fmt: skip
            console.print(table)
            whole = f"{source / archive.size:.0f}:1" if source else "-"
            console.print(
                f"{len(archive)} clip(s); whole file {archive.size:,} bytes, ratio {whole} "
                "(clip rows count their own chunk only; skeletons and models are shared)"
            )


@app.command()
def append(
    library: Annotated[Path, typer.Argument(help="The .qmz file to extend (rewritten).")],
    inputs: Annotated[list[Path], typer.Argument(help="AMC/BVH files or folders to add.")],
    max_error: Annotated[
        float | None, typer.Option(help="Bound on every joint's position error, cm.")
    ] = 1.0,
    skeleton: Annotated[
        Path | None, typer.Option("--skeleton", "-s", help="ASF of AMC inputs (else by name).")
    ] = None,
    workers: WorkersOption = None,
    scheduler: SchedulerOption = None,
) -> None:
    """Add clips to a .qmz file without re-encoding the clips already in it."""
    from quatmotion.codec import append as run_append

    with user_errors():
        require_file(library)
        if skeleton is not None:
            require_file(skeleton)
        from quatmotion.cli.warmup import ensure_kernels

        ensure_kernels("read", "codec", workers=workers, scheduler=scheduler)
        with progress_bar() as progress:
            result = run_append(
                library, inputs, max_error=max_error, skeleton=skeleton,
                progress=_reporter(progress), workers=workers, scheduler=scheduler,
            )  # fmt: skip
        console.print(
            f"added {len(result.clip_errors)} clip(s) to {library}: now {result.size:,} bytes"
        )
