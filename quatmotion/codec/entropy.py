"""Entropy coding of integer residual rows with constriction's range coder.

Conventions
-----------
* The symbols are a table ``R`` of integers ``(n, C)``: rows in coding order (spline knots),
  one column per channel. Every symbol is coded with a quantised Laplace distribution of mean 0
  whose scale (expected ``|r|``, in symbol units) is known to the decoder before the symbol:
  the model is *backward adaptive*, so no per-clip statistics are sent.
* Rows are coded in blocks of :data:`BLOCK_ROWS`. A channel's scale for a block is a running
  mean of the ``|r|`` it had in earlier blocks, started from ``initial`` (the library's typical
  value, sent once per library). Rows flagged as *starts* (the first row of a segment, predicted
  only from the library mean pose) use ``start_scale`` instead and do not update the mean.
  One range-coder call per block keeps decoding vectorised over channels.
* ``|r| >= LIMIT`` is coded as ``+-LIMIT`` followed, after all rows, by ``|r| - LIMIT`` in two
  16-bit halves (rare: a clip's values far outside the library's range).
* The range coder's 32-bit words are stored little-endian with trailing zero bytes stripped
  (the decoder pads them back), so a stream costs its bytes, not a multiple of four.
* **Decoding** runs in one compiled loop (:func:`_decode_kernel`): constriction 0.5.0's range
  decoder (64-bit state, 32-bit words, 24-bit probabilities) and its leaky quantised Laplace
  model (``left(x) = floor(w cdf(x - 1/2)) + (x - min)`` with ``w = 2^24 - 1 - (max - min)``)
  written out, so it reads the bytes constriction wrote, to the bit, without a Python call
  per block. A stream with escapes (``|r| >= LIMIT``, rare) is decoded by constriction itself.
"""

from __future__ import annotations

import constriction
import numba
import numpy as np
from numpy.typing import NDArray

__all__ = ["BLOCK_ROWS", "decode_rows", "encode_rows"]

BLOCK_ROWS = 4
LIMIT = (1 << 15) - 1
_MIN_SCALE = 0.04
_DECAY = 0.6

_LAPLACE = constriction.stream.model.QuantizedLaplace(-LIMIT, LIMIT)
_HIGH = constriction.stream.model.QuantizedLaplace(0, (1 << 16) - 1, 0.0, 2.0)
_LOW = constriction.stream.model.Uniform(1 << 16)


def _blocks(n: int):
    for a in range(0, n, BLOCK_ROWS):
        yield a, min(n, a + BLOCK_ROWS)


def _update(mean: NDArray[np.float64], block: NDArray[np.int64], starts: NDArray[np.bool_]):
    rows = block[~starts]
    if len(rows):
        mean = _DECAY * mean + (1.0 - _DECAY) * np.abs(rows).mean(axis=0)
    return np.maximum(mean, _MIN_SCALE)


@numba.njit(cache=True)
def _update_mean(R, starts, a, b, mean):  # pragma: no cover - compiled
    """:func:`_update` in place (the same arithmetic: a float sum of integers, then one
    division, so the decoder's scales are the encoder's to the bit)."""
    count = 0
    for i in range(a, b):
        if not starts[i]:
            count += 1
    C = mean.shape[0]
    for c in range(C):
        if count:
            total = 0.0
            for i in range(a, b):
                if not starts[i]:
                    total += float(abs(R[i, c]))
            mean[c] = _DECAY * mean[c] + (1.0 - _DECAY) * (total / count)
        if mean[c] < _MIN_SCALE:
            mean[c] = _MIN_SCALE


def encode_rows(
    R: NDArray[np.int64],
    initial: NDArray[np.float64],
    start_scale: NDArray[np.float64],
    starts: NDArray[np.bool_],
) -> bytes:
    """Code ``R`` ``(n, C)``.

    Parameters
    ----------
    R : ndarray of int, shape (n, C)
    initial : ndarray, shape (C,)
        Starting expected ``|r|`` of each channel, symbol units.
    start_scale : ndarray, shape (C,)
        Expected ``|r|`` of start rows.
    starts : ndarray of bool, shape (n,)
        Which rows are starts.

    Returns
    -------
    bytes
    """
    R = np.asarray(R, dtype=np.int64)
    n, C = R.shape
    mean = np.maximum(np.asarray(initial, dtype=np.float64), _MIN_SCALE)
    start_scale = np.maximum(np.asarray(start_scale, dtype=np.float64), _MIN_SCALE)
    clipped = np.clip(R, -LIMIT, LIMIT).astype(np.int32)
    encoder = constriction.stream.queue.RangeEncoder()
    zeros = np.zeros(BLOCK_ROWS * C)
    for a, b in _blocks(n):
        s = starts[a:b]
        scales = np.where(s[:, None], start_scale[None, :], mean[None, :]).ravel()
        encoder.encode(clipped[a:b].ravel(), _LAPLACE, zeros[: scales.size], scales)
        mean = _update(mean, clipped[a:b], s)
    over = np.abs(R) >= LIMIT
    if np.any(over):
        excess = np.abs(R[over]) - LIMIT
        if np.any(excess >= 1 << 32):
            raise ValueError("a residual exceeds the coder's range (2**47)")
        encoder.encode((excess >> 16).astype(np.int32), _HIGH)
        encoder.encode((excess & 0xFFFF).astype(np.int32), _LOW)
    words = encoder.get_compressed()
    return words.astype("<u4").tobytes().rstrip(b"\0")


