"""GPD features (section 3), their normalisation and PoseData."""

from __future__ import annotations

import re

import numpy as np
import pytest

from quatmotion import quat
from quatmotion.datasets import data_root
from quatmotion.pose import gpd, skeleton16
from quatmotion.pose.data import PoseClip, PoseData, angular_velocities, joint_orientations
from quatmotion.pose.scaler import MinMaxUnitScaler
from quatmotion.pose.skeleton16 import JOINTS_16, PARENTS_16

DATA = data_root(must_exist=False)

J = {name: k for k, name in enumerate(JOINTS_16)}


def t_pose(hip_height: float = 95.0) -> np.ndarray:
    """A body-local T-pose with the left forearm raised (so the arm plane is z = 0)."""
    p = {
        "Hip": (0, 0, 0), "Chest": (0, 20, 0), "Neck": (0, 45, 0), "Head": (0, 60, 5),
        "LShoulder": (15, 40, 0), "LElbow": (45, 40, 0), "LHand": (45, 70, 0),
        "RShoulder": (-15, 40, 0), "RElbow": (-45, 40, 0), "RHand": (-70, 40, 0),
        "LHip": (10, 0, 0), "LKnee": (10, -45, 0), "LFoot": (10, -90, 30),
        "RHip": (-10, 0, 0), "RKnee": (-10, -45, 0), "RFoot": (-10, -90, 0),
    }  # fmt: skip
    return np.array([p[name] for name in JOINTS_16], dtype=np.float64)[None]


