"""glTF 2.0 (``.glb`` and ``.gltf``): the skeleton as a node hierarchy with a skin, its motion as
an animation.

glTF is the open interchange format Blender, three.js, Unity, Unreal and Godot read. The JSON
structure is built and parsed with ``pygltflib`` (its dataclasses spell every field of the
specification); the binary data (times, rotations, translations) are NumPy arrays written and
read as raw little-endian float32, which is all the specification asks of them.

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
* The skeleton's ``extras``: ``format="gltf"``, ``length_scale`` (cm per file unit: 100 times
  the ancestors' scale), ``gltf_animation`` (the name read).
"""

from __future__ import annotations

import base64
import json
import struct
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quatmotion import quat
from quatmotion._atomic import atomic_write_bytes
from quatmotion.errors import FormatError
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
        ``.glb`` or ``.gltf`` (its buffers embedded or in files beside it).
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
        wrong type, no such animation.
    """
    path = Path(path)
    return parse_gltf(path.read_bytes(), path, animation, units=units)


def parse_gltf(
    data: bytes,
    path: str | Path,
    animation: str | int | None = None,
    *,
    units: str | float | None = None,
) -> Motion:
    """:func:`read_gltf` of the bytes of a file (``path`` names it and finds buffers beside
    it; it is not opened)."""
    import pygltflib

    path = Path(path)
    try:
        if data[:4] == b"glTF":
            gltf = pygltflib.GLTF2.load_from_bytes(data)
        else:
            text = data.decode("utf-8-sig")
            json.loads(text)  # a clear error for text that is no JSON
            gltf = pygltflib.GLTF2.from_json(text)
    except (ValueError, TypeError, KeyError, IndexError, AttributeError, struct.error) as error:
        raise FormatError(f"not a glTF 2.0 file ({error})", path) from None
    version = str(getattr(gltf.asset, "version", "") or "")
    if not version.startswith("2."):
        raise FormatError(f"asset.version is {version!r}: only glTF 2.0 is read", path)
    reader = _Reader(gltf, path, None if units is None else length_unit(units))
    try:
        return reader.motion(animation)
    except (IndexError, TypeError, KeyError) as error:
        raise FormatError(f"malformed glTF ({type(error).__name__}: {error})", path) from None


class _Reader:
    def __init__(self, gltf: Any, path: Path, cm_per_unit: float | None) -> None:
        self.gltf = gltf
        self.path = path
        self.metre = CM_PER_METRE if cm_per_unit is None else cm_per_unit
        self.given = cm_per_unit is not None
        self._buffers: dict[int, bytes] = {}

    def fail(self, message: str) -> FormatError:
        return FormatError(message, self.path)

    # --- data ---------------------------------------------------------------------------------

    def buffer(self, index: int) -> bytes:
        if index not in self._buffers:
            buffers = self.gltf.buffers or []
            if not 0 <= index < len(buffers):
                raise self.fail(f"buffers[{index}] does not exist")
            uri = buffers[index].uri
            if uri is None:
                blob = self.gltf.binary_blob()
                if blob is None:
                    raise self.fail(f"buffers[{index}] has no uri and the file no binary chunk")
            elif uri.startswith("data:"):
                try:
                    blob = base64.b64decode(uri.split(",", 1)[1])
                except (IndexError, ValueError):
                    raise self.fail(f"buffers[{index}].uri is not a base64 data URI") from None
            else:
                from urllib.parse import unquote

                sidecar = self.path.parent / unquote(uri)
                try:
                    blob = sidecar.read_bytes()
                except OSError as error:
                    raise self.fail(f"buffers[{index}]: cannot read {sidecar}: {error}") from None
            self._buffers[index] = blob
        return self._buffers[index]

    def accessor(self, index: int, kind: str, field: str) -> NDArray[np.float64]:
        accessors = self.gltf.accessors or []
        if not 0 <= index < len(accessors):
            raise self.fail(f"{field}: accessors[{index}] does not exist")
        acc = accessors[index]
        where = f"{field} (accessors[{index}])"
        if acc.type != kind:
            raise self.fail(f"{where} is {acc.type}, expected {kind}")
        if acc.componentType not in _DTYPES:
            raise self.fail(f"{where} has componentType {acc.componentType}")
        if acc.sparse is not None:
            raise self.fail(f"{where} is sparse, which is not read")
        width = _COMPONENTS[kind]
        dtype = np.dtype(_DTYPES[acc.componentType]).newbyteorder("<")
        count = int(acc.count)
        if acc.bufferView is None:
            return np.zeros((count, width))
        views = self.gltf.bufferViews or []
        if not 0 <= acc.bufferView < len(views):
            raise self.fail(f"{where}: bufferViews[{acc.bufferView}] does not exist")
        view = views[acc.bufferView]
        blob = self.buffer(view.buffer)
        start = (view.byteOffset or 0) + (acc.byteOffset or 0)
        element = width * dtype.itemsize
        stride = view.byteStride or element
        end = start + (stride * (count - 1) + element if count else 0)
        if end > (view.byteOffset or 0) + view.byteLength or end > len(blob):
            raise self.fail(f"{where} reads past the end of its buffer")
        raw = np.frombuffer(blob, dtype=np.uint8, count=end - start, offset=start)
        if stride == element:
            values = raw.view(dtype).reshape(count, width)
        else:
            padded = np.zeros(stride * count, dtype=np.uint8)
            padded[: len(raw)] = raw
            values = padded.reshape(count, stride)[:, :element].copy().view(dtype)
        values = values.astype(np.float64)
        if acc.normalized and acc.componentType in _NORMALIZED_MAX:
            values = np.maximum(values / _NORMALIZED_MAX[acc.componentType], -1.0)
        if not np.all(np.isfinite(values)):
            raise self.fail(f"{where} holds values that are not finite")
        return values

    # --- structure ----------------------------------------------------------------------------

    def joints(self) -> tuple[list[int], list[int], list[int], list[int]]:
        """Joint nodes parents first, their parents (joint positions), end-site nodes and their
        joints."""
        nodes = self.gltf.nodes or []
        if not nodes:
            raise self.fail("the file holds no nodes")
        parent_of: dict[int, int] = {}
        for n, node in enumerate(nodes):
            for child in node.children or []:
                if not 0 <= child < len(nodes):
                    raise self.fail(f"nodes[{n}].children names nodes[{child}], which is missing")
                if child in parent_of:
                    raise self.fail(f"nodes[{child}] has two parents")
                parent_of[child] = n
        skins = self.gltf.skins or []
        if skins:
            members = set(skins[0].joints or [])
            if not members or not all(0 <= j < len(nodes) for j in members):
                raise self.fail("skins[0].joints is empty or names missing nodes")
        else:
            scene = (self.gltf.scenes or [None])[self.gltf.scene or 0]
            roots = list(scene.nodes or []) if scene is not None else []
            roots = [r for r in roots if nodes[r].mesh is None] or roots
            if not roots:
                raise self.fail("no skin and no scene nodes: no skeleton to read")
            members = set()
            stack = roots[:1]
            while stack:
                n = stack.pop()
                if nodes[n].mesh is None and nodes[n].children:
                    members.add(n)
                    stack.extend(nodes[n].children)
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
                for child in reversed(nodes[n].children or []):
                    stack.append((child, here))
            elif nodes[n].mesh is None and not nodes[n].children and nodes[n].camera is None:
                sites.append(n)
                site_parents.append(parent)
        if len(order) != len(members):
            raise self.fail("skins[0].joints are not one tree under one root")
        return order, parents, sites, site_parents

    def ancestors(self, root: int) -> tuple[NDArray, NDArray, float]:
        """World rotation, translation and uniform scale of the root's parent."""
        nodes = self.gltf.nodes
        parent_of = {c: n for n, node in enumerate(nodes) for c in node.children or []}
        chain = []
        n = root
        while n in parent_of:
            n = parent_of[n]
            chain.append(n)
        rotation, translation, scale = quat.identity(()), np.zeros(3), 1.0
        for n in reversed(chain):
            r, t, s = self.rest(n)
            translation = translation + scale * quat.rotate(rotation, t)
            rotation = quat.multiply(rotation, r)
            scale *= s
        return rotation, translation, scale

    def rest(self, n: int) -> tuple[NDArray, NDArray, float]:
        node = self.gltf.nodes[n]
        if node.matrix is not None and list(node.matrix) != list(np.eye(4).ravel()):
            m = np.asarray(node.matrix, dtype=np.float64).reshape(4, 4).T
            scales = np.linalg.norm(m[:3, :3], axis=0)
            if not np.allclose(scales, scales[0], rtol=1e-6) or scales[0] <= 0:
                raise self.fail(f"nodes[{n}].matrix is not a rotation with a uniform scale")
            r = quat.from_matrix(m[:3, :3] / scales[0])
            return r, m[:3, 3].copy(), float(scales[0])
        t = np.asarray(node.translation or (0.0, 0.0, 0.0), dtype=np.float64)
        r = _wxyz(np.asarray(node.rotation or (0.0, 0.0, 0.0, 1.0), dtype=np.float64))
        s = np.asarray(node.scale or (1.0, 1.0, 1.0), dtype=np.float64)
        if not np.allclose(s, s[0], rtol=1e-6) or s[0] <= 0:
            raise self.fail(f"nodes[{n}].scale {s.tolist()} is not uniform and positive")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(r))):
            raise self.fail(f"nodes[{n}] has a transform that is not finite")
        return quat.normalize(r), t, float(s[0])

    def animation(self, wanted: str | int | None) -> tuple[int | None, Any]:
        animations = self.gltf.animations or []
        if wanted is None:
            return (0, animations[0]) if animations else (None, None)
        if isinstance(wanted, int) or (isinstance(wanted, str) and wanted.isdigit()):
            k = int(wanted)
            if not 0 <= k < len(animations):
                raise self.fail(f"no animation {k}: the file has {len(animations)}")
            return k, animations[k]
        names = [a.name for a in animations]
        if wanted not in names:
            raise self.fail(f"no animation named {wanted!r}; the file has {names}")
        return names.index(wanted), animations[names.index(wanted)]

    def channels(
        self, k: int | None, anim: Any, index: dict[int, int]
    ) -> tuple[dict[int, _Keys], dict[int, _Keys]]:
        """The animation's rotation and translation keyframes of each joint (by joint number),
        checked: a sampler that exists, as many values as times, times that never go back."""
        rotated: dict[int, _Keys] = {}
        moved: dict[int, _Keys] = {}
        for c, channel in enumerate((anim.channels or []) if anim is not None else []):
            target = channel.target
            j = index.get(target.node)
            if j is None or target.path not in ("rotation", "translation"):
                continue  # another node's, or weights and scale
            field = f"animations[{k}].channels[{c}]"
            if not 0 <= channel.sampler < len(anim.samplers or []):
                raise self.fail(f"{field}.sampler names a missing sampler")
            sampler = anim.samplers[channel.sampler]
            times = self.accessor(sampler.input, "SCALAR", f"{field} input")[:, 0]
            kind = "VEC4" if target.path == "rotation" else "VEC3"
            values = self.accessor(sampler.output, kind, f"{field} output")
            how = sampler.interpolation or "LINEAR"
            if how == "CUBICSPLINE":
                values = values[1::3]
            if len(values) != len(times) or not len(times):
                raise self.fail(f"{field}: {len(times)} times but {len(values)} values")
            if np.any(np.diff(times) < 0):
                raise self.fail(f"{field}: keyframe times go backwards")
            (rotated if target.path == "rotation" else moved)[j] = (times, values, how)
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
        site_offsets = np.array([self.rest(n)[1] for n in sites]).reshape(-1, 3) * cm
        k, anim = self.animation(wanted)
        rotated, moved = self.channels(k, anim, {n: j for j, n in enumerate(order)})
        keys = [t for t, _, _ in (*rotated.values(), *moved.values())]
        fps = 30.0 if anim is None else self._fps(anim, keys)
        frames = _frame_times(keys, fps)
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
        names = [self.gltf.nodes[n].name or f"node{n}" for n in order]
        site_names = [self.gltf.nodes[n].name or f"node{n}" for n in sites]
        name = self.path.stem
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
                "gltf_animation": None if anim is None else (anim.name or str(k)),
                **({"length_unit_given": True} if self.given else {}),
            },
        )
        try:
            return Motion(
                skeleton,
                fps,
                root,
                rotations,
                translations if joint_moves else None,
                name=name,
            )
        except ValueError as error:
            raise self.fail(str(error)) from None

    def _fps(self, anim: Any, times: list[NDArray]) -> float:
        extras = anim.extras if isinstance(anim.extras, dict) else {}
        fps = extras.get("fps")
        if isinstance(fps, int | float) and np.isfinite(fps) and fps > 0:
            return float(fps)
        steps = np.concatenate([np.diff(t) for t in times]) if times else np.zeros(0)
        steps = steps[steps > 0]
        if not len(steps):
            return 30.0
        fps = 1.0 / float(np.median(steps))
        return float(round(fps)) if abs(fps - round(fps)) <= 1e-3 * fps else fps


def _unique(names: list[str], taken: set[str] | None = None) -> list[str]:
    """Names made unique (glTF does not require it; a Skeleton does): ``name.1``, ``name.2``."""
    seen = set(taken or ())
    out = []
    for name in names:
        candidate, k = name, 1
        while candidate in seen:
            candidate, k = f"{name}.{k}", k + 1
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


def _frame_times(keys: list[NDArray], fps: float) -> NDArray:
    """The clip's frame times: from the first keyframe to the last at ``fps`` (none without
    keyframes)."""
    if not keys:
        return np.zeros(0)
    start = min(float(t[0]) for t in keys)
    end = max(float(t[-1]) for t in keys)
    return start + np.arange(int(round((end - start) * fps)) + 1) / fps


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
