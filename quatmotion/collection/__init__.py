"""The collection model: what the codec's library, the clip index and the pose library share.

A *collection* is a file of clips: a ``.qmz`` library (:class:`quatmotion.codec.Archive`), a
``.qidx`` clip index (:class:`quatmotion.retrieval.ClipIndex`) or a pose library
(:class:`quatmotion.pose.PoseLibrary`). Each kind has the same surface:

* ``Kind.build(sources, out, settings, *, runner, progress, on_doubt) -> BuildReport``;
* ``Kind.open(path)`` -> a reader with ``.clips()``, ``.settings`` and, where the kind
  searches, ``.search(query, k)``;
* ``Kind.add(path, sources, settings, *, runner, progress, on_doubt) -> BuildReport``

(:class:`quatmotion.collection.kind.Kind`, the protocol; a kind's own options come after);

and this package gives them their common parts: the clip identity every file stores
(:class:`ClipRef`), finding and reading clips by one set of rules (:func:`find_clips`,
:func:`read_clip`, :class:`ReadSettings`), labels from CSVs, sidecars, folders and the
catalogue (:func:`label_sources`), and the report of a build (:class:`BuildReport`).
"""

from __future__ import annotations

from quatmotion.collection.labels import (
    LabelAssignment,
    catalogue_labels,
    label_sources,
    match_keys,
)
from quatmotion.collection.reading import (
    ClipSource,
    ReadClip,
    ReadSettings,
    find_clips,
    find_skeleton,
    read_clip,
    with_joint_map,
)
from quatmotion.collection.refs import (
    ClipRef,
    content_hash,
    motion_hash,
    name_apart,
    unique_names,
)
from quatmotion.collection.report import BuildReport

__all__ = [
    "BuildReport",
    "ClipRef",
    "ClipSource",
    "LabelAssignment",
    "ReadClip",
    "ReadSettings",
    "catalogue_labels",
    "content_hash",
    "find_clips",
    "find_skeleton",
    "label_sources",
    "match_keys",
    "motion_hash",
    "read_clip",
    "name_apart",
    "unique_names",
    "with_joint_map",
]
