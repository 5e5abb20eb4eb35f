"""Reconstruction and size metrics of ``docs/metrics.md`` (the one definition each).

Conventions
-----------
* Positions come from forward kinematics of the full skeleton: every joint and every end site
  (for ASF/AMC the root and each bone's end), centimetres, Y up.
* **ARMS** (QSSD paper Eq. 12): per frame the root mean square over points of the position
  error, then the mean over frames; over a collection the frame-weighted mean.
* **Distortion rate** (Eq. 13): ``100 ||P - P_hat||_F / ||P - E(P)||_F`` with ``P`` the
  ``(T, 3N)`` positions of a clip and ``E(P)`` its mean pose; over a collection the
  frame-weighted mean of the clips' rates.
* **Max joint error**: the largest position error over frames and points.
* **Max virtual-vertex error** (the Animation Compression Library's measure): the points 3 cm
  along each joint's local x, y and z axes, carried by the joint's global transform; the
  largest distance between original and decoded ones.
* **Ratios** against the AMC/BVH text size and against raw float32 channels
  (``4 * degrees of freedom * frames``), always both; compressed sizes are whole files.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quatmotion import quat
from quatmotion.motion import Motion, WorldTransforms, forward_kinematics

__all__ = [
    "VIRTUAL_VERTEX_CM",
    "ClipErrors",
    "CollectionErrors",
    "clip_errors",
    "collection_errors",
    "frame_errors",
    "point_errors",
    "raw_float32_bytes",
]

VIRTUAL_VERTEX_CM = 3.0
"""Distance of the virtual vertices from their joint, centimetres."""


@dataclass(frozen=True)
class ClipErrors:
    """Errors of one decoded clip (centimetres; the distortion rate in percent)."""

    frames: int
    arms: float
    distortion_rate: float
    max_joint: float
    max_virtual_vertex: float


@dataclass(frozen=True)
class CollectionErrors:
    """Frame-weighted ARMS and distortion rate, largest errors, over clips."""

    frames: int
    arms: float
    distortion_rate: float
    max_joint: float
    max_virtual_vertex: float


def point_errors(
    original: WorldTransforms | NDArray[np.float64], decoded: Motion
) -> NDArray[np.float64]:
    """Position error of every point (joints then end sites) of every frame: ``(T, J + S)`` cm.

    ``original`` is the original clip's forward kinematics or its ``(T, J + S, 3)`` positions.
    """
    P = original.all_positions() if isinstance(original, WorldTransforms) else original
    return np.linalg.norm(P - forward_kinematics(decoded).all_positions(), axis=-1)


def clip_errors(original: Motion | WorldTransforms, decoded: Motion) -> ClipErrors:
    """:class:`ClipErrors` of ``decoded`` against ``original`` (a clip or its transforms)."""
    o = forward_kinematics(original) if isinstance(original, Motion) else original
    d = forward_kinematics(decoded)
    P = o.all_positions()
    Q = d.all_positions()
    T = P.shape[0]
    if Q.shape != P.shape:
        raise ValueError(f"decoded positions have shape {Q.shape}, expected {P.shape}")
    if T == 0:
        return ClipErrors(0, 0.0, 0.0, 0.0, 0.0)
    e = np.linalg.norm(P - Q, axis=-1)
    arms = float(np.mean(np.sqrt(np.mean(e * e, axis=1))))
    Pm = P.reshape(T, -1)
    spread = np.linalg.norm(Pm - Pm.mean(axis=0))
    dr = float(100.0 * np.linalg.norm(Pm - Q.reshape(T, -1)) / spread) if spread > 0 else 0.0
    axes = VIRTUAL_VERTEX_CM * np.eye(3)
    vo = o.positions[:, :, None, :] + quat.rotate(o.rotations[:, :, None, :], axes)
    vd = d.positions[:, :, None, :] + quat.rotate(d.rotations[:, :, None, :], axes)
    vv = float(np.linalg.norm(vo - vd, axis=-1).max(initial=0.0))
    return ClipErrors(T, arms, dr, float(e.max(initial=0.0)), vv)


def collection_errors(clips: list[ClipErrors]) -> CollectionErrors:
    """Frame-weighted ARMS and distortion rate, and the largest errors, of ``clips``."""
    T = sum(c.frames for c in clips)
    if T == 0:
        return CollectionErrors(0, 0.0, 0.0, 0.0, 0.0)
    return CollectionErrors(
        T,
        sum(c.arms * c.frames for c in clips) / T,
        sum(c.distortion_rate * c.frames for c in clips) / T,
        max(c.max_joint for c in clips),
        max(c.max_virtual_vertex for c in clips),
    )


def raw_float32_bytes(motion: Motion) -> int:
    """``4 * degrees of freedom * frames``: the clip as raw float32 channels."""
    return 4 * sum(len(c) for c in motion.skeleton.channels) * motion.n_frames


def frame_errors(
    original: WorldTransforms, decoded: Motion, *, vertices: bool = False
) -> NDArray[np.float64]:
    """Largest error of each frame, ``(T,)`` cm: over joints and end sites, and with
    ``vertices`` also over the virtual vertices (the bound the encoder checks)."""
    d = forward_kinematics(decoded)
    err = np.linalg.norm(original.all_positions() - d.all_positions(), axis=-1).max(axis=1)
    if vertices:
        axes = VIRTUAL_VERTEX_CM * np.eye(3)
        vo = original.positions[:, :, None, :] + quat.rotate(
            original.rotations[:, :, None, :], axes
        )
        vd = d.positions[:, :, None, :] + quat.rotate(d.rotations[:, :, None, :], axes)
        err = np.maximum(err, np.linalg.norm(vo - vd, axis=-1).max(axis=(1, 2)))
    return err
