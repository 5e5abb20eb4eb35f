"""Compression: clips in, a ``.qmz`` library out (the orchestrator, as named steps).

:func:`build_library` (:meth:`quatmotion.codec.Archive.build`) reads as the steps it takes,
none of which holds every clip in the caller's memory: scan the clips in the workers
(:func:`scan_clip`: reference, layout key, length, skeleton; every clip named by
:func:`quatmotion.collection.unique_names`), store their skeletons, plan the layouts and read
a seeded sample of at most ``fit_sample`` clips of each to fit the layouts and the shared
models (:class:`SharedModels`), code every clip in a worker that reads it itself
(:func:`code_clip` of a :class:`ClipTask`, the models sent to each worker once as the batch's
context; searching the method's quality knob for ``ratio``; decoding every clip back and
repairing the frames over ``max_error``), spool the chunks to a temporary file, then write the
header and stream the chunks into the container
(:func:`quatmotion.codec.container.write_container`) atomically. :func:`add_to_library`
(:meth:`Archive.add`) adds clips to an existing file without re-encoding the clips already in
it (their chunks are copied byte for byte). :func:`compress` and :func:`append` are the names
before 0.4.0, kept as thin wrappers.
"""

from __future__ import annotations

import contextlib
import io
import itertools
import json
import time
import zlib
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from quatmotion._atomic import atomic_output, output_lock
from quatmotion.codec.archive import ArchiveReader
from quatmotion.codec.binary import Writer
from quatmotion.codec.channels import layout_key, to_channels
from quatmotion.codec.container import (
    MAGIC,
    ClipEntry,
    Header,
    LayoutEntry,
    RecordEntry,
    SkeletonEntry,
    write_container,
)
from quatmotion.codec.library import LayoutInfo, PreparedClip, PreparedLibrary, prepare_library
from quatmotion.codec.methods import ClipContext, EncodedLibrary, Method, get_method
from quatmotion.codec.metrics import ClipErrors, clip_errors
from quatmotion.codec.repair import (
    Corrections,
    correction_lever,
    find_corrections,
    write_clip_prefix,
)
from quatmotion.codec.settings import DEFAULT_MAX_ERROR_CM, FIT_SAMPLE_CLIPS, CompressSettings
from quatmotion.codec.skeletons import deflate_text, same_skeleton, skeleton_record
from quatmotion.collection import (
    BuildReport,
    ClipRef,
    ClipSource,
    ReadSettings,
    find_clips,
    read_clip,
)
from quatmotion.errors import FormatError
from quatmotion.io import Doubt
from quatmotion.motion import Motion, Skeleton, forward_kinematics
from quatmotion.parallel import Failure, Runner, Scheduler

__all__ = [
    "DEFAULT_MAX_ERROR_CM",
    "FIT_SAMPLE_CLIPS",
    "ClipTask",
    "CodedClip",
    "CompressionResult",
    "ScannedClip",
    "SharedModels",
    "add_to_library",
    "append",
    "build_library",
    "code_clip",
    "compress",
    "plan_clip_tasks",
    "runner_of",
    "scan_clip",
]

Progress = Callable[[str, int, int], None]
OnDoubt = Callable[[str, Doubt], None]


@dataclass
class CompressionResult:
    """What :func:`compress` made (the return before 0.4.0; :class:`BuildReport` now).

    Attributes
    ----------
    data : bytes
        The whole ``.qmz`` file.
    path : Path or None
        Where it was written.
    method : str
    clip_errors : list of ClipErrors
        Per clip, as decoded from ``data``.
    clip_bytes : list of int
        Per clip, its chunk's payload bytes.
    source_bytes : list of int
        Per clip, its source file's size (0 if unknown).
    raw_bytes : list of int
        Per clip, ``4 * dofs * frames``.
    seconds : float
        Wall time of the whole compression.
    quality : float
        The method's quality knob as used.
    """

    data: bytes
    path: Path | None
    method: str
    clip_errors: list[ClipErrors]
    clip_bytes: list[int]
    source_bytes: list[int]
    raw_bytes: list[int]
    seconds: float
    quality: float
    corrections: list[int] = field(default_factory=list)
    failed: list[tuple[str, str]] = field(default_factory=list)
    """Inputs left out (``on_error="skip"``): (file or clip, one-line reason)."""

    @property
    def size(self) -> int:
        return len(self.data)

    @classmethod
    def from_report(cls, report: BuildReport) -> CompressionResult:
        d = report.details
        data = d["data"] if "data" in d else Path(report.path).read_bytes()
        return cls(
            data, report.path, d["method"], d["clip_errors"], d["clip_bytes"],
            d["source_bytes"], d["raw_bytes"], d["seconds"], d["quality"], d["corrections"],
            [(str(f.item), f.message) for f in report.failures],
        )  # fmt: skip


