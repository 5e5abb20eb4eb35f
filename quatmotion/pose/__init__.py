"""Pose distance: the 16-joint skeleton, GPD features, RDSR metric learning, baselines, labels,
evaluation and approximate-nearest-neighbour pose search (Chen et al., TVCG 2010).

Submodules
----------
skeleton16
    ``JOINTS_16``, ``PARENTS_16``; world and body-local 16-joint positions of a clip.
data
    ``PoseData``: body-local positions with velocities and accelerations; ``PoseClip``: a
    clip prepared for pose analysis (resampled, scaled, on the 16 joints).
gpd
    The 1683-dimensional Geometric Pose Descriptor.
scaler
    ``MinMaxUnitScaler``: the paper's feature scaling (Eq. 38), for every feature family.
metric
    ``RDSR``: semi-supervised metric learning with sparse representation.
baselines, methods
    The compared pose distances and the ``METHODS`` registry.
labels
    Transition labels (Kovar's point-cloud distance) and retrieval labels (k-means, DTW phase).
evaluate
    Transition precision (Eq. 36-37) and retrieval precision@s.
transition
    ``TransitionClassifier``: the probability a transition from one pose to another plays badly.
blend_labels
    Transition labels of played, blended and judged transitions.
index
    ``HNSWIndex`` (hnswlib): approximate nearest neighbours of projected poses.
library
    ``PoseLibrary`` (a saved, searchable library; a package: settings, build, file, queries).

Names are loaded on first use, so ``import quatmotion.pose`` stays cheap.
"""

from __future__ import annotations

from quatmotion._lazy import lazy_exports

_EXPORTS = {
    "JOINTS_16": "skeleton16",
    "PARENTS_16": "skeleton16",
    "local_positions16": "skeleton16",
    "world_positions16": "skeleton16",
    "PoseClip": "data",
    "PoseData": "data",
    "MinMaxUnitScaler": "scaler",
    "gpd_features": "gpd",
    "FEATURE_NAMES": "gpd",
    "RDSR": "metric",
    "METHODS": "methods",
    "transition_precision": "evaluate",
    "precision_at": "evaluate",
    "transition_labels": "labels",
    "retrieval_set": "labels",
    "HNSWIndex": "index",
    "PoseLibrary": "library",
}

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
