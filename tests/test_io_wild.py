"""Files from the wild (issue 21): every valid BVH and ASF/AMC read right or refused for a stated
reason, units never silently wrong. Each case is a small file written here, in ``tmp_path``."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from quatmotion import io
from quatmotion.cli import app
from quatmotion.collection import ReadSettings
from quatmotion.errors import FormatError, FormatWarning
from quatmotion.motion import forward_kinematics
from quatmotion.parallel import Runner
from quatmotion.synthetic import cmu_skeleton, generate_clip

# A humanoid in centimetres: (name, parent, offset, end-site offset). Its stature chain, from an
# ankle up to the top of its head, is 176 cm; in a T-pose its arm span is 176 cm too.
BODY = [
    ("Hips", None, (0, 90, 0), None),
    ("LeftUpLeg", "Hips", (9, 0, 0), None),
    ("LeftLeg", "LeftUpLeg", (0, -42, 0), None),
    ("LeftFoot", "LeftLeg", (0, -42, 0), (0, -6, 12)),
    ("RightUpLeg", "Hips", (-9, 0, 0), None),
    ("RightLeg", "RightUpLeg", (0, -42, 0), None),
    ("RightFoot", "RightLeg", (0, -42, 0), (0, -6, 12)),
    ("Spine", "Hips", (0, 10, 0), None),
    ("Chest", "Spine", (0, 25, 0), None),
    ("Neck", "Chest", (0, 20, 0), None),
    ("Head", "Neck", (0, 10, 0), (0, 18, 0)),
    ("LeftArm", "Chest", (17, 18, 0), None),
    ("LeftForeArm", "LeftArm", (28, 0, 0), None),
    ("LeftHand", "LeftForeArm", (25, 0, 0), (18, 0, 0)),
    ("RightArm", "Chest", (-17, 18, 0), None),
    ("RightForeArm", "RightArm", (-28, 0, 0), None),
    ("RightHand", "RightForeArm", (-25, 0, 0), (-18, 0, 0)),
]
STATURE_CM = 176.0
HAND = [
    ("RightHand", None, (0, 0, 0), None),
    *[
        (f"Right{finger}{k}", "RightHand" if k == 1 else f"Right{finger}{k - 1}", offset, tip)
        for finger, x in (("Thumb", -3), ("Index", -1.5), ("Middle", 0), ("Ring", 1.5))
        for k, offset, tip in (
            (1, (x, 0, 9), None),
            (2, (0, 0, 4), None),
            (3, (0, 0, 3), (0, 0, 2)),
        )
    ],
]


def _bvh(
    joints=BODY,
    unit_cm: float = 1.0,
    frames: int = 3,
    positions: str | None = None,
    names: dict[str, str] | None = None,
    header: str = "MOTION\nFrames: {n}\nFrame Time: 0.04\n",
) -> str:
    """BVH text of ``joints`` in a unit of ``unit_cm`` cm. Every joint but the root has
    three rotation channels, unless ``positions`` puts six channels on every joint, with
    position values ``"zero"`` (MakeHuman) or ``"offset"`` (Truebones)."""
    names = names or {}
    children: dict[str | None, list[int]] = {}
    for k, (_, parent, _, _) in enumerate(joints):
        children.setdefault(parent, []).append(k)
    lines = ["HIERARCHY"]
    columns: list[list[float]] = []

    def emit(k: int, depth: int) -> None:
        name, parent, offset, site = joints[k]
        pad = "  " * depth
        o = np.asarray(offset, float) / unit_cm
        lines.append(f"{pad}{'ROOT' if parent is None else 'JOINT'} {names.get(name, name)}")
        lines.append(f"{pad}{{")
        lines.append(f"{pad}  OFFSET {o[0]:.6g} {o[1]:.6g} {o[2]:.6g}")
        if parent is None or positions:
            lines.append(
                f"{pad}  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"
            )
            value = o if parent is None or positions == "offset" else np.zeros(3)
            columns.append([*value, 0.0, 0.0, 0.0])
        else:
            lines.append(f"{pad}  CHANNELS 3 Zrotation Xrotation Yrotation")
            columns.append([0.0, 0.0, 0.0])
        for child in children.get(name, []):
            emit(child, depth + 1)
        if site is not None:
            s = np.asarray(site, float) / unit_cm
            offset_line = f"{pad}    OFFSET {s[0]:.6g} {s[1]:.6g} {s[2]:.6g}"
            lines.extend([f"{pad}  End Site", f"{pad}  {{", offset_line, f"{pad}  }}"])
        lines.append(f"{pad}}}")

    emit(children[None][0], 0)
    row = " ".join(f"{v:.6g}" for column in columns for v in column)
    rows = []
    for t in range(frames):  # the root turns a little each frame: frames differ
        rows.append(row.replace(" 0 0 0", f" {3 * t} 0 0", 1) if t else row)
    return "\n".join(lines) + "\n" + header.format(n=frames) + "".join(r + "\n" for r in rows)


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_bytes(text.encode("utf-8"))
    return path


def _positions(motion) -> np.ndarray:
    return forward_kinematics(motion).all_positions()


def _cli(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


# --- 1. the MOTION header as other readers take it ------------------------------------------------


@pytest.mark.parametrize(
    "header",
    [
        "MOTION\n\nFrames: {n}\nFrame Time: 0.04\n",  # a blank line after MOTION
        "MOTION\nFrames:{n}\nFrame Time:0.04\n",  # no space after the colons
        "MOTION\n\n  Frames:   {n}\n\nFrame Time:\t0.04\n\n",  # blank lines everywhere
    ],
)
def test_motion_header_variants_are_read(tmp_path, header):
    plain = io.read_bvh(_write(tmp_path, "plain.bvh", _bvh()))
    variant = io.read_bvh(_write(tmp_path, "variant.bvh", _bvh(header=header)))
    assert variant.n_frames == 3 and variant.fps == 25.0
    np.testing.assert_array_equal(_positions(variant), _positions(plain))


# --- 2. one frame line more than announced (an exporter's off-by-one) ----------------------------


def test_an_extra_frame_line_is_read_with_a_warning_and_a_missing_one_is_an_error(tmp_path):
    text = _bvh(frames=4).replace("Frames: 4", "Frames: 3")
    path = _write(tmp_path, "extra.bvh", text)
    with pytest.warns(FormatWarning, match="announces 3 frames but the file has 4"):
        motion = io.read_bvh(path)
    assert motion.n_frames == 4
    motion, doubts = io.read_motion_checked(path)
    assert [d.kind for d in doubts] == ["read"] and "read all 4" in doubts[0].message
    result = _cli("info", path)
    assert result.exit_code == 0 and "announces 3 frames" in result.stderr
    short = _write(tmp_path, "short.bvh", _bvh(frames=2).replace("Frames: 2", "Frames: 3"))
    with pytest.raises(FormatError, match="announces 3 frames but the file has 2"):
        io.read_bvh(short)


# --- 3. UTF-8 joint names -------------------------------------------------------------------------

# Japanese (右腕: its UTF-8 bytes hold 0x85), German, French (à holds 0xA0), each a name whose
# bytes a Latin-1 reading split or garbled.
UTF8_NAMES = {
    "Hips": "Hüfte",
    "LeftArm": "左腕",
    "RightArm": "右腕",
    "Head": "Tête",
    "LeftForeArm": "Avant-bras à gauche",
    "Chest": "Brustkorb_Größe",
}


def test_utf8_joint_names_survive_read_info_and_convert(tmp_path):
    text = _bvh(names=UTF8_NAMES)
    raw = text.encode("utf-8")
    assert b"\x85" in raw and b"\xa0" in raw  # the bytes that str.split() took for spaces
    path = _write(tmp_path, "utf8.bvh", text)
    motion = io.read_bvh(path)
    for name in UTF8_NAMES.values():
        assert name in motion.skeleton.joint_names
    assert io.read_bvh(path).skeleton.joint_names == motion.skeleton.joint_names
    info = _cli("info", path, "--json")
    assert info.exit_code == 0, info.output
    assert json.loads(info.stdout)["pelvis"]["joint"] == "Hüfte"
    out = tmp_path / "again.bvh"
    assert _cli("convert", path, out).exit_code == 0
    again = io.read_bvh(out)
    assert again.skeleton.joint_names == motion.skeleton.joint_names
    np.testing.assert_allclose(_positions(again), _positions(motion), atol=1e-9)
    # A Latin-1 byte that is not UTF-8 (an HDM05 header's umlaut) still reads, as its letter.
    latin = tmp_path / "latin.bvh"
    latin.write_bytes(raw.replace("Hüfte".encode(), "H\xfcfte".encode("latin-1")))
    assert io.read_bvh(latin).skeleton.joint_names[0] == "Hüfte"


def test_utf8_joint_names_survive_the_web_app(tmp_path):
    from fastapi.testclient import TestClient

    from quatmotion import codec
    from quatmotion.server import create_app

    path = _write(tmp_path, "utf8.bvh", _bvh(names=UTF8_NAMES, frames=40))
    codec.Archive.build(
        [path], tmp_path / "x.qmz", codec.CompressSettings(max_error=1.0), runner=Runner.inline()
    )
    with TestClient(create_app(tmp_path / "x.qmz"), base_url="http://127.0.0.1") as client:
        listed = client.get("/api/clips").json()["clips"]
        (clip_id,) = [c["id"] for c in listed if "utf8" in c["name"]]
        payload = client.get(f"/api/clips/{clip_id}/frames")
        assert payload.status_code == 200, payload.text
        names = payload.json()["point_names"]
        assert "左腕" in names and "Hüfte" in names and "Avant-bras à gauche" in names


# --- 4. joint names with spaces -------------------------------------------------------------------


def test_joint_names_with_spaces_are_kept_and_written_back(tmp_path):
    biped = {n: f"Bip01 {n[0] if n[0] in 'LR' else ''} {n}".replace("  ", " ") for n, *_ in BODY}
    path = _write(tmp_path, "biped.bvh", _bvh(names=biped).replace("JOINT Bip01", "JOINT  Bip01"))
    motion = io.read_bvh(path)
    assert motion.skeleton.joint_names == tuple(biped.values())
    assert "JOINT Bip01 L LeftFoot" in io.bvh_text(motion)
    io.write_bvh(motion, tmp_path / "again.bvh")
    assert io.read_bvh(tmp_path / "again.bvh").skeleton.joint_names == tuple(biped.values())
    with pytest.raises(FormatError, match="joint name"):
        io.parse_bvh(_bvh().replace("JOINT Neck", "JOINT {"), "bad.bvh")


# --- 5. a clip of no frames -----------------------------------------------------------------------


def test_a_clip_of_no_frames_is_valid_everywhere_it_is_written(tmp_path):
    path = _write(tmp_path, "empty.bvh", _bvh(frames=0))
    motion = io.read_bvh(path)
    assert motion.n_frames == 0 and motion.skeleton.joint_names[0] == "Hips"
    for suffix in (".bvh", ".glb", ".gltf"):
        io.write_motion(motion, tmp_path / f"written{suffix}")
        back = io.read_motion(tmp_path / f"written{suffix}")
        assert back.n_frames == 0 and back.skeleton.joint_names == motion.skeleton.joint_names
    empty_amc = generate_clip("walk", 1, n_frames=4).slice(0, 0)
    io.write_amc(empty_amc, tmp_path / "empty.amc")
    io.write_asf(empty_amc.skeleton, tmp_path / "empty.asf")
    assert io.read_amc(tmp_path / "empty.amc").n_frames == 0
    result = _cli("info", path)
    assert result.exit_code == 0 and "0 (no frames)" in result.stdout, result.output
    assert _cli("convert", path, tmp_path / "converted.bvh").exit_code == 0


# --- 6. the one ASF of an AMC's folder, under another name ----------------------------------------


def test_info_says_which_asf_an_amc_was_read_with(tmp_path):
    clip = generate_clip("walk", 1, n_frames=5)
    io.write_amc(clip, tmp_path / "walking.amc")
    io.write_asf(clip.skeleton, tmp_path / "skeleton.asf")
    result = _cli("info", tmp_path / "walking.amc")
    assert result.exit_code == 0, result.output
    assert "skeleton.asf (the only ASF in its folder)" in result.stdout
    doc = json.loads(_cli("info", tmp_path / "walking.amc", "--json").stdout)
    assert doc["skeleton_file"].endswith("skeleton.asf (the only ASF in its folder)")


# --- 7. decimetres, numeric units, the guess weighed against a human stature ----------------------


@pytest.mark.parametrize(("unit", "cm"), [("dm", 10.0), ("in", 2.54), ("asf", 2.54 / 0.45)])
def test_the_unit_guess_weighs_every_unit_against_a_human_stature(tmp_path, unit, cm):
    path = _write(tmp_path, f"{unit}.bvh", _bvh(unit_cm=cm))
    motion = io.read_bvh(path)
    assert motion.skeleton.extras["bvh_unit"] == unit and motion.skeleton.extras["bvh_unit_guessed"]
    assert io.body_size(motion) == pytest.approx(STATURE_CM)
    assert io.implausible_values(motion) == []


def test_a_t_pose_child_is_read_in_centimetres(tmp_path):
    # A 90 cm child in a T-pose: 229 cm read in inches is no human, 90 cm is.
    child = [(n, p, tuple(v * 90 / STATURE_CM for v in o), s) for n, p, o, s in BODY]
    child = [(n, p, o, s and tuple(v * 90 / STATURE_CM for v in s)) for n, p, o, s in child]
    motion = io.read_bvh(_write(tmp_path, "child.bvh", _bvh(child)))
    assert motion.skeleton.extras["bvh_unit"] == "cm"
    assert io.body_size(motion) == pytest.approx(90.0, rel=1e-5)


def test_units_by_name_or_number_everywhere(tmp_path):
    path = _write(tmp_path, "dm.bvh", _bvh(unit_cm=10.0))
    by_name = io.read_motion(path, units="dm")
    by_number = io.read_motion(path, units="10")
    np.testing.assert_array_equal(_positions(by_name), _positions(by_number))
    assert by_name.skeleton.extras["bvh_unit"] == "dm"
    assert ReadSettings(units="dm").units == "dm" and ReadSettings(units=2.54).units == 2.54
    for given, cm in (("dm", 10.0), ("10", 10.0), ("2.54", 2.54)):
        result = _cli("info", path, "--units", given, "--json")
        assert result.exit_code == 0, result.output
        assert json.loads(result.stdout)["cm_per_unit"] == pytest.approx(cm)
    result = _cli("info", path, "--units", "-3")
    assert result.exit_code == 2 and "error:" in result.stderr and "positive" in result.stderr


# --- 8. position channels on every joint ----------------------------------------------------------


def test_position_channels_near_zero_are_relative_and_near_the_offsets_absolute(tmp_path):
    plain = io.read_bvh(_write(tmp_path, "plain.bvh", _bvh(unit_cm=10.0)))
    zero = _write(tmp_path, "zero.bvh", _bvh(unit_cm=10.0, positions="zero"))  # MakeHuman
    with pytest.warns(FormatWarning, match="read as relative"):
        relative = io.read_bvh(zero)
    assert relative.skeleton.extras["bvh_translations"] == "relative"
    assert relative.skeleton.extras["bvh_unit"] == "dm"  # not a 14 cm figure blamed on the unit
    np.testing.assert_allclose(_positions(relative), _positions(plain), atol=1e-9)
    offsets = _write(tmp_path, "offsets.bvh", _bvh(positions="offset"))  # Truebones
    with warnings.catch_warnings():
        warnings.simplefilter("error", FormatWarning)
        absolute = io.read_bvh(offsets)
    assert absolute.skeleton.extras["bvh_translations"] == "absolute"
    in_cm = io.read_bvh(_write(tmp_path, "cm.bvh", _bvh()))
    np.testing.assert_allclose(_positions(absolute), _positions(in_cm), atol=1e-9)
    # Written back in the mode read: the file's numbers come back.
    io.write_bvh(relative, tmp_path / "again.bvh")
    with pytest.warns(FormatWarning, match="read as relative"):
        again = io.read_bvh(tmp_path / "again.bvh")
    assert again.skeleton.extras["bvh_translations"] == "relative"
    last = [(p.read_text().splitlines()[-1]).split() for p in (tmp_path / "again.bvh", zero)]
    np.testing.assert_array_equal(np.array(last[0], float), np.array(last[1], float))
    # Given, not detected: root-only ignores them, absolute collapses the figure as asked.
    ignored = io.read_bvh(zero, translations="root-only")
    np.testing.assert_allclose(_positions(ignored), _positions(plain), atol=1e-9)
    collapsed = io.read_bvh(zero, scale="dm", translations="absolute")
    assert io.body_size(collapsed) < 0.2 * STATURE_CM  # only the end sites left
    info = _cli("info", zero)
    assert "read as relative to the offsets (detected)" in info.stdout, info.output
    assert "read as relative" in info.stderr
    given = _cli("info", zero, "--bvh-translations", "root-only")
    assert given.exit_code == 0 and "ignored (root only) (given)" in given.stdout
    bad = _cli("info", zero, "--bvh-translations", "sideways")
    assert bad.exit_code == 2 and "root-only" in bad.stderr
    # The collection's read settings carry the option, validated once.
    from quatmotion.collection import find_clips, read_clip

    with pytest.raises(ValueError, match="translations"):
        ReadSettings(translations="sideways")
    settings = ReadSettings(translations="root-only")
    (source,) = find_clips([zero], settings)
    read = read_clip(source, settings)
    assert read.motion.skeleton.extras["bvh_translations"] == "root-only" and read.doubts == []


# --- 9. an ASF whose :units length means metres ---------------------------------------------------


# A body in metres, its :units saying length 0.01 (NaturalMotion endorphin's way): read as the
# ASF documents it (one unit 1/0.01 inch, 254 cm) it is 437 cm tall; in metres, 172 cm.
METRES_ASF = (
    """:version 1.10