# ---------------------------------------------------------------------------------- scanning
@dataclass(frozen=True)
class ScannedClip:
    """What the caller keeps of one clip: :func:`scan_clip`'s result, read in a worker.

    Small (no frames): the reference, the layout key and the skeleton, the clip's length and
    its source's size and format, so that a library of any number of clips is planned in the
    caller's memory while the workers read the frames.

    Attributes
    ----------
    ref : ClipRef
    name : str
        The clip's name (the collection's rule, :func:`quatmotion.collection.unique_names`).
    key : tuple
        :func:`quatmotion.codec.channels.layout_key` of its skeleton.
    skeleton : Skeleton
    n_frames : int
    fps : float
    source : (int, str)
        The source file's size in bytes and its format (``(0, "")`` for a clip in memory).
    text_bytes : int
        The size of the AMC or BVH text the writers would produce (only when asked: a
        ``ratio`` target of a clip without a source size), else 0.
    doubts : tuple of Doubt
    """

    ref: ClipRef
    name: str
    key: tuple
    skeleton: Skeleton
    n_frames: int
    fps: float
    source: tuple[int, str]
    text_bytes: int = 0
    doubts: tuple[Doubt, ...] = ()

    @property
    def raw_bytes(self) -> int:
        """``4 * dofs * frames``: the clip as float32 channels."""
        return 4 * sum(len(ch) for ch in self.skeleton.channels) * self.n_frames


@dataclass(frozen=True)
class _Unread:
    """A clip :func:`scan_clip` could not read: the reason in one line (the caller reads it
    again to raise the error itself, or notes the failure)."""

    message: str


@dataclass(frozen=True)
class _ScanOptions:
    read: ReadSettings
    text_bytes: bool = False


def scan_clip(source: ClipSource, options: _ScanOptions) -> ScannedClip | _Unread:
    """Read one clip and keep what planning the library needs (a worker's job: the frames
    stay in the worker)."""
    try:
        motion, ref, doubts = read_clip(source, options.read)
        size = (0, "") if source.path is None else _source_size(source.path)
        text = _text_bytes(motion) if options.text_bytes and not size[0] else 0
    except (FormatError, OSError, ValueError) as error:
        return _Unread(_one_line(error))
    return ScannedClip(
        ref, motion.name, layout_key(motion.skeleton), motion.skeleton, motion.n_frames,
        motion.fps, size, text, tuple(doubts),
    )  # fmt: skip


def _one_line(error: BaseException) -> str:
    message = getattr(error, "reason", None) or str(error) or type(error).__name__
    if isinstance(error, FormatError):
        message = str(error)
    return str(message).splitlines()[0]


@dataclass
class _Inputs:
    """The clips scanned (step 1): each clip's source (what a worker reads) and its scan."""

    sources: list[ClipSource] = field(default_factory=list)
    scans: list[ScannedClip] = field(default_factory=list)
    failures: list[Failure] = field(default_factory=list)
    doubts: list[tuple[ClipRef, str]] = field(default_factory=list)

    @property
    def refs(self) -> list[ClipRef]:
        return [s.ref for s in self.scans]

    def keep(self, source: ClipSource, scan: ScannedClip) -> None:
        self.sources.append(source)
        self.scans.append(scan)

    def fail(self, item: object, message: str) -> None:
        self.failures.append(Failure(len(self.failures), item, message))

    def select(self, keep: Sequence[int]) -> None:
        self.sources = [self.sources[i] for i in keep]
        self.scans = [self.scans[i] for i in keep]


def _scan_step(
    sources: Iterable[Any],
    settings: CompressSettings,
    skip: bool,
    known: Sequence[tuple[int, str]] | None,
    on_doubt: OnDoubt | None,
    runner: _Runner,
) -> _Inputs:
    """Every clip of ``sources`` scanned by :func:`scan_clip` through the runner, named by the
    collection's rules. With ``skip``, a file that cannot be found, hashed or read is noted in
    the failures and left out instead of raising; progress hears ``("read", done, total)``."""
    out = _Inputs()
    read = settings.read
    found_errors: list[tuple[str, str]] = []
    items = [Path(s) if isinstance(s, str) else s for s in sources]
    found = find_clips(items, read, on_error=found_errors if skip else None)
    for path, reason in found_errors:
        out.failures.append(Failure(len(out.failures), path, reason))
    in_memory = [s for s in found if s.path is None]
    if known is not None and len(known) != len(in_memory):
        raise ValueError(f"sources gives {len(known)} sizes for {len(in_memory)} clips")
    sizes = iter(known or ())
    options = _ScanOptions(read, text_bytes=settings.ratio is not None)
    for source, scan in zip(found, runner.each("read", scan_clip, found, options), strict=True):
        if isinstance(scan, _Unread):
            if not skip:
                read_clip(source, read)  # raises the error itself
                raise ValueError(scan.message)
            out.fail(source, scan.message)
            continue
        if source.path is None and known is not None:
            from dataclasses import replace

            scan = replace(scan, source=tuple(next(sizes)))
        for doubt in scan.doubts:
            out.doubts.append((scan.ref, doubt.message))
            if on_doubt is not None:
                on_doubt(str(source), doubt)
        out.keep(source, scan)
    if not out.scans and not out.failures:
        raise ValueError("nothing to compress: no clips given")
    return out


def _source_size(path: Path) -> tuple[int, str]:
    return path.stat().st_size, path.suffix.lower().lstrip(".")


