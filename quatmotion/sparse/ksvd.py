"""K-SVD (Aharon, Elad & Bruckstein 2006) on quaternion arrays: the paper's Euclidean baseline.

As in the QSSD paper's comparison, each sample's ``n`` quaternions (taken on the ``w >= 0``
hemisphere) are flattened to one ``4n``-vector and decomposed by linear combination:
``Y ~ X D`` with unit-norm atoms ``D`` ``(K, 4n)`` and at most ``L`` non-zeros per row of ``X``.
Sparse coding is orthogonal matching pursuit (Batch-OMP with a precomputed Gram matrix, Numba,
parallel over samples); the dictionary stage is Algorithm 1: atom by atom, rank-1 SVD of the
residual restricted to the samples that use the atom, with the residual matrix kept up to date
so an atom update costs ``O(|Omega| 4n)``. Reconstructions are renormalised to unit
quaternions. Unused atoms are re-seeded with the worst-represented sample, as in QSSD.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray
from sklearn.utils.validation import check_is_fitted

from quatmotion.sparse import _linear_kernels as kern
from quatmotion.sparse._base import DictionaryLearner
from quatmotion.sparse._common import (
    Codes,
    codes_to_matrix,
    compute_threads,
    group_by_atom,
    matrix_to_codes,
    rank1,
)

__all__ = ["KSVD", "learn_linear_dictionary", "omp"]

_CHUNK = 8192


def omp(
    Yf: NDArray[np.float64], D: NDArray[np.float64], sparsity: int, tol: float = 1e-12
) -> Codes:
    """Batch orthogonal matching pursuit of ``Yf`` ``(N, d)`` on unit atoms ``D`` ``(K, d)``.

    Returns
    -------
    Codes
        Slots sorted by descending ``|weight|`` (the order is irrelevant to a linear model).
    """
    N = Yf.shape[0]
    K = D.shape[0]
    L = min(sparsity, K)
    G = D @ D.T
    G = np.ascontiguousarray(0.5 * (G + G.T))  # exactly symmetric: batch_omp reads its rows
    codes = Codes(np.zeros((N, L), dtype=np.int64), np.zeros((N, L)), np.zeros(N, dtype=np.int64))
    for start in range(0, N, _CHUNK):
        sl = slice(start, min(start + _CHUNK, N))
        Xy = np.ascontiguousarray(Yf[sl] @ D.T)
        kern.batch_omp(G, Xy, L, tol, codes.idx[sl], codes.coef[sl], codes.count[sl])
    return codes


def _reconstruct(D: NDArray[np.float64], codes: Codes) -> NDArray[np.float64]:
    out = np.empty((codes.idx.shape[0], D.shape[1]))
    kern.sparse_reconstruct(D, codes.idx, codes.coef, codes.count, out)
    return out


def _to_quaternions(flat: NDArray[np.float64], n: int) -> NDArray[np.float64]:
    q = flat.reshape(flat.shape[0], n, 4).copy()
    norms = np.linalg.norm(q, axis=-1, keepdims=True)
    zero = norms[..., 0] < 1e-12
    q = q / np.where(norms < 1e-12, 1.0, norms)
    # A joint the linear model drives to zero has no rotation left: return the identity.
    q[zero] = (1.0, 0.0, 0.0, 0.0)
    return q


def learn_linear_dictionary(
    Yf: NDArray[np.float64], D: NDArray[np.float64], sparsity: int, n_iter: int
) -> NDArray[np.float64]:
    """``n_iter`` plain K-SVD iterations from unit atoms ``D`` ``(K, d)`` on ``Yf`` ``(N, d)``.

    Used by QSSD's ``init="log-ksvd"`` on the logs of the samples. Returns the new atoms.
    """
    D = np.array(D, dtype=np.float64, order="C", copy=True)
    work = float(Yf.shape[0] * sparsity * max(D.shape[0], Yf.shape[1] // 4))
    for _ in range(n_iter):
        with compute_threads(work):
            codes = omp(Yf, D, sparsity)
            R = Yf - _reconstruct(D, codes)
        with compute_threads(work, blas_single=True):
            KSVD._update_dictionary(Yf, D, codes, R)
    return D


@dataclass
class _FitState:
    """What K-SVD's fit carries between iterations."""

    Y: NDArray[np.float64]  # (N, n, 4) validated samples
    Yf: NDArray[np.float64]  # (N, 4n) flattened
    D: NDArray[np.float64]  # (K, 4n) unit atoms
    work: float


