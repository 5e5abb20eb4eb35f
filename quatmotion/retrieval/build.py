"""Building and extending a clip index: one pure per-clip feature function mapped over the
clips, one writer committing in batches.

The build is a few named steps (:func:`build`): find the sources
(:func:`quatmotion.collection.find_clips`: unique names, ASF lookup, content hashes), open or
resume the index, plan (clips already there skipped, names kept unique across old and new
clips), compute the features of the others (:func:`index_clip`, mapped by
:mod:`quatmotion.parallel` over a local process pool or a Dask cluster; results in input order),
write them in transactions of ``settings.batch`` clips, and apply labels to every clip, new or
already there. So the index holds the same rows whatever ran the jobs, a killed build keeps
every batch already committed, and the next build skips those clips (same path and content
hash) and says it resumed.
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from quatmotion.collection import (
    BuildReport,
    ClipSource,
    ReadSettings,
    find_clips,
    label_sources,
    match_keys,
    read_clip,
    unique_names,
)
from quatmotion.collection.refs import named_for_file
from quatmotion.io import Doubt
from quatmotion.io.labels import read_labels_csv
from quatmotion.parallel import Failure, Runner, Scheduler
from quatmotion.retrieval.features import clip_features, skeleton_fingerprint
from quatmotion.retrieval.features_fused import (
    FIT_CLIPS,
    MODEL_KEY,
    MODEL_KEY_LABELS,
    fit_fused_model,
    labels_digest,
)
from quatmotion.retrieval.index_file import ClipRecord, IndexFile, IndexSettings
from quatmotion.retrieval.methods import fit_labels, stored_model

__all__ = [
    "ClipJob",
    "add",
    "build",
    "build_index",
    "index_clip",
    "read_labels_csv",
    "skeleton_for",
    "store_models",
]


@dataclass(frozen=True)
class ClipJob:
    """What :func:`index_clip` needs: the clip to read, how, and the feature kinds."""

    source: ClipSource
    kinds: tuple[str, ...]
    read: ReadSettings = ReadSettings()

    def __str__(self) -> str:  # how a batch failure names it
        return str(self.source)


@dataclass(frozen=True)
class _Indexed:
    """A worker's answer: the record, and what is doubtful in its file."""

    record: ClipRecord
    doubts: tuple[Doubt, ...]


def skeleton_for(path: Path, skeletons: str | Path | None) -> Path | None:
    """The ASF of an AMC (:func:`quatmotion.collection.find_skeleton`), None for other files."""
    from quatmotion.collection import find_skeleton

    if Path(path).suffix.lower() != ".amc":
        return None
    return find_skeleton(Path(path), skeletons)


def index_clip(job: ClipJob) -> ClipRecord:
    """Read one clip and compute its features (a pure function of ``job``)."""
    return _index_clip(job).record


def _index_clip(job: ClipJob) -> _Indexed:
    motion, ref, doubts = read_clip(job.source, job.read)
    record = ClipRecord(
        ref=ref,
        label="",
        frames=motion.n_frames,
        fps=float(motion.fps),
        rotation_key=skeleton_fingerprint(motion.skeleton),
        arrays=clip_features(motion, job.kinds),
    )
    return _Indexed(record, tuple(doubts))


# -- the steps ------------------------------------------------------------------------------
def _find(sources: Iterable[Any], read: ReadSettings, report: BuildReport) -> list[ClipSource]:
    """Step 1: the clips named, each with its unique name, ASF and hash (files whose ASF is
    not found, or that cannot be read to hash, become failures)."""
    errors: list[tuple[str, str]] = []
    found = find_clips(sources, read, on_error=errors)
    report.failures += [Failure(i, path, reason) for i, (path, reason) in enumerate(errors)]
    return found


def _open(out: Path, settings: IndexSettings, report: BuildReport) -> IndexFile:
    """Step 2: a new index, or the existing one resumed (noted in the report)."""
    if out.exists() and out.stat().st_size > 0:
        index = IndexFile.open(out, write=True)
        report.details["resumed"] = True
        report.details["clips_before"] = len(index)
        index.write_settings(settings)
        return index
    report.details["resumed"] = False
    return IndexFile._create(out, settings)


