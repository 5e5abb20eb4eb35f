"""Sampling poses of a clip at arbitrary times: :class:`ClipSampler` (a clip's rows and rig,
ready to sample) and :class:`Sampler` (one clip bound: joints and mode chosen once).

Conventions
-----------
* Time ``t`` seconds is frame position ``u = t fps``; frame ``f`` is at ``f / fps``.
* **Clamp** holds ``u`` in ``[0, T - 1]``; **loop** takes ``u`` modulo ``T`` (period
  ``T / fps``): between frame ``T - 1`` and ``T`` (= frame 0) the pose is interpolated from
  the last frame to the first.
* **Between frames** the clip's model decides: where a spline segment spans ``u`` its cubic
  B-spline is evaluated in channel space, then channels turn into rotations; the clip's
  corrections are added, linearly interpolated between frames, so the value at a frame is
  exactly the decoded frame. Where no spline spans ``u`` (segments kept frame by frame, the
  gap between two segments, the loop's wrap) the pose is the normalised lerp (shorter arc)
  of the two decoded frames' rotations and the lerp of their root translations.
* A :class:`Sampler` packs its clip's tables into one array (scratch rows and the output
  included), so one pose per call is one compiled call of two arguments that allocates
  nothing; a batch is decoded a block of poses at a time (each joint's rotations one loop
  over the block: :mod:`quatmotion.runtime._kernels`).
* Each pose evaluates the spline where it is sampled, and a joint subset only the channels
  of those joints.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from quatmotion.runtime import kernels
from quatmotion.runtime.clip import ClipRows, Rig

__all__ = ["MODES", "ClipSampler", "Sampler"]

MODES = ("clamp", "loop")


class ClipSampler:
    """One clip's rows and rig, ready to sample: joint selections' tables and their bound
    :class:`Sampler` made once each."""

    def __init__(self, rows: ClipRows, rig: Rig):
        self.rows = rows
        self.rig = rig
        self.name = rows.name
        self.fps = float(rows.fps)
        self.n_frames = int(rows.n_frames)
        self._segs = rows.segs
        self._knots = rows.knots
        self._P = rows.rows
        self._cols = rows.cols
        self._scale = rows.scale
        self._corr = rows.dense_corrections(rig.n_channels)
        self._names = {n: j for j, n in enumerate(rig.joint_names)}
        self._all = np.arange(rig.n_joints, dtype=np.int64)
        self._selections: dict[bytes, tuple] = {}
        self._bound: Sampler | None = None
        self._samplers: dict[tuple, Sampler] = {}

    @property
    def lazy(self) -> bool:
        """Whether this clip's rows decode by group, when a pose first needs one."""
        return self.rows.decode_groups is not None

    def decode_all(self) -> None:
        """Every group of rows decoded (samplers made from now on start with them)."""
        if self.lazy:
            self.rows = self.rows.decoded()
            self._P = self.rows.rows

    # ------------------------------------------------------------------ arguments
    def _joints(self, joints) -> NDArray[np.int64]:
        J = self.rig.n_joints
        if joints is None:
            return np.arange(J, dtype=np.int64)
        items = [joints] if isinstance(joints, str | int | np.integer) else list(joints)
        out = np.empty(len(items), dtype=np.int64)
        for k, j in enumerate(items):
            if isinstance(j, str):
                if j not in self._names:
                    raise ValueError(
                        f"clip {self.name!r}: no joint named {j!r} "
                        f"(joints: {', '.join(self.rig.joint_names)})"
                    )
                out[k] = self._names[j]
            elif isinstance(j, int | np.integer) and not isinstance(j, bool):
                if not 0 <= j < J:
                    raise ValueError(f"clip {self.name!r}: joint index {j} out of range 0..{J - 1}")
                out[k] = j
            else:
                raise ValueError(f"joints: expected joint names or indices, got {j!r}")
        return out

    def _positions(self, times, mode: str) -> tuple[NDArray[np.float64], bool]:
        if isinstance(times, float | int) and mode == "clamp" and np.isfinite(times):
            u = min(max(float(times) * self.fps, 0.0), self.n_frames - 1.0)  # the one-pose path
            return np.array([u]), True
        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(map(repr, MODES))}, not {mode!r}")
        try:
            t = np.asarray(times, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError("times: expected seconds as a number or a 1-D array") from None
        scalar = t.ndim == 0
        if t.ndim > 1:
            raise ValueError(f"times: expected a number or a 1-D array, got shape {t.shape}")
        t = np.atleast_1d(t)
        if not np.all(np.isfinite(t)):
            raise ValueError("times: every time must be finite (seconds)")
        u = t * self.fps
        T = self.n_frames
        u = np.clip(u, 0.0, T - 1.0) if mode == "clamp" else np.mod(u, float(T))
        return u, scalar

    # ------------------------------------------------------------------ sampling
    def _tables(self, sel: NDArray[np.int64]) -> tuple:
        """The coefficient columns the joints ``sel`` need (cached per selection)."""
        if sel is self._all:  # every joint: every decoded column, as decoded (no copy)
            return self._P, self._cols, self._scale, sel
        self.decode_all()  # a subset's columns are copied: from every row
        key = sel.tobytes()
        cached = self._selections.get(key)
        if cached is not None:
            return cached
        at = np.flatnonzero(np.isin(self._cols, self._needed_columns(sel)))
        cached = (
            np.ascontiguousarray(self._P[:, at]),
            np.ascontiguousarray(self._cols[at]),
            np.ascontiguousarray(self._scale[at]),
            np.ascontiguousarray(sel),
        )
        if len(self._selections) > 32:
            self._selections.clear()
        self._selections[key] = cached
        return cached

    def bound(self, sel: NDArray[np.int64] | None = None, mode: str = "clamp") -> Sampler:
        """The :class:`Sampler` of joints ``sel`` (all by default) in ``mode`` (made once)."""
        if sel is None and mode == "clamp":
            if self._bound is None:
                self._bound = Sampler(self, None, "clamp")
            return self._bound
        key = (mode, None if sel is None else sel.tobytes())
        sampler = self._samplers.get(key)
        if sampler is None:
            if len(self._samplers) > 32:
                self._samplers.clear()
            sampler = self._samplers[key] = Sampler(self, sel, mode)
        return sampler

    def sample(self, times, joints=None, *, mode: str = "clamp"):
        """Root translation and rotations at ``times`` (see
        :meth:`quatmotion.codec.archive.ArchiveReader.sample`)."""
        if joints is None and type(times) is float and mode == "clamp" and math.isfinite(times):
            root, rot = self.bound().pose(times)  # the one-pose path
            return root.copy(), rot.copy()
        sel = None if joints is None else self._joints(joints)
        u, scalar = self._positions(times, mode)
        root, rot = self.bound(sel, mode).poses_at(u)
        if scalar:
            return root[0], rot[0]
        return root, rot

    def _needed_columns(self, sel) -> NDArray[np.int64]:
        R = self.rig
        cols = [np.arange(3)]
        for j in sel:
            cols.append(np.arange(R.starts[j], R.starts[j] + R.counts[j]))
        return np.unique(np.concatenate(cols))


class Sampler:
    """One clip bound for sampling: a joint selection and a mode chosen once, the clip's
    tables packed into one array with the scratch and output buffers (made by
    :meth:`ClipSampler.bound`, :meth:`quatmotion.codec.archive.ArchiveReader.sampler`).

    Attributes
    ----------
    joints : ndarray of int, shape (k,)
        The joints sampled, in the order of the rotations returned.
    fps : float
    n_frames : int
    mode : {"clamp", "loop"}
    """

    def __init__(self, clip: ClipSampler, joints=None, mode: str = "clamp"):
        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(map(repr, MODES))}, not {mode!r}")
        sel = clip._all if joints is None else clip._joints(joints)
        P, cols, scale, sel = clip._tables(sel)
        kinds, starts, counts, dof_axes, pre, ref = clip.rig.tables()
        corr = clip._corr
        segs, knots = clip._segs, clip._knots
        J, k, C = len(kinds), len(sel), clip.rig.n_channels
        compiled = kernels()
        head = np.zeros(compiled.PACK_HEAD, dtype=np.int64)
        ints = (head, segs, cols, sel, kinds, starts, counts, dof_axes)
        n_ints = sum(a.size for a in ints)
        lazy = clip.lazy and sel is clip._all
        G, n_groups = (clip.rows.group_rows, clip.rows.n_groups) if lazy else (0, 0)
        head[:12] = (len(segs), len(cols), len(P), J, corr.shape[0], C, k, len(knots),
                     mode == "loop", n_ints, G, n_groups)  # fmt: skip
        floats = (knots, P, scale, corr, pre, ref, np.zeros(n_groups))
        scratch = 2 * C + 9 * J + 4 * k + 3 + 4 * k  # X, Y, angles, rotations; the output
        self._B = np.zeros(n_ints + 1 + sum(a.size for a in floats) + scratch)
        # each table written into its slot (one allocation: the clip's first pose pays this)
        I = self._B[:n_ints].view(np.int64)  # noqa: E741 (the kernels' name)
        o = 0
        for a in ints:
            I[o : o + a.size] = a.reshape(-1)
            o += a.size
        self._B[n_ints] = clip.fps
        o = n_ints + 1
        at = []
        for a in floats:
            at.append(o)
            self._B[o : o + a.size] = a.reshape(-1)
            o += a.size
        # with rows that decode by group: the rows and the flags in the buffer, which
        # _decode fills when a pose first needs a group (made once per sampler)
        self._decode_groups = clip.rows.decode_groups if lazy else None
        self._rows_view = self._B[at[1] : at[1] + P.size].reshape(P.shape)
        self._flags = self._B[at[6] : at[6] + n_groups]
        out = len(self._B) - 3 - 4 * k
        self._root = self._B[out : out + 3]
        self._rot = self._B[out + 3 :].reshape(k, 4)
        self._pose = compiled.pose_entry()
        self._poses = compiled.poses
        self._clip = clip
        self.joints = sel
        self.fps = clip.fps
        self.n_frames = clip.n_frames
        self.mode = mode

    def pose(self, t: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Root translation ``(3,)`` cm and rotations ``(k, 4)`` at ``t`` seconds: views of
        this sampler's buffers, overwritten by its next call (copy to keep them).

        Raises
        ------
        ValueError
            A time that is not a finite number.
        """
        status = self._pose(float(t), self._B)
        while status != 1:
            if status == 0:
                raise ValueError("times: every time must be finite (seconds)")
            self._decode(status - 2, status - 1)  # a group this pose needs, first
            status = self._pose(float(t), self._B)
        return self._root, self._rot

    def _decode(self, first: int, stop: int) -> None:
        """Groups ``first .. stop - 1`` of rows decoded into this sampler's buffer."""
        self._decode_groups(self._rows_view, first, stop)
        self._flags[first:stop] = 1.0

    def poses(self, times) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Root translations ``(n, 3)`` and rotations ``(n, k, 4)`` at ``times`` ``(n,)``
        seconds (new arrays)."""
        u, _ = self._clip._positions(np.atleast_1d(np.asarray(times, dtype=np.float64)),
                                     self.mode)  # fmt: skip
        return self.poses_at(u)

    def poses_at(self, u: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """:meth:`poses` at frame positions ``u`` already clamped or wrapped."""
        if self._decode_groups is not None and not self._flags.all():
            self._decode(0, len(self._flags))  # a batch: every group
        root = np.empty((len(u), 3))
        rot = np.empty((len(u), len(self.joints), 4))
        self._poses(u, self._B, root, rot)
        return root, rot
