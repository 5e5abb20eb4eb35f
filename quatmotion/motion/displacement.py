"""Angular displacements: each joint's rotation relative to a reference pose.

The preprocessing of the QSSD paper (section 4.2), shared by QSSD, the benchmarks, the codec
and retrieval: choose a reference pose (by default the clip's first frame), then express every
frame's local joint rotations relative to it, ``d_t = q_ref^-1 q_t`` per joint. A sample is one
frame's displacements of the joints that rotate: ``(n, 4)`` unit quaternions, w first.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quatmotion import quat
from quatmotion.motion.clip import Motion

__all__ = ["angular_displacements"]


def angular_displacements(
    motion: Motion,
    *,
    reference_frame: int = 0,
    step: int = 1,
    joints: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """Every joint's local rotation relative to the reference frame, ``q_ref^-1 q_t``.

    Parameters
    ----------
    motion : Motion
        ``T`` frames.
    reference_frame : int
        Frame of the reference pose, counted from 0 (``-1`` is the last).
    step : int
        Keep every ``step``-th frame, starting at frame 0.
    joints : array_like of int, optional
        Joints to keep, in this order; default :meth:`Skeleton.rotating_joints` (the root and
        every joint with rotation channels).

    Returns
    -------
    ndarray, shape (ceil(T / step), n, 4)
        Unit quaternions, w first, hemisphere-continuous over frames (as the motion's).
    """
    if not (isinstance(step, int | np.integer) and step >= 1):
        raise ValueError(f"step must be a positive integer, got {step!r}")
    T = motion.n_frames
    if not -T <= reference_frame < T:
        raise ValueError(
            f"reference_frame {reference_frame} is outside the clip's frames 0..{T - 1}"
        )
    keep = motion.skeleton.rotating_joints() if joints is None else np.asarray(joints, dtype=int)
    rotations = motion.rotations[:, keep]
    reference = quat.conjugate(rotations[reference_frame])
    return quat.multiply(reference, rotations[::step])
