"""Baseline pose features, joint distances and metric learners of sections 5.3-5.4.

Features (one row per pose; :class:`~quatmotion.pose.data.PoseData` in):

- ``JO`` joint orientations: Hip height (m), the 16 local orientations of
  :func:`~quatmotion.pose.data.joint_orientations` (quaternions, ``w >= 0``) and their angular
  velocities (rad per 1/30 s), 113 dims.
- ``JC`` joint coordinates: the 15 non-Hip body-local positions (cm), Hip height, their
  velocities (cm per 1/30 s) and the Hip's vertical velocity, 92 dims.
- ``JRF`` joint relative features (Tang et al. 2008, [3]): the 120 joint-pair distances, cm.

Joint distances (Eq. 40-43) :class:`JointDistance`: JOD / WJOD / LJOD on orientations, JCD /
WJCD / LJCD on coordinates. Units, which the paper leaves open: velocities are per 1/30 s (a
frame at the usual animation rate, whatever the capture rate, so ``lambda = 1`` as in [1]
weighs a frame's motion like a pose difference); the Hip position term of the orientation
distances is in metres so that it is commensurate with radians.

Learners (on normalised feature rows, sample per row), all with ``fit(X_unlabeled, X_a, X_b,
labels)`` and ``transform``-style distances:

- :class:`LMS`: weighted ``L_p`` distance ``(sum_k w_k |x_k - y_k|^p)^(1/p)`` with non-negative
  weights fitted by least squares to the labels (0 similar, 1 dissimilar), as Wang and
  Bodenheimer [1] fit their joint weights; ``p = 1`` is Eq. 44 (JRF+LMS), ``p = 2`` the
  weighted L2 of section 5.4.
- :class:`Xing`: Xing et al.'s MMC [28]: ``max sum_D ||x - y||_M`` s.t. ``sum_S ||x - y||_M^2
  <= 1``, ``M >= 0``, by projected gradient ascent on the scale-free ratio ``g(M) / sqrt(f(M))``
  (same optimum: the constraint binds). ``metric-learn``'s MMC does not run on the installed
  scikit-learn (it passes the removed ``force_all_finite`` argument), so it is implemented
  here; a full 1683 x 1683 M is impractical (an eigendecomposition per step), so features are
  first reduced by PCA (fitted on the unlabeled poses) to ``n_pca`` dimensions.
- :class:`SDA`: semi-supervised discriminant analysis (Cai, He and Han 2007, [34]) with pair
  labels: ``max Tr(W^T S_D W) / Tr(W^T (S_S + a X^T L X + b I) W)`` as a generalised
  eigenproblem, ``S_D`` / ``S_S`` the scatter of dissimilar / similar pair differences and
  ``L`` the Laplacian of the symmetric k-nearest-neighbour graph (0/1 weights) of the
  unlabeled poses; each term is divided by its trace so ``a`` and ``b`` are scale-free. With
  no unlabeled poses it is LDA on pairs, as the paper notes.
"""

from __future__ import annotations

import itertools
from typing import Literal

import numpy as np
import scipy.linalg
import scipy.sparse
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.distance import cdist
from sklearn.decomposition import PCA
from sklearn.linear_model import LinearRegression
from sklearn.neighbors import NearestNeighbors
from sklearn.utils import check_random_state
from threadpoolctl import threadpool_limits

from quatmotion.pose.data import PoseData
from quatmotion.pose.metric import pair_labels
from quatmotion.pose.skeleton16 import JOINTS_16

__all__ = [
    "LEE_WEIGHTS",
    "LMS",
    "SDA",
    "JointDistance",
    "Xing",
    "joint_coordinate_features",
    "joint_orientation_features",
    "joint_relative_features",
]

FloatArray = NDArray[np.float64]

_JOINT_PAIRS = np.array(list(itertools.combinations(range(len(JOINTS_16)), 2)), dtype=np.intp)

#: Seconds per "frame" of the velocity terms (see the module docstring).
VELOCITY_TIME_UNIT = 1.0 / 30.0

#: Lee et al. [11]: weight 1 on shoulders, elbows, hips, knees, pelvis and spine, 0 elsewhere.
LEE_WEIGHTS: FloatArray = np.array(
    [
        1.0 if name in {"Hip", "Chest", "LShoulder", "LElbow", "RShoulder", "RElbow",
                        "LHip", "LKnee", "RHip", "RKnee"} else 0.0
        for name in JOINTS_16
    ]
)  # fmt: skip


