"""Issue 20 (3, 4): the root's travel that the body frame removes, and ``GPDR`` that keeps it."""

from __future__ import annotations

import numpy as np
import pytest

from quatmotion import quat
from quatmotion.pose import methods, skeleton16
from quatmotion.pose.data import PoseData, root_motion
from quatmotion.pose.skeleton16 import JOINTS_16

_STAND = {
    "Hip": (0, 95, 0), "Chest": (0, 115, 0), "Neck": (0, 140, 0), "Head": (0, 155, 5),
    "LShoulder": (15, 135, 0), "LElbow": (40, 115, 0), "LHand": (45, 90, 5),
    "RShoulder": (-15, 135, 0), "RElbow": (-40, 115, 0), "RHand": (-45, 90, 5),
    "LHip": (10, 95, 0), "LKnee": (10, 50, 3), "LFoot": (10, 5, 0),
    "RHip": (-10, 95, 0), "RKnee": (-10, 50, 3), "RFoot": (-10, 5, 0),
}  # fmt: skip
STAND = np.array([_STAND[name] for name in JOINTS_16], dtype=np.float64)  # faces +Z, left +X


def _travel(n: int, fps: float, speed: float, turn_rate: float) -> np.ndarray:
    """The standing body moving along its facing at ``speed`` cm/s while turning at
    ``turn_rate`` rad/s about +Y (world, Y up)."""
    t = np.arange(n) / fps
    yaw = turn_rate * t
    out = np.empty((n, 16, 3))
    hip = np.zeros(3)
    for i in range(n):
        turn = quat.from_euler(np.array([0.0, yaw[i], 0.0]), "xyz")
        out[i] = quat.rotate(turn, STAND - STAND[0]) + hip + STAND[0] * [0, 1, 0]
        hip = hip + quat.rotate(turn, np.array([0.0, 0.0, speed / fps]))
    return out


@pytest.mark.parametrize(("speed", "turn_rate"), [(0.0, 0.0), (140.0, 0.0), (300.0, 0.8)])
def test_root_motion_is_the_travel_in_the_body_frame(speed: float, turn_rate: float) -> None:
    fps = 60.0
    world = _travel(240, fps, speed, turn_rate)
    root = root_motion(world, fps)[2:-2]  # central differences inside the clip
    # forward (+Z of the body) at the clip's speed, no sideways drift (the chord of the arc
    # a frame covers is the speed's own, to second order in the turn per frame)
    np.testing.assert_allclose(root[:, 1], speed, rtol=1e-3, atol=1e-6)
    np.testing.assert_allclose(root[:, 0], 0.0, atol=0.01 * speed + 1e-6)
    # the facing turns at the given rate, across the +-pi wrap of the yaw as well
    np.testing.assert_allclose(root[:, 2], turn_rate, atol=1e-6)


def test_posedata_carries_root_motion_through_concat_and_selection() -> None:
    fps = 30.0
    world = _travel(30, fps, 150.0, 0.0)
    local = skeleton16.to_body_frame(world, keep_height=True)
    walking = PoseData.from_clip(local, fps, world=world)
    standing = PoseData.from_clip(local[:10], fps)  # no world: zeros
    assert np.all(standing.root_motion == 0.0)
    both = PoseData.concat([walking, standing])
    np.testing.assert_array_equal(both.root_motion[:30], walking.root_motion)
    np.testing.assert_array_equal(both[np.array([3, 35])].root_motion[0], walking.root_motion[3])
    with pytest.raises(ValueError, match="world has 29 frames"):
        PoseData.from_clip(local, fps, world=world[:29])
    with pytest.raises(ValueError, match=r"root_motion has shape \(2, 2\)"):
        PoseData(walking.positions[:2], walking.velocities[:2], walking.accelerations[:2],
                 root_motion=np.zeros((2, 2)))  # fmt: skip


def test_gpdr_tells_a_travelling_pose_from_the_same_pose_standing() -> None:
    """The GPD of one posture is the same whether the body travels or stands (the body frame
    removes the travel); GPDR's root block is what differs, by the speed, and the same for a
    pose turning left as for its mirror turning right."""
    fps = 30.0
    moving = _travel(40, fps, 200.0, 0.5)
    still = _travel(40, fps, 0.0, 0.0)
    a = PoseData.from_clip(skeleton16.to_body_frame(moving, keep_height=True), fps, world=moving)
    b = PoseData.from_clip(skeleton16.to_body_frame(still, keep_height=True), fps, world=still)
    np.testing.assert_allclose(a.gpd[5:-5], b.gpd[5:-5], atol=1e-6)
    fa, fb = methods.gpd_root_features(a), methods.gpd_root_features(b)
    assert fa.shape == (40, 1683 + 2 * methods.ROOT_COPIES)
    root = fa[5:-5, 1683:].reshape(30, methods.ROOT_COPIES, 2)
    np.testing.assert_allclose(root[..., 0], 200.0, rtol=1e-2)
    np.testing.assert_allclose(root[..., 1], 0.5, atol=1e-6)
    assert np.all(fb[:, 1683:] == 0.0)
    mirrored = moving * np.array([-1.0, 1.0, 1.0])  # turning right, its body left-right swapped
    mirrored = mirrored[:, list(skeleton16.MIRROR_16)]
    m = PoseData.from_clip(skeleton16.to_body_frame(mirrored, keep_height=True), fps,
                           world=mirrored)  # fmt: skip
    assert np.all(m.root_motion[5:-5, 2] < 0)
    np.testing.assert_allclose(methods.root_features(m), methods.root_features(a), atol=1e-6)


@pytest.mark.needs_data
@pytest.mark.parametrize("name", ["bandai1_walk", "cmu_walk", "hdm05_jog", "cmu_bvh_walk"])
def test_root_motion_follows_the_hips_of_every_family(name: str, real_clips) -> None:
    """The root's travel is the hips' (Bandai's ``joint_Root`` never moves while its hips
    walk), at walking or jogging speed on the canonical body of every skeleton family."""
    from quatmotion import io
    from quatmotion.pose.data import PoseClip

    clip = PoseClip.from_motion(io.read_motion(real_clips[name]), fps=30, height=170)
    speed = np.hypot(clip.poses.root_motion[:, 0], clip.poses.root_motion[:, 1])
    hips = clip.world[:, 0]  # the Hip, midway between the hip joints on the canonical body
    travel = np.linalg.norm(np.diff(hips[:, [0, 2]], axis=0), axis=1).sum() / (len(clip) / 30)
    assert 50.0 < np.median(speed) < 350.0, name
    assert np.mean(speed) == pytest.approx(travel, rel=0.1), name
