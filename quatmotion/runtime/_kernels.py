"""Compiled loops of the decoding runtime: coefficient rows to rotations, whole clips and poses.

Loaded on the first decode (:func:`quatmotion.runtime.kernels`: importing it loads Numba);
kernels trust their input: the Python side (:class:`quatmotion.codec.sampling.Sampler`,
:meth:`quatmotion.codec.archive.ArchiveReader.read_rotations`) validates and lays arrays out
once.

Conventions
-----------
* A clip's segments are a table ``segs`` ``(S, 6)``: first frame, frames, first coefficient
  row, whether it is a spline, and the span of its clamped cubic knot vector in ``knots``
  (:class:`quatmotion.codec.spline.SegmentTables` side by side). ``P`` ``(n, c)`` holds every
  segment's coefficient rows of the ``c`` channels ``cols`` in weighted units; a channel is
  ``P`` evaluated, divided by ``scale``.
* The de Boor steps are those of :func:`quatmotion.codec.spline._evaluate_channels` (the
  weights computed once per position and shared by every channel), so a position at a frame
  gives that frame's decoded channels to the bit, whichever kernel evaluates it.
* Rotations from channels (:func:`_joint_block`, :func:`_pose_rotations`): one arithmetic,
  written once per kind, so a pose sampled at a frame time equals the whole clip's frame to
  the bit, and vectorised loops (over frames) give the bits of the scalar ones (no fast-math:
  no contraction, no reassociation).
* Kinds: 0 fixed (identity), 1 Euler (one rotation about a pre-rotated axis per dof, composed
  intrinsic or extrinsic; no sine-cosine pair for an absent dof), 2 rotation vector about the
  reference, 3 the root (a heading about Y, then a rotation vector).
* Whole clips are decoded in blocks of :data:`BLOCK` frames: channels evaluated row by row
  (each row's weights shared by its channels), transposed, then each joint's rotations in one
  loop over the block's frames.
"""

from __future__ import annotations

import functools

import numba
import numpy as np
from numpy.lib.stride_tricks import as_strided

from quatmotion.quat.jit import multiply

__all__ = [
    "BLOCK",
    "clip_rotations",
    "pose",
    "pose_entry",
    "poses",
    "rotations_of_channels",
    "sincos",
]

BLOCK = 64
"""Frames (or poses) decoded together: a block's channels stay in the first-level cache."""


@numba.njit(inline="always", cache=True)
def sincos(x):  # pragma: no cover - compiled
    """``(sin x, cos x)`` to within an ulp of libm's, about twice as fast: ``x`` reduced by
    the nearest multiple of pi/2 (three-part Cody-Waite), then Taylor polynomials of degree
    17 and 16 on ``[-pi/4, pi/4]`` (truncation below 1e-19)."""
    k = np.floor(x * 0.6366197723675814 + 0.5)
    r = ((x - k * 1.5707963267341256) - k * 6.077100506506192e-11) - k * 2.0222662487959506e-21
    z = r * r
    s = r + r * z * (
        -1.6666666666666666e-01
        + z
        * (
            8.3333333333333332e-03
            + z
            * (
                -1.9841269841269841e-04
                + z
                * (
                    2.7557319223985893e-06
                    + z
                    * (
                        -2.5052108385441720e-08
                        + z
                        * (
                            1.6059043836821613e-10
                            + z * (-7.6471637318198164e-13 + z * 2.8114572543455206e-15)
                        )
                    )
                )
            )
        )
    )
    c = 1.0 + z * (
        -0.5
        + z
        * (
            4.1666666666666664e-02
            + z
            * (
                -1.3888888888888889e-03
                + z
                * (
                    2.4801587301587302e-05
                    + z
                    * (
                        -2.7557319223985888e-07
                        + z
                        * (
                            2.0876756987868100e-09
                            + z * (-1.1470745597729725e-11 + z * 4.7794773323873853e-14)
                        )
                    )
                )
            )
        )
    )
    # the quadrant by exact products, not selects: a select of two floats is a branch in
    # scalar x86 code, mispredicted half the time on a pose's angles (the same values:
    # (s, c), (c, -s), (-s, -c), (-c, s) for quadrants 0..3; x 1.0 and + 0.0 are exact)
    q = np.int64(k) & 3
    odd = float(q & 1)
    even = 1.0 - odd
    sin = (s * even + c * odd) * (1.0 - float(q & 2))
    cos = (c * even + s * odd) * (1.0 - float((q + 1) & 2))
    return sin, cos


