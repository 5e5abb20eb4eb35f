"""Every pose distance of sections 5.3-5.4 behind one interface, by a stable name.

``METHODS[name](**kwargs)`` builds an unfitted :class:`PoseMethod`:

- ``"F+L"`` for every feature ``F`` in :data:`FEATURES` (``JO``, ``JC``, ``JRF``, ``GPD``, and
  ``GPDR``: the GPD with the root's speed and turn rate, :func:`gpd_root_features`) and
  learner ``L`` in :data:`LEARNERS` (``L2``, ``LMS``, ``Xing``, ``SDA``, ``RDSR``): Fig. 6's
  grid; and ``LOGIT`` (:class:`~quatmotion.pose.metric.PairLogistic`: a weighted L2 learned
  by logistic regression on good and bad pairs, issue 20). Features are normalised as the
  paper does for GPD (per-dimension min-max fitted on all training poses, clipped to that
  range, then unit length) so every learner sees comparable inputs. ``JRF+LMS`` is Eq. 44
  (weighted absolute differences); the other ``+LMS`` are weighted L2.

One implementation: :class:`~quatmotion.pose.library.PoseLibrary` learns its metric by
``METHODS[name]`` (:meth:`FeatureMetric.fit_features`) and stores
:attr:`FeatureMetric.projection_`; :func:`project_features` maps poses to the index space for
both, so the library's distances and the benchmark's are the same numbers.
- ``"PAIR-GBT"``: :class:`~quatmotion.pose.transition.TransitionClassifier`, no metric but a
  classifier of pairs (the probability that a transition plays badly), for re-ranking.
- ``"FEET"``: no learning, Euclidean distance of the two feet in the body frame (the baseline
  of the blended-transition labels, :mod:`quatmotion.pose.blend_labels`).
- ``"JOD"``, ``"WJOD"``, ``"LJOD"``, ``"JCD"``, ``"WJCD"``, ``"LJCD"``: Eq. 40-43 on raw joints.
- Aliases for the learners on GPD: ``"L2"``, ``"L2+LMS"`` / ``"LMS"``, ``"Xing"``, ``"SDA"``,
  ``"RDSR"``.

Keyword arguments go to the learner (``METHODS["GPD+RDSR"](n_components=30)`` for the Fig. 4
sweep); ``random_state`` is accepted by every method.

Pairs are two aligned :class:`~quatmotion.pose.data.PoseData` and a boolean label per pair
(True = similar / a good transition). Unsupervised methods ignore the labels; RDSR uses only the
similar pairs; LMS, Xing, SDA and LOGIT use both.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quatmotion.pose.baselines import (
    LMS,
    SDA,
    JointDistance,
    Xing,
    joint_coordinate_features,
    joint_orientation_features,
    joint_relative_features,
)
from quatmotion.pose.data import PoseData
from quatmotion.pose.metric import RDSR, PairLogistic
from quatmotion.pose.scaler import MinMaxUnitScaler
from quatmotion.pose.skeleton16 import FEET_16
from quatmotion.pose.transition import TransitionClassifier

__all__ = [
    "FEATURES",
    "FIG5_METHODS",
    "LEARNERS",
    "METHODS",
    "FeatureMetric",
    "ROOT_COPIES",
    "FeetDistance",
    "JointDistanceMethod",
    "PoseMethod",
    "gpd_root_features",
    "pose_features",
    "project_features",
    "root_features",
]

FloatArray = NDArray[np.float64]


@runtime_checkable
class PoseMethod(Protocol):
    """A trainable pose distance."""

    def fit(
        self,
        unlabeled: PoseData,
        train_a: PoseData,
        train_b: PoseData,
        train_labels: ArrayLike,
    ) -> PoseMethod:
        """Learn from unlabeled poses and labelled pairs ``(train_a[i], train_b[i])``."""
        ...

    def distances(self, a: PoseData, b: PoseData) -> FloatArray:
        """Distances of aligned pairs, shape (P,)."""
        ...

    def pairwise(self, query: PoseData, base: PoseData) -> FloatArray:
        """Distances from every query pose to every base pose, shape (Q, B)."""
        ...


#: Copies of the root block in ``GPDR``. The min-max + unit-length scaling gives every
#: dimension the same say, so two numbers beside GPD's 1683 would count for nothing; 20 copies
#: (40 dimensions) weigh about as much as one of GPD's joint blocks (``J_c``: 46). The
#: cross-skeleton benchmark moved little between 10 and 40 copies (docs/performance.md).
ROOT_COPIES = 20


def root_features(data: PoseData) -> FloatArray:
    """The root block of ``GPDR``, shape (N, 2): the Hip's speed over the floor (cm/s) and the
    facing's turn rate ``|yaw rate|`` (rad/s), from :attr:`PoseData.root_motion`.

    Speeds, not signed velocities: a pose walking sideways or turning right is of the same kind
    as its mirror image, and the body frame's heading is the least reliable part of a foreign
    skeleton's mapping.
    """
    root = np.asarray(data.root_motion)
    return np.stack((np.hypot(root[:, 0], root[:, 1]), np.abs(root[:, 2])), axis=1)


def gpd_root_features(data: PoseData) -> FloatArray:
    """``GPDR`` rows, shape (N, 1683 + 2 * ROOT_COPIES): the GPD and the root's travel the
    paper's descriptor lacks (:func:`root_features`, repeated :data:`ROOT_COPIES` times)."""
    return np.concatenate((np.asarray(data.gpd), np.tile(root_features(data), ROOT_COPIES)), axis=1)