def _admit(inputs: _Inputs, table: _SkeletonTable, skip: bool) -> None:
    """Keep the clips that can be stored (frames, a skeleton the format can record); the others
    are noted in the failures (``skip``) or raise."""
    keep = []
    for i, scan in enumerate(inputs.scans):
        try:
            if scan.n_frames == 0:
                raise ValueError(f"clip {scan.name!r} has no frames")
            table.index(scan.skeleton)
        except ValueError as error:
            if not skip:
                raise
            inputs.fail(scan.ref.path or scan.ref.name, _one_line(error))
            continue
        keep.append(i)
    inputs.select(keep)
    if not inputs.scans:
        first = inputs.failures[0] if inputs.failures else None
        raise ValueError(f"nothing to compress: every input failed ({first})")


# ---------------------------------------------------------------------------------- skeletons
@dataclass
class _SkeletonTable:
    """The archive's skeleton records and entries, found again by dictionary lookups.

    A skeleton is keyed by :meth:`Skeleton.fingerprint`; exact equality (``same_skeleton``)
    still decides within a fingerprint's bucket, so a digest collision can never merge two
    skeletons. A record is keyed by its (kind, scale, text). Each lookup is O(1) in the number
    of skeletons already held (a library of one skeleton per clip stays linear)."""

    records: list[RecordEntry] = field(default_factory=list)
    texts: list[str] = field(default_factory=list)
    skeletons: list[SkeletonEntry] = field(default_factory=list)
    objects: list[Skeleton] = field(default_factory=list)
    new_records: list[bytes] = field(default_factory=list)
    comparisons: int = 0
    """How many exact skeleton comparisons were made (the lookups' cost, for the tests)."""

    def __post_init__(self) -> None:
        self._by_object: dict[int, int] = {}  # id() of a held object (kept alive by objects)
        self._by_fingerprint: dict[str, list[int]] = {}
        self._record_of: dict[tuple[int, float, str], int] = {}
        self._first_text: dict[int, str] = {}
        for k, s in enumerate(self.objects):
            self._by_object.setdefault(id(s), k)
            self._by_fingerprint.setdefault(s.fingerprint(), []).append(k)
        for k, (r, t) in enumerate(zip(self.records, self.texts, strict=True)):
            self._record_of.setdefault((r.kind, r.scale, t), k)
            self._first_text.setdefault(r.kind, t)

    def index(self, skeleton: Skeleton) -> int:
        """The skeleton's entry, adding it (and its record, if its text is new)."""
        k = self._by_object.get(id(skeleton))
        if k is not None and self.objects[k] is skeleton:
            return k
        fingerprint = skeleton.fingerprint()
        bucket = self._by_fingerprint.setdefault(fingerprint, [])
        for k in bucket:
            self.comparisons += 1
            if same_skeleton(self.objects[k], skeleton):
                return k
        kind, text, scale = skeleton_record(skeleton)
        key = (kind, scale, text)
        record = self._record_of.get(key)
        if record is None:
            self.new_records.append(deflate_text(text, self._first_text.get(kind, "")))
            self.records.append(RecordEntry(kind, scale))
            self.texts.append(text)
            record = len(self.records) - 1
            self._record_of[key] = record
            self._first_text.setdefault(kind, text)
        self.skeletons.append(SkeletonEntry(record, skeleton.name))
        self.objects.append(skeleton)
        k = len(self.objects) - 1
        bucket.append(k)
        self._by_object[id(skeleton)] = k
        return k


# ---------------------------------------------------------------------------------- planning
@dataclass(frozen=True)
class SharedModels:
    """What every clip's job shares, sent to each worker once per batch (the batch's context,
    :meth:`quatmotion.parallel.Runner.map`): the layouts and the models learned on the sample.

    Attributes
    ----------
    method : Method
    layouts : list of LayoutInfo
        Every layout of the library (those of the file appended to first).
    models : list
        Per layout, the encoder's model (:meth:`Method.fit_models`).
    decoder_models : list
        Per layout, the same model as the decoder reads it from the file.
    quality : float
    max_error : float or None
        The bound the encoder aims at and the repair enforces (``None``: none).
    vertices : bool
        The bound also covers the virtual vertices.
    read : ReadSettings
        How a worker reads its clip.
    """

    method: Method
    layouts: list[LayoutInfo]
    models: list[Any]
    decoder_models: list[Any]
    quality: float
    max_error: float | None
    vertices: bool
    read: ReadSettings


@dataclass(frozen=True)
class ClipTask:
    """One clip's share of the encoding, without its frames (the worker reads them) and
    without the models (:class:`SharedModels`, the batch's context).

    Attributes
    ----------
    source : ClipSource
        What the worker reads (a file, or a motion given in memory).
    name : str
        The clip's name in the library.
    layout : int
    verify : bool
        Decode the payload, measure it and repair the frames over the bound.
    payload : (str, int, int) or None
        Already coded (verify only): the spool file, offset and length of its bytes.
    """

    source: ClipSource
    name: str
    layout: int
    verify: bool
    payload: tuple[str, int, int] | None = None

    def __str__(self) -> str:  # how a failure names the task
        return f"clip {self.name!r}"


@dataclass(frozen=True)
class CodedClip:
    """:func:`code_clip`'s result: the clip chunk's prefix (rest flags, corrections) and the
    method's payload, and after verification its errors (``None`` without)."""

    prefix: bytes
    payload: bytes
    corrections: int
    errors: ClipErrors | None


