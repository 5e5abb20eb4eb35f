"""The clip index as a collection: clip references, settings in the file, labels at any time,
the 0.3.0 index still read (issue 18)."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from quatmotion.cli import app
from quatmotion.collection import ClipRef, ReadSettings
from quatmotion.errors import FormatError
from quatmotion.io import write_motion
from quatmotion.parallel import Runner
from quatmotion.retrieval import ClipIndex, IndexSettings
from quatmotion.synthetic import generate_clip

runner = CliRunner()


@pytest.fixture(scope="module")
def two_sessions(tmp_path_factory) -> Path:
    """s1/take_001, s2/take_001 (one stem, two clips) and s1/punch."""
    root = tmp_path_factory.mktemp("sessions")
    for folder, kind, seed in (("s1", "walk", 0), ("s2", "squat", 1), ("s1", "punch", 2)):
        (root / folder).mkdir(exist_ok=True)
        name = "punch" if kind == "punch" else "take_001"
        write_motion(generate_clip(kind, seed, n_frames=60), root / folder / f"{name}.bvh")
    return root


def _build(*args: str):
    return runner.invoke(app, ["index", "build", *args, "--kinds", "motion", "--workers", "1"])


def test_the_0_3_0_index_opens_with_the_same_values_and_references(v030):
    expected = json.loads((v030 / "index_pose_v030.json").read_text())["index"]
    with ClipIndex.open(v030 / "index_v030.qidx") as index:
        assert index.version == 1 and index.format.version == 1
        rows = index.rows()
        _, library = index.load(("frames", "embedding"))
        refs = index.clips()
    assert [r.sha256 for r in rows] == [c["sha256"] for c in expected["clips"]]
    assert [r.label for r in rows] == [c["label"] for c in expected["clips"]]
    assert [(r.frames, r.fps) for r in rows] == [(c["frames"], c["fps"]) for c in expected["clips"]]
    for got, want in zip(library.features, expected["embeddings"], strict=True):
        np.testing.assert_array_equal(
            got["embedding"], np.asarray(want, dtype=got["embedding"].dtype)
        )
    # 0.3.0 stored the stems and relative paths: names made unique, paths found by the file
    assert [r.name for r in refs] == ["punch", "s1/take_001", "s2/take_001"]
    assert all(Path(r.path).is_absolute() and Path(r.path).is_file() for r in refs)
    with pytest.raises(FormatError, match="read-only"):
        ClipIndex.open(v030 / "index_v030.qidx", write=True)


def test_the_0_3_0_index_searches_from_any_folder(v030, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    index = str(v030 / "index_v030.qidx")
    result = runner.invoke(app, ["search", "punch", "--index", index, "--json", "--top", "2"])
    assert result.exit_code == 0, result.output
    paths = [r["path"] for r in json.loads(result.stdout)["results"]]
    assert all(Path(p).is_absolute() and Path(p).is_file() for p in paths)


def test_one_stem_in_two_folders_is_two_clips_and_an_ambiguous_name(two_sessions, tmp_path):
    out = tmp_path / "s.qidx"
    assert _build(str(two_sessions), "-o", str(out)).exit_code == 0
    with ClipIndex.open(out) as index:
        refs = index.clips()
        assert index.settings.kinds == ("motion",)
    assert sorted(r.name for r in refs) == ["punch", "s1/take_001", "s2/take_001"]
    assert all(Path(r.path).is_absolute() for r in refs)
    assert len({r.sha256 for r in refs}) == 3 and all(r.skeleton and r.units for r in refs)
    result = runner.invoke(app, ["search", "take_001", "--index", str(out)])
    assert result.exit_code == 2
    assert "ambiguous" in result.output and "s1/take_001" in result.output
    assert "s2/take_001" in result.output
    ok = runner.invoke(app, ["search", "s2/take_001", "--index", str(out), "--json"])
    assert ok.exit_code == 0, ok.output
    assert {r["clip"] for r in json.loads(ok.stdout)["results"]} == {"punch", "s1/take_001"}


def test_a_relative_build_stores_absolute_paths_found_after_a_move(
    two_sessions, tmp_path, monkeypatch
):
    work = tmp_path / "work"
    shutil.copytree(two_sessions, work / "clips")
    monkeypatch.chdir(work)
    assert _build("clips", "-o", "lib.qidx").exit_code == 0
    moved = tmp_path / "moved"
    shutil.move(str(work), str(moved))
    monkeypatch.chdir(tmp_path)
    result = runner.invoke(app, ["search", "punch", "--index", str(moved / "lib.qidx"), "--json"])
    assert result.exit_code == 0, result.output
    for hit in json.loads(result.stdout)["results"]:
        assert Path(hit["path"]).is_file() and str(moved) in hit["path"]


def test_a_stem_shared_with_an_indexed_clip_renames_both(two_sessions, tmp_path):
    out = tmp_path / "grow.qidx"
    assert _build(str(two_sessions / "s1"), "-o", str(out)).exit_code == 0
    with ClipIndex.open(out) as index:
        assert sorted(index.labels()) == ["punch", "take_001"]
    added = runner.invoke(
        app, ["index", "add", str(out), str(two_sessions / "s2"), "--kinds", "motion",
              "--workers", "1"],
    )  # fmt: skip
    assert added.exit_code == 0, added.output
    with ClipIndex.open(out) as index:
        assert sorted(index.labels()) == ["punch", "s1/take_001", "s2/take_001"]


def test_labels_on_a_resumed_build_add_and_label_apply_to_indexed_clips(two_sessions, tmp_path):
    out = tmp_path / "l.qidx"
    assert _build(str(two_sessions), "-o", str(out)).exit_code == 0
    csv = tmp_path / "labels.csv"
    csv.write_text("clip,label\npunch,hit\ns2/take_001,squat\nnobody,x\n")
    again = _build(str(two_sessions), "-o", str(out), "--labels", str(csv))
    assert again.exit_code == 0, again.output
    assert "0 clips added, 3 already indexed" in again.output and "resumed" in again.output
    assert "2 clips labelled" in again.output and "nobody" in again.output
    with ClipIndex.open(out) as index:
        assert index.labels() == {"punch": "hit", "s1/take_001": "", "s2/take_001": "squat"}
    same = runner.invoke(
        app, ["index", "add", str(out), str(two_sessions), "--labels", str(csv), "--kinds",
              "motion", "--workers", "1"],
    )  # fmt: skip
    assert same.exit_code == 0 and "changed no label" in same.output
    csv.write_text("clip,label\ns1/take_001,walk\npunch,strike\n")
    relabel = runner.invoke(app, ["index", "label", str(out), "--labels", str(csv)])
    assert relabel.exit_code == 0 and "2 clips labelled" in relabel.output
    with ClipIndex.open(out) as index:
        assert index.labels() == {"punch": "strike", "s1/take_001": "walk", "s2/take_001": "squat"}


def test_class_folders_and_sidecars_label_clips(two_sessions, tmp_path):
    root = tmp_path / "hdm"
    shutil.copytree(two_sessions, root)
    (root / "s1" / "punch.json").write_text(json.dumps({"content": "boxing", "style": "angry"}))
    settings = IndexSettings(kinds=("motion",), label_folders=True)
    report = ClipIndex.build([root], tmp_path / "f.qidx", settings, runner=Runner.inline())
    assert len(report.added) == 3 and not report.failures and not report.details["resumed"]
    with ClipIndex.open(tmp_path / "f.qidx") as index:
        labels = index.labels()
        assert index.settings == settings  # stored whole
    assert labels["s1/take_001"] == "s1" and labels["s2/take_001"] == "s2"
    assert labels["punch"] == "boxing"  # the sidecar before the folder


def test_build_report_failures_are_failures_and_settings_validate(tmp_path, two_sessions):
    folder = tmp_path / "bad"
    shutil.copytree(two_sessions / "s2", folder)
    (folder / "broken.bvh").write_text("HIERARCHY\nROOT\n")
    report = ClipIndex.build(
        [folder], tmp_path / "b.qidx", IndexSettings(kinds=("motion",)), runner=Runner.inline()
    )
    assert [r.name for r in report.added] == ["take_001"]
    assert len(report.failures) == 1 and "broken.bvh" in str(report.failures[0])
    with pytest.raises(ValueError, match="kinds"):
        IndexSettings(kinds=("colour",))
    with pytest.raises(ValueError, match="batch"):
        IndexSettings(batch=0)
    with pytest.raises(FileExistsError), pytest.warns(DeprecationWarning, match="ClipIndex.create"):
        ClipIndex.create(tmp_path / "b.qidx")
    again = ClipIndex.build(
        [folder], tmp_path / "b.qidx", IndexSettings(kinds=("motion",)), runner=Runner.inline()
    )
    assert again.details["resumed"] and [r.name for r in again.skipped] == ["take_001"]


def test_search_k_and_the_reader_surface(two_sessions, tmp_path):
    out = tmp_path / "k.qidx"
    settings = IndexSettings(kinds=("motion",), read=ReadSettings(units="cm"))
    ClipIndex.build([two_sessions], out, settings, runner=Runner.inline())
    with ClipIndex.open(out) as index:
        assert isinstance(index.clips()[0], ClipRef) and index.settings.read.units == "cm"
        hits = index.search("punch", k=1)
        assert len(hits) == 1 and os.path.isabs(hits[0].path)
        assert index.blob("missing") is None


def test_index_add_reads_and_indexes_with_the_settings_the_index_was_built_with(
    two_sessions, tmp_path
):
    """``index add`` without options keeps the stored unit, skeleton folder, kinds and label
    rule (it used to store the command line's defaults over them); an option given replaces
    its setting."""
    index = tmp_path / "x.qidx"
    built = runner.invoke(
        app,
        ["index", "build", str(two_sessions / "s1" / "take_001.bvh"), "-o", str(index),
         "--units", "cm", "--label-folders", "--workers", "1"],
    )  # fmt: skip
    assert built.exit_code == 0, built.output
    with ClipIndex.open(index) as idx:
        before = idx.settings
    assert before.read.units == "cm" and before.label_folders
    added = runner.invoke(
        app, ["index", "add", str(index), str(two_sessions / "s1" / "punch.bvh"), "--workers", "1"]
    )
    assert added.exit_code == 0, added.output
    doc = json.loads(runner.invoke(app, ["index", "ls", str(index), "--json"]).stdout)
    assert IndexSettings.from_dict(doc["settings"]) == before
    assert {c["label"] for c in doc["clips"]} == {"s1"}  # the folder rule applied to the new clip
    added = runner.invoke(
        app,
        ["index", "add", str(index), str(two_sessions / "s2"), "--units", "mm", "--workers", "1",
         "--no-label-folders"],
    )  # fmt: skip
    with ClipIndex.open(index) as idx:
        after = idx.settings
    assert after == before.replace(read=before.read.replace(units="mm"), label_folders=False)


def test_an_empty_index_is_searched_with_an_error_and_a_failed_add_exits_2(two_sessions, tmp_path):
    """Issue 29 item 6: a search of an index of no clips printed an empty table, exit 0 (read
    as "nothing alike"); it is one error line saying so, exit 2, however the query comes. An
    ``index add`` of clips that all fail adds nothing and exits 2, not 1."""
    index = tmp_path / "x.qidx"
    clip = two_sessions / "s1" / "punch.bvh"
    assert _build(str(clip), "-o", str(index)).exit_code == 0
    assert runner.invoke(app, ["index", "remove", str(index), "punch"]).exit_code == 0
    queries = tmp_path / "queries.txt"
    queries.write_text(f"{clip}\n")
    for args in ([str(clip)], [str(clip), "--json"], ["--queries", str(queries)]):
        result = runner.invoke(app, ["search", *args, "--index", str(index)])
        assert result.exit_code == 2, (args, result.output)
        assert "holds no clips" in result.stderr and "Traceback" not in result.output
        assert result.stdout == ""
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "a.bvh").write_text("HIERARCHY\nROOT x\n")
    before = index.read_bytes()
    result = runner.invoke(app, ["index", "add", str(index), str(broken), "--workers", "1"])
    assert result.exit_code == 2, result.output
    assert "no clip added, none of the 1 clips could be indexed" in result.stderr
    assert index.read_bytes() == before
