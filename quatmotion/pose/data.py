"""Poses on the 16-joint skeleton, with their time derivatives, ready for pose distances.

Conventions
-----------
- ``positions`` are body-local: centimetres, Y up, the Hip at the origin, yaw removed so the
  body faces +Z (see ``quatmotion.pose.skeleton16.local_positions16``).
- ``velocities`` (cm/s) and ``accelerations`` (cm/s^2) are finite differences of the body-local
  positions *within each clip* (central differences inside, one-sided at the ends), so the
  derivatives never straddle two clips. The Hip is fixed at the origin in that frame, so its row
  carries instead its world vertical motion ``(0, dh/dt, 0)`` and ``(0, d2h/dt2, 0)`` (the GPD
  paper keeps only the Hip's height of the root's absolute state, Eq. 1).
- ``hip_height`` (cm) is the Hip's world height; zero when unknown.
- ``root_motion`` is what the body frame removes of the root's travel, per pose: the Hip's
  horizontal world velocity expressed in the body frame (``x`` left, ``z`` forward, cm/s) and
  the facing's yaw rate (rad/s, positive turning left, about +Y); zeros when unknown (poses
  built from body-local positions alone). Derivatives within each clip, as above. The GPD
  paper's descriptor has none of it: a stooped walk and a stooped stand look alike there.
- Joint orientations (for the JOD family of baselines) are derived from positions by
  :func:`joint_orientations`: positions alone cannot give the twist about a bone, so each joint
  gets the minimal (swing) rotation from its T-pose bone direction to its current one in its
  parent's frame; Hip and Chest get full frames from the spine and the hip / shoulder lines.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quatmotion import quat
from quatmotion.io import Doubt
from quatmotion.motion import Motion
from quatmotion.pose import skeleton16
from quatmotion.pose.gpd import gpd_features
from quatmotion.pose.skeleton16 import JOINTS_16, PARENTS_16

__all__ = ["PoseClip", "PoseData", "angular_velocities", "joint_orientations", "root_motion"]

_N_JOINTS = len(JOINTS_16)
_J = {name: k for k, name in enumerate(JOINTS_16)}
# T-pose bone direction from a joint to its single child, body frame (x left, y up, z forward).
_REST_CHILD: dict[str, tuple[str, tuple[float, float, float]]] = {
    "Neck": ("Head", (0.0, 1.0, 0.0)),
    "LShoulder": ("LElbow", (1.0, 0.0, 0.0)),
    "LElbow": ("LHand", (1.0, 0.0, 0.0)),
    "RShoulder": ("RElbow", (-1.0, 0.0, 0.0)),
    "RElbow": ("RHand", (-1.0, 0.0, 0.0)),
    "LHip": ("LKnee", (0.0, -1.0, 0.0)),
    "LKnee": ("LFoot", (0.0, -1.0, 0.0)),
    "RHip": ("RKnee", (0.0, -1.0, 0.0)),
    "RKnee": ("RFoot", (0.0, -1.0, 0.0)),
}


def _check_positions(a: ArrayLike, name: str = "positions") -> NDArray[np.float64]:
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[1:] != (_N_JOINTS, 3):
        raise ValueError(f"{name} has shape {arr.shape}, expected (N, {_N_JOINTS}, 3)")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


def _frame(up: NDArray[np.float64], lateral: NDArray[np.float64]) -> NDArray[np.float64]:
    """Right-handed frames (..., 3, 3), columns (x=lateral, y=up, z=forward), up kept exact."""
    y = up / np.maximum(np.linalg.norm(up, axis=-1, keepdims=True), 1e-12)
    x = lateral - np.sum(lateral * y, axis=-1, keepdims=True) * y
    x /= np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), 1e-12)
    z = np.cross(x, y)
    return np.stack((x, y, z), axis=-1)


def _swing(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Shortest-arc unit quaternions (..., 4) rotating unit vectors ``a`` onto ``b``."""
    w = 1.0 + np.sum(a * b, axis=-1)
    v = np.cross(a, b)
    # Opposite vectors: any axis orthogonal to a works; take a x e (e the least aligned axis).
    opposite = w < 1e-9
    if np.any(opposite):
        ao = a[opposite]
        e = np.eye(3)[np.argmin(np.abs(ao), axis=-1)]
        v[opposite] = np.cross(ao, e)
        w = np.where(opposite, 0.0, w)
    q = np.concatenate((w[..., None], v), axis=-1)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def joint_orientations(positions: ArrayLike) -> NDArray[np.float64]:
    """Local joint orientations implied by 16-joint positions.

    Parameters
    ----------
    positions : array_like, shape (N, 16, 3)
        Body-local joint positions, cm.

    Returns
    -------
    ndarray, shape (N, 16, 4)
        Unit quaternions, w first, ``w >= 0``. Hip: its frame (x along RHip->LHip, y along
        Hip->Chest) in the body frame; Chest: its frame (shoulder line, Chest->Neck) relative to
        the Hip's; each joint with one child: the swing from its T-pose bone direction to the
        current bone direction expressed in the parent's frame (no twist: positions do not
        determine it); end sites (Head, hands, feet): identity.
    """
    pos = _check_positions(positions)
    n = pos.shape[0]
    frames = np.empty((n, _N_JOINTS, 3, 3))
    local = np.tile(np.array([1.0, 0.0, 0.0, 0.0]), (n, _N_JOINTS, 1))
    hip = _frame(pos[:, _J["Chest"]] - pos[:, _J["Hip"]], pos[:, _J["LHip"]] - pos[:, _J["RHip"]])
    chest = _frame(
        pos[:, _J["Neck"]] - pos[:, _J["Chest"]],
        pos[:, _J["LShoulder"]] - pos[:, _J["RShoulder"]],
    )
    frames[:, _J["Hip"]] = hip
    frames[:, _J["Chest"]] = chest
    local[:, _J["Hip"]] = quat.from_matrix(hip)
    local[:, _J["Chest"]] = quat.from_matrix(np.swapaxes(hip, -1, -2) @ chest)
    # Parents come first, so every parent frame exists before its children need it.
    for k, name in enumerate(JOINTS_16):
        if name not in _REST_CHILD:
            if k not in (_J["Hip"], _J["Chest"]):
                frames[:, k] = frames[:, PARENTS_16[k]]
            continue
        child, rest = _REST_CHILD[name]
        parent_frame = frames[:, PARENTS_16[k]]
        bone = pos[:, _J[child]] - pos[:, k]
        bone /= np.maximum(np.linalg.norm(bone, axis=-1, keepdims=True), 1e-12)
        bone_in_parent = np.einsum("nji,nj->ni", parent_frame, bone)
        q = _swing(np.broadcast_to(np.asarray(rest), bone_in_parent.shape), bone_in_parent)
        local[:, k] = q
        frames[:, k] = parent_frame @ quat.to_matrix(q)
    return quat.canonicalize(local)


