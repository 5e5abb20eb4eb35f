"""FBX (``.fbx``, binary or ASCII) in: the skeleton and one take, through ``ufbx``.

``ufbx`` (the Python wheel of the single-file C loader; no FBX SDK) parses the file and
evaluates every node's local transform as the FBX SDK defines it: pre- and post-rotations,
rotation order, pivots and offsets, inherit modes. This module only asks it for numbers and
turns them into a :class:`~quatmotion.motion.Motion`.

Conventions
-----------
* The skeleton: the limb and joint nodes (FBX ``LimbNode``/``Limb``/``Root``: ufbx's bone
  attribute) under one root, parents first, file order among siblings; nodes that are no bone
  but sit between two bones (a ``Null`` in a chain) are joints too. A file with several
  skeletons has its largest read (a ``FormatWarning`` names the others' roots); a file with no
  bone reads the node tree that holds no mesh, camera or light, when it has more than one node.
  A leaf named as an end (``*_end``, ``*_End``, ``*Nub``, ``*EndSite``) whose translation never
  moves is an end site, as a BVH's ``End Site``.
* Space: ufbx converts the file's axes to right-handed Y up (front +Z) and its unit to the
  centimetre; the transforms of the skeleton root's ancestors (an ``Armature`` node's turn and
  scale of 100, a scene's up-axis conversion) are composed into the root. The length unit the
  file states is kept as ``extras["length_scale"]`` (cm per file unit); ``units`` replaces it.
* Rotations: each joint's world rotation at rest (the nodes' transforms without animation) is
  taken out, so the skeleton's rest pose (every local rotation the identity) is the file's rest
  pose, as a BVH's, and the offsets are the rest pose's bones in the world frame. A joint's
  local rotation per frame is ``W_p R_j W_j^-1`` of its animated local rotation ``R_j`` and
  the rest world rotations ``W``. Positions are those the FBX SDK computes, to float rounding.
* A take (an FBX animation stack) is sampled at the file's frame rate (a rate within 0.1 % of
  a whole number is that number), from its start to its end, every frame evaluated by ufbx: no
  key reduction, no resampling of our own. A joint whose translation moves relative to its
  parent (beyond 1e-4 cm) makes the clip carry ``joint_translations``. A file without takes
  gives a clip of no frames. A take is named by its name, its short name
  (:func:`take_labels`: ``run`` of Blender's ``Armature|run``) or its position
  (:func:`take_index`); a collection makes a clip of every take of a file of several
  (:func:`quatmotion.collection.find_clips`).
* The skeleton's ``extras``: ``format="fbx"``, ``length_scale``, ``fbx_take`` (the take
  read), ``fbx_takes`` (every take's name), ``fbx_up`` (the file's up axis, ``"+Y"``...).

ufbx 0.0.5's Python binding has two faults that crash the interpreter (a segmentation fault,
not an exception), both guarded here and tested in a child process:

1. an element fetched from a list (``scene.nodes[i]``, ``scene.anim_stacks[i]``, iterating
   them) comes back one reference short: the binding's element cache keeps a pointer it does
   not own, so the second fetch, or the cache's own clean-up, touches a freed object.
   :func:`_element` gives the reference back (only when the binding is measured to be short:
   a fixed release is left alone);
2. a scene whose elements were fetched and that is left to Python's cycle collector (at
   interpreter exit, or any collection) crashes it. Every scene is freed explicitly
   (``scene.free()``) before its last reference goes, and nothing of ufbx outlives the read:
   everything is copied into NumPy first.
"""

from __future__ import annotations

import re
import sys
import traceback
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quatmotion import limits, quat
from quatmotion.errors import FormatError, FormatWarning, MissingDependencyError
from quatmotion.io.gltf.read import unique_names
from quatmotion.io.units import length_unit
from quatmotion.motion import Motion, Skeleton

