"""Skeletons of 200,000 joints (issue 30): every reader, and a ``.qmz`` storing one, refuses
them at the joints limit (``quatmotion.limits``) within seconds, counting before it converts
or allocates (a stored skeleton of 200,000 joints took over 60 s). Raised limits read large
hierarchies in linear time: ``test_io_text_hostile.py`` and ``test_io_gltf_hostile.py``.

Time is the process's CPU time (the machine is shared: wall time is not the code's), bounded
generously; FBX (ufbx, C) is read in a child process, where a crash is a signal.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import sys
import time
from pathlib import Path

import pytest

from quatmotion import io
from quatmotion.codec import Archive
from quatmotion.codec.container import write_container
from quatmotion.codec.skeletons import RECORD_ASF, RECORD_BVH, RECORD_EXACT, deflate_text
from quatmotion.errors import FormatError
from quatmotion.io.gltf import gltf_bytes
from quatmotion.synthetic import generate_clip

sys.path.insert(0, str(Path(__file__).parent))
sys.path.insert(0, str(Path(__file__).parent / "fuzz"))
import mutants  # noqa: E402 (the corpus beside this file)
from fuzz_corpus import ascii_fbx  # noqa: E402
from test_io_text_hostile import flat_asf, flat_bvh  # noqa: E402

JOINTS = 200_000
SECONDS = 10.0
"""CPU seconds a refusal may take (under one on a quiet machine)."""


def _refused_in_time(read, name: str) -> FormatError:
    started = time.process_time()
    with pytest.raises(FormatError, match=r"joints, over the limit of 10,000") as caught:
        read()
    assert time.process_time() - started < SECONDS
    assert str(caught.value).startswith(name)
    return caught.value


def _exact_text(joints: int) -> str:
    """A stored skeleton's exact record (JSON of every field) of ``joints`` joints."""
    fields = {
        "joint_names": {"__tuple__": [f"j{k}" for k in range(joints)]},
        "parents": {"__array__": [-1] + [0] * (joints - 1), "dtype": "<i8"},
        "offsets": {"__array__": [[0.0, 1.0, 0.0]] * joints, "dtype": "<f8"},
        "channels": {"__tuple__": [{"__tuple__": ["rz", "rx", "ry"]}] * joints},
        "euler": "intrinsic",
    }
    return json.dumps({"__dict__": fields})


def test_text_readers_refuse_200k_joints_in_seconds():
    _refused_in_time(lambda: io.parse_motion(flat_bvh(JOINTS).encode(), "w.bvh"), "w.bvh")
    _refused_in_time(lambda: io.parse_asf(flat_asf(JOINTS), "w.asf"), "w.asf")


def test_gltf_refuses_200k_joints_in_seconds():
    document = json.loads(gltf_bytes(generate_clip("walk", 1, n_frames=5), binary=False))
    base = len(document["nodes"])
    changed = copy.deepcopy(document)
    changed["nodes"] += [{"name": f"n{k}"} for k in range(JOINTS)]
    changed["nodes"][1].setdefault("children", []).extend(range(base, base + JOINTS))
    changed["skins"][0]["joints"] = list(range(base + JOINTS))
    data = json.dumps(changed).encode()
    _refused_in_time(lambda: io.parse_motion(data, "w.gltf"), "w.gltf")


def test_fbx_refuses_200k_joints_before_ufbx_reads_them(tmp_path):
    """ufbx builds every node of a file before one can be counted (7 s for these 57 MB): the
    node records are counted in the bytes first."""
    path = tmp_path / "w.fbx"
    path.write_bytes(ascii_fbx(JOINTS, chain=False))
    (outcome,) = mutants.run_commands([["info", str(path)]])
    assert outcome.problem() is None, outcome.problem()
    assert outcome.returncode == 2 and "w.fbx" in outcome.stderr
    assert "over the limit of 10,000" in outcome.stderr
    assert outcome.seconds < 30  # wall time, the file read and counted (CPU 0.5 s)


@pytest.fixture(scope="module")
def small_qmz(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("qmz")
    clip = folder / "walk.bvh"
    io.write_bvh(generate_clip("walk", 1, n_frames=30), clip)
    out = folder / "walk.qmz"
    result = mutants.run_commands([["compress", str(clip), "-o", str(out), "--workers", "1"]])
    assert result[0].returncode == 0, result[0].stderr
    return out


STORED = {
    "asf": (RECORD_ASF, lambda: flat_asf(JOINTS)),
    "bvh": (RECORD_BVH, lambda: flat_bvh(JOINTS)),
    "exact": (RECORD_EXACT, lambda: _exact_text(JOINTS)),
}


@pytest.mark.parametrize("kind", sorted(STORED))
def test_a_stored_skeleton_of_200k_joints_is_refused_in_seconds(small_qmz, tmp_path, kind):
    record, make = STORED[kind]
    with Archive.open(small_qmz) as archive:
        header = archive.header
        _, layouts, clips = archive.payloads()
    stored = dataclasses.replace(header.records[0], kind=record, scale=1.0)
    header = dataclasses.replace(header, records=(stored,))
    bad = tmp_path / "huge.qmz"
    with open(bad, "wb") as fh:
        write_container(fh, header, [deflate_text(make())], layouts, clips)

    def read():
        with Archive.open(bad) as archive:
            archive.read(0)

    error = _refused_in_time(read, str(bad))
    assert "stored skeleton" in str(error)
    (outcome,) = mutants.run_commands([["decompress", str(bad), "-o", str(tmp_path / "out")]])
    assert outcome.problem() is None and outcome.returncode == 2, outcome.stderr
    assert "huge.qmz" in outcome.stderr and not (tmp_path / "out").exists()
