"""Approximate-nearest-neighbour pose index (hnswlib) and the pose library saved for search.

A *pose library* answers "poses like frame F of clip C": every pose of a motion library is
described by the GPD, normalised, projected by a learned metric ``W`` (RDSR, 50 dimensions),
and put in an HNSW graph (Malkov & Yashunin, hnswlib). In the projected space the learned
distance ``sqrt((x - y)^T W W^T (x - y))`` is plain Euclidean distance, so an L2 index answers
learned-metric queries.

Conventions
-----------
* Distances returned are Euclidean (hnswlib's ``"l2"`` space returns squared distances; they
  are square-rooted here).
* Vectors are stored as float32 (hnswlib's precision).
* A library file is one ``.npz`` holding the serialised HNSW graph, the projection model and the
  pose catalogue (clip names, frame numbers, fps); it is written to a temporary file and then
  renamed, so a reader never sees half a library.
"""

from __future__ import annotations

import json
import os
import pathlib
import tempfile
from dataclasses import dataclass, field
from typing import Any

import hnswlib
import numpy as np
from numpy.typing import ArrayLike, NDArray

from quatmotion._atomic import atomic_output

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

_FORMAT = "quatmotion-pose-library"
_VERSION = 1


class PoseIndex:
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

    def fit(self, X: ArrayLike) -> PoseIndex:
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

    def _check_fitted(self) -> None:
        if not hasattr(self, "_index"):
            raise ValueError("this PoseIndex is not built yet: call fit first")

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
        cls, data: bytes, dim: int, ef_search: int = 64, n_threads: int = -1
    ) -> PoseIndex:
        """Rebuild an index from :meth:`to_bytes` output.

        Parameters
        ----------
        data : bytes
        dim : int
            Vector dimension the graph was built with.
        ef_search, n_threads : int
            Query-time settings.
        """
        self = cls(ef_search=ef_search, n_threads=n_threads)
        index = hnswlib.Index(space="l2", dim=int(dim))
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "index.bin")
            pathlib.Path(path).write_bytes(data)
            index.load_index(path)
        index.set_ef(int(ef_search))
        self._index = index
        self.n_items_ = index.get_current_count()
        self.dim_ = int(dim)
        self.M = index.M
        self.ef_construction = index.ef_construction
        return self


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
    """Mean overlap of approximate and exact top-k sets (METRICS.md "Recall@10").

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


@dataclass
class PoseLibrary:
    """A searchable pose library: projection model, HNSW index and pose catalogue.

    Attributes
    ----------
    index : PoseIndex
        Over the projected poses; item ``i`` is pose ``i`` of the catalogue.
    clip_names : list of str
        One per clip (file paths as given when indexing).
    clip_of : ndarray of int, shape (N,)
        Clip of every indexed pose.
    frame_of : ndarray of int, shape (N,)
        Frame number of every indexed pose, in the clip's file (before any subsampling).
    model : dict of str to ndarray
        The projection: ``scale`` and ``offset`` (shape (D,), the GPD normalisation of Eq. 38),
        ``W`` (shape (D, r), the metric's projection); poses map to
        ``unit(scale * gpd + offset) @ W``.
    meta : dict
        JSON-serialisable settings (fps, frame step, height, method, labels used...).
    """

    index: PoseIndex
    clip_names: list[str]
    clip_of: IntArray
    frame_of: IntArray
    model: dict[str, FloatArray]
    meta: dict[str, Any] = field(default_factory=dict)

    def project(self, raw_gpd: ArrayLike) -> FloatArray:
        """Map raw GPD features to the index space.

        Parameters
        ----------
        raw_gpd : array_like, shape (N, D)
            :func:`quatmotion.pose.gpd.gpd_features` output.

        Returns
        -------
        ndarray, shape (N, r)
        """
        x = np.asarray(raw_gpd, dtype=np.float64)
        x = x * self.model["scale"] + self.model["offset"]
        norm = np.linalg.norm(x, axis=1, keepdims=True)
        x = x / np.where(norm > 0, norm, 1.0)
        return x @ self.model["W"]

    def find(self, clip: str | int, frame: int) -> int:
        """Catalogue number of the indexed pose nearest in time to ``frame`` of ``clip``.

        Parameters
        ----------
        clip : str or int
            Clip number, full name, or a unique suffix of the name (e.g. the file name).
        frame : int
            Frame number in the clip's file.
        """
        c = self._clip_number(clip)
        rows = np.flatnonzero(self.clip_of == c)
        if len(rows) == 0:
            raise ValueError(f"clip {self.clip_names[c]!r} has no indexed pose")
        return int(rows[np.argmin(np.abs(self.frame_of[rows] - frame))])

    def _clip_number(self, clip: str | int) -> int:
        if isinstance(clip, (int, np.integer)):
            if not 0 <= clip < len(self.clip_names):
                raise ValueError(f"clip number {clip} out of range 0..{len(self.clip_names) - 1}")
            return int(clip)
        matches = [i for i, n in enumerate(self.clip_names) if n == clip]
        if not matches:
            matches = [
                i
                for i, n in enumerate(self.clip_names)
                if n.endswith(clip) or pathlib.Path(n).stem == clip
            ]
        if len(matches) != 1:
            raise ValueError(
                f"clip {clip!r} matches {len(matches)} indexed clips; give a longer name"
            )
        return matches[0]

    def search(self, vectors: ArrayLike, k: int = 10) -> tuple[IntArray, FloatArray]:
        """Approximate nearest indexed poses of projected query vectors, ``(Q, k)`` each."""
        return self.index.query(vectors, k)

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the library to ``path`` (one ``.npz``; temporary file, then rename)."""
        path = pathlib.Path(path)
        meta = dict(self.meta)
        meta.update(format=_FORMAT, version=_VERSION, dim=self.index.dim_)
        payload = {
            "index": np.frombuffer(self.index.to_bytes(), dtype=np.uint8),
            "clip_names": np.asarray(self.clip_names, dtype=str),
            "clip_of": self.clip_of,
            "frame_of": self.frame_of,
            "meta": np.asarray(json.dumps(meta)),
        }
        payload.update({f"model_{k}": v for k, v in self.model.items()})
        with atomic_output(path) as temp, temp.open("wb") as fh:
            np.savez(fh, **payload)

    @classmethod
    def load(cls, path: str | os.PathLike[str], ef_search: int = 64) -> PoseLibrary:
        """Read a library written by :meth:`save`.

        Raises
        ------
        ValueError
            If the file is not a pose library.
        """
        try:
            with np.load(path, allow_pickle=False) as data:
                meta = json.loads(str(data["meta"]))
                if meta.get("format") != _FORMAT:
                    raise ValueError(f"{path} is not a quatmotion pose library")
                index = PoseIndex.from_bytes(
                    data["index"].tobytes(), dim=int(meta["dim"]), ef_search=ef_search
                )
                model = {k[6:]: data[k] for k in data.files if k.startswith("model_")}
                return cls(
                    index=index,
                    clip_names=[str(n) for n in data["clip_names"]],
                    clip_of=data["clip_of"].astype(np.int64),
                    frame_of=data["frame_of"].astype(np.int64),
                    model=model,
                    meta=meta,
                )
        except (KeyError, OSError, json.JSONDecodeError) as exc:
            raise ValueError(f"{path} is not a readable quatmotion pose library: {exc}") from exc
