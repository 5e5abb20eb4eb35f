"""FBX in (issue 31): files a real exporter wrote (Blender, tools/make_fbx_fixtures.py) read
back to the BVH they came from within 0.01 cm at every frame, whatever the names, up axis and
takes; malformed files refused naming the file; and no command on FBX input ever ends in a
segmentation fault (ufbx 0.0.5's binding faults, guarded in quatmotion.io.fbx)."""

from __future__ import annotations

import json
import random
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from quatmotion import io
from quatmotion.datasets import data_root
from quatmotion.errors import FormatError, FormatWarning
from quatmotion.io.fbx import fbx_takes, parse_fbx, read_fbx
from quatmotion.motion import Motion, forward_kinematics

DATA = data_root(must_exist=False)
FIXTURES = Path(__file__).parent / "data" / "fbx"
SPEC = json.loads((FIXTURES / "fixtures.json").read_text())
TARGET_CM = 0.01
CASES = [(name, k) for name, spec in sorted(SPEC.items()) for k in range(len(spec["takes"]))]


def _bvh_excerpt(spec: dict, take: int) -> Motion:
    start = list(spec["takes"].values())[take]
    bvh = io.read_bvh(DATA / spec["bvh"], spec["cm_per_bvh_unit"])
    return bvh.slice(start, start + spec["frames"])


def _read(name: str, take: int | str | None = None) -> Motion:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FormatWarning)
        return read_fbx(FIXTURES / name, take)


def test_the_fixtures_are_small():
    sizes = {p.name: p.stat().st_size for p in FIXTURES.glob("*.fbx")}
    assert set(sizes) == set(SPEC)
    assert max(sizes.values()) < 600_000 and sum(sizes.values()) < 2_000_000


@pytest.mark.needs_data
@pytest.mark.parametrize(("name", "take"), CASES)
def test_positions_equal_the_bvh_at_every_frame(name, take):
    spec = SPEC[name]
    bvh = _bvh_excerpt(spec, take)
    fbx = _read(name, take)
    assert fbx.n_frames == bvh.n_frames == spec["frames"]
    assert fbx.fps == round(bvh.fps)
    names = spec["names"] or {n: n for n in bvh.skeleton.joint_names}
    order = [fbx.skeleton.joint_names.index(names[n]) for n in bvh.skeleton.joint_names]
    ours = forward_kinematics(fbx).positions[:, order]
    theirs = forward_kinematics(bvh).positions
    error = np.linalg.norm(ours - theirs, axis=-1)
    assert error.max() < TARGET_CM, (name, take, error.max())


@pytest.mark.needs_data
def test_end_sites_are_the_leaf_bones_named_as_ends():
    spec = SPEC["cmu_mixamo.fbx"]
    bvh, fbx = _bvh_excerpt(spec, 0), _read("cmu_mixamo.fbx")
    assert fbx.skeleton.n_sites == bvh.skeleton.n_sites == 7
    assert all(s.endswith("_end") for s in fbx.skeleton.site_names)
    renamed = {v: k for k, v in spec["names"].items()}
    ours, theirs = forward_kinematics(fbx), forward_kinematics(bvh)
    for s, parent in enumerate(fbx.skeleton.site_parents):
        joint = bvh.skeleton.index(renamed[fbx.skeleton.joint_names[parent]])
        (match,) = np.flatnonzero(bvh.skeleton.site_parents == joint)
        gap = np.linalg.norm(ours.site_positions[:, s] - theirs.site_positions[:, match], axis=-1)
        assert gap.max() < TARGET_CM


def test_up_axis_and_names_do_not_change_the_motion():
    """The Unreal copy is Z up and renamed, the Mixamo copy namespaced with leaf bones: the
    same joints in the same places as the BVH-named Y-up file."""
    base = _read("cmu_bvh_names.fbx", 0)
    for name in ("cmu_mixamo.fbx", "cmu_unreal.fbx"):
        other = _read(name)
        names = SPEC[name]["names"]
        order = [other.skeleton.joint_names.index(names[n]) for n in base.skeleton.joint_names]
        gap = forward_kinematics(other).positions[:, order] - forward_kinematics(base).positions
        assert np.abs(gap).max() < TARGET_CM, name
    assert _read("cmu_unreal.fbx").skeleton.extras["fbx_up"] == "+Z"
    assert base.skeleton.extras["fbx_up"] == "+Y"