# ------------------------------------------------------------------------------------------
# Features
# ------------------------------------------------------------------------------------------
def joint_orientation_features(data: PoseData) -> FloatArray:
    """JO feature rows, shape (N, 113): Hip height (m), 16 quaternions, 16 angular velocities."""
    n = len(data)
    return np.concatenate(
        (
            data.hip_height[:, None] / 100.0,
            data.orientations.reshape(n, -1),
            data.angular_velocities.reshape(n, -1) * VELOCITY_TIME_UNIT,
        ),
        axis=1,
    )


def joint_coordinate_features(data: PoseData) -> FloatArray:
    """JC feature rows, shape (N, 92): local positions, Hip height, velocities (cm, cm/frame)."""
    n = len(data)
    vel = data.velocities * VELOCITY_TIME_UNIT
    return np.concatenate(
        (
            data.positions[:, 1:].reshape(n, -1),
            data.hip_height[:, None],
            vel[:, 1:].reshape(n, -1),
            vel[:, 0, 1:2],
        ),
        axis=1,
    )


def joint_relative_features(data: PoseData) -> FloatArray:
    """JRF feature rows, shape (N, 120): distances between all joint pairs, cm ([3])."""
    pos = data.positions
    return np.linalg.norm(pos[:, _JOINT_PAIRS[:, 1]] - pos[:, _JOINT_PAIRS[:, 0]], axis=-1)


# ------------------------------------------------------------------------------------------
# Joint distances (Eq. 40-43)
# ------------------------------------------------------------------------------------------
def _fit_nonnegative_weights(terms: FloatArray, labels: NDArray[np.bool_]) -> FloatArray:
    """Least-squares non-negative weights so ``terms @ w + c`` predicts 0 (similar) / 1."""
    target = np.where(labels, 0.0, 1.0)
    with threadpool_limits(limits=1, user_api="blas"):
        model = LinearRegression(positive=True).fit(terms, target)
    w = np.asarray(model.coef_, dtype=np.float64)
    if not np.any(w > 0):
        # Labels not explained by any term: fall back to the unweighted sum.
        w = np.ones(terms.shape[1])
    return w


class JointDistance:
    """JOD, WJOD, LJOD (``kind="orientation"``) and JCD, WJCD, LJCD (``"coordinate"``).

    Parameters
    ----------
    kind : {"orientation", "coordinate"}
    weights : {"uniform", "lee", "learned"}
        Per-joint weights: all 1 (JOD, JCD), Lee et al.'s 0/1 (WJOD, WJCD), or least squares on
        the training pairs (LJOD, LJCD; the Hip position term gets a learned weight too).
    velocity_weight : float
        ``lambda`` of Eq. 40-43.

    Notes
    -----
    The distance is the weighted sum of squared per-joint terms (Eq. 40-43 are squared
    distances already). Orientation terms use the geodesic angle between the joint
    orientations; coordinate terms include the Hip as ``(0, height, 0)``.
    """

    def __init__(
        self,
        kind: Literal["orientation", "coordinate"] = "coordinate",
        weights: Literal["uniform", "lee", "learned"] = "uniform",
        velocity_weight: float = 1.0,
    ) -> None:
        if kind not in ("orientation", "coordinate"):
            raise ValueError(f"kind must be 'orientation' or 'coordinate', got {kind!r}")
        if weights not in ("uniform", "lee", "learned"):
            raise ValueError(f"weights must be 'uniform', 'lee' or 'learned', got {weights!r}")
        self.kind = kind
        self.weights = weights
        self.velocity_weight = velocity_weight

    def _parts(self, data: PoseData) -> tuple[FloatArray, FloatArray, FloatArray]:
        if self.kind == "orientation":
            hip = data.hip_height[:, None] / 100.0
            return hip, data.orientations, data.angular_velocities * VELOCITY_TIME_UNIT
        pos = np.array(data.positions)
        pos[:, 0, 1] = data.hip_height
        return np.zeros((len(data), 1)), pos, data.velocities * VELOCITY_TIME_UNIT

    def _terms(self, a: PoseData, b: PoseData) -> FloatArray:
        """Per-pair squared terms, shape (P, 17): Hip position, then each joint."""
        ha, pa, va = self._parts(a)
        hb, pb, vb = self._parts(b)
        if self.kind == "orientation":
            cos_half = np.clip(np.abs(np.sum(pa * pb, axis=-1)), 0.0, 1.0)
            static = (2.0 * np.arccos(cos_half)) ** 2
        else:
            static = np.sum((pa - pb) ** 2, axis=-1)
        motion = np.sum((va - vb) ** 2, axis=-1)
        hip = np.sum((ha - hb) ** 2, axis=-1, keepdims=True)
        return np.concatenate((hip, static + self.velocity_weight * motion), axis=1)

    def _pairwise_terms(self, q: PoseData, b: PoseData) -> FloatArray:
        """(Q, B) distances with the fitted weights, computed without (Q, B, 17) storage."""
        hq, pq, vq = self._parts(q)
        hb, pb, vb = self._parts(b)
        w = self.weights_
        out = w[0] * cdist(hq, hb, "sqeuclidean")
        for k in range(len(JOINTS_16)):
            if w[k + 1] == 0.0:
                continue
            if self.kind == "orientation":
                cos_half = np.clip(np.abs(pq[:, k] @ pb[:, k].T), 0.0, 1.0)
                static = (2.0 * np.arccos(cos_half)) ** 2
            else:
                static = cdist(pq[:, k], pb[:, k], "sqeuclidean")
            motion = cdist(vq[:, k], vb[:, k], "sqeuclidean")
            out += w[k + 1] * (static + self.velocity_weight * motion)
        return out

    def fit(
        self,
        unlabeled: PoseData,
        train_a: PoseData,
        train_b: PoseData,
        train_labels: ArrayLike,
    ) -> JointDistance:
        """Set the weights (learned ones from the training pairs; the rest ignore the data)."""
        if self.weights == "learned":
            labels = np.asarray(train_labels, dtype=bool)
            self.weights_ = _fit_nonnegative_weights(self._terms(train_a, train_b), labels)
        else:
            joint = np.ones(len(JOINTS_16)) if self.weights == "uniform" else LEE_WEIGHTS
            self.weights_ = np.concatenate(([1.0], joint))
        return self

    def distances(self, a: PoseData, b: PoseData) -> FloatArray:
        """Distances of aligned pose pairs, shape (P,)."""
        return self._terms(a, b) @ self.weights_

    def pairwise(self, query: PoseData, base: PoseData) -> FloatArray:
        """Distances from every query pose to every base pose, shape (Q, B)."""
        return self._pairwise_terms(query, base)


