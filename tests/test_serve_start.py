"""How ``quatmotion serve`` starts (issue 17, items 10 and 11): the port bound first (a busy
one is one ``error:`` line, exit code 2; ``--port 0`` picks a free one and prints it), and,
without files, the demo's library or a folder's clips built on the fly into a temporary
folder removed when the server stops.

Real servers run in a subprocess on a free loopback port and are stopped by the test.
"""

from __future__ import annotations

import json
import re
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from quatmotion.cli import app as cli
from quatmotion.io import write_asf, write_motion
from quatmotion.server import listen
from quatmotion.synthetic import generate_clip

URL = re.compile(r"http://127\.0\.0\.1:(\d+)/")


def _one_error(result) -> str:
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert result.exit_code == 2, result.output
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert "Traceback" not in result.output and "Errno" not in result.output
    return lines[0]


@pytest.fixture()
def busy_port() -> Iterator[int]:
    with socket.socket() as other:  # another server on the port
        other.bind(("127.0.0.1", 0))
        other.listen()
        yield other.getsockname()[1]


def test_a_busy_port_is_one_error_line_before_anything_else(motion_library, busy_port) -> None:
    runner = CliRunner()
    for args in (["--library", str(motion_library["library"])], []):  # before any building
        result = runner.invoke(cli, ["serve", *args, "--port", str(busy_port)])
        line = _one_error(result)
        assert f"port {busy_port} on 127.0.0.1 is in use" in line and "--port 0" in line
        assert "http://" not in result.stdout  # no URL of a server that never ran


def test_a_host_of_another_machine_is_one_error_line(motion_library) -> None:
    result = CliRunner().invoke(
        cli, ["serve", "--library", str(motion_library["library"]), "--host", "192.0.2.7"]
    )
    assert "--host 192.0.2.7 is not an address of this machine" in _one_error(result)


def test_bind_holds_the_port_it_reports_until_closed() -> None:
    with listen.bind("127.0.0.1", 0) as sock:
        port = int(URL.fullmatch(listen.url_of(sock)).group(1))
        assert port == sock.getsockname()[1] > 0
        with pytest.raises(listen.PortError, match=f"port {port} on 127.0.0.1 is in use"):
            listen.bind("127.0.0.1", port)  # as a second server would (SO_REUSEADDR too)
    listen.bind("127.0.0.1", port).close()  # free again


class _Server:
    """``quatmotion serve ARGS --port 0`` in a subprocess; its URL once it answers."""

    def __init__(self, tmp_path: Path, *args: str) -> None:
        self.out = (tmp_path / "serve.out").open("w+")
        self.err = (tmp_path / "serve.err").open("w+")
        command = [sys.executable, "-c", "from quatmotion.cli import main; main()", "serve"]
        self.process = subprocess.Popen(
            [*command, *args, "--port", "0"], stdout=self.out, stderr=self.err
        )
        self.url = self._wait()

    def _wait(self, timeout: float = 300) -> str:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                pytest.fail(f"serve exited {self.process.returncode}: {self.stderr()}")
            found = URL.search(Path(self.out.name).read_text())
            if found:
                url = found.group(0)
                try:
                    with urllib.request.urlopen(f"{url}api/info", timeout=5):
                        return url
                except OSError:
                    pass
            time.sleep(0.25)
        pytest.fail(f"serve did not answer within {timeout} s: {self.stderr()}")

    def get(self, path: str):
        with urllib.request.urlopen(f"{self.url}{path}", timeout=120) as response:
            return json.load(response)

    def stderr(self) -> str:
        return Path(self.err.name).read_text()

    def stop(self, how: int = signal.SIGINT) -> int:
        if self.process.poll() is None:
            self.process.send_signal(how)
            try:
                self.process.wait(timeout=120)  # a build is stopped at its next clip
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.out.close()
        self.err.close()
        return self.process.returncode


def test_port_0_serves_on_a_free_port_and_prints_it(motion_library, tmp_path) -> None:
    server = _Server(tmp_path, "--library", str(motion_library["library"]))
    try:
        port = int(URL.search(server.url).group(1))
        assert port != 0
        assert server.get("api/info")["clips"] == 6
    finally:
        assert server.stop(signal.SIGINT) == 130  # Ctrl+C: stopped as an interrupted program


def _built(server: _Server, timeout: float = 900) -> dict:
    deadline = time.monotonic() + timeout
    while (status := server.get("api/build"))["state"] == "building":
        assert time.monotonic() < deadline, f"not built within {timeout} s: {status}"
        time.sleep(0.25)
    return status