def random_poses(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return t_pose() + rng.normal(scale=8.0, size=(n, 16, 3))


def column(name: str) -> int:
    return gpd.FEATURE_NAMES.index(name)


# ------------------------------------------------------------------------------------------
def test_feature_counts_and_names_follow_the_geometry() -> None:
    assert gpd.N_FEATURES == 1337
    assert gpd.N_DIMENSIONS == 1683 == len(gpd.FEATURE_NAMES) == len(set(gpd.FEATURE_NAMES))
    dims = {k: s.stop - s.start for k, s in gpd.FEATURE_SLICES.items()}
    assert dims == {"J_c": 46, "JJ_d": 120, "JJ_o": 360, "JL_d": 420, "LL_a": 435, "JP_d": 65,
                    "LP_a": 135, "PP_a": 10, "J_k": 92}  # fmt: skip
    assert gpd.FEATURE_COUNTS["JP_d"] == 16 * 5 - 15
    assert gpd.FEATURE_COUNTS["LL_a"] == 30 * 29 // 2
    for kind, sl in gpd.FEATURE_SLICES.items():
        assert all(n.startswith(kind + "(") for n in gpd.FEATURE_NAMES[sl])
    # 30 lines: 15 limbs, 5 end site <- grandparent, 10 between end sites; no repeats.
    assert len(gpd.LINES) == 30 == len({frozenset(line) for line in gpd.LINES})
    names = {(JOINTS_16[a], JOINTS_16[b]) for a, b in gpd.LINES}
    wanted = {("Chest", "Head"), ("LShoulder", "LHand"), ("RHip", "RFoot"), ("LHand", "RFoot")}
    assert wanted <= names
    # Degenerate features are gone: no joint measured against a line or plane through it.
    for name in gpd.FEATURE_NAMES[gpd.FEATURE_SLICES["JL_d"]]:
        joint, a, b = re.fullmatch(r"JL_d\((\w+),L\((\w+)->(\w+)\)\)", name).groups()
        assert joint not in (a, b)


def test_limbs_are_the_bones_of_skeleton16() -> None:
    # The GPD's first 15 lines are the limbs parent -> child of the one 16-joint skeleton.
    limbs = {(PARENTS_16[k], k) for k in range(1, len(JOINTS_16))}
    assert set(gpd.LINES[: len(limbs)]) == limbs


def _reference_feature(name: str, pos: np.ndarray, vel: np.ndarray, acc: np.ndarray,
                       height: float) -> float:  # fmt: skip
    """Each feature computed on its own from its name, straight from the definitions."""

    def p(joint: str) -> np.ndarray:
        return pos[J[joint]] - pos[J["Hip"]]

    def unit(v: np.ndarray) -> np.ndarray:
        return v / np.linalg.norm(v)

    def line(text: str) -> np.ndarray:
        a, b = re.fullmatch(r"L\((\w+)->(\w+)\)", text).groups()
        return unit(p(b) - p(a))

    def plane(text: str) -> tuple[np.ndarray, np.ndarray]:
        a, b, c = re.fullmatch(r"P\((\w+)->(\w+)->(\w+)\)", text).groups()
        return p(a), unit(np.cross(p(b) - p(a), p(c) - p(a)))

    kind, args = re.fullmatch(r"(\w+)\((.*)\)(?:\.\w+)?", name).groups()
    axis = "xyz".find(name[-1]) if "." in name.split(")")[-1] else -1
    parts = re.split(r",(?![^()]*\))", args)
    if kind == "J_c":
        return height if name.endswith("y_world") else p(parts[0])[axis]
    if kind == "JJ_d":
        return float(np.linalg.norm(p(parts[1]) - p(parts[0])))
    if kind == "JJ_o":
        return unit(p(parts[1]) - p(parts[0]))[axis]
    if kind == "JL_d":
        a, b = re.fullmatch(r"L\((\w+)->(\w+)\)", parts[1]).groups()
        # Eq. 4 with Heron's formula, as the paper suggests.
        x, y, z = (np.linalg.norm(p(parts[0]) - p(a)), np.linalg.norm(p(parts[0]) - p(b)),
                   np.linalg.norm(p(b) - p(a)))  # fmt: skip
        s = (x + y + z) / 2
        return 2 * np.sqrt(max(s * (s - x) * (s - y) * (s - z), 0.0)) / z
    if kind == "LL_a":
        return float(np.arccos(np.clip(line(parts[0]) @ line(parts[1]), -1, 1)))
    if kind == "JP_d":
        origin, normal = plane(parts[1])
        return float((p(parts[0]) - origin) @ normal)
    if kind == "LP_a":
        return float(np.arccos(np.clip(line(parts[0]) @ plane(parts[1])[1], -1, 1)))
    if kind == "PP_a":
        return float(np.arccos(np.clip(plane(parts[0])[1] @ plane(parts[1])[1], -1, 1)))
    assert kind == "J_k"
    joint, comp = parts[0], name.split(".")[-1]
    source = vel if comp.startswith("v") else acc
    return source[J[joint]]["xyz".index(comp[1])]


def test_every_dimension_matches_its_name() -> None:
    rng = np.random.default_rng(3)
    pos = random_poses(2, seed=4) + rng.normal(scale=50, size=(2, 1, 3))  # hip anywhere
    vel = rng.normal(size=(2, 16, 3)) * 30
    acc = rng.normal(size=(2, 16, 3)) * 300
    height = np.array([91.0, 40.0])
    features = gpd.gpd_features(pos, vel, acc, height)
    assert features.shape == (2, 1683)
    for i in range(2):
        expected = [_reference_feature(n, pos[i], vel[i], acc[i], height[i])
                    for n in gpd.FEATURE_NAMES]  # fmt: skip
        np.testing.assert_allclose(features[i], expected, rtol=1e-7, atol=1e-7)


def test_known_geometry_of_a_t_pose() -> None:
    f = gpd.gpd_features(t_pose(), hip_height=np.array([95.0]))[0]
    right = np.pi / 2
    expected = {
        "J_c(LElbow).x": 45.0,
        "J_c(Hip).y_world": 95.0,
        "JJ_d(LShoulder,LElbow)": 30.0,
        "JJ_o(LShoulder,LElbow).x": 1.0,
        "JL_d(Head,L(RShoulder->RElbow))": np.hypot(20.0, 5.0),
        # A straight arm: upper arm and forearm are collinear, so the elbow is on the line.
        "JL_d(RElbow,L(RShoulder->RHand))": 0.0,
        "LL_a(L(RShoulder->RElbow),L(RElbow->RHand))": 0.0,
        "LL_a(L(Hip->Chest),L(LHip->LKnee))": np.pi,
        "LL_a(L(LShoulder->LElbow),L(LElbow->LHand))": right,
        "LL_a(L(Chest->LShoulder),L(Chest->RShoulder))": 2 * np.arctan2(15, 20),
        # Points on the left-arm plane (z = 0) have distance 0; the left foot is 30 cm off it.
        "JP_d(Chest,P(LShoulder->LElbow->LHand))": 0.0,
        "JP_d(RHand,P(LShoulder->LElbow->LHand))": 0.0,
        "JP_d(LFoot,P(LShoulder->LElbow->LHand))": 30.0,
        "LP_a(L(Hip->Chest),P(LShoulder->LElbow->LHand))": right,
        "PP_a(P(Chest->Neck->Head),P(LShoulder->LElbow->LHand))": right,
    }
    for name, value in expected.items():
        assert f[column(name)] == pytest.approx(value, abs=1e-9), name


def test_invariant_to_horizontal_translation_and_yaw() -> None:
    rng = np.random.default_rng(0)
    world = random_poses(40, seed=1) + np.array([3.0, 95.0, -7.0])
    world += np.cumsum(rng.normal(size=(40, 1, 3)), axis=0)  # a moving clip
    yaw = 1.1
    turn = quat.from_euler(np.array([0.0, yaw, 0.0]), "xyz")
    moved = quat.rotate(turn, world) + np.array([250.0, 0.0, -80.0])
    a = PoseData.from_clip(skeleton16.to_body_frame(world, keep_height=True), 120.0)
    b = PoseData.from_clip(skeleton16.to_body_frame(moved, keep_height=True), 120.0)
    np.testing.assert_allclose(a.gpd, b.gpd, atol=1e-6)
    # Relational features ignore any rigid motion of the input, not only yaw.
    rot = quat.from_euler(np.array([0.3, -0.7, 1.9]), "xyz")
    f1 = gpd.gpd_features(world)
    f2 = gpd.gpd_features(quat.rotate(rot, world) + 40.0)
    relational = slice(gpd.FEATURE_SLICES["JJ_d"].start, gpd.FEATURE_SLICES["PP_a"].stop)
    rotation_free = [n.startswith(("JJ_d", "JL_d", "LL_a", "JP_d", "LP_a", "PP_a"))
                     for n in gpd.FEATURE_NAMES[relational]]  # fmt: skip
    np.testing.assert_allclose(f1[:, relational][:, rotation_free],
                               f2[:, relational][:, rotation_free], atol=1e-8)  # fmt: skip


# ------------------------------------------------------------------------------------------
def test_normaliser_is_min_max_then_unit_length() -> None:
    features = gpd.gpd_features(random_poses(50, seed=5))
    model = MinMaxUnitScaler().fit(features)
    out = model.transform(features)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0)
    scaled = features * model.scale_ + model.offset_
    live = model.scale_ > 0
    np.testing.assert_allclose(scaled[:, live].min(axis=0), 0.0, atol=1e-12)
    np.testing.assert_allclose(scaled[:, live].max(axis=0), 1.0, atol=1e-12)
    # Unit length of the min-max vector: out is parallel to it.
    np.testing.assert_allclose(out * np.linalg.norm(scaled, axis=1, keepdims=True), scaled,
                               atol=1e-12)  # fmt: skip
    assert not live[gpd.FEATURE_SLICES["J_k"]].any()  # static poses: kinetics are constant
    assert list(model.get_feature_names_out()) == list(gpd.FEATURE_NAMES)
    data = PoseData.from_clip(random_poses(50, seed=5), 30.0)
    np.testing.assert_allclose(MinMaxUnitScaler().fit(data).transform(data),
                               MinMaxUnitScaler().fit(data.gpd).transform(data.gpd))  # fmt: skip
    with pytest.raises(ValueError, match="features"):
        model.transform(features[:, :100])
    with pytest.raises(ValueError, match="shape"):
        gpd.gpd_features(np.zeros((3, 15, 3)))


