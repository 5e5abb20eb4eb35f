"""Compression: clips in, a ``.qmz`` library out (the orchestrator, as named steps).

:func:`build_library` (:meth:`quatmotion.codec.Archive.build`) reads as the steps it takes:
read the clips (:func:`quatmotion.collection.read_clip`, every clip named by
:func:`quatmotion.collection.unique_names`), store their skeletons, prepare the library
(layouts, channels, weights), fit the shared models on a bounded seeded sample, encode every
clip (searching the method's quality knob for ``ratio``), decode every clip back and repair the
frames over ``max_error``, assemble the header and write the container
(:func:`quatmotion.codec.container.write_container`) atomically. :func:`add_to_library`
(:meth:`Archive.add`) adds clips to an existing file without re-encoding the clips already in
it (their chunks are copied byte for byte). :func:`compress` and :func:`append` are the names
before 0.4.0, kept as thin wrappers.
"""

from __future__ import annotations

import io
import json
import time
import zlib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from quatmotion._atomic import atomic_write_bytes
from quatmotion.codec.archive import Archive
from quatmotion.codec.container import (
    ClipEntry,
    Header,
    LayoutEntry,
    RecordEntry,
    SkeletonEntry,
    write_container,
)
from quatmotion.codec.library import PreparedLibrary, prepare_library
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
    ReadSettings,
    find_clips,
    read_clip,
)
from quatmotion.errors import FormatError
from quatmotion.io import Doubt
from quatmotion.motion import Motion, Skeleton
from quatmotion.parallel import Failure, Runner, Scheduler