:name endorphin
:units
  mass 1.0
  length 0.01
  angle deg
:root
   order TX TY TZ RX RY RZ
   axis XYZ
   position 0 0 0
   orientation 0 0 0
:bonedata
"""
    + "".join(
        f"""  begin
     name {name}
     direction {direction}
     length {length}
     axis 0 0 0 XYZ
    dof rx ry rz
  end
"""
        for name, direction, length in (
            ("lfemur", "0 -1 0", 0.45),
            ("ltibia", "0 -1 0", 0.42),
            ("lfoot", "0 0 1", 0.08),
            ("rfemur", "0 -1 0", 0.45),
            ("rtibia", "0 -1 0", 0.42),
            ("rfoot", "0 0 1", 0.08),
            ("lowerback", "0 1 0", 0.3),
            ("thorax", "0 1 0", 0.25),
            ("lowerneck", "0 1 0", 0.1),
            ("head", "0 1 0", 0.2),
        )
    )
    + """:hierarchy
  begin
    root lfemur rfemur lowerback
    lfemur ltibia
    ltibia lfoot
    rfemur rtibia
    rtibia rfoot
    lowerback thorax
    thorax lowerneck
    lowerneck head
  end
"""
)
BONES = ("lfemur", "ltibia", "lfoot", "rfemur", "rtibia", "rfoot", "lowerback", "thorax",
         "lowerneck", "head")  # fmt: skip
METRES_AMC = ":FULLY-SPECIFIED\n:DEGREES\n" + "".join(
    f"{k}\nroot 0 0.9 {0.01 * k} 0 0 0\n" + "".join(f"{b} {k} 0 0\n" for b in BONES)
    for k in (1, 2, 3)
)


def test_an_asf_stature_is_checked_and_its_unit_can_be_given(tmp_path):
    (tmp_path / "endorphin.asf").write_text(METRES_ASF)
    amc = _write(tmp_path, "endorphin.amc", METRES_AMC)
    motion, doubts = io.read_motion_checked(amc)
    stature = io.body_size(motion)
    assert stature == pytest.approx(1.72 * 254.0, rel=1e-9)  # as documented: 437 cm
    (doubt,) = [d for d in doubts if d.kind == "unit"]
    assert "172 cm read in m" in doubt.message and ":units length 0.01" in doubt.message
    given = io.read_motion(amc, units="m")
    assert io.body_size(given) == pytest.approx(172.0)
    assert io.implausible_values(given) == []
    assert given.skeleton.extras["length_unit_given"]
    result = _cli("info", amc)
    assert (
        result.exit_code == 0 and "172 cm read in m" in result.stderr and "--units" in result.stderr
    )
    result = _cli("info", amc, "--units", "m")
    assert result.exit_code == 0 and "warning" not in result.stderr, result.output
    # CMU's ASF, in its stated unit, is a human: no doubt.
    clip = generate_clip("walk", 1, n_frames=5)
    assert [d for d in io.implausible_values(clip) if d.kind == "unit"] == []


# --- 10. a skeleton that is not a body ------------------------------------------------------------


def test_a_lone_hand_is_not_scaled_as_a_body(tmp_path):
    motion = io.read_bvh(_write(tmp_path, "hand.bvh", _bvh(HAND)))
    assert io.find_body(motion.skeleton) is None and io.body_size(motion) is None
    assert motion.skeleton.extras["bvh_scale"] == 1.0  # not 96 cm: read as it is, in cm
    (doubt,) = io.implausible_values(motion)
    assert doubt.kind == "unit" and "not a body" in doubt.message
    unnamed = {n: f"joint{k}" for k, (n, *_) in enumerate(HAND)}  # no names to go by: its shape
    assert (
        io.find_body(io.read_bvh(_write(tmp_path, "h.bvh", _bvh(HAND, names=unnamed))).skeleton)
        is None
    )
    body = {n: f"joint{k}" for k, (n, *_) in enumerate(BODY)}  # a body by its shape alone
    assert (
        io.find_body(io.read_bvh(_write(tmp_path, "b.bvh", _bvh(names=body))).skeleton) is not None
    )
    assert io.find_body(cmu_skeleton()) is not None


# --- 11. an upright T-pose the 16-joint mapping does not know -------------------------------------


def test_an_upright_t_pose_is_not_said_to_lie_along_its_arms(tmp_path):
    mixamo = {n: f"mixamorig:{n}" for n, *_ in BODY}
    path = _write(tmp_path, "mixamo.bvh", _bvh(names=mixamo))
    doc = json.loads(_cli("info", path, "--json").stdout)
    assert doc["rest_pose_lies_along"] is None and doc["body_axis_known"]
    assert doc["rest_pose_height_cm"] == pytest.approx(173.0)
    lying = [
        (n, p, (o[0], -o[2], o[1]) if p else o, s and (s[0], -s[2], s[1])) for n, p, o, s in BODY
    ]
    doc = json.loads(
        _cli("info", _write(tmp_path, "lying.bvh", _bvh(lying, names=mixamo)), "--json").stdout
    )
    assert doc["rest_pose_lies_along"] == "Z"
    hand = json.loads(_cli("info", _write(tmp_path, "hand.bvh", _bvh(HAND)), "--json").stdout)
    assert hand["rest_pose_lies_along"] is None and not hand["body_axis_known"]
