"""Joint names taken apart: the naming knowledge the humanoid mapping and ``find_body`` share.

The one home of what a joint's name says (:mod:`quatmotion.motion.humanoid` maps skeletons with
it; :func:`quatmotion.io.units.find_body` finds a body's feet and head with it).

Conventions
-----------
* A name is normalised before it is looked up (:func:`parse_name`): the namespace or path
  (``mixamorig:``, ``Armature|``) and rig prefixes (``DEF-``, ``ORG-``, ``Bip01 ``,
  ``CC_Base_``, ``joint_``) dropped, split into lower-case words at case changes, separators
  and digits, the side taken out wherever it is written. The rest is the name's key, looked up
  in :data:`ALIASES`.
* Twist, roll, helper, end, IK and finger words (:data:`HELPER_WORDS`, :data:`TWIST_WORDS`)
  never stand for a canonical joint; :data:`QUADRUPED_WORDS` tell a four-legged rig.
* :data:`PART_WORDS` and :data:`PART_CJK`: the words of a head, foot, leg and hand in several
  languages (:func:`body_part`).
"""

from __future__ import annotations

import re
from typing import NamedTuple

__all__ = [
    "ALIASES",
    "HELPER_WORDS",
    "PART_CJK",
    "PART_WORDS",
    "QUADRUPED_WORDS",
    "TWIST_WORDS",
    "ParsedName",
    "body_part",
    "name_words",
    "parse_name",
]

# Keys (a name's words without side, digits or prefix, joined) of each canonical joint, in
# order of preference. Limb keys are per side.
ALIASES: dict[str, tuple[str, ...]] = {
    "Hip": ("hips", "pelvis", "hip", "spinebase", "root", "cog", "torso"),
    "Chest": ("chest", "thorax", "upperchest", "spineshoulder", "spinechest", "ribcage"),
    "Neck": ("neck", "lowerneck", "necklower", "neckbase", "upperneck"),
    "Head": ("head",),
    "Shoulder": ("upperarm", "armupper", "uparm", "humerus", "arm", "shoulder"),
    "Elbow": ("forearm", "lowerarm", "armlower", "radius", "elbow", "ulna", "lowarm"),
    "Hand": ("wrist", "hand", "carpus"),
    "Hip_": ("upleg", "upperleg", "legupper", "thigh", "femur", "hip", "uleg"),
    "Knee": ("lowerleg", "leglower", "calf", "shin", "tibia", "knee", "leg", "lleg", "crus"),
    "Foot": ("ankle", "foot", "tarsus"),
}
"""Name keys (see :func:`parse_name`) of each canonical joint, most telling first; the limb
entries (``Shoulder`` ... ``Foot``, ``Hip_`` for the thigh) hold for either side."""

_PREFIXES = re.compile(
    r"^(?i:def|org|mch|cc_base|bip\d*|biped\d*|joint|jnt|bn|bone|b|j|c|sk|skel|rig|mixamorig\d*)"
    r"(?:[\s_.\-:]+|(?=[A-Z]))"
)
_CAMEL = re.compile(r"(?<=[a-z])(?=[A-Z])|(?<=[A-Z])(?=[A-Z][a-z])|(?<=\D)(?=\d)|(?<=\d)(?=\D)")
_SPLIT = re.compile(r"[^a-z0-9]+")
_FINGERS = {"finger", "fingers", "thumb", "index", "middle", "ring", "pinky", "pinkie", "little"}
_TOES = {"toe", "toes", "toebase"}
_PALM = {"palm", "metacarpal", "carpal"}
HELPER_WORDS = {
    "twist", "roll", "helper", "help", "end", "nub", "tip", "ik", "fk", "pole", "target",
    "ctrl", "control", "mch", "corrective", "dummy", "null", "share", "bend", "aux", "fix",
    "top", "jaw", "eye", "brow", "lip", "cheek", "tongue", "ear", "nose", "teeth", "breast",
    *_FINGERS, *_TOES, *_PALM, "ball", "hipjoint",
    "clavicle", "collar", "scapula", "site", "weapon", "prop", "attach", "slot",
}  # fmt: skip
TWIST_WORDS = {
    "twist", "roll", "helper", "help", "share", "bend", "aux", "fix", "corrective", "dummy",
    "null", "ik", "fk", "pole", "target", "ctrl", "control", "mch",
}  # fmt: skip
"""Words of joints that double a bone (twist, roll, rig helpers): never on a limb's chain."""
QUADRUPED_WORDS = {"tail", "paw", "hoof", "hind", "front", "fore", "wing", "snout", "muzzle"}
_KNOWN = (
    {k for keys in ALIASES.values() for k in keys}
    | HELPER_WORDS
    | {
        "upper",
        "lower",
        "up",
        "low",
        "arm",
        "leg",
        "spine",
        "collar",
    }
)
_SIDE_WORDS = {"l": "L", "left": "L", "r": "R", "right": "R", "lft": "L", "rgt": "R", "rt": "R"}

