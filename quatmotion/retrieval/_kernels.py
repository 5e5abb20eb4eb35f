"""Numba kernels of the clip distances. They trust their input: the public functions in
:mod:`quatmotion.retrieval.distances` validate shapes and dtypes once.

Own kernels rather than a DTW library: the re-rank compares a query with 64 short clips, and
``dtaidistance``'s compiled multivariate DTW is called once per pair on float64 copies, where
this banded float32 kernel reads the library's concatenated frames in place in one call (the
comparison is in docs/performance.md).

Conventions
-----------
* No fast-math: every kernel's arithmetic is the order its code writes (no reassociated sums,
  no fused multiply-adds), so a distance is the same bits on every x86-64 processor, whatever
  its vector width, and under any Numba CPU target; the NumPy path of
  :mod:`quatmotion.retrieval.quick` computes :func:`dtw_band32`'s arithmetic in the same
  order and agrees with it bit for bit (tests run both under ``NUMBA_CPU_NAME=generic`` and
  the host's target).
"""

from __future__ import annotations

import numba as nb
import numpy as np

_INF = 1e30


@nb.njit(cache=True, nogil=True, inline="always")
def _extend(prev, cur, j, cost):  # pragma: no cover - compiled
    """Cell ``j`` of the row ``cur`` (the row before: ``prev``): its frame ``cost`` plus the
    least path cost of its three predecessors, diagonal (``prev[j - 1]``), above
    (``prev[j]``) and left (``cur[j - 1]``), the first of equals in that order; stored and
    returned. One addition in the arrays' precision, as each DTW here wrote it inline."""
    best = prev[j - 1]
    if prev[j] < best:
        best = prev[j]
    if cur[j - 1] < best:
        best = cur[j - 1]
    v = cost + best
    cur[j] = v
    return v


@nb.njit(cache=True, nogil=True)
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
            _extend(prev, cur, j, s)
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


@nb.njit(cache=True, nogil=True)
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


@nb.njit(cache=True, nogil=True)
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


@nb.njit(cache=True, nogil=True)
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
            v = _extend(prev, cur, j, np.sqrt(s))
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


_INF32 = np.float32(1e30)


@nb.njit(cache=True, nogil=True)
def band_radius(n, m, radius):  # pragma: no cover - compiled
    """The Sakoe-Chiba radius of :func:`dtw_band32` for lengths ``n``, ``m``: ``radius``
    frames, at least half the slope plus one (so that a path exists)."""
    slope = (m - 1) / max(n - 1, 1)
    return max(float(radius), 0.5 * slope + 1.0)


@nb.njit(cache=True, nogil=True)
def dtw_band32(a, bt, start, m, r, cutoff):  # pragma: no cover - compiled
    """DTW of float32 ``a`` (n, d) and the clip of ``m`` frames whose frame ``j`` is column
    ``start + j`` of ``bt`` (d, total), float32 (frames as columns): Euclidean frame cost,
    steps (1,0), (0,1), (1,1), a band of radius ``r`` frames around the diagonal rescaled to
    the two lengths, path cost divided by ``n + m``. Returns ``inf`` (abandoned) once every
    cell of a row exceeds ``cutoff`` (cost per ``n + m``; inf: never).

    The arithmetic is its definition, in this order (module conventions; what
    ``retrieval.quick`` computes with NumPy, bit for bit): a cell's squared frame cost is a
    float32 sum over the columns in order, ``s = s + t * t`` with ``t = a - b`` (no fused
    multiply-add, no reordering), its square root rounded to float32; a cell's path cost the
    float32 sum of that and the least of its three predecessors; the distance the float64
    quotient of the last cell by ``n + m``."""
    n, d = a.shape[0], a.shape[1]
    slope = (m - 1) / max(n - 1, 1)
    limit = np.float32(cutoff * (n + m) * (1.0 + 1e-5)) if cutoff < 1e29 else _INF32
    prev = np.full(m + 1, _INF32, dtype=np.float32)
    cur = np.full(m + 1, _INF32, dtype=np.float32)
    cost = np.empty(m + 1, dtype=np.float32)
    prev[0] = 0.0
    first = start - 1  # column of the clip's frame j (from 1)
    for i in range(1, n + 1):
        centre = (i - 1) * slope + 1
        lo = max(1, int(np.floor(centre - r)))
        hi = min(m, int(np.ceil(centre + r)))
        for j in range(lo, hi + 1):
            cost[j] = 0.0
        # columns outside, cells inside: each cell's sum runs over the columns in order, and
        # the cells of a row are independent (vectorised without reordering a sum)
        for k in range(d):
            x = a[i - 1, k]
            for j in range(lo, hi + 1):
                t = x - bt[k, first + j]
                cost[j] += t * t
        cur[lo - 1] = _INF32
        row_min = _INF32
        for j in range(lo, hi + 1):
            v = _extend(prev, cur, j, np.float32(np.sqrt(cost[j])))
            if v < row_min:
                row_min = v
        if row_min > limit:
            return np.inf
        prev, cur = cur, prev
    return float(prev[m]) / (n + m)


