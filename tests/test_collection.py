"""The collection model's shared parts: settings, format versions, clip references, finding,
reading and labelling clips."""

from __future__ import annotations

import dataclasses
import json
from numbers import Real
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

from quatmotion._format import FileFormat
from quatmotion._settings import Interval, Settings, StrOptions
from quatmotion.collection import (
    ClipRef,
    ReadSettings,
    find_clips,
    find_skeleton,
    label_sources,
    motion_hash,
    read_clip,
    unique_names,
)
from quatmotion.errors import FormatError
from quatmotion.io import write_asf, write_motion
from quatmotion.io.labels import read_labels_csv, sidecar_labels
from quatmotion.synthetic import generate_clip


@dataclasses.dataclass(frozen=True)
class _Example(Settings):
    max_error: float | None = 1.0
    method: str = "best"
    kinds: tuple[str, ...] = ("motion",)
    read: ReadSettings = dataclasses.field(default_factory=ReadSettings)

    _parameter_constraints: ClassVar[dict] = {
        "max_error": [Interval(Real, 0, None, closed="neither"), None],
        "method": [StrOptions({"best", "spline"})],
    }


# --------------------------------------------------------------------------- settings
def test_settings_validate_once_and_name_the_field():
    with pytest.raises(ValueError, match="'max_error' parameter of _Example must be"):
        _Example(max_error=-1.0)
    with pytest.raises(ValueError, match="'method' parameter of _Example"):
        _Example(method="zip")
    with pytest.raises(dataclasses.FrozenInstanceError):
        _Example().method = "spline"  # type: ignore[misc]


def test_settings_round_trip_through_json_with_nested_settings():
    s = _Example(max_error=0.5, kinds=["motion", "qssd"], read=ReadSettings(units="in"))
    assert s.kinds == ("motion", "qssd")  # lists become tuples: frozen all the way
    back = _Example.from_dict(json.loads(json.dumps(s.to_dict())))
    assert back == s
    assert isinstance(back.read, ReadSettings)


def test_settings_from_an_older_file_take_defaults_and_refuse_unknown_keys():
    assert _Example.from_dict({"method": "spline"}) == _Example(method="spline")
    with pytest.raises(FormatError, match="unknown settings colour"):
        _Example.from_dict({"colour": "red"}, "x.qmz")
    with pytest.raises(FormatError, match="x.qmz"):
        _Example.from_dict({"max_error": -3}, "x.qmz")


def test_read_settings_units():
    assert ReadSettings(units=2.54).units == 2.54
    with pytest.raises(ValueError, match="'units' parameter"):
        ReadSettings(units="furlong")
    with pytest.raises(ValueError, match="'units' parameter"):
        ReadSettings(units=-1.0)


# --------------------------------------------------------------------------- versions
def test_one_version_policy():
    fmt = FileFormat("quatmotion-x", 3, 2, "a quatmotion x file")
    assert fmt.check("quatmotion-x", 2) == 2
    assert fmt.check("quatmotion-x", "3") == 3
    with pytest.raises(FormatError, match="newer quatmotion .*reads versions 2 to 3"):
        fmt.check("quatmotion-x", 4, "f.x")
    with pytest.raises(FormatError, match="version 1 is no longer read"):
        fmt.check("quatmotion-x", 1)
    with pytest.raises(FormatError, match="not a quatmotion x file"):
        fmt.check("something-else", 3)
    with pytest.raises(FormatError, match="unreadable format version"):
        fmt.check("quatmotion-x", "three")
    with pytest.raises(ValueError):
        FileFormat("y", 1, 2, "y")


