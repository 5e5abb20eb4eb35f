"""ASF/AMC reading and writing: known values, round trips over every clip, malformed input."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

from quatmotion import FormatError, quat
from quatmotion.datasets import data_root
from quatmotion.io import (
    asf_bone_end_positions,
    find_asf_for_amc,
    read_amc,
    read_asf,
    read_bvh,
    read_motion,
    write_amc,
    write_asf,
    write_bvh,
    write_motion,
)
from quatmotion.motion import forward_kinematics

DATA = data_root(must_exist=False)

UNIT_CM = 2.54 / 0.45  # one ASF unit at ':units length 0.45'

TINY_ASF = """# a two-bone test skeleton
:version 1.10
:name tiny
:units
  mass 1.0
  length 0.45
  angle deg
:documentation
  made for tests
:root
   order TX TY TZ RX RY RZ
   axis XYZ
   position 0 0 0
   orientation 0 0 0
:bonedata
  begin
     id 1
     name a
     direction 1 0 0
     length 0.45
     axis 0 0 90 XYZ
    dof rx
    limits (-180.0 180.0)
  end
  begin
     id 2
     name b
     direction 0 0 1
     length 0.9
     axis 0 0 0 XYZ
    dof rx rz l
    limits (-180.0 180.0)
           (-180.0 180.0)
           (-inf inf)
  end
:hierarchy
  begin
    root a
    a b
  end
