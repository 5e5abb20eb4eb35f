"""Every take of an FBX file a clip (issue 31): a collection makes one clip per take of a file
of several (named file/take, hashed with the take), ``--take`` picks one on every command, the
take is stored in every collection file (``.qmz`` 3, ``.qidx`` 3, pose library 4) and files
of 0.4.0 (before takes) are still read; re-adding, search by file and the query's own clip
work per take; and no command on takes ends in a segmentation fault."""

from __future__ import annotations

import json
import shutil
import sqlite3
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from quatmotion.collection import ClipRef, ReadSettings, find_clips, read_clip
from quatmotion.collection.reading import file_hash
from quatmotion.collection.refs import content_hash
from quatmotion.errors import FormatError
from quatmotion.io.fbx import read_fbx, take_index, take_labels
from quatmotion.parallel import Runner

FIXTURES = Path(__file__).parent / "data" / "fbx"
TWO_TAKES = FIXTURES / "cmu_bvh_names.fbx"
TAKES = ("Armature|walk_a", "Armature|walk_b")
OLD = Path(__file__).parent / "data" / "v0.4.0"


def test_take_labels_are_short_unique_and_fit_a_file_name():
    assert take_labels(["Armature|walk", "Armature|run"]) == ["walk", "run"]
    # short names that collide: the whole names, with what no file name holds made "_"
    assert take_labels(["A|walk", "B|walk"]) == ["A_walk", "B_walk"]
    assert take_labels(["a/b", "", "x:y"]) == ["a_b", "take1", "x_y"]
    assert take_labels(["walk", "walk."]) == ["walk", "take1"]  # "walk." is "walk" once stripped


def test_a_take_is_named_by_name_short_name_or_position():
    names = ["Armature|walk", "Armature|run", "2"]
    assert take_index(names, "Armature|run", "f.fbx") == 1
    assert take_index(names, "run", "f.fbx") == 1
    assert take_index(names, 0, "f.fbx") == 0
    assert take_index(names, "2", "f.fbx") == 2  # a take named "2" is that take
    with pytest.raises(FormatError, match=r"f.fbx: no take named 'jump'.*Armature\|run"):
        take_index(names, "jump", "f.fbx")
    with pytest.raises(FormatError, match="no take 7: the file has 3"):
        take_index(names, 7, "f.fbx")
    assert read_fbx(TWO_TAKES, "walk_b").skeleton.extras["fbx_take"] == TAKES[1]


def test_a_file_of_several_takes_is_a_clip_per_take():
    found = {s.name: s for s in find_clips([FIXTURES])}
    assert sorted(found) == [
        "bandai_bvh_names", "bandai_mixamo", "bandai_unreal",
        "cmu_bvh_names/walk_a", "cmu_bvh_names/walk_b", "cmu_mixamo", "cmu_unreal",
    ]  # fmt: skip
    a, b = found["cmu_bvh_names/walk_a"], found["cmu_bvh_names/walk_b"]
    assert (a.take, b.take) == TAKES and a.path == b.path == TWO_TAKES.resolve()
    assert a.sha256 == content_hash(TWO_TAKES, None, TAKES[0]) != b.sha256
    assert b.sha256 == content_hash(TWO_TAKES, None, TAKES[1])
    assert a.sha256 != content_hash(TWO_TAKES)  # the take is part of the identity
    one = found["cmu_mixamo"]  # a file of one take: the file is the clip
    assert one.take is None and one.sha256 == content_hash(one.path)
    # the hash a query file gets is its take's, the first when none is named (as read)
    assert file_hash(TWO_TAKES) == a.sha256 and file_hash(TWO_TAKES, None, "walk_b") == b.sha256
    for source, take in ((a, 0), (b, 1)):
        motion, ref, _ = read_clip(source)
        assert ref.take == TAKES[take] and ref.name == source.name
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            expected = read_fbx(TWO_TAKES, take)
        np.testing.assert_array_equal(motion.rotations, expected.rotations)
        again = read_clip(ClipRef.from_dict(ref.to_dict()))  # a stored reference reads it too
        np.testing.assert_array_equal(again.motion.rotations, expected.rotations)


def test_take_picks_one_take_and_refuses_a_file_without_it():
    errors: list[tuple[str, str]] = []
    found = find_clips([FIXTURES], ReadSettings(take="walk_b"), on_error=errors)
    assert [(s.name, s.take) for s in found] == [("cmu_bvh_names/walk_b", TAKES[1])]
    assert len(errors) == 5 and all("no take named 'walk_b'" in reason for _, reason in errors)
    # the first take of a file of one: its position, as a name
    assert [s.take for s in find_clips([FIXTURES / "cmu_unreal.fbx"], ReadSettings(take="0"))] == [
        None
    ]


