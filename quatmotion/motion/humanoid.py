"""The humanoid mapping: which joints of any skeleton are the 16 joints of the pose body.

The one home of the 16-joint body (:data:`JOINTS_16`, :data:`PARENTS_16`) and of the rule
that finds it in a file's skeleton (:func:`map_humanoid`), for every command that compares
bodies: clip search, pose search, their benchmarks and the web app (through
:mod:`quatmotion.pose.skeleton16`).

Conventions
-----------
* The 16 joints (Chen et al., GPD, section 3.1): Hip (the pelvis, where legs and spine
  branch), Chest (where the arms branch), Neck, Head, and per side Shoulder (the upper arm's
  start, not the clavicle), Elbow, Hand (the wrist), Hip (the thigh's start), Knee, Foot (the
  ankle). The points every studio's rig places alike.
* **Names** (:func:`parse_name`): a joint name is normalised before it is looked up: the
  namespace or path (``mixamorig:``, ``Armature|``) and rig prefixes (``DEF-``, ``ORG-``,
  ``Bip01 ``, ``CC_Base_``, ``joint_``) dropped, split into lower-case words at case changes,
  separators and digits, the side taken out wherever it is written (``Left``/``Right``,
  ``L``/``R`` as a word, ``_l``/``.L`` suffixes, an ``l``/``r`` stuck to the front of a known
  word: ``lfemur``, ``LHip``). The rest is the name's key, looked up in :data:`ALIASES`
  (per canonical joint, keys in order of preference: ``wrist`` before ``hand``, ``upleg``
  before ``hip``, so that a rig with both means by each what its family means). Twist, roll,
  helper, end, IK and finger joints never stand for a canonical joint. Of several joints with
  one key (``Neck``, ``Neck1``; ``thigh.L``, ``thigh.L.001``) the one nearest the root wins.
* **Structure**, where names are missing or contradict the hierarchy: the pelvis is the joint
  nearest the root where two long limbs and the spine branch; the chest the next such joint
  up the spine (the arms' common ancestor); legs are the pelvis's long branches that go down
  in the rest pose (up being the pelvis-to-chest direction), arms the chest's that go
  sideways, the head the chain that continues up. Along a limb the main chain follows the
  longest branch (twist and helper leaves fall off); the ankle is where the chain turns from
  down to forward (or its end), the wrist where the fingers branch (or its end), the knee and
  elbow the joints that split the rest into two similar bones. Left is the side of
  ``up x forward``, forward being where the toes point (else +Z, the file convention): a
  mirrored rig or one listing right before left maps by its geometry, never by file order.
* **User map** (``joint_map``): canonical joint name -> file joint (or end-site) name, taken
  before anything else; a name the skeleton does not have is an error naming it.
* **Estimated**: a rig without a neck (or head) is mapped with the point placed on the chain
  between its neighbours (:data:`ESTIMATES`), and the mapping says so (``how`` is
  ``"estimated"``).
* Not humanoid: a skeleton without two legs and two arms by names or structure (a prop, a
  face rig, a hand), or one whose front limbs go down like its hind limbs from a horizontal
  spine (a quadruped), raises :class:`HumanoidError` with the reason; a humanoid without a
  mapping raises it naming the missing joints, the nearest candidates and ``--joint-map``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from quatmotion.motion.joint_names import (
    ALIASES,
    HELPER_WORDS,
    PART_CJK,
    PART_WORDS,
    QUADRUPED_WORDS,
    TWIST_WORDS,
    body_part,
    name_words,
    parse_name,
)
from quatmotion.motion.skeleton import Skeleton

__all__ = [
    "ALIASES",
    "ESTIMATES",
    "JOINTS_16",
    "JOINT_MAP_EXTRA",
    "PARENTS_16",
    "PART_CJK",
    "PART_WORDS",
    "HumanoidError",
    "HumanoidMap",
    "body_part",
    "check_joint_map",
    "map_humanoid",
    "name_words",
    "parse_name",
    "with_joint_map",
]

JOINTS_16: tuple[str, ...] = (
    "Hip",
    "Chest",
    "Neck",
    "Head",
    "LShoulder",
    "LElbow",
    "LHand",
    "RShoulder",
    "RElbow",
    "RHand",
    "LHip",
    "LKnee",
    "LFoot",
    "RHip",
    "RKnee",
    "RFoot",
)
"""The 16 joints of the pose body, in the order every 16-joint array uses."""
PARENTS_16: tuple[int, ...] = (-1, 0, 1, 2, 1, 4, 5, 1, 7, 8, 0, 10, 11, 0, 13, 14)

JOINT_MAP_EXTRA = "joint_map16"
"""The key of :attr:`Skeleton.extras` holding a user's map (:func:`with_joint_map`)."""

