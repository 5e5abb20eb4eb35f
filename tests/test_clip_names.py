"""One clip-name rule (:func:`quatmotion.io.names.match_clip`) for a ``.qmz``, a clip index and
a pose library (issue 17: ``decompress --clip NAME.bvh`` failed where ``pose search`` found it;
the index took the first of two clips of one name)."""

from __future__ import annotations

import pytest

from quatmotion import codec
from quatmotion.collection import ClipRef
from quatmotion.errors import ClipNameError
from quatmotion.io.names import match_clip
from quatmotion.parallel import Runner
from quatmotion.retrieval.index import ClipIndex, ClipRecord
from quatmotion.synthetic import generate_clip


@pytest.mark.parametrize(
    ("query", "names", "expected"),
    [
        ("walk.bvh", ["run", "walk"], 1),  # a .qmz names its clips by stem
        ("walk", ["a/run.amc", "a/walk.bvh"], 1),  # an index or pose library, by path
        ("a/walk", ["a/walk.bvh", "b/walk.bvh"], 0),
        ("b/walk.bvh", ["a/walk.bvh", "b/walk.bvh"], 1),
        ("01_01.amc", ["x/01_01.amc", "x/11_01.amc"], 0),  # whole components, not a suffix
        ("3", ["1.bvh", "2.bvh", "3.bvh", "4.bvh"], 2),  # a name before a number
        ("1", ["run", "walk"], 1),
        (0, ["run", "walk"], 0),
        ("WALK.BVH", ["WALK"], 0),
    ],
)
def test_a_clip_is_found_by_name_file_name_stem_trailing_folders_or_number(query, names, expected):
    assert match_clip(query, names) == expected


def test_no_match_names_close_ones_and_several_are_an_error_listing_them():
    with pytest.raises(ClipNameError, match="close names: walk_fast") as none:
        match_clip("walk_fst", ["run", "walk_fast"], "lib.qmz")
    assert "lib.qmz" in str(none.value) and isinstance(none.value, KeyError | ValueError)
    with pytest.raises(ClipNameError, match=r"ambiguous .* \(a/walk.bvh, b/walk.bvh\)"):
        match_clip("walk", ["a/walk.bvh", "b/walk.bvh"])
    with pytest.raises(ClipNameError, match="0 to 1"):
        match_clip(5, ["run", "walk"])


def test_a_qmz_reads_a_clip_by_its_file_name():
    clips = [generate_clip("walk", 1, n_frames=30), generate_clip("run", 2, n_frames=30)]
    with codec.Archive.open(
        codec.Archive.build(
            clips, None, codec.CompressSettings(max_error=2.0), runner=Runner.inline()
        ).details["data"]
    ) as archive:
        assert archive.read(f"{clips[1].name}.bvh").name == clips[1].name
        assert archive.index_of(f"{clips[0].name}.amc") == 0
        with pytest.raises(KeyError, match="close names"):
            archive.index_of(clips[0].name[:-1])


def test_an_index_finds_one_clip_of_a_name_or_says_which_ones(tmp_path):
    def record(name: str) -> ClipRecord:
        ref = ClipRef(name, "0" * 64, f"/data/{name}.bvh")
        return ClipRecord(ref, "", 10, 30.0, "s", {})

    with ClipIndex._create(tmp_path / "x.qidx") as index:
        index.store([record("a/walk"), record("b/walk"), record("run")])
        assert index.find("run").path == "/data/run.bvh"
        assert index.find("b/walk").name == "b/walk"
        with pytest.raises(ValueError, match=r"ambiguous.*a/walk, b/walk"):
            index.remove(["walk"])
        assert len(index) == 3  # nothing removed
        assert index.remove(["a/walk.bvh", "run.bvh"]) == ["a/walk", "run"]
        assert [c.name for c in index.clips()] == ["b/walk"]


def test_the_name_rule_knows_every_motion_suffix():
    """``_names`` imports no ``io`` (the quick search path loads no Numba): its suffixes are
    ``io.MOTION_SUFFIXES``, and a name loses any of them as ``match_clip`` reads it."""
    from quatmotion import _names
    from quatmotion.io import MOTION_SUFFIXES

    assert set(_names.CLIP_SUFFIXES) == set(MOTION_SUFFIXES)
    names = [f"clips/walk_{k}{suffix}" for k, suffix in enumerate(MOTION_SUFFIXES)]
    for k in range(len(names)):
        assert match_clip(f"walk_{k}", names) == k
        assert _names.rule_matches(f"clips/walk_{k}", names) == [k]
