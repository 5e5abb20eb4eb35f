"""Compiled loops of the runtime decoder (:mod:`quatmotion.codec.sampling`).

Kernels trust their input: the public functions there validate and lay arrays out once.

Conventions
-----------
* A clip's spline is flattened across segments: ``knots`` holds every spline segment's clamped
  knot vector back to back (``knot_start[s]`` .. ``knot_start[s + 1]``), ``coef`` every
  segment's coefficient rows (``row_start[s]`` ..), one column per channel evaluated; the
  de Boor steps are :func:`quatmotion.codec.spline._evaluate`'s, so that frame times give the
  decoded frames.
* Positions ``x`` are in frames from the segment's first frame, within ``[0, L - 1]``.
"""

from __future__ import annotations

import numba
import numpy as np

from quatmotion.codec.channels import _rotations_kernel

__all__ = ["read_uvarints", "sample_poses"]


@numba.njit(cache=True)
def _evaluate_point(knots, t0, m, coef, r0, xv, d, out, k):  # pragma: no cover
    """One segment's spline at ``xv`` into ``out[k]`` (``d`` is ``(4, c)`` scratch)."""
    C = coef.shape[1]
    n = m - 4  # coefficient rows
    # the interval as _evaluate walks to it: the last i in [3, n - 1] with t[i] <= x
    lo = 3
    hi = n - 1
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if xv >= knots[t0 + mid]:
            lo = mid
        else:
            hi = mid - 1
    interval = lo
    for r in range(4):
        for ch in range(C):
            d[r, ch] = coef[r0 + interval - 3 + r, ch]
    for r in range(1, 4):
        for q in range(3, r - 1, -1):
            i = interval - 3 + q
            den = knots[t0 + i + 4 - r] - knots[t0 + i]
            alpha = (xv - knots[t0 + i]) / den if den > 0.0 else 0.0
            for ch in range(C):
                d[q, ch] = (1.0 - alpha) * d[q - 1, ch] + alpha * d[q, ch]
    for ch in range(C):
        out[k, ch] = d[3, ch]


@numba.njit(cache=True)
def sample_poses(
    u,
    loop,
    seg_first,
    seg_last,
    knots,
    knot_start,
    coef,
    row_start,
    cols,
    scale,
    corr,
    channels,
    frame_rot,
    sel,
    kinds,
    starts,
    counts,
    dof_axes,
    pre,
    ref,
    out_root,
    out_rot,
):  # pragma: no cover
    """Root translation and rotations of joints ``sel`` at frame positions ``u`` (already
    clamped or wrapped): the spline (``coef`` columns ``cols`` of the channels, divided by
    ``scale``, plus the lerp of ``corr`` when it has rows) where a spline segment spans ``u``,
    else the nlerp of ``frame_rot`` and lerp of ``channels`` between the neighbouring frames.
    ``kinds`` .. ``ref`` are the rotation tables of the joints ``sel``."""
    T = channels.shape[0]
    C = channels.shape[1]
    S = seg_first.shape[0]
    X = np.zeros((1, C))
    vals = np.empty((1, coef.shape[1]))
    d = np.empty((4, coef.shape[1]))
    for k in range(u.shape[0]):
        x = u[k]
        i0 = min(int(np.floor(x)), T - 1)
        f = x - i0
        lo, hi = 0, S - 1  # the last segment starting at or before x
        s = -1
        while lo <= hi:
            mid = (lo + hi) // 2
            if seg_first[mid] <= x:
                s = mid
                lo = mid + 1
            else:
                hi = mid - 1
        if s >= 0 and x <= seg_last[s]:
            t0 = knot_start[s]
            _evaluate_point(
                knots,
                t0,
                knot_start[s + 1] - t0,
                coef,
                row_start[s],
                x - seg_first[s],
                d,
                vals,
                0,
            )
            for c in range(C):
                X[0, c] = 0.0
            for ch in range(cols.shape[0]):
                X[0, cols[ch]] = vals[0, ch] / scale[ch]
            if corr.shape[0] > 0:
                i1 = min(i0 + 1, T - 1)
                for c in range(C):
                    X[0, c] += (1.0 - f) * corr[i0, c] + f * corr[i1, c]
            for c in range(3):
                out_root[k, c] = X[0, c]
            R = _rotations_kernel(X, kinds, starts, counts, dof_axes, pre, ref)
            for j in range(sel.shape[0]):
                for c in range(4):
                    out_rot[k, j, c] = R[0, j, c]
        else:
            b = (i0 + 1) % T if loop else min(i0 + 1, T - 1)
            for c in range(3):
                out_root[k, c] = (1.0 - f) * channels[i0, c] + f * channels[b, c]
            for j in range(sel.shape[0]):
                q = sel[j]
                dot = 0.0
                for c in range(4):
                    dot += frame_rot[i0, q, c] * frame_rot[b, q, c]
                sign = -1.0 if dot < 0.0 else 1.0
                norm = 0.0
                for c in range(4):
                    v = (1.0 - f) * frame_rot[i0, q, c] + f * sign * frame_rot[b, q, c]
                    out_rot[k, j, c] = v
                    norm += v * v
                norm = np.sqrt(norm)
                for c in range(4):
                    out_rot[k, j, c] /= norm


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
