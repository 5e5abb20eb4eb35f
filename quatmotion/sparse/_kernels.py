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
independent in both sparse coding and the residual computation of one atom. Kernels that need
scratch buffers take the samples in chunks of ``_CHUNK`` and allocate once per chunk.

Where the time goes, and what keeps it down (the Gauss-Newton refit of the last coding step is
about half of an iteration, the residual logs of the dictionary update most of the rest):

* a residual evaluation forms each power ``(cos(x a), sin(x a) u)`` from the precomputed half
  angles and axes and multiplies it straight into the suffix products; the powers are kept so
  that a re-sort or a swapped-order trial reuses them without ``sin``/``cos``;
* the solver's trial steps go to a second set of buffers (no re-evaluation on rejection), and
  the last combination and residual log become the sample's residual without recomputation;
* the residual quaternions are carried beside their logs between coding steps (no ``exp``);
* logs use ``2 atan(|v| / (1 + w))`` instead of ``atan2(|v|, w)`` (twice as cheap in libm);
* the dictionary update moves cached powers when slots re-sort instead of recomputing them,
  reads each cached power as one contiguous block, and gets the final objective from them.

The results are those of the straightforward formulation up to rounding (the objective of a
coding pass agrees to about 1e-10 relative), except for ``GN_STEP_TOL``, which skips refit
steps whose predicted gain is below 1e-10 of the residual.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

_EPS = 1e-12
# Samples per work unit of the parallel kernels that need scratch buffers: the buffers are
# allocated once per unit instead of once per sample.
_CHUNK = 16


@njit(inline="always", cache=True)
def _qmul(aw, ax, ay, az, bw, bx, by, bz):  # type: ignore[no-untyped-def]
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@njit(inline="always", cache=True)
def _residual(c, y, left):  # type: ignore[no-untyped-def]
    """One joint's residual of sample ``y`` against its combination ``c``: ``c^-1 y`` if
    ``left`` (what the next, smaller atom must explain), else ``y c^-1`` (as printed)."""
    if left:
        return _qmul(c[0], -c[1], -c[2], -c[3], y[0], y[1], y[2], y[3])
    return _qmul(y[0], y[1], y[2], y[3], c[0], -c[1], -c[2], -c[3])


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
    # atan2(vn, w) = 2 atan(vn / (1 + w)) on the unit sphere with w >= 0; libm's atan2 costs
    # more than twice atan, and this log is in every kernel's inner loop.
    s = 1.0 / max(w, 1e-300) if vn < 1e-12 else 2.0 * math.atan(vn / (1.0 + w)) / vn
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
def _sort_slots_with_powers(idx_row, coef_row, A_i, m):  # type: ignore[no-untyped-def]
    """:func:`_sort_slots` that moves the cached powers ``A_i`` ``(L, n, 4)`` along."""
    n = A_i.shape[1]
    moved = False
    for s in range(1, m):
        ci = coef_row[s]
        ii = idx_row[s]
        t = s - 1
        if not abs(coef_row[t]) < abs(ci):
            continue
        moved = True
        saved = A_i[s].copy()
        while t >= 0 and abs(coef_row[t]) < abs(ci):
            coef_row[t + 1] = coef_row[t]
            idx_row[t + 1] = idx_row[t]
            for j in range(n):
                A_i[t + 1, j, 0] = A_i[t, j, 0]
                A_i[t + 1, j, 1] = A_i[t, j, 1]
                A_i[t + 1, j, 2] = A_i[t, j, 2]
                A_i[t + 1, j, 3] = A_i[t, j, 3]
            t -= 1
        coef_row[t + 1] = ci
        idx_row[t + 1] = ii
        A_i[t + 1] = saved
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
        rho = math.sqrt(w * w + p * p)
        # atan2(p, w) for w >= 0, by the half-angle identity (cheaper than libm's atan2).
        b = 2.0 * math.atan(p / (rho + w)) if rho > 0.0 else 0.0
        if not weighted:
            rho = 1.0
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


# Relative size of the predicted Gauss-Newton decrease of |r|^2 below which a refit stops:
# the remaining steps could only change the objective in its tenth significant digit, and each
# costs a full residual evaluation.
GN_STEP_TOL = 1e-10
# Relative gap between adjacent weight magnitudes below which the swapped order is tried.
SWAP_GAP = 0.05


