"""Static rANS coding of integer rows: ``.qmz`` format 3's entropy coder, decoded by one
table lookup a symbol.

Conventions
-----------
* The symbols are a table ``R`` of integers ``(n, c)``, rows in coding order, one column per
  channel; some rows are *start* rows (each run of rows that decodes alone begins with one).
  Every symbol is coded with a fixed Laplace model chosen by a **scale code** ``q`` (an
  integer: scale ``2 ** (q / 8)`` symbol units). A start row's symbols use their channel's
  start code. Any other symbol uses its channel's code plus ``DELTAS[j]``, where the
  *context* ``j`` (0 to 7) counts how many of ``2 ** ((q + 8 i - 24) / 8)``, ``i = 1..7``,
  the sum ``h`` of the magnitudes of the channel's last two symbols since the latest start
  row reaches (0 for a symbol missing): how active the channel has just been, against its
  scale. The model is static and backward-adapted by ``h`` alone, so a run of rows from a
  start row decodes alone, with no state before it.
* The thresholds are integers, ``ceil(2 ** (m / 8))`` (1 for ``m <= 0``), computed exactly in
  integer arithmetic (:func:`thresholds`), so every machine takes the same contexts.
* The models are the frequency tables of ``rans_tables.bin`` (made once by
  ``tools/make_rans_tables.py``; part of the format, never recomputed): 12-bit
  probabilities, values ``-M..M`` and an escape symbol. A code below ``Q_MIN`` uses the
  table of ``Q_MIN``; a code ``q >= 32`` sends the ``k = (q - 24) // 8`` low bits of every
  value raw and codes ``floor(v / 2 ** k)`` with the *shifted* table of ``q - 8 k``, so an
  alphabet never outgrows its table.
* **rANS**: 32-bit state in ``[2**16, 2**32)``, 16-bit words, encoded last symbol first so
  that it decodes first to last; a stream is the final state (u32 little-endian) then the
  words (u16 little-endian) in the order the decoder reads them. After the last symbol the
  decoder's state is the encoder's first, ``2**16``, and every word is consumed: that is
  checked (a corrupt stream is refused, not decoded to garbage).
* Per symbol, in decoding order: the table symbol; for the escape, a sign bit, a 6-bit length
  ``n`` and ``n`` bits of ``|y| - M - 1`` (least significant 16-bit chunk first); then the
  ``k`` raw low bits (chunks of 16 bits, least significant first). Raw bits are rANS symbols
  of frequency 1 out of ``2 ** bits``.
* Kernels trust their input (the caller checked shapes and codes); no fastmath: the encoder
  and decoder are integer arithmetic only.
"""

from __future__ import annotations

from importlib import resources
from math import isqrt

import numba
import numpy as np
from numpy.typing import NDArray

__all__ = [
    "DELTAS",
    "ESCAPE_BITS",
    "LIMIT",
    "PROB_BITS",
    "Q_MIN",
    "Model",
    "Tables",
    "decode_rows",
    "decode_span",
    "encode_rows",
    "load_tables",
    "model_of",
    "stream_bytes",
    "table_of",
    "thresholds",
]

PROB_BITS = 12
_TOTAL = 1 << PROB_BITS
_LOW = 1 << 16  # the state's lower bound
Q_MIN = -48
"""The smallest scale code with a table of its own (scale 2**-6)."""
_Q_DIRECT_END = 32  # direct tables for codes Q_MIN..31
_Q_SHIFT_BASE = 24  # shifted tables for codes 24..31
_N_DIRECT = _Q_DIRECT_END - Q_MIN
ESCAPE_BITS = 6
LIMIT = 1 << 62
"""Values code in ``-LIMIT < v < LIMIT``."""
_MAX_RAW = 16
_MAX_SHIFT = 40
DELTAS = (-2, -8, -5, -2, 2, 7, 13, 32)
"""A symbol's code offset by its context (measured: docs/performance.md, format 3)."""
_N_CTX = len(DELTAS)
_H_CAP = 1 << 40  # a magnitude entering a context is capped (no overflow of the sum)


