"""The codec as a collection file kind: CompressSettings, Archive.build/open/add, clip
references and settings stored in the file (format version 2 on), clips named apart."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from quatmotion.cli import app
from quatmotion.codec import Archive, CompressSettings
from quatmotion.collection import ReadSettings, content_hash
from quatmotion.errors import FormatError
from quatmotion.io import read_motion, write_bvh
from quatmotion.parallel import Failure, Runner
from quatmotion.synthetic import generate_clip

FIXTURES = Path(__file__).parent / "data" / "v0.3.0"
INLINE = Runner.inline()


@pytest.fixture(scope="module")
def takes(tmp_path_factory):
    """Two clips named take_001 in s1/ and s2/, and one broken file."""
    root = tmp_path_factory.mktemp("takes")
    for folder, kind, seed in (("s1", "walk", 1), ("s2", "squat", 2)):
        (root / folder).mkdir()
        write_bvh(generate_clip(kind, seed, n_frames=30), root / folder / "take_001.bvh")
    return root


def test_settings_validated_once_and_round_trip():
    s = CompressSettings(ratio=6.0, max_error=None, method="naive", read=ReadSettings(units="cm"))
    assert CompressSettings.from_dict(json.loads(json.dumps(s.to_dict()))) == s
    for bad in (
        {"ratio": 6.0},  # with the default bound: both
        {"max_error": 0.0},
        {"max_error": float("nan")},
        {"ratio": 1.0, "max_error": None},
        {"method": "zip"},
        {"bound_on": "bones"},
        {"on_error": "ignore"},
        {"seed": -1},
    ):
        with pytest.raises(ValueError):
            CompressSettings(**bad)


def test_two_takes_with_one_stem_compress_as_two_clips(takes, tmp_path):
    out = tmp_path / "takes.qmz"
    settings = CompressSettings(max_error=1.5, seed=3)
    report = Archive.build([takes], out, settings, runner=INLINE)
    assert [r.name for r in report.added] == ["s1/take_001", "s2/take_001"]
    assert report.ok and report.path == out and report.settings == settings
    with Archive.open(out) as archive:
        assert archive.version == 3 and archive.format.version == 3
        assert archive.settings == settings
        refs = archive.clips()
        assert [r.name for r in refs] == ["s1/take_001", "s2/take_001"]
        for ref, folder in zip(refs, ("s1", "s2"), strict=True):
            path = takes / folder / "take_001.bvh"
            assert ref.path == str(path.resolve()) and ref.sha256 == content_hash(path)
            assert ref.skeleton == read_motion(path).skeleton.fingerprint()
            assert ref.units and ref.units_guessed
        assert refs == tuple(report.added)
        original = read_motion(takes / "s2" / "take_001.bvh")
        decoded = archive.read("s2/take_001")
        assert decoded.n_frames == original.n_frames


def test_failures_are_failure_records_and_the_rest_is_written(takes, tmp_path):
    folder = tmp_path / "in"
    shutil.copytree(takes, folder)
    (folder / "broken.bvh").write_text("HIERARCHY\nROOT\n")
    settings = CompressSettings(on_error="skip")
    report = Archive.build([folder], tmp_path / "x.qmz", settings, runner=INLINE)
    assert len(report.added) == 2 and len(report.failures) == 1
    failure = report.failures[0]
    assert isinstance(failure, Failure) and "broken.bvh" in str(failure)
    with pytest.raises(FormatError):
        Archive.build([folder], tmp_path / "y.qmz", CompressSettings(), runner=INLINE)
    assert not (tmp_path / "y.qmz").exists()


def test_add_skips_clips_already_in_the_file_and_keeps_its_settings(takes, tmp_path):
    out = tmp_path / "lib.qmz"
    settings = CompressSettings(max_error=2.0)
    Archive.build([takes / "s1"], out, settings, runner=INLINE)
    before = out.read_bytes()
    report = Archive.add(out, [takes / "s1", takes / "s2"], runner=INLINE)
    assert [r.name for r in report.skipped] == ["take_001"]  # as the file names it
    with Archive.open(out) as archive:
        assert archive.settings == settings
        assert len(archive) == 2 and archive.clips()[1] == report.added[0]
        with Archive.open(before) as old:
            assert archive.payloads()[2][0] == old.payloads()[2][0]  # copied byte for byte


def test_v030_file_opens_with_no_settings_and_file_local_refs(tmp_path):
    with Archive.open(FIXTURES / "bvh.qmz") as archive:
        assert archive.version == 1 and archive.settings is None
        refs = archive.clips()
        assert [r.name for r in refs] == archive.names()
        assert len({r.sha256 for r in refs}) == 2 and all(r.path is None for r in refs)
    # adding to a version 1 file rewrites it in the current version, the old clips' bytes kept
    copy = tmp_path / "old.qmz"
    shutil.copy(FIXTURES / "bvh.qmz", copy)
    expected = np.load(FIXTURES / "expected.npz")
    clip = tmp_path / "new_take.bvh"
    write_bvh(generate_clip("jump", 7, n_frames=20), clip)
    Archive.add(copy, [clip], CompressSettings(max_error=2.0), runner=INLINE)
    with Archive.open(copy) as archive:
        assert archive.version == 3 and len(archive) == 3
        assert archive.clips()[:2] == refs
        name = refs[0].name
        _, rotations = archive.read_rotations(name)
        # Equal to a few ulp: the final normalisation's last bit follows numpy's SIMD path.
        np.testing.assert_allclose(
            rotations, expected[f"bvh.qmz/{name}/rotations"], rtol=0, atol=1e-15
        )


def test_ls_says_how_the_file_was_made_and_json_lists_refs(takes, tmp_path):
    out = tmp_path / "lib.qmz"
    cli = CliRunner()
    args = ["-o", str(out), "--max-error", "1.5", "--method", "naive", "--seed", "4"]
    made = cli.invoke(app, ["compress", str(takes), *args, "--workers", "1"])
    assert made.exit_code == 0, made.output
    shown = cli.invoke(app, ["ls", str(out)])
    assert "method naive, max error 1.5 cm on joints" in shown.output and "seed 4" in shown.output
    doc = json.loads(cli.invoke(app, ["ls", str(out), "--json"]).stdout)
    assert doc["format_version"] == 3 and doc["settings"]["max_error"] == 1.5
    assert [c["ref"]["name"] for c in doc["clips"]] == ["s1/take_001", "s2/take_001"]
    assert doc["clips"][0]["ref"]["sha256"] == content_hash(takes / "s1" / "take_001.bvh")
    old = cli.invoke(app, ["ls", str(FIXTURES / "amc.qmz")])
    assert old.exit_code == 0 and "settings not stored" in old.output


def test_add_names_a_clip_apart_from_one_with_its_stem(takes, tmp_path):
    out = tmp_path / "lib.qmz"
    Archive.build([takes / "s1"], out, runner=INLINE)
    report = Archive.add(out, [takes / "s2"], runner=INLINE)
    assert [r.name for r in report.added] == ["s2/take_001"]
    with Archive.open(out) as archive:
        assert archive.names() == ["take_001", "s2/take_001"]
        assert archive.read("s2/take_001").n_frames == 30


def test_version_3_header_bytes_are_as_docs_format_says(takes, tmp_path):
    """Parse the header by docs/format.md alone: the settings JSON, then each clip entry's
    reference fields after `arms` (with version 3's take flag: 0, these files have one take);
    each clip chunk starts with the entry's frame count."""
    import io
    import zlib

    from quatmotion.codec.binary import Reader
    from quatmotion.codec.container import MAGIC, scan_chunks

    settings = CompressSettings(max_error=1.25, seed=2, read=ReadSettings(units="cm"))
    data = Archive.build([takes], None, settings, runner=INLINE).details["data"]
    assert data[:8] == MAGIC and int.from_bytes(data[8:10], "little") == 3
    chunks = list(scan_chunks(io.BytesIO(data), tmp_path, len(data)))
    head = chunks[0]
    r = Reader(zlib.decompress(data[head.offset : head.offset + head.length], -15))
    assert r.string() == "best"
    assert json.loads(r.blob()) == settings.to_dict()
    n_records = r.uvarint()
    for _ in range(n_records):
        r.u8(), r.f64()
    for _ in range(r.uvarint()):
        r.uvarint(), r.string()
    for _ in range(r.uvarint()):
        r.uvarint()
    for _ in range(r.uvarint()):
        r.f64()
    names, frames = [], []
    for _ in range(r.uvarint()):
        names.append(r.string())
        for _ in range(3):
            r.uvarint()
        frames.append(r.uvarint())
        r.uvarint()
        r.u8(), r.f32(), r.f32()
        sha, path = r.take(32).hex(), r.string()
        assert sha == content_hash(path) and path.endswith(names[-1] + ".bvh")
        assert r.string() == "" and r.string() and r.string() == "cm" and r.u8() == 0
        assert r.u8() == 0  # no take
    r.end()
    assert names == ["s1/take_001", "s2/take_001"]
    clips = [c for c in chunks if c.tag == b"C"]
    assert [Reader(data[c.offset : c.offset + c.length]).uvarint() for c in clips] == frames
