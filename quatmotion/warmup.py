"""Compile every cached Numba kernel of quatmotion once: ``quatmotion warm-up``.

Numba compiles a kernel the first time it is called with given argument types and keeps the
machine code in its cache (:mod:`quatmotion._jit` says where); later processes load it from
there. On a cold cache every worker of a pool compiles every kernel it runs on its own, all at
once. The warm-up compiles them once, in this process, by running the real code on a tiny
generated library, so that the argument types are those of real use (docs/performance.md has
the cold and warm times).

Conventions
-----------
* The work is split into *groups* (:data:`GROUPS`), each the kernels of one kind of command:
  reading files and kinematics, compression, retrieval, pose search. A command warms the
  groups it uses (:func:`stale_groups`, then :func:`warm_up`), before it starts a pool.
* A group is *warm* when its stamp file, written after it ran, holds the current
  :func:`cache_key`: the Python, Numba and CPU, and the source of every module with cached
  kernels. A changed kernel module makes every group stale; running it again then loads the
  unchanged kernels from the cache and compiles the rest.
* Everything runs in this process, one item at a time, in a temporary folder removed after.
"""

from __future__ import annotations

import hashlib
import importlib
import json
import os
import platform
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from quatmotion import _jit
from quatmotion._atomic import atomic_write_text

__all__ = [
    "GROUPS",
    "KERNEL_MODULES",
    "GroupReport",
    "cache_key",
    "cached_kernels",
    "stale_groups",
    "warm_up",
]

KERNEL_MODULES: tuple[str, ...] = (
    "quatmotion.quat.jit",
    "quatmotion.motion.kinematics",
    "quatmotion.io._text",
    "quatmotion.sparse._kernels",
    "quatmotion.sparse._linear_kernels",
    "quatmotion.codec.channels",
    "quatmotion.codec.entropy",
    "quatmotion.codec.rans",
    "quatmotion.codec._decode_kernels",
    "quatmotion.runtime._kernels",
    "quatmotion.codec.spline",
    "quatmotion.codec.methods.spline",
    "quatmotion.retrieval._kernels",
    "quatmotion.pose.gpd",
    "quatmotion.pose.labels",
    "quatmotion.pose.metric",
)
"""Every module defining a ``cache=True`` kernel (a test keeps the list complete)."""

GROUPS: dict[str, str] = {
    "read": "reading files and kinematics",
    "codec": "compression and decompression (best, spline, naive)",
    "learn": "QSSD and K-SVD: learning, codecs, clip features",
    "retrieval": "clip index and search by motion features",
    "pose": "pose index and search (both distances)",
}
"""Group name -> what it compiles, in the order :func:`warm_up` runs them."""


@dataclass(frozen=True)
class GroupReport:
    """One group's warm-up: seconds, and kernel signatures compiled or loaded from the cache."""

    group: str
    seconds: float
    compiled: int
    loaded: int


@dataclass
class _Workspace:
    """The tiny library the groups run on, written once in a temporary folder."""

    folder: Path
    files: list[Path] = field(default_factory=list)


def cache_key() -> str:
    """What the compiled kernels depend on: interpreter, Numba, CPU, the kernels' sources."""
    import llvmlite.binding as llvm
    import numba

    digest = hashlib.sha256()
    for part in (sys.version, numba.__version__, platform.machine(), llvm.get_host_cpu_name()):
        digest.update(part.encode() + b"\0")
    for name in KERNEL_MODULES:  # read as files: importing them would cost a batch command
        source = _jit.PACKAGE_DIR.joinpath(*name.split(".")[1:]).with_suffix(".py")
        digest.update(name.encode() + b"\0" + source.read_bytes())
    return digest.hexdigest()


def _stamp(group: str) -> Path:
    """Where a group's stamp lives: in the cache folder, so it goes when the cache goes."""
    folder = os.environ.get(_jit.CACHE_ENV)
    base = Path(folder) if folder else _jit.PACKAGE_DIR / "__pycache__"
    return base / f"quatmotion-warm-{group}.json"


def stale_groups(groups: Iterable[str] = GROUPS) -> list[str]:
    """The groups among ``groups`` whose kernels may not be in the cache (see the module)."""
    key = cache_key()
    out = []
    for group in groups:
        if group not in GROUPS:
            raise ValueError(f"unknown warm-up group {group!r}; choose from {', '.join(GROUPS)}")
        try:
            stamp = json.loads(_stamp(group).read_text())
        except (OSError, ValueError):
            stamp = {}
        if stamp.get("key") != key:
            out.append(group)
    return out


def cached_kernels() -> list[Any]:
    """Every cached Numba dispatcher of :data:`KERNEL_MODULES` (importing them)."""
    from numba.core.dispatcher import Dispatcher

    out = []
    for name in KERNEL_MODULES:
        module = importlib.import_module(name)
        for value in vars(module).values():
            if (
                isinstance(value, Dispatcher)
                and value.py_func.__module__ == name
                and type(value._cache).__name__ != "NullCache"
            ):
                out.append(value)
    return out


