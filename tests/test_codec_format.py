"""The .qmz container: corruption of any kind is a FormatError, never a crash or a garbage
motion; random access, append and determinism."""

from __future__ import annotations

import numpy as np
import pytest

from quatmotion import codec
from quatmotion.codec.container import FORMAT_VERSION, MAGIC, scan_chunks
from quatmotion.errors import FormatError
from quatmotion.io import read_motion, write_bvh
from quatmotion.motion import Motion, Skeleton, forward_kinematics
from quatmotion.synthetic import generate_clip


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    """Generated clips read back from BVH (a BVH skeleton record is small: the corruption
    test flips a bit in every byte of the file)."""
    folder = tmp_path_factory.mktemp("clips")
    out = []
    for kind, seed, frames in (("walk", 3, 60), ("squat", 4, 50), ("kick", 5, 40)):
        path = folder / f"{kind}_{seed}.bvh"
        write_bvh(generate_clip(kind, seed, n_frames=frames), path)
        out.append(read_motion(path))
    return out


@pytest.fixture(scope="module")
def library(clips):
    return codec.Archive.build(clips[:2], None, codec.CompressSettings(max_error=2.0)).details[
        "data"
    ]


def _read_everything(data: bytes) -> None:
    with codec.Archive.open(data) as archive:
        archive.verify()
        for i in range(len(archive)):
            archive.read(i)


def test_every_flipped_bit_is_a_format_error(library):
    assert len(library) < 20000
    rng = np.random.default_rng(0)
    positions = range(len(library))
    for pos in positions:
        bit = int(rng.integers(8))
        bad = bytearray(library)
        bad[pos] ^= 1 << bit
        with pytest.raises(FormatError):
            _read_everything(bytes(bad))


def test_truncation_at_every_chunk_boundary(library, tmp_path):
    import io

    ends = [
        ref.offset + ref.length + 4
        for ref in scan_chunks(io.BytesIO(library), tmp_path, len(library))
    ]
    assert ends[-1] == len(library)
    for end in [0, 3, len(MAGIC), len(MAGIC) + 2, *ends[:-1], len(library) - 1]:
        with pytest.raises(FormatError):
            _read_everything(library[:end])


def test_newer_version_and_wrong_magic(library, tmp_path):
    newer = bytearray(library)
    newer[len(MAGIC) : len(MAGIC) + 2] = (FORMAT_VERSION + 1).to_bytes(2, "little")
    with pytest.raises(FormatError, match="newer"):
        codec.Archive.open(bytes(newer))
    path = tmp_path / "x.qmz"
    path.write_bytes(b"BVH" + library[3:])
    with pytest.raises(FormatError, match="magic") as info:
        codec.Archive.open(path)
    assert str(path) in str(info.value)


def test_one_clip_decodes_alone_as_in_a_full_decode(clips, library):
    with codec.Archive.open(library) as full:
        everything = [full.read(i) for i in range(len(full))]
    with codec.Archive.open(library) as archive:
        alone = archive.read(clips[1].name)  # nothing else decoded first
        assert archive._layouts  # the shared model was read, no other clip chunk
    np.testing.assert_array_equal(alone.rotations, everything[1].rotations)
    np.testing.assert_array_equal(alone.root_translation, everything[1].root_translation)


def test_append_keeps_old_clips_and_adds_the_new(clips, library, tmp_path):
    path = tmp_path / "lib.qmz"
    path.write_bytes(library)
    before = [codec.Archive.open(path).read(i) for i in range(2)]
    codec.Archive.add(path, [clips[2]], codec.CompressSettings(max_error=2.0))
    with codec.Archive.open(path) as archive:
        assert archive.names() == [c.name for c in clips]
        for i in range(2):
            np.testing.assert_array_equal(archive.read(i).rotations, before[i].rotations)
        new = archive.read(clips[2].name)
    err = np.linalg.norm(
        forward_kinematics(new).all_positions() - forward_kinematics(clips[2]).all_positions(),
        axis=-1,
    )
    assert err.max() <= 2.0
    # appending the same clip set twice gives the same bytes (the new clip is coded against the
    # file's models, whatever else is in memory)
    again = tmp_path / "again.qmz"
    again.write_bytes(library)
    codec.Archive.add(again, [clips[2]], codec.CompressSettings(max_error=2.0))
    assert again.read_bytes() == path.read_bytes()
    # a clip the file holds already is skipped, and the file left as it was
    report = codec.Archive.add(path, [clips[2]], codec.CompressSettings(max_error=2.0))
    assert not report.added and [r.name for r in report.skipped] == [clips[2].name]
    assert path.read_bytes() == again.read_bytes()


def test_same_input_and_seed_same_bytes(clips):
    a = codec.Archive.build(clips[:2], None, codec.CompressSettings(max_error=2.0, seed=7)).details[
        "data"
    ]
    b = codec.Archive.build(clips[:2], None, codec.CompressSettings(max_error=2.0, seed=7)).details[
        "data"
    ]
    assert a == b


def test_nan_input_is_a_clear_error_and_no_file(tmp_path):
    bad = tmp_path / "nan.bvh"
    bad.write_text(
        "HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 0\n  CHANNELS 6 Xposition Yposition Zposition "
        "Zrotation Xrotation Yrotation\n  End Site\n  {\n    OFFSET 0 10 0\n  }\n}\n"
        "MOTION\nFrames: 2\nFrame Time: 0.01\n0 0 0 0 0 0\n0 nan 0 0 0 0\n"
    )
    out = tmp_path / "out.qmz"
    with pytest.raises(FormatError, match="nan.bvh"):
        codec.Archive.build([bad], out, codec.CompressSettings(max_error=1.0))
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir()] == ["nan.bvh"]


def test_unstorable_skeleton_is_a_clear_error_and_no_file(clips, tmp_path):
    sk = clips[0].skeleton
    odd = Skeleton(
        sk.joint_names, sk.parents, sk.offsets, sk.channels, sk.euler, sk.axes, sk.site_names,
        sk.site_parents, sk.site_offsets, "odd", {"handle": object()},
    )  # fmt: skip
    motion = Motion(odd, clips[0].fps, clips[0].root_translation, clips[0].rotations, name="odd")
    out = tmp_path / "out.qmz"
    with pytest.raises(ValueError, match="cannot be stored"):
        codec.Archive.build([motion], out, codec.CompressSettings(max_error=1.0))
    assert not out.exists()


def test_a_bvh_skeleton_is_stored_as_its_hierarchy_whether_its_unit_was_given_or_guessed(
    tmp_path,
):
    """The compact BVH record (not the exact JSON fallback, four times its size) holds both a
    skeleton read at a given unit and one whose unit was guessed, and says which it was."""
    from quatmotion.codec.skeletons import RECORD_BVH, RECORD_BVH_GUESSED, skeleton_record
    from quatmotion.io import read_bvh, write_bvh

    path = tmp_path / "walk.bvh"
    write_bvh(generate_clip("walk", 3, n_frames=20), path)
    for motion, kind in ((read_bvh(path), RECORD_BVH_GUESSED), (read_bvh(path, 1.0), RECORD_BVH)):
        assert skeleton_record(motion.skeleton)[0] == kind
        with codec.Archive.open(
            codec.Archive.build([motion], None, codec.CompressSettings(max_error=1.0)).details[
                "data"
            ]
        ) as archive:
            back = archive.read(0).skeleton
        assert dict(back.extras) == dict(motion.skeleton.extras)
