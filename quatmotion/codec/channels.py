"""The codec's channels: a clip as ``(T, C)`` smooth real signals, and back, exactly.

Conventions
-----------
* A **layout** is fixed by a skeleton's structure (joint names, parents, channels, Euler
  convention) plus one choice per joint, its **kind**:

  - ``KIND_ROOT`` (joint 0 with three rotation dofs, and any joint with three rotation dofs
    whose translation moves, as Bandai's ``Hips``): four channels, the heading about the world
    vertical (Y) axis, unwrapped over time, then the rotation vector of ``ref^-1 Y(-h) q``
    (the tilt left once the heading is taken out), radians;
  - ``KIND_ROTVEC`` (three rotation dofs): the rotation vector ``2 log(ref^-1 q)``, radians,
    unwrapped over time against its ``2 pi`` twin (so it never jumps while the rotation turns
    past half a turn from the reference);
  - ``KIND_EULER`` (one or two rotation dofs; three in the file-channel layout of the naive
    codec): the joint's own dof angles, radians, unwrapped, so a decoded clip always lies on
    the joint's dofs and writes back to its file format;
  - ``KIND_FIXED`` (no rotation dof): no channel, the identity.

  Channels come in this order: the root translation ``(x, y, z)`` in centimetres, each joint's
  rotation channels in joint order, then ``(x, y, z)`` of every joint ``j > 0`` that has
  translation channels (centimetres).
* ``ref`` is the layout's **reference pose**, one unit quaternion per joint, stored in the
  file quantised to 1/40 rad per rotation-vector component (int8); encoder and decoder use
  the quantised one, so it need not be precise, only shared.
* The round trip ``from_channels(to_channels(m))`` reproduces rotations and translations to
  rounding (about 1e-13 cm of joint position on the test clips).
* **Weights** measure what a channel moves: ``w_c`` is the mean over frames and over all points
  (joints and end sites) of ``|dp/dx_c|^2`` (cm^2 per unit^2), ``lever_c`` the mean over frames of
  the largest ``|dp/dx_c|`` (cm per unit), both by finite differences through forward kinematics.
  A rotation about a bone's own axis moves little; an isotropic lever-arm estimate misses that.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

from quatmotion import quat
from quatmotion.io._text import decompose_channels
from quatmotion.motion import Motion, Skeleton, forward_kinematics
from quatmotion.runtime import kernels

__all__ = [
    "KIND_EULER",
    "KIND_FIXED",
    "KIND_ROOT",
    "KIND_ROTVEC",
    "ChannelLayout",
    "channel_rotations",
    "default_kinds",
    "euler_kinds",
    "from_channels",
    "layout_key",
    "make_layout",
    "measure_weights",
    "reference_pose",
    "to_channels",
]

KIND_FIXED, KIND_EULER, KIND_ROTVEC, KIND_ROOT = 0, 1, 2, 3
_ROTATION = {"rx": 0, "ry": 1, "rz": 2}
# Translations of joints other than the root that stay within this of the rest offset over a
# whole clip are taken as the offset (Bandai files repeat the offset to 1e-5 cm on every joint).
TRANSLATION_TOLERANCE_CM = 1e-3


def layout_key(skeleton: Skeleton) -> tuple:
    """What makes two skeletons share a channel layout: names, parents, channels, Euler."""
    return (
        skeleton.joint_names,
        tuple(int(p) for p in skeleton.parents),
        skeleton.channels,
        skeleton.euler,
    )


def _dof_axes(skeleton: Skeleton, j: int) -> list[int]:
    return [_ROTATION[c] for c in skeleton.channels[j] if c in _ROTATION]


@dataclass(frozen=True, eq=False)
class ChannelLayout:
    """The channels of one skeleton structure.

    Attributes
    ----------
    kinds : ndarray of int, shape (J,)
        ``KIND_*`` of each joint.
    starts : ndarray of int, shape (J,)
        First channel of each joint's rotation channels.
    counts : ndarray of int, shape (J,)
        Number of rotation channels of each joint (0, 1, 2, 3 or 4).
    translation_joints : ndarray of int, shape (M,)
        Joints ``j > 0`` with translation channels; their channels follow the rotations.
    n_channels : int
        ``C``.
    """

    kinds: NDArray[np.int64]
    starts: NDArray[np.int64]
    counts: NDArray[np.int64]
    translation_joints: NDArray[np.int64]
    n_channels: int

    def translation_columns(self, k: int) -> slice:
        """The three channels of the ``k``-th translation joint."""
        first = self.n_channels - 3 * len(self.translation_joints) + 3 * k
        return slice(first, first + 3)

    def channel_names(self, skeleton: Skeleton) -> list[str]:
        """Readable names of the ``C`` channels (for reports)."""
        names = ["root_tx", "root_ty", "root_tz"]
        for j, kind in enumerate(self.kinds):
            n = skeleton.joint_names[j]
            if kind == KIND_ROOT:
                names += [f"{n}_heading", f"{n}_tilt_x", f"{n}_tilt_y", f"{n}_tilt_z"]
            elif kind == KIND_ROTVEC:
                names += [f"{n}_v{i}" for i in range(3)]
            elif kind == KIND_EULER:
                names += [f"{n}_{c}" for c in skeleton.channels[j] if c in _ROTATION]
        for j in self.translation_joints:
            names += [f"{skeleton.joint_names[j]}_t{a}" for a in "xyz"]
        return names


def make_layout(skeleton: Skeleton, kinds: NDArray[np.int64]) -> ChannelLayout:
    """The layout of ``skeleton`` with the given joint kinds (checked against its dofs)."""
    J = skeleton.n_joints
    kinds = np.asarray(kinds, dtype=np.int64)
    if kinds.shape != (J,):
        raise ValueError(f"kinds has shape {kinds.shape}, expected ({J},)")
    starts = np.zeros(J, dtype=np.int64)
    counts = np.zeros(J, dtype=np.int64)
    c = 3
    for j in range(J):
        n_dof = len(_dof_axes(skeleton, j))
        expected = {0: (KIND_FIXED,), 1: (KIND_EULER,), 2: (KIND_EULER,)}.get(
            n_dof, (KIND_ROTVEC, KIND_ROOT, KIND_EULER)
        )
        if kinds[j] not in expected:
            raise ValueError(f"joint {skeleton.joint_names[j]!r}: kind {kinds[j]} for {n_dof} dofs")
        counts[j] = {KIND_FIXED: 0, KIND_EULER: n_dof, KIND_ROTVEC: 3, KIND_ROOT: 4}[kinds[j]]
        starts[j] = c
        c += counts[j]
    moving = [j for j in range(1, J) if any(ch[0] == "t" for ch in skeleton.channels[j])]
    return ChannelLayout(
        kinds, starts, counts, np.asarray(moving, dtype=np.int64), c + 3 * len(moving)
    )


def euler_kinds(skeleton: Skeleton) -> NDArray[np.int64]:
    """Every joint with rotation dofs as its file's Euler angles (the naive codec's channels)."""
    return np.array(
        [KIND_EULER if _dof_axes(skeleton, j) else KIND_FIXED for j in range(skeleton.n_joints)],
        dtype=np.int64,
    )


def default_kinds(skeleton: Skeleton, motions: list[Motion]) -> NDArray[np.int64]:
    """Root kind for joint 0 and for 3-dof joints whose translation moves in ``motions``."""
    J = skeleton.n_joints
    moving = np.zeros(J, dtype=bool)
    for m in motions:
        if m.joint_translations is not None:
            moving |= np.any(
                np.abs(m.joint_translations - skeleton.offsets) > TRANSLATION_TOLERANCE_CM,
                axis=(0, 2),
            )
    kinds = np.empty(J, dtype=np.int64)
    for j in range(J):
        n_dof = len(_dof_axes(skeleton, j))
        if n_dof == 3:
            kinds[j] = KIND_ROOT if (j == 0 or moving[j]) else KIND_ROTVEC
        else:
            kinds[j] = KIND_EULER if n_dof else KIND_FIXED
    return kinds


def _heading_split(q: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``q = Y(h) s``: heading ``h`` (T,) unwrapped, and the heading-free rotations ``s``."""
    p = quat.canonicalize(q)
    heading = np.unwrap(2.0 * np.arctan2(p[:, 2], p[:, 0]))
    return heading, quat.multiply(quat.about_axis(-heading, "y"), q)


