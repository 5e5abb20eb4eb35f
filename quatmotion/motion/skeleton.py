"""The skeleton: joint hierarchy, rest offsets and rotation channels.

Conventions
-----------
* Joints are listed parents first: ``parents[j] < j`` for every ``j > 0`` and ``parents[0] == -1``.
* ``offsets[j]`` is joint ``j``'s position relative to its parent joint, in the parent's frame
  at rest, in **centimetres**. A joint rotates its children: in forward kinematics
  ``position[j] = position[parent] + R_global[parent] @ offsets[j]`` (the BVH convention).
  An ASF bone becomes the joint at the bone's start; the bone's end is where its children (or
  its end site) sit.
* End sites are points without rotation (BVH ``End Site``, the tip of an ASF leaf bone):
  ``site_parents[s]`` is the joint they hang from, ``site_offsets[s]`` their offset in that
  joint's frame, in centimetres.
* ``channels[j]`` lists joint ``j``'s animated channels in file order, as tokens ``tx ty tz``
  (translation) and ``rx ry rz`` (rotation). ``euler`` says how the rotation channels compose:
  ``"intrinsic"`` (BVH: ``R = R_c0 @ R_c1 @ R_c2``) or ``"extrinsic"`` (ASF/AMC: the first listed
  channel is applied first, ``R = R_c2 @ R_c1 @ R_c0``).
* ``axes[j]`` is a fixed pre-rotation ``C`` (the ASF ``axis``; the identity for BVH): the joint's
  local rotation is ``C @ M @ C^-1`` with ``M`` the rotation of its channels.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from types import MappingProxyType
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from quatmotion import quat

TRANSLATION_CHANNELS = ("tx", "ty", "tz")
ROTATION_CHANNELS = ("rx", "ry", "rz")


@dataclass(frozen=True, eq=False)
class Skeleton:
    """An immutable joint hierarchy with rest offsets in centimetres.

    Parameters
    ----------
    joint_names : tuple of str, length J
    parents : ndarray of int, shape (J,)
        Parent index of each joint, ``-1`` for the root; parents come before children.
    offsets : ndarray of float, shape (J, 3)
        Rest offset of each joint from its parent, in the parent's frame, centimetres.
    channels : tuple of tuple of str, length J
        Each joint's animated channels in file order (``tx ty tz rx ry rz`` tokens).
    euler : {"intrinsic", "extrinsic"}
        How a joint's rotation channels compose (see the module docstring).
    axes : ndarray of float, shape (J, 4)
        Pre-rotation ``C`` of each joint as a unit quaternion (w first); identity if absent.
    site_names, site_parents, site_offsets : tuple of str (S,), ndarray (S,), ndarray (S, 3)
        End sites: points carried by a joint, offsets in centimetres.
    name : str
        A label for messages (file stem, actor).
    extras : mapping
        Format details a writer needs to reproduce its file (ASF units, bone ids, limits...).
    """

    joint_names: tuple[str, ...]
    parents: NDArray[np.int64]
    offsets: NDArray[np.float64]
    channels: tuple[tuple[str, ...], ...]
    euler: Literal["intrinsic", "extrinsic"] = "intrinsic"
    axes: NDArray[np.float64] | None = None
    site_names: tuple[str, ...] = ()
    site_parents: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    site_offsets: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))
    name: str = ""
    extras: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.joint_names)
        parents = np.asarray(self.parents, dtype=np.int64).copy()
        offsets = np.asarray(self.offsets, dtype=np.float64).copy()
        if n == 0:
            raise ValueError("a skeleton needs at least one joint")
        if parents.shape != (n,):
            raise ValueError(f"parents has shape {parents.shape}, expected ({n},)")
        if offsets.shape != (n, 3):
            raise ValueError(f"offsets has shape {offsets.shape}, expected ({n}, 3)")
        if parents[0] != -1 or np.any(parents[1:] < 0) or np.any(parents[1:] >= np.arange(1, n)):
            raise ValueError(
                "parents must be -1 for joint 0 and point to an earlier joint otherwise"
            )
        if len(set(self.joint_names)) != n:
            raise ValueError("joint names must be unique")
        if len(self.channels) != n:
            raise ValueError(f"channels lists {len(self.channels)} joints, expected {n}")
        for name, chans in zip(self.joint_names, self.channels, strict=True):
            unknown = set(chans) - set(TRANSLATION_CHANNELS + ROTATION_CHANNELS)
            if unknown or len(set(chans)) != len(chans):
                raise ValueError(f"joint {name!r} has bad channels {chans}")
        if self.euler not in ("intrinsic", "extrinsic"):
            raise ValueError(f"euler must be 'intrinsic' or 'extrinsic', got {self.euler!r}")
        axes = (
            quat.identity((n,))
            if self.axes is None
            else quat.normalize(np.asarray(self.axes, dtype=np.float64))
        )
        if axes.shape != (n, 4):
            raise ValueError(f"axes has shape {axes.shape}, expected ({n}, 4)")
        site_parents = np.asarray(self.site_parents, dtype=np.int64).copy()
        site_offsets = np.asarray(self.site_offsets, dtype=np.float64).reshape(-1, 3).copy()
        if site_parents.shape != (len(self.site_names),) or site_offsets.shape[0] != len(
            self.site_names
        ):
            raise ValueError("site_names, site_parents and site_offsets disagree in length")
        if np.any((site_parents < 0) | (site_parents >= n)):
            raise ValueError("site_parents must index joints")
        if not (np.all(np.isfinite(offsets)) and np.all(np.isfinite(site_offsets))):
            raise ValueError("offsets must be finite")
        for array in (parents, offsets, axes, site_parents, site_offsets):
            array.setflags(write=False)
        object.__setattr__(self, "joint_names", tuple(self.joint_names))
        object.__setattr__(self, "parents", parents)
        object.__setattr__(self, "offsets", offsets)
        object.__setattr__(self, "axes", axes)
        object.__setattr__(self, "site_names", tuple(self.site_names))
        object.__setattr__(self, "site_parents", site_parents)
        object.__setattr__(self, "site_offsets", site_offsets)
        object.__setattr__(self, "channels", tuple(tuple(c) for c in self.channels))
        object.__setattr__(self, "extras", MappingProxyType(dict(self.extras)))

    def __reduce__(self) -> tuple[Any, tuple[dict[str, Any]]]:
        # The read-only extras (a mappingproxy) do not pickle: rebuild through the constructor,
        # which validates again, so a skeleton can be sent to batch workers.
        values = {f.name: getattr(self, f.name) for f in fields(self) if f.init}
        values["extras"] = dict(self.extras)
        return _rebuild_skeleton, (values,)

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    @property
    def n_sites(self) -> int:
        return len(self.site_names)

    def index(self, name: str) -> int:
        """Index of the joint called ``name``; ``KeyError`` naming the skeleton if absent."""
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise KeyError(f"skeleton {self.name!r} has no joint {name!r}") from None

    def children(self, j: int) -> list[int]:
        """Indices of joint ``j``'s children."""
        return [int(c) for c in np.flatnonzero(self.parents == j)]

    def rest_positions(self, include_sites: bool = True) -> NDArray[np.float64]:
        """Joint (then end-site) positions at rest, root at ``offsets[0]``: ``(J [+ S], 3)`` cm."""
        pos = np.zeros((self.n_joints, 3))
        pos[0] = self.offsets[0]
        for j in range(1, self.n_joints):
            pos[j] = pos[self.parents[j]] + self.offsets[j]
        if include_sites and self.n_sites:
            pos = np.concatenate((pos, pos[self.site_parents] + self.site_offsets))
        return pos

    def height(self) -> float:
        """Standing height at rest in centimetres: vertical (Y) extent of joints and end sites."""
        y = self.rest_positions()[:, 1]
        return float(y.max() - y.min())

    def rotating_joints(self) -> NDArray[np.int64]:
        """Indices of the root and of every joint with rotation channels, in joint order."""
        turns = [j for j in range(self.n_joints) if j == 0 or self.rotation_dofs(j)]
        return np.asarray(turns, dtype=np.int64)

    def rotation_dofs(self, j: int) -> tuple[str, ...]:
        """Joint ``j``'s rotation channels in file order (subset of ``rx ry rz``)."""
        return tuple(c for c in self.channels[j] if c in ROTATION_CHANNELS)

    def fingerprint(self) -> str:
        """A 16-hex-digit digest of everything the skeleton holds (names, hierarchy, offsets
        and axes bit for bit, channels, end sites, name, extras): equal skeletons give equal
        fingerprints in every process and release, so files store it and tables key on it."""
        h = hashlib.sha256(b"quatmotion-skeleton-1\0")
        for f in fields(self):
            h.update(f.name.encode() + b"=")
            _digest(h, getattr(self, f.name))
        return h.hexdigest()[:16]

    def __repr__(self) -> str:
        return f"Skeleton(name={self.name!r}, joints={self.n_joints}, sites={self.n_sites})"


def _digest(h: Any, value: Any) -> None:
    """Feed ``value`` to the hash ``h`` unambiguously (type, shape and length prefixes)."""
    if isinstance(value, np.ndarray):
        a = np.ascontiguousarray(value)
        if a.dtype.kind == "f":
            a = a + 0.0  # -0.0 and 0.0 are one value
        h.update(f"a{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    elif isinstance(value, Mapping):
        h.update(f"d{len(value)}".encode())
        for key in sorted(value, key=str):
            _digest(h, str(key))
            _digest(h, value[key])
    elif isinstance(value, list | tuple):
        h.update(f"l{len(value)}".encode())
        for item in value:
            _digest(h, item)
    else:
        text = repr(value).encode()
        h.update(f"{type(value).__name__}{len(text)}:".encode() + text)


def _rebuild_skeleton(values: dict[str, Any]) -> Skeleton:
    """Unpickle a :class:`Skeleton` (see ``Skeleton.__reduce__``)."""
    return Skeleton(**values)
