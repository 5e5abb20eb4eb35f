"""Skeletons, clips and forward kinematics (the bottom layer, with :mod:`quatmotion.quat`)."""

from quatmotion.motion.clip import Motion, join
from quatmotion.motion.displacement import angular_displacements
from quatmotion.motion.kinematics import WorldTransforms, forward_kinematics, standing_height
from quatmotion.motion.skeleton import Skeleton

__all__ = [
    "Motion",
    "Skeleton",
    "WorldTransforms",
    "angular_displacements",
    "forward_kinematics",
    "join",
    "standing_height",
]
