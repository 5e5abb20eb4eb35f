"""Motion compression: codecs with a guaranteed error, the ``.qmz`` library format, metrics.

Layout (compression and decompression apart, format and math apart):

* the math: :mod:`~quatmotion.codec.channels` (a clip as smooth channels and back),
  :mod:`~quatmotion.codec.spline` (B-splines over frames), :mod:`~quatmotion.codec.entropy`
  (range coding with constriction), :mod:`~quatmotion.codec.metrics` (METRICS.md);
* the codecs behind one interface: :mod:`quatmotion.codec.methods` (``best``, ``spline``,
  ``naive``, ``qssd``, ``ksvd``);
* the format: :mod:`~quatmotion.codec.container` (chunks, CRC, header and index),
  :mod:`~quatmotion.codec.skeletons` (exact skeleton records), :mod:`~quatmotion.codec.binary`;
* compression: :mod:`~quatmotion.codec.compress` (the orchestrator: :func:`compress`,
  :func:`append`), :mod:`~quatmotion.codec.library` (a collection prepared for encoding),
  :mod:`~quatmotion.codec.repair` (per-frame corrections that make the bound hold);
* decompression: :mod:`~quatmotion.codec.archive` (:func:`open`: lazy, random access).

``docs/format.md`` specifies the file byte by byte.
"""

from quatmotion.codec.archive import Archive, DamagedClip, open_archive
from quatmotion.codec.compress import DEFAULT_MAX_ERROR_CM, CompressionResult, append, compress
from quatmotion.codec.methods import METHODS

open = open_archive  # noqa: A001 (the API the issue names: codec.open(path))

__all__ = [
    "DEFAULT_MAX_ERROR_CM",
    "METHODS",
    "Archive",
    "DamagedClip",
    "CompressionResult",
    "append",
    "compress",
    "open",
    "open_archive",
]
