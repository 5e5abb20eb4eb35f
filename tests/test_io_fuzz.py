"""Mutated real files: the readers either succeed or raise FormatError, and never hang.

Each reader gets small real files (the first frames of a clip) damaged by truncation, byte
flips, line deletion or duplication, and token replacement. Any exception other than
:class:`quatmotion.FormatError` fails the test, as does an example slower than the deadline.
"""

from __future__ import annotations

import tempfile
from datetime import timedelta
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from quatmotion import FormatError
from quatmotion.datasets import data_root
from quatmotion.io import read_amc, read_asf, read_bvh
from quatmotion.motion import Motion, Skeleton

DATA = data_root(must_exist=False)

pytestmark = pytest.mark.needs_data
N_FRAMES = 50
FUZZ = settings(
    max_examples=60,
    deadline=timedelta(seconds=5),
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    database=None,
)
NASTY_TOKENS = [
    "",
    "nan",
    "-inf",
    "1e999",
    "-",
    "abc",
    "{",
    "}",
    "JOINT",
    "End",
    "MOTION",
    "Frames:",
    "begin",
    "end",
    ":bonedata",
    "root",
    "99999999999",
    "0x10",
    "1.5.2",
    "\u00e9",
    "CHANNELS",
    "-1",
]


def _head_of_amc(path: Path, frames: int) -> bytes:
    lines = path.read_bytes().split(b"\n")
    starts = [i for i, line in enumerate(lines) if line.strip().isdigit()]
    return b"\n".join(lines[: starts[frames]]) + b"\n"


def _head_of_bvh(path: Path, frames: int) -> bytes:
    text = path.read_bytes()
    head, body = text.split(b"MOTION", 1)
    lines = body.split(b"\n")
    frame_lines = lines[3 : 3 + frames]
    return (
        head + b"MOTION\nFrames: %d\n" % frames + lines[2] + b"\n" + b"\n".join(frame_lines) + b"\n"
    )


def _sources() -> dict[str, bytes]:
    if not DATA.is_dir():
        return {}
    amc = sorted(DATA.glob("cmu/*/*.amc"))[0]
    return {
        "asf": (amc.parent / (amc.stem.split("_")[0] + ".asf")).read_bytes(),
        "amc": _head_of_amc(amc, N_FRAMES),
        "bvh_bandai": _head_of_bvh(sorted(DATA.glob("bandai1/clips/*.bvh"))[0], N_FRAMES),
        "bvh_cmu": _head_of_bvh(sorted(DATA.glob("cmu_bvh/*/*.bvh"))[0], N_FRAMES),
    }


SOURCES = _sources()


@st.composite
def mutated(draw: st.DrawFn, original: bytes) -> bytes:
    data = original
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["truncate", "flip", "delete", "duplicate", "token"]))
        if kind == "truncate":
            data = data[: draw(st.integers(0, len(data)))]
        elif kind == "flip" and data:
            i = draw(st.integers(0, len(data) - 1))
            data = data[:i] + bytes([draw(st.integers(0, 255))]) + data[i + 1 :]
        elif kind in ("delete", "duplicate"):
            lines = data.split(b"\n")
            i = draw(st.integers(0, len(lines) - 1))
            lines[i : i + 1] = [] if kind == "delete" else [lines[i], lines[i]]
            data = b"\n".join(lines)
        elif kind == "token":
            tokens = data.split(b" ")
            i = draw(st.integers(0, len(tokens) - 1))
            tokens[i] = draw(st.sampled_from(NASTY_TOKENS)).encode("latin-1")
            data = b" ".join(tokens)
    return data


def _read_or_format_error(reader, data: bytes, suffix: str) -> object | None:
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / f"fuzz{suffix}"
        path.write_bytes(data)
        try:
            return reader(path)
        except FormatError as error:
            assert error.path == path
            assert str(path) in str(error)
            return None


def test_sources_are_valid():
    asf_skeleton = _read_or_format_error(read_asf, SOURCES["asf"], ".asf")
    assert isinstance(asf_skeleton, Skeleton)
    motion = _read_or_format_error(lambda p: read_amc(p, asf_skeleton), SOURCES["amc"], ".amc")
    assert isinstance(motion, Motion) and motion.n_frames == N_FRAMES
    for key in ("bvh_bandai", "bvh_cmu"):
        motion = _read_or_format_error(read_bvh, SOURCES[key], ".bvh")
        assert isinstance(motion, Motion) and motion.n_frames == N_FRAMES


@FUZZ
@given(st.data())
def test_fuzz_asf(data: st.DataObject):
    result = _read_or_format_error(read_asf, data.draw(mutated(SOURCES["asf"])), ".asf")
    assert result is None or isinstance(result, Skeleton)


@FUZZ
@given(st.data())
def test_fuzz_amc(data: st.DataObject):
    skeleton = _SKELETON.get("asf") or read_asf_cached()
    result = _read_or_format_error(
        lambda p: read_amc(p, skeleton), data.draw(mutated(SOURCES["amc"])), ".amc"
    )
    if result is not None:
        assert isinstance(result, Motion)
        assert np.isfinite(result.rotations).all() and np.isfinite(result.root_translation).all()


@FUZZ
@given(st.data(), st.sampled_from(["bvh_bandai", "bvh_cmu"]))
def test_fuzz_bvh(data: st.DataObject, source: str):
    result = _read_or_format_error(read_bvh, data.draw(mutated(SOURCES[source])), ".bvh")
    if result is not None:
        assert isinstance(result, Motion)
        assert np.isfinite(result.rotations).all() and np.isfinite(result.root_translation).all()


_SKELETON: dict[str, Skeleton] = {}


def read_asf_cached() -> Skeleton:
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "source.asf"
        path.write_bytes(SOURCES["asf"])
        _SKELETON["asf"] = read_asf(path)
    return _SKELETON["asf"]
