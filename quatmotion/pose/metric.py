"""RDSR: Regularized Distance metric learning with Sparse Representation (section 4).

Learns ``W`` (D, r) with orthonormal columns so that ``d(x, y) = ||W^T (x - y)||`` (Eq. 11)
maximises the trace ratio of Eq. 26::

    W* = argmax_{W^T W = I}  Tr(W^T A W) / Tr(W^T B W),
    A = X S_C X^T  (regulariser: stay close to L2, Eq. 24),
    B = X S_L X^T + alpha S_W  (sparse-representation relationship, Eq. 17, plus labels, Eq. 12).

Conventions
-----------
- Arrays hold one sample per *row* (scikit-learn style): ``X`` is (N, D), the paper's ``X^T``.
- ``S_L = (I - A)(I - A)^T`` is never formed: with ``C`` the (N, N) sparse code matrix (row i
  holds the lasso weights reconstructing pose i from the others, ``C_ii = 0``), the residuals
  are ``R = X - C X`` and ``X S_L X^T`` is ``R^T R``. ``X S_C X^T`` is the centred scatter.
- ``alpha`` is scale-free: ``S_W`` is multiplied by ``alpha * Tr(X S_L X^T) / Tr(S_W)``, so
  ``alpha = 1`` gives the label term and the relationship term the same total weight (the paper
  leaves alpha's value unstated, and the raw traces differ by orders of magnitude).
- The lasso of Eq. 16 is solved in its usual squared form ``0.5 ||x_i - X^T a||^2 + gamma
  ||a||_1`` with ``gamma_i = lasso_alpha * max_{j != i} |<x_i, x_j>|`` (``lasso_alpha`` is the
  fraction of the smallest penalty that makes the code all zero, so it does not depend on the
  feature scale).

Speed (the paper's S_L took 5,260 s for 5,000 poses): one Gram matrix ``G = X X^T`` serves all
N lassos; each is solved exactly (no candidate restriction) by coordinate descent on an active
set grown from the strongest KKT violators, so a sweep costs O(active^2) instead of O(N D); the
poses run in parallel (Numba ``prange``).
"""

from __future__ import annotations

import time
from typing import Any, Literal

import numba
import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.special
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.distance import cdist
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.utils.validation import check_is_fitted
from threadpoolctl import threadpool_limits

__all__ = [
    "PairLogistic",
    "pair_labels",
    "RDSR",
    "sparse_codes",
    "trace_ratio",
    "trace_ratio_bounds",
    "trace_ratio_objective",
]

FloatArray = NDArray[np.float64]


def pair_labels(labels: ArrayLike, learner: str) -> NDArray[np.bool_]:
    """Pair labels as booleans, shape (P,) (True: similar), for a ``learner`` that needs both
    kinds.

    Raises
    ------
    ValueError
        The pairs are all similar or all dissimilar.
    """
    similar = np.asarray(labels, dtype=bool).reshape(-1)
    if similar.all() or not similar.any():
        raise ValueError(f"{learner} needs both similar and dissimilar pairs")
    return similar


