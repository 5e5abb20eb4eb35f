"""Cubic B-splines over frames: knot vectors, least-squares fits, fast evaluation.

Conventions
-----------
* A clip is cut into **segments** at break frames (glitches the temporal model must not smooth
  away): segment ``s`` holds frames ``[b_s, b_{s+1})``. Each segment has its own clamped cubic
  knot vector on ``[0, L - 1]`` (frames counted from the segment's start): about ``(L - 1) / k``
  uniform intervals for knot spacing ``k`` frames, plus any **inserted knots** (integer frames)
  where the encoder refined the fit. A segment shorter than :data:`MIN_SPLINE_FRAMES` keeps
  one coefficient row per frame (the identity basis).
* Coefficients of a segment are ``(n, C)``: ``n = n_intervals + 3`` rows (cubic), or ``L`` rows
  for a short segment. The rows of all segments, in order, are what the entropy coder sees.
* A spacing below 2 frames means no spline at all: every segment keeps its frames (the
  identity basis), for bounds tighter than the capture's frame-to-frame noise.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import make_lsq_spline

__all__ = [
    "MIN_SPLINE_FRAMES",
    "evaluate_segments",
    "fit_segments",
    "knot_vector",
    "n_rows",
    "segment_bounds",
]

MIN_SPLINE_FRAMES = 8
"""Segments shorter than this keep their frames as they are (one row per frame)."""


def segment_bounds(n_frames: int, breaks: list[int] | NDArray[np.int64]) -> list[tuple[int, int]]:
    """``[(start, stop), ...]`` of the segments of a clip cut before each break frame."""
    cuts = [0, *sorted(int(b) for b in breaks), n_frames]
    return [(cuts[i], cuts[i + 1]) for i in range(len(cuts) - 1)]


def knot_vector(length: int, spacing: float, inserted=()) -> NDArray[np.float64]:
    """Clamped cubic knots on ``[0, length - 1]``: uniform intervals of about ``spacing`` frames
    plus ``inserted`` interior knots. ``(n_intervals + 7,)``."""
    n = max(1, int(round((length - 1) / spacing)))
    inner = np.linspace(0.0, length - 1.0, n + 1)
    if len(inserted):
        inner = np.unique(np.concatenate((inner, np.asarray(inserted, dtype=np.float64))))
    end = float(length - 1)
    return np.concatenate(([0.0] * 3, inner, [end] * 3))


def n_rows(length: int, spacing: float, inserted=()) -> int:
    """Coefficient rows of a segment of ``length`` frames."""
    if length < MIN_SPLINE_FRAMES or spacing < 2:
        return length
    return len(knot_vector(length, spacing, inserted)) - 4


def fit_segments(
    Y: NDArray[np.float64], breaks, spacing: float, inserted: dict[int, list[int]] | None = None
) -> list[NDArray[np.float64]]:
    """Least-squares cubic B-spline coefficients of each segment of ``Y`` ``(T, C)``.

    Returns
    -------
    list of ndarray, each (n_s, C)
    """
    inserted = inserted or {}
    out = []
    for s, (a, b) in enumerate(segment_bounds(len(Y), breaks)):
        L = b - a
        if L < MIN_SPLINE_FRAMES or spacing < 2:
            out.append(np.array(Y[a:b], dtype=np.float64))
            continue
        t = knot_vector(L, spacing, inserted.get(s, ()))
        x = np.arange(L, dtype=np.float64)
        out.append(make_lsq_spline(x, Y[a:b], t, k=3, axis=0).c)
    return out


@numba.njit(cache=True)
def _evaluate(t, c, L, out, row0):  # pragma: no cover - compiled
    """Cubic B-spline with knots ``t`` and coefficients ``c`` at frames 0..L-1 into
    ``out[row0 + frame]`` (de Boor)."""
    C = c.shape[1]
    n = c.shape[0]
    interval = 3
    d = np.empty((4, C))
    for f in range(L):
        x = float(f)
        while interval < n - 1 and x >= t[interval + 1]:
            interval += 1
        for r in range(4):
            for ch in range(C):
                d[r, ch] = c[interval - 3 + r, ch]
        for r in range(1, 4):
            for q in range(3, r - 1, -1):
                i = interval - 3 + q
                den = t[i + 4 - r] - t[i]
                alpha = (x - t[i]) / den if den > 0.0 else 0.0
                for ch in range(C):
                    d[q, ch] = (1.0 - alpha) * d[q - 1, ch] + alpha * d[q, ch]
        for ch in range(C):
            out[row0 + f, ch] = d[3, ch]


def evaluate_segments(
    coefficients: list[NDArray[np.float64]],
    n_frames: int,
    breaks,
    spacing: float,
    inserted: dict[int, list[int]] | None = None,
) -> NDArray[np.float64]:
    """The ``(T, C)`` signals of :func:`fit_segments`' coefficients."""
    inserted = inserted or {}
    C = coefficients[0].shape[1] if coefficients else 0
    out = np.empty((n_frames, C))
    for s, ((a, b), c) in enumerate(
        zip(segment_bounds(n_frames, breaks), coefficients, strict=True)
    ):
        L = b - a
        if L < MIN_SPLINE_FRAMES or spacing < 2:
            out[a:b] = c
        else:
            t = knot_vector(L, spacing, inserted.get(s, ()))
            _evaluate(t, np.ascontiguousarray(c, dtype=np.float64), L, out, a)
    return out


class SplineBasis:
    """The B-spline basis of a whole clip (all segments), for many least-squares fits.

    ``B`` is the sparse ``(T, n)`` design matrix (a short segment contributes identity rows);
    the Gram matrix ``B^T B`` is banded (cubic: 3 off-diagonals, segments do not overlap), so a
    fit is one sparse product and one banded Cholesky solve: cheap enough to fit each joint's
    channels separately, as hierarchical compensation needs.
    """

    def __init__(self, n_frames: int, breaks, spacing: float, inserted=None):
        from scipy.interpolate import BSpline
        from scipy.sparse import block_diag, identity

        inserted = inserted or {}
        blocks = []
        for s, (a, b) in enumerate(segment_bounds(n_frames, breaks)):
            L = b - a
            if L < MIN_SPLINE_FRAMES or spacing < 2:
                blocks.append(identity(L, format="csr"))
            else:
                t = knot_vector(L, spacing, inserted.get(s, ()))
                blocks.append(BSpline.design_matrix(np.arange(L, dtype=np.float64), t, 3))
        self.B = block_diag(blocks, format="csr")
        self.Bt = self.B.T.tocsr()
        gram = (self.Bt @ self.B).toarray() if self.B.shape[1] <= 2048 else None
        n = self.B.shape[1]
        if gram is None:
            gram = (self.Bt @ self.B).todia()
            ab = np.zeros((4, n))
            for u in range(4):
                diag = gram.diagonal(u)
                ab[3 - u, u:] = diag
        else:
            ab = np.zeros((4, n))
            for u in range(4):
                ab[3 - u, u:] = np.diagonal(gram, u)
        self._banded = ab

    @property
    def n_rows(self) -> int:
        return self.B.shape[1]

    def fit(self, Y: NDArray[np.float64]) -> NDArray[np.float64]:
        """Least-squares coefficients ``(n, c)`` of ``Y`` ``(T, c)``."""
        from scipy.linalg import solveh_banded

        return solveh_banded(self._banded, self.Bt @ Y)

    def evaluate(self, coefficients: NDArray[np.float64]) -> NDArray[np.float64]:
        """``B c``: ``(n, c) -> (T, c)``."""
        return self.B @ coefficients
