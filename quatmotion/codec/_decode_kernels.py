"""Compiled loops of the runtime decoder (:mod:`quatmotion.codec.sampling`).

Kernels trust their input: the public functions there validate and lay arrays out once.

Conventions
-----------
* A clip's segments are a table ``segs`` ``(S, 6)``: first frame, frames, first coefficient
  row, whether it is a spline, and the span of its clamped knot vector in ``knots``
  (:class:`quatmotion.codec.spline.SegmentTables` side by side); ``P`` holds every segment's
  coefficient rows, one column per channel evaluated. The de Boor steps are those of
  :func:`quatmotion.codec.spline._evaluate_channels`, so frame times give the decoded frames
  to the bit.
* Positions ``x`` are in frames from the clip's first frame, within ``[0, T - 1]`` (``T`` for
  the loop's wrap).
"""

from __future__ import annotations

import numba
import numpy as np

from quatmotion.codec.channels import rotation_row

__all__ = ["PACK_HEAD", "pose_packed", "poses_packed", "read_uvarints", "sample_poses"]


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
def _channels_at(x, s, segs, knots, P, cols, scale, X):  # pragma: no cover - compiled
    """The channels ``cols`` at frame position ``x`` of segment ``s`` into ``X[0]``: the
    spline (the de Boor steps of :func:`quatmotion.codec.spline._evaluate_channels`, so frame
    times give the decoded frames to the bit) or, in a segment kept frame by frame, the row
    of frame ``x`` (an integer)."""
    a = segs[s, 0]
    r0 = segs[s, 2]
    if segs[s, 3] == 0:
        f = r0 + int(x) - a
        for k in range(cols.shape[0]):
            X[0, cols[k]] = P[f, k] / scale[k]
        return
    t0 = segs[s, 4]
    n = segs[s, 5] - t0 - 4
    xv = x - a
    lo = 3  # the last i in [3, n - 1] with t[i] <= x, as _evaluate_channels walks to it
    hi = n - 1
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if xv >= knots[t0 + mid]:
            lo = mid
        else:
            hi = mid - 1
    iv = t0 + lo
    # the de Boor weights of _evaluate_channels' loop (r, q) = (1, 3), (1, 2), (1, 1), (2, 3),
    # (2, 2), (3, 3), as scalars
    a0 = _alpha(knots, iv, 3, xv)
    a1 = _alpha(knots, iv - 1, 3, xv)
    a2 = _alpha(knots, iv - 2, 3, xv)
    a3 = _alpha(knots, iv, 2, xv)
    a4 = _alpha(knots, iv - 1, 2, xv)
    a5 = _alpha(knots, iv, 1, xv)
    interval = lo
    b = r0 + interval - 3
    for c in range(cols.shape[0]):
        d0, d1, d2, d3 = P[b, c], P[b + 1, c], P[b + 2, c], P[b + 3, c]
        d3 = (1.0 - a0) * d2 + a0 * d3
        d2 = (1.0 - a1) * d1 + a1 * d2
        d1 = (1.0 - a2) * d0 + a2 * d1
        d3 = (1.0 - a3) * d2 + a3 * d3
        d2 = (1.0 - a4) * d1 + a4 * d2
        d3 = (1.0 - a5) * d2 + a5 * d3
        X[0, cols[c]] = d3 / scale[c]


@numba.njit(inline="always", cache=True)
def _frame(i, segs, knots, P, cols, scale, corr, X):  # pragma: no cover - compiled
    """The decoded channels ``cols`` of frame ``i`` (corrections added) into ``X[0]``."""
    _channels_at(float(i), _segment_of(segs, i), segs, knots, P, cols, scale, X)
    if corr.shape[0] > 0:
        for k in range(cols.shape[0]):
            X[0, cols[k]] += corr[i, cols[k]]


@numba.njit(cache=True)
def sample_poses(
    u, loop, segs, knots, P, cols, scale, corr, sel, kinds, starts, counts, dof_axes, pre, ref,
    out_root, out_rot,
):  # pragma: no cover  # fmt: skip
    """Root translation and rotations of joints ``sel`` at frame positions ``u`` (already
    clamped or wrapped) of a clip of ``T = corr.shape[0]`` frames (or ``segs``' last frame).

    ``segs`` ``(S, 6)``: each segment's first frame, frames, first coefficient row, whether it
    is a spline, and its knots' span in ``knots``; ``P`` the coefficient rows of the channels
    ``cols`` (divided by ``scale``), ``corr`` ``(T, C)`` the clip's corrections (or no rows).
    Where a spline spans ``u`` the pose is the spline's (corrections lerped between frames),
    elsewhere the nlerp of the two neighbouring decoded frames' rotations.
    """
    S = segs.shape[0]
    T = segs[S - 1, 0] + segs[S - 1, 1]
    C = 3
    for k in range(cols.shape[0]):
        C = max(C, cols[k] + 1)
    X = np.zeros((1, C))
    Y = np.zeros((1, C))
    for k in range(u.shape[0]):
        x = u[k]
        i0 = min(int(np.floor(x)), T - 1)
        f = x - i0
        s = _segment_of(segs, i0)
        if segs[s, 3] != 0 and x <= segs[s, 0] + segs[s, 1] - 1:
            _channels_at(x, s, segs, knots, P, cols, scale, X)
            if corr.shape[0] > 0:
                i1 = min(i0 + 1, T - 1)
                for c in range(cols.shape[0]):
                    ch = cols[c]
                    X[0, ch] += (1.0 - f) * corr[i0, ch] + f * corr[i1, ch]
            for c in range(3):
                out_root[k, c] = X[0, c]
            for j in range(sel.shape[0]):
                w, qx, qy, qz = rotation_row(
                    X, 0, sel[j], kinds, starts, counts, dof_axes, pre, ref
                )
                out_rot[k, j, 0] = w
                out_rot[k, j, 1] = qx
                out_rot[k, j, 2] = qy
                out_rot[k, j, 3] = qz
            continue
        b = (i0 + 1) % T if loop else min(i0 + 1, T - 1)
        _frame(i0, segs, knots, P, cols, scale, corr, X)
        _frame(b, segs, knots, P, cols, scale, corr, Y)
        for c in range(3):
            out_root[k, c] = (1.0 - f) * X[0, c] + f * Y[0, c]
        for j in range(sel.shape[0]):
            q = sel[j]
            aw, ax, ay, az = rotation_row(X, 0, q, kinds, starts, counts, dof_axes, pre, ref)
            bw, bx, by, bz = rotation_row(Y, 0, q, kinds, starts, counts, dof_axes, pre, ref)
            g = 1.0 - f
            h = -f if aw * bw + ax * bx + ay * by + az * bz < 0.0 else f  # the shorter arc
            vw, vx, vy, vz = g * aw + h * bw, g * ax + h * bx, g * ay + h * by, g * az + h * bz
            norm = np.sqrt(vw * vw + vx * vx + vy * vy + vz * vz)
            out_rot[k, j, 0] = vw / norm
            out_rot[k, j, 1] = vx / norm
            out_rot[k, j, 2] = vy / norm
            out_rot[k, j, 3] = vz / norm


