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
def _block_scales(starts, a, b, mean, start_scale, out):  # pragma: no cover - compiled
    """``out[:(b - a) C]``: the scales of rows ``a:b``, as :func:`encode_rows` forms them."""
    C = mean.shape[0]
    for i in range(a, b):
        src = start_scale if starts[i] else mean
        for c in range(C):
            out[(i - a) * C + c] = src[c]


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
    decoder = constriction.stream.queue.RangeDecoder(words)
    mean = np.maximum(np.asarray(initial, dtype=np.float64), _MIN_SCALE)
    start_scale = np.maximum(np.asarray(start_scale, dtype=np.float64), _MIN_SCALE)
    R = np.empty((n, C), dtype=np.int64)
    zeros = np.zeros(BLOCK_ROWS * C)
    scales = np.empty(BLOCK_ROWS * C)
    starts = np.ascontiguousarray(starts, dtype=np.bool_)
    try:
        for a, b in _blocks(n):
            k = (b - a) * C
            _block_scales(starts, a, b, mean, start_scale, scales)
            R[a:b] = decoder.decode(_LAPLACE, zeros[:k], scales[:k]).reshape(b - a, C)
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