# ------------------------------------------------------------------------------------------
# Learners on feature rows
# ------------------------------------------------------------------------------------------
class LMS:
    """Weighted ``L_p`` distance with least-squares non-negative weights ([1], Eq. 44).

    Parameters
    ----------
    power : {1, 2}
        ``p``: 1 for Eq. 44 (weighted absolute differences), 2 for weighted L2.

    Attributes
    ----------
    weights_ : ndarray, shape (D,)
    """

    def __init__(self, power: int = 2) -> None:
        if power not in (1, 2):
            raise ValueError(f"power must be 1 or 2, got {power}")
        self.power = power

    def fit(
        self, X_unlabeled: FloatArray, X_a: FloatArray, X_b: FloatArray, labels: ArrayLike
    ) -> LMS:
        """Fit weights on pairs ``(X_a[i], X_b[i])`` (P, D) labelled True = similar."""
        terms = np.abs(X_a - X_b) ** self.power
        self.weights_ = _fit_nonnegative_weights(terms, np.asarray(labels, dtype=bool))
        return self

    def distances(self, A: FloatArray, B: FloatArray) -> FloatArray:
        return (np.abs(A - B) ** self.power @ self.weights_) ** (1.0 / self.power)

    def pairwise(self, Q: FloatArray, B: FloatArray) -> FloatArray:
        if self.power == 2:
            s = np.sqrt(self.weights_)
            return cdist(Q * s, B * s)
        return cdist(Q * self.weights_, B * self.weights_, "cityblock")


class _Projection:
    """A learner whose distance is Euclidean after ``x -> x @ projection_``."""

    projection_: FloatArray

    def transform(self, X: FloatArray) -> FloatArray:
        return X @ self.projection_

    def distances(self, A: FloatArray, B: FloatArray) -> FloatArray:
        return np.linalg.norm(self.transform(A) - self.transform(B), axis=1)

    def pairwise(self, Q: FloatArray, B: FloatArray) -> FloatArray:
        return cdist(self.transform(Q), self.transform(B))


