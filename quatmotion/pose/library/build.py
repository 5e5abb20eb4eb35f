"""A pose library's build in bounded memory, as named steps: :func:`draw_sample` (a seeded
sample of clips; step 1, the distance learned on it by
:func:`~quatmotion.pose.library.learn.learn_projection` and the transition judge by
:func:`~quatmotion.pose.library.transitions.learn_transitions`), :func:`index_pass` (step 2:
every clip prepared and projected in batch workers) into a :class:`Graph` (the HNSW graph grown
in input order) and a :class:`Catalogue` (what the library records of each clip).
:func:`build_fields` runs them all and returns the library's fields; :func:`index_more` runs
step 2 for clips added to a library. Where each batch runs is the caller's
:class:`~quatmotion.parallel.Runner`.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quatmotion.io import Doubt
from quatmotion.parallel import Failure, Runner
from quatmotion.pose import labels
from quatmotion.pose.data import PoseClip
from quatmotion.pose.index import HNSWIndex
from quatmotion.pose.library.clips import ProjectedClip, projected_clip
from quatmotion.pose.library.learn import learn_projection
from quatmotion.pose.library.settings import PoseSettings
from quatmotion.pose.library.transitions import learn_transitions

__all__ = [
    "Catalogue",
    "Graph",
    "as_given",
    "build_fields",
    "draw_sample",
    "index_more",
    "index_pass",
    "learn_model",
    "none_read",
]

FloatArray = NDArray[np.float64]


def build_fields(
    sources: Sequence[Any],
    load: Callable[[Any], PoseClip],
    settings: PoseSettings,
    *,
    runner: Runner,
    progress: Callable[[str, int, int], None] | None = None,
    log: Callable[[str], None] | None = None,
    on_doubt: Callable[[str, Doubt], None] | None = None,
    estimator: Any = None,
) -> tuple[dict[str, Any], list[Failure]]:
    """The fields of the library of ``sources`` and the clips that failed, in input order
    (:meth:`quatmotion.pose.library.PoseLibrary.build_streamed` says what each parameter is;
    ``settings`` are trusted: :class:`PoseSettings` checked them)."""
    say = log or (lambda _msg: None)
    sources = list(sources)
    if not sources:
        raise ValueError("no clips to index")
    stage = _stages(progress)
    sample = draw_sample(sources, load, settings.fit_poses, settings.seed, runner, stage("learn"))
    say(f"learning the distance on {len(sample.clips)} clips ({sample.n_poses} poses)")
    model, meta = learn_model(sample.clips, settings, estimator=estimator, say=say)
    fps, height = sample.clips[0].fps, sample.clips[0].height
    failed = sample.failed
    kept = [i for i in range(len(sources)) if i not in failed]
    index = HNSWIndex(
        M=settings.M, ef_construction=settings.ef_construction,
        n_threads=settings.index_threads, random_state=settings.seed,
    )  # fmt: skip
    capacity = int(1.05 * sample.n_poses / len(sample.clips) * len(kept))
    graph = Graph(index, flush_poses=settings.flush_poses, capacity=capacity)
    meta = {**meta, "fit_clips": len(sample.clips), "fit_poses": sample.n_poses}
    del sample
    t0 = time.perf_counter()
    catalogue = index_pass(
        sources, kept, load, model, fps=fps, height=height, graph=graph, failed=failed,
        chunk_size=settings.chunk_size, runner=runner, progress=stage("index"),
        on_doubt=on_doubt, metric=meta["metric"],
    )  # fmt: skip
    index = graph.close()
    if not catalogue.names:
        raise ValueError(none_read(len(sources), failed))
    seconds = time.perf_counter() - t0
    say(f"indexed {index.n_items_} poses of {len(catalogue.names)} clips: {seconds:.1f} s")
    fields = {"index": index, "model": model, **catalogue.library_fields(fps, meta)}
    return fields, [failed[i] for i in sorted(failed)]


def learn_model(
    clips: Sequence[PoseClip],
    settings: PoseSettings,
    *,
    estimator: Any = None,
    say: Callable[[str], None],
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Step 1 of the build on the sample's ``clips``: the distance's projection
    (:func:`~quatmotion.pose.library.learn.learn_projection`) and the transition judge
    (:func:`~quatmotion.pose.library.transitions.learn_transitions`, on the same poses), as the
    library's ``model`` arrays and what its ``meta`` records of them."""
    model, meta, poses = learn_projection(clips, settings, estimator=estimator, say=say)
    judge, judged = learn_transitions(
        clips, n_pairs=settings.n_pairs, n_unlabeled=settings.n_unlabeled, seed=settings.seed,
        say=say, poses=poses,
    )  # fmt: skip
    return {**model, **judge}, {**meta, **judged}


