"""The demo behind ``make demo`` / ``quatmotion demo``: a tour of the main job in under a minute.

Steps: generate a labelled library of procedural clips (or read the clips given), print what
they are, draw one as a stick figure (PNG), learn a QSSD dictionary and a K-SVD dictionary
on the clips' angular displacements and compare their reconstruction errors on held-out frames,
then compress the clips into a ``.qmz`` library with every joint within 1 cm (the default codec
beside the spline and naive baselines) and, when the data folder is present, one real clip;
last, index the clips and search them by example (the first clip), and write ``view.html``,
the example beside its best match. :func:`build_library` makes the library ``quatmotion serve``
serves without files (the same clips) or from a folder.

Conventions
-----------
* Samples are angular displacements (QSSD paper, Sec. 4.2; see
  :func:`quatmotion.motion.angular_displacements`): one frame's rotations of every joint with
  rotation channels relative to the clip's first frame, ``(n, 4)`` unit quaternions.
* Clips are subsampled to at most 20 frames/s before sampling frames (neighbouring frames at
  120 frames/s are near-duplicates); 80 % of the frames train, 20 % test (random split).
* Errors are the mean rotation angle between sample and reconstruction, degrees per joint per
  frame (docs/metrics.md "Angular error", with the factor 2).
* Outputs go to ``out_dir``: ``stick_<clip>.png``, the ``.qmz`` files, ``library.qidx``,
  ``view.html``, ``clips/`` (the generated clips as BVH, for the index) and ``summary.json``
  (written atomically).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from rich.console import Console
from rich.table import Table

from quatmotion._atomic import atomic_write_text
from quatmotion.motion import Motion, angular_displacements, forward_kinematics, standing_height
from quatmotion.viz import pyplot, save_figure

if TYPE_CHECKING:
    from quatmotion.collection import BuildReport, ReadSettings

__all__ = [
    "BuiltLibrary",
    "build_library",
    "plot_stick_figure",
    "run_demo",
    "sample_step",
    "write_clips",
]

_MAX_SAMPLE_FPS = 20.0
_MAX_USER_CLIPS = 60
_TEST_FRACTION = 0.2


def sample_step(motion: Motion, max_fps: float = _MAX_SAMPLE_FPS) -> int:
    """Frames to skip between samples so that at most ``max_fps`` samples a second remain."""
    return max(1, int(np.ceil(motion.fps / max_fps - 1e-9)))


def plot_stick_figure(motion: Motion, path: str | Path, n_poses: int = 8) -> Path:
    """Draw ``n_poses`` evenly spaced frames of ``motion`` as stick figures, saved as PNG.

    The left panel looks at the body from its side along the direction of travel (or along the
    world X axis when it stays in place, poses spread out); the right panel from the front.
    Written to a temporary file and renamed.

    Parameters
    ----------
    motion : Motion
    path : str or Path
        Output ``.png``.
    n_poses : int
        Frames to draw.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    plt = pyplot()
    path = Path(path)
    points = forward_kinematics(motion).positions  # (T, J, 3) cm
    parents = motion.skeleton.parents
    frames = np.linspace(0, motion.n_frames - 1, min(n_poses, motion.n_frames)).astype(int)
    travel = points[-1, 0, [0, 2]] - points[0, 0, [0, 2]]
    if np.linalg.norm(travel) > 30.0:
        forward = travel / np.linalg.norm(travel)
    else:
        forward = np.array([0.0, 1.0])
    side = np.array([forward[1], -forward[0]])
    along = points[..., [0, 2]] @ forward  # (T, J)
    across = points[..., [0, 2]] @ side
    height = points[..., 1]
    spread = np.linalg.norm(travel) <= 30.0
    fig, axes = plt.subplots(1, 2, figsize=(14, 4.5), gridspec_kw={"width_ratios": [3, 2]})
    colours = plt.cm.viridis(np.linspace(0.0, 0.9, len(frames)))
    for k, (f, colour) in enumerate(zip(frames, colours, strict=True)):
        shift_side = k * 80.0 if spread else 0.0
        shift_front = k * 90.0
        for j in range(1, len(parents)):
            p = parents[j]
            axes[0].plot(along[f, [p, j]] + shift_side, height[f, [p, j]], color=colour, lw=1.6)
            axes[1].plot(
                across[f, [p, j]] - across[f, 0] + shift_front,
                height[f, [p, j]],
                color=colour,
                lw=1.6,
            )
        axes[0].plot(along[f, 0] + shift_side, height[f, 0], "o", color=colour, ms=3)
    for ax, title in zip(axes, ("side view (cm)", "front view (cm, poses spread)"), strict=True):
        ax.axhline(0.0, color="0.6", lw=0.8)
        ax.set_aspect("equal")
        ax.set_title(title)
    fig.suptitle(
        f"{motion.name}: {motion.n_frames} frames at {motion.fps:g} fps, "
        f"{len(frames)} poses (dark = early)"
    )
    return save_figure(fig, path, dpi=90)


