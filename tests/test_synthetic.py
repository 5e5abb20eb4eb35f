"""Procedural clips: determinism, skeleton, physical plausibility, channel limits, file trips."""

from __future__ import annotations

import numpy as np
import pytest

from quatmotion import io, quat
from quatmotion.motion import forward_kinematics
from quatmotion.synthetic import (
    KINDS,
    cmu_skeleton,
    foot_positions,
    generate_clip,
    generate_library,
    standing_pose,
)

CMU_JOINTS = (
    "root",
    "lhipjoint",
    "lfemur",
    "ltibia",
    "lfoot",
    "ltoes",
    "rhipjoint",
    "rfemur",
    "rtibia",
    "rfoot",
    "rtoes",
    "lowerback",
    "upperback",
    "thorax",
    "lowerneck",
    "upperneck",
    "head",
    "lclavicle",
    "lhumerus",
    "lradius",
    "lwrist",
    "lhand",
    "lfingers",
    "lthumb",
    "rclavicle",
    "rhumerus",
    "rradius",
    "rwrist",
    "rhand",
    "rfingers",
    "rthumb",
)


def _horizontal_speed(motion) -> np.ndarray:
    """Root speed over the floor per frame, m/s."""
    step = np.diff(motion.root_translation[:, [0, 2]], axis=0)
    return np.linalg.norm(step, axis=1) * motion.fps / 100.0


def _lowest(points: np.ndarray) -> np.ndarray:
    """Height of the lowest of a foot's points per frame: (T, P, 3) -> (T,)."""
    return points[..., 1].min(axis=1)


def _intervals(mask: np.ndarray) -> list[tuple[int, int]]:
    edges = np.diff(np.concatenate(([0], mask.astype(int), [0])))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True))


# --- skeleton ---------------------------------------------------------------------------------


def test_skeleton_has_cmu_layout_and_stands_at_requested_height():
    sk = cmu_skeleton()
    assert sk.joint_names == tuple(CMU_JOINTS)
    assert sk.euler == "extrinsic"
    assert sk.channels[0] == ("tx", "ty", "tz", "rx", "ry", "rz")
    assert sk.channels[sk.index("ltibia")] == ("rx",)
    assert sk.channels[sk.index("lhipjoint")] == ()
    for height in (150.0, 170.0, 190.0):
        pose = standing_pose(cmu_skeleton(height))
        y = forward_kinematics(pose).all_positions()[0, :, 1]
        assert y.max() - y.min() == pytest.approx(height, abs=1e-6)
        assert y.min() == pytest.approx(0.0, abs=1e-9)


def test_skeleton_bone_lengths_are_human():
    sk = cmu_skeleton(170.0)
    thigh = np.linalg.norm(sk.offsets[sk.index("ltibia")])
    shin = np.linalg.norm(sk.offsets[sk.index("lfoot")])
    upper_arm = np.linalg.norm(sk.offsets[sk.index("lradius")])
    assert 38 < thigh < 52 and 36 < shin < 50 and 25 < upper_arm < 36
    # Mirror symmetry: right offsets are the left ones with X negated.
    for name in ("femur", "tibia", "foot", "humerus", "radius"):
        left = sk.offsets[sk.index("l" + name)]
        right = sk.offsets[sk.index("r" + name)]
        np.testing.assert_allclose(right, left * [-1, 1, 1], atol=1e-9)


# --- determinism and API ------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["walk", "jumping_jack"])
def test_same_seed_gives_identical_arrays_and_other_seeds_differ(kind):
    a = generate_clip(kind, 7)
    b = generate_clip(kind, 7)
    c = generate_clip(kind, 8)
    np.testing.assert_array_equal(a.rotations, b.rotations)
    np.testing.assert_array_equal(a.root_translation, b.root_translation)
    n = min(a.n_frames, c.n_frames)
    assert not np.allclose(a.rotations[:n], c.rotations[:n])


@pytest.mark.parametrize("kind", KINDS)
def test_every_kind_gives_valid_unit_quaternion_clip(kind):
    m = generate_clip(kind, 1, n_frames=90, fps=30.0)
    assert m.n_frames == 90 and m.fps == 30.0 and m.rotations.shape == (90, 31, 4)
    np.testing.assert_allclose(np.linalg.norm(m.rotations, axis=-1), 1.0, atol=1e-9)
    assert np.all(np.isfinite(m.root_translation))
    assert m.name.startswith(kind)
    # Feet never go through the floor, and the lowest foot point touches it (or the body is
    # airborne, only ever upwards).
    feet = foot_positions(m)
    lowest = np.minimum(_lowest(feet["l"]), _lowest(feet["r"]))
    assert lowest.min() > -1e-6


