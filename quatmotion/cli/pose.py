"""``quatmotion pose index | search``: a motion library's poses under a learned distance.

``index`` reads every ``.amc`` and ``.bvh`` file under the given folders (ASF skeletons found
as :func:`quatmotion.io.read_amc` finds them, or ``--skeleton``), prepares each clip
(:meth:`quatmotion.pose.data.PoseClip.from_motion`: resampled to ``--fps``, put on the canonical
body of ``--height`` cm, so that skeletons of different proportions compare) and builds a
:class:`~quatmotion.pose.library.PoseLibrary` with
:meth:`~quatmotion.pose.library.PoseLibrary.build`: clips prepared in parallel
(``--workers``, ``--scheduler``: one :class:`~quatmotion.parallel.Runner`), a bar counting
finished clips, unreadable files listed at the end and exit code 1 when there were any.
``search`` answers
with the nearest poses: clip, frame number in the clip's file (from 0), time in seconds and
distance.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer
from rich.progress import Progress, TaskID

from quatmotion.cli._app import app
from quatmotion.cli._common import (
    FRAMES_HELP,
    CliInputError,
    ForceOption,
    JointMapOption,
    JsonOption,
    SchedulerOption,
    SkeletonOption,
    TakeOption,
    UnitsOption,
    WorkersOption,
    at_least,
    check_frame,
    check_outputs,
    check_units,
    console,
    doubt_reporter,
    error_console,
    joint_map_entries,
    print_json,
    print_mappings,
    progress_bar,
    read_clip,
    report_skipped,
    require_file,
    say_wrote,
    skeleton_mappings,
    user_errors,
    warn,
)

pose_app = typer.Typer(
    help="Index a motion library's poses and search it under a learned pose distance.",
    no_args_is_help=True,
)
app.add_typer(pose_app, name="pose")

from quatmotion.pose.ranges import DEFAULTS, FPS_RANGE  # noqa: E402  (the settings' ranges)


def _echo(message: str) -> None:
    error_console.print(message, markup=False, highlight=False, soft_wrap=True)


PathsArgument = Annotated[
    list[Path], typer.Argument(help="Folders (searched recursively) or .amc/.bvh files.")
]
FpsOption = Annotated[
    float,
    typer.Option(help=f"Frame rate poses are sampled at, {FPS_RANGE[0]:g} to {FPS_RANGE[1]:g}."),
]
HeightOption = Annotated[
    float, typer.Option(help="Stature of the common body every skeleton is put on, cm.")
]
MetricOption = Annotated[
    str,
    typer.Option(
        help="Pose distance to learn: GPDR+LOGIT or GPDR+LMS (the GPD with the root's speed "
        "and turn rate), GPD+LOGIT, GPD+LMS or GPD+RDSR (docs/performance.md)."
    ),
]
RankOption = Annotated[int, typer.Option(help="Dimensions of RDSR's projection W.")]
UnlabeledOption = Annotated[int, typer.Option(help="Unlabeled poses for RDSR.")]
PairsOption = Annotated[
    int, typer.Option(help="Transition pairs wanted (similar, and as many dissimilar for LMS).")
]
SeedOption = Annotated[int, typer.Option(help="Random seed (0 or more).")]
FitPosesOption = Annotated[
    int, typer.Option(help="Poses (of clips drawn at random) the distance is learned on.")
]
IndexThreadsOption = Annotated[
    int,
    typer.Option(help="Threads inserting poses into the HNSW graph (1: the same file every run)."),
]


@pose_app.command("index")
def index_command(
    paths: PathsArgument,
    output: Annotated[Path, typer.Option("-o", "--output", help="Library file to write.")],
    fps: FpsOption = DEFAULTS["fps"],
    height: HeightOption = DEFAULTS["height"],
    metric: MetricOption = DEFAULTS["metric"],
    rank: RankOption = DEFAULTS["rank"],
    unlabeled: UnlabeledOption = DEFAULTS["n_unlabeled"],
    pairs: PairsOption = DEFAULTS["n_pairs"],
    seed: SeedOption = DEFAULTS["seed"],
    fit_poses: FitPosesOption = DEFAULTS["fit_poses"],
    workers: WorkersOption = None,
    index_threads: IndexThreadsOption = DEFAULTS["index_threads"],
    scheduler: SchedulerOption = None,
    skeleton: SkeletonOption = None,
    units: UnitsOption = None,
    joint_map: JointMapOption = None,
    take: TakeOption = None,
    force: ForceOption = False,
) -> None:
    """Learn a pose distance on the library and index every pose of it.

    Clips are read and described in parallel; a file that cannot be read is reported and
    skipped, and the command then exits with code 1 after writing the library of the others.
    """
    from quatmotion.io import find_motion_files
    from quatmotion.parallel import Runner
    from quatmotion.pose.library import PoseLibrary

    with user_errors(output):
        settings = _pose_settings(
            fps=fps, height=height, metric=metric, rank=rank, n_unlabeled=unlabeled,
            n_pairs=pairs, seed=seed, fit_poses=fit_poses, index_threads=index_threads,
            skeleton=skeleton, units=units, joint_map=joint_map, take=take,
        )  # fmt: skip
        runner = Runner.resolve(scheduler, workers=workers)
        files = find_motion_files(paths)
        check_outputs([output], [*files, skeleton], force=force)
        from quatmotion.cli._kernels import ensure_kernels

        ensure_kernels("read", "pose", workers=workers, scheduler=scheduler)
        _echo(f"{len(files)} clips, prepared on {runner.describe()}")
        with progress_bar(error_console) as bar:
            report = PoseLibrary.build(
                paths,
                output,
                settings,
                runner=runner,
                progress=_StageBars(bar),
                log=lambda message: bar.console.print(message, markup=False, highlight=False),
                on_doubt=doubt_reporter(bar),
            )
    library = report.details["library"]
    report_skipped(report.failures)
    say_wrote(
        output,
        f"{len(library.clip_of)} poses of {len(library.clip_names)} clips; "
        f"{len(report.failures)} of {len(report.added) + len(report.failures)} clips failed",
    )
    if report.failures:
        raise typer.Exit(code=1)


@pose_app.command("add")
def add_command(
    library_path: Annotated[Path, typer.Argument(help="Pose library file (.npz) to add to.")],
    paths: PathsArgument,
    workers: WorkersOption = None,
    scheduler: SchedulerOption = None,
    skeleton: SkeletonOption = None,
    units: UnitsOption = None,
    joint_map: JointMapOption = None,
    take: TakeOption = None,
) -> None:
    """Add clips to a pose library with its stored settings and distance (nothing learned
    again); clips it already holds are skipped. Exits with code 1 if a clip failed."""
    from quatmotion.parallel import Runner
    from quatmotion.pose.library import PoseLibrary

    with user_errors(library_path):
        if not library_path.is_file():
            raise CliInputError(f"{library_path}: no pose library there (pose index makes one)")
        check_units(units)
        if skeleton is not None and not skeleton.exists():
            raise CliInputError(f"{skeleton}: no such skeleton file or folder")
        stored = PoseLibrary.stored_settings(library_path)
        settings = _read_over(stored, skeleton, units, joint_map, take)
        runner = Runner.resolve(scheduler, workers=workers)
        from quatmotion.cli._kernels import ensure_kernels

        ensure_kernels("read", "pose", workers=workers, scheduler=scheduler)
        with progress_bar(error_console) as bar:
            report = PoseLibrary.add(
                library_path, paths, settings, runner=runner, progress=_StageBars(bar),
                on_doubt=doubt_reporter(bar),
            )  # fmt: skip
    library = report.details["library"]
    report_skipped(report.failures)
    say_wrote(
        library_path,
        f"{len(report.added)} clips added, {len(report.skipped)} already there, "
        f"{len(report.failures)} failed; {len(library.clip_names)} clips, "
        f"{len(library.clip_of)} poses",
    )
    if report.failures:
        raise typer.Exit(code=1)


def _read_over(
    stored, skeleton: Path | None, units: str | None, joint_map: Path | None, take: str | None
):
    """The stored settings of a library (None: a version-2 library, which ``add`` refuses
    saying why) with the reading options given over their ``read``."""
    entries = joint_map_entries(joint_map)
    given = {"skeleton": None if skeleton is None else str(skeleton), "units": units,
             "joint_map": tuple(entries) if entries else None, "take": take}  # fmt: skip
    given = {k: v for k, v in given.items() if v is not None}
    if stored is None or not given:
        return stored
    return stored.replace(read=stored.read.replace(**given))


_OPTION_OF = {
    "fps": "--fps", "height": "--height", "metric": "--metric", "rank": "--rank",
    "n_unlabeled": "--unlabeled", "n_pairs": "--pairs", "seed": "--seed",
    "fit_poses": "--fit-poses", "index_threads": "--index-threads",
}  # fmt: skip


def _pose_settings(
    *,
    skeleton: Path | None,
    units: str | None,
    joint_map: Path | None = None,
    take: str | None = None,
    **values,
):  # -> PoseSettings
    """One :class:`PoseSettings` of the options, validated once by its constraints; a value
    refused is named by its option."""
    import re

    from quatmotion.collection import ReadSettings
    from quatmotion.pose.library import PoseSettings

    check_units(units)
    if skeleton is not None and not skeleton.exists():
        raise CliInputError(f"{skeleton}: no such skeleton file or folder")
    read = ReadSettings(
        units=units,
        skeleton=None if skeleton is None else str(skeleton),
        joint_map=joint_map_entries(joint_map),
        take=take,
    )
    try:
        return PoseSettings(**values, read=read)
    except ValueError as error:
        text = str(error)
        found = re.search(r"The '(\w+)' parameter of PoseSettings must be (.*)", text)
        if found is None:
            raise CliInputError(text) from None
        option = _OPTION_OF.get(found.group(1), found.group(1))
        raise CliInputError(f"{option} must be {found.group(2)}") from None


@pose_app.command("ls")
def ls_command(
    library_path: Annotated[Path, typer.Argument(help="A library written by 'pose index'.")],
    as_json: JsonOption = False,
) -> None:
    """List the clips of a pose library and the settings it was built with."""
    import numpy as np

    from quatmotion.pose.library import PoseLibrary

    with user_errors():
        library = PoseLibrary.open(library_path)
        refs = library.clips()
        read = library.settings.read if library.settings is not None else None
        mappings = skeleton_mappings(refs, read)
    settings = library.settings.to_dict() if library.settings is not None else None
    counts = np.bincount(library.clip_of, minlength=len(refs))
    if as_json:
        print_json(
            {
                "format": {"name": library.format.name, "version": library.version},
                "settings": settings,
                "clips": [
                    {**r.to_dict(), "poses": int(n)} for r, n in zip(refs, counts, strict=True)
                ],
                "skeletons": mappings,
            }
        )
        return
    for ref, n in zip(refs, counts, strict=True):
        console.print(f"{ref.name}\t{int(n)} poses\t{ref.path or ''}", markup=False)
    made = (
        "settings not recorded (version 2)"
        if settings is None
        else (f"{settings['metric']}, {settings['fps']:g} fps, height {settings['height']:g} cm")
    )
    if read is not None and read.joint_map:
        made += f"; joint map {', '.join(read.joint_map)}"
    console.print(
        f"{len(refs)} clips, {len(library.clip_of)} poses; pose library version "
        f"{library.version}; {made}",
        markup=False,
    )
    print_mappings(mappings)


class _StageBars:
    """``progress(stage, done, total)`` of a build drawn as one bar per stage."""

    _TEXT = {"learn": "reading a sample to learn the distance", "index": "indexing clips"}

    def __init__(self, bar: Progress) -> None:
        self.bar = bar
        self.tasks: dict[str, TaskID] = {}

    def __call__(self, stage: str, done: int, total: int) -> None:
        if stage not in self.tasks:
            for task in self.tasks.values():  # an earlier stage stopped where it was: complete
                self.bar.update(task, total=self.bar.tasks[task].completed)
            self.tasks[stage] = self.bar.add_task(self._TEXT.get(stage, stage), total=total)
        self.bar.update(self.tasks[stage], completed=done, total=total)


LibraryArgument = Annotated[Path, typer.Argument(help="A library written by 'pose index'.")]
FrameOption = Annotated[
    int, typer.Option("--frame", "-f", help=f"Frame number in the clip's file ({FRAMES_HELP}).")
]
ClipOption = Annotated[
    str | None,
    typer.Option("--clip", "-c", help="Indexed clip: its name, file name, stem or number."),
]
FileOption = Annotated[
    Path | None, typer.Option("--file", help="Query from a clip not in the library.")
]
KOption = Annotated[int, typer.Option("-k", help="Number of results (1 to the library's poses).")]
OtherClipsOption = Annotated[
    bool, typer.Option(help="Leave out results from the query's own clip.")
]
EfOption = Annotated[int, typer.Option(help="HNSW search breadth (higher: slower, more exact).")]
TransitionsOption = Annotated[
    bool,
    typer.Option(
        help="Rank the nearest poses by the library's transition judge: the probability "
        "that a jump from the query pose into each plays badly (shown as the distance)."
    ),
]


@pose_app.command("search")
def search_command(
    library_path: LibraryArgument,
    frame: FrameOption,
    clip: ClipOption = None,
    file: FileOption = None,
    k: KOption = 10,
    other_clips: OtherClipsOption = False,
    ef: EfOption = 64,
    transitions: TransitionsOption = False,
    as_json: JsonOption = False,
    skeleton: SkeletonOption = None,
    units: UnitsOption = None,
    joint_map: JointMapOption = None,
    take: TakeOption = None,
) -> None:
    """Find the poses most like frame F of a clip (frames count from 0), or with
    --transitions the best poses to jump to from it."""
    import numpy as np

    from quatmotion.pose.library import PoseLibrary

    with user_errors():
        if (clip is None) == (file is None):
            raise CliInputError("give exactly one of --clip (an indexed clip) or --file")
        if file is None and (skeleton is not None or units is not None or take is not None):
            raise CliInputError("--skeleton, --units and --take apply to a --file query")
        check_units(units)
        if skeleton is not None:
            require_file(skeleton)
        at_least("--ef", ef, 1)
        library = PoseLibrary.open(library_path, ef_search=ef)
        if file is not None:
            query, start, own_clip, query_doc = _file_query(
                library, file, frame, skeleton, units, joint_map, take, transitions
            )
        else:
            query, own_clip, found = library.pose_query(clip, frame)
            start = library.transition_start(frame, clip=clip) if transitions else None
            name = library.clip_names[own_clip]
            query_doc = {"clip": Path(name).stem, "path": name, "frame": found}
        n_poses = len(library.clip_of)
        available = int(np.sum(library.clip_of != own_clip)) if other_clips else n_poses
        if not 1 <= k <= available:
            where = " outside the query's clip" if other_clips else ""
            raise CliInputError(
                f"-k must be from 1 to {available} (the library's poses{where}), got {k}"
            )
        t0 = time.perf_counter()
        matches = library.nearest(
            query, k, exclude_clip=own_clip if other_clips else None, transition_from=start
        )
        elapsed = time.perf_counter() - t0
    results = _results(matches, [ref.name for ref in library.refs])
    if as_json:
        doc = {
            "query": query_doc,
            "method": library.metric + (" re-ranked by PAIR-GBT" if transitions else ""),
            "search_ms": 1e3 * elapsed,
            "results": results,
        }
        print_json(doc)
        return
    _print_matches(query_doc, frame, file is None, transitions, elapsed, results)


def _results(matches: list, names: list[str]) -> list[dict]:
    """The matches of a search as its JSON document lists them (with their catalogue labels),
    each clip by the collection's name (``names``; none in a version-2 library: its stem)."""
    labels = _labels([m.name for m in matches])
    return [
        {
            "rank": m.rank,
            "clip": names[m.clip] if names else Path(m.name).stem,
            "path": m.name,
            "label": labels.get(m.name, ""),
            "distance": m.distance,
            "frame": m.frame,
            "seconds": m.seconds,
        }
        for m in matches
    ]


