"""``quatmotion pose``: index a motion library's poses and search it ("poses like this one").

Commands (a Typer sub-app, mounted by :mod:`quatmotion.cli` as ``quatmotion pose``)::

    quatmotion pose index DIR_OR_FILE... -o poses.idx [--fps 30] [--rank 50] [--seed 0]
    quatmotion pose search poses.idx --clip 02_01 --frame 120 [-k 10] [--other-clips]
    quatmotion pose search poses.idx --file new.bvh --frame 40

``index`` reads every ``.amc`` and ``.bvh`` file under the given folders (ASF skeletons are
found next to the AMC files, as :func:`quatmotion.io.read_amc` does), resamples clips to
``--fps``, scales every body to ``--height`` cm, describes each pose by the GPD and learns the
metric from the library itself: positive pairs are good transitions labelled by Kovar's
windowed point-cloud distance (:func:`quatmotion.pose.labels.transition_labels`), unlabeled
poses a random sample; RDSR then gives the rank ``--rank`` projection. Every pose is projected
and stored in an HNSW index (hnswlib) in one library file
(:class:`~quatmotion.pose.index.PoseLibrary`).
A library of a single clip has no cross-clip pairs: then consecutive frames serve as the
positive pairs.

``search`` answers with the nearest poses under the learned distance: clip, frame number in the
clip's file, time in seconds and distance.
"""

from __future__ import annotations

import json
import pathlib
import sys
import time
from dataclasses import dataclass
from typing import Annotated, Any

import numpy as np
import typer
from numpy.typing import NDArray

from quatmotion.pose import labels, skeleton16
from quatmotion.pose.data import PoseData
from quatmotion.pose.gpd import GPD
from quatmotion.pose.index import PoseIndex, PoseLibrary
from quatmotion.pose.metric import RDSR

app = typer.Typer(
    name="pose",
    help="Index a motion library's poses and search it under a learned pose distance.",
    no_args_is_help=True,
)

MOTION_SUFFIXES = (".amc", ".bvh")


@dataclass
class LoadedClip:
    """A clip resampled for pose indexing."""

    path: str
    fps: float
    step: int  # file frames per kept frame
    local: NDArray[np.float64]  # (T, 16, 3) body frame, Hip at (0, h, 0), scaled
    world: NDArray[np.float64]  # (T, 16, 3) world, scaled
    poses: PoseData


def find_motion_files(paths: list[pathlib.Path]) -> list[pathlib.Path]:
    """Every ``.amc`` / ``.bvh`` file given or found (recursively) under the given folders.

    Parameters
    ----------
    paths : list of Path
        Files or folders.

    Returns
    -------
    list of Path
        Sorted within each folder, in argument order, without duplicates.

    Raises
    ------
    ValueError
        If a path does not exist or nothing is found.
    """
    found: list[pathlib.Path] = []
    for p in paths:
        if p.is_dir():
            found.extend(sorted(f for f in p.rglob("*") if f.suffix.lower() in MOTION_SUFFIXES))
        elif p.is_file():
            found.append(p)
        else:
            raise ValueError(f"{p} does not exist")
    unique = list(dict.fromkeys(found))
    if not unique:
        raise ValueError(f"no .amc or .bvh files under {', '.join(map(str, paths))}")
    return unique


def read_motion(path: pathlib.Path) -> Any:
    """Read an AMC (its ASF found by :func:`quatmotion.io.find_asf_for_amc`) or a BVH file."""
    from quatmotion import io as qio

    suffix = path.suffix.lower()
    if suffix == ".amc":
        return qio.read_amc(path)
    if suffix == ".bvh":
        read_bvh = getattr(qio, "read_bvh", None)
        if read_bvh is None:
            raise ValueError("this build of quatmotion cannot read BVH files")
        return read_bvh(path)
    raise ValueError(f"{path}: unsupported motion file type {suffix!r} (use .amc or .bvh)")


def load_clip(path: pathlib.Path, fps: float = 30.0, height: float = 170.0) -> LoadedClip:
    """Read a clip, resample it to about ``fps`` and scale the body to ``height`` cm.

    Parameters
    ----------
    path : Path
    fps : float
        Target frame rate (the clip keeps every ``round(file_fps / fps)``-th frame).
    height : float
        Standing height the skeleton is scaled to, centimetres.

    Returns
    -------
    LoadedClip
    """
    motion = read_motion(path)
    step = max(1, int(round(motion.fps / fps)))
    if step > 1:
        motion = motion.slice(step=step)
    scale = skeleton16.height_scale(motion.skeleton, height)
    world = skeleton16.world_positions16(motion) * scale
    local = skeleton16.to_body_frame(world, keep_height=True)
    return LoadedClip(
        str(path), motion.fps, step, local, world, PoseData.from_clip(local, motion.fps)
    )


