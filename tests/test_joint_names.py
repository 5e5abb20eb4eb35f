"""One home for joint-name knowledge (issue 31): the body parts find_body reads by name
(quatmotion.io.units) are motion.humanoid's words, and in every naming family the ankles it
finds are the feet the 16-joint mapping finds."""

from __future__ import annotations

import pytest

from quatmotion.io import find_body
from quatmotion.motion import JOINTS_16, map_humanoid
from quatmotion.motion.humanoid import ALIASES, PART_WORDS, body_part, name_words
from quatmotion.synthetic import generate_clip
from quatmotion.synthetic.rerig import FAMILIES, rerig


@pytest.mark.parametrize(
    ("name", "part"),
    [
        ("Head", "head"), ("mixamorig:HeadTop_End", "head"), ("Kopf", "head"), ("頭", "head"),
        ("lfoot", "foot"), ("Bip01 L Foot", "foot"), ("足首_L", "foot"), ("ball_l", None),
        ("thigh_l", "leg"), ("LeftUpLeg", "leg"), ("rtibia", "leg"), ("Oberschenkel.R", "leg"),
        ("LeftHandIndex1", "hand"), ("wrist_r", "hand"), ("Hips", None), ("LHip", None),
        ("spine_01", None),
    ],
)  # fmt: skip
def test_body_parts_by_name(name, part):
    assert body_part(name) == part


def test_the_mappings_keys_name_their_body_parts():
    for canonical, part in (("Head", "head"), ("Foot", "foot"), ("Hand", "hand"), ("Knee", "leg")):
        for key in ALIASES[canonical]:
            assert key in PART_WORDS[part], (canonical, key)
    assert name_words("lfoot") == ["l", "foot"] and name_words("LeftToeBase")[:2] == ["left", "toe"]


@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_find_body_and_the_mapping_agree_on_the_feet(family):
    motion = rerig(generate_clip("walk", 0), family).motion
    body = find_body(motion.skeleton)
    assert body is not None and body.head is not None and len(body.ankles) == 2
    points = motion.skeleton.joint_names + motion.skeleton.site_names
    mapped = map_humanoid(motion.skeleton).points
    feet = {mapped[JOINTS_16.index("LFoot")], mapped[JOINTS_16.index("RFoot")]}
    assert {points[a] for a in body.ankles} == feet
