"""Re-rigging: the same motion on another studio's skeleton (names, helpers, order, mirror).

What the humanoid mapping (:mod:`quatmotion.motion.humanoid`) is tested and benchmarked
against: a clip of a shared skeleton (CMU or HDM05 ASF, CMU BVH, Bandai BVH) renamed to a
naming family of :data:`FAMILIES` (Mixamo, Unreal, 3ds Max Biped, HumanIK, Rigify, SMPL,
Kinect, MakeHuman, keypoint rigs, Character Creator), with twist or roll joints inserted
(leaves, or inline segments where the family splits its bones), toes and fingers dropped,
children listed in another order (right before left, the spine first), or mirrored left for
right. Every joint the source has keeps its world position at every frame (inserted joints
carry no rotation); :func:`rerig` returns the new clip and the renaming, source joint -> new
joint, so a test can check a mapping joint for joint.

Run as ``python -m quatmotion.synthetic.rerig IN.bvh OUT.bvh FAMILY`` to write one (for the
FBX exporter's inputs, by hand).
"""

from __future__ import annotations

import sys
from typing import NamedTuple

import numpy as np

from quatmotion.motion.clip import Motion
from quatmotion.motion.skeleton import Skeleton

__all__ = ["FAMILIES", "SOURCE_ROLES", "Rerigged", "rerig", "source_family"]

# The role of every joint of the shared skeletons: (role, side).
_ASF = {
    "root": "pelvis", "lowerback": "spine0", "upperback": "spine1", "thorax": "spine2",
    "lowerneck": "neck", "upperneck": "neck2", "head": "head", "clavicle": "clavicle",
    "humerus": "upperarm", "radius": "forearm", "wrist": "hand", "hand": "handend",
    "fingers": "fingers", "thumb": "thumb", "hipjoint": "hipjoint", "femur": "thigh",
    "tibia": "shin", "foot": "foot", "toes": "toe",
}  # fmt: skip
_CMU_BVH = {
    "Hips": "pelvis", "LowerBack": "spine0", "Spine": "spine1", "Spine1": "spine2",
    "Neck": "neck", "Neck1": "neck2", "Head": "head", "Shoulder": "clavicle", "Arm": "upperarm",
    "ForeArm": "forearm", "Hand": "hand", "FingerBase": "handend", "HandIndex1": "fingers",
    "Thumb": "thumb", "HipJoint": "hipjoint", "UpLeg": "thigh", "Leg": "shin", "Foot": "foot",
    "ToeBase": "toe",
}  # fmt: skip
_BANDAI = {
    "joint_Root": "root", "Hips": "pelvis", "Spine": "spine1", "Chest": "spine2", "Neck": "neck",
    "Head": "head", "Shoulder": "clavicle", "UpperArm": "upperarm", "LowerArm": "forearm",
    "Hand": "hand", "UpperLeg": "thigh", "LowerLeg": "shin", "Foot": "foot", "Toes": "toe",
}  # fmt: skip
SOURCE_ROLES: dict[str, dict[str, str]] = {"asf": _ASF, "cmu_bvh": _CMU_BVH, "bandai": _BANDAI}
"""Roles of the joints of each shared skeleton family, by the name without its side."""

_CENTRE = ("root", "pelvis", "spine0", "spine1", "spine2", "neck", "neck2", "head")
_LIMB = (
    "clavicle", "upperarm", "forearm", "hand", "handend", "fingers", "thumb",
    "hipjoint", "thigh", "shin", "foot", "toe",
)  # fmt: skip
_DROPPED = ("toe", "handend", "fingers", "thumb")


class _Family(NamedTuple):
    names: dict[str, str]  # role -> name, "{S}" the side word, "{s}" the side letter
    sides: tuple[str, str]  # how the family writes left and right
    twist: dict[str, str]  # role -> the name of the twist joint it gets
    inline: bool  # twist joints split the bone (else leaves)