def build_library(
    clips: list[LoadedClip],
    rank: int = 50,
    n_unlabeled: int = 5000,
    n_pairs: int = 500,
    seed: int = 0,
    M: int = 16,
    ef_construction: int = 100,
    log: Any = None,
) -> PoseLibrary:
    """Learn GPD+RDSR on the clips' own poses, project every pose and index it.

    Parameters
    ----------
    clips : list of LoadedClip
        All at the same frame rate.
    rank : int
        Rank of W (projection dimension).
    n_unlabeled : int
        Unlabeled poses for RDSR's sparse-representation term.
    n_pairs : int
        Positive transition pairs wanted (negatives are not used by RDSR).
    seed : int
    M, ef_construction : int
        HNSW graph parameters.
    log : callable, optional
        Called with progress messages.

    Returns
    -------
    PoseLibrary
    """
    say = log or (lambda _msg: None)
    if not clips:
        raise ValueError("no clips to index")
    fps = clips[0].fps
    rng = np.random.default_rng(seed)
    poses = PoseData.concat([c.poses for c in clips])
    indexer = labels.PoseIndexer(np.array([len(c.local) for c in clips]))
    t0 = time.perf_counter()
    raw = poses.gpd
    say(f"GPD of {len(poses)} poses: {time.perf_counter() - t0:.1f} s")
    positive = np.zeros((0, 2), dtype=np.int64)
    method = "transition pairs (Kovar point-cloud distance)"
    if len(clips) >= 2:
        try:
            pairs, thr = labels.transition_labels(
                [c.local for c in clips],
                [c.world for c in clips],
                fps,
                n_positive=n_pairs,
                n_negative=0,
                n_queries=max(2000, 4 * n_pairs),
                random_state=rng,
            )
            p = pairs.pairs[pairs.labels]
            positive = np.stack([indexer(p[:, 0], p[:, 1]), indexer(p[:, 2], p[:, 3])], axis=1)
            say(f"{len(positive)} positive pairs below {thr[0]:.2f} cm")
        except ValueError as exc:
            say(f"no transition pairs ({exc})")
    if len(positive) < 10:
        method = "consecutive frames"
        starts = indexer.offsets
        within = np.flatnonzero(np.isin(np.arange(len(poses) - 1) + 1, starts, invert=True))
        take = rng.permutation(within)[:n_pairs]
        positive = np.stack([take, take + 1], axis=1)
        if len(positive) == 0:
            raise ValueError("the library needs at least two frames to learn a pose distance")
    unl = rng.permutation(len(poses))[:n_unlabeled]
    normaliser = GPD().fit(raw[np.unique(np.r_[unl, positive.ravel()])])
    X = normaliser.transform(raw)
    rank = min(rank, X.shape[1])
    t0 = time.perf_counter()
    metric = RDSR(n_components=rank, random_state=seed).fit(
        X[unl], np.stack([X[positive[:, 0]], X[positive[:, 1]]], axis=1)
    )
    say(f"RDSR rank {rank}: {time.perf_counter() - t0:.1f} s")
    W = metric.components_.T
    vectors = X @ W
    t0 = time.perf_counter()
    index = PoseIndex(M=M, ef_construction=ef_construction, random_state=seed).fit(vectors)
    say(f"HNSW index of {len(vectors)} poses: {time.perf_counter() - t0:.1f} s")
    frame_of = indexer.frame_of() * np.repeat([c.step for c in clips], indexer.lengths)
    return PoseLibrary(
        index=index,
        clip_names=[c.path for c in clips],
        clip_of=indexer.clip_of(),
        frame_of=frame_of,
        model={"scale": normaliser.scale_, "offset": normaliser.offset_, "W": W},
        meta={
            "fps": fps,
            "file_fps": [c.fps * c.step for c in clips],
            "rank": rank,
            "n_unlabeled": len(unl),
            "n_positive_pairs": len(positive),
            "positive_pairs_from": method,
            "seed": seed,
        },
    )


def _echo(msg: str) -> None:
    typer.echo(msg, err=True)