class Tables:
    """The format's frequency tables, unpacked for coding: ``M`` ``(n_tables,)``, ``freq`` and
    ``cum`` ``(n_tables, 256)`` by symbol index (``v + M``; the escape at ``2 M + 1``), and
    ``dec`` ``(n_tables, 4096)``: per slot, the symbol index ``<< 32``, its frequency
    ``<< 16`` and the slot's offset in the symbol's range."""

    def __init__(self, freqs: list[list[int]]):
        n = len(freqs)
        self.freqs = freqs
        self.M = np.array([(len(f) - 2) // 2 for f in freqs], dtype=np.int64)
        self.freq = np.zeros((n, 256), dtype=np.int64)
        self.cum = np.zeros((n, 256), dtype=np.int64)
        self.dec = np.zeros((n, _TOTAL), dtype=np.int64)
        for t, f in enumerate(freqs):
            f = np.asarray(f, dtype=np.int64)
            cum = np.concatenate(([0], np.cumsum(f)[:-1]))
            self.freq[t, : len(f)] = f
            self.cum[t, : len(f)] = cum
            sym = np.repeat(np.arange(len(f), dtype=np.int64), f)
            slots = np.arange(_TOTAL, dtype=np.int64)
            self.dec[t] = (sym << 32) | (f[sym] << 16) | (slots - cum[sym])


_TABLES: Tables | None = None


def load_tables() -> Tables:
    """The format's tables (read once from the package's ``rans_tables.bin``)."""
    global _TABLES
    if _TABLES is None:
        data = resources.files("quatmotion.codec").joinpath("rans_tables.bin").read_bytes()
        if data[:8] != b"QMZRANS1":
            raise RuntimeError("quatmotion/codec/rans_tables.bin is not the format's tables")
        n = int.from_bytes(data[8:10], "little")
        pos = 10
        freqs = []
        for _ in range(n):
            M = data[pos]
            k = 2 * M + 2
            freqs.append(np.frombuffer(data, "<u2", k, pos + 1).astype(np.int64).tolist())
            pos += 1 + 2 * k
        _TABLES = Tables(freqs)
    return _TABLES


def table_of(q: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The table index and the raw low bits ``k`` of scale codes ``q`` (any shape)."""
    q = np.maximum(np.asarray(q, dtype=np.int64), Q_MIN)
    k = np.where(q >= _Q_DIRECT_END, (q - _Q_SHIFT_BASE) >> 3, 0)
    k = np.minimum(k, _MAX_SHIFT)
    t = np.where(k > 0, _N_DIRECT + (q - 8 * k - _Q_SHIFT_BASE), q - Q_MIN)
    t = np.where((k > 0) & (q - 8 * k >= _Q_DIRECT_END), _N_DIRECT + 7, t)  # past the cap
    return t.astype(np.int64), k.astype(np.int64)


_THRESHOLDS: dict[int, int] = {}


def thresholds(m: NDArray[np.int64]) -> NDArray[np.int64]:
    """``ceil(2 ** (m / 8))`` of integers ``m`` (1 for ``m <= 0``), exactly, capped at 2**62."""
    m = np.asarray(m, dtype=np.int64)
    out = np.empty(m.shape, dtype=np.int64)
    for idx, v in np.ndenumerate(m):
        v = int(v)
        if v not in _THRESHOLDS:
            if v <= 0:
                x = 1
            elif v >= 8 * 62:
                x = 1 << 62
            else:
                n = 1 << v
                x = isqrt(isqrt(isqrt(n)))  # floor of the eighth root
                x += x**8 < n
            _THRESHOLDS[v] = x
        out[idx] = _THRESHOLDS[v]
    return out


class Model:
    """One stream's models, per channel: ``t_start``, ``k_start`` ``(c,)`` (start rows), and by
    context ``t_ctx``, ``k_ctx`` ``(c, 8)`` and the context thresholds ``thr`` ``(c, 7)``."""

    def __init__(self, main_codes, start_codes):
        main = np.asarray(main_codes, dtype=np.int64)
        t_ctx, k_ctx = table_of(main[:, None] + np.asarray(DELTAS, dtype=np.int64)[None, :])
        self.t_ctx = np.ascontiguousarray(t_ctx)
        self.k_ctx = np.ascontiguousarray(k_ctx)
        self.thr = thresholds(main[:, None] + 8 * np.arange(1, _N_CTX)[None, :] - 24)
        t, k = table_of(np.asarray(start_codes, dtype=np.int64))
        self.t_start = np.ascontiguousarray(t)
        self.k_start = np.ascontiguousarray(k)

    def args(self) -> tuple:
        return self.t_start, self.k_start, self.t_ctx, self.k_ctx, self.thr


_MODELS: dict[bytes, Model] = {}


def model_of(main_codes: NDArray[np.int64], start_codes: NDArray[np.int64]) -> Model:
    """The :class:`Model` of these codes (remembered: a library's clips share a few)."""
    main = np.asarray(main_codes, dtype=np.int64)
    start = np.asarray(start_codes, dtype=np.int64)
    key = main.tobytes() + b"|" + start.tobytes()
    model = _MODELS.get(key)
    if model is None:
        if len(_MODELS) > 1024:
            _MODELS.clear()
        model = _MODELS[key] = Model(main, start)
    return model


@numba.njit(inline="always", cache=True)
def _context(h, thr, c):  # pragma: no cover - compiled
    j = 0
    while j < _N_CTX - 1 and h >= thr[c, j]:
        j += 1
    return j


# ---------------------------------------------------------------------------- encoding
@numba.njit(inline="always", cache=True)
def _put(x, freq, cum, bits, out, n_out):  # pragma: no cover - compiled
    """Encode a symbol of frequency ``freq`` at ``cum`` out of ``2 ** bits``; the state and
    the words written."""
    x_max = np.uint64(freq) << np.uint64(32 - bits)
    while x >= x_max:
        out[n_out] = np.uint16(x & np.uint64(0xFFFF))
        n_out += 1
        x = x >> np.uint64(16)
    x = ((x // np.uint64(freq)) << np.uint64(bits)) + (x % np.uint64(freq)) + np.uint64(cum)
    return x, n_out


@numba.njit(inline="always", cache=True)
def _put_raw(x, value, bits, out, n_out):  # pragma: no cover - compiled
    """Encode ``bits`` raw bits of ``value`` (``bits`` may exceed 16: chunks, the least
    significant decoded first, so encoded last)."""
    n_chunks = (bits + _MAX_RAW - 1) // _MAX_RAW
    for j in range(n_chunks - 1, -1, -1):
        width = min(_MAX_RAW, bits - j * _MAX_RAW)
        chunk = (value >> np.uint64(j * _MAX_RAW)) & np.uint64((1 << width) - 1)
        x, n_out = _put(x, 1, chunk, width, out, n_out)
    return x, n_out


@numba.njit(cache=True)
def _encode_kernel(
    R, starts, t_start, k_start, t_ctx, k_ctx, thr, M, freq, cum, out
):  # pragma: no cover - compiled  # noqa: E501
    """Encode rows ``R`` into ``out`` (uint16, reversed); the final state and the word count.
    The contexts are found first to last, then the symbols coded last to first."""
    n, C = R.shape
    T = np.empty((n, C), dtype=np.int64)
    K = np.empty((n, C), dtype=np.int64)
    h1 = np.zeros(C, dtype=np.int64)
    h2 = np.zeros(C, dtype=np.int64)
    for i in range(n):
        for c in range(C):
            if starts[i]:
                T[i, c] = t_start[c]
                K[i, c] = k_start[c]
                h1[c] = 0
                h2[c] = 0
            else:
                j = _context(h1[c] + h2[c], thr, c)
                T[i, c] = t_ctx[c, j]
                K[i, c] = k_ctx[c, j]
                h2[c] = h1[c]
                h1[c] = min(abs(R[i, c]), _H_CAP)
    x = np.uint64(_LOW)
    n_out = 0
    for i in range(n - 1, -1, -1):
        for c in range(C - 1, -1, -1):
            t = T[i, c]
            k = K[i, c]
            v = R[i, c]
            y = v >> k
            if k > 0:
                x, n_out = _put_raw(x, np.uint64(v - (y << k)), k, out, n_out)
            m = M[t]
            if -m <= y <= m:
                s = y + m
            else:
                s = 2 * m + 1
                e = (y if y > 0 else -y) - m - 1
                nb = 0
                while (e >> nb) > 0:
                    nb += 1
                x, n_out = _put_raw(x, np.uint64(e), nb, out, n_out)
                x, n_out = _put_raw(x, np.uint64(nb), ESCAPE_BITS, out, n_out)
                x, n_out = _put_raw(x, np.uint64(1 if y < 0 else 0), 1, out, n_out)
            x, n_out = _put(x, freq[t, s], cum[t, s], PROB_BITS, out, n_out)
    return x, n_out


def _checked(R) -> NDArray[np.int64]:
    R = np.ascontiguousarray(R, dtype=np.int64)
    if R.size and (R.max() >= LIMIT or R.min() <= -LIMIT):
        raise ValueError("a value exceeds the entropy coder's range (2**62)")
    return R


def encode_rows(R: NDArray[np.int64], starts: NDArray[np.bool_], model: Model) -> bytes:
    """One stream of rows ``R`` ``(n, c)``, ``starts`` ``(n,)`` flagging the start rows.

    Raises
    ------
    ValueError
        A value beyond the coder's range (``|v| >= 2 ** 62``).
    """
    tables = load_tables()
    R = _checked(R)
    # a symbol writes at most its table symbol, the escape's 1 + 6 + 63 bits and 40 raw bits
    out = np.empty(8 * R.size + 4, dtype=np.uint16)
    starts = np.ascontiguousarray(starts, dtype=np.bool_)
    x, n_out = _encode_kernel(R, starts, *model.args(), tables.M, tables.freq, tables.cum, out)
    return int(x).to_bytes(4, "little") + out[:n_out][::-1].astype("<u2").tobytes()


def stream_bytes(R: NDArray[np.int64], starts: NDArray[np.bool_], model: Model) -> int:
    """The size :func:`encode_rows` makes, without the bytes (the encoder's choices)."""
    tables = load_tables()
    R = _checked(R)
    out = np.empty(8 * R.size + 4, dtype=np.uint16)
    starts = np.ascontiguousarray(starts, dtype=np.bool_)
    _, n_out = _encode_kernel(R, starts, *model.args(), tables.M, tables.freq, tables.cum, out)
    return 4 + 2 * int(n_out)


# ---------------------------------------------------------------------------- decoding
@numba.njit(inline="always", cache=True)
def _word(buf, pos, n, base):  # pragma: no cover - compiled
    """Word ``pos`` of the little-endian u16 words at ``buf[base:]``, 0 past ``n`` words."""
    if pos >= n:
        return np.uint64(0)
    p = base + 2 * pos
    return np.uint64(buf[p]) | (np.uint64(buf[p + 1]) << np.uint64(8))


@numba.njit(inline="always", cache=True)
def _get_raw(x, bits, buf, pos, n, base):  # pragma: no cover - compiled
    """``bits`` raw bits (chunks of 16, least significant first); the value, state and
    position (``pos > n`` when the words ran out)."""
    value = np.uint64(0)
    shift = 0
    while bits > 0:
        width = min(_MAX_RAW, bits)
        value |= (x & np.uint64((1 << width) - 1)) << np.uint64(shift)
        x = x >> np.uint64(width)
        while x < np.uint64(_LOW):
            x = (x << np.uint64(16)) | _word(buf, pos, n, base)
            pos += 1
        shift += width
        bits -= width
    return value, x, pos


@numba.njit(cache=True)
def decode_span(
    buf, begin, end, R, a, b, starts, t_start, k_start, t_ctx, k_ctx, thr, M, dec
):  # pragma: no cover - compiled  # noqa: E501
    """Decode rows ``a..b`` of ``R`` from the stream ``buf[begin:end]`` (uint8; ``starts``
    indexed as ``R``); 0, or -1 for a stream no encoder wrote (too short, words left over, a
    final state that is not the encoder's first)."""
    if end - begin < 4 or (end - begin) % 2:
        return -1
    x = np.uint64(0)
    for j in range(4):
        x |= np.uint64(buf[begin + j]) << np.uint64(8 * j)
    n = (end - begin - 4) // 2
    base = begin + 4
    pos = 0
    mask = np.uint64(_TOTAL - 1)
    C = R.shape[1]
    h1 = np.zeros(C, dtype=np.int64)
    h2 = np.zeros(C, dtype=np.int64)
    for i in range(a, b):
        start = starts[i]
        for c in range(C):
            if start:
                t = t_start[c]
                k = k_start[c]
            else:
                j = _context(h1[c] + h2[c], thr, c)
                t = t_ctx[c, j]
                k = k_ctx[c, j]
            slot = x & mask
            entry = dec[t, slot]
            s = entry >> 32
            x = np.uint64((entry >> 16) & 0xFFFF) * (x >> np.uint64(PROB_BITS)) + np.uint64(
                entry & 0xFFFF
            )
            while x < np.uint64(_LOW):
                x = (x << np.uint64(16)) | _word(buf, pos, n, base)
                pos += 1
            m = M[t]
            if s <= 2 * m:
                y = s - m
            else:
                sign, x, pos = _get_raw(x, 1, buf, pos, n, base)
                nb, x, pos = _get_raw(x, ESCAPE_BITS, buf, pos, n, base)
                e, x, pos = _get_raw(x, np.int64(nb), buf, pos, n, base)
                if e >= np.uint64(LIMIT):
                    return -1
                y = np.int64(e) + m + 1
                if sign:
                    y = -y
            if k > 0:
                low, x, pos = _get_raw(x, k, buf, pos, n, base)
                v = (y << k) + np.int64(low)
            else:
                v = y
            R[i, c] = v
            if start:
                h1[c] = 0
                h2[c] = 0
            else:
                h2[c] = h1[c]
                h1[c] = min(abs(v), _H_CAP)
            if pos > n:
                return -1
    if pos != n or x != np.uint64(_LOW):
        return -1
    return 0


def decode_rows(
    data: bytes, starts: NDArray[np.bool_], model: Model, n_channels: int
) -> NDArray[np.int64]:
    """The rows :func:`encode_rows` coded (``n = len(starts)``).

    Raises
    ------
    ValueError
        If the bytes are not a stream of these rows and codes (corruption).
    """
    tables = load_tables()
    buf = np.frombuffer(bytes(data), dtype=np.uint8)
    starts = np.ascontiguousarray(starts, dtype=np.bool_)
    R = np.empty((len(starts), n_channels), dtype=np.int64)
    status = decode_span(buf, 0, len(buf), R, 0, len(starts), starts, *model.args(), tables.M,
                         tables.dec)  # fmt: skip
    if status:
        raise ValueError("corrupt entropy-coded stream (its words or final state)")
    return R
