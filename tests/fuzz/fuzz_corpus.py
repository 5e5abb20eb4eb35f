"""The fuzz corpus: seed files for each reader and the mutations applied to them.

Seeds are the heads of real files from the shared data (when present), files the writers make
from generated clips, and the hostile files of issue 30 (a hierarchy wide or deep beyond the
limits, counts and rates of a billion, deep JSON, buffers outside the folder). Mutations take a
:class:`random.Random`, so the suite's Hypothesis tests (``st.randoms()``, shrinkable) and the
long runs of ``make fuzz`` (a seeded generator) share them.
"""

from __future__ import annotations

import base64
import copy
import json
import random
import re
import struct
from functools import cache
from pathlib import Path
from typing import Any

from quatmotion import io
from quatmotion.datasets import data_root
from quatmotion.synthetic import generate_clip

DATA = data_root(must_exist=False)
N_FRAMES = 20
READERS = ("bvh", "asf", "amc", "gltf", "glb", "qmz", "qidx")
ISOLATED = ("fbx", "pose")
"""Readers of C or C++ code (ufbx, hnswlib): fuzzed in a process of their own, where a crash is
a finding."""
OWN = ("qmz", "qidx", "pose")
"""quatmotion's own files: seeds, mutations and readers in ``fuzz_files``."""
FBX_SEEDS = ("bandai_bvh_names.fbx", "cmu_mixamo.fbx")  # tests/data/fbx, made by Blender
NASTY_TOKENS = [
    "", "nan", "-inf", "1e999", "-", "abc", "{", "}", "JOINT", "End", "Site", "ROOT", "MOTION",
    "Frames:", "Frame Time:", "begin", "end", ":bonedata", ":hierarchy", ":units", "root",
    "99999999999", "1000000000", "0x10", "1.5.2", "\u00e9", "CHANNELS", "-1", "0", "1e-300",
    "length", "dof", "axis", "XYZ", "rx", ":DEGREES",
]  # fmt: skip
NASTY_VALUES: list[Any] = [
    None, True, -1, 0, 1, 2**31, 2**53, 10**9, -(2**40), 1e308, -1e-300, float("nan"),
    float("inf"), "", "x", "../../etc/passwd", "/dev/zero", "data:;base64,!!", [], [0], [-1],
    [1e9, 0, 0], {}, {"node": 0}, [[[[]]]],
]  # fmt: skip


def _head_of_amc(path: Path, frames: int) -> bytes:
    lines = path.read_bytes().split(b"\n")
    starts = [i for i, line in enumerate(lines) if line.strip().isdigit()]
    return b"\n".join(lines[: starts[frames]]) + b"\n"


def _head_of_bvh(path: Path, frames: int) -> bytes:
    head, body = path.read_bytes().split(b"MOTION", 1)
    lines = body.split(b"\n")
    return (
        head
        + b"MOTION\nFrames: %d\n" % frames
        + lines[2]
        + b"\n"
        + b"\n".join(lines[3 : 3 + frames])
        + b"\n"
    )


def _wide_bvh(joints: int) -> bytes:
    body = "".join(f"JOINT j{k}\n{{\nOFFSET 1 2 3\n}}\n" for k in range(joints))
    return (
        "HIERARCHY\nROOT hips\n{\nOFFSET 0 0 0\nCHANNELS 6 Xposition Yposition Zposition "
        f"Zrotation Xrotation Yrotation\n{body}}}\nMOTION\nFrames: 1\nFrame Time: 0.0333333\n"
        "0 0 0 0 0 0\n"
    ).encode()


@cache
def generated() -> dict[str, bytes]:
    """Files the writers make of a generated clip (no data folder needed)."""
    import tempfile

    clip = generate_clip("walk", 3, n_frames=N_FRAMES)
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder)
        io.write_bvh(clip, out / "clip.bvh")
        io.write_amc(clip, out / "clip.amc")
        io.write_asf(clip.skeleton, out / "clip.asf")
        return {
            "bvh": (out / "clip.bvh").read_bytes(),
            "amc": (out / "clip.amc").read_bytes(),
            "asf": (out / "clip.asf").read_bytes(),
            "gltf": io.gltf.gltf_bytes(clip, binary=False),
            "glb": io.gltf.gltf_bytes(clip, binary=True),
        }


