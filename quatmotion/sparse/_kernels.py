"""Numba kernels for QSSD: batched quaternion combination, sparse coding and atom residuals.

Conventions shared by every kernel (the estimator in :mod:`quatmotion.sparse.qssd` owns the
validation and the layout changes; these functions trust their inputs):

* **Structure of arrays.** A sample's ``n`` quaternions are stored as ``(4, n)`` (w, x, y, z,
  each a contiguous run over the joints) and logs as ``(3, n)``; a flattened log is
  component-major (``3n``, all x first). ``YT`` is ``(N, 4, n)`` unit quaternions with
  ``w >= 0``. Every per-joint loop then walks contiguous memory with no dependence between
  joints, so LLVM vectorises it (4 or 8 joints per instruction): the quaternion products, the
  sines and cosines and the arctangents of all joints of one slot advance together.
* A dictionary is stored by its logarithms ``DlogT`` ``(K, 3, n)``: atom ``k`` joint ``j`` is
  ``exp(DlogT[k, :, j])`` and ``atom ** x = exp(x * log)``. ``Dnorm`` ``(K, n)`` holds the
  per-joint half angles and ``DaxisT`` ``(K, 3, n)`` the unit axes (zero where the half angle
  is zero), so ``atom ** x = (cos(x a), sin(x a) u)``.
* A sparse code is stored per sample as slots in combination order: ``idx`` ``(N, L)`` atom
  indices, ``coef`` ``(N, L)`` weights, ``count`` ``(N,)`` the number of used slots. The
  combination (paper Eq. 2) is ``A_0 A_1 ... A_{m-1}`` with ``A_s = atom(idx_s) ** coef_s``, the
  slots sorted by descending ``|coef|``.
* The objective of a sample is ``sum_j 1 - |<Y_j, Yhat_j>|`` (paper Eq. 4 turned into a
  minimisation, with the absolute value because ``q`` and ``-q`` are the same rotation).

Every kernel that walks over samples runs them in parallel with ``prange``: samples are
independent in both sparse coding and the residual computation of one atom. Kernels that need
scratch buffers take the samples in chunks of ``_CHUNK`` and allocate once per chunk.

What keeps the time down, besides the layout:

* sine, cosine and arctangent are branch-free polynomials (:func:`_sincos`,
  :func:`_atan_ratio`) that vectorise, where libm's are scalar calls that do not;
* a residual evaluation forms each power and multiplies it straight into the suffix products;
  the powers are kept so that a re-sort or a swapped-order trial reuses them;
* the solver's trial steps go to a second set of buffers (no re-evaluation on rejection), and
  the last combination and residual log become the sample's residual without recomputation;
* the residual quaternions are carried beside their logs between coding steps (no ``exp``);
* the dictionary update forms the powers afresh for each atom's residuals: caching all
  ``N L`` of them made every atom's pass stream them from memory, which was slower;
* loops that update an array in place take it once (:func:`_rmul`): passed as two arguments,
  LLVM's runtime overlap check fails and the scalar loop runs; loops over five or more arrays
  are split in two for the same reason.

Floating-point flags: the functions that use the polynomials allow contraction into fused
multiply-adds only; sums over joints are separate functions that also allow reassociation (so
that they vectorise), which changes only the order of the additions.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from quatmotion.quat.jit import multiply as _qmul
from quatmotion.quat.jit import rotate as _rotate

# Samples per work unit of the parallel kernels that need scratch buffers: the buffers are
# allocated once per unit instead of once per sample.
_CHUNK = 16
# No fast-math: contracting a product and a sum into one FMA, or reassociating a sum into
# vector lanes, makes the results depend on the processor (its FMA unit, its vector width),
# and these results are compared and ranked (dictionaries, codes, the paper-qssd retrieval
# features, the bytes of a sparse .qmz). The named flags stay so that a kernel says which it
# would take.
_FM = False
_FM_SUM = False

# sin and cos together, written by hand because glibc's are slow scalar calls here, Numba
# calls them one at a time and LLVM cannot vectorise a loop that calls them; they were most of
# the Gauss-Newton refit. Reduction by pi/2 in two parts (Cody-Waite: exact for |x| < 1.6e6,
# beyond which the error is of the order of ulp(x), the precision the argument itself has;
# meaningless past 2^62, where the quadrant overflows), then fdlibm's kernel polynomials on
# [-pi/4, pi/4]; within 2 ulp of libm. No branches: the quadrant is selected with masks.
_PIO2_HI = 1.57079632673412561417e00
_PIO2_LO = 6.07710050650619224932e-11
_TWO_OVER_PI = 0.63661977236758134308
_S1, _S2, _S3 = -1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04
_S4, _S5, _S6 = 2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10
_C1, _C2, _C3 = 4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05
_C4, _C5, _C6 = -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11

# atan on [-0.66, 0.66] (Cephes' rational approximation, relative error about 1e-16), for the
# same reason as _sincos: libm's atan does not vectorise.
_AP0, _AP1, _AP2 = (
    -8.750608600031904122785e-01,
    -1.615753718733365076637e01,
    -7.500855792314704667340e01,
)
_AP3, _AP4 = -1.228866684490136173410e02, -6.485021904942025371773e01
_AQ0, _AQ1, _AQ2 = (
    2.485846490142306297962e01,
    1.650270098316988542046e02,
    4.328810604912902668951e02,
)
_AQ3, _AQ4 = 4.853903996359136964868e02, 1.945506571482613964425e02
_PIO2 = math.pi / 2.0
_PIO4 = math.pi / 4.0


@njit(inline="always", cache=True)
def _sincos(x):  # type: ignore[no-untyped-def]
    """``(sin x, cos x)``."""
    k = np.floor(x * _TWO_OVER_PI + 0.5)
    r = (x - k * _PIO2_HI) - k * _PIO2_LO
    z = r * r
    sp = r + r * z * (_S1 + z * (_S2 + z * (_S3 + z * (_S4 + z * (_S5 + z * _S6)))))
    cp = 1.0 - 0.5 * z + z * z * (_C1 + z * (_C2 + z * (_C3 + z * (_C4 + z * (_C5 + z * _C6)))))
    quadrant = np.int64(k)  # only its last two bits matter
    s = cp if quadrant & 1 else sp
    c = sp if quadrant & 1 else cp
    s = -s if quadrant & 2 else s
    c = -c if (quadrant + 1) & 2 else c
    return s, c


@njit(inline="always", cache=True)
def _atan_ratio(num, den):  # type: ignore[no-untyped-def]
    """``atan2(num, den)`` for ``num, den >= 0``, in ``[0, pi/2]`` (0 when both are 0)."""
    big = num > den
    hi = num if big else den
    lo = den if big else num
    # With t = lo / hi in [0, 1]: atan t directly up to 0.66, else pi/4 + atan((t-1)/(t+1)),
    # whose argument is (lo - hi) / (lo + hi): one division either way.
    mid = lo > 0.66 * hi
    x = (lo - hi if mid else lo) / max(lo + hi if mid else hi, 1e-300)
    z = x * x
    p = (z * ((((_AP0 * z + _AP1) * z + _AP2) * z + _AP3) * z + _AP4)) / (
        ((((z + _AQ0) * z + _AQ1) * z + _AQ2) * z + _AQ3) * z + _AQ4
    )
    a = x + x * p
    a = a + _PIO4 if mid else a
    return _PIO2 - a if big else a


@njit(inline="always", cache=True)
def _qlog(w, x, y, z):  # type: ignore[no-untyped-def]
    """Shortest-arc log (the sign of ``q`` is chosen so that ``w >= 0``)."""
    sign = -1.0 if w < 0.0 else 1.0
    w *= sign
    vn = math.sqrt(x * x + y * y + z * z)
    half_angle = _atan_ratio(vn, w)
    # half_angle / vn, or its limit 1 / w for a (numerically) zero angle: one division.
    tiny = vn < 1e-12
    s = sign * (1.0 if tiny else half_angle) / max(w if tiny else vn, 1e-300)
    return x * s, y * s, z * s


# ----------------------------------------------------------------------------------------------
# Per-joint building blocks: each is one vectorised loop over the n joints of one sample.


@njit(cache=True, fastmath=_FM_SUM, error_model="numpy")
def _sum(v):  # type: ignore[no-untyped-def]
    total = 0.0
    for t in range(v.shape[0]):
        total += v[t]
    return total


@njit(cache=True, fastmath=_FM_SUM, error_model="numpy")
def _sumsq(v):  # type: ignore[no-untyped-def]
    total = 0.0
    for t in range(v.shape[0]):
        total += v[t] * v[t]
    return total


@njit(cache=True, fastmath=_FM_SUM, error_model="numpy")
def _row_objective(YTi, C):  # type: ignore[no-untyped-def]
    """``sum_j 1 - |<Y_j, C_j>|`` for ``(4, n)`` quaternions."""
    total = 0.0
    for j in range(YTi.shape[1]):
        d = YTi[0, j] * C[0, j] + YTi[1, j] * C[1, j] + YTi[2, j] * C[2, j] + YTi[3, j] * C[3, j]
        total += 1.0 - min(abs(d), 1.0)
    return total


@njit(cache=True, fastmath=_FM_SUM, error_model="numpy")
def _residual_objective(R):  # type: ignore[no-untyped-def]
    """``sum_j 1 - |w(R_j)|``: the objective from a residual (left or right alike)."""
    total = 0.0
    for j in range(R.shape[1]):
        total += 1.0 - min(abs(R[0, j]), 1.0)
    return total


@njit(cache=True)
def _copy(src, dst):  # type: ignore[no-untyped-def]
    for c in range(src.shape[0]):
        for j in range(src.shape[1]):
            dst[c, j] = src[c, j]


@njit(cache=True)
def _identity_into(Q):  # type: ignore[no-untyped-def]
    for j in range(Q.shape[1]):
        Q[0, j] = 1.0
        Q[1, j] = 0.0
        Q[2, j] = 0.0
        Q[3, j] = 0.0


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _power_into(dn, da, x, out):  # type: ignore[no-untyped-def]
    """``out`` ``(4, n)`` = ``atom ** x`` from its half angles ``dn`` and unit axes ``da``."""
    for j in range(dn.shape[0]):
        sn, c = _sincos(x * dn[j])
        out[0, j] = c
        out[1, j] = sn * da[0, j]
        out[2, j] = sn * da[1, j]
        out[3, j] = sn * da[2, j]


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _exp_into(v, x, out):  # type: ignore[no-untyped-def]
    """``out`` ``(4, n)`` = ``exp(x v)`` for logs ``v`` ``(3, n)``."""
    for j in range(v.shape[1]):
        a = math.sqrt(v[0, j] * v[0, j] + v[1, j] * v[1, j] + v[2, j] * v[2, j])
        sn, c = _sincos(x * a)
        s = sn / max(a, 1e-300) if a > 0.0 else 0.0
        out[0, j] = c
        out[1, j] = s * v[0, j]
        out[2, j] = s * v[1, j]
        out[3, j] = s * v[2, j]


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _times(a, b, out, conj_a=False, conj_b=False):  # type: ignore[no-untyped-def]
    """``out = a' b'`` per joint, where ``a' = a^-1`` if ``conj_a`` (unit ``a``), else ``a``,
    and likewise ``b'``; ``out`` distinct from both (see :func:`_rmul`)."""
    sa = -1.0 if conj_a else 1.0
    sb = -1.0 if conj_b else 1.0
    for j in range(a.shape[1]):
        w, x, y, z = _qmul(
            a[0, j],
            sa * a[1, j],
            sa * a[2, j],
            sa * a[3, j],
            b[0, j],
            sb * b[1, j],
            sb * b[2, j],
            sb * b[3, j],
        )
        out[0, j] = w
        out[1, j] = x
        out[2, j] = y
        out[3, j] = z