_PRECISION = 24
_FREE = float((1 << _PRECISION) - 1 - 2 * LIMIT)  # the leaky quantiser's free weight


@numba.njit(inline="always", cache=True)
def _left(x, b):  # pragma: no cover - compiled
    """Left cumulative of symbol ``x`` (int64) under the leaky Laplace of scale ``b``, as
    constriction's ``LeakyQuantizer<f64, i32, u32, 24>`` of ``probability``'s ``Laplace(0, b)``."""
    if x <= -LIMIT:
        return np.uint64(0)
    if x > LIMIT:
        return np.uint64(1 << _PRECISION)
    v = float(x) - 0.5
    cdf = 0.5 * np.exp(v / b) if v <= 0.0 else 1.0 - 0.5 * np.exp(-v / b)
    return np.uint64(_FREE * cdf) + np.uint64(x + LIMIT)


_CACHED = 8  # left cumulatives of symbols -8..9 are kept per channel and scale


@numba.njit(inline="always", cache=True)
def _cached_left(cum, stamp, k, c, x, b, key):  # pragma: no cover - compiled
    """:func:`_left` of symbol ``x``, remembered in ``cum[k, c]`` while ``stamp`` says ``key``
    (the scale of channel ``c`` is the same while ``key`` is)."""
    j = x + _CACHED
    if j < 0 or j > 2 * _CACHED + 1:
        return _left(x, b)
    if stamp[k, c, j] != key:
        cum[k, c, j] = _left(x, b)
        stamp[k, c, j] = key
    return cum[k, c, j]


@numba.njit(cache=True)
def _decode_kernel(words, initial, start_scale, starts, R, used):  # pragma: no cover - compiled
    """Decode ``R`` ``(n, C)`` in place; 0, or -1 for data no encoder wrote (a quantile out of
    range), or 1 when a symbol is an escape (the caller decodes the stream with constriction).
    ``used`` receives the words read and the words wanted past the end (read as zeros).

    A channel's scale holds for a block (start rows: for the stream), so the cumulatives of its
    few common symbols are computed once per block; the search for a symbol walks from 0 over
    them, and only a symbol beyond them starts from the continuous inverse."""
    n, C = R.shape
    nw = words.shape[0]
    pos = 0
    point = np.uint64(0)
    got = 0
    while pos < nw and got < 2:
        point = (point << np.uint64(32)) | np.uint64(words[pos])
        pos += 1
        got += 1
    if got == 1:
        point = point << np.uint64(32)
    beyond = 2 - got
    lower = np.uint64(0)
    rng = np.uint64(0xFFFFFFFFFFFFFFFF)
    one24 = np.uint64(1 << _PRECISION)
    low_range = np.uint64(1 << 32)
    mean = initial.copy()
    cum = np.empty((2, C, 2 * _CACHED + 2), dtype=np.uint64)
    stamp = np.full((2, C, 2 * _CACHED + 2), -1, dtype=np.int64)
    escaped = False
    for a in range(0, n, BLOCK_ROWS):
        b = min(n, a + BLOCK_ROWS)
        for i in range(a, b):
            k = 1 if starts[i] else 0
            key = 0 if k else a
            for c in range(C):
                scale = start_scale[c] if k else mean[c]
                step = rng >> np.uint64(_PRECISION)
                q = (point - lower) // step
                if q >= one24:
                    return -1
                x = 0
                left = _cached_left(cum, stamp, k, c, 0, scale, key)
                if left > q:
                    while left > q and x > -_CACHED:
                        x -= 1
                        left = _cached_left(cum, stamp, k, c, x, scale, key)
                    right = _cached_left(cum, stamp, k, c, x + 1, scale, key)
                else:
                    right = _cached_left(cum, stamp, k, c, 1, scale, key)
                    while right <= q and x < _CACHED:
                        x += 1
                        left = right
                        right = _cached_left(cum, stamp, k, c, x + 1, scale, key)
                if left > q or right <= q:
                    # beyond the cached symbols: a guess from the continuous inverse, then
                    # the exact search
                    p = (float(q) + 0.5) / 16777216.0
                    g = scale * np.log(2.0 * p) if p <= 0.5 else -scale * np.log(2.0 - 2.0 * p)
                    x = np.int64(np.floor(min(max(g, -LIMIT), LIMIT) + 0.5))
                    left = _left(x, scale)
                    while left > q:
                        x -= 1
                        left = _left(x, scale)
                    right = _left(x + 1, scale)
                    while right <= q:
                        x += 1
                        left = right
                        right = _left(x + 1, scale)
                lower = lower + step * left
                rng = step * (right - left)
                if rng < low_range:
                    lower = lower << np.uint64(32)
                    rng = rng << np.uint64(32)
                    point = point << np.uint64(32)
                    if pos < nw:
                        point = point | np.uint64(words[pos])
                        pos += 1
                    else:
                        beyond += 1
                R[i, c] = x
                if x == LIMIT or x == -LIMIT:
                    escaped = True
        _update_mean(R, starts, a, b, mean)
    used[0] = pos
    used[1] = beyond
    return 1 if escaped else 0