KTIME_PER_SECOND = 46_186_158_000
"""FBX's time unit (KTime) per second."""


def ascii_fbx(
    joints: int = 3,
    *,
    fps: float = 30.0,
    seconds: tuple[float, float] = (0.0, 1.0),
    takes: int = 1,
    chain: bool = True,
) -> bytes:
    """A minimal ASCII FBX 7.4 file ufbx reads: ``joints`` limb nodes (a chain, or all
    children of the first), ``takes`` animation stacks over ``seconds`` (no curves: the rest
    pose at every frame) at a custom frame rate ``fps`` (any float, NaN included)."""
    objects, links = [], []
    for k in range(joints):
        attribute, model = 10_000_000 + k, 20_000_000 + k
        parent = 0 if k == 0 else 20_000_000 + (k - 1 if chain else 0)
        objects.append(
            f'\tNodeAttribute: {attribute}, "NodeAttribute::", "LimbNode" {{\n'
            '\t\tTypeFlags: "Skeleton"\n\t}\n'
            f'\tModel: {model}, "Model::j{k}", "LimbNode" {{\n\t\tVersion: 232\n'
            "\t\tProperties70:  {\n"
            '\t\t\tP: "Lcl Translation", "Lcl Translation", "", "A",0,1,0\n\t\t}\n\t}\n'
        )
        links.append(f'\tC: "OO",{attribute},{model}\n\tC: "OO",{model},{parent}\n')
    start, stop = (int(t * KTIME_PER_SECOND) for t in seconds)
    for t in range(takes):
        stack, layer = 30_000_000 + 2 * t, 30_000_001 + 2 * t
        objects.append(
            f'\tAnimationStack: {stack}, "AnimStack::take{t}", "" {{\n\t\tProperties70:  {{\n'
            f'\t\t\tP: "LocalStart", "KTime", "Time", "",{start}\n'
            f'\t\t\tP: "LocalStop", "KTime", "Time", "",{stop}\n\t\t}}\n\t}}\n'
            f'\tAnimationLayer: {layer}, "AnimLayer::BaseLayer", "" {{\n\t}}\n'
        )
        links.append(f'\tC: "OO",{layer},{stack}\n')
    return (
        "; FBX 7.4.0 project file\nFBXHeaderExtension:  {\n\tFBXHeaderVersion: 1003\n"
        "\tFBXVersion: 7400\n}\nGlobalSettings:  {\n\tVersion: 1000\n\tProperties70:  {\n"
        '\t\tP: "UpAxis", "int", "Integer", "",1\n\t\tP: "TimeMode", "enum", "", "",14\n'
        f'\t\tP: "CustomFrameRate", "double", "Number", "",{fps!r}\n\t}}\n}}\n'
        "Objects:  {\n" + "".join(objects) + "}\nConnections:  {\n" + "".join(links) + "}\n"
    ).encode()


HOSTILE_FBX = {
    "joints_200k": lambda: ascii_fbx(200_000, chain=False),
    "depth_300": lambda: ascii_fbx(300),
    "frames_1e9": lambda: ascii_fbx(seconds=(0.0, 1e9 / 30)),  # KTime overflows: negative
    "duration_1e7": lambda: ascii_fbx(seconds=(0.0, 1e7)),
    "frames_2e6": lambda: ascii_fbx(seconds=(0.0, 2e6 / 30)),
    "backwards": lambda: ascii_fbx(seconds=(5.0, 1.0)),
    "fps_nan": lambda: ascii_fbx(fps=float("nan")),
    "fps_inf": lambda: ascii_fbx(fps=float("inf")),
    "fps_zero": lambda: ascii_fbx(fps=0.0),
    "fps_negative": lambda: ascii_fbx(fps=-30.0),
    "fps_1e9": lambda: ascii_fbx(fps=1e9),
    "nested_braces": lambda: ascii_fbx().replace(
        b"Objects:  {\n", b"Objects:  {\n" + b"X: {\n" * 100_000 + b"}\n" * 100_000, 1
    ),
    "truncated": lambda: ascii_fbx()[:300],
}
"""Crafted FBX files every command must refuse with one error line (never a signal), each
before it samples a frame or allocates what a count implies."""


