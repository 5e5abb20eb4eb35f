"""The SQLite clip index and its commands: build, resume after a kill, search, bad files."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from quatmotion.cli import app
from quatmotion.io import write_motion
from quatmotion.retrieval.index import FORMAT_VERSION, ClipIndex
from quatmotion.retrieval.methods import DEFAULT_METHOD
from quatmotion.synthetic import generate_clip

runner = CliRunner()


@pytest.fixture(scope="module")
def clip_folder(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("clips")
    for kind in ("walk", "squat", "punch"):
        for seed in range(3):
            write_motion(generate_clip(kind, seed, n_frames=180), folder / f"{kind}_{seed}.bvh")
    return folder


def _build(folder: Path, out: Path, *extra: str):
    return runner.invoke(
        app,
        [
            "index",
            "build",
            str(folder),
            "-o",
            str(out),
            "--kinds",
            "motion",
            "--workers",
            "1",
            *extra,
        ],
    )


def test_build_search_json_and_twice_indexed_clip(clip_folder, tmp_path):
    out = tmp_path / "lib.qidx"
    result = _build(clip_folder, out)
    assert result.exit_code == 0, result.output
    copy = tmp_path / "copy"
    copy.mkdir()
    (copy / "walk_0_again.bvh").write_bytes((clip_folder / "walk_0.bvh").read_bytes())
    assert (
        runner.invoke(
            app, ["index", "add", str(out), str(copy), "--kinds", "motion", "--workers", "1"]
        ).exit_code
        == 0
    )
    result = runner.invoke(
        app,
        ["search", str(clip_folder / "walk_0.bvh"), "--index", str(out), "--top", "4", "--json"],
    )
    assert result.exit_code == 0, result.output
    doc = json.loads(result.stdout)
    assert doc["method"] == DEFAULT_METHOD
    names = [r["clip"] for r in doc["results"]]
    # the file is walk_0 (left out: the query itself); its copy elsewhere is another clip
    assert doc["left_out"] == "walk_0" and "walk_0" not in names
    assert names[0] == "walk_0_again"
    assert doc["results"][0]["distance"] == pytest.approx(0.0, abs=1e-9)
    assert [r["rank"] for r in doc["results"]] == [1, 2, 3, 4]
    by_name = runner.invoke(app, ["search", "squat_1", "--index", str(out), "--top", "2", "--json"])
    assert {r["clip"] for r in json.loads(by_name.stdout)["results"]} == {"squat_0", "squat_2"}


def test_bad_file_is_reported_and_skipped(clip_folder, tmp_path):
    folder = tmp_path / "mixed"
    folder.mkdir()
    (folder / "broken.bvh").write_text("HIERARCHY\nROOT\n")
    (folder / "ok.bvh").write_bytes((clip_folder / "punch_1.bvh").read_bytes())
    result = _build(folder, tmp_path / "m.qidx")
    assert result.exit_code == 1  # the others are indexed; the failure is in the exit code
    assert "broken.bvh" in result.output and "1 clips added" in result.output
    with ClipIndex.open(tmp_path / "m.qidx") as idx:
        assert [c.name for c in idx.clips()] == ["ok"]


def _kill_once_rows(proc: subprocess.Popen, out: Path, rows: int, timeout: float, kill) -> None:
    """Wait until the index at ``out`` holds ``rows`` committed clips, then ``kill`` the build."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            with sqlite3.connect(f"{out.resolve().as_uri()}?mode=ro", uri=True) as db:
                count = db.execute("SELECT count(*) FROM clips").fetchone()[0]
        except sqlite3.DatabaseError:
            count = 0
        if count >= rows:
            kill()
            break
        time.sleep(0.05)
    proc.wait()


def test_add_after_a_killed_build_completes_it_once(tmp_path):
    folder = tmp_path / "many"
    folder.mkdir()
    for seed in range(16):
        write_motion(generate_clip("wave", seed, n_frames=120), folder / f"wave_{seed:02d}.bvh")
    out = tmp_path / "killed.qidx"
    code = (
        "from quatmotion.retrieval.build import build_index\n"
        f"build_index([{str(folder)!r}], {str(out)!r}, kinds=('motion',), workers=1, batch=1)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", code])
    _kill_once_rows(proc, out, 3, 120, lambda: os.kill(proc.pid, signal.SIGKILL))
    with ClipIndex.open(out) as idx:  # readable after the kill
        partial = len(idx)
    assert partial >= 3
    result = runner.invoke(
        app, ["index", "add", str(out), str(folder), "--kinds", "motion", "--workers", "1"]
    )
    assert result.exit_code == 0, result.output
    assert f"{partial} already indexed" in result.output or partial == 16
    with ClipIndex.open(out) as idx:
        names = [c.name for c in idx.clips()]
    assert sorted(names) == [f"wave_{s:02d}" for s in range(16)]


