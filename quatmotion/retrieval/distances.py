"""Clip-to-clip distances: banded DTW, subsequence DTW, pooled embeddings, and the QSSD paper's
optimal matching of dictionary atoms (Eq. 10).

Conventions
-----------
* A *library* of sequences is one concatenated ``(sum T_c, d)`` float32 array with ``offsets``
  ``(C + 1,)``: clip ``c`` is ``frames[offsets[c]:offsets[c + 1]]``.
* DTW costs are squared Euclidean per frame pair, summed along the path and divided by
  ``n + m`` (so clips of different lengths compare); subsequence costs are Euclidean.
* Atom distance (Eq. 10): ``1 - |<d, d'>|`` of unit ``4n``-vectors, the nearer of ``d'`` and its
  inverse for quaternion atoms; clip distance: the minimum over the 120 one-to-one maps of
  the five atoms of the summed atom distances.
"""

from __future__ import annotations

import itertools

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quatmotion import quat
from quatmotion.retrieval import _kernels

__all__ = [
    "atom_matching_distances",
    "dtw",
    "dtw_euclidean_to_library",
    "dtw_to_library",
    "embedding_distances",
    "find_within",
    "pack_sequences",
]

FloatArray = NDArray[np.float64]

_PERMUTATIONS = np.array(list(itertools.permutations(range(5))), dtype=np.intp)