def angular_velocities(
    positions: ArrayLike, velocities: ArrayLike, step: float = 1e-3
) -> NDArray[np.float64]:
    """Angular velocity of every :func:`joint_orientations` joint, rad/s, in the joint's frame.

    The derivative of the orientation map along the joint velocities (chain rule, a central
    difference of ``step`` seconds), so it needs no neighbouring frames and stays valid after
    poses of different clips are mixed.

    Parameters
    ----------
    positions, velocities : array_like, shape (N, 16, 3)
        Body-local positions (cm) and their time derivatives (cm/s).
    step : float
        Time step of the central difference, seconds.

    Returns
    -------
    ndarray, shape (N, 16, 3)
    """
    pos = _check_positions(positions)
    vel = _check_positions(velocities, "velocities")
    vel = vel.copy()
    vel[:, 0] = 0.0  # the Hip row holds world vertical motion, not body-local motion
    before = joint_orientations(pos - step * vel)
    after = joint_orientations(pos + step * vel)
    # log returns half the rotation angle; the angle over 2*step seconds is 2|log|.
    return quat.log(quat.multiply(quat.conjugate(before), after)) / step


def _derivative(x: NDArray[np.float64], fps: float) -> NDArray[np.float64]:
    if x.shape[0] < 2:
        return np.zeros_like(x)
    return np.gradient(x, 1.0 / fps, axis=0)