# ------------------------------------------------------------------------------------------
# Sparse representation (Eq. 15-16)
# ------------------------------------------------------------------------------------------
@numba.njit(cache=True, nogil=True)
def _lasso_gram_one(
    G: FloatArray,
    i: int,
    gamma: float,
    max_active: int,
    add_per_round: int,
    max_sweeps: int,
    tol: float,
    out_index: NDArray[np.int64],
    out_value: FloatArray,
) -> tuple[int, bool]:  # pragma: no cover - compiled
    """Lasso code of row ``i`` of the Gram matrix, ``a_i = 0``; returns (nnz, converged)."""
    n = G.shape[0]
    active = np.empty(max_active, dtype=np.int64)
    coef = np.zeros(max_active)
    grad = np.empty(max_active)  # b - G a restricted to the active set
    in_active = np.zeros(n, dtype=np.bool_)
    in_active[i] = True  # never a candidate: a_ii = 0
    residual_corr = G[i].copy()  # b - G a over all atoms, b = G[i]
    n_active = 0
    converged = False
    for _outer in range(n):
        # Grow the active set by the strongest KKT violators |b_j - (G a)_j| > gamma.
        n_added = 0
        for _ in range(add_per_round):
            if n_active >= max_active:
                break
            best = -1
            best_value = gamma * (1.0 + 1e-9)
            for j in range(n):
                if not in_active[j]:
                    v = abs(residual_corr[j])
                    if v > best_value:
                        best_value = v
                        best = j
            if best < 0:
                break
            in_active[best] = True
            active[n_active] = best
            coef[n_active] = 0.0
            grad[n_active] = residual_corr[best]
            n_active += 1
            n_added += 1
        if n_added == 0:
            converged = True
            break
        # Coordinate descent on the active set only: each update costs O(n_active).
        for _sweep in range(max_sweeps):
            max_step = 0.0
            for k in range(n_active):
                j = active[k]
                gjj = G[j, j]
                if gjj <= 0.0:
                    continue
                z = grad[k] + gjj * coef[k]
                if z > gamma:
                    new = (z - gamma) / gjj
                elif z < -gamma:
                    new = (z + gamma) / gjj
                else:
                    new = 0.0
                step = new - coef[k]
                if step != 0.0:
                    coef[k] = new
                    for m in range(n_active):
                        grad[m] -= step * G[active[m], j]
                    if abs(step) > max_step:
                        max_step = abs(step)
            if max_step < tol:
                break
        # Refresh the correlations of every atom with the new residual.
        residual_corr[:] = G[i]
        for k in range(n_active):
            if coef[k] != 0.0:
                c = coef[k]
                row = G[active[k]]
                for j in range(n):
                    residual_corr[j] -= c * row[j]
        if n_active >= max_active:
            break
    nnz = 0
    for k in range(n_active):
        if coef[k] != 0.0:
            out_index[nnz] = active[k]
            out_value[nnz] = coef[k]
            nnz += 1
    return nnz, converged


@numba.njit(cache=True, parallel=True)
def _lasso_gram_all(
    G: FloatArray,
    gammas: FloatArray,
    max_active: int,
    add_per_round: int,
    max_sweeps: int,
    tol: float,
) -> tuple[NDArray[np.int64], FloatArray, NDArray[np.int64], NDArray[np.bool_]]:  # pragma: no cover
    n = G.shape[0]
    index = np.zeros((n, max_active), dtype=np.int64)
    value = np.zeros((n, max_active))
    nnz = np.zeros(n, dtype=np.int64)
    converged = np.zeros(n, dtype=np.bool_)
    for i in numba.prange(n):
        k, ok = _lasso_gram_one(
            G, i, gammas[i], max_active, add_per_round, max_sweeps, tol, index[i], value[i]
        )
        nnz[i] = k
        converged[i] = ok
    return index, value, nnz, converged


def sparse_codes(
    X: ArrayLike,
    lasso_alpha: float = 0.05,
    max_active: int = 256,
    tol: float = 1e-7,
) -> tuple[scipy.sparse.csr_array, NDArray[np.bool_]]:
    """Sparse representation of every sample by all the others (Eq. 15-16).

    Parameters
    ----------
    X : array_like, shape (N, D)
        Samples as rows.
    lasso_alpha : float
        Penalty as a fraction (0, 1) of each sample's ``gamma_max = max_{j != i} |<x_i, x_j>|``.
    max_active : int
        Most atoms a code may try; a code that reaches it stops early (reported as not
        converged).
    tol : float
        Coordinate-descent stop: largest coefficient change in a sweep.

    Returns
    -------
    codes : scipy.sparse.csr_array, shape (N, N)
        Row i: weights ``a_i`` with ``x_i ~ sum_j a_ij x_j`` and ``a_ii = 0``.
    converged : ndarray of bool, shape (N,)
        Whether each code satisfies the lasso's optimality (KKT) conditions.
    """
    x = np.ascontiguousarray(X, dtype=np.float64)
    if x.ndim != 2:
        raise ValueError(f"X must be (N, D), got shape {x.shape}")
    if not 0.0 < lasso_alpha < 1.0:
        raise ValueError(f"lasso_alpha must be in (0, 1), got {lasso_alpha}")
    n = x.shape[0]
    if n < 2:
        return scipy.sparse.csr_array((n, n)), np.ones(n, dtype=bool)
    gram = x @ x.T
    off = np.abs(gram)
    np.fill_diagonal(off, 0.0)
    gammas = lasso_alpha * off.max(axis=1)
    del off
    cap = int(min(max_active, n - 1))
    index, value, nnz, converged = _lasso_gram_all(gram, gammas, cap, 4, 10_000, float(tol))
    rows = np.repeat(np.arange(n), nnz)
    mask = np.arange(cap)[None, :] < nnz[:, None]
    codes = scipy.sparse.csr_array((value[mask], (rows, index[mask])), shape=(n, n))
    return codes, converged