@njit(inline="always", cache=True)
def _rotate_by_conj(sw, sx, sy, sz, vx, vy, vz):  # type: ignore[no-untyped-def]
    """``S^* v S`` for unit ``S`` and the pure quaternion ``v`` (a rotation by ``S^*``)."""
    # v' = v + w t + u x t, t = 2 u x v, with (w, u) = S^* = (sw, -sx, -sy, -sz).
    ux, uy, uz = -sx, -sy, -sz
    tx = 2.0 * (uy * vz - uz * vy)
    ty = 2.0 * (uz * vx - ux * vz)
    tz = 2.0 * (ux * vy - uy * vx)
    return (
        vx + sw * tx + (uy * tz - uz * ty),
        vy + sw * ty + (uz * tx - ux * tz),
        vz + sw * tz + (ux * ty - uy * tx),
    )


@njit(cache=True)
def _gn_eval(Y_i, Dnorm, Daxis, idx_row, coef, m, Apow, suf, r):  # type: ignore[no-untyped-def]
    """``suf[s] = A_s .. A_{m-1}`` for weights ``coef``, ``r = ln(suf[0]^-1 Y)``; ``|r|^2``.

    One pass per joint: each power ``A_s = (cos(x a), sin(x a) u)`` (half angle ``a``, unit
    axis ``u`` precomputed) is formed, kept in ``Apow`` (a re-ordering of the same weights
    then needs no ``sin``/``cos``, :func:`_gn_eval_powers`) and multiplied into the suffix.
    """
    n = Y_i.shape[0]
    total = 0.0
    for j in range(n):
        pw, px, py, pz = 1.0, 0.0, 0.0, 0.0
        suf[m, j, 0] = 1.0
        suf[m, j, 1] = 0.0
        suf[m, j, 2] = 0.0
        suf[m, j, 3] = 0.0
        for s in range(m - 1, -1, -1):
            k = idx_row[s]
            angle = coef[s] * Dnorm[k, j]
            c = math.cos(angle)
            sn = math.sin(angle)
            ax, ay, az = sn * Daxis[k, j, 0], sn * Daxis[k, j, 1], sn * Daxis[k, j, 2]
            Apow[s, j, 0] = c
            Apow[s, j, 1] = ax
            Apow[s, j, 2] = ay
            Apow[s, j, 3] = az
            pw, px, py, pz = _qmul(c, ax, ay, az, pw, px, py, pz)
            suf[s, j, 0] = pw
            suf[s, j, 1] = px
            suf[s, j, 2] = py
            suf[s, j, 3] = pz
        q = _qmul(pw, -px, -py, -pz, Y_i[j, 0], Y_i[j, 1], Y_i[j, 2], Y_i[j, 3])
        lx, ly, lz = _qlog(q[0], q[1], q[2], q[3])
        r[3 * j] = lx
        r[3 * j + 1] = ly
        r[3 * j + 2] = lz
        total += lx * lx + ly * ly + lz * lz
    return total


@njit(cache=True)
def _gn_eval_powers(Y_i, Apow, m, suf, r):  # type: ignore[no-untyped-def]
    """:func:`_gn_eval` from the powers ``Apow`` ``(m, n, 4)`` already formed."""
    n = Y_i.shape[0]
    total = 0.0
    for j in range(n):
        pw, px, py, pz = 1.0, 0.0, 0.0, 0.0
        suf[m, j, 0] = 1.0
        suf[m, j, 1] = 0.0
        suf[m, j, 2] = 0.0
        suf[m, j, 3] = 0.0
        for s in range(m - 1, -1, -1):
            pw, px, py, pz = _qmul(
                Apow[s, j, 0], Apow[s, j, 1], Apow[s, j, 2], Apow[s, j, 3], pw, px, py, pz
            )
            suf[s, j, 0] = pw
            suf[s, j, 1] = px
            suf[s, j, 2] = py
            suf[s, j, 3] = pz
        q = _qmul(pw, -px, -py, -pz, Y_i[j, 0], Y_i[j, 1], Y_i[j, 2], Y_i[j, 3])
        lx, ly, lz = _qlog(q[0], q[1], q[2], q[3])
        r[3 * j] = lx
        r[3 * j + 1] = ly
        r[3 * j + 2] = lz
        total += lx * lx + ly * ly + lz * lz
    return total


