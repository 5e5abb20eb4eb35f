"""Writing glTF 2.0 (:func:`gltf_bytes`, :func:`write_gltf`): one node per joint, a skin, one
animation; the conventions are :mod:`quatmotion.io.gltf`'s.
"""

from __future__ import annotations

import base64
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quatmotion import quat
from quatmotion._atomic import atomic_write_bytes
from quatmotion.io.gltf.spec import CM_PER_METRE, FLOAT, GLTF_SUFFIXES, xyzw
from quatmotion.motion import Motion, Skeleton


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
                componentType=FLOAT,
                count=len(data),
                type=kind,
                min=flat.min(axis=0).tolist() if bounds else None,
                max=flat.max(axis=0).tolist() if bounds else None,
            )
        )
        return len(self.accessors) - 1

    def bytes(self) -> bytes:
        return b"".join(self.chunks)


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
            rotation=xyzw(rest_rotation[j]).tolist(),
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
        animate(j, "rotation", blob.add(xyzw(motion.rotations[:, j]), "VEC4"))
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