__all__ = [
    "DEFAULT_MAX_ERROR_CM",
    "FIT_SAMPLE_CLIPS",
    "ClipJob",
    "CodedClip",
    "CompressionResult",
    "add_to_library",
    "append",
    "build_library",
    "code_clip",
    "compress",
    "plan_clip_jobs",
    "runner_of",
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
        return cls(
            d["data"], report.path, d["method"], d["clip_errors"], d["clip_bytes"],
            d["source_bytes"], d["raw_bytes"], d["seconds"], d["quality"], d["corrections"],
            [(str(f.item), f.message) for f in report.failures],
        )  # fmt: skip


# ---------------------------------------------------------------------------------- reading
@dataclass
class _Inputs:
    """The clips read (step 1), each with its reference and its source's size and format."""

    motions: list[Motion] = field(default_factory=list)
    refs: list[ClipRef] = field(default_factory=list)
    sources: list[tuple[int, str]] = field(default_factory=list)
    failures: list[Failure] = field(default_factory=list)
    doubts: list[tuple[ClipRef, str]] = field(default_factory=list)

    def keep(self, motion: Motion, ref: ClipRef, source: tuple[int, str]) -> None:
        self.motions.append(motion)
        self.refs.append(ref)
        self.sources.append(source)

    def fail(self, item: object, error: BaseException) -> None:
        message = getattr(error, "reason", None) or str(error) or type(error).__name__
        if isinstance(error, FormatError):
            message = str(error)
        self.failures.append(Failure(len(self.failures), item, str(message).splitlines()[0]))


def _read_step(
    sources: Iterable[Any],
    read: ReadSettings,
    skip: bool,
    known: Sequence[tuple[int, str]] | None,
    on_doubt: OnDoubt | None,
    report: Progress | None = None,
) -> _Inputs:
    """Every clip of ``sources`` read by :func:`quatmotion.collection.read_clip`, named by the
    collection's rules. With ``skip``, a file that cannot be found, hashed or read is noted in
    the failures and left out instead of raising; ``report`` hears ``("read", done, total)``
    as clips are read."""
    out = _Inputs()
    found_errors: list[tuple[str, str]] = []
    items = [Path(s) if isinstance(s, str) else s for s in sources]
    found = find_clips(items, read, on_error=found_errors if skip else None)
    for path, reason in found_errors:
        out.failures.append(Failure(len(out.failures), path, reason))
    in_memory = [s for s in found if s.path is None]
    if known is not None and len(known) != len(in_memory):
        raise ValueError(f"sources gives {len(known)} sizes for {len(in_memory)} clips")
    sizes = iter(known or ())
    if report is not None and found:
        report("read", 0, len(found))
    for n_read, source in enumerate(found, 1):
        if report is not None and (n_read == len(found) or n_read % 16 == 0):
            report("read", n_read, len(found))
        try:
            motion, ref, doubts = read_clip(source, read)
            size = (0, "") if source.path is None else _source_size(source.path)
        except (FormatError, OSError, ValueError) as error:
            if not skip:
                raise
            out.fail(source, error)
            continue
        if source.path is None and known is not None:
            size = tuple(next(sizes))  # type: ignore[assignment]
        for doubt in doubts:
            out.doubts.append((ref, doubt.message))
            if on_doubt is not None:
                on_doubt(str(source), doubt)
        out.keep(motion, ref, size)
    if not out.motions and not out.failures:
        raise ValueError("nothing to compress: no clips given")
    return out


def _source_size(path: Path) -> tuple[int, str]:
    return path.stat().st_size, path.suffix.lower().lstrip(".")


def _admit(inputs: _Inputs, table: _SkeletonTable, skip: bool) -> None:
    """Keep the clips that can be stored (frames, a skeleton the format can record); the others
    are noted in the failures (``skip``) or raise."""
    kept = _Inputs(failures=inputs.failures, doubts=inputs.doubts)
    for motion, ref, source in zip(inputs.motions, inputs.refs, inputs.sources, strict=True):
        try:
            if motion.n_frames == 0:
                raise ValueError(f"clip {motion.name!r} has no frames")
            table.index(motion.skeleton)
        except ValueError as error:
            if not skip:
                raise
            kept.fail(ref.path or ref.name, error)
            continue
        kept.keep(motion, ref, source)
    if not kept.motions:
        first = kept.failures[0] if kept.failures else None
        raise ValueError(f"nothing to compress: every input failed ({first})")
    inputs.motions, inputs.refs, inputs.sources = kept.motions, kept.refs, kept.sources


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


# ---------------------------------------------------------------------------------- encoding
def _clip_context(library: PreparedLibrary, i: int) -> ClipContext:
    clip = library.clips[i]
    info = library.layouts[clip.layout]
    active = np.ones(info.layout.n_channels, dtype=bool)
    for k in range(len(info.layout.translation_joints)):
        if clip.at_rest[k]:
            active[info.layout.translation_columns(k)] = False
    return ClipContext(info, clip.motion.skeleton, clip.motion.n_frames, clip.motion.fps, active)


@dataclass(frozen=True)
class ClipJob:
    """One clip's share of the encoding: what :func:`code_clip` needs, and nothing of the
    other clips, so the clips of a library are coded in any process with the same bytes.

    Attributes
    ----------
    method : Method
    library : PreparedLibrary
        The clip alone (index 0) with every layout of the library.
    model : object
        The encoder's model of the clip's layout (:meth:`Method.fit_models`).
    decoder_model : object
        The same model as the decoder reads it from the file (:meth:`Method.load_model`).
    quality : float
    max_error : float or None
        The bound the encoder aims at and the repair enforces (``None``: none).
    verify : bool
        Decode the payload, measure it and repair the frames over ``max_error``.
    payload : bytes or None
        Already coded (verify only).
    """

    method: Method
    library: PreparedLibrary
    model: Any
    decoder_model: Any
    quality: float
    max_error: float | None
    verify: bool
    payload: bytes | None = None

    def __str__(self) -> str:  # how a failure names the job
        return f"clip {self.library.clips[0].motion.name!r}"


@dataclass(frozen=True)
class CodedClip:
    """:func:`code_clip`'s result: the clip's payload, and after verification its corrections
    and errors (``None`` without)."""

    payload: bytes
    corrections: Corrections
    errors: ClipErrors | None


def code_clip(job: ClipJob) -> CodedClip:
    """Encode one clip (unless its payload is given), then decode it from its bytes, measure
    it and correct the frames over the bound: the per-clip job of :func:`compress` and
    :func:`append`, run by :mod:`quatmotion.parallel`."""
    payload = job.payload
    if payload is None:
        payload = job.method.encode_clip(
            job.library, 0, job.model, quality=job.quality, max_error=job.max_error
        )
    if not job.verify:
        return CodedClip(payload, Corrections.empty(), None)
    fix, errors = _verify_clip(
        job.method, job.library, 0, payload, job.decoder_model, job.max_error
    )
    return CodedClip(payload, fix, errors)


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


def _one_clip(library: PreparedLibrary, i: int) -> PreparedLibrary:
    """Clip ``i`` alone, with every layout (so its layout index stays valid)."""
    clip = library.clips[i]
    members = [[0] if k == clip.layout else [] for k in range(len(library.layouts))]
    return PreparedLibrary(library.layouts, [clip], members, library.vertices)


def _fit_members(library: PreparedLibrary, seed: int, sample: int) -> list[list[int]]:
    """The clips each layout's shared model is learned on: all of them, or a seeded sample of
    ``sample`` in a larger library (learning time then stays flat in its size)."""
    rng = np.random.default_rng(seed)
    out = []
    for members in library.members:
        if len(members) <= sample:
            out.append(list(members))
        else:
            out.append(sorted(int(i) for i in rng.choice(members, sample, replace=False)))
    return out


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
    fit_sample: int = FIT_SAMPLE_CLIPS

    def run(self, step: str, jobs: list[ClipJob]) -> list[CodedClip]:
        """``code_clip`` of every job, in input order.

        Raises
        ------
        ValueError
            Naming the first clip whose job failed (nothing is written then).
        """
        runner = self.runner
        if runner is None:
            # one clip: a process pool would only add its start-up
            runner = Runner.inline() if len(jobs) < 2 else Runner.resolve(None)
        self.report(step, 0, len(jobs))
        result = runner.run(
            code_clip, jobs, progress=lambda done, total: self.report(step, done, total)
        )
        if result.failures:
            raise ValueError(str(result.failures[0]))
        return list(result.results)


@dataclass
class _Coded:
    """A library coded at one quality: payloads, the models as the decoder reads them, and
    after verification every clip's corrections and errors."""

    encoded: EncodedLibrary
    models: list[Any]
    corrections: list[Corrections] = field(default_factory=list)
    errors: list[ClipErrors] = field(default_factory=list)


def plan_clip_jobs(
    method: Method,
    library: PreparedLibrary,
    quality: float,
    max_error: float | None,
    seed: int,
    given: list,
    *,
    verify: bool,
    fit_sample: int = FIT_SAMPLE_CLIPS,
) -> tuple[list[ClipJob], list[bytes], list[Any]]:
    """The fit step: the shared models learned on a seeded sample of at most ``fit_sample``
    clips per layout (``given`` models of the file appended to are kept), then one
    :class:`ClipJob` per clip. Returns the jobs, the ``L`` chunks' model bytes (empty for a
    given model: already in the file) and the models as the decoder reads them."""
    fitted = method.fit_models(
        library, _fit_members(library, seed, fit_sample), quality=quality, max_error=max_error,
        seed=seed, models=given,
    )  # fmt: skip
    blobs, models = [], []
    for k, info in enumerate(library.layouts):
        if k < len(given) and given[k] is not None:
            blobs.append(b"")  # already in the file
            models.append(given[k])
        else:
            blob = method.model_bytes(fitted[k], info) if fitted[k] is not None else b""
            blobs.append(blob)
            models.append(method.load_model(blob, info) if blob or library.members[k] else None)
    jobs = [
        ClipJob(
            method,
            _one_clip(library, i),
            fitted[clip.layout],
            models[clip.layout],
            quality,
            max_error,
            verify,
        )  # fmt: skip
        for i, clip in enumerate(library.clips)
    ]
    return jobs, blobs, models


def _encode_once(
    method: Method,
    library: PreparedLibrary,
    quality: float,
    max_error: float | None,
    seed: int,
    given: list,
    runner: _Runner,
    *,
    verify: bool,
) -> _Coded:
    """Learn the shared models (on a sample), then code every clip as a per-clip job."""
    runner.report("learn", 0, 1)
    jobs, blobs, models = plan_clip_jobs(
        method, library, quality, max_error, seed, given, verify=verify,
        fit_sample=runner.fit_sample,
    )  # fmt: skip
    coded = runner.run("encode", jobs)
    out = _Coded(EncodedLibrary(blobs, [c.payload for c in coded]), models)
    if verify:
        out.corrections = [c.corrections for c in coded]
        out.errors = [c.errors for c in coded]
    return out


def _verify(
    method: Method, library: PreparedLibrary, coded: _Coded, max_error: float | None, runner
) -> _Coded:
    """Decode, measure and repair every clip of a library coded without verification."""
    jobs = [
        ClipJob(
            method,
            _one_clip(library, i),
            None,
            coded.models[clip.layout],
            0.0,
            max_error,
            True,
            coded.encoded.clips[i],
        )  # fmt: skip
        for i, clip in enumerate(library.clips)
    ]
    checked = runner.run("verify", jobs)
    coded.corrections = [c.corrections for c in checked]
    coded.errors = [c.errors for c in checked]
    return coded


def _clip_chunks(
    library: PreparedLibrary,
    refs: list[ClipRef],
    clip_skeleton: list[int],
    encoded: EncodedLibrary,
    corrections: list[Corrections] | None,
    errors: list[ClipErrors] | None,
) -> tuple[list[ClipEntry], list[bytes]]:
    """Every clip's index entry and ``C`` payload (its prefix of corrections, then the
    method's bytes); declared errors of 0 where none are given yet (sizing a try)."""
    entries, chunks = [], []
    for i, clip in enumerate(library.clips):
        fix = corrections[i] if corrections else Corrections.empty()
        err = errors[i] if errors else None
        chunks.append(write_clip_prefix(clip.at_rest, fix) + encoded.clips[i])
        entries.append(
            ClipEntry(
                clip.motion.name,
                clip_skeleton[i],
                clip.layout,
                clip.motion.n_frames,
                clip.motion.fps,
                clip.source_bytes,
                clip.source_format,
                err.max_joint if err else 0.0,
                err.arms if err else 0.0,
                refs[i],
            )
        )
    return entries, chunks


def _layout_chunks(library: PreparedLibrary, encoded: EncodedLibrary, start: int) -> list[bytes]:
    """``L`` payloads: raw deflate of the shared layout part and the method's model."""
    out = []
    for k in range(start, len(library.layouts)):
        compressor = zlib.compressobj(9, zlib.DEFLATED, -15, 9)
        data = library.layouts[k].to_bytes() + encoded.models[k]
        out.append(compressor.compress(data) + compressor.flush())
    return out


def _assemble(
    method: str,
    settings: CompressSettings,
    table: _SkeletonTable,
    layout_skeletons: list[int],
    entries: list[ClipEntry],
    record_chunks: list[bytes],
    layout_chunks: list[bytes],
    clip_chunks: list[bytes],
) -> bytes:
    """The assemble step: the header (tables, clip index, the settings' JSON) and every chunk,
    as :func:`~quatmotion.codec.container.write_container` writes them."""
    header = Header(
        method,
        tuple(table.records),
        tuple(table.skeletons),
        tuple(LayoutEntry(s) for s in layout_skeletons),
        tuple(entries),
        json.dumps(settings.to_dict(), sort_keys=True, separators=(",", ":")).encode("utf-8"),
    )
    out = io.BytesIO()
    write_container(out, header, record_chunks, layout_chunks, clip_chunks)
    return out.getvalue()


def _search_ratio(
    method: Method,
    library: PreparedLibrary,
    ratio: float,
    seed: int,
    size_of: Callable[[EncodedLibrary], int],
    runner: _Runner,
) -> tuple[float, _Coded]:
    """The smallest quality knob (best fidelity) whose file fits ``source / ratio``: doubling
    or halving until the target is bracketed, then geometric bisection."""
    target = sum(c.source_bytes or _text_bytes(c.motion) for c in library.clips) / ratio
    # the sizes below are measured with zeros for the declared errors, which deflate better
    # than the final values: keep room for their 8 bytes per clip
    target -= 8 * len(library.clips) + 8
    fits: dict[float, _Coded] = {}
    too_big: set[float] = set()
    q = method.default_quality
    for _ in range(24):
        coded = _encode_once(method, library, q, None, seed, [], runner, verify=False)
        if size_of(coded.encoded) <= target:
            fits[q] = coded
        else:
            too_big.add(q)
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
    if not fits:
        raise ValueError(f"no setting of {method.name} reaches ratio {ratio:g}")
    q = min(fits)
    return q, fits[q]


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
    data: bytes,
    method: str,
    library: PreparedLibrary,
    coded: _Coded,
    started: float,
    quality: float,
    first: int = 0,
) -> dict[str, Any]:
    """What a build or an add made, per clip of ``library`` (``first``: the file's index of
    its first clip; the clips before it were already in the file)."""
    with Archive.open(data) as archive:
        clip_bytes = [archive.chunk_bytes(i) for i in range(first, len(archive))]
    return {
        "data": data,
        "method": method,
        "quality": quality,
        "clip_errors": list(coded.errors),
        "clip_bytes": clip_bytes,
        "corrections": [len(c) for c in coded.corrections],
        "source_bytes": [c.source_bytes for c in library.clips],
        "raw_bytes": [
            4 * sum(len(ch) for ch in c.motion.skeleton.channels) * c.motion.n_frames
            for c in library.clips
        ],
        "seconds": time.perf_counter() - started,
    }