__all__ = [
    "FBX_SUFFIXES",
    "fbx_takes",
    "parse_fbx",
    "read_fbx",
    "read_fbx_takes",
    "take_index",
    "take_labels",
]

FBX_SUFFIXES = (".fbx",)
CM_PER_METRE = 100.0
MOVING_TRANSLATION_CM = 1e-4
"""A joint whose offset from its parent varies more than this over a take carries
``joint_translations`` (float32 keys of centimetre translations vary by ~1e-6 cm)."""

_MODEL = re.compile(rb"^[ \t]*Model:", re.MULTILINE)
_NOT_IN_FILE_NAMES = re.compile(r'[\x00-\x1f/\\:*?"<>|]')
_END_NAME = re.compile(r"(?:[_\-.\s]end|nub|end_?site)$", re.IGNORECASE)


def read_fbx(
    path: str | Path, take: str | int | None = None, *, units: str | float | None = None
) -> Motion:
    """Read the skeleton and one take of an FBX file.

    Parameters
    ----------
    path : str or Path
        A binary or ASCII ``.fbx`` file.
    take : str, int or None
        The take (animation stack) by name or position; None reads the first (a
        ``FormatWarning`` names the others when there are several).
    units : str, float or None
        A length unit replacing the one the file states (a name of
        :data:`quatmotion.io.units.LENGTH_UNITS` or cm per file unit), for files written in
        the wrong unit. Kept with ``extras["length_unit_given"] = True``.

    Returns
    -------
    Motion
        Centimetres, Y up, local rotations w first.

    Raises
    ------
    FormatError
        Naming the file: not FBX, truncated or malformed, no skeleton, no such take.
    """
    path = Path(path)
    limits.check("file_bytes", path.stat().st_size, path, "the file's size")
    return parse_fbx(path.read_bytes(), path, take, units=units)


def parse_fbx(
    data: bytes,
    path: str | Path,
    take: str | int | None = None,
    *,
    units: str | float | None = None,
) -> Motion:
    """:func:`read_fbx` of the bytes of a file (``path`` only names it; it is not opened)."""
    path = Path(path)
    cm_given = None if units is None else length_unit(units)
    with _Scene(data, path) as loaded:
        return _Reader(loaded.scene, path).motion(take, cm_given)


def fbx_takes(data: bytes, path: str | Path) -> list[str]:
    """The names of the takes (animation stacks) of an FBX file's bytes, in file order."""
    with _Scene(data, Path(path)) as loaded:
        return [stack.name for stack in _elements(loaded.scene, loaded.scene.anim_stacks)]


def read_fbx_takes(path: str | Path) -> list[str]:
    """:func:`fbx_takes` of the file at ``path`` (its size checked first)."""
    path = Path(path)
    limits.check("file_bytes", path.stat().st_size, path, "the file's size")
    return fbx_takes(path.read_bytes(), path)


def take_labels(names: Sequence[str]) -> list[str]:
    """Short names of a file's takes, unique, for clip names (``walk/run``): the part after
    the last ``|`` (Blender writes ``Armature|run``) where those are unique, else the whole
    name; characters a file name cannot hold made ``_``; a take named by nothing usable, and
    one whose short name another took first, ``take{k}`` (its position)."""
    shorts = [name.rsplit("|", 1)[-1] for name in names]
    chosen = shorts if len(set(shorts)) == len(shorts) else list(names)
    labels: list[str] = []
    for k, name in enumerate(chosen):
        label = _NOT_IN_FILE_NAMES.sub("_", name).strip(" .")
        labels.append(label if label and label not in labels else f"take{k}")
    return labels


def take_index(names: Sequence[str], wanted: str | int, path: str | Path | None) -> int:
    """The position of the take ``wanted`` names among a file's takes ``names``: a take's
    name, else its short name (:func:`take_labels`), else a position from 0 (a take named
    ``"2"`` is that take, not the third).

    Raises
    ------
    FormatError
        Naming the file and its takes.
    """
    text = str(wanted)
    if text in names:
        return list(names).index(text)
    labels = take_labels(names)
    if text in labels:
        return labels.index(text)
    if isinstance(wanted, int) or text.isdigit():
        if not 0 <= int(text) < len(names):
            raise FormatError(f"no take {int(text)}: the file has {len(names)}", path)
        return int(text)
    raise FormatError(f"no take named {text!r}; the file has {list(names)}", path)