@numba.njit(inline="always", cache=True)
def _rotvec(r0, r1, r2, r3, v0, v1, v2):  # pragma: no cover - compiled
    """``ref exp(v / 2)``: the rotation vector ``v`` (radians) about the reference."""
    vx, vy, vz = 0.5 * v0, 0.5 * v1, 0.5 * v2
    ang = np.sqrt(vx * vx + vy * vy + vz * vz)
    sn, ew = sincos(ang)
    s = sn / ang if ang > 1e-12 else 1.0
    return multiply(r0, r1, r2, r3, ew, vx * s, vy * s, vz * s)


@numba.njit(inline="always", cache=True)
def _heading(h, w, x, y, z):  # pragma: no cover - compiled
    """``Y(h) q``: the heading ``h`` about the vertical, then ``q``."""
    sh, ch = sincos(0.5 * h)
    return multiply(ch, 0.0, sh, 0.0, w, x, y, z)


@numba.njit(inline="always", cache=True)
def _dof(j, ax, sh, ch, first, intrinsic, w, x, y, z, pre):  # pragma: no cover - compiled
    """``q`` composed with the rotation ``(ch, sh C e_ax)`` about joint ``j``'s axis ``ax``
    (``C e_ax``: :func:`quatmotion.codec.channels._kernel_tables`' ``pre``); for the joint's
    first dof, that rotation itself (the identity's product without its 28 operations: the
    same values)."""
    ex, ey, ez = sh * pre[j, ax, 0], sh * pre[j, ax, 1], sh * pre[j, ax, 2]
    if first:
        return ch, ex, ey, ez
    if intrinsic:  # q <- q e
        return multiply(w, x, y, z, ch, ex, ey, ez)
    return multiply(ch, ex, ey, ez, w, x, y, z)  # extrinsic: q <- e q


@numba.njit(inline="always", cache=True)
def _joint_block(Xc, n, j, kinds, starts, counts, dof_axes, pre, ref, Q):  # pragma: no cover
    """Joint ``j``'s rotations of the first ``n`` columns of channel-major ``Xc`` ``(C, B)``
    into ``Q`` ``(4, B)``: the kind's branch once, then one loop over the columns (the
    arithmetic of :func:`_pose_rotations`)."""
    kind = kinds[j]
    a = starts[j]
    if kind == 2 or kind == 3:
        b = a + 1 if kind == 3 else a
        r0, r1, r2, r3 = ref[j, 0], ref[j, 1], ref[j, 2], ref[j, 3]
        for t in range(n):
            w, x, y, z = _rotvec(r0, r1, r2, r3, Xc[b, t], Xc[b + 1, t], Xc[b + 2, t])
            Q[0, t] = w
            Q[1, t] = x
            Q[2, t] = y
            Q[3, t] = z
        if kind == 3:
            for t in range(n):
                w, x, y, z = _heading(Xc[a, t], Q[0, t], Q[1, t], Q[2, t], Q[3, t])
                Q[0, t] = w
                Q[1, t] = x
                Q[2, t] = y
                Q[3, t] = z
        return
    if kind == 1:
        intrinsic = pre[j, 3, 0] > 0.5
        for i in range(counts[j]):
            ax = dof_axes[j, i]
            first = i == 0
            for t in range(n):
                sh, ch = sincos(0.5 * Xc[a + i, t])
                w, x, y, z = _dof(j, ax, sh, ch, first, intrinsic,
                                  Q[0, t], Q[1, t], Q[2, t], Q[3, t], pre)  # fmt: skip
                Q[0, t] = w
                Q[1, t] = x
                Q[2, t] = y
                Q[3, t] = z
        return
    for t in range(n):
        Q[0, t] = 1.0
        Q[1, t] = 0.0
        Q[2, t] = 0.0
        Q[3, t] = 0.0


