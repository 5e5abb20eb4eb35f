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

from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

__all__ = [
    "MIN_SPLINE_FRAMES",
    "SegmentTables",
    "evaluate_channels",
    "evaluate_segments",
    "segment_tables",
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
    from scipy.interpolate import make_lsq_spline  # the encoder's: a reader never fits

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


@dataclass(frozen=True)
class SegmentTables:
    """A clip's segments flattened for the compiled evaluators (:func:`segment_tables`).

    ``first[s]``, ``length[s]`` and ``rows[s]`` are segment ``s``'s first frame, frames and
    first coefficient row; ``spline[s]`` whether it is a spline (else one row per frame);
    ``knots[knot_start[s] : knot_start[s + 1]]`` its clamped knot vector (empty for frames).
    """

    first: NDArray[np.int64]
    length: NDArray[np.int64]
    rows: NDArray[np.int64]
    spline: NDArray[np.bool_]
    knots: NDArray[np.float64]
    knot_start: NDArray[np.int64]
    n_rows: int

    def packed(self) -> NDArray[np.int64]:
        """The table side by side, ``(S, 6)``: each segment's first frame, frames, first row,
        whether it is a spline, and its knots' span (the runtime's ``segs``)."""
        segs = np.empty((len(self.first), 6), dtype=np.int64)
        segs[:, 0] = self.first
        segs[:, 1] = self.length
        segs[:, 2] = self.rows
        segs[:, 3] = self.spline
        segs[:, 4] = self.knot_start[:-1]
        segs[:, 5] = self.knot_start[1:]
        return segs


def segment_tables(
    n_frames: int, breaks, spacing: float, inserted: dict[int, tuple[int, ...]] | None = None
) -> SegmentTables:
    """The :class:`SegmentTables` of a clip's segments (each knot vector built once)."""
    inserted = inserted or {}
    bounds = segment_bounds(n_frames, breaks)
    S = len(bounds)
    first = np.empty(S, dtype=np.int64)
    length = np.empty(S, dtype=np.int64)
    rows = np.empty(S, dtype=np.int64)
    spline = np.zeros(S, dtype=np.bool_)
    knot_start = np.zeros(S + 1, dtype=np.int64)
    knots = []
    pos = 0
    for s, (a, b) in enumerate(bounds):
        L = b - a
        first[s], length[s], rows[s] = a, L, pos
        if L < MIN_SPLINE_FRAMES or spacing < 2:
            pos += L
            knot_start[s + 1] = knot_start[s]
            continue
        t = _knots(L, float(spacing), tuple(inserted.get(s, ())))
        spline[s] = True
        knots.append(t)
        knot_start[s + 1] = knot_start[s] + len(t)
        pos += len(t) - 4
    flat = np.concatenate(knots) if knots else np.zeros(0)
    return SegmentTables(first, length, rows, spline, flat, knot_start, pos)


_KNOTS: dict[tuple, NDArray[np.float64]] = {}


def _knots(length: int, spacing: float, inserted: tuple) -> NDArray[np.float64]:
    """:func:`knot_vector`, cached (clips of a library share their few segment lengths)."""
    key = (length, spacing, inserted)
    t = _KNOTS.get(key)
    if t is None:
        if len(_KNOTS) > 4096:
            _KNOTS.clear()
        t = _KNOTS[key] = knot_vector(length, spacing, inserted)
        t.flags.writeable = False
    return t


@numba.njit(cache=True)
def _evaluate_channels(first, length, rows, spl, knots, ks, P, cols, scale, X):  # pragma: no cover
    C = cols.shape[0]
    alpha = np.empty(6)
    for s in range(first.shape[0]):
        a = first[s]
        r0 = rows[s]
        if not spl[s]:
            for f in range(length[s]):
                for ch in range(C):
                    X[a + f, cols[ch]] = P[r0 + f, ch] / scale[ch]
            continue
        t0 = ks[s]
        n = ks[s + 1] - t0 - 4
        interval = 3
        for f in range(length[s]):
            x = float(f)
            while interval < n - 1 and x >= knots[t0 + interval + 1]:
                interval += 1
            # the de Boor steps with the weights shared by every channel (the same
            # arithmetic, so the same bits)
            k = 0
            for r in range(1, 4):
                for q in range(3, r - 1, -1):
                    i = interval - 3 + q
                    den = knots[t0 + i + 4 - r] - knots[t0 + i]
                    alpha[k] = (x - knots[t0 + i]) / den if den > 0.0 else 0.0
                    k += 1
            b = r0 + interval - 3
            for ch in range(C):
                d0, d1, d2, d3 = P[b, ch], P[b + 1, ch], P[b + 2, ch], P[b + 3, ch]
                d3 = (1.0 - alpha[0]) * d2 + alpha[0] * d3
                d2 = (1.0 - alpha[1]) * d1 + alpha[1] * d2
                d1 = (1.0 - alpha[2]) * d0 + alpha[2] * d1
                d3 = (1.0 - alpha[3]) * d2 + alpha[3] * d3
                d2 = (1.0 - alpha[4]) * d1 + alpha[4] * d2
                d3 = (1.0 - alpha[5]) * d2 + alpha[5] * d3
                X[a + f, cols[ch]] = d3 / scale[ch]


def evaluate_channels(
    tables: SegmentTables,
    P: NDArray[np.float64],
    cols: NDArray[np.int64],
    scale: NDArray[np.float64],
    X: NDArray[np.float64],
) -> None:
    """Every segment's spline (coefficient rows ``P`` ``(n, c)``, weighted units) at its
    frames, divided by ``scale`` ``(c,)``, into the columns ``cols`` of ``X`` ``(T, C)``: one
    compiled pass over every channel's control points, the same values as
    :func:`evaluate_segments` to the bit."""
    _evaluate_channels(
        tables.first, tables.length, tables.rows, tables.spline, tables.knots,
        tables.knot_start, P, cols, scale, X,
    )  # fmt: skip


def evaluate_segments(
    coefficients: list[NDArray[np.float64]],
    n_frames: int,
    breaks,
    spacing: float,
    inserted: dict[int, list[int]] | None = None,
) -> NDArray[np.float64]:
    """The ``(T, C)`` signals of :func:`fit_segments`' coefficients."""
    C = coefficients[0].shape[1] if coefficients else 0
    out = np.empty((n_frames, C))
    if coefficients:
        P = np.ascontiguousarray(np.concatenate(coefficients), dtype=np.float64)
        tables = segment_tables(n_frames, breaks, spacing, inserted)
        evaluate_channels(tables, P, np.arange(C), np.ones(C), out)
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