# --------------------------------------------------------------------------------------------
# The ufbx binding, guarded
# --------------------------------------------------------------------------------------------


def _ufbx() -> Any:
    try:
        import ufbx
    except ImportError as error:  # a dependency of the package, but an install can lack it
        raise MissingDependencyError(
            f"reading FBX needs the ufbx package ({error}): pip install 'ufbx>=0.0.5'"
        ) from None
    return ufbx


class _Scene:
    """A loaded ufbx scene (``with _Scene(...) as loaded``: ``loaded.scene``), freed on leaving
    the ``with`` block whatever happened (fault 2). The block's frame holds this holder, not
    the scene: a frame kept by an error's traceback then keeps no freed scene alive."""

    def __init__(self, data: bytes, path: Path) -> None:
        self.data = bytes(data)
        self.path = path
        self.scene: Any = None

    def __enter__(self) -> _Scene:
        ufbx = _ufbx()
        limits.check("file_bytes", len(self.data), self.path, "the file's size")
        if not self.data.lstrip()[:1]:
            raise FormatError("an empty file is no FBX", self.path)
        # ufbx reads every node before one can be counted (200,000 in a 57 MB file: 7 s): the
        # node records are counted in the bytes first, a binary one by its name's length byte
        # and name, an ASCII one by its line; the scene's root node is implicit.
        binary = self.data.startswith(b"Kaydara FBX Binary")
        records = self.data.count(b"\x05Model") if binary else len(_MODEL.findall(self.data))
        limits.check("joints", records + 1, self.path, "the file's nodes (Model records)")
        try:
            self.scene = ufbx.load_memory(
                self.data,
                file_format=ufbx.FileFormat.FBX,
                no_format_from_content=True,
                no_format_from_extension=True,
                ignore_geometry=True,
                ignore_embedded=True,
                load_external_files=False,
                target_axes=ufbx.axes_right_handed_y_up,
                target_unit_meters=1.0 / CM_PER_METRE,
                space_conversion=ufbx.SpaceConversion.TRANSFORM_ROOT,
                inherit_mode_handling=ufbx.InheritModeHandling.COMPENSATE,
                pivot_handling=ufbx.PivotHandling.RETAIN,
            )
        except ufbx.UfbxError as error:
            message = str(error).strip().splitlines()[0] if str(error).strip() else ""
            raise FormatError(
                f"not a readable FBX file ({type(error).__name__}: {message})", self.path
            ) from None
        return self

    def __exit__(self, kind: object, error: BaseException | None, trace: object) -> None:
        # An error leaving the read keeps the frames it passed through alive in its traceback,
        # and their ufbx elements with them: they are let go of while the scene still is (a
        # refused file whose error was kept, as a CLI test runner keeps it, crashed the cycle
        # collector's next pass after the scene was freed: a fuzz finding).
        seen: set[int] = set()
        while error is not None and id(error) not in seen:
            seen.add(id(error))
            traceback.clear_frames(error.__traceback__)
            error = error.__context__
        if self.scene is not None:
            self.scene.free()
            self.scene = None


_SHORT_REFERENCE: bool | None = None
"""Whether the binding returns list elements one reference short (fault 1), measured once."""


def _elements(scene: Any, listed: Any) -> list[Any]:
    """Every element of a ufbx element list, each fetched once, references made whole."""
    return [_element(listed, i) for i in range(len(listed))]


