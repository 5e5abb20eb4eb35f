"""The ``quatmotion`` command line (Typer + Rich).

Commands: ``info``, ``convert``, ``generate``, ``datasets list|fetch``, ``bench``, ``demo`` and,
when :mod:`quatmotion.pose.cli` imports, ``pose``. Bad input (a missing file, a malformed file,
an unknown extension or name) ends the command with exit code 2 and a one-line ``error:``
message on stderr, never a traceback.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import pkgutil
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from quatmotion.errors import FormatError

__all__ = ["app", "main"]

app = typer.Typer(
    name="quatmotion",
    help="Compress and search human motion-capture libraries.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_show_locals=False,
)
datasets_app = typer.Typer(
    help="The motion-capture data folder: list clips, fetch CMU subjects.", no_args_is_help=True
)
app.add_typer(datasets_app, name="datasets")

console = Console()
error_console = Console(stderr=True)

MOTION_SUFFIXES = (".amc", ".bvh")
EXIT_BAD_INPUT = 2


class CliInputError(Exception):
    """Bad input detected by the CLI itself (reported like a FormatError)."""


def _fail(message: str) -> typer.Exit:
    # One line: the first line of the message, without Rich markup interpretation.
    first = str(message).strip().splitlines()[0] if str(message).strip() else "failed"
    error_console.print(f"error: {first}", markup=False, highlight=False, soft_wrap=True)
    return typer.Exit(code=EXIT_BAD_INPUT)


@contextlib.contextmanager
def _user_errors() -> Iterator[None]:
    """Turn bad-input exceptions into exit code 2 with a one-line message."""
    from quatmotion.datasets import DataNotFoundError, FetchError

    try:
        yield
    except FormatError as error:
        raise _fail(str(error)) from None
    except (DataNotFoundError, FileNotFoundError, IsADirectoryError, NotADirectoryError) as error:
        detail = error.strerror if getattr(error, "filename", None) else None
        raise _fail(f"{error.filename}: {detail}" if detail else str(error)) from None
    except (CliInputError, FetchError, ValueError, KeyError, PermissionError) as error:
        text = error.args[0] if isinstance(error, KeyError) and error.args else error
        raise _fail(str(text)) from None


def _require_file(path: Path) -> Path:
    if not path.exists():
        raise CliInputError(f"{path}: no such file")
    if path.is_dir():
        raise CliInputError(f"{path}: is a folder, expected a file")
    return path


def _read(path: Path, skeleton: Path | None):  # -> Motion
    from quatmotion.io import read_motion

    _require_file(path)
    if path.suffix.lower() not in MOTION_SUFFIXES:
        raise CliInputError(
            f"{path}: unknown motion file type {path.suffix!r} "
            f"(expected {', '.join(MOTION_SUFFIXES)})"
        )
    if skeleton is not None:
        _require_file(skeleton)
        if path.suffix.lower() != ".amc":
            raise CliInputError("--skeleton applies to AMC input only (a BVH has its own)")
    return read_motion(path, skeleton)


def _asf_path_for(amc: Path) -> Path:
    """Where an AMC's ASF goes so that :func:`quatmotion.io.find_asf_for_amc` finds it."""
    parts = amc.stem.split("_")
    if len(parts) >= 2 and parts[0].upper() == "HDM":
        return amc.with_name(f"{parts[0]}_{parts[1]}.asf")
    if len(parts) >= 2:
        return amc.with_name(f"{parts[0]}.asf")
    return amc.with_suffix(".asf")


def _write(motion, out: Path) -> list[Path]:  # noqa: ANN001 (Motion, imported lazily)
    """Write ``motion`` to ``out`` by extension; an AMC gets its ASF beside it."""
    from quatmotion.io import write_asf, write_motion

    suffix = out.suffix.lower()
    if suffix not in MOTION_SUFFIXES:
        raise CliInputError(
            f"{out}: unknown output type {out.suffix!r} (expected {', '.join(MOTION_SUFFIXES)})"
        )
    if suffix == ".amc" and motion.skeleton.extras.get("format") != "asf":
        raise CliInputError(
            f"{out}: AMC output needs an ASF skeleton; this clip's skeleton "
            f"({motion.skeleton.name!r}) comes from a BVH, write .bvh instead"
        )
    out.parent.mkdir(parents=True, exist_ok=True)
    written = [out]
    write_motion(motion, out)
    if suffix == ".amc":
        asf = _asf_path_for(out)
        write_asf(motion.skeleton, asf)
        written.append(asf)
    return written


