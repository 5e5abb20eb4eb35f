"""Length units of motion files and the one unit guess: the unit that makes a plausible human.

Conventions
-----------
* A length unit is a number of centimetres per file unit. :data:`LENGTH_UNITS` names those a
  file may be in; :func:`length_unit` takes a name or a number (``2.54``, ``"2.54"``).
* **The body** (:func:`find_body`): the head and the ankles of a skeleton, found by joint names
  (English and the usual rig prefixes, ``lfoot``, ``LeftFoot``, ``Foot_L``, ``Bip01 L Foot``,
  and German, French, Spanish, Italian, Japanese and Chinese words: those of
  :func:`quatmotion.motion.humanoid.body_part`, the one home of joint names), else by its
  shape: a body has two joints where two long limbs or more branch off (pelvis and chest), a
  spine apart; a lone hand has one (the wrist). A skeleton with neither a named head or leg
  nor that shape is not a body, and its size says nothing about its unit.
* **Its size** in file units (:func:`body_size`): the stature chain, the bone path from an ankle
  up to the top of the head, which no pose changes (a T-pose's arm span, a figure lying down,
  a rest pose laid out along an axis, a studio's position channels all leave it alone); bone
  lengths are the posed ones where joints carry position channels. A body whose head or ankles
  are not named is measured by its posed figure's largest extent (:func:`posed_extent`).
* **The guess** (:func:`guess_length_unit`): every unit of :data:`LENGTH_UNITS` reads that size
  as a stature; the guess is the unit whose stature lies in :data:`PLAUSIBLE_FIGURE_CM` and is
  nearest (in ratio) a typical adult's 170 cm; when none does, the one nearest the range. A
  skeleton that is not a body keeps centimetres (the commonest unit), marked as assumed.
"""

from __future__ import annotations

import copy
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from quatmotion.motion import Motion, Skeleton, forward_kinematics
from quatmotion.motion.humanoid import body_part

__all__ = [
    "LENGTH_UNITS",
    "LENGTH_UNIT_RANGE_CM",
    "PLAUSIBLE_FIGURE_CM",
    "TYPICAL_HEIGHT_CM",
    "Body",
    "body_size",
    "check_length_unit",
    "find_body",
    "guess_length_unit",
    "length_unit",
    "posed_extent",
    "rescaled",
    "unit_name",
]

LENGTH_UNITS: dict[str, float] = {
    "mm": 0.1,
    "cm": 1.0,
    "dm": 10.0,
    "m": 100.0,
    "in": 2.54,
    "asf": 2.54 / 0.45,
}
"""Length units a file may be in, by name: centimetres per file unit (``asf`` is the CMU/ASF
unit of 1/0.45 inch; MakeHuman's exporter writes decimetres)."""
TYPICAL_HEIGHT_CM = 170.0
PLAUSIBLE_FIGURE_CM = (50.0, 220.0)
"""A human figure's stature: an infant to a very tall adult. A figure outside is doubtful."""


def length_unit(unit: str | float) -> float:
    """Centimetres per file unit of a unit name of :data:`LENGTH_UNITS` or a positive number
    (a string of digits too: ``"2.54"``).

    Raises
    ------
    ValueError
        Naming the unit and the choices.
    """
    if isinstance(unit, str):
        name = unit.strip().lower()
        if name in LENGTH_UNITS:
            return LENGTH_UNITS[name]
        try:
            value = float(name)
        except ValueError:
            raise ValueError(
                f"unknown length unit {unit!r}; choose from {', '.join(LENGTH_UNITS)} or give "
                "centimetres per file unit (2.54 for inches)"
            ) from None
    else:
        value = float(unit)
    if not (np.isfinite(value) and value > 0):
        raise ValueError(f"a length unit is a positive number of cm per file unit, got {unit!r}")
    return check_length_unit(value)


LENGTH_UNIT_RANGE_CM = (1e-3, 1e5)
"""The centimetres per file unit a length unit may be, given or stated by a file: from ten
micrometres to a kilometre (:data:`LENGTH_UNITS` span a millimetre to a metre). Anything
beyond is a typing error or a hostile file, and would make every coordinate absurd."""


def check_length_unit(cm_per_unit: float) -> float:
    """``cm_per_unit`` if it lies in :data:`LENGTH_UNIT_RANGE_CM`; ``ValueError`` saying so
    otherwise."""
    low, high = LENGTH_UNIT_RANGE_CM
    if not low <= cm_per_unit <= high:
        raise ValueError(
            f"a unit of {cm_per_unit:g} cm is no length unit of motion capture "
            f"(from {low:g} to {high:g} cm)"
        )
    return cm_per_unit