def hostile(reader: str) -> list[bytes]:
    """The issue's proofs of concept for a reader (all must be refused)."""
    if reader in OWN:
        import fuzz_files

        return list(fuzz_files.hostile(reader))
    if reader == "fbx":
        return [make() for name, make in HOSTILE_FBX.items() if name != "joints_200k"]
    made = generated()
    if reader == "bvh":
        text = made["bvh"]
        return [
            _wide_bvh(10_050),
            text.replace(b"Frames: %d" % N_FRAMES, b"Frames: 1000000000"),
            text.replace(b"Frame Time:", b"Frame Time: 1e-9 #"),
            b"HIERARCHY\nROOT a\n{\nOFFSET 0 0 0\n" + b"JOINT b\n{\nOFFSET 0 0 0\n" * 300,
        ]
    if reader == "asf":
        return [re.sub(rb"(:units\s+mass \S+\s+length) \S+", rb"\1 1e-300", made["asf"])]
    if reader in ("gltf", "glb"):
        document = json.loads(made["gltf"])
        out = []
        for edit in _GLTF_POCS:
            changed = copy.deepcopy(document)
            edit(changed)
            out.append(_as(reader, changed, made))
        return out
    return []


def _set(path: tuple, value: Any):
    def edit(document: dict) -> None:
        owner = document
        for key in path[:-1]:
            owner = owner[key]
        owner[path[-1]] = value

    return edit


_GLTF_POCS = [
    _set(("buffers", 0, "uri"), "/etc/passwd"),
    _set(("buffers", 0, "uri"), "../../../../dev/zero"),
    _set(("animations", 0, "extras", "fps"), 1e9),
    _set(("accessors", 1, "count"), 10**9),
    _set(("accessors", 1, "byteOffset"), -16),
    _set(("bufferViews", 1, "byteLength"), 1 << 40),
    _set(("animations", 0, "channels", 0, "target"), None),
    _set(("extras",), json.loads("[" * 250 + "]" * 250)),
]


def _as(reader: str, document: dict, made: dict[str, bytes]) -> bytes:
    """The document as a .gltf, or as a .glb with the generated clip's binary chunk."""
    if reader == "gltf":
        return json.dumps(document).encode()
    glb = made["glb"]
    (json_length,) = struct.unpack_from("<I", glb, 12)
    binary = glb[20 + json_length :]
    document = copy.deepcopy(document)
    if document.get("buffers") and isinstance(document["buffers"], list):
        first = document["buffers"][0]
        if isinstance(first, dict) and str(first.get("uri", "")).startswith("data:"):
            first.pop("uri")
    text = json.dumps(document).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + binary
    return b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body


@cache
def seeds(reader: str) -> tuple[bytes, ...]:
    """Every seed of a reader: real heads, generated files, the hostile files."""
    if reader in OWN:
        import fuzz_files

        return fuzz_files.seeds(reader)
    if reader == "fbx":
        folder = Path(__file__).parents[1] / "data" / "fbx"
        made = [(folder / name).read_bytes() for name in FBX_SEEDS]
        return (*made, ascii_fbx(4), ascii_fbx(3, takes=3), *hostile(reader))
    found = [generated()[reader]]
    if DATA.is_dir():
        amc = sorted(DATA.glob("cmu/*/*.amc"))
        bvh = (
            sorted(DATA.glob("bandai1/clips/*.bvh"))[:1] + sorted(DATA.glob("cmu_bvh/*/*.bvh"))[:1]
        )
        if reader == "bvh":
            found += [_head_of_bvh(path, N_FRAMES) for path in bvh]
        elif reader == "amc" and amc:
            found.append(_head_of_amc(amc[0], N_FRAMES))
        elif reader == "asf" and amc:
            found.append((amc[0].parent / (amc[0].stem.split("_")[0] + ".asf")).read_bytes())
    return tuple(found + hostile(reader))


@cache
def amc_skeleton():
    """The skeleton the AMC seeds are read with (the data's, else the generated clip's)."""
    if DATA.is_dir() and sorted(DATA.glob("cmu/*/*.amc")):
        amc = sorted(DATA.glob("cmu/*/*.amc"))[0]
        return io.read_asf(amc.parent / (amc.stem.split("_")[0] + ".asf"))
    return io.parse_asf(generated()["asf"].decode(), "clip.asf")


