"""The feature scaling of the GPD paper (Eq. 38), used on every pose feature set.

Each dimension is mapped linearly to ``[0, 1]`` over its range on the training poses, then each
pose vector is scaled to unit length, so that every feature family (GPD, joint coordinates,
joint orientations, relative features) reaches a metric learner on a comparable scale.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.utils.validation import check_is_fitted

from quatmotion.pose.gpd import FEATURE_NAMES, N_DIMENSIONS

__all__ = ["MinMaxUnitScaler"]


class MinMaxUnitScaler(TransformerMixin, BaseEstimator):
    """Per-dimension min-max, then unit length: the GPD paper's normalisation (Eq. 38).

    ``fit`` learns each dimension's range on training poses; ``transform`` maps it linearly to
    ``[0, 1]`` (values of new poses outside the training range are not clipped, so they stay
    distinguishable) and scales every pose vector to unit Euclidean length. Dimensions constant
    on the training poses map to 0.

    Parameters
    ----------
    clip : bool
        Clip the min-max output to ``[0, 1]`` before the unit-length step.

    Attributes
    ----------
    data_min_, data_max_ : ndarray, shape (D,)
        Per-dimension range on the training poses.
    scale_, offset_ : ndarray, shape (D,)
        ``U`` and ``v`` of Eq. 38: ``x' = scale_ * x + offset_``.
    feature_names_ : ndarray of str, shape (D,)
        :data:`FEATURE_NAMES` when D is 1683, else ``x0 .. x{D-1}``.
    n_features_in_ : int
    """

    def __init__(self, clip: bool = False) -> None:
        self.clip = clip

    @staticmethod
    def _as_matrix(X: ArrayLike) -> NDArray[np.float64]:
        gpd = getattr(X, "gpd", None)  # a PoseData works as input too
        arr = np.asarray(gpd if gpd is not None else X, dtype=np.float64)
        if arr.ndim != 2:
            raise ValueError(f"expected a (N, D) feature matrix, got shape {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError("features must be finite")
        return arr

    def fit(self, X: ArrayLike, y: object = None) -> MinMaxUnitScaler:
        """Learn per-dimension ranges.

        Parameters
        ----------
        X : array_like, shape (N, D), or PoseData
            Raw features (:func:`gpd_features`), N >= 1.
        y : ignored
        """
        arr = self._as_matrix(X)
        if arr.shape[0] == 0:
            raise ValueError("MinMaxUnitScaler.fit needs at least one row")
        self.data_min_ = arr.min(axis=0)
        self.data_max_ = arr.max(axis=0)
        span = self.data_max_ - self.data_min_
        constant = span <= 1e-12 * np.maximum(1.0, np.abs(self.data_max_))
        self.scale_ = np.where(constant, 0.0, 1.0 / np.where(constant, 1.0, span))
        self.offset_ = -self.data_min_ * self.scale_
        self.n_features_in_ = arr.shape[1]
        generic = [f"x{k}" for k in range(arr.shape[1])]
        self.feature_names_ = np.asarray(FEATURE_NAMES if arr.shape[1] == N_DIMENSIONS else generic)
        return self

    def transform(self, X: ArrayLike) -> NDArray[np.float64]:
        """Normalise features.

        Parameters
        ----------
        X : array_like, shape (N, D), or PoseData

        Returns
        -------
        ndarray, shape (N, D)
            Unit-length rows (a row that is all zero after min-max stays zero).
        """
        check_is_fitted(self, "scale_")
        arr = self._as_matrix(X)
        if arr.shape[1] != self.n_features_in_:
            raise ValueError(f"expected {self.n_features_in_} features, got {arr.shape[1]}")
        out = arr * self.scale_ + self.offset_
        if self.clip:
            np.clip(out, 0.0, 1.0, out=out)
        norm = np.linalg.norm(out, axis=1, keepdims=True)
        return out / np.where(norm > 0.0, norm, 1.0)

    def get_feature_names_out(self, input_features: object = None) -> NDArray[np.str_]:
        check_is_fitted(self, "feature_names_")
        return self.feature_names_