def _plan(index: IndexFile, found: list[ClipSource], report: BuildReport) -> list[ClipSource]:
    """Step 3: the clips to compute. Those already indexed (same path and content hash) are
    skipped; names are unique across the old clips and the new ones (a stem shared with an
    indexed clip makes both names relative paths: the old clip is renamed)."""
    rows = index.rows()
    held = {(r.ref.path, r.sha256) for r in rows}
    kept = {r.ref.path for r in rows if r.ref.path}
    new = [s for s in found if (str(s.path) if s.path else None, s.sha256) not in held]
    report.skipped += [s.ref() for s in found if s not in new]
    old_paths = list(dict.fromkeys(r.ref.path for r in rows if r.ref.path))  # a file's takes:
    new_files = list(dict.fromkeys(  # one path, named once
        str(s.path) for s in new if s.path is not None and str(s.path) not in kept
    ))  # fmt: skip
    names = unique_names([Path(p) for p in old_paths + new_files])
    file_names = dict(zip(old_paths + new_files, names, strict=True))
    index.rename(
        {
            r.name: renamed
            for r in rows
            if r.ref.path
            and (renamed := named_for_file(r.name, file_names[r.ref.path], r.ref.take)) != r.name
        }
    )
    out = []
    for s in new:
        name = s.name
        if s.path is not None:  # a changed file keeps its clip's name
            name = named_for_file(s.name, file_names[str(s.path)], s.take)
        out.append(dataclasses.replace(s, name=name))
    return out


def _compute_and_write(
    index: IndexFile,
    jobs: list[ClipJob],
    labels: Mapping[str, str],
    report: BuildReport,
    *,
    runner: Runner,
    progress: Callable[[int, int], None] | None,
    on_doubt: Callable[[str, Doubt], None] | None,
) -> None:
    """Steps 4 and 5: features in the workers, records committed ``batch`` at a time."""
    batch = index.settings.batch
    pending: list[ClipRecord] = []

    def flush() -> None:
        index.store(pending)
        report.added.extend(r.ref for r in pending)
        pending.clear()

    stream = runner.map(_index_clip, jobs, progress=progress)
    with stream:
        for outcome in stream:
            if outcome.failure is not None:
                report.failures.append(outcome.failure)
                continue
            result: _Indexed = outcome.value
            record = result.record
            label = labels.get(record.ref.name, "")
            pending.append(
                ClipRecord(
                    record.ref, label, record.frames, record.fps, record.rotation_key, record.arrays
                )
            )
            for doubt in result.doubts:
                report.doubts.append((record.ref, doubt.message))
                if on_doubt is not None:
                    on_doubt(record.ref.path or record.ref.name, doubt)
            if len(pending) >= batch:
                flush()
    if pending:
        flush()
    report.stats = stream.stats()


def _key(s: ClipSource) -> tuple[str, str]:
    return (str(s.path) if s.path is not None else s.name, s.sha256)


def _relabel(
    index: IndexFile,
    found: list[ClipSource],
    todo: list[ClipSource],
    given: Mapping[str, str] | None,
) -> tuple[dict[str, str], list[str], int]:
    """The labels of every clip found, by its name in the index (the new clips' names from
    the plan, the others' as stored); the keys of ``given`` naming no clip; and how many
    clips already indexed changed label (set here)."""
    settings = index.settings
    planned = {_key(s) for s in todo}
    by_path = {r.ref.path: r.name for r in index.rows() if r.ref.path}
    held = [
        ClipSource(by_path.get(str(s.path), s.name), s.sha256, s.path, s.skeleton_path, s.motion)
        for s in found
        if _key(s) not in planned
    ]
    assignment = label_sources(
        [*todo, *held], given, sidecars=settings.label_sidecars, folders=settings.label_folders
    )
    changed = index.set_labels(
        {s.name: assignment.labels[s.name] for s in held if s.name in assignment.labels}
    )
    return assignment.labels, assignment.unmatched, changed