def _element(listed: Any, i: int) -> Any:
    """``listed[i]`` with the reference the binding forgets given back (fault 1).

    Measured on the first fetch of the process: a correct binding returns a new element with
    two references (the caller's and its cache's), plus ``getrefcount``'s own.
    """
    global _SHORT_REFERENCE
    element = listed[i]
    if _SHORT_REFERENCE is None:
        _SHORT_REFERENCE = sys.getrefcount(element) <= 2
    if _SHORT_REFERENCE:
        import ctypes

        increment = ctypes.pythonapi.Py_IncRef
        increment.argtypes = [ctypes.py_object]
        increment.restype = None
        increment(element)
    return element


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------


def _transform(t: Any) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
    """A ufbx Transform as (translation xyz, rotation wxyz, scale xyz)."""
    tr, r, s = t.translation, t.rotation, t.scale
    return (tr.x, tr.y, tr.z), (r.w, r.x, r.y, r.z), (s.x, s.y, s.z)


class _Reader:
    def __init__(self, scene: Any, path: Path) -> None:
        self.scene = scene
        self.path = path
        ufbx = _ufbx()
        self.bone_type = ufbx.ElementType.BONE
        self.other_types = {
            ufbx.ElementType.MESH,
            ufbx.ElementType.CAMERA,
            ufbx.ElementType.LIGHT,
        }

    def fail(self, message: str) -> FormatError:
        return FormatError(message, self.path)

    # --- structure ----------------------------------------------------------------------------

    def nodes(self) -> tuple[list[Any], list[int]]:
        """Every node (fetched once) and its parent's position in that list (-1: none)."""
        nodes = _elements(self.scene, self.scene.nodes)
        limits.check("joints", len(nodes), self.path, "the file's nodes")
        depth = max((int(node.node_depth) for node in nodes), default=0)
        limits.check("depth", depth, self.path, "the node hierarchy's depth")
        index = {node.element_id: k for k, node in enumerate(nodes)}
        parents = []
        for node in nodes:
            parent = node.parent
            parents.append(-1 if parent is None else index.get(parent.element_id, -1))
        return nodes, parents

    def skeleton_nodes(self, nodes: list[Any], parents: list[int]) -> tuple[list[int], list[int]]:
        """The joints (node positions, parents first) and their parents (joint positions)."""
        children: list[list[int]] = [[] for _ in nodes]
        for k, p in enumerate(parents):
            if p >= 0:
                children[p].append(k)
        bones = {k for k, node in enumerate(nodes) if node.attrib_type == self.bone_type}
        if bones:
            roots = [k for k in bones if not self._has_bone_above(k, parents, bones)]
        else:  # no limb nodes: the node tree of no mesh, camera or light
            bones = {
                k
                for k, node in enumerate(nodes)
                if parents[k] >= 0 and node.attrib_type not in self.other_types
            }
            roots = [k for k in bones if parents[k] not in bones]
        if not roots:
            raise self.fail("no skeleton: the file has no limb or joint nodes")
        members = {root: self._members(root, children, bones) for root in sorted(roots)}
        root = max(members, key=lambda r: len(members[r]))
        if len(members[root]) < 2:
            raise self.fail("no skeleton: no node tree of two joints or more")
        others = [nodes[r].name for r in members if r != root and len(members[r]) > 1]
        if others:
            warnings.warn(
                FormatWarning(
                    f"the file holds {len(others) + 1} skeletons: the largest, under "
                    f"{nodes[root].name!r} ({len(members[root])} joints), is read; not "
                    f"{', '.join(repr(o) for o in others[:5])}",
                    self.path,
                ),
                stacklevel=4,
            )
        keep = members[root]
        order: list[int] = []
        joint_parents: list[int] = []
        stack = [(root, -1)]
        while stack:
            k, parent = stack.pop()
            order.append(k)
            joint_parents.append(parent)
            here = len(order) - 1
            for child in reversed(children[k]):
                if child in keep:
                    stack.append((child, here))
        return order, joint_parents

    @staticmethod
    def _has_bone_above(k: int, parents: list[int], bones: set[int]) -> bool:
        p = parents[k]
        while p >= 0:
            if p in bones:
                return True
            p = parents[p]
        return False

    @staticmethod
    def _members(root: int, children: list[list[int]], bones: set[int]) -> set[int]:
        """The root, the bones below it and the nodes between them (a Null in a chain)."""
        keep: set[int] = set()

        def visit(k: int) -> bool:  # whether k or a node below is a bone
            below = [visit(c) for c in children[k]]
            if k in bones or any(below):
                keep.add(k)
                return True
            return False

        visit(root)
        return keep

    # --- the motion ---------------------------------------------------------------------------

    def takes(self) -> list[Any]:
        return _elements(self.scene, self.scene.anim_stacks)

    def choose_take(self, stacks: list[Any], wanted: str | int | None) -> Any:
        names = [s.name for s in stacks]
        if wanted is None:
            if len(stacks) > 1:
                warnings.warn(
                    FormatWarning(
                        f"the file holds {len(stacks)} takes ({', '.join(map(repr, names[:8]))}"
                        f"{'...' if len(names) > 8 else ''}); the first is read (--take NAME reads "
                        "another)",
                        self.path,
                    ),
                    stacklevel=4,
                )
            return stacks[0] if stacks else None
        return stacks[take_index(names, wanted, self.path)]

    def frame_rate(self) -> tuple[float, float]:
        """(the rate frames are evaluated at, the rate reported), frames per second."""
        fps = float(self.scene.settings.frames_per_second)
        limits.check("fps", fps, self.path, "the frame rate")
        rounded = float(round(fps))
        return fps, rounded if rounded and abs(fps - rounded) <= 1e-3 * fps else fps

    def motion(self, wanted: str | int | None, cm_given: float | None) -> Motion:
        nodes, parents = self.nodes()
        order, joint_parents = self.skeleton_nodes(nodes, parents)
        chain = []  # the skeleton root's ancestors, from the scene's root down
        p = parents[order[0]]
        while p >= 0:
            chain.append(p)
            p = parents[p]
        chain.reverse()
        evaluated = [nodes[k] for k in (*chain, *order)]
        limits.check("joints", len(order), self.path, "the skeleton's joints")
        stacks = self.takes()
        stack = self.choose_take(stacks, wanted)
        fps_file, fps = self.frame_rate()
        if stack is None:
            times = np.zeros(0)
        else:
            begin, end = float(stack.time_begin), float(stack.time_end)
            if not (np.isfinite(begin) and np.isfinite(end)) or end < begin:
                raise self.fail(f"take {stack.name!r} runs from {begin} s to {end} s")
            field = f"take {stack.name!r}'s"
            limits.check("duration", end - begin, self.path, f"{field} duration")
            count = int(round((end - begin) * fps_file)) + 1
            limits.check("frames", count, self.path, f"{field} frames")
            nodes_frames = count * len(evaluated)
            limits.check("joint_frames", nodes_frames, self.path, f"{field} nodes x frames")
            times = begin + np.arange(count) / fps_file
        rest = [_transform(node.local_transform) for node in evaluated]
        anim = None if stack is None else stack.anim
        frames = [
            [_transform(node.evaluate_transform(anim, float(t))) for node in evaluated]
            for t in times
        ]
        up = _axis_name(self.scene.settings.axes.up)  # the file's, before conversion
        stated_cm = float(self.scene.settings.original_unit_meters) * CM_PER_METRE
        if not np.isfinite(stated_cm) or stated_cm <= 0:
            stated_cm = CM_PER_METRE / 100.0  # FBX's default unit: the centimetre
        scale = 1.0 if cm_given is None else cm_given / stated_cm
        names = [nodes[k].name or f"node{k}" for k in order]
        extras = {
            "format": "fbx",
            "length_scale": stated_cm if cm_given is None else cm_given,
            "fbx_take": None if stack is None else stack.name,
            "fbx_takes": tuple(s.name for s in stacks),
            "fbx_up": up,
            **({"length_unit_given": True} if cm_given is not None else {}),
        }
        return _build(
            rest,
            frames,
            n_chain=len(chain),
            joint_parents=joint_parents,
            names=names,
            scale=scale,
            fps=fps,
            extras=extras,
            name=self.path.stem,
            path=self.path,
        )


