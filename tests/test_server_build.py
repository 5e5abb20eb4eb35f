"""A library built while the web app already answers (issue 29, item 7): the stages served
as they land (index, library, pose index), what is missing meanwhile a 503 (not a 404), the
build's progress at /api/build, its stop at shutdown; ``serve DIR`` listening at once, with
labels as ``index build`` takes them and originals for compare."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from quatmotion.demo import build_library
from quatmotion.io import write_asf, write_motion
from quatmotion.server import CSRF_HEADER, LibraryBuild, create_app
from quatmotion.server.building import BuildStoppedError
from quatmotion.synthetic import generate_clip

BASE = "http://127.0.0.1"


def _wait(condition, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.02)


class _Staged:
    """A build that publishes the fixture's files one stage at a time, each when let go."""

    def __init__(self, files: dict[str, Path]) -> None:
        self.files = files
        self.go = [threading.Event() for _ in range(3)]
        self.stopped = False

    def __call__(self, progress, publish):
        stages = [
            (None, self.files["index"], None),
            (self.files["library"], self.files["index"], None),
            (self.files["library"], self.files["index"], self.files["poses"]),
        ]
        try:
            for k, stage in enumerate(stages):
                while not self.go[k].wait(0.01):
                    progress(f"stage {k}", k, 3)  # raises once the server stops
                publish(*stage)
        except BuildStoppedError:
            self.stopped = True
            raise
        return ["broken.bvh: not a BVH file"]


def test_a_build_serves_each_stage_as_it_lands_and_503s_what_may_still_come(motion_library):
    run = _Staged(motion_library)
    build = LibraryBuild("studio/", run)
    app = create_app(build=build)
    with TestClient(app, base_url=BASE) as client:
        build.start()
        status = client.get("/api/build").json()
        assert status["state"] == "building" and status["served"] == []
        assert client.get("/api/info").json()["building"] is True
        assert client.get("/api/clips").json()["clips"] == []
        early = client.get("/api/search", params={"clip": "walk_0"})
        assert early.status_code == 503 and early.headers["retry-after"]
        assert "still being built: stage 0" in early.json()["detail"]

        run.go[0].set()  # the index: every clip listed, played from its file, searchable
        _wait(lambda: client.get("/api/build").json()["served"] == ["index"])
        clips = {c["name"]: c for c in client.get("/api/clips").json()["clips"]}
        assert len(clips) == 7 and not any(c["in_library"] for c in clips.values())
        assert clips["walk_0"]["label"] == "walk" and clips["walk_0"]["has_original"]
        assert client.get("/api/clips/walk_0/frames").status_code == 200
        assert client.get("/api/search", params={"clip": "walk_0"}).status_code == 200
        assert client.get("/api/clips/walk_0/compare").status_code == 503  # not compressed yet

        run.go[1].set()  # the library: compare
        _wait(lambda: len(client.get("/api/build").json()["served"]) == 2)
        compared = client.get("/api/clips/walk_0/compare")
        assert compared.status_code == 200, compared.text
        assert client.get("/api/poses", params={"clip": "walk_0", "frame": 3}).status_code == 503

        run.go[2].set()  # the pose index; the build ends
        _wait(lambda: client.get("/api/build").json()["state"] == "ready")
        status = client.get("/api/build").json()
        assert status["served"] == ["index", "library", "poses"] and status["clips"] == 7
        assert status["failed"] == ["broken.bvh: not a BVH file"]
        assert client.get("/api/poses", params={"clip": "walk_0", "frame": 3}).status_code == 200
        assert client.get("/api/clips/nothing_such").status_code == 404  # built: not coming
        assert client.get("/api/info").json()["building"] is False


def test_a_server_that_stops_stops_its_build(motion_library):
    run = _Staged(motion_library)
    build = LibraryBuild("studio/", run)
    with TestClient(create_app(build=build), base_url=BASE):
        build.start()
        _wait(lambda: build.where().startswith("stage 0"))
    assert run.stopped and build.status()["state"] == "stopped"  # stopped at shutdown