# ------------------------------------------------------------------------------------------
def test_posedata_derivatives_within_a_clip() -> None:
    fps = 60.0
    t = np.arange(30) / fps
    base = t_pose()[0]
    velocity = np.array([3.0, -2.0, 5.0])
    accel = np.array([0.0, 40.0, -10.0])
    local = base + (velocity * t[:, None] + 0.5 * accel * t[:, None] ** 2)[:, None, :]
    local[:, 0] = 0.0  # the Hip stays at the origin of the body frame
    height = 90 + 20 * t - 0.5 * 980 * t**2
    data = PoseData.from_clip(local, fps, hip_height=height)
    inner = slice(2, -2)
    expected_velocity = (velocity + accel * t[inner, None])[:, None, :].repeat(15, axis=1)
    np.testing.assert_allclose(data.velocities[inner, 1:], expected_velocity, atol=1e-9)
    np.testing.assert_allclose(data.accelerations[inner, 1:], np.broadcast_to(accel, (26, 15, 3)),
                               atol=1e-6)  # fmt: skip
    np.testing.assert_allclose(data.velocities[inner, 0], np.stack(
        (0 * t, 20 - 980 * t, 0 * t), axis=1)[inner], atol=1e-9)  # fmt: skip
    np.testing.assert_allclose(data.accelerations[inner, 0, 1], -980.0, atol=1e-6)
    # A Hip row at (0, h, 0) (skeleton16's keep_height) is re-centred and read as the height.
    raised = local.copy()
    raised[:, :, 1] += height[:, None]
    again = PoseData.from_clip(raised, fps)
    np.testing.assert_allclose(again.positions, data.positions - data.positions[:, :1], atol=1e-9)
    np.testing.assert_allclose(again.hip_height, height)
    # Concatenation keeps each clip's derivatives; indexing keeps rows (and the cached GPD).
    other = PoseData.from_clip(random_poses(7, seed=8), 120.0)
    both = PoseData.concat([data, other])
    assert len(both) == 37
    np.testing.assert_array_equal(both[30:].velocities, other.velocities)
    np.testing.assert_array_equal(both[[0, 31]].gpd, np.concatenate((data.gpd[:1], other.gpd[1:2])))
    assert len(both[-1]) == 1 and len(PoseData.from_clip(local[:1], fps)) == 1
    with pytest.raises(ValueError, match="fps"):
        PoseData.from_clip(local, 0.0)


