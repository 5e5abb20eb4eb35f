"""BVH reading and writing: known values, units, round trips over every clip, bad input."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from quatmotion import FormatError, quat
from quatmotion.datasets import data_root
from quatmotion.io import (
    detect_bvh_scale,
    read_bvh,
    read_motion,
    write_bvh,
    write_motion,
)
from quatmotion.motion import forward_kinematics

DATA = data_root(must_exist=False)

TINY_BVH = """HIERARCHY
ROOT hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT chest
  {
    OFFSET 0 0 1
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 0 1
    }
  }
  JOINT leg
  {
    OFFSET 0 -1 0
    CHANNELS 4 Yposition Xrotation Zrotation Yrotation
  }
}
MOTION
Frames: 2
Frame Time: 0.04
1 2 3 90 90 0 0 0 0 -2 0 0 0
1 2 3 0 0 0 90 0 0 -1 30 0 0
"""


@pytest.fixture()
def tiny(tmp_path: Path) -> Path:
    path = tmp_path / "tiny.bvh"
    path.write_text(TINY_BVH)
    return path


# ------------------------------------------------------------------------------------------
# Known values
# ------------------------------------------------------------------------------------------


def test_tiny_skeleton_and_channels(tiny: Path):
    motion = read_bvh(tiny, scale=1.0)
    sk = motion.skeleton
    assert sk.joint_names == ("hips", "chest", "leg")
    assert list(sk.parents) == [-1, 0, 0]
    assert sk.euler == "intrinsic"
    assert sk.channels[0] == ("tx", "ty", "tz", "rz", "rx", "ry")
    assert sk.channels[2] == ("ty", "rx", "rz", "ry")
    assert sk.site_names == ("chest_end",) and list(sk.site_parents) == [1]
    assert motion.fps == 25.0 and motion.n_frames == 2


def test_intrinsic_channel_order_and_position_channels(tiny: Path):
    motion = read_bvh(tiny, scale=1.0)
    pose = forward_kinematics(motion)
    # Frame 0: R = Rz(90) @ Rx(90) carries the chest offset +z to +x (Rx first: z -> -y).
    assert np.allclose(pose.positions[0, 0], [1, 2, 3])
    assert np.allclose(pose.positions[0, 1], [2, 2, 3], atol=1e-12)
    assert np.allclose(pose.site_positions[0, 0], [3, 2, 3], atol=1e-12)
    # The leg's Yposition channel (-2) replaces its offset's y: (0, -2, 0), rotated to (0, 0, -2).
    assert np.allclose(pose.positions[0, 2], [1, 2, 1], atol=1e-12)
    # Frame 1: chest turned 90 deg about z; its end site +z is unchanged.
    assert np.allclose(pose.site_positions[1, 0], [1, 2, 5], atol=1e-12)
    expected_leg = quat.from_euler([30, 0, 0], "XZY", degrees=True)
    assert quat.angle(motion.rotations[1, 2], expected_leg) < 1e-12


@pytest.mark.parametrize(("unit", "cm"), [("m", 100.0), ("cm", 1.0), ("mm", 0.1), ("inch", 2.54)])
def test_scale_detection_and_explicit_scale(tmp_path: Path, unit: str, cm: float):
    # A 170 cm stick figure (a body: it has a head) written in the given unit is read back in
    # centimetres.
    height = 170.0 / cm
    text = (
        "HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 0\n  CHANNELS 3 Xposition Yposition Zposition\n"
        f"  JOINT Head\n  {{\n    OFFSET 0 {height / 2!r} 0\n    CHANNELS 1 Zrotation\n"
        f"    End Site\n    {{\n      OFFSET 0 {height / 2!r} 0\n    }}\n  }}\n}}\n"
        f"MOTION\nFrames: 1\nFrame Time: 0.01\n0 {height / 10!r} 0 0\n"
    )
    path = tmp_path / f"{unit}.bvh"
    path.write_text(text)
    motion = read_bvh(path)
    assert motion.skeleton.extras["bvh_scale"] == pytest.approx(cm)
    assert motion.skeleton.height() == pytest.approx(170.0)
    assert motion.root_translation[0, 1] == pytest.approx(17.0)
    forced = read_bvh(path, scale=2.0)
    assert forced.skeleton.height() == pytest.approx(2.0 * height)
    # The writer keeps the file's unit: numbers come back unchanged.
    write_bvh(motion, tmp_path / "again.bvh")
    assert read_bvh(tmp_path / "again.bvh", scale=1.0).skeleton.height() == pytest.approx(height)


def test_detect_scale_candidates():
    stick = np.array([[0.0, 0.0, 0.0], [0.0, 30.0, 0.0]])
    assert detect_bvh_scale(stick) == pytest.approx(2.54 / 0.45)  # CMU/ASF unit
    assert detect_bvh_scale(stick * 0) == 1.0


def test_tiny_round_trip_keeps_numbers(tiny: Path, tmp_path: Path):
    motion = read_bvh(tiny, scale=1.0)
    write_motion(motion, tmp_path / "w.bvh")
    lines = (tmp_path / "w.bvh").read_text().splitlines()
    original = TINY_BVH.splitlines()
    assert [np.array(x.split(), float).tolist() for x in lines[-2:]] == [
        np.array(x.split(), float).tolist() for x in original[-2:]
    ]
    # A 2-unit figure would be auto-detected as metres: the unit is given.
    again = read_bvh(tmp_path / "w.bvh", scale=1.0)
    assert again.skeleton.channels == motion.skeleton.channels
    assert np.allclose(
        forward_kinematics(again).all_positions(), forward_kinematics(motion).all_positions()
    )


def test_read_and_write_motion_dispatch(tiny: Path, tmp_path: Path):
    with pytest.raises(ValueError, match="unknown motion file type"):
        read_motion(tmp_path / "x.c3d")
    for suffix in (".c3d", ".fbx"):  # FBX is read, not written
        with pytest.raises(ValueError, match=r"cannot write motion file type .*\.bvh"):
            write_motion(read_bvh(tiny), tmp_path / f"x{suffix}")
    with pytest.raises(ValueError, match="own skeleton"):
        read_motion(tiny, skeleton=tmp_path / "x.asf")
    with pytest.raises(ValueError, match="ASF"):
        write_motion(read_bvh(tiny), tmp_path / "x.amc")


def test_writer_is_atomic(tiny: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    motion = read_bvh(tiny)
    target = tmp_path / "out.bvh"
    target.write_text("previous content")

    def failing_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", failing_replace)
    with pytest.raises(OSError, match="disk full"):
        write_bvh(motion, target)
    monkeypatch.undo()
    assert target.read_text() == "previous content"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bvh", "tiny.bvh"]
    write_bvh(motion, target)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bvh", "tiny.bvh"]
    assert read_bvh(target).n_frames == 2


# ------------------------------------------------------------------------------------------
# Every clip in the data
# ------------------------------------------------------------------------------------------

BVH_GROUPS = {
    "bandai1": sorted(DATA.glob("bandai1/clips/*.bvh")) if DATA.is_dir() else [],
    "cmu_bvh": sorted(DATA.glob("cmu_bvh/*/*.bvh")) if DATA.is_dir() else [],
}
FRAME_STEP = 10


@pytest.mark.needs_data
@pytest.mark.parametrize("group", sorted(BVH_GROUPS))
def test_every_bvh_round_trips(group: str, tmp_path: Path):
    clips = BVH_GROUPS[group]
    assert clips, f"no BVH files under {group}"
    expected_scale = 1.0 if group == "bandai1" else 2.54 / 0.45
    for clip in clips:
        motion = read_bvh(clip)
        assert motion.skeleton.extras["bvh_scale"] == pytest.approx(expected_scale)
        kept = motion.slice(0, None, FRAME_STEP)
        write_bvh(kept, tmp_path / "x.bvh")
        again = read_bvh(tmp_path / "x.bvh")
        assert again.skeleton.channels == kept.skeleton.channels
        assert np.allclose(again.skeleton.offsets, kept.skeleton.offsets, rtol=1e-9, atol=1e-9)
        expected = forward_kinematics(kept).all_positions()
        error = np.abs(forward_kinematics(again).all_positions() - expected).max()
        assert error < 1e-3, f"{clip.name}: position error {error} cm"
        assert np.degrees(quat.angle(again.rotations, kept.rotations)).max() < 1e-4


@pytest.mark.needs_data
def test_bandai_joints_carry_translations_and_cmu_root_only():
    bandai = read_bvh(BVH_GROUPS["bandai1"][0])
    assert bandai.joint_translations is not None
    assert all(len(c) == 6 for c in bandai.skeleton.channels)
    assert bandai.fps == 30.0
    cmu = read_bvh(BVH_GROUPS["cmu_bvh"][0])
    assert cmu.joint_translations is None and cmu.fps == 120.0
    # Hips about 17 units (95 cm) above the floor in the CMU conversion.
    assert 70 < np.median(cmu.root_translation[:, 1]) < 110


# ------------------------------------------------------------------------------------------
# Malformed input
# ------------------------------------------------------------------------------------------


def _line_of(text: str, needle: str) -> int:
    return text[: text.index(needle)].count("\n") + 1


@pytest.mark.parametrize(
    ("old", "new", "needle", "message"),
    [
        ("MOTION\n", "MOTON\n", "MOTON", "MOTION"),
        ("Frames: 2", "Frames: 3", None, "announces 3 frames"),
        ("0 0 -1 30 0 0\n", "0 0 -1 30 0\n", "1 2 3 0 0 0 90", "12 values, expected 13"),
        ("-1 30 0 0", "-1 3x0 0 0", "1 2 3 0 0 0 90", "number"),
        ("-1 30 0 0", "-1 nan 0 0", "1 2 3 0 0 0 90", "not finite"),
        (
            "Zrotation Xrotation Yrotation\n    End",
            "Zrotation Xrotation Wrotation\n    End",
            "Wrot",
            "channel",
        ),
        ("OFFSET 0 0 1\n    CHANNELS", "OFFSET 0 0\n    CHANNELS", "CHANNELS 3", "OFFSET value"),
        ("Frame Time: 0.04", "Frame Time: -1", "Frame Time", "positive"),
        ("JOINT leg", "JOINT chest", "JOINT chest\n  {\n    OFFSET 0 -1", "twice"),
    ],
)
def test_malformed_bvh(tmp_path: Path, old: str, new: str, needle: str | None, message: str):
    assert old in TINY_BVH
    text = TINY_BVH.replace(old, new, 1)
    path = tmp_path / "bad.bvh"
    path.write_text(text)
    with pytest.raises(FormatError, match=message) as info:
        read_bvh(path)
    assert info.value.path == path
    if needle is not None:
        # Name lines point at the joint name token, one past 'JOINT'.
        assert info.value.line == _line_of(text, needle)


def test_truncated_and_binary_bvh(tmp_path: Path):
    path = tmp_path / "cut.bvh"
    path.write_text(TINY_BVH[: TINY_BVH.index("End Site") + 12])
    with pytest.raises(FormatError, match="truncated"):
        read_bvh(path)
    path.write_text(TINY_BVH[:-10])
    with pytest.raises(FormatError):
        read_bvh(path)
    path.write_bytes(TINY_BVH.encode().replace(b"Frames", b"Fr\x01mes"))
    with pytest.raises(FormatError, match="not a text file") as info:
        read_bvh(path)
    assert info.value.line == _line_of(TINY_BVH, "Frames")


def test_a_byte_order_mark_is_ignored(tiny: Path, tmp_path: Path):
    """Issue 9: files saved by Windows editors start with a UTF-8 byte-order mark."""
    marked = tmp_path / "marked.bvh"
    marked.write_bytes(b"\xef\xbb\xbf" + tiny.read_bytes())
    a, b = read_bvh(tiny), read_bvh(marked)
    np.testing.assert_array_equal(a.rotations, b.rotations)
    assert a.skeleton.joint_names == b.skeleton.joint_names
