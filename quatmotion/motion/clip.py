"""A motion clip: a skeleton animated over frames."""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from quatmotion import quat
from quatmotion.motion.skeleton import Skeleton

_UNIT_TOLERANCE = 1e-3


@dataclass(frozen=True, eq=False)
class Motion:
    """An immutable clip.

    Parameters
    ----------
    skeleton : Skeleton
    fps : float
        Frames per second.
    root_translation : ndarray, shape (T, 3)
        Position of joint 0 in the world, centimetres, Y up.
    rotations : ndarray, shape (T, J, 4)
        Local joint rotations (``C M C^-1`` of each joint), unit quaternions, w first. Stored
        normalised and hemisphere-continuous over time (no jump between ``q`` and ``-q``).
    joint_translations : ndarray, shape (T, J, 3), optional
        Per-frame local translation of every joint, centimetres, for files whose joints carry
        position channels (BVH with 6 channels on every joint). ``None`` means each joint sits at
        its rest offset. Column 0 is ignored: ``root_translation`` places the root.
    name : str
        A label (file stem).
    """

    skeleton: Skeleton
    fps: float
    root_translation: NDArray[np.float64]
    rotations: NDArray[np.float64]
    joint_translations: NDArray[np.float64] | None = None
    name: str = field(default="")

    def __post_init__(self) -> None:
        J = self.skeleton.n_joints
        rot = np.asarray(self.rotations, dtype=np.float64)
        trans = np.asarray(self.root_translation, dtype=np.float64)
        if rot.ndim != 3 or rot.shape[1:] != (J, 4):
            raise ValueError(f"rotations has shape {rot.shape}, expected (T, {J}, 4)")
        T = rot.shape[0]
        if trans.shape != (T, 3):
            raise ValueError(f"root_translation has shape {trans.shape}, expected ({T}, 3)")
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ValueError(f"fps must be positive and finite, got {self.fps}")
        if not (np.all(np.isfinite(rot)) and np.all(np.isfinite(trans))):
            raise ValueError("rotations and root_translation must be finite")
        norms = np.linalg.norm(rot, axis=-1)
        if T and np.max(np.abs(norms - 1.0)) > _UNIT_TOLERANCE:
            raise ValueError("rotations must be unit quaternions")
        rot = quat.make_continuous(rot / norms[..., None], axis=0)
        jt = None
        if self.joint_translations is not None:
            jt = np.asarray(self.joint_translations, dtype=np.float64).copy()
            if jt.shape != (T, J, 3):
                raise ValueError(f"joint_translations has shape {jt.shape}, expected ({T}, {J}, 3)")
            if not np.all(np.isfinite(jt)):
                raise ValueError("joint_translations must be finite")
            jt.setflags(write=False)
        trans = trans.copy()
        for array in (rot, trans):
            array.setflags(write=False)
        object.__setattr__(self, "rotations", rot)
        object.__setattr__(self, "root_translation", trans)
        object.__setattr__(self, "joint_translations", jt)
        object.__setattr__(self, "fps", float(self.fps))

    def renamed(self, name: str) -> Motion:
        """The same clip (the same arrays, not validated again) under another name."""
        other = copy.copy(self)
        object.__setattr__(other, "name", name)
        return other

    @property
    def n_frames(self) -> int:
        return self.rotations.shape[0]

    @property
    def n_joints(self) -> int:
        return self.skeleton.n_joints

    @property
    def duration(self) -> float:
        """Length in seconds, ``n_frames / fps``."""
        return self.n_frames / self.fps

    def slice(
        self, start: int | None = None, stop: int | None = None, step: int | None = None
    ) -> Motion:
        """Frames ``start:stop:step`` as a new clip (fps divided by ``step``)."""
        s = slice(start, stop, step)
        jt = None if self.joint_translations is None else self.joint_translations[s]
        return Motion(
            skeleton=self.skeleton,
            fps=self.fps / (step or 1),
            root_translation=self.root_translation[s],
            rotations=self.rotations[s],
            joint_translations=jt,
            name=self.name,
        )

    def __repr__(self) -> str:
        return (
            f"Motion(name={self.name!r}, skeleton={self.skeleton.name!r}, frames={self.n_frames}, "
            f"fps={self.fps:g}, joints={self.n_joints})"
        )


def _heading(root_rotation: NDArray[np.float64]) -> float:
    """Yaw about +Y of one root rotation (w first): the angle of its twist about the vertical."""
    w, y = float(root_rotation[0]), float(root_rotation[2])
    return 2.0 * float(np.arctan2(y, w))


def join(motions: list[Motion] | tuple[Motion, ...], name: str = "") -> Motion:
    """One take made of ``motions`` one after the other, each turned about the vertical and
    moved on the floor so that it starts where the previous one stopped, facing the way it
    faced (its heading, the root rotation's twist about +Y); heights are kept.

    Parameters
    ----------
    motions : sequence of Motion
        At least one clip, all of one frame rate and of the same joints (names and parents);
        the take has the first clip's skeleton. Either every clip has joint translations or
        none has.
    name : str
        The take's name.

    Returns
    -------
    Motion
        ``sum(len)`` frames; clip ``k`` starts at frame ``sum(len[:k])``.

    Raises
    ------
    ValueError
        No clip, different frame rates or joints, joint translations on some clips only.
    """
    clips = list(motions)
    if not clips:
        raise ValueError("join needs at least one motion")
    first = clips[0]
    for c in clips[1:]:
        if c.fps != first.fps:
            raise ValueError(f"{c.name!r} runs at {c.fps:g} fps, {first.name!r} at {first.fps:g}")
        same = c.skeleton.joint_names == first.skeleton.joint_names and np.array_equal(
            c.skeleton.parents, first.skeleton.parents
        )
        if not same:
            raise ValueError(f"{c.name!r} and {first.name!r} have different joints")
    with_translations = [c.joint_translations is not None for c in clips]
    if any(with_translations) and not all(with_translations):
        raise ValueError("some clips have joint translations and others not")
    roots, rotations = [], []
    end_position, end_heading = None, None
    for c in clips:
        root = c.root_translation.copy()
        rot = c.rotations.copy()
        if end_position is not None and c.n_frames:
            turn = end_heading - _heading(rot[0, 0])
            spin = quat.about_axis(turn, "y")
            rot[:, 0] = quat.multiply(spin, rot[:, 0])
            offset = quat.rotate(spin, root - root[0])
            root = offset + np.array([end_position[0], root[0, 1], end_position[2]])
        if c.n_frames:
            end_position, end_heading = root[-1], _heading(rot[-1, 0])
        roots.append(root)
        rotations.append(rot)
    translations = (
        np.concatenate([c.joint_translations for c in clips]) if all(with_translations) else None
    )
    return Motion(
        skeleton=first.skeleton,
        fps=first.fps,
        root_translation=np.concatenate(roots),
        rotations=quat.make_continuous(np.concatenate(rotations), axis=0),
        joint_translations=translations,
        name=name,
    )
