"""A saved, searchable pose library: "poses like frame F of clip C" (:class:`PoseLibrary`;
:mod:`quatmotion.pose.library.pose_library` says how it works and how the package is laid out).
"""

from __future__ import annotations

from quatmotion.pose.library.clips import (
    ProjectedClip,
    load_pose_clip,
    load_pose_source,
    project_gpd,
    projected_clip,
)
from quatmotion.pose.library.file import FORMAT
from quatmotion.pose.library.learn import training_set
from quatmotion.pose.library.pose_library import PoseLibrary, PoseMatch
from quatmotion.pose.library.settings import DEFAULT_METRIC, HEIGHT_RANGE, METRICS, PoseSettings
from quatmotion.pose.library.transitions import learn_transitions, transition_judge

__all__ = [
    "DEFAULT_METRIC",
    "FORMAT",
    "HEIGHT_RANGE",
    "METRICS",
    "PoseLibrary",
    "PoseMatch",
    "PoseSettings",
    "ProjectedClip",
    "learn_transitions",
    "load_pose_clip",
    "load_pose_source",
    "project_gpd",
    "projected_clip",
    "training_set",
    "transition_judge",
]