@numba.njit(inline="always", cache=True)
def _pose_rotations(X, sel, kinds, starts, counts, dof_axes, pre, ref, A, SN, CS, rot):  # noqa: E501  # pragma: no cover
    """The rotations of joints ``sel`` from one row of channels ``X`` ``(1, C)`` into ``rot``
    ``(k, 4)``, the arithmetic of :func:`_joint_block` in three passes: every angle whose
    sine and cosine a joint needs into ``A``, their sines and cosines in one loop (``SN``,
    ``CS``: independent, so they overlap, where joint by joint each waits on the last),
    then the products."""
    n = 0
    for jj in range(sel.shape[0]):
        j = sel[jj]
        kind = kinds[j]
        a = starts[j]
        if kind == 1:
            for i in range(counts[j]):
                A[n] = 0.5 * X[0, a + i]
                n += 1
        elif kind == 2 or kind == 3:
            b = a + 1 if kind == 3 else a
            vx, vy, vz = 0.5 * X[0, b], 0.5 * X[0, b + 1], 0.5 * X[0, b + 2]
            A[n] = np.sqrt(vx * vx + vy * vy + vz * vz)
            n += 1
            if kind == 3:
                A[n] = 0.5 * X[0, a]
                n += 1
    for i in range(n):
        SN[i], CS[i] = sincos(A[i])
    n = 0
    for jj in range(sel.shape[0]):
        j = sel[jj]
        kind = kinds[j]
        a = starts[j]
        w, x, y, z = 1.0, 0.0, 0.0, 0.0
        if kind == 1:
            intrinsic = pre[j, 3, 0] > 0.5
            for i in range(counts[j]):
                w, x, y, z = _dof(j, dof_axes[j, i], SN[n], CS[n], i == 0, intrinsic, w, x, y, z,
                                  pre)  # fmt: skip
                n += 1
        elif kind == 2 or kind == 3:
            b = a + 1 if kind == 3 else a
            vx, vy, vz = 0.5 * X[0, b], 0.5 * X[0, b + 1], 0.5 * X[0, b + 2]
            ang = A[n]
            sn, ew = SN[n], CS[n]
            n += 1
            s = sn / ang if ang > 1e-12 else 1.0
            w, x, y, z = multiply(ref[j, 0], ref[j, 1], ref[j, 2], ref[j, 3], ew, vx * s, vy * s,
                                  vz * s)  # fmt: skip
            if kind == 3:
                sh, ch = SN[n], CS[n]
                n += 1
                w, x, y, z = multiply(ch, 0.0, sh, 0.0, w, x, y, z)
        rot[jj, 0] = w
        rot[jj, 1] = x
        rot[jj, 2] = y
        rot[jj, 3] = z


@numba.njit(cache=True)
def rotations_of_channels(X, kinds, starts, counts, dof_axes, pre, ref):  # pragma: no cover
    """Local rotations ``(T, J, 4)`` of channels ``X`` ``(T, C)``, block by block."""
    T = X.shape[0]
    J = kinds.shape[0]
    C = X.shape[1]
    out = np.empty((T, J, 4))
    Xc = np.empty((C, BLOCK))
    Q = np.empty((4, BLOCK))
    for f0 in range(0, T, BLOCK):
        n = min(BLOCK, T - f0)
        for t in range(n):
            for c in range(C):
                Xc[c, t] = X[f0 + t, c]
        for j in range(J):
            _joint_block(Xc, n, j, kinds, starts, counts, dof_axes, pre, ref, Q)
            for t in range(n):
                out[f0 + t, j, 0] = Q[0, t]
                out[f0 + t, j, 1] = Q[1, t]
                out[f0 + t, j, 2] = Q[2, t]
                out[f0 + t, j, 3] = Q[3, t]
    return out


@numba.njit(inline="always", cache=True)
def _segment_of(segs, i):  # pragma: no cover - compiled
    """The segment holding frame ``i``: the last ``s`` with ``segs[s, 0] <= i``."""
    lo, hi = 0, segs.shape[0] - 1
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if segs[mid, 0] <= i:
            lo = mid
        else:
            hi = mid - 1
    return lo