def _load(
    paths: Sequence[Path],
    seed: int,
    quick: bool,
    units: str | None = None,
    skeleton: str | Path | None = None,
) -> list[tuple[Motion, str]]:
    if paths:
        from quatmotion.io import find_motion_files, read_motion

        files = find_motion_files(paths)[:_MAX_USER_CLIPS]
        out = []
        for p in files:
            amc = p.suffix.lower() == ".amc"
            motion = read_motion(p, skeleton if amc else None, units=None if amc else units)
            out.append((motion, p.parent.name))
        return out
    from quatmotion.synthetic import generate_library

    return generate_library(1 if quick else 2, seed=seed)


def _compare(
    train: NDArray[np.float64], test: NDArray[np.float64], seed: int, quick: bool
) -> list[dict[str, Any]]:
    from quatmotion.sparse import KSVD, QSSD, angular_error_deg

    params = {
        "n_atoms": 16 if quick else 32,
        "sparsity": 3,
        "max_iter": 3 if quick else 5,
        "random_state": seed,
    }
    rows = []
    for name, cls in (("QSSD", QSSD), ("K-SVD", KSVD)):
        start = time.perf_counter()
        model = cls(**params).fit(train)
        fit_s = time.perf_counter() - start
        start = time.perf_counter()
        test_hat = model.inverse_transform(model.transform(test))
        code_s = time.perf_counter() - start
        train_hat = model.inverse_transform(model.transform(train))
        rows.append(
            {
                "method": name,
                **{k: v for k, v in params.items() if k != "random_state"},
                "train_error_deg": angular_error_deg(train, train_hat),
                "test_error_deg": angular_error_deg(test, test_hat),
                "fit_seconds": fit_s,
                "test_coding_seconds": code_s,
            }
        )
    return rows


