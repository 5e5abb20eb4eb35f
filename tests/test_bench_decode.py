"""The decode benchmark's own measuring parts (the benchmark itself is not a test)."""

import numpy as np
import pytest

from quatmotion import quat
from quatmotion.bench.decode import independent_positions
from quatmotion.motion import forward_kinematics
from quatmotion.synthetic import generate_clip


@pytest.fixture(scope="module")
def clip():
    return generate_clip("walk", 3, n_frames=30)


def test_independent_fk_agrees_with_the_package(clip):
    ours = forward_kinematics(clip).all_positions()
    assert np.abs(independent_positions(clip) - ours).max() < 1e-9


def test_independent_fk_sees_a_turned_joint(clip):
    turned = clip.rotations.copy()
    j = clip.skeleton.n_joints // 2
    turned[:, j] = quat.multiply(turned[:, j], quat.about_axis(np.full(len(turned), 0.1), "x"))
    moved = type(clip)(clip.skeleton, clip.fps, clip.root_translation, turned, None, clip.name)
    d = np.linalg.norm(independent_positions(moved) - independent_positions(clip), axis=-1)
    assert d.max() > 0.1
