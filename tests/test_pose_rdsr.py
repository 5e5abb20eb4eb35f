"""RDSR (section 4): sparse codes, the trace-ratio solvers and the estimator."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import ortho_group

from quatmotion.pose.metric import (
    RDSR,
    sparse_codes,
    trace_ratio,
    trace_ratio_bounds,
    trace_ratio_objective,
)


def random_psd(d: int, rank: int, rng: np.random.Generator) -> np.ndarray:
    m = rng.normal(size=(d, rank)) * rng.uniform(0.2, 3.0, size=rank)
    return m @ m.T


def test_sparse_codes_solve_the_lasso() -> None:
    rng = np.random.default_rng(0)
    # Correlated, unit-length samples like normalised GPD rows.
    X = np.abs(rng.normal(size=(80, 30)) + 1.5)
    X /= np.linalg.norm(X, axis=1, keepdims=True)
    lasso_alpha = 0.05
    codes, converged = sparse_codes(X, lasso_alpha=lasso_alpha, tol=1e-12)
    assert converged.all()
    C = codes.toarray()
    np.testing.assert_array_equal(np.diag(C), 0.0)
    G = X @ X.T
    for i in range(len(X)):
        others = np.delete(np.arange(len(X)), i)
        gamma = lasso_alpha * np.abs(G[i, others]).max()
        a = C[i]
        # Optimality (KKT) of 0.5 ||x_i - X^T a||^2 + gamma |a|_1 with a_ii = 0.
        grad = G[i] - G @ a
        active = a != 0
        assert active.sum() >= 1
        np.testing.assert_allclose(grad[active], gamma * np.sign(a[active]), atol=1e-8)
        assert np.all(np.abs(grad[others][~active[others]]) <= gamma * (1 + 1e-8))
    assert (C != 0).sum(axis=1).mean() < 30  # sparse


def test_trace_ratio_solvers_agree_and_respect_the_bounds() -> None:
    rng = np.random.default_rng(1)
    d, r = 24, 5
    A = random_psd(d, d, rng)
    B = random_psd(d, d, rng) + 0.1 * np.eye(d)
    lower, upper = trace_ratio_bounds(A, B, r)
    W_n, eta_n, info_n = trace_ratio(A, B, r, solver="newton")
    W_b, eta_b, info_b = trace_ratio(A, B, r, solver="bisection", tol=1e-12)
    assert eta_n == pytest.approx(eta_b, rel=1e-9)
    # Eq. 28-30: the optimum lies between the bounds.
    assert lower <= eta_n <= upper
    assert (info_n["eta_lower"], info_n["eta_upper"]) == (lower, upper)
    np.testing.assert_allclose(W_n.T @ W_n, np.eye(r), atol=1e-10)
    assert trace_ratio_objective(W_n, A, B) == pytest.approx(eta_n)

    # Eq. 33: f(eta) = max_W Tr(W^T (A - eta B) W) changes sign at eta*.
    def f(eta: float) -> float:
        return float(np.sum(np.linalg.eigvalsh(A - eta * B)[-r:]))

    assert f(eta_n * (1 - 1e-6)) > 0 > f(eta_n * (1 + 1e-6))
    assert abs(info_n["f_eta"]) < 1e-8 * np.trace(A)
    # Newton rises monotonically from a lower bound.
    history = np.array(info_n["history"])
    assert np.all(np.diff(history) >= -1e-9 * eta_n)
    # No orthonormal W does better than the optimum.
    others = ortho_group.rvs(d, size=300, random_state=2)[:, :, :r]
    assert max(trace_ratio_objective(W, A, B) for W in others) < eta_n
    # The ratio-trace (generalised eigenvector) answer, orthonormalised, does not beat it either.
    _, V = np.linalg.eigh(np.linalg.solve(B, A))
    Q, _ = np.linalg.qr(np.real(V[:, -r:]))
    assert trace_ratio_objective(Q, A, B) <= eta_n + 1e-12
    with pytest.raises(ValueError, match="rank"):
        trace_ratio(A, B, d + 1)
    with pytest.raises(ValueError, match="solver"):
        trace_ratio(A, B, r, solver="magic")  # type: ignore[arg-type]


def _synthetic(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unlabeled rows on a 6-D signal; similar pairs differ only along 2 nuisance axes."""
    rng = np.random.default_rng(seed)
    n, d = 400, 20
    X = rng.normal(size=(n, d)) * 0.05
    X[:, :6] += rng.normal(size=(n, 6))
    X[:, 6:8] += rng.normal(size=(n, 2)) * 1.5  # large variance, but irrelevant to similarity
    a = X[rng.choice(n, 60)]
    b = a.copy()
    b[:, 6:8] += rng.normal(size=(60, 2)) * 1.5
    b += rng.normal(size=b.shape) * 0.01
    return X, a, b


