"""Data folder location, clip catalogue and the CMU fetcher (against a local HTTP server)."""

from __future__ import annotations

import http.server
import json
from pathlib import Path

import pytest

from quatmotion.datasets import (
    DATA_ENV_VAR,
    DataNotFoundError,
    FetchError,
    catalogue,
    cmu_index,
    cmu_trials,
    cmu_url,
    data_root,
    fetch_cmu,
    project_root,
)

DATA = data_root(must_exist=False)

PROJECT = Path(__file__).resolve().parents[1]


# --- data_root ----------------------------------------------------------------------------------


def test_data_root_follows_the_environment_variable(tmp_path, monkeypatch):
    monkeypatch.setenv(DATA_ENV_VAR, str(tmp_path))
    assert data_root() == tmp_path.resolve()
    missing = tmp_path / "nowhere"
    monkeypatch.setenv(DATA_ENV_VAR, str(missing))
    with pytest.raises(DataNotFoundError, match=DATA_ENV_VAR):
        data_root()
    assert data_root(must_exist=False) == missing.resolve()


def test_data_root_defaults_to_shared_data_beside_the_project(monkeypatch, tmp_path):
    monkeypatch.delenv(DATA_ENV_VAR, raising=False)
    monkeypatch.chdir(tmp_path)  # the package location decides, not the current directory
    assert project_root() == PROJECT
    expected = (PROJECT / ".." / "shared" / "data").resolve()
    assert data_root(must_exist=False) == expected
    if not expected.is_dir():
        with pytest.raises(DataNotFoundError, match=DATA_ENV_VAR):
            data_root()


# --- catalogue on a small fake tree (always runs) -------------------------------------------------


def _touch(path: Path, text: str = "") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


@pytest.fixture()
def fake_root(tmp_path: Path) -> Path:
    root = tmp_path / "data"
    _touch(root / "cmu" / "05" / "05.asf")
    _touch(root / "cmu" / "05" / "05_01.amc")
    _touch(root / "cmu" / "05" / "05_02.amc")
    _touch(root / "cmu_bvh" / "05" / "05_01.bvh")
    _touch(
        root / "cmu_bvh" / "cmu-mocap-index-text.txt",
        "Subject #5 (modern dance)\n\n05_01\twalk\n05_02\tdance - pirouette\n",
    )
    _touch(root / "hdm05" / "skeletons" / "HDM_xy.asf")
    _touch(root / "hdm05" / "clips" / "hopBothLegs" / "HDM_xy_hopBothLegs_003_120.amc")
    _touch(root / "hdm05" / "clips" / "squat1Reps" / "HDM_zz_squat1Reps_010_120.amc")
    _touch(root / "bandai1" / "content_label.txt", "dataset-1_walk\ndataset-1_kick\n")
    _touch(root / "bandai1" / "style_label.txt", "dataset-1_normal\ndataset-1_tired\n")
    clips = root / "bandai1" / "clips"
    _touch(clips / "dataset-1_kick_tired_002.bvh")
    _touch(clips / "dataset-1_kick_tired_002.json", json.dumps({"content": 1, "style": 1}))
    _touch(clips / "dataset-1_walk_normal_001.bvh")
    _touch(clips / "dataset-1_walk_normal_001.json", "{broken")
    return root


def test_catalogue_parses_every_layout(fake_root):
    listed = catalogue(fake_root)
    assert len(listed) == 7
    entries = {e.name: e for e in listed if e.collection != "cmu_bvh"}
    cmu = entries["05_02"]
    assert (cmu.collection, cmu.format) == ("cmu", "amc")
    assert cmu.skeleton_path == fake_root / "cmu" / "05" / "05.asf"
    assert dict(cmu.labels) == {"subject": "05", "trial": "02", "description": "dance - pirouette"}
    assert cmu.label == "dance - pirouette"
    bvh = [e for e in listed if e.collection == "cmu_bvh"][0]
    assert bvh.skeleton_path is None and bvh.labels["description"] == "walk"
    hop = entries["HDM_xy_hopBothLegs_003_120"]
    assert dict(hop.labels) == {"class": "hopBothLegs", "actor": "xy", "take": "003", "fps": "120"}
    assert hop.skeleton_path == fake_root / "hdm05" / "skeletons" / "HDM_xy.asf"
    assert entries["HDM_zz_squat1Reps_010_120"].skeleton_path is None  # no HDM_zz.asf
    kick = entries["dataset-1_kick_tired_002"]
    assert dict(kick.labels) == {"take": "002", "content": "kick", "style": "tired"}
    # A broken sidecar leaves the clip listed, without content/style labels.
    assert "content" not in entries["dataset-1_walk_normal_001"].labels
    with pytest.raises(TypeError):
        kick.labels["content"] = "punch"  # read-only


def test_catalogue_filters(fake_root):
    assert {e.collection for e in catalogue(fake_root, collection="hdm05")} == {"hdm05"}
    assert len(catalogue(fake_root, collection=["cmu", "bandai1"])) == 4
    assert [e.name for e in catalogue(fake_root, labels={"actor": "XY"})] == [
        "HDM_xy_hopBothLegs_003_120"
    ]
    assert {(e.collection, e.name) for e in catalogue(fake_root, match="walk")} == {
        ("cmu", "05_01"),
        ("cmu_bvh", "05_01"),
        ("bandai1", "dataset-1_walk_normal_001"),
    }
    with pytest.raises(ValueError, match="unknown collection"):
        catalogue(fake_root, collection="mocapx")
    with pytest.raises(DataNotFoundError):
        catalogue(fake_root / "missing")


