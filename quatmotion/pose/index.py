"""Approximate nearest neighbours under Euclidean distance: an HNSW graph (hnswlib).

The pose library (:mod:`quatmotion.pose.library`) projects poses so that the learned pose
distance is Euclidean and searches them with :class:`HNSWIndex`; :func:`exact_knn` and
:func:`recall_at_k` measure how close the approximate answers are to the exact ones.

Conventions
-----------
* Distances returned are Euclidean (hnswlib's ``"l2"`` space returns squared distances; they
  are square-rooted here).
* Vectors are stored as float32 (hnswlib's precision).
* hnswlib's own reader trusts the bytes it loads (sizes, neighbour ids, levels): a damaged or
  crafted graph reads and writes outside its arrays. :meth:`HNSWIndex.from_bytes` checks every
  size, count and id of the serialised graph against the others (:func:`check_graph`) before
  the bytes reach it.
"""

from __future__ import annotations

import math
import os
import pathlib
import struct
import tempfile

import hnswlib
import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["HNSWIndex", "check_graph", "exact_knn", "recall_at_k"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


class HNSWIndex:
    """Approximate nearest neighbours under Euclidean distance, an HNSW graph (hnswlib).

    Parameters
    ----------
    M : int
        Graph degree (links per node); higher is more accurate and larger.
    ef_construction : int
        Candidate list size while building.
    ef_search : int
        Candidate list size while querying (at least ``k``); trades speed for recall.
    n_threads : int
        Threads for building and batch queries; ``-1`` uses all cores.
    random_state : int
        Seed of the graph's level assignment.

    Attributes
    ----------
    n_items_ : int
    dim_ : int
    """

    def __init__(
        self,
        M: int = 16,
        ef_construction: int = 200,
        ef_search: int = 64,
        n_threads: int = -1,
        random_state: int = 0,
    ) -> None:
        self.M = M
        self.ef_construction = ef_construction
        self.ef_search = ef_search
        self.n_threads = n_threads
        self.random_state = random_state

    def _check_params(self) -> None:
        for name in ("M", "ef_construction", "ef_search"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")

    @staticmethod
    def _as_vectors(X: ArrayLike, dim: int | None = None) -> NDArray[np.float32]:
        arr = np.ascontiguousarray(X, dtype=np.float32)
        if arr.ndim == 1:
            arr = arr[None, :]
        if arr.ndim != 2:
            raise ValueError(f"expected a (N, D) array of vectors, got shape {arr.shape}")
        if dim is not None and arr.shape[1] != dim:
            raise ValueError(f"vectors have {arr.shape[1]} dimensions, the index has {dim}")
        if not np.all(np.isfinite(arr)):
            raise ValueError("vectors must be finite")
        return arr

    def fit(self, X: ArrayLike) -> HNSWIndex:
        """Build the index over ``X``; item ``i`` is row ``i``.

        Parameters
        ----------
        X : array_like, shape (N, D)

        Returns
        -------
        self
        """
        self._check_params()
        arr = self._as_vectors(X)
        if len(arr) == 0:
            raise ValueError("cannot index zero vectors")
        index = hnswlib.Index(space="l2", dim=arr.shape[1])
        index.init_index(
            max_elements=len(arr),
            M=int(self.M),
            ef_construction=int(self.ef_construction),
            random_seed=int(self.random_state),
        )
        index.add_items(arr, np.arange(len(arr)), num_threads=int(self.n_threads))
        index.set_ef(int(self.ef_search))
        self._index = index
        self.n_items_ = len(arr)
        self.dim_ = arr.shape[1]
        return self

    def partial_fit(self, X: ArrayLike, *, capacity: int | None = None) -> HNSWIndex:
        """Add the rows of ``X`` as the next items (``n_items_``, ``n_items_ + 1``, ...).

        For indexes built in chunks that never sit in memory all at once. The first call
        creates the graph with the rows' dimension; later ones grow its capacity by half again
        when needed, so adding stays amortised linear. Items go in in row order on
        ``n_threads`` threads; with one thread the graph is a function of the rows, their
        chunking and ``random_state`` alone.

        Parameters
        ----------
        X : array_like, shape (N, D)
            ``D`` must match the vectors already indexed.
        capacity : int, optional
            Items to make room for at once (the expected total): growing the graph copies it,
            so a good guess saves time and the memory of the copy.

        Returns
        -------
        self
        """
        self._check_params()
        arr = self._as_vectors(X, getattr(self, "dim_", None))
        room = max(int(capacity or 0), 0)
        if not hasattr(self, "_index"):
            if len(arr) == 0:
                raise ValueError("cannot start an index with zero vectors")
            index = hnswlib.Index(space="l2", dim=arr.shape[1])
            index.init_index(
                max_elements=max(len(arr), room),
                M=int(self.M),
                ef_construction=int(self.ef_construction),
                random_seed=int(self.random_state),
            )
            index.set_ef(int(self.ef_search))
            self._index = index
            self.n_items_ = 0
            self.dim_ = arr.shape[1]
        needed = self.n_items_ + len(arr)
        capacity = self._index.get_max_elements()
        if needed > capacity:
            self._index.resize_index(max(needed, room, capacity + capacity // 2))
        if len(arr):
            ids = np.arange(self.n_items_, needed)
            self._index.add_items(arr, ids, num_threads=int(self.n_threads))
        self.n_items_ = needed
        return self

    def _check_fitted(self) -> None:
        if not hasattr(self, "_index"):
            raise ValueError("this HNSWIndex is not built yet: call fit first")

    def query(self, Q: ArrayLike, k: int = 10) -> tuple[IntArray, FloatArray]:
        """The ``k`` approximate nearest items of each query.

        Parameters
        ----------
        Q : array_like, shape (Q, D) or (D,)
        k : int
            ``1 <= k <= n_items_``.

        Returns
        -------
        indices : ndarray of int, shape (Q, k)
            Item numbers, nearest first.
        distances : ndarray, shape (Q, k)
            Euclidean distances.
        """
        self._check_fitted()
        if not 1 <= k <= self.n_items_:
            raise ValueError(f"k must lie in 1..{self.n_items_}, got {k}")
        arr = self._as_vectors(Q, self.dim_)
        self._index.set_ef(max(int(self.ef_search), k))
        labels, sq = self._index.knn_query(arr, k=k, num_threads=int(self.n_threads))
        return labels.astype(np.int64), np.sqrt(np.maximum(sq, 0.0)).astype(np.float64)

    def vectors(self, items: ArrayLike) -> FloatArray:
        """The stored vectors of ``items``, shape (len(items), D) (float32 precision)."""
        self._check_fitted()
        ids = np.asarray(items, dtype=np.int64).reshape(-1)
        return np.asarray(self._index.get_items(ids), dtype=np.float64).reshape(len(ids), -1)

    def to_bytes(self) -> bytes:
        """The serialised HNSW graph (hnswlib's own format)."""
        self._check_fitted()
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "index.bin")
            self._index.save_index(path)
            return pathlib.Path(path).read_bytes()

    @classmethod
    def from_bytes(
        cls,
        data: bytes,
        dim: int,
        ef_search: int = 64,
        n_threads: int = -1,
        *,
        n_items: int | None = None,
    ) -> HNSWIndex:
        """Rebuild an index from :meth:`to_bytes` output, the bytes checked first
        (:func:`check_graph`).

        Parameters
        ----------
        data : bytes
        dim : int
            Vector dimension the graph was built with.
        ef_search, n_threads : int
            Query-time settings.
        n_items : int, optional
            Items the graph must hold (the catalogue's poses).

        Raises
        ------
        ValueError
            Bytes that are not a whole graph of ``n_items`` vectors of ``dim`` dimensions.
        """
        graph = check_graph(data, dim, n_items)
        self = cls(ef_search=ef_search, n_threads=n_threads)
        index = hnswlib.Index(space="l2", dim=int(dim))
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "index.bin")
            pathlib.Path(path).write_bytes(data)
            # Room for the items it holds, not for what the file declares.
            index.load_index(path, max_elements=graph.n_items)
        index.set_ef(int(ef_search))
        self._index = index
        self.n_items_ = index.get_current_count()
        self.dim_ = int(dim)
        self.M = index.M
        self.ef_construction = index.ef_construction
        return self


_HEADER = struct.Struct("<QQQQQQiIQQQdQ")
"""hnswlib's saveIndex header (0.8): offsetLevel0, max_elements, cur_element_count,
size_data_per_element, label_offset, offsetData, maxlevel, enterpoint_node, maxM, maxM0, M,
mult, ef_construction."""
_MAX_DEGREE = 1 << 12
_MAX_LEVEL = 64


class GraphSummary:
    """What :func:`check_graph` found: the items and the graph degree."""

    def __init__(self, n_items: int, M: int) -> None:
        self.n_items = n_items
        self.M = M


def check_graph(data: bytes, dim: int, n_items: int | None = None) -> GraphSummary:
    """Check hnswlib's serialised graph against itself before hnswlib reads it.

    Every size field must be the one ``dim`` and ``M`` imply; the file's length what its
    counts imply; every neighbour id an item, listed at a level the neighbour has; the labels
    ``0..N-1`` once each; the vectors finite; no item marked deleted.

    Raises
    ------
    ValueError
        Naming the first field that disagrees.
    """
    dim = int(dim)
    if dim < 1:
        raise ValueError(f"the graph's vectors have {dim} dimensions")
    if len(data) < _HEADER.size:
        raise ValueError(f"the graph is {len(data)} bytes, shorter than its header")
    (off0, _max_elements, n, per_item, label_at, data_at, max_level, entry, max_m, max_m0, M,
     mult, ef_construction) = _HEADER.unpack_from(data)  # fmt: skip
    if n_items is not None and n != n_items:
        raise ValueError(f"the graph holds {n} items, the catalogue {n_items}")
    links0 = max_m0 * 4 + 4
    if not (1 <= M <= _MAX_DEGREE and max_m == M and max_m0 == 2 * M):
        raise ValueError(f"the graph's degree fields disagree (M {M}, {max_m}, {max_m0})")
    if (off0, data_at, label_at, per_item) != (0, links0, links0 + 4 * dim, links0 + 4 * dim + 8):
        raise ValueError(
            f"the graph's item layout does not hold {dim}-dimensional vectors (item size "
            f"{per_item}, vector at {data_at}, label at {label_at})"
        )
    if n < 1 or not 0 <= max_level <= _MAX_LEVEL or entry >= n:
        raise ValueError(f"the graph's {n} items, top level {max_level}, entry {entry} disagree")
    if not (math.isfinite(mult) and mult > 0 and 1 <= ef_construction <= 1 << 20):
        raise ValueError("the graph's construction parameters are invalid")
    level0_end = _HEADER.size + n * per_item
    if len(data) < level0_end + 4 * n:
        raise ValueError(f"the graph is {len(data)} bytes, too short for {n} items")
    items = np.frombuffer(data, dtype=np.uint8, count=n * per_item, offset=_HEADER.size)
    items = items.reshape(n, per_item)
    counts = items[:, :2].copy().view("<u2")[:, 0]
    if items[:, 2:4].any() or counts.max() > max_m0:
        raise ValueError("the graph's bottom level has a deleted item or an overfull list")
    links = items[:, 4:links0].copy().view("<u4")
    listed = np.arange(max_m0)[None, :] < counts[:, None]
    if np.any(links[listed] >= n):
        raise ValueError("the graph's bottom level names an item it does not hold")
    labels = items[:, label_at:per_item].copy().view("<u8")[:, 0]
    if not np.array_equal(np.sort(labels), np.arange(n, dtype=np.uint64)):
        raise ValueError("the graph's item labels are not 0 to N-1 once each")
    vectors = items[:, data_at:label_at].copy().view("<f4")
    if not np.all(np.isfinite(vectors)):
        raise ValueError("the graph holds vectors that are not finite")
    levels, upper = _upper_levels(data, level0_end, n, max_m)
    if levels[entry] != max_level or levels.max() != max_level:
        raise ValueError("the graph's entry item is not on its top level")
    for level, lists in enumerate(upper, start=1):
        count = lists[:, 0] & 0xFFFF
        if np.any(lists[:, 0] >> 16) or count.max(initial=0) > max_m:
            raise ValueError(f"the graph's level {level} has a deleted mark or an overfull list")
        ids = lists[:, 1:][np.arange(max_m)[None, :] < count[:, None]]
        if np.any(ids >= n) or np.any(levels[ids.astype(np.int64)] < level):
            raise ValueError(f"the graph's level {level} names an item not on that level")
    return GraphSummary(int(n), int(M))


def _upper_levels(
    data: bytes, start: int, n: int, max_m: int
) -> tuple[NDArray[np.int64], list[NDArray[np.uint32]]]:
    """Every item's level, and per level above the bottom the ``(k, 1 + max_m)`` link lists
    (count word, then ids) of the items on it, from hnswlib's per-item upper link blocks."""
    per_level = max_m * 4 + 4
    levels = np.zeros(n, dtype=np.int64)
    blocks: list[tuple[int, int]] = []
    pos = start
    view = memoryview(data)
    size_of = struct.Struct("<I").unpack_from
    for i in range(n):
        if pos + 4 > len(data):
            raise ValueError("the graph ends inside its upper levels")
        (size,) = size_of(view, pos)
        pos += 4
        if size:
            if size % per_level or size // per_level > _MAX_LEVEL or pos + size > len(data):
                raise ValueError(f"the graph's item {i} has an upper link block of {size} bytes")
            levels[i] = size // per_level
            blocks.append((i, pos))
            pos += size
    if pos != len(data):
        raise ValueError(f"the graph has {len(data) - pos} bytes after its last item")
    upper = []
    for level in range(1, int(levels.max(initial=0)) + 1):
        lists = np.array(
            [
                np.frombuffer(data, "<u4", 1 + max_m, at + (level - 1) * per_level)
                for i, at in blocks
                if levels[i] >= level
            ],
            dtype=np.uint32,
        ).reshape(-1, 1 + max_m)
        upper.append(lists)
    return levels, upper


def exact_knn(
    X: ArrayLike, Q: ArrayLike, k: int = 10, chunk: int = 256
) -> tuple[IntArray, FloatArray]:
    """Exact Euclidean k nearest neighbours by brute force (ground truth for recall).

    Parameters
    ----------
    X : array_like, shape (N, D)
    Q : array_like, shape (Q, D)
    k : int
    chunk : int
        Queries per matrix product (lowered so a block holds at most 2^25 distances).

    Returns
    -------
    indices : ndarray of int, shape (Q, k)
    distances : ndarray, shape (Q, k)
        Nearest first.
    """
    x = np.ascontiguousarray(X, dtype=np.float32)
    q = np.ascontiguousarray(Q, dtype=np.float32)
    if x.ndim != 2 or q.ndim != 2 or x.shape[1] != q.shape[1]:
        raise ValueError(f"need (N, D) and (Q, D) arrays, got {x.shape} and {q.shape}")
    if not 1 <= k <= len(x):
        raise ValueError(f"k must lie in 1..{len(x)}, got {k}")
    # at most ~32 M distances (128 MB) per block, whatever N
    chunk = max(1, min(chunk, (1 << 25) // max(len(x), 1)))
    xx = np.einsum("ij,ij->i", x, x)
    idx = np.empty((len(q), k), dtype=np.int64)
    dist = np.empty((len(q), k))
    for s in range(0, len(q), chunk):
        qq = q[s : s + chunk]
        d = xx[None, :] - 2.0 * (qq @ x.T)  # |q|^2 is constant per row: order unchanged
        part = np.argpartition(d, k - 1, axis=1)[:, :k]
        dp = np.take_along_axis(d, part, axis=1)
        order = np.argsort(dp, axis=1, kind="stable")
        top = np.take_along_axis(part, order, axis=1)
        idx[s : s + chunk] = top
        exact = np.linalg.norm(x[top] - qq[:, None, :].astype(np.float64), axis=-1)
        dist[s : s + chunk] = exact
    return idx, dist


def recall_at_k(approx: ArrayLike, exact: ArrayLike) -> float:
    """Mean overlap of approximate and exact top-k sets (docs/metrics.md "Recall@10").

    Parameters
    ----------
    approx, exact : array_like of int, shape (Q, k)

    Returns
    -------
    float
        ``mean_q |approx_q & exact_q| / k``.
    """
    a = np.asarray(approx)
    e = np.asarray(exact)
    if a.shape != e.shape or a.ndim != 2:
        raise ValueError(f"need equal (Q, k) arrays, got {a.shape} and {e.shape}")
    hits = [len(np.intersect1d(ra, re)) for ra, re in zip(a, e, strict=True)]
    return float(np.mean(hits) / a.shape[1])
