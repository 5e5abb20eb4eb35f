"""Which points of a clip are the body: the point the viewer follows and the bones it draws.

Conventions
-----------
* A skeleton's first joint is not always the body. bandai1's ``joint_Root`` stays at the floor
  origin while ``Hips`` travel (6 channels on every joint); other exporters put a reference
  joint on the floor under the pelvis, far from it, or one that only turns. Such a joint is
  **detached**: not followed, not drawn (no bone from it, no sphere on it), not framed. Its
  end sites are hidden with it. Positions and errors still cover every point (the payload
  keeps them), so nothing measured changes.
* **Detached joints.** For a skeleton the humanoid mapping reads (:mod:`quatmotion.pose.skeleton16`:
  by names or structure), the Hip's ancestors down to the deepest link above the Hip that is
  not a bone (by the rule below: a static ``joint_Root``, a root on the floor; a reference
  joint carried on the pelvis stays). For any other skeleton, the
  *root chain*: from joint 0, each step goes into the child whose subtree holds most points,
  as long as that subtree holds more than half of the skeleton's points (below that the body
  branches into its limbs). A link of the chain is *not a bone* when it is longer than
  :data:`LONG_BONE` of the body's size (the subtree below it: the median over frames of its
  bounding-box diagonal), or when its length changes over the clip by more than
  :data:`STRETCH` of that size (a bone keeps its length; a root left behind by travelling
  hips, or one the body circles, does not). Every joint of the chain down to the deepest
  link that is not a bone is detached (a static reference joint above another one included).
* **The body's centre** (the point the viewer follows and frames): the Hip of the 16-joint
  mapping, else the first joint of the body (the chain's first joint not detached), which
  carries the body's travel. If that joint stays behind while the body travels (a root with
  several children, none holding most of the points), the joint nearest the root of those that
  travel: at least half as far as the joint that travels most (which is a foot or a hand:
  the hips of a short walk travel a step less than its feet).
* Point indices are those of :func:`quatmotion.viz.frame_data.clip_points`: joints, then end
  sites. Positions in centimetres, Y up.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from quatmotion.motion import Skeleton
from quatmotion.pose.skeleton16 import joint_indices16

__all__ = ["LONG_BONE", "STRETCH", "BodyFraming", "body_framing", "skeleton_bones"]

LONG_BONE = 1 / 3
"""A root-chain "bone" longer than this share of the body's size is not a bone: a human's
longest (the femur) is about a quarter of the diagonal of its bounding box, and a root on the
floor under the pelvis about half."""
STRETCH = 0.1
"""A root-chain "bone" whose length varies by more than this share of the body's size over a
clip is not a bone (a bone of a figure keeps its length)."""
_MAX_SAMPLED_FRAMES = 512  # the decision needs the clip's spread, not every frame
_CHAIN_SHARE = 0.5  # the root chain goes on while one child's subtree holds more of the points
_TRAVELS = 0.25  # a clip whose joints span less than this share of the body's size stays put
_KEEPS_UP = 0.5  # a joint travels with the body if it spans this share of the most any does

CentreRule = Literal["hip16", "first body joint", "travelling"]


@dataclass(frozen=True)
class BodyFraming:
    """What of a clip the viewer shows as the body.

    Attributes
    ----------
    centre : int
        The point (a joint) the viewer follows and frames.
    rule : {"hip16", "first body joint", "travelling"}
        How ``centre`` was chosen (see the module docstring).
    detached : tuple of int
        Joints that are not the body, ascending.
    hidden : tuple of int
        Points not drawn: the detached joints and their end sites, ascending.
    bones : tuple of (int, int)
        The bones drawn, ``(parent point, child point)``: every bone whose parent is shown.
    """

    centre: int
    rule: CentreRule
    detached: tuple[int, ...]
    hidden: tuple[int, ...]
    bones: tuple[tuple[int, int], ...]


def body_framing(skeleton: Skeleton, positions: NDArray[np.floating]) -> BodyFraming:
    """The body of a clip of ``skeleton`` whose points are at ``positions``.

    Parameters
    ----------
    skeleton : Skeleton
        ``J`` joints, ``S`` end sites.
    positions : ndarray, shape (T, J + S, 3)
        Every point over the clip, cm (:func:`quatmotion.viz.frame_data.clip_points`).

    Returns
    -------
    BodyFraming
    """
    J, S = skeleton.n_joints, skeleton.n_sites
    points = np.asarray(positions, dtype=np.float64)
    if points.ndim != 3 or points.shape[1:] != (J + S, 3):
        raise ValueError(f"positions has shape {points.shape}, expected (T, {J + S}, 3)")
    sample = points[:: max(1, -(-points.shape[0] // _MAX_SAMPLED_FRAMES))]
    rule: CentreRule
    try:
        hip = int(joint_indices16(skeleton)[0])
    except ValueError:
        hip = None
    if hip is not None:
        detached = _detached_above(skeleton, sample, hip)
        centre, rule = hip, "hip16"
    else:
        detached, centre = _detached_root_chain(skeleton, sample)
        rule = "first body joint"
    shown_joints = np.ones(J, dtype=bool)
    shown_joints[list(detached)] = False
    shown = np.concatenate((shown_joints, shown_joints[skeleton.site_parents]))
    if hip is None and sample.shape[0]:
        travelling = _centre_if_left_behind(skeleton, sample, shown, centre)
        if travelling is not None:
            centre, rule = travelling, "travelling"
    return BodyFraming(
        centre=centre,
        rule=rule,
        detached=tuple(detached),
        hidden=tuple(int(p) for p in np.flatnonzero(~shown)),
        bones=tuple(b for b in skeleton_bones(skeleton) if shown[b[0]]),
    )


def skeleton_bones(skeleton: Skeleton) -> list[tuple[int, int]]:
    """Every bone of ``skeleton`` as ``(parent point, child point)``: one per non-root joint,
    then one per end site (point ``J + s``)."""
    J = skeleton.n_joints
    bones = [(int(skeleton.parents[j]), j) for j in range(1, J)]
    return bones + [(int(p), J + s) for s, p in enumerate(skeleton.site_parents)]


def _ancestors(skeleton: Skeleton, joint: int) -> list[int]:
    out = []
    parent = int(skeleton.parents[joint])
    while parent >= 0:
        out.append(parent)
        parent = int(skeleton.parents[parent])
    return sorted(out)


def _detached_above(skeleton: Skeleton, sample: NDArray[np.float64], hip: int) -> list[int]:
    """The Hip's ancestors that are not the body: every one down to the deepest link of the
    chain from the root to the Hip that is not a bone (:func:`_not_a_bone`); a reference joint
    carried on the pelvis is a bone of the body and stays."""
    path = [*_ancestors(skeleton, hip), hip]
    deepest = -1
    for k, (parent, child) in enumerate(zip(path[:-1], path[1:], strict=True)):
        body = _subtree_points(skeleton, child)
        if sample.shape[0] and _not_a_bone(sample, parent, child, body):
            deepest = k
    return path[: deepest + 1]


def _subtree_points(skeleton: Skeleton, joint: int) -> NDArray[np.bool_]:
    """Mask over points (joints, then sites) of ``joint`` and everything below it."""
    inside = np.zeros(skeleton.n_joints, dtype=bool)
    inside[joint] = True
    for k in range(joint + 1, skeleton.n_joints):  # parents come first
        inside[k] = inside[skeleton.parents[k]]
    return np.concatenate((inside, inside[skeleton.site_parents]))


def _size(points: NDArray[np.float64]) -> float:
    """The median over frames of the bounding-box diagonal of ``points`` ``(T, N, 3)``."""
    if points.shape[0] == 0 or points.shape[1] == 0:
        return 0.0
    return float(np.median(np.linalg.norm(points.max(axis=1) - points.min(axis=1), axis=-1)))


def _detached_root_chain(skeleton: Skeleton, sample: NDArray[np.float64]) -> tuple[list[int], int]:
    """Detached joints of the root chain and the first joint of the body."""
    total = skeleton.n_joints + skeleton.n_sites
    links: list[tuple[int, int, NDArray[np.bool_]]] = []
    joint = 0
    while True:
        children = skeleton.children(joint)
        if not children:
            break
        subtrees = [_subtree_points(skeleton, c) for c in children]
        best = int(np.argmax([m.sum() for m in subtrees]))
        if subtrees[best].sum() <= _CHAIN_SHARE * total:
            break
        links.append((joint, children[best], subtrees[best]))
        joint = children[best]
    deepest = -1
    for k, (parent, child, body) in enumerate(links):
        if sample.shape[0] and _not_a_bone(sample, parent, child, body):
            deepest = k
    if deepest < 0:
        return [], 0
    return [parent for parent, _, _ in links[: deepest + 1]], links[deepest][1]


def _not_a_bone(
    sample: NDArray[np.float64], parent: int, child: int, body: NDArray[np.bool_]
) -> bool:
    size = _size(sample[:, body])
    if size <= 0:
        return False
    length = np.linalg.norm(sample[:, child] - sample[:, parent], axis=-1)
    return bool(np.median(length) > LONG_BONE * size or np.ptp(length) > STRETCH * size)


def _travel(track: NDArray[np.float64]) -> NDArray[np.float64]:
    """Horizontal span of trajectories ``(T, ..., 3)``: the larger of their X and Z ranges."""
    return np.maximum(np.ptp(track[..., 0], axis=0), np.ptp(track[..., 2], axis=0))


def _centre_if_left_behind(
    skeleton: Skeleton, sample: NDArray[np.float64], shown: NDArray[np.bool_], centre: int
) -> int | None:
    """The travelling joint nearest the root when ``centre`` stays behind while the body
    travels; None otherwise."""
    joints = np.flatnonzero(shown[: skeleton.n_joints])
    travel = _travel(sample[:, joints])
    most = float(travel.max(initial=0.0))
    if most <= _TRAVELS * _size(sample[:, shown]) or _travel(sample[:, centre]) >= _KEEPS_UP * most:
        return None
    depth = np.zeros(skeleton.n_joints, dtype=np.int64)
    for j in range(1, skeleton.n_joints):
        depth[j] = depth[skeleton.parents[j]] + 1
    candidates = joints[travel >= _KEEPS_UP * most]
    return int(candidates[np.argmin(depth[candidates])])