def _prepared(task: ClipTask, models: SharedModels) -> PreparedLibrary:
    """The task's clip read and prepared alone, with every layout (its index stays valid)."""
    motion = read_clip(task.source, models.read).motion
    if motion.name != task.name:
        motion = motion.renamed(task.name)
    info = models.layouts[task.layout]
    X, at_rest = to_channels(motion, info.layout, info.reference)
    clip = PreparedClip(motion, task.layout, X, at_rest, forward_kinematics(motion))
    members = [[0] if k == task.layout else [] for k in range(len(models.layouts))]
    return PreparedLibrary(models.layouts, [clip], members, models.vertices)


def code_clip(task: ClipTask, models: SharedModels) -> CodedClip:
    """Read one clip, encode it (unless its payload is given), then decode it from its bytes,
    measure it and correct the frames over the bound: the per-clip job of
    :func:`build_library` and :func:`add_to_library`, run by :mod:`quatmotion.parallel` with
    ``models`` as the batch's context."""
    library = _prepared(task, models)
    method = models.method
    if task.payload is None:
        payload = method.encode_clip(
            library, 0, models.models[task.layout], quality=models.quality,
            max_error=models.max_error,
        )  # fmt: skip
    else:
        spool, offset, length = task.payload
        with open(spool, "rb") as file:
            file.seek(offset)
            payload = file.read(length)
    fix, errors = Corrections.empty(), None
    if task.verify:
        max_error = models.max_error
        fix, errors = _verify_clip(
            method, library, 0, payload, models.decoder_models[task.layout], max_error
        )
    return CodedClip(write_clip_prefix(library.clips[0].at_rest, fix), payload, len(fix), errors)


@dataclass
class _Plan:
    """The library planned from the scans: every clip's layout, and the sample the layouts
    and the shared models are learned on (read in the caller: at most ``fit_sample`` clips of
    each layout)."""

    layout_of: list[int]
    sample: PreparedLibrary
    given: list[Any]


def _plan(
    inputs: _Inputs,
    existing: Sequence[tuple[LayoutInfo, Any]],
    settings: CompressSettings,
    vertices: bool,
    report: Progress,
) -> _Plan:
    """Group the clips by layout (the existing layouts first, then new ones in order of first
    appearance), draw the seeded sample of each layout (all of its clips up to
    ``fit_sample``), read the sample and fit the new layouts on it
    (:func:`~quatmotion.codec.library.prepare_library`)."""
    keys = [layout_key(info.skeleton) for info, _ in existing]
    layout_index = {key: k for k, key in reversed(list(enumerate(keys)))}  # first one wins
    layout_of = []
    for scan in inputs.scans:
        if scan.key not in layout_index:
            layout_index[scan.key] = len(keys)
            keys.append(scan.key)
        layout_of.append(layout_index[scan.key])
    members: list[list[int]] = [[] for _ in keys]
    for i, k in enumerate(layout_of):
        members[k].append(i)
    rng = np.random.default_rng(settings.seed)
    given = [model for _, model in existing]
    chosen: list[int] = []
    for k, group in enumerate(members):
        if len(group) > settings.fit_sample:
            group = sorted(int(i) for i in rng.choice(group, settings.fit_sample, replace=False))
        if k >= len(given) or given[k] is None:
            chosen.extend(group)
    chosen.sort(key=lambda i: (layout_of[i], i))
    report("prepare", 0, len(chosen))
    motions = []
    for n, i in enumerate(chosen, 1):
        motion = read_clip(inputs.sources[i], settings.read).motion
        name = inputs.scans[i].name
        motions.append(motion if motion.name == name else motion.renamed(name))
        if n == len(chosen) or n % 16 == 0:
            report("prepare", n, len(chosen))
    sample = prepare_library(
        motions,
        [inputs.scans[i].source for i in chosen],
        [info for info, _ in existing],
        vertices=vertices,
    )
    if len(sample.layouts) != len(keys):  # a bug of this module
        raise RuntimeError(f"{len(sample.layouts)} layouts fitted for {len(keys)}")
    return _Plan(layout_of, sample, given)


def _fit(
    method: Method,
    plan: _Plan,
    quality: float,
    max_error: float | None,
    seed: int,
    read: ReadSettings,
) -> tuple[SharedModels, list[bytes]]:
    """The shared models learned on the sample (the models of the file appended to kept), and
    the ``L`` chunks' model bytes (empty for a given model: already in the file)."""
    sample, given = plan.sample, plan.given
    fitted = method.fit_models(
        sample, sample.members, quality=quality, max_error=max_error, seed=seed, models=given
    )
    blobs, decoder_models = [], []
    for k, info in enumerate(sample.layouts):
        if k < len(given) and given[k] is not None:
            blobs.append(b"")  # already in the file
            decoder_models.append(given[k])
        else:
            blob = method.model_bytes(fitted[k], info) if fitted[k] is not None else b""
            blobs.append(blob)
            used = blob or sample.members[k]
            decoder_models.append(method.load_model(blob, info) if used else None)
    models = SharedModels(
        method, sample.layouts, fitted, decoder_models, quality, max_error, sample.vertices, read
    )
    return models, blobs


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
    runner_ = _Runner(runner, lambda *_: None)
    inputs = _scan_step(sources, settings, False, None, None, runner_)
    _admit(inputs, _SkeletonTable(), False)
    plan = _plan(inputs, [], settings, settings.bound_on == "vertices", lambda *_: None)
    q = settings.quality if settings.quality is not None else method.default_quality
    models, _ = _fit(method, plan, q, settings.max_error, settings.seed, settings.read)
    return _tasks(inputs, plan, verify=True), models