"""

TINY_AMC = """:FULLY-SPECIFIED
:DEGREES
1
root 1 2 3 0 0 0
a 90
b 90 90 0.5
2
root 1 2 3 0 0 0
a 0
b 0 0 0
"""


@pytest.fixture()
def tiny(tmp_path: Path) -> tuple[Path, Path]:
    asf = tmp_path / "tiny.asf"
    amc = tmp_path / "tiny_01.amc"
    asf.write_text(TINY_ASF)
    amc.write_text(TINY_AMC)
    return asf, amc


# ------------------------------------------------------------------------------------------
# Known values
# ------------------------------------------------------------------------------------------


def test_asf_units_offsets_axes_and_sites(tiny):
    sk = read_asf(tiny[0])
    assert sk.joint_names == ("root", "a", "b")
    assert list(sk.parents) == [-1, 0, 1]
    assert sk.euler == "extrinsic"
    assert sk.channels == (("tx", "ty", "tz", "rx", "ry", "rz"), ("rx",), ("rx", "rz"))
    # A joint sits at its bone's start: a at the root, b at a's end (0.45 units = 2.54 cm).
    assert np.allclose(sk.offsets, [[0, 0, 0], [0, 0, 0], [2.54, 0, 0]])
    assert sk.site_names == ("b_end",) and list(sk.site_parents) == [2]
    assert np.allclose(sk.site_offsets, [[0, 0, 0.9 * UNIT_CM]])
    # axis 0 0 90 XYZ is a 90-degree turn about z.
    assert quat.angle(sk.axes[1], quat.from_euler([0, 0, 90], "xyz", degrees=True)) < 1e-12


def test_amc_known_positions(tiny):
    motion = read_amc(tiny[1], tiny[0])
    assert motion.n_frames == 2 and motion.fps == 120
    assert np.allclose(motion.root_translation, np.array([1, 2, 3]) * UNIT_CM)
    ends = asf_bone_end_positions(motion) - motion.root_translation[:, None]
    # Frame 1: a turns 90 deg about C x = y, carrying +x to -z; b's M = Rz(90) Rx(90) (rx first)
    # carries +z to +x, then a's turn carries it to -z.
    expected = np.array([[0, 0, 0], [0, 0, -2.54], [0, 0, -2.54 - 0.9 * UNIT_CM]])
    assert np.allclose(ends[0], expected, atol=1e-12)
    rest = np.array([[0, 0, 0], [2.54, 0, 0], [2.54, 0, 0.9 * UNIT_CM]])
    assert np.allclose(ends[1], rest, atol=1e-12)


def test_amc_radians_header_and_asf_radian_unit(tmp_path: Path, tiny):
    asf_rad = TINY_ASF.replace("angle deg", "angle rad").replace(
        "axis 0 0 90 XYZ", f"axis 0 0 {np.pi / 2!r} XYZ"
    )
    (tmp_path / "rad.asf").write_text(asf_rad)
    amc_rad = TINY_AMC.replace(":DEGREES", ":RADIANS").replace(" 90", f" {np.pi / 2!r}")
    (tmp_path / "rad.amc").write_text(amc_rad)
    expected = asf_bone_end_positions(read_amc(tiny[1], tiny[0]))
    actual = asf_bone_end_positions(read_amc(tmp_path / "rad.amc", tmp_path / "rad.asf"))
    assert np.allclose(actual, expected, atol=1e-12)
    # No angle header: the ASF's unit decides.
    (tmp_path / "plain.amc").write_text(amc_rad.replace(":RADIANS\n", ""))
    plain = asf_bone_end_positions(read_amc(tmp_path / "plain.amc", tmp_path / "rad.asf"))
    assert np.allclose(plain, expected, atol=1e-12)


def test_root_position_orientation_and_order(tmp_path: Path):
    text = (
        TINY_ASF.replace("order TX TY TZ RX RY RZ", "order RZ TX TY TZ")
        .replace("position 0 0 0", "position 0.45 0 0")
        .replace("orientation 0 0 0", "orientation 0 90 0")
    )
    (tmp_path / "r.asf").write_text(text)
    (tmp_path / "r.amc").write_text("1\nroot 90 0 0.45 0\na 0\nb 0 0 0\n")
    motion = read_amc(tmp_path / "r.amc", tmp_path / "r.asf")
    sk = motion.skeleton
    assert sk.channels[0] == ("rz", "tx", "ty", "tz")
    # Root at position + translation; its rotation is C Rz(90) C^-1 with C = Ry(90): about C z = x.
    assert np.allclose(motion.root_translation[0], [2.54, 2.54, 0])
    expected = quat.from_euler([90, 0, 0], "xyz", degrees=True)
    assert quat.angle(motion.rotations[0, 0], expected) < 1e-12
    back_path = tmp_path / "back.amc"
    write_amc(motion, back_path)
    assert back_path.read_text().splitlines()[4].split() == ["root", "90", "0", "0.45", "0"]


def test_bone_order_not_parent_first_gets_depth_first_joints(tmp_path: Path):
    a_block = TINY_ASF[TINY_ASF.index("  begin\n     id 1") : TINY_ASF.index("  begin\n     id 2")]
    b_block = TINY_ASF[TINY_ASF.index("  begin\n     id 2") : TINY_ASF.index(":hierarchy")]
    swapped = TINY_ASF.replace(a_block + b_block, b_block + a_block)
    (tmp_path / "s.asf").write_text(swapped)
    sk = read_asf(tmp_path / "s.asf")
    assert sk.joint_names == ("root", "a", "b")
    (tmp_path / "s.amc").write_text(TINY_AMC)
    motion = read_amc(tmp_path / "s.amc", sk)
    ends = asf_bone_end_positions(motion)
    # Reference layout follows the file: b's end comes first.
    assert np.allclose(ends[0, 1] - ends[0, 0], [0, 0, -2.54 - 0.9 * UNIT_CM])


def test_tiny_round_trips(tmp_path: Path, tiny):
    motion = read_amc(tiny[1], tiny[0])
    write_asf(motion.skeleton, tmp_path / "w.asf")
    write_motion(motion, tmp_path / "w.amc")
    again = read_amc(tmp_path / "w.amc", tmp_path / "w.asf")
    assert np.allclose(asf_bone_end_positions(again), asf_bone_end_positions(motion), atol=1e-9)
    # The 'l' dof is read and dropped; the writer puts 0 in its place.
    assert (tmp_path / "w.amc").read_text().splitlines()[6].split() == ["b", "90", "90", "0"]
    assert list(read_asf(tmp_path / "w.asf").extras["asf_bones"][1]["limits"][2]) == ["-inf", "inf"]


# ------------------------------------------------------------------------------------------
# Skeleton lookup
# ------------------------------------------------------------------------------------------


def test_find_asf_missing_raises_format_error_with_hint(tmp_path: Path):
    (tmp_path / "77_01.amc").write_text(TINY_AMC)
    with pytest.raises(FormatError, match="--skeleton"):
        read_amc(tmp_path / "77_01.amc")
    with pytest.raises(FormatError, match="--skeleton"):
        read_motion(tmp_path / "77_01.amc")


def test_find_asf_conventions(tmp_path: Path):
    (tmp_path / "07.asf").write_text(TINY_ASF)
    assert find_asf_for_amc(tmp_path / "07_03.amc") == tmp_path / "07.asf"
    hdm = tmp_path / "hdm" / "clips" / "squat"
    hdm.mkdir(parents=True)
    (tmp_path / "hdm" / "skeletons").mkdir()
    (tmp_path / "hdm" / "skeletons" / "HDM_xx.asf").write_text(TINY_ASF)
    found = find_asf_for_amc(hdm / "HDM_xx_squat_001_120.amc")
    assert found.resolve() == (tmp_path / "hdm" / "skeletons" / "HDM_xx.asf").resolve()


@pytest.mark.needs_data
def test_find_asf_on_the_data():
    cmu = next(iter(sorted((DATA / "cmu").glob("*/*.amc"))))
    assert find_asf_for_amc(cmu) == cmu.with_name(cmu.stem.split("_")[0] + ".asf")
    hdm = next(iter(sorted((DATA / "hdm05" / "clips").glob("*/*.amc"))))
    actor = "_".join(hdm.stem.split("_")[:2])
    assert (
        find_asf_for_amc(hdm).resolve() == (DATA / "hdm05" / "skeletons" / f"{actor}.asf").resolve()
    )


# ------------------------------------------------------------------------------------------
# Every clip in the data
# ------------------------------------------------------------------------------------------


def _amc_groups() -> dict[str, list[Path]]:
    groups: dict[str, list[Path]] = defaultdict(list)
    if DATA.is_dir():
        for amc in sorted(DATA.glob("cmu/*/*.amc")) + sorted(DATA.glob("hdm05/clips/*/*.amc")):
            groups[find_asf_for_amc(amc).stem].append(amc)
    return dict(groups)


AMC_GROUPS = _amc_groups()
FRAME_STEP = 15  # write-read trips use every 15th frame; every file is still parsed whole


def _raw_amc_values(path: Path, frames: list[int]) -> dict[int, dict[str, list[float]]]:
    """A plain parse of selected frames, independent of the reader under test.

    The data's AMC files give every frame the same number of lines, so frame ``f`` starts at
    a known line; the frame number found there is checked.
    """
    lines = path.read_text(encoding="latin-1").splitlines()
    starts = [i for i, line in enumerate(lines[:200]) if line.strip().isdigit()]
    first, per_frame = starts[0], starts[1] - starts[0]
    out: dict[int, dict[str, list[float]]] = {}
    for f in frames:
        i = first + (f - 1) * per_frame
        assert lines[i].strip() == str(f)
        out[f] = {
            t[0]: [float(v) for v in t[1:]] for t in map(str.split, lines[i + 1 : i + per_frame])
        }
    return out


def _principal(angles: np.ndarray) -> np.ndarray:
    """Rows ``(F, n)`` of Euler angles (degrees) in the principal range, clear of gimbal lock."""
    inside = np.all((angles > -180) & (angles <= 180), axis=1)
    if angles.shape[1] == 3:
        inside &= np.abs(angles[:, 1]) < 89.0
    return inside


@pytest.mark.needs_data
def test_every_skeleton_round_trips(tmp_path: Path):
    asfs = sorted(DATA.glob("cmu/*/*.asf")) + sorted(DATA.glob("hdm05/skeletons/*.asf"))
    assert asfs
    for asf in asfs:
        sk = read_asf(asf)
        write_asf(sk, tmp_path / asf.name)
        again = read_asf(tmp_path / asf.name)
        assert again.joint_names == sk.joint_names
        assert again.channels == sk.channels
        assert np.array_equal(again.parents, sk.parents)
        assert np.allclose(again.offsets, sk.offsets, rtol=1e-9, atol=1e-12)
        assert np.allclose(again.site_offsets, sk.site_offsets, rtol=1e-9, atol=1e-12)
        assert np.all(quat.angle(again.axes, sk.axes) < 1e-9)
        assert [b["limits"] for b in again.extras["asf_bones"]] == [
            b["limits"] for b in sk.extras["asf_bones"]
        ]


@pytest.mark.needs_data
@pytest.mark.parametrize("actor", sorted(AMC_GROUPS))
def test_every_amc_round_trips_through_amc_and_bvh(actor: str, tmp_path: Path):
    """AMC -> Motion -> AMC keeps rotations (1e-4 deg) and the file's numbers; AMC -> BVH ->
    Motion keeps every joint and end-site position (1e-3 cm). Every clip is parsed whole."""
    clips = AMC_GROUPS[actor]
    skeleton = read_asf(find_asf_for_amc(clips[0]))
    n_rotations = {
        b["name"]: sum(d[0] == "r" for d in b["dof"]) for b in skeleton.extras["asf_bones"]
    }
    n_rotations["root"] = 3
    for clip in clips:
        motion = read_amc(clip, skeleton)
        assert motion.n_frames > 0
        kept = motion.slice(0, None, FRAME_STEP)
        out = tmp_path / clip.name
        write_amc(kept, out)
        again = read_amc(out, skeleton)
        worst = np.degrees(quat.angle(again.rotations, kept.rotations)).max()
        assert worst < 1e-4, f"{clip.name}: rotation error {worst} deg"
        assert np.allclose(again.root_translation, kept.root_translation, atol=1e-6)
        # Same numbers as the file wherever its angles are in the principal range.
        original_frames = list(range(1, motion.n_frames + 1, FRAME_STEP))
        original = _raw_amc_values(clip, original_frames)
        written = _raw_amc_values(out, list(range(1, kept.n_frames + 1)))
        compared = []
        for bone in original[1]:
            before = np.array([original[f][bone] for f in original_frames])
            after = np.array([written[k][bone] for k in range(1, kept.n_frames + 1)])
            rows = _principal(before[:, before.shape[1] - n_rotations[bone] :])
            compared.append(rows.mean())
            difference = np.abs(after[rows] - before[rows]).max(initial=0.0)
            assert difference < 1e-7, (clip.name, bone, difference)
        # Most values are in range (root yaw often is not); the check must not be vacuous.
        assert np.mean(compared) > 0.5, clip.name

        write_bvh(kept, tmp_path / "x.bvh")
        via_bvh = read_bvh(tmp_path / "x.bvh")
        assert via_bvh.skeleton.joint_names == kept.skeleton.joint_names
        expected = forward_kinematics(kept).all_positions()
        error = np.abs(forward_kinematics(via_bvh).all_positions() - expected).max()
        assert error < 1e-3, f"{clip.name}: position error {error} cm"


# ------------------------------------------------------------------------------------------
# Malformed input
# ------------------------------------------------------------------------------------------


def _line_of(text: str, needle: str) -> int:
    return text[: text.index(needle)].count("\n") + 1


@pytest.mark.parametrize(
    ("old", "new", "needle", "message"),
    [
        (":bonedata", ":bonedatum", None, "bonedata"),
        ("length 0.9", "length abc", "length abc", "length"),
        ("length 0.9", "length nan", "length nan", "not finite"),
        ("direction 0 0 1", "direction 0 1", "direction 0 1", "3 values"),
        ("    a b\n", "    a zz\n", "a zz", "unknown bone"),
        ("dof rx rz l", "dof rx rq", "dof rx rq", "dof"),
        ("  end\n:hierarchy", ":hierarchy", None, "end"),
    ],
)
def test_malformed_asf(tmp_path: Path, old: str, new: str, needle: str | None, message: str):
    text = TINY_ASF.replace(old, new, 1)
    path = tmp_path / "bad.asf"
    path.write_text(text)
    with pytest.raises(FormatError, match=message) as info:
        read_asf(path)
    assert info.value.path == path
    if needle is not None:
        assert info.value.line == _line_of(text, needle)
        assert f"bad.asf:{info.value.line}" in str(info.value)


def test_truncated_asf(tmp_path: Path):
    path = tmp_path / "cut.asf"
    path.write_text(TINY_ASF[: TINY_ASF.index("dof rx rz l")])
    with pytest.raises(FormatError, match="truncated|missing"):
        read_asf(path)


@pytest.mark.parametrize(
    ("old", "new", "needle", "message"),
    [
        ("a 90\n", "zz 90\n", "zz 90", "unknown bone"),
        ("b 0 0 0\n", "b 0 0\n", "b 0 0\n", "values"),
        ("a 90\n", "a nan\n", "a nan", "not finite"),
        ("a 90\n", "a inf\n", "a inf", "not finite"),
        ("a 0\n", "a 0x\n", "a 0x", "number"),
        ("2\nroot", "5\nroot", "5\nroot", "frame number"),
        ("a 0\n", "", "2\n", "lacks"),
    ],
)
def test_malformed_amc(tiny, old: str, new: str, needle: str, message: str):
    text = TINY_AMC.replace(old, new, 1)
    tiny[1].write_text(text)
    with pytest.raises(FormatError, match=message) as info:
        read_amc(tiny[1], tiny[0])
    assert info.value.path == tiny[1]
    assert info.value.line == _line_of(text, needle)


def test_amc_without_frames_and_binary_bytes(tiny):
    tiny[1].write_text(":FULLY-SPECIFIED\n:DEGREES\n")  # a header alone: a clip of no frames
    assert read_amc(tiny[1], tiny[0]).n_frames == 0
    tiny[1].write_text("")
    with pytest.raises(FormatError, match="no frames"):
        read_amc(tiny[1], tiny[0])
    tiny[1].write_bytes(TINY_AMC.encode().replace(b"a 90", b"a 9\x000"))
    with pytest.raises(FormatError, match="not a text file") as info:
        read_amc(tiny[1], tiny[0])
    assert info.value.line == _line_of(TINY_AMC, "a 90")


def test_amc_needs_an_asf_skeleton(tiny):
    bvh_like = read_amc(tiny[1], tiny[0])
    with pytest.raises(ValueError, match="ASF"):
        write_amc(_as_bvh(bvh_like), tiny[1])


def _as_bvh(motion):
    from quatmotion.io import to_bvh_skeleton
    from quatmotion.motion import Motion

    return Motion(
        skeleton=to_bvh_skeleton(motion.skeleton),
        fps=motion.fps,
        root_translation=motion.root_translation,
        rotations=motion.rotations,
    )


def test_bvh_export_keeps_rotation_of_a_joint_without_dofs(tmp_path: Path):
    from quatmotion.motion import Motion

    text = TINY_ASF.replace("    dof rx\n    limits (-180.0 180.0)\n", "", 1)
    (tmp_path / "n.asf").write_text(text)
    (tmp_path / "n.amc").write_text("1\nroot 1 2 3 0 0 0\nb 90 90 0\n")
    motion = read_amc(tmp_path / "n.amc", tmp_path / "n.asf")
    assert motion.skeleton.channels[1] == ()
    rotations = motion.rotations.copy()
    rotations[:, 1] = quat.from_euler([0.3, 0.2, 0.1], "xyz")  # e.g. a lossy decoder's output
    turned = Motion(motion.skeleton, motion.fps, motion.root_translation, rotations)
    write_bvh(turned, tmp_path / "n.bvh")
    again = read_bvh(tmp_path / "n.bvh", scale=1.0)
    assert again.skeleton.channels[1] == ("rz", "ry", "rx")
    expected = forward_kinematics(turned).all_positions()
    assert np.allclose(forward_kinematics(again).all_positions(), expected, atol=1e-6)


def test_irregular_but_valid_amc_layouts_parse_the_same(tmp_path: Path, tiny):
    expected = read_amc(tiny[1], tiny[0])
    # Bones in another order in frame 2, blank lines and a comment: the careful path.
    irregular = TINY_AMC.replace(
        "2\nroot 1 2 3 0 0 0\na 0\nb 0 0 0\n", "\n2\nb 0 0 0\n# c\na 0\nroot 1 2 3 0 0 0\n\n"
    )
    assert irregular != TINY_AMC
    tiny[1].write_text(irregular)
    motion = read_amc(tiny[1], tiny[0])
    assert np.array_equal(motion.rotations, expected.rotations)
    assert np.array_equal(motion.root_translation, expected.root_translation)


def test_find_motion_files_walks_folders_and_names_what_is_missing(tmp_path: Path):
    from quatmotion.io import find_motion_files

    (tmp_path / "lib" / "sub").mkdir(parents=True)
    for name in ("lib/b.amc", "lib/a.BVH", "lib/sub/c.bvh", "lib/notes.txt", "single.txt"):
        (tmp_path / name).write_text("x")
    (tmp_path / "lib" / "folder.bvh").mkdir()  # a folder with a motion suffix is not a clip
    found = find_motion_files([tmp_path / "lib", tmp_path / "single.txt", tmp_path / "lib"])
    names = [p.relative_to(tmp_path).as_posix() for p in found]
    assert names == ["lib/a.BVH", "lib/b.amc", "lib/sub/c.bvh", "single.txt"]
    with pytest.raises(FileNotFoundError, match="nope"):
        find_motion_files([tmp_path / "nope"])
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no .amc or .bvh or .glb or .gltf or .fbx files"):
        find_motion_files([tmp_path / "empty"])
