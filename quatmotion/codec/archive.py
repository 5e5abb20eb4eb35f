"""Reading ``.qmz`` files: lazy, random access to clips (decompression), apart from the
writer: :class:`ArchiveReader` imports nothing of :mod:`~quatmotion.codec.writer`. Users call
it as :class:`quatmotion.codec.Archive` (:mod:`~quatmotion.codec.qmz`), which adds the file
kind's ``build``/``add`` on top.

:meth:`ArchiveReader.open` reads the preamble, walks the chunk framing and parses the header
(the decoder of the file's format version); nothing else. :meth:`ArchiveReader.read` decodes
one clip
from its own chunk plus the skeleton record and library model it needs (each parsed once and
cached), so one clip decodes without decoding any other.
"""

from __future__ import annotations

import hashlib
import io
import os
from collections import OrderedDict
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO, Self

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quatmotion._format import FileFormat
from quatmotion.codec.binary import Reader, Writer, inflate
from quatmotion.codec.channels import _kernel_tables, from_channels
from quatmotion.codec.container import (
    FORMAT_VERSION,
    QMZ_FORMAT,
    ChunkRef,
    ClipEntry,
    DamagedSpan,
    Header,
    read_chunk,
    read_preamble,
    recover_chunks,
    scan_chunks,
)
from quatmotion.codec.library import LayoutInfo
from quatmotion.codec.methods import ClipContext, get_method
from quatmotion.codec.repair import (
    Corrections,
    check_frames,
    correction_lever,
    read_clip_prefix,
)
from quatmotion.codec.sampling import Sampler, sampler_for
from quatmotion.codec.skeletons import (
    RECORD_BVH,
    RECORD_BVH_GUESSED,
    inflate_text,
    skeleton_from_record,
)
from quatmotion.codec.spline import segment_tables
from quatmotion.collection import ClipRef
from quatmotion.errors import FormatError
from quatmotion.io.names import match_clip
from quatmotion.limits import check, load_json
from quatmotion.motion import Motion, Skeleton
from quatmotion.runtime.clip import ClipRows, Rig, clip_rotations

if TYPE_CHECKING:
    from quatmotion.codec.settings import CompressSettings

__all__ = ["ArchiveReader", "ClipParts", "DamagedClip", "DecodedChannels"]


@dataclass(frozen=True)
class DamagedClip:
    """A clip of a damaged file that cannot be decoded (:attr:`ArchiveReader.damaged`).

    Attributes
    ----------
    index : int
        Its position in the header's index.
    name : str
    reason : str
        What is damaged (its own chunk, or the skeleton record or layout it needs), with the
        byte offset where the damage was found.
    """

    index: int
    name: str
    reason: str


@dataclass(frozen=True)
class ClipParts:
    """One clip's parts before its method payload is decoded (:meth:`ArchiveReader.clip_parts`)."""

    index: int
    entry: ClipEntry
    skeleton: Skeleton
    layout: LayoutInfo
    model: Any
    payload: bytes
    context: ClipContext
    at_rest: NDArray[np.bool_]
    corrections: Corrections


@dataclass(frozen=True)
class DecodedChannels:
    """A clip decoded to channels, before they become a :class:`Motion`."""

    channels: NDArray[np.float64]
    at_rest: NDArray[np.bool_]
    layout: LayoutInfo
    skeleton: Skeleton
    entry: ClipEntry


