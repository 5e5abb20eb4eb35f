"""Hostile glTF files (issue 30): a buffer uri reads nothing outside the glTF's folder and
nothing at all for an upload; every count, rate, duration, depth, offset and range a file
declares is refused before anything is allocated, with a FormatError naming the field."""

from __future__ import annotations

import base64
import copy
import json
import os
import struct
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from quatmotion import io, limits
from quatmotion.cli import app
from quatmotion.errors import FormatError
from quatmotion.io.gltf import gltf_bytes, parse_gltf, read_gltf
from quatmotion.synthetic import generate_clip

SECRET = b"root:x:0:0:root:/root:/bin/bash\n" * 64


@pytest.fixture(scope="module")
def document() -> dict:
    """A valid .gltf (31 joints, 5 frames at 30 frames/s) as JSON, its buffer a data URI."""
    return json.loads(gltf_bytes(generate_clip("walk", 1, n_frames=5), binary=False))


def _payload(document: dict) -> bytes:
    return base64.b64decode(document["buffers"][0]["uri"].split(",", 1)[1])


def _with_uri(document: dict, uri: str) -> dict:
    changed = copy.deepcopy(document)
    changed["buffers"][0]["uri"] = uri
    return changed


def _write(folder: Path, document: dict, name: str = "clip.gltf") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / name).write_text(json.dumps(document))
    return folder / name


# --- item 1: buffers in other files -----------------------------------------------------------


def test_a_buffer_beside_the_file_is_read(tmp_path, document):
    (tmp_path / "clip data.bin").write_bytes(_payload(document))
    external = read_gltf(_write(tmp_path, _with_uri(document, "clip%20data.bin")))
    embedded = parse_gltf(json.dumps(document).encode(), "clip.gltf")
    assert np.array_equal(external.rotations, embedded.rotations)


@pytest.mark.parametrize("kind", ["absolute", "dotdot", "encoded", "symlink", "file-url"])
def test_a_buffer_outside_the_folder_is_refused_and_its_existence_not_told(
    tmp_path, document, kind
):
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "secret.bin").write_bytes(SECRET)
    messages = []
    for name in ("secret.bin", "missing.bin"):
        uri = {
            "absolute": str(outside / name),
            "dotdot": f"../outside/{name}",
            "encoded": f"%2e%2e/outside/{name}",
            "symlink": f"link-{name}",
            "file-url": f"file://{outside / name}",
        }[kind]
        folder = tmp_path / "clip"
        if kind == "symlink":
            folder.mkdir(exist_ok=True)
            os.symlink(outside / name, folder / uri)
        gltf = _write(folder, _with_uri(document, uri))
        with pytest.raises(FormatError, match=r"buffers\[0\]\.uri must be a relative path") as e:
            read_gltf(gltf)
        messages.append(str(e.value))
    assert messages[0] == messages[1]  # the same words whether the file exists or not
    assert "root:" not in messages[0] and "secret" not in messages[0]


def test_an_upload_reads_no_other_file(tmp_path, document, monkeypatch):
    (tmp_path / "clip.bin").write_bytes(_payload(document))
    monkeypatch.chdir(tmp_path)  # where a relative name would be found
    for uri in ("clip.bin", "/etc/passwd", "../../../../etc/passwd"):
        data = json.dumps(_with_uri(document, uri)).encode()
        with pytest.raises(FormatError, match="not read for a glTF given as bytes"):
            io.parse_motion(data, "upload.gltf")


def test_a_device_or_a_pipe_is_no_buffer(tmp_path, document):
    os.mkfifo(tmp_path / "pipe.bin")
    os.symlink("/dev/zero", tmp_path / "zero.bin")
    started = time.monotonic()
    with pytest.raises(FormatError, match="not a regular file"):
        read_gltf(_write(tmp_path, _with_uri(document, "pipe.bin")))
    with pytest.raises(FormatError, match="must be a relative path inside"):
        read_gltf(_write(tmp_path, _with_uri(document, "zero.bin")))
    assert time.monotonic() - started < 60  # a blocking open() would hang here


def test_a_buffer_file_is_read_no_further_than_its_byte_length(tmp_path, document, monkeypatch):
    payload = _payload(document)
    (tmp_path / "clip.bin").write_bytes(payload + b"\0" * (1 << 20))
    read = []
    real_read = io.gltf.document.os.fdopen

    def spy(*args, **kwargs):
        file = real_read(*args, **kwargs)
        original = file.read
        file.read = lambda n=-1: read.append(n) or original(n)
        return file

    monkeypatch.setattr(io.gltf.document.os, "fdopen", spy)
    read_gltf(_write(tmp_path, _with_uri(document, "clip.bin")))
    assert read == [len(payload)]
    huge = _with_uri(document, "clip.bin")
    huge["buffers"][0]["byteLength"] = 1 << 40
    with pytest.raises(FormatError, match=r"buffers\[0\]\.byteLength is 1,099,511,627,776 bytes"):
        read_gltf(_write(tmp_path, huge))