@njit(cache=True, fastmath={"reassoc", "contract"})
def _normal_equations(Wmat, r, G, g, m):  # type: ignore[no-untyped-def]
    """``G = W W^T``, ``g = W r`` for the first ``m`` rows of ``Wmat``; returns ``trace(G)``.

    Reassociation lets LLVM vectorise the ``3n``-long dot products (they were a chain of
    dependent additions, as long as a residual evaluation); only the summation order changes.
    """
    n3 = Wmat.shape[1]
    trace = 0.0
    for a in range(m):
        acc = 0.0
        for t in range(n3):
            acc += Wmat[a, t] * r[t]
        g[a] = acc
        for b in range(a + 1):
            acc = 0.0
            for t in range(n3):
                acc += Wmat[a, t] * Wmat[b, t]
            G[a, b] = acc
            G[b, a] = acc
        trace += G[a, a]
    return trace


@njit(cache=True)
def _gauss_newton(  # type: ignore[no-untyped-def]
    Y_i,
    Dlog,
    Dnorm,
    Daxis,
    idx_row,
    coef_row,
    m,
    n_iter,
    ws,
    keep_sorted,
    from_powers,
    C_out,
    r_out,
    P_out,
):
    """Joint Gauss-Newton refinement of the ``m`` weights of one sample, order kept sorted.

    With ``Yhat = A_0 .. A_{m-1}`` and the residual ``r = ln(Yhat^-1 Y)`` (``3n``-vector), moving
    weight ``s`` by ``delta`` right-multiplies ``Yhat`` by ``exp(delta w_s)``, where
    ``w_s = S^-1 v_s S`` is the atom log ``v_s`` rotated by the suffix ``S = A_{s+1} .. A_{m-1}``.
    So ``r(x + delta) ~ r - W delta`` and one step solves the ``m x m`` normal equations
    ``W^T W delta = W^T r``. Exact data are a zero-residual problem, where Gauss-Newton
    converges quadratically; coordinate descent (Algorithm 2's solver) only linearly and slowly
    when the atoms are far from commuting. A step that does not lower ``|r|`` is halved (up to
    twice) and dropped if it still does not; the refit stops when the predicted decrease
    ``g . delta`` is below ``GN_STEP_TOL`` times ``|r|^2``. A re-sort after a step reuses the
    powers (only their order changed); with ``from_powers`` the caller has put the powers of
    ``coef_row`` in ``ws[9]`` already.

    Trial weights are evaluated into a second set of buffers (``ws``), swapped in on acceptance,
    so a rejected step costs no re-evaluation. On exit ``C_out`` ``(n, 4)`` holds the
    combination of the returned weights, ``r_out`` ``(3n,)`` its residual log and ``P_out``
    ``(L, n, 4)`` the powers of its slots; returns ``|r|^2``.
    """
    n = Y_i.shape[0]
    suf, suf2, r, r2, Wmat, G, g, delta, trial, Apow, Apow2 = ws
    if from_powers:
        current = _gn_eval_powers(Y_i, Apow, m, suf, r)
    else:
        current = _gn_eval(Y_i, Dnorm, Daxis, idx_row, coef_row, m, Apow, suf, r)
    for _ in range(n_iter):
        if current < 1e-28:
            break
        # Columns w_s: rotate v_s by conj(suf[s + 1]), i.e. S^* v S.
        for s in range(m):
            k = idx_row[s]
            for j in range(n):
                wx, wy, wz = _rotate_by_conj(
                    suf[s + 1, j, 0],
                    suf[s + 1, j, 1],
                    suf[s + 1, j, 2],
                    suf[s + 1, j, 3],
                    Dlog[k, j, 0],
                    Dlog[k, j, 1],
                    Dlog[k, j, 2],
                )
                Wmat[s, 3 * j] = wx
                Wmat[s, 3 * j + 1] = wy
                Wmat[s, 3 * j + 2] = wz
        trace = _normal_equations(Wmat, r, G, g, m)
        ridge = 1e-12 * trace + 1e-300
        for a in range(m):
            G[a, a] += ridge
        if not _cholesky_solve(G, g, delta, m):
            break
        predicted = 0.0
        for a in range(m):
            predicted += g[a] * delta[a]
        if predicted <= GN_STEP_TOL * current:
            break
        step = 1.0
        accepted = False
        value = current
        for _half in range(3):
            for s in range(m):
                trial[s] = coef_row[s] + step * delta[s]
            value = _gn_eval(Y_i, Dnorm, Daxis, idx_row, trial, m, Apow2, suf2, r2)
            if value < current:
                accepted = True
                break
            step *= 0.5
        if not accepted:
            break
        for s in range(m):
            coef_row[s] = trial[s]
        suf, suf2 = suf2, suf
        r, r2 = r2, r
        Apow, Apow2 = Apow2, Apow
        current = value
        if keep_sorted and _sort_slots_with_powers(idx_row, coef_row, Apow, m):
            current = _gn_eval_powers(Y_i, Apow, m, suf, r)
    for j in range(n):
        C_out[j, 0] = suf[0, j, 0]
        C_out[j, 1] = suf[0, j, 1]
        C_out[j, 2] = suf[0, j, 2]
        C_out[j, 3] = suf[0, j, 3]
    for t in range(3 * n):
        r_out[t] = r[t]
    P_out[:m] = Apow[:m]
    return current


