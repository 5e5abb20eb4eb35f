"""compress keys skeletons by fingerprint (issue 17, item 7): the skeleton table's lookups cost
O(1) in the skeletons it holds, while distinct skeletons stay distinct and equal ones share."""

from __future__ import annotations

import dataclasses

import numpy as np

from quatmotion import codec
from quatmotion.codec.writer.skeleton_table import SkeletonTable
from quatmotion.motion import Motion, Skeleton
from quatmotion.synthetic import cmu_skeleton, generate_clip


def _scaled(skeleton: Skeleton, factor: float) -> Skeleton:
    return dataclasses.replace(
        skeleton,
        offsets=skeleton.offsets * factor,
        site_offsets=skeleton.site_offsets * factor,
    )


def test_distinct_skeletons_cost_no_comparisons_with_earlier_ones():
    base = cmu_skeleton()
    table = SkeletonTable()
    skeletons = [_scaled(base, 1.0 + 0.001 * k) for k in range(200)]
    for k, sk in enumerate(skeletons):
        assert table.index(sk) == k
    # The quadratic scan made k comparisons for the k-th new skeleton (19,900 in all).
    assert table.comparisons == 0
    # Equal skeletons (new objects, same contents) find their entry with one comparison each.
    for k in (0, 57, 199):
        assert table.index(_scaled(base, 1.0 + 0.001 * k)) == k
    assert table.comparisons == 3
    assert len(table.skeletons) == 200 and len(table.records) == 200


def test_table_restored_from_an_archive_finds_its_skeletons():
    base = cmu_skeleton()
    first = SkeletonTable()
    for k in range(5):
        first.index(_scaled(base, 1.0 + 0.01 * k))
    again = SkeletonTable(
        list(first.records), list(first.texts), list(first.skeletons), list(first.objects)
    )
    assert again.index(_scaled(base, 1.03)) == 3
    assert again.index(_scaled(base, 2.0)) == 5
    assert len(again.new_records) == 1


def _clip(seed: int, skeleton: Skeleton, name: str) -> Motion:
    return generate_clip("walk", seed, n_frames=24, skeleton=skeleton).renamed(name)


def test_distinct_skeletons_stay_distinct_and_equal_ones_share(tmp_path):
    base = cmu_skeleton()
    small, tall = _scaled(base, 0.8), _scaled(base, 1.1)
    no_sites = dataclasses.replace(
        base,
        site_names=(),
        site_parents=np.zeros(0, dtype=base.site_parents.dtype),
        site_offsets=np.zeros((0, 3)),
    )
    # Another structure: a joint renamed gives another channel layout.
    names = list(base.joint_names)
    names[-1] = names[-1] + "_renamed"
    other = dataclasses.replace(base, joint_names=tuple(names))
    clips = [
        _clip(1, small, "a"),
        _clip(2, tall, "b"),
        _clip(3, _scaled(base, 0.8), "c"),
        dataclasses.replace(_clip(4, base, "d"), skeleton=other),
        dataclasses.replace(_clip(5, base, "e"), skeleton=no_sites),
    ]
    path = tmp_path / "x.qmz"
    codec.Archive.build(clips, path, codec.CompressSettings(max_error=1.0))
    with codec.Archive.open(path) as archive:
        entries = {c.name: c for c in archive.entries}
        # a and c: equal skeletons (distinct objects) share one entry; b, d, e have their own.
        assert entries["a"].skeleton == entries["c"].skeleton
        assert len({entries[n].skeleton for n in "abde"}) == 4
        assert len(archive.entries) == 5
        # Layouts follow structure: d's renamed joint has its own; a, b, c share one.
        assert entries["a"].layout == entries["b"].layout == entries["c"].layout
        assert entries["d"].layout != entries["a"].layout
        for name, clip in zip("abcde", clips, strict=True):
            decoded = archive.read(name)
            assert np.array_equal(decoded.skeleton.offsets, clip.skeleton.offsets)
            assert decoded.skeleton.joint_names == clip.skeleton.joint_names
