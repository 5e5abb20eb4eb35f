"""``quatmotion compress | ls | decompress | append`` through Typer's CliRunner."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from quatmotion.cli import app
from quatmotion.io import read_motion, write_bvh
from quatmotion.motion import forward_kinematics
from quatmotion.synthetic import generate_clip

runner = CliRunner()


def _invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def test_compress_ls_decompress_append(tmp_path: Path):
    src = tmp_path / "src"
    src.mkdir()
    clips = [generate_clip("walk", 1, n_frames=80), generate_clip("run", 2, n_frames=70)]
    for clip in clips:
        write_bvh(clip, src / f"{clip.name}.bvh")
    lib = tmp_path / "lib.qmz"
    result = _invoke("compress", src / f"{clips[0].name}.bvh", "-o", lib, "--max-error", "2")
    assert result.exit_code == 0, result.output
    result = _invoke("append", lib, src / f"{clips[1].name}.bvh", "--max-error", "2")
    assert result.exit_code == 0, result.output
    result = _invoke("ls", lib)
    assert (
        result.exit_code == 0 and clips[0].name in result.output and clips[1].name in result.output
    )
    out = tmp_path / "out"
    result = _invoke("decompress", lib, "-o", out, "--clip", clips[1].name)
    assert result.exit_code == 0, result.output
    assert [p.name for p in out.iterdir()] == [f"{clips[1].name}.bvh"]
    back = read_motion(out / f"{clips[1].name}.bvh")
    original = read_motion(src / f"{clips[1].name}.bvh")
    assert back.n_frames == original.n_frames and back.fps == original.fps
    err = np.linalg.norm(
        forward_kinematics(back).all_positions() - forward_kinematics(original).all_positions(),
        axis=-1,
    )
    assert err.max() <= 2.0 + 1e-6  # 10-digit text on both sides


def test_bad_input_is_one_line_and_exit_2(tmp_path: Path):
    out = tmp_path / "x.qmz"
    for args in (
        ("compress", tmp_path / "missing.bvh", "-o", out),
        ("compress", tmp_path, "-o", out, "--method", "zip"),
        ("compress", tmp_path, "-o", out, "--max-error", "1", "--ratio", "10"),
        ("ls", tmp_path / "missing.qmz"),
    ):
        result = _invoke(*args)
        assert result.exit_code == 2, (args, result.output)
        assert result.output.count("error:") == 1 and "Traceback" not in result.output
    garbage = tmp_path / "garbage.qmz"
    garbage.write_bytes(b"not a library at all")
    result = _invoke("ls", garbage)
    assert result.exit_code == 2 and "magic" in result.output
    assert not out.exists()


def test_a_bad_file_is_reported_and_skipped_and_the_exit_code_is_1(tmp_path: Path):
    src = tmp_path / "src"
    src.mkdir()
    clips = [generate_clip("walk", 1, n_frames=60), generate_clip("kick", 2, n_frames=50)]
    for clip in clips:
        write_bvh(clip, src / f"{clip.name}.bvh")
    text = (src / f"{clips[0].name}.bvh").read_text()
    (src / "broken.bvh").write_text(text[: len(text) // 2])  # truncated mid-frame
    lib = tmp_path / "lib.qmz"
    result = _invoke("compress", src, "-o", lib, "--max-error", "2", "--workers", "2")
    assert result.exit_code == 1, result.output
    assert "skipped" in result.stderr and "broken.bvh" in result.stderr
    listing = _invoke("ls", lib)
    assert all(clip.name in listing.output for clip in clips)
    assert "broken" not in listing.output
    # the output exists now: replacing it needs --force
    again = _invoke("compress", src / f"{clips[0].name}.bvh", "-o", lib)
    assert again.exit_code == 2 and "--force" in again.stderr
    forced = _invoke("compress", src / f"{clips[0].name}.bvh", "-o", lib, "--force")
    assert forced.exit_code == 0, forced.output


def test_append_codes_new_clips_at_the_bound_the_library_was_made_with(tmp_path: Path):
    """No --max-error: the file's own bound (0.1 cm here), not 1 cm; given, it applies to the
    new clips and the file keeps the settings it was made with."""
    import json

    clips = [generate_clip(kind, seed, n_frames=60) for kind, seed in (("walk", 1), ("run", 2))]
    clips.append(generate_clip("walk", 3, n_frames=60))
    files = []
    for clip in clips:
        files.append(tmp_path / f"{clip.name}.bvh")
        write_bvh(clip, files[-1])
    lib = tmp_path / "lib.qmz"
    result = _invoke("compress", files[0], "-o", lib, "--max-error", "0.1")
    assert result.exit_code == 0, result.output
    result = _invoke("append", lib, files[1])
    assert result.exit_code == 0, result.output
    assert "every joint within 0.1 cm" in result.stdout
    result = _invoke("append", lib, files[2], "--max-error", "3")
    assert result.exit_code == 0, result.output
    assert "every joint within 3 cm" in result.stdout
    doc = json.loads(_invoke("ls", lib, "--json").stdout)
    assert doc["settings"]["max_error"] == 0.1
    errors = {c["name"]: c["max_error_cm"] for c in doc["clips"]}
    assert errors[clips[1].name] <= 0.1 + 1e-9
    assert errors[clips[2].name] > 0.1  # coded at 3 cm: far coarser than the file's bound
    for clip, bound in ((clips[1], 0.1), (clips[2], 3.0)):  # what was declared, measured
        out = tmp_path / f"out_{clip.name}"
        assert _invoke("decompress", lib, "-o", out, "--clip", clip.name).exit_code == 0
        back, original = (
            read_motion(out / f"{clip.name}.bvh"),
            read_motion(tmp_path / f"{clip.name}.bvh"),
        )
        err = np.linalg.norm(
            forward_kinematics(back).all_positions() - forward_kinematics(original).all_positions(),
            axis=-1,
        )
        assert err.max() <= bound + 1e-4


def test_every_writing_command_ends_with_one_wrote_line_on_stdout(tmp_path: Path):
    """The success line is the same everywhere: ``wrote PATH...`` as stdout's last line; and
    ``compress --ratio`` (no bound asked) does not say an error bound holds."""
    clip = generate_clip("walk", 1, n_frames=60)
    bvh = tmp_path / "walk.bvh"
    write_bvh(clip, bvh)
    other = tmp_path / "run.bvh"
    write_bvh(generate_clip("run", 2, n_frames=60), other)
    steps = [
        (("convert", bvh, tmp_path / "c.bvh"), tmp_path / "c.bvh"),
        (("generate", "walk", tmp_path / "g.bvh", "--frames", "30"), tmp_path / "g.bvh"),
        (("view", bvh, "-o", tmp_path / "v.html"), tmp_path / "v.html"),
        (("compress", bvh, "-o", tmp_path / "r.qmz", "--ratio", "5"), tmp_path / "r.qmz"),
        (("append", tmp_path / "r.qmz", other), tmp_path / "r.qmz"),
        (("decompress", tmp_path / "r.qmz", "-o", tmp_path / "d"), tmp_path / "d"),
        (("index", "build", bvh, "-o", tmp_path / "i.qidx", "--workers", "1"), tmp_path / "i.qidx"),
        (("index", "add", tmp_path / "i.qidx", other, "--workers", "1"), tmp_path / "i.qidx"),
    ]
    for args, out in steps:
        result = _invoke(*args)
        assert result.exit_code == 0, (args, result.output)
        last = result.stdout.strip().splitlines()[-1]
        assert last.startswith("wrote ") and str(out) in last, (args, result.stdout)
        assert out.exists()
        if args[0] == "compress":
            assert "error bound" not in result.stdout and "errors are measured" in result.stdout


@pytest.mark.needs_data
def test_a_renamed_cmu_skeleton_decompresses_to_asf_amc_under_its_own_names(tmp_path: Path):
    """Issue 29 item 11: a studio's names on CMU's skeleton (the last joint, then every one)
    once failed with "no joint 'rthumb'" (the ASF/AMC writers took the names the ASF was read
    with). The writers follow the skeleton's names; the clip comes back within the bound."""
    import dataclasses

    from quatmotion.codec import Archive, CompressSettings
    from quatmotion.datasets import data_root

    original = read_motion(data_root() / "cmu" / "02" / "02_01.amc").slice(0, 60)
    sk = original.skeleton
    for renamed in (
        (*sk.joint_names[:-1], "thumb_R"),
        ("root", *(f"Bone{k:02d}_{n.upper()}" for k, n in enumerate(sk.joint_names[1:]))),
    ):
        motion = dataclasses.replace(
            original, skeleton=dataclasses.replace(sk, joint_names=renamed)
        ).renamed("studio")
        lib = tmp_path / f"{renamed[-1]}.qmz"
        Archive.build([motion], lib, CompressSettings(max_error=0.5))
        out = tmp_path / f"out_{renamed[-1]}"
        result = _invoke("decompress", lib, "-o", out)
        assert result.exit_code == 0, result.output
        back = read_motion(out / "studio.amc")  # its ASF beside it, written by quatmotion
        assert back.skeleton.joint_names == renamed
        err = np.linalg.norm(
            forward_kinematics(back).all_positions() - forward_kinematics(original).all_positions(),
            axis=-1,
        )
        assert err.max() <= 0.5 + 1e-4


def test_the_asf_writers_refuse_a_skeleton_that_is_no_longer_its_asf():
    """Joints renamed are written under their new names; other parents, or a name an ASF
    cannot hold, are a ValueError naming the problem, never a KeyError from inside."""
    import dataclasses

    from quatmotion.io import asf_text, parse_asf

    sk = generate_clip("walk", 0, n_frames=2).skeleton
    renamed = dataclasses.replace(sk, joint_names=(*sk.joint_names[:-1], "tip"))
    assert parse_asf(asf_text(renamed), "x.asf").joint_names == renamed.joint_names
    spaced = dataclasses.replace(sk, joint_names=(*sk.joint_names[:-1], "left tip"))
    with pytest.raises(ValueError, match="cannot be written"):
        asf_text(spaced)
    parents = sk.parents.copy()
    parents[-1] = 0
    moved = dataclasses.replace(sk, parents=parents)
    with pytest.raises(ValueError, match="not the .* bones of the ASF"):
        asf_text(moved)