@numba.njit(inline="always", cache=True)
def _alpha(knots, i, width, x):  # pragma: no cover - compiled
    den = knots[i + width] - knots[i]
    return (x - knots[i]) / den if den > 0.0 else 0.0


@numba.njit(inline="always", cache=True)
def _interval(knots, t0, n, xv):  # pragma: no cover - compiled
    """The last ``i`` in ``[3, n - 1]`` with ``t[i] <= xv``, as _evaluate_channels walks to it."""
    lo = 3
    hi = n - 1
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if xv >= knots[t0 + mid]:
            lo = mid
        else:
            hi = mid - 1
    return lo


@numba.njit(inline="always", cache=True)
def _weights(x, s, segs, knots):  # pragma: no cover - compiled
    """The first coefficient row and the six de Boor weights (the loop (r, q) = (1, 3),
    (1, 2), (1, 1), (2, 3), (2, 2), (3, 3) of :func:`quatmotion.codec.spline.
    _evaluate_channels`, as scalars) at frame position ``x`` of spline segment ``s``."""
    t0 = segs[s, 4]
    xv = x - segs[s, 0]
    iv = t0 + _interval(knots, t0, segs[s, 5] - t0 - 4, xv)
    return (
        segs[s, 2] + iv - t0 - 3,
        _alpha(knots, iv, 3, xv),
        _alpha(knots, iv - 1, 3, xv),
        _alpha(knots, iv - 2, 3, xv),
        _alpha(knots, iv, 2, xv),
        _alpha(knots, iv - 1, 2, xv),
        _alpha(knots, iv, 1, xv),
    )


@numba.njit(inline="always", cache=True)
def _deboor(P, b, c, a0, a1, a2, a3, a4, a5):  # pragma: no cover - compiled
    """Column ``c`` of the cubic spline with rows ``P[b : b + 4]`` and weights ``a0 .. a5``."""
    return _lerps(P[b, c], P[b + 1, c], P[b + 2, c], P[b + 3, c], a0, a1, a2, a3, a4, a5)


@numba.njit(inline="always", cache=True)
def _lerps(d0, d1, d2, d3, a0, a1, a2, a3, a4, a5):  # pragma: no cover - compiled
    """The de Boor steps of four control points with weights ``a0 .. a5``."""
    d3 = (1.0 - a0) * d2 + a0 * d3
    d2 = (1.0 - a1) * d1 + a1 * d2
    d1 = (1.0 - a2) * d0 + a2 * d1
    d3 = (1.0 - a3) * d2 + a3 * d3
    d2 = (1.0 - a4) * d1 + a4 * d2
    return (1.0 - a5) * d2 + a5 * d3


@numba.njit(inline="always", cache=True)
def _spline_row(x, s, segs, knots, P, scale, m, X, t):  # pragma: no cover - compiled
    """The first ``m`` columns of ``P`` at frame position ``x`` of spline segment ``s``,
    divided by ``scale``, into ``X[t, :m]``."""
    b, a0, a1, a2, a3, a4, a5 = _weights(x, s, segs, knots)
    for c in range(m):
        X[t, c] = _deboor(P, b, c, a0, a1, a2, a3, a4, a5) / scale[c]