def root_motion(world: ArrayLike, fps: float) -> NDArray[np.float64]:
    """The root's travel that the body frame removes: ``(vx, vz, yaw rate)`` per frame.

    Parameters
    ----------
    world : array_like, shape (T, 16, 3)
        World positions of one clip, cm, Y up, :data:`JOINTS_16` order.
    fps : float
        Its frame rate.

    Returns
    -------
    ndarray, shape (T, 3)
        The Hip's horizontal velocity in the body frame (``x`` left, ``z`` forward, cm/s) and
        the yaw rate of the facing (rad/s, unwrapped so a turn through +-pi is no jump).
    """
    w = _check_positions(world, "world")
    yaw = np.unwrap(skeleton16.facing_yaw(w))
    velocity = _derivative(w[:, 0], fps)
    velocity[:, 1] = 0.0
    body = skeleton16.rotate_about_y(velocity[:, None, :], -yaw)[:, 0]
    return np.stack([body[:, 0], body[:, 2], _derivative(yaw, fps)], axis=1)


@dataclass(frozen=True, eq=False)
class PoseData:
    """A set of poses: body-local 16-joint positions and their time derivatives.

    Parameters
    ----------
    positions : ndarray, shape (N, 16, 3)
        Body-local positions, cm.
    velocities : ndarray, shape (N, 16, 3)
        cm/s; the Hip row is ``(0, vertical world velocity, 0)``.
    accelerations : ndarray, shape (N, 16, 3)
        cm/s^2; the Hip row is ``(0, vertical world acceleration, 0)``.
    hip_height : ndarray, shape (N,), optional
        World height of the Hip, cm; ``None`` stores zeros.
    root_motion : ndarray, shape (N, 3), optional
        ``(vx, vz, yaw rate)``: the Hip's horizontal velocity in the body frame (cm/s) and the
        facing's yaw rate (rad/s); ``None`` stores zeros (module conventions).

    Notes
    -----
    Build from clips with :meth:`from_clip` (or :meth:`PoseClip.from_motion`), join with
    :meth:`concat`,
    select with ``data[idx]`` (an int, slice, index array or boolean mask). ``gpd`` (N, 1683)
    and ``orientations`` (N, 16, 4) are computed on first use and cached.
    """

    positions: NDArray[np.float64]
    velocities: NDArray[np.float64]
    accelerations: NDArray[np.float64]
    hip_height: NDArray[np.float64] | None = None
    root_motion: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        pos = _check_positions(self.positions)
        n = pos.shape[0]
        vel = _check_positions(self.velocities, "velocities")
        acc = _check_positions(self.accelerations, "accelerations")
        if vel.shape[0] != n or acc.shape[0] != n:
            raise ValueError(
                f"positions, velocities and accelerations disagree on the pose count: "
                f"{n}, {vel.shape[0]}, {acc.shape[0]}"
            )
        if self.hip_height is None:
            height = np.zeros(n)
        else:
            height = np.asarray(self.hip_height, dtype=np.float64).reshape(-1)
            if height.shape != (n,):
                raise ValueError(f"hip_height has shape {height.shape}, expected ({n},)")
            if not np.all(np.isfinite(height)):
                raise ValueError("hip_height must be finite")
        if self.root_motion is None:
            root = np.zeros((n, 3))
        else:
            root = np.asarray(self.root_motion, dtype=np.float64)
            if root.shape != (n, 3):
                raise ValueError(f"root_motion has shape {root.shape}, expected ({n}, 3)")
            if not np.all(np.isfinite(root)):
                raise ValueError("root_motion must be finite")
        for name, value in (
            ("positions", pos),
            ("velocities", vel),
            ("accelerations", acc),
            ("hip_height", height),
            ("root_motion", root),
        ):
            value = np.array(value, dtype=np.float64)  # own copy, so freezing is safe
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    # ----------------------------------------------------------------------------------------
    @classmethod
    def from_clip(
        cls,
        local_positions: ArrayLike,
        fps: float,
        *,
        hip_height: ArrayLike | None = None,
        world: ArrayLike | None = None,
    ) -> PoseData:
        """Poses of one clip, with derivatives taken within the clip.

        Parameters
        ----------
        local_positions : array_like, shape (T, 16, 3)
            Body-local positions, cm: Hip at the origin, or at ``(0, h, 0)`` with ``h`` its
            height (``local_positions16(motion, keep_height=True)``); the result is re-centred
            on the Hip either way.
        fps : float
            Frames per second of the clip.
        hip_height : array_like, shape (T,), optional
            World height of the Hip, cm. Default: the Hip row's Y. Its time derivatives fill
            the Hip rows of the velocities and accelerations.
        world : array_like, shape (T, 16, 3), optional
            The same poses in world coordinates (cm, Y up), for ``root_motion``: the Hip's
            travel over the floor and the facing's turn. ``None``: zeros.

        Returns
        -------
        PoseData
            T poses. A one-frame clip has zero derivatives.
        """
        pos = _check_positions(local_positions, "local_positions")
        if not (np.isfinite(fps) and fps > 0):
            raise ValueError(f"fps must be positive and finite, got {fps}")
        n = pos.shape[0]
        if hip_height is None:
            height = pos[:, 0, 1].copy()
        else:
            height = np.asarray(hip_height, dtype=np.float64)
        pos = pos - pos[:, :1, :]
        if height.shape != (n,):
            raise ValueError(f"hip_height has shape {height.shape}, expected ({n},)")
        vel = _derivative(pos, fps)
        acc = _derivative(vel, fps)
        height_vel = _derivative(height, fps)
        height_acc = _derivative(height_vel, fps)
        vel[:, 0] = 0.0
        acc[:, 0] = 0.0
        vel[:, 0, 1] = height_vel
        acc[:, 0, 1] = height_acc
        root = None if world is None else root_motion(world, fps)
        if root is not None and root.shape[0] != n:
            raise ValueError(f"world has {root.shape[0]} frames, local_positions {n}")
        return cls(pos, vel, acc, height, root)

    @classmethod
    def concat(cls, parts: Sequence[PoseData]) -> PoseData:
        """Join pose sets in order (derivatives stay those computed within each clip)."""
        parts = list(parts)
        if not parts:
            return cls(np.zeros((0, _N_JOINTS, 3)), np.zeros((0, _N_JOINTS, 3)),
                       np.zeros((0, _N_JOINTS, 3)))  # fmt: skip
        return cls(
            np.concatenate([p.positions for p in parts]),
            np.concatenate([p.velocities for p in parts]),
            np.concatenate([p.accelerations for p in parts]),
            np.concatenate([p.hip_height for p in parts]),
            np.concatenate([p.root_motion for p in parts]),
        )

    # ----------------------------------------------------------------------------------------
    def __len__(self) -> int:
        return self.positions.shape[0]

    def __getitem__(self, index: int | slice | ArrayLike) -> PoseData:
        if isinstance(index, (int, np.integer)):
            index = slice(int(index), int(index) + 1 if int(index) != -1 else None)
        out = PoseData(
            self.positions[index],
            self.velocities[index],
            self.accelerations[index],
            self.hip_height[index],
            self.root_motion[index],
        )
        cached = self.__dict__.get("gpd")
        if cached is not None:
            out.__dict__["gpd"] = cached[index]
        return out

    @cached_property
    def gpd(self) -> NDArray[np.float64]:
        """Raw Geometric Pose Descriptor, shape (N, 1683) (see :mod:`quatmotion.pose.gpd`)."""
        out = gpd_features(self.positions, self.velocities, self.accelerations, self.hip_height)
        out.setflags(write=False)
        return out

    @cached_property
    def orientations(self) -> NDArray[np.float64]:
        """Local joint orientations, shape (N, 16, 4), from :func:`joint_orientations`."""
        out = joint_orientations(self.positions)
        out.setflags(write=False)
        return out

    @cached_property
    def angular_velocities(self) -> NDArray[np.float64]:
        """Joint angular velocities, rad/s, shape (N, 16, 3), from :func:`angular_velocities`."""
        out = angular_velocities(self.positions, self.velocities)
        out.setflags(write=False)
        return out


