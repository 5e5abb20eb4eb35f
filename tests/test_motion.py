"""Skeleton and Motion invariants, and forward kinematics on chains with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from quatmotion import quat
from quatmotion.motion import Motion, Skeleton, forward_kinematics, standing_height


def chain(n: int = 3, length: float = 10.0) -> Skeleton:
    offsets = np.zeros((n, 3))
    offsets[1:, 0] = length
    return Skeleton(
        joint_names=tuple(f"j{i}" for i in range(n)),
        parents=np.arange(-1, n - 1),
        offsets=offsets,
        channels=(("tx", "ty", "tz", "rx", "ry", "rz"),) + (("rx", "ry", "rz"),) * (n - 1),
        site_names=("tip",),
        site_parents=np.array([n - 1]),
        site_offsets=np.array([[length, 0.0, 0.0]]),
        name="chain",
    )


def test_rest_positions_and_height():
    sk = chain(3, 10.0)
    np.testing.assert_allclose(sk.rest_positions(), [[0, 0, 0], [10, 0, 0], [20, 0, 0], [30, 0, 0]])
    assert sk.height() == 0.0
    assert sk.index("j2") == 2
    with pytest.raises(KeyError, match="no joint"):
        sk.index("nope")


def test_fk_quarter_turns_about_z_fold_the_chain():
    sk = chain(3, 10.0)
    quarter_z = quat.from_euler([0, 0, np.pi / 2], "XYZ")
    rot = np.tile(quat.identity(), (1, 3, 1))
    rot[0, 1] = quarter_z
    motion = Motion(sk, 30.0, np.array([[1.0, 2.0, 3.0]]), rot)
    pose = forward_kinematics(motion)
    # Joint 1 is placed by the root (identity), then turns its child 90 degrees to +Y.
    np.testing.assert_allclose(pose.positions[0], [[1, 2, 3], [11, 2, 3], [11, 12, 3]], atol=1e-12)
    np.testing.assert_allclose(pose.site_positions[0], [[11, 22, 3]], atol=1e-12)
    np.testing.assert_allclose(np.abs(quat.dot(pose.rotations[0, 2], quarter_z)), 1.0, atol=1e-12)


def test_fk_preserves_bone_lengths_and_is_vectorised_over_frames():
    rng = np.random.default_rng(0)
    sk = chain(5, 7.0)
    rot = quat.normalize(rng.normal(size=(40, 5, 4)))
    motion = Motion(sk, 120.0, rng.normal(size=(40, 3)), rot)
    pose = forward_kinematics(motion)
    lengths = np.linalg.norm(np.diff(pose.all_positions(), axis=1), axis=-1)
    np.testing.assert_allclose(lengths, 7.0, atol=1e-10)
    one = forward_kinematics(motion.slice(7, 8))
    np.testing.assert_allclose(one.positions[0], pose.positions[7], atol=1e-12)


def test_joint_translations_replace_offsets():
    sk = chain(2, 10.0)
    jt = np.zeros((1, 2, 3))
    jt[0, 1] = (0.0, 5.0, 0.0)
    motion = Motion(sk, 30.0, np.zeros((1, 3)), quat.identity((1, 2)), joint_translations=jt)
    np.testing.assert_allclose(forward_kinematics(motion).positions[0, 1], [0, 5, 0])


def test_motion_makes_rotations_continuous_and_validates():
    sk = chain(2)
    path = quat.exp(
        np.linspace(0, 2, 30)[:, None, None] * np.array([[0.1, 0.4, 0.0], [0.0, 0.2, 0.3]])
    )
    signs = np.where(np.arange(30) % 3 == 0, -1.0, 1.0)[:, None, None]
    m = Motion(sk, 60.0, np.zeros((30, 3)), path * signs)
    assert np.all(quat.dot(m.rotations[1:], m.rotations[:-1]) > 0)
    assert m.duration == pytest.approx(0.5)
    with pytest.raises(ValueError, match="rotations has shape"):
        Motion(sk, 60.0, np.zeros((30, 3)), path[:, :1])
    with pytest.raises(ValueError, match="unit"):
        Motion(sk, 60.0, np.zeros((30, 3)), path * 2)
    with pytest.raises(ValueError, match="finite"):
        Motion(sk, 60.0, np.full((30, 3), np.nan), path)
    with pytest.raises(ValueError):
        m.rotations[0, 0, 0] = 1.0  # frozen arrays


def test_skeleton_rejects_bad_hierarchies():
    with pytest.raises(ValueError, match="parents"):
        Skeleton(("a", "b"), np.array([-1, 1]), np.zeros((2, 3)), ((), ()))
    with pytest.raises(ValueError, match="unique"):
        Skeleton(("a", "a"), np.array([-1, 0]), np.zeros((2, 3)), ((), ()))
    with pytest.raises(ValueError, match="channels"):
        Skeleton(("a", "b"), np.array([-1, 0]), np.zeros((2, 3)), ((), ("qq",)))


def test_standing_height_measures_the_posed_figure_not_the_rest_pose():
    # A chain lying along X at rest (height 0) is stood up by a quarter turn of its root.
    sk = chain(4, 10.0)
    rot = np.tile(quat.identity(), (5, 4, 1))
    rot[:, 0] = quat.from_euler([0, 0, np.pi / 2], "XYZ")
    motion = Motion(sk, 30.0, np.zeros((5, 3)), rot)
    assert sk.height() == 0.0
    assert standing_height(motion) == pytest.approx(40.0)


def test_angular_displacements_recompose_the_rotations():
    from quatmotion.motion import angular_displacements

    sk = Skeleton(
        joint_names=("root", "a", "still"),
        parents=np.array([-1, 0, 1]),
        offsets=np.zeros((3, 3)),
        channels=(("tx", "ty", "tz", "rx", "ry", "rz"), ("rx", "ry"), ()),
    )
    rng = np.random.default_rng(0)
    rot = quat.normalize(rng.standard_normal((9, 3, 4)))
    rot[:, 2] = (1.0, 0.0, 0.0, 0.0)  # a joint without rotation channels never turns
    motion = Motion(sk, 30.0, np.zeros((9, 3)), rot)
    np.testing.assert_array_equal(sk.rotating_joints(), [0, 1])
    d = angular_displacements(motion, reference_frame=2, step=2)
    assert d.shape == (5, 2, 4)
    # q_ref d_t = q_t for the kept frames 0, 2, 4, 6, 8; the reference frame maps to identity.
    recomposed = quat.multiply(motion.rotations[2, :2], d)
    np.testing.assert_allclose(quat.angle(recomposed, motion.rotations[::2, :2]), 0, atol=1e-7)
    np.testing.assert_allclose(quat.angle(d[1], quat.identity((2,))), 0, atol=1e-7)
    with pytest.raises(ValueError, match="frames 0..8"):
        angular_displacements(motion, reference_frame=9)
    with pytest.raises(ValueError, match="step"):
        angular_displacements(motion, step=0)