def _tasks(inputs: _Inputs, plan: _Plan, *, verify: bool) -> list[ClipTask]:
    return [
        ClipTask(source, scan.name, k, verify)
        for source, scan, k in zip(inputs.sources, inputs.scans, plan.layout_of, strict=True)
    ]


def runner_of(
    workers: int | None = None, scheduler: str | Scheduler | None = None
) -> Runner | None:
    """The :class:`~quatmotion.parallel.Runner` of the command line's ``--workers`` and
    ``--scheduler`` (None for neither: the default, :meth:`Runner.resolve`)."""
    if workers is None and scheduler is None:
        return None
    if isinstance(scheduler, Scheduler):
        return Runner(scheduler)
    return Runner.resolve(scheduler, workers=workers)


@dataclass(frozen=True)
class _Runner:
    """Where per-clip jobs run (:mod:`quatmotion.parallel`) and how progress is reported."""

    runner: Runner | None
    report: Progress

    def each(
        self, step: str, func: Callable[..., Any], items: Sequence[Any], context: Any
    ) -> Iterator[Any]:
        """``func(item, context)`` of every item, streamed in input order.

        Raises
        ------
        ValueError
            Naming the first item whose job failed (nothing is written then).
        """
        runner = self.runner
        if runner is None:
            # one clip: a process pool would only add its start-up
            runner = Runner.inline() if len(items) < 2 else Runner.resolve(None)
        self.report(step, 0, len(items))
        progress = lambda done, total: self.report(step, done, total)  # noqa: E731
        with runner.map(func, items, context=context, progress=progress) as stream:
            for outcome in stream:
                if outcome.failure is not None:
                    raise ValueError(str(outcome.failure))
                yield outcome.value


# ---------------------------------------------------------------------------------- coding
@dataclass
class _Coded:
    """A library coded at one quality: the clips' chunks spooled to a temporary file (prefix
    then payload, in clip order), the models, and after verification every clip's errors."""

    models: SharedModels
    blobs: list[bytes]
    spool: Any  # a named temporary file
    spans: list[tuple[int, int, int]] = field(default_factory=list)  # offset, prefix, payload
    corrections: list[int] = field(default_factory=list)
    errors: list[ClipErrors] = field(default_factory=list)

    @property
    def chunk_sizes(self) -> list[int]:
        return [p + n for _, p, n in self.spans]

    def payload_ref(self, i: int) -> tuple[str, int, int]:
        offset, prefix, length = self.spans[i]
        return self.spool.name, offset + prefix, length

    def chunks(self) -> Iterator[bytes]:
        """Every clip's chunk payload, read back from the spool in order."""
        self.spool.flush()
        with open(self.spool.name, "rb") as file:
            for offset, prefix, length in self.spans:
                file.seek(offset)
                yield file.read(prefix + length)

    def close(self) -> None:
        self.spool.close()


def _spool(models: SharedModels, blobs: list[bytes], coded: Iterable[CodedClip]) -> _Coded:
    import tempfile

    from quatmotion.parallel import scratch

    out = _Coded(models, blobs, tempfile.NamedTemporaryFile(prefix=scratch.prefix("spool")))  # noqa: SIM115 (closed by _Coded.close)
    try:
        offset = 0
        for clip in coded:
            out.spool.write(clip.prefix)
            out.spool.write(clip.payload)
            out.spans.append((offset, len(clip.prefix), len(clip.payload)))
            offset += len(clip.prefix) + len(clip.payload)
            out.corrections.append(clip.corrections)
            if clip.errors is not None:
                out.errors.append(clip.errors)
        out.spool.flush()
    except BaseException:
        out.close()
        raise
    return out


@dataclass
class _Job:
    """One build or add: the method, the clips planned, where their jobs run."""

    method: Method
    inputs: _Inputs
    plan: _Plan
    settings: CompressSettings
    runner: _Runner

    def encode(self, quality: float, max_error: float | None, *, verify: bool) -> _Coded:
        """Learn the shared models on the sample, then code every clip in a worker."""
        self.runner.report("learn", 0, 1)
        models, blobs = _fit(
            self.method, self.plan, quality, max_error, self.settings.seed, self.settings.read
        )
        tasks = _tasks(self.inputs, self.plan, verify=verify)
        return _spool(models, blobs, self.runner.each("encode", code_clip, tasks, models))

    def verify(self, coded: _Coded, max_error: float | None) -> _Coded:
        """Decode, measure and repair every clip of a library coded without verification."""
        from dataclasses import replace

        models = replace(coded.models, quality=0.0, max_error=max_error)
        tasks = [
            replace(task, payload=coded.payload_ref(i))
            for i, task in enumerate(_tasks(self.inputs, self.plan, verify=True))
        ]
        try:
            return _spool(models, coded.blobs, self.runner.each("verify", code_clip, tasks, models))
        finally:
            coded.close()