@numba.njit(cache=True)
def clip_rotations(segs, knots, P, scale, m, fix_frames, fix_channels, fix_values, kinds,
                   starts, counts, dof_axes, pre, ref, root, rot):  # pragma: no cover  # fmt: skip
    """A whole clip from its coefficient rows to root translation ``root`` ``(T, 3)`` and
    local rotations ``rot`` ``(T, J, 4)``, in one call: whether every channel is finite.

    ``P``'s first ``m`` columns are channels ``0 .. m - 1`` (the root's translation and every
    rotation channel: the columns the rotations read); ``fix_*`` the clip's corrections in
    frame order (frame, channel, value added), as :meth:`quatmotion.codec.repair.Corrections.apply`
    adds them.
    """
    T = root.shape[0]
    J = kinds.shape[0]
    Xr = np.empty((BLOCK, m))
    Xc = np.empty((m, BLOCK))
    Q = np.empty((4, BLOCK))
    finite = True
    s = 0
    k = 0
    nfix = fix_frames.shape[0]
    for f0 in range(0, T, BLOCK):
        n = min(BLOCK, T - f0)
        for t in range(n):
            f = f0 + t
            while segs[s, 0] + segs[s, 1] <= f:
                s += 1
            if segs[s, 3] != 0:
                _spline_row(float(f), s, segs, knots, P, scale, m, Xr, t)
            else:
                r = segs[s, 2] + f - segs[s, 0]
                for c in range(m):
                    Xr[t, c] = P[r, c] / scale[c]
            while k < nfix and fix_frames[k] == f:
                if fix_channels[k] < m:
                    Xr[t, fix_channels[k]] += fix_values[k]
                k += 1
        for t in range(n):
            for c in range(m):
                v = Xr[t, c]
                finite &= v - v == 0.0
                Xc[c, t] = v
        for t in range(n):
            root[f0 + t, 0] = Xr[t, 0]
            root[f0 + t, 1] = Xr[t, 1]
            root[f0 + t, 2] = Xr[t, 2]
        for j in range(J):
            _joint_block(Xc, n, j, kinds, starts, counts, dof_axes, pre, ref, Q)
            for t in range(n):
                rot[f0 + t, j, 0] = Q[0, t]
                rot[f0 + t, j, 1] = Q[1, t]
                rot[f0 + t, j, 2] = Q[2, t]
                rot[f0 + t, j, 3] = Q[3, t]
    return finite


PACK_HEAD = 16
"""Integers before the tables in a packed clip (:func:`_unpack`)."""


@numba.njit(inline="always", cache=True)
def _rows(a, n, m):  # pragma: no cover - compiled
    """``a`` (contiguous, 8-byte items) viewed as ``(n, m)`` rows: a reshape without the call
    into Numba's reshape helper (about 25 ns each, a fifth of a pose)."""
    return as_strided(a, shape=(n, m), strides=(8 * m, 8))


@numba.njit(inline="always", cache=True)
def _unpack(B):  # pragma: no cover - compiled
    """The tables of a packed clip, views of one float64 buffer ``B`` whose first ``I[9]``
    slots are int64 ``I``: a head (segments ``S``, channels ``c``, rows ``n``, joints ``J``,
    correction rows, layout channels ``C``, selected joints ``k``, knots, loop flag, ``I``'s
    length, rows a group and groups when the rows decode by group), then ``segs``, ``cols``,
    ``sel``, ``kinds``, ``starts``, ``counts``, ``dof_axes``; the floats after ``I``: ``fps``,
    ``knots``, ``P``, ``scale``, ``corr``, ``pre``, ``ref``, a flag per group of rows (1.0:
    decoded), two scratch rows ``X`` and ``Y`` ``(C,)``, scratch angles, sines and cosines
    ``(3 J,)`` each and rotations ``(k, 4)``, then one pose's output (``root`` ``(3,)``,
    ``rot`` ``(k, 4)``)."""
    I = B[:PACK_HEAD].view(np.int64)
    S, c, n, J, nc, C, k, nk, ni = I[0], I[1], I[2], I[3], I[4], I[5], I[6], I[7], I[9]
    I = B[:ni].view(np.int64)
    o = PACK_HEAD
    segs = _rows(I[o : o + 6 * S], S, 6)
    o += 6 * S
    cols = I[o : o + c]
    o += c
    sel = I[o : o + k]
    o += k
    kinds = I[o : o + J]
    o += J
    starts = I[o : o + J]
    o += J
    counts = I[o : o + J]
    o += J
    dof_axes = _rows(I[o : o + 3 * J], J, 3)
    f = ni + 1
    knots = B[f : f + nk]
    f += nk
    P = _rows(B[f : f + n * c], n, c)
    f += n * c
    scale = B[f : f + c]
    f += c
    corr = _rows(B[f : f + nc * C], nc, C)
    f += nc * C
    pre = as_strided(B[f : f + 12 * J], shape=(J, 4, 3), strides=(96, 24, 8))
    f += 12 * J
    ref = _rows(B[f : f + 4 * J], J, 4)
    f += 4 * J
    flags = B[f : f + I[11]]
    f += I[11]
    X = _rows(B[f : f + C], 1, C)
    f += C
    Y = _rows(B[f : f + C], 1, C)
    f += C
    A = B[f : f + 9 * J + 4 * k]
    f += 9 * J + 4 * k
    root = B[f : f + 3]
    f += 3
    rot = _rows(B[f : f + 4 * k], k, 4)
    return segs, cols, sel, kinds, starts, counts, dof_axes, B[ni], knots, P, scale, corr, \
        pre, ref, X, Y, A, root, rot, flags  # fmt: skip