def _axis_name(axis: Any) -> str | None:
    name = getattr(axis, "name", "")
    if not name or name == "UNKNOWN":
        return None
    sign, _, letter = name.partition("_")
    return ("+" if sign == "POSITIVE" else "-") + letter


def _world(
    translations: NDArray, rotations: NDArray, scales: NDArray, parents: list[int]
) -> tuple[NDArray, NDArray]:
    """World rotations (wxyz, ``(T, N, 4)``) and positions (``(T, N, 3)``) of nodes listed
    parents first (``parents[k] < k``, -1 for none), from local translations, rotations (wxyz)
    and scales ``(T, N, ...)``: ``M = M_parent @ (T R S)``. Uniform scales (every rig we know)
    compose as quaternions and a factor; others as matrices, the rotation taken from each."""
    T, N = translations.shape[:2]
    position = np.empty((T, N, 3))
    if np.allclose(scales, scales[..., :1], rtol=1e-5, atol=0.0) and np.all(scales > 0):
        factor = scales[..., 0]
        rotation = np.empty((T, N, 4))
        world_factor = np.empty((T, N))
        for k in range(N):
            p = parents[k]
            if p < 0:
                rotation[:, k], position[:, k] = rotations[:, k], translations[:, k]
                world_factor[:, k] = factor[:, k]
                continue
            moved = quat.rotate(rotation[:, p], translations[:, k])
            position[:, k] = position[:, p] + world_factor[:, p, None] * moved
            rotation[:, k] = quat.multiply(rotation[:, p], rotations[:, k])
            world_factor[:, k] = world_factor[:, p] * factor[:, k]
        return quat.normalize(rotation), position
    local = quat.to_matrix(rotations) * scales[..., None, :]
    linear = np.empty((T, N, 3, 3))
    for k in range(N):
        p = parents[k]
        if p < 0:
            linear[:, k], position[:, k] = local[:, k], translations[:, k]
        else:
            linear[:, k] = linear[:, p] @ local[:, k]
            position[:, k] = position[:, p] + np.einsum(
                "tij,tj->ti", linear[:, p], translations[:, k]
            )
    columns = np.linalg.norm(linear, axis=-2, keepdims=True)
    unscaled = linear / np.where(columns > 0, columns, 1.0)
    return quat.normalize(quat.from_matrix(unscaled)), position


