"""Reading ASF skeletons (:func:`read_asf`, :func:`parse_asf`, :func:`asf_extras`) and the ASF's
bone layout (:func:`asf_bone_end_positions`); the conventions are :mod:`quatmotion.io.asf_amc`'s.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quatmotion import limits, quat
from quatmotion.errors import FormatError
from quatmotion.io._text import (
    check_count,
    fields,
    parse_float,
    parse_floats,
    parse_int,
    read_text,
)
from quatmotion.io.units import check_length_unit, length_unit
from quatmotion.motion import Motion, Skeleton, WorldTransforms, forward_kinematics

INCH_CM = 2.54

ROTATION_DOFS = {"rx": "x", "ry": "y", "rz": "z"}
_KNOWN_BONE_DOFS = {"rx", "ry", "rz", "l", "tx", "ty", "tz"}
_ROOT_CHANNELS = {"TX": "tx", "TY": "ty", "TZ": "tz", "RX": "rx", "RY": "ry", "RZ": "rz"}
_BEGIN_LINE = re.compile(r"^[ \t]*begin[ \t]*$", re.IGNORECASE | re.MULTILINE)


def _euler_order(token: str, path: Path, line: int) -> str:
    order = token.lower()
    if len(order) != 3 or set(order) != {"x", "y", "z"}:
        raise FormatError(f"expected an axis order such as XYZ, got {token!r}", path, line)
    return order


def _asf_lines(text: str) -> list[tuple[int, list[str]]]:
    """Non-empty lines as (line number, tokens), comments (``#`` to end of line) removed."""
    out = []
    for number, raw in enumerate(text.split("\n"), start=1):
        body = raw.split("#", 1)[0]
        tokens = fields(body)
        if tokens:
            out.append((number, tokens))
    return out


def _parse_limits(tokens: list[str], path: Path, line: int) -> tuple[str, str]:
    """``(lo hi)`` as two raw strings, each a number or +-inf."""
    joined = " ".join(tokens).replace("(", " ").replace(")", " ").split()
    if len(joined) != 2 or not "".join(tokens).startswith("(") or not "".join(tokens).endswith(")"):
        raise FormatError(f"expected limits '(lo hi)', got {' '.join(tokens)!r}", path, line)
    for value in joined:
        try:
            float(value)
        except ValueError:
            raise FormatError(f"bad limit {value!r}", path, line) from None
    return joined[0], joined[1]


def _parse_bone(block: list[tuple[int, list[str]]], path: Path, begin_line: int) -> dict[str, Any]:
    bone: dict[str, Any] = {"line": begin_line, "limits": [], "other": []}
    k = 0
    while k < len(block):
        line, tokens = block[k]
        key = tokens[0].lower()
        args = tokens[1:]
        if key == "id":
            if len(args) != 1:
                raise FormatError("expected 'id N'", path, line)
            bone["id"] = parse_int(args[0], path, line, "bone id")
        elif key == "name":
            if len(args) != 1:
                raise FormatError("expected 'name NAME'", path, line)
            bone["name"] = args[0]
        elif key == "direction":
            if len(args) != 3:
                raise FormatError(f"direction needs 3 values, got {len(args)}", path, line)
            bone["direction"] = tuple(parse_floats(args, path, line, "direction component"))
        elif key == "length":
            if len(args) != 1:
                raise FormatError("expected 'length VALUE'", path, line)
            bone["length"] = parse_float(args[0], path, line, "length")
            if bone["length"] < 0:
                raise FormatError("bone length is negative", path, line)
        elif key == "axis":
            if len(args) != 4:
                raise FormatError("expected 'axis a b c ORDER'", path, line)
            bone["axis"] = tuple(parse_floats(args[:3], path, line, "axis angle"))
            bone["axis_order"] = _euler_order(args[3], path, line)
        elif key == "dof":
            dofs = tuple(a.lower() for a in args)
            unknown = set(dofs) - _KNOWN_BONE_DOFS
            if unknown or len(set(dofs)) != len(dofs) or len(dofs) > 7:
                raise FormatError(f"bad dof list {' '.join(args)!r}", path, line)
            if set(dofs) & {"tx", "ty", "tz"}:
                raise FormatError("translation dofs on a bone are not supported", path, line)
            bone["dof"] = dofs
            bone["dof_line"] = line
        elif key == "limits":
            bone["limits"] = [_parse_limits(args, path, line)]
            # Further limits follow one per line, each starting with '('.
            while k + 1 < len(block) and block[k + 1][1][0].startswith("("):
                k += 1
                bone["limits"].append(_parse_limits(block[k][1], path, block[k][0]))
        else:
            bone["other"].append(" ".join(tokens))
        k += 1
    for required in ("name", "direction", "length", "axis"):
        if required not in bone:
            raise FormatError(f"bone has no {required!r}", path, begin_line)
    bone.setdefault("dof", ())
    bone.setdefault("id", None)
    if bone["limits"] and len(bone["limits"]) != len(bone["dof"]):
        raise FormatError(
            f"bone {bone['name']!r} has {len(bone['dof'])} dofs but {len(bone['limits'])} limits",
            path,
            begin_line,
        )
    return bone


def read_asf(path: str | Path, units: str | float | None = None) -> Skeleton:
    """Read an Acclaim ASF skeleton (CMU and HDM05 variants).

    Parameters
    ----------
    path : str or Path
    units : str, float or None
        A length unit replacing the one the file states (a name of
        :data:`quatmotion.io.units.LENGTH_UNITS` or centimetres per unit): for exporters whose
        ``:units length`` means something else (NaturalMotion's ``length 0.01`` for metres).
        Kept as ``extras["length_scale"]`` with ``extras["length_unit_given"] = True``.

    Returns
    -------
    Skeleton
        Root plus one joint per bone, offsets in centimetres, ``euler="extrinsic"``, ``axes``
        from the bones' ``axis``; end sites at the tips of leaf bones; ``extras`` as described
        in the module docstring. ``name`` is the file stem.

    Raises
    ------
    FormatError
        Naming the file and line, for anything malformed: missing ``:root``/``:bonedata``/
        ``:hierarchy``, unknown bones, bad numbers, cycles, unreachable bones...
    """
    path = Path(path)
    return parse_asf(read_text(path), path, units)


def parse_asf(text: str, path: str | Path, units: str | float | None = None) -> Skeleton:
    """Parse the text of an ASF file: :func:`read_asf` without reading a file.

    Parameters
    ----------
    text : str
        The whole ASF text.
    path : str or Path
        The name messages give and whose stem names the skeleton (it is not opened).
    units : str, float or None
        As for :func:`read_asf`.

    Returns
    -------
    Skeleton
        As :func:`read_asf` returns it.
    """
    path = Path(path)
    given = None if units is None else length_unit(units)
    # Each bone's 'begin', and the hierarchy's, in place of the root's: the joints, counted
    # before any line is split.
    begins = limits.current().joints
    check_count(text, _BEGIN_LINE, "joints", begins, path, "the bones and the root")
    sections = _AsfSections.split(_asf_lines(text), path)
    stated, to_cm, to_rad, angle_unit = _parse_units(sections.body.get("units", []), path)
    to_cm = to_cm if given is None else given
    root = _parse_root(sections.body["root"], path)
    bones = _parse_bones(sections.body["bonedata"], sections.line["bonedata"], path)
    parent_of, hierarchy = _parse_hierarchy(
        sections.body["hierarchy"], sections.line["hierarchy"], bones, path
    )
    order = _joint_order([b["name"] for b in bones], parent_of, sections.line["hierarchy"], path)
    extras = asf_extras(
        version=sections.header.get("version", "1.10"),
        name=sections.header.get("name", ""),
        documentation=tuple(" ".join(t) for _, t in sections.body.get("documentation", [])),
        units=tuple(stated),
        root={k: root[k] for k in ("order", "axis", "position", "orientation")},
        bones=bones,
        hierarchy=tuple(hierarchy),
        length_scale=to_cm,
        angle_unit=angle_unit,
    )
    if given is not None:
        extras["length_unit_given"] = True
    try:
        return _asf_skeleton(order, parent_of, root, bones, to_cm, to_rad, path, extras)
    except ValueError as error:  # e.g. lengths so large they overflow once in centimetres
        raise FormatError(str(error), path) from error


def asf_extras(
    *,
    version: str,
    name: str,
    documentation: Sequence[str],
    units: Sequence[tuple[str, str]],
    root: Mapping[str, Any],
    bones: Sequence[Mapping[str, Any]],
    hierarchy: Sequence[tuple[str, ...]],
    length_scale: float,
    angle_unit: str,
) -> dict[str, Any]:
    """The ASF bookkeeping of a skeleton, in the layout :func:`read_asf` gives ``extras`` and
    :func:`write_asf` / :func:`write_amc` read: the one constructor of that layout, for a
    skeleton made without a file (generated clips) to carry it.

    Parameters
    ----------
    version, name : str
        ``:version`` and ``:name``.
    documentation : sequence of str
        ``:documentation`` lines.
    units : sequence of (str, str)
        ``:units`` entries as written (``("length", "0.45")``).
    root : mapping
        ``order`` (tuple of str), ``axis`` (str), ``position`` and ``orientation`` (3 floats).
    bones : sequence of mapping
        One per bone, in file order: ``id``, ``name``, ``direction`` (3 floats, unit length),
        ``length`` (file units), ``axis`` (3 floats, degrees), ``axis_order``, ``dof`` (tuple of
        str), ``limits`` (a ``(low, high)`` pair of strings per dof) and ``other`` (extra
        lines, tuple).
    hierarchy : sequence of tuple of str
        ``(parent, child, ...)`` lines.
    length_scale : float
        Centimetres per file length unit.
    angle_unit : str
        ``"deg"`` or ``"rad"``.
    """
    return {
        "format": "asf",
        "asf_version": version,
        "asf_name": name,
        "asf_documentation": tuple(documentation),
        "asf_units": tuple(units),
        "asf_root": dict(root),
        "asf_bones": tuple(
            {
                "id": b["id"],
                "name": b["name"],
                "direction": b["direction"],
                "length": b["length"],
                "axis": b["axis"],
                "axis_order": b["axis_order"],
                "dof": b["dof"],
                "limits": tuple(b["limits"]),
                "other": tuple(b["other"]),
            }
            for b in bones
        ),
        "asf_hierarchy": tuple(hierarchy),
        "length_scale": length_scale,
        "angle_unit": angle_unit,
    }


@dataclass
class _AsfSections:
    """The ``:section`` blocks of an ASF: their lines, first line and header text."""

    body: dict[str, list[tuple[int, list[str]]]]
    line: dict[str, int]
    header: dict[str, str]

    @classmethod
    def split(cls, lines: list[tuple[int, list[str]]], path: Path) -> _AsfSections:
        out = cls({}, {}, {})
        current: str | None = None
        for line, tokens in lines:
            if tokens[0].startswith(":"):
                current = tokens[0][1:].lower()
                if current in out.body:
                    raise FormatError(f"section :{current} appears twice", path, line)
                out.body[current] = []
                out.line[current] = line
                out.header[current] = " ".join(tokens[1:])
                continue
            if current is None:
                raise FormatError(
                    f"text before the first section: {' '.join(tokens)!r}", path, line
                )
            out.body[current].append((line, tokens))
        for required in ("root", "bonedata", "hierarchy"):
            if required not in out.body:
                raise FormatError(f"missing :{required} section", path)
        return out


def _parse_units(
    block: list[tuple[int, list[str]]], path: Path
) -> tuple[list[tuple[str, str]], float, float, str]:
    """``:units``: the raw pairs, centimetres per length unit, radians per angle unit, and the
    angle unit's name."""
    units: list[tuple[str, str]] = []
    length_unit = 1.0
    angle_unit = "deg"
    for line, tokens in block:
        if len(tokens) != 2:
            raise FormatError("expected 'KEY VALUE' in :units", path, line)
        key = tokens[0].lower()
        if key == "length":
            length_unit = parse_float(tokens[1], path, line, "length unit")
            if length_unit <= 0:
                raise FormatError("length unit must be positive", path, line)
            try:  # one file unit is 1/length inch
                check_length_unit(INCH_CM / length_unit)
            except ValueError as error:
                raise FormatError(f":units length {tokens[1]}: {error}", path, line) from None
        elif key == "angle":
            angle_unit = tokens[1].lower()
            if angle_unit not in ("deg", "rad"):
                raise FormatError(f"angle unit must be deg or rad, got {tokens[1]!r}", path, line)
        elif key == "mass":
            parse_float(tokens[1], path, line, "mass")
        units.append((tokens[0], tokens[1]))
    to_rad = np.pi / 180.0 if angle_unit == "deg" else 1.0
    return units, INCH_CM / length_unit, to_rad, angle_unit


def _parse_root(block: list[tuple[int, list[str]]], path: Path) -> dict[str, Any]:
    """``:root``: channel order, axis order, position and orientation (file units)."""
    root: dict[str, Any] = {
        "order": ("TX", "TY", "TZ", "RX", "RY", "RZ"),
        "axis": "xyz",
        "position": (0.0, 0.0, 0.0),
        "orientation": (0.0, 0.0, 0.0),
    }
    for line, tokens in block:
        key, args = tokens[0].lower(), tokens[1:]
        if key == "order":
            order = tuple(a.upper() for a in args)
            if set(order) - set(_ROOT_CHANNELS) or len(set(order)) != len(order):
                raise FormatError(f"bad root order {' '.join(args)!r}", path, line)
            root["order"] = order
        elif key == "axis":
            if len(args) != 1:
                raise FormatError("expected 'axis ORDER' for the root", path, line)
            root["axis"] = _euler_order(args[0], path, line)
        elif key in ("position", "orientation"):
            if len(args) != 3:
                raise FormatError(f"root {key} needs 3 values, got {len(args)}", path, line)
            root[key] = tuple(parse_floats(args, path, line, f"root {key}"))
        else:
            raise FormatError(f"unknown root field {tokens[0]!r}", path, line)
    return root


def _parse_bones(
    block: list[tuple[int, list[str]]], section_line: int, path: Path
) -> list[dict[str, Any]]:
    """``:bonedata``: every ``begin ... end`` block, in file order, names unique."""
    bones: list[dict[str, Any]] = []
    lines: list[tuple[int, list[str]]] | None = None
    begin_line = section_line
    for line, tokens in block:
        key = tokens[0].lower()
        if key == "begin":
            if lines is not None:
                raise FormatError("'begin' inside a bone (missing 'end')", path, line)
            lines, begin_line = [], line
        elif key == "end":
            if lines is None:
                raise FormatError("'end' without 'begin'", path, line)
            limits.check("joints", len(bones) + 2, path, ":bonedata's bones and the root", line)
            bones.append(_parse_bone(lines, path, begin_line))
            lines = None
        elif lines is None:
            raise FormatError(f"text outside a bone's begin/end: {' '.join(tokens)!r}", path, line)
        else:
            lines.append((line, tokens))
    if lines is not None:
        raise FormatError("bone not closed by 'end' (file truncated?)", path, begin_line)
    if not bones:
        raise FormatError("no bones in :bonedata", path, section_line)
    names = [b["name"] for b in bones]
    if "root" in names or len(set(names)) != len(names):
        raise FormatError("bone names must be unique and not 'root'", path, section_line)
    return bones


def _parse_hierarchy(
    block: list[tuple[int, list[str]]],
    section_line: int,
    bones: list[dict[str, Any]],
    path: Path,
) -> tuple[dict[str, str], list[tuple[str, ...]]]:
    """``:hierarchy``: each bone's parent, and the raw lines (for the writer)."""
    known = {b["name"] for b in bones}
    parent_of: dict[str, str] = {}
    hierarchy: list[tuple[str, ...]] = []
    inside = False
    closed = False
    for line, tokens in block:
        key = tokens[0].lower()
        if key == "begin" and len(tokens) == 1 and not inside and not closed:
            inside = True
            continue
        if key == "end" and len(tokens) == 1 and inside:
            inside, closed = False, True
            continue
        if not inside:
            raise FormatError(f"hierarchy line outside begin/end: {' '.join(tokens)!r}", path, line)
        parent, children = tokens[0], tokens[1:]
        if parent != "root" and parent not in known:
            raise FormatError(f"unknown bone {parent!r} in hierarchy", path, line)
        for child in children:
            if child not in known:
                raise FormatError(f"unknown bone {child!r} in hierarchy", path, line)
            if child in parent_of:
                raise FormatError(f"bone {child!r} has two parents", path, line)
            parent_of[child] = parent
        hierarchy.append(tuple(tokens))
    if not closed:
        raise FormatError("hierarchy not closed by 'end' (file truncated?)", path, section_line)
    orphans = [b["name"] for b in bones if b["name"] not in parent_of]
    if orphans:
        raise FormatError(f"bones missing from the hierarchy: {orphans}", path, section_line)
    return parent_of, hierarchy


def _joint_order(
    names: list[str], parent_of: dict[str, str], section_line: int, path: Path
) -> list[str]:
    """Joints: the root, then the bones in file order if parents come first, else depth first."""
    order = ["root"]
    placed = {"root"}
    for n in names:
        if parent_of[n] not in placed:
            break
        placed.add(n)
    if len(placed) == len(names) + 1:
        return order + names
    children_of: dict[str, list[str]] = {}
    for n in names:
        children_of.setdefault(parent_of[n], []).append(n)
    stack = list(reversed(children_of.get("root", [])))
    while stack:
        n = stack.pop()
        order.append(n)
        stack.extend(reversed(children_of.get(n, [])))
    if len(order) != len(names) + 1:
        raise FormatError("the hierarchy has a cycle", path, section_line)
    return order


def _asf_skeleton(
    order: list[str],
    parent_of: dict[str, str],
    root: dict[str, Any],
    bones: list[dict[str, Any]],
    to_cm: float,
    to_rad: float,
    path: Path,
    extras: dict[str, Any],
) -> Skeleton:
    """The skeleton of the parsed sections: offsets, pre-rotations, channels, end sites."""
    by_name = {b["name"]: b for b in bones}
    index = {n: i for i, n in enumerate(order)}
    J = len(order)
    parents = np.full(J, -1, dtype=np.int64)
    offsets = np.zeros((J, 3))
    axes = np.zeros((J, 4))
    channels: list[tuple[str, ...]] = []
    site_names: list[str] = []
    site_parents: list[int] = []
    site_offsets: list[NDArray[np.float64]] = []
    bone_vectors = np.zeros((J, 3))
    offsets[0] = np.asarray(root["position"]) * to_cm
    axes[0] = quat.from_euler(np.asarray(root["orientation"]) * to_rad, root["axis"])
    by_order: dict[str, list[int]] = {}  # one vectorised Euler conversion per axis order
    channels.append(tuple(_ROOT_CHANNELS[c] for c in root["order"]))
    has_children = set(parent_of.values())
    for j, n in enumerate(order[1:], start=1):
        bone = by_name[n]
        bone_vectors[j] = np.asarray(bone["direction"]) * bone["length"] * to_cm
        parent = parent_of[n]
        parents[j] = index[parent]
        if parent != "root":
            offsets[j] = bone_vectors[index[parent]]
        by_order.setdefault(bone["axis_order"], []).append(j)
        channels.append(tuple(d for d in bone["dof"] if d in ROTATION_DOFS))
        if n not in has_children:
            site_names.append(f"{n}_end")
            site_parents.append(j)
            site_offsets.append(bone_vectors[j])
    for axis_order, joints in by_order.items():
        angles = np.array([by_name[order[j]]["axis"] for j in joints], dtype=np.float64)
        axes[joints] = quat.from_euler(angles * to_rad, axis_order)
    bone_vectors.setflags(write=False)
    return Skeleton(
        joint_names=tuple(order),
        parents=parents,
        offsets=offsets,
        channels=tuple(channels),
        euler="extrinsic",
        axes=axes,
        site_names=tuple(site_names),
        site_parents=np.asarray(site_parents, dtype=np.int64),
        site_offsets=np.asarray(site_offsets).reshape(-1, 3),
        name=path.stem,
        extras={**extras, "bone_vectors_cm": bone_vectors},
    )


def require_asf(skeleton: Skeleton, what: str) -> None:
    if skeleton.extras.get("format") != "asf":
        raise ValueError(
            f"{what} needs a skeleton read from an ASF file (skeleton {skeleton.name!r} has "
            f"format {skeleton.extras.get('format')!r})"
        )


def asf_names(skeleton: Skeleton, what: str) -> dict[str, str]:
    """Each bone name of the ASF bookkeeping (``extras``) -> the skeleton's joint name.

    The bookkeeping names the bones as the file did; the skeleton's joints may since have been
    renamed (a studio's names on CMU's skeleton). Joints are matched by position: the joint
    order the reader makes of the bookkeeping (:func:`_joint_order`) is the skeleton's, parent
    for parent, so the writers put the skeleton's names on the file's bones whatever they are.
    The root stays ``root`` (an ASF keyword).

    Raises
    ------
    ValueError
        If the skeleton's joints are not the bookkeeping's (other joints, other parents), or a
        name cannot stand in an ASF (empty, white space, ``#``, a second ``root``).
    """
    require_asf(skeleton, what)
    bones = [b["name"] for b in skeleton.extras["asf_bones"]]
    parent_of = {child: h[0] for h in skeleton.extras["asf_hierarchy"] for child in h[1:]}
    try:
        order = _joint_order(bones, parent_of, 0, Path(skeleton.name or "skeleton"))
    except (FormatError, KeyError):
        order = []
    parents = [-1] + [order.index(parent_of[n]) for n in order[1:]] if order else []
    if len(order) != skeleton.n_joints or not np.array_equal(parents, skeleton.parents):
        raise ValueError(
            f"{what}: skeleton {skeleton.name!r} has {skeleton.n_joints} joints that are not "
            f"the {len(order)} bones of the ASF it was read from (other joints or parents)"
        )
    names = {"root": "root"}
    for old, new in zip(order[1:], skeleton.joint_names[1:], strict=True):
        if not new or new == "root" or any(c.isspace() or c in "#()" for c in new):
            raise ValueError(f"{what}: joint name {new!r} cannot be written to an ASF")
        names[old] = new
    return names


def asf_bone_end_positions(
    motion: Motion, world: WorldTransforms | None = None
) -> NDArray[np.float64]:
    """Positions of the root and of every bone's END, in ASF file order.

    This is the layout of the CMU/HDM05 reference positions: index 0 the root position, then
    ``1 + b`` the end of the ``b``-th bone of the ASF file (its start plus
    ``global_rotation @ (direction * length)``).

    Parameters
    ----------
    motion : Motion
        On a skeleton read with :func:`read_asf`.
    world : WorldTransforms, optional
        ``forward_kinematics(motion)`` if already computed.

    Returns
    -------
    ndarray, shape (T, 1 + B, 3)
        Centimetres.
    """
    sk = motion.skeleton
    renamed = asf_names(sk, "asf_bone_end_positions")
    if world is None:
        world = forward_kinematics(motion, include_sites=False)
    joints = [sk.index(renamed[b["name"]]) for b in sk.extras["asf_bones"]]
    vectors = np.asarray(sk.extras["bone_vectors_cm"])[joints]
    ends = world.positions[:, joints] + quat.rotate(world.rotations[:, joints], vectors)
    return np.concatenate((world.positions[:, :1], ends), axis=1)