def test_rdsr_learns_to_ignore_what_similar_pairs_differ_in() -> None:
    X, a, b = _synthetic()
    model = RDSR(n_components=4, alpha=1.0, variance_kept=1.0).fit(X, np.stack((a, b), axis=1))
    W = model.components_.T
    np.testing.assert_allclose(W.T @ W, np.eye(4), atol=1e-10)
    # The nuisance axes carry most of the variance, yet W avoids them.
    assert np.linalg.norm(W[6:8]) ** 2 < 0.05 * 4
    # Similar pairs, relative to typical distances, get far closer than under L2.
    d_pairs = model.distances(a, b)
    d_all = model.pairwise_distances(X[:50], X[50:100])
    l2_pairs = np.linalg.norm(a - b, axis=1)
    l2_all = np.linalg.norm(X[:50, None] - X[None, 50:100], axis=-1)
    learned = np.median(d_pairs) / np.median(d_all)
    plain = np.median(l2_pairs) / np.median(l2_all)
    assert plain > 0.3
    assert learned < 0.2 * plain
    # Consistency of the three views of the metric.
    np.testing.assert_allclose(np.diag(model.pairwise_distances(a, b)), d_pairs, atol=1e-12)
    np.testing.assert_allclose(model.transform(a), a @ W)
    # Objective at the solution: the optimal ratio, not beaten by random orthonormal W.
    W_k = model.basis_.T @ W
    assert trace_ratio_objective(W_k, model.A_, model.B_) == pytest.approx(model.eta_)
    lower, upper = model.eta_bounds_
    assert lower <= model.eta_ <= upper
    k = model.basis_.shape[1]
    others = ortho_group.rvs(k, size=200, random_state=3)[:, :, :4]
    assert max(trace_ratio_objective(Q, model.A_, model.B_) for Q in others) < model.eta_
    assert set(model.timings_) >= {"S_W", "S_L", "S_C", "A", "B", "optimisation", "total"}
    assert model.codes_converged_ == 1.0


def test_rdsr_pair_formats_solvers_and_no_unlabeled_data() -> None:
    X, a, b = _synthetic(seed=1)
    idx = np.arange(0, 40).reshape(20, 2)
    by_index = RDSR(n_components=3).fit(X, idx)
    by_value = RDSR(n_components=3).fit(X, np.stack((X[idx[:, 0]], X[idx[:, 1]]), axis=1))
    np.testing.assert_allclose(by_index.eta_, by_value.eta_)
    bisect = RDSR(n_components=3, solver="bisection", tol=1e-12).fit(X, idx)
    assert bisect.eta_ == pytest.approx(by_index.eta_, rel=1e-8)
    # Eq. 46: without unlabeled poses W spans the least-scatter directions of S_W.
    pairs = np.stack((a, b), axis=1)
    supervised = RDSR(n_components=3, reg=0.0).fit(np.zeros((0, X.shape[1])), pairs)
    diffs = a - b
    smallest = np.linalg.eigvalsh(diffs.T @ diffs)[:3]
    assert np.sum(supervised.distances(a, b) ** 2) == pytest.approx(np.sum(smallest), rel=1e-6)
    with pytest.raises(ValueError, match="n_components"):
        RDSR(n_components=50).fit(X, idx)
    with pytest.raises(ValueError, match="positive_pairs"):
        RDSR(n_components=3).fit(X, np.zeros((5, 3)))
    with pytest.raises(ValueError, match="outside"):
        RDSR(n_components=3).fit(X, np.array([[0, 10_000]]))
