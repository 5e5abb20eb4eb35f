"""The compiled varint reader of :class:`quatmotion.codec.binary.Reader` (a loop over bytes
NumPy cannot vectorise). The decoding runtime's loops are :mod:`quatmotion.runtime._kernels`."""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["read_uvarints"]


@numba.njit(cache=True)
def read_uvarints(buf, pos, out):  # pragma: no cover
    """LEB128 varints from ``buf`` (uint8) at ``pos`` into ``out`` (uint64, its length many);
    the position after them, ``-1`` if the data end first, ``-2`` for a varint over 64 bits."""
    n = buf.shape[0]
    for k in range(out.shape[0]):
        value = np.uint64(0)
        shift = 0
        while True:
            if pos >= n:
                return -1
            byte = buf[pos]
            pos += 1
            value |= np.uint64(byte & 0x7F) << np.uint64(shift)
            if not byte & 0x80:
                break
            shift += 7
            if shift > 63:
                return -2
        out[k] = value
    return pos