def test_takes_by_name_and_number():
    path = FIXTURES / "cmu_bvh_names.fbx"
    names = fbx_takes(path.read_bytes(), path)
    assert names == ["Armature|walk_a", "Armature|walk_b"]
    with pytest.warns(FormatWarning, match="2 takes"):
        first = read_fbx(path)
    assert first.skeleton.extras["fbx_take"] == names[0]
    second = read_fbx(path, names[1])
    assert second.skeleton.extras["fbx_take"] == names[1]
    assert np.array_equal(second.rotations, read_fbx(path, 1).rotations)
    assert not np.allclose(first.root_translation, second.root_translation)
    with pytest.raises(FormatError, match=r"cmu_bvh_names.fbx: no take named 'run'.*walk_b"):
        read_fbx(path, "run")
    with pytest.raises(FormatError, match="no take 5: the file has 2"):
        read_fbx(path, 5)
    with warnings.catch_warnings():
        warnings.simplefilter("error", FormatWarning)  # one take: nothing to say
        read_fbx(FIXTURES / "bandai_unreal.fbx")


def test_a_unit_given_replaces_the_stated_one():
    stated = _read("bandai_bvh_names.fbx")
    assert stated.skeleton.extras["length_scale"] == pytest.approx(1.0)
    assert io.unit_reading(stated.skeleton)[1] == "stated"
    inches = read_fbx(FIXTURES / "bandai_bvh_names.fbx", units="in")
    assert inches.skeleton.extras["length_unit_given"] is True
    scaled = forward_kinematics(inches).positions
    # (translations that move less than 1e-4 cm are the rest offsets, in either unit)
    assert np.allclose(scaled, 2.54 * forward_kinematics(stated).positions, rtol=0, atol=1e-3)


def test_bytes_and_files_read_alike():
    path = FIXTURES / "cmu_unreal.fbx"
    by_bytes = io.parse_motion(path.read_bytes(), path.name)
    by_file = io.read_motion(path)
    assert by_bytes.skeleton.joint_names == by_file.skeleton.joint_names
    assert np.array_equal(by_bytes.rotations, by_file.rotations)
    assert ".fbx" in io.MOTION_SUFFIXES and ".fbx" not in io.WRITTEN_SUFFIXES
    assert io.find_motion_files([FIXTURES]) == sorted(FIXTURES.glob("*.fbx"))


def _damaged(seed: int, flips: int) -> bytes:
    data = bytearray((FIXTURES / "cmu_mixamo.fbx").read_bytes())
    rng = random.Random(seed)
    for _ in range(flips):
        data[rng.randrange(27, len(data))] = rng.randrange(256)
    return bytes(data)


BAD = {
    "empty": b"",
    "text": b"; FBX 7.4.0 project file\nnot really\n",
    "random": random.Random(0).randbytes(3000),
    "truncated": (FIXTURES / "cmu_mixamo.fbx").read_bytes()[:5000],
    "cut_in_data": (FIXTURES / "cmu_mixamo.fbx").read_bytes()[:100_000],
    "damaged": _damaged(1, 200),
}


@pytest.mark.parametrize("kind", sorted(BAD))
def test_a_malformed_file_is_a_format_error_naming_it(kind):
    with pytest.raises(FormatError, match=rf"^bad_{kind}\.fbx: "):
        parse_fbx(BAD[kind], f"bad_{kind}.fbx")


def test_writing_fbx_is_refused_with_what_is_written(tmp_path):
    with pytest.raises(ValueError, match=r"cannot write.*\.fbx.*\.bvh"):
        io.write_motion(_read("bandai_unreal.fbx"), tmp_path / "out.fbx")


# --- ufbx 0.0.5's crashes: every run in a child process, which must end by itself ----------

_READ_TWICE = """
import gc, sys, warnings
from pathlib import Path
from quatmotion.io.fbx import fbx_takes, read_fbx
warnings.simplefilter("ignore")
for path in sorted(Path(sys.argv[1]).glob("*.fbx")):
    for _ in range(3):  # every take's wrapper fetched again and again, every scene freed
        takes = fbx_takes(path.read_bytes(), path)
        for take in range(len(takes)):
            motion = read_fbx(path, take)
        gc.collect()
print("read", flush=True)
"""


def _ended_by_itself(result: subprocess.CompletedProcess) -> None:
    assert result.returncode >= 0, f"killed by signal {-result.returncode}: {result.stderr}"
    assert "Segmentation fault" not in result.stderr + result.stdout


