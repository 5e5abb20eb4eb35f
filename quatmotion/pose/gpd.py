"""Geometric Pose Descriptor (GPD): 1337 features in 1683 dimensions per pose.

Section 3 of Chen et al., "Learning a 3D Human Pose Distance Metric from Geometric Pose
Descriptor" (TVCG 2010).

Conventions
-----------
- Input positions are the 16 joints of ``quatmotion.pose.skeleton16.JOINTS_16``, in that
  order, in the body's local frame: centimetres, Y up, the Hip at the origin, yaw removed.
  Velocities are cm/s and accelerations cm/s^2 of those local coordinates; row 0 (Hip)
  carries the *world* vertical velocity and acceleration of the hip in its Y component (see
  :class:`quatmotion.pose.data.PoseData`).
- The world height of the Hip (cm) is the one coordinate of the Hip kept (Eq. 1).
- Angles are radians in ``[0, pi]``; distances are centimetres.
- Geometry (section 3.1): 16 joints, 30 lines (15 limbs ``parent -> child``, 5 lines from an
  end site's grandparent to the end site, 10 lines between end sites), 5 planes (torso, arms,
  legs) as oriented triangles ``J1 -> J2 -> J3`` with normal ``unit((J2-J1) x (J3-J1))``.
- Degenerate features are removed as the paper says, and the geometry fixes the counts
  (Table 1 of our copy is garbled): a joint's distance to a line through it (420 = 16 x 30 - 60
  kept), a joint's distance to a plane through it (65 = 16 x 5 - 15 kept), and the angle between
  a line lying in a plane and that plane's normal (always pi/2; 135 = 30 x 5 - 15 kept).

  ======  =====  =====  ====  ====  ====  ====  ====  ====  ===  =====
  type    J_c    JJ_d   JJ_o  JL_d  LL_a  JP_d  LP_a  PP_a  J_k  total
  count   16     120    120   420   435   65    135   10    16   1337
  dims    46     120    360   420   435   65    135   10    92   1683
  ======  =====  =====  ====  ====  ====  ====  ====  ====  ===  =====

  ``J_c`` is the 15 non-Hip joints' coordinates plus the Hip's world height (15 x 3 + 1);
  ``J_k`` is velocity and acceleration of the same 15 joints plus the Hip's vertical velocity
  and acceleration (15 x 6 + 2), the temporal counterpart of the same choice.
- Joint-plane distance (Eq. 6) is the *signed* distance ``(J - J1) . n`` in cm, as the feature's
  name says; the printed Eq. 6 dots the normal with the unit vector ``J1 -> J`` (the sine of the
  elevation), which is scale-free but not a distance. A joint on the plane scores 0 either way.
"""

from __future__ import annotations

import itertools

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from quatmotion.pose.skeleton16 import END_SITES_16, JOINTS_16, PARENTS_16

__all__ = [
    "FEATURE_COUNTS",
    "FEATURE_NAMES",
    "FEATURE_SLICES",
    "FEATURE_TYPES",
    "LINES",
    "N_DIMENSIONS",
    "N_FEATURES",
    "PLANES",
    "gpd_features",
]

_J = {name: k for k, name in enumerate(JOINTS_16)}


def _build_lines() -> tuple[tuple[int, int], ...]:
    limbs = [(PARENTS_16[k], k) for k in range(1, len(JOINTS_16))]
    to_grandparent = [(PARENTS_16[PARENTS_16[e]], e) for e in END_SITES_16]
    between_ends = list(itertools.combinations(END_SITES_16, 2))
    return tuple(limbs + to_grandparent + between_ends)


#: The 30 lines ``(J1, J2)``, directed from J1 to J2.
LINES: tuple[tuple[int, int], ...] = _build_lines()
#: The 5 planes ``(J1, J2, J3)``: torso, left arm, right arm, left leg, right leg.
PLANES: tuple[tuple[int, int, int], ...] = tuple(
    (_J[a], _J[b], _J[c])
    for a, b, c in (
        ("Chest", "Neck", "Head"),
        ("LShoulder", "LElbow", "LHand"),
        ("RShoulder", "RElbow", "RHand"),
        ("LHip", "LKnee", "LFoot"),
        ("RHip", "RKnee", "RFoot"),
    )
)