def test_serve_dir_listens_at_once_builds_in_the_background_then_removes_its_work(
    tmp_path,
) -> None:
    clips = tmp_path / "studio"
    (clips / "walks").mkdir(parents=True)
    for k in range(2):
        write_motion(
            generate_clip("walk", seed=k, n_frames=60, fps=30.0), clips / "walks" / f"w{k}.bvh"
        )
    squat = generate_clip("squat", seed=3, n_frames=60, fps=30.0)
    write_motion(squat, clips / "s3.amc")
    write_asf(squat.skeleton, clips / "s3.asf")
    (clips / "broken.bvh").write_text("HIERARCHY\nROOT hips\n{\n")
    (tmp_path / "labels.csv").write_text("clip,label\ns3,deep squat\nnone_such,x\n")
    server = _Server(
        tmp_path, str(clips), "--labels", str(tmp_path / "labels.csv"), "--label-folders"
    )
    try:
        first = server.get("api/build")  # answered at once, before the build is done
        assert first["state"] == "building" and first["source"] == str(clips)
        status = _built(server)
        assert status["state"] == "ready" and status["served"] == ["index", "library", "poses"]
        assert len(status["failed"]) == 1 and "broken.bvh" in status["failed"][0]
        listed = {c["name"]: c for c in server.get("api/clips")["clips"]}
        assert sorted(listed) == ["s3", "w0", "w1"]
        assert all(c["in_library"] and c["in_index"] and c["in_poses"] for c in listed.values())
        assert {n: c["label"] for n, c in listed.items()} == {
            "s3": "deep squat",  # --labels
            "w0": "walks",  # --label-folders
            "w1": "walks",
        }
        for clip in listed.values():  # the originals were given: every clip compares
            assert clip["has_original"]
            assert server.get(f"api/clips/{clip['id']}/compare")["pairs"][0]["max_cm"] <= 1.0001
        info = server.get("api/info")
        assert info["poses"] and info["default_method"] in info["methods"]
        hits = server.get("api/search?clip=w0")
        assert hits["results"][0]["clip"] == "w1"  # the other walk first
        err = server.stderr()
        assert "skipped" in err and "broken.bvh" in err
        assert "clips listed, playable from their files and searchable after" in err
        assert "keys name no clip (none_such)" in err
        work = Path(re.search(r"in (\S+quatmotion-serve-\S+) \(removed at exit\)", err).group(1))
        assert (work / "library.qmz").is_file()
    finally:
        assert server.stop(signal.SIGTERM) == 128 + signal.SIGTERM
    assert not work.exists()  # cleaned up, though SIGTERM's default action kills at once


def test_serve_dir_stopped_while_building_stops_the_build_and_removes_its_work(
    tmp_path,
) -> None:
    clips = tmp_path / "studio"
    clips.mkdir()
    for k in range(6):
        write_motion(generate_clip("walk", seed=k, n_frames=400, fps=60.0), clips / f"w{k}.bvh")
    server = _Server(tmp_path, str(clips))
    try:
        assert server.get("api/build")["state"] == "building"
        err = server.stderr()
        work = Path(re.search(r"in (\S+quatmotion-serve-\S+) \(removed at exit\)", err).group(1))
    finally:
        assert server.stop(signal.SIGINT) == 130
    assert not work.exists()


def test_serve_without_files_serves_the_demos_library(monkeypatch, tmp_path) -> None:
    # The demo's library, made smaller here: three short clips of two kinds.
    from quatmotion import synthetic

    def small_library(n_per_kind, seed=0, **_):
        return [
            (generate_clip(kind, seed=seed + k, n_frames=45, fps=30.0), kind)
            for k, kind in enumerate(("walk", "walk", "squat"))
        ]

    monkeypatch.setattr(synthetic, "generate_library", small_library)
    seen: dict[str, object] = {}

    def serve_on(application, sock):  # instead of uvicorn: look at the app, then stop
        seen["url"] = listen.url_of(sock)
        with TestClient(application, base_url="http://127.0.0.1") as client:
            deadline = time.monotonic() + 300
            while client.get("/api/build").json()["state"] == "building":
                assert time.monotonic() < deadline
                time.sleep(0.2)
            seen["clips"] = client.get("/api/clips").json()["clips"]
        sock.close()

    monkeypatch.setattr(listen, "serve_on", serve_on)
    result = CliRunner().invoke(cli, ["serve", "--port", "0"])
    assert result.exit_code == 0, result.output
    assert [c["label"] for c in seen["clips"]] == ["squat", "walk", "walk"]
    assert "the demo's generated library, being built" in result.stdout
    assert seen["url"] in result.stdout
    assert "building the demo's generated library" in result.stderr
    work = re.search(r"in (\S+quatmotion-serve-\S+) \(removed at exit\)", result.stderr)
    assert work and not Path(work.group(1)).exists()


def test_serve_refuses_a_folder_beside_files_and_a_file_as_folder(motion_library) -> None:
    runner = CliRunner()
    both = runner.invoke(
        cli, ["serve", str(motion_library["clips"]), "--library", str(motion_library["library"])]
    )
    assert "not both" in _one_error(both)
    not_folder = runner.invoke(cli, ["serve", str(motion_library["library"])])
    assert "not a folder" in _one_error(not_folder)
    empty = runner.invoke(cli, ["serve", str(motion_library["clips"].parent / "none")])
    assert "not a folder" in _one_error(empty)
    labels_beside_files = runner.invoke(
        cli, ["serve", "--library", str(motion_library["library"]), "--label-folders"]
    )
    assert "label the clips of a folder" in _one_error(labels_beside_files)
