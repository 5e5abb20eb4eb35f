"""The humanoid mapping: every naming family, helpers, order and mirror map joint for joint."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from quatmotion import io
from quatmotion.cli import app
from quatmotion.datasets import data_root
from quatmotion.motion import JOINTS_16, HumanoidError, Skeleton, map_humanoid, with_joint_map
from quatmotion.motion.humanoid import parse_name
from quatmotion.pose import skeleton16 as s16
from quatmotion.synthetic import cmu_skeleton
from quatmotion.synthetic.rerig import FAMILIES, rerig

DATA = data_root(must_exist=False)
MIRROR = [
    JOINTS_16.index(("R" if n[0] == "L" else "L") + n[1:]) if n[0] in "LR" else k
    for k, n in enumerate(JOINTS_16)
]


def _sources() -> dict[str, Path]:
    return {
        "cmu_asf": DATA / "cmu" / "01" / "01_01.amc",
        "hdm05": next(iter(sorted((DATA / "hdm05" / "clips").glob("*/*.amc"))), Path("-")),
        "cmu_bvh": DATA / "cmu_bvh" / "07" / "07_01.bvh",
        "bandai": next(iter(sorted((DATA / "bandai1" / "clips").glob("*.bvh"))), Path("-")),
    }


@pytest.fixture(scope="module")
def shared() -> dict[str, object]:
    return {name: io.read_motion(path).slice(0, 30) for name, path in _sources().items()}


@pytest.mark.parametrize(
    ("name", "family", "key", "side"),
    [
        ("mixamorig:LeftUpLeg", "upleg", "upleg", "L"),
        ("thigh_l", "thigh", "thigh", "L"),
        ("Bip01 R Calf", "calf", "calf", "R"),
        ("DEF-upper_arm.L.001", "upperarm", "upperarm", "L"),
        ("L_Hip", "hip", "hip", "L"),
        ("ShoulderRight", "shoulder", "shoulder", "R"),
        ("upperleg01.R", "upperleg", "upperleg", "R"),
        ("CC_Base_L_Forearm", "forearm", "forearm", "L"),
        ("lhumerus", "humerus", "humerus", "L"),
        ("J_Bip_R_LowerLeg", "lowerleg", "lowerleg", "R"),
        ("Neck1", "neck", "neck", None),
        ("Chest", "chest", "chest", None),
        ("RightArm", "arm", "arm", "R"),
    ],
)
def test_names_normalise_namespace_prefix_case_and_side(name, family, key, side) -> None:
    parsed = parse_name(name)
    assert (parsed.key, parsed.side) == (key, side)


@pytest.mark.needs_data
@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_every_family_maps_the_shared_skeletons_joint_for_joint(shared, family) -> None:
    for source, motion in shared.items():
        original = map_humanoid(motion.skeleton)
        want = s16.world_positions16(motion)
        for options in ({}, {"twist": False, "drop_extremities": False, "reorder": False}):
            copy = rerig(motion, family, **options)
            mapping = map_humanoid(copy.motion.skeleton)
            expected = tuple(copy.renamed[p] for p in original.points)
            assert mapping.points == expected, (source, family, options)
            np.testing.assert_allclose(s16.world_positions16(copy.motion), want, atol=1e-6)


@pytest.mark.needs_data
@pytest.mark.parametrize("source", ["cmu_asf", "hdm05", "cmu_bvh"])
def test_structure_alone_maps_an_unnamed_and_a_mirrored_rig(shared, source) -> None:
    motion = shared[source]
    original = map_humanoid(motion.skeleton).points
    for mirror in (False, True):
        copy = rerig(motion, "mixamo", strip_names=True, mirror=mirror)
        back = {new: old for old, new in copy.renamed.items()}
        mapping = map_humanoid(copy.motion.skeleton)
        assert set(mapping.how) == {"structure"}
        got = [back[p] for p in mapping.points]
        # mirrored, the leg that was the right one now lies on the left: it is LHip
        want = [original[MIRROR[k]] for k in range(16)] if mirror else list(original)
        assert got == want, (source, mirror)


@pytest.mark.needs_data
def test_names_decide_left_and_right_not_file_order(shared) -> None:
    motion = shared["cmu_bvh"]
    copy = rerig(motion, "unreal", reorder=True)
    names = copy.motion.skeleton.joint_names
    assert names.index("thigh_r") < names.index("thigh_l")  # right listed first
    mapping = map_humanoid(copy.motion.skeleton)
    assert mapping.points[JOINTS_16.index("LHip")] == "thigh_l"


def _chain_skeleton(bones: list[tuple[str, str | None, tuple[float, float, float]]]) -> Skeleton:
    index = {b[0]: i for i, b in enumerate(bones)}
    return Skeleton(
        joint_names=tuple(b[0] for b in bones),
        parents=np.array([-1 if p is None else index[p] for _, p, _ in bones]),
        offsets=np.array([o for *_, o in bones], dtype=float),
        channels=tuple(("rz", "rx", "ry") for _ in bones),
        name="rig",
    )


_BODY = [
    ("Hips", None, (0, 95, 0)),
    ("Spine", "Hips", (0, 25, 0)),
    ("Neck", "Spine", (0, 20, 0)),
    ("Head", "Neck", (0, 12, 0)),
    ("UpperArm_L", "Spine", (18, 15, 0)),
    ("LowerArm_L", "UpperArm_L", (28, 0, 0)),
    ("Hand_L", "LowerArm_L", (25, 0, 0)),
    ("UpperArm_R", "Spine", (-18, 15, 0)),
    ("LowerArm_R", "UpperArm_R", (-28, 0, 0)),
    ("Hand_R", "LowerArm_R", (-25, 0, 0)),
    ("UpperLeg_L", "Hips", (9, -5, 0)),
    ("LowerLeg_L", "UpperLeg_L", (0, -42, 0)),
    ("Foot_L", "LowerLeg_L", (0, -40, 0)),
    ("UpperLeg_R", "Hips", (-9, -5, 0)),
    ("LowerLeg_R", "UpperLeg_R", (0, -42, 0)),
    ("Foot_R", "LowerLeg_R", (0, -40, 0)),
]


def test_a_rig_without_a_neck_maps_what_it_has_and_says_what_it_estimated() -> None:
    bones = [b for b in _BODY if b[0] != "Neck"]
    bones = [("Head", "Spine", (0, 32, 0)) if b[0] == "Head" else b for b in bones]
    mapping = map_humanoid(_chain_skeleton(bones))
    assert mapping.estimated == ("Neck",)
    rest = _chain_skeleton(bones).rest_positions()
    neck = mapping.positions(rest)[JOINTS_16.index("Neck")]
    chest, head = rest[1], rest[bones.index(("Head", "Spine", (0, 32, 0)))]
    np.testing.assert_allclose(neck, chest + 0.4 * (head - chest))
    assert "estimated Neck" in mapping.summary()


def test_a_neck_named_neck1_and_no_head_joint() -> None:
    bones = [("Neck1", *b[1:]) if b[0] == "Neck" else b for b in _BODY if b[0] != "Head"]
    sk = _chain_skeleton(bones)
    sk = Skeleton(**{**_fields(sk), "site_names": ("Neck1_end",), "site_parents": [2],
                     "site_offsets": [[0.0, 12.0, 0.0]]})  # fmt: skip
    mapping = map_humanoid(sk)
    assert mapping.points[:4] == ("Hips", "Spine", "Neck1", "Neck1_end")
    assert mapping.how[3] == "structure"


def _fields(sk: Skeleton) -> dict[str, object]:
    return {
        "joint_names": sk.joint_names,
        "parents": sk.parents,
        "offsets": sk.offsets,
        "channels": sk.channels,
        "name": sk.name,
    }


def test_non_humanoids_are_refused_with_the_reason() -> None:
    prop = _chain_skeleton([("Sword", None, (0, 0, 0)), ("Blade", "Sword", (0, 80, 0))])
    with pytest.raises(HumanoidError, match="not a humanoid"):
        map_humanoid(prop)
    face = _chain_skeleton(
        [("head", None, (0, 0, 0)), ("jaw", "head", (0, -8, 5)), ("eye_l", "head", (3, 4, 8)),
         ("eye_r", "head", (-3, 4, 8)), ("brow", "head", (0, 7, 8))]
    )  # fmt: skip
    with pytest.raises(HumanoidError, match="not a humanoid"):
        map_humanoid(face)
    dog = _chain_skeleton(
        [("pelvis", None, (0, 60, 0)), ("spine", "pelvis", (0, 0, 30)), ("chest", "spine",
         (0, 0, 30)), ("neck", "chest", (0, 10, 10)), ("head", "neck", (0, 5, 12)),
         ("tail", "pelvis", (0, 5, -30)), ("hind_l", "pelvis", (8, -30, 0)),
         ("hindpaw_l", "hind_l", (0, -28, 0)), ("hind_r", "pelvis", (-8, -30, 0)),
         ("hindpaw_r", "hind_r", (0, -28, 0)), ("front_l", "chest", (8, -30, 0)),
         ("frontpaw_l", "front_l", (0, -28, 0)), ("front_r", "chest", (-8, -30, 0)),
         ("frontpaw_r", "front_r", (0, -28, 0))]
    )  # fmt: skip
    with pytest.raises(HumanoidError, match="not a humanoid"):
        map_humanoid(dog)
    dog_unnamed = Skeleton(
        **{**_fields(dog), "joint_names": tuple(f"b{k}" for k in range(dog.n_joints))}
    )
    with pytest.raises(HumanoidError, match="quadruped|not a humanoid"):
        map_humanoid(dog_unnamed)


def test_a_user_map_wins_and_is_checked() -> None:
    sk = _chain_skeleton(_BODY)
    mapped = with_joint_map(sk, {"Chest": "Neck", "neck": "Head"})
    mapping = map_humanoid(mapped)
    assert mapping.points[1:3] == ("Neck", "Head") and mapping.how[1:3] == ("user", "user")
    with pytest.raises(HumanoidError, match="Pelvis"):
        with_joint_map(sk, {"Hip": "Pelvis"})
    with pytest.raises(HumanoidError, match="no canonical joint"):
        with_joint_map(sk, {"Tail": "Hips"})


def test_joint_map_files_csv_and_json(tmp_path: Path) -> None:
    csv_file = tmp_path / "map.csv"
    csv_file.write_text("canonical,joint\n# the thighs\nLHip,thigh_l\nRightHip,thigh_r\n")
    assert io.read_joint_map(csv_file) == {"LHip": "thigh_l", "RHip": "thigh_r"}
    json_file = tmp_path / "map.json"
    json_file.write_text(json.dumps({"LKnee": "calf_l"}))
    assert io.read_joint_map(json_file) == {"LKnee": "calf_l"}
    bad = tmp_path / "bad.csv"
    bad.write_text("LHip,thigh_l\nLHip,thigh_r\n")
    with pytest.raises(io.FormatError if hasattr(io, "FormatError") else ValueError, match=":2"):
        io.read_joint_map(bad)


def test_an_unmappable_skeleton_is_one_error_line_naming_candidates_and_the_option(
    tmp_path: Path,
) -> None:
    from quatmotion.motion import Motion

    bones = [b for b in _BODY if b[0] not in ("Hand_L", "LowerArm_L")]
    sk = _chain_skeleton(bones)
    quat = np.zeros((3, sk.n_joints, 4))
    quat[..., 0] = 1
    motion = Motion(sk, 30.0, np.zeros((3, 3)) + [0, 95, 0], quat, name="onearm")
    path = tmp_path / "onearm.bvh"
    io.write_motion(motion, path)
    result = CliRunner().invoke(app, ["index", "build", str(path), "-o", str(tmp_path / "x.qidx")])
    assert result.exit_code == 2 and not (tmp_path / "x.qidx").exists()
    output = result.output
    assert "missing LElbow, LHand" in output and "--joint-map" in output, output
    assert "LowerArm_R" in output  # the nearest candidates
    info = CliRunner().invoke(app, ["info", str(path)])
    assert info.exit_code == 0 and "not mapped" in info.output


def test_index_build_stores_the_joint_map_and_info_prints_the_mapping(tmp_path: Path) -> None:
    from quatmotion.retrieval.index import ClipIndex
    from quatmotion.synthetic import generate_clip

    motion = generate_clip("walk", 0)
    copy = rerig_synthetic(motion)
    clip = tmp_path / "walk.bvh"
    io.write_motion(copy, clip)
    map_file = tmp_path / "map.json"
    map_file.write_text(json.dumps({"LHip": "joint_a", "RHip": "joint_b"}))
    runner = CliRunner()
    index = tmp_path / "x.qidx"
    result = runner.invoke(
        app, ["index", "build", str(clip), "-o", str(index), "--joint-map", str(map_file)]
    )
    assert result.exit_code == 0, result.output
    with ClipIndex.open(index) as idx:
        assert idx.settings.read.joint_map == ("LHip=joint_a", "RHip=joint_b")
    info = runner.invoke(app, ["info", str(clip), "--joint-map", str(map_file)])
    assert "joint_a (user)" in info.output
    listing = runner.invoke(app, ["index", "ls", str(index)])
    assert "2 by user" in listing.output and "LHip=joint_a" in listing.output, listing.output
    doc = json.loads(runner.invoke(app, ["index", "ls", str(index), "--json"]).stdout)
    (entry,) = doc["skeletons"].values()
    assert entry["joints"]["LHip"] == {"joint": "joint_a", "how": "user"}
    bad = runner.invoke(
        app, ["index", "build", str(clip), "-o", str(tmp_path / "y.qidx"), "--joint-map",
              str(tmp_path / "missing.json")]
    )  # fmt: skip
    assert bad.exit_code == 2 and "missing.json" in bad.output


def rerig_synthetic(motion):  # the generator's CMU-like body with its thighs renamed
    names = list(motion.skeleton.joint_names)
    names[names.index("lfemur")] = "joint_a"
    names[names.index("rfemur")] = "joint_b"
    sk = motion.skeleton
    skeleton = dataclasses.replace(sk, joint_names=tuple(names))
    from quatmotion.motion import Motion

    return Motion(skeleton, motion.fps, motion.root_translation, motion.rotations, name="walk")


@pytest.mark.needs_data
def test_retrieval_on_a_rerigged_bandai1_scores_as_the_original() -> None:
    from quatmotion.bench.retrieval import retrieval_scores
    from quatmotion.datasets import catalogue
    from quatmotion.retrieval.features import clip_features, skeleton_fingerprint
    from quatmotion.retrieval.methods import DEFAULT_METHOD, METHODS, Library, QueryFeatures

    entries = catalogue(collection="bandai1")[::3]
    labels = [e.label for e in entries]
    scores = []
    for family in (None, "unreal", "mixamo"):
        features, prints = [], []
        for entry in entries:
            motion = io.read_motion(entry.path)
            if family is not None:
                motion = rerig(motion, family).motion
            features.append(clip_features(motion, ("motion",)))
            prints.append(skeleton_fingerprint(motion.skeleton))
        library = Library(features, prints)
        rankings = [
            METHODS[DEFAULT_METHOD].rank(library, QueryFeatures(features[i], prints[i]), exclude=i)
            for i in range(len(entries))
        ]
        scores.append(retrieval_scores(rankings, labels)["map"])
    assert max(abs(s - scores[0]) for s in scores) <= 0.01, scores


def test_the_cmu_like_generator_maps_by_name() -> None:
    assert map_humanoid(cmu_skeleton()).how.count("name") >= 14
