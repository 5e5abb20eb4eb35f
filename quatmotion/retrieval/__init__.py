"""Content-based motion retrieval: "find motions like this one" over a clip library.

Submodules
----------
features
    Per-clip features: motion frames (16-joint body-frame positions and the Hip's travel, 10
    frames/s), the pooled embedding, the QSSD paper's per-clip dictionaries.
distances
    Banded and subsequence DTW, embedding distances, the paper's atom matching (Eq. 10).
methods
    ``METHODS``: every retrieval method by name (the paper's, the DTW baseline, ours) and
    ``DEFAULT_METHOD``; ``Library``, clips' features packed in memory.
index_file
    ``IndexFile``: the SQLite ``.qidx`` file (clip references, labels, features, settings),
    read and written, one reader per format version; ``IndexSettings``.
build
    The writer: the build's steps, a pure per-clip feature function mapped over all cores, one
    writer (``build_index``: the deprecated keyword form of ``ClipIndex.build``).
search
    The reader: ``search`` and ``search_within`` (subsequence DTW inside long takes).
index
    ``ClipIndex`` (``build``/``open``/``add``/``search``): the file with the writer and the
    reader, a thin facade above both (the file's names re-exported).

Names are loaded on first use, so ``import quatmotion.retrieval`` stays cheap. The function
``search`` is imported from its module (``from quatmotion.retrieval.search import search``):
the package attribute of that name is the submodule once anything has imported it, so a lazy
export of the function would be a module or a function depending on what ran first.
"""

from __future__ import annotations

from quatmotion._lazy import lazy_exports

_MODULE_EXPORTS = {
    "features": ("clip_features", "motion_frames"),
    "methods": ("DEFAULT_METHOD", "METHODS", "Library"),
    "index": ("ClipIndex", "IndexSettings"),
    "build": ("build_index",),
    "search": ("search_within", "query_features"),
}
_EXPORTS = {name: module for module, names in _MODULE_EXPORTS.items() for name in names}

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
