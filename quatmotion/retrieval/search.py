"""Searching an index: a query clip's features, the ranked clips, and search inside takes.

The query is a :class:`~quatmotion.motion.Motion` (read from an AMC/BVH file) or a clip of the
index itself (its stored features; a name two clips share is an error listing both). Results
carry the clip's unique name, its path (absolute, where the file is found now), label and
distance;
:func:`search_within` also the frame range of the match, in frames of the clip's file counted
from 0 (``stop`` exclusive), as the rest of quatmotion counts frames.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from quatmotion.collection.refs import motion_hash
from quatmotion.motion import Motion
from quatmotion.retrieval import distances as dist
from quatmotion.retrieval.features import clip_features, feature_step, skeleton_fingerprint
from quatmotion.retrieval.index_file import ClipRow, IndexFile, match_row
from quatmotion.retrieval.methods import DEFAULT_METHOD, METHODS, QueryFeatures
from quatmotion.retrieval.ranges import DEFAULT_TOP, check_top

__all__ = [
    "DEFAULT_K",
    "SearchResult",
    "default_method",
    "method_keys",
    "query_features",
    "query_row",
    "search",
    "search_within",
]

DEFAULT_K = DEFAULT_TOP
"""Clips a search answers with when the caller names no number (``search``, ``search_within``
and the web app's search): :data:`quatmotion.retrieval.ranges.DEFAULT_TOP`."""


@dataclass(frozen=True)
class SearchResult:
    """One ranked clip. ``start_frame``/``stop_frame`` only for :func:`search_within`."""

    rank: int
    clip: str
    path: str
    label: str
    distance: float
    start_frame: int | None = None
    stop_frame: int | None = None

    def as_dict(self) -> dict[str, object]:
        out: dict[str, object] = {
            "rank": self.rank,
            "clip": self.clip,
            "path": self.path,
            "label": self.label,
            "distance": None if not np.isfinite(self.distance) else float(self.distance),
        }
        if self.start_frame is not None:
            out["start_frame"] = self.start_frame
            out["stop_frame"] = self.stop_frame
        return out


def method_keys(method: str) -> tuple[str, ...]:
    """The stored feature arrays a method reads."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    explicit = getattr(METHODS[method], "keys", None)
    if explicit is not None:
        return tuple(explicit)
    keys: list[str] = []
    for kind in METHODS[method].kinds:
        keys += ["frames", "embedding"] if kind == "motion" else [kind]
    return tuple(keys)


def query_features(motion: Motion, method: str = DEFAULT_METHOD) -> QueryFeatures:
    """The features ``method`` needs of a query clip (computed as at indexing time)."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
    return QueryFeatures(
        clip_features(motion, METHODS[method].kinds), skeleton_fingerprint(motion.skeleton)
    )


# What an index written before the default's features existed is searched with, in order: the
# default, then 0.3.0's default (its files hold motion frames and the embedding, not the path).
_FALLBACK_METHODS = ("pooled+dtw",)
# --within reads the motion frames only (any index with the motion kind has them).
_WITHIN_METHOD = "dtw-motion"


def default_method(index: IndexFile) -> str:
    """The method a search uses when none is named: :data:`DEFAULT_METHOD`, or for an index
    built before its features existed, the first of the earlier defaults the index serves."""
    stored: set[str] = set().union(*index.feature_keys().values()) if len(index) else set()
    for method in (DEFAULT_METHOD, *_FALLBACK_METHODS):
        if set(method_keys(method)) <= stored:
            return method
    return DEFAULT_METHOD


def _same_content(rows: list[ClipRow], sha256: str | None, path: str | Path | None) -> int:
    """The row of content hash ``sha256`` (the one at ``path`` first), else -1."""
    if not sha256:
        return -1
    same = [i for i, r in enumerate(rows) if r.sha256 == sha256]
    if path is not None:
        where = os.path.abspath(path)
        same = [i for i in same if where in (rows[i].path, rows[i].ref.path)] or same
    return same[0] if same else -1


def query_row(
    index: IndexFile,
    query: Motion | str,
    *,
    sha256: str | None = None,
    path: str | Path | None = None,
) -> ClipRow | None:
    """The indexed clip ``query`` is, which :func:`search` leaves out of its results (one
    rule whichever way a query comes): the clip a name names; for a clip read from a file or
    uploaded, the indexed clip with its content hash ``sha256``
    (:func:`quatmotion.collection.reading.file_hash`), the one at ``path`` first; for a clip
    made in memory (no ``sha256``), the indexed clip made from the same motion
    (:func:`~quatmotion.collection.refs.motion_hash`). None: the query is no indexed clip.

    Raises
    ------
    ValueError
        (:class:`~quatmotion.errors.ClipNameError`) A name of no clip, or of several.
    """
    rows = index.rows()
    if isinstance(query, str):
        return rows[match_row(query, rows, str(index.path))]
    own = _same_content(rows, sha256 or motion_hash(query), path)
    return rows[own] if own >= 0 else None


def _query(
    index: IndexFile,
    query: Motion | str,
    method: str,
    sha256: str | None = None,
    path: str | Path | None = None,
) -> tuple[list[ClipRow], object, QueryFeatures, int]:
    keys = method_keys(method)
    if not len(index):  # an empty ranking would read as "nothing alike": say what it is
        raise ValueError(
            f"{index.path}: the index holds no clips, so there is nothing to search (quatmotion "
            "index add INDEX CLIPS adds some)"
        )
    rows, library = index.load(keys)
    if not rows and len(index):
        raise ValueError(
            f"{index.path}: no clip has the {method} features ({', '.join(keys)}); add them with "
            "quatmotion index build --kinds"
        )
    if isinstance(query, Motion):
        own = _same_content(rows, sha256 or motion_hash(query), path)
        return rows, library, query_features(query, method), own
    where = f"{index.path} (the clips with {method} features)"
    i = match_row(query, rows, where)
    return rows, library, QueryFeatures(library.features[i], rows[i].skeleton), i


def search(
    index: IndexFile,
    query: Motion | str,
    *,
    method: str | None = None,
    k: int = DEFAULT_K,
    sha256: str | None = None,
    path: str | Path | None = None,
) -> list[SearchResult]:
    """The ``k`` clips most like ``query`` under ``method``, the query's own clip left out
    (:func:`query_row`).

    Parameters
    ----------
    index : IndexFile
    query : Motion or str
        A clip, or an indexed clip as a name, path, file name or number reads it
        (:func:`quatmotion.io.names.match_clip`).
    method : str or None
        A key of :data:`~quatmotion.retrieval.methods.METHODS`; None: :func:`default_method`.
    k : int
        Results wanted (fewer when the index has fewer comparable clips).
    sha256, path : str, optional
        A clip query's content hash and file (:func:`query_row`): an indexed clip of the same
        content is the query itself.

    Returns
    -------
    list of SearchResult

    Raises
    ------
    ValueError
        An index of no clips; unknown method or clip name; a query skeleton without the 16
        pose joints; for the dictionary methods, no indexed clip of the query's skeleton.
    """
    check_top(k)
    if method is None:
        method = default_method(index)
    rows, library, features, own = _query(index, query, method, sha256, path)
    ranking = METHODS[method].rank(library, features, exclude=own, k=k)  # type: ignore[arg-type]
    if ranking.clips.size == 0 and len(rows):
        if not set(METHODS[method].kinds) & {"qssd", "ksvd"}:
            # a position method ranks every clip but the query: none is the query alone or
            # distances that were never defined
            why = (
                "the query is the only indexed clip with its features"
                if len(rows) == 1 and own >= 0
                else "no distance to it is defined (the index's stored features may be "
                "damaged: build it again)"
            )
            raise ValueError(f"no indexed clip compares with the query under {method}: {why}")
        raise ValueError(
            f"no indexed clip compares with the query under {method}: it compares joint "
            "rotations, so only clips of the same skeleton (use a position-based method such "
            f"as {DEFAULT_METHOD}, which retargets through the 16-joint pose skeleton)"
        )
    out = []
    pairs = zip(ranking.clips[:k], ranking.distances[:k], strict=True)
    for r, (c, d) in enumerate(pairs):
        row = rows[int(c)]
        out.append(SearchResult(r + 1, row.name, row.path, row.label, float(d)))
    return out


def search_within(
    index: IndexFile,
    query: Motion | str,
    *,
    k: int = DEFAULT_K,
    sha256: str | None = None,
    path: str | Path | None = None,
) -> list[SearchResult]:
    """Where ``query`` matches best inside each indexed clip (subsequence DTW over the motion
    frames), clips ranked by that match's cost; the query's own clip left out (:func:`search`).

    Returns
    -------
    list of SearchResult
        With ``start_frame`` / ``stop_frame`` in frames of each clip's file (from 0, stop
        exclusive, to the resolution of the feature step).
    """
    check_top(k)
    rows, library, features, own = _query(index, query, _WITHIN_METHOD, sha256, path)
    q = features.arrays["frames"]
    hits = []
    for i, row in enumerate(rows):
        if i == own:
            continue
        cost, start, stop = dist.find_within(q, library.features[i]["frames"])  # type: ignore[attr-defined]
        step = feature_step(row.fps)
        hits.append((cost, i, min(start * step, row.frames), min(stop * step, row.frames)))
    hits.sort(key=lambda h: (h[0], h[1]))
    return [
        SearchResult(k + 1, rows[i].name, rows[i].path, rows[i].label, float(c), int(a), int(b))
        for k, (c, i, a, b) in enumerate(hits[:k])
    ]