def run_demo(
    paths: Sequence[Path] = (),
    out_dir: str | Path = "demo-out",
    seed: int = 0,
    quick: bool = False,
    console: Console | None = None,
    units: str | None = None,
    skeleton: str | Path | None = None,
) -> dict[str, Any]:
    """Run the demo and print a Rich summary; returns what it wrote to ``summary.json``.

    Parameters
    ----------
    paths : sequence of Path
        Clips or folders (``.amc`` with their ASF found by name, ``.bvh``); empty: the built-in
        generated library (2 clips of each kind, 1 with ``quick``).
    out_dir : str or Path
        Folder for ``stick_<clip>.png`` and ``summary.json``.
    seed : int
        Seed of the library, the train/test split and the dictionary initialisation.
    quick : bool
        Fewer clips, atoms and iterations.
    console : rich.console.Console, optional
    units : str, optional
        Length unit of the BVH clips given (see :func:`quatmotion.io.read_motion`); ``None``
        guesses it.
    skeleton : str or Path, optional
        The ASF of the AMC clips given (else each one's is found by name).

    Returns
    -------
    dict
        Clips, sample counts, the figure's path and one row per method (errors in degrees).
    """
    console = console or Console()
    out_dir = Path(out_dir)
    start = time.perf_counter()
    clips = _load(list(paths), seed, quick, units, skeleton)
    source = "given clips" if paths else "generated library"
    console.print(_clip_table(clips, source))
    figure = plot_stick_figure(clips[0][0], out_dir / f"stick_{clips[0][0].name}.png")
    console.print(f"stick figure of {clips[0][0].name}: {figure}")
    summary: dict[str, Any] = {
        "source": source,
        "seed": seed,
        "quick": quick,
        "clips": [
            {"name": m.name, "label": lab, "frames": m.n_frames, "fps": m.fps} for m, lab in clips
        ],
        "figure": str(figure),
    }
    summary.update(_dictionary_comparison(clips, seed, quick, console))
    summary["compression"] = _compression(clips, out_dir, seed, quick, console)
    summary["search"] = _search_by_example(clips, list(paths), out_dir, console)
    summary["seconds"] = time.perf_counter() - start
    atomic_write_text(out_dir / "summary.json", json.dumps(summary, indent=2))
    console.print(f"summary: {out_dir / 'summary.json'} ({summary['seconds']:.1f} s)")
    console.print(
        f"next: open {summary['search']['view']} in a browser (offline; space plays); "
        "`quatmotion serve` shows the same library in the web app",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
    return summary


def _search_by_example(
    clips: list[tuple[Motion, str]], paths: list[Path], out_dir: Path, console: Console
) -> dict[str, Any]:
    """Index the clips (motion features), search with the first one as the example, and
    write ``view.html``: the example beside its best match."""
    from quatmotion.io import find_motion_files
    from quatmotion.retrieval import DEFAULT_METHOD, ClipIndex, IndexSettings
    from quatmotion.retrieval.search import search
    from quatmotion.viz import write_view

    if paths:
        files = find_motion_files(paths)[:_MAX_USER_CLIPS]
        labels = {f.stem: label for f, (_, label) in zip(files, clips, strict=True)}
    else:
        labels = {f.stem: label for f, label in write_clips(clips, out_dir / "clips").items()}
        files = [out_dir / "clips" / f"{m.name}.bvh" for m, _ in clips]
    index_path = out_dir / "library.qidx"
    index_path.unlink(missing_ok=True)  # built afresh: the demo runs with --force
    report = ClipIndex.build(files, index_path, IndexSettings(kinds=("motion",)), labels=labels)
    query = clips[0][0]
    with ClipIndex.open(index_path) as index:
        results = search(index, query.name, k=5)
    console.print(
        f"search by example: {len(report.added)} clips indexed ({index_path}); the clips most like "
        f"{query.name} under {DEFAULT_METHOD}, the example itself left out",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
    table = Table(title=f"clips like {query.name}", title_justify="left")
    for column in ("rank", "clip", "label", "distance"):
        table.add_column(column, justify="right" if column in ("rank", "distance") else "left")
    for hit in results:
        table.add_row(str(hit.rank), hit.clip, hit.label, f"{hit.distance:.3f}")
    console.print(table)
    rows = [
        {"rank": h.rank, "clip": h.clip, "label": h.label, "distance": h.distance} for h in results
    ]
    if not results:
        return {"index": str(index_path), "query": query.name, "results": rows, "view": None}
    by_name = {m.name: m for m, _ in clips}
    best = by_name.get(results[0].clip) or _read(results[0].path)
    view = write_view(out_dir / "view.html", [query, best], title=f"{query.name} and {best.name}")
    console.print(
        f"view: {view} (the example beside its best match, {best.name})",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
    return {"index": str(index_path), "query": query.name, "results": rows, "view": str(view)}


def _read(path: str) -> Motion:
    from quatmotion.io import read_motion

    return read_motion(path)


def _compression(
    clips: list[tuple[Motion, str]], out_dir: Path, seed: int, quick: bool, console: Console
) -> list[dict[str, Any]]:
    """Compress the clips (and one real clip if the data are there) at a 1 cm bound."""
    from quatmotion.codec import Archive, CompressSettings
    from quatmotion.codec.metrics import collection_errors
    from quatmotion.datasets import data_root
    from quatmotion.io import bvh_text

    motions = [m for m, _ in clips]
    text = sum(len(bvh_text(m)) for m in motions)  # the clips written as BVH
    jobs = [(name, motions, text) for name in (("best",) if quick else ("best", "spline", "naive"))]
    real = data_root(must_exist=False) / "cmu" / "02" / "02_01.amc"
    if real.is_file():
        from quatmotion.io import read_motion

        jobs.append(("best", [read_motion(real)], real.stat().st_size))
    table = Table(title="compression, every joint of every frame within 1 cm", title_justify="left")
    columns = ("clips", "method", "bytes", "ratio (text)", "ratio (float32)", "ARMS cm", "max cm")
    for column in columns:
        table.add_column(column, justify="left" if column in ("clips", "method") else "right")
    rows = []
    for method, group, source in jobs:
        name = f"{len(group)} generated" if group is motions else group[0].name
        out = out_dir / f"{'generated' if group is motions else group[0].name}_{method}.qmz"
        settings = CompressSettings(max_error=1.0, method=method, seed=seed)
        details = Archive.build(group, out, settings).details
        errors = collection_errors(details["clip_errors"])
        size = out.stat().st_size
        row = {
            "clips": name,
            "method": method,
            "bytes": size,
            "ratio_text": source / size,
            "ratio_raw": sum(details["raw_bytes"]) / size,
            "arms_cm": errors.arms,
            "max_joint_cm": errors.max_joint,
            "file": str(out),
        }
        rows.append(row)
        table.add_row(
            name, method, f"{size:,}", f"{row['ratio_text']:.0f}",
            f"{row['ratio_raw']:.0f}", f"{errors.arms:.3f}", f"{errors.max_joint:.3f}",
        )  # fmt: skip
    console.print(table)
    return rows


def _clip_table(clips: list[tuple[Motion, str]], source: str) -> Table:
    table = Table(title=f"{len(clips)} clips ({source})", title_justify="left")
    # the median over frames of the figure's vertical extent: its height only when it stands
    columns = ("clip", "label", "frames", "fps", "seconds", "joints", "median vertical extent cm")
    for column in columns:
        table.add_column(column, justify="left" if column in ("clip", "label") else "right")
    for motion, label in clips:
        table.add_row(
            motion.name,
            label,
            str(motion.n_frames),
            f"{motion.fps:g}",
            f"{motion.duration:.2f}",
            str(motion.n_joints),
            f"{standing_height(motion, max(1, motion.n_frames // 100)):.0f}",
        )
    return table


def _dictionary_comparison(
    clips: list[tuple[Motion, str]], seed: int, quick: bool, console: Console
) -> dict[str, Any]:
    """QSSD against K-SVD on the clips' angular displacements (a random frame split)."""
    samples = [angular_displacements(m, step=sample_step(m)) for m, _ in clips]
    if len({s.shape[1] for s in samples}) != 1:
        console.print(
            "the clips have different skeletons; the dictionary comparison needs one "
            "skeleton, so it is skipped.",
            style="yellow",
        )
        return {"methods": []}
    Y = np.concatenate(samples)
    order = np.random.default_rng(seed).permutation(len(Y))
    n_test = max(1, int(round(_TEST_FRACTION * len(Y))))
    train, test = Y[order[n_test:]], Y[order[:n_test]]
    console.print(
        f"angular displacements: {len(train)} training and {len(test)} test "
        f"frames of {Y.shape[1]} joint quaternions; learning dictionaries..."
    )
    rows = _compare(train, test, seed, quick)
    result = Table(
        title="reconstruction of angular displacements",
        caption="errors: mean rotation angle, degrees per joint per frame",
        title_justify="left",
        caption_justify="left",
    )
    columns = (
        "method",
        "atoms K",
        "sparsity L",
        "iterations",
        "train error",
        "test error",
        "fit s",
    )
    for column in columns:
        result.add_column(column, justify="left" if column == "method" else "right")
    for row in rows:
        result.add_row(
            row["method"],
            str(row["n_atoms"]),
            str(row["sparsity"]),
            str(row["max_iter"]),
            f"{row['train_error_deg']:.3f}",
            f"{row['test_error_deg']:.3f}",
            f"{row['fit_seconds']:.1f}",
        )
    console.print(result)
    return {
        "n_train": int(len(train)),
        "n_test": int(len(test)),
        "quaternions_per_sample": int(Y.shape[1]),
        "methods": rows,
    }


# --- a browsable, searchable library built from clips (the demo's ending, `quatmotion serve`) --


@dataclass(frozen=True)
class BuiltLibrary:
    """What :func:`build_library` wrote.

    Attributes
    ----------
    files : list of Path
        The motion files it read (the clips written, or those found under the sources).
    library : Path
        The ``.qmz`` library: every clip within 1 cm.
    index : Path
        The ``.qidx`` clip index (motion features: search by example with the default method).
    poses : Path or None
        The pose index (pose search), when asked for.
    failed : list of str
        ``"file: reason"`` of each clip left out.
    unmatched_labels : list of str
        Keys of the ``labels`` given that named no clip.
    """

    files: list[Path]
    library: Path
    index: Path
    poses: Path | None
    failed: list[str] = field(default_factory=list)
    unmatched_labels: list[str] = field(default_factory=list)


BuildProgress = Callable[[str, int, int], None]
"""``progress(step, done, total)`` of :func:`build_library`: steps ``index``, ``compress: ...``
(the codec's steps) and ``poses: ...``; it may raise to stop the build."""

StageReady = Callable[["Path | None", "Path | None", "Path | None"], None]
"""``on_stage(library, index, poses)`` of :func:`build_library`: called when a stage's file is
complete, with every file complete so far (None for those still to come)."""


def write_clips(clips: Sequence[tuple[Motion, str]], folder: str | Path) -> dict[Path, str]:
    """Each clip written as ``<folder>/<name>.bvh``; returns file -> label, in clip order."""
    from quatmotion.io import write_motion

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = {}
    for motion, label in clips:
        path = folder / f"{motion.name}.bvh"
        write_motion(motion, path)
        out[path] = label
    return out


def build_library(
    folder: str | Path,
    sources: Sequence[str | Path] = (),
    *,
    seed: int = 0,
    poses: bool = True,
    progress: BuildProgress | None = None,
    workers: int | None = None,
    labels: Mapping[str, str] | None = None,
    label_folders: bool = False,
    on_stage: StageReady | None = None,
    joint_map: Sequence[str] = (),
    take: str | None = None,
) -> BuiltLibrary:
    """Index, compress (and pose-index) clips into ``folder``, ready to serve or search.

    The index comes first (it is the quickest step, and with it the clips can be listed,
    played from their files and searched), then the library (every clip that reads, those the
    index refused too), then the pose index of the clips compressed; ``on_stage`` hears of each
    file as it is complete.

    Parameters
    ----------
    folder : str or Path
        Where the files go (created): ``library.qidx``, ``library.qmz``, ``poses.idx``, and
        ``clips/`` when the clips are generated.
    sources : sequence of paths
        Clips or folders of clips (``.amc`` with their ASF found by name, ``.bvh``); empty: the
        demo's generated library (two clips of every kind, labelled by kind).
    seed : int
        Seed of the generated clips and of the learners.
    poses : bool
        Build the pose index too.
    progress : callable, optional
        See :data:`BuildProgress`.
    workers : int, optional
        Processes of the batch steps (default: every core).
    labels : mapping, optional
        Clip (name, file name, stem or path) -> label, before every other source of labels
        (:func:`quatmotion.collection.label_sources`, as ``index build`` does).
    label_folders : bool
        Label a clip without another label by its folder's name.
    on_stage : callable, optional
        See :data:`StageReady`.
    joint_map, take
        A user's humanoid map and the FBX take read (None: every take a clip), as
        :class:`quatmotion.collection.ReadSettings` says.

    Returns
    -------
    BuiltLibrary

    Raises ``ValueError`` naming the sources where no clip could be read.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    report = progress or (lambda _step, _done, _total: None)
    stage = on_stage or (lambda _library, _index, _poses: None)
    from quatmotion.collection import ReadSettings

    files, labels = _clip_files(folder, sources, seed, labels, report)
    read = ReadSettings(joint_map=tuple(joint_map), take=take)
    index, indexed = _index_step(folder, files, labels, label_folders, read, workers, report)
    failed = {str(f.item): f.message for f in indexed.failures}
    if indexed.added:
        stage(None, index, None)
    library, good = _library_step(folder, files, seed, take, workers, report, failed)
    if not good:
        where = ", ".join(str(s) for s in sources) or "the generated library"
        raise ValueError(f"{where}: no clip could be read ({next(iter(failed.values()), '')})")
    stage(library, index if indexed.added else None, None)
    pose_path = None
    if poses:
        pose_path = _pose_step(folder, good, seed, read, workers, report, failed)
        stage(library, index if indexed.added else None, pose_path)
    failures = [f"{k}: {v}" for k, v in failed.items()]
    return BuiltLibrary(files, library, index, pose_path, failures, list(indexed.unmatched_labels))


def _clip_files(
    folder: Path,
    sources: Sequence[str | Path],
    seed: int,
    labels: Mapping[str, str] | None,
    report: BuildProgress,
) -> tuple[list[Path], Mapping[str, str] | None]:
    """The clip files of ``sources``, or the demo's generated library written to
    ``folder/clips`` (labelled by kind, ``labels`` first)."""
    from quatmotion.io import find_motion_files

    if sources:
        return find_motion_files(sources), labels
    from quatmotion.synthetic import generate_library

    generated = generate_library(2, seed=seed)
    report("clips", 0, len(generated))
    written = write_clips(generated, folder / "clips")
    report("clips", len(generated), len(generated))
    return list(written), {str(p): label for p, label in written.items()} | dict(labels or {})


def _step(report: BuildProgress, prefix: str) -> BuildProgress:
    return lambda name, done, total: report(f"{prefix}: {name}", done, total)


def _index_step(
    folder: Path,
    files: list[Path],
    labels: Mapping[str, str] | None,
    label_folders: bool,
    read: ReadSettings,
    workers: int | None,
    report: BuildProgress,
) -> tuple[Path, BuildReport]:
    """The clip index (``folder/library.qidx``) and its build report."""
    from quatmotion.parallel import Runner
    from quatmotion.retrieval.index import ClipIndex, IndexSettings

    index = folder / "library.qidx"
    indexed = ClipIndex.build(
        files,
        index,
        IndexSettings(
            kinds=("motion",),
            label_folders=label_folders,
            read=read,
        ),
        labels=labels,
        runner=Runner.of(workers),
        progress=lambda done, total: report("index", done, total),
    )
    return index, indexed


def _library_step(
    folder: Path,
    files: list[Path],
    seed: int,
    take: str | None,
    workers: int | None,
    report: BuildProgress,
    failed: dict[str, str],
) -> tuple[Path, list[Path]]:
    """The ``.qmz`` library of every clip, those the index refused too (still played and
    compared), at the default bound: its path and the files it holds (the others noted in
    ``failed``)."""
    from quatmotion.codec import Archive, CompressSettings
    from quatmotion.collection import ReadSettings
    from quatmotion.parallel import Runner

    library = folder / "library.qmz"
    settings = CompressSettings(seed=seed, on_error="skip", read=ReadSettings(take=take))
    try:
        built = Archive.build(
            files, library, settings, runner=Runner.of(workers), progress=_step(report, "compress")
        )
    except ValueError:  # nothing to compress: every clip failed
        return library, []
    refused = {str(f.item): f.message for f in built.failures}
    failed.update(refused)
    bad = {str(Path(name)) for name in refused}  # named by path, or by stem
    return library, [f for f in files if str(f) not in bad and f.stem not in bad]


def _pose_step(
    folder: Path,
    files: list[Path],
    seed: int,
    read: ReadSettings,
    workers: int | None,
    report: BuildProgress,
    failed: dict[str, str],
) -> Path:
    """The pose index of ``files`` (``folder/poses.idx``: every take of an FBX file of several
    a clip, with the clips' references); the clips it refused noted in ``failed``."""
    import functools

    from quatmotion.collection import find_clips
    from quatmotion.parallel import Runner
    from quatmotion.pose.library import PoseLibrary, PoseSettings, load_pose_source

    clips = find_clips(files, read)
    pose_library, pose_failures = PoseLibrary.build_streamed(
        clips,
        functools.partial(load_pose_source, fps=30.0, height=170.0, read=read),
        PoseSettings(seed=seed),
        runner=Runner.resolve(workers=workers),
        progress=_step(report, "poses"),
    )
    for failure in pose_failures:
        failed.setdefault(str(failure.item), failure.message)
    lost = {failure.index for failure in pose_failures}
    pose_library.refs = [c.ref() for i, c in enumerate(clips) if i not in lost]
    pose_path = folder / "poses.idx"
    pose_library.save(pose_path)
    return pose_path