@pytest.mark.filterwarnings("ignore::quatmotion.errors.FormatWarning")
def test_every_collection_file_stores_the_take_and_adds_per_take(tmp_path):
    from quatmotion.codec import Archive, CompressSettings
    from quatmotion.pose.library import PoseLibrary, PoseSettings
    from quatmotion.retrieval.index import ClipIndex, IndexSettings

    sources = [TWO_TAKES, FIXTURES / "cmu_unreal.fbx"]
    expected = {s.name: (s.take, s.sha256) for s in find_clips(sources)}
    Archive.build(sources, tmp_path / "l.qmz", CompressSettings(), runner=Runner.inline())
    ClipIndex.build(sources, tmp_path / "x.qidx", IndexSettings(), runner=Runner.inline())
    PoseLibrary.build(
        sources,
        tmp_path / "p.npz",
        PoseSettings(rank=2, n_pairs=20, n_unlabeled=50),
        runner=Runner.inline(),
    )
    with Archive.open(tmp_path / "l.qmz") as archive:
        assert archive.version == 3
        stored = {"qmz": archive.clips()}
    with ClipIndex.open(tmp_path / "x.qidx") as index:
        assert index.version == 3
        stored["qidx"] = index.clips()
    stored["pose"] = PoseLibrary.open(tmp_path / "p.npz").clips()
    for kind, refs in stored.items():
        assert {r.name: (r.take, r.sha256) for r in refs} == expected, kind
    # re-adding the same file: every take already there; the index keeps both takes
    assert not Archive.add(tmp_path / "l.qmz", [TWO_TAKES], runner=Runner.inline()).added
    assert len(ClipIndex.add(tmp_path / "x.qidx", [TWO_TAKES], runner=Runner.inline()).skipped) == 2
    assert not PoseLibrary.add(tmp_path / "p.npz", [TWO_TAKES], runner=Runner.inline()).added
    with ClipIndex.open(tmp_path / "x.qidx") as index:
        assert len(index) == 3


def _expected_v040() -> dict:
    return json.loads((OLD / "expected_v040.json").read_text())


def test_files_of_0_4_0_are_read_with_no_takes(tmp_path):
    from quatmotion.codec import Archive
    from quatmotion.pose.library import PoseLibrary
    from quatmotion.retrieval.index import ClipIndex

    expected = _expected_v040()
    with Archive.open(OLD / "lib_v040.qmz") as archive:
        assert archive.version == expected["qmz"]["version"] == 2
        read = {"qmz": archive.clips()}
    with ClipIndex.open(OLD / "index_v040.qidx") as index:
        assert index.version == expected["qidx"]["version"] == 2
        read["qidx"] = index.clips()
    pose = PoseLibrary.open(OLD / "pose_v040.npz")
    assert pose.version == expected["pose"]["version"] == 3
    read["pose"] = pose.clips()
    for kind, refs in read.items():
        assert [r.to_dict() for r in refs] == [
            {**r, "take": None} for r in expected[kind]["clips"]
        ], kind


def test_a_version_2_index_opened_for_writing_becomes_version_3(tmp_path):
    from quatmotion.retrieval.index import ClipIndex

    copy = tmp_path / "old.qidx"
    shutil.copyfile(OLD / "index_v040.qidx", copy)
    before = [r.to_dict() for r in ClipIndex.open(copy).clips()]
    report = ClipIndex.add(copy, [TWO_TAKES], runner=Runner.inline())
    assert [r.name for r in report.added] == ["cmu_bvh_names/walk_a", "cmu_bvh_names/walk_b"]
    with ClipIndex.open(copy) as index:
        assert index.version == 3
        refs = [r.to_dict() for r in index.clips()]
    assert refs[:2] == before and [r["take"] for r in refs[2:]] == list(TAKES)
    with sqlite3.connect(copy) as db:
        assert db.execute("SELECT value FROM meta WHERE key = 'version'").fetchone() == ("3",)


def _quatmotion(*args: object, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", "from quatmotion.cli import main; main()", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=900,
        cwd=cwd,
    )