# ------------------------------------------------------------------------------------------
# Trace ratio (section 4.3)
# ------------------------------------------------------------------------------------------
def _top_eigen(M: FloatArray, r: int, vectors: bool) -> tuple[FloatArray, FloatArray | None]:
    d = M.shape[0]
    M = 0.5 * (M + M.T)
    # One BLAS thread: OpenBLAS threads spin-wait, and on a shared 2-core machine a 1683 x 1683
    # partial eigendecomposition took 12 s with two threads against 0.9 s with one.
    with threadpool_limits(limits=1, user_api="blas"):
        if vectors:
            w, v = scipy.linalg.eigh(M, subset_by_index=[d - r, d - 1], driver="evr")
            return w[::-1], v[:, ::-1]
        w = scipy.linalg.eigh(M, subset_by_index=[d - r, d - 1], eigvals_only=True, driver="evr")
    return w[::-1], None


def trace_ratio_objective(W: ArrayLike, A: ArrayLike, B: ArrayLike) -> float:
    """``Tr(W^T A W) / Tr(W^T B W)`` for W (D, r), A and B (D, D)."""
    W = np.asarray(W, dtype=np.float64)
    return float(np.sum(W * (np.asarray(A) @ W)) / np.sum(W * (np.asarray(B) @ W)))


def trace_ratio_bounds(A: ArrayLike, B: ArrayLike, rank: int) -> tuple[float, float]:
    """Bounds on the optimal trace ratio (Eq. 28-30).

    Parameters
    ----------
    A, B : array_like, shape (D, D)
        Symmetric; A positive semi-definite, B positive definite.
    rank : int
        Columns of W, ``d'``.

    Returns
    -------
    (eta_lower, eta_upper) : tuple of float
        ``Tr(A) / Tr(B)`` and (sum of the ``rank`` largest eigenvalues of A) / (sum of the
        ``rank`` smallest eigenvalues of B).
    """
    bounds, _ = _bounds_and_start(np.asarray(A, dtype=np.float64),
                                  np.asarray(B, dtype=np.float64), rank)  # fmt: skip
    return bounds


def _bounds_and_start(A: FloatArray, B: FloatArray, rank: int) -> tuple[tuple[float, float], float]:
    """Eq. 29-30 bounds, and the best ratio among the two eigenbases they compute.

    The top eigenvectors of A and the bottom eigenvectors of B are feasible W, so their
    ratios are lower bounds on eta* too, usually far tighter than ``Tr(A) / Tr(B)``.
    """
    top_a, W_a = _top_eigen(A, rank, vectors=True)
    low_b, W_b = _top_eigen(-B, rank, vectors=True)
    low_b = -low_b
    assert W_a is not None and W_b is not None
    lower = float(np.trace(A) / np.trace(B))
    upper = float(np.sum(top_a) / np.sum(low_b))
    start = max(lower, trace_ratio_objective(W_a, A, B), trace_ratio_objective(W_b, A, B))
    return (lower, upper), start