@dataclass(frozen=True, eq=False)
class PoseClip:
    """One clip prepared for pose analysis: resampled, scaled, on the 16-joint skeleton.

    The one way a clip becomes poses, for the pose library, its queries and the benchmarks.

    Parameters
    ----------
    name : str
        The clip's name (its file path when read from a file).
    fps : float
        Frame rate after resampling.
    step : int
        File frames per kept frame (frame ``i`` here is frame ``i * step`` of the file).
    world : ndarray, shape (T, 16, 3)
        World positions of the 16 pose joints on the canonical body, centimetres.
    local : ndarray, shape (T, 16, 3)
        The same in the body frame, the Hip at ``(0, hip height, 0)`` (see
        :func:`quatmotion.pose.skeleton16.to_body_frame` with ``keep_height=True``).
    poses : PoseData
        The ``T`` poses with their time derivatives.
    height : float or None
        The stature of the canonical body, centimetres (``None``: the skeleton's own).
    file_frames : int or None
        Frames of the clip's file (before resampling), so frame numbers can be checked;
        ``None`` when unknown.
    skeleton_kind : str or None
        The skeleton family it came from (:func:`skeleton16.skeleton_kind`), ``None`` when
        unknown.
    doubts : tuple of Doubt
        What is doubtful in the file it was read from (:func:`quatmotion.io.implausible_values`),
        for the caller to report.
    """

    name: str
    fps: float
    step: int
    world: NDArray[np.float64]
    local: NDArray[np.float64]
    poses: PoseData
    height: float | None = None
    file_frames: int | None = None
    skeleton_kind: str | None = None
    doubts: tuple[Doubt, ...] = ()

    @classmethod
    def from_motion(
        cls,
        motion: Motion,
        *,
        fps: float | None = None,
        height: float | None = None,
        name: str | None = None,
    ) -> PoseClip:
        """Resample ``motion`` to about ``fps``, put it on the canonical body and describe it.

        Parameters
        ----------
        motion : Motion
            A clip of a skeleton :mod:`quatmotion.pose.skeleton16` maps.
        fps : float, optional
            Target frame rate: every ``round(motion.fps / fps)``-th frame is kept (at least
            every frame). ``None`` keeps every frame.
        height : float, optional
            Stature of the body the poses are put on, centimetres: every clip goes onto the
            canonical body (:func:`skeleton16.canonical_positions16`), so that poses of
            different skeletons compare. ``None`` keeps the skeleton's own stature.
        name : str, optional
            Default ``motion.name``.

        Returns
        -------
        PoseClip
        """
        if fps is not None and not (np.isfinite(fps) and fps > 0):
            raise ValueError(f"fps must be positive and finite, got {fps}")
        file_frames = motion.n_frames
        step = 1 if fps is None else max(1, int(round(motion.fps / fps)))
        if step > 1:
            motion = motion.slice(step=step)
        world = skeleton16.canonical_positions16(motion, height)
        local = skeleton16.to_body_frame(world, keep_height=True)
        return cls(
            name=motion.name if name is None else name,
            fps=motion.fps,
            step=step,
            world=world,
            local=local,
            poses=PoseData.from_clip(local, motion.fps, world=world),
            height=height,
            file_frames=file_frames,
            skeleton_kind=skeleton16.skeleton_kind(motion.skeleton),
        )

    def mirrored(self) -> PoseClip:
        """The clip's mirror image: left and right swapped (a left kick becomes a right one).

        A pose distance is not mirror-invariant; this lets a search or a test compare a motion
        with the same motion done on the other side. World X is negated, so the body frame of
        the mirrored clip is the mirror of the original's.
        """
        world = self.world[:, list(skeleton16.MIRROR_16)] * np.array([-1.0, 1.0, 1.0])
        local = skeleton16.to_body_frame(world, keep_height=True)
        return PoseClip(
            name=self.name,
            fps=self.fps,
            step=self.step,
            world=world,
            local=local,
            poses=PoseData.from_clip(local, self.fps, world=world),
            height=self.height,
            file_frames=self.file_frames,
            skeleton_kind=self.skeleton_kind,
        )

    def __len__(self) -> int:
        return self.local.shape[0]
