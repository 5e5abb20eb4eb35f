"""The decoding runtime: from a clip's coefficient rows to poses, fast per call.

Apart from the compressor, as the Animation Compression Library's decompression is: its
compiled loops (:mod:`quatmotion.runtime._kernels`) are loaded by :func:`kernels` on the
first decode, so importing this package loads neither Numba nor any part of the encoder.
"""

from __future__ import annotations

from types import ModuleType

__all__ = ["kernels"]


def kernels() -> ModuleType:
    """The runtime's compiled loops, :mod:`quatmotion.runtime._kernels` (imported, with Numba,
    on the first call)."""
    from quatmotion.runtime import _kernels

    return _kernels