class ArchiveReader:
    """An open ``.qmz`` file (or bytes), read. Use as a context manager or call :meth:`close`.

    Attributes
    ----------
    path : Path or None
    header : Header
    entries : tuple of ClipEntry
        The index, in file order (damaged clips included: indices never shift).
    damaged : tuple of DamagedClip
        With ``recover=True``, the clips that cannot be decoded and why (empty for a whole
        file); reading one raises :class:`~quatmotion.errors.FormatError` with its reason.
        Without it a damaged file raises when opened, or when a damaged clip is read.
    format : FileFormat
        The ``.qmz`` format; :attr:`version` is the version this file was read in.
    """

    format: FileFormat = QMZ_FORMAT

    @classmethod
    def open(cls, path: str | Path | bytes, *, recover: bool = False) -> Self:
        """Open a ``.qmz`` file (a path, or its bytes) for lazy clip access.

        With ``recover=True`` a damaged file (a flipped byte, a file cut short) opens as long
        as its header is whole: every chunk's CRC is checked at once, the clips that cannot be
        decoded are listed in :attr:`damaged` and every other clip reads bit for bit as from
        the whole file.

        Raises
        ------
        FormatError
            Wrong magic, a format version this code does not read, truncation, a checksum
            failure in the header, or tables that do not match the chunks (naming the file).
        FileNotFoundError
            If the path does not exist.
        """
        return cls(path, recover=recover)

    def __init__(self, source: str | Path | bytes, *, recover: bool = False):
        if isinstance(source, bytes | bytearray):
            self.path = None
            self._name = Path("<bytes>")
            self._file: BinaryIO = io.BytesIO(bytes(source))
            size = len(source)
        else:
            self.path = Path(source)
            self._name = self.path
            self._file = open(self.path, "rb")  # noqa: SIM115 (closed by close())
            size = os.fstat(self._file.fileno()).st_size
        try:
            self.size = size
            self.damaged: tuple[DamagedClip, ...] = ()
            self._clip_damage: dict[int, str] = {}
            self.version = read_preamble(self._file, self._name)
            if recover:
                self._open_recovering()
            else:
                chunks = list(scan_chunks(self._file, self._name, size))
                if not chunks or chunks[0].tag != b"H":
                    raise FormatError("the first chunk is not the header", self._name)
                self.header = Header.from_bytes(
                    read_chunk(self._file, chunks[0], self._name), self._name, self.version
                )
                self._split(chunks[1:])
                self._check_frames()
        except BaseException:
            self._file.close()
            raise
        self.method = get_method(self.header.method) if self.header.method in _known() else None
        if self.method is None:
            self._file.close()
            raise FormatError(f"unknown codec method {self.header.method!r}", self._name)
        try:  # every command reads the same file: the settings are checked here, once
            self._settings = self._read_settings()
        except BaseException:
            self._file.close()
            raise
        self._records: dict[int, str] = {}
        self._skeletons: dict[int, Skeleton] = {}
        self._layouts: dict[int, tuple[LayoutInfo, Any]] = {}
        self._samplers: OrderedDict[int, Any] = OrderedDict()
        self._rigs: dict[tuple[int, int], Rig] = {}
        self._by_name: dict[str, int] | None = None

    def _split(self, chunks: list[ChunkRef]) -> None:
        h = self.header
        expected = [b"S"] * len(h.records) + [b"L"] * len(h.layouts) + [b"C"] * len(h.clips)
        tags = [c.tag for c in chunks]
        if len(tags) < len(expected) and tags == expected[: len(tags)]:
            raise FormatError(
                f"truncated: {len(expected) - len(tags)} of {len(expected)} chunks missing",
                self._name,
            )
        if tags != expected:
            raise FormatError("chunks do not match the header's tables", self._name)
        n_s, n_l = len(h.records), len(h.layouts)
        self._record_chunks = chunks[:n_s]
        self._layout_chunks = chunks[n_s : n_s + n_l]
        self._clip_chunks = chunks[n_s + n_l :]

    def _check_frames(self) -> None:
        """Every clip chunk's frame count against its header entry (format 3 on): a header
        that says one frame more than the data is refused when the file is opened, whatever
        the command (recovering too: the checksums hold), naming the clip."""
        if self.version < 3:
            return
        for entry, ref in zip(self.header.clips, self._clip_chunks, strict=True):
            if ref is None:  # lost in a damaged file opened to recover
                continue
            self._file.seek(ref.offset)
            head = self._file.read(min(10, ref.length))
            try:
                check_frames(Reader(head, self._name, "clip").uvarint(), entry.n_frames)
            except FormatError as error:
                raise FormatError(f"clip {entry.name!r}: {error.reason}", self._name) from None

    def _open_recovering(self) -> None:
        """Read what a damaged file still holds: every chunk whose CRC holds, placed by the
        header's tables; the clips whose chunk, skeleton record or layout is lost go to
        :attr:`damaged`."""
        self._file.seek(0)
        items = recover_chunks(self._file.read())
        first = items[0] if items else None
        if not isinstance(first, ChunkRef) or first.tag != b"H":
            where = first.reason if isinstance(first, DamagedSpan) else "the file ends"
            raise FormatError(
                f"the header is damaged ({where}): no clip can be named or recovered", self._name
            )
        self.header = h = Header.from_bytes(
            read_chunk(self._file, first, self._name), self._name, self.version
        )
        expected = [b"S"] * len(h.records) + [b"L"] * len(h.layouts) + [b"C"] * len(h.clips)
        placed: list[ChunkRef | None] = [None] * len(expected)
        rest = items[1:]
        last = rest[-1] if rest else None
        end_whole = isinstance(last, ChunkRef) and last.offset + last.length + 4 == self.size
        lost = [
            "lost in a damaged part of the file"
            if end_whole
            else f"missing: the file ends at byte {self.size}"
        ] * len(expected)

        def place(order: list[int], sequence) -> int:
            """Give chunks positions in ``order`` while their count is known; returns how
            many positions were decided."""
            done = 0
            for item in sequence:
                if done == len(order):
                    break
                k = order[done]
                if isinstance(item, ChunkRef):
                    if item.tag != expected[k]:
                        break  # out of step with the tables: stop placing from this side
                    placed[k] = item
                elif item.n_chunks == 1:
                    lost[k] = item.reason
                else:
                    for j in order[done:]:
                        lost[j] = item.reason  # somewhere in this span, or after it
                    break
                done += 1
            return done

        forward = place(list(range(len(expected))), rest)
        if end_whole:
            # The file's end is whole: place from the end back as far as counts are known.
            undecided = list(range(len(expected) - 1, forward - 1, -1))
            place(undecided, reversed(rest))
        n_s, n_l = len(h.records), len(h.layouts)
        self._record_chunks = placed[:n_s]
        self._layout_chunks = placed[n_s : n_s + n_l]
        self._clip_chunks = placed[n_s + n_l :]
        record_damage: dict[int, str] = {}
        for k, rec in enumerate(h.records):
            base = next(i for i, r in enumerate(h.records) if r.kind == rec.kind)
            if placed[k] is None:
                record_damage[k] = f"its skeleton record {k} is lost ({lost[k]})"
            elif base in record_damage:
                record_damage[k] = record_damage[base]  # deflated against record ``base``
        layout_damage: dict[int, str] = {}
        for k, lay in enumerate(h.layouts):
            if placed[n_s + k] is None:
                layout_damage[k] = f"its layout {k} is lost ({lost[n_s + k]})"
            elif h.skeletons[lay.skeleton].record in record_damage:
                layout_damage[k] = record_damage[h.skeletons[lay.skeleton].record]
        for i, entry in enumerate(h.clips):
            if placed[n_s + n_l + i] is None:
                self._clip_damage[i] = lost[n_s + n_l + i]
            elif h.skeletons[entry.skeleton].record in record_damage:
                self._clip_damage[i] = record_damage[h.skeletons[entry.skeleton].record]
            elif entry.layout in layout_damage:
                self._clip_damage[i] = layout_damage[entry.layout]
        self.damaged = tuple(
            DamagedClip(i, h.clips[i].name, reason) for i, reason in self._clip_damage.items()
        )
        self._check_frames()  # a chunk whose checksum holds says what it says: not damage

    def _check_intact(self, i: int) -> None:
        if i in self._clip_damage:
            raise FormatError(
                f"clip {self.header.clips[i].name!r} is damaged: {self._clip_damage[i]}",
                self._name,
            )

    # ------------------------------------------------------------------ context management
    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ index
    @property
    def entries(self) -> tuple[ClipEntry, ...]:
        """The clip index, in file order."""
        return self.header.clips

    def clips(self) -> tuple[ClipRef, ...]:
        """Every clip's reference, in file order. A version 1 file stored none: its clips'
        references hash the clip's stored chunk (an identity within this file only) and name
        no source."""
        return tuple(
            entry.ref if entry.ref is not None else self._v1_ref(i)
            for i, entry in enumerate(self.header.clips)
        )

    def _v1_ref(self, i: int) -> ClipRef:
        digest = hashlib.sha256(b"quatmotion-qmz-v1-clip\0")
        if i in self._clip_damage:  # a damaged clip of a recovered file: its name only
            digest.update(b"damaged\0" + self.header.clips[i].name.encode())
        else:
            digest.update(read_chunk(self._file, self._clip_chunks[i], self._name))
        return ClipRef(self.header.clips[i].name, digest.hexdigest())

    @property
    def settings(self) -> CompressSettings | None:
        """How the file was made (version 2 on); None for a version 1 file."""
        return self._settings

    def _read_settings(self) -> CompressSettings | None:
        from quatmotion.codec.settings import CompressSettings

        if not self.header.settings:
            return None
        values = load_json(self.header.settings, self._name, "header: settings")
        if not isinstance(values, dict):
            raise FormatError("header: settings are not a JSON object", self._name)
        try:
            return CompressSettings.from_dict(values, self._name)
        except FormatError:
            raise
        except (TypeError, ValueError, KeyError) as error:
            raise FormatError(f"header: settings are invalid ({error})", self._name) from None

    def __len__(self) -> int:
        return len(self.header.clips)

    def names(self) -> list[str]:
        return [c.name for c in self.header.clips]

    def index_of(self, clip: int | str) -> int:
        """The position of a clip given by position or name: its name, file name (``walk.bvh``)
        or number, as every command reads a clip name (:func:`quatmotion.io.names.match_clip`).

        Raises
        ------
        KeyError
            (:class:`~quatmotion.errors.ClipNameError`) No such clip, or several.
        """
        if isinstance(clip, int | np.integer) and 0 <= clip < len(self):
            return int(clip)  # the fast path of every read
        if isinstance(clip, str):
            if self._by_name is None:  # a name held by one clip only (version 1 repeats some)
                names = self.names()
                once = (
                    {n for n in names if names.count(n) == 1}
                    if len(set(names)) < len(names)
                    else set(names)
                )
                self._by_name = {n: i for i, n in enumerate(names) if n in once}
            i = self._by_name.get(clip)
            if i is not None:
                return i
        return match_clip(clip, self.names(), str(self._name))

    def chunk_bytes(self, clip: int | str) -> int:
        """Size of a clip's own chunk (payload), bytes; 0 for a clip whose chunk is lost."""
        ref = self._clip_chunks[self.index_of(clip)]
        return 0 if ref is None else ref.length

    # ------------------------------------------------------------------ shared parts
    def record_text(self, k: int) -> str:
        """The text of the ``k``-th skeleton record."""
        return self._record_text(k)

    def payloads(self) -> tuple[list[bytes], list[bytes], list[bytes]]:
        """The payloads of the ``S``, ``L`` and ``C`` chunks, CRC checked (for appending)."""
        return tuple(
            [read_chunk(self._file, ref, self._name) for ref in refs]
            for refs in (self._record_chunks, self._layout_chunks, self._clip_chunks)
        )

    def shared_payloads(self) -> tuple[list[bytes], list[bytes]]:
        """The payloads of the ``S`` and ``L`` chunks, CRC checked (for appending)."""
        return tuple(
            [read_chunk(self._file, ref, self._name) for ref in refs]
            for refs in (self._record_chunks, self._layout_chunks)
        )

    def clip_payloads(self) -> Iterator[bytes]:
        """The payloads of the ``C`` chunks in clip order, CRC checked, read one at a time
        (streamed into a file appended to), in :data:`FORMAT_VERSION`: a clip of an older
        file is re-coded by its method (:meth:`Method.upgrade_payload`, without loss)."""
        for i, ref in enumerate(self._clip_chunks):
            data = read_chunk(self._file, ref, self._name)
            if self.version < FORMAT_VERSION:
                parts = self.clip_parts(i)
                try:
                    new = self.method.upgrade_payload(parts.model, parts.payload, parts.context)
                except FormatError as error:
                    raise self.method_error(parts, error) from None
                frames = Writer().uvarint(parts.entry.n_frames).bytes()
                data = frames + data[: len(data) - len(parts.payload)] + new
            yield data

    def _record_text(self, k: int) -> str:
        if k not in self._records:
            rec = self.header.records[k]
            first = next(i for i, r in enumerate(self.header.records) if r.kind == rec.kind)
            extra = self._record_text(first) if first != k else ""
            data = read_chunk(self._file, self._record_chunks[k], self._name)
            self._records[k] = inflate_text(data, extra, self._name)
        return self._records[k]

    def skeleton(self, k: int) -> Skeleton:
        """The ``k``-th skeleton of the header."""
        if k not in self._skeletons:
            from dataclasses import replace

            entry = self.header.skeletons[k]
            rec = self.header.records[entry.record]
            sk = skeleton_from_record(
                rec.kind, self._record_text(entry.record), rec.scale, self._name
            )
            self._skeletons[k] = sk if sk.name == entry.name else replace(sk, name=entry.name)
        return self._skeletons[k]

    def bvh_unit(self, k: int) -> tuple[float, bool] | None:
        """The ``k``-th skeleton's BVH length unit, centimetres per file unit, and whether it
        was guessed, from the header alone (no record parsed: ``ls`` of a library of thousands
        of skeletons); ``None`` for a skeleton that did not come from a BVH file."""
        rec = self.header.records[self.header.skeletons[k].record]
        if rec.kind not in (RECORD_BVH, RECORD_BVH_GUESSED):
            return None
        return rec.scale, rec.kind == RECORD_BVH_GUESSED

    def layout(self, k: int) -> tuple[LayoutInfo, Any]:
        """The ``k``-th layout and its method model."""
        if k not in self._layouts:
            packed = read_chunk(self._file, self._layout_chunks[k], self._name)
            data = inflate(packed, "library chunk", self._name)
            r = Reader(data, self._name, "library chunk")
            skeleton = self.skeleton(self.header.layouts[k].skeleton)
            try:  # the parts' errors name no file: this one's
                info = LayoutInfo.read(r, skeleton)
                model = self.method.load_model(r.take(r.remaining), info)
            except FormatError as error:
                raise FormatError(error.reason, self._name) from None
            self._layouts[k] = (info, model)
        return self._layouts[k]

    # ------------------------------------------------------------------ clips
    def clip_parts(self, clip: int | str) -> ClipParts:
        """What decoding clip ``clip`` needs, parsed (its prefix read, the method payload not
        yet decoded): the shared step of :meth:`read_channels` and of sampling."""
        i = self.index_of(clip)
        self._check_intact(i)
        entry = self.header.clips[i]
        skeleton = self.skeleton(entry.skeleton)
        info, model = self.layout(entry.layout)
        if skeleton.n_joints != info.skeleton.n_joints:
            raise FormatError(f"clip {entry.name!r}: skeleton and layout disagree", self._name)
        layout = info.layout
        # What decoding allocates, from the header's frame count: checked before it is.
        what = f"clip {entry.name!r}: frames x joints"
        check("joint_frames", entry.n_frames * skeleton.n_joints, self._name, what)
        n_bytes = 8 * entry.n_frames * max(layout.n_channels, 1)
        check("decompressed_bytes", n_bytes, self._name, f"clip {entry.name!r}: decoded size")
        data = read_chunk(self._file, self._clip_chunks[i], self._name)
        r = Reader(data, self._name, f"clip {entry.name!r}")
        try:
            at_rest, corrections = read_clip_prefix(
                r, len(layout.translation_joints), entry.n_frames, layout.n_channels, self.version
            )
        except FormatError as error:  # names no file, nor the header's frame count it checks
            where = f"clip {entry.name!r} (frames: {entry.n_frames:,} in the header)"
            raise FormatError(f"{where}: {error.reason}", self._name) from None
        active = np.ones(layout.n_channels, dtype=bool)
        for k in range(len(layout.translation_joints)):
            if at_rest[k]:
                active[layout.translation_columns(k)] = False
        context = ClipContext(info, skeleton, entry.n_frames, entry.fps, active, self.version)
        return ClipParts(i, entry, skeleton, info, model, r.take(r.remaining), context,
                         at_rest, corrections)  # fmt: skip

    def checked_channels(self, parts: ClipParts, X: NDArray[np.float64]) -> NDArray[np.float64]:
        """``X`` ``(T, C)`` from the method, validated, with the clip's corrections applied."""
        entry = parts.entry
        if X.shape != (entry.n_frames, parts.layout.layout.n_channels) or not np.all(
            np.isfinite(X)
        ):
            raise FormatError(f"clip {entry.name!r}: decoded channels are invalid", self._name)
        _apply(parts.corrections, X, parts.layout)
        return X

    def method_error(self, parts: ClipParts, error: FormatError) -> FormatError:
        """A method's :class:`FormatError` restated with the clip and file names, and the
        header's frame count (what a payload that does not decode most often contradicts)."""
        entry = parts.entry
        where = f"clip {entry.name!r} (frames: {entry.n_frames:,} in the header)"
        return FormatError(f"{where}: {error.reason}", self._name)

    def read_channels(self, clip: int | str) -> DecodedChannels:
        """A clip decoded to channels (corrections applied)."""
        parts = self.clip_parts(clip)
        try:
            X = self.method.decode(parts.model, parts.payload, parts.context)
        except FormatError as error:
            raise self.method_error(parts, error) from None
        X = self.checked_channels(parts, X)
        return DecodedChannels(X, parts.at_rest, parts.layout, parts.skeleton, parts.entry)

    def sample(
        self,
        clip: int | str,
        times: ArrayLike,
        joints: ArrayLike | None = None,
        *,
        mode: str = "clamp",
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Root translation (cm) and local rotations (w-first unit quaternions) of a clip at
        ``times`` in seconds, between frames as the clip's model defines (see
        :mod:`quatmotion.codec.sampling`). The clip is decoded on its first sample and kept
        (the last few clips sampled).

        Parameters
        ----------
        clip : int or str
        times : float or array_like, shape (n,)
            Seconds from the clip's first frame (frame ``f`` is at ``f / fps``).
        joints : array_like of int or str, shape (k,), optional
            A subset of joints (indices or names), in the order wanted; all by default.
        mode : {"clamp", "loop"}
            Outside ``[0, (T - 1) / fps]``: hold the end frames, or repeat the clip with period
            ``T / fps`` (between its last and first frame the pose is interpolated).

        Returns
        -------
        root : ndarray, shape (n, 3) (``(3,)`` for a scalar time)
        rotations : ndarray, shape (n, k, 4) (``(k, 4)`` for a scalar time)

        Raises
        ------
        ValueError
            A time that is not finite, an unknown mode, or a joint that is not in the skeleton.
        """
        if joints is None and mode == "clamp" and type(times) is float:
            # one pose of a clip sampled before: its bound sampler, nothing resolved again
            i = clip if type(clip) is int else None
            if type(clip) is str and self._by_name is not None:
                i = self._by_name.get(clip)  # a name held by one clip (index_of's table)
            cached = None if i is None else self._samplers.get(i)
            if cached is not None:
                self._samplers.move_to_end(i)
                root, rot = cached.bound().pose(times)
                return root.copy(), rot.copy()
        return sampler_for(self, clip).sample(times, joints, mode=mode)

    def sampler(
        self, clip: int | str, joints: ArrayLike | None = None, *, mode: str = "clamp"
    ) -> Sampler:
        """A :class:`~quatmotion.codec.sampling.Sampler` bound to one clip (decoded now), its
        joints (indices or names; all by default) and mode (as :meth:`sample`) chosen once:
        ``sampler.pose(t)`` is :meth:`sample` of one time without resolving anything again,
        into buffers the next call overwrites; ``sampler.poses(times)`` a batch."""
        return Sampler(sampler_for(self, clip), joints, mode)

    def read_rotations(self, clip: int | str) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """A clip's root translation ``(T, 3)`` cm and local rotations ``(T, J, 4)``: the
        decoded arrays without the validation a :class:`Motion` adds (the fast path: one
        compiled call from the clip's coefficient rows, :func:`quatmotion.runtime.clip.
        clip_rotations`)."""
        rows = self.clip_rows(clip)
        decoded = clip_rotations(rows, self.rig(clip))
        if decoded is None:
            raise FormatError(f"clip {rows.name!r}: decoded channels are invalid", self._name)
        return decoded

    def clip_rows(self, clip: int | str, *, lazy: bool = False) -> ClipRows:
        """A clip decoded to its coefficient rows (:class:`~quatmotion.runtime.clip.ClipRows`,
        what the runtime samples and decodes from): a spline method's control points, no frame
        evaluated; any other method's decoded frames, one row each. ``lazy``: a format 3
        file's rows are left in their groups, each decoded when a sampler first needs it."""
        parts = self.clip_parts(clip)
        T, C = parts.entry.n_frames, parts.layout.layout.n_channels
        group_rows, decode_groups = 0, None
        try:
            if lazy and parts.context.version >= 3 and hasattr(self.method, "decode_coefficients"):
                from quatmotion.codec.methods.spline import read_rows_v3

                streams, cols, scale = read_rows_v3(parts.model, parts.payload, parts.context)
                tables = streams.tables
                P = np.zeros((tables.n_rows, len(cols)))
                group_rows = streams.group_rows
                method_error = self.method_error

                def decode_groups(P, first, stop, streams=streams, parts=parts):
                    try:
                        streams.decode(P, first, stop)
                    except FormatError as error:
                        raise method_error(parts, error) from None

                fix = parts.corrections
                lever = correction_lever(parts.layout)
                fixes = (fix.frames, fix.channels, fix.values * fix.quantum / lever[fix.channels])
            elif hasattr(self.method, "decode_coefficients"):
                _, tables, P, cols, scale = self.method.decode_coefficients(
                    parts.model, parts.payload, parts.context
                )
                fix = parts.corrections
                lever = correction_lever(parts.layout)
                fixes = (fix.frames, fix.channels, fix.values * fix.quantum / lever[fix.channels])
            else:
                X = self.method.decode(parts.model, parts.payload, parts.context)
                P = self.checked_channels(parts, X)  # corrections applied
                tables = segment_tables(T, (), 1)  # one segment kept frame by frame
                cols, scale = np.arange(C), np.ones(C)
                none = np.zeros(0, dtype=np.int64)
                fixes = (none, none, np.zeros(0))
        except FormatError as error:
            raise self.method_error(parts, error) from None
        return ClipRows(
            parts.entry.name, T, float(parts.entry.fps), tables.packed(),
            np.ascontiguousarray(tables.knots), np.ascontiguousarray(P, dtype=np.float64),
            np.asarray(cols, dtype=np.int64), np.ascontiguousarray(scale, dtype=np.float64),
            *(np.ascontiguousarray(a) for a in fixes), group_rows, decode_groups,
        )  # fmt: skip

    def rig(self, clip: int | str) -> Rig:
        """The rotation tables of a clip's skeleton and layout
        (:class:`~quatmotion.runtime.clip.Rig`, made once per pair)."""
        entry = self.header.clips[self.index_of(clip)]
        key = (entry.skeleton, entry.layout)
        rig = self._rigs.get(key)
        if rig is None:
            skeleton = self.skeleton(entry.skeleton)
            info, _ = self.layout(entry.layout)
            L = info.layout
            dof_axes, pre = _kernel_tables(skeleton, L)
            rig = self._rigs[key] = Rig(
                skeleton.joint_names, *(np.ascontiguousarray(a) for a in (
                    L.kinds, L.starts, L.counts, dof_axes, pre, info.reference)),
                L.n_channels,
            )  # fmt: skip
        return rig

    def read(self, clip: int | str) -> Motion:
        """A clip as a :class:`Motion` (skeleton, fps, frames and name exactly as stored)."""
        d = self.read_channels(clip)
        return from_channels(
            d.channels,
            d.skeleton,
            d.layout.layout,
            d.layout.reference,
            d.at_rest,
            d.entry.fps,
            d.entry.name,
        )

    def __iter__(self):
        for i in range(len(self)):
            yield self.read(i)

    def verify(self) -> None:
        """Read every chunk, checking every CRC (``FormatError`` on the first mismatch)."""
        if self.damaged:
            self._check_intact(self.damaged[0].index)
        for ref in [*self._record_chunks, *self._layout_chunks, *self._clip_chunks]:
            read_chunk(self._file, ref, self._name)


def _apply(corrections: Corrections, X: NDArray[np.float64], info: LayoutInfo) -> None:
    corrections.apply(X, correction_lever(info))


def _known() -> set[str]:
    from quatmotion.codec.methods import METHODS

    return set(METHODS)
