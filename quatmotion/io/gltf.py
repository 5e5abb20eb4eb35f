"""glTF 2.0 (``.glb`` and ``.gltf``): the skeleton as a node hierarchy with a skin, its motion as
an animation.

glTF is the open interchange format Blender, three.js, Unity, Unreal and Godot read. The JSON
structure is built with ``pygltflib`` (its dataclasses spell every field of the specification)
and read as plain JSON, each field checked where it is used (pygltflib's parser checks no
type and takes a millisecond a node); the binary data (times, rotations, translations) are
NumPy arrays written and read as raw little-endian float32, which is all the specification
asks of them.

Conventions
-----------
* Lengths are metres in the file (the specification's unit), centimetres in the motion. Y up,
  right-handed, as quatmotion. Quaternions are ``x y z w`` in the file, ``w x y z`` here.
* Writing: one node per joint (named as the joint, its ``translation`` the rest offset),
  joint 0 the scene's root; one child node per end site; a skin whose joints are the joint
  nodes, with inverse bind matrices of the rest pose; one animation (named as the clip) with
  one sampler per joint for its rotation and one for its translation where it moves (the root,
  and every joint of a clip with ``joint_translations``), keyframes at the clip's frame times
  (``k / fps``), linear. The frame rate is kept exactly in the animation's ``extras``. A
  ``.glb`` holds the data in its binary chunk; a ``.gltf`` holds them as a base64 data URI, so
  that it is one file too.
* Reading: the first skin's joints (or, without a skin, the node tree of the first scene)
  are the joints, parents first; their child nodes that are no joint, hold no mesh and have no
  children are end sites. The root's ancestors' transform (an ``Armature`` node's turn or
  uniform scale) is applied to the root. The first animation, or the one named, is sampled at
  its frame rate (``extras`` if there, else the median step of its keyframe times): linear
  and step samplers by interpolation, cubic splines at their keyframes' values. A joint with
  no channel keeps its node's rest rotation and translation in every frame.
* Reading trusts nothing in the file: the JSON is read as plain data (its depth checked
  before parsing), every field is checked for its type and range where it is used, and every
  count, frame rate, duration and buffer length against :func:`quatmotion.limits.current`
  before anything is allocated; a failure is a ``FormatError`` naming the field. A buffer in
  another file is read only for a file on disk, only inside its folder (symbolic links
  followed), only a regular file and no further than its ``byteLength``; a glTF given as bytes
  (an upload) reads no other file.
* The skeleton's ``extras``: ``format="gltf"``, ``length_scale`` (cm per file unit: 100 times
  the ancestors' scale), ``gltf_animation`` (the name read).
"""

from __future__ import annotations

import base64
import json
import os
import re
import stat
import struct
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import Any
from urllib.parse import unquote

import numpy as np
from numpy.typing import NDArray

from quatmotion import limits, quat
from quatmotion._atomic import atomic_write_bytes
from quatmotion.errors import FormatError
from quatmotion.io._text import read_bytes
from quatmotion.io.units import length_unit
from quatmotion.motion import Motion, Skeleton

__all__ = ["GLTF_SUFFIXES", "gltf_bytes", "parse_gltf", "read_gltf", "write_gltf"]

GLTF_SUFFIXES = (".glb", ".gltf")
CM_PER_METRE = 100.0
_FLOAT = 5126  # componentType of float32
_COMPONENTS = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}
_DTYPES = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32}
_DTYPES[_FLOAT] = np.float32
_NORMALIZED_MAX = {5120: 127.0, 5121: 255.0, 5122: 32767.0, 5123: 65535.0}


# --------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------


class _Blob:
    """The binary buffer being written, and the accessors into it."""

    def __init__(self) -> None:
        self.chunks: list[bytes] = []
        self.length = 0
        self.views: list[Any] = []
        self.accessors: list[Any] = []

    def add(self, array: NDArray[np.float64], kind: str, bounds: bool = False) -> int:
        import pygltflib

        data = np.ascontiguousarray(array, dtype="<f4")
        raw = data.tobytes()
        self.views.append(
            pygltflib.BufferView(buffer=0, byteOffset=self.length, byteLength=len(raw))
        )
        self.chunks.append(raw)
        self.length += len(raw)
        pad = -self.length % 4
        self.chunks.append(b"\0" * pad)
        self.length += pad
        flat = data.reshape(len(data), -1)
        self.accessors.append(
            pygltflib.Accessor(
                bufferView=len(self.views) - 1,
                componentType=_FLOAT,
                count=len(data),
                type=kind,
                min=flat.min(axis=0).tolist() if bounds else None,
                max=flat.max(axis=0).tolist() if bounds else None,
            )
        )
        return len(self.accessors) - 1

    def bytes(self) -> bytes:
        return b"".join(self.chunks)


