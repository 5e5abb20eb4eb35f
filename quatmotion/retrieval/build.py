"""Building and extending a clip index: one pure per-clip feature function mapped over the
clips, one writer committing in batches.

``index_clip`` reads a clip and computes its features; it depends on nothing but its
arguments, so the execution layer (:mod:`quatmotion.parallel`) maps it over the clips: a local
process pool over all cores by default, or a Dask cluster. Results come back in input order,
and the writer, in the calling process, stores them in transactions of ``batch`` clips, so the
index holds the same rows whatever ran the jobs, a killed build keeps every batch already
committed, and the next build skips those clips (same path and content hash).
"""

from __future__ import annotations

import csv
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from quatmotion.errors import FormatError
from quatmotion.io import Doubt
from quatmotion.parallel import Scheduler, imap_batch
from quatmotion.retrieval.features import clip_features, skeleton_fingerprint
from quatmotion.retrieval.index import ClipIndex, ClipRecord, content_hash

__all__ = [
    "BuildReport",
    "ClipJob",
    "build_index",
    "catalogue_labels",
    "index_clip",
    "read_labels_csv",
    "skeleton_for",
]


@dataclass(frozen=True)
class ClipJob:
    """What :func:`index_clip` needs: the file, its ASF (AMC only), kinds, label, and the
    length unit of a BVH (``None``: guessed)."""

    path: str
    skeleton: str | None
    kinds: tuple[str, ...]
    label: str
    sha256: str
    units: str | float | None = None


@dataclass
class BuildReport:
    """What a build did: clips added, skipped (already indexed) and failed (path, reason)."""

    added: int = 0
    skipped: int = 0
    failed: list[tuple[str, str]] = field(default_factory=list)


@dataclass(frozen=True)
class _Indexed:
    """A worker's answer: the record, and what is doubtful in its file."""

    record: ClipRecord
    doubts: tuple[Doubt, ...]


def skeleton_for(path: Path, skeletons: Path | None) -> Path | None:
    """The ASF of an AMC: ``skeletons`` if it is a file; from ``skeletons`` (a folder) when
    given; else by the CMU / HDM05 layouts (:func:`quatmotion.io.find_asf_for_amc`); ``None``
    for BVH files.

    Raises
    ------
    FormatError
        When no skeleton is found (naming where it looked).
    """
    from quatmotion.io import find_asf_for_amc

    if path.suffix.lower() != ".amc":
        return None
    if skeletons is not None and skeletons.is_file():
        return skeletons
    if skeletons is None:
        try:
            return find_asf_for_amc(path)
        except FormatError as error:
            reason = error.reason.replace("pass it (--skeleton)", "pass their folder (--skeletons)")
            raise FormatError(reason, path) from None
    stem = path.stem
    candidates = [skeletons / (stem.split("_", 1)[0] + ".asf")]
    parts = stem.split("_")
    if len(parts) >= 2:
        candidates.append(skeletons / f"{parts[0]}_{parts[1]}.asf")
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    found = sorted(skeletons.glob("*.asf"))
    if len(found) == 1:
        return found[0]
    raise FormatError(
        f"no ASF for this AMC in {skeletons} (looked for "
        f"{', '.join(c.name for c in candidates)}, and the folder holds {len(found)} ASF files)",
        path,
    )


def index_clip(job: ClipJob) -> ClipRecord:
    """Read one clip and compute its features (a pure function of ``job``)."""
    return _index_clip(job).record


def _index_clip(job: ClipJob) -> _Indexed:
    from quatmotion.io import implausible_values, read_motion

    amc = Path(job.path).suffix.lower() == ".amc"
    motion = read_motion(job.path, job.skeleton, units=None if amc else job.units)
    record = ClipRecord(
        name=Path(job.path).stem,
        path=job.path,
        sha256=job.sha256,
        label=job.label,
        frames=motion.n_frames,
        fps=float(motion.fps),
        skeleton=skeleton_fingerprint(motion.skeleton),
        arrays=clip_features(motion, job.kinds),
    )
    return _Indexed(record, tuple(implausible_values(motion)))


def _guarded(job: ClipJob) -> _Indexed | tuple[str, str]:
    """:func:`index_clip` with the file's doubts, a bad file turned into ``(path, reason)``."""
    try:
        return _index_clip(job)
    except (FormatError, ValueError, OSError) as error:
        return (job.path, _reason(error))


