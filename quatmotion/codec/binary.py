"""Little byte-level readers and writers: LEB128 varints, zigzag, IEEE floats, strings.

Conventions
-----------
* Unsigned integers are LEB128 varints (7 bits per byte, low bits first, high bit set on all
  bytes but the last). Signed integers are zigzag-mapped first (``0, -1, 1, -2...`` to
  ``0, 1, 2, 3...``).
* Floats are IEEE 754, little-endian (``f32``, ``f64``). Strings are a varint byte count then
  UTF-8.
* :class:`Reader` raises :class:`~quatmotion.errors.FormatError` (naming the file and what it was
  reading) when the data end early or a value is out of range, never ``IndexError``; a count
  is checked against the bytes left before anything is allocated for it.
* :func:`inflate` is the one inflater of the file's raw deflate streams (header, skeleton
  records, library models): it never makes more bytes than the limit in force
  (:mod:`quatmotion.limits`, ``decompressed_bytes``) or than the caller expects.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from quatmotion.errors import FormatError
from quatmotion.limits import check, current

__all__ = ["Reader", "Writer", "inflate"]

_F32 = struct.Struct("<f")
_F64 = struct.Struct("<d")


class Writer:
    """Appends values to a growing byte string."""

    def __init__(self) -> None:
        self._parts: list[bytes] = []

    def u8(self, value: int) -> Writer:
        if not 0 <= value < 256:
            raise ValueError(f"byte value out of range: {value}")
        self._parts.append(bytes((value,)))
        return self

    def uvarint(self, value: int) -> Writer:
        value = int(value)
        if value < 0:
            raise ValueError(f"unsigned varint of a negative number: {value}")
        out = bytearray()
        while True:
            byte = value & 0x7F
            value >>= 7
            if value:
                out.append(byte | 0x80)
            else:
                out.append(byte)
                break
        self._parts.append(bytes(out))
        return self

    def svarint(self, value: int) -> Writer:
        value = int(value)
        return self.uvarint(2 * value if value >= 0 else -2 * value - 1)

    def f32(self, value: float) -> Writer:
        self._parts.append(_F32.pack(value))
        return self

    def f64(self, value: float) -> Writer:
        self._parts.append(_F64.pack(value))
        return self

    def raw(self, data: bytes) -> Writer:
        self._parts.append(bytes(data))
        return self

    def blob(self, data: bytes) -> Writer:
        """A varint length, then the bytes."""
        return self.uvarint(len(data)).raw(data)

    def string(self, text: str) -> Writer:
        return self.blob(text.encode("utf-8"))

    def array(self, values: NDArray, dtype: str) -> Writer:
        """Fixed-width little-endian values (``"<i2"``, ``"<u1"``...), count not written."""
        return self.raw(np.asarray(values).astype(dtype).tobytes())

    def bytes(self) -> bytes:
        return b"".join(self._parts)


class Reader:
    """Reads what :class:`Writer` wrote; errors name ``source`` and ``what``."""

    def __init__(self, data: bytes, source: str | Path | None = None, what: str = "data"):
        self._data = memoryview(data)
        self._pos = 0
        self._source = source
        self._what = what

    @property
    def remaining(self) -> int:
        return len(self._data) - self._pos

    def _fail(self, message: str) -> FormatError:
        return FormatError(f"{self._what}: {message}", self._source)

    def take(self, n: int) -> bytes:
        if n < 0 or self._pos + n > len(self._data):
            raise self._fail(f"ends early (wanted {n} bytes at offset {self._pos})")
        out = bytes(self._data[self._pos : self._pos + n])
        self._pos += n
        return out

    def u8(self) -> int:
        return self.take(1)[0]

    def uvarint(self, limit: int = 1 << 62) -> int:
        value = 0
        shift = 0
        while True:
            byte = self.u8()
            value |= (byte & 0x7F) << shift
            if not byte & 0x80:
                break
            shift += 7
            if shift > 63:
                raise self._fail("varint longer than 64 bits")
        if value > limit:
            raise self._fail(f"value {value} exceeds {limit}")
        return value

    def uvarints(self, count: int) -> NDArray[np.uint64]:
        """``count`` uvarints in a row, ``(count,)`` (one compiled pass: clips hold thousands)."""
        from quatmotion.codec._decode_kernels import read_uvarints

        if count > self.remaining:  # a varint takes a byte at least
            raise self._fail(f"ends early ({count} varints wanted, {self.remaining} bytes left)")
        out = np.empty(count, dtype=np.uint64)
        buf = np.frombuffer(self._data, dtype=np.uint8)
        pos = read_uvarints(buf, self._pos, out)
        if pos == -1:
            raise self._fail(f"ends early (in {count} varints from offset {self._pos})")
        if pos == -2:
            raise self._fail("varint longer than 64 bits")
        self._pos = pos
        return out

    def svarint(self) -> int:
        u = self.uvarint()
        return u // 2 if u % 2 == 0 else -(u + 1) // 2

    def f32(self) -> float:
        return _F32.unpack(self.take(4))[0]

    def f64(self) -> float:
        return _F64.unpack(self.take(8))[0]

    def blob(self, limit: int = 1 << 40) -> bytes:
        return self.take(self.uvarint(limit))

    def string(self) -> str:
        raw = self.blob()
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise self._fail("a name is not UTF-8") from None

    def array(self, count: int, dtype: str) -> NDArray:
        size = np.dtype(dtype).itemsize
        return np.frombuffer(self.take(count * size), dtype=dtype).copy()

    def end(self) -> None:
        """Raise unless everything was read."""
        if self.remaining:
            raise self._fail(f"{self.remaining} unexpected bytes at the end")


def inflate(
    data: bytes,
    what: str,
    source: str | Path | None = None,
    *,
    limit: int | None = None,
    zdict: bytes = b"",
) -> bytes:
    """A raw deflate stream (window bits -15, as :class:`Writer`'s callers deflate) inflated.

    At most ``limit`` bytes (default: the ``decompressed_bytes`` limit in force) are ever made:
    a stream that would expand further is refused before it does (a decompression bomb), as
    is a stream cut short or followed by other bytes.

    Raises
    ------
    FormatError
        Naming ``what`` and ``source``.
    """
    cap = current().decompressed_bytes
    cap = cap if limit is None else min(limit, cap)
    try:
        inflater = zlib.decompressobj(-15, zdict) if zdict else zlib.decompressobj(-15)
        out = inflater.decompress(data, cap + 1)
    except zlib.error as error:
        raise FormatError(f"{what}: not a valid deflate stream ({error})", source) from None
    if len(out) > cap:
        check("decompressed_bytes", len(out), source, f"{what}: the inflated size (at least)")
        raise FormatError(f"{what}: inflates to more than the {cap:,} bytes expected", source)
    if not inflater.eof or inflater.unused_data:
        raise FormatError(f"{what}: not a valid deflate stream (incomplete stream)", source)
    return out