def _file_query(library, file: Path, frame: int, skeleton: Path | None, units: str | None,
                joint_map: Path | None, take: str | None, transitions: bool):  # fmt: skip
    """The query of ``pose search --file``: its vector, where a transition leaves from (with
    ``--transitions``), the library's clip of the same content (-1: none) and the query as
    the JSON document names it."""
    import numpy as np

    from quatmotion.collection.reading import file_hash
    from quatmotion.pose.skeleton16 import skeleton_kind

    entries = joint_map_entries(joint_map)
    motion = read_clip(file, skeleton, units, strict=True, joint_map=entries, take=take)
    stored = library.settings.read.joint_map if library.settings else ()
    if not entries and stored:
        from quatmotion.collection import with_joint_map

        motion = with_joint_map(motion, stored, if_fits=True)
    check_frame(frame, motion.n_frames, str(file))
    kinds = library.meta.get("skeletons")
    if kinds and skeleton_kind(motion.skeleton) not in kinds:
        warn(
            f"{file}: a {skeleton_kind(motion.skeleton)} skeleton, the library's are "
            f"{', '.join(kinds)}: poses are compared on one common body, but distances "
            "between skeletons run larger than within one"
        )
    with np.errstate(all="ignore"):
        query, found = library.motion_query(motion, frame)
        start = library.transition_start(frame, motion=motion) if transitions else None
    # a file of an indexed clip is that clip (its content hash), as --clip names it
    sha256 = file_hash(file, skeleton, take)
    same = [i for i, ref in enumerate(library.clips()) if ref.sha256 == sha256]
    own_clip = same[0] if same else -1
    return query, start, own_clip, {"clip": file.stem, "path": str(file), "frame": found}