# In-place products take the updated array once: given as two arguments, LLVM's runtime
# check finds them overlapping and runs the scalar loop.


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _rmul(io, b, conj_b=False):  # type: ignore[no-untyped-def]
    """``io <- io b'`` per joint, ``b' = b^-1`` if ``conj_b`` (unit ``b``), else ``b``."""
    sb = -1.0 if conj_b else 1.0
    for j in range(io.shape[1]):
        w, x, y, z = _qmul(
            io[0, j],
            io[1, j],
            io[2, j],
            io[3, j],
            b[0, j],
            sb * b[1, j],
            sb * b[2, j],
            sb * b[3, j],
        )
        io[0, j] = w
        io[1, j] = x
        io[2, j] = y
        io[3, j] = z


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _lmul(a, io, conj_a=False):  # type: ignore[no-untyped-def]
    """``io <- a' io`` per joint, ``a' = a^-1`` if ``conj_a`` (unit ``a``), else ``a``."""
    sa = -1.0 if conj_a else 1.0
    for j in range(io.shape[1]):
        w, x, y, z = _qmul(
            a[0, j],
            sa * a[1, j],
            sa * a[2, j],
            sa * a[3, j],
            io[0, j],
            io[1, j],
            io[2, j],
            io[3, j],
        )
        io[0, j] = w
        io[1, j] = x
        io[2, j] = y
        io[3, j] = z


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _log_into(Q, out):  # type: ignore[no-untyped-def]
    """``out`` ``(3, n)`` = shortest-arc logs of ``Q`` ``(4, n)``."""
    for j in range(Q.shape[1]):
        lx, ly, lz = _qlog(Q[0, j], Q[1, j], Q[2, j], Q[3, j])
        out[0, j] = lx
        out[1, j] = ly
        out[2, j] = lz


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _residual_log(YTi, C, r):  # type: ignore[no-untyped-def]
    """``r`` ``(3, n)`` = ``ln(C^-1 Y)``; returns ``|r|^2``."""
    for j in range(YTi.shape[1]):
        w, x, y, z = _qmul(
            C[0, j], -C[1, j], -C[2, j], -C[3, j], YTi[0, j], YTi[1, j], YTi[2, j], YTi[3, j]
        )
        lx, ly, lz = _qlog(w, x, y, z)
        r[0, j] = lx
        r[1, j] = ly
        r[2, j] = lz
    return _sumsq(r.reshape(r.size))


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
def _sort_slots_with_powers(idx_row, coef_row, A_i, m, saved):  # type: ignore[no-untyped-def]
    """:func:`_sort_slots` that moves the cached powers ``A_i`` ``(L, 4, n)`` along
    (``saved`` is a ``(4, n)`` scratch buffer)."""
    moved = False
    for s in range(1, m):
        ci = coef_row[s]
        ii = idx_row[s]
        t = s - 1
        if not abs(coef_row[t]) < abs(ci):
            continue
        moved = True
        _copy(A_i[s], saved)
        while t >= 0 and abs(coef_row[t]) < abs(ci):
            coef_row[t + 1] = coef_row[t]
            idx_row[t + 1] = idx_row[t]
            _copy(A_i[t], A_i[t + 1])
            t -= 1
        coef_row[t + 1] = ci
        idx_row[t + 1] = ii
        _copy(saved, A_i[t + 1])
    return moved


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _solve_coef(E, dn, da, weighted, scratch):  # type: ignore[no-untyped-def]
    """Weight ``x`` maximising ``sum_j <E_j, atom_j ** x>`` (paper Eq. 5-6).

    Per joint the optimum satisfies ``tan(x phi_j / 2) = (u_j . v_j) tan(theta_j / 2)``, i.e.
    ``x a_j = b_j`` with ``a_j = phi_j / 2`` and ``b_j = atan2(u_j . vec(E_j), w(E_j))``
    (the same arctan without forming ``tan``). Eq. 6 combines the joints by least squares; a
    joint with ``a_j = 0`` carries no information and adds nothing to either sum. With
    ``weighted`` each joint is weighted by ``rho_j = |(w, u_j . vec)|``, the amplitude of its
    term ``rho_j cos(x a_j - b_j)``: the exact second-order model of Eq. 5 around each optimum.
    ``scratch`` is ``(2, n)``.
    """
    for j in range(dn.shape[0]):
        a = dn[j]
        w = E[0, j]
        p = da[0, j] * E[1, j] + da[1, j] * E[2, j] + da[2, j] * E[3, j]
        sign = -1.0 if w < 0.0 else 1.0
        w *= sign
        p *= sign
        b = _atan_ratio(abs(p), w)
        b = -b if p < 0.0 else b
        weight = math.sqrt(w * w + p * p) if weighted else 1.0
        scratch[0, j] = weight * a * b
        scratch[1, j] = weight * a * a
    num = _sum(scratch[0])
    den = _sum(scratch[1])
    if den <= 0.0:
        return 0.0
    return num / den


