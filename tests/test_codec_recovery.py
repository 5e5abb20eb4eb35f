"""A damaged ``.qmz`` is partly recovered (issue 17, item 9): a flipped byte in a chunk or a
file cut short loses only the clips whose chunks (or the shared parts they need) are gone;
every other clip decodes bit for bit as from the whole file. Without ``recover`` a damaged
file still fails with a FormatError naming the file and the byte offset."""

from __future__ import annotations

import dataclasses
import io
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from quatmotion import codec
from quatmotion.cli import app
from quatmotion.codec.container import scan_chunks
from quatmotion.errors import FormatError
from quatmotion.synthetic import cmu_skeleton, generate_clip

N_CLIPS = 5


@pytest.fixture(scope="module")
def library(tmp_path_factory) -> tuple[bytes, list]:
    """Five clips on two skeleton structures (two layouts: clips 0-2 and 3-4), and their
    decode from the whole file."""
    base = cmu_skeleton()
    names = list(base.joint_names)
    names[-1] += "_other"
    other = dataclasses.replace(base, joint_names=tuple(names))
    clips = []
    for k in range(N_CLIPS):
        clip = generate_clip(("walk", "run")[k % 2], 10 + k, n_frames=40).renamed(f"clip{k}")
        clips.append(dataclasses.replace(clip, skeleton=other) if k >= 3 else clip)
    path = tmp_path_factory.mktemp("qmz") / "x.qmz"
    codec.Archive.build(clips, path, codec.CompressSettings(max_error=1.0))
    data = path.read_bytes()
    with codec.Archive.open(data) as archive:
        assert len(archive.header.layouts) == 2
        decoded = [archive.read_rotations(k) for k in range(N_CLIPS)]
    return data, decoded


def _chunks(data: bytes):
    return list(scan_chunks(io.BytesIO(data), Path("<bytes>"), len(data)))


def _clip_chunk(data: bytes, k: int):
    return [c for c in _chunks(data) if c.tag == b"C"][k]


def _flip(data: bytes, at: int) -> bytes:
    damaged = bytearray(data)
    damaged[at] ^= 0x5A
    return bytes(damaged)


def _check_recovered(archive, decoded, lost: set[int]) -> None:
    assert {d.index for d in archive.damaged} == lost
    assert {d.name for d in archive.damaged} == {f"clip{k}" for k in lost}
    for k in range(N_CLIPS):
        if k in lost:
            with pytest.raises(FormatError, match="damaged"):
                archive.read(k)
            continue
        root, rotations = archive.read_rotations(k)
        assert np.array_equal(root, decoded[k][0]) and np.array_equal(rotations, decoded[k][1])