FAMILIES: dict[str, _Family] = {
    "mixamo": _Family(
        {"root": "mixamorig:Reference", "pelvis": "mixamorig:Hips", "spine0": "mixamorig:Spine",
         "spine1": "mixamorig:Spine1", "spine2": "mixamorig:Spine2", "neck": "mixamorig:Neck",
         "neck2": "mixamorig:Neck1", "head": "mixamorig:Head",
         "clavicle": "mixamorig:{S}Shoulder", "upperarm": "mixamorig:{S}Arm",
         "forearm": "mixamorig:{S}ForeArm", "hand": "mixamorig:{S}Hand",
         "handend": "mixamorig:{S}HandMiddle1", "fingers": "mixamorig:{S}HandIndex1",
         "thumb": "mixamorig:{S}HandThumb1", "hipjoint": "mixamorig:{S}HipHelper",
         "thigh": "mixamorig:{S}UpLeg", "shin": "mixamorig:{S}Leg", "foot": "mixamorig:{S}Foot",
         "toe": "mixamorig:{S}ToeBase"},
        ("Left", "Right"), {}, False),
    "unreal": _Family(
        {"root": "root", "pelvis": "pelvis", "spine0": "spine_01", "spine1": "spine_02",
         "spine2": "spine_03", "neck": "neck_01", "neck2": "neck_02", "head": "head",
         "clavicle": "clavicle_{s}", "upperarm": "upperarm_{s}", "forearm": "lowerarm_{s}",
         "hand": "hand_{s}", "handend": "middle_01_{s}", "fingers": "index_01_{s}",
         "thumb": "thumb_01_{s}", "hipjoint": "pelvis_helper_{s}", "thigh": "thigh_{s}",
         "shin": "calf_{s}", "foot": "foot_{s}", "toe": "ball_{s}"},
        ("l", "r"),
        {"upperarm": "upperarm_twist_01_{s}", "forearm": "lowerarm_twist_01_{s}",
         "thigh": "thigh_twist_01_{s}", "shin": "calf_twist_01_{s}"}, False),
    "biped": _Family(
        {"root": "Bip01", "pelvis": "Bip01 Pelvis", "spine0": "Bip01 Spine",
         "spine1": "Bip01 Spine1", "spine2": "Bip01 Spine2", "neck": "Bip01 Neck",
         "neck2": "Bip01 Neck1", "head": "Bip01 Head", "clavicle": "Bip01 {S} Clavicle",
         "upperarm": "Bip01 {S} UpperArm", "forearm": "Bip01 {S} Forearm",
         "hand": "Bip01 {S} Hand", "handend": "Bip01 {S} Finger2", "fingers": "Bip01 {S} Finger1",
         "thumb": "Bip01 {S} Finger0", "hipjoint": "Bip01 {S} HipBone",
         "thigh": "Bip01 {S} Thigh", "shin": "Bip01 {S} Calf", "foot": "Bip01 {S} Foot",
         "toe": "Bip01 {S} Toe0"},
        ("L", "R"),
        {"upperarm": "Bip01 {S} UpArmTwist", "forearm": "Bip01 {S} ForeTwist",
         "thigh": "Bip01 {S} ThighTwist", "shin": "Bip01 {S} CalfTwist"}, False),
    "humanik": _Family(
        {"root": "Reference", "pelvis": "Hips", "spine0": "Spine", "spine1": "Spine1",
         "spine2": "Spine2", "neck": "Neck", "neck2": "Neck1", "head": "Head",
         "clavicle": "{S}Shoulder", "upperarm": "{S}Arm", "forearm": "{S}ForeArm",
         "hand": "{S}Hand", "handend": "{S}HandMiddle1", "fingers": "{S}HandIndex1",
         "thumb": "{S}HandThumb1", "hipjoint": "{S}UpLegHelper", "thigh": "{S}UpLeg",
         "shin": "{S}Leg", "foot": "{S}Foot", "toe": "{S}ToeBase"},
        ("Left", "Right"),
        {"upperarm": "{S}ArmRoll", "forearm": "{S}ForeArmRoll", "thigh": "{S}UpLegRoll",
         "shin": "{S}LegRoll"}, True),
    "rigify": _Family(
        {"root": "root", "pelvis": "DEF-spine", "spine0": "DEF-spine.001",
         "spine1": "DEF-spine.002", "spine2": "DEF-spine.003", "neck": "DEF-spine.004",
         "neck2": "DEF-spine.005", "head": "DEF-spine.006", "clavicle": "DEF-shoulder.{s}",
         "upperarm": "DEF-upper_arm.{s}", "forearm": "DEF-forearm.{s}", "hand": "DEF-hand.{s}",
         "handend": "DEF-f_middle.01.{s}", "fingers": "DEF-f_index.01.{s}",
         "thumb": "DEF-thumb.01.{s}", "hipjoint": "DEF-pelvis.{s}", "thigh": "DEF-thigh.{s}",
         "shin": "DEF-shin.{s}", "foot": "DEF-foot.{s}", "toe": "DEF-toe.{s}"},
        ("L", "R"),
        {"upperarm": "DEF-upper_arm.{s}.001", "forearm": "DEF-forearm.{s}.001",
         "thigh": "DEF-thigh.{s}.001", "shin": "DEF-shin.{s}.001"}, True),
    "smpl": _Family(
        {"root": "root", "pelvis": "Pelvis", "spine0": "Spine1", "spine1": "Spine2",
         "spine2": "Spine3", "neck": "Neck", "neck2": "Neck2", "head": "Head",
         "clavicle": "{s}_Collar", "upperarm": "{s}_Shoulder", "forearm": "{s}_Elbow",
         "hand": "{s}_Wrist", "handend": "{s}_Hand", "fingers": "{s}_Index1",
         "thumb": "{s}_Thumb1", "hipjoint": "{s}_HipJoint", "thigh": "{s}_Hip",
         "shin": "{s}_Knee", "foot": "{s}_Ankle", "toe": "{s}_Foot"},
        ("L", "R"), {}, False),
    "kinect": _Family(
        {"root": "Root", "pelvis": "SpineBase", "spine0": "SpineLow", "spine1": "SpineMid",
         "spine2": "SpineShoulder", "neck": "Neck", "neck2": "Neck2", "head": "Head",
         "clavicle": "Collar{S}", "upperarm": "Shoulder{S}", "forearm": "Elbow{S}",
         "hand": "Wrist{S}", "handend": "Hand{S}", "fingers": "HandTip{S}",
         "thumb": "Thumb{S}", "hipjoint": "HipJoint{S}", "thigh": "Hip{S}", "shin": "Knee{S}",
         "foot": "Ankle{S}", "toe": "Foot{S}"},
        ("Left", "Right"), {}, False),
    "makehuman": _Family(
        {"root": "Armature", "pelvis": "root", "spine0": "spine05", "spine1": "spine04",
         "spine2": "spine03", "neck": "neck01", "neck2": "neck02", "head": "head",
         "clavicle": "clavicle.{s}", "upperarm": "upperarm01.{s}", "forearm": "lowerarm01.{s}",
         "hand": "wrist.{s}", "handend": "metacarpal2.{s}", "fingers": "finger2-1.{s}",
         "thumb": "finger1-1.{s}", "hipjoint": "pelvis.{s}", "thigh": "upperleg01.{s}",
         "shin": "lowerleg01.{s}", "foot": "foot.{s}", "toe": "toe1-1.{s}"},
        ("L", "R"),
        {"upperarm": "upperarm02.{s}", "forearm": "lowerarm02.{s}", "thigh": "upperleg02.{s}",
         "shin": "lowerleg02.{s}"}, True),
    "keypoints": _Family(
        {"root": "World", "pelvis": "Hip", "spine0": "Spine", "spine1": "Spine1",
         "spine2": "Thorax", "neck": "Neck", "neck2": "Neck2", "head": "Head",
         "clavicle": "{s}Collar", "upperarm": "{s}Shoulder", "forearm": "{s}Elbow",
         "hand": "{s}Wrist", "handend": "{s}HandEnd", "fingers": "{s}Fingers",
         "thumb": "{s}ThumbTip", "hipjoint": "{s}Pelvis", "thigh": "{s}Hip", "shin": "{s}Knee",
         "foot": "{s}Foot", "toe": "{s}Toe"},
        ("L", "R"), {}, False),
    "cc": _Family(
        {"root": "CC_Base_BoneRoot", "pelvis": "CC_Base_Pelvis", "spine0": "CC_Base_Waist",
         "spine1": "CC_Base_Spine01", "spine2": "CC_Base_Spine02",
         "neck": "CC_Base_NeckTwist01", "neck2": "CC_Base_NeckTwist02", "head": "CC_Base_Head",
         "clavicle": "CC_Base_{s}_Clavicle", "upperarm": "CC_Base_{s}_Upperarm",
         "forearm": "CC_Base_{s}_Forearm", "hand": "CC_Base_{s}_Hand",
         "handend": "CC_Base_{s}_Mid1", "fingers": "CC_Base_{s}_Index1",
         "thumb": "CC_Base_{s}_Thumb1", "hipjoint": "CC_Base_{s}_Hip0",
         "thigh": "CC_Base_{s}_Thigh", "shin": "CC_Base_{s}_Calf", "foot": "CC_Base_{s}_Foot",
         "toe": "CC_Base_{s}_ToeBase"},
        ("L", "R"),
        {"upperarm": "CC_Base_{s}_UpperarmTwist01", "forearm": "CC_Base_{s}_ForearmTwist01",
         "thigh": "CC_Base_{s}_ThighTwist01", "shin": "CC_Base_{s}_CalfTwist01"}, False),
}  # fmt: skip
"""The naming families a clip can be re-rigged to."""