How = Literal["name", "structure", "user", "estimated"]

_LIMB_SLOTS = {
    "Shoulder": "Shoulder", "Elbow": "Elbow", "Hand": "Hand",
    "Hip": "Hip_", "Knee": "Knee", "Foot": "Foot",
}  # fmt: skip

ESTIMATES: dict[str, tuple[str, str, float]] = {
    "Neck": ("Chest", "Head", 0.4),
    "Head": ("Chest", "Neck", 2.5),
}
"""A missing joint placed on the line of two mapped ones: ``a + t (b - a)`` (the canonical
body's proportions: the neck 0.4 of the way from chest to head, the head 1.5 chest-neck
lengths beyond the neck)."""


class HumanoidError(ValueError):
    """A skeleton that cannot be mapped onto the 16-joint body: one line saying why (the
    joints missing with the nearest candidates and ``--joint-map``, or that it is no
    humanoid and why)."""


@dataclass(frozen=True, eq=False)
class HumanoidMap:
    """Where the 16 pose joints are in one skeleton, and how each was found.

    Attributes
    ----------
    points : tuple of str, length 16
        The file joint (or end site) of each canonical joint, :data:`JOINTS_16` order; for an
        estimated joint, ``"~A+B"`` naming the two it is placed between.
    how : tuple of str, length 16
        ``"name"``, ``"structure"``, ``"user"`` or ``"estimated"``.
    weights : ndarray, shape (16, J + S)
        Each canonical position as a combination of the skeleton's points (joints then end
        sites, the order of :meth:`Skeleton.rest_positions`); rows sum to 1.
    joints : ndarray of int, shape (16,)
        The joint carrying each canonical joint (an end site's parent; for an estimated one,
        the nearer mapped joint): where its rotation is read.
    n_joints : int
        The skeleton's joints (the points after them are end sites).
    family : str
        The naming family recognised (``asf``, ``cmu_bvh``, ``bandai``, ``mixamo``,
        ``unreal``, ``biped``, ``rigify``, ``smpl``, ``kinect``, ``humanoid``...).
    """

    points: tuple[str, ...]
    how: tuple[str, ...]
    weights: NDArray[np.float64]
    joints: NDArray[np.int64]
    family: str
    n_joints: int

    @property
    def estimated(self) -> tuple[str, ...]:
        """The canonical joints the skeleton does not have, placed by :data:`ESTIMATES`."""
        return tuple(n for n, h in zip(JOINTS_16, self.how, strict=True) if h == "estimated")

    @property
    def uses_sites(self) -> bool:
        """Whether an end site stands for (or helps place) a canonical joint."""
        return bool(np.any(self.weights[:, self.n_joints :] != 0))

    def positions(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        """The 16 canonical positions from every point's: ``(..., J + S, 3)`` (or ``(..., J,
        3)`` when :attr:`uses_sites` is False) -> ``(..., 16, 3)``."""
        w = self.weights[:, : points.shape[-2]]
        return np.einsum("kp,...pc->...kc", w, points)

    def as_dict(self) -> dict[str, dict[str, str]]:
        """``{canonical: {"joint": file point, "how": how}}``: what ``info`` and the files
        show."""
        return {
            n: {"joint": p, "how": h}
            for n, p, h in zip(JOINTS_16, self.points, self.how, strict=True)
        }

    def summary(self) -> str:
        """One line: the family, how many joints by each way, what was estimated."""
        counts = {h: self.how.count(h) for h in ("name", "structure", "user", "estimated")}
        parts = [f"{c} by {h}" for h, c in counts.items() if c and h != "estimated"]
        text = f"{self.family}: " + ", ".join(parts)
        if self.estimated:
            text += f"; estimated {', '.join(self.estimated)}"
        return text


def with_joint_map(skeleton: Skeleton, joint_map: Mapping[str, str] | None) -> Skeleton:
    """``skeleton`` carrying a user's map (canonical -> file joint) for :func:`map_humanoid`,
    checked against its joints (:class:`HumanoidError` naming what does not fit); the
    skeleton itself when ``joint_map`` is empty."""
    if not joint_map:
        return skeleton
    clean = check_joint_map(joint_map)
    names = set(skeleton.joint_names) | set(skeleton.site_names)
    unknown = [f"{k}={v}" for k, v in clean.items() if v not in names]
    if unknown:
        raise HumanoidError(
            f"skeleton {skeleton.name!r}: the joint map names joints it does not have: "
            f"{', '.join(unknown)}"
        )
    import dataclasses

    return dataclasses.replace(skeleton, extras={**skeleton.extras, JOINT_MAP_EXTRA: clean})


def check_joint_map(joint_map: Mapping[str, object]) -> dict[str, str]:
    """A user's map with its canonical names checked (case-insensitive, ``LeftShoulder``
    for ``LShoulder`` too) and its values strings: :class:`HumanoidError` otherwise."""
    lookup = {n.lower(): n for n in JOINTS_16}
    lookup.update({("left" + n[1:]).lower(): n for n in JOINTS_16 if n[0] == "L"})
    lookup.update({("right" + n[1:]).lower(): n for n in JOINTS_16 if n[0] == "R"})
    out: dict[str, str] = {}
    for key, value in joint_map.items():
        canonical = lookup.get(str(key).strip().lower())
        if canonical is None:
            raise HumanoidError(
                f"joint map: {key!r} is no canonical joint; they are {', '.join(JOINTS_16)}"
            )
        if not isinstance(value, str) or not value.strip():
            raise HumanoidError(f"joint map: {key}: expected a joint name, got {value!r}")
        out[canonical] = value.strip()
    return out


# --------------------------------------------------------------------------------------------
# The mapping
# --------------------------------------------------------------------------------------------


class _Tree:
    """The skeleton's points (joints then end sites) as a tree, at rest."""

    def __init__(self, skeleton: Skeleton):
        self.n_joints = skeleton.n_joints
        self.names = skeleton.joint_names + skeleton.site_names
        self.parents = np.concatenate((skeleton.parents, skeleton.site_parents)).astype(int)
        self.rest = skeleton.rest_positions(include_sites=True)
        n = len(self.names)
        self.lengths = np.zeros(n)
        self.lengths[1:] = np.linalg.norm(self.rest[1:] - self.rest[self.parents[1:]], axis=1)
        self.children: list[list[int]] = [[] for _ in range(n)]
        for p in range(1, n):
            self.children[self.parents[p]].append(p)
        self.reach = np.zeros(n)  # the longest path down from each point
        order = sorted(range(1, n), key=self._depth, reverse=True)
        for p in order:
            parent = self.parents[p]
            self.reach[parent] = max(self.reach[parent], self.reach[p] + self.lengths[p])
        self.parsed = [parse_name(name) for name in self.names]

    def _depth(self, p: int) -> int:
        d = 0
        while p > 0:
            p = int(self.parents[p])
            d += 1
        return d

    def ancestors(self, p: int) -> list[int]:
        """``p`` and its ancestors, ``p`` first."""
        out = [p]
        while p > 0:
            p = int(self.parents[p])
            out.append(p)
        return out

    def is_ancestor(self, a: int, b: int) -> bool:
        """Whether ``a`` is ``b`` or above it."""
        return a in self.ancestors(b)

    def lca(self, a: int, b: int) -> int:
        above = set(self.ancestors(a))
        return next(p for p in self.ancestors(b) if p in above)

    def branch(self, p: int) -> float:
        return float(self.lengths[p] + self.reach[p])

    def main_chain(self, start: int) -> list[int]:
        """``start`` and the points below it along the longest branch."""
        chain = [start]
        while self.children[chain[-1]]:
            chain.append(max(self.children[chain[-1]], key=self.branch))
        return chain

    def path_length(self, a: int, b: int) -> float:
        """Bone path length from ``a`` down to its descendant ``b``."""
        below_a = [p for p in self.ancestors(b) if p != a and self.is_ancestor(a, p)]
        return float(sum(self.lengths[p] for p in below_a))

    def between(self, a: int, b: int) -> list[int]:
        """The points strictly between ``a`` and its descendant ``b``, ``b``'s side first."""
        return [p for p in self.ancestors(b)[1:] if p != a and self.is_ancestor(a, p)]


def map_humanoid(skeleton: Skeleton, joint_map: Mapping[str, str] | None = None) -> HumanoidMap:
    """The 16 pose joints of ``skeleton``: by the user's map, names, structure, in that order.

    Parameters
    ----------
    skeleton : Skeleton
    joint_map : mapping, optional
        Canonical joint -> file joint (or end site) name; defaults to the map the skeleton
        carries (:func:`with_joint_map`).

    Returns
    -------
    HumanoidMap

    Raises
    ------
    HumanoidError
        One line: a skeleton that is not humanoid (why), or the canonical joints that could
        not be found with the nearest candidates and the ``--joint-map`` option.
    """
    if joint_map is None:
        joint_map = skeleton.extras.get(JOINT_MAP_EXTRA)
    user = check_joint_map(joint_map) if joint_map else {}
    tree = _Tree(skeleton)
    found: dict[str, tuple[int, str]] = {}
    lookup = {name: p for p, name in enumerate(tree.names)}
    lookup_lower = {name.lower(): p for p, name in enumerate(tree.names)}
    for canonical, name in user.items():
        p = lookup.get(name, lookup_lower.get(name.lower()))
        if p is None:
            raise HumanoidError(
                f"skeleton {skeleton.name!r}: the joint map's {canonical}={name!r} names no "
                "joint of it"
            )
        found[canonical] = (p, "user")
    _quadruped_check(skeleton, tree)
    _by_names(tree, found)
    _by_structure(skeleton, tree, found)
    _torso(tree, found)
    missing = [n for n in JOINTS_16 if n not in found and n not in ESTIMATES]
    if missing:
        raise HumanoidError(_missing_message(skeleton, tree, missing))
    return _assemble(skeleton, tree, found)


def _quadruped_check(skeleton: Skeleton, tree: _Tree) -> None:
    words = {w for parsed in tree.parsed[: tree.n_joints] for w in parsed.words}
    animal = sorted(words & QUADRUPED_WORDS)
    if len(animal) >= 2 or ({"tail"} & words and {"paw", "hoof", "hind", "front"} & words):
        raise HumanoidError(
            f"skeleton {skeleton.name!r} is not a humanoid: its joints are named for an "
            f"animal's body ({', '.join(animal)}); search compares human bodies"
        )


def _named(tree: _Tree, keys: tuple[str, ...], side: str | None) -> int | None:
    """The joint nearest the root with the first key of ``keys`` that any joint has."""
    for key in keys:
        hits = [
            p
            for p in range(tree.n_joints)
            if tree.parsed[p].key == key and (side is None or tree.parsed[p].side == side)
        ]
        if side is None:
            hits = [p for p in hits if tree.parsed[p].side is None]
        if hits:
            return min(hits, key=tree._depth)
    return None


def _by_names(tree: _Tree, found: dict[str, tuple[int, str]]) -> None:
    """Every joint the names give, where the hierarchy agrees (a knee below its hip...)."""
    for side in "LR":
        limbs = (("Shoulder", "Elbow", "Hand"), ("Hip", "Knee", "Foot"))
        for limb in limbs:
            chain: list[tuple[str, int]] = []
            for part in limb:
                canonical = side + part
                if canonical in found:
                    chain.append((canonical, found[canonical][0]))
                    continue
                keys = ALIASES[_LIMB_SLOTS[part]]
                if part == "Hip":  # a sided "hip" is the thigh only where no thigh is named
                    keys = tuple(k for k in keys if k != "hip") + ("hip",)
                p = _named(tree, keys, side)
                if p is not None and all(tree.is_ancestor(q, p) and q != p for _, q in chain):
                    found[canonical] = (p, "name")
                    chain.append((canonical, p))
    for canonical in ("Neck", "Head"):
        if canonical not in found:
            p = _named(tree, ALIASES[canonical], None)
            if p is not None:
                found[canonical] = (p, "name")
    if "Neck" in found and "Head" in found:
        neck, head = found["Neck"][0], found["Head"][0]
        if neck == head or not tree.is_ancestor(neck, head):
            found.pop("Neck") if found["Neck"][1] == "name" else found.pop("Head")


def _facing(tree: _Tree, up: NDArray[np.float64], ankles: list[int]) -> NDArray[np.float64]:
    """Forward: where the toes point from the ankles (perpendicular to up), else +Z."""
    forward = np.zeros(3)
    for ankle in ankles:
        chain = tree.main_chain(ankle)
        forward += tree.rest[chain[-1]] - tree.rest[ankle]
    forward -= up * (forward @ up)
    if np.linalg.norm(forward) < 1e-6 * max(1.0, float(tree.reach[0])):
        forward = np.array([0.0, 0.0, 1.0]) - up * up[2]
    return forward / max(np.linalg.norm(forward), 1e-12)


def _by_structure(skeleton: Skeleton, tree: _Tree, found: dict[str, tuple[int, str]]) -> None:
    """The limbs the names left out, from the shape (see the module docstring)."""
    limb_names = [s + p for s in "LR" for p in ("Shoulder", "Elbow", "Hand", "Hip", "Knee", "Foot")]
    if all(n in found for n in limb_names):
        return
    n = tree.n_joints
    span = max(
        [float(tree.reach[0])]
        + [sum(sorted(tree.branch(c) for c in tree.children[p])[-2:]) for p in range(n)]
    )
    long_ = [[c for c in tree.children[p] if tree.branch(c) >= 0.2 * span] for p in range(n)]
    hubs = [p for p in range(n) if len(long_[p]) >= 2]
    if not hubs or span <= 0:
        raise HumanoidError(
            f"skeleton {skeleton.name!r} is not a humanoid: no joint where two limbs branch "
            "(a prop, a face rig or a single limb); search compares human bodies"
        )
    named_hip = [found[s + "Hip"][0] for s in "LR" if s + "Hip" in found]
    pelvis = min(hubs, key=tree._depth)
    if len(named_hip) == 2:
        pelvis = tree.lca(*named_hip)
    below = [p for p in hubs if p != pelvis and tree.is_ancestor(pelvis, p)]
    named_arm = [found[s + "Shoulder"][0] for s in "LR" if s + "Shoulder" in found]
    if len(named_arm) == 2:
        chest = tree.lca(*named_arm)
    elif below:
        chest = min(below, key=tree._depth)
    else:
        raise HumanoidError(
            f"skeleton {skeleton.name!r} is not a humanoid: one joint where limbs branch, "
            "no second for the arms (a hand or a creature); search compares human bodies"
        )
    up = tree.rest[chest] - tree.rest[pelvis]
    if np.linalg.norm(up) <= 0:
        raise HumanoidError(f"skeleton {skeleton.name!r}: its pelvis and chest coincide at rest")
    up = up / np.linalg.norm(up)
    spine_child = next((c for c in tree.children[pelvis] if tree.is_ancestor(c, chest)), None)
    leg_roots = [c for c in long_[pelvis] if c != spine_child]
    leg_roots = sorted(leg_roots, key=lambda c: _drop(tree, c, up))[:2]
    arm_roots = [c for c in long_[chest] if not tree.is_ancestor(c, pelvis)]
    arm_roots = sorted(arm_roots, key=lambda c: -_lateral(tree, chest, c, up))[:2]
    if len(leg_roots) < 2 or len(arm_roots) < 2:  # a body, not all of its limbs found
        raise HumanoidError(
            _missing_message(skeleton, tree, [n for n in limb_names if n not in found])
        )
    height = float(np.linalg.norm(tree.rest[chest] - tree.rest[pelvis]))
    for c in leg_roots:
        if _drop(tree, c, up) > -0.5 * height:
            raise HumanoidError(
                f"skeleton {skeleton.name!r} is not a humanoid: its hind limbs do not go down "
                "from the pelvis at rest; search compares human bodies"
            )
    arm_drop = [_drop(tree, c, up) for c in arm_roots]
    leg_drop = [_drop(tree, c, up) for c in leg_roots]
    if min(arm_drop) < 0.5 * max(leg_drop) and abs(up[1]) < 0.5:
        raise HumanoidError(
            f"skeleton {skeleton.name!r} is not a humanoid: a horizontal spine with four limbs "
            "going down (a quadruped); search compares human bodies"
        )
    legs = [_leg(tree, c, up) for c in leg_roots]
    arms = [_arm(tree, c) for c in arm_roots]
    forward = _facing(tree, up, [leg[2] for leg in legs])
    left = np.cross(up, forward)
    for limbs, hub, parts in ((legs, pelvis, ("Hip", "Knee", "Foot")),
                              (arms, chest, ("Shoulder", "Elbow", "Hand"))):  # fmt: skip
        sides = _sides(tree, limbs, hub, left, found, parts)
        for limb, side in zip(limbs, sides, strict=True):
            for part, p in zip(parts, limb, strict=True):
                found.setdefault(side + part, (p, "structure"))
    found.setdefault("Hip", (pelvis, "structure"))


def _drop(tree: _Tree, start: int, up: NDArray[np.float64]) -> float:
    """How far the end of ``start``'s main chain lies above (+) or below (-) its root."""
    chain = tree.main_chain(start)
    return float((tree.rest[chain[-1]] - tree.rest[tree.parents[start]]) @ up)


def _lateral(tree: _Tree, hub: int, start: int, up: NDArray[np.float64]) -> float:
    chain = tree.main_chain(start)
    d = tree.rest[chain[-1]] - tree.rest[hub]
    return float(np.linalg.norm(d - up * (d @ up)) - abs(d @ up))


def _compact(tree: _Tree, chain: list[int]) -> list[int]:
    """The chain without points that sit on their parent (inline helpers), and without
    twist, roll and helper joints."""
    total = sum(tree.lengths[p] for p in chain[1:]) or 1.0
    out = [chain[0]]
    for p in chain[1:]:
        if tree.lengths[p] >= 0.01 * total and not (TWIST_WORDS & set(tree.parsed[p].words)):
            out.append(p)
    return out


def _split(tree: _Tree, points: list[int], end: int, ratio: float) -> tuple[int, int]:
    """The root and the middle joint of a two-bone limb ending at ``end`` (thigh and knee,
    upper arm and elbow): the middle is the point of ``points`` (a compacted chain) whose bone
    from the point before it and whose path on to ``end`` are nearest the ratio ``ratio``
    (upper/lower); the later point on ties."""
    best, best_score = (points[0], points[-1]), np.inf
    for j in range(1, len(points)):
        upper = tree.path_length(points[j - 1], points[j])
        lower = tree.path_length(points[j], end)
        if upper <= 0 or lower <= 0:
            continue
        score = abs(np.log(upper / lower / ratio))
        if score <= best_score + 1e-9:
            best, best_score = (points[j - 1], points[j]), score
    return best


def _leg(tree: _Tree, start: int, up: NDArray[np.float64]) -> tuple[int, int, int]:
    """Hip, knee, ankle of a leg from the joint leaving the pelvis."""
    chain = _compact(tree, tree.main_chain(start))
    ankle = chain[-1]
    for k in range(2, len(chain) - 1):
        rest = tree.rest[chain[-1]] - tree.rest[chain[k]]
        if np.linalg.norm(rest) > 0 and (rest @ up) > -0.6 * np.linalg.norm(rest):
            ankle = chain[k]
            break
    hip, knee = _split(tree, chain[: chain.index(ankle)], ankle, 1.1)
    return hip, knee, ankle


def _arm(tree: _Tree, start: int) -> tuple[int, int, int]:
    """Shoulder, elbow, wrist of an arm from the joint leaving the chest."""
    chain = _compact(tree, tree.main_chain(start))
    joints = [p for p in chain if p < tree.n_joints]
    wrist = joints[-1]  # no fingers branch: the last joint (an end site is the hand's end)
    for k in range(2, len(chain)):
        # fingers are chains (a leaf off the forearm is a twist helper, not a finger)
        kids = [c for c in tree.children[chain[k]] if tree.lengths[c] > 0 and tree.reach[c] > 0]
        if len(kids) >= 2 and tree.reach[chain[k]] <= 0.6 * tree.path_length(start, chain[k]):
            wrist = chain[k]  # where the fingers branch, the hand shorter than the arm
            break
    shoulder, elbow = _split(tree, chain[: chain.index(wrist)], wrist, 1.15)
    return shoulder, elbow, wrist


def _sides(
    tree: _Tree,
    limbs: list[tuple[int, int, int]],
    hub: int,
    left: NDArray[np.float64],
    found: dict[str, tuple[int, str]],
    parts: tuple[str, str, str],
) -> list[str]:
    """Each limb's side: by what the names already gave it, else by the rest pose."""
    for limb in limbs:
        for side in "LR":
            if any(found.get(side + part, (-1,))[0] in limb for part in parts):
                other = "R" if side == "L" else "L"
                return [side, other] if limb is limbs[0] else [other, side]
    offsets = [float((tree.rest[limb[0]] - tree.rest[hub]) @ left) for limb in limbs]
    return ["L", "R"] if offsets[0] >= offsets[1] else ["R", "L"]


def _torso(tree: _Tree, found: dict[str, tuple[int, str]]) -> None:
    """Hip, Chest, Neck and Head once the limbs are known."""
    hips = [found[s + "Hip"][0] for s in "LR" if s + "Hip" in found]
    arms = [found[s + "Shoulder"][0] for s in "LR" if s + "Shoulder" in found]
    if len(hips) < 2 or len(arms) < 2:
        return
    lca = tree.lca(*hips)
    if "Hip" not in found or found["Hip"][1] == "structure":
        named = _named(tree, ALIASES["Hip"], None)
        if named is not None and tree.is_ancestor(named, lca) and named != lca:
            # a named pelvis above the branch (Biped's Pelvis over its Spine) when it lies
            # level with the hips, not the floor-level root of game rigs
            level = abs(tree.rest[named] - tree.rest[lca]) @ np.ones(3)
            if level <= 0.25 * tree.path_length(lca, hips[0]) + 1e-9:
                found["Hip"] = (named, "name")
        if "Hip" not in found or found["Hip"][1] == "structure":
            found["Hip"] = (lca, "name" if tree.parsed[lca].key in ALIASES["Hip"] else "structure")
    if "Chest" not in found:
        chest = tree.lca(*arms)
        head = found.get("Head", (None,))[0]
        neck = found.get("Neck", (None,))[0]
        if head is None:  # the chain that continues up: from the neck, else the arms' branch
            start = neck
            if start is None:
                ups = [
                    c for c in tree.children[chest]
                    if c < tree.n_joints and not any(tree.is_ancestor(c, a) for a in arms)
                    and not HELPER_WORDS & set(tree.parsed[c].words)
                ]  # fmt: skip
                start = max(ups, key=tree.branch) if ups else None
            if start is not None:
                chain = _compact(tree, tree.main_chain(start))
                after = chain[1:] if neck is not None else chain
                joints = [p for p in after if p < tree.n_joints]
                head = joints[-1] if joints else (after[-1] if after else None)
                if head is not None:
                    found["Head"] = (head, "structure")
                    if neck is None and chain[0] != head:
                        neck = chain[0]
                        found["Neck"] = (neck, "structure")
        if neck is None and head is not None and tree.is_ancestor(chest, head):
            between = tree.between(chest, head)
            if between:
                neck = between[-1]
                found["Neck"] = (neck, "structure")
        # the chest lies strictly below the neck, not at its point (CMU BVH's Spine1 sits on
        # its Neck; Biped's arms hang from its Neck)
        top = neck if neck is not None else head
        pelvis = found["Hip"][0]
        stature = float(tree.path_length(pelvis, hips[0]) + tree.reach[pelvis]) or 1.0
        while (
            chest != pelvis
            and top is not None
            and (
                chest == top
                or not tree.is_ancestor(chest, top)
                or np.linalg.norm(tree.rest[chest] - tree.rest[top]) < 0.01 * stature
            )
        ):
            chest = int(tree.parents[chest])
        how = "name" if tree.parsed[chest].key in ALIASES["Chest"] else "structure"
        found["Chest"] = (chest, how)
    chest = found["Chest"][0]
    if "Neck" not in found and "Head" in found:
        between = tree.between(chest, found["Head"][0])
        if between:
            found["Neck"] = (between[-1], "structure")


def _assemble(skeleton: Skeleton, tree: _Tree, found: dict[str, tuple[int, str]]) -> HumanoidMap:
    n_points = len(tree.names)
    weights = np.zeros((16, n_points))
    joints = np.zeros(16, dtype=np.int64)
    points, hows = [], []
    for k, canonical in enumerate(JOINTS_16):
        if canonical in found:
            p, how = found[canonical]
            weights[k, p] = 1.0
            joints[k] = p if p < tree.n_joints else tree.parents[p]
            points.append(tree.names[p])
            hows.append(how)
            continue
        a, b, t = ESTIMATES[canonical]
        if a not in found or b not in found:
            raise HumanoidError(_missing_message(skeleton, tree, [canonical]))
        pa, pb = found[a][0], found[b][0]
        weights[k, pa] += 1.0 - t
        weights[k, pb] += t
        joints[k] = pb if pb < tree.n_joints else tree.parents[pb]
        points.append(f"~{a}+{b}")
        hows.append("estimated")
    used = [found[n][0] for n in found]
    if len(set(used)) != len(used):
        dup = sorted({tree.names[p] for p in used if used.count(p) > 1})
        raise HumanoidError(
            f"skeleton {skeleton.name!r}: one joint stands for two canonical joints "
            f"({', '.join(dup)}); give the map with --joint-map"
        )
    return HumanoidMap(tuple(points), tuple(hows), weights, joints, _family(tree), tree.n_joints)


def _missing_message(skeleton: Skeleton, tree: _Tree, missing: list[str]) -> str:
    words = {w for n in missing for w in ALIASES.get(_LIMB_SLOTS.get(n[1:], n), (n.lower(),))}
    keys = [tree.parsed[p].key for p in range(tree.n_joints)]
    candidates = [
        name
        for name, key in zip(tree.names, keys, strict=False)
        if key and any(w in key or key in w for w in words)
    ][:6]
    near = f"; nearest candidates: {', '.join(candidates)}" if candidates else ""
    return (
        f"skeleton {skeleton.name!r}: cannot map the 16-joint body, missing "
        f"{', '.join(missing)}{near}; give them with --joint-map FILE (CSV or JSON, canonical "
        "joint -> file joint)"
    )


_FAMILIES: dict[str, tuple[str, ...]] = {
    "asf": ("root", "lfemur", "ltibia", "lhumerus", "lradius", "lwrist", "thorax", "lowerneck"),
    "cmu_bvh": ("Hips", "LeftUpLeg", "LeftLeg", "LeftArm", "LeftForeArm", "Spine1", "Neck1"),
    "bandai": ("UpperLeg_L", "LowerLeg_L", "UpperArm_L", "LowerArm_L", "Hand_L", "Chest"),
}


def _family(tree: _Tree) -> str:
    names = set(tree.names[: tree.n_joints])
    lower = [n.lower() for n in names]
    for family, signature in _FAMILIES.items():
        if all(s in names for s in signature):
            return family
    rules = (
        ("mixamo", lambda n: n.startswith("mixamorig")),
        ("biped", lambda n: n.startswith(("bip0", "biped"))),
        ("character creator", lambda n: n.startswith("cc_base_")),
        ("rigify", lambda n: n.startswith("def-") or n.endswith((".l", ".r"))),
        ("unreal", lambda n: n in ("thigh_l", "calf_l", "lowerarm_l", "clavicle_l")),
        ("kinect", lambda n: n in ("spinebase", "hipleft", "kneeleft", "spineshoulder")),
        ("smpl", lambda n: n in ("l_hip", "l_knee", "l_ankle", "l_shoulder", "l_collar")),
        ("makehuman", lambda n: n.startswith(("upperleg0", "lowerleg0", "upperarm0"))),
        ("humanik", lambda n: n in ("leftupleg", "leftforearm", "leftuplegroll")),
    )
    for family, rule in rules:
        if any(rule(n) for n in lower):
            return family
    return "humanoid"