@numba.njit(inline="always", cache=True)
def _frame(i, segs, knots, P, cols, scale, corr, X, t):  # pragma: no cover - compiled
    """The decoded channels ``cols`` of frame ``i`` (corrections added) into column ``t`` of
    channel-major ``X`` ``(C, B)``."""
    s = _segment_of(segs, i)
    if segs[s, 3] != 0:
        b, a0, a1, a2, a3, a4, a5 = _weights(float(i), s, segs, knots)
        for c in range(cols.shape[0]):
            X[cols[c], t] = _deboor(P, b, c, a0, a1, a2, a3, a4, a5) / scale[c]
    else:
        r = segs[s, 2] + i - segs[s, 0]
        for c in range(cols.shape[0]):
            X[cols[c], t] = P[r, c] / scale[c]
    if corr.shape[0] > 0:
        for c in range(cols.shape[0]):
            X[cols[c], t] += corr[i, cols[c]]


@numba.njit(inline="always", cache=True)
def _spline_at(x, segs, knots, P, cols, scale, corr, X, t):  # pragma: no cover - compiled
    """The channels ``cols`` at frame position ``x`` into column ``t`` of channel-major ``X``
    ``(C, B)`` where a spline spans ``x`` (corrections lerped between frames): whether one
    does."""
    s = _spline_segment(x, segs)
    if s < 0:
        return False
    b, a0, a1, a2, a3, a4, a5 = _weights(x, s, segs, knots)
    for c in range(cols.shape[0]):
        X[cols[c], t] = _deboor(P, b, c, a0, a1, a2, a3, a4, a5) / scale[c]
    _corrections_at(x, segs, cols, corr, X, t)
    return True


@numba.njit(inline="always", cache=True)
def _spline_segment(x, segs):  # pragma: no cover - compiled
    """The spline segment spanning frame position ``x``, or -1."""
    T = segs[segs.shape[0] - 1, 0] + segs[segs.shape[0] - 1, 1]
    s = _segment_of(segs, min(int(np.floor(x)), T - 1))
    if segs[s, 3] == 0 or x > segs[s, 0] + segs[s, 1] - 1:
        return -1
    return s


@numba.njit(inline="always", cache=True)
def _corrections_at(x, segs, cols, corr, X, t):  # pragma: no cover - compiled
    """The corrections of channels ``cols`` lerped at ``x`` added to column ``t`` of ``X``."""
    if corr.shape[0] > 0:
        T = segs[segs.shape[0] - 1, 0] + segs[segs.shape[0] - 1, 1]
        i0 = min(int(np.floor(x)), T - 1)
        f = x - i0
        i1 = min(i0 + 1, T - 1)
        for c in range(cols.shape[0]):
            ch = cols[c]
            X[ch, t] += (1.0 - f) * corr[i0, ch] + f * corr[i1, ch]


@numba.njit(inline="always", cache=True)
def _neighbours(x, loop, segs, knots, P, cols, scale, corr, X, Y, t):  # pragma: no cover  # noqa: E501
    """Where no spline spans ``x``: the two neighbouring decoded frames' channels into column
    ``t`` of ``X`` and ``Y``; the fraction of the way from the first to the second."""
    T = segs[segs.shape[0] - 1, 0] + segs[segs.shape[0] - 1, 1]
    i0 = min(int(np.floor(x)), T - 1)
    b = (i0 + 1) % T if loop else min(i0 + 1, T - 1)
    _frame(i0, segs, knots, P, cols, scale, corr, X, t)
    _frame(b, segs, knots, P, cols, scale, corr, Y, t)
    return x - i0


