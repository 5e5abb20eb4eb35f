"""glTF 2.0 in and out (issue 21): BVH -> glTF -> BVH keeps joint positions within 1e-4 cm, a
file's own structure (an armature node above the root, a named animation) is read, bad files
are refused naming the field, and every command takes .glb clips like any other."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from quatmotion import codec, io, quat
from quatmotion.cli import app
from quatmotion.datasets import data_root
from quatmotion.errors import FormatError
from quatmotion.io.gltf import read_gltf, write_gltf
from quatmotion.motion import forward_kinematics
from quatmotion.synthetic import cmu_skeleton, generate_clip

DATA = data_root(must_exist=False)
ROUND_TRIP_CM = 1e-4


def _positions(motion) -> np.ndarray:
    return forward_kinematics(motion).all_positions()


def _cli(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def _bvh_round_trip(bvh: Path, tmp_path: Path, suffix: str) -> float:
    """Largest joint or end-site distance, cm, between a BVH and its BVH -> glTF -> BVH copy."""
    original = io.read_motion(bvh)
    gltf = tmp_path / f"{bvh.stem}{suffix}"
    io.write_motion(original, gltf)
    io.write_motion(io.read_motion(gltf), tmp_path / "back.bvh")
    back = io.read_motion(tmp_path / "back.bvh", units="cm")  # the writer's unit
    assert back.skeleton.joint_names == original.skeleton.joint_names
    assert back.skeleton.site_names == original.skeleton.site_names
    assert back.n_frames == original.n_frames and back.fps == original.fps
    return float(np.max(np.linalg.norm(_positions(back) - _positions(original), axis=-1)))


@pytest.mark.parametrize("suffix", [".glb", ".gltf"])
@pytest.mark.parametrize(("kind", "height"), [("walk", 170.0), ("jump", 120.0), ("run", 195.0)])
def test_bvh_to_gltf_to_bvh_keeps_joint_positions(tmp_path, suffix, kind, height):
    clip = generate_clip(kind, 2, n_frames=90, skeleton=cmu_skeleton(height))
    io.write_bvh(clip, tmp_path / "clip.bvh")
    assert _bvh_round_trip(tmp_path / "clip.bvh", tmp_path, suffix) <= ROUND_TRIP_CM


@pytest.mark.needs_data
@pytest.mark.parametrize("collection", ["bandai1", "cmu_bvh"])
def test_bvh_to_gltf_to_bvh_on_the_shared_libraries(tmp_path, collection):
    for path in sorted((DATA / collection).rglob("*.bvh"))[::25][:3]:
        assert _bvh_round_trip(path, tmp_path, ".glb") <= ROUND_TRIP_CM, path


@pytest.mark.needs_data
def test_an_amc_through_gltf_keeps_joint_positions(tmp_path):
    amc = sorted((DATA / "cmu").rglob("*.amc"))[0]
    original = io.read_motion(amc)
    write_gltf(original, tmp_path / "x.glb")
    back = read_gltf(tmp_path / "x.glb")
    error = np.max(np.linalg.norm(_positions(back) - _positions(original), axis=-1))
    assert error <= ROUND_TRIP_CM


def test_the_file_is_gltf_as_other_tools_read_it(tmp_path):
    import pygltflib

    clip = generate_clip("walk", 1, n_frames=30)
    write_gltf(clip, tmp_path / "x.glb")
    gltf = pygltflib.GLTF2().load(str(tmp_path / "x.glb"))
    sk = clip.skeleton
    assert [n.name for n in gltf.nodes] == [*sk.joint_names, *sk.site_names]
    assert gltf.skins[0].joints == list(range(sk.n_joints))
    (animation,) = gltf.animations
    paths = {(c.target.node, c.target.path) for c in animation.channels}
    assert {(j, "rotation") for j in range(sk.n_joints)} <= paths and (0, "translation") in paths
    times = gltf.accessors[animation.samplers[0].input]
    assert times.count == 30 and times.max[0] == pytest.approx(29 / clip.fps)
    # Metres: the first leg bone's node translation is its offset / 100.
    np.testing.assert_allclose(gltf.nodes[2].translation, sk.offsets[2] / 100, rtol=1e-12)


def test_an_armature_node_and_a_named_animation_are_read(tmp_path):
    import pygltflib

    clip = generate_clip("walk", 1, n_frames=20)
    write_gltf(clip, tmp_path / "plain.glb")
    gltf = pygltflib.GLTF2().load(str(tmp_path / "plain.glb"))
    # Above the root: an armature turned a quarter about X and scaled by a half.
    turn = quat.about_axis(np.pi / 2, "x")
    armature = pygltflib.Node(
        name="Armature", children=[0], scale=[0.5, 0.5, 0.5], rotation=[*turn[1:], turn[0]]
    )
    gltf.nodes.append(armature)
    gltf.scenes[0].nodes = [len(gltf.nodes) - 1]
    # A second animation, named: the first one's rotations, root held still.
    first = gltf.animations[0]
    still = pygltflib.Animation(
        name="still",
        samplers=first.samplers,
        channels=[c for c in first.channels if c.target.path == "rotation"],
    )
    gltf.animations.append(still)
    gltf.save(str(tmp_path / "armature.glb"))
    motion = read_gltf(tmp_path / "armature.glb")
    expected = 0.5 * quat.rotate(turn, _positions(clip))
    np.testing.assert_allclose(_positions(motion), expected, atol=1e-4)
    held = io.read_motion(tmp_path / "armature.glb", animation="still")
    assert held.skeleton.extras["gltf_animation"] == "still"
    root = forward_kinematics(held).positions[:, 0]
    np.testing.assert_allclose(root, root[:1].repeat(len(root), 0), atol=1e-9)
    with pytest.raises(FormatError, match="no animation named 'jog'"):
        read_gltf(tmp_path / "armature.glb", "jog")


def test_bad_gltf_files_are_refused_naming_the_field(tmp_path):
    (tmp_path / "junk.glb").write_bytes(b"glTF\x02\x00\x00\x00junk")
    with pytest.raises(FormatError, match="junk.glb"):
        io.read_motion(tmp_path / "junk.glb")
    (tmp_path / "text.gltf").write_text("this is not JSON")
    with pytest.raises(FormatError, match="not a glTF 2.0 file"):
        io.read_motion(tmp_path / "text.gltf")
    clip = generate_clip("walk", 1, n_frames=5)
    document = json.loads(io.gltf.gltf_bytes(clip, binary=False))
    document["animations"][0]["samplers"][0]["output"] = 999
    (tmp_path / "index.gltf").write_text(json.dumps(document))
    with pytest.raises(FormatError, match=r"channels\[0\] output: accessors\[999\] does not"):
        io.read_motion(tmp_path / "index.gltf")
    document["asset"]["version"] = "1.0"
    (tmp_path / "old.gltf").write_text(json.dumps(document))
    with pytest.raises(FormatError, match="only glTF 2.0"):
        io.read_motion(tmp_path / "old.gltf")


def test_every_command_takes_glb_clips(tmp_path):
    clips = tmp_path / "clips"
    clips.mkdir()
    for k, kind in enumerate(("walk", "run", "jump")):
        io.write_motion(generate_clip(kind, k, n_frames=60), clips / f"{kind}.glb")
    io.write_motion(generate_clip("squat", 1, n_frames=60), clips / "squat.bvh")
    assert _cli("convert", clips / "squat.bvh", tmp_path / "squat.gltf").exit_code == 0
    info = _cli("info", clips / "walk.glb")
    assert info.exit_code == 0 and "m (glTF: metres)" in info.stdout, info.output
    lib = tmp_path / "lib.qmz"
    result = _cli("compress", clips, "-o", lib, "--max-error", "1", "--workers", "1")
    assert result.exit_code == 0, result.output
    with codec.Archive.open(lib) as archive:
        assert sorted(archive.names()) == ["jump", "run", "squat", "walk"]
        decoded = archive.read("walk")
    error = np.linalg.norm(
        _positions(decoded) - _positions(io.read_motion(clips / "walk.glb")), axis=-1
    )
    assert error.max() <= 1.0 + 1e-6
    index = tmp_path / "x.qidx"
    built = _cli("index", "build", clips, "-o", index, "--kinds", "motion", "--workers", "1")
    assert built.exit_code == 0 and "4 clips added" in built.stdout, built.output
    found = _cli("search", clips / "run.glb", "--index", index, "--json")
    assert found.exit_code == 0, found.output
    poses = tmp_path / "p.idx"
    built = _cli(
        "pose", "index", clips, "-o", poses, "--rank", "4", "--unlabeled", "50", "--pairs", "10",
        "--workers", "1",
    )  # fmt: skip
    assert built.exit_code == 0 and "60 poses of 4 clips" in built.output, built.output

    from fastapi.testclient import TestClient

    from quatmotion.server import CSRF_HEADER, create_app

    app = create_app(lib, index, poses)
    with TestClient(app, base_url="http://127.0.0.1", headers={CSRF_HEADER: "1"}) as client:
        listed = {c["name"]: c for c in client.get("/api/clips").json()["clips"]}
        assert {"walk", "run", "jump", "squat"} <= {n.rsplit("/", 1)[-1] for n in listed}
        some = next(c for n, c in listed.items() if n.endswith("run"))
        assert client.get(f"/api/clips/{some['id']}/frames").status_code == 200
        upload = (clips / "jump.glb").read_bytes()
        hits = client.post("/api/search/upload", files={"file": ("jump.glb", upload)})
        assert hits.status_code == 200, hits.text
        answer = hits.json()
        # the upload is the indexed jump.glb: found by its bytes, and left out of its results
        assert answer["left_out"].endswith("jump"), answer
        assert not any(r["clip"].endswith("jump") for r in answer["results"]), answer
