"""Crafted FBX files (issue 30): ufbx is C, so every file runs through the commands in a child
process, where a crash is a signal (a negative return code), never a lost test run. Truncated
files, huge counts, deep nesting, many takes, a frame range of a billion, rates that are NaN,
zero, negative or huge: one ``error:`` line and exit 2 each, refused before a frame is sampled;
a file of many takes is read (its first take)."""

from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

import pytest

from quatmotion import limits

sys.path.insert(0, str(Path(__file__).parent))
sys.path.insert(0, str(Path(__file__).parent / "fuzz"))
import mutants  # noqa: E402 (the runner beside this file)
from fuzz_corpus import HOSTILE_FBX, ascii_fbx  # noqa: E402

pytest.importorskip("ufbx")
FIXTURE = Path(__file__).parent / "data" / "fbx" / "cmu_mixamo.fbx"


def _binary_mutants() -> dict[str, bytes]:
    """The Blender fixture cut short, and with 32-bit fields made huge (a node record's end
    offset, property and array counts: every 4 bytes of its first kilobytes set to 2^31)."""
    data = FIXTURE.read_bytes()
    out = {f"cut_{n}": data[:n] for n in (27, 100, 1000, len(data) // 2, len(data) - 1)}
    for at in range(27, 1500, 97):
        out[f"count_{at}"] = data[:at] + (2**31).to_bytes(4, "little") + data[at + 4 :]
    return out


def test_crafted_fbx_files_end_in_one_error_line_in_every_command(tmp_path):
    files = {name: make() for name, make in HOSTILE_FBX.items() if name != "joints_200k"}
    files |= _binary_mutants()
    commands = []
    for name, data in files.items():
        path = tmp_path / f"{name}.fbx"
        path.write_bytes(data)
        commands += [["info", str(path)], ["convert", str(path), str(tmp_path / f"{name}.bvh")]]
    outcomes = mutants.run_commands(commands)
    problems = [p for o in outcomes if (p := o.problem()) is not None]
    assert not problems, "\n".join(problems[:5])
    assert len(outcomes) == len(commands)
    for o in outcomes:
        name = Path(o.args[1]).stem
        if name in HOSTILE_FBX:  # crafted: refused, naming the file
            assert o.returncode == 2 and f"{name}.fbx" in o.stderr, (o.args, o.stderr)
    written = {p.stem for p in tmp_path.glob("*.bvh")}
    read = {Path(o.args[1]).stem for o in outcomes if o.args[0] == "convert" and o.returncode == 0}
    assert written == read  # nothing half-written by a command that failed


def test_many_takes_are_listed_and_the_first_read(tmp_path):
    path = tmp_path / "takes.fbx"
    path.write_bytes(ascii_fbx(3, takes=2000))
    (outcome,) = mutants.run_commands([["info", str(path), "--json"]])
    assert outcome.problem() is None and outcome.returncode == 0, outcome.stderr
    assert "2000 takes" in outcome.stderr


def test_frame_limits_hold_before_any_frame_is_sampled():
    """A take of 2,000,001 frames refused in milliseconds (sampled, each frame costs ufbx an
    evaluation of every node: minutes); raised limits read a long take."""
    from quatmotion.errors import FormatError
    from quatmotion.io.fbx import parse_fbx

    started = time.process_time()
    with pytest.raises(FormatError, match=r"frames is 2,000,001 frames, over the limit"):
        parse_fbx(HOSTILE_FBX["frames_2e6"](), "long.fbx")
    with limits.raised(joint_frames=100), pytest.raises(FormatError, match="nodes x frames"):
        parse_fbx(ascii_fbx(4), "long.fbx")
    assert time.process_time() - started < 5
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        motion = parse_fbx(ascii_fbx(2, seconds=(0.0, 100.0)), "long.fbx")
    assert motion.n_frames == 3001 and motion.fps == 30.0


_KEEP_ERRORS = """
import gc, sys, warnings
sys.path.insert(0, sys.argv[1])
from fuzz_corpus import HOSTILE_FBX, ascii_fbx
from quatmotion.errors import FormatError
from quatmotion.io.fbx import fbx_takes, parse_fbx
warnings.simplefilter("ignore")
kept = []
for data in (HOSTILE_FBX["depth_300"](), HOSTILE_FBX["fps_nan"](), ascii_fbx(3)[:-40]):
    for read in (parse_fbx, fbx_takes):
        try:
            read(data, "x.fbx")
        except FormatError as error:
            kept.append(error)  # its traceback, its frames, what they held
        gc.collect()
print(len(kept), "kept", flush=True)
"""


def test_an_error_kept_after_its_scene_was_freed_crashes_nothing():
    """A refused file's error, kept (as a CLI test runner keeps it) with its traceback: the
    frames it holds held the scene and its nodes, which the cycle collector then visited after
    the scene was freed (a segmentation fault: a finding of these crafted files)."""
    import subprocess

    done = subprocess.run(
        [sys.executable, "-c", _KEEP_ERRORS, str(Path(__file__).parent / "fuzz")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, f"exit {done.returncode}: {done.stderr[-2000:]}"
    assert "kept" in done.stdout