def _encode_step(
    codec: Method,
    library: PreparedLibrary,
    settings: CompressSettings,
    runner: _Runner,
    file_size: Callable[..., int],
) -> tuple[float, _Coded]:
    """Fit, encode, verify and repair, by the settings' target: a ratio (search the quality
    knob, then verify), a bound the method cannot aim at itself (try four quality steps and
    keep the smallest file after repair), or one pass."""
    q = settings.quality if settings.quality is not None else codec.default_quality
    seed, max_error = settings.seed, settings.max_error
    if settings.ratio is not None:
        q, coded = _search_ratio(codec, library, settings.ratio, seed, file_size, runner)
        return q, _verify(codec, library, coded, None, runner)
    if max_error is not None and not codec.controls_bound and settings.quality is None:
        best = None
        for scale in (1.0, 0.5, 0.25, 0.125):
            coded = _encode_once(
                codec, library, q * scale, max_error, seed, [], runner, verify=True
            )
            size = file_size(coded.encoded, coded.corrections)
            if best is None or size < best[0]:
                best = (size, q * scale, coded)
        assert best is not None
        return best[1], best[2]
    return q, _encode_once(codec, library, q, max_error, seed, [], runner, verify=True)


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
        Where the per-clip jobs (encode, decode, repair) run (default
        :meth:`Runner.resolve`: a local pool, or ``QUATMOTION_SCHEDULER``). The shared models
        are learned here first (on at most ``settings.fit_sample`` clips of each skeleton
        structure) and the file is assembled here: every scheduler and number of workers gives
        the same bytes.
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
        ``details`` the bytes and per-clip sizes and errors (``data``, ``clip_errors``,
        ``clip_bytes``, ``source_bytes``, ``raw_bytes``, ``quality``, ``seconds``).

    Raises
    ------
    ValueError
        Clips without frames, a skeleton that cannot be stored exactly, nothing to compress.
        No file is written then.
    FormatError
        A malformed input file (naming it), with ``on_error="raise"``.
    """
    t0 = time.perf_counter()
    settings = settings or CompressSettings()
    report = progress or (lambda *_: None)
    codec = get_method(settings.method)
    skip = settings.on_error == "skip"
    # 1. read
    inputs = _read_step(sources, settings.read, skip, source_sizes, on_doubt, report)
    # 2. store the skeletons
    table = _SkeletonTable()
    _admit(inputs, table, skip)
    clip_skeleton = [table.index(m.skeleton) for m in inputs.motions]
    # 3. prepare (layouts, channels, weights)
    report("prepare", 0, len(inputs.motions))
    library = prepare_library(
        inputs.motions,
        inputs.sources,
        vertices=settings.bound_on == "vertices",
        progress=lambda done, total: report("prepare", done, total),
    )
    layout_skeletons = [table.index(info.skeleton) for info in library.layouts]

    def assemble(encoded: EncodedLibrary, corrections=None, errors=None) -> bytes:
        entries, chunks = _clip_chunks(
            library, inputs.refs, clip_skeleton, encoded, corrections, errors
        )
        return _assemble(
            codec.name, settings, table, layout_skeletons, entries, table.new_records,
            _layout_chunks(library, encoded, 0), chunks,
        )  # fmt: skip

    # 4. fit the shared models, encode, verify and repair
    runner_ = _Runner(runner, report, settings.fit_sample)
    q, coded = _encode_step(
        codec, library, settings, runner_, lambda enc, fix=None: len(assemble(enc, fix))
    )
    # 5. assemble, 6. write
    data = assemble(coded.encoded, coded.corrections, coded.errors)
    path = None if out is None else Path(out)
    if path is not None:
        atomic_write_bytes(path, data)
    report("done", len(inputs.motions), len(inputs.motions))
    return BuildReport(
        path=path,
        added=list(inputs.refs),
        failures=inputs.failures,
        doubts=inputs.doubts,
        settings=settings,
        details=_details(data, codec.name, library, coded, t0, q),
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

    The clips already in the file keep their chunks byte for byte; the new ones are coded with
    the file's method, with its library models where their skeleton structure is known, and
    with ``settings`` (default: the file's own, else :class:`CompressSettings`; the method is
    always the file's). A clip whose content hash the file already holds is skipped (in
    ``report.skipped``); a new clip whose name the file holds is an error. The file keeps the
    settings it was made with. A version 1 file is rewritten in the current version.
    """
    t0 = time.perf_counter()
    path = Path(path)
    with Archive.open(path) as archive:
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
        old_records, old_layout_chunks, old_clip_chunks = archive.payloads()
    inputs = _read_step(sources, settings.read, False, None, on_doubt)
    known = {r.sha256: r for r in old_refs}
    skipped = [known[r.sha256] for r in inputs.refs if r.sha256 in known]
    keep = [i for i, r in enumerate(inputs.refs) if r.sha256 not in known]
    inputs.motions = [inputs.motions[i] for i in keep]
    inputs.refs = [_name_apart(r, old_refs, path) for r in (inputs.refs[i] for i in keep)]
    inputs.sources = [inputs.sources[i] for i in keep]
    inputs.motions = [
        m if m.name == r.name else m.renamed(r.name)
        for m, r in zip(inputs.motions, inputs.refs, strict=True)
    ]
    if not inputs.motions:
        return BuildReport(path=path, skipped=skipped, settings=stored, details={})
    codec = get_method(old.method)
    _admit(inputs, table, False)
    clip_skeleton = [table.index(m.skeleton) for m in inputs.motions]
    library = prepare_library(inputs.motions, inputs.sources, [info for info, _ in layouts])
    given = [model for _, model in layouts]
    n_old = len(layouts)
    layout_skeletons = [lay.skeleton for lay in old.layouts] + [
        table.index(info.skeleton) for info in library.layouts[n_old:]
    ]
    q = settings.quality if settings.quality is not None else codec.default_quality
    runner_ = _Runner(runner, progress or (lambda *_: None), settings.fit_sample)
    coded = _encode_once(
        codec, library, q, settings.max_error, settings.seed, given, runner_, verify=True
    )
    new_entries, new_chunks = _clip_chunks(
        library, inputs.refs, clip_skeleton, coded.encoded, coded.corrections, coded.errors
    )
    old_entries = [
        entry if entry.ref is not None else _with_ref(entry, ref)
        for entry, ref in zip(old.clips, old_refs, strict=True)
    ]
    data = _assemble(
        old.method, stored, table, layout_skeletons, old_entries + new_entries,
        old_records + table.new_records,
        old_layout_chunks + _layout_chunks(library, coded.encoded, n_old),
        list(old_clip_chunks) + new_chunks,
    )  # fmt: skip
    atomic_write_bytes(path, data)
    return BuildReport(
        path=path,
        added=list(inputs.refs),
        skipped=skipped,
        doubts=inputs.doubts,
        settings=stored,
        details=_details(data, codec.name, library, coded, t0, q, first=len(old.clips)),
    )


def _name_apart(ref: ClipRef, old: Sequence[ClipRef], path: Path) -> ClipRef:
    """A new clip's reference named apart from the file's clips: where its name is taken by
    another file's clip, the collection's rule (:func:`~quatmotion.collection.unique_names`)
    over the two paths names it; a clip given in memory with a taken name is an error."""
    from dataclasses import replace

    from quatmotion.collection import unique_names

    names = {r.name: r for r in old}
    if ref.name not in names:
        return ref
    other = names[ref.name]
    if ref.path is not None and other.path is not None and other.path != ref.path:
        renamed = unique_names([Path(other.path), Path(ref.path)])[1]
        if renamed not in names:
            return replace(ref, name=renamed)
    raise ValueError(f"{path}: already holds a clip named {ref.name!r}")


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
