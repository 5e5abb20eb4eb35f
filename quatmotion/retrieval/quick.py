"""A single query of the default method by an indexed clip's name, without Numba.

Conventions
-----------
* What it answers: :func:`~quatmotion.retrieval.search.search` of ``dtw-fused`` (the default)
  for a clip of the index named by its name, a unique end of its path or its stem (rules 1-3
  of :func:`quatmotion.io.names.match_clip`), on a version-2 or 3 index that stores the default's
  model. Anything else (another method, a number, an unknown, ambiguous or damaged name or
  index, a model to refit) returns ``None``, and the caller takes the full path, which
  answers or says what is wrong.
* Why: a shell query is one process per query, and importing Numba and loading its cached
  kernels costs more than the search itself (docs/performance.md, 0.4.0). This module imports
  NumPy, SQLite and the fused stream's model only (no ``quatmotion.motion``, ``.io`` or
  ``.collection``, whose kernels import Numba); a batch (``--queries``) and the server keep
  the Numba kernels, cheaper once loaded.
* The same answer, bit for bit: :func:`fused_distances` is ``_kernels.dtw_band32`` (the
  band of ``_kernels.band_radius``) computed for every clip at once, in the kernel's
  arithmetic and order (its docstring): each band cell's squared frame cost a float32 sum
  over the stream's columns in order, then a loop over the query's frames and the band's
  cells, arrays over clips. No clip is pruned, so the ``k`` nearest are those of the exact
  pruned search, with the same distances (NumPy's elementwise float32 operations and the
  kernel's, compiled without fast-math, round alike on every processor).
"""

from __future__ import annotations

import re
import sqlite3
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from quatmotion._names import rule_matches
from quatmotion.retrieval.features_fused import MODEL_KEY, FusedModel, streams_mismatch
from quatmotion.retrieval.ranges import DEFAULT_TOP, check_top
from quatmotion.retrieval.stored import check_index, read_array

__all__ = [
    "FORMAT_NAME",
    "INDEX_VERSION",
    "METHOD",
    "fused_distances",
    "quick_query",
    "quick_search",
]

METHOD = "dtw-fused"
"""The method answered (:data:`quatmotion.retrieval.methods.DEFAULT_METHOD`; a test checks)."""
RADIUS = 8
""":data:`quatmotion.retrieval.methods.FUSED_RADIUS` (a test checks)."""
FORMAT_NAME = "quatmotion-retrieval-index"
INDEX_VERSION = 3
"""The index format written (:data:`quatmotion.retrieval.index.FORMAT`; a test checks)."""
_ANSWERED = ("2", str(INDEX_VERSION))  # the versions whose tables hold what _search reads
# (version 3 adds the take of a clip, which a search by name does not need)
_NPY_HEADER = re.compile(
    r"\{'descr': '([<>|][a-z]\d+)', 'fortran_order': False, 'shape': \(([\d, ]*)\), \}"
)
_INF32 = np.float32(1e30)
_CELLS = 1 << 20
"""Band cells whose frame costs are computed at once (memory: a few arrays of this size)."""


