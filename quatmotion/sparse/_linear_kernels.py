"""Numba kernels of the linear model: Batch-OMP and sparse reconstruction (K-SVD), and the
one-pass Gram product of the rank-1 fits both dictionary learners use.

Codes use the slot layout of :mod:`quatmotion.sparse._kernels` (``idx``, ``coef``, ``count``,
slots sorted by descending ``|coef|``); like those kernels, these trust their inputs.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from quatmotion.sparse._kernels import _FM_SUM, back_substitute
from quatmotion.sparse._kernels import _sort_slots as sort_slots


@njit(parallel=True, cache=True, fastmath=_FM_SUM)
def gram_matvec(A, u, out):  # type: ignore[no-untyped-def]
    """``out = A^T (A u)`` for ``A`` ``(M, d)`` in one pass over ``A`` (BLAS takes two).

    Rows are summed in fixed blocks and the blocks in order, so the result does not depend on
    the number of threads.
    """
    M, d = A.shape
    block = 256
    n_blocks = (M + block - 1) // block
    partial = np.zeros((n_blocks, d))
    for b in prange(n_blocks):
        acc = partial[b]
        for i in range(b * block, min(M, (b + 1) * block)):
            row = A[i]
            t = 0.0
            for k in range(d):
                t += row[k] * u[k]
            for k in range(d):
                acc[k] += t * row[k]
    for k in range(d):
        out[k] = 0.0
    for b in range(n_blocks):
        for k in range(d):
            out[k] += partial[b, k]


@njit(parallel=True, cache=True)
def batch_omp(G, Xy, sparsity, tol, idx, coef, count):  # type: ignore[no-untyped-def]
    """Orthogonal matching pursuit with a precomputed Gram matrix (Batch-OMP), all samples.

    ``G = D D^T`` ``(K, K)`` for unit atoms, ``Xy = Y D^T`` ``(N, K)``. Per sample the Cholesky
    factor of ``G[I, I]`` grows by one row per selected atom, so a step costs ``O(K |I|)``
    (the correlation update) instead of a least-squares solve. Stops early when every
    correlation magnitude is below ``tol``.
    """
    N, K = Xy.shape
    for i in prange(N):
        alpha = Xy[i].copy()
        Lc = np.zeros((sparsity, sparsity))
        sel = np.empty(sparsity, dtype=np.int64)
        c = np.zeros(sparsity)
        z = np.empty(sparsity)
        w = np.empty(sparsity)
        m = 0
        while m < sparsity:
            best = -1
            best_val = tol
            for k in range(K):
                v = abs(alpha[k])
                if v > best_val:
                    taken = False
                    for t in range(m):
                        if sel[t] == k:
                            taken = True
                            break
                    if not taken:
                        best_val = v
                        best = k
            if best < 0:
                break
            if m == 0:
                Lc[0, 0] = math.sqrt(G[best, best])
            else:
                # Solve Lc[:m, :m] w = G[sel, best] (read as row ``best``: G is symmetric).
                for r in range(m):
                    acc = G[best, sel[r]]
                    for t in range(r):
                        acc -= Lc[r, t] * w[t]
                    w[r] = acc / Lc[r, r]
                d2 = G[best, best]
                for r in range(m):
                    d2 -= w[r] * w[r]
                if d2 <= 1e-12:
                    break  # the atom is (numerically) in the span already
                for r in range(m):
                    Lc[m, r] = w[r]
                Lc[m, m] = math.sqrt(d2)
            sel[m] = best
            m += 1
            # c = (Lc Lc^T)^-1 Xy[i, sel]
            for r in range(m):
                acc = Xy[i, sel[r]]
                for t in range(r):
                    acc -= Lc[r, t] * z[t]
                z[r] = acc / Lc[r, r]
            back_substitute(Lc, z, c, m)
            # alpha = Xy - G[:, sel] c, by rows of G (symmetric): contiguous reads, where its
            # columns are K strided ones per selected atom.
            for k in range(K):
                alpha[k] = Xy[i, k]
            for t in range(m):
                row = G[sel[t]]
                ct = c[t]
                for k in range(K):
                    alpha[k] -= row[k] * ct
        for t in range(m):
            idx[i, t] = sel[t]
            coef[i, t] = c[t]
        count[i] = m
        sort_slots(idx[i], coef[i], m)


@njit(parallel=True, cache=True)
def sparse_reconstruct(D, idx, coef, count, out):  # type: ignore[no-untyped-def]
    """Linear combination ``out[i] = sum_s coef[i, s] D[idx[i, s]]`` ``(N, d)``."""
    N = idx.shape[0]
    d = D.shape[1]
    for i in prange(N):
        for t in range(d):
            out[i, t] = 0.0
        for s in range(count[i]):
            k = idx[i, s]
            x = coef[i, s]
            for t in range(d):
                out[i, t] += x * D[k, t]
