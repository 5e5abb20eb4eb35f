"""A transition judge learned from good and bad pairs: no metric, a classifier of pairs (issue 20).

:class:`TransitionClassifier` scores a pair of poses ``(a, b)`` by the probability that the
transition from ``a`` into what follows ``b`` plays badly, learned from the blended-transition
labels (:mod:`quatmotion.pose.blend_labels`) by gradient-boosted trees (scikit-learn's
``HistGradientBoostingClassifier``: maintained, deterministic for a seed, fast on a few
thousand pairs). A weighted distance must add its terms; a blended transition fails on the
*worst* of foot skating, bone acceleration, root-velocity jumps and penetration, which trees
model and a sum does not. It is no metric (no triangle inequality, no index can search it): it
re-ranks candidates a pose index or a window distance found; the pose library keeps its
learned metric for search.

Conventions
-----------
- The pose description (:func:`pose_rows`), per pose, on the canonical body: both feet's
  body-local positions (cm) and velocities (cm per frame at 30 frames/s), the Hip's height
  (cm), the root's body-frame horizontal velocity (cm per frame) and turn rate (rad per frame)
  (:attr:`~quatmotion.pose.data.PoseData.root_motion`), and the first ``n_components``
  principal components of the GPD fitted on the unlabeled poses (the rest of the body).
- A pair's row is ``|a - b|`` and ``(a + b) / 2`` of the two descriptions: how far apart, and
  where (a difference of feet means less in a stand than in a stride).
- ``distances`` is the probability of *bad* (0 good .. 1 bad), so that lower is better as for
  every pose distance.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quatmotion.pose.data import PoseData

__all__ = ["TransitionClassifier", "pose_rows"]

FloatArray = NDArray[np.float64]

_FEET = (12, 15)  # LFoot, RFoot in JOINTS_16 order
_PER_FRAME = 1.0 / 30.0  # velocities in units per 30 fps frame, so trees see comparable scales


def pose_rows(data: PoseData, components: FloatArray | None, mean: FloatArray | None) -> FloatArray:
    """The description of each pose (module conventions), shape (N, 17 + n_components).

    ``components`` (k, 1683) and ``mean`` (1683,) project the GPD; ``None`` leaves it out.
    """
    n = len(data)
    parts = [
        np.asarray(data.positions)[:, _FEET].reshape(n, -1),
        np.asarray(data.velocities)[:, _FEET].reshape(n, -1) * _PER_FRAME,
        np.asarray(data.hip_height)[:, None],
        np.asarray(data.root_motion) * _PER_FRAME,
    ]
    if components is not None and mean is not None:
        parts.append((np.asarray(data.gpd) - mean) @ components.T)
    return np.concatenate(parts, axis=1)


class TransitionClassifier:
    """Probability that a transition plays badly, learned from labelled pairs.

    Parameters
    ----------
    n_components : int
        Principal components of the GPD in the pose description (0: feet and root only).
    max_iter : int
        Boosting rounds.
    learning_rate : float
    random_state : int or None
        Seed of the trees' binning subsample and the PCA's solver.

    Attributes
    ----------
    classifier_ : HistGradientBoostingClassifier
    components_ : ndarray, shape (n_components, 1683) or None
    mean_ : ndarray, shape (1683,) or None
    uses_dissimilar : bool
        True: good and bad pairs are both read.
    """

    uses_dissimilar = True

    def __init__(
        self,
        n_components: int = 30,
        max_iter: int = 200,
        learning_rate: float = 0.05,
        random_state: Any = None,
    ) -> None:
        if n_components < 0:
            raise ValueError(f"n_components must be 0 or more, got {n_components}")
        if max_iter < 1:
            raise ValueError(f"max_iter must be at least 1, got {max_iter}")
        if not learning_rate > 0:
            raise ValueError(f"learning_rate must be positive, got {learning_rate}")
        self.n_components = n_components
        self.max_iter = max_iter
        self.learning_rate = learning_rate
        self.random_state = random_state

    def _pair_rows(self, a: PoseData, b: PoseData) -> FloatArray:
        ra = pose_rows(a, self.components_, self.mean_)
        rb = pose_rows(b, self.components_, self.mean_)
        return np.concatenate((np.abs(ra - rb), (ra + rb) / 2.0), axis=1)

    def fit(
        self, unlabeled: PoseData, train_a: PoseData, train_b: PoseData, train_labels: ArrayLike
    ) -> TransitionClassifier:
        """Learn from pairs ``(train_a[i], train_b[i])``, labels True = a good transition; the
        GPD's principal components from ``unlabeled``."""
        from sklearn.decomposition import PCA
        from sklearn.ensemble import HistGradientBoostingClassifier

        good = np.asarray(train_labels, dtype=bool).reshape(-1)
        if not (len(train_a) == len(train_b) == good.shape[0]):
            raise ValueError(
                f"train_a, train_b and train_labels disagree: "
                f"{len(train_a)}, {len(train_b)}, {good.shape[0]}"
            )
        if good.all() or not good.any():
            raise ValueError("TransitionClassifier needs both good and bad pairs")
        self.components_ = self.mean_ = None
        k = min(self.n_components, len(unlabeled) - 1, 1683)
        if k > 0:
            pca = PCA(k, random_state=self.random_state).fit(np.asarray(unlabeled.gpd))
            self.components_, self.mean_ = pca.components_, pca.mean_
        seed = self.random_state if isinstance(self.random_state, (int, np.integer)) else 0
        self.classifier_ = HistGradientBoostingClassifier(
            max_iter=self.max_iter, learning_rate=self.learning_rate, random_state=int(seed)
        ).fit(self._pair_rows(train_a, train_b), ~good)
        return self

    def distances(self, a: PoseData, b: PoseData) -> FloatArray:
        """Probability that each transition ``a[i] -> b[i]`` is bad, shape (P,)."""
        return self.classifier_.predict_proba(self._pair_rows(a, b))[:, 1]

    def pairwise(self, query: PoseData, base: PoseData) -> FloatArray:
        """:meth:`distances` of every query pose with every base pose, shape (Q, B)."""
        q, b = len(query), len(base)
        _ = query.gpd, base.gpd  # computed once, carried by the selections below
        rows = np.repeat(np.arange(q), b), np.tile(np.arange(b), q)
        return self.distances(query[rows[0]], base[rows[1]]).reshape(q, b)
