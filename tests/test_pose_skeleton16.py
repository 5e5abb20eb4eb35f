"""Tests of the 16-joint pose skeleton and its body-local frame."""

from __future__ import annotations

import numpy as np
import pytest

from quatmotion import quat
from quatmotion.datasets import data_root
from quatmotion.motion import Motion, Skeleton, forward_kinematics
from quatmotion.pose import skeleton16 as s16

DATA = data_root(must_exist=False)

# A Bandai-named skeleton in a T-pose facing +Z (left is +X), offsets in cm.
_BONES = [
    ("Hips", None, (0, 95, 0)),
    ("Chest", "Hips", (0, 25, 0)),
    ("Neck", "Chest", (0, 20, 0)),
    ("Head", "Neck", (0, 12, 0)),
    ("UpperArm_L", "Chest", (18, 15, 0)),
    ("LowerArm_L", "UpperArm_L", (28, 0, 0)),
    ("Hand_L", "LowerArm_L", (25, 0, 0)),
    ("UpperArm_R", "Chest", (-18, 15, 0)),
    ("LowerArm_R", "UpperArm_R", (-28, 0, 0)),
    ("Hand_R", "LowerArm_R", (-25, 0, 0)),
    ("UpperLeg_L", "Hips", (9, -5, 0)),
    ("LowerLeg_L", "UpperLeg_L", (0, -42, 0)),
    ("Foot_L", "LowerLeg_L", (0, -40, 0)),
    ("UpperLeg_R", "Hips", (-9, -5, 0)),
    ("LowerLeg_R", "UpperLeg_R", (0, -42, 0)),
    ("Foot_R", "LowerLeg_R", (0, -40, 0)),
]


def _skeleton(names: list[str] | None = None) -> Skeleton:
    names = names or [b[0] for b in _BONES]
    index = {b[0]: i for i, b in enumerate(_BONES)}
    parents = [-1 if p is None else index[p] for _, p, _ in _BONES]
    channels = [("tx", "ty", "tz", "rz", "rx", "ry")] + [("rz", "rx", "ry")] * (len(_BONES) - 1)
    return Skeleton(
        joint_names=tuple(names),
        parents=np.array(parents),
        offsets=np.array([o for _, _, o in _BONES], dtype=float),
        channels=tuple(channels),
        name="synthetic",
    )


def _motion(rng: np.random.Generator, T: int = 12, spread: float = 0.4) -> Motion:
    sk = _skeleton()
    rot = quat.exp(rng.normal(scale=spread, size=(T, sk.n_joints, 3)))
    trans = rng.normal(scale=50, size=(T, 3)) + np.array([0, 95, 0])
    return Motion(sk, 30.0, trans, rot)


def _yaw_quat(theta: float) -> np.ndarray:
    return np.array([np.cos(theta / 2), 0.0, np.sin(theta / 2), 0.0])


def test_joint_tables_are_a_tree_with_end_site_leaves() -> None:
    assert len(s16.JOINTS_16) == len(s16.PARENTS_16) == 16
    assert s16.PARENTS_16[0] == -1
    assert all(0 <= p < j for j, p in enumerate(s16.PARENTS_16) if j > 0)
    leaves = {j for j in range(16) if j not in s16.PARENTS_16}
    assert leaves == set(s16.END_SITES_16)
    assert {s16.JOINTS_16[j] for j in s16.END_SITES_16} == {
        "Head",
        "LHand",
        "RHand",
        "LFoot",
        "RFoot",
    }


def test_world_positions_pick_the_mapped_joints() -> None:
    motion = _motion(np.random.default_rng(0))
    fk = forward_kinematics(motion, include_sites=False).positions
    assert s16.skeleton_kind(motion.skeleton) == "bandai"
    np.testing.assert_allclose(s16.world_positions16(motion), fk)  # synthetic order is JOINTS_16


def test_a_joint_without_a_known_name_is_found_by_structure() -> None:
    names = [b[0] for b in _BONES]
    names[names.index("Foot_L")] = "LeftToe"
    mapping = s16.humanoid_map(_skeleton(names))
    k = s16.JOINTS_16.index("LFoot")
    assert mapping.points[k] == "LeftToe" and mapping.how[k] == "structure"
    np.testing.assert_array_equal(s16.joint_indices16(_skeleton(names)), np.arange(16))


def test_rest_pose_faces_plus_z_and_yaw_is_recovered() -> None:
    sk = _skeleton()
    for theta in (0.0, 0.7, -2.5, 3.0):
        rot = np.tile(quat.identity((1, sk.n_joints)), (1, 1, 1))
        rot[:, 0] = _yaw_quat(theta)
        m = Motion(sk, 30.0, np.array([[10.0, 95.0, -4.0]]), rot)
        yaw = s16.facing_yaw(s16.world_positions16(m))
        assert np.isclose(np.angle(np.exp(1j * (yaw[0] - theta))), 0.0, atol=1e-9)
        local = s16.local_positions16(m)
        np.testing.assert_allclose(local[0], sk.rest_positions(False) - sk.offsets[0], atol=1e-9)
        assert local[0, s16.JOINTS_16.index("LHip"), 0] > 0  # left is +X