class Rerigged(NamedTuple):
    """What :func:`rerig` gives: the new clip and the renaming (source joint -> new joint)."""

    motion: Motion
    renamed: dict[str, str]


def source_family(skeleton: Skeleton) -> str:
    """Which shared family (:data:`SOURCE_ROLES`) ``skeleton`` is, by its names."""
    names = set(skeleton.joint_names)
    if "lfemur" in names:
        return "asf"
    if "LeftUpLeg" in names:
        return "cmu_bvh"
    if "UpperLeg_L" in names:
        return "bandai"
    raise ValueError(f"skeleton {skeleton.name!r} is none of the shared families")


def _role(family: str, name: str) -> tuple[str, str | None]:
    roles = SOURCE_ROLES[family]
    if name in roles:
        return roles[name], None
    for prefix, side in (("Left", "L"), ("Right", "R"), ("l", "L"), ("r", "R"), ("L", "L"),
                         ("R", "R")):  # fmt: skip
        if name.startswith(prefix) and name[len(prefix) :] in roles:
            return roles[name[len(prefix) :]], side
    for suffix, side in (("_L", "L"), ("_R", "R")):
        if name.endswith(suffix) and name[: -len(suffix)] in roles:
            return roles[name[: -len(suffix)]], side
    raise ValueError(f"joint {name!r} of a {family} skeleton has no role")