@njit(cache=True)
def _refit_with_swaps(  # type: ignore[no-untyped-def]
    Y_i,
    Dlog,
    Dnorm,
    Daxis,
    idx_row,
    coef_row,
    m,
    n_iter,
    signal,
    ws,
    C_best,
    r_best,
    C_trial,
    r_trial,
    trial_idx,
    trial_coef,
    P_best,
    P_trial,
):
    """Gauss-Newton, then try the other order of every adjacent pair of near-tied weights.

    The combination order follows the weights, so where two magnitudes are close the fit can
    settle in the wrong order: refitting in that order would swap them, and re-sorting swaps
    them back. For each such pair the swapped order is refit with the order held fixed and
    kept if the result is consistent (still sorted) and fits better. ``signal`` is ``|ln Y|^2``
    of the sample. On exit ``C_best``/``r_best`` hold the combination and residual log of the
    returned weights (see :func:`_gauss_newton`).
    """
    best = _gauss_newton(
        Y_i,
        Dlog,
        Dnorm,
        Daxis,
        idx_row,
        coef_row,
        m,
        n_iter,
        ws,
        True,
        False,
        C_best,
        r_best,
        P_best,
    )
    if m < 2 or best < 1e-28:
        return best
    # Only a fit that is still poor can be an order problem; a good one is left alone.
    if best < 1e-6 * signal:
        return best
    # The two closest pairs at most (relative gap <= 0.05): each trial is a full refit.
    first = -1
    second = -1
    gap_first = np.inf
    gap_second = np.inf
    for s in range(m - 1):
        a = abs(coef_row[s])
        gap = (a - abs(coef_row[s + 1])) / max(a, 1e-300)
        if gap < gap_first:
            second, gap_second = first, gap_first
            first, gap_first = s, gap
        elif gap < gap_second:
            second, gap_second = s, gap
    for c in range(2):
        s = first if c == 0 else second
        gap = gap_first if c == 0 else gap_second
        if s < 0 or gap > SWAP_GAP:
            continue
        for t in range(m):
            trial_idx[t] = idx_row[t]
            trial_coef[t] = coef_row[t]
        trial_idx[s], trial_idx[s + 1] = idx_row[s + 1], idx_row[s]
        trial_coef[s], trial_coef[s + 1] = coef_row[s + 1], coef_row[s]
        # The swapped order starts from the same powers, swapped: no sin/cos to redo.
        Apow = ws[9]
        Apow[:m] = P_best[:m]
        Apow[s] = P_best[s + 1]
        Apow[s + 1] = P_best[s]
        value = _gauss_newton(
            Y_i,
            Dlog,
            Dnorm,
            Daxis,
            trial_idx,
            trial_coef,
            m,
            min(n_iter, 2),
            ws,
            False,
            True,
            C_trial,
            r_trial,
            P_trial,
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
            C_best[:, :] = C_trial
            r_best[:] = r_trial
            P_best[:m] = P_trial[:m]
    return best


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
            r = _residual(C[j], Y[i, j], left)
            lx, ly, lz = _qlog(r[0], r[1], r[2], r[3])
            out[i, j, 0] = lx
            out[i, j, 1] = ly
            out[i, j, 2] = lz


@njit(cache=True)
def _power_axis_into(Dnorm, Daxis, k, x, out):  # type: ignore[no-untyped-def]
    """``atom_k ** x`` per joint as ``(cos(x a), sin(x a) u)`` ``(n, 4)``."""
    for j in range(Dnorm.shape[1]):
        angle = x * Dnorm[k, j]
        sn = math.sin(angle)
        out[j, 0] = math.cos(angle)
        out[j, 1] = sn * Daxis[k, j, 0]
        out[j, 2] = sn * Daxis[k, j, 1]
        out[j, 3] = sn * Daxis[k, j, 2]


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
    signal,
    Rq,
    Rlog,
    obj,
):  # type: ignore[no-untyped-def]
    """One step of Algorithm 2 for every active sample.

    ``Rq`` ``(N, n, 4)`` and ``Rlog`` ``(N, n, 3)`` hold each sample's residual (``C^-1 Y`` if
    ``left``, else ``Y C^-1``) and its log on entry, the updated ones on exit. Appends
    ``new_atom[i]`` with its Eq. 6 weight against the residual; if ``refit``, refits all
    weights (``solver``: 0 coordinate descent with plain Eq. 6, 1 with weighted Eq. 6, 2 joint
    Gauss-Newton with order swaps; ``n_sweeps`` sweeps or steps). ``signal`` ``(N,)`` is
    ``|ln Y_i|^2`` (used by the order swaps). Slots stay sorted by magnitude. ``obj[i]``
    receives ``sum_j 1 - |<Y_j, C_j>|``, which equals ``sum_j 1 - |w(R_j)|`` for either residual.
    When the new atom lands last and nothing is refit, the left residual is updated with one
    product per joint instead of recomputing the whole combination; after a Gauss-Newton refit
    the solver's last combination and residual log are reused.
    """
    N = idx.shape[0]
    n = Dlog.shape[1]
    L = idx.shape[1]
    n_chunks = (N + _CHUNK - 1) // _CHUNK
    for c in prange(n_chunks):
        R = np.empty((n, 4))
        tmp = np.empty((n, 4))
        C = np.empty((n, 4))
        A = np.empty((L, n, 4))
        suf = np.empty((L + 1, n, 4))
        ws = (
            suf,
            np.empty((L + 1, n, 4)),
            np.empty(3 * n),
            np.empty(3 * n),
            np.empty((L, 3 * n)),
            np.empty((L, L)),
            np.empty(L),
            np.empty(L),
            np.empty(L),
            np.empty((L, n, 4)),
            np.empty((L, n, 4)),
        )
        r_best = np.empty(3 * n)
        C_trial = np.empty((n, 4))
        r_trial = np.empty(3 * n)
        trial_idx = np.empty(L, dtype=idx.dtype)
        trial_coef = np.empty(L)
        P_best = np.empty((L, n, 4))
        P_trial = np.empty((L, n, 4))
        for i in range(c * _CHUNK, min(N, (c + 1) * _CHUNK)):
            if not active[i]:
                continue
            m = count[i]
            for j in range(n):
                R[j, 0] = Rq[i, j, 0]
                R[j, 1] = Rq[i, j, 1]
                R[j, 2] = Rq[i, j, 2]
                R[j, 3] = Rq[i, j, 3]
            k = new_atom[i]
            x = _solve_coef(R, Dnorm, Daxis, k, solver >= 1)
            idx[i, m] = k
            coef[i, m] = x
            m += 1
            count[i] = m
            # Between refits the slots stay in selection order (the greedy order the paper
            # assumes descending), so the left residual advances by one product; the refit
            # sorts them.
            moved = _sort_slots(idx[i], coef[i], m) if (refit or not left) else False
            recompute = True
            have_combination = False
            if refit:
                if solver == 2:
                    _refit_with_swaps(
                        Y[i],
                        Dlog,
                        Dnorm,
                        Daxis,
                        idx[i],
                        coef[i],
                        m,
                        n_sweeps,
                        signal[i],
                        ws,
                        C,
                        r_best,
                        C_trial,
                        r_trial,
                        trial_idx,
                        trial_coef,
                        P_best,
                        P_trial,
                    )
                    if left:
                        # r_best = ln(C^-1 Y) is the left residual's log already.
                        total = 0.0
                        for j in range(n):
                            Rlog[i, j, 0] = r_best[3 * j]
                            Rlog[i, j, 1] = r_best[3 * j + 1]
                            Rlog[i, j, 2] = r_best[3 * j + 2]
                            d = (
                                C[j, 0] * Y[i, j, 0]
                                + C[j, 1] * Y[i, j, 1]
                                + C[j, 2] * Y[i, j, 2]
                                + C[j, 3] * Y[i, j, 3]
                            )
                            total += 1.0 - min(abs(d), 1.0)
                            q = _qmul(
                                C[j, 0],
                                -C[j, 1],
                                -C[j, 2],
                                -C[j, 3],
                                Y[i, j, 0],
                                Y[i, j, 1],
                                Y[i, j, 2],
                                Y[i, j, 3],
                            )
                            Rq[i, j, 0] = q[0]
                            Rq[i, j, 1] = q[1]
                            Rq[i, j, 2] = q[2]
                            Rq[i, j, 3] = q[3]
                        obj[i] = total
                        continue
                    have_combination = True  # C holds the combination
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
                _power_axis_into(Dnorm, Daxis, k, x, tmp)
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
                if not have_combination:
                    _combine_row(Dlog, idx[i], coef[i], m, C, tmp)
                for j in range(n):
                    r = _residual(C[j], Y[i, j], left)
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
                Rq[i, j, 0] = R[j, 0]
                Rq[i, j, 1] = R[j, 1]
                Rq[i, j, 2] = R[j, 2]
                Rq[i, j, 3] = R[j, 3]
                total += 1.0 - min(abs(R[j, 0]), 1.0)
            obj[i] = total


