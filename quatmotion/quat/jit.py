"""Scalar quaternion algebra for Numba kernels, inlined into the caller.

The same conventions as :mod:`quatmotion.quat` (w first, active rotations, ``multiply(p, q)``
is "first q, then p"), written on scalars so that a kernel's loop over joints or samples keeps
everything in registers. Each function is compiled with ``inline="always"``: it is copied into
the calling kernel's IR before optimisation, so it costs no call and takes the caller's
floating-point flags. Kernels import these instead of writing the products out again.
"""

from __future__ import annotations

import math

from numba import njit

__all__ = ["about_axis", "multiply", "rotate"]


@njit(inline="always", cache=True)
def multiply(aw, ax, ay, az, bw, bx, by, bz):  # type: ignore[no-untyped-def]
    """Hamilton product ``a b`` as a ``(w, x, y, z)`` tuple."""
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@njit(inline="always", cache=True)
def rotate(qw, qx, qy, qz, vx, vy, vz):  # type: ignore[no-untyped-def]
    """``q v q*`` for a unit ``q`` and a 3-vector ``v``, as an ``(x, y, z)`` tuple."""
    # v' = v + w t + u x t with t = 2 u x v: two cross products instead of two Hamilton products.
    tx = 2.0 * (qy * vz - qz * vy)
    ty = 2.0 * (qz * vx - qx * vz)
    tz = 2.0 * (qx * vy - qy * vx)
    return (
        vx + qw * tx + (qy * tz - qz * ty),
        vy + qw * ty + (qz * tx - qx * tz),
        vz + qw * tz + (qx * ty - qy * tx),
    )


@njit(inline="always", cache=True)
def about_axis(angle, ux, uy, uz):  # type: ignore[no-untyped-def]
    """Rotation by ``angle`` radians about the unit axis ``u``, as a ``(w, x, y, z)`` tuple."""
    half = 0.5 * angle
    s = math.sin(half)
    return math.cos(half), s * ux, s * uy, s * uz