def _chunk_size(n: int) -> int:
    """Bytes of a chunk of an ``n``-byte payload (tag, length, payload, CRC)."""
    return 1 + len(Writer().uvarint(n).bytes()) + n + 4


@dataclass
class _Layout:
    """The file's tables and shared chunks around the clips' chunks."""

    method: str
    settings: CompressSettings
    table: _SkeletonTable
    layout_skeletons: list[int]
    records: list[bytes]
    old_layout_chunks: list[bytes]
    old_entries: list[ClipEntry]
    first_layout: int = 0

    def header(self, entries: list[ClipEntry]) -> Header:
        return Header(
            self.method,
            tuple(self.table.records),
            tuple(self.table.skeletons),
            tuple(LayoutEntry(s) for s in self.layout_skeletons),
            tuple(self.old_entries + entries),
            json.dumps(self.settings.to_dict(), sort_keys=True, separators=(",", ":")).encode(),
        )

    def layout_chunks(self, plan: _Plan, coded: _Coded) -> list[bytes]:
        return self.old_layout_chunks + _layout_chunks(
            plan.sample, EncodedLibrary(coded.blobs, []), self.first_layout
        )

    def file_size(
        self, inputs: _Inputs, plan: _Plan, clip_skeleton: list[int], coded: _Coded, old: int = 0
    ) -> int:
        """The size of the file ``coded`` makes (declared errors of 0: sizing a try); ``old``
        the bytes of the clip chunks already in the file."""
        entries = _clip_entries(inputs, plan, clip_skeleton, None)
        chunks = [self.header(entries).to_bytes(), *self.records, *self.layout_chunks(plan, coded)]
        size = len(MAGIC) + 2 + sum(_chunk_size(len(c)) for c in chunks) + old
        return size + sum(_chunk_size(n) for n in coded.chunk_sizes)


def _clip_context(library: PreparedLibrary, i: int) -> ClipContext:
    clip = library.clips[i]
    info = library.layouts[clip.layout]
    active = np.ones(info.layout.n_channels, dtype=bool)
    for k in range(len(info.layout.translation_joints)):
        if clip.at_rest[k]:
            active[info.layout.translation_columns(k)] = False
    return ClipContext(info, clip.motion.skeleton, clip.motion.n_frames, clip.motion.fps, active)


def _verify_clip(
    method: Method,
    library: PreparedLibrary,
    i: int,
    payload: bytes,
    model: Any,
    max_error: float | None,
) -> tuple[Corrections, ClipErrors]:
    """Decode clip ``i`` from its bytes, correct the frames over the bound, measure it."""
    clip = library.clips[i]
    info = library.layouts[clip.layout]
    context = _clip_context(library, i)
    X = method.decode(model, payload, context)
    fix = Corrections.empty()
    if max_error is not None:
        fix = find_corrections(
            clip.channels,
            X,
            clip.world,
            clip.motion.skeleton,
            info,
            clip.at_rest,
            context.active,
            max_error,
            library.vertices,
        )
        fix.apply(X, correction_lever(info))
    return fix, clip_errors(clip.world, library.motion_of(i, X))


def _clip_entries(
    inputs: _Inputs, plan: _Plan, clip_skeleton: list[int], errors: list[ClipErrors] | None
) -> list[ClipEntry]:
    """Every clip's index entry; declared errors of 0 where none are given yet (sizing a
    try)."""
    entries = []
    for i, scan in enumerate(inputs.scans):
        err = errors[i] if errors else None
        entries.append(
            ClipEntry(
                scan.name,
                clip_skeleton[i],
                plan.layout_of[i],
                scan.n_frames,
                scan.fps,
                scan.source[0],
                scan.source[1],
                err.max_joint if err else 0.0,
                err.arms if err else 0.0,
                scan.ref,
            )
        )
    return entries


def _layout_chunks(library: PreparedLibrary, encoded: EncodedLibrary, start: int) -> list[bytes]:
    """``L`` payloads: raw deflate of the shared layout part and the method's model."""
    out = []
    for k in range(start, len(library.layouts)):
        compressor = zlib.compressobj(9, zlib.DEFLATED, -15, 9)
        data = library.layouts[k].to_bytes() + encoded.models[k]
        out.append(compressor.compress(data) + compressor.flush())
    return out


def _write(
    out: Path | None,
    layout: _Layout,
    entries: list[ClipEntry],
    layout_chunks: list[bytes],
    clip_chunks: Iterable[bytes],
) -> bytes | None:
    """The write step: the header and every chunk (:func:`write_container`), the clips'
    chunks streamed from their spool into the file, written atomically; the bytes when
    ``out`` is None."""
    header = layout.header(entries)
    if out is None:
        buffer = io.BytesIO()
        write_container(buffer, header, layout.records, layout_chunks, clip_chunks)
        return buffer.getvalue()
    with atomic_output(out) as temp, open(temp, "wb") as file:
        write_container(file, header, layout.records, layout_chunks, clip_chunks)
    return None