#: Feature extractors: PoseData -> (N, D) raw rows.
FEATURES: dict[str, Callable[[PoseData], FloatArray]] = {
    "JO": joint_orientation_features,
    "JC": joint_coordinate_features,
    "JRF": joint_relative_features,
    "GPD": lambda data: np.asarray(data.gpd),
    "GPDR": gpd_root_features,
}


def pose_features(data: PoseData, metric: str) -> FloatArray:
    """Raw feature rows of ``data`` for the registered method ``metric`` (``"GPDR+LOGIT"``
    reads :data:`FEATURES` ``["GPDR"]``), shape (N, D)."""
    feature = metric.split("+", 1)[0]
    if feature not in FEATURES:
        raise ValueError(f"metric {metric!r} names no feature set of {sorted(FEATURES)}")
    return np.asarray(FEATURES[feature](data), dtype=np.float64)


LEARNERS: tuple[str, ...] = ("L2", "LMS", "Xing", "SDA", "RDSR", "LOGIT")


class _L2:
    """No learning: Euclidean distance between normalised feature rows."""

    def fit(self, X_unlabeled: FloatArray, X_a: FloatArray, X_b: FloatArray, labels: Any) -> _L2:
        return self

    def distances(self, A: FloatArray, B: FloatArray) -> FloatArray:
        return np.linalg.norm(A - B, axis=1)

    def pairwise(self, Q: FloatArray, B: FloatArray) -> FloatArray:
        from scipy.spatial.distance import cdist

        return cdist(Q, B)

    def projection(self, n_features: int) -> FloatArray:
        return np.eye(n_features)


def project_features(raw: ArrayLike, projection: dict[str, Any]) -> FloatArray:
    """Raw feature rows mapped to a metric's Euclidean space:
    ``unit(clip(scale * x + offset, 0, 1)) @ W`` (no clip when ``projection["clip"]`` is
    False; a row all zero after the min-max step stays zero).

    Parameters
    ----------
    raw : array_like, shape (N, D)
    projection : dict
        ``scale`` and ``offset`` of shape (D,), ``W`` of shape (D, r), optional ``clip``.

    Returns
    -------
    ndarray, shape (N, r)
    """
    x = np.asarray(raw, dtype=np.float64) * projection["scale"] + projection["offset"]
    if projection.get("clip", True):
        np.clip(x, 0.0, 1.0, out=x)
    norm = np.linalg.norm(x, axis=1, keepdims=True)
    x /= np.where(norm > 0.0, norm, 1.0)
    return x @ np.asarray(projection["W"], dtype=np.float64)


class _RDSRLearner:
    """RDSR behind the learner interface: similar pairs only.

    ``estimator`` replaces the RDSR model by any object with ``fit(X_unlabeled,
    positive_pairs)`` and ``components_`` (r, D) (a PCA, say), as the library allows.
    """

    def __init__(self, estimator: Any = None, **kwargs: Any) -> None:
        self.model = RDSR(**kwargs) if estimator is None else estimator

    def fit(
        self, X_unlabeled: FloatArray, X_a: FloatArray, X_b: FloatArray, labels: ArrayLike
    ) -> _RDSRLearner:
        positive = np.asarray(labels, dtype=bool)
        if not positive.any():
            raise ValueError("RDSR needs at least one similar pair")
        self.model.fit(X_unlabeled, np.stack((X_a[positive], X_b[positive]), axis=1))
        return self

    def projection(self) -> FloatArray:
        return np.asarray(self.model.components_, dtype=np.float64).T