@numba.njit(cache=True)
def read_uvarints(buf, pos, out):  # pragma: no cover
    """LEB128 varints from ``buf`` (uint8) at ``pos`` into ``out`` (uint64, its length many);
    the position after them, ``-1`` if the data end first, ``-2`` for a varint over 64 bits."""
    n = buf.shape[0]
    for k in range(out.shape[0]):
        value = np.uint64(0)
        shift = 0
        while True:
            if pos >= n:
                return -1
            byte = buf[pos]
            pos += 1
            value |= np.uint64(byte & 0x7F) << np.uint64(shift)
            if not byte & 0x80:
                break
            shift += 7
            if shift > 63:
                return -2
        out[k] = value
    return pos


PACK_HEAD = 16
"""Integers before the tables in a packed clip (:func:`pose_packed`)."""


@numba.njit(inline="always", cache=True)
def _unpack(I, F):  # pragma: no cover - compiled
    """The tables of :func:`sample_poses` as views of a packed clip: ``I`` int64 holds a head
    (segments ``S``, channels ``c``, rows ``n``, joints ``J``, correction rows, layout
    channels ``C``, selected joints ``k``, knots, loop flag) then ``segs``, ``cols``, ``sel``,
    ``kinds``, ``starts``, ``counts``, ``dof_axes``; ``F`` float64 holds ``fps``, then
    ``knots``, ``P``, ``scale``, ``corr``, ``pre``, ``ref``, then one pose's output
    (``root`` (3,), ``rot`` (k, 4)) and the one position ``u``."""
    S, c, n, J, nc, C, k, nk = I[0], I[1], I[2], I[3], I[4], I[5], I[6], I[7]
    o = PACK_HEAD
    segs = I[o : o + 6 * S].reshape((S, 6))
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
    dof_axes = I[o : o + 3 * J].reshape((J, 3))
    f = 1
    knots = F[f : f + nk]
    f += nk
    P = F[f : f + n * c].reshape((n, c))
    f += n * c
    scale = F[f : f + c]
    f += c
    corr = F[f : f + nc * C].reshape((nc, C))
    f += nc * C
    pre = F[f : f + 12 * J].reshape((J, 4, 3))
    f += 12 * J
    ref = F[f : f + 4 * J].reshape((J, 4))
    f += 4 * J
    root = F[f : f + 3].reshape((1, 3))
    f += 3
    rot = F[f : f + 4 * k].reshape((1, k, 4))
    f += 4 * k
    u = F[f : f + 1]
    return segs, cols, sel, kinds, starts, counts, dof_axes, knots, P, scale, corr, pre, ref, \
        root, rot, u  # fmt: skip


@numba.njit(cache=True)
def pose_packed(t, I, F):  # pragma: no cover - compiled
    """One pose of a packed clip (:func:`_unpack`) at ``t`` seconds (finite) into its output
    slots of ``F``: clamped to the clip, or wrapped with period ``T / fps`` if ``I[8]``."""
    segs, cols, sel, kinds, starts, counts, dof_axes, knots, P, scale, corr, pre, ref, \
        root, rot, u = _unpack(I, F)  # fmt: skip
    S = segs.shape[0]
    T = segs[S - 1, 0] + segs[S - 1, 1]
    x = t * F[0]
    u[0] = x % T if I[8] else min(max(x, 0.0), T - 1.0)
    sample_poses(u, I[8] != 0, segs, knots, P, cols, scale, corr, sel, kinds, starts, counts,
                 dof_axes, pre, ref, root, rot)  # fmt: skip


@numba.njit(cache=True)
def poses_packed(u, I, F, out_root, out_rot):  # pragma: no cover - compiled
    """Poses of a packed clip at frame positions ``u`` (already clamped or wrapped)."""
    segs, cols, sel, kinds, starts, counts, dof_axes, knots, P, scale, corr, pre, ref, \
        _, _, _ = _unpack(I, F)  # fmt: skip
    sample_poses(u, I[8] != 0, segs, knots, P, cols, scale, corr, sel, kinds, starts, counts,
                 dof_axes, pre, ref, out_root, out_rot)  # fmt: skip