def test_bad_arguments_raise_value_error():
    with pytest.raises(ValueError, match="unknown motion kind"):
        generate_clip("moonwalk", 0)
    with pytest.raises(ValueError, match="n_frames"):
        generate_clip("walk", 0, n_frames=0)
    with pytest.raises(ValueError, match="fps"):
        generate_clip("walk", 0, fps=0.0)
    with pytest.raises(ValueError, match="n_per_kind"):
        generate_library(0)
    with pytest.raises(ValueError, match="unknown motion kinds"):
        generate_library(1, kinds=["walk", "fly"])


def test_library_is_labelled_and_reproducible():
    lib = generate_library(2, kinds=["squat", "wave"], seed=3, fps=30.0)
    assert [label for _, label in lib] == ["squat", "squat", "wave", "wave"]
    again = generate_library(2, kinds=["squat", "wave"], seed=3, fps=30.0)
    for (m1, _), (m2, _) in zip(lib, again, strict=True):
        np.testing.assert_array_equal(m1.rotations, m2.rotations)
    assert lib[0][0].name != lib[1][0].name
    assert all(m.skeleton is lib[0][0].skeleton for m, _ in lib)


# --- plausibility -------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_walk_moves_at_walking_speed_with_alternating_planted_feet(seed):
    m = generate_clip("walk", seed, n_frames=480)
    speed = _horizontal_speed(m)
    assert 0.5 <= speed.mean() <= 2.0
    assert speed.max() < 1.6 * speed.mean()  # no lurching
    feet = foot_positions(m)
    contact = {s: _lowest(feet[s]) < 1.0 for s in "lr"}
    swing = {s: _lowest(feet[s]) > 3.0 for s in "lr"}
    for s in "lr":
        # Several steps: contact and clear swing phases alternate.
        assert len(_intervals(contact[s])) >= 2 and len(_intervals(swing[s])) >= 2
    # Always at least one foot on the floor, never both feet in the air.
    assert np.all(contact["l"] | contact["r"])
    assert not np.any(swing["l"] & swing["r"])
    # A planted foot does not skate: its lowest point moves slowly while on the floor.
    for s in "lr":
        pts = feet[s]
        pivot = np.argmin(pts[:-1, :, 1], axis=1)
        rows = np.arange(len(pts) - 1)
        step = pts[rows + 1, pivot] - pts[rows, pivot]
        planted = contact[s][1:] & contact[s][:-1]
        skate = np.linalg.norm(step[planted][:, [0, 2]], axis=1) * m.fps
        assert np.median(skate) < 10.0  # cm/s, against a body speed of 50-200 cm/s


def test_walk_speed_varies_with_style():
    speeds = [_horizontal_speed(generate_clip("walk", s, n_frames=240)).mean() for s in range(6)]
    assert np.std(speeds) > 0.05


def test_run_is_faster_than_walk_and_has_flight():
    run = generate_clip("run", 0, n_frames=360)
    walk = generate_clip("walk", 0, n_frames=360)
    assert _horizontal_speed(run).mean() > 1.5 * _horizontal_speed(walk).mean()
    feet = foot_positions(run)
    airborne = (_lowest(feet["l"]) > 0.5) & (_lowest(feet["r"]) > 0.5)
    assert len(_intervals(airborne)) >= 2


@pytest.mark.parametrize("seed", [0, 1])
def test_squat_lowers_the_hips_with_feet_on_the_floor(seed):
    m = generate_clip("squat", seed)
    drop = m.root_translation[0, 1] - m.root_translation[:, 1].min()
    assert drop > 20.0
    feet = foot_positions(m)
    for s in "lr":
        assert np.abs(_lowest(feet[s])).max() < 1.0
        # The feet stay where they are.
        ankle = feet[s][:, 1, [0, 2]]
        assert np.linalg.norm(ankle - ankle[0], axis=1).max() < 5.0


@pytest.mark.parametrize("seed", [0, 1])
def test_jumping_jack_raises_the_hands_above_the_head(seed):
    m = generate_clip("jumping_jack", seed)
    pos = forward_kinematics(m).positions
    sk = m.skeleton
    head = pos[:, sk.index("head"), 1]
    hands = np.minimum(pos[:, sk.index("lhand"), 1], pos[:, sk.index("rhand"), 1])
    assert hands[0] < head[0] - 30.0  # starts with the arms down
    assert np.any(hands > head + 10.0)
    # The feet spread apart and come back together.
    feet = foot_positions(m)
    width = np.linalg.norm(feet["l"][:, 1] - feet["r"][:, 1], axis=1)
    assert width.max() > width[0] + 20.0


