"""Forward kinematics: local rotations and offsets to global positions and rotations."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quatmotion import quat
from quatmotion.motion.clip import Motion


@dataclass(frozen=True, eq=False)
class Pose:
    """World-space result of forward kinematics.

    Attributes
    ----------
    positions : ndarray, shape (T, J, 3)
        Joint positions, centimetres, Y up.
    rotations : ndarray, shape (T, J, 4)
        Global joint rotations, unit quaternions, w first.
    site_positions : ndarray, shape (T, S, 3)
        End-site positions, centimetres (``S = 0`` when not asked for).
    """

    positions: NDArray[np.float64]
    rotations: NDArray[np.float64]
    site_positions: NDArray[np.float64]

    def all_positions(self) -> NDArray[np.float64]:
        """Joints then end sites: ``(T, J + S, 3)`` centimetres."""
        return np.concatenate((self.positions, self.site_positions), axis=1)


def forward_kinematics(motion: Motion, include_sites: bool = True) -> Pose:
    """Global positions and rotations of every joint (and end site) of ``motion``.

    Vectorised over frames; one pass over joints in parent-first order.

    Parameters
    ----------
    motion : Motion
        ``T`` frames of a skeleton with ``J`` joints and ``S`` end sites.
    include_sites : bool
        Also place the end sites.

    Returns
    -------
    Pose
        ``positions (T, J, 3)``, ``rotations (T, J, 4)``, ``site_positions (T, S, 3)``.
    """
    sk = motion.skeleton
    T, J = motion.n_frames, sk.n_joints
    local = motion.rotations
    # Rotation matrices make the per-joint step one small matmul over frames, the fastest
    # NumPy form of the chain; quaternions are converted once per clip, both ways.
    local_m = quat.to_matrix(local)
    global_m = np.empty_like(local_m)
    positions = np.empty((T, J, 3))
    global_m[:, 0] = local_m[:, 0]
    positions[:, 0] = motion.root_translation
    translations = motion.joint_translations
    parents = sk.parents
    for j in range(1, J):
        p = parents[j]
        global_m[:, j] = global_m[:, p] @ local_m[:, j]
        if translations is None:
            moved = global_m[:, p] @ sk.offsets[j]
        else:
            moved = np.einsum("tab,tb->ta", global_m[:, p], translations[:, j])
        positions[:, j] = positions[:, p] + moved
    if include_sites and sk.n_sites:
        sites = positions[:, sk.site_parents] + np.einsum(
            "tsab,sb->tsa", global_m[:, sk.site_parents], sk.site_offsets
        )
    else:
        sites = np.zeros((T, 0, 3))
    return Pose(positions=positions, rotations=quat.from_matrix(global_m), site_positions=sites)
