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
    read_chunk,
    write_chunk,
)
from quatmotion.codec.library import PreparedLibrary, prepare_library
from quatmotion.codec.methods import ClipContext, EncodedLibrary, Method, get_method
from quatmotion.codec.metrics import ClipErrors, clip_errors
from quatmotion.codec.repair import Corrections, find_corrections, write_clip_prefix
from quatmotion.codec.skeletons import deflate_text, same_skeleton, skeleton_record
from quatmotion.io import find_motion_files, read_motion
from quatmotion.motion import Motion, Skeleton

__all__ = ["CompressionResult", "append", "compress"]

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

    @property
    def size(self) -> int:
        return len(self.data)


# ---------------------------------------------------------------------------------- inputs
def _load_inputs(
    items: Sequence[Motion | str | Path], skeleton: Skeleton | str | Path | None
) -> tuple[list[Motion], list[tuple[int, str]]]:
    """Motions and their source sizes from clips, files and folders."""
    motions: list[Motion] = []
    sources: list[tuple[int, str]] = []
    paths: list[Path] = []
    for item in items:
        if isinstance(item, Motion):
            motions.append(item)
            sources.append((0, ""))
        else:
            paths.append(Path(item))
    for path in find_motion_files(paths) if paths else []:
        motions.append(read_motion(path, skeleton if path.suffix.lower() == ".amc" else None))
        sources.append((path.stat().st_size, path.suffix.lower().lstrip(".")))
    if not motions:
        raise ValueError("nothing to compress: no clips given")
    return motions, sources


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
    records: list[RecordEntry] = field(default_factory=list)
    texts: list[str] = field(default_factory=list)
    skeletons: list[SkeletonEntry] = field(default_factory=list)
    objects: list[Skeleton] = field(default_factory=list)
    new_records: list[bytes] = field(default_factory=list)

    def index(self, skeleton: Skeleton) -> int:
        """The skeleton's entry, adding it (and its record, if its text is new)."""
        for k, s in enumerate(self.objects):
            if s is skeleton or same_skeleton(s, skeleton):
                return k
        kind, text, scale = skeleton_record(skeleton)
        key = (kind, scale, text)
        known = [(r.kind, r.scale, t) for r, t in zip(self.records, self.texts, strict=True)]
        if key in known:
            record = known.index(key)
        else:
            first = next(
                (t for r, t in zip(self.records, self.texts, strict=True) if r.kind == kind), ""
            )
            self.new_records.append(deflate_text(text, first))
            self.records.append(RecordEntry(kind, scale))
            self.texts.append(text)
            record = len(self.records) - 1
        self.skeletons.append(SkeletonEntry(record, skeleton.name))
        self.objects.append(skeleton)
        return len(self.objects) - 1


# ---------------------------------------------------------------------------------- encoding
def _clip_context(library: PreparedLibrary, i: int) -> ClipContext:
    clip = library.clips[i]
    info = library.layouts[clip.layout]
    active = np.ones(info.layout.n_channels, dtype=bool)
    for k in range(len(info.layout.translation_joints)):
        if clip.at_rest[k]:
            active[info.layout.translation_columns(k)] = False
    return ClipContext(info, clip.motion.skeleton, clip.motion.n_frames, clip.motion.fps, active)


def _verify_and_repair(
    method: Method,
    library: PreparedLibrary,
    encoded: EncodedLibrary,
    models: list,
    max_error: float | None,
    first_clip: int = 0,
) -> tuple[list[Corrections], list[ClipErrors]]:
    """Decode every clip from its bytes, measure it, and correct frames over the bound."""
    corrections, errors = [], []
    for i in range(first_clip, len(library.clips)):
        clip = library.clips[i]
        info = library.layouts[clip.layout]
        context = _clip_context(library, i)
        X = method.decode(models[clip.layout], encoded.clips[i - first_clip], context)
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
            fix.apply(X, np.maximum(info.lever, 1e-9))
        corrections.append(fix)
        errors.append(clip_errors(clip.world, library.motion_of(i, X)))
    return corrections, errors


def _loaded_models(method: Method, library: PreparedLibrary, encoded: EncodedLibrary, given: list):
    out = []
    for k, info in enumerate(library.layouts):
        if k < len(given) and given[k] is not None:
            out.append(given[k])
        else:
            blob = encoded.models[k] if k < len(encoded.models) else b""
            out.append(method.load_model(blob, info) if blob or library.members[k] else None)
    return out


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


def _encode_once(method, library, quality, max_error, seed, given):
    encoded = method.encode(library, quality=quality, max_error=max_error, seed=seed, models=given)
    models = _loaded_models(method, library, encoded, given)
    return encoded, models