def _xyzw(q: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.concatenate((q[..., 1:], q[..., :1]), axis=-1)


def _wxyz(q: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.concatenate((q[..., 3:], q[..., :3]), axis=-1)


def _matrix(rotation: NDArray[np.float64], translation: NDArray[np.float64]) -> NDArray:
    """4x4 column-major-ready matrices of rigid transforms (``(..., 4, 4)``, row-major here)."""
    m = np.zeros((*rotation.shape[:-1], 4, 4))
    m[..., :3, :3] = quat.to_matrix(rotation)
    m[..., :3, 3] = translation
    m[..., 3, 3] = 1.0
    return m


def gltf_bytes(motion: Motion, binary: bool = True) -> bytes:
    """The bytes :func:`write_gltf` writes: a ``.glb`` (``binary``) or a ``.gltf``."""
    import pygltflib

    sk = motion.skeleton
    rest_translation = sk.offsets * (1.0 / CM_PER_METRE)
    rest_rotation = quat.identity((sk.n_joints,))  # the rest pose: every local rotation zero
    blob = _Blob()
    # glTF stores matrices column-major: the transpose of each row-major matrix, flattened.
    inverse_bind = _inverse_bind_matrices(sk.parents, rest_rotation, rest_translation)
    bind_accessor = blob.add(np.transpose(inverse_bind, (0, 2, 1)).reshape(-1, 16), "MAT4")
    animations = [_animation(motion, blob)] if motion.n_frames else []
    data = blob.bytes()
    gltf = pygltflib.GLTF2(
        asset=pygltflib.Asset(version="2.0", generator="quatmotion"),
        scene=0,
        scenes=[pygltflib.Scene(name=motion.name or sk.name or "clip", nodes=[0])],
        nodes=_nodes(sk, rest_rotation, rest_translation),
        skins=[
            pygltflib.Skin(
                name=sk.name or "skeleton",
                joints=list(range(sk.n_joints)),
                skeleton=0,
                inverseBindMatrices=bind_accessor,
            )
        ],
        animations=animations,
        accessors=blob.accessors,
        bufferViews=blob.views,
        buffers=[pygltflib.Buffer(byteLength=len(data))],
    )
    if binary:
        gltf.set_binary_blob(data)
        return b"".join(gltf.save_to_bytes())
    gltf.buffers[0].uri = "data:application/octet-stream;base64," + base64.b64encode(data).decode(
        "ascii"
    )
    return gltf.gltf_to_json().encode("utf-8")


def _nodes(sk: Skeleton, rest_rotation: np.ndarray, rest_translation: np.ndarray) -> list:
    """One node per joint (its rest transform, its children) then one per end site."""
    import pygltflib

    J = sk.n_joints
    children: list[list[int]] = [[] for _ in range(J)]
    for j in range(1, J):
        children[int(sk.parents[j])].append(j)
    for s in range(sk.n_sites):
        children[int(sk.site_parents[s])].append(J + s)
    nodes = [
        pygltflib.Node(
            name=sk.joint_names[j],
            translation=rest_translation[j].tolist(),
            rotation=_xyzw(rest_rotation[j]).tolist(),
            children=children[j] or None,
        )
        for j in range(J)
    ]
    nodes += [
        pygltflib.Node(
            name=sk.site_names[s],
            translation=(sk.site_offsets[s] * (1.0 / CM_PER_METRE)).tolist(),
        )
        for s in range(sk.n_sites)
    ]
    return nodes


def _inverse_bind_matrices(
    parents: np.ndarray, rest_rotation: np.ndarray, rest_translation: np.ndarray
) -> np.ndarray:
    """The inverses of the rest pose's world transforms, shape (J, 4, 4), row-major."""
    J = len(parents)
    world_r = np.zeros((J, 4))
    world_t = np.zeros((J, 3))
    for j in range(J):
        parent = int(parents[j])
        if parent < 0:
            world_r[j], world_t[j] = rest_rotation[j], rest_translation[j]
        else:
            world_r[j] = quat.multiply(world_r[parent], rest_rotation[j])
            world_t[j] = world_t[parent] + quat.rotate(world_r[parent], rest_translation[j])
    return np.linalg.inv(_matrix(world_r, world_t))


def _animation(motion: Motion, blob: _Blob):  # -> pygltflib.Animation
    """Every joint's rotation over time, and the root's translation (every joint's where the
    clip moves joints other than the root), linearly interpolated at the clip's frame times."""
    import pygltflib

    m = 1.0 / CM_PER_METRE
    times = blob.add(np.arange(motion.n_frames) / motion.fps, "SCALAR", bounds=True)
    translations = None
    if motion.joint_translations is not None:
        translations = motion.joint_translations.copy()
        translations[:, 0] = motion.root_translation
    samplers, channels = [], []

    def animate(node: int, path: str, output: int) -> None:
        samplers.append(
            pygltflib.AnimationSampler(input=times, output=output, interpolation="LINEAR")
        )
        channels.append(
            pygltflib.AnimationChannel(
                sampler=len(samplers) - 1,
                target=pygltflib.AnimationChannelTarget(node=node, path=path),
            )
        )

    for j in range(motion.skeleton.n_joints):
        animate(j, "rotation", blob.add(_xyzw(motion.rotations[:, j]), "VEC4"))
        if j == 0 or translations is not None:
            moved = motion.root_translation if j == 0 else translations[:, j]
            animate(j, "translation", blob.add(moved * m, "VEC3"))
    return pygltflib.Animation(
        name=motion.name or "motion",
        samplers=samplers,
        channels=channels,
        extras={"fps": motion.fps, "frames": motion.n_frames},
    )


def write_gltf(motion: Motion, path: str | Path) -> None:
    """Write a motion as glTF 2.0 (atomically): ``.glb`` binary, ``.gltf`` JSON with its data
    embedded. Any skeleton (BVH, ASF, built in code): the nodes carry each joint's local
    rotation, whatever composed it.

    Parameters
    ----------
    motion : Motion
    path : str or Path
        Ending in ``.glb`` or ``.gltf`` (``ValueError`` otherwise).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in GLTF_SUFFIXES:
        raise ValueError(f"{path}: a glTF file ends in .glb or .gltf")
    atomic_write_bytes(path, gltf_bytes(motion, binary=suffix == ".glb"))


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------


def read_gltf(
    path: str | Path, animation: str | int | None = None, *, units: str | float | None = None
) -> Motion:
    """Read the skeleton and one animation of a glTF 2.0 file.

    Parameters
    ----------
    path : str or Path
        ``.glb`` or ``.gltf``: its buffers embedded, or in files inside its folder (a relative
        ``uri`` that stays there once symbolic links are followed; anything else is refused).
    animation : str, int or None
        The animation's name or position; None takes the first.
    units : str, float or None
        A length unit replacing the metre (a name of :data:`quatmotion.io.units.LENGTH_UNITS`
        or cm per file unit): for files written in the wrong unit. Kept with
        ``extras["length_unit_given"] = True``.

    Returns
    -------
    Motion
        Centimetres; ``joint_translations`` when joints other than the root have translation
        channels. A file without animations gives a clip of no frames.

    Raises
    ------
    FormatError
        Naming the file and the field: not glTF 2.0, indices out of range, accessors of the
        wrong type or out of their buffer, a buffer outside the file's folder, counts, frame
        rates or durations over :func:`quatmotion.limits.current`, no such animation.
    """
    path = Path(path)
    return parse_gltf(read_bytes(path), path, animation, units=units, folder=path.parent)


def parse_gltf(
    data: bytes,
    path: str | Path,
    animation: str | int | None = None,
    *,
    units: str | float | None = None,
    folder: str | Path | None = None,
) -> Motion:
    """:func:`read_gltf` of the bytes of a file. ``path`` names it in messages and is not
    opened; ``folder`` is where buffers in other files may be read from (the file's own folder,
    for a file on disk). Without one (an upload), a buffer in another file is refused."""
    path = Path(path)
    limits.check("file_bytes", len(data), path, "the file's size")
    document, chunk = _document(data, path)
    version = (
        document.get("asset", {}).get("version") if _is_object(document.get("asset")) else None
    )
    if not (isinstance(version, str) and version.startswith("2.")):
        raise FormatError(f"asset.version is {version!r}: only glTF 2.0 is read", path)
    reader = _Reader(
        document,
        chunk,
        path,
        None if units is None else length_unit(units),
        None if folder is None else Path(folder),
    )
    return reader.motion(animation)


_GLB_JSON = 0x4E4F534A
_GLB_BIN = 0x004E4942


def _document(data: bytes, path: Path) -> tuple[dict[str, Any], bytes | None]:
    """The JSON document (its depth checked before parsing) and the GLB's binary chunk."""
    chunk = None
    if data[:4] == b"glTF":
        if len(data) < 20:
            raise FormatError(f"not a glTF 2.0 file: a GLB of {len(data)} bytes", path)
        _, version, length = struct.unpack_from("<4sII", data)
        if version != 2:
            raise FormatError(f"GLB version {version}: only glTF 2.0 is read", path)
        if length > len(data):
            raise FormatError(f"the GLB header says {length} bytes, the file has {len(data)}", path)
        chunks: list[tuple[int, int, bytes]] = []
        offset = 12
        while offset + 8 <= length:
            size, kind = struct.unpack_from("<II", data, offset)
            if offset + 8 + size > length:
                raise FormatError(f"the GLB chunk at byte {offset} runs past the file's end", path)
            chunks.append((offset, kind, data[offset + 8 : offset + 8 + size]))
            offset += 8 + size
        if not chunks or chunks[0][1] != _GLB_JSON:
            raise FormatError("the GLB's first chunk (byte 12) is not its JSON chunk", path)
        text = chunks[0][2]
        chunk = next((body for _, kind, body in chunks[1:] if kind == _GLB_BIN), None)
    else:
        text = data[3:] if data[:3] == b"\xef\xbb\xbf" else data
    limits.check("depth", limits.json_depth(text), path, "the JSON's nesting depth")
    try:
        document = json.loads(text)
    except ValueError as error:  # UnicodeDecodeError included
        raise FormatError(f"not a glTF 2.0 file ({error})", path) from None
    if not _is_object(document):
        raise FormatError("not a glTF 2.0 file (its JSON is no object)", path)
    return document, chunk


def _is_object(value: Any) -> bool:
    return isinstance(value, dict)


def _is_index(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


class _Reader:
    """The document's fields, each checked for its type and range where it is read: a field
    of the wrong type is a FormatError naming it, never an exception of the code using it."""

    def __init__(
        self,
        document: dict[str, Any],
        chunk: bytes | None,
        path: Path,
        cm_per_unit: float | None,
        folder: Path | None,
    ) -> None:
        self.document = document
        self.chunk = chunk
        self.path = path
        self.folder = folder
        self.metre = CM_PER_METRE if cm_per_unit is None else cm_per_unit
        self.given = cm_per_unit is not None
        self._buffers: dict[int, bytes] = {}
        self._accessors: dict[tuple[int, str], NDArray[np.float64]] = {}
        self.keys_read = 0
        self.nodes = self.objects(document, "nodes", "")

    def fail(self, message: str) -> FormatError:
        return FormatError(message, self.path)

    # --- typed fields -------------------------------------------------------------------------

    def objects(self, owner: dict[str, Any], key: str, where: str) -> list[dict[str, Any]]:
        """``owner[key]``: a list of objects (empty if absent)."""
        items = owner.get(key, [])
        if not isinstance(items, list) or not all(_is_object(item) for item in items):
            raise self.fail(f"{where}{key} is not a list of objects")
        return items

    def index(self, owner: dict[str, Any], key: str, size: int, where: str, into: str) -> int:
        """``owner[key]``: a required index of one of ``size`` items of ``into``."""
        value = owner.get(key)
        if not _is_index(value) or not 0 <= value < size:
            raise self.fail(f"{where}.{key} is {value!r}: no index of {into} (it has {size})")
        return value

    def indices(self, owner: dict[str, Any], key: str, size: int, where: str) -> list[int]:
        values = owner.get(key, [])
        if not isinstance(values, list) or not all(_is_index(v) and 0 <= v < size for v in values):
            raise self.fail(f"{where}.{key} is not a list of node indices (0 to {size - 1})")
        return values

    def count(self, owner: dict[str, Any], key: str, where: str, default: int | None = None) -> int:
        """``owner[key]``: a whole number, 0 or more."""
        value = owner.get(key, default)
        if not _is_index(value) or value < 0:
            raise self.fail(f"{where}.{key} is {value!r}: expected a whole number, 0 or more")
        return value

    def numbers(self, owner: dict[str, Any], key: str, n: int, where: str) -> NDArray | None:
        """``owner[key]``: ``n`` finite numbers, or None if absent."""
        value = owner.get(key)
        if value is None:
            return None
        if not (
            isinstance(value, list)
            and len(value) == n
            and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
            and np.all(np.isfinite(value))
        ):
            raise self.fail(f"{where}.{key} is not {n} finite numbers")
        return np.asarray(value, dtype=np.float64)

    # --- data ---------------------------------------------------------------------------------

    def buffer(self, index: int) -> bytes:
        if index in self._buffers:
            return self._buffers[index]
        where = f"buffers[{index}]"
        buffer = self.objects(self.document, "buffers", "")[index]
        length = self.count(buffer, "byteLength", where)
        limits.check("file_bytes", length, self.path, f"{where}.byteLength")
        uri = buffer.get("uri")
        if uri is None:
            if self.chunk is None or index != 0:
                raise self.fail(f"{where} has no uri and is not the GLB's binary chunk")
            blob = self.chunk
        elif not isinstance(uri, str):
            raise self.fail(f"{where}.uri is not a string")
        elif uri.startswith("data:"):
            head, comma, payload = uri.partition(",")
            if not comma or not head.endswith(";base64"):
                raise self.fail(f"{where}.uri is a data URI that is not base64")
            try:
                blob = base64.b64decode(payload)
            except ValueError:
                raise self.fail(f"{where}.uri is not a valid base64 data URI") from None
        else:
            blob = self.external(where, uri, length)
        self._buffers[index] = blob
        return blob

    def external(self, where: str, uri: str, length: int) -> bytes:
        """The first ``length`` bytes of a regular file inside the glTF's folder, symbolic
        links followed. The messages for a path outside are the same whatever is there."""
        if self.folder is None:
            raise self.fail(
                f"{where}.uri names another file, which is not read for a glTF given as bytes "
                "(an upload): embed the buffers (a .glb, or a .gltf with data URIs)"
            )
        outside = self.fail(f"{where}.uri must be a relative path inside the glTF's folder")
        name = unquote(uri)
        if (
            "\0" in name
            or _SCHEME.match(name)
            or PurePosixPath(name).is_absolute()
            or PureWindowsPath(name).anchor
        ):
            raise outside
        folder = self.folder.resolve()
        target = (folder / name).resolve()
        if not target.is_relative_to(folder) or target == folder:
            raise outside
        try:  # non-blocking: a FIFO named by a file must not hang the reader
            handle = os.open(target, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
        except OSError as error:
            raise self.fail(f"{where}: cannot read {name}: {error.strerror}") from None
        with os.fdopen(handle, "rb") as file:
            if not stat.S_ISREG(os.fstat(handle).st_mode):
                raise self.fail(f"{where}.uri names {name}, which is not a regular file")
            return file.read(length)

    def accessor_count(self, index: int, field: str) -> int:
        accessors = self.objects(self.document, "accessors", "")
        if not _is_index(index) or not 0 <= index < len(accessors):
            raise self.fail(f"{field}: accessors[{index}] does not exist")
        return self.count(accessors[index], "count", f"accessors[{index}]")

    def accessor(self, index: int, kind: str, field: str) -> NDArray[np.float64]:
        """The accessor's values as float64 ``(count, width)``; its count bounded by the
        caller (:meth:`accessor_count`) before this reads it."""
        key = (index, kind)
        if key not in self._accessors:
            self._accessors[key] = self._read_accessor(index, kind, field)
        return self._accessors[key]

    def _read_accessor(self, index: int, kind: str, field: str) -> NDArray[np.float64]:
        count = self.accessor_count(index, field)
        acc = self.document["accessors"][index]
        where = f"{field} (accessors[{index}])"
        if acc.get("type") != kind:
            raise self.fail(f"{where} is {acc.get('type')!r}, expected {kind}")
        component = acc.get("componentType")
        if not _is_index(component) or component not in _DTYPES:
            raise self.fail(f"{where} has componentType {component!r}")
        if acc.get("sparse") is not None:
            raise self.fail(f"{where} is sparse, which is not read")
        width = _COMPONENTS[kind]
        dtype = np.dtype(_DTYPES[component]).newbyteorder("<")
        if acc.get("bufferView") is None:
            return np.zeros((count, width))  # the specification's default
        views = self.objects(self.document, "bufferViews", "")
        v = self.index(acc, "bufferView", len(views), f"accessors[{index}]", "bufferViews")
        view = views[v]
        view_where = f"bufferViews[{v}]"
        buffers = self.objects(self.document, "buffers", "")
        blob = self.buffer(self.index(view, "buffer", len(buffers), view_where, "buffers"))
        view_start = self.count(view, "byteOffset", view_where, 0)
        view_length = self.count(view, "byteLength", view_where)
        if view_start + view_length > len(blob):
            raise self.fail(
                f"{view_where} (bytes {view_start} to {view_start + view_length}) runs past the "
                f"end of its buffer ({len(blob)} bytes)"
            )
        element = width * dtype.itemsize
        stride = view.get("byteStride", element)
        if not _is_index(stride) or not element <= stride <= 252:
            raise self.fail(f"{view_where}.byteStride is {stride!r}: expected {element} to 252")
        start = self.count(acc, "byteOffset", f"accessors[{index}]", 0)
        end = start + (stride * (count - 1) + element if count else 0)
        if end > view_length:
            raise self.fail(
                f"{where} reads bytes {start} to {end} of {view_where}, which has {view_length}"
            )
        raw = np.frombuffer(blob, dtype=np.uint8, count=end - start, offset=view_start + start)
        if stride == element:
            values = raw.view(dtype).reshape(count, width)
        else:
            padded = np.zeros(stride * count, dtype=np.uint8)
            padded[: len(raw)] = raw
            values = padded.reshape(count, stride)[:, :element].copy().view(dtype)
        with np.errstate(invalid="ignore", over="ignore"):  # not finite: refused just below
            values = values.astype(np.float64)
        if acc.get("normalized") is True and component in _NORMALIZED_MAX:
            values = np.maximum(values / _NORMALIZED_MAX[component], -1.0)
        if not np.all(np.isfinite(values)):
            raise self.fail(f"{where} holds values that are not finite")
        return values

    # --- structure ----------------------------------------------------------------------------

    def joints(self) -> tuple[list[int], list[int], list[int], list[int]]:
        """Joint nodes parents first, their parents (joint positions), end-site nodes and their
        joints."""
        nodes = self.nodes
        if not nodes:
            raise self.fail("the file holds no nodes")
        children = [
            self.indices(node, "children", len(nodes), f"nodes[{n}]")
            for n, node in enumerate(nodes)
        ]
        parent_of: dict[int, int] = {}
        for n, kids in enumerate(children):
            for child in kids:
                if child in parent_of:
                    raise self.fail(f"nodes[{child}] has two parents")
                parent_of[child] = n
        skins = self.objects(self.document, "skins", "")
        if skins:
            members = set(self.indices(skins[0], "joints", len(nodes), "skins[0]"))
            if not members:
                raise self.fail("skins[0].joints is empty")
        else:
            scenes = self.objects(self.document, "scenes", "")
            roots: list[int] = []
            if scenes:
                scene = self.index(
                    {"scene": 0, **self.document}, "scene", len(scenes), "", "scenes"
                )
                roots = self.indices(scenes[scene], "nodes", len(nodes), f"scenes[{scene}]")
            roots = [r for r in roots if nodes[r].get("mesh") is None] or roots
            if not roots:
                raise self.fail("no skin and no scene nodes: no skeleton to read")
            members = set()
            stack = roots[:1]
            while stack:
                n = stack.pop()
                if n not in members and nodes[n].get("mesh") is None and children[n]:
                    members.add(n)
                    stack.extend(children[n])
        limits.check("joints", len(members), self.path, "the skeleton's joints")
        roots = [j for j in members if parent_of.get(j) not in members]
        if len(roots) != 1:
            raise self.fail(
                f"the skeleton has {len(roots)} root joints (nodes {sorted(roots)[:5]}); "
                "one is read"
            )
        order: list[int] = []
        parents: list[int] = []
        sites: list[int] = []
        site_parents: list[int] = []
        stack = [(roots[0], -1)]
        while stack:
            n, parent = stack.pop()
            if n in members:
                order.append(n)
                parents.append(parent)
                here = len(order) - 1
                for child in reversed(children[n]):
                    stack.append((child, here))
            elif not children[n] and all(nodes[n].get(k) is None for k in ("mesh", "camera")):
                sites.append(n)
                site_parents.append(parent)
        if len(order) != len(members):
            raise self.fail("skins[0].joints are not one tree under one root")
        self.parent_of = parent_of
        return order, parents, sites, site_parents

    def ancestors(self, root: int) -> tuple[NDArray, NDArray, float]:
        """World rotation, translation and uniform scale of the root's parent."""
        chain = []
        n = root
        while n in self.parent_of:
            n = self.parent_of[n]
            if n == root or len(chain) >= len(self.nodes):
                raise self.fail(f"nodes[{root}]'s ancestors form a cycle")
            chain.append(n)
        rotation, translation, scale = quat.identity(()), np.zeros(3), 1.0
        for n in reversed(chain):
            r, t, s = self.rest(n)
            translation = translation + scale * quat.rotate(rotation, t)
            rotation = quat.multiply(rotation, r)
            scale *= s
        return rotation, translation, scale

    def rest(self, n: int) -> tuple[NDArray, NDArray, float]:
        node = self.nodes[n]
        where = f"nodes[{n}]"
        matrix = self.numbers(node, "matrix", 16, where)
        if matrix is not None and not np.array_equal(matrix, np.eye(4).ravel()):
            m = matrix.reshape(4, 4).T
            scales = np.linalg.norm(m[:3, :3], axis=0)
            uniform = np.allclose(scales, scales[0], rtol=1e-6)
            if not (uniform and np.all(np.isfinite(scales)) and scales[0] > 0):
                raise self.fail(f"{where}.matrix is not a rotation with a uniform scale")
            r = quat.from_matrix(m[:3, :3] / scales[0])
            return r, m[:3, 3].copy(), float(scales[0])
        t = self.numbers(node, "translation", 3, where)
        r = self.numbers(node, "rotation", 4, where)
        s = self.numbers(node, "scale", 3, where)
        t = np.zeros(3) if t is None else t
        r = np.array([1.0, 0.0, 0.0, 0.0]) if r is None else _wxyz(r)
        s = np.ones(3) if s is None else s
        if not np.allclose(s, s[0], rtol=1e-6) or not s[0] > 0:
            raise self.fail(f"{where}.scale {s.tolist()} is not uniform and positive")
        largest = np.max(np.abs(r))
        if not largest > 0:
            raise self.fail(f"{where}.rotation is zero, not a rotation")
        r = r / largest  # a norm of huge components would overflow
        return quat.normalize(r), t, float(s[0])

    def translation(self, n: int) -> NDArray:
        """A node's rest translation (an end site's offset): :meth:`rest`'s, quicker."""
        if "matrix" in self.nodes[n]:
            return self.rest(n)[1]
        t = self.numbers(self.nodes[n], "translation", 3, f"nodes[{n}]")
        return np.zeros(3) if t is None else t

    def animation(self, wanted: str | int | None) -> tuple[int | None, dict[str, Any] | None]:
        animations = self.objects(self.document, "animations", "")
        if wanted is None:
            return (0, animations[0]) if animations else (None, None)
        if isinstance(wanted, int) or (isinstance(wanted, str) and wanted.isdigit()):
            k = int(wanted)
            if not 0 <= k < len(animations):
                raise self.fail(f"no animation {k}: the file has {len(animations)}")
            return k, animations[k]
        names = [a.get("name") for a in animations]
        if wanted not in names:
            raise self.fail(f"no animation named {wanted!r}; the file has {names}")
        return names.index(wanted), animations[names.index(wanted)]

    def channels(
        self, k: int | None, anim: dict[str, Any] | None, index: dict[int, int]
    ) -> tuple[dict[int, _Keys], dict[int, _Keys]]:
        """The animation's rotation and translation keyframes of each joint (by joint number),
        checked: a sampler that exists, as many values as times, times that never go back, no
        more keyframes in all than :func:`quatmotion.limits.current` allows a clip."""
        rotated: dict[int, _Keys] = {}
        moved: dict[int, _Keys] = {}
        if anim is None:
            return rotated, moved
        samplers = self.objects(anim, "samplers", f"animations[{k}].")
        for c, channel in enumerate(self.objects(anim, "channels", f"animations[{k}].")):
            field = f"animations[{k}].channels[{c}]"
            target = channel.get("target")
            if not _is_object(target):
                raise self.fail(f"{field}.target is missing")
            node = target.get("node")
            j = index.get(node) if _is_index(node) else None
            path = target.get("path")
            if j is None or path not in ("rotation", "translation"):
                continue  # another node's, or weights and scale
            s = self.index(channel, "sampler", len(samplers), field, f"animations[{k}].samplers")
            sampler = samplers[s]
            how = sampler.get("interpolation", "LINEAR")
            if how not in ("LINEAR", "STEP", "CUBICSPLINE"):
                raise self.fail(f"animations[{k}].samplers[{s}].interpolation is {how!r}")
            n_times = self.accessor_count(sampler.get("input"), f"{field} input")
            n_values = self.accessor_count(sampler.get("output"), f"{field} output")
            per_key = 3 if how == "CUBICSPLINE" else 1
            if n_values != per_key * n_times or not n_times:
                raise self.fail(f"{field}: {n_times} times but {n_values} values ({how})")
            self.keys_read += n_times
            limits.check("joint_frames", self.keys_read, self.path, f"keyframes up to {field}")
            times = self.accessor(sampler["input"], "SCALAR", f"{field} input")[:, 0]
            kind = "VEC4" if path == "rotation" else "VEC3"
            values = self.accessor(sampler["output"], kind, f"{field} output")[
                per_key // 2 :: per_key
            ]
            if np.any(np.diff(times) < 0):
                raise self.fail(f"{field}: keyframe times go backwards")
            if path == "rotation":
                largest = np.max(np.abs(values), axis=1, keepdims=True)  # no overflow below
                if not np.all(largest > 0):
                    raise self.fail(f"{field} output holds a zero quaternion, not a rotation")
                values = values / largest
            (rotated if path == "rotation" else moved)[j] = (times, values, how)
        return rotated, moved

    # --- the motion ---------------------------------------------------------------------------

    def motion(self, wanted: str | int | None) -> Motion:
        order, parents, sites, site_parents = self.joints()
        J = len(order)
        rests = [self.rest(n) for n in order]
        for j, (_, _, s) in enumerate(rests):
            if j and abs(s - 1.0) > 1e-6:
                raise self.fail(f"nodes[{order[j]}] (a joint) is scaled: not read")
        up_r, up_t, up_s = self.ancestors(order[0])
        # The root's own scale scales the bones below it, not its own translation.
        cm = self.metre * up_s * rests[0][2]
        offsets = np.array([t for _, t, _ in rests]) * cm
        offsets[0] = self.metre * (up_t + up_s * quat.rotate(up_r, rests[0][1]))
        site_offsets = np.array([self.translation(n) for n in sites]).reshape(-1, 3) * cm
        k, anim = self.animation(wanted)
        rotated, moved = self.channels(k, anim, {n: j for j, n in enumerate(order)})
        keys = [t for t, _, _ in (*rotated.values(), *moved.values())]
        fps = 30.0 if anim is None else self._fps(k, anim, keys)
        frames = self._frame_times(k, keys, fps, J)
        n_frames = len(frames)
        for table in (rotated, moved):
            for j, (times, values, how) in table.items():
                table[j] = (_snapped(times, frames, fps), values, how)
        rotations = np.empty((n_frames, J, 4))
        translations = np.empty((n_frames, J, 3))
        for j, (r, t, _) in enumerate(rests):
            rotations[:, j] = r
            translations[:, j] = t
            if j in rotated:
                rotations[:, j] = _wxyz(_sample_rotation(*rotated[j], frames))
            if j in moved:
                translations[:, j] = _sample(*moved[j], frames)
        root = self.metre * (up_t + up_s * quat.rotate(up_r, translations[:, 0]))
        rotations[:, 0] = quat.multiply(up_r, rotations[:, 0])
        translations *= cm
        joint_moves = any(j > 0 for j in moved)
        names = [self.name(n) for n in order]
        site_names = [self.name(n) for n in sites]
        name = self.path.stem
        try:
            skeleton = Skeleton(
                joint_names=tuple(_unique(names)),
                parents=np.asarray(parents, dtype=np.int64),
                offsets=offsets,
                channels=tuple(
                    (("tx", "ty", "tz") if j == 0 or j in moved else ())
                    + (("rz", "ry", "rx") if j == 0 or j in rotated else ())
                    for j in range(J)
                ),
                euler="intrinsic",
                site_names=tuple(_unique(site_names, taken=set(names))),
                site_parents=np.asarray(site_parents, dtype=np.int64),
                site_offsets=site_offsets,
                name=name,
                extras={
                    "format": "gltf",
                    "length_scale": cm,
                    "gltf_animation": None if anim is None else (anim.get("name") or str(k)),
                    **({"length_unit_given": True} if self.given else {}),
                },
            )
            return Motion(
                skeleton,
                fps,
                root,
                rotations,
                translations if joint_moves else None,
                name=name,
            )
        except ValueError as error:  # e.g. offsets that overflow once in centimetres
            raise self.fail(str(error)) from None

    def name(self, n: int) -> str:
        name = self.nodes[n].get("name")
        return name if isinstance(name, str) and name else f"node{n}"

    def _fps(self, k: int | None, anim: dict[str, Any], times: list[NDArray]) -> float:
        extras = anim.get("extras")
        fps = extras.get("fps") if _is_object(extras) else None
        if fps is not None:
            limits.check("fps", fps, self.path, f"animations[{k}].extras.fps")
            return float(fps)
        steps = np.concatenate([np.diff(t) for t in times]) if times else np.zeros(0)
        steps = steps[steps > 0]
        if not len(steps):
            return 30.0
        fps = 1.0 / float(np.median(steps))
        limits.check("fps", fps, self.path, f"animations[{k}]'s frame rate (1 / median key step)")
        return float(round(fps)) if abs(fps - round(fps)) <= 1e-3 * fps else fps

    def _frame_times(self, k: int | None, keys: list[NDArray], fps: float, joints: int) -> NDArray:
        """The clip's frame times: from the first keyframe to the last at ``fps`` (none without
        keyframes), their number checked against the limits before they are made."""
        if not keys:
            return np.zeros(0)
        start = min(float(t[0]) for t in keys)
        end = max(float(t[-1]) for t in keys)
        field = f"animations[{k}]"
        limits.check("duration", end - start, self.path, f"{field}'s duration (keyframe times)")
        n_frames = int(round((end - start) * fps)) + 1
        limits.check("frames", n_frames, self.path, f"{field}'s frames ({fps:g} frames/s)")
        limits.check("joint_frames", n_frames * joints, self.path, f"{field}'s frames x joints")
        return start + np.arange(n_frames) / fps


_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*:")


def _unique(names: list[str], taken: set[str] | None = None) -> list[str]:
    """Names made unique (glTF does not require it; a Skeleton does): ``name.1``, ``name.2``.
    Linear: each name's next suffix is remembered."""
    seen = set(taken or ())
    suffix: dict[str, int] = {}
    out = []
    for name in names:
        candidate, k = name, suffix.get(name, 1)
        while candidate in seen:
            candidate, k = f"{name}.{k}", k + 1
        suffix[name] = k
        seen.add(candidate)
        out.append(candidate)
    return out


def _sample(times: NDArray, values: NDArray, how: str, at: NDArray) -> NDArray:
    """Values at times ``at``: linear between keyframes (the last before for STEP)."""
    if how == "STEP":
        k = np.clip(np.searchsorted(times, at, side="right") - 1, 0, len(times) - 1)
        return values[k]
    return np.stack([np.interp(at, times, values[:, c]) for c in range(values.shape[1])], axis=-1)


_Keys = tuple  # (times (K,), values (K, 3 or 4), interpolation): one channel's keyframes


def _snapped(times: NDArray, frames: NDArray, fps: float) -> NDArray:
    """Keyframe times snapped to the frame grid they sit on (within a thousandth of a frame):
    they are float32, and a frame should take its keyframe's value exactly, not a mix of two."""
    start = frames[0] if len(frames) else 0.0
    grid = (times - start) * fps
    if np.all(np.abs(grid - np.round(grid)) < 1e-3):
        return start + np.round(grid) / fps
    return times


def _sample_rotation(times: NDArray, values: NDArray, how: str, at: NDArray) -> NDArray:
    """Unit quaternions (x y z w) at times ``at``: exact at keyframes, normalised linear
    interpolation between them (on the shorter arc)."""
    q = values / np.linalg.norm(values, axis=1, keepdims=True)
    signs = np.ones(len(q))
    if len(q) > 1:
        flips = np.sum(q[1:] * q[:-1], axis=1) < 0
        signs[1:] = np.where(np.cumsum(flips) % 2, -1.0, 1.0)
    q = q * signs[:, None]
    out = _sample(times, q, how, at)
    return out / np.linalg.norm(out, axis=1, keepdims=True)