class KSVD(DictionaryLearner):
    """K-SVD with OMP on flattened quaternion arrays (the paper's baseline, Algorithm 1).

    Parameters
    ----------
    n_atoms : int
        ``K``.
    sparsity : int
        ``L``.
    max_iter : int
        Largest number of iterations.
    tol : float
        Stop when the squared residual after coding improves by less than ``tol`` times its value.
    random_state : int, RandomState or None
        Seeds the initial atoms (random samples, as for QSSD).
    verbose : bool

    Attributes
    ----------
    dictionary_ : ndarray, shape (K, n, 4)
        Atoms reshaped to quaternions (unit as ``4n``-vectors, not per quaternion).
    dictionary_flat_ : ndarray, shape (K, 4n)
    n_iter_ : int
    errors_ : ndarray, shape (n_iter_,)
        Training error after each coding stage, mean rotation angle in degrees per quaternion
        (Eq. 11 with the factor 2), on renormalised reconstructions.
    objective_ : ndarray, shape (n_iter_,)
        ``|Y - X D|_F^2`` after each coding stage.
    iteration_seconds_ : ndarray, shape (n_iter_,)
        Wall time of each iteration (coding + dictionary update).
    iteration_cpu_seconds_ : ndarray, shape (n_iter_,)
        Processor time of each iteration summed over threads (robust to a shared machine).
    n_features_in_ : int
    """

    def _start(self, Y: NDArray[np.float64], rng: np.random.RandomState) -> _FitState:
        N, n, _ = Y.shape
        Yf = np.ascontiguousarray(Y.reshape(N, 4 * n))
        K = self.n_atoms
        chosen = rng.permutation(N)[:K]
        D = np.empty((K, 4 * n))
        D[: chosen.size] = Yf[chosen] / np.linalg.norm(Yf[chosen], axis=1, keepdims=True)
        if chosen.size < K:
            extra = rng.standard_normal((K - chosen.size, 4 * n))
            D[chosen.size :] = extra / np.linalg.norm(extra, axis=1, keepdims=True)
        # OMP's per-sample work is about K L (correlation updates), comparable to QSSD's n L.
        work = float(N * self.sparsity * max(self.n_atoms, n))
        return _FitState(Y, Yf, D, work)

    def _iterate(self, state: _FitState) -> tuple[float, float, str]:
        with compute_threads(state.work):
            codes = omp(state.Yf, state.D, self.sparsity)
            R = state.Yf - _reconstruct(state.D, codes)
        total = float(np.sum(R * R))
        Yhat = _to_quaternions(state.Yf - R, state.Y.shape[1])
        cosines = np.minimum(np.abs(np.sum(state.Y * Yhat, -1)), 1.0)
        error = float(np.degrees(np.mean(2 * np.arccos(cosines))))
        with compute_threads(state.work, blas_single=True):
            self._update_dictionary(state.Yf, state.D, codes, R)
        return error, total, ""

    def _finish(self, state: _FitState) -> None:
        self.dictionary_flat_ = state.D
        self.dictionary_ = state.D.reshape(self.n_atoms, state.Y.shape[1], 4)

    @staticmethod
    def _update_dictionary(
        Yf: NDArray[np.float64], D: NDArray[np.float64], codes: Codes, R: NDArray[np.float64]
    ) -> None:
        """Algorithm 1 lines 9-14 in place on ``D``, ``codes.coef`` and the residual ``R``."""
        K = D.shape[0]
        groups = group_by_atom(codes, K)
        unused = [k for k in range(K) if groups[k].size == 0]
        if unused:
            worst = np.argsort(-np.einsum("ij,ij->i", R, R), kind="stable")[: len(unused)]
            for k, i in zip(unused, worst, strict=False):
                norm = np.linalg.norm(Yf[i])
                if norm > 0:
                    D[k] = Yf[i] / norm
        for k in range(K):
            samples = groups[k]
            if samples.size == 0:
                continue
            slot = np.argmax(codes.idx[samples] == k, axis=1)
            x = codes.coef[samples, slot]
            E = R[samples] + np.outer(x, D[k])
            u, w = rank1(E, D[k])
            D[k] = u
            codes.coef[samples, slot] = w
            R[samples] = E - np.outer(w, u)

    def transform(self, X: ArrayLike) -> sp.csr_matrix:
        """OMP weights of ``X`` ``(N, n, 4)``: ``csr_matrix`` ``(N, K)``."""
        check_is_fitted(self)
        Y = self._check_samples(X)
        with compute_threads(float(len(Y) * self.sparsity * max(self.n_atoms, Y.shape[1]))):
            codes = omp(
                np.ascontiguousarray(Y.reshape(len(Y), -1)), self.dictionary_flat_, self.sparsity
            )
        return codes_to_matrix(codes, self.n_atoms)

    def inverse_transform(self, X: ArrayLike | sp.spmatrix) -> NDArray[np.float64]:
        """``X D`` reshaped to ``(N, n, 4)`` and renormalised per quaternion."""
        check_is_fitted(self)
        codes = matrix_to_codes(X, self.n_atoms)
        return _to_quaternions(_reconstruct(self.dictionary_flat_, codes), self.n_features_in_)