def _search_ratio(
    job: _Job, ratio: float, size_of: Callable[[_Coded], int]
) -> tuple[float, _Coded]:
    """The smallest quality knob (best fidelity) whose file fits ``source / ratio``: doubling
    or halving until the target is bracketed, then geometric bisection."""
    method, scans = job.method, job.inputs.scans
    target = sum(s.source[0] or s.text_bytes for s in scans) / ratio
    # the sizes below are measured with zeros for the declared errors, which deflate better
    # than the final values: keep room for their 8 bytes per clip
    target -= 8 * len(scans) + 8
    fits: set[float] = set()
    best: tuple[float, _Coded] | None = None  # the smallest quality that fits, kept
    too_big: set[float] = set()
    q = method.default_quality
    try:
        for _ in range(24):
            coded = job.encode(q, None, verify=False)
            if size_of(coded) <= target:
                fits.add(q)
                if best is None or q < best[0]:
                    if best is not None:
                        best[1].close()
                    best = (q, coded)
                else:
                    coded.close()
            else:
                too_big.add(q)
                coded.close()
            smallest_fit = min(fits, default=None)
            largest_miss = max(
                (b for b in too_big if smallest_fit is None or b < smallest_fit), default=None
            )
            if smallest_fit is None:
                q *= 2.0
            elif largest_miss is None:
                q /= 2.0
            elif smallest_fit / largest_miss < 1.06:
                break
            else:
                q = float(np.sqrt(smallest_fit * largest_miss))
    except BaseException:
        if best is not None:
            best[1].close()
        raise
    if best is None:
        raise ValueError(f"no setting of {method.name} reaches ratio {ratio:g}")
    return best


def _text_bytes(motion: Motion) -> int:
    """Size of the AMC (ASF skeletons) or BVH text the writers would produce."""
    from quatmotion.io import bvh_text
    from quatmotion.io.asf_amc import amc_channel_values

    if motion.skeleton.extras.get("format") == "asf":
        names, counts, values = amc_channel_values(motion)
        per_frame = sum(len(n) + 1 for n in names) + sum(len(f"{v:.6g}") + 1 for v in values[0])
        return per_frame * motion.n_frames
    return len(bvh_text(motion))


def _details(
    data: bytes | None, method: str, inputs: _Inputs, coded: _Coded, started: float, quality: float
) -> dict[str, Any]:
    """What a build or an add made, per clip coded (``data``: the file's bytes, when it was
    written to no path)."""
    details: dict[str, Any] = {} if data is None else {"data": data}
    details.update({
        "method": method,
        "quality": quality,
        "clip_errors": list(coded.errors),
        "clip_bytes": coded.chunk_sizes,
        "corrections": list(coded.corrections),
        "source_bytes": [s.source[0] for s in inputs.scans],
        "raw_bytes": [s.raw_bytes for s in inputs.scans],
        "seconds": time.perf_counter() - started,
    })  # fmt: skip
    return details