@njit(cache=True)
def _combine_row(Dnorm, DaxisT, idx_row, coef_row, m, out, tmp):  # type: ignore[no-untyped-def]
    """``out`` ``(4, n)`` = combination of the first ``m`` slots."""
    _identity_into(out)
    for s in range(m):
        k = idx_row[s]
        _power_into(Dnorm[k], DaxisT[k], coef_row[s], tmp)
        _rmul(out, tmp)


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _residual_into(C, YTi, left, out):  # type: ignore[no-untyped-def]
    """One sample's residual against its combination ``C``: ``C^-1 Y`` if ``left`` (what the
    next, smaller atom must explain), else ``Y C^-1`` (Algorithm 2 line 8 as printed)."""
    if left:
        _times(C, YTi, out, True, False)
    else:
        _times(YTi, C, out, False, True)


# ----------------------------------------------------------------------------------------------
# Coefficient solvers for one sample.


@njit(cache=True)
def _bcd(YTi, Dnorm, DaxisT, idx_row, coef_row, m, n_sweeps, weighted, A, suf, Lq, E, scratch):  # type: ignore[no-untyped-def]
    """Block coordinate descent over the ``m`` weights of one sample, keeping the order sorted.

    Each sweep visits the slots left to right. For slot ``s`` the other factors are fixed:
    ``E = (A_0 .. A_{s-1})^-1 Y (A_{s+1} .. A_{m-1})^-1`` and Eq. 6 gives the new weight.
    The suffix products are formed once per sweep (they only involve slots not yet visited) and
    the left factor ``P^-1 Y`` is carried along, so a sweep costs O(m n) quaternion products.
    After each sweep the slots are re-sorted by magnitude, which is the order Eq. 2 defines.
    """
    for s in range(m):
        k = idx_row[s]
        _power_into(Dnorm[k], DaxisT[k], coef_row[s], A[s])
    for _ in range(n_sweeps):
        # suf[s] = A_s A_{s+1} ... A_{m-1}; suf[m] = identity.
        _identity_into(suf[m])
        for t in range(m):
            s = m - 1 - t
            _times(A[s], suf[s + 1], suf[s])
        _copy(YTi, Lq)
        for s in range(m):
            _times(Lq, suf[s + 1], E, False, True)
            k = idx_row[s]
            x = _solve_coef(E, Dnorm[k], DaxisT[k], weighted, scratch)
            coef_row[s] = x
            _power_into(Dnorm[k], DaxisT[k], x, A[s])
            _lmul(A[s], Lq, True)
        if _sort_slots(idx_row, coef_row, m):
            for s in range(m):
                k = idx_row[s]
                _power_into(Dnorm[k], DaxisT[k], coef_row[s], A[s])