def _search_ratio(
    method, library, ratio, seed, given, size_of
) -> tuple[float, EncodedLibrary, list]:
    """Bisect the quality knob (geometrically) for the largest file within source / ratio."""
    target = sum(c.source_bytes or _text_bytes(c.motion) for c in library.clips) / ratio
    lo, hi = None, None
    q = method.default_quality
    best = None
    for _ in range(14):
        encoded, models = _encode_once(method, library, q, None, seed, given)
        size = size_of(encoded)
        if size <= target:
            lo = q
            if best is None or q < best[0]:
                best = (q, encoded, models)
        else:
            hi = q
        if lo is not None and hi is not None and hi / lo < 1.06:
            break
        q = q * 2.0 if hi is None else (q / 2.0 if lo is None else float(np.sqrt(lo * hi)))
    if best is None:
        best = (q, encoded, models)
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
    seed: int = 0,
    progress: Progress | None = None,
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
        ``max_error`` it caps the step the rate control may use.
    bound_on : {"joints", "vertices"}
        What ``max_error`` bounds: joint and end-site positions, or also the virtual vertices
        3 cm along each joint's axes (the Animation Compression Library's measure).
    skeleton : Skeleton or path, optional
        The ASF for AMC inputs whose skeleton is not found by name.
    seed : int
        Seed of every random choice (dictionary initialisation): same input and seed, same bytes.
    progress : callable, optional
        Called as ``progress(step_name, done, total)``.

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
    motions, sources = _load_inputs(clips, skeleton)
    _validate(motions, max_error, ratio)
    if bound_on not in ("joints", "vertices"):
        raise ValueError(f"bound_on must be 'joints' or 'vertices', got {bound_on!r}")
    codec = get_method(method)
    table = _SkeletonTable()
    clip_skeleton = [table.index(m.skeleton) for m in motions]
    report("prepare", 0, len(motions))
    library = prepare_library(motions, sources, vertices=bound_on == "vertices")
    layout_skeletons = [table.index(info.skeleton) for info in library.layouts]
    report("encode", 0, len(motions))
    q = quality if quality is not None else codec.default_quality

    def file_size(encoded: EncodedLibrary, corrections=None) -> int:
        return len(_build(encoded, corrections, None))

    def _build(encoded, corrections, errors) -> bytes:
        entries = []
        chunks = []
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
        return _assemble(
            codec.name,
            table,
            layout_skeletons,
            entries,
            table.new_records,
            _layout_chunks(library, encoded, 0),
            chunks,
        )

    if ratio is not None:
        q, encoded, models = _search_ratio(codec, library, ratio, seed, [], file_size)
        corrections, errors = _verify_and_repair(codec, library, encoded, models, None)
    elif max_error is not None and not codec.controls_bound:
        best = None
        for scale in (1.0, 0.5, 0.25, 0.125):
            encoded, models = _encode_once(codec, library, q * scale, max_error, seed, [])
            corrections, errors = _verify_and_repair(codec, library, encoded, models, max_error)
            size = file_size(encoded, corrections)
            if best is None or size < best[0]:
                best = (size, q * scale, encoded, corrections, errors)
        _, q, encoded, corrections, errors = best
    else:
        encoded, models = _encode_once(codec, library, q, max_error, seed, [])
        report("verify", 0, len(motions))
        corrections, errors = _verify_and_repair(codec, library, encoded, models, max_error)
    data = _build(encoded, corrections, errors)
    path = None
    if out is not None:
        path = Path(out)
        atomic_write_bytes(path, data)
    report("done", len(motions), len(motions))
    with open_archive(data) as archive:
        clip_bytes = [archive.chunk_bytes(i) for i in range(len(archive))]
    return CompressionResult(
        data,
        path,
        codec.name,
        errors,
        clip_bytes,
        [c.source_bytes for c in library.clips],
        [
            4 * sum(len(ch) for ch in c.motion.skeleton.channels) * c.motion.n_frames
            for c in library.clips
        ],
        time.perf_counter() - t0,
        q,
        [len(c) for c in corrections],
    )


def append(
    path: str | Path,
    clips: Sequence[Motion | str | Path],
    *,
    max_error: float | None = None,
    quality: float | None = None,
    skeleton: Skeleton | str | Path | None = None,
    seed: int = 0,
) -> CompressionResult:
    """Add clips to an existing ``.qmz`` file (rewritten atomically).

    The clips already in the file keep their chunks byte for byte; the new ones are coded with
    the file's method and with its library models where their skeleton structure is known.
    Names must stay unique.
    """
    t0 = time.perf_counter()
    path = Path(path)
    motions, sources = _load_inputs(clips, skeleton)
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
            [archive._record_text(k) for k in range(len(old.records))],
            list(old.skeletons),
            [archive.skeleton(k) for k in range(len(old.skeletons))],
        )
        layouts = [archive.layout(k) for k in range(len(old.layouts))]
        old_records = [read_chunk(archive._file, r, path) for r in archive._record_chunks]
        old_layout_chunks = [read_chunk(archive._file, r, path) for r in archive._layout_chunks]
        old_clip_chunks = [read_chunk(archive._file, r, path) for r in archive._clip_chunks]
    clip_skeleton = [table.index(m.skeleton) for m in motions]
    library = prepare_library(motions, sources, [info for info, _ in layouts])
    given = [model for _, model in layouts]
    n_old = len(layouts)
    layout_skeletons = [lay.skeleton for lay in old.layouts] + [
        table.index(info.skeleton) for info in library.layouts[n_old:]
    ]
    q = quality if quality is not None else codec.default_quality
    encoded, models = _encode_once(codec, library, q, max_error, seed, given)
    corrections, errors = _verify_and_repair(codec, library, encoded, models, max_error)
    entries = list(old.clips)
    chunks = list(old_clip_chunks)
    for i, clip in enumerate(library.clips):
        chunks.append(write_clip_prefix(clip.at_rest, corrections[i]) + encoded.clips[i])
        entries.append(
            ClipEntry(
                clip.motion.name,
                clip_skeleton[i],
                clip.layout,
                clip.motion.n_frames,
                clip.motion.fps,
                clip.source_bytes,
                clip.source_format,
                errors[i].max_joint,
                errors[i].arms,
            )
        )
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
    with open_archive(data) as archive:
        clip_bytes = [archive.chunk_bytes(i) for i in range(len(archive))]
    return CompressionResult(
        data,
        path,
        codec.name,
        errors,
        clip_bytes[len(old.clips) :],
        [c.source_bytes for c in library.clips],
        [
            4 * sum(len(ch) for ch in c.motion.skeleton.channels) * c.motion.n_frames
            for c in library.clips
        ],
        time.perf_counter() - t0,
        q,
        [len(c) for c in corrections],
    )