@njit(parallel=True, cache=True)
def objective_from_powers(Y, A, count, out):  # type: ignore[no-untyped-def]
    """Per-sample objective ``sum_j 1 - |<Y_j, C_j>|`` ``(N,)`` from cached slot powers ``A``
    ``(N, L, n, 4)`` (:func:`slot_powers`): the combination without any ``exp``."""
    N = Y.shape[0]
    n = Y.shape[1]
    for i in prange(N):
        total = 0.0
        for j in range(n):
            pw, px, py, pz = 1.0, 0.0, 0.0, 0.0
            for s in range(count[i]):
                pw, px, py, pz = _qmul(
                    pw, px, py, pz, A[i, s, j, 0], A[i, s, j, 1], A[i, s, j, 2], A[i, s, j, 3]
                )
            d = Y[i, j, 0] * pw + Y[i, j, 1] * px + Y[i, j, 2] * py + Y[i, j, 3] * pz
            total += 1.0 - min(abs(d), 1.0)
        out[i] = total


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
    the slots right of it, for sample ``samples[r]``. Slot by slot over all joints, so each
    cached power ``A[i, s]`` is read as one contiguous block.
    """
    M = samples.shape[0]
    n = Y.shape[1]
    n_chunks = (M + _CHUNK - 1) // _CHUNK
    for c in prange(n_chunks):
        E = np.empty((n, 4))
        for r in range(c * _CHUNK, min(M, (c + 1) * _CHUNK)):
            i = samples[r]
            p = positions[r]
            m = count[i]
            for j in range(n):
                E[j, 0] = Y[i, j, 0]
                E[j, 1] = Y[i, j, 1]
                E[j, 2] = Y[i, j, 2]
                E[j, 3] = Y[i, j, 3]
            for s in range(p - 1, -1, -1):
                As = A[i, s]
                for j in range(n):
                    q = _qmul(
                        As[j, 0],
                        -As[j, 1],
                        -As[j, 2],
                        -As[j, 3],
                        E[j, 0],
                        E[j, 1],
                        E[j, 2],
                        E[j, 3],
                    )
                    E[j, 0] = q[0]
                    E[j, 1] = q[1]
                    E[j, 2] = q[2]
                    E[j, 3] = q[3]
            for s in range(m - 1, p, -1):
                As = A[i, s]
                for j in range(n):
                    q = _qmul(
                        E[j, 0],
                        E[j, 1],
                        E[j, 2],
                        E[j, 3],
                        As[j, 0],
                        -As[j, 1],
                        -As[j, 2],
                        -As[j, 3],
                    )
                    E[j, 0] = q[0]
                    E[j, 1] = q[1]
                    E[j, 2] = q[2]
                    E[j, 3] = q[3]
            for j in range(n):
                ex, ey, ez = _qlog(E[j, 0], E[j, 1], E[j, 2], E[j, 3])
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
    """Write the accepted weights of atom ``k`` (already in ``Dlog[k]``), refresh the cached
    power of its slot and re-sort the slots of the touched samples (powers move along)."""
    M = samples.shape[0]
    for r in prange(M):
        i = samples[r]
        p = positions[r]
        coef[i, p] = new_weights[r]
        _power_into(Dlog, k, new_weights[r], A[i, p])
        _sort_slots_with_powers(idx[i], coef[i], A[i], count[i])


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