_SEAL_WORDS = 2
"""Words a decoder of exactly the rows coded may want past the stream's end: its look-ahead
beyond the encoder's last word (1), and a last word of zeros, stripped (1; two such words
would come once in 2**64 streams)."""


def decode_rows(
    data: bytes,
    n: int,
    initial: NDArray[np.float64],
    start_scale: NDArray[np.float64],
    starts: NDArray[np.bool_],
) -> NDArray[np.int64]:
    """The ``(n, C)`` rows :func:`encode_rows` coded (``C = len(initial)``).

    Raises
    ------
    ValueError
        If the data are not a valid stream for these models (corruption).
    """
    C = len(initial)
    padded = data + b"\0" * (-len(data) % 4)
    words = np.frombuffer(padded, dtype="<u4").astype(np.uint32)
    mean = np.maximum(np.asarray(initial, dtype=np.float64), _MIN_SCALE)
    start_scale = np.maximum(np.asarray(start_scale, dtype=np.float64), _MIN_SCALE)
    starts = np.ascontiguousarray(starts, dtype=np.bool_)
    R = np.empty((n, C), dtype=np.int64)
    used = np.zeros(2, dtype=np.int64)
    status = _decode_kernel(words, mean, start_scale, starts, R, used)
    if status < 0:
        raise ValueError("corrupt entropy-coded stream (a quantile out of range)")
    if status == 0:
        # A stream is its rows' to the word: one that goes on after them, or ends before them,
        # holds other rows than asked for (a header's frame count the data contradict).
        if used[0] < len(words):
            raise ValueError(f"corrupt entropy-coded stream (it goes on after its {n:,} rows)")
        if used[1] > _SEAL_WORDS:
            raise ValueError(f"corrupt entropy-coded stream (it ends before its {n:,} rows)")
        return R
    return _decode_rows_constriction(words, n, mean, start_scale, starts)


def _decode_rows_constriction(words, n, initial, start_scale, starts) -> NDArray[np.int64]:
    """:func:`decode_rows` by constriction's decoder, a block per call (streams with escapes)."""
    C = len(initial)
    decoder = constriction.stream.queue.RangeDecoder(words)
    mean = np.maximum(np.asarray(initial, dtype=np.float64), _MIN_SCALE)
    start_scale = np.maximum(np.asarray(start_scale, dtype=np.float64), _MIN_SCALE)
    R = np.empty((n, C), dtype=np.int64)
    zeros = np.zeros(BLOCK_ROWS * C)
    starts = np.ascontiguousarray(starts, dtype=np.bool_)
    try:
        for a, b in _blocks(n):
            k = (b - a) * C
            s = starts[a:b]
            scales = np.where(s[:, None], start_scale[None, :], mean[None, :]).ravel()
            R[a:b] = decoder.decode(_LAPLACE, zeros[:k], scales).reshape(b - a, C)
            _update_mean(R, starts, a, b, mean)
        over = np.abs(R) >= LIMIT
        if np.any(over):
            k = int(over.sum())
            high = decoder.decode(_HIGH, k).astype(np.int64)
            low = decoder.decode(_LOW, k).astype(np.int64)
            R[over] = np.sign(R[over]) * (LIMIT + (high << 16) + low)
    except (AssertionError, KeyError, ValueError) as error:
        raise ValueError(f"corrupt entropy-coded stream ({error})") from None
    return R