def _motion_summary(motion, path: str) -> Table:  # noqa: ANN001
    from quatmotion.motion import standing_height

    sk = motion.skeleton
    table = Table(title=path, show_header=False, title_justify="left")
    table.add_column("field", style="bold")
    table.add_column("value")
    rows = [
        ("skeleton", sk.name or "-"),
        ("joints", str(sk.n_joints)),
        ("end sites", str(sk.n_sites)),
        ("frames", str(motion.n_frames)),
        ("fps", f"{motion.fps:g}"),
        ("duration (s)", f"{motion.duration:.3f}"),
        ("rest height (cm)", f"{sk.height():.1f}"),
    ]
    if motion.n_frames:
        step = max(1, motion.n_frames // 200)
        rows.append(("standing height (cm)", f"{standing_height(motion, step):.1f}"))
        rows.append(
            ("root at frame 0 (cm)", " ".join(f"{v:.1f}" for v in motion.root_translation[0]))
        )
    for field, value in rows:
        table.add_row(field, value)
    return table


@app.command()
def info(
    file: Annotated[Path, typer.Argument(help="A .amc, .bvh or .asf file.")],
    skeleton: Annotated[
        Path | None, typer.Option("--skeleton", "-s", help="ASF of an AMC (else found by name).")
    ] = None,
) -> None:
    """Print a clip's skeleton name, joints, frames, fps, duration and height (cm)."""
    with _user_errors():
        if file.suffix.lower() == ".asf":
            from quatmotion.io import read_asf

            sk = read_asf(_require_file(file))
            table = Table(title=str(file), show_header=False, title_justify="left")
            for field, value in (
                ("skeleton", sk.name),
                ("joints", str(sk.n_joints)),
                ("end sites", str(sk.n_sites)),
                ("rest height (cm)", f"{sk.height():.1f}"),
            ):
                table.add_row(field, value)
            console.print(table)
            return
        motion = _read(file, skeleton)
        console.print(_motion_summary(motion, str(file)))


@app.command()
def convert(
    paths: Annotated[
        list[Path],
        typer.Argument(
            help="Input clip(s) then the output: a .amc/.bvh file for one input, else a folder."
        ),
    ],
    skeleton: Annotated[
        Path | None, typer.Option("--skeleton", "-s", help="ASF of AMC input (else found by name).")
    ] = None,
    to: Annotated[str, typer.Option(help="Output format when writing into a folder.")] = "bvh",
) -> None:
    """Convert AMC <-> BVH by extension (ASF+AMC -> BVH too); many inputs into a folder."""
    with _user_errors():
        if len(paths) < 2:
            raise CliInputError("convert needs at least one input and an output")
        *inputs, out = paths
        fmt = "." + to.lower().lstrip(".")
        if fmt not in MOTION_SUFFIXES:
            raise CliInputError(f"--to must be one of amc, bvh; got {to!r}")
        if len(inputs) == 1 and out.suffix.lower() in MOTION_SUFFIXES:
            motion = _read(inputs[0], skeleton)
            written = _write(motion, out)
            console.print(f"wrote {', '.join(str(w) for w in written)}")
            return
        if out.exists() and not out.is_dir():
            raise CliInputError(f"{out}: several inputs need an output folder, not a file")
        if out.suffix.lower() in MOTION_SUFFIXES:
            raise CliInputError(f"{out}: several inputs need an output folder")
        for path in inputs:  # fail before writing anything when an input is missing
            _require_file(path)
        out.mkdir(parents=True, exist_ok=True)
        columns = (
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
        )
        with Progress(*columns, console=console) as progress:
            task = progress.add_task("converting", total=len(inputs))
            for path in inputs:
                motion = _read(path, skeleton)
                _write(motion, out / f"{path.stem}{fmt}")
                progress.advance(task)
        console.print(f"wrote {len(inputs)} clip(s) to {out}")


@app.command()
def generate(
    kind: Annotated[str, typer.Argument(help="Motion kind (see --help of 'demo' for the list).")],
    out: Annotated[Path, typer.Argument(help="Output .bvh or .amc (ASF written beside).")],
    seed: Annotated[int, typer.Option(help="Seed of style and noise.")] = 0,
    frames: Annotated[int | None, typer.Option(help="Frames (default: kind-dependent).")] = None,
    fps: Annotated[float, typer.Option(help="Frame rate.")] = 120.0,
) -> None:
    """Write one procedural clip (walk, run, jump, jumping_jack, squat, ...)."""
    from quatmotion.motion.synthetic import generate_clip

    with _user_errors():
        motion = generate_clip(kind, seed, n_frames=frames, fps=fps)
        written = _write(motion, out)
        console.print(
            f"wrote {', '.join(str(w) for w in written)} "
            f"({motion.n_frames} frames at {motion.fps:g} fps)"
        )


@datasets_app.command("list")
def datasets_list(
    collection: Annotated[str | None, typer.Option(help="cmu, cmu_bvh, hdm05 or bandai1.")] = None,
    match: Annotated[str | None, typer.Option(help="Text in a label or file name.")] = None,
    limit: Annotated[int, typer.Option(help="Show at most this many rows (0: all).")] = 0,
) -> None:
    """List the clips of the data folder ($QUATMOTION_DATA) with their labels."""
    from quatmotion.datasets import catalogue, data_root

    with _user_errors():
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
    overwrite: Annotated[bool, typer.Option(help="Download files that already exist.")] = False,
) -> None:
    """Download CMU subjects' ASF and AMC files, each written atomically."""
    from quatmotion.datasets import DEFAULT_CMU_BASE_URL, fetch_cmu

    with _user_errors():
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


