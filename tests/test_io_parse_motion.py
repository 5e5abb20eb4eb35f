"""Reading motions from bytes (an upload): the same motion as from the file, the same errors."""

from __future__ import annotations

import numpy as np
import pytest

from quatmotion.errors import FormatError
from quatmotion.io import decode_text, parse_motion, read_asf, read_motion, write_asf, write_motion
from quatmotion.synthetic import generate_clip


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bytes")
    clip = generate_clip("squat", 2, n_frames=40)
    write_motion(clip, folder / "squat_2.bvh")
    write_motion(clip, folder / "squat_2.amc")
    write_asf(clip.skeleton, folder / "squat.asf")
    return folder


def _same(a, b) -> None:
    assert a.name == b.name and a.fps == b.fps
    assert a.skeleton.joint_names == b.skeleton.joint_names
    np.testing.assert_array_equal(a.rotations, b.rotations)
    np.testing.assert_array_equal(a.root_translation, b.root_translation)


def test_bvh_bytes_give_the_files_motion(files):
    path = files / "squat_2.bvh"
    _same(parse_motion(path.read_bytes(), "squat_2.bvh"), read_motion(path))
    crlf = path.read_bytes().replace(b"\n", b"\r\n")
    _same(parse_motion(crlf, "squat_2.bvh"), read_motion(path))
    # A UTF-8 byte-order mark (Windows editors) is skipped in bytes as in files.
    _same(parse_motion(b"\xef\xbb\xbf" + path.read_bytes(), "squat_2.bvh"), read_motion(path))


def test_amc_bytes_with_asf_bytes_or_skeleton_give_the_files_motion(files):
    amc, asf = files / "squat_2.amc", files / "squat.asf"
    expected = read_motion(amc, asf)
    _same(parse_motion(amc.read_bytes(), "squat_2.amc", asf.read_bytes(), "squat.asf"), expected)
    _same(parse_motion(amc.read_bytes(), "squat_2.amc", read_asf(asf)), expected)
    with pytest.raises(FormatError, match=r"^squat_2\.amc: an AMC holds no skeleton"):
        parse_motion(amc.read_bytes(), "squat_2.amc")


def test_bad_bytes_get_the_file_readers_messages(files):
    text = (files / "squat_2.bvh").read_bytes()
    cut = text[: len(text) // 3]
    with pytest.raises(FormatError) as from_bytes:
        parse_motion(cut, "cut.bvh")
    (files / "cut.bvh").write_bytes(cut)
    with pytest.raises(FormatError) as from_file:
        read_motion(files / "cut.bvh")
    assert from_bytes.value.reason == from_file.value.reason
    assert from_bytes.value.line == from_file.value.line
    with pytest.raises(FormatError, match=r"^x\.bvh:2: not a text file \(byte 0x00\)"):
        parse_motion(b"HIERARCHY\nROOT\x00", "x.bvh")
    with pytest.raises(ValueError, match="unknown motion file type"):
        parse_motion(text, "x.c3d")
    with pytest.raises(ValueError, match="carries its own skeleton"):
        parse_motion(text, "x.bvh", (files / "squat.asf").read_bytes())
    assert decode_text(b"a\r\nb\rc", "t.txt") == "a\nb\nc"
