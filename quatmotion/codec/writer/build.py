""":func:`build_library` (:meth:`quatmotion.codec.Archive.build`): the steps in order (scan, store
the skeletons, plan, fit and code, write); :func:`plan_clip_tasks`, the per-clip tasks and
their shared models on their own (the benchmarks' hook).
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from quatmotion._atomic import output_lock
from quatmotion.codec.methods import get_method
from quatmotion.codec.settings import CompressSettings
from quatmotion.codec.writer.code import ClipTask, clip_tasks
from quatmotion.codec.writer.fit import SharedModels, fit_shared_models
from quatmotion.codec.writer.plan import plan_library
from quatmotion.codec.writer.runner import OnDoubt, Progress, StepRunner
from quatmotion.codec.writer.scan import admit, scan_step
from quatmotion.codec.writer.search import encode_step
from quatmotion.codec.writer.skeleton_table import SkeletonTable
from quatmotion.codec.writer.spool import Job
from quatmotion.codec.writer.write import FileLayout, build_details, clip_entries, write_file
from quatmotion.collection import (
    BuildReport,
)
from quatmotion.parallel import Runner


def build_library(
    sources: Iterable[Any],
    out: str | Path | None,
    settings: CompressSettings | None = None,
    *,
    runner: Runner | None = None,
    progress: Progress | None = None,
    on_doubt: OnDoubt | None = None,
    source_sizes: Sequence[tuple[int, str]] | None = None,
) -> BuildReport:
    """Compress clips into one ``.qmz`` library (:meth:`quatmotion.codec.Archive.build`).

    The caller holds no clip's frames: the clips are scanned in the runner's workers
    (:func:`scan_clip`), the layouts and the shared models are learned on a seeded sample of
    at most ``settings.fit_sample`` clips of each skeleton structure (read here), and every
    clip is read, coded, decoded and repaired in a worker (:func:`code_clip`, the models sent
    to each worker once), its chunk spooled to a temporary file and streamed into the
    container.

    Parameters
    ----------
    sources : iterable
        AMC (with its ASF found by :func:`quatmotion.collection.find_skeleton`) and BVH files,
        folders (searched), motions in memory or :class:`~quatmotion.collection.ClipSource`.
        Clips are named by :func:`quatmotion.collection.unique_names` (two ``take_001`` in
        ``s1/`` and ``s2/`` are ``s1/take_001`` and ``s2/take_001``).
    out : str or Path or None
        Where to write the file (atomically). None: only the bytes, in
        ``report.details["data"]``.
    settings : CompressSettings, optional
        How (stored in the file). Default: every joint within 1 cm with ``best``.
    runner : Runner, optional
        Where the per-clip jobs (scan, encode, decode, repair) run (default
        :meth:`Runner.resolve`: a local pool, or ``QUATMOTION_SCHEDULER``). The shared models
        are learned here and the file is assembled here: every scheduler and number of
        workers gives the same bytes.
    progress : callable, optional
        ``progress(step_name, done, total)``.
    on_doubt : callable, optional
        ``on_doubt(file, doubt)`` as each doubtful clip is read (they are also in
        ``report.doubts``).
    source_sizes : sequence of (int, str), optional
        For clips given in memory, the size and format of the files they came from.

    Returns
    -------
    BuildReport
        ``added`` the clips' references; ``failures`` the inputs left out (``on_error="skip"``);
        ``details`` the per-clip sizes and errors (``clip_errors``, ``clip_bytes``,
        ``source_bytes``, ``raw_bytes``, ``quality``, ``seconds``) and, when ``out`` is None,
        the bytes (``data``).

    Raises
    ------
    ValueError
        Clips without frames, a skeleton that cannot be stored exactly, nothing to compress.
        No file is written then.
    FormatError
        A malformed input file (naming it), with ``on_error="raise"``.
    """
    lock = contextlib.nullcontext() if out is None else output_lock(out)
    with lock:  # two builds of one file: the second is refused, not silently overwritten
        return _build_library(
            sources, out, settings, runner, progress, on_doubt, source_sizes
        )  # fmt: skip


def _build_library(
    sources: Iterable[Any],
    out: str | Path | None,
    settings: CompressSettings | None,
    runner: Runner | None,
    progress: Progress | None,
    on_doubt: OnDoubt | None,
    source_sizes: Sequence[tuple[int, str]] | None,
) -> BuildReport:
    t0 = time.perf_counter()
    settings = settings or CompressSettings()
    report = progress or (lambda *_: None)
    codec = get_method(settings.method)
    skip = settings.on_error == "skip"
    runner_ = StepRunner(runner, report)
    # 1. scan (in the workers)
    inputs = scan_step(sources, settings, skip, source_sizes, on_doubt, runner_)
    # 2. store the skeletons
    table = SkeletonTable()
    admit(inputs, table, skip)
    clip_skeleton = [table.index(s.skeleton) for s in inputs.scans]
    # 3. plan: layouts, the sample read and the layouts fitted on it
    plan = plan_library(inputs, [], settings, settings.bound_on == "vertices", report)
    layout = FileLayout(
        codec.name, settings, table, [table.index(info.skeleton) for info in plan.sample.layouts],
        table.new_records, [], [],
    )  # fmt: skip
    # 4. fit the shared models, code every clip in a worker (encode, verify, repair)
    job = Job(codec, inputs, plan, settings, runner_)
    q, coded = encode_step(job, lambda c: layout.file_size(inputs, plan, clip_skeleton, c))
    # 5. assemble and write, the clips' chunks streamed from the spool
    try:
        path = None if out is None else Path(out)
        entries = clip_entries(inputs, plan, clip_skeleton, coded.errors)
        data = write_file(path, layout, entries, layout.layout_chunks(plan, coded), coded.chunks())
        details = build_details(data, codec.name, inputs, coded, t0, q)
    finally:
        coded.close()
    report("done", len(inputs.scans), len(inputs.scans))
    return BuildReport(
        path=path,
        added=inputs.refs,
        failures=inputs.failures,
        doubts=inputs.doubts,
        settings=settings,
        details=details,
    )


def plan_clip_tasks(
    sources: Iterable[Any],
    settings: CompressSettings | None = None,
    *,
    runner: Runner | None = None,
) -> tuple[list[ClipTask], SharedModels]:
    """The per-clip tasks ``compress`` hands to :mod:`quatmotion.parallel` and their shared
    models, at the method's default quality with verification: ``code_clip`` over them with
    the models as context is the batch step on its own (the benchmarks' hook)."""
    settings = settings or CompressSettings()
    method = get_method(settings.method)
    runner_ = StepRunner(runner, lambda *_: None)
    inputs = scan_step(sources, settings, False, None, None, runner_)
    admit(inputs, SkeletonTable(), False)
    plan = plan_library(inputs, [], settings, settings.bound_on == "vertices", lambda *_: None)
    q = settings.quality if settings.quality is not None else method.default_quality
    models, _ = fit_shared_models(method, plan, q, settings.max_error, settings.seed, settings.read)
    return clip_tasks(inputs, plan, verify=True), models