# Relative size of the predicted Gauss-Newton decrease of |r|^2 below which a refit stops:
# each step costs a full residual evaluation. On exact data the decrease stays large until the
# residual vanishes (quadratic convergence), so this only cuts the last steps on noisy and real
# data, where they move |r|^2 by under 0.1 %: less time per iteration for the same results
# (the measurement against 1e-10 is in docs/performance.md).
GN_STEP_TOL = 1e-3
# Relative gap between adjacent weight magnitudes below which the swapped order is tried, and
# how many such pairs (the closest first) are tried.
SWAP_GAP = 0.05
SWAP_PAIRS = 2


@njit(cache=True)
def _gn_eval(YTi, Dnorm, DaxisT, idx_row, coef, m, Apow, suf, r):  # type: ignore[no-untyped-def]
    """``suf[s] = A_s .. A_{m-1}`` for weights ``coef``, ``r = ln(suf[0]^-1 Y)``; ``|r|^2``.

    Each power ``A_s`` is formed, kept in ``Apow`` (a re-ordering of the same weights then
    needs no sines, :func:`_gn_eval_powers`) and multiplied into the suffix.
    """
    _identity_into(suf[m])
    for t in range(m):
        s = m - 1 - t
        k = idx_row[s]
        # Two loops rather than one: a loop over five or more arrays is left scalar by LLVM
        # (too many runtime alias checks), these two vectorise.
        _power_into(Dnorm[k], DaxisT[k], coef[s], Apow[s])
        _times(Apow[s], suf[s + 1], suf[s])
    return _residual_log(YTi, suf[0], r)