def _encode_step(job: _Job, size_of: Callable[[_Coded], int]) -> tuple[float, _Coded]:
    """Fit, encode, verify and repair, by the settings' target: a ratio (search the quality
    knob, then verify), a bound the method cannot aim at itself (try four quality steps and
    keep the smallest file after repair), or one pass."""
    codec, settings = job.method, job.settings
    q = settings.quality if settings.quality is not None else codec.default_quality
    max_error = settings.max_error
    if settings.ratio is not None:
        q, coded = _search_ratio(job, settings.ratio, size_of)
        return q, job.verify(coded, None)
    if max_error is not None and not codec.controls_bound and settings.quality is None:
        best: tuple[int, float, _Coded] | None = None
        try:
            for scale in (1.0, 0.5, 0.25, 0.125):
                coded = job.encode(q * scale, max_error, verify=True)
                size = size_of(coded)
                if best is None or size < best[0]:
                    if best is not None:
                        best[2].close()
                    best = (size, q * scale, coded)
                else:
                    coded.close()
        except BaseException:
            if best is not None:
                best[2].close()
            raise
        assert best is not None
        return best[1], best[2]
    return q, job.encode(q, max_error, verify=True)


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
    runner_ = _Runner(runner, report)
    # 1. scan (in the workers)
    inputs = _scan_step(sources, settings, skip, source_sizes, on_doubt, runner_)
    # 2. store the skeletons
    table = _SkeletonTable()
    _admit(inputs, table, skip)
    clip_skeleton = [table.index(s.skeleton) for s in inputs.scans]
    # 3. plan: layouts, the sample read and the layouts fitted on it
    plan = _plan(inputs, [], settings, settings.bound_on == "vertices", report)
    layout = _Layout(
        codec.name, settings, table, [table.index(info.skeleton) for info in plan.sample.layouts],
        table.new_records, [], [],
    )  # fmt: skip
    # 4. fit the shared models, code every clip in a worker (encode, verify, repair)
    job = _Job(codec, inputs, plan, settings, runner_)
    q, coded = _encode_step(job, lambda c: layout.file_size(inputs, plan, clip_skeleton, c))
    # 5. assemble and write, the clips' chunks streamed from the spool
    try:
        path = None if out is None else Path(out)
        entries = _clip_entries(inputs, plan, clip_skeleton, coded.errors)
        data = _write(path, layout, entries, layout.layout_chunks(plan, coded), coded.chunks())
        details = _details(data, codec.name, inputs, coded, t0, q)
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
    holds is an error. The file keeps the settings it was made with. A version 1 file is
    rewritten in the current version. Another writer of ``path`` at the same time is refused
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
        table = _SkeletonTable(
            list(old.records),
            [archive.record_text(k) for k in range(len(old.records))],
            list(old.skeletons),
            [archive.skeleton(k) for k in range(len(old.skeletons))],
        )
        layouts = [archive.layout(k) for k in range(len(old.layouts))]
        old_records, old_layout_chunks = archive.shared_payloads()
    runner_ = _Runner(runner, report)
    inputs = _scan_step(sources, settings, False, None, on_doubt, runner_)
    known = {r.sha256: r for r in old_refs}
    skipped = [known[r.sha256] for r in inputs.refs if r.sha256 in known]
    inputs.select([i for i, r in enumerate(inputs.refs) if r.sha256 not in known])
    for i, scan in enumerate(inputs.scans):
        ref = _name_apart(scan.ref, old_refs, path)
        inputs.scans[i] = replace(scan, ref=ref, name=ref.name)
    if not inputs.scans:
        return BuildReport(path=path, skipped=skipped, settings=stored, details={})
    codec = get_method(old.method)
    _admit(inputs, table, False)
    clip_skeleton = [table.index(s.skeleton) for s in inputs.scans]
    plan = _plan(inputs, layouts, settings, False, report)
    n_old = len(layouts)
    layout_skeletons = [lay.skeleton for lay in old.layouts] + [
        table.index(info.skeleton) for info in plan.sample.layouts[n_old:]
    ]
    q = settings.quality if settings.quality is not None else codec.default_quality
    job = _Job(codec, inputs, plan, settings, runner_)
    coded = job.encode(q, settings.max_error, verify=True)
    old_entries = [
        entry if entry.ref is not None else _with_ref(entry, ref)
        for entry, ref in zip(old.clips, old_refs, strict=True)
    ]
    layout = _Layout(
        old.method, stored, table, layout_skeletons, old_records + table.new_records,
        old_layout_chunks, old_entries, n_old,
    )  # fmt: skip
    try:
        entries = _clip_entries(inputs, plan, clip_skeleton, coded.errors)
        with ArchiveReader.open(path) as archive:
            chunks = itertools.chain(archive.clip_payloads(), coded.chunks())
            _write(path, layout, entries, layout.layout_chunks(plan, coded), chunks)
        details = _details(None, codec.name, inputs, coded, t0, q)
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


# ---------------------------------------------------------------------------------- before 0.4.0
def compress(
    clips: Sequence[Motion | str | Path],
    out: str | Path | None = None,
    *,
    max_error: float | None = None,
    ratio: float | None = None,
    method: str = "best",
    quality: float | None = None,
    bound_on: str = "joints",
    skeleton: Skeleton | str | Path | None = None,
    units: str | float | None = None,
    sources: Sequence[tuple[int, str]] | None = None,
    seed: int = 0,
    progress: Progress | None = None,
    workers: int | None = None,
    scheduler: str | Scheduler | None = None,
    on_error: str = "raise",
    on_doubt: OnDoubt | None = None,
) -> CompressionResult:
    """The name before 0.4.0: :meth:`Archive.build` with a :class:`CompressSettings` made of
    the keywords (``max_error`` and ``ratio`` both None: no bound, as before). ``skeleton`` may
    only be a path now (an ASF file or a folder)."""
    if isinstance(skeleton, Skeleton):
        raise TypeError("skeleton must be the path of an ASF file or folder")
    settings = CompressSettings(
        max_error=max_error, ratio=ratio, method=method, quality=quality, bound_on=bound_on,
        seed=seed, on_error=on_error,
        read=ReadSettings(units=units, skeleton=None if skeleton is None else str(skeleton)),
    )  # fmt: skip
    report = build_library(
        clips, out, settings, runner=runner_of(workers, scheduler), progress=progress,
        on_doubt=on_doubt, source_sizes=sources,
    )  # fmt: skip
    return CompressionResult.from_report(report)


def append(
    path: str | Path,
    clips: Sequence[Motion | str | Path],
    *,
    max_error: float | None = None,
    quality: float | None = None,
    skeleton: Skeleton | str | Path | None = None,
    units: str | float | None = None,
    seed: int = 0,
    progress: Progress | None = None,
    workers: int | None = None,
    scheduler: str | Scheduler | None = None,
    on_doubt: OnDoubt | None = None,
) -> CompressionResult:
    """The name before 0.4.0: :meth:`Archive.add` with the keywords as settings."""
    if isinstance(skeleton, Skeleton):
        raise TypeError("skeleton must be the path of an ASF file or folder")
    settings = CompressSettings(
        max_error=max_error, quality=quality, seed=seed,
        read=ReadSettings(units=units, skeleton=None if skeleton is None else str(skeleton)),
    )  # fmt: skip
    report = add_to_library(
        path, clips, settings, runner=runner_of(workers, scheduler), progress=progress,
        on_doubt=on_doubt,
    )  # fmt: skip
    if not report.added:
        raise ValueError(f"{path}: already holds every clip given")
    return CompressionResult.from_report(report)