# Body parts by the words of a name, in the languages rigs are named in: the head, feet, legs
# and hands, what finds a body's stature chain (quatmotion.io.units.find_body) whether or not
# the 16 joints can be mapped. The English keys of ALIASES are among them.
PART_WORDS: dict[str, frozenset[str]] = {
    "head": frozenset({
        *ALIASES["Head"], "headtop", "kopf", "tete", "tête", "cabeza", "testa", "skull",
        "cranium",
    }),
    "foot": frozenset({
        *ALIASES["Foot"], *_TOES, "feet", "heel", "fuss", "fuß", "knöchel", "knochel", "zeh",
        "zehe", "zehen", "pied", "cheville", "orteil", "orteils", "pie", "tobillo", "piede",
        "caviglia",
    }),
    "leg": frozenset({
        *(k for k in ALIASES["Hip_"] if k != "hip"), *ALIASES["Knee"], "leg", "knee", "bein",
        "oberschenkel", "unterschenkel", "knie", "jambe", "cuisse", "genou", "pierna",
        "muslo", "rodilla", "gamba", "coscia", "ginocchio",
    }),
    "hand": frozenset({
        *ALIASES["Hand"], *_FINGERS, *_PALM, "phalanx", "phalange", "knuckle", "daumen",
        "pouce", "doigt", "main", "mano", "dedo", "pulgar", "dito",
    }),
}  # fmt: skip
"""Words (lower case, any script that separates words) naming each body part; a thigh is a
leg (``hip`` is not: many rigs call the pelvis so)."""
PART_CJK: dict[str, tuple[str, ...]] = {
    "head": ("頭", "头"),
    "foot": ("足首", "つま先", "足先", "爪先", "かかと", "踵", "脚踝"),
    "leg": ("足", "脚", "ひざ", "膝", "もも", "腿"),
    "hand": ("指", "手"),
}
"""Words of scripts that do not separate words, matched as substrings; feet before legs (足首,
the ankle, holds 足, the leg of Japanese rigs)."""
_PART_ORDER = ("head", "foot", "leg", "hand")
_PART_SIDES = ("left", "right", "l", "r")
_PART_CAMEL = re.compile(r"(?<=[a-z0-9])(?=[A-Z])|(?<=[A-Z])(?=[A-Z][a-z])")
_NOT_A_LETTER = re.compile(r"[\W_\d]+")


def name_words(name: str) -> list[str]:
    """A joint name's words, lower case, any script: ``mixamorig:LeftToeBase`` -> mixamorig,
    left, toe, base; a side letter or word stuck to the front of a head, foot or leg word
    split off (``lfoot`` -> l, foot)."""
    limbs = PART_WORDS["head"] | PART_WORDS["foot"] | PART_WORDS["leg"]
    words = []
    for word in _NOT_A_LETTER.split(_PART_CAMEL.sub(" ", name).lower()):
        if not word:
            continue
        for side in _PART_SIDES:
            rest = word[len(side) :]
            if word.startswith(side) and rest in limbs:
                words += [side, rest]
                break
        else:
            words.append(word)
    return words


def body_part(name: str) -> str | None:
    """``"head"``, ``"foot"``, ``"leg"``, ``"hand"`` or None: the body part a joint name says
    (:data:`PART_WORDS`, :data:`PART_CJK`), in that order of precedence."""
    words = set(name_words(name))
    for part in _PART_ORDER:
        if words & PART_WORDS[part] or any(c in name for c in PART_CJK[part]):
            return part
    return None


class ParsedName(NamedTuple):
    """A joint name taken apart (:func:`parse_name`)."""

    key: str
    """The words without side, digits or prefixes, joined: ``upperleg`` of ``upperleg01.R``."""
    side: str | None
    """``"L"``, ``"R"`` or None."""
    words: tuple[str, ...]
    """Every word, lower case, side and digits removed."""


def parse_name(name: str) -> ParsedName:
    """Normalise a joint name: namespace, rig prefix, case, separators, digits and the side
    marker taken out (see the module docstring).

    ``mixamorig:LeftUpLeg`` -> (``upleg``, L); ``thigh_l`` -> (``thigh``, L); ``Bip01 L
    Thigh`` -> (``thigh``, L); ``DEF-thigh.L.001`` -> (``thigh``, L); ``lfemur`` -> (``femur``,
    L); ``HipLeft`` -> (``hip``, L); ``Hips`` -> (``hips``, None).
    """
    text = re.split(r"[:|/]", name)[-1]
    for _ in range(3):  # nested prefixes: "Bip01_DEF-"...
        stripped = _PREFIXES.sub("", text, count=1)
        if stripped == text or not stripped:
            break
        text = stripped
    words = [w for w in _SPLIT.split(_CAMEL.sub(" ", text).lower()) if w]
    side: str | None = None
    kept: list[str] = []
    for w in words:
        if w.isdigit():
            continue
        if w in _SIDE_WORDS and side is None:
            side = _SIDE_WORDS[w]
            continue
        if side is None and len(w) > 2 and w[0] in "lr" and w[1:] in _KNOWN:
            side, w = ("L" if w[0] == "l" else "R"), w[1:]
        kept.append(w)
    return ParsedName("".join(kept), side, tuple(kept))
