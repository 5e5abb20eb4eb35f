"""What the runtime decodes from: a clip's coefficient rows and its skeleton's rotation tables.

Conventions
-----------
* :class:`ClipRows` is what a format's clip decoder hands the runtime (bytes -> rows is the
  format's work, :mod:`quatmotion.codec`; rows -> poses is the runtime's): the clip's
  segments side by side, their knots, the coefficient rows of the coded channels in weighted
  units (a channel is its row evaluated, divided by its scale) and the clip's corrections as
  the values they add to channels of frames.
* :class:`Rig` is a skeleton and channel layout as the kernels read them: each joint's kind,
  first channel and channel count, its dof axes and pre-rotated unit axes, and the reference
  rotations of the layout (w first).
* Channels ``0, 1, 2`` are the root's translation in centimetres; the rotation channels of
  every joint follow, then the translations of joints that move (not needed for rotations).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quatmotion.runtime import kernels

__all__ = ["ClipRows", "Rig", "clip_rotations"]


@dataclass(frozen=True, eq=False)
class ClipRows:
    """One clip as coefficient rows (arrays contiguous, as the kernels read them).

    Attributes
    ----------
    name : str
    n_frames : int
        ``T``.
    fps : float
    segs : ndarray of int64, shape (S, 6)
        Each segment's first frame, frames, first row, whether it is a cubic B-spline (else
        one row per frame), and the span of its clamped knot vector in ``knots``.
    knots : ndarray of float64, shape (K,)
    rows : ndarray of float64, shape (n, c)
        Coefficient rows of the channels ``cols``, weighted units.
    cols : ndarray of int64, shape (c,)
        The coded channels, ascending.
    scale : ndarray of float64, shape (c,)
        Channel = weighted value / scale.
    fix_frames, fix_channels : ndarray of int64, shape (m,)
        The corrections' frames (ascending) and channels.
    fix_values : ndarray of float64, shape (m,)
        What each adds to its channel of its frame, in the channel's units.
    group_rows : int
        With ``decode_groups``: rows ``[g G, (g + 1) G)`` are group ``g``, which decodes
        alone; 0 when ``rows`` holds every row decoded.
    decode_groups : callable or None
        ``decode_groups(P, first, stop)`` decodes groups ``first .. stop - 1`` into their rows
        of ``P`` (``rows`` itself is then not decoded: a sampler decodes a group when a pose
        first needs it).
    """

    name: str
    n_frames: int
    fps: float
    segs: NDArray[np.int64]
    knots: NDArray[np.float64]
    rows: NDArray[np.float64]
    cols: NDArray[np.int64]
    scale: NDArray[np.float64]
    fix_frames: NDArray[np.int64]
    fix_channels: NDArray[np.int64]
    fix_values: NDArray[np.float64]
    group_rows: int = 0
    decode_groups: Callable[[NDArray[np.float64], int, int], None] | None = None

    @property
    def n_groups(self) -> int:
        """Groups of rows that decode alone (0: every row decoded)."""
        return -(-len(self.rows) // self.group_rows) if self.group_rows else 0

    def decoded(self) -> ClipRows:
        """These rows with every group decoded (itself when they are)."""
        if self.decode_groups is None:
            return self
        P = np.zeros_like(self.rows)
        self.decode_groups(P, 0, self.n_groups)
        return ClipRows(self.name, self.n_frames, self.fps, self.segs, self.knots, P,
                        self.cols, self.scale, self.fix_frames, self.fix_channels,
                        self.fix_values)  # fmt: skip

    def dense_corrections(self, n_channels: int) -> NDArray[np.float64]:
        """The corrections as a ``(T, C)`` array (no rows when there are none)."""
        if not len(self.fix_frames):
            return np.zeros((0, 0))
        corr = np.zeros((self.n_frames, n_channels))
        np.add.at(corr, (self.fix_frames, self.fix_channels), self.fix_values)
        return corr


@dataclass(frozen=True, eq=False)
class Rig:
    """A skeleton's rotation tables (module docstring).

    Attributes
    ----------
    joint_names : tuple of str
    kinds, starts, counts : ndarray of int64, shape (J,)
        Each joint's kind (0 fixed, 1 Euler, 2 rotation vector, 3 root), first rotation
        channel and number of rotation channels.
    dof_axes : ndarray of int64, shape (J, 3)
        The axis (0, 1, 2 for x, y, z) of each Euler dof, in order.
    pre : ndarray of float64, shape (J, 4, 3)
        ``pre[j, i]`` the joint's axis ``i`` rotated by its axis rotation; ``pre[j, 3, 0]``
        1.0 for intrinsic composition.
    ref : ndarray of float64, shape (J, 4)
        The layout's reference rotations.
    n_channels : int
    """

    joint_names: tuple[str, ...]
    kinds: NDArray[np.int64]
    starts: NDArray[np.int64]
    counts: NDArray[np.int64]
    dof_axes: NDArray[np.int64]
    pre: NDArray[np.float64]
    ref: NDArray[np.float64]
    n_channels: int

    @property
    def n_joints(self) -> int:
        return len(self.kinds)

    @property
    def rotation_channels(self) -> int:
        """The channels the rotations read: the root's translation and every rotation's."""
        return int(self.starts[-1] + self.counts[-1]) if len(self.starts) else 3

    def tables(self) -> tuple:
        """``(kinds, starts, counts, dof_axes, pre, ref)``, as the kernels take them."""
        return self.kinds, self.starts, self.counts, self.dof_axes, self.pre, self.ref


def clip_rotations(
    rows: ClipRows, rig: Rig
) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """Root translation ``(T, 3)`` cm and local rotations ``(T, J, 4)`` of a whole clip, one
    compiled call from its rows; ``None`` if a channel is not finite (a damaged clip)."""
    m = rig.rotation_channels
    rows = rows.decoded()
    if len(rows.cols) < m or rows.cols[m - 1] != m - 1:  # not the first coded ones
        raise ValueError(f"clip {rows.name!r}: its rotation channels are not all coded")
    root = np.empty((rows.n_frames, 3))
    rotations = np.empty((rows.n_frames, rig.n_joints, 4))
    finite = kernels().clip_rotations(
        rows.segs, rows.knots, rows.rows, rows.scale, m, rows.fix_frames, rows.fix_channels,
        rows.fix_values, *rig.tables(), root, rotations,
    )  # fmt: skip
    return (root, rotations) if finite else None