def rerig(
    motion: Motion,
    family: str,
    *,
    twist: bool = True,
    drop_extremities: bool = True,
    reorder: bool = True,
    mirror: bool = False,
    strip_names: bool = False,
) -> Rerigged:
    """``motion`` on a skeleton of naming family ``family`` (:data:`FAMILIES`).

    Parameters
    ----------
    motion : Motion
        A clip of a shared skeleton (:data:`SOURCE_ROLES`).
    family : str
    twist : bool
        Insert the family's twist (or roll, or segment) joints: leaves, or inline halfway
        along the bone for families that split bones.
    drop_extremities : bool
        Leave out toes, fingers and hand ends.
    reorder : bool
        List children right side first and the spine before the limbs.
    mirror : bool
        Mirror the figure left for right (X negated); the names still say the original side.
    strip_names : bool
        Name every joint ``jointN`` (a rig without names: only its structure tells).

    Returns
    -------
    Rerigged
    """
    spec = FAMILIES[family]
    sk = motion.skeleton
    source = source_family(sk)
    keep = [True] * sk.n_joints
    names: list[str] = []
    for j, name in enumerate(sk.joint_names):
        role, side = _role(source, name)
        if drop_extremities and role in _DROPPED or (j > 0 and not keep[sk.parents[j]]):
            keep[j] = False
        names.append(_named(spec, spec.names[role], side))
    rows, position = _joint_rows(sk, source, spec, names, keep, twist, reorder)
    parents = np.array([r[2] for r in rows], dtype=np.int64)
    offsets, channels, axes, rotations, jt = _joint_arrays(motion, rows, keep)
    site_names, site_parents, site_offsets = [], [], []
    for s, (name, p) in enumerate(zip(sk.site_names, sk.site_parents, strict=True)):
        if keep[p]:
            site_names.append(name or f"{names[p]}_end")
            site_parents.append(position[p])
            site_offsets.append(sk.site_offsets[s])
    site_offsets = np.array(site_offsets).reshape(-1, 3)
    root_translation = np.array(motion.root_translation)
    if mirror:  # reflect through the YZ plane: x -> -x
        for x in (offsets, site_offsets, root_translation, *([] if jt is None else [jt])):
            x[..., 0] *= -1
        rotations[..., 2:] *= -1
        axes[:, 2:] *= -1
    new_names = [r[1] for r in rows]
    if strip_names:
        new_names = [f"joint{k}" for k in range(len(rows))]
        site_names = [f"site{k}" for k in range(len(site_names))]
    skeleton = Skeleton(
        joint_names=tuple(new_names),
        parents=parents,
        offsets=offsets,
        channels=tuple(channels),
        euler=sk.euler,
        axes=axes,
        site_names=tuple(site_names),
        site_parents=np.array(site_parents, dtype=np.int64),
        site_offsets=site_offsets,
        name=f"{sk.name}-{family}",
    )
    out = Motion(skeleton, motion.fps, root_translation, rotations, jt, motion.name)
    renamed = {sk.joint_names[r[0]]: new_names[k] for k, r in enumerate(rows) if r[0] >= 0}
    return Rerigged(out, renamed)