def _bisection(
    A: FloatArray, B: FloatArray, rank: int, lower: float, upper: float, tol: float, max_iter: int
) -> tuple[FloatArray, list[float]]:
    """Fig. 3: ``[lower, upper]`` halved by the sign of ``f`` (eigenvalues only) until its width
    is below ``tol * upper``; the top eigenvectors at the midpoint and the eta tried per step."""
    lo, hi = lower, upper
    history: list[float] = []
    while hi - lo > tol * max(abs(hi), 1e-300) and len(history) < max_iter:
        eta = 0.5 * (lo + hi)
        f_eta = float(np.sum(_top_eigen(A - eta * B, rank, vectors=False)[0]))
        if f_eta > 0.0:
            lo = eta
        else:
            hi = eta
        history.append(eta)
    _, W = _top_eigen(A - 0.5 * (lo + hi) * B, rank, vectors=True)
    return W, history


def _newton(
    A: FloatArray, B: FloatArray, rank: int, start: float, tol: float, max_iter: int
) -> tuple[FloatArray, list[float]]:
    """The trace-ratio update ``eta <- ratio(W(eta))`` from ``start`` (Newton's method on
    ``f``); the last eigenvectors and the ratio per iteration."""
    eta = start
    history: list[float] = []
    _, W = _top_eigen(A - eta * B, rank, vectors=True)
    while True:
        new_eta = trace_ratio_objective(W, A, B)
        history.append(new_eta)
        done = abs(new_eta - eta) <= tol * max(abs(new_eta), 1e-300)
        eta = max(eta, new_eta)  # the update never decreases eta; guard rounding
        if done or len(history) >= max_iter:
            return W, history
        _, W = _top_eigen(A - eta * B, rank, vectors=True)


def trace_ratio(
    A: ArrayLike,
    B: ArrayLike,
    rank: int,
    solver: Literal["newton", "bisection"] = "newton",
    tol: float = 1e-10,
    max_iter: int = 200,
) -> tuple[FloatArray, float, dict[str, object]]:
    """Solve ``max_{W^T W = I} Tr(W^T A W) / Tr(W^T B W)`` globally.

    Both solvers find the root ``eta*`` of ``f(eta) = max_W Tr(W^T (A - eta B) W)`` (Eq. 31),
    the sum of the ``rank`` largest eigenvalues of ``A - eta B``, which is decreasing in eta
    and has the optimal ratio as its only root (Eq. 33).

    Parameters
    ----------
    A, B : array_like, shape (D, D)
        Symmetric; B positive definite.
    rank : int
        ``d'``, 1 <= rank <= D.
    solver : {"newton", "bisection"}
        ``"bisection"``: Fig. 3, halving ``[eta_lower, eta_upper]`` (Eq. 29-30) by the sign of
        ``f`` (eigenvalues only) until its width is below ``tol * eta_upper``. ``"newton"``:
        the iterative trace-ratio update ``eta <- ratio(W(eta))`` (Wang et al. 2007, [45]),
        which is Newton's method on ``f`` (``-Tr(W^T B W)`` is its slope): it starts from the
        best ratio of the eigenbases the bounds need (a lower bound on eta*), rises
        monotonically and converges superlinearly to the same root.
    tol : float
        Relative tolerance on eta.
    max_iter : int

    Returns
    -------
    W : ndarray, shape (D, rank)
        Orthonormal columns: the top eigenvectors of ``A - eta* B`` (Eq. 32).
    eta : float
        The optimal ratio, ``trace_ratio_objective(W, A, B)``.
    info : dict
        ``eta_lower``, ``eta_upper`` (the Eq. 29-30 bounds), ``n_iter``, ``f_eta`` (f at the
        returned eta, ~0) and ``history`` (eta per iteration).
    """
    A = np.asarray(A, dtype=np.float64)
    B = np.asarray(B, dtype=np.float64)
    d = A.shape[0]
    if A.shape != (d, d) or B.shape != (d, d):
        raise ValueError(f"A and B must be square and alike, got {A.shape} and {B.shape}")
    if not 1 <= rank <= d:
        raise ValueError(f"rank must be in [1, {d}], got {rank}")
    (lower, upper), start = _bounds_and_start(A, B, rank)
    if solver == "bisection":
        W, history = _bisection(A, B, rank, lower, upper, tol, max_iter)
    elif solver == "newton":
        W, history = _newton(A, B, rank, start, tol, max_iter)
    else:
        raise ValueError(f"solver must be 'newton' or 'bisection', got {solver!r}")
    n_iter = len(history)
    eta_w = trace_ratio_objective(W, A, B)
    f_eta = float(np.sum(W * ((A - eta_w * B) @ W)))
    info: dict[str, object] = {
        "eta_lower": lower,
        "eta_upper": upper,
        "n_iter": n_iter,
        "f_eta": f_eta,
        "history": history,
    }
    return W, eta_w, info