@app.command("index")
def index_command(
    paths: Annotated[
        list[pathlib.Path],
        typer.Argument(help="Folders (searched recursively) or .amc/.bvh files."),
    ],
    output: Annotated[pathlib.Path, typer.Option("-o", "--output", help="Library file to write.")],
    fps: Annotated[float, typer.Option(help="Frame rate poses are sampled at.")] = 30.0,
    height: Annotated[
        float, typer.Option(help="Body height every skeleton is scaled to, cm.")
    ] = 170.0,
    rank: Annotated[int, typer.Option(help="Dimensions of the learned projection W.")] = 50,
    unlabeled: Annotated[int, typer.Option(help="Unlabeled poses for RDSR.")] = 5000,
    pairs: Annotated[int, typer.Option(help="Positive transition pairs for RDSR.")] = 500,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
) -> None:
    """Learn a pose distance on the library and index every pose of it."""
    try:
        files = find_motion_files(paths)
        clips = []
        for f in files:
            try:
                clips.append(load_clip(f, fps, height))
            except Exception as exc:  # one unreadable file should not stop a library build
                _echo(f"skipping {f}: {exc}")
        _echo(f"read {len(clips)} of {len(files)} clips")
        library = build_library(clips, rank, unlabeled, pairs, seed, log=_echo)
        library.meta["height_cm"] = height
        library.save(output)
    except ValueError as exc:
        _echo(f"error: {exc}")
        raise typer.Exit(code=2) from exc
    _echo(f"wrote {output}: {len(library.clip_of)} poses of {len(library.clip_names)} clips")


@app.command("search")
def search_command(
    library_path: Annotated[
        pathlib.Path, typer.Argument(help="A library written by 'pose index'.")
    ],
    frame: Annotated[int, typer.Option("--frame", "-f", help="Frame number in the clip's file.")],
    clip: Annotated[
        str | None, typer.Option("--clip", "-c", help="Indexed clip: name, file name or number.")
    ] = None,
    file: Annotated[
        pathlib.Path | None, typer.Option("--file", help="Query from a clip not in the library.")
    ] = None,
    k: Annotated[int, typer.Option("-k", help="Number of results.")] = 10,
    other_clips: Annotated[
        bool, typer.Option(help="Leave out results from the query's own clip.")
    ] = False,
    ef: Annotated[int, typer.Option(help="HNSW search breadth (higher: slower, more exact).")] = 64,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
) -> None:
    """Find the poses most like frame F of a clip."""
    try:
        if (clip is None) == (file is None):
            raise ValueError("give exactly one of --clip (an indexed clip) or --file")
        library = PoseLibrary.load(library_path, ef_search=ef)
        if file is not None:
            loaded = load_clip(file, library.meta["fps"], library.meta.get("height_cm", 170.0))
            row = min(max(int(round(frame / loaded.step)), 0), len(loaded.local) - 1)
            query = library.project(loaded.poses[row : row + 1].gpd)
            own_clip = -1
            label = f"{file} frame {row * loaded.step}"
        else:
            item = library.find(clip, frame)
            query = library.index.vectors([item])
            own_clip = int(library.clip_of[item])
            label = f"{library.clip_names[own_clip]} frame {library.frame_of[item]}"
        n_items = library.index.n_items_
        want = min(n_items, k if not other_clips else k + int(np.sum(library.clip_of == own_clip)))
        t0 = time.perf_counter()
        ids, dist = library.search(query, want)
        elapsed = time.perf_counter() - t0
        ids, dist = ids[0], dist[0]
        if other_clips:
            keep = library.clip_of[ids] != own_clip
            ids, dist = ids[keep], dist[keep]
        ids, dist = ids[:k], dist[:k]
    except ValueError as exc:
        _echo(f"error: {exc}")
        raise typer.Exit(code=2) from exc
    file_fps = library.meta.get("file_fps")
    results = []
    for rank_, (i, d) in enumerate(zip(ids, dist, strict=True), start=1):
        c = int(library.clip_of[i])
        f = int(library.frame_of[i])
        seconds = f / file_fps[c] if file_fps else None
        results.append(
            {
                "rank": rank_,
                "clip": library.clip_names[c],
                "frame": f,
                "seconds": seconds,
                "distance": float(d),
            }
        )
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
            str(r["rank"]),
            pathlib.Path(r["clip"]).name,
            str(r["frame"]),
            secs,
            f"{r['distance']:.4g}",
        )
    Console().print(table)
