"""Numba kernels of the clip distances. They trust their input: the public functions in
:mod:`quatmotion.retrieval.distances` validate shapes and dtypes once.

Own kernels rather than a DTW library: the re-rank compares a query with 64 short clips, and
``dtaidistance``'s compiled multivariate DTW is called once per pair on float64 copies, where
this banded float32 kernel reads the library's concatenated frames in place in one call (the
comparison is in docs/performance.md).
"""

from __future__ import annotations

import numba as nb
import numpy as np

_INF = 1e30


@nb.njit(cache=True, fastmath=True, nogil=True)
def dtw_banded(a, b, band, dims, max_radius):  # pragma: no cover - compiled
    """DTW of ``a`` (n, d) and ``b`` (m, d) on their first ``dims`` columns: squared Euclidean
    local cost, steps (1,0), (0,1), (1,1), a Sakoe-Chiba band around the diagonal rescaled to
    the two lengths, of radius ``band * max(n, m)`` frames, at most ``max_radius`` (if
    positive), at least 1 and half the slope plus one (so that a path exists); the path cost
    divided by ``n + m``."""
    n, m = a.shape[0], b.shape[0]
    slope = (m - 1) / max(n - 1, 1)
    r = band * max(n, m)
    if max_radius > 0 and r > max_radius:
        r = max_radius
    r = max(r, 1.0, 0.5 * slope + 1.0)
    prev = np.full(m + 1, _INF, dtype=np.float64)
    cur = np.full(m + 1, _INF, dtype=np.float64)
    prev[0] = 0.0
    for i in range(1, n + 1):
        centre = (i - 1) * slope + 1
        lo = max(1, int(np.floor(centre - r)))
        hi = min(m, int(np.ceil(centre + r)))
        for j in range(m + 1):
            cur[j] = _INF
        for j in range(lo, hi + 1):
            s = 0.0
            for k in range(dims):
                t = a[i - 1, k] - b[j - 1, k]
                s += t * t
            best = prev[j - 1]
            if prev[j] < best:
                best = prev[j]
            if cur[j - 1] < best:
                best = cur[j - 1]
            cur[j] = s + best
        prev, cur = cur, prev
    return prev[m] / (n + m)


@nb.njit(cache=True, nogil=True)
def dtw_to_candidates(query, frames, offsets, candidates, band, dims, max_radius):
    """:func:`dtw_banded` from ``query`` to clips ``candidates`` of the concatenated
    ``frames`` (clip ``c`` is ``frames[offsets[c]:offsets[c + 1]]``)."""
    out = np.empty(candidates.shape[0])
    for t in range(candidates.shape[0]):
        c = candidates[t]
        out[t] = dtw_banded(query, frames[offsets[c] : offsets[c + 1]], band, dims, max_radius)
    return out


@nb.njit(cache=True, nogil=True)
def squared_distances(embeddings, query):  # pragma: no cover - compiled
    """``|embeddings[i] - query|^2`` for every row, in one pass on one thread (a BLAS
    matrix-vector product spends more time waking its threads than computing at this size)."""
    n, d = embeddings.shape
    out = np.empty(n)
    for i in range(n):
        s = 0.0
        for k in range(d):
            t = embeddings[i, k] - query[k]
            s += t * t
        out[i] = s
    return out


@nb.njit(cache=True, fastmath=True, nogil=True)
def frame_distances(query, take):  # pragma: no cover - compiled
    """Euclidean distance of every query frame to every take frame, ``(n, m)``."""
    n, m, d = query.shape[0], take.shape[0], query.shape[1]
    dist = np.empty((n, m))
    for i in range(n):
        for j in range(m):
            s = 0.0
            for k in range(d):
                t = query[i, k] - take[j, k]
                s += t * t
            dist[i, j] = np.sqrt(s)
    return dist


@nb.njit(cache=True, fastmath=True, nogil=True)
def subsequence_dtw(dist):  # pragma: no cover - compiled
    """Best match of the query anywhere in the take, from their frame distances ``dist``
    (n, m): free start and end in the take, step pattern symmetricP1 (steps (1,1) weight 2;
    (1,2) and (2,1) weights 2 + 1), so a path's weight is n + matched length and the matched
    length lies between n/2 and 2n. Returns (cost per unit weight, first take frame,
    last + 1)."""
    n, m = dist.shape
    C = np.full((n, m), _INF)
    start = np.zeros((n, m), dtype=np.int64)
    for j in range(m):
        C[0, j] = 2.0 * dist[0, j]
        start[0, j] = j
    for i in range(1, n):
        for j in range(1, m):
            best = C[i - 1, j - 1] + 2.0 * dist[i, j]
            origin = start[i - 1, j - 1]
            if j >= 2:
                c = C[i - 1, j - 2] + 2.0 * dist[i, j - 1] + dist[i, j]
                if c < best:
                    best = c
                    origin = start[i - 1, j - 2]
            if i >= 2:
                c = C[i - 2, j - 1] + 2.0 * dist[i - 1, j] + dist[i, j]
                if c < best:
                    best = c
                    origin = start[i - 2, j - 1]
            C[i, j] = best
            start[i, j] = origin
    best = _INF
    end = -1
    for j in range(m):
        if C[n - 1, j] < _INF:
            v = C[n - 1, j] / (n + j - start[n - 1, j] + 1)
            if v < best:
                best = v
                end = j
    if end < 0:
        return _INF, 0, 0
    return best, start[n - 1, end], end + 1


@nb.njit(cache=True, fastmath=True, nogil=True)
def dtw_euclidean(a, b, weights, cutoff):  # pragma: no cover - compiled
    """Unbanded DTW of ``a`` (n, d) and ``b`` (m, d): local cost the Euclidean distance of the
    two frames with column weights ``weights`` (d,) (``sqrt(sum w_k (a_k - b_k)^2)``), steps
    (1,0), (0,1), (1,1), the path cost divided by ``n + m``. Abandons early, returning
    ``inf``, once every cell of a row exceeds ``cutoff * (n + m)`` (``cutoff`` inf: never)."""
    n, m, d = a.shape[0], b.shape[0], a.shape[1]
    limit = cutoff * (n + m)
    prev = np.full(m + 1, _INF, dtype=np.float64)
    cur = np.full(m + 1, _INF, dtype=np.float64)
    prev[0] = 0.0
    for i in range(1, n + 1):
        cur[0] = _INF
        row_min = _INF
        for j in range(1, m + 1):
            s = 0.0
            for k in range(d):
                t = a[i - 1, k] - b[j - 1, k]
                s += weights[k] * t * t
            best = prev[j - 1]
            if prev[j] < best:
                best = prev[j]
            if cur[j - 1] < best:
                best = cur[j - 1]
            v = np.sqrt(s) + best
            cur[j] = v
            if v < row_min:
                row_min = v
        if row_min > limit:
            return np.inf
        prev, cur = cur, prev
    return prev[m] / (n + m)


@nb.njit(cache=True, nogil=True)
def dtw_euclidean_to_candidates(query, frames, offsets, candidates, weights):
    """:func:`dtw_euclidean` from ``query`` to clips ``candidates`` of the concatenated
    ``frames`` (no early abandoning)."""
    out = np.empty(candidates.shape[0])
    for t in range(candidates.shape[0]):
        c = candidates[t]
        out[t] = dtw_euclidean(query, frames[offsets[c] : offsets[c + 1]], weights, np.inf)
    return out