def test_cmu_index_and_trials(fake_root, tmp_path):
    index = cmu_index(fake_root / "cmu_bvh" / "cmu-mocap-index-text.txt")
    assert index == {"05_01": "walk", "05_02": "dance - pirouette"}
    assert cmu_trials(5, index) == [1, 2]
    assert cmu_trials("05", index) == [1, 2]
    assert cmu_trials(6, index) == []
    assert cmu_index(tmp_path / "none.txt") == {}
    assert cmu_url(2, None, "http://h/") == "http://h/subjects/02/02.asf"
    assert cmu_url("2", 7, "http://h") == "http://h/subjects/02/02_07.amc"
    with pytest.raises(FetchError):
        cmu_url("x")


# --- catalogue on the real data ------------------------------------------------------------------


@pytest.mark.needs_data
def test_catalogue_of_the_real_data_matches_its_files():
    entries = catalogue(DATA)
    by = {
        c: [e for e in entries if e.collection == c] for c in ("cmu", "cmu_bvh", "hdm05", "bandai1")
    }
    assert len(by["cmu"]) == len(list((DATA / "cmu").glob("*/*.amc")))
    assert len(by["cmu_bvh"]) == len(list((DATA / "cmu_bvh").glob("*/*.bvh")))
    assert len(by["hdm05"]) == len(list((DATA / "hdm05" / "clips").glob("*/*.amc")))
    assert len(by["bandai1"]) == len(list((DATA / "bandai1" / "clips").glob("*.bvh")))
    for e in by["hdm05"]:
        assert e.labels["class"] == e.path.parent.name
        assert e.name.startswith(f"HDM_{e.labels['actor']}_{e.labels['class']}_")
    for e in by["bandai1"]:
        # The JSON's indices agree with the content and style in the file name.
        assert e.name.startswith(f"dataset-1_{e.labels['content']}_{e.labels['style']}_")
    for e in by["cmu"]:
        assert e.skeleton_path is not None and e.skeleton_path.is_file()
        assert e.name == f"{e.labels['subject']}_{e.labels['trial']}"
    assert all("description" in e.labels for e in by["cmu"] + by["cmu_bvh"])
    walks = catalogue(DATA, collection="cmu_bvh", labels={"description": "walk"})
    assert walks and all(e.labels["description"] == "walk" for e in walks)


# --- fetch against a local server -----------------------------------------------------------------


@pytest.fixture()
def cmu_site(tmp_path: Path) -> Path:
    """A folder laid out like the CMU site, ``subjects/SS`` -> the data folder's ``cmu/SS``."""
    if not (DATA / "cmu").is_dir():
        pytest.skip(f"mocap data folder {DATA} has no cmu/ (set {DATA_ENV_VAR})")
    site = tmp_path / "site" / "subjects"
    site.mkdir(parents=True)
    for subject in (DATA / "cmu").iterdir():
        (site / subject.name).symlink_to(subject, target_is_directory=True)
    return tmp_path / "site"


def test_fetch_by_probing_downloads_identical_files(cmu_site, tmp_path, serve_directory):
    dest = tmp_path / "dest"
    url = serve_directory(cmu_site)
    files = fetch_cmu([3], dest=dest, base_url=url, index={}, show_progress=False)
    source = sorted((DATA / "cmu" / "03").iterdir())
    assert [f.name for f in files] == [p.name for p in source]  # ASF first, then trials in order
    for f, original in zip(files, source, strict=True):
        assert f.read_bytes() == original.read_bytes()
    assert not list(dest.rglob("*.part"))


def test_fetch_uses_the_index_and_skips_existing_files(cmu_site, tmp_path, serve_directory):
    dest = tmp_path / "dest"
    index = {"02_01": "walk", "02_02": "walk"}
    url = serve_directory(cmu_site)
    files = fetch_cmu(["2"], dest=dest, base_url=url, index=index, show_progress=False)
    assert [f.name for f in files] == ["02.asf", "02_01.amc", "02_02.amc"]
    (dest / "02" / "02_01.amc").write_text("kept")
    again = fetch_cmu([2], dest=dest, base_url=url, index=index, show_progress=False)
    assert (dest / "02" / "02_01.amc").read_text() == "kept" and again == files
    fetch_cmu([2], dest=dest, base_url=url, trials=[1], overwrite=True, show_progress=False)
    assert (dest / "02" / "02_01.amc").read_bytes() == (DATA / "cmu/02/02_01.amc").read_bytes()


def test_fetch_errors(cmu_site, tmp_path, serve_directory):
    url = serve_directory(cmu_site)
    with pytest.raises(FetchError, match="404"):
        fetch_cmu([99], dest=tmp_path / "d", base_url=url, index={}, show_progress=False)
    with pytest.raises(FetchError, match="404"):
        fetch_cmu([2], dest=tmp_path / "d", base_url=url, trials=[42], show_progress=False)
    with pytest.raises(FetchError):
        fetch_cmu([], dest=tmp_path / "d")


class _TruncatingHandler(http.server.SimpleHTTPRequestHandler):
    """Promises more bytes than it sends, then hangs up: a download cut off mid-file."""

    def do_GET(self):  # noqa: N802 (http.server's naming)
        self.send_response(200)
        self.send_header("Content-Length", "100000")
        self.end_headers()
        self.wfile.write(b"partial content")
        self.wfile.flush()
        self.close_connection = True


def test_interrupted_download_leaves_no_file(tmp_path, serve_directory):
    dest = tmp_path / "dest"
    url = serve_directory(tmp_path, _TruncatingHandler)
    with pytest.raises(FetchError):
        fetch_cmu([1], dest=dest, base_url=url, index={}, show_progress=False)
    assert not (dest / "01" / "01.asf").exists()
    assert not [p for p in dest.rglob("*") if p.is_file()]