@pytest.mark.parametrize("theta", [0.3, -1.9, np.pi])
def test_local_frame_is_invariant_to_translation_and_yaw(theta: float) -> None:
    rng = np.random.default_rng(1)
    m = _motion(rng)
    shift = np.array([123.0, 0.0, -77.0])
    rot = m.rotations.copy()
    rot[:, 0] = quat.multiply(_yaw_quat(theta), rot[:, 0])
    moved = Motion(
        m.skeleton, m.fps, quat.rotate(_yaw_quat(theta), m.root_translation) + shift, rot
    )
    # the world poses moved rigidly ...
    w0, w1 = s16.world_positions16(m), s16.world_positions16(moved)
    np.testing.assert_allclose(w1, quat.rotate(_yaw_quat(theta), w0) + shift, atol=1e-8)
    # ... the body-local ones did not
    np.testing.assert_allclose(s16.local_positions16(moved), s16.local_positions16(m), atol=1e-8)
    np.testing.assert_allclose(
        s16.local_positions16(moved, keep_height=True),
        s16.local_positions16(m, keep_height=True),
        atol=1e-8,
    )
    r0, r1 = s16.local_rotations16(m), s16.local_rotations16(moved)
    np.testing.assert_allclose(quat.angle(r0, r1), 0.0, atol=1e-6)


def test_local_frame_keeps_shape_height_and_scale() -> None:
    m = _motion(np.random.default_rng(2))
    w = s16.world_positions16(m)
    local = s16.local_positions16(m)
    assert np.allclose(local[:, 0], 0.0)
    # a rigid map: all pairwise joint distances survive
    dw = np.linalg.norm(w[:, :, None] - w[:, None], axis=-1)
    dl = np.linalg.norm(local[:, :, None] - local[:, None], axis=-1)
    np.testing.assert_allclose(dl, dw, atol=1e-9)
    # the hip line is along X: no forward component between the hips
    hips = local[:, s16.JOINTS_16.index("LHip")] - local[:, s16.JOINTS_16.index("RHip")]
    np.testing.assert_allclose(hips[:, 2], 0.0, atol=1e-9)
    assert np.all(hips[:, 0] >= 0)
    high = s16.local_positions16(m, keep_height=True)
    np.testing.assert_allclose(high[:, 0, 1], w[:, 0, 1])
    np.testing.assert_allclose(high - high[:, :1], local, atol=1e-9)
    scaled = s16.local_positions16(m, height=2 * s16.stature16(m.skeleton))
    np.testing.assert_allclose(scaled, 2 * local, atol=1e-9)
    # the stature is the ankle-knee-hip-Hip-Chest-Neck-Head bone chain: 40+42+hip+25+20+12 cm
    assert s16.stature16(m.skeleton) == pytest.approx(40 + 42 + np.hypot(9, 5) + 25 + 20 + 12)


def _reference(name: str) -> dict[str, np.ndarray]:
    with np.load(DATA / "reference" / f"{name}.npz") as z:
        return {k: z[k] for k in z.files}


# An ASF joint sits at its bone's start; the reference places each bone's END: so each 16-joint
# point is the end of the mapped bone's parent bone.
_ASF_PARENT_BONE = {
    "root": "root", "thorax": "upperback", "lowerneck": "thorax", "head": "upperneck",
    "lhumerus": "lclavicle", "lradius": "lhumerus", "lwrist": "lradius",
    "rhumerus": "rclavicle", "rradius": "rhumerus", "rwrist": "rradius",
    "lfemur": "lhipjoint", "ltibia": "lfemur", "lfoot": "ltibia",
    "rfemur": "rhipjoint", "rtibia": "rfemur", "rfoot": "rtibia",
}  # fmt: skip


@pytest.mark.needs_data
@pytest.mark.parametrize(
    ("ref", "path"),
    [
        ("02_01", "cmu/02/02_01.amc"),
        (
            "HDM_bd_kickLFront1Reps_003_120",
            "hdm05/clips/kickLFront1Reps/HDM_bd_kickLFront1Reps_003_120.amc",
        ),
    ],
)
def test_asf_positions_match_independent_reference(ref: str, path: str) -> None:
    from quatmotion.io import read_amc

    motion = read_amc(DATA / path)
    assert s16.skeleton_kind(motion.skeleton) == "asf"
    r = _reference(ref)
    names = [str(n) for n in r["joint_names"]]
    bones = [s16._JOINT_MAPS["asf"][k] for k in range(16)]
    expected = r["positions_cm"][:, [names.index(_ASF_PARENT_BONE[b]) for b in bones]]
    got = s16.world_positions16(motion)[: len(expected)]
    np.testing.assert_allclose(got, expected, atol=1e-3)
    # a walking body faces where it goes: the hip-line yaw agrees with the root's travel
    if ref == "02_01":
        local_fwd = np.stack([np.sin(s16.facing_yaw(got)), np.cos(s16.facing_yaw(got))], 1)
        travel = np.gradient(got[:, 0, [0, 2]], axis=0)
        cos = np.sum(local_fwd * travel, 1) / np.linalg.norm(travel, axis=1)
        assert np.median(cos) > 0.9


