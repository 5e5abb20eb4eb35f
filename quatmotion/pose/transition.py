"""A transition judge learned from good and bad pairs: no metric, a classifier of pairs (issue 20).

:class:`TransitionClassifier` scores a pair of poses ``(a, b)`` by the probability that the
transition from ``a`` into what follows ``b`` plays badly, learned from the blended-transition
labels (:mod:`quatmotion.pose.blend_labels`) by gradient-boosted trees (scikit-learn's
``HistGradientBoostingClassifier``: maintained, deterministic for a seed, fast on a few
thousand pairs). A weighted distance must add its terms; a blended transition fails on the
*worst* of foot skating, bone acceleration, root-velocity jumps and penetration, which trees
model and a sum does not. It is no metric (no triangle inequality, no index can search it): it
re-ranks candidates a pose index found. A pose library learns one on its sample and stores it
as plain arrays (:meth:`TransitionClassifier.to_arrays`) with every pose's description, for
``quatmotion pose search --transitions``; its index stays on the learned metric.

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
from threadpoolctl import threadpool_limits

from quatmotion.pose.baselines import VELOCITY_TIME_UNIT
from quatmotion.pose.data import PoseData
from quatmotion.pose.skeleton16 import FEET_16

__all__ = ["SCHEMA", "TransitionClassifier", "pose_rows"]

#: The arrays of a stored classifier (:meth:`TransitionClassifier.to_arrays`).
SCHEMA = (
    "components", "mean", "tree_starts", "baseline", "node_value", "node_feature",
    "node_threshold", "node_missing_left", "node_left", "node_right", "node_leaf",
)  # fmt: skip

FloatArray = NDArray[np.float64]

_PER_FRAME = VELOCITY_TIME_UNIT  # velocities per 30 fps frame, as the JC features take them


def pose_rows(data: PoseData, components: FloatArray | None, mean: FloatArray | None) -> FloatArray:
    """The description of each pose (module conventions), shape (N, 16 + n_components).

    ``components`` (k, 1683) and ``mean`` (1683,) project the GPD; ``None`` leaves it out.
    """
    n = len(data)
    parts = [
        np.asarray(data.positions)[:, FEET_16].reshape(n, -1),
        np.asarray(data.velocities)[:, FEET_16].reshape(n, -1) * _PER_FRAME,
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
        # One OpenMP thread: a few thousand pairs gain little from more, and on a busy machine
        # spinning OpenMP workers made a 5 s fit take 40 s.
        with threadpool_limits(limits=1, user_api="openmp"):
            self.classifier_ = HistGradientBoostingClassifier(
                max_iter=self.max_iter, learning_rate=self.learning_rate, random_state=int(seed)
            ).fit(_pair_features(self.describe(train_a), self.describe(train_b)), ~good)
        return self

    def distances(self, a: PoseData, b: PoseData) -> FloatArray:
        """Probability that each transition ``a[i] -> b[i]`` is bad, shape (P,)."""
        return self.score_rows(self.describe(a), self.describe(b))

    def describe(self, data: PoseData) -> FloatArray:
        """:func:`pose_rows` with the fitted GPD components: what a library stores per pose."""
        return pose_rows(data, self.components_, self.mean_)

    def score_rows(self, rows_a: ArrayLike, rows_b: ArrayLike) -> FloatArray:
        """Probability of bad for pairs of pose descriptions (:meth:`describe`), shape (P,)."""
        pairs = _pair_features(rows_a, rows_b)
        if getattr(self, "classifier_", None) is not None:
            with threadpool_limits(limits=1, user_api="openmp"):
                return self.classifier_.predict_proba(pairs)[:, 1]
        return _predict_trees(self.trees_, pairs)

    def to_arrays(self) -> dict[str, FloatArray]:
        """The fitted model as plain arrays (a file stores these, never a pickle): the GPD
        components and mean, and every tree's nodes (:func:`from_arrays` reads them back)."""
        predictors = [tree[0] for tree in self.classifier_._predictors]  # binary: 1 per round
        nodes = [p.nodes for p in predictors]
        if any(np.any(n["is_categorical"]) for n in nodes):
            raise ValueError("categorical splits are not stored")  # none: the features are real
        starts = np.cumsum([0] + [len(n) for n in nodes])
        allnodes = np.concatenate(nodes)
        k = 0 if self.components_ is None else len(self.components_)
        return {
            "components": np.zeros((0, 1683)) if k == 0 else self.components_,
            "mean": np.zeros(1683) if self.mean_ is None else self.mean_,
            "tree_starts": starts.astype(np.int64),
            "baseline": np.asarray(self.classifier_._baseline_prediction, np.float64).reshape(1),
            "node_value": allnodes["value"].astype(np.float64),
            "node_feature": allnodes["feature_idx"].astype(np.int64),
            "node_threshold": allnodes["num_threshold"].astype(np.float64),
            "node_missing_left": allnodes["missing_go_to_left"].astype(np.int64),
            "node_left": allnodes["left"].astype(np.int64),
            "node_right": allnodes["right"].astype(np.int64),
            "node_leaf": allnodes["is_leaf"].astype(np.int64),
        }

    @classmethod
    def from_arrays(
        cls, arrays: dict[str, ArrayLike], n_features: int | None = None
    ) -> TransitionClassifier:
        """A fitted classifier from :meth:`to_arrays` (scores by :func:`_predict_trees`), its
        trees checked (:func:`check_trees`; ``n_features``: the pair rows it will score).

        Raises ``KeyError`` naming the arrays missing, ``ValueError`` for trees that do not
        hold together."""
        missing = [k for k in SCHEMA if k not in arrays]
        if missing:
            raise KeyError(f"a stored transition classifier lacks {missing}")
        check_trees({k: np.asarray(v) for k, v in arrays.items()}, n_features)
        out = cls.__new__(cls)
        components = np.asarray(arrays["components"], dtype=np.float64)
        out.n_components = len(components)
        out.components_ = components if len(components) else None
        out.mean_ = np.asarray(arrays["mean"], dtype=np.float64) if len(components) else None
        out.classifier_ = None
        out.trees_ = {k: np.asarray(v) for k, v in arrays.items()}
        return out

    def pairwise(self, query: PoseData, base: PoseData) -> FloatArray:
        """:meth:`distances` of every query pose with every base pose, shape (Q, B)."""
        q, b = len(query), len(base)
        _ = query.gpd, base.gpd  # computed once, carried by the selections below
        rows = np.repeat(np.arange(q), b), np.tile(np.arange(b), q)
        return self.distances(query[rows[0]], base[rows[1]]).reshape(q, b)