_JOINT_PAIRS = np.array(list(itertools.combinations(range(len(JOINTS_16)), 2)), dtype=np.intp)
_LINES = np.array(LINES, dtype=np.intp)
_PLANES = np.array(PLANES, dtype=np.intp)
_LINE_PAIRS = np.array(list(itertools.combinations(range(len(LINES)), 2)), dtype=np.intp)
_PLANE_PAIRS = np.array(list(itertools.combinations(range(len(PLANES)), 2)), dtype=np.intp)
# (joint, line) with the joint off the line: the distance to a line through it is always 0.
_JOINT_LINE = np.array(
    [(j, m) for m, line in enumerate(LINES) for j in range(len(JOINTS_16)) if j not in line],
    dtype=np.intp,
)
_JOINT_PLANE = np.array(
    [(j, p) for p, plane in enumerate(PLANES) for j in range(len(JOINTS_16)) if j not in plane],
    dtype=np.intp,
)
# A line with both ends on a plane's vertices lies in the plane: its angle to the normal is pi/2.
_LINE_PLANE = np.array(
    [
        (m, p)
        for p, plane in enumerate(PLANES)
        for m, line in enumerate(LINES)
        if not set(line) <= set(plane)
    ],
    dtype=np.intp,
)

_EPS = 1e-9


def _line_name(m: int) -> str:
    a, b = LINES[m]
    return f"L({JOINTS_16[a]}->{JOINTS_16[b]})"


def _plane_name(p: int) -> str:
    return "P(" + "->".join(JOINTS_16[k] for k in PLANES[p]) + ")"


def _build_names() -> tuple[dict[str, tuple[str, ...]], dict[str, int]]:
    names: dict[str, tuple[str, ...]] = {}
    counts: dict[str, int] = {}
    xyz = ("x", "y", "z")
    jc = [f"J_c({JOINTS_16[j]}).{c}" for j in range(1, len(JOINTS_16)) for c in xyz]
    names["J_c"] = (*jc, "J_c(Hip).y_world")
    counts["J_c"] = len(JOINTS_16)
    names["JJ_d"] = tuple(f"JJ_d({JOINTS_16[a]},{JOINTS_16[b]})" for a, b in _JOINT_PAIRS)
    counts["JJ_d"] = len(_JOINT_PAIRS)
    names["JJ_o"] = tuple(
        f"JJ_o({JOINTS_16[a]},{JOINTS_16[b]}).{c}" for a, b in _JOINT_PAIRS for c in xyz
    )
    counts["JJ_o"] = len(_JOINT_PAIRS)
    names["JL_d"] = tuple(f"JL_d({JOINTS_16[j]},{_line_name(m)})" for j, m in _JOINT_LINE)
    counts["JL_d"] = len(_JOINT_LINE)
    names["LL_a"] = tuple(f"LL_a({_line_name(a)},{_line_name(b)})" for a, b in _LINE_PAIRS)
    counts["LL_a"] = len(_LINE_PAIRS)
    names["JP_d"] = tuple(f"JP_d({JOINTS_16[j]},{_plane_name(p)})" for j, p in _JOINT_PLANE)
    counts["JP_d"] = len(_JOINT_PLANE)
    names["LP_a"] = tuple(f"LP_a({_line_name(m)},{_plane_name(p)})" for m, p in _LINE_PLANE)
    counts["LP_a"] = len(_LINE_PLANE)
    names["PP_a"] = tuple(f"PP_a({_plane_name(a)},{_plane_name(b)})" for a, b in _PLANE_PAIRS)
    counts["PP_a"] = len(_PLANE_PAIRS)
    kinetic = ("vx", "vy", "vz", "ax", "ay", "az")
    jk = [f"J_k({JOINTS_16[j]}).{c}" for j in range(1, len(JOINTS_16)) for c in kinetic]
    names["J_k"] = (*jk, "J_k(Hip).vy_world", "J_k(Hip).ay_world")
    counts["J_k"] = len(JOINTS_16)
    return names, counts


_NAMES_BY_TYPE, _COUNTS = _build_names()
#: The nine feature types in descriptor order.
FEATURE_TYPES: tuple[str, ...] = tuple(_NAMES_BY_TYPE)
#: Number of features (not dimensions) of each type (Table 1, "Count").
FEATURE_COUNTS: dict[str, int] = dict(_COUNTS)
#: Name of every one of the 1683 dimensions, in descriptor order.
FEATURE_NAMES: tuple[str, ...] = tuple(n for names in _NAMES_BY_TYPE.values() for n in names)


def _build_slices() -> dict[str, slice]:
    out: dict[str, slice] = {}
    start = 0
    for kind, names in _NAMES_BY_TYPE.items():
        out[kind] = slice(start, start + len(names))
        start += len(names)
    return out


#: Columns of each feature type in the descriptor.
FEATURE_SLICES: dict[str, slice] = _build_slices()
N_FEATURES: int = sum(FEATURE_COUNTS.values())
N_DIMENSIONS: int = len(FEATURE_NAMES)


