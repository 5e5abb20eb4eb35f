"""``quatmotion pose index | search``: a motion library's poses under a learned distance.

``index`` reads every ``.amc`` and ``.bvh`` file under the given folders (ASF skeletons found
as :func:`quatmotion.io.read_amc` finds them), prepares each clip
(:meth:`quatmotion.pose.data.PoseClip.from_motion`: resampled to ``--fps``, scaled to
``--height`` cm) and builds a :class:`~quatmotion.pose.library.PoseLibrary`. ``search`` answers
with the nearest poses: clip, frame number in the clip's file, time in seconds and distance.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Annotated

import typer

from quatmotion.cli._app import app
from quatmotion.cli._common import CliInputError, read_clip, user_errors

pose_app = typer.Typer(
    help="Index a motion library's poses and search it under a learned pose distance.",
    no_args_is_help=True,
)
app.add_typer(pose_app, name="pose")


def _echo(message: str) -> None:
    typer.echo(message, err=True)


@pose_app.command("index")
def index_command(
    paths: Annotated[
        list[Path], typer.Argument(help="Folders (searched recursively) or .amc/.bvh files.")
    ],
    output: Annotated[Path, typer.Option("-o", "--output", help="Library file to write.")],
    fps: Annotated[float, typer.Option(help="Frame rate poses are sampled at.")] = 30.0,
    height: Annotated[
        float, typer.Option(help="Body height every skeleton is scaled to, cm.")
    ] = 170.0,
    metric: Annotated[
        str, typer.Option(help="Pose distance to learn: GPD+LMS (measured best) or GPD+RDSR.")
    ] = "GPD+LMS",
    rank: Annotated[int, typer.Option(help="Dimensions of RDSR's projection W.")] = 50,
    unlabeled: Annotated[int, typer.Option(help="Unlabeled poses for RDSR.")] = 5000,
    pairs: Annotated[
        int, typer.Option(help="Transition pairs wanted (similar, and as many dissimilar for LMS).")
    ] = 500,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
) -> None:
    """Learn a pose distance on the library and index every pose of it."""
    from quatmotion.io import find_motion_files
    from quatmotion.pose.data import PoseClip
    from quatmotion.pose.library import METRICS, PoseLibrary

    with user_errors():
        if metric not in METRICS:
            raise CliInputError(f"unknown --metric {metric!r}; choose from {', '.join(METRICS)}")
        files = find_motion_files(paths)
        clips = []
        for f in files:
            try:
                clips.append(
                    PoseClip.from_motion(read_clip(f), fps=fps, height=height, name=str(f))
                )
            except Exception as exc:  # noqa: BLE001 - one unreadable file must not stop a build
                _echo(f"skipping {f}: {exc}")
        _echo(f"read {len(clips)} of {len(files)} clips")
        library = PoseLibrary.build(
            clips,
            rank=rank,
            n_unlabeled=unlabeled,
            n_pairs=pairs,
            seed=seed,
            metric_name=metric,
            log=_echo,
        )
        library.save(output)
    _echo(f"wrote {output}: {len(library.clip_of)} poses of {len(library.clip_names)} clips")


@pose_app.command("search")
def search_command(
    library_path: Annotated[Path, typer.Argument(help="A library written by 'pose index'.")],
    frame: Annotated[int, typer.Option("--frame", "-f", help="Frame number in the clip's file.")],
    clip: Annotated[
        str | None, typer.Option("--clip", "-c", help="Indexed clip: name, file name or number.")
    ] = None,
    file: Annotated[
        Path | None, typer.Option("--file", help="Query from a clip not in the library.")
    ] = None,
    k: Annotated[int, typer.Option("-k", help="Number of results.")] = 10,
    other_clips: Annotated[
        bool, typer.Option(help="Leave out results from the query's own clip.")
    ] = False,
    ef: Annotated[int, typer.Option(help="HNSW search breadth (higher: slower, more exact).")] = 64,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
) -> None:
    """Find the poses most like frame F of a clip."""
    from quatmotion.pose.library import PoseLibrary

    with user_errors():
        if (clip is None) == (file is None):
            raise CliInputError("give exactly one of --clip (an indexed clip) or --file")
        library = PoseLibrary.load(library_path, ef_search=ef)
        if file is not None:
            query, found = library.motion_query(read_clip(file), frame)
            own_clip = -1
            label = f"{file} frame {found}"
        else:
            query, own_clip, found = library.pose_query(clip, frame)
            label = f"{library.clip_names[own_clip]} frame {found}"
        t0 = time.perf_counter()
        matches = library.nearest(query, k, exclude_clip=own_clip if other_clips else None)
        elapsed = time.perf_counter() - t0
    results = [
        {
            "rank": m.rank,
            "clip": m.name,
            "frame": m.frame,
            "seconds": m.seconds,
            "distance": m.distance,
        }
        for m in matches
    ]
    if as_json:
        json.dump(
            {"query": label, "search_ms": 1e3 * elapsed, "results": results}, sys.stdout, indent=2
        )
        sys.stdout.write("\n")
        return
    from rich.console import Console
    from rich.table import Table

    table = Table(title=f"poses like {label} ({1e3 * elapsed:.2f} ms)")
    for col in ("rank", "clip", "frame", "time (s)", "distance"):
        table.add_column(col, justify="left" if col == "clip" else "right")
    for r in results:
        secs = "" if r["seconds"] is None else f"{r['seconds']:.2f}"
        table.add_row(
            str(r["rank"]), Path(r["clip"]).name, str(r["frame"]), secs, f"{r['distance']:.4g}"
        )
    Console().print(table)
