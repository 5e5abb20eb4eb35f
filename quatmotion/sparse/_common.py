"""Helpers shared by the QSSD and K-SVD estimators: input checks, code layouts, rank-1 SVD.

A sparse code is kept in two layouts. Internally, per sample, as slots in combination order
(``idx`` ``(N, L)`` atom indices, ``coef`` ``(N, L)`` weights, ``count`` ``(N,)`` used slots,
sorted by descending ``|coef|``). At the API, as a ``scipy.sparse.csr_matrix`` ``(N, K)``, the
sparse weight matrix ``X^T`` of the paper: the order of a row is recovered from the magnitudes.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import NamedTuple

import numba
import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray
from threadpoolctl import threadpool_limits

from quatmotion import quat
from quatmotion.sparse._linear_kernels import gram_matvec

UNIT_TOLERANCE = 1e-6
# Below this many quaternion products per kernel call, thread start-up and waiting for a
# descheduled thread (the machine is shared) cost more than the second core gains.
_PARALLEL_WORK = 2e5


@contextmanager
def compute_threads(work: float, blas_single: bool = False) -> Iterator[None]:
    """Run Numba kernels on one thread for small ``work`` (quaternion products per call).

    ``blas_single`` also keeps BLAS on one thread: its idle threads spin and steal the cores
    from Numba's threads between the many small SVDs of a dictionary stage.
    """
    previous = numba.get_num_threads()
    numba.set_num_threads(1 if work < _PARALLEL_WORK else previous)
    try:
        if blas_single:
            with threadpool_limits(limits=1, user_api="blas"):
                yield
        else:
            yield
    finally:
        numba.set_num_threads(previous)


class Codes(NamedTuple):
    """Sparse codes as slots: ``idx`` ``(N, L)`` int64, ``coef`` ``(N, L)``, ``count`` ``(N,)``."""

    idx: NDArray[np.int64]
    coef: NDArray[np.float64]
    count: NDArray[np.int64]


def check_quaternion_samples(Y: ArrayLike, name: str = "Y") -> NDArray[np.float64]:
    """Validate ``(N, n, 4)`` unit quaternions; return a C-contiguous copy with every ``w >= 0``.

    Raises ``ValueError`` on a wrong shape, non-finite values or a quaternion whose norm differs
    from 1 by more than ``1e-6``.
    """
    arr = np.asarray(Y, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[-1] != 4:
        raise ValueError(
            f"{name} must have shape (N, n, 4) (N samples of n quaternions), got {arr.shape}"
        )
    if arr.shape[0] < 1 or arr.shape[1] < 1:
        raise ValueError(
            f"{name} needs at least one sample of at least one quaternion, got {arr.shape}"
        )
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or infinite values")
    norms = np.linalg.norm(arr, axis=-1)
    worst = float(np.max(np.abs(norms - 1.0)))
    if worst > UNIT_TOLERANCE:
        raise ValueError(
            f"{name} must hold unit quaternions; the largest | |q| - 1 | is {worst:.3g}"
        )
    # Renormalise away the admitted rounding and pick the w >= 0 hemisphere: the shortest-arc
    # representative that every log below assumes.
    return np.ascontiguousarray(quat.canonicalize(arr / norms[..., None]))


def check_positive_int(value: object, name: str, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def codes_to_matrix(codes: Codes, n_atoms: int) -> sp.csr_matrix:
    """Slots -> ``csr_matrix`` ``(N, K)`` of weights."""
    N, L = codes.idx.shape
    used = np.arange(L)[None, :] < codes.count[:, None]
    rows = np.broadcast_to(np.arange(N)[:, None], (N, L))[used]
    return sp.csr_matrix(
        (codes.coef[used], (rows, codes.idx[used])), shape=(N, n_atoms), dtype=np.float64
    )


def matrix_to_codes(W: ArrayLike | sp.spmatrix, n_atoms: int) -> Codes:
    """Weight matrix ``(N, K)`` (dense or sparse) -> slots sorted by descending ``|weight|``.

    Ties keep ascending atom index, so the combination order is a function of ``W``.
    """
    M = (
        sp.csr_matrix(W, dtype=np.float64)
        if sp.issparse(W)
        else sp.csr_matrix(np.asarray(W, dtype=np.float64))
    )
    if M.ndim != 2 or M.shape[1] != n_atoms:
        raise ValueError(f"weights must have shape (N, {n_atoms}), got {M.shape}")
    M.eliminate_zeros()
    M.sum_duplicates()
    M.sort_indices()
    if not np.all(np.isfinite(M.data)):
        raise ValueError("weights contain NaN or infinite values")
    N = M.shape[0]
    count = np.diff(M.indptr).astype(np.int64)
    L = max(int(count.max(initial=0)), 1)
    idx = np.zeros((N, L), dtype=np.int64)
    coef = np.zeros((N, L))
    for i in range(N):
        lo, hi = M.indptr[i], M.indptr[i + 1]
        cols = M.indices[lo:hi]
        vals = M.data[lo:hi]
        order = np.argsort(-np.abs(vals), kind="stable")
        idx[i, : hi - lo] = cols[order]
        coef[i, : hi - lo] = vals[order]
    return Codes(idx, coef, count)


def group_by_atom(codes: Codes, n_atoms: int) -> list[NDArray[np.int64]]:
    """For every atom the samples whose code uses it (the set Omega of Algorithm 1/3)."""
    N, L = codes.idx.shape
    used = np.arange(L)[None, :] < codes.count[:, None]
    rows = np.broadcast_to(np.arange(N)[:, None], (N, L))[used]
    atoms = codes.idx[used]
    order = np.argsort(atoms, kind="stable")
    bounds = np.searchsorted(atoms[order], np.arange(n_atoms + 1))
    return [rows[order[bounds[k] : bounds[k + 1]]] for k in range(n_atoms)]


def rank1(
    A: NDArray[np.float64], warm: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Best rank-1 approximation ``A ~ w u^T`` with ``|u| = 1``: ``(M, d) -> (u (d,), w (M,))``.

    ``w = sigma_1 v_1`` and ``u`` the first right singular vector (the atom in K-SVD, Algorithm 1
    line 13; ``ln`` of the atom in Algorithm 3 line 9). Power iteration on ``A^T A`` warm-started
    from the current atom ``warm``, which is already close, so a few passes over ``A`` replace a
    factorisation (a LAPACK SVD of each atom's small residual matrix was most of a K = 2000
    iteration); large ``A`` are passed over once per step (:func:`gram_matvec`). Where it has not
    converged to 1e-8 in 30 steps (two nearly equal singular values), a small ``A`` goes to
    LAPACK's SVD and a large one keeps the last iterate (an SVD of a 5000 x 300 matrix costs as
    much as a whole coding pass, and either vector fits nearly as well). The sign is chosen so
    that ``u . warm >= 0`` (the atom does not flip between iterations).
    """
    M, d = A.shape
    large = M * d > 40_000
    u, converged = _power_iteration(A, warm, large) if M >= 3 else (warm, False)
    if not converged and not large:
        _, _, vt = np.linalg.svd(A, full_matrices=False)
        u = vt[0].copy()
    if np.dot(u, warm) < 0.0:
        u = -u
    return u, A @ u


def _power_iteration(
    A: NDArray[np.float64],
    warm: NDArray[np.float64],
    large: bool,
    steps: int = 30,
    tol: float = 1e-8,
) -> tuple[NDArray[np.float64], bool]:
    """Leading right singular vector of ``A`` by power iteration; whether it converged."""
    d = A.shape[1]
    if large:
        A = np.ascontiguousarray(A)
    u = warm / max(np.linalg.norm(warm), 1e-300)
    if not np.any(u):
        u = A[np.argmax(np.einsum("ij,ij->i", A, A))].copy()
        u /= max(np.linalg.norm(u), 1e-300)
    z = np.empty(d)
    for _ in range(steps):
        if large:
            gram_matvec(A, u, z)
        else:
            z = A.T @ (A @ u)
        norm = np.linalg.norm(z)
        if norm == 0.0:
            return u, False
        # A new array: z is the output buffer of the next step.
        updated = z / norm
        change = np.linalg.norm(updated - u)
        u = updated
        if change < tol:
            return u, True
    return u, False
