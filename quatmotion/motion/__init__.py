"""Skeletons, clips and forward kinematics (the bottom layer, with :mod:`quatmotion.quat`)."""

from quatmotion.motion.clip import Motion, join
from quatmotion.motion.displacement import angular_displacements
from quatmotion.motion.humanoid import (
    JOINTS_16,
    HumanoidError,
    HumanoidMap,
    map_humanoid,
    with_joint_map,
)
from quatmotion.motion.kinematics import WorldTransforms, forward_kinematics, standing_height
from quatmotion.motion.skeleton import Skeleton

__all__ = [
    "JOINTS_16",
    "HumanoidError",
    "HumanoidMap",
    "Motion",
    "Skeleton",
    "WorldTransforms",
    "angular_displacements",
    "forward_kinematics",
    "join",
    "map_humanoid",
    "standing_height",
    "with_joint_map",
]