def _make_learner(feature: str, learner: str, kwargs: dict[str, Any]) -> Any:
    random_state = kwargs.pop("random_state", None)
    if learner == "L2":
        if kwargs:
            raise TypeError(f"L2 takes no parameters, got {sorted(kwargs)}")
        return _L2()
    if learner == "LMS":
        kwargs.setdefault("power", 1 if feature == "JRF" else 2)
        return LMS(**kwargs)
    if learner == "Xing":
        return Xing(random_state=random_state, **kwargs)
    if learner == "SDA":
        return SDA(**kwargs)
    if learner == "RDSR":
        return _RDSRLearner(random_state=random_state, **kwargs)
    if learner == "LOGIT":
        return PairLogistic(**kwargs)
    raise ValueError(f"unknown learner {learner!r}")


class FeatureMetric:
    """A feature set, the min-max (clipped) + unit-length scaling, and a metric learner.

    Parameters
    ----------
    feature : str
        Key of :data:`FEATURES`.
    learner : str
        One of :data:`LEARNERS`.
    clip : bool
        Clip the min-max step to the training range (the library's convention: a pose of
        another body cannot dominate its unit-length vector by one out-of-range feature).
    estimator : object, optional
        RDSR only: a replacement model with ``fit(X_unlabeled, positive_pairs)`` and
        ``components_``.
    **kwargs
        Learner parameters (and ``random_state``).

    Attributes
    ----------
    normalizer_ : MinMaxUnitScaler
        Min-max + unit-length normalisation fitted on all training poses.
    learner_ : object
        The fitted learner.
    projection_ : dict or None
        ``scale``, ``offset`` (D,), ``W`` (D, r) and ``clip``: the metric is
        ``||project_features(a) - project_features(b)||`` (:func:`project_features`); None for
        a learner that is no Euclidean projection (``JRF+LMS``'s weighted L1).
    uses_dissimilar : bool
        Whether the learner reads dissimilar pairs (L2 and RDSR do not).
    """

    def __init__(
        self, feature: str, learner: str, clip: bool = True, estimator: Any = None, **kwargs: Any
    ) -> None:
        if feature not in FEATURES:
            raise ValueError(f"unknown feature {feature!r}; expected one of {sorted(FEATURES)}")
        if learner not in LEARNERS:
            raise ValueError(f"unknown learner {learner!r}; expected one of {LEARNERS}")
        if estimator is not None and learner != "RDSR":
            raise TypeError("estimator replaces the RDSR model only")
        self.feature = feature
        self.learner = learner
        self.clip = clip
        self.kwargs = dict(kwargs)
        self.uses_dissimilar = learner in ("LMS", "Xing", "SDA", "LOGIT")
        if estimator is not None:
            self.learner_ = _RDSRLearner(estimator=estimator)
        else:
            self.learner_ = _make_learner(feature, learner, dict(kwargs))

    def raw_features(self, data: PoseData) -> FloatArray:
        """Unscaled feature rows of ``data``, shape (N, D)."""
        return np.asarray(FEATURES[self.feature](data), dtype=np.float64)

    def features(self, data: PoseData) -> FloatArray:
        """Normalised feature rows of ``data``, shape (N, D)."""
        return self.normalizer_.transform(self.raw_features(data))

    def fit(
        self,
        unlabeled: PoseData,
        train_a: PoseData,
        train_b: PoseData,
        train_labels: ArrayLike,
    ) -> FeatureMetric:
        return self.fit_features(
            self.raw_features(unlabeled),
            self.raw_features(train_a),
            self.raw_features(train_b),
            train_labels,
        )

    def fit_features(
        self, raw_u: ArrayLike, raw_a: ArrayLike, raw_b: ArrayLike, train_labels: ArrayLike
    ) -> FeatureMetric:
        """:meth:`fit` on raw feature rows (unlabeled (N', D), pairs (P, D) each)."""
        labels = np.asarray(train_labels, dtype=bool).reshape(-1)
        raw_u, raw_a, raw_b = (np.asarray(x, dtype=np.float64) for x in (raw_u, raw_a, raw_b))
        if not (len(raw_a) == len(raw_b) == labels.shape[0]):
            raise ValueError(
                f"train_a, train_b and train_labels disagree: "
                f"{len(raw_a)}, {len(raw_b)}, {labels.shape[0]}"
            )
        self.normalizer_ = MinMaxUnitScaler(clip=self.clip).fit(
            np.concatenate((raw_u, raw_a, raw_b))
        )
        norm = self.normalizer_.transform
        self.learner_.fit(norm(raw_u), norm(raw_a), norm(raw_b), labels)
        W = self._projection_matrix(raw_u.shape[1])
        self.projection_ = (
            None
            if W is None
            else {
                "scale": self.normalizer_.scale_,
                "offset": self.normalizer_.offset_,
                "W": W,
                "clip": self.clip,
            }
        )
        return self

    def _projection_matrix(self, n_features: int) -> FloatArray | None:
        learner = self.learner_
        if isinstance(learner, _L2):
            return learner.projection(n_features)
        if isinstance(learner, _RDSRLearner):
            return learner.projection()
        if isinstance(learner, (LMS, PairLogistic)):
            if learner.power != 2:
                return None
            kept = np.flatnonzero(learner.weights_ > 0)
            W = np.zeros((n_features, kept.size))
            W[kept, np.arange(kept.size)] = np.sqrt(learner.weights_[kept])
            return W
        return np.asarray(learner.projection_, dtype=np.float64)

    def transform(self, data: PoseData) -> FloatArray:
        """Poses in the metric's Euclidean space, shape (N, r) (projection learners only)."""
        if self.projection_ is None:
            raise TypeError(f"{self.feature}+{self.learner} is no Euclidean projection")
        return project_features(self.raw_features(data), self.projection_)

    def distances(self, a: PoseData, b: PoseData) -> FloatArray:
        if self.projection_ is None:
            return self.learner_.distances(self.features(a), self.features(b))
        return np.linalg.norm(self.transform(a) - self.transform(b), axis=1)

    def pairwise(self, query: PoseData, base: PoseData) -> FloatArray:
        if self.projection_ is None:
            return self.learner_.pairwise(self.features(query), self.features(base))
        from scipy.spatial.distance import cdist

        return cdist(self.transform(query), self.transform(base))

    def __repr__(self) -> str:
        return f"FeatureMetric({self.feature!r}, {self.learner!r}, {self.kwargs!r})"


