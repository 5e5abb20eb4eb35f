"""Quaternion algebra, vectorised over any leading shape.

Conventions (every function in this module follows them):

* A quaternion is an array whose last axis has length 4, **scalar first**: ``(w, x, y, z)``.
  Shapes are written ``(..., 4)``; the leading shape ``...`` is broadcast NumPy-style.
* Rotations are **active** and quaternions act on column vectors: ``rotate(q, v)`` returns
  ``q v q*``, and ``multiply(p, q)`` is the rotation "first ``q``, then ``p``" (the same order as
  the matrix product ``to_matrix(p) @ to_matrix(q)``).
* ``log`` returns the pure-imaginary quaternion logarithm as a 3-vector: for
  ``q = (cos a, sin a * u)`` with ``a in [0, pi]`` and unit ``u``, ``log(q) = a * u``. The rotation
  angle is ``2 a``. ``log`` does not canonicalise: ``log(-q)`` differs from ``log(q)`` (it is the
  other branch), so call :func:`canonicalize` first where a shortest-arc log is wanted.
* ``exp`` is the inverse of ``log``: ``exp(a * u) = (cos a, sin a * u)``; ``exp(log(q)) == q``
  for every unit ``q``, including ``-1``.
* ``power(q, t) = exp(t * log(q))``, so ``q**a * q**b == q**(a + b)`` (shared axis).
* Euler orders follow SciPy: an upper-case order such as ``"ZXY"`` is *intrinsic* (the matrix is
  ``R_Z(a0) @ R_X(a1) @ R_Y(a2)``, the BVH convention), a lower-case order such as ``"xyz"`` is
  *extrinsic* (the matrix is ``R_z(a2) @ R_y(a1) @ R_x(a0)``, the ASF/AMC convention). Angles
  are in radians unless ``degrees=True``.

Near the identity the log and the power use ``sinc`` so that no NaN appears; at 180 degrees
(``w == 0``) the log is ``pi/2 * u``, finite as well.

Numba kernels elsewhere in the package do not call these array functions per element: they
share the scalar, inlined versions of the same algebra in :mod:`quatmotion.quat.jit`.
"""

from __future__ import annotations

import warnings

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

__all__ = [
    "about_axis",
    "angle",
    "canonicalize",
    "conjugate",
    "dot",
    "exp",
    "from_euler",
    "from_matrix",
    "identity",
    "inverse",
    "log",
    "make_continuous",
    "multiply",
    "normalize",
    "power",
    "rotate",
    "slerp",
    "to_euler",
    "to_matrix",
]


def _as_quat(q: ArrayLike) -> FloatArray:
    q = np.asarray(q, dtype=np.float64)
    if q.shape[-1:] != (4,):
        raise ValueError(f"quaternions need a last axis of length 4, got shape {q.shape}")
    return q


def identity(shape: tuple[int, ...] = ()) -> FloatArray:
    """Identity quaternions of shape ``(*shape, 4)``."""
    q = np.zeros((*shape, 4))
    q[..., 0] = 1.0
    return q


_AXIS_COMPONENT = {"x": 1, "y": 2, "z": 3}


def about_axis(angles: ArrayLike, axis: str, degrees: bool = False) -> FloatArray:
    """Rotations about one coordinate axis ``"x"``, ``"y"`` or ``"z"``: ``(...) -> (..., 4)``.

    ``(cos(a/2), sin(a/2) e_axis)``: the elementary rotation every Euler composition is built
    from. Angles in radians unless ``degrees=True``.
    """
    if axis not in _AXIS_COMPONENT:
        raise ValueError(f"axis must be 'x', 'y' or 'z', got {axis!r}")
    a = np.asarray(angles, dtype=np.float64)
    half = (np.deg2rad(a) if degrees else a) / 2.0
    q = np.zeros((*half.shape, 4))
    q[..., 0] = np.cos(half)
    q[..., _AXIS_COMPONENT[axis]] = np.sin(half)
    return q


def multiply(p: ArrayLike, q: ArrayLike) -> FloatArray:
    """Hamilton product ``p q``: ``(..., 4) x (..., 4) -> (..., 4)`` (broadcast)."""
    p = _as_quat(p)
    q = _as_quat(q)
    pw, px, py, pz = np.moveaxis(p, -1, 0)
    qw, qx, qy, qz = np.moveaxis(q, -1, 0)
    return np.stack(
        (
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ),
        axis=-1,
    )


def conjugate(q: ArrayLike) -> FloatArray:
    """Conjugate ``(w, -x, -y, -z)``: ``(..., 4) -> (..., 4)``."""
    q = _as_quat(q)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def inverse(q: ArrayLike) -> FloatArray:
    """Multiplicative inverse ``q* / |q|^2``: ``(..., 4) -> (..., 4)``."""
    q = _as_quat(q)
    return conjugate(q) / np.sum(q * q, axis=-1, keepdims=True)


def normalize(q: ArrayLike) -> FloatArray:
    """Scale to unit norm: ``(..., 4) -> (..., 4)``. Raises ``ValueError`` on a zero quaternion."""
    q = _as_quat(q)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(norm == 0) or not np.all(np.isfinite(norm)):
        raise ValueError("cannot normalise a zero or non-finite quaternion")
    return q / norm


