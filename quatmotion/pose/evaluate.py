"""Evaluation of pose distances: transition precision and retrieval precision@s.

Definitions follow docs/metrics.md ("Pose distance"), the project's one definition of every metric,
and the GPD paper:

* **Transition precision** (Eq. 36-37): with test pairs labelled positive (good transition) or
  negative, a threshold ``delta`` decides a pair correctly when a positive pair has distance
  ``< delta`` or a negative pair has distance ``>= delta``; the precision is the best fraction
  of correct decisions over all thresholds (found exhaustively).
* **Retrieval precision@s** (section 6.2): the fraction of the top ``s`` results of a query
  that are correct, averaged over queries.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

DEFAULT_SCOPES: tuple[int, ...] = (5, 10, 15, 20, 25, 30, 35, 40, 45, 50)


def transition_precision(distances: ArrayLike, labels: ArrayLike) -> tuple[float, float]:
    """Best fraction of pairs decided correctly by one distance threshold (Eq. 36-37).

    Parameters
    ----------
    distances : array_like, shape (P,)
        Distance of each test pair (any unit; only the order and ties matter).
    labels : array_like of bool, shape (P,)
        True for positive (similar, good transition) pairs.

    Returns
    -------
    precision : float
        ``max_delta n(delta) / P`` with ``n(delta) = #{pos: d < delta} + #{neg: d >= delta}``.
    threshold : float
        A ``delta`` reaching it: the smallest distance that is decided negative, or ``inf``
        when calling every pair positive is best.
    """
    d = np.asarray(distances, dtype=np.float64).reshape(-1)
    y = np.asarray(labels, dtype=bool).reshape(-1)
    if d.shape != y.shape:
        raise ValueError(f"distances {d.shape} and labels {y.shape} differ in length")
    if d.size == 0:
        raise ValueError("need at least one pair")
    if not np.all(np.isfinite(d)):
        raise ValueError("distances must be finite")
    order = np.argsort(d, kind="stable")
    d, y = d[order], y[order]
    # Candidate thresholds: each distinct distance (pairs at or above it go negative) and +inf.
    starts = np.flatnonzero(np.r_[True, d[1:] != d[:-1]])
    pos_below = np.r_[0, np.cumsum(y)]  # positives strictly before index i
    neg_total = int(np.count_nonzero(~y))
    neg_below = np.arange(d.size + 1) - pos_below
    cut = np.r_[starts, d.size]
    correct = pos_below[cut] + (neg_total - neg_below[cut])
    best = int(np.argmax(correct))
    threshold = float(d[cut[best]]) if cut[best] < d.size else float("inf")
    return float(correct[best] / d.size), threshold


def ranked_correct(
    distances: ArrayLike,
    correct: ArrayLike,
    max_scope: int = 50,
    exclude: ArrayLike | None = None,
) -> NDArray[np.bool_]:
    """Correctness of each query's top results, nearest first.

    Parameters
    ----------
    distances : array_like, shape (Q, B)
        Distance from each query to each base pose.
    correct : array_like of bool, shape (Q, B)
        Whether base pose ``b`` is a correct result for query ``q``.
    max_scope : int
        How many results to keep per query.
    exclude : array_like of bool, shape (Q, B), optional
        Base poses never returned for a query (the query itself, poses of the same clip...).

    Returns
    -------
    ndarray of bool, shape (Q, S)
        ``S = min(max_scope, B)``; ties broken by base index (stable sort).
    """
    dist = np.array(distances, dtype=np.float64)
    ok = np.asarray(correct, dtype=bool)
    if dist.ndim != 2 or ok.shape != dist.shape:
        raise ValueError(f"distances {dist.shape} and correct {ok.shape} must be equal (Q, B)")
    if max_scope < 1:
        raise ValueError(f"max_scope must be positive, got {max_scope}")
    if exclude is not None:
        ex = np.asarray(exclude, dtype=bool)
        if ex.shape != dist.shape:
            raise ValueError(f"exclude has shape {ex.shape}, expected {dist.shape}")
        dist[ex] = np.inf
        n_allowed = int(np.min(np.count_nonzero(~ex, axis=1)))
    else:
        n_allowed = dist.shape[1]
    S = min(max_scope, n_allowed)
    if S < 1:
        raise ValueError("some query has no base pose left to rank")
    top = np.argsort(dist, axis=1, kind="stable")[:, :S]
    return np.take_along_axis(ok, top, axis=1)


def precision_at(ranked: ArrayLike, scopes: Sequence[int] = DEFAULT_SCOPES) -> NDArray[np.float64]:
    """Retrieval precision at each scope, averaged over queries.

    Parameters
    ----------
    ranked : array_like of bool, shape (Q, S)
        Correctness of each query's results in rank order (see :func:`ranked_correct`).
    scopes : sequence of int
        Each ``s`` in ``1..S``.

    Returns
    -------
    ndarray, shape (len(scopes),)
        Mean over queries of the fraction of correct results among the top ``s``.
    """
    r = np.asarray(ranked, dtype=bool)
    if r.ndim != 2 or r.shape[0] == 0:
        raise ValueError(f"ranked must be a non-empty (Q, S) array, got shape {r.shape}")
    scopes = [int(s) for s in scopes]
    if any(s < 1 or s > r.shape[1] for s in scopes):
        raise ValueError(f"scopes must lie in 1..{r.shape[1]}, got {scopes}")
    hits = np.cumsum(r, axis=1)
    return np.array([hits[:, s - 1].mean() / s for s in scopes])
