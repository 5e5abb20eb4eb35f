"""The hand-written numerics under the QSSD kernels agree with NumPy and LAPACK."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit

from quatmotion import quat
from quatmotion.sparse import _kernels as kern
from quatmotion.sparse._common import rank1


@njit(cache=False)
def _sincos_array(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s = np.empty_like(x)
    c = np.empty_like(x)
    for i in range(x.size):
        s[i], c[i] = kern._sincos(x[i])
    return s, c


@njit(cache=False)
def _atan_ratio_array(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    out = np.empty_like(num)
    for i in range(num.size):
        out[i] = kern._atan_ratio(num[i], den[i])
    return out


def test_sincos_matches_libm_to_a_few_ulp() -> None:
    rng = np.random.default_rng(0)
    quadrant_edges = np.pi / 4 * np.arange(-40, 41)
    x = np.concatenate(
        [
            rng.uniform(-10, 10, 20_000),
            rng.uniform(-1e6, 1e6, 2_000),
            quadrant_edges,
            np.nextafter(quadrant_edges, np.inf),
            [0.0, -0.0, 1e-300, -1e-12, 3.0, np.pi, -np.pi / 2],
        ]
    )
    s, c = _sincos_array(x)
    # Absolute error: near a zero of sin or cos a relative bound is meaningless.
    assert np.max(np.abs(s - np.sin(x))) < 4e-16
    assert np.max(np.abs(c - np.cos(x))) < 4e-16
    # Beyond exact reduction the error grows like ulp(x), the argument's own precision.
    big = rng.uniform(-1e12, 1e12, 1000)
    s, c = _sincos_array(big)
    assert np.max(np.abs(s - np.sin(big))) < 1e-3
    assert np.max(np.abs(c - np.cos(big))) < 1e-3


def test_atan_ratio_is_atan2_on_the_quadrant() -> None:
    rng = np.random.default_rng(1)
    num = np.concatenate([rng.uniform(0, 1, 20_000), rng.uniform(0, 1e-9, 100), [0, 0, 1, 0.66]])
    den = np.concatenate([rng.uniform(0, 1, 20_000), rng.uniform(0, 1, 100), [0, 1, 0, 1.0]])
    got = _atan_ratio_array(num, den)
    np.testing.assert_allclose(got, np.arctan2(num, den), rtol=4e-16, atol=1e-300)
    assert got[-4] == 0.0 and got[-3] == 0.0 and got[-2] == np.pi / 2


def test_log_kernel_matches_quat_log_on_both_hemispheres() -> None:
    rng = np.random.default_rng(2)
    q = rng.normal(size=(2000, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[:5] = [[1, 0, 0, 0], [-1, 0, 0, 0], [0, 1, 0, 0], [np.cos(1e-13), np.sin(1e-13), 0, 0],
             [-np.cos(0.3), 0, 0, np.sin(0.3)]]  # fmt: skip
    out = np.empty((1, 3, q.shape[0]))
    kern.logs(np.ascontiguousarray(q.T[None]), out)
    expected = quat.log(quat.canonicalize(q))
    np.testing.assert_allclose(out[0].T, expected, atol=2e-15)


def test_best_atoms_skips_atoms_already_in_the_code() -> None:
    rng = np.random.default_rng(3)
    N, K, L = 50, 12, 4
    proj = rng.normal(size=(N, K))
    idx = np.stack([rng.permutation(K)[:L] for _ in range(N)])
    count = rng.integers(0, L + 1, N)
    out = np.full(N, -1, dtype=np.int64)
    kern.best_atoms(proj, idx, count, 0, out)
    masked = np.abs(proj)
    for i in range(N):
        masked[i, idx[i, : count[i]]] = -1.0
    np.testing.assert_array_equal(out, np.argmax(masked, axis=1))


@pytest.mark.parametrize("shape", [(40, 30), (5000, 60)])
def test_rank1_matches_the_svd(shape: tuple[int, int]) -> None:
    rng = np.random.default_rng(4)
    M, d = shape
    u_true = rng.normal(size=d)
    u_true /= np.linalg.norm(u_true)
    A = np.outer(rng.normal(size=M) * 3, u_true) + 0.1 * rng.normal(size=(M, d))
    warm = u_true + 0.3 * rng.normal(size=d)
    u, w = rank1(A, warm)
    _, sigma, vt = np.linalg.svd(A, full_matrices=False)
    assert abs(abs(u @ vt[0]) - 1.0) < 1e-12
    assert u @ warm > 0  # the sign follows the warm start
    np.testing.assert_allclose(w, A @ u)
    np.testing.assert_allclose(np.linalg.norm(w), sigma[0], rtol=1e-12)


def test_gram_matvec_is_a_transpose_a_u() -> None:
    rng = np.random.default_rng(5)
    A = rng.normal(size=(1000, 37))
    u = rng.normal(size=37)
    out = np.empty(37)
    from quatmotion.sparse._linear_kernels import gram_matvec

    gram_matvec(A, u, out)
    np.testing.assert_allclose(out, A.T @ (A @ u), rtol=1e-12)