def dot(p: ArrayLike, q: ArrayLike) -> FloatArray:
    """Four-dimensional inner product: ``(..., 4) x (..., 4) -> (...)``."""
    return np.sum(_as_quat(p) * _as_quat(q), axis=-1)


def angle(p: ArrayLike, q: ArrayLike) -> FloatArray:
    """Geodesic rotation angle between unit quaternions, radians in ``[0, pi]``: ``-> (...)``.

    Equal to ``2 * arccos(|<p, q>|)``; ``q`` and ``-q`` are the same rotation, so the angle is 0
    between them. Computed as ``2 atan2(|vec(p* q)|, |w(p* q)|)``, which keeps full precision for
    small angles where ``arccos`` near 1 loses half the digits.
    """
    d = multiply(conjugate(p), q)
    return 2.0 * np.arctan2(np.linalg.norm(d[..., 1:], axis=-1), np.abs(d[..., 0]))


def log(q: ArrayLike) -> FloatArray:
    """Logarithm of unit quaternions as 3-vectors ``a * u``: ``(..., 4) -> (..., 3)``.

    ``a = atan2(|v|, w)`` lies in ``[0, pi]``, so the branch follows the sign of ``w`` (no
    canonicalisation). At the identity the result is exactly zero.
    """
    q = _as_quat(q)
    w = q[..., 0]
    v = q[..., 1:]
    # hypot, not sqrt(x^2 + y^2 + z^2): the squares of a tiny vector part (1e-161) fall into
    # the subnormals and lose the digits that fix the axis length near 180 degrees.
    vnorm = np.hypot(np.hypot(v[..., 0], v[..., 1]), v[..., 2])
    half_angle = np.arctan2(vnorm, w)
    # a / |v| -> 1/|q| as |v| -> 0 with w > 0; guard the division instead of dividing 0/0.
    safe = (vnorm > 1e-12) | ((w < 0.0) & (np.abs(v).max(axis=-1) > 0.0))
    # The axis v / |v| from v divided by its largest component first: near q = -1 the squares
    # of components below 1e-154 are subnormal or zero, and |v| would lose its digits.
    largest = np.abs(v).max(axis=-1, keepdims=True)
    scaled = v / np.where(largest > 0.0, largest, 1.0)
    axis = scaled / np.maximum(np.linalg.norm(scaled, axis=-1, keepdims=True), 1e-300)
    small = v * (1.0 / np.maximum(np.abs(w), 1e-300))[..., None]
    out = np.where(safe[..., None], axis * half_angle[..., None], small)
    # q = -1 has no axis; any pi * u is a log of it. Pick the x axis so exp(log(-1)) == -1.
    minus_one = (w < 0.0) & (np.abs(v).max(axis=-1) == 0.0)
    if np.any(minus_one):
        out[minus_one] = (np.pi, 0.0, 0.0)
    return out


def exp(v: ArrayLike) -> FloatArray:
    """Exponential of pure-imaginary 3-vectors: ``(..., 3) -> (..., 4)`` unit quaternions."""
    v = np.asarray(v, dtype=np.float64)
    if v.shape[-1:] != (3,):
        raise ValueError(f"exp takes 3-vectors (the imaginary part), got shape {v.shape}")
    a = np.linalg.norm(v, axis=-1)
    # sin(a)/a via numpy's normalised sinc: sinc(x) = sin(pi x)/(pi x).
    s = np.sinc(a / np.pi)
    return np.concatenate((np.cos(a)[..., None], v * s[..., None]), axis=-1)


def power(q: ArrayLike, t: ArrayLike) -> FloatArray:
    """``q ** t = exp(t log q)``, ``t`` broadcast against ``q[..., 0]``: ``-> (..., 4)``."""
    t = np.asarray(t, dtype=np.float64)
    return exp(log(q) * t[..., None])


def canonicalize(q: ArrayLike) -> FloatArray:
    """Map each quaternion to the hemisphere ``w >= 0`` (ties at ``w == 0`` broken on x, y, z)."""
    q = _as_quat(q)
    # The first non-zero component decides, so that the map is a function of the rotation.
    sign_source = np.where(np.abs(q[..., 0]) > 1e-12, q[..., 0], 0.0)
    for k in (1, 2, 3):
        undecided = sign_source == 0.0
        sign_source = np.where(undecided, q[..., k], sign_source)
    sign = np.where(sign_source < 0.0, -1.0, 1.0)
    return q * sign[..., None]


def make_continuous(q: ArrayLike, axis: int = 0) -> FloatArray:
    """Flip signs along ``axis`` so consecutive quaternions have non-negative dot products.

    The rotations are unchanged; the sequence no longer jumps between ``q`` and ``-q``, which is
    what interpolation, logs over time and compression need. ``(..., 4) -> (..., 4)``.
    """
    q = np.moveaxis(_as_quat(q), axis, 0)
    if q.shape[0] < 2:
        return np.moveaxis(q.copy(), 0, axis)
    flips = np.sum(q[1:] * q[:-1], axis=-1) < 0.0
    # A flip at step t changes the sign of every later quaternion: cumulative parity.
    parity = np.concatenate(
        (np.zeros((1, *flips.shape[1:]), dtype=bool), np.cumsum(flips, axis=0) % 2 == 1)
    )
    out = np.where(parity[..., None], -q, q)
    return np.moveaxis(out, 0, axis)


