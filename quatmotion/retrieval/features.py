"""Clip features for content-based retrieval: per-frame motion features, a pooled embedding,
and the QSSD paper's per-clip dictionaries.

Conventions
-----------
* Every position-based feature is computed on the 16-joint pose skeleton
  (:mod:`quatmotion.pose.skeleton16`), so clips of any supported skeleton (CMU/HDM05 ASF, CMU
  BVH, Bandai BVH) compare with each other: that *is* the retargeting. Bodies are scaled
  uniformly to a stature of :data:`HEIGHT_CM`; limb proportions stay the actor's.
* Clips are resampled to about :data:`FEATURE_FPS` (every ``round(fps / FEATURE_FPS)``-th frame:
  a whole-number step, so frame ``k`` of the features is file frame ``k * step``).
* **Motion frames** ``(T, 52)``, centimetres: the 16 joints in the body frame (Hip at the
  origin, facing +Z, left +X; 48 numbers), then the Hip's velocity in the body frame (left, up,
  forward) and the yaw rate, both multiplied by the horizon :data:`HORIZON_S` (the velocities
  become displacements over that time; the yaw rate is turned into centimetres at a 100 cm
  radius). The horizon weights travel against posture; it is the one parameter tuned on data
  (hdm05 and bandai1, see ``docs/performance.md``), kept at a round half gait cycle.
* Everything is invariant to a rotation about the vertical axis and to a translation: the
  body frame comes from the hip line in each frame, the Hip velocity is expressed in that frame
  and the yaw enters only through its rate.
* **Path frames** ``(T, 51)``, leg lengths: the 16 joints relative to the Hip and the Hip's
  trajectory from its first-frame position, all rotated by the *first* frame's heading only
  and divided by the actor's leg length (thigh plus shin). Invariant to the clip's start
  heading and position and to the body's size; *not* invariant to a change of heading during
  the clip (a turn left and a turn right differ in sign), nor to left against right, nor to
  the order and rhythm of frames (compared by DTW).
* **Embedding** ``(156,)``: the mean and standard deviation over time of the motion frames and
  the mean absolute value of their velocity counterpart (joint velocities in the body frame,
  Hip velocity and yaw rate, all times the horizon). Plain Euclidean distance in these units.
* **Dictionaries** (the QSSD paper, section 5.2): angular displacements
  (:func:`quatmotion.motion.angular_displacements`) of the rotating joints at most
  :data:`DICTIONARY_MAX_FPS`, a QSSD (or K-SVD) dictionary of K = 5 atoms with L = 2 fitted per
  clip; atoms as unit ``4n``-vectors (Eq. 10). Rotation-based, so comparable only between clips
  of one skeleton (see :func:`skeleton_fingerprint`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from quatmotion.motion import Motion, Skeleton
# quatmotion.motion, .pose and .quat (whose kernels import Numba) are imported where used: the
# constants and the fused stream of a query by clip name (retrieval.quick) need none of them.

__all__ = [
    "DICTIONARY_ATOMS",
    "DICTIONARY_MAX_FPS",
    "DICTIONARY_SPARSITY",
    "EMBEDDING_DIM",
    "FEATURE_FPS",
    "FRAME_DIM",
    "PATH_DIM",
    "HEIGHT_CM",
    "HORIZON_S",
    "clip_dictionary",
    "clip_features",
    "feature_step",
    "motion_embedding",
    "motion_frames",
    "path_frames",
    "skeleton_fingerprint",
]

FloatArray = NDArray[np.float64]

FEATURE_FPS = 10.0
"""Target frame rate of the motion frames (frames per second)."""
HEIGHT_CM = 170.0
"""Stature every body is scaled to, centimetres."""
HORIZON_S = 0.5
"""Seconds that turn velocities into displacements in the motion frames."""
YAW_RADIUS_CM = 100.0
"""Centimetres per radian of the yaw rate term."""
BODY = "scaled"
"""Which body the features are computed on (:data:`BODIES`)."""
BODIES = ("scaled", "canonical")
"""``scaled``: the clip's own 16 joints scaled uniformly to :data:`HEIGHT_CM` (limb
proportions stay the rig's); ``canonical``: every bone put on the canonical body of that
stature, keeping its direction (:func:`quatmotion.pose.skeleton16.canonical_positions16`):
two rigs doing one motion give one stream, whatever their proportions and where their root
sits."""
FRAME_DIM = 52
"""Numbers per motion frame: 48 body-frame coordinates, 3 Hip velocity, 1 yaw rate."""
POSITION_DIM = 48
"""The body-frame coordinates: the first columns of a motion frame."""
PATH_DIM = POSITION_DIM + 3
"""Numbers per path frame: 48 Hip-relative coordinates and the Hip's route (3)."""
EMBEDDING_DIM = 3 * FRAME_DIM
DICTIONARY_ATOMS = 5
DICTIONARY_SPARSITY = 2
DICTIONARY_MAX_FPS = 20.0
DICTIONARY_MAX_ITER = 20


