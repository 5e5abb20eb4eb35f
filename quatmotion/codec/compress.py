"""Compression: clips in, a ``.qmz`` library out (the orchestrator, as named steps).

:func:`compress` reads as the steps it takes: load the inputs, store the skeletons, prepare the
library (layouts, channels, weights), encode with the chosen method (searching its quality knob
for ``ratio``), decode every clip back and repair the frames over ``max_error``, assemble the
container, write it atomically. :func:`append` adds clips to an existing file without
re-encoding the clips already in it (their chunks are copied byte for byte).
"""

from __future__ import annotations

import io
import time
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from quatmotion._atomic import atomic_write_bytes
from quatmotion.codec.archive import open_archive
from quatmotion.codec.container import (
    FORMAT_VERSION,
    MAGIC,
    ClipEntry,
    Header,
    LayoutEntry,
    RecordEntry,
    SkeletonEntry,
    write_chunk,
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
from quatmotion.codec.skeletons import deflate_text, same_skeleton, skeleton_record
from quatmotion.errors import FormatError
from quatmotion.io import Doubt, find_motion_files, implausible_values, read_motion
from quatmotion.motion import Motion, Skeleton
from quatmotion.parallel import Scheduler, run_batch

__all__ = [
    "DEFAULT_MAX_ERROR_CM",
    "FIT_SAMPLE_CLIPS",
    "ClipJob",
    "CodedClip",
    "CompressionResult",
    "append",
    "clip_jobs",
    "code_clip",
    "compress",
]

DEFAULT_MAX_ERROR_CM = 1.0
"""The bound the command line and the viewer use when none is given: every joint within 1 cm."""

FIT_SAMPLE_CLIPS = 256
"""Most clips of one skeleton structure its shared model is learned on; a larger library
learns on a seeded sample of this many and encodes every clip with it."""

Progress = Callable[[str, int, int], None]


@dataclass
class CompressionResult:
    """What :func:`compress` made.

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


# ---------------------------------------------------------------------------------- inputs
def _load_inputs(
    items: Sequence[Motion | str | Path],
    skeleton: Skeleton | str | Path | None,
    known: Sequence[tuple[int, str]] | None = None,
    failed: list[tuple[str, str]] | None = None,
    units: str | float | None = None,
    on_doubt: Callable[[str, Doubt], None] | None = None,
    report: Progress | None = None,
) -> tuple[list[Motion], list[tuple[int, str]]]:
    """Motions and their source sizes from clips, files and folders (AMC files on
    ``skeleton``, BVH files in ``units``). With ``failed``, a file that cannot be read is noted
    there (file, reason) and left out instead of raising; ``on_doubt(file, doubt)`` hears what
    is doubtful in a file read (:func:`quatmotion.io.implausible_values`); ``report`` hears
    ``("read", done, total)`` as files are read."""
    motions: list[Motion] = []
    sources: list[tuple[int, str]] = []
    paths: list[Path] = []
    in_memory = [item for item in items if isinstance(item, Motion)]
    if known is not None and len(known) != len(in_memory):
        raise ValueError(f"sources gives {len(known)} sizes for {len(in_memory)} clips")
    for item in items:
        if isinstance(item, Motion):
            motions.append(item)
            sources.append(tuple(known[len(motions) - 1]) if known is not None else (0, ""))
        else:
            paths.append(Path(item))
    files = find_motion_files(paths) if paths else []
    if report is not None and files:
        report("read", 0, len(files))
    for n_read, path in enumerate(files, 1):
        if report is not None and (n_read == len(files) or n_read % 16 == 0):
            report("read", n_read, len(files))
        try:
            amc = path.suffix.lower() == ".amc"
            motion = read_motion(path, skeleton if amc else None, units=None if amc else units)
            size = path.stat().st_size
        except (FormatError, OSError, ValueError) as error:
            if failed is None:
                raise
            failed.append((str(path), str(error).splitlines()[0]))
            continue
        for doubt in implausible_values(motion) if on_doubt is not None else ():
            on_doubt(str(path), doubt)
        motions.append(motion)
        sources.append((size, path.suffix.lower().lstrip(".")))
    if not motions:
        raise ValueError("nothing to compress: no clips given")
    return motions, sources


def _admit(
    motions: list[Motion],
    sources: list[tuple[int, str]],
    table: _SkeletonTable,
    failed: list[tuple[str, str]],
) -> tuple[list[Motion], list[tuple[int, str]]]:
    """The clips that can be stored (frames, a name, a skeleton the format can record); the
    others are noted in ``failed`` and left out."""
    kept, kept_sources = [], []
    for motion, source in zip(motions, sources, strict=True):
        try:
            if motion.n_frames == 0:
                raise ValueError("no frames")
            if not motion.name:
                raise ValueError("every clip needs a name (its file stem)")
            table.index(motion.skeleton)
        except ValueError as error:
            failed.append((motion.name or "<unnamed clip>", str(error).splitlines()[0]))
            continue
        kept.append(motion)
        kept_sources.append(source)
    if not kept:
        name, reason = failed[0]
        raise ValueError(f"nothing to compress: every input failed ({name}: {reason})")
    return kept, kept_sources


def _validate(motions: list[Motion], max_error: float | None, ratio: float | None) -> None:
    if max_error is not None and ratio is not None:
        raise ValueError("give max_error or ratio, not both")
    if max_error is not None and not (np.isfinite(max_error) and max_error > 0):
        raise ValueError(f"max_error must be a positive number of centimetres, got {max_error}")
    if ratio is not None and not (np.isfinite(ratio) and ratio > 1):
        raise ValueError(f"ratio must be a number above 1, got {ratio}")
    names = [m.name for m in motions]
    for m in motions:
        if m.n_frames == 0:
            raise ValueError(f"clip {m.name!r} has no frames")
        if not m.name:
            raise ValueError("every clip needs a name (its file stem)")
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise ValueError(f"clip names must be unique; repeated: {', '.join(dup[:5])}")


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


def _fit_members(library: PreparedLibrary, seed: int) -> list[list[int]]:
    """The clips each layout's shared model is learned on: all of them, or a seeded sample of
    :data:`FIT_SAMPLE_CLIPS` in a larger library (learning time then stays flat in its size)."""
    rng = np.random.default_rng(seed)
    out = []
    for members in library.members:
        if len(members) <= FIT_SAMPLE_CLIPS:
            out.append(list(members))
        else:
            out.append(sorted(int(i) for i in rng.choice(members, FIT_SAMPLE_CLIPS, replace=False)))
    return out


@dataclass(frozen=True)
class _Runner:
    """Where per-clip jobs run (:mod:`quatmotion.parallel`) and how progress is reported."""

    workers: int | None
    scheduler: str | Scheduler | None
    report: Progress

    def run(self, step: str, jobs: list[ClipJob]) -> list[CodedClip]:
        """``code_clip`` of every job, in input order.

        Raises
        ------
        ValueError
            Naming the first clip whose job failed (nothing is written then).
        """
        scheduler = self.scheduler
        if scheduler is None and self.workers is None and len(jobs) < 2:
            scheduler = "inline"  # one clip: a process pool would only add its start-up
        self.report(step, 0, len(jobs))
        result = run_batch(
            code_clip,
            jobs,
            workers=self.workers,
            scheduler=scheduler,
            progress=lambda done, total: self.report(step, done, total),
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
    fitted = method.fit_models(
        library, _fit_members(library, seed), quality=quality, max_error=max_error, seed=seed,
        models=given,
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
    coded = runner.run("encode", jobs)
    out = _Coded(EncodedLibrary(blobs, [c.payload for c in coded]), models)
    if verify:
        out.corrections = [c.corrections for c in coded]
        out.errors = [c.errors for c in coded]
    return out


def clip_jobs(
    clips: Sequence[Motion],
    *,
    max_error: float | None = DEFAULT_MAX_ERROR_CM,
    method: str = "best",
    quality: float | None = None,
    seed: int = 0,
) -> list[ClipJob]:
    """The per-clip jobs :func:`compress` hands to :mod:`quatmotion.parallel` for ``clips``
    (shared models learned, every clip prepared): :func:`code_clip` over them gives the
    clips' payloads, corrections and errors. For measuring the batch step on its own (``bench
    scale``); :func:`compress` is the way to make a file."""
    codec = get_method(method)
    motions = list(clips)
    _validate(motions, max_error, None)
    library = prepare_library(motions, [(0, "")] * len(motions))
    q = quality if quality is not None else codec.default_quality
    jobs: list[ClipJob] = []

    class _Keep(_Runner):
        """Keeps the jobs instead of running them."""

        def run(self, step: str, planned: list[ClipJob]) -> list[CodedClip]:
            jobs.extend(planned)
            return [CodedClip(b"", Corrections.empty(), None) for _ in planned]

    keep = _Keep(1, "inline", lambda *_: None)
    _encode_once(codec, library, q, max_error, seed, [], keep, verify=True)
    return jobs


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
    table: _SkeletonTable,
    layout_skeletons: list[int],
    entries: list[ClipEntry],
    record_chunks: list[bytes],
    layout_chunks: list[bytes],
    clip_chunks: list[bytes],
) -> bytes:
    header = Header(
        method,
        tuple(table.records),
        tuple(table.skeletons),
        tuple(LayoutEntry(s) for s in layout_skeletons),
        tuple(entries),
    )
    out = io.BytesIO()
    out.write(MAGIC + FORMAT_VERSION.to_bytes(2, "little"))
    write_chunk(out, b"H", header.to_bytes())
    for tag, chunks in ((b"S", record_chunks), (b"L", layout_chunks), (b"C", clip_chunks)):
        for payload in chunks:
            write_chunk(out, tag, payload)
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


def _result(
    data: bytes,
    path: Path | None,
    method: str,
    library: PreparedLibrary,
    errors: list[ClipErrors],
    corrections: list[Corrections],
    started: float,
    quality: float,
    *,
    first: int = 0,
    failed: list[tuple[str, str]] | None = None,
) -> CompressionResult:
    """What :func:`compress` or :func:`append` made; ``first`` is the file's index of the
    library's first clip (the clips before it were already in the file)."""
    with open_archive(data) as archive:
        clip_bytes = [archive.chunk_bytes(i) for i in range(first, len(archive))]
    return CompressionResult(
        data,
        path,
        method,
        errors,
        clip_bytes,
        [c.source_bytes for c in library.clips],
        [
            4 * sum(len(ch) for ch in c.motion.skeleton.channels) * c.motion.n_frames
            for c in library.clips
        ],
        time.perf_counter() - started,
        quality,
        [len(c) for c in corrections],
        list(failed or []),
    )


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
    on_doubt: Callable[[str, Doubt], None] | None = None,
) -> CompressionResult:
    """Compress clips into one ``.qmz`` library.

    Parameters
    ----------
    clips : sequence of Motion, or paths of files and folders
        AMC (with its ASF found by name, or ``skeleton``) and BVH files; folders are searched.
    out : str or Path, optional
        Where to write the file (atomically). Without it only the bytes are returned.
    max_error : float, optional
        Bound on the position error of every joint and end site of every frame, centimetres.
        The encoder checks by decoding and repairs what exceeds it.
    ratio : float, optional
        Target compression ratio against the source text (or the writers' text for clips
        given in memory) instead of a bound; the errors reached are reported.
    method : {"best", "spline", "naive", "qssd", "ksvd"}
    quality : float, optional
        The method's size knob (its quantiser step; larger means smaller files). With
        ``max_error`` it caps the step the rate control may use (``best``, ``spline``) or
        fixes it (the others; without it they try their default and 1/2, 1/4, 1/8 of it and
        keep the smallest file after repair).
    bound_on : {"joints", "vertices"}
        What ``max_error`` bounds: joint and end-site positions, or also the virtual vertices
        3 cm along each joint's axes (the Animation Compression Library's measure).
    skeleton : Skeleton or path, optional
        The ASF for AMC inputs (else each AMC's is found by name).
    units : str or float, optional
        The length unit of BVH inputs (a name of :data:`quatmotion.io.BVH_UNITS` or
        centimetres per unit); ``None`` guesses it from each file (stored with the skeleton,
        which says it was guessed). ``max_error`` holds in the unit the clips are read in.
    sources : sequence of (int, str), optional
        For clips given in memory, the size and format (``"amc"``, ``"bvh"``) of the files
        they came from (stored for ratios and ``ls``).
    seed : int
        Seed of every random choice (dictionary initialisation): same input and seed, same bytes.
    progress : callable, optional
        Called as ``progress(step_name, done, total)``.
    workers, scheduler : optional
        Where the per-clip jobs (encode, decode, repair) run, as for
        :func:`quatmotion.parallel.run_batch`: by default a local process pool on every core
        (or ``QUATMOTION_SCHEDULER``), ``"inline"`` in this process, ``tcp://HOST:PORT`` a Dask
        cluster. The shared models are learned here first (on at most
        :data:`FIT_SAMPLE_CLIPS` clips of each skeleton structure) and the file is assembled
        here at the end: every scheduler and number of workers gives the same bytes.
    on_error : {"raise", "skip"}
        What a file that cannot be read, or a clip that cannot be stored, does: stop the
        compression (nothing is written), or be left out and listed in
        :attr:`CompressionResult.failed`.
    on_doubt : callable, optional
        ``on_doubt(file, doubt)`` for what is doubtful in an input file read
        (:func:`quatmotion.io.implausible_values`: a guessed unit near a boundary, a frame rate
        motion capture does not run at...), as the file is read.

    Returns
    -------
    CompressionResult

    Raises
    ------
    ValueError
        Bad options, clips without frames or with duplicate names, a skeleton that cannot be
        stored exactly. No file is written then.
    FormatError
        A malformed input file (naming it).
    """
    t0 = time.perf_counter()
    report = progress or (lambda *_: None)
    if on_error not in ("raise", "skip"):
        raise ValueError(f"on_error must be 'raise' or 'skip', got {on_error!r}")
    if bound_on not in ("joints", "vertices"):
        raise ValueError(f"bound_on must be 'joints' or 'vertices', got {bound_on!r}")
    codec = get_method(method)
    failed: list[tuple[str, str]] = []
    skip = on_error == "skip"
    motions, sources = _load_inputs(
        clips, skeleton, sources, failed if skip else None, units, on_doubt, report
    )
    table = _SkeletonTable()
    if skip:
        motions, sources = _admit(motions, sources, table, failed)
    _validate(motions, max_error, ratio)
    clip_skeleton = [table.index(m.skeleton) for m in motions]
    report("prepare", 0, len(motions))
    library = prepare_library(
        motions,
        sources,
        vertices=bound_on == "vertices",
        progress=lambda done, total: report("prepare", done, total),
    )
    layout_skeletons = [table.index(info.skeleton) for info in library.layouts]
    q = quality if quality is not None else codec.default_quality

    def file_size(encoded: EncodedLibrary, corrections=None) -> int:
        return len(_build(encoded, corrections, None))

    def _build(encoded, corrections, errors) -> bytes:
        entries, chunks = _clip_chunks(library, clip_skeleton, encoded, corrections, errors)
        return _assemble(
            codec.name,
            table,
            layout_skeletons,
            entries,
            table.new_records,
            _layout_chunks(library, encoded, 0),
            chunks,
        )

    runner = _Runner(workers, scheduler, report)
    if ratio is not None:
        q, coded = _search_ratio(codec, library, ratio, seed, file_size, runner)
        coded = _verify(codec, library, coded, None, runner)
    elif max_error is not None and not codec.controls_bound and quality is None:
        best = None
        for scale in (1.0, 0.5, 0.25, 0.125):
            coded = _encode_once(
                codec, library, q * scale, max_error, seed, [], runner, verify=True
            )
            size = file_size(coded.encoded, coded.corrections)
            if best is None or size < best[0]:
                best = (size, q * scale, coded)
        _, q, coded = best
    else:
        coded = _encode_once(codec, library, q, max_error, seed, [], runner, verify=True)
    encoded, corrections, errors = coded.encoded, coded.corrections, coded.errors
    data = _build(encoded, corrections, errors)
    path = None
    if out is not None:
        path = Path(out)
        atomic_write_bytes(path, data)
    report("done", len(motions), len(motions))
    return _result(data, path, codec.name, library, errors, corrections, t0, q, failed=failed)


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
    on_doubt: Callable[[str, Doubt], None] | None = None,
) -> CompressionResult:
    """Add clips to an existing ``.qmz`` file (rewritten atomically).

    The clips already in the file keep their chunks byte for byte; the new ones are coded with
    the file's method and with its library models where their skeleton structure is known.
    Names must stay unique. ``skeleton``, ``units``, ``progress``, ``workers``, ``scheduler``
    and ``on_doubt`` are those of :func:`compress`.
    """
    t0 = time.perf_counter()
    path = Path(path)
    motions, sources = _load_inputs(clips, skeleton, None, None, units, on_doubt)
    with open_archive(path) as archive:
        old = archive.header
        old_names = set(archive.names())
        for m in motions:
            if m.name in old_names:
                raise ValueError(f"{path}: already holds a clip named {m.name!r}")
        _validate(motions, max_error, None)
        codec = get_method(old.method)
        table = _SkeletonTable(
            list(old.records),
            [archive.record_text(k) for k in range(len(old.records))],
            list(old.skeletons),
            [archive.skeleton(k) for k in range(len(old.skeletons))],
        )
        layouts = [archive.layout(k) for k in range(len(old.layouts))]
        old_records, old_layout_chunks, old_clip_chunks = archive.payloads()
    clip_skeleton = [table.index(m.skeleton) for m in motions]
    library = prepare_library(motions, sources, [info for info, _ in layouts])
    given = [model for _, model in layouts]
    n_old = len(layouts)
    layout_skeletons = [lay.skeleton for lay in old.layouts] + [
        table.index(info.skeleton) for info in library.layouts[n_old:]
    ]
    q = quality if quality is not None else codec.default_quality
    runner = _Runner(workers, scheduler, progress or (lambda *_: None))
    coded = _encode_once(codec, library, q, max_error, seed, given, runner, verify=True)
    encoded, corrections, errors = coded.encoded, coded.corrections, coded.errors
    new_entries, new_chunks = _clip_chunks(library, clip_skeleton, encoded, corrections, errors)
    entries = list(old.clips) + new_entries
    chunks = list(old_clip_chunks) + new_chunks
    data = _assemble(
        old.method,
        table,
        layout_skeletons,
        entries,
        old_records + table.new_records,
        old_layout_chunks + _layout_chunks(library, encoded, n_old),
        chunks,
    )
    atomic_write_bytes(path, data)
    return _result(
        data, path, codec.name, library, errors, corrections, t0, q, first=len(old.clips)
    )