def test_jump_leaves_the_floor():
    m = generate_clip("jump", 2)
    feet = foot_positions(m)
    clearance = np.minimum(_lowest(feet["l"]), _lowest(feet["r"]))
    assert clearance.max() > 5.0
    assert m.root_translation[:, 1].max() > m.root_translation[0, 1] + 5.0


def test_kick_lifts_one_foot_while_the_other_stays_planted():
    m = generate_clip("kick", 4)
    feet = foot_positions(m)
    heights = {s: _lowest(feet[s]) for s in "lr"}
    kicking = max(heights, key=lambda s: heights[s].max())
    support = "r" if kicking == "l" else "l"
    assert heights[kicking].max() > 40.0
    assert heights[support].max() < 2.0


@pytest.mark.parametrize("kind", KINDS)
def test_limited_joints_use_only_their_channels_within_cmu_limits(kind):
    """Each joint with fewer than 3 dofs rotates only about its dof axes, within CMU's limits."""
    m = generate_clip(kind, 5, n_frames=150)
    sk = m.skeleton
    limits = sk.extras["dof_limits_deg"]
    for j in range(1, sk.n_joints):
        dofs = sk.rotation_dofs(j)
        c = sk.axes[j]
        # M = C^-1 L C is the rotation of the joint's channels.
        m_rot = quat.multiply(quat.multiply(quat.conjugate(c), m.rotations[:, j]), c)
        if not dofs:
            np.testing.assert_allclose(quat.angle(m_rot, quat.identity()), 0.0, atol=1e-9)
            continue
        if len(dofs) == 3:
            # Free joints: just human ranges (no joint turns further than 150 deg).
            assert np.degrees(quat.angle(m_rot, quat.identity())).max() < 150.0, sk.joint_names[j]
            continue
        angles = np.degrees(quat.to_euler(m_rot, "xyz"))
        for axis in range(3):
            name = "r" + "xyz"[axis]
            if name in dofs:
                lo, hi = limits[sk.joint_names[j]][dofs.index(name)]
                assert angles[:, axis].min() >= lo - 1e-6 and angles[:, axis].max() <= hi + 1e-6
            else:
                np.testing.assert_allclose(angles[:, axis], 0.0, atol=1e-6)


def test_knees_and_elbows_bend_the_human_way_in_a_run():
    m = generate_clip("run", 6, n_frames=240)
    sk = m.skeleton
    pos = forward_kinematics(m).positions
    heading = m.root_translation[-1, [0, 2]] - m.root_translation[0, [0, 2]]
    forward = heading / np.linalg.norm(heading)
    for side in "lr":
        hip, knee, ankle = (
            pos[:, sk.index(side + n), [0, 2]] @ forward for n in ("femur", "tibia", "foot")
        )
        # Knee in front of the hip-ankle line most of the time (it never hyperextends backwards).
        t = 0.5
        assert np.mean(knee >= hip + t * (ankle - hip) - 1.0) > 0.9


# --- files ---------------------------------------------------------------------------------------


def test_generated_clip_round_trips_through_asf_amc_and_bvh(tmp_path):
    m = generate_clip("wave", 11, n_frames=60)
    io.write_asf(m.skeleton, tmp_path / "gen.asf")
    io.write_amc(m, tmp_path / "gen_01.amc")
    io.write_bvh(m, tmp_path / "gen_01.bvh")
    expected = forward_kinematics(m).positions
    from_amc = io.read_amc(tmp_path / "gen_01.amc", tmp_path / "gen.asf")
    from_bvh = io.read_bvh(tmp_path / "gen_01.bvh")
    np.testing.assert_allclose(forward_kinematics(from_amc).positions, expected, atol=1e-4)
    np.testing.assert_allclose(forward_kinematics(from_bvh).positions, expected, atol=1e-4)


def test_generated_skeletons_carry_the_asf_readers_own_layout(tmp_path):
    """The generated skeleton's ASF bookkeeping is the reader's (quatmotion.io.asf_extras):
    written and read back, every key of the reader's layout is there with the same value."""
    from quatmotion.io import read_asf, write_asf
    from quatmotion.synthetic import cmu_skeleton

    made = cmu_skeleton(163.0)
    write_asf(made, tmp_path / "made.asf")
    read = read_asf(tmp_path / "made.asf")
    reader_keys = set(read.extras) - {"bone_vectors_cm"}
    assert reader_keys <= set(made.extras)
    for key in ("format", "asf_units", "asf_root", "asf_hierarchy", "angle_unit"):
        assert made.extras[key] == read.extras[key], key
    assert [b["name"] for b in made.extras["asf_bones"]] == [
        b["name"] for b in read.extras["asf_bones"]
    ]
    assert set(made.extras["asf_bones"][0]) == set(read.extras["asf_bones"][0])