def index_more(
    index: HNSWIndex,
    model: dict[str, Any],
    meta: dict[str, Any],
    n_clips: int,
    sources: list[Any],
    load: Callable[[Any], PoseClip],
    settings: PoseSettings,
    *,
    runner: Runner,
    progress: Callable[[str, int, int], None] | None,
    on_doubt: Callable[[str, Doubt], None] | None,
) -> tuple[Catalogue, dict[int, Failure]]:
    """Step 2 of the build for clips added to a library of ``n_clips`` clips: each projected
    with the stored ``model`` into the stored graph ``index``; the clips indexed and those
    that failed (by position in ``sources``)."""
    failed: dict[int, Failure] = {}
    capacity = index.n_items_ * (n_clips + len(sources)) // max(1, n_clips)
    graph = Graph(index, flush_poses=settings.flush_poses, capacity=capacity)
    catalogue = index_pass(
        sources, list(range(len(sources))), load, model, fps=meta["fps"],
        height=meta["height_cm"], graph=graph, failed=failed, chunk_size=settings.chunk_size,
        runner=runner, progress=_stages(progress)("index"), on_doubt=on_doubt,
        metric=str(meta.get("metric", "GPD+RDSR")),
    )  # fmt: skip
    graph.close()
    if not catalogue.names:
        raise ValueError(none_read(len(sources), failed))
    return catalogue, failed


def _stages(
    progress: Callable[[str, int, int], None] | None,
) -> Callable[[str], Callable[[int, int], None] | None]:
    """``stage(name)``: the ``progress(done, total)`` of one stage of ``progress(stage, done,
    total)``."""

    def stage(name: str) -> Callable[[int, int], None] | None:
        return None if progress is None else functools.partial(progress, name)

    return stage


def as_given(clip: PoseClip) -> PoseClip:
    """The ``load`` of an in-memory build: the clips are already prepared."""
    return clip


@dataclass
class _Sample:
    """The clips the distance is learned on, in input order, and the clips that failed."""

    clips: list[PoseClip]
    failed: dict[int, Failure]
    n_poses: int


def draw_sample(
    sources: list[Any],
    load: Callable[[Any], PoseClip],
    fit_poses: int,
    seed: int,
    runner: Runner,
    progress: Callable[[int, int], None] | None,
) -> _Sample:
    """Step 1 of the build: clips loaded in a seeded order until they hold ``fit_poses``
    poses (at least two clips), returned in input order."""
    order = np.random.default_rng([seed, len(sources)]).permutation(len(sources))
    failed: dict[int, Failure] = {}
    drawn: list[tuple[int, PoseClip]] = []
    n_poses = 0
    with runner.map(load, [sources[i] for i in order], progress=progress) as stream:
        for outcome in stream:
            where = int(order[outcome.index])
            if outcome.failure is not None:
                failed[where] = dataclasses.replace(outcome.failure, index=where)
                continue
            drawn.append((where, outcome.value))
            n_poses += len(outcome.value)
            if n_poses >= fit_poses and len(drawn) >= 2:
                break
    if not drawn:
        raise ValueError(none_read(len(sources), failed))
    drawn.sort(key=lambda pair: pair[0])
    return _Sample([clip for _, clip in drawn], failed, n_poses)