def _reason(error: Exception) -> str:
    """The first line of ``error``'s message, without the file name a FormatError prepends
    (the report names the file already)."""
    text = getattr(error, "reason", None) or str(error) or type(error).__name__
    return str(text).splitlines()[0]


def read_labels_csv(path: str | Path) -> dict[str, str]:
    """Labels from a CSV with columns ``clip`` (file name stem or path) and ``label``.

    Raises
    ------
    FormatError
        When the header lacks those columns.
    """
    path = Path(path)
    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        if not reader.fieldnames or not {"clip", "label"} <= set(reader.fieldnames):
            raise FormatError("a labels CSV needs the columns 'clip' and 'label'", path, 1)
        return {row["clip"].strip(): (row["label"] or "").strip() for row in reader}


def catalogue_labels() -> dict[str, str]:
    """Resolved path -> label of every clip of the data folder's catalogue (empty without one)."""
    from quatmotion.datasets import DataNotFoundError, catalogue

    try:
        return {str(e.path.resolve()): e.label for e in catalogue()}
    except DataNotFoundError:
        return {}


def _label(path: Path, labels: dict[str, str], known: dict[str, str]) -> str:
    for key in (str(path), path.name, path.stem):
        if key in labels:
            return labels[key]
    return known.get(str(path.resolve()), "")


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
    """Index every motion file under ``paths`` into ``out`` (created, or extended: clips
    already there with the same content hash are skipped).

    Parameters
    ----------
    paths : iterable of str or Path
        Files or folders (searched recursively, :func:`quatmotion.io.find_motion_files`).
    out : str or Path
        The ``.qidx`` file.
    kinds : iterable of str
        Feature kinds to compute (:data:`quatmotion.retrieval.methods.FEATURE_KINDS`).
    labels : dict, optional
        Clip (path, file name or stem) -> label; clips not in it take the catalogue's label.
    skeletons : str or Path, optional
        The ASF of every AMC clip, or a folder holding their ASF files (:func:`skeleton_for`).
    units : str or float, optional
        Length unit of the BVH clips (:data:`quatmotion.io.BVH_UNITS`); guessed when None.
        The features are scale-free (every clip is put on one stature), so the unit changes
        what ``on_doubt`` hears, not the index.
    workers : int, optional
        Processes (default: every core; 1 computes in this process).
    scheduler : str or Scheduler, optional
        Where the features are computed: :func:`quatmotion.parallel.resolve_scheduler` (a Dask
        address ``tcp://HOST:PORT``; ``$QUATMOTION_SCHEDULER`` when None).
    batch : int
        Clips per committed transaction.
    progress : callable, optional
        Called with ``(done, total)`` as clips finish.
    on_doubt : callable, optional
        ``on_doubt(path, doubt)`` for what is doubtful in a clip indexed
        (:func:`quatmotion.io.implausible_values`), in this process as its result comes back.

    Returns
    -------
    BuildReport
    """
    from quatmotion.io import find_motion_files

    files = find_motion_files(paths)
    skeleton_dir = Path(skeletons) if skeletons is not None else None
    labels = dict(labels or {})
    known = catalogue_labels()
    report = BuildReport()
    jobs: list[ClipJob] = []
    kinds = tuple(kinds)
    with ClipIndex.create(out) as index:
        for path in files:
            try:
                skeleton = skeleton_for(path, skeleton_dir)
                sha = content_hash(path, skeleton)
            except (FormatError, OSError) as error:
                report.failed.append((str(path), _reason(error)))
                continue
            if index.contains(str(path), sha):
                report.skipped += 1
                continue
            label = _label(path, labels, known)
            asf = str(skeleton) if skeleton else None
            jobs.append(ClipJob(str(path), asf, kinds, label, sha, units))
        pending: list[ClipRecord] = []
        stream = imap_batch(_guarded, jobs, workers=workers, scheduler=scheduler, progress=progress)
        with stream:
            for outcome in stream:
                result = outcome.value
                if outcome.failure is not None:  # its worker died, on every attempt
                    report.failed.append((outcome.item.path, outcome.failure.message))
                elif isinstance(result, _Indexed):
                    pending.append(result.record)
                    for doubt in result.doubts if on_doubt is not None else ():
                        on_doubt(result.record.path, doubt)
                else:
                    report.failed.append(result)  # type: ignore[arg-type]
                if len(pending) >= batch:
                    report.added += index.add(pending)
                    pending = []
        if pending:
            report.added += index.add(pending)
    return report