def _run(
    index: IndexFile,
    found: list[ClipSource],
    report: BuildReport,
    *,
    labels: Mapping[str, str] | None,
    runner: Runner,
    progress: Callable[[int, int], None] | None,
    on_doubt: Callable[[str, Doubt], None] | None,
) -> BuildReport:
    """Steps 3 to 6 on an open index."""
    settings = index.settings
    todo = _plan(index, found, report)
    assigned, report.unmatched_labels, changed = _relabel(index, found, todo, labels)
    jobs = [ClipJob(s, settings.kinds, settings.read) for s in todo]
    _compute_and_write(
        index, jobs, assigned, report, runner=runner, progress=progress, on_doubt=on_doubt
    )
    report.labels_changed = changed
    if "motion" in settings.kinds:
        store_models(index)
    if labels is not None:  # new clips labelled by the given mapping count as set
        given = match_keys(labels, todo).labels
        report.labels_changed += sum(1 for r in report.added if given.get(r.name))
    report.settings = settings
    return report


def _runner(runner: Runner | str | Scheduler | None, workers: int | None, where: str) -> Runner:
    """Where a build runs: ``runner``, or the :class:`Runner` of a scheduler name or
    :class:`Scheduler` (:meth:`Runner.resolve`; None: ``$QUATMOTION_SCHEDULER``, else a local
    pool). ``workers`` is the keyword before 0.5.0: it warns, and names a local pool's size
    (1: this process) as it did.

    Raises
    ------
    ValueError
        ``workers`` with a :class:`Runner`: where the batch runs is said twice.
    """
    if workers is None:
        return runner if isinstance(runner, Runner) else Runner.resolve(runner)
    warnings.warn(
        f"{where}(..., workers=...) is the name before quatmotion 0.5.0 (removed in 0.6.0): "
        f"use {where}(..., runner=Runner.local(workers)) (docs/migration-0.4.md)",
        DeprecationWarning,
        stacklevel=5,  # this function, build or add, ClipIndex's _write, ClipIndex, the caller
    )
    if isinstance(runner, Runner):
        raise ValueError("say where the batch runs once: runner, or workers and a scheduler")
    return Runner.resolve(runner, workers=workers)


def store_models(index: IndexFile, seed: int = 0) -> list[str]:
    """Step 6: fit and store in ``index`` (open for writing) the default's model when it is
    missing, damaged, of other parameters, or fitted on fewer clips than it would be now; and,
    when the index has labels, ``dtw-fused-labels``'s when it is missing, damaged or learned
    from other labels. Returns the keys written."""
    n = len(index)
    if n == 0 or not index.holds_blobs:  # a version-1 index has no blobs table
        return []
    labels = [r.label for r in index.rows()]
    model = stored_model(index.blob(MODEL_KEY))
    learned = stored_model(index.blob(MODEL_KEY_LABELS)) if any(labels) else None
    refit = model is None or model.fitted_clips < min(FIT_CLIPS, n)
    relearn = any(labels) and (
        refit
        or learned is None
        or learned.labels_digest != labels_digest(labels)
        or model is None
        or learned.scales != model.scales
    )
    if not (refit or relearn):
        return []  # what is stored is current: the clips' features are not read
    rows, library = index.load(("frames", "path"))
    if len(library) == 0:
        return []
    written = []
    if refit:
        model = fit_fused_model(library._need("frames"), library._need("path"), seed)
        index.set_blob(MODEL_KEY, model.to_bytes())
        written.append(MODEL_KEY)
    if relearn:
        library.labels = [r.label for r in rows]
        learned = fit_labels(library, model, seed)
        index.set_blob(MODEL_KEY_LABELS, learned.to_bytes())
        written.append(MODEL_KEY_LABELS)
    return written