@pytest.mark.needs_data
def test_bandai_bvh_positions_match_independent_reference() -> None:
    from quatmotion.io import read_bvh

    motion = read_bvh(DATA / "bandai1" / "clips" / "dataset-1_walk_normal_001.bvh")
    assert s16.skeleton_kind(motion.skeleton) == "bandai"
    r = _reference("dataset-1_walk_normal_001")
    names = [str(n) for n in r["joint_names"]]
    expected = r["positions_file_units"][:, [names.index(n) for n in s16._JOINT_MAPS["bandai"]]]
    got = s16.world_positions16(motion)[: len(expected)]
    np.testing.assert_allclose(got, expected, atol=1e-3)


def _reproportioned(motion: Motion, factors: dict[str, float], default: float) -> Motion:
    """``motion`` on a skeleton whose bones are scaled (``factors`` by joint, whose offset is
    its parent bone), the root carried by ``default`` too, as a body of those legs would be."""
    sk = motion.skeleton
    scale = np.array([factors.get(name, default) for name in sk.joint_names])
    skeleton = Skeleton(
        joint_names=sk.joint_names,
        parents=sk.parents,
        offsets=sk.offsets * scale[:, None],
        channels=sk.channels,
        euler=sk.euler,
        axes=sk.axes,
        site_names=sk.site_names,
        site_parents=sk.site_parents,
        site_offsets=sk.site_offsets * default,
        name="reproportioned",
        extras=dict(sk.extras),
    )
    return Motion(skeleton, motion.fps, motion.root_translation * default, motion.rotations)


def test_a_pose_on_a_body_of_other_proportions_gets_the_same_description() -> None:
    """Issue 9 (1): the same motion on a body with 1.3x legs and trunk, 0.7x arms and a neck
    twice as long is described exactly as on the original body."""
    from quatmotion.pose.data import PoseClip
    from quatmotion.synthetic import generate_clip

    motion = generate_clip("jumping_jack", 5, n_frames=60)
    arms = {n: 0.7 for n in ("lradius", "lwrist", "rradius", "rwrist")}
    other = _reproportioned(motion, {**arms, "upperneck": 2.0, "head": 2.0}, default=1.3)
    a = PoseClip.from_motion(motion, fps=30, height=170)
    b = PoseClip.from_motion(other, fps=30, height=170)
    np.testing.assert_allclose(b.world, a.world, atol=1e-8)
    np.testing.assert_allclose(b.poses.gpd, a.poses.gpd, atol=1e-6)
    # the canonical body's bones, whatever the file's
    lengths = np.linalg.norm(a.world[:, 1:] - a.world[:, list(s16.PARENTS_16[1:])], axis=-1)
    np.testing.assert_allclose(lengths, np.broadcast_to(s16.canonical_bone_lengths(170)[1:],
                                                        lengths.shape), atol=1e-9)  # fmt: skip


def test_a_skeleton_whose_mapped_joints_coincide_is_refused() -> None:
    bones = [list(b) for b in _BONES]
    bones[10][2] = bones[13][2] = (0, -5, 0)  # both hip joints at one point
    index = {b[0]: i for i, b in enumerate(bones)}
    sk = Skeleton(
        joint_names=tuple(b[0] for b in bones),
        parents=np.array([-1 if p is None else index[p] for _, p, _ in bones]),
        offsets=np.array([o for _, _, o in bones], dtype=float),
        channels=(("tx", "ty", "tz", "rz", "rx", "ry"),) + (("rz", "rx", "ry"),) * 15,
        name="narrow",
    )
    motion = Motion(sk, 30.0, np.array([[0.0, 95.0, 0.0]] * 3), quat.identity((3, 16)))
    with pytest.raises(ValueError, match=r"narrow.*Hip-LHip.*one point"):
        s16.canonical_positions16(motion)


def test_a_mirrored_clip_swaps_left_and_right() -> None:
    from quatmotion.pose.data import PoseClip
    from quatmotion.synthetic import generate_clip

    clip = PoseClip.from_motion(generate_clip("wave", 2, n_frames=40), fps=30, height=170)
    mirror = clip.mirrored()
    left, right = s16.JOINTS_16.index("LHand"), s16.JOINTS_16.index("RHand")
    flip = np.array([-1.0, 1.0, 1.0])
    np.testing.assert_allclose(mirror.local[:, left], clip.local[:, right] * flip, atol=1e-9)
    np.testing.assert_allclose(mirror.local[:, right], clip.local[:, left] * flip, atol=1e-9)
    np.testing.assert_allclose(mirror.mirrored().poses.gpd, clip.poses.gpd, atol=1e-9)
