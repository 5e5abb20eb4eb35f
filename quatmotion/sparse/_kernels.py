"""Numba kernels for QSSD: batched quaternion combination, sparse coding and atom residuals.

Conventions shared by every kernel (the estimator in :mod:`quatmotion.sparse.qssd` owns the
validation; these functions trust their inputs):

* ``Y`` is ``(N, n, 4)`` unit quaternions, w first, each with ``w >= 0``.
* A dictionary is stored by its logarithms ``Dlog`` ``(K, n, 3)``: atom ``k`` joint ``j`` is
  ``exp(Dlog[k, j])`` and ``atom ** x = exp(x * Dlog[k, j])``. ``Dnorm`` ``(K, n)`` holds the
  per-joint half angles ``|Dlog[k, j]|`` and ``Daxis`` ``(K, n, 3)`` the unit axes (zero where
  the half angle is zero).
* A sparse code is stored per sample as slots in combination order: ``idx`` ``(N, L)`` atom
  indices, ``coef`` ``(N, L)`` weights, ``count`` ``(N,)`` the number of used slots. The
  combination (paper Eq. 2) is ``A_0 A_1 ... A_{m-1}`` with ``A_s = atom(idx_s) ** coef_s``, the
  slots sorted by descending ``|coef|``.
* The objective of a sample is ``sum_j 1 - |<Y_j, Yhat_j>|`` (paper Eq. 4 turned into a
  minimisation, with the absolute value because ``q`` and ``-q`` are the same rotation).

Every kernel that walks over samples runs them in parallel with ``prange``: samples are
independent in both sparse coding and the residual computation of one atom.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

_EPS = 1e-12


@njit(inline="always", cache=True)
def _qmul(aw, ax, ay, az, bw, bx, by, bz):  # type: ignore[no-untyped-def]
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@njit(inline="always", cache=True)
def _qexp(vx, vy, vz):  # type: ignore[no-untyped-def]
    a = math.sqrt(vx * vx + vy * vy + vz * vz)
    # Below 1e-8, sin(a)/a = 1 - a^2/6 to double precision.
    s = 1.0 - a * a / 6.0 if a < 1e-8 else math.sin(a) / a
    return math.cos(a), vx * s, vy * s, vz * s


@njit(inline="always", cache=True)
def _qlog(w, x, y, z):  # type: ignore[no-untyped-def]
    """Shortest-arc log (the sign of ``q`` is chosen so that ``w >= 0``)."""
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    vn = math.sqrt(x * x + y * y + z * z)
    s = 1.0 / max(w, 1e-300) if vn < 1e-12 else math.atan2(vn, w) / vn
    return x * s, y * s, z * s


@njit(cache=True)
def _sort_slots(idx_row, coef_row, m):  # type: ignore[no-untyped-def]
    """Stable insertion sort of the first ``m`` slots by descending ``|coef|``; True if moved."""
    moved = False
    for s in range(1, m):
        ci = coef_row[s]
        ii = idx_row[s]
        t = s - 1
        while t >= 0 and abs(coef_row[t]) < abs(ci):
            coef_row[t + 1] = coef_row[t]
            idx_row[t + 1] = idx_row[t]
            t -= 1
            moved = True
        coef_row[t + 1] = ci
        idx_row[t + 1] = ii
    return moved


@njit(cache=True)
def _power_into(Dlog, k, x, out):  # type: ignore[no-untyped-def]
    n = Dlog.shape[1]
    for j in range(n):
        w, qx, qy, qz = _qexp(x * Dlog[k, j, 0], x * Dlog[k, j, 1], x * Dlog[k, j, 2])
        out[j, 0] = w
        out[j, 1] = qx
        out[j, 2] = qy
        out[j, 3] = qz


@njit(cache=True)
def _solve_coef(E, Dnorm, Daxis, k, weighted):  # type: ignore[no-untyped-def]
    """Weight ``x`` maximising ``sum_j <E_j, atom_k_j ** x>`` (paper Eq. 5-6).

    Per joint the optimum satisfies ``tan(x phi_j / 2) = (u_j . v_j) tan(theta_j / 2)``, i.e.
    ``x a_j = b_j`` with ``a_j = phi_j / 2`` and ``b_j = atan2(v_j . vec(E_j), w(E_j))``
    (the same arctan without forming ``tan``). Eq. 6 combines the joints by least squares. With
    ``weighted`` each joint is weighted by ``rho_j = |(w, v_j . vec)|``, the amplitude of its
    term ``rho_j cos(x a_j - b_j)``: the exact second-order model of Eq. 5 around each optimum.
    """
    n = E.shape[0]
    num = 0.0
    den = 0.0
    for j in range(n):
        a = Dnorm[k, j]
        if a <= 0.0:
            continue
        w = E[j, 0]
        p = Daxis[k, j, 0] * E[j, 1] + Daxis[k, j, 1] * E[j, 2] + Daxis[k, j, 2] * E[j, 3]
        if w < 0.0:
            w = -w
            p = -p
        b = math.atan2(p, w)
        rho = math.sqrt(w * w + p * p) if weighted else 1.0
        num += rho * a * b
        den += rho * a * a
    if den <= 0.0:
        return 0.0
    return num / den


@njit(cache=True)
def _bcd(Y_i, Dlog, Dnorm, Daxis, idx_row, coef_row, m, n_sweeps, weighted, A, suf, Lq, E):  # type: ignore[no-untyped-def]
    """Block coordinate descent over the ``m`` weights of one sample, keeping the order sorted.

    Each sweep visits the slots left to right. For slot ``s`` the other factors are fixed:
    ``E = (A_0 .. A_{s-1})^-1 Y (A_{s+1} .. A_{m-1})^-1`` and Eq. 6 gives the new weight.
    The suffix products are formed once per sweep (they only involve slots not yet visited) and
    the left factor ``P^-1 Y`` is carried along, so a sweep costs O(m n) quaternion products.
    After each sweep the slots are re-sorted by magnitude, which is the order Eq. 2 defines.
    """
    n = Y_i.shape[0]
    for s in range(m):
        _power_into(Dlog, idx_row[s], coef_row[s], A[s])
    for _ in range(n_sweeps):
        # suf[s] = A_s A_{s+1} ... A_{m-1}; suf[m] = identity.
        for j in range(n):
            suf[m, j, 0] = 1.0
            suf[m, j, 1] = 0.0
            suf[m, j, 2] = 0.0
            suf[m, j, 3] = 0.0
        for s in range(m - 1, -1, -1):
            for j in range(n):
                r = _qmul(
                    A[s, j, 0],
                    A[s, j, 1],
                    A[s, j, 2],
                    A[s, j, 3],
                    suf[s + 1, j, 0],
                    suf[s + 1, j, 1],
                    suf[s + 1, j, 2],
                    suf[s + 1, j, 3],
                )
                suf[s, j, 0] = r[0]
                suf[s, j, 1] = r[1]
                suf[s, j, 2] = r[2]
                suf[s, j, 3] = r[3]
        for j in range(n):
            Lq[j, 0] = Y_i[j, 0]
            Lq[j, 1] = Y_i[j, 1]
            Lq[j, 2] = Y_i[j, 2]
            Lq[j, 3] = Y_i[j, 3]
        for s in range(m):
            for j in range(n):
                # E = Lq * conj(suf[s + 1])
                r = _qmul(
                    Lq[j, 0],
                    Lq[j, 1],
                    Lq[j, 2],
                    Lq[j, 3],
                    suf[s + 1, j, 0],
                    -suf[s + 1, j, 1],
                    -suf[s + 1, j, 2],
                    -suf[s + 1, j, 3],
                )
                E[j, 0] = r[0]
                E[j, 1] = r[1]
                E[j, 2] = r[2]
                E[j, 3] = r[3]
            x = _solve_coef(E, Dnorm, Daxis, idx_row[s], weighted)
            coef_row[s] = x
            _power_into(Dlog, idx_row[s], x, A[s])
            for j in range(n):
                # Lq <- A_s^-1 Lq
                r = _qmul(
                    A[s, j, 0],
                    -A[s, j, 1],
                    -A[s, j, 2],
                    -A[s, j, 3],
                    Lq[j, 0],
                    Lq[j, 1],
                    Lq[j, 2],
                    Lq[j, 3],
                )
                Lq[j, 0] = r[0]
                Lq[j, 1] = r[1]
                Lq[j, 2] = r[2]
                Lq[j, 3] = r[3]
        if _sort_slots(idx_row, coef_row, m):
            for s in range(m):
                _power_into(Dlog, idx_row[s], coef_row[s], A[s])


@njit(cache=True)
def _gauss_newton(Y_i, Dlog, idx_row, coef_row, m, n_iter, A, suf, Wmat, keep_sorted):  # type: ignore[no-untyped-def]
    """Joint Gauss-Newton refinement of the ``m`` weights of one sample, order kept sorted.

    With ``Yhat = A_0 .. A_{m-1}`` and the residual ``r = ln(Yhat^-1 Y)`` (``3n``-vector), moving
    weight ``s`` by ``delta`` right-multiplies ``Yhat`` by ``exp(delta w_s)``, where
    ``w_s = S^-1 v_s S`` is the atom log ``v_s`` rotated by the suffix ``S = A_{s+1} .. A_{m-1}``.
    So ``r(x + delta) ~ r - W delta`` and one step solves the ``m x m`` normal equations
    ``W^T W delta = W^T r``. Exact data are a zero-residual problem, where Gauss-Newton
    converges quadratically; coordinate descent (Algorithm 2's solver) only linearly and slowly
    when the atoms are far from commuting. A step that does not lower ``|r|`` is halved (up to
    four times) and dropped if it still does not.
    """
    n = Y_i.shape[0]
    G = np.empty((m, m))
    g = np.empty(m)
    delta = np.empty(m)
    trial = np.empty(m)
    r = np.empty(3 * n)
    current = _gn_residual(Y_i, Dlog, idx_row, coef_row, m, A, suf, r)
    for _ in range(n_iter):
        if current < 1e-28:
            break
        # Columns w_s: rotate v_s by conj(suf[s + 1]), i.e. S^* v S.
        for s in range(m):
            k = idx_row[s]
            for j in range(n):
                sw, sx, sy, sz = (
                    suf[s + 1, j, 0],
                    suf[s + 1, j, 1],
                    suf[s + 1, j, 2],
                    suf[s + 1, j, 3],
                )
                t = _qmul(sw, -sx, -sy, -sz, 0.0, Dlog[k, j, 0], Dlog[k, j, 1], Dlog[k, j, 2])
                q = _qmul(t[0], t[1], t[2], t[3], sw, sx, sy, sz)
                Wmat[s, 3 * j] = q[1]
                Wmat[s, 3 * j + 1] = q[2]
                Wmat[s, 3 * j + 2] = q[3]
        trace = 0.0
        for a in range(m):
            acc = 0.0
            for t in range(3 * n):
                acc += Wmat[a, t] * r[t]
            g[a] = acc
            for b in range(a + 1):
                acc = 0.0
                for t in range(3 * n):
                    acc += Wmat[a, t] * Wmat[b, t]
                G[a, b] = acc
                G[b, a] = acc
            trace += G[a, a]
        ridge = 1e-12 * trace + 1e-300
        for a in range(m):
            G[a, a] += ridge
        if not _cholesky_solve(G, g, delta, m):
            break
        step = 1.0
        accepted = False
        for _half in range(3):
            for s in range(m):
                trial[s] = coef_row[s] + step * delta[s]
            value = _gn_residual_trial(Y_i, Dlog, idx_row, trial, m, A, suf, r)
            if value < current:
                accepted = True
                break
            step *= 0.5
        if not accepted:
            current = _gn_residual(Y_i, Dlog, idx_row, coef_row, m, A, suf, r)
            break
        for s in range(m):
            coef_row[s] = trial[s]
        current = value
        if keep_sorted and _sort_slots(idx_row, coef_row, m):
            current = _gn_residual(Y_i, Dlog, idx_row, coef_row, m, A, suf, r)
    return current


@njit(cache=True)
def _refit_with_swaps(Y_i, Dlog, idx_row, coef_row, m, n_iter, A, suf, Wmat):  # type: ignore[no-untyped-def]
    """Gauss-Newton, then try the other order of every adjacent pair of near-tied weights.

    The combination order follows the weights, so where two magnitudes are close the fit can
    settle in the wrong order: refitting in that order would swap them, and re-sorting swaps
    them back. For each such pair the swapped order is refit with the order held fixed and
    kept if the result is consistent (still sorted) and fits better.
    """
    best = _gauss_newton(Y_i, Dlog, idx_row, coef_row, m, n_iter, A, suf, Wmat, True)
    if m < 2 or best < 1e-28:
        return
    # Only a fit that is still poor can be an order problem; a good one is left alone.
    signal = 0.0
    for j in range(Y_i.shape[0]):
        lx, ly, lz = _qlog(Y_i[j, 0], Y_i[j, 1], Y_i[j, 2], Y_i[j, 3])
        signal += lx * lx + ly * ly + lz * lz
    if best < 1e-6 * signal:
        return
    trial_idx = np.empty_like(idx_row)
    trial_coef = np.empty_like(coef_row)
    # The two closest pairs at most: each trial is a full refit.
    gaps = np.empty(m - 1)
    for s in range(m - 1):
        a = abs(coef_row[s])
        gaps[s] = (a - abs(coef_row[s + 1])) / max(a, 1e-300)
    order = np.argsort(gaps)
    candidates = order[:2].copy()
    for c in range(candidates.shape[0]):
        s = candidates[c]
        if gaps[s] > 0.05:
            continue
        for t in range(m):
            trial_idx[t] = idx_row[t]
            trial_coef[t] = coef_row[t]
        trial_idx[s], trial_idx[s + 1] = idx_row[s + 1], idx_row[s]
        trial_coef[s], trial_coef[s + 1] = coef_row[s + 1], coef_row[s]
        value = _gauss_newton(
            Y_i, Dlog, trial_idx, trial_coef, m, min(n_iter, 2), A, suf, Wmat, False
        )
        consistent = True
        for t in range(m - 1):
            if abs(trial_coef[t]) < abs(trial_coef[t + 1]):
                consistent = False
                break
        if consistent and value < best:
            best = value
            for t in range(m):
                idx_row[t] = trial_idx[t]
                coef_row[t] = trial_coef[t]


@njit(cache=True)
def _cholesky_solve(G, g, out, m):  # type: ignore[no-untyped-def]
    """Solve ``G out = g`` for SPD ``G`` ``(m, m)``; G is overwritten. False if singular."""
    for a in range(m):
        acc = G[a, a]
        for t in range(a):
            acc -= G[a, t] * G[a, t]
        if acc <= 0.0:
            return False
        G[a, a] = math.sqrt(acc)
        for b in range(a + 1, m):
            acc = G[b, a]
            for t in range(a):
                acc -= G[b, t] * G[a, t]
            G[b, a] = acc / G[a, a]
    for a in range(m):
        acc = g[a]
        for t in range(a):
            acc -= G[a, t] * out[t]
        out[a] = acc / G[a, a]
    for a in range(m - 1, -1, -1):
        acc = out[a]
        for t in range(a + 1, m):
            acc -= G[t, a] * out[t]
        out[a] = acc / G[a, a]
    return True


@njit(cache=True)
def _gn_residual_trial(Y_i, Dlog, idx_row, coef, m, A, suf, r):  # type: ignore[no-untyped-def]
    """Residual for weights ``coef`` in the current slot order (suffixes refreshed)."""
    for s in range(m):
        _power_into(Dlog, idx_row[s], coef[s], A[s])
    return _suffix_and_residual(Y_i, m, A, suf, r)


@njit(cache=True)
def _gn_residual(Y_i, Dlog, idx_row, coef_row, m, A, suf, r):  # type: ignore[no-untyped-def]
    return _gn_residual_trial(Y_i, Dlog, idx_row, coef_row, m, A, suf, r)


@njit(cache=True)
def _suffix_and_residual(Y_i, m, A, suf, r):  # type: ignore[no-untyped-def]
    """``suf[s] = A_s .. A_{m-1}``, ``r = ln(suf[0]^-1 Y)``; returns ``|r|^2``."""
    n = Y_i.shape[0]
    for j in range(n):
        suf[m, j, 0] = 1.0
        suf[m, j, 1] = 0.0
        suf[m, j, 2] = 0.0
        suf[m, j, 3] = 0.0
    for s in range(m - 1, -1, -1):
        for j in range(n):
            q = _qmul(
                A[s, j, 0],
                A[s, j, 1],
                A[s, j, 2],
                A[s, j, 3],
                suf[s + 1, j, 0],
                suf[s + 1, j, 1],
                suf[s + 1, j, 2],
                suf[s + 1, j, 3],
            )
            suf[s, j, 0] = q[0]
            suf[s, j, 1] = q[1]
            suf[s, j, 2] = q[2]
            suf[s, j, 3] = q[3]
    total = 0.0
    for j in range(n):
        q = _qmul(
            suf[0, j, 0],
            -suf[0, j, 1],
            -suf[0, j, 2],
            -suf[0, j, 3],
            Y_i[j, 0],
            Y_i[j, 1],
            Y_i[j, 2],
            Y_i[j, 3],
        )
        lx, ly, lz = _qlog(q[0], q[1], q[2], q[3])
        r[3 * j] = lx
        r[3 * j + 1] = ly
        r[3 * j + 2] = lz
        total += lx * lx + ly * ly + lz * lz
    return total


@njit(cache=True)
def _combine_row(Dlog, idx_row, coef_row, m, out, tmp):  # type: ignore[no-untyped-def]
    n = out.shape[0]
    for j in range(n):
        out[j, 0] = 1.0
        out[j, 1] = 0.0
        out[j, 2] = 0.0
        out[j, 3] = 0.0
    for s in range(m):
        _power_into(Dlog, idx_row[s], coef_row[s], tmp)
        for j in range(n):
            r = _qmul(
                out[j, 0],
                out[j, 1],
                out[j, 2],
                out[j, 3],
                tmp[j, 0],
                tmp[j, 1],
                tmp[j, 2],
                tmp[j, 3],
            )
            out[j, 0] = r[0]
            out[j, 1] = r[1]
            out[j, 2] = r[2]
            out[j, 3] = r[3]


@njit(cache=True)
def _row_objective(Y_i, Q):  # type: ignore[no-untyped-def]
    total = 0.0
    for j in range(Y_i.shape[0]):
        d = Y_i[j, 0] * Q[j, 0] + Y_i[j, 1] * Q[j, 1] + Y_i[j, 2] * Q[j, 2] + Y_i[j, 3] * Q[j, 3]
        total += 1.0 - min(abs(d), 1.0)
    return total


@njit(parallel=True, cache=True)
def combine(Dlog, idx, coef, count, out):  # type: ignore[no-untyped-def]
    """Quaternion combination of every sample (Eq. 2-3) into ``out`` ``(N, n, 4)``."""
    N = idx.shape[0]
    n = Dlog.shape[1]
    for i in prange(N):
        tmp = np.empty((n, 4))
        _combine_row(Dlog, idx[i], coef[i], count[i], out[i], tmp)


@njit(parallel=True, cache=True)
def residual_logs(Y, Dlog, idx, coef, count, left, out):  # type: ignore[no-untyped-def]
    """Shortest-arc logs of the residuals into ``out`` ``(N, n, 3)``.

    ``left``: ``R = C^-1 Y`` (what remains to the right of the combination ``C``, where the next,
    smaller atom goes). Otherwise ``R = Y C^-1``, Algorithm 2 line 8 as printed.
    """
    N = idx.shape[0]
    n = Dlog.shape[1]
    for i in prange(N):
        C = np.empty((n, 4))
        tmp = np.empty((n, 4))
        _combine_row(Dlog, idx[i], coef[i], count[i], C, tmp)
        for j in range(n):
            if left:
                r = _qmul(
                    C[j, 0],
                    -C[j, 1],
                    -C[j, 2],
                    -C[j, 3],
                    Y[i, j, 0],
                    Y[i, j, 1],
                    Y[i, j, 2],
                    Y[i, j, 3],
                )
            else:
                r = _qmul(
                    Y[i, j, 0],
                    Y[i, j, 1],
                    Y[i, j, 2],
                    Y[i, j, 3],
                    C[j, 0],
                    -C[j, 1],
                    -C[j, 2],
                    -C[j, 3],
                )
            lx, ly, lz = _qlog(r[0], r[1], r[2], r[3])
            out[i, j, 0] = lx
            out[i, j, 1] = ly
            out[i, j, 2] = lz


@njit(parallel=True, cache=True)
def add_atom_and_refit(
    Y,
    Dlog,
    Dnorm,
    Daxis,
    idx,
    coef,
    count,
    new_atom,
    active,
    left,
    n_sweeps,
    solver,
    refit,
    Rlog,
    obj,
):  # type: ignore[no-untyped-def]
    """One step of Algorithm 2 for every active sample.

    ``Rlog`` ``(N, n, 3)`` holds each sample's residual log on entry (``C^-1 Y`` if ``left``,
    else ``Y C^-1``) and the updated one on exit. Appends ``new_atom[i]`` with its Eq. 6
    weight against the residual; if ``refit``, refits all weights (``solver``: 0 coordinate
    descent with plain Eq. 6, 1 with weighted Eq. 6, 2 joint Gauss-Newton with order swaps;
    ``n_sweeps`` sweeps or steps). Slots stay sorted by magnitude. ``obj[i]`` receives
    ``sum_j 1 - |<Y_j, C_j>|``, which equals ``sum_j 1 - |w(R_j)|`` for either residual.
    When the new atom lands last and nothing is refit, the left residual is updated with one
    product per joint instead of recomputing the whole combination.
    """
    N = idx.shape[0]
    n = Dlog.shape[1]
    L = idx.shape[1]
    for i in prange(N):
        if not active[i]:
            continue
        m = count[i]
        R = np.empty((n, 4))
        for j in range(n):
            w, x_, y_, z_ = _qexp(Rlog[i, j, 0], Rlog[i, j, 1], Rlog[i, j, 2])
            R[j, 0] = w
            R[j, 1] = x_
            R[j, 2] = y_
            R[j, 3] = z_
        k = new_atom[i]
        x = _solve_coef(R, Dnorm, Daxis, k, solver >= 1)
        idx[i, m] = k
        coef[i, m] = x
        m += 1
        count[i] = m
        # Between refits the slots stay in selection order (the greedy order the paper assumes
        # descending), so the left residual advances by one product; the refit sorts them.
        moved = _sort_slots(idx[i], coef[i], m) if (refit or not left) else False
        recompute = True
        tmp = np.empty((n, 4))
        if refit:
            A = np.empty((L, n, 4))
            suf = np.empty((L + 1, n, 4))
            if solver == 2:
                Wmat = np.empty((L, 3 * n))
                _refit_with_swaps(Y[i], Dlog, idx[i], coef[i], m, n_sweeps, A, suf, Wmat)
            else:
                _bcd(
                    Y[i],
                    Dlog,
                    Dnorm,
                    Daxis,
                    idx[i],
                    coef[i],
                    m,
                    n_sweeps,
                    solver == 1,
                    A,
                    suf,
                    R,
                    tmp,
                )
        elif left and not moved:
            _power_into(Dlog, k, x, tmp)
            for j in range(n):
                r = _qmul(
                    tmp[j, 0],
                    -tmp[j, 1],
                    -tmp[j, 2],
                    -tmp[j, 3],
                    R[j, 0],
                    R[j, 1],
                    R[j, 2],
                    R[j, 3],
                )
                R[j, 0] = r[0]
                R[j, 1] = r[1]
                R[j, 2] = r[2]
                R[j, 3] = r[3]
            recompute = False
        if recompute:
            C = np.empty((n, 4))
            _combine_row(Dlog, idx[i], coef[i], m, C, tmp)
            for j in range(n):
                if left:
                    r = _qmul(
                        C[j, 0],
                        -C[j, 1],
                        -C[j, 2],
                        -C[j, 3],
                        Y[i, j, 0],
                        Y[i, j, 1],
                        Y[i, j, 2],
                        Y[i, j, 3],
                    )
                else:
                    r = _qmul(
                        Y[i, j, 0],
                        Y[i, j, 1],
                        Y[i, j, 2],
                        Y[i, j, 3],
                        C[j, 0],
                        -C[j, 1],
                        -C[j, 2],
                        -C[j, 3],
                    )
                R[j, 0] = r[0]
                R[j, 1] = r[1]
                R[j, 2] = r[2]
                R[j, 3] = r[3]
        total = 0.0
        for j in range(n):
            lx, ly, lz = _qlog(R[j, 0], R[j, 1], R[j, 2], R[j, 3])
            Rlog[i, j, 0] = lx
            Rlog[i, j, 1] = ly
            Rlog[i, j, 2] = lz
            total += 1.0 - min(abs(R[j, 0]), 1.0)
        obj[i] = total


@njit(parallel=True, cache=True)
def slot_powers(Dlog, idx, coef, count, A):  # type: ignore[no-untyped-def]
    """``A[i, s] = atom(idx[i, s]) ** coef[i, s]`` for the used slots: ``(N, L, n, 4)``."""
    N = idx.shape[0]
    for i in prange(N):
        for s in range(count[i]):
            _power_into(Dlog, idx[i, s], coef[i, s], A[i, s])


@njit(parallel=True, cache=True)
def atom_residual_logs(Y, A, count, samples, positions, out):  # type: ignore[no-untyped-def]
    """Algorithm 3 line 5 for one atom: ``ln E`` with ``E = P^-1 Y S^-1`` into ``(M, n, 3)``.

    ``P`` is the product of the slots left of ``positions[r]`` (larger weights) and ``S`` of
    the slots right of it, for sample ``samples[r]``.
    """
    M = samples.shape[0]
    n = Y.shape[1]
    for r in prange(M):
        i = samples[r]
        p = positions[r]
        m = count[i]
        for j in range(n):
            lw, lx, ly, lz = Y[i, j, 0], Y[i, j, 1], Y[i, j, 2], Y[i, j, 3]
            for s in range(p - 1, -1, -1):
                lw, lx, ly, lz = _qmul(
                    A[i, s, j, 0], -A[i, s, j, 1], -A[i, s, j, 2], -A[i, s, j, 3], lw, lx, ly, lz
                )
            for s in range(m - 1, p, -1):
                lw, lx, ly, lz = _qmul(
                    lw, lx, ly, lz, A[i, s, j, 0], -A[i, s, j, 1], -A[i, s, j, 2], -A[i, s, j, 3]
                )
            ex, ey, ez = _qlog(lw, lx, ly, lz)
            out[r, j, 0] = ex
            out[r, j, 1] = ey
            out[r, j, 2] = ez


@njit(parallel=True, cache=True)
def candidate_objective(
    Y, Dlog, A, idx, coef, count, samples, positions, atom_log, new_weights, out
):  # type: ignore[no-untyped-def]
    """Objective of each sample in ``samples`` if its slot ``positions[r]`` became
    ``exp(new_weights[r] * atom_log)``, with the slots re-sorted by magnitude (Eq. 2 order)."""
    M = samples.shape[0]
    n = Y.shape[1]
    L = idx.shape[1]
    for r in prange(M):
        i = samples[r]
        p = positions[r]
        m = count[i]
        order_idx = np.empty(L, dtype=np.int64)
        order_coef = np.empty(L)
        for s in range(m):
            order_idx[s] = s
            order_coef[s] = coef[i, s]
        order_coef[p] = new_weights[r]
        _sort_slots(order_idx, order_coef, m)
        P = np.empty((n, 4))
        for j in range(n):
            P[j, 0] = 1.0
            P[j, 1] = 0.0
            P[j, 2] = 0.0
            P[j, 3] = 0.0
        for t in range(m):
            s = order_idx[t]
            for j in range(n):
                if s == p:
                    x = new_weights[r]
                    bw, bx, by, bz = _qexp(
                        x * atom_log[j, 0], x * atom_log[j, 1], x * atom_log[j, 2]
                    )
                else:
                    bw, bx, by, bz = A[i, s, j, 0], A[i, s, j, 1], A[i, s, j, 2], A[i, s, j, 3]
                q = _qmul(P[j, 0], P[j, 1], P[j, 2], P[j, 3], bw, bx, by, bz)
                P[j, 0] = q[0]
                P[j, 1] = q[1]
                P[j, 2] = q[2]
                P[j, 3] = q[3]
        out[r] = _row_objective(Y[i], P)


@njit(parallel=True, cache=True)
def commit_atom(Dlog, A, idx, coef, count, samples, positions, k, new_weights):  # type: ignore[no-untyped-def]
    """Write the accepted weights of atom ``k`` (already in ``Dlog[k]``), re-sort the slots of
    the touched samples and refresh their cached powers."""
    M = samples.shape[0]
    for r in prange(M):
        i = samples[r]
        coef[i, positions[r]] = new_weights[r]
        if _sort_slots(idx[i], coef[i], count[i]):
            for s in range(count[i]):
                _power_into(Dlog, idx[i, s], coef[i, s], A[i, s])
        else:
            _power_into(Dlog, k, new_weights[r], A[i, positions[r]])


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
                # Solve Lc[:m, :m] w = G[sel, best].
                for r in range(m):
                    acc = G[sel[r], best]
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
            for r in range(m - 1, -1, -1):
                acc = z[r]
                for t in range(r + 1, m):
                    acc -= Lc[t, r] * c[t]
                c[r] = acc / Lc[r, r]
            for k in range(K):
                acc = Xy[i, k]
                for t in range(m):
                    acc -= G[k, sel[t]] * c[t]
                alpha[k] = acc
        for t in range(m):
            idx[i, t] = sel[t]
            coef[i, t] = c[t]
        count[i] = m
        _sort_slots(idx[i], coef[i], m)


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