def _as_frames(x: ArrayLike, name: str) -> NDArray[np.float32]:
    arr = np.ascontiguousarray(x, dtype=np.float32)
    if arr.ndim != 2 or arr.shape[0] < 1:
        raise ValueError(f"{name} must have shape (T, d) with T >= 1, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return arr


def pack_sequences(sequences: list[ArrayLike]) -> tuple[NDArray[np.float32], NDArray[np.int64]]:
    """Concatenate ``C`` sequences ``(T_c, d)``: ``(sum T_c, d)`` float32, offsets ``(C+1,)``."""
    seqs = [_as_frames(s, f"sequence {i}") for i, s in enumerate(sequences)]
    if not seqs:
        return np.zeros((0, 0), dtype=np.float32), np.zeros(1, dtype=np.int64)
    dims = {s.shape[1] for s in seqs}
    if len(dims) != 1:
        raise ValueError(f"sequences have different widths {sorted(dims)}")
    offsets = np.zeros(len(seqs) + 1, dtype=np.int64)
    offsets[1:] = np.cumsum([len(s) for s in seqs])
    return np.ascontiguousarray(np.concatenate(seqs)), offsets


def dtw(
    a: ArrayLike,
    b: ArrayLike,
    *,
    band: float = 0.1,
    dims: int | None = None,
    max_radius: float = 0.0,
) -> float:
    """Banded DTW distance of two sequences ``(n, d)`` and ``(m, d)`` (module conventions).

    Parameters
    ----------
    a, b : array_like, shapes (n, d) and (m, d)
    band : float
        Sakoe-Chiba radius as a fraction of the longer sequence.
    dims : int, optional
        Compare only the first ``dims`` columns (default all).
    max_radius : float
        Largest radius in frames (0: none). The radius is at least one frame, and at least
        half the length ratio plus one, so that a warping path exists.

    Returns
    -------
    float
    """
    A, B = _as_frames(a, "a"), _as_frames(b, "b")
    if A.shape[1] != B.shape[1]:
        raise ValueError(f"a has {A.shape[1]} columns, b {B.shape[1]}")
    d = A.shape[1] if dims is None else int(dims)
    return float(_kernels.dtw_banded(A, B, float(band), d, float(max_radius)))


def dtw_to_library(
    query: ArrayLike,
    frames: NDArray[np.float32],
    offsets: NDArray[np.int64],
    candidates: ArrayLike | None = None,
    *,
    band: float = 0.1,
    dims: int | None = None,
    max_radius: float = 0.0,
) -> FloatArray:
    """Banded DTW from ``query`` ``(n, d)`` to library clips (module conventions).

    Parameters
    ----------
    query : array_like, shape (n, d)
    frames, offsets : library from :func:`pack_sequences`
    candidates : array_like of int, optional
        Clip numbers to compare (default all).
    band, dims, max_radius : see :func:`dtw`

    Returns
    -------
    ndarray, shape (len(candidates),)
    """
    q, cand = _query_and_candidates(query, frames, offsets, candidates)
    d = q.shape[1] if dims is None else int(dims)
    return _kernels.dtw_to_candidates(q, frames, offsets, cand, float(band), d, float(max_radius))


def _query_and_candidates(
    query: ArrayLike,
    frames: NDArray[np.float32],
    offsets: NDArray[np.int64],
    candidates: ArrayLike | None,
) -> tuple[NDArray[np.float32], NDArray[np.int64]]:
    """The query as frames of the library's width and the clip numbers to compare with
    (default all), checked.

    Raises
    ------
    ValueError
        Library frames of another width or dtype than the query's; a candidate that is not a
        clip number of the library.
    """
    q = _as_frames(query, "query")
    if frames.ndim != 2 or frames.shape[1] != q.shape[1] or frames.dtype != np.float32:
        raise ValueError(f"library frames {frames.shape} {frames.dtype} do not match the query")
    n_clips = offsets.shape[0] - 1
    cand = (
        np.arange(n_clips, dtype=np.int64)
        if candidates is None
        else np.ascontiguousarray(candidates, dtype=np.int64)
    )
    if cand.size and (cand.min() < 0 or cand.max() >= n_clips):
        raise ValueError(f"candidates must be clip numbers in 0..{n_clips - 1}")
    return q, cand


def dtw_euclidean_to_library(
    query: ArrayLike,
    frames: NDArray[np.float32],
    offsets: NDArray[np.int64],
    candidates: ArrayLike | None = None,
) -> FloatArray:
    """Unbanded DTW with a Euclidean (not squared) frame cost, path cost divided by ``n + m``,
    from ``query`` ``(n, d)`` to library clips.

    Parameters
    ----------
    query : array_like, shape (n, d)
    frames, offsets : library from :func:`pack_sequences`
    candidates : array_like of int, optional
        Clip numbers to compare (default all).

    Returns
    -------
    ndarray, shape (len(candidates),)
    """
    q, cand = _query_and_candidates(query, frames, offsets, candidates)
    weights = np.ones(q.shape[1], dtype=np.float32)
    return _kernels.dtw_euclidean_to_candidates(q, frames, offsets, cand, weights)


def embedding_distances(embeddings: NDArray[np.float32], query: ArrayLike) -> FloatArray:
    """Euclidean distances from ``query`` ``(D,)`` to every row of ``embeddings`` ``(C, D)``."""
    q = np.ascontiguousarray(query, dtype=np.float32)
    if embeddings.ndim != 2 or q.shape != (embeddings.shape[1],):
        raise ValueError(f"query has shape {q.shape}, embeddings {embeddings.shape}")
    return np.sqrt(_kernels.squared_distances(embeddings, q))


def atom_matching_distances(
    query_atoms: ArrayLike, atoms: ArrayLike, *, quaternion: bool
) -> FloatArray:
    """The paper's clip distance from one dictionary to many (module conventions).

    Parameters
    ----------
    query_atoms : array_like, shape (5, n, 4)
        Unit ``4n``-vectors.
    atoms : array_like, shape (C, 5, n, 4)
    quaternion : bool
        QSSD atoms (also compare with each atom's inverse) or K-SVD atoms (sign only).

    Returns
    -------
    ndarray, shape (C,)
    """
    q = np.asarray(query_atoms, dtype=np.float64)
    A = np.asarray(atoms, dtype=np.float64)
    if q.ndim != 3 or q.shape[0] != 5 or q.shape[-1] != 4 or A.shape[1:] != q.shape:
        raise ValueError(f"atoms of shapes {q.shape} and {A.shape} do not compare")
    flat = A.reshape(A.shape[0], 5, -1)
    sim = np.abs(np.einsum("kd,cld->ckl", q.reshape(5, -1), flat))
    if quaternion:
        inverse = quat.conjugate(q).reshape(5, -1)
        sim = np.maximum(sim, np.abs(np.einsum("kd,cld->ckl", inverse, flat)))
    cost = 1.0 - sim  # (C, 5 query atoms, 5 clip atoms)
    return cost[:, np.arange(5)[None, :], _PERMUTATIONS].sum(-1).min(-1)


# The refined ends (find_within): matched frames farther than _SHRINK_FACTOR times the
# matched frames' 90th-percentile distance to their nearest query frame are dropped from the
# ends; take frames as near the body of the query (its frames but the first and last
# _LEAD_SHARE) as 90 % of the matched frames are added.
_SHRINK_FACTOR = 2.0
_REFINE_QUANTILE = 90.0
_LEAD_SHARE = 0.2


def find_within(
    query: ArrayLike, take: ArrayLike, *, refine: bool = True
) -> tuple[float, int, int]:
    """Where ``query`` ``(n, d)`` matches best inside ``take`` ``(m, d)`` (subsequence DTW).

    The match is the warping path of least Euclidean cost per unit path weight (step pattern
    symmetricP1, module conventions), its length in the take between ``n/2`` and ``2n``. A
    periodic motion at another tempo aligns whole cycles with fewer or more of the take's, so
    its path can stop short of the segment; ``refine`` then re-aligns the ends on what each
    take frame looks like. The ends first move inward past matched frames more than twice as
    far from their nearest query frame as 90 % of the matched frames are; then outward over
    take frames as near the *body* of the query (its frames but the first and last 20 %, the
    lead-in and lead-out poses that neighbouring motions share) as 90 % of the matched frames
    are, crossing a single frame that is not: a take doing the query's motion for longer
    than the query is matched whole.

    Parameters
    ----------
    query, take : array_like, shapes (n, d) and (m, d)
    refine : bool
        Re-align the ends as above (default); False: the warping path's ends.

    Returns
    -------
    cost : float
        The path's Euclidean cost per unit path weight (``inf`` when the take is under half
        the query); not changed by ``refine``.
    start, stop : int
        Frames of ``take``, ``stop`` exclusive.
    """
    q, x = _as_frames(query, "query"), _as_frames(take, "take")
    if q.shape[1] != x.shape[1]:
        raise ValueError(f"query has {q.shape[1]} columns, take {x.shape[1]}")
    frame_cost = _kernels.frame_distances(q, x)
    cost, start, stop = _kernels.subsequence_dtw(frame_cost)
    if cost >= 1e29:
        return float("inf"), 0, 0
    start, stop = int(start), int(stop)
    if refine:
        start, stop = _refine_ends(frame_cost, start, stop)
    return float(cost), start, stop


def _refine_ends(frame_cost: FloatArray, start: int, stop: int) -> tuple[int, int]:
    """The ends of a match ``[start, stop)`` re-aligned on the frame distances ``(n, m)``
    (see :func:`find_within`)."""
    n, m = frame_cost.shape
    nearest = frame_cost.min(axis=0)
    limit = _SHRINK_FACTOR * float(np.percentile(nearest[start:stop], _REFINE_QUANTILE))
    while stop - start > 1 and nearest[stop - 1] > limit:
        stop -= 1
    while stop - start > 1 and nearest[start] > limit:
        start += 1
    lead = int(_LEAD_SHARE * n)
    body = frame_cost[lead : n - lead].min(axis=0) if n - 2 * lead >= 1 else nearest
    near = body <= float(np.percentile(body[start:stop], _REFINE_QUANTILE))
    # one frame over the limit on its own is crossed (a tenth of the matched frames are)
    while stop < m and (near[stop] or (stop + 1 < m and near[stop + 1])):
        stop += 1
    while start > 0 and (near[start - 1] or (start > 1 and near[start - 2])):
        start -= 1
    return start, stop