def test_a_failed_build_says_why():
    def run(progress, publish):
        progress("index", 0, 2)
        raise ValueError("studio/: no clip could be read (bad.bvh: not a BVH file)\nmore")

    build = LibraryBuild("studio/", run)
    with TestClient(create_app(build=build), base_url=BASE) as client:
        build.start()
        _wait(lambda: client.get("/api/build").json()["state"] == "failed")
        status = client.get("/api/build").json()
        assert status["message"] == "studio/: no clip could be read (bad.bvh: not a BVH file)"
        assert client.get("/api/clips/x").status_code == 404


def test_a_server_of_files_has_no_build(client_headers, motion_library):
    app = create_app(motion_library["library"], motion_library["index"])
    with TestClient(app, base_url=BASE, headers=client_headers) as client:
        assert client.get("/api/build").json()["state"] == "none"
    with pytest.raises(ValueError, match="not both"):
        create_app(motion_library["library"], build=LibraryBuild("x", lambda p, q: []))


@pytest.fixture()
def client_headers() -> dict[str, str]:
    return {CSRF_HEADER: "1"}


def _studio(root: Path) -> Path:
    """Two walks and two squats (one an AMC with its ASF) in class folders, two of them
    ``w0``, a broken file, and a sidecar label."""
    clips = root / "studio"
    (clips / "walks").mkdir(parents=True)
    (clips / "squats").mkdir()
    for k in range(2):
        walk = generate_clip("walk", seed=k, n_frames=60, fps=30.0)
        write_motion(walk, clips / "walks" / f"w{k}.bvh")
    squat = generate_clip("squat", seed=3, n_frames=60, fps=30.0)
    write_motion(squat, clips / "squats" / "s3.amc")
    # A second w0 (another take of the same name): names collide, contents do not.
    write_motion(generate_clip("squat", seed=4, n_frames=50, fps=30.0), clips / "squats" / "w0.bvh")
    write_asf(squat.skeleton, clips / "squats" / "s3.asf")
    (clips / "walks" / "w1.json").write_text('{"content": 1}')  # a sidecar beats the folder
    (clips / "content_label.txt").write_text("run\nstroll\n")  # as bandai's lists its labels
    (clips / "broken.bvh").write_text("HIERARCHY\nROOT hips\n{\n")
    return clips


def test_build_library_indexes_first_labels_as_index_build_does_and_joins_the_originals(
    tmp_path,
):
    clips = _studio(tmp_path)
    stages: list[tuple[bool, bool, bool]] = []
    csv_labels = {"s3": "deep squat", "nothing": "x"}
    built = build_library(
        tmp_path / "work",
        [clips],
        poses=False,
        workers=1,
        labels=csv_labels,
        label_folders=True,
        on_stage=lambda lib, idx, poses: stages.append((bool(lib), bool(idx), bool(poses))),
    )
    assert stages == [(False, True, False), (True, True, False)]  # the index first
    assert any("broken.bvh" in f for f in built.failed)
    assert built.unmatched_labels == ["nothing"]
    app = create_app(built.library, built.index)
    with TestClient(app, base_url=BASE) as client:
        listed = {c["name"]: c for c in client.get("/api/clips").json()["clips"]}
        assert {n: c["label"] for n, c in listed.items()} == {
            "walks/w0": "walks",  # its folder
            "squats/w0": "squats",
            "w1": "stroll",  # its sidecar
            "s3": "deep squat",  # the CSV, first of all
        }
        for name, clip in listed.items():  # every clip compares with its original
            assert clip["in_library"] and clip["in_index"] and clip["has_original"], name
            compared = client.get(f"/api/clips/{clip['id']}/compare")
            assert compared.status_code == 200, (name, compared.text)
            assert compared.json()["pairs"][0]["max_cm"] <= 1.0 + 1e-6