def _print_matches(
    query_doc: dict, frame: int, indexed: bool, transitions: bool, elapsed: float, results: list
) -> None:
    """``pose search``'s answer as a line about the query and a table of the matches."""
    from rich.table import Table

    used = query_doc["frame"]
    nearest = f", the nearest {'indexed' if indexed else 'sampled'} to {frame}"
    what = "poses to jump to from" if transitions else "poses like"
    console.print(
        f"{what} {query_doc['path']} frame {used}{nearest if used != frame else ''} "
        f"({FRAMES_HELP}); {1e3 * elapsed:.2f} ms",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
    table = Table()
    score = "P(bad transition)" if transitions else "distance"
    for col in ("rank", "clip", "label", "frame", "time (s)", score):
        table.add_column(col, justify="left" if col in ("clip", "label") else "right")
    for r in results:
        secs = "" if r["seconds"] is None else f"{r['seconds']:.2f}"
        table.add_row(
            str(r["rank"]), r["clip"], r["label"], str(r["frame"]), secs, f"{r['distance']:.4g}"
        )
    console.print(table)


def _labels(paths: list[str]) -> dict[str, str]:
    """Labels of the clips the data folder's catalogue knows (HDM05 class, Bandai content, CMU
    description), by path; other clips have none."""
    from quatmotion.datasets import catalogue, data_root

    root = data_root(must_exist=False)
    inside = [p for p in paths if Path(p).resolve().is_relative_to(root)]
    if not inside or not root.is_dir():
        return {}
    wanted = {Path(p).resolve(): p for p in inside}
    return {
        wanted[e.path.resolve()]: e.label for e in catalogue(root) if e.path.resolve() in wanted
    }