def _transforms(rows: list, n: int, path: Path) -> tuple[NDArray, NDArray, NDArray]:
    """Translations ``(T, n, 3)``, unit rotations (wxyz) ``(T, n, 4)`` and scales ``(T, n, 3)``
    of ``rows`` (per frame, per node, :func:`_transform`'s triples), checked.

    Raises
    ------
    FormatError
        A value not finite, a scale that is zero or mirrors, a rotation of zero.
    """
    T = len(rows)
    t, r, s = (
        np.array([[node[part] for node in row] for row in rows], dtype=np.float64).reshape(
            T, n, width
        )
        for part, width in ((0, 3), (1, 4), (2, 3))
    )
    if not all(np.all(np.isfinite(a)) for a in (t, r, s)):
        raise FormatError("a node's transform is not finite", path)
    if not np.all(np.prod(s, axis=-1) > 0):  # a mirror or a collapse is no rotation (fuzzed)
        raise FormatError("a node's scale is zero or mirrors it (negative): not read", path)
    largest = np.max(np.abs(r), axis=-1, keepdims=True)  # scaled first: a norm of huge
    if not np.all(largest > 0):  # components overflows
        raise FormatError("a node's rotation is zero, no rotation: not read", path)
    r /= largest
    r /= np.linalg.norm(r, axis=-1, keepdims=True)
    return t, r, s