def bench_names() -> list[str]:
    """Benchmarks present in :mod:`quatmotion.bench` (modules with a ``run`` function)."""
    import quatmotion.bench as bench_package

    return sorted(
        m.name for m in pkgutil.iter_modules(bench_package.__path__) if not m.name.startswith("_")
    )


@app.command()
def bench(
    name: Annotated[str, typer.Argument(help="Benchmark: a module of quatmotion.bench.")],
    out: Annotated[Path, typer.Option(help="JSON file to write (figures go beside it).")],
    quick: Annotated[bool, typer.Option(help="A small, fast version.")] = False,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
) -> None:
    """Run ``quatmotion.bench.NAME.run(out, quick=..., seed=...)``."""
    with _user_errors():
        available = bench_names()
        if name not in available:
            raise CliInputError(f"unknown benchmark {name!r}; available: {', '.join(available)}")
        module = importlib.import_module(f"quatmotion.bench.{name}")
        if not callable(getattr(module, "run", None)):
            raise CliInputError(f"quatmotion.bench.{name} has no run() function")
        out.parent.mkdir(parents=True, exist_ok=True)
    # Outside the bad-input guard: an exception inside a benchmark is a bug, shown in full.
    result = module.run(out, quick=quick, seed=seed)
    console.print(f"benchmark {name}: wrote {out}")
    if isinstance(result, dict):
        table = Table(show_header=False)
        for key, value in result.items():
            if isinstance(value, int | float | str | bool):
                table.add_row(str(key), f"{value:.4g}" if isinstance(value, float) else str(value))
        if table.row_count:
            console.print(table)


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
) -> None:
    """Generate (or load) clips, show them, and compress them with QSSD vs K-SVD."""
    from quatmotion.demo import run_demo

    with _user_errors():
        run_demo(paths or [], out_dir=out, seed=seed, quick=quick, console=console)


def _mount_pose() -> None:
    """Add ``quatmotion pose ...`` when :mod:`quatmotion.pose.cli` exists.

    The pose CLI pulls in scikit-learn and friends (seconds of imports), so it is imported only
    when a ``pose`` command runs: this command forwards its arguments to that Typer app.
    """
    try:
        found = importlib.util.find_spec("quatmotion.pose.cli") is not None
    except (ImportError, ValueError):
        found = False
    if not found:
        return

    @app.command(
        "pose",
        help="Index a motion library's poses and search it under a learned pose distance "
        "('quatmotion pose --help' for its commands).",
        context_settings={"allow_extra_args": True, "ignore_unknown_options": True},
        add_help_option=False,
    )
    def pose(ctx: typer.Context) -> None:
        try:
            pose_cli = importlib.import_module("quatmotion.pose.cli")
            pose_app = pose_cli.app
        except Exception as error:  # noqa: BLE001 (any failure: report, do not crash)
            raise _fail(f"the pose commands are unavailable: {error}") from None
        command = typer.main.get_command(pose_app)
        command.main(args=list(ctx.args), prog_name="quatmotion pose", standalone_mode=True)


_mount_pose()


def main() -> None:
    """Console-script entry point."""
    app()


if __name__ == "__main__":
    sys.exit(main())
