"""Step 5, writing: the file's tables and shared chunks around the clips' chunks
(:class:`FileLayout`), the clips' index entries, and the container written atomically with
the clips' chunks streamed from their spool (:func:`write_file`).
"""

from __future__ import annotations

import io
import json
import time
import zlib
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from quatmotion._atomic import atomic_output
from quatmotion.codec.binary import Writer
from quatmotion.codec.container import (
    MAGIC,
    ClipEntry,
    Header,
    LayoutEntry,
    write_container,
)
from quatmotion.codec.library import PreparedLibrary
from quatmotion.codec.methods import EncodedLibrary
from quatmotion.codec.metrics import ClipErrors
from quatmotion.codec.settings import CompressSettings
from quatmotion.codec.writer.plan import Plan
from quatmotion.codec.writer.scan import Inputs
from quatmotion.codec.writer.skeleton_table import SkeletonTable
from quatmotion.codec.writer.spool import Coded


def _chunk_size(n: int) -> int:
    """Bytes of a chunk of an ``n``-byte payload (tag, length, payload, CRC)."""
    return 1 + len(Writer().uvarint(n).bytes()) + n + 4


@dataclass
class FileLayout:
    """The file's tables and shared chunks around the clips' chunks."""

    method: str
    settings: CompressSettings
    table: SkeletonTable
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

    def layout_chunks(self, plan: Plan, coded: Coded) -> list[bytes]:
        return self.old_layout_chunks + _layout_chunks(
            plan.sample, EncodedLibrary(coded.blobs, []), self.first_layout
        )

    def file_size(
        self, inputs: Inputs, plan: Plan, clip_skeleton: list[int], coded: Coded, old: int = 0
    ) -> int:
        """The size of the file ``coded`` makes (declared errors of 0: sizing a try); ``old``
        the bytes of the clip chunks already in the file."""
        entries = clip_entries(inputs, plan, clip_skeleton, None)
        chunks = [self.header(entries).to_bytes(), *self.records, *self.layout_chunks(plan, coded)]
        size = len(MAGIC) + 2 + sum(_chunk_size(len(c)) for c in chunks) + old
        return size + sum(_chunk_size(n) for n in coded.chunk_sizes)


def clip_entries(
    inputs: Inputs, plan: Plan, clip_skeleton: list[int], errors: list[ClipErrors] | None
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


def write_file(
    out: Path | None,
    layout: FileLayout,
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


def build_details(
    data: bytes | None, method: str, inputs: Inputs, coded: Coded, started: float, quality: float
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