class FeetDistance:
    """The strong simple baseline of the blended-transition labels: no learning, the Euclidean
    distance between the two feet's body-local positions (cm), the Hip at the origin."""

    _FEET = FEET_16

    def __init__(self, random_state: Any = None) -> None:
        pass

    def fit(
        self, unlabeled: PoseData, train_a: PoseData, train_b: PoseData, train_labels: ArrayLike
    ) -> FeetDistance:
        return self

    def _rows(self, data: PoseData) -> FloatArray:
        return np.asarray(data.positions)[:, self._FEET].reshape(len(data), -1)

    def distances(self, a: PoseData, b: PoseData) -> FloatArray:
        return np.linalg.norm(self._rows(a) - self._rows(b), axis=1)

    def pairwise(self, query: PoseData, base: PoseData) -> FloatArray:
        from scipy.spatial.distance import cdist

        return cdist(self._rows(query), self._rows(base))


class JointDistanceMethod(JointDistance):
    """:class:`~quatmotion.pose.baselines.JointDistance` accepting (and ignoring) a seed."""

    def __init__(self, kind: str, weights: str, random_state: Any = None, **kwargs: Any) -> None:
        super().__init__(kind, weights, **kwargs)  # type: ignore[arg-type]


def _feature_method(feature: str, learner: str) -> Callable[..., PoseMethod]:
    def build(**kwargs: Any) -> PoseMethod:
        return FeatureMetric(feature, learner, **kwargs)

    return build


def _joint_method(kind: str, weights: str) -> Callable[..., PoseMethod]:
    def build(**kwargs: Any) -> PoseMethod:
        return JointDistanceMethod(kind, weights, **kwargs)

    return build


def _build_registry() -> dict[str, Callable[..., PoseMethod]]:
    registry: dict[str, Callable[..., PoseMethod]] = {}
    for kind, prefix in (("orientation", "JO"), ("coordinate", "JC")):
        for weights, tag in (("uniform", ""), ("lee", "W"), ("learned", "L")):
            registry[f"{tag}{prefix}D"] = _joint_method(kind, weights)
    for feature in FEATURES:
        for learner in LEARNERS:
            registry[f"{feature}+{learner}"] = _feature_method(feature, learner)
    registry["FEET"] = FeetDistance
    registry["PAIR-GBT"] = TransitionClassifier
    registry["L2"] = registry["GPD+L2"]
    registry["LMS"] = registry["L2+LMS"] = registry["GPD+LMS"]
    registry["Xing"] = registry["GPD+Xing"]
    registry["SDA"] = registry["GPD+SDA"]
    registry["RDSR"] = registry["GPD+RDSR"]
    return registry


#: Name -> factory of an unfitted :class:`PoseMethod`.
METHODS: dict[str, Callable[..., PoseMethod]] = _build_registry()
#: The distances compared in Fig. 5 (RGF+Boost is not reproduced: its 500,000-feature pool
#: and AdaBoost selection come from another paper).
FIG5_METHODS: tuple[str, ...] = (
    "JOD", "WJOD", "LJOD", "JCD", "WJCD", "LJCD", "JRF+LMS", "GPD+RDSR",
)  # fmt: skip