class Xing(_Projection):
    """Xing et al.'s MMC metric [28] in a PCA subspace (full M there).

    Parameters
    ----------
    n_pca : int
        PCA dimensions kept before learning M (fitted on the unlabeled poses, or on the pair
        poses when there are none).
    max_iter : int
        Projected gradient steps.
    tol : float
        Relative change of the objective that stops the ascent.
    random_state : int, RandomState or None
        Seeds the (randomised) PCA.

    Attributes
    ----------
    metric_ : ndarray, shape (n_pca, n_pca)
        M, with ``sum_S ||x - y||_M^2 = 1``.
    projection_ : ndarray, shape (D, n_pca)
        ``P L`` with ``M = L L^T``: distances are Euclidean after projecting.
    n_iter_ : int
    """

    def __init__(
        self,
        n_pca: int = 50,
        max_iter: int = 300,
        tol: float = 1e-6,
        random_state: int | np.random.RandomState | None = None,
    ) -> None:
        self.n_pca = n_pca
        self.max_iter = max_iter
        self.tol = tol
        self.random_state = random_state

    def fit(
        self, X_unlabeled: FloatArray, X_a: FloatArray, X_b: FloatArray, labels: ArrayLike
    ) -> Xing:
        labels = pair_labels(labels, "Xing")
        base = X_unlabeled if len(X_unlabeled) >= 2 else np.concatenate((X_a, X_b))
        k = int(min(self.n_pca, base.shape[1], base.shape[0]))
        pca = PCA(n_components=k, random_state=check_random_state(self.random_state)).fit(base)
        P = pca.components_.T
        diff = (X_a - X_b) @ P
        sim, dis = diff[labels], diff[~labels]
        S = sim.T @ sim
        fs = float(np.trace(S))
        if fs <= 0:
            raise ValueError("similar pairs are identical in the PCA subspace")

        def ratio(M: FloatArray) -> float:
            g = np.sum(np.sqrt(np.maximum(np.einsum("pi,ij,pj->p", dis, M, dis), 0.0)))
            return float(g / np.sqrt(max(np.sum(M * S), 1e-300)))

        def project(M: FloatArray) -> FloatArray:
            w, v = np.linalg.eigh(0.5 * (M + M.T))
            M = (v * np.maximum(w, 0.0)) @ v.T
            return M / max(float(np.sum(M * S)), 1e-300)

        M = project(np.eye(k))
        value = ratio(M)
        step = 1.0
        n_iter = 0
        for n_iter in range(1, self.max_iter + 1):  # noqa: B007
            q = np.sqrt(np.maximum(np.einsum("pi,ij,pj->p", dis, M, dis), 1e-12))
            g = float(np.sum(q))
            f = float(np.sum(M * S))
            grad = (dis / (2.0 * q[:, None])).T @ dis / np.sqrt(f) - g / (2.0 * f**1.5) * S
            grad /= max(np.linalg.norm(grad), 1e-300)
            improved = False
            while step > 1e-8:
                candidate = project(M + step * grad * np.linalg.norm(M))
                new_value = ratio(candidate)
                if new_value > value:
                    improved = True
                    break
                step *= 0.5
            if not improved:
                break
            change = (new_value - value) / value
            M, value = candidate, new_value
            step *= 2.0
            if change < self.tol:
                break
        w, v = np.linalg.eigh(M)
        self.metric_ = M
        self.projection_ = P @ (v * np.sqrt(np.maximum(w, 0.0)))
        self.n_iter_ = n_iter
        return self


class SDA(_Projection):
    """Semi-supervised discriminant analysis on pairs ([34], see the module docstring).

    Parameters
    ----------
    n_components : int
        Projection rank.
    alpha : float
        Weight of the k-NN graph smoothness term (trace-normalised).
    beta : float
        Weight of the Tikhonov term (trace-normalised).
    n_neighbors : int
        k of the graph.

    Attributes
    ----------
    projection_ : ndarray, shape (D, n_components)
    """

    def __init__(
        self, n_components: int = 50, alpha: float = 0.1, beta: float = 0.01, n_neighbors: int = 5
    ) -> None:
        self.n_components = n_components
        self.alpha = alpha
        self.beta = beta
        self.n_neighbors = n_neighbors

    def fit(
        self, X_unlabeled: FloatArray, X_a: FloatArray, X_b: FloatArray, labels: ArrayLike
    ) -> SDA:
        labels = pair_labels(labels, "SDA")
        d = X_a.shape[1]
        diff = X_a - X_b
        S_D = diff[~labels].T @ diff[~labels]
        S_S = diff[labels].T @ diff[labels]
        denominator = S_S / max(np.trace(S_S), 1e-300) + self.beta * np.eye(d) / d
        n = X_unlabeled.shape[0]
        if n > self.n_neighbors and self.alpha > 0:
            nn = NearestNeighbors(n_neighbors=self.n_neighbors + 1).fit(X_unlabeled)
            graph = nn.kneighbors_graph(mode="connectivity")
            graph.setdiag(0.0)
            graph = ((graph + graph.T) > 0).astype(np.float64)
            degree = np.asarray(graph.sum(axis=1)).ravel()
            J = (X_unlabeled * degree[:, None]).T @ X_unlabeled - X_unlabeled.T @ (
                graph @ X_unlabeled
            )
            denominator += self.alpha * J / max(np.trace(J), 1e-300)
        r = int(min(self.n_components, d))
        with threadpool_limits(limits=1, user_api="blas"):
            _, v = scipy.linalg.eigh(
                0.5 * (S_D + S_D.T), 0.5 * (denominator + denominator.T),
                subset_by_index=[d - r, d - 1],
            )  # fmt: skip
        self.projection_ = v[:, ::-1]
        return self