def test_convert_copies_nothing_from_outside(tmp_path, document):
    (tmp_path / "secret.bin").write_bytes(SECRET)
    gltf = _write(tmp_path / "clip", _with_uri(document, "../secret.bin"))
    out = tmp_path / "out.bvh"
    result = CliRunner().invoke(app, ["convert", str(gltf), str(out)])
    assert result.exit_code == 2, result.output
    assert result.output.count("error:") == 1 and not out.exists()


# --- item 5: no bounds --------------------------------------------------------------------------


def _animation_times(document: dict, times: np.ndarray) -> dict:
    """The document with its keyframe times replaced (one accessor shared by every sampler)
    and values to match (rest rotations, zero translations), its fps hint removed."""
    changed = copy.deepcopy(document)
    payload = bytearray(_payload(changed))

    def append(array: np.ndarray, kind: str) -> int:
        raw = np.ascontiguousarray(array, dtype="<f4").tobytes()
        view = {"buffer": 0, "byteOffset": len(payload), "byteLength": len(raw)}
        payload.extend(raw)
        changed["bufferViews"].append(view)
        changed["accessors"].append(
            {"bufferView": len(changed["bufferViews"]) - 1, "componentType": 5126}
            | {"count": len(array), "type": kind}
        )
        return len(changed["accessors"]) - 1

    time_accessor = append(times, "SCALAR")
    rest = append(np.tile([0.0, 0.0, 0.0, 1.0], (len(times), 1)), "VEC4")
    still = append(np.zeros((len(times), 3)), "VEC3")
    anim = changed["animations"][0]
    anim.pop("extras", None)
    for sampler in anim["samplers"]:
        kind = changed["accessors"][sampler["output"]]["type"]
        sampler["input"], sampler["output"] = time_accessor, rest if kind == "VEC4" else still
    changed["buffers"][0] = {
        "byteLength": len(payload),
        "uri": "data:application/octet-stream;base64," + base64.b64encode(payload).decode(),
    }
    return changed


def _refused(data: dict | bytes, match: str) -> FormatError:
    raw = data if isinstance(data, bytes) else json.dumps(data).encode()
    started = time.process_time()
    with pytest.raises(FormatError, match=match) as caught:
        io.parse_motion(raw, "hostile.gltf")
    assert time.process_time() - started < 5
    assert str(caught.value).startswith("hostile.gltf: ")
    return caught.value


def test_a_frame_rate_of_a_billion_is_refused(document):
    changed = copy.deepcopy(document)
    changed["animations"][0]["extras"]["fps"] = 1e9
    _refused(changed, r"animations\[0\]\.extras\.fps is 1,000,000,000 frames/s, over the limit")
    for fps in (0, -30, [30]):
        changed["animations"][0]["extras"]["fps"] = fps
        _refused(changed, r"animations\[0\]\.extras\.fps is")


def test_keyframes_over_hours_are_refused(document):
    hours = np.array([0.0, 1 / 30, 2 / 30, 1e4])  # 30 frames/s by the median step
    _refused(_animation_times(document, hours), r"frames x joints is 9,300,031 joint-frames")
    _refused(_animation_times(document, hours * 1000), "duration")
    assert (
        io.parse_motion(
            json.dumps(_animation_times(document, np.array([0, 1 / 30, 2 / 30, 100]))).encode(),
            "minutes.gltf",
        ).n_frames
        == 3001
    )


def test_a_tiny_time_step_is_refused(document):
    _refused(_animation_times(document, np.array([0.0, 1e-7, 2e-7])), "frame rate")


def test_a_count_of_a_billion_is_refused(document):
    changed = copy.deepcopy(document)
    sampler = changed["animations"][0]["samplers"][0]
    for accessor in (sampler["input"], sampler["output"]):
        changed["accessors"][accessor].pop("bufferView")
        changed["accessors"][accessor]["count"] = 10**9
    _refused(changed, "keyframes up to animations")


def test_deep_json_is_refused_before_parsing():
    _refused(
        b'{"asset": {"version": "2.0"}, "x": ' + b"[" * 100_000 + b"]" * 100_000 + b"}",
        "nesting depth is 100,001 levels",
    )


def test_a_hundred_thousand_nodes_read_in_linear_time(document):
    changed = copy.deepcopy(document)
    base = len(changed["nodes"])
    many = 100_000
    changed["nodes"] += [{"name": "same"} for _ in range(many)]  # end sites of one joint
    changed["nodes"][1].setdefault("children", []).extend(range(base, base + many))
    started = time.process_time()
    motion = io.parse_motion(json.dumps(changed).encode(), "many.gltf")
    assert motion.skeleton.n_sites >= many and time.process_time() - started < 20
    changed["skins"][0]["joints"] = list(range(base + many))
    _refused(changed, r"the skeleton's joints is 100,0\d\d joints, over the limit")