def feature_step(fps: float) -> int:
    """File frames per motion frame: ``max(1, round(fps / FEATURE_FPS))``."""
    return max(1, int(round(fps / FEATURE_FPS)))


def _gradient(x: FloatArray, dt: float) -> FloatArray:
    """Time derivative along axis 0 (central inside, one-sided at the ends; 0 for one frame)."""
    if x.shape[0] < 2:
        return np.zeros_like(x)
    return np.gradient(x, dt, axis=0)


def _frames_and_velocities(world16: FloatArray, fps: float) -> tuple[FloatArray, FloatArray]:
    """Motion frames ``(T, 52)`` and their velocity counterpart ``(T, 52)`` from world
    positions ``(T, 16, 3)`` (cm, already scaled) sampled at ``fps``."""
    from quatmotion.pose import skeleton16

    T = world16.shape[0]
    dt = 1.0 / fps
    body = skeleton16.to_body_frame(world16)
    yaw = np.unwrap(skeleton16.facing_yaw(world16))
    hip_velocity = _gradient(world16[:, 0], dt)
    c, s = np.cos(yaw), np.sin(yaw)
    # the world velocity rotated by -yaw about Y: the body's (left, up, forward) components
    root = np.stack(
        (
            hip_velocity[:, 0] * c - hip_velocity[:, 2] * s,
            hip_velocity[:, 1],
            hip_velocity[:, 0] * s + hip_velocity[:, 2] * c,
        ),
        axis=1,
    )
    travel = np.concatenate(
        (root * HORIZON_S, _gradient(yaw, dt)[:, None] * (HORIZON_S * YAW_RADIUS_CM)), axis=1
    )
    frames = np.concatenate((body.reshape(T, -1), travel), axis=1)
    joint_velocity = _gradient(body, dt).reshape(T, -1) * HORIZON_S
    return frames, np.concatenate((joint_velocity, travel), axis=1)


def world16(motion: Motion, body: str = BODY) -> FloatArray:
    """World positions ``(T', 16, 3)`` of every ``feature_step``-th frame on the features'
    body (:data:`BODIES`), centimetres, stature :data:`HEIGHT_CM`."""
    from quatmotion.pose import skeleton16

    step = feature_step(motion.fps)
    if body == "canonical":
        return skeleton16.canonical_positions16(motion, height=HEIGHT_CM)[::step]
    if body != "scaled":
        raise ValueError(f"unknown body {body!r}; expected one of {', '.join(BODIES)}")
    scale = skeleton16.height_scale(motion.skeleton, HEIGHT_CM)
    # Kinematics of every frame, then every step-th: cheaper than Motion.slice, whose
    # validation of the new clip costs more than the kinematics of the frames it drops.
    return skeleton16.world_positions16(motion)[::step] * scale