@numba.njit(inline="always", cache=True)
def _nlerp(f, aw, ax, ay, az, bw, bx, by, bz):  # pragma: no cover - compiled
    """The normalised lerp (shorter arc) of two rotations, ``a`` itself at ``f = 0`` (a frame,
    as the whole clip decodes it)."""
    if f == 0.0:
        return aw, ax, ay, az
    g = 1.0 - f
    h = -f if aw * bw + ax * bx + ay * by + az * bz < 0.0 else f  # the shorter arc
    vw, vx, vy, vz = g * aw + h * bw, g * ax + h * bx, g * ay + h * by, g * az + h * bz
    norm = np.sqrt(vw * vw + vx * vx + vy * vy + vz * vz)
    return vw / norm, vx / norm, vy / norm, vz / norm


@numba.njit(cache=True)
def pose(t, B):  # pragma: no cover - compiled
    """One pose of a packed clip (:func:`_unpack`) at ``t`` seconds into its output slots:
    clamped to the clip, or wrapped with period ``T / fps`` if its loop flag is set. Returns
    1; 0 for a time that is not finite, ``2 + g`` when the pose needs group ``g`` of rows,
    not decoded yet (nothing written either way)."""
    segs, cols, sel, kinds, starts, counts, dof_axes, fps, knots, P, scale, corr, pre, ref, \
        X, Y, A, root, rot, flags = _unpack(B)  # fmt: skip
    x = t * fps
    if not np.isfinite(x):
        return 0
    S = segs.shape[0]
    T = segs[S - 1, 0] + segs[S - 1, 1]
    head = B[:PACK_HEAD].view(np.int64)
    loop = head[8] != 0
    x = x % T if loop else min(max(x, 0.0), T - 1.0)
    if head[10] > 0:
        g = _missing_group(x, loop, segs, knots, flags, head[10])
        if g >= 0:
            return 2 + g
    Xc = as_strided(X[0], shape=(X.shape[1], 1), strides=(8, 8))
    if _spline_at(x, segs, knots, P, cols, scale, corr, Xc, 0):
        root[0] = X[0, 0]
        root[1] = X[0, 1]
        root[2] = X[0, 2]
        J = kinds.shape[0]
        _pose_rotations(X, sel, kinds, starts, counts, dof_axes, pre, ref, A[: 3 * J],
                        A[3 * J : 6 * J], A[6 * J : 9 * J], rot)  # fmt: skip
    else:
        Yc = as_strided(Y[0], shape=(Y.shape[1], 1), strides=(8, 8))
        f = _neighbours(x, loop, segs, knots, P, cols, scale, corr, Xc, Yc, 0)
        for c in range(3):
            root[c] = (1.0 - f) * X[0, c] + f * Y[0, c]
        J = kinds.shape[0]
        _pose_rotations(X, sel, kinds, starts, counts, dof_axes, pre, ref, A[: 3 * J],
                        A[3 * J : 6 * J], A[6 * J : 9 * J], rot)  # fmt: skip
        if f != 0.0:
            R = _rows(A[9 * J : 9 * J + 4 * rot.shape[0]], rot.shape[0], 4)
            _pose_rotations(Y, sel, kinds, starts, counts, dof_axes, pre, ref, A[: 3 * J],
                            A[3 * J : 6 * J], A[6 * J : 9 * J], R)  # fmt: skip
            for jj in range(rot.shape[0]):
                w, qx, qy, qz = _nlerp(f, rot[jj, 0], rot[jj, 1], rot[jj, 2], rot[jj, 3],
                                       R[jj, 0], R[jj, 1], R[jj, 2], R[jj, 3])  # fmt: skip
                rot[jj, 0] = w
                rot[jj, 1] = qx
                rot[jj, 2] = qy
                rot[jj, 3] = qz
    return 1


@numba.njit(inline="always", cache=True)
def _rows_of_frame(i, segs, knots):  # pragma: no cover - compiled
    """The first and last coefficient row frame ``i`` is evaluated from."""
    s = _segment_of(segs, i)
    if segs[s, 3] != 0:
        b = _weights(float(i), s, segs, knots)[0]
        return b, b + 3
    r = segs[s, 2] + i - segs[s, 0]
    return r, r


