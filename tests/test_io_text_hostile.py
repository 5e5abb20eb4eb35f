"""Hostile BVH, ASF and AMC files (issue 30): hierarchies parsed in linear time and bounded by
the joints and depth limits, frame counts, frame rates and units checked before anything is
allocated, each refusal a FormatError naming the file and the line."""

from __future__ import annotations

import time

import numpy as np
import pytest

from quatmotion import io, limits
from quatmotion.errors import FormatError
from quatmotion.io import parse_amc, parse_asf, parse_bvh
from quatmotion.synthetic import generate_clip

ROOT = (
    "ROOT hips\n{\nOFFSET 0 0 0\n"
    "CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n"
)
MOTION = "MOTION\nFrames: 1\nFrame Time: 0.0333333\n0 0 0 0 0 0\n"


def flat_bvh(joints: int, motion: str = MOTION) -> str:
    """A root with ``joints`` children, each with an end site: a wide, shallow hierarchy."""
    body = "".join(
        f"JOINT j{k}\n{{\nOFFSET 1 2 3\nEnd Site\n{{\nOFFSET 0 1 0\n}}\n}}\n" for k in range(joints)
    )
    return f"HIERARCHY\n{ROOT}{body}}}\n{motion}"


def chain_bvh(joints: int) -> str:
    """A chain ``joints`` deep."""
    opening = "".join(f"JOINT j{k}\n{{\nOFFSET 0 1 0\n" for k in range(joints))
    closing = "}\n" * (joints + 1)
    return f"HIERARCHY\n{ROOT}{opening}{closing}{MOTION}"


def flat_asf(bones: int, length: str = "0.45") -> str:
    blocks = "".join(
        f"begin\nid {k + 1}\nname b{k}\ndirection 0 1 0\nlength 1\naxis 0 0 {k % 90} XYZ\n"
        "dof rx ry rz\nend\n"
        for k in range(bones)
    )
    children = " ".join(f"b{k}" for k in range(bones))
    return (
        f":version 1.10\n:name x\n:units\n  mass 1.0\n  length {length}\n  angle deg\n"
        ":documentation\n:root\n  order TX TY TZ RX RY RZ\n  axis XYZ\n  position 0 0 0\n"
        f"  orientation 0 0 0\n:bonedata\n{blocks}:hierarchy\n  begin\n    root {children}\n"
        "  end\n"
    )


def _quickly_refused(parse, text: str, name: str, match: str) -> FormatError:
    started = time.process_time()
    with pytest.raises(FormatError, match=match) as caught:
        parse(text, name)
    assert time.process_time() - started < 5, "refused, but only after parsing it all"
    assert str(caught.value).startswith(f"{name}:")
    return caught.value


def test_forty_thousand_bvh_joints_are_refused_at_once():
    error = _quickly_refused(parse_bvh, flat_bvh(40_000), "wide.bvh", "over the limit of 10,000")
    assert error.line is not None and error.line > 10_000  # the first joint too many


def test_bvh_hierarchies_parse_in_linear_time():
    """20,000 joints, limits raised: seconds (a list lookup per joint made it minutes)."""
    with limits.raised(joints=30_000):
        started = time.process_time()
        motion = parse_bvh(flat_bvh(20_000), "wide.bvh", scale="cm")
        elapsed = time.process_time() - started
    assert motion.skeleton.n_joints == 20_001 and motion.skeleton.n_sites == 20_000
    assert elapsed < 15


def test_bvh_depth_is_bounded_and_parsed_without_recursion():
    _quickly_refused(parse_bvh, chain_bvh(300), "deep.bvh", "nesting is 201 levels")
    with limits.raised(depth=5_000):
        motion = parse_bvh(chain_bvh(3_000), "deep.bvh", scale="cm")  # deeper than the stack
    assert motion.skeleton.n_joints == 3_001


@pytest.mark.parametrize(
    ("header", "match"),
    [
        ("Frames: 1000000000\nFrame Time: 0.0333333", r":\d+: 'Frames:' is 1,000,000,000 frames"),
        ("Frames: 1\nFrame Time: 1e-9", r"'Frame Time: 1e-9' \(a frame rate\) is 1e\+09"),
        ("Frames: 1\nFrame Time: 1e-320", r"'Frame Time: 1e-320' \(a frame rate\) is inf"),
        ("Frames: 900000\nFrame Time: 1", r"'Frames:' x 'Frame Time:' is 900,000 s"),
        ("Frames: 900000\nFrame Time: 0.01", r"'Frames:' x 9,001 joints is 8,100,900,000"),
    ],
)
def test_bvh_frame_counts_and_rates_are_bounded(header, match):
    text = flat_bvh(9_000 if "9,001" in match else 2, f"MOTION\n{header}\n0 0 0 0 0 0\n")
    _quickly_refused(parse_bvh, text, "clip.bvh", match)


def test_a_hundred_thousand_asf_bones_are_refused_at_once():
    _quickly_refused(parse_asf, flat_asf(100_000), "wide.asf", "over the limit of 10,000")


def test_asf_bones_parse_in_linear_time():
    with limits.raised(joints=30_000):
        started = time.process_time()
        skeleton = parse_asf(flat_asf(20_000), "wide.asf")
        elapsed = time.process_time() - started
    assert skeleton.n_joints == 20_001 and elapsed < 15
    # The vectorised pre-rotations are each bone's own: bone k turns k % 90 degrees about z.
    assert skeleton.axes[1 + 45][0] == pytest.approx(np.cos(np.deg2rad(45) / 2))


@pytest.mark.parametrize("length", ["1e-300", "1e300", "inf", "nan"])
def test_an_absurd_asf_unit_is_refused(length):
    with pytest.raises(FormatError, match=r"wide.asf:\d+: (:units length|length unit)") as e:
        parse_asf(flat_asf(2, length=length), "wide.asf")
    assert e.value.line is not None


def test_an_absurd_unit_given_is_refused():
    with pytest.raises(ValueError, match="no length unit of motion capture"):
        io.length_unit(1e-300)
    with pytest.raises(ValueError, match="no length unit of motion capture"):
        parse_bvh(flat_bvh(2), "clip.bvh", scale=1e9)
    assert io.length_unit("mm") == 0.1 and io.length_unit(100.0) == 100.0


@pytest.mark.parametrize("fps", [0.0, -120.0, float("nan"), 1e9])
def test_amc_frame_rates_are_checked(tmp_path, fps):
    clip = generate_clip("walk", 1, n_frames=3)
    io.write_amc(clip, tmp_path / "clip.amc")
    io.write_asf(clip.skeleton, tmp_path / "clip.asf")
    skeleton = io.read_asf(tmp_path / "clip.asf")
    text = (tmp_path / "clip.amc").read_text()
    with pytest.raises(FormatError, match="clip.amc: the frame rate given is"):
        parse_amc(text, "clip.amc", skeleton, fps=fps)
    assert parse_amc(text, "clip.amc", skeleton, fps=60.0).n_frames == 3