def unit_name(cm_per_unit: float) -> str | None:
    """The name in :data:`LENGTH_UNITS` of a unit, or None."""
    return next(
        (n for n, v in LENGTH_UNITS.items() if abs(v - cm_per_unit) <= 1e-9 * v),
        None,
    )


# --------------------------------------------------------------------------------------------
# The body
# --------------------------------------------------------------------------------------------


class Body(NamedTuple):
    """Where a skeleton's head and ankles are: indices of points, joints then end sites (the
    order of :meth:`quatmotion.motion.Skeleton.rest_positions`)."""

    head: int | None
    """The top of the head (the farthest point from the root named for the head)."""
    ankles: tuple[int, ...]
    """The first point named for a foot along each leg (else the last named for a leg)."""


class _Tree(NamedTuple):
    parents: NDArray[np.int64]  # of every point, joints then sites
    lengths: NDArray[np.float64]  # bone from the parent to each point, file units
    depth: NDArray[np.float64]  # path length from the root


def _tree(skeleton: Skeleton, motion: Motion | None = None) -> _Tree:
    # Absurd but finite lengths (doubts of their own) may overflow here: inf says enough.
    with np.errstate(over="ignore", invalid="ignore"):
        return _tree_of(skeleton, motion)


def _tree_of(skeleton: Skeleton, motion: Motion | None) -> _Tree:
    offsets = np.asarray(skeleton.offsets, dtype=np.float64)
    lengths = np.linalg.norm(offsets, axis=1)
    if motion is not None and motion.joint_translations is not None and motion.n_frames:
        with np.errstate(over="ignore", invalid="ignore"):
            posed = np.linalg.norm(motion.joint_translations, axis=-1)
        lengths = np.median(posed, axis=0)
    lengths[0] = 0.0
    sites = np.linalg.norm(np.asarray(skeleton.site_offsets).reshape(-1, 3), axis=1)
    parents = np.concatenate((skeleton.parents, skeleton.site_parents))
    lengths = np.concatenate((lengths, sites))
    depth = np.zeros(len(parents))
    for p in range(1, len(parents)):  # joints come parents first, sites after every joint
        depth[p] = depth[parents[p]] + lengths[p]
    return _Tree(parents, lengths, depth)


def _names(skeleton: Skeleton) -> tuple[str, ...]:
    return skeleton.joint_names + skeleton.site_names


def find_body(skeleton: Skeleton) -> Body | None:
    """The head and ankles of ``skeleton``, or None when it is not a body.

    By names first (see the module docstring); a skeleton with none of those names is a body
    when its shape is one (two hubs of limbs a spine apart), and then ``Body(None, ())``: a
    body whose parts are not known. A lone hand, a prop or a tail is None.
    """
    names = _names(skeleton)
    parts = [body_part(n) for n in names]
    parents = np.concatenate((skeleton.parents, skeleton.site_parents))
    tree = _tree(skeleton)
    heads = [p for p, part in enumerate(parts) if part == "head"]
    head = max(heads, key=lambda p: tree.depth[p]) if heads else None
    ankles = tuple(
        p for p, part in enumerate(parts) if part == "foot" and parts[parents[p]] != "foot"
    )
    if not ankles:  # legs without a named foot: the last point named for a leg, each leg
        has_leg_child = {int(parents[p]) for p, part in enumerate(parts) if part == "leg"}
        ankles = tuple(
            p for p, part in enumerate(parts) if part == "leg" and p not in has_leg_child
        )
    if head is not None or ankles:
        return Body(head, ankles)
    joint_parts = parts[: skeleton.n_joints]
    if sum(part == "hand" for part in joint_parts) * 2 >= len(joint_parts):
        return None  # a hand (or two): its joints are named for one
    return Body(None, ()) if _shaped_like_a_body(tree) else None


def _shaped_like_a_body(tree: _Tree) -> bool:
    """Two points at which two limbs or more (each over a fifth of the tree's span) branch
    off, at least a tenth of the span apart: pelvis and chest. A hand has one, its wrist."""
    n = len(tree.parents)
    reach = np.zeros(n)  # longest path down from each point
    for p in range(n - 1, 0, -1):  # children after parents: walk back
        parent = tree.parents[p]
        reach[parent] = max(reach[parent], reach[p] + tree.lengths[p])
    limbs = [[] for _ in range(n)]
    for p in range(1, n):
        limbs[tree.parents[p]].append(reach[p] + tree.lengths[p])
    span = max((sum(sorted(ls)[-2:]) for ls in limbs if len(ls) >= 2), default=0.0)
    span = max(span, float(reach[0]))
    if not span > 0:
        return False
    hubs = [p for p in range(n) if sum(length >= 0.2 * span for length in limbs[p]) >= 2]
    for i, a in enumerate(hubs):
        for b in hubs[i + 1 :]:
            if _path_length(tree, a, b) >= 0.1 * span:
                return True
    return False


