"""The 16-joint pose skeleton of the GPD paper and its body-local frame.

Every pose-distance computation in :mod:`quatmotion.pose` works on the same 16 joints, whatever
skeleton the file defines (Chen et al., "Learning a 3D Human Pose Distance Metric from Geometric
Pose Descriptor", section 3.1, Fig. 1a)::

    0 Hip                                   root
    1 Chest      2 Neck      3 Head         spine chain (Head is an end site)
    4 LShoulder  5 LElbow    6 LHand        left arm  (LHand is an end site)
    7 RShoulder  8 RElbow    9 RHand        right arm (RHand is an end site)
    10 LHip      11 LKnee    12 LFoot       left leg  (LFoot is an end site)
    13 RHip      14 RKnee    15 RFoot       right leg (RFoot is an end site)

Conventions
-----------
* Positions are in centimetres, Y up (the file skeleton's units after I/O).
* The shoulders hang from the Chest (as in the Bandai and most 16/17-joint skeletons), the hips
  from the Hip; the Head's grandparent is the Chest.
* Which joints of a file are the 16: :func:`quatmotion.motion.humanoid.map_humanoid` (names
  of every usual family, structure, a user's map; :func:`humanoid_map` here). Placement in
  the three families of the shared data (an ASF bone's joint sits at the bone's *start*, see
  :mod:`quatmotion.motion.skeleton`):

  - Hip: ``root`` (ASF), ``Hips`` (CMU BVH, Bandai)
  - Chest: ``thorax``, ``Spine``, ``Chest`` (Hahne's ``Spine1`` sits exactly at ``Neck``: the
    conversion folds the thorax into the neck base, so the bone below stands in)
  - Neck: ``lowerneck``, ``Neck``, ``Neck``
  - Head: ``head``, ``Head``, ``Head``
  - Shoulder: ``(l|r)humerus``, ``(Left|Right)Arm``, ``UpperArm_(L|R)``
  - Elbow: ``(l|r)radius``, ``(Left|Right)ForeArm``, ``LowerArm_(L|R)``
  - Hand: ``(l|r)wrist``, ``(Left|Right)Hand``, ``Hand_(L|R)``
  - Hip (leg): ``(l|r)femur``, ``(Left|Right)UpLeg``, ``UpperLeg_(L|R)``
  - Knee: ``(l|r)tibia``, ``(Left|Right)Leg``, ``LowerLeg_(L|R)``
  - Foot: ``(l|r)foot``, ``(Left|Right)Foot``, ``Foot_(L|R)``

  So Hand is the wrist and Foot the ankle in every skeleton: the points all three skeletons
  place alike.
* **Body-local frame** (paper section 3.1): translated so the Hip is at the origin and rotated
  about the vertical (Y) axis by the body's yaw so that it faces +Z. The facing direction is the
  horizontal part of ``(LHip - RHip) x Y``: the hip line is defined on every skeleton, does
  not depend on a file's root-axis convention, and points sideways whatever the torso does.
  Left is then +X. A pose whose hip line is vertical (lying on the side) has no yaw; it keeps
  the last valid yaw of its clip (or 0).
* **Canonical body** (:func:`canonical_positions16`): skeletons place the 16 joints with their
  own proportions (Bandai's shoulders are half as wide as CMU's, its neck joint higher, its
  root level with the hip joints where CMU's sits a tenth of the stature above them), and a
  pose descriptor measures those proportions as much as the pose: bone lengths are the GPD's
  most constant features, so one skeleton's constants lie far outside another's range. Poses
  of different skeletons compare once each is put on one body: the Hip goes midway between
  the hip joints (the same anatomical points in every skeleton, unlike the root), every bone
  keeps its direction and takes the canonical length, and the Hip's trajectory is scaled by
  the ratio of the leg lengths (so the floor, ``y = 0``, stays the floor).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quatmotion import quat
from quatmotion.motion import Motion, Skeleton, forward_kinematics
from quatmotion.motion.humanoid import JOINTS_16, PARENTS_16, HumanoidMap, map_humanoid

END_SITES_16: tuple[int, ...] = (3, 6, 9, 12, 15)
"""Indices of the five end sites of the paper: Head, LHand, RHand, LFoot, RFoot."""
FEET_16: tuple[int, int] = (JOINTS_16.index("LFoot"), JOINTS_16.index("RFoot"))
"""Indices of the two feet (LFoot, RFoot): what contacts, skating and the feet baseline read."""
MIRROR_16: tuple[int, ...] = tuple(
    JOINTS_16.index(("R" if n[0] == "L" else "L") + n[1:]) if n[0] in "LR" else k
    for k, n in enumerate(JOINTS_16)
)
"""Each joint's mirror image (left and right swapped): ``positions[:, MIRROR_16]`` with X
negated in the body frame is the mirrored pose."""

SkeletonKind = str
"""A naming family of :func:`quatmotion.motion.humanoid.map_humanoid` (``asf``, ``cmu_bvh``,
``bandai``, ``mixamo``, ``unreal``, ``biped``, ``rigify``, ``smpl``, ``kinect``,
``humanoid``...)."""

# The three families the project's shared data comes in, joint for joint (what the tests
# check the mapping against).
_JOINT_MAPS: dict[str, tuple[str, ...]] = {
    "asf": (
        "root", "thorax", "lowerneck", "head",
        "lhumerus", "lradius", "lwrist", "rhumerus", "rradius", "rwrist",
        "lfemur", "ltibia", "lfoot", "rfemur", "rtibia", "rfoot",
    ),
    "cmu_bvh": (
        "Hips", "Spine", "Neck", "Head",
        "LeftArm", "LeftForeArm", "LeftHand", "RightArm", "RightForeArm", "RightHand",
        "LeftUpLeg", "LeftLeg", "LeftFoot", "RightUpLeg", "RightLeg", "RightFoot",
    ),
    "bandai": (
        "Hips", "Chest", "Neck", "Head",
        "UpperArm_L", "LowerArm_L", "Hand_L", "UpperArm_R", "LowerArm_R", "Hand_R",
        "UpperLeg_L", "LowerLeg_L", "Foot_L", "UpperLeg_R", "LowerLeg_R", "Foot_R",
    ),
}  # fmt: skip


# Length of the bone from each joint's parent to the joint on the canonical body, as a fraction
# of its stature (the ankle-to-head chain LFoot-LKnee-LHip-Hip-Chest-Neck-Head, which sums to
# 1), with the Hip midway between the hip joints. The proportions are those of the generator's
# CMU-like body (synthetic.cmu_skeleton, CMU subject 02 mirrored), fixed here so that
# indexed libraries do not change with the generator.
_CANONICAL_BONE_FRACTIONS: dict[str, float] = {
    "Chest": 0.2157, "Neck": 0.0746, "Head": 0.1129,
    "LShoulder": 0.1670, "LElbow": 0.1756, "LHand": 0.1211,
    "RShoulder": 0.1670, "RElbow": 0.1756, "RHand": 0.1211,
    "LHip": 0.0598, "LKnee": 0.2740, "LFoot": 0.2630,
    "RHip": 0.0598, "RKnee": 0.2740, "RFoot": 0.2630,
}  # fmt: skip
_STATURE_CHAIN = ("LFoot", "LKnee", "LHip", "Hip", "Chest", "Neck", "Head")
_LEG_BONES = tuple(JOINTS_16.index(n) for n in ("LKnee", "LFoot", "RKnee", "RFoot"))
_MIN_BONE_FRACTION = 1e-3  # a mapped bone shorter than this share of the stature has no direction

_HIP_L, _HIP_R = JOINTS_16.index("LHip"), JOINTS_16.index("RHip")
_MIN_HIP_LINE = 1e-6  # cm: a shorter horizontal hip line gives no usable yaw


def humanoid_map(skeleton: Skeleton) -> HumanoidMap:
    """The mapping of ``skeleton`` onto the 16 joints (:func:`quatmotion.motion.humanoid.
    map_humanoid`, with the user's map the skeleton carries), cached on the skeleton.

    Raises
    ------
    ValueError
        (:class:`~quatmotion.motion.humanoid.HumanoidError`) one line: not a humanoid, or
        the joints that could not be mapped.
    """
    cached = _CACHE.get(id(skeleton))
    if cached is not None and cached[0] is skeleton:
        return cached[1]
    mapping = map_humanoid(skeleton)
    if len(_CACHE) > 256:
        _CACHE.clear()
    _CACHE[id(skeleton)] = (skeleton, mapping)
    return mapping


_CACHE: dict[int, tuple[Skeleton, HumanoidMap]] = {}


def skeleton_kind(skeleton: Skeleton) -> SkeletonKind:
    """The naming family of ``skeleton`` (:attr:`HumanoidMap.family`).

    Raises
    ------
    ValueError
        For a skeleton that cannot be mapped onto the 16 joints (see :func:`humanoid_map`).
    """
    return humanoid_map(skeleton).family


def joint_indices16(skeleton: Skeleton) -> NDArray[np.int64]:
    """Indices into ``skeleton``'s joints of the joints carrying the 16 pose joints, in
    :data:`JOINTS_16` order (an end site's parent; for an estimated joint, the nearer
    mapped one: :attr:`HumanoidMap.joints`).

    Parameters
    ----------
    skeleton : Skeleton

    Returns
    -------
    ndarray of int, shape (16,)

    Raises
    ------
    ValueError
        For a skeleton that cannot be mapped (see :func:`humanoid_map`).
    """
    return humanoid_map(skeleton).joints.copy()


def world_positions16(motion: Motion) -> NDArray[np.float64]:
    """World positions of the 16 pose joints over a clip.

    Parameters
    ----------
    motion : Motion
        A clip of a humanoid skeleton (see :func:`humanoid_map`), ``T`` frames.

    Returns
    -------
    ndarray, shape (T, 16, 3)
        Centimetres, Y up, in :data:`JOINTS_16` order (an estimated joint placed as the
        mapping says).
    """
    mapping = humanoid_map(motion.skeleton)
    if not mapping.uses_sites and not mapping.estimated:
        return forward_kinematics(motion, include_sites=False).positions[:, mapping.joints]
    fk = forward_kinematics(motion, include_sites=mapping.uses_sites)
    return mapping.positions(fk.all_positions())


def facing_yaw(positions16: NDArray[np.float64]) -> NDArray[np.float64]:
    """Yaw of the body's facing direction, from the hip line.

    Parameters
    ----------
    positions16 : ndarray, shape (..., 16, 3)
        Joint positions in :data:`JOINTS_16` order, Y up.

    Returns
    -------
    ndarray, shape (...)
        Radians, ``atan2(f_x, f_z)`` of the facing direction ``f = (LHip - RHip) x Y``: 0 when
        the body faces +Z, ``pi/2`` when it faces +X. Where the hip line is vertical the yaw is
        carried forward from the previous pose along the second-to-last leading axis (0 if none).
    """
    p = np.asarray(positions16, dtype=np.float64)
    if p.shape[-2:] != (16, 3):
        raise ValueError(f"positions16 has shape {p.shape}, expected (..., 16, 3)")
    left = p[..., _HIP_L, :] - p[..., _HIP_R, :]
    # (lx, ly, lz) x (0, 1, 0) = (-lz, 0, lx)
    fx, fz = -left[..., 2], left[..., 0]
    yaw = np.arctan2(fx, fz)
    bad = np.hypot(fx, fz) < _MIN_HIP_LINE
    if np.any(bad):
        yaw = np.where(bad, np.nan, yaw)
        flat = yaw.reshape(-1)
        last = 0.0
        for i in range(flat.size):  # rare: only poses whose hips are stacked vertically
            if np.isnan(flat[i]):
                flat[i] = last
            else:
                last = flat[i]
        yaw = flat.reshape(yaw.shape)
    return yaw


def to_body_frame(
    positions16: NDArray[np.float64], keep_height: bool = False
) -> NDArray[np.float64]:
    """Express world poses in the body-local frame (Hip at the origin, facing +Z).

    Parameters
    ----------
    positions16 : ndarray, shape (..., 16, 3)
        World positions, centimetres, Y up, :data:`JOINTS_16` order.
    keep_height : bool
        Translate only horizontally, so that Y stays the height above the floor and the Hip
        sits at ``(0, hip_height, 0)`` (the GPD's extra "Hip height" coordinate needs it).

    Returns
    -------
    ndarray, shape (..., 16, 3)
        Centimetres in the body frame; left is +X.
    """
    p = np.asarray(positions16, dtype=np.float64)
    yaw = facing_yaw(p)
    hip = p[..., :1, :].copy()
    if keep_height:
        hip[..., 1] = 0.0
    # Rotate by -yaw about Y: the facing direction (sin yaw, 0, cos yaw) goes to +Z.
    return rotate_about_y(p - hip, -yaw)


def rotate_about_y(points: ArrayLike, theta: ArrayLike) -> NDArray[np.float64]:
    """Rotate points by ``theta`` radians about Y: ``(x, z) -> (x cos + z sin, -x sin + z cos)``.

    Parameters
    ----------
    points : array_like, shape (..., K, 3)
    theta : array_like, shape (...)

    Returns
    -------
    ndarray, shape (..., K, 3)
    """
    p = np.asarray(points, dtype=np.float64)
    th = np.asarray(theta, dtype=np.float64)[..., None]
    c, s = np.cos(th), np.sin(th)
    out = p.copy()
    out[..., 0] = p[..., 0] * c + p[..., 2] * s
    out[..., 2] = -p[..., 0] * s + p[..., 2] * c
    return out


def local_positions16(
    motion: Motion, keep_height: bool = False, height: float | None = None
) -> NDArray[np.float64]:
    """Positions of the 16 pose joints in the body-local frame of each frame.

    Parameters
    ----------
    motion : Motion
        A clip of a supported skeleton, ``T`` frames.
    keep_height : bool
        See :func:`to_body_frame`: keep Y as height above the floor (Hip at ``(0, h, 0)``).
    height : float, optional
        Rescale uniformly so that the skeleton's stature (:func:`stature16`) becomes ``height``
        centimetres, as the paper does to compare subjects of different builds.

    Returns
    -------
    ndarray, shape (T, 16, 3)
        Centimetres; Hip at the origin (unless ``keep_height``), facing +Z, left +X, Y up.
    """
    local = to_body_frame(world_positions16(motion), keep_height=keep_height)
    if height is not None:
        local *= height_scale(motion.skeleton, height)
    return local


def stature16(skeleton: Skeleton) -> float:
    """A rotation-free proxy of standing height: the ankle-to-head chain length at rest.

    The sum of the rest distances LFoot-LKnee, LKnee-LHip, LHip-Hip, Hip-Chest, Chest-Neck and
    Neck-Head. It needs no standing rest pose (the Bandai BVH rest pose lies along X), and
    comes within about 5 % of the standing height of the CMU and HDM05 skeletons (the foot below
    the ankle and the skull above the head point roughly make up for the slack of the chain).

    Parameters
    ----------
    skeleton : Skeleton
        Of a supported family.

    Returns
    -------
    float
        Centimetres.
    """
    rest = humanoid_map(skeleton).positions(skeleton.rest_positions(include_sites=True))
    chain = [JOINTS_16.index(n) for n in _STATURE_CHAIN]
    return float(np.sum(np.linalg.norm(np.diff(rest[chain], axis=0), axis=1)))


def canonical_bone_lengths(height: float) -> NDArray[np.float64]:
    """Bone lengths of the canonical body of stature ``height`` cm.

    Parameters
    ----------
    height : float
        Stature: the ankle-to-head chain LFoot-LKnee-LHip-Hip-Chest-Neck-Head, with the Hip
        midway between the hip joints; centimetres, positive.

    Returns
    -------
    ndarray, shape (16,)
        Entry ``k`` is the length of the bone from ``PARENTS_16[k]`` to joint ``k``, cm; entry
        0 (the Hip, the root) is 0.
    """
    if not (np.isfinite(height) and height > 0):
        raise ValueError(f"height must be positive and finite, got {height}")
    fractions = np.array([0.0] + [_CANONICAL_BONE_FRACTIONS[n] for n in JOINTS_16[1:]])
    chain = sum(_CANONICAL_BONE_FRACTIONS[n] for n in _STATURE_CHAIN if n != "Hip")
    return fractions * (height / chain)


def canonical_positions16(motion: Motion, height: float | None = None) -> NDArray[np.float64]:
    """World positions of the 16 pose joints moved onto the canonical body.

    The Hip goes midway between the hip joints; every bone of :data:`PARENTS_16` then keeps its
    direction in each frame and takes its length on the canonical body of stature ``height``
    (:func:`canonical_bone_lengths`); the Hip's world trajectory is scaled about the origin by
    the ratio of the canonical legs (thigh and shin) to the clip's own. Two skeletons with
    different proportions doing the same pose give the same positions.

    Parameters
    ----------
    motion : Motion
        A clip of a supported skeleton (see :func:`skeleton_kind`), ``T`` frames.
    height : float, optional
        Stature of the canonical body, centimetres; ``None`` takes the clip's own, measured
        along the same chain.

    Returns
    -------
    ndarray, shape (T, 16, 3)
        Centimetres, Y up, :data:`JOINTS_16` order.

    Raises
    ------
    ValueError
        For a skeleton of no supported family, or one that places two joints of a mapped bone
        at the same point (the bone's direction is then undefined).
    """
    world = world_positions16(motion)
    world[:, 0] = 0.5 * (world[:, _HIP_L] + world[:, _HIP_R])
    parents = np.asarray(PARENTS_16)
    bones = world[:, 1:] - world[:, parents[1:]]
    own = np.linalg.norm(bones, axis=-1)
    # The median over frames: joints with translation channels (Bandai) may stretch a little.
    own_median = np.r_[0.0, np.median(own, axis=0)]
    chain = [JOINTS_16.index(n) for n in _STATURE_CHAIN if n != "Hip"]
    own_stature = float(own_median[chain].sum())
    short = own_median[1:] <= _MIN_BONE_FRACTION * own_stature
    if np.any(short):
        names = [f"{JOINTS_16[parents[k]]}-{JOINTS_16[k]}" for k in np.flatnonzero(short) + 1]
        raise ValueError(
            f"skeleton {motion.skeleton.name!r} puts the ends of the 16-joint bones {names} at "
            "one point: their directions are undefined"
        )
    lengths = canonical_bone_lengths(own_stature if height is None else float(height))
    legs = list(_LEG_BONES)
    directions = bones / np.maximum(own, 1e-12)[..., None]
    out = np.empty_like(world)
    out[:, 0] = world[:, 0] * (lengths[legs].sum() / own_median[legs].sum())
    for k in range(1, len(JOINTS_16)):  # parents come first
        out[:, k] = out[:, parents[k]] + lengths[k] * directions[:, k - 1]
    return out


def height_scale(skeleton: Skeleton, height: float) -> float:
    """Uniform factor that brings ``skeleton``'s stature (:func:`stature16`) to ``height`` cm.

    Parameters
    ----------
    skeleton : Skeleton
    height : float
        Target standing height, centimetres (positive).

    Returns
    -------
    float
    """
    if not height > 0:
        raise ValueError(f"height must be positive, got {height}")
    rest = stature16(skeleton)
    if not rest > 0:
        raise ValueError(f"skeleton {skeleton.name!r} has a zero-length body at rest")
    return float(height / rest)


def local_rotations16(motion: Motion) -> NDArray[np.float64]:
    """Global rotations of the 16 pose joints with the body's facing yaw removed.

    For the orientation-based distances (JOD, WJOD, LJOD): the rotation of each mapped joint
    in the body-local frame of :func:`local_positions16`. Joint rest orientations differ
    between skeleton families, so compare these only within one family.

    Parameters
    ----------
    motion : Motion
        A clip of a supported skeleton, ``T`` frames.

    Returns
    -------
    ndarray, shape (T, 16, 4)
        Unit quaternions, w first, hemisphere-continuous over frames.
    """
    idx = joint_indices16(motion.skeleton)
    pose = forward_kinematics(motion, include_sites=False)
    yaw = facing_yaw(pose.positions[:, idx])
    unyaw = quat.about_axis(-yaw, "y")
    rot = quat.multiply(unyaw[:, None, :], pose.rotations[:, idx])
    return quat.make_continuous(quat.canonicalize(rot), axis=0)
