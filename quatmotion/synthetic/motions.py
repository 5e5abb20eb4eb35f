"""Procedural, seeded motion clips on a CMU-like 31-joint skeleton.

Conventions
-----------
* The world is CMU's: Y up, the body faces +Z at rest and its left side is +X. Positions are in
  centimetres, clip rates in frames per second.
* :func:`cmu_skeleton` copies the layout of the CMU ASF files: the root and 30 bones with CMU's
  names, bone directions, ``axis`` pre-rotations, degrees of freedom and limits (subject 02,
  made left/right symmetric and scaled to a chosen standing height). The rest pose is CMU's
  T-pose, every joint's rotation channels compose extrinsically (x first), so a generated clip
  can be written to AMC (and BVH) by :mod:`quatmotion.io`.
* Motions are designed as *pose parameters*: anatomical angles in degrees (hip flexion, knee
  flexion, shoulder abduction...), per frame. A 3-dof joint turns them into rotations about the
  world axes of the rest pose (which is also the joint's local frame, since every global rotation
  is the identity at rest); a joint with fewer dofs (knee, elbow, ankle, clavicle, hand) is driven
  through its own dof angles, clipped to CMU's limits, so every frame is exactly representable
  with the joint's channels.
* The root is placed afterwards from the legs: vertically so that the lowest point of the feet
  touches the floor ``y = 0`` (plus a ballistic arc while no foot is on the ground), horizontally
  so that the feet in stance do not slide. Walking speed therefore follows from stride and tempo
  instead of being imposed.
* Every clip is a pure function of ``(kind, seed, n_frames, fps)``: the same arguments give
  bit-identical arrays.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import PchipInterpolator
from scipy.ndimage import gaussian_filter1d

from quatmotion import quat
from quatmotion.io.asf_amc import asf_extras
from quatmotion.motion.clip import Motion
from quatmotion.motion.kinematics import forward_kinematics
from quatmotion.motion.skeleton import Skeleton

FloatArray = NDArray[np.float64]

__all__ = [
    "DEFAULT_HEIGHT_CM",
    "KINDS",
    "cmu_skeleton",
    "foot_positions",
    "generate_clip",
    "generate_library",
    "standing_pose",
]

KINDS: tuple[str, ...] = (
    "walk",
    "run",
    "jump",
    "jumping_jack",
    "squat",
    "arm_circles",
    "kick",
    "wave",
    "punch",
)
"""The motion kinds :func:`generate_clip` knows, also the labels of :func:`generate_library`."""

DEFAULT_HEIGHT_CM = 170.0
"""Standing height of the default generated skeleton, centimetres (floor to top of head)."""

GRAVITY_CM_S2 = 981.0
_HEEL_BACK_FRACTION = 0.03  # heel behind the ankle, as a fraction of the standing height
_CONTACT_BAND_CM = 2.0  # a foot this close to the floor bears weight (contact from height)
_ROOT_SMOOTHING_S = 0.08  # std of the Gaussian that smooths the root's horizontal velocity
_REST_LEG_SPLAY_DEG = 20.0  # CMU's femur axis: the T-pose legs point 20 deg away from vertical

# One bone: name, parent, direction, length, axis, dofs, limits.
_BoneRow = tuple[
    str,
    str,
    tuple[float, float, float],
    float,
    tuple[float, float, float],
    tuple[str, ...],
    tuple[tuple[float, float], ...],
]

# CMU subject 02's bones, left side (the right side mirrors them): name, parent, direction,
# length in ASF units, axis (degrees, XYZ), dofs, limits in degrees per dof.
_LEFT_BONES: tuple[_BoneRow, ...] = (
    ("lhipjoint", "root", (0.655637, -0.713449, 0.247245), 2.52691, (0, 0, 0), (), ()),
    (
        "lfemur",
        "lhipjoint",
        (0.34202, -0.939693, 0),
        7.59371,
        (0, 0, 20),
        ("rx", "ry", "rz"),
        ((-160, 20), (-70, 70), (-60, 70)),
    ),
    ("ltibia", "lfemur", (0.34202, -0.939693, 0), 7.28717, (0, 0, 20), ("rx",), ((-10, 170),)),
    (
        "lfoot",
        "ltibia",
        (0.0886837, -0.243657, 0.965798),
        2.2218,
        (-90, 0, 20),
        ("rx", "rz"),
        ((-45, 90), (-70, 20)),
    ),
    ("ltoes", "lfoot", (0, 0, 1), 1.11249, (-90, 0, 20), ("rx",), ((-90, 20),)),
)
_SPINE_BONES: tuple[tuple[str, str, tuple[float, float, float], float], ...] = (
    ("lowerback", "root", (0.00952301, 0.997604, -0.0685217), 2.05943),
    ("upperback", "lowerback", (0.00494399, 0.999577, -0.0286701), 2.06523),
    ("thorax", "upperback", (0.000729686, 0.999992, 0.00388603), 2.06807),
    ("lowerneck", "thorax", (0.00452882, 0.995459, 0.0950816), 1.57426),
    ("upperneck", "lowerneck", (0.021922, 0.997711, -0.0639762), 1.56399),
    ("head", "upperneck", (0.008024, 0.999444, -0.0323691), 1.6265),
)
_SPINE_LIMITS = ((-20, 45), (-30, 30), (-30, 30))
_LEFT_ARM: tuple[_BoneRow, ...] = (
    (
        "lclavicle",
        "thorax",
        (0.967826, 0.247107, -0.0474446),
        3.6598,
        (0, 0, 0),
        ("ry", "rz"),
        ((-20, 10), (0, 20)),
    ),
    (
        "lhumerus",
        "lclavicle",
        (1, 0, 0),
        4.86513,
        (180, -30, -90),
        ("rx", "ry", "rz"),
        ((-60, 90), (-90, 90), (-90, 90)),
    ),
    ("lradius", "lhumerus", (1, 0, 0), 3.35554, (180, -30, -90), ("rx",), ((-10, 170),)),
    ("lwrist", "lradius", (1, 0, 0), 1.67777, (0, 90, 90), ("ry",), ((-180, 0),)),
    ("lhand", "lwrist", (1, 0, 0), 0.661175, (0, 90, 90), ("rx", "rz"), ((-90, 90), (-45, 45))),
    ("lfingers", "lhand", (1, 0, 0), 0.533057, (0, 90, 90), ("rx",), ((0, 90),)),
    (
        "lthumb",
        "lwrist",
        (0.707107, 0, 0.707107),
        0.765366,
        (-90, 45, 0),
        ("rx", "rz"),
        ((-45, 45), (-45, 45)),
    ),
)
# CMU's right-side limits are not an exact mirror of the left ones; these are subject 02's.
_RIGHT_LIMITS: dict[str, tuple[tuple[float, float], ...]] = {
    "rfemur": ((-160, 20), (-70, 70), (-70, 60)),
    "rtibia": ((-10, 170),),
    "rfoot": ((-45, 90), (-20, 70)),
    "rtoes": ((-90, 20),),
    "rclavicle": ((-10, 20), (-20, 0)),
    "rhumerus": ((-90, 60), (-90, 90), (-90, 90)),
    "rradius": ((-10, 170),),
    "rwrist": ((-180, 0),),
    "rhand": ((-90, 90), (-45, 45)),
    "rfingers": ((0, 90),),
    "rthumb": ((-45, 45), (-45, 45)),
}


def _mirror(
    name: str, parent: str, direction: tuple[float, float, float], axis: tuple[float, float, float]
) -> tuple[str, str, tuple[float, float, float], tuple[float, float, float]]:
    """Right-side counterpart of a left bone: names swap l->r, X flips, the axis mirrors."""

    def swap(n: str) -> str:
        return "r" + n[1:] if n.startswith("l") and n not in ("lowerback", "lowerneck") else n

    return (
        swap(name),
        swap(parent),
        (-direction[0], direction[1], direction[2]),
        (axis[0], -axis[1], -axis[2]),
    )


@dataclass(frozen=True)
class _Bone:
    name: str
    parent: str
    direction: tuple[float, float, float]
    length: float  # ASF units
    axis: tuple[float, float, float]
    dofs: tuple[str, ...]
    limits: tuple[tuple[float, float], ...]


def _cmu_bones() -> list[_Bone]:
    bones: list[_Bone] = []
    for side in ("l", "r"):
        for name, parent, direction, length, axis, dofs, limits in _LEFT_BONES:
            if side == "r":
                name, parent, direction, axis = _mirror(name, parent, direction, axis)
                limits = _RIGHT_LIMITS.get(name, limits)
            bones.append(_Bone(name, parent, direction, length, axis, dofs, limits))
    for name, parent, direction, length in _SPINE_BONES:
        bones.append(
            _Bone(name, parent, direction, length, (0, 0, 0), ("rx", "ry", "rz"), _SPINE_LIMITS)
        )
    for side in ("l", "r"):
        for name, parent, direction, length, axis, dofs, limits in _LEFT_ARM:
            if side == "r":
                name, parent, direction, axis = _mirror(name, parent, direction, axis)
                limits = _RIGHT_LIMITS.get(name, limits)
            bones.append(_Bone(name, parent, direction, length, axis, dofs, limits))
    return bones


def cmu_skeleton(height_cm: float = DEFAULT_HEIGHT_CM) -> Skeleton:
    """A CMU-like 31-joint skeleton (root + CMU's 30 bones) standing ``height_cm`` tall.

    Joints are CMU's ASF bones in ASF order, each placed at the start of its bone (the
    :class:`~quatmotion.motion.Skeleton` convention); the tips of the leaf bones (toes, head,
    fingers, thumbs) are end sites named ``<bone>_end``. Directions, axes and dofs are CMU
    subject 02's (left side mirrored to the right), lengths are scaled so the rest pose's vertical
    extent is ``height_cm``.

    Parameters
    ----------
    height_cm : float
        Floor to top of head at rest, centimetres. Must be positive.

    Returns
    -------
    Skeleton
        31 joints, 7 end sites, ``euler="extrinsic"``, root channels ``tx ty tz rx ry rz``.
        ``extras["dof_limits_deg"]`` maps each joint to its dofs' ``(low, high)`` limits in
        degrees; the other extras follow :mod:`quatmotion.io.asf_amc`'s layout (``format="asf"``,
        bones, units, hierarchy), so ``write_asf`` and ``write_amc`` accept generated clips.
    """
    if not (np.isfinite(height_cm) and height_cm > 0):
        raise ValueError(f"height_cm must be positive, got {height_cm}")
    bones = _cmu_bones()
    names = ["root"] + [b.name for b in bones]
    index = {n: i for i, n in enumerate(names)}
    vectors = {
        b.name: np.asarray(b.direction) / np.linalg.norm(b.direction) * b.length for b in bones
    }
    vectors["root"] = np.zeros(3)
    parents = [-1] + [index[b.parent] for b in bones]
    # A joint sits at its bone's start, i.e. at the end of its parent bone.
    offsets = np.stack([np.zeros(3)] + [vectors[b.parent] for b in bones])
    leaves = [b for b in bones if not any(c.parent == b.name for c in bones)]
    site_offsets = np.stack([vectors[b.name] for b in leaves])
    axes = np.stack(
        [quat.identity()]
        + [quat.from_euler(np.asarray(b.axis, dtype=float), "xyz", degrees=True) for b in bones]
    )
    channels = [("tx", "ty", "tz", "rx", "ry", "rz")] + [b.dofs for b in bones]
    unit = Skeleton(
        joint_names=tuple(names),
        parents=np.asarray(parents),
        offsets=offsets,
        channels=tuple(channels),
        euler="extrinsic",
        axes=axes,
        site_names=tuple(f"{b.name}_end" for b in leaves),
        site_parents=np.asarray([index[b.name] for b in leaves]),
        site_offsets=site_offsets,
    )
    limits = {"root": ((-180.0, 180.0),) * 3}
    limits.update({b.name: tuple((float(lo), float(hi)) for lo, hi in b.limits) for b in bones})
    unit = Skeleton(
        joint_names=unit.joint_names,
        parents=unit.parents,
        offsets=unit.offsets,
        channels=unit.channels,
        euler="extrinsic",
        axes=unit.axes,
        site_names=unit.site_names,
        site_parents=unit.site_parents,
        site_offsets=unit.site_offsets,
        extras={"dof_limits_deg": limits},
    )
    # The T-pose splays the legs, so "standing height" is measured in the neutral standing pose.
    scale = height_cm / _standing_height(unit)
    # ASF bookkeeping in the layout quatmotion.io's ASF reader produces, so that write_asf and
    # write_amc accept generated clips: same bones and units as CMU, lengths rescaled.
    length_scale = scale  # cm per ASF length unit (CMU: 2.54 / 0.45)
    children: dict[str, list[str]] = {}
    for b in bones:
        children.setdefault(b.parent, []).append(b.name)
    hierarchy = tuple((parent, *kids) for parent, kids in children.items())
    bone_vectors = np.stack([np.zeros(3)] + [vectors[b.name] * length_scale for b in bones])
    bone_vectors.setflags(write=False)
    asf_bones = [
        {
            "id": k + 1,
            "name": b.name,
            "direction": tuple(
                float(v) for v in np.asarray(b.direction) / np.linalg.norm(b.direction)
            ),
            "length": float(b.length),
            "axis": tuple(float(v) for v in b.axis),
            "axis_order": "xyz",
            "dof": b.dofs,
            "limits": tuple((f"{lo:g}", f"{hi:g}") for lo, hi in b.limits),
            "other": (),
        }
        for k, b in enumerate(bones)
    ]
    return Skeleton(
        joint_names=unit.joint_names,
        parents=unit.parents,
        offsets=unit.offsets * scale,
        channels=unit.channels,
        euler="extrinsic",
        axes=unit.axes,
        site_names=unit.site_names,
        site_parents=unit.site_parents,
        site_offsets=unit.site_offsets * scale,
        name=f"synthetic_cmu_{height_cm:g}cm",
        extras={
            "dof_limits_deg": limits,
            "source": "quatmotion.synthetic",
            # The layout of quatmotion.io's ASF reader, made by its constructor.
            **asf_extras(
                version="1.10",
                name=f"synthetic_cmu_{height_cm:g}cm",
                documentation=("generated by quatmotion.synthetic (CMU-like layout)",),
                units=(
                    ("mass", "1.0"),
                    ("length", f"{2.54 / length_scale:.10g}"),
                    ("angle", "deg"),
                ),
                root={
                    "order": ("TX", "TY", "TZ", "RX", "RY", "RZ"),
                    "axis": "xyz",
                    "position": (0.0, 0.0, 0.0),
                    "orientation": (0.0, 0.0, 0.0),
                },
                bones=asf_bones,
                hierarchy=hierarchy,
                length_scale=length_scale,
                angle_unit="deg",
            ),
            "bone_vectors_cm": bone_vectors,
        },
    )


def standing_pose(skeleton: Skeleton | None = None) -> Motion:
    """One frame of the neutral standing pose: legs straight and together, arms by the sides.

    Parameters
    ----------
    skeleton : Skeleton, optional
        A :func:`cmu_skeleton` (default: 170 cm).

    Returns
    -------
    Motion
        One frame at 1 frame/s, the lowest foot point on the floor ``y = 0``.
    """
    sk = cmu_skeleton() if skeleton is None else skeleton
    rotations = _local_rotations(sk, {"l_knee": np.zeros(1), "r_knee": np.zeros(1)}, 1)
    y = forward_kinematics(Motion(sk, 1.0, np.zeros((1, 3)), rotations)).all_positions()[0, :, 1]
    return Motion(sk, 1.0, np.array([[0.0, -y.min(), 0.0]]), rotations, name="standing")


def _standing_height(sk: Skeleton) -> float:
    """Vertical extent (skeleton units) of :func:`standing_pose`."""
    y = forward_kinematics(standing_pose(sk)).all_positions()[0, :, 1]
    return float(y.max() - y.min())


def foot_positions(motion: Motion) -> dict[str, FloatArray]:
    """Heel, ankle, ball and toe tip of each foot over the clip, centimetres.

    The heel is not a CMU joint: it is placed on the sole, under and 3 % of the standing height
    behind the ankle at rest, carried by the ankle (``lfoot``/``rfoot``) joint's global rotation.

    Parameters
    ----------
    motion : Motion
        A clip on a :func:`cmu_skeleton`.

    Returns
    -------
    dict
        ``{"l": (T, 4, 3), "r": (T, 4, 3)}``: rows heel, ankle, ball (``ltoes`` joint), toe tip
        (``ltoes_end`` site), world coordinates in centimetres.
    """
    sk = motion.skeleton
    pose = forward_kinematics(motion)
    points = pose.all_positions()
    rest = sk.rest_positions()
    out = {}
    for side in ("l", "r"):
        ankle, ball = sk.index(f"{side}foot"), sk.index(f"{side}toes")
        tip = sk.n_joints + sk.site_names.index(f"{side}toes_end")
        heel_offset = np.array(
            [0.0, rest[ball, 1] - rest[ankle, 1], -_HEEL_BACK_FRACTION * _standing_height(sk)]
        )
        heel = points[:, ankle] + quat.rotate(pose.rotations[:, ankle], heel_offset)
        out[side] = np.stack((heel, points[:, ankle], points[:, ball], points[:, tip]), axis=1)
    return out


# --------------------------------------------------------------------------------------------
# Pose parameters -> local rotations


def _chain(*rotations: FloatArray) -> FloatArray:
    """Product ``r0 r1 ... rn``: the last one is applied first."""
    out = rotations[0]
    for r in rotations[1:]:
        out = quat.multiply(out, r)
    return out


@dataclass
class _Plan:
    """What a kind designs: pose angles (degrees, per frame), feet in stance, flight."""

    angles: dict[str, FloatArray]
    stance: FloatArray  # (T, 2) weights of the left and right foot being planted, in [0, 1]
    flight_drift: FloatArray | None = None  # (T,) extra forward cm per frame while airborne
    contact_from_height: bool = False  # planted feet = the lowest ones (stance only gates flight)
    no_jitter: tuple[str, ...] = ()  # angles kept exact (foot placement depends on them)


def _get(angles: dict[str, FloatArray], key: str, T: int, default: float = 0.0) -> FloatArray:
    value = angles.get(key)
    return np.full(T, default) if value is None else np.broadcast_to(value, (T,)).astype(float)


def _local_rotations(sk: Skeleton, angles: dict[str, FloatArray], T: int) -> FloatArray:
    """Local joint rotations ``(T, J, 4)`` of the pose parameters ``angles`` (degrees)."""
    limits = sk.extras["dof_limits_deg"]
    rot = np.tile(quat.identity(), (T, sk.n_joints, 1))

    def a(key: str, default: float = 0.0) -> FloatArray:
        return _get(angles, key, T, default)

    def set_world(name: str, q: FloatArray) -> None:
        rot[:, sk.index(name)] = q

    def set_dofs(name: str, values: dict[str, FloatArray]) -> None:
        # Driven through the joint's own channels, clipped to CMU's limits: C M C^-1.
        j = sk.index(name)
        euler = np.zeros((T, 3))
        for k, dof in enumerate(sk.rotation_dofs(j)):
            lo, hi = limits[name][k]
            euler[:, "xyz".index(dof[1])] = np.clip(values.get(dof, 0.0), lo, hi)
        m = quat.from_euler(euler, "xyz", degrees=True)
        c = sk.axes[j]
        rot[:, j] = quat.multiply(quat.multiply(c, m), quat.conjugate(c))

    pelvis_tilt = _chain(
        quat.about_axis(a("pelvis_pitch"), "x", degrees=True),
        quat.about_axis(-a("pelvis_roll"), "z", degrees=True),
    )
    set_world(
        "root",
        quat.multiply(
            quat.about_axis(a("heading") + a("pelvis_yaw"), "y", degrees=True), pelvis_tilt
        ),
    )
    # The legs are designed in the heading frame (what balance and foot placement see), so the
    # pelvis tilt is undone at the hips; the pelvis yaw still carries them, as it does in gait.
    untilt = quat.conjugate(pelvis_tilt)
    for name in ("lowerback", "upperback", "thorax"):
        set_world(
            name,
            _chain(
                quat.about_axis(a("spine_twist") / 3, "y", degrees=True),
                quat.about_axis(a("spine_flex") / 3, "x", degrees=True),
                quat.about_axis(-a("spine_side") / 3, "z", degrees=True),
            ),
        )
    for name in ("lowerneck", "upperneck"):
        set_world(name, quat.about_axis(a("neck_flex") / 2, "x", degrees=True))
    set_world("head", quat.about_axis(a("head_turn"), "y", degrees=True))
    for side, s in (("l", 1.0), ("r", -1.0)):
        # Hip: CMU's rest legs splay 20 deg outward (the femur axis); adduct them to vertical
        # first, then twist about the thigh, abduct outward and flex forward (-x).
        set_world(
            f"{side}femur",
            _chain(
                untilt,
                quat.about_axis(-a(f"{side}_hip_flex"), "x", degrees=True),
                quat.about_axis(s * a(f"{side}_hip_abd"), "z", degrees=True),
                quat.about_axis(-s * a(f"{side}_hip_twist"), "y", degrees=True),
                quat.about_axis(np.full(T, -s * _REST_LEG_SPLAY_DEG), "z", degrees=True),
            ),
        )
        set_dofs(f"{side}tibia", {"rx": a(f"{side}_knee", 2.0)})
        set_dofs(f"{side}foot", {"rx": -a(f"{side}_ankle"), "rz": s * a(f"{side}_foot_turn")})
        set_dofs(f"{side}toes", {"rx": -a(f"{side}_toe")})
        set_dofs(
            f"{side}clavicle", {"rz": s * a(f"{side}_clav_elev"), "ry": -s * a(f"{side}_clav_fwd")}
        )
        # Shoulder from CMU's T-pose: twist 30 deg about the arm so the elbow hinges forward when
        # the arm hangs, abduction 0 = arm down, 90 = sideways, 180 = overhead, then flexion.
        set_world(
            f"{side}humerus",
            _chain(
                quat.about_axis(-a(f"{side}_sh_flex"), "x", degrees=True),
                quat.about_axis(s * (a(f"{side}_sh_abd", 8.0) - 90.0), "z", degrees=True),
                quat.about_axis(30.0 + a(f"{side}_sh_twist"), "x", degrees=True),
            ),
        )
        set_dofs(f"{side}radius", {"rx": a(f"{side}_elbow", 12.0)})
        set_dofs(f"{side}wrist", {"ry": -np.abs(a(f"{side}_wrist", 5.0))})
        set_dofs(f"{side}hand", {"rx": a(f"{side}_hand", 0.0), "rz": 0.0})
        set_dofs(f"{side}fingers", {"rx": a(f"{side}_fingers", 10.0)})
        set_dofs(f"{side}thumb", {"rx": 0.0, "rz": 0.0})
    return rot


# --------------------------------------------------------------------------------------------
# Curves and noise


def _timeline(t: FloatArray, keys: Sequence[tuple[float, float]]) -> FloatArray:
    """Monotone (overshoot-free) interpolation of ``(time, value)`` keys, held at the ends."""
    x = np.array([k[0] for k in keys])
    y = np.array([k[1] for k in keys])
    return PchipInterpolator(x, y, extrapolate=False)(np.clip(t, x[0], x[-1]))


def _smooth_noise(
    rng: np.random.Generator, t: FloatArray, amplitude: float, max_hz: float = 0.7, n_waves: int = 3
) -> FloatArray:
    """A smooth random signal of RMS about ``amplitude``: a sum of slow random sinusoids."""
    freqs = rng.uniform(0.1, max_hz, n_waves)
    phases = rng.uniform(0.0, 2 * np.pi, n_waves)
    amps = rng.normal(0.0, 1.0, n_waves) * amplitude * np.sqrt(2.0 / n_waves)
    return np.sum(amps * np.sin(2 * np.pi * freqs * t[:, None] + phases), axis=1)


def _window(phase: FloatArray, start: float, stop: float, ramp: float = 0.03) -> FloatArray:
    """Periodic trapezoid: 1 on ``[start, stop)`` of each cycle, linear ramps ``ramp`` wide."""
    distance = np.abs(np.mod(phase - (start + stop) / 2 + 0.5, 1.0) - 0.5)
    return np.clip(((stop - start) / 2 - distance) / ramp + 0.5, 0.0, 1.0)


def _smoothstep(x: FloatArray) -> FloatArray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


@dataclass(frozen=True)
class _Style:
    tempo: float  # multiplier on the kind's base frequency
    amplitude: float  # multiplier on the kind's main joint excursions
    asymmetry: float  # relative left-right difference of amplitude, +: left larger
    phase_noise: float  # RMS drift of the phase, cycles
    jitter: float  # RMS of the smooth noise on every pose angle, degrees
    side: str  # the leading side for one-sided kinds, "l" or "r"
    thigh_cm: float  # hip-to-knee and knee-to-ankle lengths of the skeleton
    shin_cm: float

    def gain(self, side: str) -> float:
        return self.amplitude * (1.0 + (self.asymmetry if side == "l" else -self.asymmetry) / 2)


def _phase(rng: np.random.Generator, t: FloatArray, hz: float, style: _Style) -> FloatArray:
    """Cycle count over time: ``hz * t`` plus a random start and slow, monotone drift."""
    drift = _smooth_noise(rng, t, style.phase_noise, max_hz=min(0.5, hz / 2))
    return hz * t + drift


def _standing(T: int) -> dict[str, FloatArray]:
    return {
        "l_knee": np.full(T, 3.0),
        "r_knee": np.full(T, 3.0),
        "l_hip_abd": np.full(T, 3.0),
        "r_hip_abd": np.full(T, 3.0),
        "l_sh_abd": np.full(T, 8.0),
        "r_sh_abd": np.full(T, 8.0),
    }


def _flat_feet(angles: dict[str, FloatArray], T: int) -> None:
    """Ankle dorsiflexion that keeps each sole level: knee flexion minus hip flexion."""
    for side in ("l", "r"):
        angles[f"{side}_ankle"] = _get(angles, f"{side}_knee", T, 2.0) - _get(
            angles, f"{side}_hip_flex", T
        )


# --------------------------------------------------------------------------------------------
# The kinds. Each returns the pose angles over ``t`` (seconds) and the feet in stance.


def _leg_ik(
    z: FloatArray, y: FloatArray, thigh: float, shin: float
) -> tuple[FloatArray, FloatArray]:
    """Hip and knee flexion (degrees) that put the ankle at ``(z, y)`` cm from the hip.

    Sagittal two-link inverse kinematics in the heading frame (``z`` forward, ``y`` up, the leg
    hanging along ``-y`` at zero), knee bending backwards. Out-of-reach targets are pulled in.
    """
    reach = np.clip(np.hypot(z, y), abs(thigh - shin) + 1e-6, 0.999 * (thigh + shin))
    inner = np.arccos(np.clip((thigh**2 + shin**2 - reach**2) / (2 * thigh * shin), -1.0, 1.0))
    line = np.arctan2(z, -y)
    spread = np.arccos(np.clip((thigh**2 + reach**2 - shin**2) / (2 * thigh * reach), -1.0, 1.0))
    return np.rad2deg(line + spread), np.rad2deg(np.pi - inner)


_LEG_KEYS = tuple(
    f"{side}_{name}"
    for side in "lr"
    for name in ("hip_flex", "hip_abd", "hip_twist", "knee", "ankle", "toe", "foot_turn")
)
"""Leg angles: kinds that plant both feet keep them exact, so no foot lifts or slides."""


def _locomotion(t: FloatArray, rng: np.random.Generator, style: _Style, run: bool) -> _Plan:
    """Walk or run: each ankle follows a stance-and-swing path, the legs follow by IK.

    In stance the ankle slides backwards under the hip at constant speed, with the sole level,
    so the planted foot stays still while the root advances ``stride / stance time``; in swing it
    returns along a raised arc. Walking ankles ride an arc of constant hip distance (the pelvis
    vaults over the stance leg); running ankles a level line that dips at mid-stance.
    """
    T = t.size
    thigh, shin = style.thigh_cm, style.shin_cm
    leg = thigh + shin
    hz = (1.45 if run else 0.95) * style.tempo
    duty = 0.38 if run else 0.6
    phase = _phase(rng, t, hz, style) + rng.uniform(0.0, 1.0)
    lean = (9.0 if run else 3.0) + rng.normal(0.0, 1.5)
    angles = _standing(T)
    stance = np.zeros((T, 2))
    for k, (side, offset) in enumerate((("l", 0.0), ("r", 0.5))):
        g = style.gain(side)
        stride = (0.95 if run else 0.72) * leg * g  # ankle travel relative to the hip in stance
        p = np.mod(phase + offset, 1.0)
        in_stance = p < duty
        s_stance = p / duty
        s_swing = (p - duty) / (1.0 - duty)
        z = np.where(
            in_stance,
            stride * (0.5 - s_stance),
            stride * (-0.5 + 0.5 * (1.0 - np.cos(np.pi * np.clip(s_swing, 0.0, 1.0)))),
        )
        if run:
            level = np.sqrt((0.99 * leg) ** 2 - (stride / 2) ** 2)
            y_stance = -(level - 4.0 * np.sin(np.pi * s_stance) ** 2)
            lift = 0.32 * leg * g * np.sin(np.pi * np.clip(s_swing, 0.0, 1.0) ** 0.7)
        else:
            y_stance = -np.sqrt((0.985 * leg) ** 2 - z**2)
            lift = 0.08 * leg * np.sin(np.pi * np.clip(s_swing, 0.0, 1.0))
        y_swing = -np.sqrt((0.985 * leg) ** 2 - (stride / 2) ** 2) + lift
        hip, knee = _leg_ik(z, np.where(in_stance, y_stance, y_swing), thigh, shin)
        angles[f"{side}_hip_flex"] = hip
        angles[f"{side}_knee"] = knee
        # Sole level in stance; in swing the toes drop a little after push-off.
        angles[f"{side}_ankle"] = (
            knee
            - hip
            - np.where(
                in_stance,
                0.0,
                12.0 * np.sin(np.pi * np.clip(s_swing, 0.0, 1.0)) * (1.0 if run else 0.5),
            )
        )
        angles[f"{side}_hip_abd"] = np.full(T, 2.0)
        # The arm swings against the leg on its side.
        swing = (z / (stride / 2)) * (30.0 if run else 18.0) * g
        angles[f"{side}_sh_flex"] = -swing + (10.0 if run else 0.0)
        angles[f"{side}_sh_abd"] = np.full(T, 12.0 if run else 8.0)
        angles[f"{side}_elbow"] = (80.0 if run else 18.0) - 0.5 * swing
        stance[:, k] = in_stance
    cycle = 2 * np.pi * phase
    angles["pelvis_pitch"] = np.full(T, lean * 0.5)
    angles["pelvis_yaw"] = -4.0 * style.amplitude * np.cos(cycle)
    angles["pelvis_roll"] = 3.0 * np.sin(2 * cycle)
    angles["spine_twist"] = 8.0 * style.amplitude * np.cos(cycle)
    angles["spine_flex"] = np.full(T, lean * 0.5)
    angles["neck_flex"] = np.full(T, -lean * 0.8)
    return _Plan(
        angles, stance if run else np.ones((T, 2)), contact_from_height=True, no_jitter=_LEG_KEYS
    )


def _walk(t: FloatArray, rng: np.random.Generator, style: _Style) -> _Plan:
    return _locomotion(t, rng, style, run=False)


def _run(t: FloatArray, rng: np.random.Generator, style: _Style) -> _Plan:
    return _locomotion(t, rng, style, run=True)


def _jump(t: FloatArray, rng: np.random.Generator, style: _Style) -> _Plan:
    """Countermovement jumps: crouch, push off, fly, land, recover; optionally forward."""
    T = t.size
    period = 2.2 / style.tempo
    start = rng.uniform(0.2, 0.5)
    flight = rng.uniform(0.28, 0.42) * np.sqrt(style.amplitude)
    depth = np.clip(style.amplitude * rng.uniform(0.7, 1.0), 0.4, 1.1)
    forward = rng.uniform(0.0, 60.0)
    crouch = np.zeros(T)
    extend = np.zeros(T)
    arms = np.zeros(T)
    stance = np.ones((T, 2))
    drift = np.zeros(T)
    n_jumps = max(1, int((t[-1] - start) // period) if T > 1 else 1)
    for n in range(n_jumps):
        t0 = start + n * period
        takeoff = t0 + 0.75
        land = takeoff + flight
        keys_c = [
            (t0, 0),
            (t0 + 0.45, depth),
            (t0 + 0.55, depth),
            (takeoff, 0.0),
            (land, 0.0),
            (land + 0.18, 0.6 * depth),
            (land + 0.7, 0.0),
        ]
        crouch += _timeline(t, keys_c)
        extend += _timeline(
            t,
            [
                (t0 + 0.5, 0),
                (takeoff - 0.02, 1.0),
                (takeoff + 0.1, 0.6),
                (land, 0.4),
                (land + 0.1, 0.0),
            ],
        )
        arms += _timeline(
            t, [(t0, 0.0), (t0 + 0.45, -1.0), (takeoff, 1.0), (land, 0.6), (land + 0.7, 0.0)]
        )
        airborne = (t >= takeoff) & (t < land)
        stance[airborne] = 0.0
        drift[airborne] += forward / max(1, int(np.sum(airborne)))
    angles = _standing(T)
    angles["pelvis_pitch"] = 35.0 * crouch
    angles["spine_flex"] = 20.0 * crouch
    angles["neck_flex"] = -25.0 * crouch
    for side in ("l", "r"):
        g = style.gain(side)
        thigh = 75.0 * crouch  # both feet push off together: the legs stay symmetric
        shin = 30.0 * crouch
        angles[f"{side}_hip_flex"] = thigh
        angles[f"{side}_knee"] = thigh + shin + 3.0
        angles[f"{side}_hip_abd"] = np.full(T, 5.0)
        angles[f"{side}_sh_flex"] = np.where(arms < 0, 45.0 * arms, 150.0 * arms) * g
        angles[f"{side}_elbow"] = 15.0 + 10.0 * np.abs(arms)
    _flat_feet(angles, T)
    for side in ("l", "r"):
        # Push off through the toes: plantarflex while extending.
        angles[f"{side}_ankle"] = angles[f"{side}_ankle"] - 35.0 * extend
    return _Plan(angles, stance, flight_drift=drift, no_jitter=_LEG_KEYS)


def _jumping_jack(t: FloatArray, rng: np.random.Generator, style: _Style) -> _Plan:
    T = t.size
    hz = 0.9 * style.tempo
    phase = _phase(rng, t, hz, style)
    open_amount = 0.5 - 0.5 * np.cos(2 * np.pi * phase)
    angles = _standing(T)
    # A short hop carries each change of stance (phase 1/4: out, 3/4: in).
    airborne = np.maximum(_window(phase, 0.21, 0.29, ramp=0.02), _window(phase, 0.71, 0.79, 0.02))
    land = np.maximum(_window(phase, 0.29, 0.4, 0.06), _window(phase, 0.79, 0.9, 0.06))
    for side in ("l", "r"):
        g = style.gain(side)
        # Symmetric legs keep both feet on the floor; the style's asymmetry goes to the arms.
        angles[f"{side}_hip_abd"] = 3.0 + 17.0 * open_amount * style.amplitude
        angles[f"{side}_knee"] = 4.0 + 18.0 * land
        angles[f"{side}_hip_flex"] = 9.0 * land
        angles[f"{side}_sh_abd"] = 8.0 + np.minimum(167.0 * g, 170.0) * open_amount
        angles[f"{side}_elbow"] = 10.0 + 10.0 * open_amount
        angles[f"{side}_clav_elev"] = 15.0 * open_amount
    _flat_feet(angles, T)
    stance = np.repeat((1.0 - airborne)[:, None], 2, axis=1)
    return _Plan(angles, stance, no_jitter=_LEG_KEYS)


def _squat(t: FloatArray, rng: np.random.Generator, style: _Style) -> _Plan:
    T = t.size
    hz = 0.3 * style.tempo
    phase = _phase(rng, t, hz, style)
    depth = _smoothstep(0.5 - 0.5 * np.cos(2 * np.pi * np.maximum(phase, 0.0)))
    thigh = np.clip(82.0 * style.amplitude, 65.0, 98.0) * depth  # thigh from vertical, world
    shin = 0.33 * thigh
    angles = _standing(T)
    angles["pelvis_pitch"] = 0.4 * thigh
    angles["spine_flex"] = 0.15 * thigh
    angles["neck_flex"] = -0.35 * thigh
    for side in ("l", "r"):
        angles[f"{side}_hip_flex"] = thigh
        angles[f"{side}_knee"] = thigh + shin + 3.0
        angles[f"{side}_hip_abd"] = np.full(T, 3.0)
        angles[f"{side}_sh_flex"] = 85.0 * depth * style.gain(side) / style.amplitude
        angles[f"{side}_sh_abd"] = 8.0 + 4.0 * depth
        angles[f"{side}_elbow"] = 8.0 + 5.0 * depth
    _flat_feet(angles, T)
    return _Plan(angles, np.ones((T, 2)), no_jitter=_LEG_KEYS)


def _arm_circles(t: FloatArray, rng: np.random.Generator, style: _Style) -> _Plan:
    T = t.size
    hz = 1.1 * style.tempo
    phase = _phase(rng, t, hz, style)
    direction = rng.choice([-1.0, 1.0])
    angles = _standing(T)
    ramp = _smoothstep(t / 0.6)  # lift the arms first, then circle
    for side in ("l", "r"):
        radius = 25.0 * style.gain(side)
        cycle = 2 * np.pi * phase
        angles[f"{side}_sh_abd"] = 8.0 + ramp * (82.0 + radius * np.sin(cycle))
        angles[f"{side}_sh_flex"] = ramp * direction * radius * np.cos(cycle)
        angles[f"{side}_elbow"] = np.full(T, 6.0)
        angles[f"{side}_hip_abd"] = np.full(T, 3.0)
    angles["spine_flex"] = 3.0 * np.sin(2 * np.pi * phase)
    return _Plan(angles, np.ones((T, 2)), no_jitter=_LEG_KEYS)


def _kick(t: FloatArray, rng: np.random.Generator, style: _Style) -> _Plan:
    """Front kicks with one leg: chamber, extend, re-chamber, put down."""
    T = t.size
    kick, support = style.side, "r" if style.side == "l" else "l"
    period = 1.5 / style.tempo
    start = rng.uniform(0.3, 0.6)
    height = np.clip(80.0 * style.amplitude, 55.0, 100.0)
    hip = np.zeros(T)
    knee = np.zeros(T)
    ankle = np.zeros(T)
    lifted = np.zeros(T)
    n_kicks = max(1, int((t[-1] - start) // period) if T > 1 else 1)
    for n in range(n_kicks):
        t0 = start + n * period
        d = 0.9 / style.tempo
        hip += _timeline(
            t,
            [
                (t0, 0),
                (t0 + 0.25 * d, 55),
                (t0 + 0.42 * d, height),
                (t0 + 0.6 * d, 55),
                (t0 + d, 0),
            ],
        )
        knee += _timeline(
            t, [(t0, 0), (t0 + 0.25 * d, 100), (t0 + 0.42 * d, 5), (t0 + 0.6 * d, 95), (t0 + d, 0)]
        )
        ankle += _timeline(
            t,
            [
                (t0, 0),
                (t0 + 0.15 * d, 0),
                (t0 + 0.25 * d, -15),
                (t0 + 0.42 * d, -35),
                (t0 + 0.6 * d, -15),
                (t0 + 0.8 * d, 0),
            ],
        )
        lifted += ((t > t0 + 0.05 * d) & (t < t0 + 0.95 * d)).astype(float)
    angles = _standing(T)
    angles[f"{kick}_hip_flex"] = hip
    angles[f"{kick}_knee"] = knee + 3.0
    # Near the floor the kicking foot is kept level (like the support foot), so that it lands
    # flat instead of toe first.
    near_floor = np.clip(1.0 - hip / 20.0, 0.0, 1.0)
    angles[f"{kick}_ankle"] = ankle + near_floor * (knee + 3.0 - hip)
    angles[f"{support}_knee"] = 3.0 + 0.05 * hip
    angles[f"{support}_hip_flex"] = 0.02 * hip
    angles[f"{support}_ankle"] = angles[f"{support}_knee"] - angles[f"{support}_hip_flex"]
    angles["spine_flex"] = -0.15 * hip
    angles["spine_side"] = np.full(T, 4.0 if kick == "r" else -4.0) * (hip / height)
    for side in ("l", "r"):
        angles[f"{side}_sh_flex"] = np.full(T, 50.0)
        angles[f"{side}_sh_abd"] = np.full(T, 20.0)
        angles[f"{side}_elbow"] = np.full(T, 110.0)
    stance = np.ones((T, 2))
    stance[:, 0 if kick == "l" else 1] = 1.0 - np.clip(lifted, 0.0, 1.0)
    return _Plan(angles, stance, contact_from_height=True, no_jitter=_LEG_KEYS)


def _wave(t: FloatArray, rng: np.random.Generator, style: _Style) -> _Plan:
    """One hand raised beside the head, waving side to side."""
    T = t.size
    side = style.side
    hz = 2.0 * style.tempo
    raise_ = _timeline(t, [(0.0, 0.0), (0.25, 0.0), (0.8, 1.0)])
    phase = _phase(rng, t, hz, style)
    angles = _standing(T)
    angles[f"{side}_sh_abd"] = 8.0 + raise_ * (95.0 + rng.uniform(-10.0, 20.0))
    angles[f"{side}_sh_flex"] = raise_ * 20.0
    # External rotation turns the hinge so the bent forearm points up, then rocks it.
    angles[f"{side}_sh_twist"] = raise_ * (
        -90.0 + 25.0 * style.amplitude * np.sin(2 * np.pi * phase)
    )
    angles[f"{side}_elbow"] = 12.0 + raise_ * 85.0
    angles[f"{side}_clav_elev"] = raise_ * 10.0
    angles["spine_side"] = raise_ * (-3.0 if side == "l" else 3.0)
    angles["head_turn"] = raise_ * (10.0 if side == "l" else -10.0)
    return _Plan(angles, np.ones((T, 2)), no_jitter=_LEG_KEYS)


def _punch(t: FloatArray, rng: np.random.Generator, style: _Style) -> _Plan:
    """Boxing stance, straight punches alternating between the arms."""
    T = t.size
    hz = 1.2 * style.tempo
    phase = _phase(rng, t, hz, style)
    angles = _standing(T)
    for side, offset in (("l", 0.0), ("r", 0.5)):
        strike = _window(phase + offset, 0.0, 0.18, ramp=0.12) * style.gain(side)
        strike = np.clip(strike, 0.0, 1.0)
        angles[f"{side}_sh_flex"] = 45.0 + 40.0 * strike
        angles[f"{side}_sh_abd"] = 25.0 - 10.0 * strike
        angles[f"{side}_elbow"] = 120.0 - 110.0 * strike
        angles[f"{side}_hip_flex"] = np.full(T, 12.0)
        angles[f"{side}_knee"] = np.full(T, 15.0)
        angles[f"{side}_hip_abd"] = np.full(T, 8.0)
    angles["spine_twist"] = 15.0 * np.sin(2 * np.pi * phase)
    angles["spine_flex"] = np.full(T, 8.0)
    _flat_feet(angles, T)
    return _Plan(angles, np.ones((T, 2)), no_jitter=_LEG_KEYS)


_KIND_FUNCTIONS: dict[str, Callable[[FloatArray, np.random.Generator, _Style], _Plan]] = {
    "walk": _walk,
    "run": _run,
    "jump": _jump,
    "jumping_jack": _jumping_jack,
    "squat": _squat,
    "arm_circles": _arm_circles,
    "kick": _kick,
    "wave": _wave,
    "punch": _punch,
}
_DURATION_S: dict[str, tuple[float, float]] = {
    "walk": (3.0, 5.0),
    "run": (2.5, 4.0),
    "jump": (2.2, 3.0),
    "jumping_jack": (3.0, 5.0),
    "squat": (3.5, 5.5),
    "arm_circles": (3.0, 5.0),
    "kick": (2.0, 3.5),
    "wave": (2.5, 4.0),
    "punch": (2.5, 4.0),
}
# Pose angles never jittered (the heading is drawn separately).
_NO_JITTER = ("heading",)


# --------------------------------------------------------------------------------------------
# Root placement


def _place_root(
    sk: Skeleton, rotations: FloatArray, plan: _Plan, fps: float, start_xz: FloatArray
) -> FloatArray:
    """Root translation ``(T, 3)`` cm that grounds the feet and keeps planted feet still."""
    T = rotations.shape[0]
    floating = foot_positions(Motion(sk, fps, np.zeros((T, 3)), rotations))
    feet = np.stack((floating["l"], floating["r"]), axis=1)  # (T, 2 feet, 4 points, 3)
    lowest = np.min(feet[..., 1], axis=2)  # (T, 2)
    height = -np.min(lowest, axis=1)

    stance = np.clip(plan.stance, 0.0, 1.0)
    if plan.contact_from_height:
        # A foot is planted while its lowest point is within a few cm of the floor; the
        # kind's stance pattern still says when the body is airborne.
        above = lowest - np.min(lowest, axis=1, keepdims=True)
        stance = np.clip(1.0 - above / _CONTACT_BAND_CM, 0.0, 1.0) * (
            np.sum(stance, axis=1, keepdims=True) > 1e-6
        )
    airborne = np.sum(stance, axis=1) < 1e-6
    # Ballistic arcs over each airborne stretch: h(s) = g/2 s (tau - s).
    if np.any(airborne):
        edges = np.diff(np.concatenate(([0], airborne.astype(int), [0])))
        for first, stop in zip(
            np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True
        ):
            s = (np.arange(first, stop) - first + 1.0) / fps
            tau = (stop - first + 1.0) / fps
            height[first:stop] += 0.5 * GRAVITY_CM_S2 * s * (tau - s)

    # Horizontal: the root moves so as to cancel the planted feet's motion relative to it.
    # Each foot pivots about its lowest point (heel, then ball, then toe as it rolls over).
    pivot = np.argmin(feet[..., 1], axis=2)  # (T, 2)
    xz = np.tile(start_xz, (T, 1))
    if T > 1:
        rows = np.arange(T - 1)[:, None]
        cols = np.arange(2)[None, :]
        p = pivot[:-1]
        velocity = (feet[rows + 1, cols, p] - feet[rows, cols, p])[..., [0, 2]]  # (T-1, 2, 2)
        w = 0.5 * (stance[1:] + stance[:-1])
        total = w.sum(axis=1)
        grounded = total > 1e-6
        root_v = np.zeros((T - 1, 2))
        root_v[grounded] = (
            -np.einsum("tf,tfc->tc", w[grounded], velocity[grounded]) / total[grounded, None]
        )
        if np.any(grounded) and not np.all(grounded):
            frames = np.arange(T - 1)
            for c in range(2):
                root_v[~grounded, c] = np.interp(
                    frames[~grounded], frames[grounded], root_v[grounded, c]
                )
        if plan.flight_drift is not None:
            heading = np.deg2rad(_get(plan.angles, "heading", T)[1:])
            forward = np.stack((np.sin(heading), np.cos(heading)), axis=1)
            root_v += plan.flight_drift[1:, None] * forward
        # A light smoothing: the body's momentum evens out what foot locking alone leaves jerky.
        root_v = gaussian_filter1d(root_v, sigma=_ROOT_SMOOTHING_S * fps, axis=0, mode="nearest")
        xz = xz + np.concatenate((np.zeros((1, 2)), np.cumsum(root_v, axis=0)))
    return np.column_stack((xz[:, 0], height, xz[:, 1]))


# --------------------------------------------------------------------------------------------
# Public API


def generate_clip(
    kind: str,
    seed: int,
    n_frames: int | None = None,
    fps: float = 120.0,
    skeleton: Skeleton | None = None,
) -> Motion:
    """One procedural clip of ``kind``, a pure function of its arguments.

    The style is drawn from ``seed``: tempo (x0.8-1.25), amplitude (x0.8-1.2), left-right
    asymmetry (up to +-15 %), phase drift (up to 0.05 cycles), smooth jitter on every pose angle
    (1-3 degrees), leading side, heading and start position on the floor.

    Parameters
    ----------
    kind : str
        One of :data:`KINDS`.
    seed : int
        Seed of the style and noise; the same seed gives identical arrays.
    n_frames : int, optional
        Clip length; by default a kind-dependent duration of 2-5.5 s drawn from the seed.
    fps : float
        Frame rate, frames per second.
    skeleton : Skeleton, optional
        A skeleton from :func:`cmu_skeleton` (default: ``cmu_skeleton()``, 170 cm tall).

    Returns
    -------
    Motion
        ``n_frames`` frames at ``fps``; root translation ``(T, 3)`` cm, local rotations
        ``(T, 31, 4)``; ``name`` is ``"<kind>_<seed>"``.
    """
    if kind not in _KIND_FUNCTIONS:
        raise ValueError(f"unknown motion kind {kind!r}; choose from {', '.join(KINDS)}")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be positive, got {fps}")
    sk = cmu_skeleton() if skeleton is None else skeleton
    if "dof_limits_deg" not in sk.extras:
        raise ValueError("skeleton must come from cmu_skeleton()")
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), KINDS.index(kind)]))
    style = _Style(
        tempo=float(rng.uniform(0.8, 1.25)),
        amplitude=float(rng.uniform(0.8, 1.2)),
        asymmetry=float(rng.uniform(-0.15, 0.15)),
        phase_noise=float(rng.uniform(0.0, 0.05)),
        jitter=float(rng.uniform(1.0, 3.0)),
        side=str(rng.choice(["l", "r"])),
        thigh_cm=float(np.linalg.norm(sk.offsets[sk.index("ltibia")])),
        shin_cm=float(np.linalg.norm(sk.offsets[sk.index("lfoot")])),
    )
    if n_frames is None:
        n_frames = int(round(rng.uniform(*_DURATION_S[kind]) * fps))
    if int(n_frames) < 1:
        raise ValueError(f"n_frames must be at least 1, got {n_frames}")
    T = int(n_frames)
    t = np.arange(T) / fps
    plan = _KIND_FUNCTIONS[kind](t, rng, style)
    for key in sorted(plan.angles):
        if key not in _NO_JITTER and key not in plan.no_jitter:
            plan.angles[key] = _get(plan.angles, key, T) + _smooth_noise(rng, t, style.jitter)
    plan.angles["heading"] = np.full(T, rng.uniform(-180.0, 180.0))
    rotations = _local_rotations(sk, plan.angles, T)
    start_xz = rng.uniform(-100.0, 100.0, 2)
    root = _place_root(sk, rotations, plan, fps, start_xz)
    return Motion(
        skeleton=sk, fps=fps, root_translation=root, rotations=rotations, name=f"{kind}_{int(seed)}"
    )


def generate_library(
    n_per_kind: int, kinds: Sequence[str] | None = None, seed: int = 0, fps: float = 120.0
) -> list[tuple[Motion, str]]:
    """``n_per_kind`` labelled clips of every kind, seeds derived from ``seed``.

    Parameters
    ----------
    n_per_kind : int
        Clips per kind, at least 1.
    kinds : sequence of str, optional
        Kinds to generate (default: all of :data:`KINDS`).
    seed : int
        Master seed; each clip gets its own seed from a :class:`numpy.random.SeedSequence`.
    fps : float
        Frame rate of every clip.

    Returns
    -------
    list of (Motion, str)
        Clips with their kind as label, grouped by kind in the order of ``kinds``.
    """
    kinds = KINDS if kinds is None else tuple(kinds)
    if n_per_kind < 1:
        raise ValueError(f"n_per_kind must be at least 1, got {n_per_kind}")
    unknown = [k for k in kinds if k not in _KIND_FUNCTIONS]
    if unknown:
        raise ValueError(f"unknown motion kinds {unknown}; choose from {', '.join(KINDS)}")
    seeds = np.random.SeedSequence(int(seed)).generate_state(n_per_kind * len(kinds))
    sk = cmu_skeleton()
    library = []
    for i, kind in enumerate(kinds):
        for k in range(n_per_kind):
            clip_seed = int(seeds[i * n_per_kind + k])
            library.append((generate_clip(kind, clip_seed, fps=fps, skeleton=sk), kind))
    return library