@njit(cache=True)
def _gn_eval_powers(YTi, Apow, m, suf, r):  # type: ignore[no-untyped-def]
    """:func:`_gn_eval` from the powers ``Apow`` ``(m, 4, n)`` already formed."""
    _identity_into(suf[m])
    for t in range(m):
        s = m - 1 - t
        _times(Apow[s], suf[s + 1], suf[s])
    return _residual_log(YTi, suf[0], r)


@njit(cache=True, fastmath=_FM, error_model="numpy")
def _jacobian_row(S, v, out):  # type: ignore[no-untyped-def]
    """``out`` ``(3, n)`` = the logs ``v`` ``(3, n)`` rotated by ``S^*`` (``S^* v S``)."""
    for j in range(v.shape[1]):
        # A rotation by S^*: the conjugate negates the vector part.
        wx, wy, wz = _rotate(S[0, j], -S[1, j], -S[2, j], -S[3, j], v[0, j], v[1, j], v[2, j])
        out[0, j] = wx
        out[1, j] = wy
        out[2, j] = wz


@njit(cache=True, fastmath=_FM_SUM, error_model="numpy")
def _normal_equations(Wmat3, r3, G, g, m):  # type: ignore[no-untyped-def]
    """``G = W W^T``, ``g = W r`` for the first ``m`` rows of ``Wmat3`` ``(L, 3, n)`` and
    ``r3`` ``(3, n)``, both read as ``3n``-vectors; returns ``trace(G)``.

    Reassociation lets LLVM vectorise the ``3n``-long dot products; only the summation order
    changes.
    """
    n3 = r3.size
    Wmat = Wmat3.reshape((Wmat3.shape[0], n3))
    r = r3.reshape(n3)
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
    back_substitute(G, out, out, m)
    return True


@njit(cache=True, inline="always")
def back_substitute(L, y, x, m):  # type: ignore[no-untyped-def]
    """Solve ``L^T x = y`` for lower-triangular ``L`` ``(m, m)``, the last row first (``x``
    may be ``y``: each ``y[a]`` is read before ``x[a]`` is written); the second half of a
    Cholesky solve, written once for QSSD's and linear K-SVD's kernels (inlined: their flags,
    the same arithmetic in the same order)."""
    for a in range(m - 1, -1, -1):
        acc = y[a]
        for t in range(a + 1, m):
            acc -= L[t, a] * x[t]
        x[a] = acc / L[a, a]