@nb.njit(cache=True, nogil=True)
def envelopes(frames, offsets, radius):  # pragma: no cover - compiled
    """Upper and lower envelopes of every clip of ``frames`` (float32, concatenated): per
    column, the max and min over frames ``j - radius .. j + radius`` of the same clip."""
    upper = np.empty_like(frames)
    lower = np.empty_like(frames)
    d = frames.shape[1]
    for c in range(offsets.shape[0] - 1):
        a, b = offsets[c], offsets[c + 1]
        for j in range(a, b):
            lo = max(a, j - radius)
            hi = min(b, j + radius + 1)
            for k in range(d):
                u = frames[lo, k]
                w = u
                for t in range(lo + 1, hi):
                    x = frames[t, k]
                    if x > u:
                        u = x
                    if x < w:
                        w = x
                upper[j, k] = u
                lower[j, k] = w
    return upper, lower


@nb.njit(cache=True, nogil=True)
def lb_keogh(qp, upper, lower, a, m, r_env):  # pragma: no cover - compiled
    """LB_Keogh of the projected query ``qp`` (n, p) against one clip's envelopes (rows
    ``a .. a + m`` of ``upper``/``lower``, radius ``r_env``): the distance of each query frame
    to the box of the frames its band row can reach, summed, over ``n + m``."""
    n, p = qp.shape[0], qp.shape[1]
    slope = (m - 1) / max(n - 1, 1)
    total = 0.0
    for i in range(n):
        j = a + min(m - 1, int(np.floor(i * slope + 0.5)))
        s = 0.0
        for k in range(p):
            x = qp[i, k]
            if x > upper[j, k]:
                t = x - upper[j, k]
                s += t * t
            elif x < lower[j, k]:
                t = lower[j, k] - x
                s += t * t
        total += np.sqrt(s)
    return total / (n + m)


@nb.njit(cache=True, nogil=True)
def fused_search(q, qp, frames_t, projected_t, upper, lower, offsets, radius, k, exclude):
    """Exact ``k`` nearest clips under :func:`dtw_band32` (radius ``radius``), pruned.

    ``q`` (n, D) and ``qp`` (n, p) are the query's stream and its projection on orthonormal
    directions; ``frames_t`` (D, total) and ``projected_t`` (p, total) the library's, frames
    as columns; ``upper``/``lower`` (total, p) the envelopes of the projection at radius
    ``radius + 1``. With ``k`` below the number of candidates, clips
    are visited by increasing LB_Keogh (valid where the pair's band radius is ``radius``; 0
    otherwise), skipped when the bound, or the DTW of the projections, exceeds the ``k``-th
    best distance so far, and the full DTW abandons above it. Returns the distance of every
    clip: exact where computed, ``inf`` where pruned (never one of the ``k`` nearest) or
    ``exclude``; and the number of full DTWs computed."""
    C = offsets.shape[0] - 1
    n = q.shape[0]
    out = np.full(C, np.inf)
    candidates = C - (1 if 0 <= exclude < C else 0)
    prune = k < candidates
    order = np.arange(C)
    lbs = np.zeros(C)
    if prune:
        for c in range(C):
            m = offsets[c + 1] - offsets[c]
            if band_radius(n, m, radius) <= radius:
                lbs[c] = lb_keogh(qp, upper, lower, offsets[c], m, radius + 1)
        order = np.argsort(lbs)
    best = np.full(k, np.inf)  # the k smallest distances so far, ascending (k >= 1: checked)
    full = 0
    slack = 1.0 + 1e-5
    for t in range(C):
        c = order[t]
        if c == exclude:
            continue
        kth = best[k - 1] if prune else np.inf
        if lbs[c] > kth * slack:
            break  # every later clip's bound is larger
        a, b = offsets[c], offsets[c + 1]
        r = band_radius(n, b - a, radius)
        if prune and kth < np.inf and dtw_band32(qp, projected_t, a, b - a, r, kth) > kth * slack:
            continue
        full += 1
        d = dtw_band32(q, frames_t, a, b - a, r, kth)
        out[c] = d
        if prune and d < best[k - 1]:
            pos = k - 1
            while pos > 0 and best[pos - 1] > d:
                best[pos] = best[pos - 1]
                pos -= 1
            best[pos] = d
    return out, full
