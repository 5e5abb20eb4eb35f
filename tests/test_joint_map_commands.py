"""``--joint-map`` on the pose commands and ``serve`` (issue 31): a rig whose joint names say
nothing and whose rest pose lies flat (spine along +Z, every limb straight down, as a
quadruped's) is refused by names and structure alike, and is mapped by a user's map alone:
``pose index``/``pose add``/``pose search`` and ``serve DIR``'s build (index and pose index)
take it with ``--joint-map``; the map is stored in the pose file and the index, read back by
``pose add`` and by a query file, and shown by ``pose ls`` and ``index ls``."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from quatmotion import io
from quatmotion.cli import app
from quatmotion.motion import HumanoidError, Motion, map_humanoid
from quatmotion.synthetic import generate_clip

_SPINE = ("lowerback", "upperback", "thorax", "lowerneck", "upperneck", "head")
_ARM = ("humerus", "radius", "wrist", "hand", "fingers", "thumb")
_CANONICAL = {
    "Hip": "root", "Chest": "thorax", "Neck": "lowerneck", "Head": "head",
    "LShoulder": "lhumerus", "LElbow": "lradius", "LHand": "lwrist",
    "RShoulder": "rhumerus", "RElbow": "rradius", "RHand": "rwrist",
    "LHip": "lfemur", "LKnee": "ltibia", "LFoot": "lfoot",
    "RHip": "rfemur", "RKnee": "rtibia", "RFoot": "rfoot",
}  # fmt: skip
SMALL_POSES = ["--rank", "2", "--pairs", "20", "--unlabeled", "50", "--workers", "1"]


def _flat_rig(kind: str, seed: int) -> tuple[Motion, dict[str, str]]:
    """A generated clip on a rig of names ``boneNN`` lying flat (no humanoid by structure),
    and the user's map of its 16 joints (canonical -> the rig's name)."""
    motion = generate_clip(kind, seed, n_frames=60, fps=30.0)
    sk = motion.skeleton
    names = list(sk.joint_names)
    offsets = np.array(sk.offsets, dtype=np.float64)
    for j, name in enumerate(names):
        if name in _SPINE or name.endswith("clavicle"):  # turned forward: y up becomes z
            offsets[j] = (offsets[j, 0], -offsets[j, 2], offsets[j, 1])
        elif name[1:] in _ARM:  # the arms hang straight down
            offsets[j] = (0.0, -np.linalg.norm(offsets[j]), 0.0)
    renamed = tuple(f"bone{j:02d}" for j in range(len(names)))
    skeleton = dataclasses.replace(sk, joint_names=renamed, offsets=offsets)
    flat = Motion(skeleton, motion.fps, motion.root_translation, motion.rotations, name=kind)
    return flat, {k: renamed[names.index(v)] for k, v in _CANONICAL.items()}


@pytest.fixture(scope="module")
def rig(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("rig")
    (folder / "clips").mkdir()
    walk, mapping = _flat_rig("walk", 0)
    squat, _ = _flat_rig("squat", 1)
    io.write_motion(walk, folder / "clips" / "walk.bvh")
    io.write_motion(squat, folder / "squat.bvh")
    (folder / "map.json").write_text(json.dumps(mapping))
    return {
        "walk": folder / "clips" / "walk.bvh",
        "squat": folder / "squat.bvh",
        "map": folder / "map.json",
        "clips": folder / "clips",
    }


def _entries(rig: dict[str, Path]) -> tuple[str, ...]:
    return tuple(f"{k}={v}" for k, v in json.loads(rig["map"].read_text()).items())


def test_the_rig_maps_only_through_the_users_map(rig):
    motion = io.read_motion(rig["walk"])
    with pytest.raises(HumanoidError, match="not a humanoid"):
        map_humanoid(motion.skeleton)
    from quatmotion.collection import with_joint_map

    mapped = map_humanoid(with_joint_map(motion, _entries(rig)).skeleton)
    assert mapped.summary().endswith("16 by user")


def test_pose_index_add_search_and_ls_with_the_users_map(rig, tmp_path):
    from quatmotion.pose.library import PoseLibrary

    runner = CliRunner()
    out = tmp_path / "p.npz"
    refused = runner.invoke(
        app, ["pose", "index", str(rig["walk"]), "-o", str(out), "--units", "cm", *SMALL_POSES]
    )
    assert refused.exit_code != 0 and not out.exists()  # no map: not a humanoid
    built = runner.invoke(
        app, ["pose", "index", str(rig["walk"]), "-o", str(out), "--units", "cm",
              "--joint-map", str(rig["map"]), *SMALL_POSES],
    )  # fmt: skip
    assert built.exit_code == 0, built.output
    assert PoseLibrary.open(out).settings.read.joint_map == _entries(rig)
    # pose add reads the new clip with the stored map (no --joint-map given)
    added = runner.invoke(app, ["pose", "add", str(out), str(rig["squat"]), "--workers", "1"])
    assert added.exit_code == 0 and "1 clips added" in added.output, added.output
    listing = runner.invoke(app, ["pose", "ls", str(out)])
    assert listing.exit_code == 0, listing.output
    assert "16 by user" in listing.output and "joint map Hip=bone00" in listing.output
    doc = json.loads(runner.invoke(app, ["pose", "ls", str(out), "--json"]).stdout)
    (entry,) = doc["skeletons"].values()
    assert entry["joints"]["LHip"]["how"] == "user"
    assert doc["settings"]["read"]["joint_map"] == list(_entries(rig))
    # a query file of the rig: the stored map, or the one given
    for extra in ([], ["--joint-map", str(rig["map"])]):
        found = runner.invoke(
            app, ["pose", "search", str(out), "--file", str(rig["squat"]), "-f", "10",
                  "--units", "cm", "-k", "3", "--json", *extra],
        )  # fmt: skip
        assert found.exit_code == 0, found.output
        results = json.loads(found.stdout)["results"]
        assert results[0]["clip"] == "squat" and results[0]["distance"] < 1e-3, results


def test_index_build_search_and_ls_with_the_users_map(rig, tmp_path):
    runner = CliRunner()
    out = tmp_path / "x.qidx"
    refused = runner.invoke(
        app, ["index", "build", str(rig["walk"]), "-o", str(out), "--units", "cm"]
    )
    assert refused.exit_code == 2 and not out.exists()
    built = runner.invoke(
        app, ["index", "build", str(rig["clips"]), "-o", str(out), "--units", "cm",
              "--joint-map", str(rig["map"])],
    )  # fmt: skip
    assert built.exit_code == 0, built.output
    added = runner.invoke(app, ["index", "add", str(out), str(rig["squat"])])
    assert added.exit_code == 0 and "1 clips added" in added.output, added.output
    listing = runner.invoke(app, ["index", "ls", str(out)])
    assert "16 by user" in listing.output and "Hip=bone00" in listing.output, listing.output
    found = runner.invoke(
        app, ["search", "--index", str(out), str(rig["squat"]), "--units", "cm", "--json"]
    )
    assert found.exit_code == 0, found.output
    assert json.loads(found.stdout)["left_out"] == "squat"  # its own clip, mapped alike


def test_serve_builds_a_folder_with_the_users_map(rig, tmp_path):
    from fastapi.testclient import TestClient

    from quatmotion.demo import build_library
    from quatmotion.server import create_app

    refused = CliRunner().invoke(app, ["serve", "--joint-map", str(rig["map"])])
    assert refused.exit_code == 2 and "folder" in refused.output
    without = build_library(tmp_path / "without", [rig["clips"]], workers=1, poses=False)
    assert without.failed and "not a humanoid" in without.failed[0]
    built = build_library(tmp_path / "with", [rig["clips"]], workers=1, joint_map=_entries(rig))
    assert not built.failed, built.failed
    application = create_app(built.library, built.index, built.poses)
    with TestClient(application, base_url="http://127.0.0.1") as client:
        (clip,) = client.get("/api/clips").json()["clips"]
        assert clip["in_index"] and clip["in_poses"], clip
        poses = client.get("/api/poses", params={"clip": clip["id"], "frame": 12, "k": 2})
        assert poses.status_code == 200, poses.text
        assert poses.json()["results"][0]["frame"] == 12
