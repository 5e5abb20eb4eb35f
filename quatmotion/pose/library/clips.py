"""A clip as a pose library takes it: read and prepared (:func:`load_pose_source`,
:func:`load_pose_clip`), its poses projected into the index space (:func:`project_gpd`,
:func:`projected_clip`): the per-clip jobs batch workers run, at module level (picklable).

Clips are prepared by :meth:`PoseClip.from_motion` (resampled, put on the canonical body of
one stature), so that they are described alike whatever their skeleton. Features are clipped to
the library's range after the min-max step: a query from another body or motion may exceed the
range in a few features (nearly constant ones, such as the spread of a rigid pelvis), and
unclipped they would dominate its unit-length vector, so that every such query lands on the
same few poses.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quatmotion.collection import ClipSource, ReadSettings, read_clip, with_joint_map
from quatmotion.io import Doubt
from quatmotion.pose.data import PoseClip
from quatmotion.pose.library.transitions import transition_judge
from quatmotion.pose.methods import pose_features, project_features

__all__ = [
    "ProjectedClip",
    "load_pose_clip",
    "load_pose_source",
    "project_gpd",
    "projected_clip",
]

FloatArray = NDArray[np.float64]


def project_gpd(raw_gpd: ArrayLike, model: dict[str, FloatArray]) -> FloatArray:
    """Raw feature rows (the GPD, or :func:`~quatmotion.pose.methods.pose_features` of the
    library's metric) mapped to a library's index space:
    ``unit(clip(scale * x + offset, 0, 1)) @ W``.

    Parameters
    ----------
    raw_gpd : array_like, shape (N, D)
    model : dict
        ``scale`` and ``offset`` of shape (D,), ``W`` of shape (D, r).

    Returns
    -------
    ndarray, shape (N, r)
    """
    # Clipped to the library's range (see the module's conventions), as the method learned it.
    return project_features(raw_gpd, {**model, "clip": True})


@dataclass(frozen=True)
class ProjectedClip:
    """A clip as the index pass of :meth:`PoseLibrary.build_streamed` needs it.

    Attributes
    ----------
    name : str
    fps : float
        Frame rate after resampling.
    step : int
        File frames per kept frame.
    height : float or None
        Stature of the canonical body, centimetres.
    file_frames : int or None
        Frames of the clip's file, before resampling.
    skeleton_kind : str or None
        The skeleton family it came from.
    vectors : ndarray of float32, shape (T, r)
        Every pose projected into the index space.
    doubts : tuple of Doubt
        :attr:`PoseClip.doubts`.
    """

    name: str
    fps: float
    step: int
    height: float | None
    file_frames: int | None
    skeleton_kind: str | None
    vectors: NDArray[np.float32]
    doubts: tuple[Doubt, ...] = ()
    rows: NDArray[np.float32] | None = None


def projected_clip(
    source: Any, *, load: Callable[[Any], PoseClip], model: dict, metric: str = "GPD+LOGIT"
) -> ProjectedClip:
    """Load one clip and project its poses' ``metric`` features (the per-clip job run by batch
    workers)."""
    clip = load(source)
    vectors = project_gpd(pose_features(clip.poses, metric), model).astype(np.float32)
    judge = transition_judge(model)
    rows = None if judge is None else judge.describe(clip.poses).astype(np.float32)
    return ProjectedClip(
        clip.name, clip.fps, clip.step, clip.height, clip.file_frames, clip.skeleton_kind,
        vectors, clip.doubts, rows,
    )  # fmt: skip


def load_pose_source(
    source: ClipSource, *, fps: float, height: float, read: ReadSettings
) -> PoseClip:
    """Read one clip of a collection (:func:`quatmotion.collection.read_clip`) and prepare it
    for a pose library (the per-clip job of :meth:`PoseLibrary.build`: module level).

    The clip is named by its file's path (its name for a clip made in memory; for one take of
    a file of several, the path without its suffix, then the take's short name: matched by
    ``walk/run`` as the collection names it); a clip beyond a kilometre is refused
    (``read.strict``: its features would overflow).
    """
    motion, _, doubts = read_clip(source, dataclasses.replace(read, strict=True))
    name = str(source.path) if source.path is not None else source.name
    if source.path is not None and source.take is not None:
        name = f"{source.path.with_suffix('')}/{pathlib.PurePosixPath(source.name).name}"
    with np.errstate(all="ignore"):
        clip = PoseClip.from_motion(motion, fps=fps, height=height, name=name)
    return dataclasses.replace(clip, doubts=tuple(doubts))


def load_pose_clip(
    path: str | os.PathLike[str],
    *,
    fps: float,
    height: float,
    skeleton: str | os.PathLike[str] | None = None,
    units: str | None = None,
    joint_map: Sequence[str] = (),
) -> PoseClip:
    """Read a motion file and prepare it for a pose library (a batch job: module level).

    Parameters
    ----------
    path : str or Path
        An ``.amc`` (its ASF found by :func:`quatmotion.io.read_amc`'s rules, else
        ``skeleton``) or ``.bvh``.
    fps, height : float
        As for :meth:`PoseClip.from_motion`.
    skeleton : str or Path, optional
        The ASF of AMC files (else each one's is found by name).
    units : str, optional
        Length unit of a BVH file (:data:`quatmotion.io.BVH_UNITS`); guessed when None.
    joint_map : sequence of str
        A user's humanoid map, ``"Canonical=joint"`` entries
        (:attr:`quatmotion.collection.ReadSettings.joint_map`).

    Returns
    -------
    PoseClip
        Named by ``str(path)``, with the file's unit and frame-rate doubts
        (:attr:`PoseClip.doubts`).

    Raises
    ------
    ValueError
        For a clip with coordinates beyond a kilometre: not human motion capture, and its
        features would overflow.
    """
    from quatmotion.io import implausible_values, read_motion

    path = pathlib.Path(path)
    amc = path.suffix.lower() == ".amc"
    motion = read_motion(path, skeleton if amc else None, units=None if amc else units)
    if joint_map:
        motion = with_joint_map(motion, joint_map)
    doubts = implausible_values(motion)
    for doubt in doubts:
        if doubt.kind == "far":
            raise ValueError(f"{path}: {doubt.message}: not human motion capture")
    # A clip that cannot be described fails with a message, not NumPy's overflow warnings.
    with np.errstate(all="ignore"):
        clip = PoseClip.from_motion(motion, fps=fps, height=height, name=str(path))
    return dataclasses.replace(clip, doubts=tuple(doubts))