def test_a_killed_index_build_command_resumes_every_clip_once_with_the_labels_given(tmp_path):
    """`quatmotion index build --kinds motion` killed once a batch is committed; the same
    command again with --labels indexes the rest (every clip once), says it resumed, applies
    the labels to old and new clips, and a third run says the labels changed nothing."""
    folder = tmp_path / "many"
    folder.mkdir()
    total = 36  # over two batches of 16: the kill comes with clips left to index
    for seed in range(total):
        write_motion(generate_clip("wave", seed, n_frames=120), folder / f"wave_{seed:02d}.bvh")
    out = tmp_path / "killed.qidx"
    argv = ["quatmotion", "index", "build", str(folder), "-o", str(out), "--kinds", "motion"]
    argv += ["--workers", "1"]
    code = f"import sys\nfrom quatmotion.cli import main\nsys.argv = {argv!r}\nmain()\n"
    # its own session: the kill takes the command and any worker it started
    proc = subprocess.Popen([sys.executable, "-c", code], start_new_session=True)
    _kill_once_rows(proc, out, 1, 300, lambda: os.killpg(proc.pid, signal.SIGKILL))
    with ClipIndex.open(out) as idx:  # readable after the kill
        partial = len(idx)
    assert 1 <= partial < total
    labels = tmp_path / "labels.csv"
    labels.write_text(
        "clip,label\n" + "".join(f"wave_{s:02d},wave-{s % 2}\n" for s in range(total)),
        encoding="utf-8",
    )
    result = _build(folder, out, "--labels", str(labels))
    assert result.exit_code == 0, result.output
    assert f"{total - partial} clips added, {partial} already indexed" in result.output
    assert "(resumed" in result.output and f"{total} clips labelled" in result.output
    with ClipIndex.open(out) as idx:
        names = [c.name for c in idx.clips()]
        assert sorted(names) == [f"wave_{s:02d}" for s in range(total)]
        assert idx.labels() == {f"wave_{s:02d}": f"wave-{s % 2}" for s in range(total)}
    again = _build(folder, out, "--labels", str(labels))
    assert again.exit_code == 0, again.output
    assert f"0 clips added, {total} already indexed" in again.output
    assert "changed no label" in again.output


def test_remove_and_ls(clip_folder, tmp_path):
    out = tmp_path / "r.qidx"
    _build(clip_folder, out)
    assert runner.invoke(app, ["index", "remove", str(out), "walk_1"]).exit_code == 0
    listed = runner.invoke(app, ["index", "ls", str(out), "--json"])
    doc = json.loads(listed.stdout)
    names = {r["name"] for r in doc["clips"]}
    assert doc["settings"]["kinds"] == ["motion"] and doc["format"]["version"] == FORMAT_VERSION
    assert "walk_1" not in names and len(names) == 8


@pytest.mark.parametrize("content", [None, b"not a database at all", "truncated", "newer"])
def test_bad_index_files_exit_2_with_one_line(clip_folder, tmp_path, content):
    path = tmp_path / "bad.qidx"
    if content == "truncated":
        good = tmp_path / "good.qidx"
        _build(clip_folder, good)
        path.write_bytes(good.read_bytes()[:3000])
    elif content == "newer":
        _build(clip_folder, path)
        with sqlite3.connect(path) as db:
            db.execute(
                "UPDATE meta SET value = ? WHERE key = 'version'", (str(FORMAT_VERSION + 1),)
            )
    elif content is not None:
        path.write_bytes(content)
    result = runner.invoke(app, ["search", "walk_0", "--index", str(path)])
    assert result.exit_code == 2
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:"), result.output
    assert "Traceback" not in result.output


def test_dictionary_method_rejects_another_skeleton(clip_folder, tmp_path):
    from quatmotion.retrieval.search import search

    bvh = clip_folder / "walk_2.bvh"
    out = tmp_path / "d.qidx"
    assert _build(bvh.parent, out).exit_code == 0
    from quatmotion.io import read_motion

    query = read_motion(bvh)
    with ClipIndex.open(out) as idx, pytest.raises(ValueError, match="qssd"):
        search(idx, query, method="paper-qssd")  # no qssd features were indexed