def reference_pose(motions: list[Motion], layout: ChannelLayout) -> NDArray[np.float64]:
    """Chordal mean rotation of each joint over ``motions`` (heading removed on root kinds),
    quantised as the file stores it: ``(J, 4)``."""
    J = len(layout.kinds)
    scatter = np.zeros((J, 4, 4))
    for m in motions:
        q = m.rotations[:: max(1, m.n_frames // 256)].copy()
        for j in np.flatnonzero(layout.kinds == KIND_ROOT):
            q[:, j] = _heading_split(q[:, j])[1]
        scatter += np.einsum("tji,tjk->jik", q, q)
    ref = np.empty((J, 4))
    for j in range(J):
        vecs = np.linalg.eigh(scatter[j])[1][:, -1]
        ref[j] = vecs if vecs[0] >= 0 else -vecs
    return dequantize_reference(quantize_reference(ref))


_REFERENCE_STEPS_PER_RAD = 40.0


def quantize_reference(ref: NDArray[np.float64]) -> NDArray[np.int8]:
    """Reference rotations ``(J, 4)`` as rotation vectors in 1/40 rad, int8 ``(J, 3)``."""
    v = 2.0 * quat.log(quat.canonicalize(ref))
    return np.clip(np.round(v * _REFERENCE_STEPS_PER_RAD), -127, 127).astype(np.int8)


def dequantize_reference(codes: NDArray[np.int8]) -> NDArray[np.float64]:
    """Inverse of :func:`quantize_reference`: ``(J, 3)`` int8 -> ``(J, 4)``."""
    return quat.exp(np.asarray(codes, dtype=np.float64) / (2.0 * _REFERENCE_STEPS_PER_RAD))


def _unwrap_rotvec(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """Per frame ``v`` or its twin ``v (1 - 2 pi / |v|)`` (the same rotation), whichever is
    nearer the previous frame's choice: ``(T, 3) -> (T, 3)``."""
    a = np.linalg.norm(v, axis=1)
    if a.max(initial=0.0) < 0.75 * np.pi:
        return v
    return _unwrap_rotvec_kernel(np.ascontiguousarray(v), a)


@numba.njit(cache=True)
def _unwrap_rotvec_kernel(v, a):  # pragma: no cover - compiled
    out = v.copy()
    for t in range(1, v.shape[0]):
        if a[t] < 1e-12:
            continue
        s = 1.0 - 2.0 * np.pi / a[t]
        d0 = 0.0
        d1 = 0.0
        for i in range(3):
            d0 += (v[t, i] - out[t - 1, i]) ** 2
            d1 += (v[t, i] * s - out[t - 1, i]) ** 2
        if d1 < d0:
            for i in range(3):
                out[t, i] = v[t, i] * s
    return out


def to_channels(
    motion: Motion, layout: ChannelLayout, ref: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """A clip's channels.

    Parameters
    ----------
    motion : Motion
        ``T`` frames on a skeleton of ``layout``'s structure.
    layout : ChannelLayout
    ref : ndarray, shape (J, 4)
        The layout's reference pose.

    Returns
    -------
    channels : ndarray, shape (T, C)
    at_rest : ndarray of bool, shape (M,)
        For each translation joint, whether its translation stays at the rest offset (its
        channels then hold the offset and need not be coded).
    """
    sk = motion.skeleton
    T = motion.n_frames
    X = np.zeros((T, layout.n_channels))
    X[:, :3] = motion.root_translation
    intrinsic = sk.euler == "intrinsic"
    for j, kind in enumerate(layout.kinds):
        a, n = layout.starts[j], layout.counts[j]
        q = motion.rotations[:, j]
        if kind == KIND_ROOT:
            heading, s = _heading_split(q)
            X[:, a] = heading
            v = 2.0 * quat.log(quat.canonicalize(quat.multiply(quat.conjugate(ref[j]), s)))
            X[:, a + 1 : a + 4] = _unwrap_rotvec(v)
        elif kind == KIND_ROTVEC:
            v = 2.0 * quat.log(quat.canonicalize(quat.multiply(quat.conjugate(ref[j]), q)))
            X[:, a : a + 3] = _unwrap_rotvec(v)
        elif kind == KIND_EULER:
            c = sk.axes[j]
            local = quat.multiply(quat.multiply(quat.conjugate(c), q), c)
            letters = "".join("xyz"[i] for i in _dof_axes(sk, j))
            X[:, a : a + n] = np.unwrap(decompose_channels(local, letters, intrinsic), axis=0)
    at_rest = np.ones(len(layout.translation_joints), dtype=bool)
    for k, j in enumerate(layout.translation_joints):
        cols = layout.translation_columns(k)
        if motion.joint_translations is None:
            X[:, cols] = sk.offsets[j]
        else:
            X[:, cols] = motion.joint_translations[:, j]
            at_rest[k] = bool(
                np.all(
                    np.abs(motion.joint_translations[:, j] - sk.offsets[j])
                    <= TRANSLATION_TOLERANCE_CM
                )
            )
    return X, at_rest


def _kernel_tables(skeleton: Skeleton, layout: ChannelLayout):
    """Dof axes ``(J, 3)`` and pre-rotated unit axes ``pre[j, i] = C_j e_i`` with
    ``pre[j, 3, 0]`` flagging intrinsic composition, cached on the skeleton object."""
    cached = _TABLES.get(id(skeleton))
    if cached is not None and cached[0] is skeleton:
        return cached[1], cached[2]
    J = skeleton.n_joints
    dof_axes = np.zeros((J, 3), dtype=np.int64)
    for j in range(J):
        axes = _dof_axes(skeleton, j)
        dof_axes[j, : len(axes)] = axes
    pre = np.zeros((J, 4, 3))
    pre[:, :3] = quat.rotate(skeleton.axes[:, None, :], np.eye(3)[None])
    pre[:, 3, 0] = 1.0 if skeleton.euler == "intrinsic" else 0.0
    if len(_TABLES) > 4096:  # many: a library of one skeleton per clip reads them all
        _TABLES.clear()
    _TABLES[id(skeleton)] = (skeleton, dof_axes, pre)
    return dof_axes, pre


_TABLES: dict[int, tuple] = {}


def channel_rotations(
    X: NDArray[np.float64], skeleton: Skeleton, layout: ChannelLayout, ref: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Local joint rotations ``(T, J, 4)`` of channels ``X`` ``(T, C)`` (one compiled pass)."""
    X = np.ascontiguousarray(X, dtype=np.float64)
    dof_axes, pre = _kernel_tables(skeleton, layout)
    return kernels().rotations_of_channels(
        X, layout.kinds, layout.starts, layout.counts, dof_axes, pre, np.ascontiguousarray(ref)
    )


def from_channels(
    X: NDArray[np.float64],
    skeleton: Skeleton,
    layout: ChannelLayout,
    ref: NDArray[np.float64],
    at_rest: NDArray[np.bool_],
    fps: float,
    name: str = "",
) -> Motion:
    """The clip of channels ``X`` ``(T, C)``: the inverse of :func:`to_channels`."""
    rotations = channel_rotations(X, skeleton, layout, ref)
    translations = None
    if len(layout.translation_joints) and not np.all(at_rest):
        translations = np.repeat(skeleton.offsets[None], len(X), axis=0)
        for k, j in enumerate(layout.translation_joints):
            if not at_rest[k]:
                translations[:, j] = X[:, layout.translation_columns(k)]
    return Motion(skeleton, fps, X[:, :3].copy(), rotations, translations, name)


def measure_weights(
    motions: list[Motion],
    layout: ChannelLayout,
    ref: NDArray[np.float64],
    *,
    n_frames: int = 240,
    eps: float = 1e-4,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The metric weights ``w`` and lever arms ``lever`` of the ``C`` channels (module
    docstring), from about ``n_frames`` frames spread over ``motions``."""
    per_clip = max(1, n_frames // max(1, len(motions)))
    rows = []
    for m in motions:
        X, _ = to_channels(m, layout, ref)
        frames = np.unique(np.linspace(0, len(X) - 1, min(per_clip, len(X))).astype(int))
        rows.append(X[frames])
    X = np.concatenate(rows)
    sk = motions[0].skeleton
    moving = np.zeros(len(layout.translation_joints), dtype=bool)
    base = forward_kinematics(from_channels(X, sk, layout, ref, moving, 1.0)).all_positions()
    C = layout.n_channels
    w = np.empty(C)
    lever = np.empty(C)
    for c in range(C):
        Xp = X.copy()
        Xp[:, c] += eps
        moved = forward_kinematics(from_channels(Xp, sk, layout, ref, moving, 1.0)).all_positions()
        d = np.linalg.norm(moved - base, axis=2) / eps
        w[c] = np.mean(d * d)
        lever[c] = np.mean(d.max(axis=1))
    return w, lever


def joint_rotations(
    x: NDArray[np.float64],
    j: int,
    skeleton: Skeleton,
    layout: ChannelLayout,
    ref: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Local rotations ``(T, 4)`` of joint ``j`` from its channels ``x`` ``(T, counts[j])``."""
    kind = layout.kinds[j]
    T = len(x)
    if kind == KIND_FIXED:
        return quat.identity((T,))
    if kind == KIND_ROTVEC:
        return quat.multiply(ref[j], quat.exp(x / 2.0))
    if kind == KIND_ROOT:
        s = quat.multiply(ref[j], quat.exp(x[:, 1:4] / 2.0))
        return quat.multiply(quat.about_axis(x[:, 0], "y"), s)
    from quatmotion.io._text import compose_channels

    letters = "".join("xyz"[i] for i in _dof_axes(skeleton, j))
    c = skeleton.axes[j]
    m = compose_channels(x, letters, skeleton.euler == "intrinsic")
    return quat.multiply(quat.multiply(c, m), quat.conjugate(c))


def joint_channels(
    q: NDArray[np.float64],
    j: int,
    skeleton: Skeleton,
    layout: ChannelLayout,
    ref: NDArray[np.float64],
    near: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Channels ``(T, counts[j])`` of joint ``j`` with local rotations ``q`` ``(T, 4)``, each
    frame on the branch nearest ``near`` (the same rotation, angles shifted by whole turns)."""
    kind = layout.kinds[j]
    two_pi = 2.0 * np.pi
    if kind in (KIND_ROTVEC, KIND_ROOT):
        if kind == KIND_ROOT:
            heading, q = _heading_split(q)
            heading = heading + two_pi * np.round((near[:, 0] - heading) / two_pi)
            target = near[:, 1:4]
        else:
            target = near
        v = 2.0 * quat.log(quat.canonicalize(quat.multiply(quat.conjugate(ref[j]), q)))
        a = np.linalg.norm(v, axis=1, keepdims=True)
        twin = v * (1.0 - two_pi / np.maximum(a, 1e-12))
        pick = np.sum((twin - target) ** 2, axis=1) < np.sum((v - target) ** 2, axis=1)
        v = np.where(pick[:, None] & (a > 1e-12), twin, v)
        return np.column_stack((heading, v)) if kind == KIND_ROOT else v
    if kind == KIND_EULER:
        c = skeleton.axes[j]
        local = quat.multiply(quat.multiply(quat.conjugate(c), q), c)
        letters = "".join("xyz"[i] for i in _dof_axes(skeleton, j))
        a = decompose_channels(local, letters, skeleton.euler == "intrinsic")
        return a + two_pi * np.round((near - a) / two_pi)
    return np.zeros((len(q), 0))