def _counts(kernels: Sequence[Any]) -> tuple[int, int]:
    """Signatures compiled and loaded from the cache so far, summed over ``kernels``."""
    compiled = loaded = 0
    for kernel in kernels:
        stats = kernel.stats
        compiled += sum(stats.cache_misses.values())
        loaded += sum(stats.cache_hits.values())
    return compiled, loaded


def warm_up(
    groups: Iterable[str] = GROUPS,
    *,
    report: Callable[[GroupReport], None] | None = None,
    workers: int | None = None,
) -> list[GroupReport]:
    """Compile (or load) the kernels of ``groups`` and stamp each group warm.

    ``read`` (the kernels every group runs) goes first, in this process; the other groups
    then compile side by side, one per worker process, longest first: they share few kernels,
    and Numba compiles one kernel at a time in a process.

    Parameters
    ----------
    groups : iterable of str
        Keys of :data:`GROUPS` (default all).
    report : callable, optional
        Called with each group's :class:`GroupReport` as it finishes (in the order of
        :data:`GROUPS` for those run here, then longest first).
    workers : int, optional
        Processes compiling groups at once (default: the CPUs available); 1 runs every group
        in this process.

    Returns
    -------
    list of GroupReport
        One per group asked for.
    """
    from quatmotion.parallel import available_cpus, run_batch

    wanted = [g for g in GROUPS if g in set(groups)]
    unknown = set(groups) - set(GROUPS)
    if unknown:
        raise ValueError(
            f"unknown warm-up groups {sorted(unknown)}; choose from {', '.join(GROUPS)}"
        )
    n = available_cpus() if workers is None else workers
    side_by_side = [g for g in _LONGEST_FIRST if g in wanted and g != "read"] if n > 1 else []
    if len(side_by_side) < 2:
        side_by_side = []
    here = [g for g in GROUPS if g in wanted and g not in side_by_side]
    if side_by_side and "read" not in here:
        here.insert(0, "read")  # every group reads clips: compiled once, before the workers
    key = cache_key()
    reports = []

    def finished(done: GroupReport) -> None:
        _write_stamp(done.group, key, done)
        if done.group in wanted:
            reports.append(done)
            if report is not None:
                report(done)

    with tempfile.TemporaryDirectory(prefix="quatmotion-warm-up-") as folder:
        kernels = cached_kernels()
        start = time.perf_counter()
        files = _write_library(Path(folder))  # forward kinematics: counted in the first group
        setup = (time.perf_counter() - start, *_counts(kernels))
        for group in here:
            done = _run_group((group, folder, files))
            if group == here[0]:
                done = GroupReport(
                    group, done.seconds + setup[0], done.compiled + setup[1], done.loaded + setup[2]
                )
            finished(done)
        if side_by_side:
            jobs = [(group, folder, files) for group in side_by_side]
            result = run_batch(_run_group, jobs, workers=min(n, len(jobs)))
            if result.failures:
                failure = result.failures[0]
                raise RuntimeError(f"warm-up of {failure.item[0]!r} failed: {failure.message}")
            for done in result.results:
                assert done is not None
                finished(done)
    return reports


# The groups run side by side, longest first (measured cold: learn far the longest).
_LONGEST_FIRST = ("learn", "pose", "codec", "retrieval", "read")


def _run_group(job: tuple[str, str, tuple[str, ...]]) -> GroupReport:
    """Run one group on the library in ``folder`` (a batch job: module level)."""
    group, folder, files = job
    kernels = cached_kernels()
    before = _counts(kernels)
    start = time.perf_counter()
    _RUNNERS[group](_Workspace(Path(folder), [Path(f) for f in files]))
    after = _counts(kernels)
    return GroupReport(
        group, time.perf_counter() - start, after[0] - before[0], after[1] - before[1]
    )


def _write_stamp(group: str, key: str, done: GroupReport) -> None:
    path = _stamp(group)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, json.dumps({"key": key, "seconds": round(done.seconds, 2)}))
    except OSError:
        pass  # no writable cache: Numba keeps nothing either, and the next run warms up again


# --- the work of each group, on a tiny library ------------------------------------------------


def _write_library(folder: Path) -> tuple[str, ...]:
    """Three short generated clips in ``folder``: two as BVH, one as AMC with its ASF."""
    from quatmotion.io import write_asf, write_motion
    from quatmotion.synthetic import generate_clip

    files = []
    for k, kind in enumerate(("walk", "jump", "squat")):
        motion = generate_clip(kind, seed=k, n_frames=60, fps=30.0)
        if kind == "squat":
            path = folder / f"{kind}.amc"
            write_asf(motion.skeleton, path.with_suffix(".asf"))
        else:
            path = folder / f"{kind}.bvh"
        write_motion(motion, path)
        files.append(str(path))
    return tuple(files)