def build(
    sources: Iterable[Any],
    out: str | Path,
    settings: IndexSettings | None = None,
    *,
    runner: Runner | str | Scheduler | None = None,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    labels: Mapping[str, str] | None = None,
    on_doubt: Callable[[str, Doubt], None] | None = None,
) -> BuildReport:
    """Index every clip of ``sources`` into ``out`` (:meth:`ClipIndex.build`).

    Parameters
    ----------
    sources : iterable
        Files, folders (searched recursively), motions in memory or
        :class:`~quatmotion.collection.ClipSource` items.
    out : str or Path
        The ``.qidx`` file: created, or resumed when it is there (``details["resumed"]``).
    settings : IndexSettings, optional
        Defaults when None; stored in the file.
    runner : Runner, str or Scheduler, optional
        Where the features are computed: a :class:`quatmotion.parallel.Runner`
        (``Runner.local(workers)``, ``Runner.inline()``, ``Runner.dask(...)``), or a scheduler
        as :meth:`Runner.resolve` reads it (``None``: ``$QUATMOTION_SCHEDULER``, else a local
        pool of every core).
    workers : int, optional
        The name before 0.5.0 (warns, removed in 0.6.0): ``runner=Runner.local(workers)``.
    progress : callable, optional
        ``progress(done, total)`` as clips finish.
    labels : mapping, optional
        Clip (name, file name, stem or path) -> label: applied to new clips and to clips
        already indexed; keys naming no clip are in ``report.unmatched_labels``. Clips it
        does not name take their sidecar's, folder's (``settings.label_folders``) or the
        catalogue's label.
    on_doubt : callable, optional
        ``on_doubt(path, doubt)`` for what is doubtful in a clip indexed, in this process.

    Returns
    -------
    BuildReport
        ``added``/``skipped`` as clip references, ``failures`` as
        :class:`quatmotion.parallel.Failure`, ``labels_changed``.
    """
    batch = _runner(runner, workers, "ClipIndex.build")
    settings = settings or IndexSettings()
    out = Path(out)
    report = BuildReport(path=out, settings=settings)
    found = _find(sources, settings.read, report)
    with _open(out, settings, report) as index:
        return _run(
            index, found, report, labels=labels, runner=batch, progress=progress, on_doubt=on_doubt
        )


def add(
    path: str | Path,
    sources: Iterable[Any],
    *,
    settings: IndexSettings | None = None,
    runner: Runner | str | Scheduler | None = None,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    labels: Mapping[str, str] | None = None,
    on_doubt: Callable[[str, Doubt], None] | None = None,
) -> BuildReport:
    """Add ``sources`` to the index at ``path`` (:meth:`ClipIndex.add`): its stored settings
    unless ``settings`` is given; ``labels`` as for :func:`build`, clips already there
    relabelled.

    Raises
    ------
    FileNotFoundError
        No index at ``path``.
    """
    batch = _runner(runner, workers, "ClipIndex.add")
    path = Path(path)
    with IndexFile.open(path, write=True) as index:
        settings = settings or index.settings
        if settings != index.settings:
            index.write_settings(settings)
        report = BuildReport(path=path, settings=settings, details={"resumed": True})
        report.details["clips_before"] = len(index)
        found = _find(sources, settings.read, report)
        return _run(
            index, found, report, labels=labels, runner=batch, progress=progress, on_doubt=on_doubt
        )


def build_index(
    paths: Iterable[str | Path],
    out: str | Path,
    *,
    kinds: Iterable[str] = ("motion",),
    labels: dict[str, str] | None = None,
    skeletons: str | Path | None = None,
    units: str | float | None = None,
    workers: int | None = None,
    scheduler: str | Scheduler | None = None,
    batch: int = 16,
    progress: Callable[[int, int], None] | None = None,
    on_doubt: Callable[[str, Doubt], None] | None = None,
) -> BuildReport:
    """:meth:`ClipIndex.build` with an :class:`IndexSettings` made of the keywords (the name
    before 0.4.0; warns)."""
    from quatmotion._deprecated import warn_renamed

    warn_renamed("retrieval.build_index", "ClipIndex.build with IndexSettings")
    read = ReadSettings(
        units=units, skeleton=None if skeletons is None else os.fspath(skeletons), strict=False
    )
    settings = IndexSettings(kinds=tuple(kinds), batch=batch, read=read)
    runner = Runner.of(workers, scheduler)
    return build(
        paths, out, settings, runner=runner, progress=progress, labels=labels, on_doubt=on_doubt
    )
