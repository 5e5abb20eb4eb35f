"""Compiled loops of the runtime decoder (:mod:`quatmotion.codec.sampling`).

Kernels trust their input: the public functions there validate and lay arrays out once.

Conventions
-----------
* A clip's spline is flattened across segments: ``knots`` holds every spline segment's clamped
  knot vector back to back (``knot_start[s]`` .. ``knot_start[s + 1]``), ``coef`` every
  segment's coefficient rows (``row_start[s]`` ..), one column per channel evaluated.
* Positions ``x`` are in frames from the segment's first frame, within ``[0, L - 1]``.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["evaluate_at", "nlerp_rows"]


@numba.njit(cache=True)
def evaluate_at(knots, knot_start, coef, row_start, seg, x, out):  # pragma: no cover
    """``out[k] = spline_seg[k](x[k])`` for every sample ``k`` (de Boor, as
    :func:`quatmotion.codec.spline._evaluate` so that frame times give the same values).

    Shapes: ``seg, x`` (n,), ``coef`` (rows, c), ``out`` (n, c).
    """
    C = coef.shape[1]
    d = np.empty((4, C))
    for k in range(x.shape[0]):
        s = seg[k]
        t0 = knot_start[s]
        m = knot_start[s + 1] - t0  # knots in this segment
        n = m - 4  # coefficient rows
        r0 = row_start[s]
        xv = x[k]
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
def nlerp_rows(a, b, frac, out):  # pragma: no cover
    """Normalised lerp of unit quaternions ``a, b`` ``(n, J, 4)`` by ``frac`` ``(n,)`` along
    the shorter arc, into ``out``."""
    n, J = a.shape[0], a.shape[1]
    for k in range(n):
        f = frac[k]
        for j in range(J):
            dot = a[k, j, 0] * b[k, j, 0] + a[k, j, 1] * b[k, j, 1]
            dot += a[k, j, 2] * b[k, j, 2] + a[k, j, 3] * b[k, j, 3]
            sign = -1.0 if dot < 0.0 else 1.0
            norm = 0.0
            for c in range(4):
                v = (1.0 - f) * a[k, j, c] + f * sign * b[k, j, c]
                out[k, j, c] = v
                norm += v * v
            norm = np.sqrt(norm)
            for c in range(4):
                out[k, j, c] /= norm