def _read(space: _Workspace) -> None:
    from quatmotion.io import read_motion
    from quatmotion.motion import forward_kinematics

    for path in space.files:
        forward_kinematics(read_motion(path))


def _learn(space: _Workspace) -> None:
    import numpy as np

    from quatmotion.io import read_motion
    from quatmotion.motion import angular_displacements
    from quatmotion.pose.labels import dtw_path
    from quatmotion.sparse import KSVD, QSSD
    from quatmotion.sparse._common import rank1

    bvh = [p for p in space.files if p.suffix == ".bvh"]
    Y = np.concatenate([angular_displacements(read_motion(p), step=2) for p in bvh])
    # Besides the defaults: the safeguarded atom update, and more atoms than ten samples use
    # (unused atoms are re-seeded): paths with kernels of their own.
    runs = (
        (QSSD, Y, {}),
        (QSSD, Y, {"safeguard": True}),
        (QSSD, Y[:10], {"sparsity": 1}),
        (KSVD, Y, {}),
    )
    for cls, samples, options in runs:
        settings = {"n_atoms": 24, "sparsity": 3, "max_iter": 2, "random_state": 0, **options}
        model = cls(**settings).fit(samples)
        model.inverse_transform(model.transform(samples))
    rng = np.random.default_rng(0)
    rank1(rng.standard_normal((400, 120)), rng.standard_normal(120))  # a large one: a kernel
    dtw_path(Y[:20].reshape(20, -1), Y[5:30].reshape(25, -1))
    _compress(space, _DICTIONARY_CODECS)
    _index_and_search(space, ("qssd", "ksvd"))  # the clip index's dictionary features


def _compress(space: _Workspace, methods: Iterable[str]) -> None:
    from quatmotion.codec import Archive, CompressSettings
    from quatmotion.parallel import Runner

    for method in methods:
        out = space.folder / f"{method}.qmz"
        settings = CompressSettings(max_error=1.0, method=method)
        Archive.build(space.files, out, settings, runner=Runner.inline())
        with Archive.open(out) as library:
            for name in library.names():
                library.read(name)
                library.read_rotations(name)  # the whole clip from its rows, one call
                library.sample(name, [0.0, 0.01])
                sampler = library.sampler(name)  # one pose per call, and a batch
                sampler.pose(0.0)
                sampler.poses([0.0, 0.01])


def _codec(space: _Workspace) -> None:
    from quatmotion.codec import METHODS

    _compress(space, [m for m in METHODS if m not in _DICTIONARY_CODECS])


_DICTIONARY_CODECS = ("qssd", "ksvd")


def _index_and_search(space: _Workspace, kinds: tuple[str, ...]) -> None:
    """Index the clips with feature ``kinds``, then search with every method they serve."""
    from quatmotion.io import read_motion
    from quatmotion.parallel import Runner
    from quatmotion.retrieval import METHODS, ClipIndex, IndexSettings, search_within
    from quatmotion.retrieval.search import search

    out = space.folder / f"clips-{'-'.join(kinds)}.qidx"
    ClipIndex.build(space.files, out, IndexSettings(kinds=kinds), runner=Runner.inline())
    query = read_motion(space.files[0])
    with ClipIndex.open(out) as index:
        for method in METHODS:
            if set(METHODS[method].kinds) <= set(kinds):
                search(index, query, method=method, k=2)
        if "motion" in kinds:
            search_within(index, query, k=2)


def _retrieval(space: _Workspace) -> None:
    # Motion features only, the default method's (what `quatmotion serve` builds); the
    # dictionary features are the learn group's.
    _index_and_search(space, ("motion",))


def _pose(space: _Workspace) -> None:
    import functools

    from quatmotion.io import read_motion
    from quatmotion.parallel import Runner
    from quatmotion.pose.library import METRICS, PoseLibrary, PoseSettings, load_pose_clip

    load = functools.partial(load_pose_clip, fps=15.0, height=170.0)
    query = read_motion(space.files[0])
    for metric in METRICS:
        settings = PoseSettings(fit_poses=200, rank=8, n_unlabeled=100, n_pairs=20, metric=metric)
        library, _ = PoseLibrary.build_streamed(space.files, load, settings, runner=Runner.inline())
        vector, clip, _ = library.pose_query(0, 10)
        library.nearest(vector, k=3, exclude_clip=clip)
        library.nearest(library.motion_query(query, 10)[0], k=3)


_RUNNERS: dict[str, Callable[[_Workspace], None]] = {
    "read": _read,
    "codec": _codec,
    "learn": _learn,
    "retrieval": _retrieval,
    "pose": _pose,
}