class Graph:
    """The HNSW graph filled in input order, ``flush_poses`` vectors per insertion (with one
    thread the graph is a function of the vectors and the chunking alone)."""

    def __init__(self, index: HNSWIndex, *, flush_poses: int, capacity: int) -> None:
        self.index, self.flush_poses, self.capacity = index, flush_poses, capacity
        self._pending: list[NDArray[np.float32]] = []
        self._n_pending = 0

    def add(self, vectors: NDArray[np.float32]) -> None:
        self._pending.append(vectors)
        self._n_pending += len(vectors)
        if self._n_pending >= self.flush_poses:
            self._flush()

    def _flush(self) -> None:
        self.index.partial_fit(np.concatenate(self._pending), capacity=self.capacity)
        self._pending, self._n_pending = [], 0

    def close(self) -> HNSWIndex:
        if self._pending:
            self._flush()
        return self.index


@dataclass
class Catalogue:
    """What the library records of each indexed clip, in input order."""

    names: list[str] = field(default_factory=list)
    lengths: list[int] = field(default_factory=list)
    steps: list[int] = field(default_factory=list)
    file_frames: list[int | None] = field(default_factory=list)
    kinds: set[str] = field(default_factory=set)
    rows: list[NDArray[np.float32]] = field(default_factory=list)

    def add(self, clip: ProjectedClip) -> None:
        if clip.rows is not None:
            self.rows.append(clip.rows)
        self.names.append(clip.name)
        self.lengths.append(len(clip.vectors))
        self.steps.append(clip.step)
        self.file_frames.append(clip.file_frames)
        self.kinds.update([clip.skeleton_kind] if clip.skeleton_kind else [])

    def library_fields(self, fps: float, meta: dict[str, Any]) -> dict[str, Any]:
        """The :class:`PoseLibrary` fields of the clips (the model and index apart)."""
        offsets = labels.ClipOffsets(np.array(self.lengths))
        return {
            "pose_rows": np.concatenate(self.rows) if self.rows else None,
            "clip_names": self.names,
            "clip_of": offsets.clip_of(),
            "frame_of": offsets.frame_of() * np.repeat(self.steps, offsets.lengths),
            "meta": {
                **meta,
                "file_fps": [fps * s for s in self.steps],
                "file_frames": self.file_frames,
                "skeletons": sorted(self.kinds),
            },
        }


def index_pass(
    sources: list[Any],
    kept: list[int],
    load: Callable[[Any], PoseClip],
    model: dict[str, FloatArray],
    *,
    fps: float,
    height: float,
    graph: Graph,
    failed: dict[int, Failure],
    chunk_size: int | None,
    runner: Runner,
    progress: Callable[[int, int], None] | None,
    on_doubt: Callable[[str, Doubt], None] | None,
    metric: str,
) -> Catalogue:
    """Step 2 of the build: every clip loaded and projected in a worker, its vectors inserted
    in input order; failures (and clips prepared at another rate) added to ``failed``."""
    job = functools.partial(projected_clip, load=load, model=model, metric=metric)
    if chunk_size is None:
        chunk_size = 8 if len(kept) >= 64 else 1
    catalogue = Catalogue()
    items = [sources[i] for i in kept]
    runner = dataclasses.replace(runner, chunk_size=chunk_size)
    with runner.map(job, items, progress=progress) as stream:
        for outcome in stream:
            where = kept[outcome.index]
            if outcome.failure is not None:
                failed[where] = dataclasses.replace(outcome.failure, index=where)
                continue
            clip = outcome.value
            if clip.fps != fps or clip.height != height:
                message = (
                    f"prepared at {clip.fps:g} fps and height {clip.height}, the library at "
                    f"{fps:g} fps and height {height} (its file rate is no multiple of it)"
                )
                failed[where] = Failure(where, sources[where], message)
                continue
            for doubt in clip.doubts if on_doubt is not None else ():
                on_doubt(clip.name, doubt)
            catalogue.add(clip)
            graph.add(clip.vectors)
    return catalogue


def none_read(n_sources: int, failed: dict[int, Failure]) -> str:
    """The error when every clip failed: its distinct reasons (a few), in input order."""
    reasons = list(dict.fromkeys(str(failed[i]) for i in sorted(failed)))
    more = f"; and {len(reasons) - 3} other reasons" if len(reasons) > 3 else ""
    return f"none of the {n_sources} clips could be read: {'; '.join(reasons[:3])}{more}"