@pytest.mark.parametrize("k", [0, 2, 4])
def test_flipped_byte_in_a_clip_chunk_loses_that_clip_only(library, k, tmp_path):
    data, decoded = library
    ref = _clip_chunk(data, k)
    damaged = _flip(data, ref.offset + ref.length // 2)
    path = tmp_path / "damaged.qmz"
    path.write_bytes(damaged)
    # Without recovery: the damaged clip fails naming the file and the chunk's byte offset.
    pattern = r"damaged\.qmz: checksum mismatch .* byte \d+"
    with codec.Archive.open(path) as archive, pytest.raises(FormatError, match=pattern):
        archive.read(k)
    with codec.Archive.open(path, recover=True) as archive:
        _check_recovered(archive, decoded, {k})
        assert "checksum mismatch" in archive.damaged[0].reason


def test_flipped_chunk_length_resynchronises(library):
    data, decoded = library
    ref = _clip_chunk(data, 1)
    length_byte = ref.offset - 1  # the last byte of the length varint (framing damaged)
    damaged = _flip(data, length_byte)
    with pytest.raises(FormatError, match="byte"):
        codec.Archive.open(damaged)
    with codec.Archive.open(damaged, recover=True) as archive:
        _check_recovered(archive, decoded, {1})


def test_flipped_tag_byte_of_a_clip_chunk(library):
    data, decoded = library
    ref = _clip_chunk(data, 3)
    damaged = _flip(data, ref.offset - len(ref.header_bytes))
    with pytest.raises(FormatError, match="unknown chunk tag .* at byte"):
        codec.Archive.open(damaged)
    with codec.Archive.open(damaged, recover=True) as archive:
        _check_recovered(archive, decoded, {3})


def test_truncated_in_the_last_chunk_keeps_the_whole_clips(library):
    data, decoded = library
    ref = _clip_chunk(data, N_CLIPS - 1)
    cut = data[: ref.offset + ref.length // 2]
    with pytest.raises(FormatError, match=r"<bytes>: truncated.* byte \d+"):
        codec.Archive.open(cut)
    with codec.Archive.open(cut, recover=True) as archive:
        _check_recovered(archive, decoded, {N_CLIPS - 1})
        assert "truncated" in archive.damaged[0].reason


def test_truncated_inside_a_layout_chunk_loses_the_clips_needing_it(library):
    data, decoded = library
    layouts = [c for c in _chunks(data) if c.tag == b"L"]
    cut = data[: layouts[1].offset + 3]
    with codec.Archive.open(cut, recover=True) as archive:
        # Layout 0 is whole but every clip chunk comes after the cut.
        _check_recovered(archive, decoded, set(range(N_CLIPS)))
        assert all("truncated" in d.reason for d in archive.damaged)


def test_flipped_byte_in_a_layout_chunk_loses_the_clips_of_that_layout(library):
    data, decoded = library
    ref = [c for c in _chunks(data) if c.tag == b"L"][1]
    damaged = _flip(data, ref.offset + ref.length // 3)
    with codec.Archive.open(damaged, recover=True) as archive:
        _check_recovered(archive, decoded, {3, 4})
    ref = [c for c in _chunks(data) if c.tag == b"S"][0]
    with codec.Archive.open(_flip(data, ref.offset + 1), recover=True) as archive:
        _check_recovered(archive, decoded, set(range(N_CLIPS)))  # the one skeleton record
        assert all("skeleton record 0" in d.reason for d in archive.damaged)


def test_a_damaged_header_is_refused_even_when_recovering(library):
    data, _ = library
    header = _chunks(data)[0]
    with pytest.raises(FormatError, match="header is damaged"):
        codec.Archive.open(_flip(data, header.offset + 2), recover=True)


def test_whole_file_has_nothing_damaged(library):
    data, decoded = library
    with codec.Archive.open(data, recover=True) as archive:
        _check_recovered(archive, decoded, set())


def test_cli_decompress_skip_damaged_and_ls(library, tmp_path):
    data, _ = library
    ref = _clip_chunk(data, 2)
    path = tmp_path / "damaged.qmz"
    path.write_bytes(_flip(data, ref.offset + 5))
    runner = CliRunner()
    out = tmp_path / "out"
    result = runner.invoke(app, ["decompress", str(path), "-o", str(out)])
    assert result.exit_code == 2
    assert "checksum mismatch" in result.output and "--skip-damaged" in result.output
    assert not out.exists() or not any(out.iterdir())  # nothing half-written
    wanted = [a for k in range(3) for a in ("--clip", f"clip{k}")]  # the first layout's
    result = runner.invoke(
        app, ["decompress", str(path), "-o", str(out), "--skip-damaged", *wanted]
    )
    assert result.exit_code == 1, result.output
    assert {p.stem for p in out.iterdir() if p.suffix == ".amc"} == {"clip0", "clip1"}
    assert "clip2" in result.output and "checksum mismatch" in result.output
    result = runner.invoke(app, ["ls", str(path)])
    assert result.exit_code == 1
    assert "clip2 (damaged)" in result.output and "1 damaged clip" in result.output
    result = runner.invoke(app, ["ls", str(path), "--json"])
    assert result.exit_code == 1