def _rows(path: Path) -> list[tuple]:
    with sqlite3.connect(path) as db:
        tables = [r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")]
        return [
            (table, *row)
            for table in sorted(tables)
            for row in db.execute(f"SELECT * FROM {table} ORDER BY 1")  # noqa: S608 (our tables)
        ]


def test_bad_file_is_skipped_and_the_pool_builds_the_same_index(clip_folder, tmp_path):
    folder = tmp_path / "mixed"
    folder.mkdir()
    for name in ("walk_0.bvh", "squat_1.bvh", "punch_2.bvh"):
        (folder / name).write_bytes((clip_folder / name).read_bytes())
    (folder / "broken.bvh").write_text("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0\n")
    inline, pooled = tmp_path / "inline.qidx", tmp_path / "pooled.qidx"
    result = _build(folder, inline)  # --workers 1: in this process
    assert result.exit_code == 1, result.output
    assert "broken.bvh" in result.output and "3 clips added" in result.output
    result = runner.invoke(
        app,
        ["index", "build", str(folder), "-o", str(pooled), "--kinds", "motion", "--workers", "2"],
    )
    assert result.exit_code == 1, result.output
    # The same rows, features included, whichever ran the per-clip jobs.
    assert _rows(inline) == _rows(pooled)


@pytest.mark.same_answer
def test_search_queries_in_one_process_equal_one_at_a_time(clip_folder, tmp_path):
    out = tmp_path / "lib.qidx"
    assert _build(clip_folder, out).exit_code == 0
    files = sorted(str(p) for p in clip_folder.glob("*.bvh"))[:4]
    listing = tmp_path / "queries.txt"
    listing.write_text("\n".join(files + ["squat_1"]) + "\n", encoding="utf-8")
    args = ["--index", str(out), "--top", "5", "--json"]
    batch = runner.invoke(app, ["search", "--queries", str(listing), *args])
    assert batch.exit_code == 0, batch.output
    docs = json.loads(batch.stdout)["queries"]
    assert [d["query"] for d in docs] == files + ["squat_1"]
    for d in docs:
        single = runner.invoke(app, ["search", d["query"], *args])
        assert json.loads(single.stdout)["results"] == d["results"]
    folder = runner.invoke(app, ["search", "--queries", str(clip_folder), *args])
    assert [d["query"] for d in json.loads(folder.stdout)["queries"]][:4] == files
    both = runner.invoke(app, ["search", files[0], "--queries", str(listing), *args])
    assert both.exit_code != 0 and "not both" in both.output


def test_a_query_from_the_shell_imports_no_scikit_learn(clip_folder, tmp_path):
    """`quatmotion search NAME` opens the index (its settings validated) and ranks without
    importing scikit-learn or SciPy's statistics (about a second of CPU at start-up)."""
    out = tmp_path / "light.qidx"
    assert _build(clip_folder, out).exit_code == 0
    argv = ["quatmotion", "search", "walk_0", "--index", str(out), "--top", "3", "--json"]
    code = (
        "import sys\nfrom quatmotion.cli import main\n"
        f"sys.argv = {argv!r}\n"
        "try:\n    main()\nexcept SystemExit:\n    pass\n"
        "heavy = [m for m in ('sklearn', 'scipy.stats') if m in sys.modules]\n"
        "print('HEAVY', heavy, file=sys.stderr)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert "HEAVY []" in done.stderr, done.stderr
    assert json.loads(done.stdout)["results"]


def test_index_build_computes_the_dictionaries_only_for_a_method_that_needs_them(
    clip_folder, tmp_path
):
    plain, ksvd = tmp_path / "plain.qidx", tmp_path / "ksvd.qidx"
    assert _build(clip_folder, plain).exit_code == 0
    with ClipIndex.open(plain) as idx:
        assert idx.settings.kinds == ("motion",)
        assert not {"ksvd", "qssd"} & set().union(*idx.feature_keys().values())
    assert _build(clip_folder, ksvd, "--method", "paper-ksvd").exit_code == 0
    with ClipIndex.open(ksvd) as idx:
        assert idx.settings.kinds == ("motion", "ksvd")
        assert "ksvd" in set().union(*idx.feature_keys().values())
    bad = _build(clip_folder, tmp_path / "bad.qidx", "--method", "nonesuch")
    assert bad.exit_code == 2 and "unknown method" in bad.output


def test_a_search_of_an_index_holding_only_the_query_says_so(tmp_path):
    """A position method ranks every clip but the query: with nothing else indexed the error
    says that, not the dictionary methods' 'same skeleton' explanation."""
    from quatmotion.parallel import Runner

    out = tmp_path / "one.qidx"
    ClipIndex.build([generate_clip("walk", 0, n_frames=60)], out, runner=Runner.inline())
    with ClipIndex.open(out) as index:
        name = index.rows()[0].name
        with pytest.raises(ValueError, match="the only indexed clip with its features"):
            index.search(name, k=3)