def test_a_glb_without_its_json_chunk_is_refused(document):
    glb = gltf_bytes(generate_clip("walk", 1, n_frames=3), binary=True)
    (json_length,) = struct.unpack_from("<I", glb, 12)
    without = glb[:12] + glb[20 + json_length :]
    without = without[:8] + struct.pack("<I", len(without)) + without[12:]
    _refused(without, "is not its JSON chunk")
    cut = glb[:8] + struct.pack("<III", 28, 1 << 31, 0x4E4F534A) + b"{}      "
    _refused(cut, "the GLB chunk at byte 12 runs past the file's end")
    _refused(glb[:8] + struct.pack("<I", 1 << 31) + glb[12:], "the GLB header says")


def test_a_channel_without_a_target_is_refused(document):
    changed = copy.deepcopy(document)
    del changed["animations"][0]["channels"][3]["target"]
    _refused(changed, r"animations\[0\]\.channels\[3\]\.target is missing")


def test_negative_offsets_and_ranges_out_of_the_buffer_are_refused(document):
    sampler = document["animations"][0]["samplers"][0]
    accessor = sampler["output"]
    view = document["accessors"][accessor]["bufferView"]
    for owner, key, value, match in [
        ("accessors", "byteOffset", -16, r"accessors\[\d+\]\.byteOffset is -16"),
        ("bufferViews", "byteOffset", -16, r"bufferViews\[\d+\]\.byteOffset is -16"),
        ("bufferViews", "byteLength", 1 << 40, "runs past the end of its buffer"),
        ("bufferViews", "byteStride", 2, r"byteStride is 2"),
        ("accessors", "byteOffset", 1 << 20, "reads bytes"),
        ("accessors", "componentType", True, "componentType"),
    ]:
        changed = copy.deepcopy(document)
        index = accessor if owner == "accessors" else view
        changed[owner][index][key] = value
        _refused(changed, match)


@pytest.mark.parametrize(
    ("where", "value", "match"),
    [
        (("nodes", 0, "children"), [-1], r"nodes\[0\]\.children is not a list of node"),
        (("nodes", 0, "rotation"), ["a", 0, 0, 1], r"nodes\[0\]\.rotation is not 4 finite"),
        (("nodes", 0, "translation"), [1, 2], r"nodes\[0\]\.translation is not 3"),
        (("nodes", 1, "rotation"), [0, 0, 0, 0], r"nodes\[1\]\.rotation is zero"),
        (("skins", 0, "joints"), [0, -1], r"skins\[0\]\.joints is not a list"),
        (("animations", 0, "samplers"), {}, "samplers is not a list of objects"),
        (("buffers", 0, "uri"), 7, r"buffers\[0\]\.uri is not a string"),
    ],
)
def test_fields_of_the_wrong_type_are_refused_naming_them(document, where, value, match):
    changed = copy.deepcopy(document)
    owner, index, key = where
    changed[owner][index][key] = value
    _refused(changed, match)


def test_a_cycle_above_the_root_is_refused(document):
    changed = copy.deepcopy(document)
    n = len(changed["nodes"])
    changed["nodes"] += [{"children": [n + 1, 0]}, {"children": [n]}]  # n and n + 1: a loop
    _refused(changed, "ancestors form a cycle")


def test_limits_raised_read_what_they_refuse(document):
    changed = copy.deepcopy(document)
    changed["animations"][0]["extras"]["fps"] = 20_000
    _refused(changed, "over the limit")
    with limits.raised(fps=50_000):
        assert io.parse_motion(json.dumps(changed).encode(), "fast.gltf").fps == 20_000


def test_zero_quaternions_are_refused(document):
    changed = copy.deepcopy(document)
    rotation = next(
        s["output"]
        for s in changed["animations"][0]["samplers"]
        if changed["accessors"][s["output"]]["type"] == "VEC4"
    )
    del changed["accessors"][rotation]["bufferView"]  # all zeros, as the specification says
    _refused(changed, "output holds a zero quaternion")


def test_huge_quaternion_components_are_read_as_the_rotation_they_are(document):
    """A norm of 1e308-sized components overflows: they are scaled first (a fuzz finding)."""
    changed = copy.deepcopy(document)
    changed["nodes"][1]["rotation"] = [1e308, 0.0, 0.0, 1e308]  # x y z w: 90 degrees about x
    anim = changed["animations"][0]
    anim["channels"] = [c for c in anim["channels"] if c["target"]["node"] != 1]
    motion = io.parse_motion(json.dumps(changed).encode(), "huge.gltf")
    assert np.isfinite(motion.rotations).all()
    half = np.sqrt(0.5)
    assert np.allclose(motion.rotations[:, 1], [half, half, 0.0, 0.0])  # w x y z, the rest
