"""Every skeleton in the data comes out human-sized in centimetres (a check on units).

ASF skeletons stand upright at rest, so ``Skeleton.height()`` (the vertical extent of the rest
pose) is their standing height and must lie in [140, 210] cm.

BVH rest poses are not all standing poses: the Bandai hierarchy lies along +-X at rest (its
``height()`` is about 100 cm, the hip offset), and the CMU BVH conversion's rest pose measures
138 cm (a shorter head and neck than the ASF, legs splayed). For BVH the figure is measured
in motion instead: the hips' height and the vertical extent of all joints and end sites. A
wrong unit (mm, m, inch, or the ASF unit of 1/0.45 inch) would be off by a factor of 2.5 or
more, far outside the bands below.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from quatmotion.datasets import data_root
from quatmotion.io import read_asf, read_bvh
from quatmotion.motion import forward_kinematics

DATA = data_root(must_exist=False)

pytestmark = pytest.mark.needs_data
ASFS = (
    sorted(DATA.glob("cmu/*/*.asf")) + sorted(DATA.glob("hdm05/skeletons/*.asf"))
    if DATA.is_dir()
    else []
)
BVH_FAMILIES = {"bandai1": "bandai1/clips/*.bvh", "cmu_bvh": "cmu_bvh/*/*.bvh"}


@pytest.mark.parametrize("asf", ASFS, ids=lambda p: p.stem)
def test_asf_skeleton_stands_between_140_and_210_cm(asf: Path):
    height = read_asf(asf).height()
    assert 140.0 <= height <= 210.0, f"{asf.name}: {height:.1f} cm"


def test_every_asf_family_is_present():
    assert {p.parent.parent.name for p in ASFS} >= {"cmu", "hdm05"}


@pytest.mark.parametrize("family", sorted(BVH_FAMILIES))
def test_bvh_figures_are_human_sized(family: str):
    clips = sorted(DATA.glob(BVH_FAMILIES[family]))
    assert clips
    statures, hips = [], []
    for clip in clips:
        motion = read_bvh(clip).slice(0, None, 10)
        positions = forward_kinematics(motion).all_positions()
        y = positions[..., 1]
        statures.append(np.median(y.max(axis=1) - y.min(axis=1)))
        hip = next(i for i, n in enumerate(motion.skeleton.joint_names) if "hip" in n.lower())
        hips.append(np.median(positions[:, hip, 1] - y.min(axis=1)))
    # Joints stop short of the crown of the head (Bandai's head end site has zero length).
    assert 120.0 <= np.median(statures) <= 210.0, f"{family}: stature {np.median(statures):.1f}"
    assert 75.0 <= np.median(hips) <= 115.0, f"{family}: hips {np.median(hips):.1f}"