def slerp(p: ArrayLike, q: ArrayLike, t: ArrayLike) -> FloatArray:
    """Interpolation on the shorter arc, ``p (p^-1 q)^t``, ``t`` broadcast: ``-> (..., 4)``."""
    p = _as_quat(p)
    q = _as_quat(q)
    q = np.where((dot(p, q) < 0.0)[..., None], -q, q)
    return multiply(p, power(multiply(conjugate(p), q), t))


def rotate(q: ArrayLike, v: ArrayLike) -> FloatArray:
    """Rotate 3-vectors by unit quaternions, ``q v q*``: ``(..., 4) x (..., 3) -> (..., 3)``."""
    q = _as_quat(q)
    v = np.asarray(v, dtype=np.float64)
    w = q[..., :1]
    u = q[..., 1:]
    # v' = v + 2 w (u x v) + 2 u x (u x v): two cross products instead of two Hamilton products.
    uv = np.cross(u, v)
    return v + 2.0 * (w * uv + np.cross(u, uv))


def to_matrix(q: ArrayLike) -> FloatArray:
    """Rotation matrices of unit quaternions: ``(..., 4) -> (..., 3, 3)``."""
    q = _as_quat(q)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        (
            np.stack((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)), axis=-1),
            np.stack((2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)), axis=-1),
            np.stack((2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)), axis=-1),
        ),
        axis=-2,
    )


def _wxyz(scipy_xyzw: FloatArray) -> FloatArray:
    return np.roll(scipy_xyzw, 1, axis=-1)


def _xyzw(q: FloatArray) -> FloatArray:
    return np.roll(q, -1, axis=-1)


def from_matrix(m: ArrayLike) -> FloatArray:
    """Unit quaternions (``w >= 0``) of rotation matrices: ``(..., 3, 3) -> (..., 4)``."""
    m = np.asarray(m, dtype=np.float64)
    if m.shape[-2:] != (3, 3):
        raise ValueError(f"rotation matrices need trailing shape (3, 3), got {m.shape}")
    lead = m.shape[:-2]
    from scipy.spatial.transform import Rotation  # on first use: SciPy's import is slow

    q = _wxyz(Rotation.from_matrix(m.reshape(-1, 3, 3)).as_quat())
    return canonicalize(q.reshape(*lead, 4))


def _check_order(order: str) -> None:
    if (
        len(order) != 3
        or not (order.isupper() or order.islower())
        or set(order.lower()) - set("xyz")
    ):
        raise ValueError(
            "Euler order must be 3 letters of xyz, all upper (intrinsic) or all lower "
            f"(extrinsic), got {order!r}"
        )
    if order[0].lower() == order[1].lower() or order[1].lower() == order[2].lower():
        raise ValueError(f"Euler order {order!r} repeats an axis in consecutive places")


def from_euler(angles: ArrayLike, order: str, degrees: bool = False) -> FloatArray:
    """Unit quaternions from Euler angles: ``(..., 3) -> (..., 4)``.

    ``angles[..., i]`` is the angle about axis ``order[i]``; see the module docstring for the
    intrinsic (upper-case) and extrinsic (lower-case) conventions.
    """
    _check_order(order)
    a = np.asarray(angles, dtype=np.float64)
    if a.shape[-1:] != (3,):
        raise ValueError(f"Euler angles need a last axis of length 3, got shape {a.shape}")
    if degrees:
        a = np.deg2rad(a)
    # Built from elementary half-angle quaternions: exact, and faster than a round trip via SciPy.
    out = None
    for i, axis_name in enumerate(order):
        e = about_axis(a[..., i], axis_name.lower())
        if out is None:
            out = e
        elif order.isupper():
            out = multiply(out, e)
        else:
            out = multiply(e, out)
    assert out is not None
    return out


def to_euler(q: ArrayLike, order: str, degrees: bool = False) -> FloatArray:
    """Euler angles of unit quaternions in the principal range: ``(..., 4) -> (..., 3)``.

    The inverse of :func:`from_euler` for angles with the first and last in ``(-pi, pi]`` and
    the middle one in ``[-pi/2, pi/2]`` (the principal range SciPy returns). At gimbal lock
    the split between the first and last angle is SciPy's choice.
    """
    _check_order(order)
    q = _as_quat(q)
    lead = q.shape[:-1]
    from scipy.spatial.transform import Rotation  # on first use: SciPy's import is slow

    rot = Rotation.from_quat(_xyzw(q.reshape(-1, 4)))
    with warnings.catch_warnings():
        # Gimbal lock is a property of the data, not an error: SciPy still returns valid angles.
        warnings.simplefilter("ignore", UserWarning)
        angles = rot.as_euler(order, degrees=degrees)
    return angles.reshape(*lead, 3)