# --------------------------------------------------------------------------- references
def _write(clip, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_motion(clip, path)
    return path


def test_same_stem_in_two_folders_stays_two_clips(tmp_path):
    a = _write(generate_clip("walk", 1, n_frames=20), tmp_path / "s1" / "take_001.bvh")
    b = _write(generate_clip("run", 2, n_frames=20), tmp_path / "s2" / "take_001.bvh")
    c = _write(generate_clip("walk", 3, n_frames=20), tmp_path / "s2" / "other.bvh")
    sources = find_clips([tmp_path])
    assert sorted(s.name for s in sources) == ["other", "s1/take_001", "s2/take_001"]
    assert {s.path for s in sources} == {a.resolve(), b.resolve(), c.resolve()}
    assert len({s.sha256 for s in sources}) == 3


def test_unique_names_keep_the_suffix_where_only_it_differs(tmp_path):
    names = unique_names([tmp_path / "a" / "x.bvh", tmp_path / "a" / "x.amc", tmp_path / "y.bvh"])
    assert names == ["x.bvh", "x.amc", "y"]


def test_motions_in_memory_need_unique_names():
    clip = generate_clip("walk", 1, n_frames=10)
    with pytest.raises(ValueError, match="unique"):
        find_clips([clip, clip])


def test_reference_round_trip_and_reading_completes_it(tmp_path):
    path = _write(generate_clip("walk", 1, n_frames=20), tmp_path / "walk.bvh")
    (source,) = find_clips([path])
    read = read_clip(source)
    ref = read.ref
    assert ref.name == "walk" == read.motion.name
    assert ref.skeleton == read.motion.skeleton.fingerprint()
    assert ref.units and ref.units_guessed  # a BVH read without a unit: guessed, and said
    assert ClipRef.from_dict(json.loads(json.dumps(ref.to_dict()))) == ref
    given = read_clip(source, ReadSettings(units="cm")).ref
    assert given.units == "cm" and not given.units_guessed
    with pytest.raises(FormatError, match="malformed clip reference"):
        ClipRef.from_dict({"name": "x", "sha256": "nothex"})


def test_reference_found_again_after_the_folder_moved(tmp_path):
    path = _write(generate_clip("walk", 1, n_frames=10), tmp_path / "lib" / "clips" / "w.bvh")
    ref = read_clip(find_clips([path])[0]).ref
    moved = tmp_path / "elsewhere"
    (tmp_path / "lib").rename(moved)
    assert ref.locate() == (None, None)
    assert ref.locate(moved)[0] == moved / "clips" / "w.bvh"


def test_motion_hash_is_content_not_name():
    clip = generate_clip("walk", 1, n_frames=10)
    assert motion_hash(clip) == motion_hash(clip.renamed("other"))
    other = generate_clip("walk", 2, n_frames=10)
    assert motion_hash(clip) != motion_hash(other)


def test_skeleton_fingerprint_is_exact():
    sk = generate_clip("walk", 1, n_frames=2).skeleton
    same = dataclasses.replace(sk)
    assert sk.fingerprint() == same.fingerprint()
    offsets = sk.offsets.copy()
    offsets[3, 1] = np.nextafter(offsets[3, 1], np.inf)
    assert dataclasses.replace(sk, offsets=offsets).fingerprint() != sk.fingerprint()
    zeroed = sk.offsets.copy()
    zeroed[zeroed == 0] = -0.0
    assert dataclasses.replace(sk, offsets=zeroed).fingerprint() == sk.fingerprint()
    assert dataclasses.replace(sk, name="x").fingerprint() != sk.fingerprint()


# --------------------------------------------------------------------------- skeletons
def _amc_library(tmp_path: Path) -> tuple[Path, Path]:
    clip = generate_clip("walk", 1, n_frames=10)
    folder = tmp_path / "takes"
    folder.mkdir()
    amc = folder / "walking.amc"
    write_motion(clip, amc)
    asf = folder / "skeleton.asf"
    write_asf(clip.skeleton, asf)
    return amc, asf


def test_the_only_asf_of_the_folder_is_used(tmp_path):
    amc, asf = _amc_library(tmp_path)
    assert find_skeleton(amc) == asf
    assert read_clip(find_clips([amc])[0]).ref.skeleton_path == str(asf.resolve())


def test_several_asf_files_are_named_in_the_error(tmp_path):
    amc, asf = _amc_library(tmp_path)
    (asf.parent / "other.asf").write_bytes(asf.read_bytes())
    with pytest.raises(FormatError, match=r"holds 2 ASF files \(other.asf, skeleton.asf\)"):
        find_skeleton(amc)
    failed: list = []
    assert find_clips([amc.parent], on_error=failed) == [] and len(failed) == 1


def test_skeleton_given_as_file_or_folder(tmp_path):
    amc, asf = _amc_library(tmp_path)
    (asf.parent / "other.asf").write_bytes(asf.read_bytes())
    assert find_skeleton(amc, asf.parent / "other.asf") == asf.parent / "other.asf"
    store = tmp_path / "skeletons"
    store.mkdir()
    (store / "walking.asf").write_bytes(asf.read_bytes())
    (store / "unrelated.asf").write_bytes(asf.read_bytes())
    assert find_skeleton(amc, store) == store / "walking.asf"
    with pytest.raises(FileNotFoundError):
        find_skeleton(amc, tmp_path / "missing")


@pytest.mark.needs_data
def test_the_data_folder_conventions_still_hold():
    from quatmotion.datasets import data_root

    root = data_root()
    cmu = find_clips([root / "cmu" / "02" / "02_01.amc"])[0]
    assert cmu.skeleton_path == (root / "cmu" / "02" / "02.asf").resolve()
    hdm = next(iter(sorted((root / "hdm05" / "clips" / "squat1Reps").glob("*.amc"))))
    actor = hdm.stem.split("_")[1]
    assert find_clips([hdm])[0].skeleton_path.name == f"HDM_{actor}.asf"


# --------------------------------------------------------------------------- labels
def test_sidecar_labels_resolve_index_lists_up_the_tree(tmp_path):
    clips = tmp_path / "data" / "clips"
    path = _write(generate_clip("walk", 1, n_frames=10), clips / "a.bvh")
    (tmp_path / "data" / "content_label.txt").write_text("set-1_walk\nset-1_run\n")
    (clips / "a.json").write_text('{"content": 1, "style": "tired"}')
    assert sidecar_labels(path) == {"content": "run", "style": "tired"}
    (clips / "a.json").write_text('{"content": 7}')
    with pytest.raises(FormatError, match="outside its label list"):
        sidecar_labels(path)
    (clips / "a.json").write_text("[1, 2]")
    with pytest.raises(FormatError, match="JSON object"):
        sidecar_labels(path)


def test_label_precedence_and_unmatched_keys(tmp_path):
    walk = _write(generate_clip("walk", 1, n_frames=10), tmp_path / "walking" / "t1.bvh")
    run = _write(generate_clip("run", 2, n_frames=10), tmp_path / "running" / "t2.bvh")
    (run.parent / "t2.json").write_text('{"label": "jog"}')
    sources = find_clips([tmp_path])
    found = label_sources(sources, folders=True, catalogue=False)
    assert found.labels == {"t1": "walking", "t2": "jog"}
    csv = tmp_path / "labels.csv"
    csv.write_text("clip,label\nt1.bvh,stroll\nnobody,x\n")
    given = label_sources(sources, read_labels_csv(csv), folders=True, catalogue=False)
    assert given.labels == {"t1": "stroll", "t2": "jog"}
    assert given.unmatched == ["nobody"]
    assert label_sources(sources, {str(walk): "by path"}, catalogue=False).labels["t1"] == "by path"