def _path_length(tree: _Tree, a: int, b: int) -> float:
    """Length of the bone path between points ``a`` and ``b``."""
    above = {a}
    p = a
    while p > 0:
        p = int(tree.parents[p])
        above.add(p)
    common = b
    while common not in above:
        common = int(tree.parents[common])
    return float(tree.depth[a] + tree.depth[b] - 2 * tree.depth[common])


def body_size(motion: Motion) -> float | None:
    """The figure's size in the skeleton's length (as stored: centimetres once read), or None
    when it is not a body (:func:`find_body`).

    The stature chain, the longest bone path from an ankle to the top of the head (posed bone
    lengths where joints carry position channels); the posed figure's largest extent
    (:func:`posed_extent`) when the head or the ankles are not known.
    """
    body = find_body(motion.skeleton)
    if body is None:
        return None
    if body.head is None or not body.ankles:
        return posed_extent(motion)
    tree = _tree(motion.skeleton, motion)
    return max(_path_length(tree, ankle, body.head) for ankle in body.ankles)


def posed_extent(motion: Motion, n_frames: int = 30) -> float:
    """The figure's size as posed: the median over frames of its largest extent.

    Unlike the rest pose's extent, this holds for skeletons whose rest pose is no pose at all
    (Bandai's lies along X, 4.5 m long). A root that stays put while position channels of
    other joints carry the body is a reference node, not part of the figure, and is left out
    (Bandai's stays on the floor at the origin while its Hips walk away). ``n_frames`` evenly
    spaced frames are measured; a clip of no frames is measured at rest.
    """
    if motion.n_frames == 0:
        rest = motion.skeleton.rest_positions()
        return float(np.max(np.ptp(rest, axis=0))) if len(rest) else 0.0
    clip = motion.slice(0, None, max(1, motion.n_frames // n_frames))
    with np.errstate(over="ignore", invalid="ignore"):
        points = forward_kinematics(clip).all_positions()
        carried = clip.joint_translations is not None and np.any(
            np.ptp(clip.joint_translations[:, 1:], axis=0) > 0
        )
        if carried and np.all(points[:, 0] == points[:1, 0]):
            points = points[:, 1:]
        return float(np.median(np.max(np.ptp(points, axis=1), axis=-1)))


def _typicality(stature_cm: float) -> tuple[float, float]:
    """Sort key of a stature: first how far (in ratio) outside the plausible range, then how
    far from a typical adult."""
    low, high = PLAUSIBLE_FIGURE_CM
    outside = max(np.log(low / stature_cm), np.log(stature_cm / high), 0.0)
    return float(outside), float(abs(np.log(stature_cm / TYPICAL_HEIGHT_CM)))


def guess_length_unit(size: float | None) -> float | None:
    """The unit of :data:`LENGTH_UNITS` that reads a body of ``size`` file units (from
    :func:`body_size` of the clip read in file units) as the most plausible stature; None
    when there is no body to weigh (``size`` None, zero or not finite)."""
    if size is None or not (np.isfinite(size) and size > 0):
        return None
    return min(LENGTH_UNITS.values(), key=lambda cm: _typicality(size * cm))


def rescaled(motion: Motion, cm_per_unit: float, extras: dict[str, object]) -> Motion:
    """``motion`` (read in file units) with every length multiplied by ``cm_per_unit`` and the
    skeleton's extras updated by ``extras``; the rotations are shared, not validated again.

    Raises
    ------
    ValueError
        If a length overflows once scaled.
    """
    sk = motion.skeleton
    with np.errstate(over="ignore", invalid="ignore"):
        skeleton = Skeleton(
            joint_names=sk.joint_names,
            parents=sk.parents,
            offsets=sk.offsets * cm_per_unit,
            channels=sk.channels,
            euler=sk.euler,
            axes=sk.axes,
            site_names=sk.site_names,
            site_parents=sk.site_parents,
            site_offsets=sk.site_offsets * cm_per_unit,
            name=sk.name,
            extras={**sk.extras, **extras},
        )
        root = motion.root_translation * cm_per_unit
        joints = None
        if motion.joint_translations is not None:
            joints = motion.joint_translations * cm_per_unit
    if not np.all(np.isfinite(root)) or (joints is not None and not np.all(np.isfinite(joints))):
        raise ValueError("translations overflow once in centimetres (values beyond 1e300)")
    out = copy.copy(motion)
    for name, value in (("skeleton", skeleton), ("root_translation", root)):
        object.__setattr__(out, name, value)
    object.__setattr__(out, "joint_translations", joints)
    for array in (root, joints):
        if array is not None:
            array.setflags(write=False)
    return out
