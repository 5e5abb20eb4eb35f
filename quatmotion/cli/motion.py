"""``quatmotion info | convert | generate``: look at, convert and make single clips."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.table import Table

from quatmotion.cli._app import app
from quatmotion.cli._common import (
    CliInputError,
    console,
    progress_bar,
    read_clip,
    require_file,
    user_errors,
    write_clip,
)

if TYPE_CHECKING:
    from quatmotion.motion import Motion


def _motion_summary(motion: Motion, path: str) -> Table:
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
    with user_errors():
        if file.suffix.lower() == ".asf":
            from quatmotion.io import read_asf

            sk = read_asf(require_file(file))
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
        motion = read_clip(file, skeleton)
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
    from quatmotion.io import MOTION_SUFFIXES

    with user_errors():
        if len(paths) < 2:
            raise CliInputError("convert needs at least one input and an output")
        *inputs, out = paths
        fmt = "." + to.lower().lstrip(".")
        if fmt not in MOTION_SUFFIXES:
            raise CliInputError(f"--to must be one of amc, bvh; got {to!r}")
        if len(inputs) == 1 and out.suffix.lower() in MOTION_SUFFIXES:
            motion = read_clip(inputs[0], skeleton)
            written = write_clip(motion, out)
            console.print(f"wrote {', '.join(str(w) for w in written)}")
            return
        if out.exists() and not out.is_dir():
            raise CliInputError(f"{out}: several inputs need an output folder, not a file")
        if out.suffix.lower() in MOTION_SUFFIXES:
            raise CliInputError(f"{out}: several inputs need an output folder")
        for path in inputs:  # fail before writing anything when an input is missing
            require_file(path)
        out.mkdir(parents=True, exist_ok=True)
        with progress_bar() as progress:
            task = progress.add_task("converting", total=len(inputs))
            for path in inputs:
                motion = read_clip(path, skeleton)
                write_clip(motion, out / f"{path.stem}{fmt}")
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

    with user_errors():
        motion = generate_clip(kind, seed, n_frames=frames, fps=fps)
        written = write_clip(motion, out)
        console.print(
            f"wrote {', '.join(str(w) for w in written)} "
            f"({motion.n_frames} frames at {motion.fps:g} fps)"
        )
