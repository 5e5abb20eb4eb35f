""":func:`add_to_library` (:meth:`quatmotion.codec.Archive.add`): clips added to an existing
file, the clips already in it copied byte for byte (from an older format version, re-coded
without loss), the new ones coded with the file's method
and, where their skeleton structure is known, its models.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from quatmotion._atomic import output_lock
from quatmotion.codec.archive import ArchiveReader
from quatmotion.codec.container import (
    ClipEntry,
)
from quatmotion.codec.methods import get_method
from quatmotion.codec.settings import CompressSettings
from quatmotion.codec.writer.plan import plan_library
from quatmotion.codec.writer.runner import OnDoubt, Progress, StepRunner
from quatmotion.codec.writer.scan import admit, scan_step
from quatmotion.codec.writer.skeleton_table import SkeletonTable
from quatmotion.codec.writer.spool import Job
from quatmotion.codec.writer.write import FileLayout, build_details, clip_entries, write_file
from quatmotion.collection import (
    BuildReport,
    ClipRef,
)
from quatmotion.parallel import Runner


def add_to_library(
    path: str | Path,
    sources: Iterable[Any],
    settings: CompressSettings | None = None,
    *,
    runner: Runner | None = None,
    progress: Progress | None = None,
    on_doubt: OnDoubt | None = None,
) -> BuildReport:
    """Add clips to an existing ``.qmz`` file, rewritten atomically (:meth:`Archive.add`).

    The clips already in the file keep their chunks byte for byte (streamed from the old
    file); the new ones are coded with the file's method, with its library models where their
    skeleton structure is known, and with ``settings`` (default: the file's own, else
    :class:`CompressSettings`; the method is always the file's). A clip whose content hash the
    file already holds is skipped (in ``report.skipped``); a new clip whose name the file
    holds is an error. The file keeps the settings it was made with. A file of an older format
    version is rewritten in the current one (its clips re-coded without loss by their method:
    :meth:`ArchiveReader.clip_payloads`). Another writer of ``path`` at the same time is refused
    (:func:`quatmotion._atomic.output_lock`).
    """
    with output_lock(path):  # read, code and rewrite: no other writer between
        return _add_to_library(Path(path), sources, settings, runner, progress, on_doubt)


def _add_to_library(
    path: Path,
    sources: Iterable[Any],
    settings: CompressSettings | None,
    runner: Runner | None,
    progress: Progress | None,
    on_doubt: OnDoubt | None,
) -> BuildReport:
    from dataclasses import replace

    t0 = time.perf_counter()
    report = progress or (lambda *_: None)
    with ArchiveReader.open(path) as archive:
        old = archive.header
        settings = settings or archive.settings or CompressSettings()
        settings = settings.replace(method=old.method)
        stored = archive.settings or settings
        old_refs = archive.clips()
        table = SkeletonTable(
            list(old.records),
            [archive.record_text(k) for k in range(len(old.records))],
            list(old.skeletons),
            [archive.skeleton(k) for k in range(len(old.skeletons))],
        )
        layouts = [archive.layout(k) for k in range(len(old.layouts))]
        old_records, old_layout_chunks = archive.shared_payloads()
    runner_ = StepRunner(runner, report)
    inputs = scan_step(sources, settings, False, None, on_doubt, runner_)
    known = {r.sha256: r for r in old_refs}
    skipped = [known[r.sha256] for r in inputs.refs if r.sha256 in known]
    inputs.select([i for i, r in enumerate(inputs.refs) if r.sha256 not in known])
    for i, scan in enumerate(inputs.scans):
        ref = _name_apart(scan.ref, old_refs, path)
        inputs.scans[i] = replace(scan, ref=ref, name=ref.name)
    if not inputs.scans:
        return BuildReport(path=path, skipped=skipped, settings=stored, details={})
    codec = get_method(old.method)
    admit(inputs, table, False)
    clip_skeleton = [table.index(s.skeleton) for s in inputs.scans]
    plan = plan_library(inputs, layouts, settings, False, report)
    n_old = len(layouts)
    layout_skeletons = [lay.skeleton for lay in old.layouts] + [
        table.index(info.skeleton) for info in plan.sample.layouts[n_old:]
    ]
    q = settings.quality if settings.quality is not None else codec.default_quality
    job = Job(codec, inputs, plan, settings, runner_)
    coded = job.encode(q, settings.max_error, verify=True)
    old_entries = [
        entry if entry.ref is not None else _with_ref(entry, ref)
        for entry, ref in zip(old.clips, old_refs, strict=True)
    ]
    layout = FileLayout(
        old.method, stored, table, layout_skeletons, old_records + table.new_records,
        old_layout_chunks, old_entries, n_old,
    )  # fmt: skip
    try:
        entries = clip_entries(inputs, plan, clip_skeleton, coded.errors)
        with ArchiveReader.open(path) as archive:
            chunks = itertools.chain(archive.clip_payloads(), coded.chunks())
            write_file(path, layout, entries, layout.layout_chunks(plan, coded), chunks)
        details = build_details(None, codec.name, inputs, coded, t0, q)
    finally:
        coded.close()
    return BuildReport(
        path=path,
        added=inputs.refs,
        skipped=skipped,
        doubts=inputs.doubts,
        settings=stored,
        details=details,
    )


def _name_apart(ref: ClipRef, old: Sequence[ClipRef], path: Path) -> ClipRef:
    """A new clip's reference named apart from the file's clips (the collection's rule:
    :func:`~quatmotion.collection.name_apart`)."""
    from quatmotion.collection import name_apart

    return name_apart(ref, old, path)


def _with_ref(entry: ClipEntry, ref: ClipRef) -> ClipEntry:
    from dataclasses import replace

    return replace(entry, ref=ref)