def _check_joint_array(name: str, a: ArrayLike, n: int | None) -> NDArray[np.float64]:
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[1:] != (len(JOINTS_16), 3):
        raise ValueError(f"{name} has shape {arr.shape}, expected (N, {len(JOINTS_16)}, 3)")
    if n is not None and arr.shape[0] != n:
        raise ValueError(f"{name} has {arr.shape[0]} poses, expected {n}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


def gpd_features(
    positions: ArrayLike,
    velocities: ArrayLike | None = None,
    accelerations: ArrayLike | None = None,
    hip_height: ArrayLike | None = None,
) -> NDArray[np.float64]:
    """Raw (unnormalised) Geometric Pose Descriptor of every pose.

    Parameters
    ----------
    positions : array_like, shape (N, 16, 3)
        Joint positions in the body's local frame, cm (Hip at the origin, yaw removed).
    velocities, accelerations : array_like, shape (N, 16, 3), optional
        Time derivatives of the local positions, cm/s and cm/s^2; the Hip row's Y component is
        the Hip's world vertical velocity / acceleration. ``None`` means zero (static poses:
        the temporal dimensions are then constant and carry no information).
    hip_height : array_like, shape (N,), optional
        World height of the Hip, cm. ``None`` means the Hip row of ``positions`` holds it in its
        Y component (so a pose given in a frame translated only horizontally works as is).

    Returns
    -------
    ndarray, shape (N, 1683)
        Columns named by :data:`FEATURE_NAMES`, grouped by :data:`FEATURE_SLICES`. Distances
        in cm, angles in radians, kinetics in cm/s and cm/s^2.
    """
    pos = _check_joint_array("positions", positions, None)
    n = pos.shape[0]
    if velocities is None:
        vel = np.zeros_like(pos)
    else:
        vel = _check_joint_array("velocities", velocities, n)
    acc = (
        np.zeros_like(pos)
        if accelerations is None
        else _check_joint_array("accelerations", accelerations, n)
    )
    if hip_height is None:
        height = pos[:, 0, 1].copy()
    else:
        height = np.asarray(hip_height, dtype=np.float64).reshape(-1)
        if height.shape != (n,):
            raise ValueError(f"hip_height has shape {height.shape}, expected ({n},)")
    out = np.empty((n, N_DIMENSIONS))
    _gpd_kernel(
        np.ascontiguousarray(pos), np.ascontiguousarray(vel), np.ascontiguousarray(acc),
        np.ascontiguousarray(height), _JOINT_PAIRS, _LINES, _PLANES, _JOINT_LINE, _LINE_PAIRS,
        _JOINT_PLANE, _LINE_PLANE, _PLANE_PAIRS, out,
    )  # fmt: skip
    return out


@numba.njit(cache=True, inline="always")
def _clipped_acos(c: float) -> float:  # pragma: no cover - compiled
    return np.arccos(min(1.0, max(-1.0, c)))


@numba.njit(cache=True, inline="always")
def _angle(
    u: NDArray[np.float64], i: int, v: NDArray[np.float64], j: int
) -> float:  # pragma: no cover - compiled
    """The angle between unit vectors ``u[i]`` and ``v[j]``."""
    return _clipped_acos(u[i, 0] * v[j, 0] + u[i, 1] * v[j, 1] + u[i, 2] * v[j, 2])


@numba.njit(cache=True, inline="always")
def _put_unit(
    out: NDArray[np.float64], i: int, x: float, y: float, z: float
) -> None:  # pragma: no cover - compiled
    """``out[i]`` = ``(x, y, z)`` made unit length (a zero vector stays near zero)."""
    inv = 1.0 / max(np.sqrt(x * x + y * y + z * z), _EPS)
    out[i, 0] = x * inv
    out[i, 1] = y * inv
    out[i, 2] = z * inv


@numba.njit(cache=True, parallel=True)
def _gpd_kernel(
    pos_all: NDArray[np.float64],
    vel: NDArray[np.float64],
    acc: NDArray[np.float64],
    height: NDArray[np.float64],
    joint_pairs: NDArray[np.intp],
    lines: NDArray[np.intp],
    planes: NDArray[np.intp],
    joint_line: NDArray[np.intp],
    line_pairs: NDArray[np.intp],
    joint_plane: NDArray[np.intp],
    line_plane: NDArray[np.intp],
    plane_pairs: NDArray[np.intp],
    out: NDArray[np.float64],
) -> None:  # pragma: no cover - compiled
    """One pose per iteration, columns in the order of :data:`FEATURE_NAMES`."""
    n_joints = pos_all.shape[1]
    for i in numba.prange(pos_all.shape[0]):
        row = out[i]
        # Every geometric feature is relative, so subtracting the Hip changes none of them; it
        # makes J_c body-local even when the caller kept the Hip's height in row 0.
        pos = np.empty((n_joints, 3))
        for j in range(n_joints):
            for c in range(3):
                pos[j, c] = pos_all[i, j, c] - pos_all[i, 0, c]
        col = 0
        for j in range(1, n_joints):  # J_c
            for c in range(3):
                row[col] = pos[j, c]
                col += 1
        row[col] = height[i]
        col += 1
        n_pairs = joint_pairs.shape[0]
        for f in range(n_pairs):  # JJ_d, then JJ_o right after the distances
            a, b = joint_pairs[f, 0], joint_pairs[f, 1]
            dx = pos[b, 0] - pos[a, 0]
            dy = pos[b, 1] - pos[a, 1]
            dz = pos[b, 2] - pos[a, 2]
            norm = np.sqrt(dx * dx + dy * dy + dz * dz)
            row[col + f] = norm
            inv = 1.0 / max(norm, _EPS)
            base = col + n_pairs + 3 * f
            row[base] = dx * inv
            row[base + 1] = dy * inv
            row[base + 2] = dz * inv
        col += 4 * n_pairs
        n_lines = lines.shape[0]
        line_dir = np.empty((n_lines, 3))
        for m in range(n_lines):
            a, b = lines[m, 0], lines[m, 1]
            dx = pos[b, 0] - pos[a, 0]
            dy = pos[b, 1] - pos[a, 1]
            dz = pos[b, 2] - pos[a, 2]
            _put_unit(line_dir, m, dx, dy, dz)
        for f in range(joint_line.shape[0]):  # JL_d = |(J - J1) x u| (Eq. 4)
            j, m = joint_line[f, 0], joint_line[f, 1]
            a = lines[m, 0]
            rx = pos[j, 0] - pos[a, 0]
            ry = pos[j, 1] - pos[a, 1]
            rz = pos[j, 2] - pos[a, 2]
            ux, uy, uz = line_dir[m, 0], line_dir[m, 1], line_dir[m, 2]
            cx = ry * uz - rz * uy
            cy = rz * ux - rx * uz
            cz = rx * uy - ry * ux
            row[col + f] = np.sqrt(cx * cx + cy * cy + cz * cz)
        col += joint_line.shape[0]
        for f in range(line_pairs.shape[0]):  # LL_a
            a, b = line_pairs[f, 0], line_pairs[f, 1]
            row[col + f] = _angle(line_dir, a, line_dir, b)
        col += line_pairs.shape[0]
        n_planes = planes.shape[0]
        normal = np.empty((n_planes, 3))
        for p in range(n_planes):
            a, b, c3 = planes[p, 0], planes[p, 1], planes[p, 2]
            ex, ey, ez = pos[b, 0] - pos[a, 0], pos[b, 1] - pos[a, 1], pos[b, 2] - pos[a, 2]
            fx, fy, fz = pos[c3, 0] - pos[a, 0], pos[c3, 1] - pos[a, 1], pos[c3, 2] - pos[a, 2]
            nx = ey * fz - ez * fy
            ny = ez * fx - ex * fz
            nz = ex * fy - ey * fx
            _put_unit(normal, p, nx, ny, nz)
        for f in range(joint_plane.shape[0]):  # JP_d, signed
            j, p = joint_plane[f, 0], joint_plane[f, 1]
            a = planes[p, 0]
            row[col + f] = (
                (pos[j, 0] - pos[a, 0]) * normal[p, 0]
                + (pos[j, 1] - pos[a, 1]) * normal[p, 1]
                + (pos[j, 2] - pos[a, 2]) * normal[p, 2]
            )
        col += joint_plane.shape[0]
        for f in range(line_plane.shape[0]):  # LP_a
            m, p = line_plane[f, 0], line_plane[f, 1]
            row[col + f] = _angle(line_dir, m, normal, p)
        col += line_plane.shape[0]
        for f in range(plane_pairs.shape[0]):  # PP_a
            a, b = plane_pairs[f, 0], plane_pairs[f, 1]
            row[col + f] = _angle(normal, a, normal, b)
        col += plane_pairs.shape[0]
        for j in range(1, n_joints):  # J_k
            for c in range(3):
                row[col + c] = vel[i, j, c]
                row[col + 3 + c] = acc[i, j, c]
            col += 6
        row[col] = vel[i, 0, 1]
        row[col + 1] = acc[i, 0, 1]