def motion_frames(
    motion: Motion, body: str = BODY
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Motion frames and embedding of a clip (module docstring).

    Parameters
    ----------
    motion : Motion
        A clip of a supported skeleton (:func:`quatmotion.pose.skeleton16.skeleton_kind`).

    Returns
    -------
    frames : ndarray of float32, shape (T', 52)
        ``T' = ceil(T / step)`` with ``step = feature_step(motion.fps)``.
    embedding : ndarray of float32, shape (156,)

    Raises
    ------
    ValueError
        For a skeleton without the 16 pose joints.
    """
    step = feature_step(motion.fps)
    world = world16(motion, body)
    frames, velocities = _frames_and_velocities(world, motion.fps / step)
    return frames.astype(np.float32), motion_embedding(frames, velocities).astype(np.float32)


def _leg_length(world16: FloatArray) -> float:
    """Median over frames of thigh plus shin, averaged over both legs (same units)."""
    from quatmotion.pose import skeleton16

    legs = []
    for hip, knee, foot in (("LHip", "LKnee", "LFoot"), ("RHip", "RKnee", "RFoot")):
        h, k, f = (skeleton16.JOINTS_16.index(n) for n in (hip, knee, foot))
        thigh = np.linalg.norm(world16[:, k] - world16[:, h], axis=-1)
        shin = np.linalg.norm(world16[:, f] - world16[:, k], axis=-1)
        legs.append(np.median(thigh + shin))
    length = float(np.mean(legs))
    if not length > 0:
        raise ValueError("the clip's legs have zero length: no body-size normalisation")
    return length


def path_from_world(world16: FloatArray) -> FloatArray:
    """Path frames ``(T, 51)`` (module docstring) from world positions ``(T, 16, 3)``."""
    from quatmotion.pose import skeleton16

    T = world16.shape[0]
    yaw0 = float(skeleton16.facing_yaw(world16[:1])[0])
    hip = world16[:, :1, :]
    local = skeleton16.rotate_about_y(world16 - hip, -yaw0)
    travel = skeleton16.rotate_about_y(world16[:, 0] - world16[:1, 0], -yaw0)
    out = np.concatenate((local.reshape(T, -1), travel), axis=1)
    return out / _leg_length(world16)


def path_frames(motion: Motion, body: str = BODY) -> NDArray[np.float32]:
    """Path frames ``(T', 51)`` of a clip (module docstring), every
    ``feature_step(motion.fps)``-th frame."""
    return path_from_world(world16(motion, body)).astype(np.float32)


def motion_embedding(frames: FloatArray, velocities: FloatArray) -> FloatArray:
    """Pooled embedding ``(156,)``: mean and std of ``frames`` ``(T, 52)``, mean |velocities|."""
    return np.concatenate((frames.mean(0), frames.std(0), np.abs(velocities).mean(0)))


def clip_dictionary(motion: Motion, kind: str = "qssd", seed: int = 0) -> FloatArray:
    """The QSSD paper's per-clip dictionary: ``(5, n, 4)`` atoms, each a unit ``4n``-vector.

    Parameters
    ----------
    motion : Motion
    kind : {"qssd", "ksvd"}
        Quaternion combination (the paper's method) or linear K-SVD (its baseline).
    seed : int
        Seed of the initial atoms.

    Returns
    -------
    ndarray, shape (5, n, 4)
        ``n`` rotating joints. QSSD atoms have unit quaternions (divided by ``sqrt(n)`` here);
        K-SVD atoms are unit as ``4n``-vectors already. Fewer distinct frames than atoms
        still gives five atoms (the estimators fill with random directions).
    """
    from quatmotion import quat
    from quatmotion.motion import angular_displacements
    from quatmotion.sparse import KSVD, QSSD

    step = max(1, int(np.ceil(motion.fps / DICTIONARY_MAX_FPS - 1e-9)))
    Y = quat.canonicalize(angular_displacements(motion, step=step))
    n = Y.shape[1]
    options = dict(
        n_atoms=DICTIONARY_ATOMS,
        sparsity=DICTIONARY_SPARSITY,
        max_iter=DICTIONARY_MAX_ITER,
        random_state=seed,
    )
    if kind == "qssd":
        atoms = quat.canonicalize(QSSD(**options).fit(Y).dictionary_) / np.sqrt(n)
    elif kind == "ksvd":
        atoms = KSVD(**options).fit(Y).dictionary_
    else:
        raise ValueError(f"kind must be 'qssd' or 'ksvd', got {kind!r}")
    return np.ascontiguousarray(atoms, dtype=np.float64)


def skeleton_fingerprint(skeleton: Skeleton) -> str:
    """A short hash of the joints that rotate, their parents and channels (not bone lengths).

    Two clips with the same fingerprint have comparable angular displacements (the paper's
    features); positions-based features compare across fingerprints.
    """
    parts: Iterable[str] = (
        f"{skeleton.joint_names[j]}<{skeleton.parents[j]}:{','.join(skeleton.rotation_dofs(j))}"
        for j in skeleton.rotating_joints()
    )
    return hashlib.sha1("|".join(parts).encode()).hexdigest()[:16]


def clip_features(
    motion: Motion, kinds: Iterable[str], seed: int = 0, body: str = BODY
) -> dict[str, np.ndarray]:
    """The arrays of the feature ``kinds`` of one clip: a pure function of its arguments.

    Parameters
    ----------
    motion : Motion
    kinds : iterable of {"motion", "qssd", "ksvd"}
        ``motion`` gives ``frames`` and ``embedding`` (:func:`motion_frames`); ``qssd`` and
        ``ksvd`` give the dictionaries of :func:`clip_dictionary` under those keys.
    seed : int
        Seed of the dictionaries' initial atoms.
    body : str
        The body the motion features are computed on (:data:`BODIES`).

    Returns
    -------
    dict of str to ndarray
    """
    out: dict[str, np.ndarray] = {}
    for kind in kinds:
        if kind == "motion":
            out["frames"], out["embedding"] = motion_frames(motion, body)
            out["path"] = path_frames(motion, body)
        elif kind in ("qssd", "ksvd"):
            out[kind] = clip_dictionary(motion, kind, seed)
        else:
            raise ValueError(f"unknown feature kind {kind!r}; expected motion, qssd or ksvd")
    return out