def test_reading_every_take_again_and_again_never_crashes():
    result = subprocess.run(
        [sys.executable, "-c", _READ_TWICE, str(FIXTURES)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    _ended_by_itself(result)
    assert result.returncode == 0 and "read" in result.stdout, result.stderr


def test_damaged_files_never_crash_the_interpreter(tmp_path):
    for seed in range(12):
        (tmp_path / f"damaged_{seed}.fbx").write_bytes(_damaged(seed, 1 + 8 * seed))
    code = (
        "import sys, warnings\nfrom pathlib import Path\nfrom quatmotion.errors import "
        "FormatError\nfrom quatmotion.io.fbx import read_fbx\nwarnings.simplefilter('ignore')\n"
        "for p in sorted(Path(sys.argv[1]).glob('*.fbx')):\n    try:\n        read_fbx(p)\n"
        "    except FormatError as e:\n        assert str(e).startswith(str(p)), e\n"
        "print('done', flush=True)\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, timeout=300
    )
    _ended_by_itself(result)
    assert result.returncode == 0 and "done" in result.stdout, result.stderr


def _quatmotion(*args: object, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", "from quatmotion.cli import main; main()", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=900,
        cwd=cwd,
    )


def test_an_install_without_ufbx_says_what_to_install_in_one_line(tmp_path):
    code = (
        "import sys\nsys.modules['ufbx'] = None  # as if it were not installed\n"
        "from quatmotion.cli import main\nmain()"
    )
    result = subprocess.run(
        [sys.executable, "-c", code, "info", str(FIXTURES / "cmu_bvh_names.fbx")],
        capture_output=True, text=True, timeout=300, cwd=tmp_path,
    )  # fmt: skip
    assert result.returncode == 2, result.stderr
    assert result.stderr.startswith("error: reading FBX needs the ufbx package"), result.stderr
    assert "Traceback" not in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_every_command_on_fbx_ends_by_itself(tmp_path):
    """info, convert (to BVH and glTF), compress, view, index build and pose index on FBX
    input (every fixture: BVH, Mixamo and Unreal names), and a bad FBX: each in
    its own process, each ending with its own exit code; the outputs read back."""
    fbx = FIXTURES / "cmu_unreal.fbx"
    named = sorted(FIXTURES.glob("*.fbx"))  # the BVH's, Mixamo's and Unreal's names
    runs = {
        "info": _quatmotion("info", FIXTURES / "cmu_bvh_names.fbx", "--take", "1", cwd=tmp_path),
        "bvh": _quatmotion("convert", fbx, tmp_path / "out.bvh", cwd=tmp_path),
        "glb": _quatmotion("convert", fbx, tmp_path / "out.glb", cwd=tmp_path),
        "compress": _quatmotion(
            "compress", FIXTURES, "--out", tmp_path / "lib.qmz", "--workers", "1", cwd=tmp_path
        ),
        "view": _quatmotion("view", fbx, "--out", tmp_path / "view.html", cwd=tmp_path),
        "index": _quatmotion(
            "index", "build", *named, "-o", tmp_path / "x.qidx", "--workers", "1", cwd=tmp_path
        ),
        "pose": _quatmotion(
            "pose", "index", *named, "-o", tmp_path / "x.qpose", "--workers", "1", cwd=tmp_path
        ),
        "bad": _quatmotion("info", _write(tmp_path / "bad.fbx", BAD["damaged"]), cwd=tmp_path),
    }
    for name, result in runs.items():
        _ended_by_itself(result)
        expected = 2 if name == "bad" else 0
        assert result.returncode == expected, (name, result.stdout, result.stderr)
    assert "'Armature|walk_b' (walk_b) of 2; also 'Armature|walk_a' (walk_a)" in runs["info"].stdout
    said = {name: result.stdout + result.stderr for name, result in runs.items()}
    assert "7 clips added, 0 already indexed, 0 failed" in said["index"]
    assert "130 poses of 7 clips; 0 of 7 clips failed" in said["pose"]
    assert runs["bad"].stderr.startswith("error: ") and "bad.fbx" in runs["bad"].stderr
    original = _read("cmu_unreal.fbx")
    for out in ("out.bvh", "out.glb"):
        back = io.read_motion(tmp_path / out, units="cm" if out.endswith(".bvh") else None)
        gap = (
            forward_kinematics(back).all_positions() - forward_kinematics(original).all_positions()
        )
        assert np.abs(gap).max() < TARGET_CM, out


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def test_the_readers_limits_hold_for_fbx():
    from quatmotion import limits

    path = FIXTURES / "cmu_bvh_names.fbx"
    with limits.raised(frames=39), pytest.raises(FormatError, match=r"cmu_bvh_names.fbx: take"):
        read_fbx(path, 0)
    with limits.raised(joints=30), pytest.raises(FormatError, match="joints"):
        read_fbx(path, 0)
    with limits.raised(file_bytes=1000), pytest.raises(FormatError, match="size"):
        read_fbx(path, 0)
    with limits.raised(frames=40):
        assert read_fbx(path, 0).n_frames == 40


@pytest.mark.filterwarnings("ignore:.*2 takes:quatmotion.errors.FormatWarning")
def test_the_web_app_searches_by_an_uploaded_fbx(motion_library):
    """An upload goes through io.parse_motion: an FBX is searched like a BVH; a damaged one
    gets 400 with the parser's one line naming the upload."""
    from fastapi.testclient import TestClient

    from quatmotion.server import CSRF_HEADER, create_app

    app = create_app(motion_library["library"], motion_library["index"], motion_library["poses"])
    data = (FIXTURES / "cmu_bvh_names.fbx").read_bytes()  # names search maps today
    with TestClient(app, base_url="http://127.0.0.1", headers={CSRF_HEADER: "1"}) as client:
        good = client.post(
            "/api/search/upload", files={"file": ("cmu_bvh_names.fbx", data)}, data={"top": "2"}
        )
        bad = client.post("/api/search/upload", files={"file": ("bad.fbx", BAD["damaged"])})
    assert good.status_code == 200, good.text
    assert good.json()["query"] == "cmu_bvh_names" and len(good.json()["results"]) == 2
    assert bad.status_code == 400 and bad.json()["detail"].startswith("bad.fbx: ")


def test_world_transforms_compose_alike_as_quaternions_and_as_matrices():
    """A non-uniform scale on a leaf sends the composition through matrices; the rotations and
    positions are those the quaternion path gives without it (a leaf's scale moves nothing)."""
    from quatmotion import quat
    from quatmotion.io.fbx import _world

    rng = np.random.default_rng(3)
    T, parents = 5, [-1, 0, 1, 1, 3]
    N = len(parents)
    translations = rng.normal(size=(T, N, 3)) * 10
    rotations = quat.normalize(rng.normal(size=(T, N, 4)))
    uniform = np.repeat(rng.uniform(0.5, 2.0, size=(T, N, 1)), 3, axis=-1)
    uniform[:, 4] = 1.0
    skewed = uniform.copy()
    skewed[:, 4] = (2.0, 1.0, 0.5)
    r_quat, p_quat = _world(translations, rotations, uniform, parents)
    r_matrix, p_matrix = _world(translations, rotations, skewed, parents)
    assert np.allclose(p_quat, p_matrix, atol=1e-9)
    assert np.allclose(np.abs(np.sum(r_quat * r_matrix, axis=-1)), 1.0, atol=1e-9)


def test_serve_a_folder_of_fbx(tmp_path):
    """``serve DIR``'s library (demo.build_library: compressed, indexed, pose-indexed) from a
    folder of FBX files, browsed through the web app: every take of a file of two a clip,
    joined across the library, the index and the pose index (no take read by default)."""
    import shutil

    from fastapi.testclient import TestClient

    from quatmotion.demo import build_library
    from quatmotion.server import create_app

    folder = tmp_path / "clips"
    folder.mkdir()
    for name in ("cmu_bvh_names.fbx", "bandai_bvh_names.fbx"):
        shutil.copy(FIXTURES / name, folder / name)
    built = build_library(tmp_path / "served", [folder], workers=1)
    assert not built.failed
    app = create_app(built.library, built.index, built.poses)
    with TestClient(app, base_url="http://127.0.0.1") as client:
        clips = client.get("/api/clips")
    assert clips.status_code == 200
    served = {c["name"]: c for c in clips.json()["clips"]}
    assert sorted(served) == ["bandai_bvh_names", "cmu_bvh_names/walk_a", "cmu_bvh_names/walk_b"]
    for clip in served.values():
        assert clip["in_library"] and clip["in_index"] and clip["in_poses"], clip


@pytest.mark.parametrize("source", ["cmu", "bandai"])
def test_mixamo_and_unreal_names_map_joint_for_joint_as_the_bvh_names(source):
    """The humanoid mapping (index, pose, search) finds the same 16 joints in the renamed FBX
    files as in the BVH-named one, so they go through index build and pose index alike."""
    from quatmotion.pose.skeleton16 import joint_indices16

    base = _read(f"{source}_bvh_names.fbx", 0).skeleton
    expected = [base.joint_names[j] for j in joint_indices16(base)]
    for family in ("mixamo", "unreal"):
        name = f"{source}_{family}.fbx"
        renamed = _read(name).skeleton
        found = [renamed.joint_names[j] for j in joint_indices16(renamed)]
        assert found == [SPEC[name]["names"][j] for j in expected], name
