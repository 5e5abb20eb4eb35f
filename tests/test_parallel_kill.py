"""A run killed outright (``kill -9``) leaves no worker process and, after the next run, no
temporary file (issue 30): workers die with their run, temporary names carry the run's process
id and the next run removes those of dead runs."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from quatmotion.io import write_bvh
from quatmotion.parallel import scratch
from quatmotion.synthetic import generate_clip

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")


def _parents() -> dict[int, int]:
    out = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            out[int(entry.name)] = int(stat.rsplit(")", 1)[1].split()[1])
    return out


def _descendants(pid: int) -> set[int]:
    parents = _parents()
    found, grown = {pid}, True
    while grown:
        more = {p for p, pp in parents.items() if pp in found} - found
        found |= more
        grown = bool(more)
    return found - {pid}


def _running(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _compress(folder: Path, out: Path, tmp: Path) -> subprocess.Popen:
    env = {**os.environ, "TMPDIR": str(tmp)}
    args = ["compress", str(folder), "-o", str(out), "--workers", "2", "--force"]
    return subprocess.Popen(
        [str(Path(sys.executable).parent / "quatmotion"), *args],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=open(out.parent / f"{out.stem}.log", "w"),  # noqa: SIM115 (closed with the run)
    )


def test_workers_and_temporary_files_of_a_killed_run_do_not_outlive_it(tmp_path, request):
    clips = tmp_path / "clips"
    clips.mkdir()
    for i in range(24):
        write_bvh(generate_clip("walk", i, n_frames=400), clips / f"walk_{i}.bvh")
    tmp = Path(tempfile.mkdtemp(prefix="qmk-", dir="/tmp"))  # short: sockets live there
    request.addfinalizer(lambda: shutil.rmtree(tmp, ignore_errors=True))
    run = _compress(clips, tmp_path / "a.qmz", tmp)
    deadline = time.monotonic() + 240
    workers: set[int] = set()
    while time.monotonic() < deadline and run.poll() is None:
        workers = _descendants(run.pid)
        if len(workers) >= 3 and any(p.name.startswith("quatmotion-") for p in tmp.iterdir()):
            break  # the fork server and two workers, and a temporary file
        time.sleep(0.2)
    log = (tmp_path / "a.log").read_text()
    assert run.poll() is None and len(workers) >= 3, f"the run ended before its workers: {log}"
    left = sorted(p.name for p in tmp.iterdir())
    assert all(name.startswith("quatmotion-") and f"-{run.pid}-" in name for name in left), left
    os.kill(run.pid, signal.SIGKILL)
    run.wait()
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline and any(_running(p) for p in workers):
        time.sleep(0.2)
    assert not [p for p in workers if _running(p)], "workers outlived their run"
    assert any(f"-{run.pid}-" in p.name for p in tmp.iterdir())  # left behind, as killed runs do
    # The next run removes them (its own are removed as it ends).
    small = tmp_path / "small"
    small.mkdir()
    write_bvh(generate_clip("run", 1, n_frames=40), small / "run.bvh")
    after = _compress(small, tmp_path / "b.qmz", tmp)
    assert after.wait(timeout=600) == 0
    assert [p.name for p in tmp.iterdir()] == []


def test_stale_names_of_live_runs_are_kept(tmp_path):
    mine = tmp_path / f"quatmotion-spool-{os.getpid()}-abc"
    parent = tmp_path / f"quatmotion-context-{os.getppid()}-abc.pickle"
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    gone = tmp_path / f"quatmotion-mp-{dead.pid}-abc"
    gone.mkdir()
    (gone / "sock").write_text("")
    other = tmp_path / "pymp-abc"
    for path in (mine, parent, other):
        path.write_text("")
    assert scratch.clean_stale(tmp_path) == [gone]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        p.name for p in (mine, parent, other)
    )
