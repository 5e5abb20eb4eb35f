"""``quatmotion view | report``: the 3D viewer page and the benchmark report page."""

from __future__ import annotations

import contextlib
import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from quatmotion.cli._app import app
from quatmotion.cli._common import (
    CliInputError,
    ForceOption,
    SkeletonOption,
    TakeOption,
    UnitsOption,
    check_outputs,
    check_units,
    console,
    read_clip,
    require_file,
    user_errors,
)

if TYPE_CHECKING:
    from quatmotion.motion import Motion

LIBRARY_SEPARATOR = "::"
"""``LIB.qmz::CLIP`` names one clip of a compressed library."""


def _read(
    spec: str, skeleton: Path | None, units: str | None = None, take: str | None = None
) -> Motion:
    """The clip named on the command line: a motion file, or ``LIB.qmz::CLIP``."""
    if LIBRARY_SEPARATOR in spec:
        library, clip = spec.split(LIBRARY_SEPARATOR, 1)
        if not library or not clip:
            raise CliInputError(f"{spec}: expected LIBRARY.qmz::CLIP")
        from quatmotion import codec

        with codec.Archive.open(require_file(Path(library))) as archive:
            motion = archive.read(clip)
        return dataclasses.replace(motion, name=f"{Path(library).name}::{clip}")
    return read_clip(Path(spec), skeleton, units, take=take)


def _decoded(motion: Motion) -> Motion:
    """``motion`` compressed into a one-clip ``.qmz`` in memory (the default bound), then
    decoded."""
    from quatmotion import codec

    built = codec.Archive.build([motion], None, codec.CompressSettings())
    with codec.Archive.open(built.details["data"]) as archive:
        decoded = archive.read(0)
    return dataclasses.replace(decoded, name=f"{motion.name} (decoded)")


@app.command()
def view(
    files: Annotated[
        list[str],
        typer.Argument(
            help="Clips: .amc, .bvh, .glb/.gltf or .fbx files (a .qmz clip as LIB.qmz::CLIP)."
        ),
    ],
    out: Annotated[Path, typer.Option("--out", "-o", help="HTML page to write.")] = Path(
        "view.html"
    ),
    compare: Annotated[
        list[str] | None,
        typer.Option(
            help="A clip to play with each FILE, in order (repeat the option): in green beside "
            "(or over) the FILE in blue, each at its own length (the shorter holds its last "
            "frame); the per-joint error when both share skeleton, frame rate and frame count."
        ),
    ] = None,
    compare_decoded: Annotated[
        bool,
        typer.Option(
            "--compare-decoded",
            help="Compare each FILE with its compressed-then-decoded version (codec).",
        ),
    ] = False,
    ghost: Annotated[int, typer.Option(help="A faint pose every N frames (0: none).", min=0)] = 0,
    layout: Annotated[
        str | None, typer.Option(help="side (a viewport per clip) or overlay (one viewport).")
    ] = None,
    skeleton: SkeletonOption = None,
    units: UnitsOption = None,
    take: TakeOption = None,
    force: ForceOption = False,
) -> None:
    """Write a standalone 3D viewer page (opens offline; frames count from 0)."""
    from quatmotion.viz import write_view
    from quatmotion.viz.frame_data import comparison_obstacle

    with user_errors():
        if compare and compare_decoded:
            raise CliInputError("give --compare or --compare-decoded, not both")
        if layout not in (None, "side", "overlay"):
            raise CliInputError(f"--layout must be side or overlay, got {layout!r}")
        check_units(units)
        inputs = [Path(spec.split(LIBRARY_SEPARATOR)[0]) for spec in [*files, *(compare or [])]]
        check_outputs([out], [*inputs, skeleton], force=force)
        motions = [_read(spec, skeleton, units, take) for spec in files]
        others = None
        if compare:
            if len(compare) != len(files):
                raise CliInputError(
                    f"{len(compare)} --compare clip(s) for {len(files)} file(s): give one per file"
                )
            others = [_read(spec, skeleton, units) for spec in compare]
        elif compare_decoded:
            others = [_decoded(m) for m in motions]
        path = write_view(out, motions, others, ghost=ghost, layout=layout)  # type: ignore[arg-type]
        frames = sum(m.n_frames for m in motions)
        console.print(f"wrote {path} ({len(motions)} clip(s), {frames} frames)")
        for motion, other in zip(motions, others or (), strict=False):
            reason = comparison_obstacle(motion, other)
            if reason:
                console.print(f"no per-frame error for {motion.name} vs {other.name}: {reason}")


@app.command()
def report(
    results: Annotated[list[Path], typer.Argument(help="Benchmark JSON files (PNGs beside them).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="HTML page to write.")] = Path(
        "report.html"
    ),
    title: Annotated[str, typer.Option(help="Page title.")] = "quatmotion benchmarks",
    force: ForceOption = False,
) -> None:
    """Write one standalone page with the tables and figures of benchmark runs."""
    from quatmotion.errors import FormatError
    from quatmotion.viz import write_report
    from quatmotion.viz.report import load_result

    with user_errors():
        figures = []  # the PNGs the page embeds are inputs too
        for path in results:
            with contextlib.suppress(FormatError, OSError):  # reported by write_report
                figures += load_result(path).figures
        check_outputs([out], [*results, *figures], force=force)
        path = write_report(out, results, title=title)
        console.print(f"wrote {path} ({len(results)} benchmark result(s))")