def test_every_collection_command_takes_every_take_or_the_one_named(tmp_path):
    """compress, index build/add, search by file, pose index/add and pose search on a file
    of two takes, each in its own process: each ends by itself (no signal), as it should."""
    unreal = FIXTURES / "cmu_unreal.fbx"
    runs = {
        "compress": _quatmotion(
            "compress", TWO_TAKES, unreal, "--out", "l.qmz", "--workers", "1", cwd=tmp_path
        ),
        "compress_take": _quatmotion(
            "compress", TWO_TAKES, "--take", "walk_b", "--out", "b.qmz", cwd=tmp_path
        ),
        "index": _quatmotion(
            "index", "build", unreal, "-o", "x.qidx", "--workers", "1", cwd=tmp_path
        ),
        "index_add": _quatmotion(
            "index", "add", "x.qidx", TWO_TAKES, "--workers", "1", cwd=tmp_path
        ),
        "search": _quatmotion(
            "search", "--index", "x.qidx", TWO_TAKES, "--take", "walk_b", "--json", cwd=tmp_path
        ),
        "pose": _quatmotion(
            "pose",
            "index",
            unreal,
            TWO_TAKES,
            "--take",
            "0",
            "-o",
            "p.npz",
            "--workers",
            "1",
            "--rank",
            "2",
            "--pairs",
            "20",
            "--unlabeled",
            "50",
            cwd=tmp_path,
        ),  # fmt: skip
        "pose_add": _quatmotion("pose", "add", "p.npz", TWO_TAKES, "--take", "1", cwd=tmp_path),
        "pose_search": _quatmotion(
            "pose",
            "search",
            "p.npz",
            "--file",
            TWO_TAKES,
            "--take",
            "walk_b",
            "-f",
            "3",
            "--other-clips",
            "--json",
            cwd=tmp_path,
        ),  # fmt: skip
    }
    for name, result in runs.items():
        assert result.returncode >= 0, (name, f"killed by signal {-result.returncode}")
        assert "Segmentation fault" not in result.stderr
        # --take 0 of pose index: cmu_unreal's one take and cmu_bvh_names' first
        assert result.returncode == 0, (name, result.stdout, result.stderr)
    said = {name: result.stdout + result.stderr for name, result in runs.items()}
    assert "3 clip(s)" in said["compress"] and "1 clip(s)" in said["compress_take"]
    assert "2 clips added, 0 already indexed" in said["index_add"]
    found = json.loads(runs["search"].stdout)
    assert found["left_out"] == "cmu_bvh_names/walk_b"  # the query's own take, not walk_a
    assert "cmu_bvh_names/walk_a" in [r["clip"] for r in found["results"]]
    assert "1 clips added, 0 already there" in said["pose_add"]
    poses = json.loads(runs["pose_search"].stdout)
    assert "cmu_bvh_names/walk_b" not in [r["clip"] for r in poses["results"]]
    assert "cmu_bvh_names/walk_a" in [r["clip"] for r in poses["results"]]


def test_serve_reads_the_take_named_of_every_file(tmp_path):
    from fastapi.testclient import TestClient
    from typer.testing import CliRunner

    from quatmotion.cli import app
    from quatmotion.demo import build_library
    from quatmotion.server import create_app

    refused = CliRunner().invoke(app, ["serve", "--take", "walk_b"])
    assert refused.exit_code == 2 and "--take applies to a folder" in refused.output
    folder = tmp_path / "clips"
    folder.mkdir()
    for name in (TWO_TAKES, FIXTURES / "cmu_unreal.fbx"):
        shutil.copy(name, folder / name.name)
    built = build_library(tmp_path / "served", [folder], workers=1, take="0")
    assert not built.failed, built.failed
    application = create_app(built.library, built.index, built.poses)
    with TestClient(application, base_url="http://127.0.0.1") as client:
        served = {c["name"]: c for c in client.get("/api/clips").json()["clips"]}
    assert sorted(served) == ["cmu_bvh_names/walk_a", "cmu_unreal"]
    assert all(c["in_library"] and c["in_index"] and c["in_poses"] for c in served.values())


def test_the_takes_of_a_file_share_its_bytes_in_the_ratio(tmp_path):
    from quatmotion.codec import Archive, CompressSettings

    report = Archive.build([TWO_TAKES], None, CompressSettings(), runner=Runner.inline())
    sizes = report.details["source_bytes"]
    assert len(sizes) == 2 and sum(sizes) <= TWO_TAKES.stat().st_size
    assert sizes == [TWO_TAKES.stat().st_size // 2] * 2
