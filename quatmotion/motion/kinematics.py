"""Forward kinematics: local rotations and offsets to global positions and rotations.

The chain is walked in parent-first order (``parents[j] < j``), one frame after another on one
core (fast enough that threads would cost more to start than they save). It is a Numba kernel
because the per-joint step on ``(T, 4)`` arrays is too small for NumPy to amortise its call
overhead (the I/O benchmark measures its throughput: ``docs/performance.md``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

from quatmotion.motion.clip import Motion
from quatmotion.quat.jit import multiply, rotate


@dataclass(frozen=True, eq=False)
class WorldTransforms:
    """World-space joint transforms of a clip: the result of forward kinematics.

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


@numba.njit(cache=True)
def _fk_kernel(
    local: np.ndarray,
    root: np.ndarray,
    offsets: np.ndarray,
    translations: np.ndarray,
    use_translations: bool,
    parents: np.ndarray,
    site_parents: np.ndarray,
    site_offsets: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    T, J = local.shape[0], local.shape[1]
    S = site_parents.shape[0]
    glob = np.empty((T, J, 4))
    pos = np.empty((T, J, 3))
    sites = np.empty((T, S, 3))
    for t in range(T):
        glob[t, 0] = local[t, 0]
        pos[t, 0] = root[t]
        for j in range(1, J):
            p = parents[j]
            a = glob[t, p]
            b = local[t, j]
            w, x, y, z = multiply(a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3])
            glob[t, j, 0] = w
            glob[t, j, 1] = x
            glob[t, j, 2] = y
            glob[t, j, 3] = z
            o = translations[t, j] if use_translations else offsets[j]
            dx, dy, dz = rotate(a[0], a[1], a[2], a[3], o[0], o[1], o[2])
            pos[t, j, 0] = pos[t, p, 0] + dx
            pos[t, j, 1] = pos[t, p, 1] + dy
            pos[t, j, 2] = pos[t, p, 2] + dz
        for s in range(S):
            p = site_parents[s]
            a = glob[t, p]
            o = site_offsets[s]
            dx, dy, dz = rotate(a[0], a[1], a[2], a[3], o[0], o[1], o[2])
            sites[t, s, 0] = pos[t, p, 0] + dx
            sites[t, s, 1] = pos[t, p, 1] + dy
            sites[t, s, 2] = pos[t, p, 2] + dz
    return pos, glob, sites


def forward_kinematics(motion: Motion, include_sites: bool = True) -> WorldTransforms:
    """Global positions and rotations of every joint (and end site) of ``motion``.

    Parameters
    ----------
    motion : Motion
        ``T`` frames of a skeleton with ``J`` joints and ``S`` end sites.
    include_sites : bool
        Also place the end sites.

    Returns
    -------
    WorldTransforms
        ``positions (T, J, 3)`` cm, ``rotations (T, J, 4)``, ``site_positions (T, S, 3)`` cm.
    """
    sk = motion.skeleton
    translations = motion.joint_translations
    use_translations = translations is not None
    if translations is None:
        translations = np.zeros((1, 1, 3))
    site_parents = sk.site_parents if include_sites else sk.site_parents[:0]
    positions, rotations, sites = _fk_kernel(
        np.ascontiguousarray(motion.rotations),
        np.ascontiguousarray(motion.root_translation),
        np.ascontiguousarray(sk.offsets),
        np.ascontiguousarray(translations),
        use_translations,
        np.ascontiguousarray(sk.parents),
        np.ascontiguousarray(site_parents),
        np.ascontiguousarray(sk.site_offsets[: len(site_parents)]),
    )
    return WorldTransforms(positions=positions, rotations=rotations, site_positions=sites)


def standing_height(motion: Motion, step: int = 1) -> float:
    """The figure's height in centimetres as seen in motion: the median over frames of the
    vertical (Y) extent of all joints and end sites.

    Unlike :meth:`Skeleton.height`, which measures the zero-rotation rest pose, this does not
    assume the rest pose stands upright (Bandai's BVH rest pose lies along the X axis). The
    median ignores the few frames of a clip with raised arms or a crouch. ``step`` subsamples
    frames for speed.
    """
    if motion.n_frames == 0:
        raise ValueError(f"clip {motion.name!r} has no frames")
    y = forward_kinematics(motion.slice(0, None, step)).all_positions()[..., 1]
    return float(np.median(y.max(axis=1) - y.min(axis=1)))
