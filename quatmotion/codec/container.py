"""The ``.qmz`` container: preamble, chunks with CRC32, the header and its clip index.

``docs/format.md`` specifies these bytes; this module is its one implementation. It knows
nothing of how clips are coded: chunk payloads are opaque bytes here.

Conventions
-----------
* A file is the 10-byte preamble (:data:`MAGIC`, then the format version as u16 little-endian)
  followed by chunks. A chunk is a one-byte ASCII tag, the payload length as a varint, the
  payload, and the CRC32 (u32 little-endian, zlib's polynomial) of the tag, length bytes and
  payload.
* Chunk order: one header ``H``; skeleton records ``S``; library models ``L``; one ``C`` per
  clip. The header's counts say how many of each follow, so truncation is detected at any
  chunk boundary.
* The header payload is raw deflate (zlib, level 9) of the :class:`Header` fields (see
  :meth:`Header.to_bytes`). A format version, once released, never changes meaning: this
  module writes :data:`FORMAT_VERSION` and keeps a reader of the header of every version from
  :data:`QMZ_FORMAT` ``.oldest_readable`` (version 1, 0.3.0: no clip references, no settings;
  version 2, 0.4.0: each clip's :class:`~quatmotion.collection.ClipRef` and the settings'
  JSON; version 3: the reference's take, one take of a file of several; and, not this
  module's, every clip chunk starting with its frame count and the spline codecs' clip
  payloads in groups of rows coded by static rANS, :mod:`quatmotion.codec.methods.spline`).
* :func:`write_container` is the one writer of these bytes (the compressor assembles a
  :class:`Header` and the chunk payloads and hands them here).
* Every error in reading is a :class:`~quatmotion.errors.FormatError` that names the file and
  says what is wrong: wrong magic, a newer version, truncation, a checksum mismatch, a value
  out of range.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import BinaryIO

from quatmotion._format import FileFormat
from quatmotion.codec.binary import Reader, Writer, inflate
from quatmotion.collection import ClipRef
from quatmotion.collection.refs import duplicates
from quatmotion.errors import FormatError
from quatmotion.limits import check

__all__ = [
    "FORMAT_VERSION",
    "MAGIC",
    "QMZ_FORMAT",
    "ChunkRef",
    "ClipEntry",
    "DamagedSpan",
    "Header",
    "LayoutEntry",
    "RecordEntry",
    "SkeletonEntry",
    "read_chunk",
    "recover_chunks",
    "scan_chunks",
    "write_chunk",
    "write_container",
]

MAGIC = b"\x89QMZ\r\n\x1a\n"
"""First bytes of every ``.qmz`` file (as PNG's: catches text-mode mangling)."""
FORMAT_VERSION = 3
"""The version this code writes and the newest it reads."""
QMZ_FORMAT = FileFormat("qmz", FORMAT_VERSION, 1, "a .qmz motion library")
"""The ``.qmz`` format's name and versions (the one version check, :mod:`quatmotion._format`)."""
PREAMBLE_BYTES = len(MAGIC) + 2
TAGS = {b"H": "header", b"S": "skeleton", b"L": "library", b"C": "clip"}
SOURCE_FORMATS = ("", "amc", "bvh", "glb", "gltf", "fbx")  # codes append-only: a code never changes


@dataclass(frozen=True)
class RecordEntry:
    """A stored skeleton text: its record kind and BVH scale (cm per unit, 0 for others)."""

    kind: int
    scale: float


@dataclass(frozen=True)
class SkeletonEntry:
    """A skeleton: its record (index into the ``S`` chunks) and its name."""

    record: int
    name: str


@dataclass(frozen=True)
class LayoutEntry:
    """A library model (index into the ``L`` chunks) and the skeleton whose structure it has."""

    skeleton: int


@dataclass(frozen=True)
class ClipEntry:
    """One clip of the index.

    Attributes
    ----------
    name : str
        The clip's name (its file stem).
    skeleton, layout : int
        Indices into the header's skeletons and layouts.
    n_frames : int
    fps : float
    source_bytes : int
        Size of the file it came from (AMC or BVH text), 0 when unknown.
    source_format : str
        ``"amc"``, ``"bvh"``, ``"glb"``, ``"gltf"`` or ``""``.
    max_error, arms : float
        The clip's largest joint-position error and ARMS as encoded, centimetres.
    """

    name: str
    skeleton: int
    layout: int
    n_frames: int
    fps: float
    source_bytes: int
    source_format: str
    max_error: float
    arms: float
    ref: ClipRef | None = None
    """Its reference (version 2 on; None in a version 1 file)."""


@dataclass(frozen=True)
class Header:
    """What the ``H`` chunk holds: the method, the tables and the clip index."""

    method: str
    records: tuple[RecordEntry, ...]
    skeletons: tuple[SkeletonEntry, ...]
    layouts: tuple[LayoutEntry, ...]
    clips: tuple[ClipEntry, ...]
    settings: bytes = field(default=b"")
    """UTF-8 JSON of the :class:`~quatmotion.codec.CompressSettings` used (version 2 on;
    empty in version 1)."""

    def to_bytes(self) -> bytes:
        """The deflated header payload, in :data:`FORMAT_VERSION` (every clip needs a ref)."""
        w = Writer().string(self.method).blob(self.settings)
        w.uvarint(len(self.records))
        for r in self.records:
            w.u8(r.kind).f64(r.scale)
        w.uvarint(len(self.skeletons))
        for s in self.skeletons:
            w.uvarint(s.record).string(s.name)
        w.uvarint(len(self.layouts))
        for lay in self.layouts:
            w.uvarint(lay.skeleton)
        rates = sorted({c.fps for c in self.clips})
        w.uvarint(len(rates))
        for r in rates:
            w.f64(r)
        w.uvarint(len(self.clips))
        for c in self.clips:
            w.string(c.name).uvarint(c.skeleton).uvarint(c.layout).uvarint(rates.index(c.fps))
            w.uvarint(c.n_frames).uvarint(c.source_bytes)
            w.u8(SOURCE_FORMATS.index(c.source_format)).f32(c.max_error).f32(c.arms)
            _write_ref(w, c)
        compressor = zlib.compressobj(9, zlib.DEFLATED, -15, 9)
        return compressor.compress(w.bytes()) + compressor.flush()

    @classmethod
    def from_bytes(
        cls, payload: bytes, source: str | Path | None = None, version: int = FORMAT_VERSION
    ) -> Header:
        """Parse a header payload of format ``version``, checking every index against the
        tables (the clip entries' decoder is the version's: :data:`_REF_READERS`)."""
        read_ref = _REF_READERS[version]
        raw = inflate(payload, "header", source)
        r = Reader(raw, source, "header")
        method = r.string()
        settings = r.blob()
        records = tuple(RecordEntry(r.u8(), r.f64()) for _ in range(r.uvarint(r.remaining // 9)))
        skeletons = tuple(
            SkeletonEntry(_index(r, len(records), "skeleton record", source), r.string())
            for _ in range(r.uvarint(r.remaining // 2))
        )
        layouts = tuple(
            LayoutEntry(_index(r, len(skeletons), "skeleton", source))
            for _ in range(r.uvarint(r.remaining))
        )
        rates = [r.f64() for _ in range(r.uvarint(r.remaining // 8))]
        for k, rate in enumerate(rates):
            check("fps", rate, source, f"header: frame rate {k}")
        clips = []
        for _ in range(r.uvarint(r.remaining // _MIN_CLIP_BYTES)):
            name = r.string()
            sk = _index(r, len(skeletons), "skeleton", source)
            lay = _index(r, len(layouts), "layout", source)
            fps = rates[_index(r, len(rates), "frame rate", source)]
            frames = r.uvarint()
            check("frames", frames, source, f"header: clip {name!r}: frames")
            if frames < 1:
                raise FormatError(f"header: clip {name!r} has no frames", source)
            source_bytes = r.uvarint()
            fmt = r.u8()
            if fmt >= len(SOURCE_FORMATS):
                raise FormatError(f"header: unknown source format code {fmt}", source)
            max_error, arms = r.f32(), r.f32()
            if not (math.isfinite(max_error) and math.isfinite(arms)) or min(max_error, arms) < 0:
                raise FormatError(
                    f"header: clip {name!r}: errors {max_error}, {arms} are not distances", source
                )
            clips.append(
                ClipEntry(
                    name,
                    sk,
                    lay,
                    frames,
                    fps,
                    source_bytes,
                    SOURCE_FORMATS[fmt],
                    max_error,
                    arms,
                    read_ref(r, name, source),
                )  # fmt: skip
            )
        r.end()
        if (skeletons or layouts or clips) and not records:
            raise FormatError("header: clips without skeleton records", source)
        twice = duplicates(c.name for c in clips)
        if twice:
            raise FormatError(
                f"header: {len(twice)} clip name(s) given to several clips ({twice[0]!r}...): "
                "a clip's name is its identity",
                source,
            )
        return cls(method, records, skeletons, layouts, tuple(clips), settings)


_MIN_CLIP_BYTES = 15
"""The fewest bytes a clip entry takes (its fields at one byte per varint): what a count of
entries is checked against before any is read."""


def _index(r: Reader, n: int, what: str, source: str | Path | None) -> int:
    """An index into a table of ``n`` entries (refused when the table is empty)."""
    if n == 0:
        raise FormatError(f"header: a {what} is named, but the header lists none", source)
    return r.uvarint(n - 1)


def _write_ref(w: Writer, entry: ClipEntry) -> None:
    """A clip entry's reference fields (version 3): sha256 (32 bytes), path, skeleton path,
    skeleton fingerprint, units (strings, "" for none), units_guessed (u8), then the take (u8
    0: none; 1: a string follows, the take's name)."""
    ref = entry.ref
    if ref is None:
        raise ValueError(f"clip {entry.name!r}: a version {FORMAT_VERSION} entry needs its ref")
    w.raw(bytes.fromhex(ref.sha256)).string(ref.path or "").string(ref.skeleton_path or "")
    w.string(ref.skeleton).string(ref.units).u8(int(ref.units_guessed))
    w.u8(int(ref.take is not None))
    if ref.take is not None:
        w.string(ref.take)


def _ref_v1(r: Reader, name: str, source: str | Path | None) -> ClipRef | None:
    """Version 1 stored no reference."""
    return None


def _ref_v2(r: Reader, name: str, source: str | Path | None) -> ClipRef:
    sha = r.take(32).hex()
    path, skeleton_path, fingerprint, units = r.string(), r.string(), r.string(), r.string()
    guessed = r.u8()
    if guessed > 1:
        raise FormatError(f"header: clip {name!r}: units_guessed is {guessed}, not 0 or 1", source)
    return ClipRef(
        name, sha, path or None, skeleton_path or None, fingerprint, units, bool(guessed)
    )


def _ref_v3(r: Reader, name: str, source: str | Path | None) -> ClipRef:
    """Version 2's fields, then the take: a flag (0 none, 1 a string follows)."""
    ref = _ref_v2(r, name, source)
    flag = r.u8()
    if flag > 1:
        raise FormatError(f"header: clip {name!r}: take flag is {flag}, not 0 or 1", source)
    return ref if not flag else replace(ref, take=r.string())


_REF_READERS = {1: _ref_v1, 2: _ref_v2, 3: _ref_v3}
"""The clip entry's tail by format version: a decoder per version, kept once released."""


def write_container(
    out: BinaryIO,
    header: Header,
    records: list[bytes],
    layouts: list[bytes],
    clips: Iterable[bytes],
) -> None:
    """Write a whole ``.qmz`` file in :data:`FORMAT_VERSION`: the preamble, the header, then
    the ``S``, ``L`` and ``C`` chunks (as many as the header's tables list; ``clips`` may be
    an iterator, read once, so clip payloads can stream from a spool)."""
    if len(records) != len(header.records) or len(layouts) != len(header.layouts):
        raise ValueError("the chunks do not match the header's tables")
    out.write(MAGIC + FORMAT_VERSION.to_bytes(2, "little"))
    write_chunk(out, b"H", header.to_bytes())
    for tag, chunks in ((b"S", records), (b"L", layouts)):
        for payload in chunks:
            write_chunk(out, tag, payload)
    n = 0
    for payload in clips:
        write_chunk(out, b"C", payload)
        n += 1
    if n != len(header.clips):
        raise ValueError(f"{n} clip chunks for {len(header.clips)} clips in the header")


@dataclass(frozen=True)
class ChunkRef:
    """Where a chunk's payload lies in the file."""

    tag: bytes
    offset: int
    length: int
    crc: int
    header_bytes: bytes


def write_chunk(out: BinaryIO, tag: bytes, payload: bytes) -> int:
    """Write one chunk; returns its size in bytes."""
    head = tag + Writer().uvarint(len(payload)).bytes()
    crc = zlib.crc32(payload, zlib.crc32(head))
    data = head + payload + crc.to_bytes(4, "little")
    out.write(data)
    return len(data)


def _read_varint(f: BinaryIO, source: Path) -> tuple[int, bytes]:
    raw = bytearray()
    value = 0
    shift = 0
    while True:
        b = f.read(1)
        if not b:
            raise FormatError("truncated inside a chunk length", source)
        raw += b
        value |= (b[0] & 0x7F) << shift
        if not b[0] & 0x80:
            return value, bytes(raw)
        shift += 7
        if shift > 63:
            raise FormatError("chunk length varint longer than 64 bits", source)


def read_preamble(f: BinaryIO, source: Path) -> int:
    """Check the magic and version; returns the version."""
    head = f.read(PREAMBLE_BYTES)
    if len(head) < len(MAGIC) or head[: len(MAGIC)] != MAGIC:
        raise FormatError("not a .qmz file (wrong magic bytes)", source)
    if len(head) < PREAMBLE_BYTES:
        raise FormatError("truncated in the preamble", source)
    version = int.from_bytes(head[len(MAGIC) :], "little")
    if version < 1:
        raise FormatError(f"invalid format version {version}", source)
    return QMZ_FORMAT.check(QMZ_FORMAT.name, version, source)


def scan_chunks(f: BinaryIO, source: Path, size: int) -> Iterator[ChunkRef]:
    """Walk the chunks after the preamble without reading payloads."""
    pos = PREAMBLE_BYTES
    f.seek(pos)
    while pos < size:
        tag = f.read(1)
        if tag not in TAGS:
            raise FormatError(f"unknown chunk tag {tag!r} at byte {pos}", source)
        length, raw = _read_varint(f, source)
        offset = pos + 1 + len(raw)
        end = offset + length + 4
        if end > size:
            raise FormatError(
                f"truncated: the {TAGS[tag]} chunk at byte {pos} needs {end - pos} bytes, "
                f"{size - pos} remain",
                source,
            )
        f.seek(offset + length)
        crc = int.from_bytes(f.read(4), "little")
        yield ChunkRef(tag, offset, length, crc, tag + raw)
        pos = end


def read_chunk(f: BinaryIO, ref: ChunkRef, source: Path) -> bytes:
    """A chunk's payload, its CRC checked."""
    f.seek(ref.offset)
    payload = f.read(ref.length)
    if len(payload) != ref.length:
        raise FormatError(f"truncated in the {TAGS[ref.tag]} chunk at byte {ref.offset}", source)
    if zlib.crc32(payload, zlib.crc32(ref.header_bytes)) != ref.crc:
        raise FormatError(
            f"checksum mismatch in the {TAGS[ref.tag]} chunk at byte {ref.offset} (corrupt file)",
            source,
        )
    return payload


@dataclass(frozen=True)
class DamagedSpan:
    """Bytes of a file where no intact chunk could be read (recovery scanning).

    ``n_chunks`` is how many chunks the span held when that is known (its framing was whole
    and only the checksum failed: 1), else ``None`` (the framing itself is damaged, or the file
    ends inside it)."""

    start: int
    end: int
    reason: str
    n_chunks: int | None


def _chunk_at(data: bytes, pos: int) -> tuple[ChunkRef | None, int | None, str]:
    """The chunk starting at ``pos`` of ``data``: (ref if its CRC holds, its end if its framing
    is whole, why not)."""
    tag = data[pos : pos + 1]
    if tag not in TAGS:
        return None, None, f"unknown chunk tag {tag!r} at byte {pos}"
    length = shift = 0
    p = pos + 1
    while True:
        if p >= len(data):
            return None, None, f"truncated inside the chunk length at byte {pos}"
        b = data[p]
        p += 1
        length |= (b & 0x7F) << shift
        if not b & 0x80:
            break
        shift += 7
        if shift > 63:
            return None, None, f"chunk length varint longer than 64 bits at byte {pos}"
    end = p + length + 4
    if end > len(data):
        return (
            None,
            None,
            (
                f"truncated: the {TAGS[tag]} chunk at byte {pos} needs {end - pos} bytes, "
                f"{len(data) - pos} remain"
            ),
        )
    head = data[pos:p]
    crc = int.from_bytes(data[end - 4 : end], "little")
    if zlib.crc32(memoryview(data)[p : end - 4], zlib.crc32(head)) != crc:
        return None, end, f"checksum mismatch in the {TAGS[tag]} chunk at byte {pos}"
    return ChunkRef(tag, p, length, crc, head), end, ""


def recover_chunks(data: bytes) -> list[ChunkRef | DamagedSpan]:
    """Every intact chunk of a file's bytes (after the preamble), in order, with the damaged
    spans between them.

    A chunk whose framing is whole but whose checksum fails is one damaged span of one chunk.
    Where the framing is damaged (a flipped tag or length) the scan resynchronises on the next
    byte where a chunk with a matching CRC32 starts; where the file ends early the rest is one
    span of unknown count. Each chunk returned has passed its CRC check."""
    items: list[ChunkRef | DamagedSpan] = []
    pos = PREAMBLE_BYTES
    while pos < len(data):
        ref, end, reason = _chunk_at(data, pos)
        if ref is not None:
            items.append(ref)
            pos = end
            continue
        if end is not None and (end == len(data) or _chunk_at(data, end)[0] is not None):
            items.append(DamagedSpan(pos, end, reason, 1))  # framing whole: one chunk lost
            pos = end
            continue
        start = pos
        pos += 1
        while pos < len(data):
            if data[pos : pos + 1] in TAGS and _chunk_at(data, pos)[0] is not None:
                break
            pos += 1
        items.append(DamagedSpan(start, pos, reason, None))
    return items