# ------------------------------------------------------------------------------------------
# The estimator
# ------------------------------------------------------------------------------------------
class RDSR(TransformerMixin, BaseEstimator):
    """Semi-supervised Mahalanobis metric ``W W^T`` of rank ``n_components`` (Fig. 3).

    Parameters
    ----------
    n_components : int
        Rank of W (the paper's ``d'``, 50).
    alpha : float
        Weight of the label term ``S_W`` relative to the sparse-representation term, as a
        multiple of ``Tr(X S_L X^T) / Tr(S_W)`` (1 = equal total weight).
    lasso_alpha : float
        Sparse-code penalty as a fraction of each pose's smallest all-zero penalty (see
        :func:`sparse_codes`).
    solver : {"newton", "bisection"}
        Trace-ratio solver (:func:`trace_ratio`); both reach the same optimum.
    reg : float
        Ridge added to B, as a fraction of ``Tr(B) / D``, so B is positive definite (features
        constant on the training set make it singular) and Eq. 30's bound is finite.
    variance_kept : float
        The trace ratio is solved in the span of the principal directions holding this
        fraction of the unlabeled poses' variance (at least ``n_components`` of them). In the
        directions the data do not vary, ``A`` and ``B`` are both ~0, and the optimum of Eq. 27
        degenerates: it keeps the single best direction and pads W with those free null
        directions, so most columns of W carry no information. Restricting
        to the data's span is the usual preprocessing of trace-ratio / LDA-type methods; it
        also makes every eigendecomposition small.
    max_active : int
        Most atoms per sparse code.
    tol : float
        Relative tolerance of the trace-ratio solver.
    random_state : int, RandomState or None
        Unused (the fit is deterministic); kept for a uniform estimator interface.

    Attributes
    ----------
    components_ : ndarray, shape (n_components, D)
        ``W^T`` (orthonormal rows): ``transform(X) = X @ components_.T``.
    eta_ : float
        Optimal trace ratio.
    eta_bounds_ : tuple of float
        Eq. 29-30 bounds.
    sparse_codes_ : scipy.sparse.csr_array, shape (N, N)
        The lasso weights of the unlabeled poses.
    codes_converged_ : float
        Fraction of sparse codes that met the lasso's optimality conditions.
    basis_ : ndarray, shape (D, k)
        Orthonormal principal directions the problem is solved in.
    A_, B_ : ndarray, shape (k, k)
        The trace-ratio matrices in ``basis_`` coordinates (``B_`` includes the ridge).
    n_iter_ : int
    timings_ : dict of str to float
        Seconds per step, as in Table 2: ``S_W``, ``S_L``, ``S_C``, ``A``, ``B``,
        ``optimisation`` and ``total``.
    n_features_in_ : int
    """

    def __init__(
        self,
        n_components: int = 50,
        alpha: float = 1.0,
        lasso_alpha: float = 0.05,
        solver: Literal["newton", "bisection"] = "newton",
        reg: float = 1e-6,
        variance_kept: float = 0.999,
        max_active: int = 256,
        tol: float = 1e-10,
        random_state: int | np.random.RandomState | None = None,
    ) -> None:
        self.n_components = n_components
        self.alpha = alpha
        self.lasso_alpha = lasso_alpha
        self.solver = solver
        self.reg = reg
        self.variance_kept = variance_kept
        self.max_active = max_active
        self.tol = tol
        self.random_state = random_state

    def fit(self, X_unlabeled: ArrayLike, positive_pairs: ArrayLike) -> RDSR:
        """Learn W.

        Parameters
        ----------
        X_unlabeled : array_like, shape (N, D)
            Unlabeled (normalised) pose features; N may be 0 (then the objective is Eq. 46:
            the ``n_components`` smallest-variance directions of ``S_W``).
        positive_pairs : array_like, shape (P, 2, D) or (P, 2) of int
            Similar pairs, either as feature vectors or as row indices into ``X_unlabeled``.

        Returns
        -------
        self
        """
        t_total = time.perf_counter()
        X, diffs = self._validate(X_unlabeled, positive_pairs)
        n, d = X.shape
        if not 1 <= self.n_components <= d:
            raise ValueError(f"n_components must be in [1, {d}], got {self.n_components}")
        if self.alpha < 0:
            raise ValueError(f"alpha must be non-negative, got {self.alpha}")
        timings: dict[str, float] = {}

        t = time.perf_counter()
        if n >= 2:
            codes, converged = sparse_codes(X, self.lasso_alpha, self.max_active)
        else:
            codes, converged = scipy.sparse.csr_array((n, n)), np.ones(n, dtype=bool)
        timings["S_L"] = time.perf_counter() - t

        basis, A, B = self._matrices(X, codes, diffs, timings)

        t = time.perf_counter()
        W_k, eta, info = self._optimise(A, B, n)
        W = basis @ W_k
        timings["optimisation"] = time.perf_counter() - t
        timings["total"] = time.perf_counter() - t_total

        self.basis_ = basis
        self.components_ = np.ascontiguousarray(W.T)
        self.eta_ = eta
        self.eta_bounds_ = (float(info["eta_lower"]), float(info["eta_upper"]))  # type: ignore[arg-type]
        self.n_iter_ = int(info["n_iter"])  # type: ignore[call-overload]
        self.sparse_codes_ = codes
        self.codes_converged_ = float(np.mean(converged)) if n else 1.0
        self.A_ = A
        self.B_ = B
        self.timings_ = timings
        self.n_features_in_ = d
        return self

    def _matrices(
        self, X: FloatArray, codes: Any, diffs: FloatArray, timings: dict[str, float]
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The principal basis and, in it, the trace ratio's ``A`` (Eq. 23's centred scatter)
        and ``B`` (the sparse-representation residuals plus the weighted ``S_W``, Eq. 13-18,
        regularised); each step's seconds into ``timings``."""
        n = len(X)
        t = time.perf_counter()
        centred = X - X.mean(axis=0) if n else X  # X S_C: S_C = I - 11^T / N (Eq. 23)
        timings["S_C"] = time.perf_counter() - t

        t = time.perf_counter()
        basis = self._principal_basis(centred, diffs)
        centred_k = centred @ basis
        A = centred_k.T @ centred_k
        timings["A"] = time.perf_counter() - t

        t = time.perf_counter()
        diffs_k = diffs @ basis
        S_W_k = diffs_k.T @ diffs_k  # Eq. 13
        timings["S_W"] = time.perf_counter() - t

        t = time.perf_counter()
        residuals = (X - codes @ X) @ basis
        B_L = residuals.T @ residuals  # X S_L X^T (Eq. 17-18)
        tr_sw = float(np.trace(S_W_k))
        tr_bl = float(np.trace(B_L))
        # alpha is relative to the traces; with no unlabeled data S_W stands alone (Eq. 46).
        weight = self.alpha * tr_bl / tr_sw if n >= 2 and tr_sw > 0 else 1.0
        B = B_L + weight * S_W_k
        k = basis.shape[1]
        B += (self.reg * max(np.trace(B), 1e-300) / k) * np.eye(k)
        timings["B"] = time.perf_counter() - t
        return basis, A, B

    def _optimise(self, A: FloatArray, B: FloatArray, n: int) -> tuple[FloatArray, float, dict]:
        """``W`` in the basis, the ratio reached and the solver's info."""
        if n < 2:
            # Eq. 46: with no unlabeled data only E_supervision is left; minimise it.
            w, W_k = _top_eigen(-B, self.n_components, vectors=True)
            assert W_k is not None
            eta = float(-np.sum(w))
            return W_k, eta, {"eta_lower": eta, "eta_upper": eta, "n_iter": 0}
        return trace_ratio(A, B, self.n_components, self.solver, self.tol)

    def _principal_basis(self, centred: FloatArray, diffs: FloatArray) -> FloatArray:
        """Orthonormal (D, k) basis of the directions the training poses vary along."""
        d = centred.shape[1]
        if centred.shape[0] < 2:
            return np.eye(d)  # Eq. 46 needs the least-scatter directions of S_W: keep them all
        scatter = centred.T @ centred  # the full-space A; its eigenbasis is the PCA basis
        with threadpool_limits(limits=1, user_api="blas"):
            variances, vectors = scipy.linalg.eigh(scatter, driver="evd")
        variances, vectors = np.maximum(variances[::-1], 0.0), vectors[:, ::-1]
        energy = np.cumsum(variances)
        if energy[-1] <= 0:
            raise ValueError("the training poses do not vary: no metric to learn")
        k = int(np.searchsorted(energy, self.variance_kept * energy[-1]) + 1)
        k = min(max(k, self.n_components), d)
        return np.ascontiguousarray(vectors[:, :k])

    @staticmethod
    def _validate(
        X_unlabeled: ArrayLike, positive_pairs: ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        X = np.asarray(X_unlabeled, dtype=np.float64)
        if X.ndim != 2:
            raise ValueError(f"X_unlabeled must be (N, D), got shape {X.shape}")
        pairs = np.asarray(positive_pairs)
        if pairs.ndim == 2 and pairs.shape[1] == 2 and np.issubdtype(pairs.dtype, np.integer):
            if pairs.size and (pairs.min() < 0 or pairs.max() >= X.shape[0]):
                raise ValueError("positive_pairs indices fall outside X_unlabeled")
            diffs = X[pairs[:, 0]] - X[pairs[:, 1]]
        elif pairs.ndim == 3 and pairs.shape[1] == 2:
            if pairs.shape[2] != X.shape[1] and X.shape[0] > 0:
                raise ValueError(
                    f"positive_pairs have {pairs.shape[2]} features, X_unlabeled {X.shape[1]}"
                )
            pairs = pairs.astype(np.float64)
            diffs = pairs[:, 0] - pairs[:, 1]
            if X.shape[0] == 0:
                X = np.zeros((0, pairs.shape[2]))
        else:
            raise ValueError(
                f"positive_pairs must be (P, 2, D) features or (P, 2) indices, got {pairs.shape}"
            )
        if diffs.shape[0] == 0:
            raise ValueError("RDSR needs at least one positive pair")
        if not (np.all(np.isfinite(X)) and np.all(np.isfinite(diffs))):
            raise ValueError("features must be finite")
        return np.ascontiguousarray(X), diffs

    def transform(self, X: ArrayLike) -> FloatArray:
        """Project onto W: ``(N, D) -> (N, n_components)``; Euclidean distances there are Eq. 11."""
        check_is_fitted(self, "components_")
        X = np.asarray(X, dtype=np.float64)
        if X.ndim != 2 or X.shape[1] != self.n_features_in_:
            raise ValueError(f"expected (N, {self.n_features_in_}) features, got {X.shape}")
        return X @ self.components_.T

    def pairwise_distances(self, A: ArrayLike, B: ArrayLike) -> FloatArray:
        """Learned distances (Eq. 11) between every row of A (Q, D) and of B (M, D): (Q, M)."""
        return cdist(self.transform(A), self.transform(B))

    def distances(self, A: ArrayLike, B: ArrayLike) -> FloatArray:
        """Learned distances between aligned rows of A and B, both (P, D): (P,)."""
        return np.linalg.norm(self.transform(A) - self.transform(B), axis=1)


# ------------------------------------------------------------------------------------------
# Learning from good and bad pairs
# ------------------------------------------------------------------------------------------
class PairLogistic:
    """A weighted L2 distance learned by logistic regression on good *and* bad pairs.

    The squared distance ``sum_k w_k (a_k - b_k)^2`` (``w >= 0``) minus a threshold ``c`` is
    the log-odds that a pair is bad (a transition that plays badly): ``w`` and ``c`` minimise
    the mean logistic loss over the labelled pairs plus ``alpha / 2 * ||v||^2``, ``v`` the
    weights in units of each feature's mean squared difference over the pairs (so ``alpha``
    does not depend on the features' scale). Bounded L-BFGS; convex, so deterministic.

    Parameters
    ----------
    alpha : float
        Ridge penalty (on the standardised weights), > 0.
    max_iter : int

    Attributes
    ----------
    weights_ : ndarray, shape (D,)
        ``w`` (non-negative).
    threshold_ : float
        ``c``: pairs with a squared distance above it are more likely bad than good.
    power : int
        2 (the distance is Euclidean after scaling each feature by ``sqrt(w)``).
    """

    power = 2

    def __init__(self, alpha: float = 1e-3, max_iter: int = 500) -> None:
        if not alpha > 0:
            raise ValueError(f"alpha must be positive, got {alpha}")
        if max_iter < 1:
            raise ValueError(f"max_iter must be at least 1, got {max_iter}")
        self.alpha = alpha
        self.max_iter = max_iter

    def fit(
        self, X_unlabeled: ArrayLike, X_a: ArrayLike, X_b: ArrayLike, labels: ArrayLike
    ) -> PairLogistic:
        """Fit on pairs ``(X_a[i], X_b[i])`` (P, D), labels True = similar (a good pair)."""
        from scipy.optimize import minimize

        similar = pair_labels(labels, "PairLogistic")
        d2 = (np.asarray(X_a, dtype=np.float64) - np.asarray(X_b, dtype=np.float64)) ** 2
        unit = d2.mean(axis=0)
        unit = np.where(unit > 0, unit, 1.0)
        Z = d2 / unit
        sign = np.where(similar, -1.0, 1.0)  # +1: bad
        n, d = Z.shape

        def loss(theta: FloatArray) -> tuple[float, FloatArray]:
            v, c = theta[:d], theta[d]
            m = sign * (Z @ v - c)  # margin: positive when right
            loss = np.logaddexp(0.0, -m).mean() + 0.5 * self.alpha * v @ v
            g = -sign * scipy.special.expit(-m) / n  # d loss / d logit
            grad = np.r_[Z.T @ g + self.alpha * v, -g.sum()]
            return float(loss), grad

        theta0 = np.r_[np.full(d, 1.0 / d), 1.0]
        bounds = [(0.0, None)] * d + [(None, None)]
        result = minimize(
            loss, theta0, jac=True, method="L-BFGS-B", bounds=bounds,
            options={"maxiter": self.max_iter},
        )  # fmt: skip
        self.weights_ = np.maximum(result.x[:d], 0.0) / unit
        self.threshold_ = float(result.x[d])
        self.n_iter_ = int(result.nit)
        return self

    def distances(self, A: ArrayLike, B: ArrayLike) -> FloatArray:
        diff = np.asarray(A, dtype=np.float64) - np.asarray(B, dtype=np.float64)
        return np.sqrt(diff**2 @ self.weights_)

    def pairwise(self, Q: ArrayLike, B: ArrayLike) -> FloatArray:
        s = np.sqrt(self.weights_)
        return cdist(np.asarray(Q) * s, np.asarray(B) * s)