# --- mutations --------------------------------------------------------------------------------


def mutate(reader: str, data: bytes, rng: random.Random) -> bytes:
    """One to three mutations: byte and line edits for every reader, token swaps for text,
    structural edits of the JSON for glTF (a .glb rebuilt around it, or its bytes cut); for
    quatmotion's own files, ``fuzz_files.mutate``."""
    if reader in OWN:
        import fuzz_files

        return fuzz_files.mutate(reader, data, rng)
    if reader in ("gltf", "glb") and rng.random() < 0.7:
        document = _json_of(reader, data)
        if document is not None:
            for _ in range(rng.randint(1, 3)):
                _mutate_json(document, rng)
            return _as(reader, document, generated())
    for _ in range(rng.randint(1, 3)):
        data = _mutate_bytes(data, rng, text=reader not in ("gltf", "glb", "fbx"))
    return data


def _json_of(reader: str, data: bytes) -> dict | None:
    try:
        if reader == "glb":
            (length,) = struct.unpack_from("<I", data, 12)
            return json.loads(data[20 : 20 + length])
        return json.loads(data)
    except (ValueError, struct.error):
        return None


def _mutate_bytes(data: bytes, rng: random.Random, text: bool) -> bytes:
    kinds = ["truncate", "flip", "delete", "duplicate", "insert"]
    kinds += ["token"] * 3 if text else ["integer"] * 3
    kind = rng.choice(kinds)
    if kind == "truncate":
        return data[: rng.randint(0, len(data))]
    if kind == "flip" and data:
        i = rng.randrange(len(data))
        return data[:i] + bytes([rng.randrange(256)]) + data[i + 1 :]
    if kind == "integer" and len(data) >= 4:  # a count, length or offset of a binary format
        i = rng.randrange(len(data) - 3)
        value = rng.choice([0, 1, 0x7FFFFFFF, 0xFFFFFFFF, 0x80000000, rng.randrange(1 << 32)])
        return data[:i] + struct.pack("<I", value) + data[i + 4 :]
    if kind == "insert":
        i = rng.randint(0, len(data))
        return data[:i] + rng.choice([b"\0", b"\xff\xff\xff\x7f", b"\n", b"{", b"}"]) + data[i:]
    if kind in ("delete", "duplicate"):
        lines = data.split(b"\n")
        i = rng.randrange(len(lines))
        lines[i : i + 1] = [] if kind == "delete" else [lines[i]] * rng.choice([2, 3, 50])
        return b"\n".join(lines)
    if kind == "token":
        tokens = data.split(b" ")
        i = rng.randrange(len(tokens))
        tokens[i] = rng.choice(NASTY_TOKENS).encode("utf-8")
        return b" ".join(tokens)
    return data


def _containers(value: Any, found: list) -> list:
    """Every (owner, key) of a JSON tree, depth first."""
    if isinstance(value, dict):
        for key in list(value):
            found.append((value, key))
            _containers(value[key], found)
    elif isinstance(value, list):
        for index in range(len(value)):
            found.append((value, index))
            _containers(value[index], found)
    return found


def _mutate_json(document: dict, rng: random.Random) -> None:
    places = _containers(document, [])
    if not places:
        return
    owner, key = rng.choice(places)
    kind = rng.choice(["replace", "replace", "delete", "duplicate", "number"])
    if kind == "replace":
        owner[key] = copy.deepcopy(rng.choice(NASTY_VALUES))
    elif kind == "delete":
        if isinstance(owner, dict):
            del owner[key]
        else:
            owner.pop(key)
    elif kind == "duplicate" and isinstance(owner, list):
        owner.insert(key, copy.deepcopy(owner[key]))
    elif (
        kind == "number"
        and isinstance(owner[key], int | float)
        and not isinstance(owner[key], bool)
    ):
        owner[key] = rng.choice([-1, 1, -owner[key], owner[key] * 1000, owner[key] + 1])


def base64_uri(payload: bytes) -> str:
    return "data:application/octet-stream;base64," + base64.b64encode(payload).decode()