@numba.njit(inline="always", cache=True)
def _missing_group(x, loop, segs, knots, flags, G):  # pragma: no cover - compiled
    """The first group of rows (``G`` a group) the pose at ``x`` needs whose flag is not
    set, or -1."""
    s = _spline_segment(x, segs)
    if s >= 0:
        b = _weights(x, s, segs, knots)[0]
        lo, hi = b, b + 3
    else:
        T = segs[segs.shape[0] - 1, 0] + segs[segs.shape[0] - 1, 1]
        i0 = min(int(np.floor(x)), T - 1)
        i1 = (i0 + 1) % T if loop else min(i0 + 1, T - 1)
        lo, hi = _rows_of_frame(i0, segs, knots)
        lo1, hi1 = _rows_of_frame(i1, segs, knots)
        for g in range(lo1 // G, hi1 // G + 1):
            if flags[g] == 0.0:
                return g
    for g in range(lo // G, hi // G + 1):
        if flags[g] == 0.0:
            return g
    return -1


@functools.cache
def pose_entry():  # type: ignore[no-untyped-def]
    """:func:`pose` as the function it compiles to for a packed clip's argument types (a
    float and a contiguous float64 array): called without the dispatcher's resolution of
    types, 0.31 -> 0.17 µs a call measured here. Its one caller, the Sampler, passes exactly
    these (a ``float(t)`` and its own buffer). Made once (``Dispatcher.compile`` costs about
    100 µs even when the function is compiled: a Sampler's first pose would pay it)."""
    return pose.compile((numba.float64, numba.types.Array(numba.float64, 1, "C")))


@numba.njit(cache=True)
def poses(u, B, out_root, out_rot):  # pragma: no cover - compiled
    """Poses of a packed clip at frame positions ``u`` (already clamped or wrapped) into
    ``out_root`` ``(n, 3)`` and ``out_rot`` ``(n, k, 4)``, a block of poses at a time: each
    pose's channels, then each joint's rotations in one loop over the block."""
    segs, cols, sel, kinds, starts, counts, dof_axes, fps, knots, P, scale, corr, pre, ref, \
        X, Y, _, _, _, _ = _unpack(B)  # fmt: skip
    loop = B[:PACK_HEAD].view(np.int64)[8] != 0
    C = X.shape[1]
    Xc = np.zeros((C, BLOCK))
    Yc = np.zeros((C, BLOCK))
    Q = np.empty((4, BLOCK))
    R = np.empty((4, BLOCK))
    frac = np.empty(BLOCK)  # -1 where a spline spans the pose, else between two frames
    for p0 in range(0, u.shape[0], BLOCK):
        n = min(BLOCK, u.shape[0] - p0)
        between = False
        for t in range(n):
            x = u[p0 + t]
            if _spline_at(x, segs, knots, P, cols, scale, corr, Xc, t):
                frac[t] = -1.0
                for c in range(3):
                    out_root[p0 + t, c] = Xc[c, t]
            else:
                f = _neighbours(x, loop, segs, knots, P, cols, scale, corr, Xc, Yc, t)
                frac[t] = f
                between = True
                for c in range(3):
                    out_root[p0 + t, c] = (1.0 - f) * Xc[c, t] + f * Yc[c, t]
        for jj in range(sel.shape[0]):
            _joint_block(Xc, n, sel[jj], kinds, starts, counts, dof_axes, pre, ref, Q)
            if between:
                _joint_block(Yc, n, sel[jj], kinds, starts, counts, dof_axes, pre, ref, R)
            for t in range(n):
                w, qx, qy, qz = Q[0, t], Q[1, t], Q[2, t], Q[3, t]
                if frac[t] > 0.0:
                    w, qx, qy, qz = _nlerp(frac[t], w, qx, qy, qz, R[0, t], R[1, t], R[2, t],
                                           R[3, t])  # fmt: skip
                out_rot[p0 + t, jj, 0] = w
                out_rot[p0 + t, jj, 1] = qx
                out_rot[p0 + t, jj, 2] = qy
                out_rot[p0 + t, jj, 3] = qz