def fused_distances(
    query: NDArray[np.float32], streams: list[NDArray[np.float32]], radius: int = RADIUS
) -> NDArray[np.float64]:
    """Banded DTW (``dtw_band32``'s) of ``query`` ``(n, D)`` float32 to every clip of
    ``streams`` (each ``(m_c, D)`` float32), without abandoning: ``(C,)`` float64, the
    kernel's arithmetic in its order (its docstring), so the same bits."""
    C, n = len(streams), query.shape[0]
    if C == 0:
        return np.zeros(0)
    q = np.ascontiguousarray(query, dtype=np.float32)
    m = np.array([len(s) for s in streams], dtype=np.int64)
    start = np.concatenate(([0], np.cumsum(m)[:-1]))
    frames_t = np.ascontiguousarray(np.concatenate(streams).astype(np.float32).T)  # (D, total)
    slope = (m - 1) / max(n - 1, 1)
    r = np.maximum(float(radius), 0.5 * slope + 1.0)
    rows = np.arange(n, dtype=np.int64)
    centre = rows[:, None] * slope[None, :] + 1  # (n, C): the kernel's (i - 1) * slope + 1
    lo = np.maximum(1, np.floor(centre - r).astype(np.int64))
    hi = np.minimum(m, np.ceil(centre + r).astype(np.int64))
    width = int((hi - lo).max()) + 1
    # every band cell's frame cost, rows in blocks (memory), each sum over the columns in order
    cost = np.empty((n, C, width), dtype=np.float32)
    block = max(1, _CELLS // (C * width))
    for a in range(0, n, block):
        b = min(n, a + block)
        j = lo[a:b, :, None] + np.arange(width)[None, None, :]  # (rows, C, width)
        column = np.where(j <= hi[a:b, :, None], start[None, :, None] + j - 1, 0)
        s = np.zeros(column.shape, dtype=np.float32)
        for k in range(frames_t.shape[0]):
            t = q[a:b, k, None, None] - frames_t[k][column]
            t *= t
            s += t
        np.sqrt(s, out=cost[a:b])
    M = int(m.max())
    clips = np.arange(C)
    prev = np.full((C, M + 2), _INF32, dtype=np.float32)
    prev[:, 0] = 0.0
    cur = np.empty_like(prev)
    for i in range(n):
        j = lo[i][:, None] + np.arange(width)[None, :]  # (C, width)
        inside = j <= hi[i][:, None]
        j = np.where(inside, j, M + 1)  # cells past a clip's band: a column kept at inf
        step = np.minimum(prev[clips[:, None], j - 1], prev[clips[:, None], j])
        step[~inside] = _INF32
        cur.fill(_INF32)
        left = np.full(C, _INF32, dtype=np.float32)  # cur[lo - 1]
        for t in range(width):
            left = cost[i, :, t] + np.minimum(step[:, t], left)
            cur[clips, j[:, t]] = left
        cur[:, M + 1] = _INF32
        prev, cur = cur, prev
    return prev[clips, m].astype(np.float64) / (n + m)


def _array(data: bytes) -> np.ndarray:
    """A stored feature array (``.npy`` bytes, as ``stored.read_array`` reads them): the header
    read by a pattern (``np.load`` parses it with ``ast``, 0.1 ms an array), else
    ``read_array``."""
    if data[:8] == b"\x93NUMPY\x01\x00":
        size = int.from_bytes(data[8:10], "little")
        found = _NPY_HEADER.match(data[10 : 10 + size].decode("latin1"))
        if found is not None:
            shape = tuple(int(x) for x in found.group(2).split(",") if x.strip())
            out = np.frombuffer(data, dtype=found.group(1), offset=10 + size)
            if out.size == int(np.prod(shape)):
                return out.reshape(shape)
    return read_array(data)


def _match(query: str, names: list[str]) -> int | None:
    """Rules 1-3 of ``match_clip``: the one clip the first rule with matches finds; None for
    none or several (the full path says which)."""
    matches = rule_matches(query, names)
    return matches[0] if len(matches) == 1 else None


def _locate(stored: str | None, base: Path) -> str:
    """``ClipRef.locate``'s motion file, else the stored path (``ClipRow.path``)."""
    if not stored:
        return ""
    path = Path(stored)
    if path.is_file():
        return str(path)
    parts = path.parts[1:] if path.is_absolute() else path.parts
    for k in range(len(parts)):
        candidate = Path(base, *parts[k:])
        if candidate.is_file():
            return str(candidate)
    return stored


def quick_search(
    index: str | Path, query: str, k: int = DEFAULT_TOP
) -> list[dict[str, object]] | None:
    """The default method's ``k`` nearest clips to the indexed clip ``query`` names (left out),
    as :meth:`SearchResult.as_dict <quatmotion.retrieval.search.SearchResult.as_dict>`
    documents, or ``None`` when this path does not answer (module conventions).

    Raises
    ------
    ValueError
        ``k`` below 1 (:func:`~quatmotion.retrieval.ranges.check_top`).
    """
    answer = quick_query(index, query, check_top(k))
    return None if answer is None else answer[1]


def quick_query(
    index: str | Path, query: str, k: int = DEFAULT_TOP
) -> tuple[str, list[dict[str, object]]] | None:
    """:func:`quick_search`'s results after the name of the clip ``query`` names (the clip
    left out of them), or ``None``. ``k`` is checked by the caller (the command line's
    ``--top``, :func:`quick_search`)."""
    path = Path(index)
    if not path.is_file():
        return None
    try:
        db = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)
    except sqlite3.Error:
        return None
    try:
        check_index(
            db, path
        )  # what ClipIndex.open checks: a file it refuses, the full path says why
        return _search(db, path, query, k)
    except (sqlite3.Error, ValueError, KeyError, TypeError, OSError):  # FormatError too
        return None
    finally:
        db.close()


def _search(
    db: sqlite3.Connection, path: Path, query: str, k: int
) -> tuple[str, list[dict[str, object]]] | None:
    meta = dict(db.execute("SELECT key, value FROM meta").fetchall())
    if str(meta.get("version")) not in _ANSWERED:
        return None
    rows = db.execute("SELECT id, name, path, label FROM clips ORDER BY id").fetchall()
    arrays: dict[int, dict[str, np.ndarray]] = {int(r[0]): {} for r in rows}
    for clip, key, data in db.execute(
        "SELECT clip, key, data FROM features WHERE key IN ('frames', 'path')"
    ):
        arrays[int(clip)][key] = _array(data)
    rows = [r for r in rows if len(arrays[int(r[0])]) == 2]
    if not rows:
        return None  # an index without the default's features: the full path chooses
    if any(streams_mismatch(a["frames"], a["path"]) for a in arrays.values() if len(a) == 2):
        return None  # a damaged clip: the full path names it
    blob = db.execute("SELECT data FROM blobs WHERE key = ?", (MODEL_KEY,)).fetchone()
    if blob is None:
        return None
    try:
        model = FusedModel.from_bytes(bytes(blob[0]))
    except ValueError:  # damaged or mismatched: the full path refits
        return None
    own = _match(query, [str(r[1]) for r in rows])
    if own is None:
        return None
    streams = [model.stream(arrays[int(r[0])]["frames"], arrays[int(r[0])]["path"]) for r in rows]
    if not all(len(s) and np.isfinite(s).all() for s in streams):
        return None
    d = fused_distances(streams[own], streams)
    ids = np.flatnonzero(np.arange(len(rows)) != own)
    order = ids[np.argsort(d[ids], kind="stable")[:k]]
    base = path.resolve().parent
    return str(rows[own][1]), [
        {
            "rank": rank + 1,
            "clip": str(rows[c][1]),
            "path": _locate(rows[c][2], base),
            "label": str(rows[c][3]),
            "distance": float(d[c]) if np.isfinite(d[c]) else None,
        }
        for rank, c in enumerate(order)
    ]
