"""Motion compression: codecs with a guaranteed error, the ``.qmz`` library format, metrics.

Layout (compression and decompression apart, format and math apart):

* the math: :mod:`~quatmotion.codec.channels` (a clip as smooth channels and back),
  :mod:`~quatmotion.codec.spline` (B-splines over frames), :mod:`~quatmotion.codec.entropy`
  (range coding with constriction), :mod:`~quatmotion.codec.metrics` (docs/metrics.md);
* the codecs behind one interface: :mod:`quatmotion.codec.methods` (``best``, ``spline``,
  ``naive``, ``qssd``, ``ksvd``);
* the format: :mod:`~quatmotion.codec.container` (chunks, CRC, header and index),
  :mod:`~quatmotion.codec.skeletons` (exact skeleton records), :mod:`~quatmotion.codec.binary`;
* the file kind (the collection model's surface): :meth:`Archive.build` (sources and a
  :class:`CompressSettings` in, a ``.qmz`` and a :class:`~quatmotion.collection.BuildReport`
  out), :meth:`Archive.open` (a reader: ``.clips()`` references, ``.settings``, ``.format``),
  :meth:`Archive.add`;
* compression: :mod:`~quatmotion.codec.writer` (the orchestrator, a module per step),
  :mod:`~quatmotion.codec.settings`, :mod:`~quatmotion.codec.library` (a collection prepared
  for encoding), :mod:`~quatmotion.codec.repair` (per-frame corrections that make the bound
  hold);
* the facade: :mod:`~quatmotion.codec.qmz` (:class:`Archive`: the reader with the writer's
  ``build``/``add`` on top, so neither imports the other's side);
* decompression: :mod:`~quatmotion.codec.archive` (lazy, random access; imports no
  compressor) and
  :mod:`~quatmotion.codec.sampling` (poses at any time; :class:`Sampler`, one clip bound).

``compress``, ``append``, ``open`` and ``open_archive`` are the names before 0.4.0 (thin
wrappers of the above that warn; :mod:`~quatmotion.codec._old_names`, loaded when one is first
asked for, so that ``import quatmotion.codec`` loads the decoder and no compressor).

``docs/format.md`` specifies the file byte by byte.
"""

from typing import Any

from quatmotion.codec.archive import DamagedClip
from quatmotion.codec.methods import METHODS
from quatmotion.codec.qmz import Archive
from quatmotion.codec.sampling import Sampler
from quatmotion.codec.settings import DEFAULT_MAX_ERROR_CM, CompressSettings

_OLD_NAMES = ("CompressionResult", "append", "compress", "open", "open_archive")


def __getattr__(name: str) -> Any:
    """The names before 0.4.0, from :mod:`~quatmotion.codec._old_names` when first asked for."""
    if name in _OLD_NAMES:
        from quatmotion.codec import _old_names

        return getattr(_old_names, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "DEFAULT_MAX_ERROR_CM",
    "METHODS",
    "Archive",
    "CompressSettings",
    "CompressionResult",
    "DamagedClip",
    "Sampler",
    "append",
    "compress",
    "open",
    "open_archive",
]