@njit(cache=True)
def _gauss_newton(  # type: ignore[no-untyped-def]
    YTi,
    DlogT,
    Dnorm,
    DaxisT,
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

    With ``Yhat = A_0 .. A_{m-1}`` and the residual ``r = ln(Yhat^-1 Y)`` (a ``3n``-vector), moving
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
    so a rejected step costs no re-evaluation. On exit ``C_out`` ``(4, n)`` holds the
    combination of the returned weights, ``r_out`` ``(3, n)`` its residual log and ``P_out``
    ``(L, 4, n)`` the powers of its slots; returns ``|r|^2``.
    """
    suf, suf2, r, r2, Wmat, G, g, delta, trial, Apow, Apow2, saved = ws
    if from_powers:
        current = _gn_eval_powers(YTi, Apow, m, suf, r)
    else:
        current = _gn_eval(YTi, Dnorm, DaxisT, idx_row, coef_row, m, Apow, suf, r)
    for _ in range(n_iter):
        if current < 1e-28:
            break
        for s in range(m):
            _jacobian_row(suf[s + 1], DlogT[idx_row[s]], Wmat[s])
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
            value = _gn_eval(YTi, Dnorm, DaxisT, idx_row, trial, m, Apow2, suf2, r2)
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
        if keep_sorted and _sort_slots_with_powers(idx_row, coef_row, Apow, m, saved):
            current = _gn_eval_powers(YTi, Apow, m, suf, r)
    _copy(suf[0], C_out)
    _copy(r, r_out)
    for s in range(m):
        _copy(Apow[s], P_out[s])
    return current


@njit(cache=True)
def _refit_with_swaps(  # type: ignore[no-untyped-def]
    YTi,
    DlogT,
    Dnorm,
    DaxisT,
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
        YTi,
        DlogT,
        Dnorm,
        DaxisT,
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
    for c in range(min(SWAP_PAIRS, 2)):
        s = first if c == 0 else second
        gap = gap_first if c == 0 else gap_second
        if s < 0 or gap > SWAP_GAP:
            continue
        for t in range(m):
            trial_idx[t] = idx_row[t]
            trial_coef[t] = coef_row[t]
        trial_idx[s], trial_idx[s + 1] = idx_row[s + 1], idx_row[s]
        trial_coef[s], trial_coef[s + 1] = coef_row[s + 1], coef_row[s]
        # The swapped order starts from the same powers, swapped: no sines to redo.
        Apow = ws[9]
        for t in range(m):
            _copy(P_best[t], Apow[t])
        _copy(P_best[s + 1], Apow[s])
        _copy(P_best[s], Apow[s + 1])
        value = _gauss_newton(
            YTi,
            DlogT,
            Dnorm,
            DaxisT,
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
                _copy(P_trial[t], P_best[t])
            _copy(C_trial, C_best)
            _copy(r_trial, r_best)
    return best


# ----------------------------------------------------------------------------------------------
# Parallel kernels over samples.


@njit(parallel=True, cache=True)
def combine(Dnorm, DaxisT, idx, coef, count, out):  # type: ignore[no-untyped-def]
    """Quaternion combination of every sample (Eq. 2-3) into ``out`` ``(N, 4, n)``."""
    N = idx.shape[0]
    n = Dnorm.shape[1]
    n_chunks = (N + _CHUNK - 1) // _CHUNK
    for c in prange(n_chunks):
        tmp = np.empty((4, n))
        for i in range(c * _CHUNK, min(N, (c + 1) * _CHUNK)):
            _combine_row(Dnorm, DaxisT, idx[i], coef[i], count[i], out[i], tmp)


@njit(parallel=True, cache=True)
def logs(QT, out):  # type: ignore[no-untyped-def]
    """Shortest-arc logs ``(N, 3, n)`` of quaternions ``QT`` ``(N, 4, n)``."""
    for i in prange(QT.shape[0]):
        _log_into(QT[i], out[i])


@njit(parallel=True, cache=True)
def residual_logs(YT, Dnorm, DaxisT, idx, coef, count, left, out):  # type: ignore[no-untyped-def]
    """Shortest-arc logs of the residuals into ``out`` ``(N, 3, n)``.

    ``left``: ``R = C^-1 Y`` (what remains to the right of the combination ``C``, where the next,
    smaller atom goes). Otherwise ``R = Y C^-1``, Algorithm 2 line 8 as printed.
    """
    N = idx.shape[0]
    n = Dnorm.shape[1]
    n_chunks = (N + _CHUNK - 1) // _CHUNK
    for c in prange(n_chunks):
        C = np.empty((4, n))
        tmp = np.empty((4, n))
        for i in range(c * _CHUNK, min(N, (c + 1) * _CHUNK)):
            _combine_row(Dnorm, DaxisT, idx[i], coef[i], count[i], C, tmp)
            _residual_into(C, YT[i], left, tmp)
            _log_into(tmp, out[i])


@njit(parallel=True, cache=True)
def add_atom_and_refit(
    YT,
    DlogT,
    Dnorm,
    DaxisT,
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
    resid_sq,
):  # type: ignore[no-untyped-def]
    """One step of Algorithm 2 for every active sample.

    ``Rq`` ``(N, 4, n)`` and ``Rlog`` ``(N, 3, n)`` hold each sample's residual (``C^-1 Y`` if
    ``left``, else ``Y C^-1``) and its log on entry, the updated ones on exit. Appends
    ``new_atom[i]`` with its Eq. 6 weight against the residual; if ``refit``, refits all
    weights (``solver``: 0 coordinate descent with plain Eq. 6, 1 with weighted Eq. 6, 2 joint
    Gauss-Newton with order swaps; ``n_sweeps`` sweeps or steps). ``signal`` ``(N,)`` is
    ``|ln Y_i|^2`` (used by the order swaps). Slots stay sorted by magnitude. ``obj[i]``
    receives ``sum_j 1 - |<Y_j, C_j>|``, which equals ``sum_j 1 - |w(R_j)|`` for either residual,
    and ``resid_sq[i]`` the squared norm of the residual log.
    When the new atom lands last and nothing is refit, the left residual is updated with one
    product per joint instead of recomputing the whole combination; after a Gauss-Newton refit
    the solver's last combination and residual log are reused.
    """
    N = idx.shape[0]
    n = Dnorm.shape[1]
    L = idx.shape[1]
    n_chunks = (N + _CHUNK - 1) // _CHUNK
    for c in prange(n_chunks):
        R = np.empty((4, n))
        tmp = np.empty((4, n))
        C = np.empty((4, n))
        E = np.empty((4, n))
        scratch = np.empty((2, n))
        A = np.empty((L, 4, n))
        suf = np.empty((L + 1, 4, n))
        ws = (
            suf,
            np.empty((L + 1, 4, n)),
            np.empty((3, n)),
            np.empty((3, n)),
            np.empty((L, 3, n)),
            np.empty((L, L)),
            np.empty(L),
            np.empty(L),
            np.empty(L),
            np.empty((L, 4, n)),
            np.empty((L, 4, n)),
            np.empty((4, n)),
        )
        r_best = np.empty((3, n))
        C_trial = np.empty((4, n))
        r_trial = np.empty((3, n))
        trial_idx = np.empty(L, dtype=idx.dtype)
        trial_coef = np.empty(L)
        P_best = np.empty((L, 4, n))
        P_trial = np.empty((L, 4, n))
        for i in range(c * _CHUNK, min(N, (c + 1) * _CHUNK)):
            if not active[i]:
                continue
            m = count[i]
            _copy(Rq[i], R)
            k = new_atom[i]
            x = _solve_coef(R, Dnorm[k], DaxisT[k], solver >= 1, scratch)
            idx[i, m] = k
            coef[i, m] = x
            m += 1
            count[i] = m
            # Between refits the slots stay in selection order (the greedy order the paper
            # assumes descending), so the left residual advances by one product; the refit
            # sorts them.
            moved = _sort_slots(idx[i], coef[i], m) if (refit or not left) else False
            if refit and solver == 2:
                _refit_with_swaps(
                    YT[i],
                    DlogT,
                    Dnorm,
                    DaxisT,
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
                _residual_into(C, YT[i], left, R)
                if left:
                    # r_best = ln(C^-1 Y) is the left residual's log already.
                    _copy(r_best, Rlog[i])
                else:
                    _log_into(R, Rlog[i])
            else:
                if refit:
                    _bcd(
                        YT[i],
                        Dnorm,
                        DaxisT,
                        idx[i],
                        coef[i],
                        m,
                        n_sweeps,
                        solver == 1,
                        A,
                        suf,
                        tmp,
                        E,
                        scratch,
                    )
                if left and not moved and not refit:
                    _power_into(Dnorm[k], DaxisT[k], x, tmp)
                    _lmul(tmp, R, True)
                else:
                    _combine_row(Dnorm, DaxisT, idx[i], coef[i], m, C, tmp)
                    _residual_into(C, YT[i], left, R)
                _log_into(R, Rlog[i])
            _copy(R, Rq[i])
            obj[i] = _residual_objective(R)
            resid_sq[i] = _sumsq(Rlog[i].reshape(3 * n))


@njit(parallel=True, cache=True)
def objectives(YT, Dnorm, DaxisT, idx, coef, count, out):  # type: ignore[no-untyped-def]
    """Per-sample objective ``sum_j 1 - |<Y_j, C_j>|`` ``(N,)`` of the codes."""
    N = idx.shape[0]
    n = Dnorm.shape[1]
    n_chunks = (N + _CHUNK - 1) // _CHUNK
    for c in prange(n_chunks):
        C = np.empty((4, n))
        tmp = np.empty((4, n))
        for i in range(c * _CHUNK, min(N, (c + 1) * _CHUNK)):
            _combine_row(Dnorm, DaxisT, idx[i], coef[i], count[i], C, tmp)
            out[i] = _row_objective(YT[i], C)


@njit(parallel=True, cache=True)
def atom_residual_logs(YT, Dnorm, DaxisT, idx, coef, count, samples, positions, out):  # type: ignore[no-untyped-def]
    """Algorithm 3 line 5 for one atom: ``ln E`` with ``E = P^-1 Y S^-1`` into ``(M, 3, n)``.

    ``P`` is the product of the slots left of ``positions[r]`` (larger weights) and ``S`` of
    the slots right of it, for sample ``samples[r]``. The powers are formed afresh rather than
    cached: a cache of every slot's power is ``N L`` blocks of ``4n`` numbers that each atom's
    pass streams from memory, which took longer than the vectorised sines.
    """
    M = samples.shape[0]
    n = YT.shape[2]
    n_chunks = (M + _CHUNK - 1) // _CHUNK
    for c in prange(n_chunks):
        E = np.empty((4, n))
        tmp = np.empty((4, n))
        for r in range(c * _CHUNK, min(M, (c + 1) * _CHUNK)):
            i = samples[r]
            p = positions[r]
            _copy(YT[i], E)
            # P^-1 Y = A_{p-1}^-1 ... A_1^-1 A_0^-1 Y: the first slot's inverse goes next to Y.
            for s in range(p):
                k = idx[i, s]
                _power_into(Dnorm[k], DaxisT[k], coef[i, s], tmp)
                _lmul(tmp, E, True)
            # Y S^-1 = Y A_{m-1}^-1 ... A_{p+1}^-1: the last slot's inverse goes next to Y.
            for s in range(count[i] - 1, p, -1):
                k = idx[i, s]
                _power_into(Dnorm[k], DaxisT[k], coef[i, s], tmp)
                _rmul(E, tmp, True)
            _log_into(E, out[r])


@njit(parallel=True, cache=True)
def candidate_objective(
    YT, Dnorm, DaxisT, idx, coef, count, samples, positions, atom_logT, new_weights, out
):  # type: ignore[no-untyped-def]
    """Objective of each sample in ``samples`` if its slot ``positions[r]`` became
    ``exp(new_weights[r] * atom_logT)`` (``atom_logT`` ``(3, n)``), with the slots re-sorted by
    magnitude (Eq. 2 order)."""
    M = samples.shape[0]
    n = YT.shape[2]
    L = coef.shape[1]
    n_chunks = (M + _CHUNK - 1) // _CHUNK
    for c in prange(n_chunks):
        order_idx = np.empty(L, dtype=np.int64)
        order_coef = np.empty(L)
        P = np.empty((4, n))
        power = np.empty((4, n))
        for r in range(c * _CHUNK, min(M, (c + 1) * _CHUNK)):
            i = samples[r]
            p = positions[r]
            m = count[i]
            for s in range(m):
                order_idx[s] = s
                order_coef[s] = coef[i, s]
            order_coef[p] = new_weights[r]
            _sort_slots(order_idx, order_coef, m)
            _identity_into(P)
            for t in range(m):
                s = order_idx[t]
                if s == p:
                    _exp_into(atom_logT, new_weights[r], power)
                else:
                    k = idx[i, s]
                    _power_into(Dnorm[k], DaxisT[k], coef[i, s], power)
                _rmul(P, power)
            out[r] = _row_objective(YT[i], P)


@njit(parallel=True, cache=True)
def commit_atom(idx, coef, count, samples, positions, new_weights):  # type: ignore[no-untyped-def]
    """Write the accepted weights of an atom and re-sort the slots of the touched samples."""
    for r in prange(samples.shape[0]):
        i = samples[r]
        coef[i, positions[r]] = new_weights[r]
        _sort_slots(idx[i], coef[i], count[i])


@njit(parallel=True, cache=True)
def best_atoms(proj, idx, count, start, out):  # type: ignore[no-untyped-def]
    """Atom selection of Algorithm 2: ``out[start + r]`` = the atom of largest ``|proj[r]|``
    among those not yet in sample ``start + r``'s code (``idx[., :count[.]]``).

    ``proj`` ``(M, K)`` are the projections of ``M`` consecutive samples' residual logs on the
    atom logs. One pass, where ``abs``, masking and ``argmax`` in NumPy took three.
    """
    M, K = proj.shape
    n_chunks = (M + _CHUNK - 1) // _CHUNK
    for c in prange(n_chunks):
        used = np.zeros(K, dtype=np.bool_)
        for r in range(c * _CHUNK, min(M, (c + 1) * _CHUNK)):
            i = start + r
            for t in range(count[i]):
                used[idx[i, t]] = True
            best = 0
            best_value = -1.0
            for k in range(K):
                v = abs(proj[r, k])
                if v > best_value and not used[k]:
                    best_value = v
                    best = k
            out[i] = best
            for t in range(count[i]):
                used[idx[i, t]] = False