def test_orientations_from_positions() -> None:
    pose = t_pose()
    pose[0, J["LHand"]] = (75, 40, 0)  # straighten the left arm: a true T-pose
    pose[0, J["Head"]] = (0, 60, 0)
    pose[0, J["LFoot"]] = (10, -90, 0)
    q = joint_orientations(pose)[0]
    np.testing.assert_allclose(q, np.tile([1.0, 0, 0, 0], (16, 1)), atol=1e-12)
    # Bend the left elbow by 70 degrees: only the elbow's orientation changes, by 70 degrees.
    bent = pose.copy()
    theta = np.deg2rad(70)
    bent[0, J["LHand"]] = pose[0, J["LElbow"]] + 30 * np.array([np.cos(theta), np.sin(theta), 0])
    angles = quat.angle(joint_orientations(pose)[0], joint_orientations(bent)[0])
    expected = np.zeros(16)
    expected[J["LElbow"]] = theta
    np.testing.assert_allclose(angles, expected, atol=1e-9)
    # Raising the forearm at 2 rad/s reads as 2 rad/s about the elbow.
    omega = 2.0
    vel = np.zeros_like(pose)
    vel[0, J["LHand"]] = (0, 30 * omega, 0)
    w = angular_velocities(pose, vel)[0]
    assert np.linalg.norm(w[J["LElbow"]]) == pytest.approx(omega, rel=1e-5)
    assert np.linalg.norm(np.delete(w, J["LElbow"], axis=0)) < 1e-9


@pytest.mark.skipif(not (DATA / "cmu").is_dir(), reason=f"no mocap data folder at {DATA}")
def test_real_clip_features_are_finite_and_stable() -> None:
    from quatmotion.io import read_amc

    motion = read_amc(DATA / "cmu" / "02" / "02_01.amc", DATA / "cmu" / "02" / "02.asf")
    data = PoseClip.from_motion(motion).poses
    assert len(data) == motion.n_frames
    features = data.gpd
    assert np.all(np.isfinite(features))
    world = skeleton16.canonical_positions16(motion)  # the Hip midway between the hip joints
    np.testing.assert_allclose(data.hip_height, world[:, 0, 1], atol=1e-9)
    # Limb lengths are fixed by the skeleton: JJ_d of a limb barely moves over the clip.
    limb = features[:, column("JJ_d(LKnee,LFoot)")]
    assert limb.std() < 1e-6 * limb.mean() + 1e-6