def _end_sites(names: list[str], parents: NDArray, moving: NDArray) -> NDArray:
    """Which joints are end sites: leaves named as ends whose translation never moves (never
    the root)."""
    leaves = np.ones(len(names), dtype=bool)
    leaves[parents[1:]] = False
    named = np.array([bool(_END_NAME.search(n)) for n in names])
    is_site = leaves & ~moving & named
    is_site[0] = False
    return is_site


def _build(
    rest: list,
    frames: list,
    *,
    n_chain: int,
    joint_parents: list[int],
    names: list[str],
    scale: float,
    fps: float,
    extras: dict,
    name: str,
    path: Path,
) -> Motion:
    """The Motion of nodes' local transforms: ``rest`` per node, ``frames`` per frame per node
    (the root's ancestors first, ``n_chain`` of them, then the joints)."""
    N, T, J = len(rest), len(frames), len(rest) - n_chain
    parents = [k - 1 for k in range(n_chain)]  # the ancestors: a chain
    parents += [(n_chain - 1) if p < 0 else n_chain + p for p in joint_parents]
    try:
        rest_world, rest_position = _world(*_transforms([rest], N, path), parents)
        animated_world, position = _world(*_transforms(frames, N, path), parents)
    except ValueError:  # scipy: a matrix that is no rotation (fuzz findings)
        raise FormatError(
            "a node's world transform is no rotation (degenerate or mirrored): not read", path
        ) from None
    rest_position = rest_position[0, n_chain:] * scale
    position = position[:, n_chain:] * scale
    # G'_j = G_j W_j^-1: the world rotation relative to the rest pose's W_j
    world = quat.multiply(animated_world[:, n_chain:], quat.conjugate(rest_world[0, n_chain:]))
    jp = np.asarray(joint_parents, dtype=np.int64)
    offsets = rest_position.copy()
    offsets[1:] -= rest_position[jp[1:]]
    local = world.copy()
    local[:, 1:] = quat.multiply(quat.conjugate(world[:, jp[1:]]), world[:, 1:])
    moved = np.zeros((T, J, 3))
    moved[:, 1:] = quat.rotate(
        quat.conjugate(world[:, jp[1:]]), position[:, 1:] - position[:, jp[1:]]
    )
    drift = np.abs(moved[:, 1:] - offsets[None, 1:]).max(axis=(0, 2)) if T else np.zeros(J - 1)
    moving = np.concatenate(([False], drift > MOVING_TRANSLATION_CM))
    is_site = _end_sites(names, jp, moving)
    keep, sites = np.flatnonzero(~is_site), np.flatnonzero(is_site)
    renumber = -np.ones(J, dtype=np.int64)
    renumber[keep] = np.arange(len(keep))
    kept_names = unique_names([names[j] for j in keep])
    try:
        skeleton = Skeleton(
            joint_names=tuple(kept_names),
            parents=np.array([-1] + [renumber[jp[j]] for j in keep[1:]], dtype=np.int64),
            offsets=offsets[keep],
            channels=tuple(
                (("tx", "ty", "tz") if j == 0 or moving[j] else ()) + ("rz", "ry", "rx")
                for j in keep
            ),
            euler="intrinsic",
            site_names=tuple(unique_names([names[s] for s in sites], taken=set(kept_names))),
            site_parents=renumber[jp[sites]],
            site_offsets=offsets[sites],
            name=name,
            extras=extras,
        )
        translations = None
        if moving.any():
            translations = np.where(moving[None, keep, None], moved[:, keep], offsets[None, keep])
        return Motion(
            skeleton,
            fps,
            position[:, 0] if T else np.zeros((0, 3)),
            local[:, keep] if T else np.zeros((0, len(keep), 4)),
            translations,
            name=name,
        )
    except ValueError as error:  # e.g. offsets that overflow once scaled (a fuzz finding)
        raise FormatError(str(error), path) from None