def _named(spec: _Family, template: str, side: str | None) -> str:
    """A joint's name in ``spec``'s family: its role's ``template`` with the side's word."""
    word = {"L": spec.sides[0], "R": spec.sides[1]}.get(side or "", "")
    return template.replace("{S}", word).replace("{s}", word)


_Row = tuple[int, str, int, float]
"""A joint of the new skeleton: its source joint (``-1 - child`` for an inline twist joint,
``-10_000 - owner`` for a leaf twist joint), name, parent row and share of the offset."""


def _joint_rows(
    sk: Skeleton,
    source: str,
    spec: _Family,
    names: list[str],
    keep: list[bool],
    twist: bool,
    reorder: bool,
) -> tuple[list[_Row], dict[int, int]]:
    """The new joint list, parents first (the kept joints, children right side first with
    ``reorder``, twist joints inserted with ``twist``), and each kept source joint's row."""
    rows: list[_Row] = []
    position: dict[int, int] = {}
    side_order = {None: 0, "R": 1, "L": 2}

    def children(j: int) -> list[int]:
        kids = [c for c in sk.children(j) if keep[c]]
        if not reorder:
            return kids
        return sorted(kids, key=lambda c: side_order[_role(source, sk.joint_names[c])[1]])

    def visit(j: int, parent: int) -> None:
        role, side = _role(source, sk.joint_names[j])
        inline_parent = parent
        if twist and spec.inline and j > 0 and _parent_role(source, sk, j) in spec.twist:
            p_role, p_side = _role(source, sk.joint_names[sk.parents[j]])
            rows.append((-1 - j, _named(spec, spec.twist[p_role], p_side), parent, 0.5))
            inline_parent = len(rows) - 1
        rows.append((j, names[j], inline_parent, 0.5 if inline_parent != parent else 1.0))
        me = len(rows) - 1
        position[j] = me
        for c in children(j):
            visit(c, me)
        if twist and not spec.inline and role in spec.twist:
            rows.append((-10_000 - j, _named(spec, spec.twist[role], side), me, 0.0))

    visit(0, -1)
    return rows, position


def _joint_arrays(
    motion: Motion, rows: list[_Row], keep: list[bool]
) -> tuple[np.ndarray, list[tuple[str, ...]], np.ndarray, np.ndarray, np.ndarray | None]:
    """Offsets ``(J, 3)``, channels, axes ``(J, 4)``, rotations ``(T, J, 4)`` and joint
    translations ``(T, J, 3)`` (or None) of the new joints: a kept joint's own (its offset
    shared with an inline twist joint above it), no rotation for an inserted joint."""
    sk = motion.skeleton
    n, T = len(rows), motion.n_frames
    offsets = np.zeros((n, 3))
    channels: list[tuple[str, ...]] = []
    axes = np.zeros((n, 4))
    axes[:, 0] = 1.0
    rotations = np.zeros((T, n, 4))
    rotations[..., 0] = 1.0
    jt = None if motion.joint_translations is None else np.zeros((T, n, 3))
    for k, (src, _name, _parent, share) in enumerate(rows):
        if src >= 0:
            offsets[k] = sk.offsets[src] * share
            channels.append(sk.channels[src])
            axes[k] = sk.axes[src]
            rotations[:, k] = motion.rotations[:, src]
            if jt is not None:
                jt[:, k] = motion.joint_translations[:, src] * share
        elif src > -10_000:  # inline: the first half of the child's offset, no rotation
            child = -1 - src
            offsets[k] = sk.offsets[child] * 0.5
            channels.append(())
            if jt is not None:
                jt[:, k] = motion.joint_translations[:, child] * 0.5
        else:  # a leaf twist joint a third along the bone to the first kept child
            owner = -10_000 - src
            kids = [c for c in sk.children(owner) if keep[c]]
            offsets[k] = (sk.offsets[kids[0]] / 3.0) if kids else np.zeros(3)
            channels.append(("rx", "ry", "rz"))
    return offsets, channels, axes, rotations, jt


def _parent_role(source: str, sk: Skeleton, j: int) -> str:
    return _role(source, sk.joint_names[sk.parents[j]])[0]


def main(argv: list[str] | None = None) -> int:
    """``python -m quatmotion.synthetic.rerig IN OUT FAMILY``: write a re-rigged BVH."""
    from quatmotion.io import read_motion, write_motion

    args = sys.argv[1:] if argv is None else argv
    if len(args) != 3 or args[2] not in FAMILIES:
        print(f"usage: rerig IN OUT FAMILY ({', '.join(FAMILIES)})", file=sys.stderr)
        return 2
    result = rerig(read_motion(args[0]), args[2])
    write_motion(result.motion, args[1])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