def _pair_features(rows_a: ArrayLike, rows_b: ArrayLike) -> FloatArray:
    """A pair's row from its two pose descriptions: ``|a - b|`` and ``(a + b) / 2``."""
    a = np.asarray(rows_a, dtype=np.float64)
    b = np.asarray(rows_b, dtype=np.float64)
    return np.concatenate((np.abs(a - b), (a + b) / 2.0), axis=1)


def check_trees(trees: dict[str, NDArray[Any]], n_features: int | None = None) -> None:
    """Refuse (``ValueError``) stored trees that :func:`_predict_trees` cannot walk safely: node
    arrays of unequal lengths, tree starts that do not split them, a child that is not a later
    node of its own tree (no cycle, no jump out), a split on a feature the rows lack."""
    n = len(trees["node_feature"])
    keys = ("node_value", "node_threshold", "node_missing_left", "node_left", "node_right",
            "node_leaf")  # fmt: skip
    if any(np.ndim(trees[k]) != 1 or len(trees[k]) != n for k in (*keys, "node_feature")):
        raise ValueError("a stored transition classifier's node arrays disagree in length")
    starts = np.asarray(trees["tree_starts"])
    if starts.ndim != 1 or not len(starts) or starts[0] != 0 or starts[-1] != n:
        raise ValueError("a stored transition classifier's trees do not cover its nodes")
    if np.any(np.diff(starts) < 1) or np.asarray(trees["baseline"]).size < 1:
        raise ValueError("a stored transition classifier has an empty tree or no baseline")
    tree = np.repeat(np.arange(len(starts) - 1), np.diff(starts))
    local = np.arange(n) - starts[tree]
    inner = ~trees["node_leaf"].astype(bool)
    for side in ("node_left", "node_right"):
        child = trees[side][inner].astype(np.int64)
        end = (starts[tree + 1] - starts[tree])[inner]
        if np.any(child <= local[inner]) or np.any(child >= end):
            raise ValueError("a stored transition classifier's tree links outside its nodes")
    feature = trees["node_feature"][inner].astype(np.int64)
    if feature.size and (feature.min() < 0 or (n_features and feature.max() >= n_features)):
        raise ValueError("a stored transition classifier splits on a feature rows lack")
    if not np.all(np.isfinite(trees["node_value"].astype(np.float64))):
        raise ValueError("a stored transition classifier holds values that are not finite")


def _predict_trees(trees: dict[str, NDArray[Any]], X: FloatArray) -> FloatArray:
    """Probability of the positive class from stored trees: the baseline plus each tree's leaf
    value, through the logistic function. The rule is scikit-learn's for numeric splits (go
    left when ``x <= threshold``, a missing value where ``missing_left`` says); written here
    because a library file holds arrays, not a pickled estimator, and vectorised over rows,
    one level of every row at a time."""
    from scipy.special import expit

    starts = trees["tree_starts"]
    feature, threshold = trees["node_feature"], trees["node_threshold"]
    left, right, leaf = trees["node_left"], trees["node_right"], trees["node_leaf"].astype(bool)
    missing_left, value = trees["node_missing_left"].astype(bool), trees["node_value"]
    rows = np.arange(len(X))
    raw = np.full(len(X), float(np.asarray(trees["baseline"]).reshape(-1)[0]))
    for t in range(len(starts) - 1):
        node = np.full(len(X), starts[t])
        active = ~leaf[node]
        while active.any():
            n = node[active]
            x = X[rows[active], feature[n]]
            go_left = np.where(np.isnan(x), missing_left[n], x <= threshold[n])
            node[active] = starts[t] + np.where(go_left, left[n], right[n])
            active = ~leaf[node]
        raw += value[node]
    return expit(raw)
