"""Acclaim ASF (skeleton) and AMC (motion) files: readers and writers.

Conventions
-----------
* Lengths: ``:units length L`` means one file unit is ``1/L`` inch, so centimetres are
  ``value * 2.54 / L`` (CMU and HDM05 use ``L = 0.45``: one unit is about 5.644 cm). Missing
  ``length`` means ``L = 1`` (inches). ``mass`` is kept for the writer, not used. A unit
  outside :data:`quatmotion.io.units.LENGTH_UNIT_RANGE_CM` (``length 1e-300``) is refused.
* Bounds: the bones are counted before any line is split and parsed in linear time; bones,
  frames, frames x joints and the frame rate given are checked against
  :func:`quatmotion.limits.current` (a ``FormatError`` naming the file and line).
* Angles: ``:units angle deg|rad`` for the ASF; an AMC's ``:DEGREES`` / ``:RADIANS`` header
  decides for the AMC (the ASF's unit when neither is present). Radians inside.
* Euler angles (``axis``, ``orientation``, dof values) are extrinsic in the order listed: for
  ``axis a b c XYZ`` and ``dof rx ry rz`` the rotation is ``R = Rz @ Ry @ Rx``.
* Skeleton mapping: joint 0 is the root; every ASF bone becomes the joint at the bone's START.
  A joint's offset from its parent joint is the parent bone's ``direction * length`` (zero for
  the root's children), in centimetres; each leaf bone carries an end site at its own
  ``direction * length``. Rotation channels are the bone's dofs in file order, ``euler =
  "extrinsic"``, ``axes`` the bone's ``axis`` ``C``. The stored local rotation is ``C M C^-1``
  (``M`` the dof rotation), so a bone's global rotation is ``parent_global @ C @ M @ C^-1``.
* The root: ``order`` gives its channels; ``orientation`` (composed in the order of ``axis``)
  is its ``C``; ``position`` is its rest position (``offsets[0]``) and the AMC translation is
  added to it: ``root_translation = position + (TX, TY, TZ)``, in centimetres.
* Joints are listed root first, then the bones in ASF file order when that order already puts
  parents first (CMU, HDM05), otherwise in depth-first hierarchy order.
* ``dof l`` (bone length change) is read and ignored; :func:`write_amc` writes 0 for it. Bone
  translation dofs (``tx ty tz`` on a non-root bone) are not supported (FormatError).
* ``Skeleton.extras`` keeps what :func:`write_asf` needs: ``format="asf"``, ``asf_units``,
  ``asf_version``, ``asf_name``, ``asf_documentation``, ``asf_root`` and ``asf_bones`` (file
  order, each with id, name, direction, length, axis, dof, limits and other raw lines),
  ``asf_hierarchy``, ``length_scale`` (cm per unit), ``angle_unit``.
* The AMC frame rate is not in the file: ``fps`` defaults to 120 (CMU, HDM05).
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from quatmotion import limits, quat
from quatmotion.errors import FormatError
from quatmotion.io._text import (
    atomic_write,
    check_count,
    compose_joint_channels,
    decompose_channels,
    fields,
    parse_float,
    parse_floats,
    parse_int,
    read_text,
    scan_tokens,
    token_hash,
)
from quatmotion.io.units import check_length_unit, length_unit
from quatmotion.motion import Motion, Skeleton, WorldTransforms, forward_kinematics

__all__ = [
    "AsfMatch",
    "asf_bone_end_positions",
    "asf_extras",
    "asf_text",
    "find_asf_for_amc",
    "match_asf_for_amc",
    "parse_amc",
    "parse_asf",
    "read_amc",
    "read_asf",
    "write_amc",
    "write_asf",
]

INCH_CM = 2.54
DEFAULT_AMC_FPS = 120.0
_ROTATION_DOFS = {"rx": "x", "ry": "y", "rz": "z"}
_KNOWN_BONE_DOFS = {"rx", "ry", "rz", "l", "tx", "ty", "tz"}
_ROOT_CHANNELS = {"TX": "tx", "TY": "ty", "TZ": "tz", "RX": "rx", "RY": "ry", "RZ": "rz"}
_BEGIN_LINE = re.compile(r"^[ \t]*begin[ \t]*$", re.IGNORECASE | re.MULTILINE)
_INTEGER = re.compile(r"[+-]?\d+")


# --------------------------------------------------------------------------------------------
# ASF reading
# --------------------------------------------------------------------------------------------


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
        channels.append(tuple(d for d in bone["dof"] if d in _ROTATION_DOFS))
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


def _require_asf(skeleton: Skeleton, what: str) -> None:
    if skeleton.extras.get("format") != "asf":
        raise ValueError(
            f"{what} needs a skeleton read from an ASF file (skeleton {skeleton.name!r} has "
            f"format {skeleton.extras.get('format')!r})"
        )


def _asf_names(skeleton: Skeleton, what: str) -> dict[str, str]:
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
    _require_asf(skeleton, what)
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


# --------------------------------------------------------------------------------------------
# AMC reading
# --------------------------------------------------------------------------------------------


class AsfMatch(NamedTuple):
    """The ASF found for an AMC (:func:`match_asf_for_amc`) and the rule that found it."""

    path: Path
    rule: str
    """``"named for the AMC"``, ``"CMU naming"``, ``"HDM05 naming"`` or ``"the only ASF in
    its folder"``."""


def find_asf_for_amc(path: str | Path, folder: str | Path | None = None) -> Path:
    """The ASF that goes with an AMC: same name first, then the CMU or HDM05 conventions, then
    the only ASF of the folder (the path of :func:`match_asf_for_amc`).

    Raises
    ------
    FormatError
        As :func:`match_asf_for_amc`.
    """
    return match_asf_for_amc(path, folder).path


def match_asf_for_amc(path: str | Path, folder: str | Path | None = None) -> AsfMatch:
    """The ASF that goes with an AMC, and by which rule.

    In order: ``NAME.asf`` beside ``NAME.amc`` (where quatmotion writes it); CMU:
    ``SS_TT.amc`` -> ``SS.asf`` in the same folder; HDM05: ``clips/CLASS/HDM_AA_....amc`` ->
    ``../../skeletons/HDM_AA.asf`` or ``HDM_AA.asf`` in the same folder; else the one ASF in the
    AMC's folder (some exporters write ``skeleton.asf`` beside ``walking.amc``). With
    ``folder``, the same names are looked for in that folder instead (a folder of skeletons),
    then its only ASF.

    Raises
    ------
    FormatError
        If none is found, naming where it looked, or if the folder holds several ASF files and
        no name tells which (naming them); the message says to pass the skeleton.
    """
    path = Path(path)
    stem = path.stem
    parts = stem.split("_")
    candidates: list[tuple[Path, str]]
    if folder is not None:
        base = Path(folder)
        candidates = [(base / f"{stem}.asf", "named for the AMC")]
        if len(parts) >= 2:
            candidates += [
                (base / f"{parts[0]}.asf", "CMU naming"),
                (base / f"{parts[0]}_{parts[1]}.asf", "HDM05 naming"),
            ]
    else:
        base = path.parent
        candidates = [(path.with_suffix(".asf"), "named for the AMC")]
        if "_" in stem:
            candidates.append((path.with_name(stem.split("_", 1)[0] + ".asf"), "CMU naming"))
        if len(parts) >= 2 and parts[0].upper() == "HDM":
            actor = f"{parts[0]}_{parts[1]}.asf"
            candidates.append((path.parent.parent.parent / "skeletons" / actor, "HDM05 naming"))
            candidates.append((path.parent / actor, "HDM05 naming"))
    for candidate, rule in candidates:
        if candidate.is_file():
            return AsfMatch(candidate, rule)
    found = sorted(p for p in base.glob("*") if p.suffix.lower() == ".asf" and p.is_file())
    if len(found) == 1:
        return AsfMatch(found[0], "the only ASF in its folder")
    if found:
        listed = ", ".join(p.name for p in found[:6]) + (" ..." if len(found) > 6 else "")
        raise FormatError(
            f"cannot tell which ASF skeleton goes with this AMC: {base} holds {len(found)} ASF "
            f"files ({listed}) and none is named for it; pass one (--skeleton)",
            path,
        )
    raise FormatError(
        "cannot find the ASF skeleton for this AMC (looked for "
        f"{', '.join(str(c) for c, _ in candidates)}, and {base} holds no ASF file); "
        "pass it (--skeleton)",
        path,
    )


def _amc_header(text: str, path: Path) -> tuple[int, int, bool | None]:
    """Offset and line number where frames start (the end of the text for a header without
    frames: a clip of no frames), and whether angles are degrees (None: unsaid)."""
    degrees: bool | None = None
    offset = 0
    line = 1
    header = False
    while offset < len(text):
        end = text.find("\n", offset)
        end = len(text) if end < 0 else end
        stripped = text[offset:end].strip()
        if stripped and not stripped.startswith("#"):
            if stripped.startswith(":"):
                header = True
                key = stripped.split()[0].upper()
                if key == ":DEGREES":
                    degrees = True
                elif key == ":RADIANS":
                    degrees = False
            elif _INTEGER.fullmatch(stripped):
                return offset, line, degrees
            else:
                raise FormatError(f"expected a frame number, got {stripped[:40]!r}", path, line)
        offset = end + 1
        line += 1
    if header:
        return len(text), line, degrees
    raise FormatError("no frames and no header (file empty or truncated?)", path, line)


def _amc_layout(
    skeleton: Skeleton, body: str, path: Path, first_line: int
) -> tuple[list[str], list[int]]:
    """Bone names and value counts of the first frame, in the order written there."""
    dof_count = {b["name"]: len(b["dof"]) for b in skeleton.extras["asf_bones"]}
    dof_count["root"] = len(skeleton.channels[0])
    names: list[str] = []
    # The first frame is a few hundred bytes: split only a generous head of the body.
    head = body[: 64 * 1024]
    head_lines = head.split("\n")[1:]
    if len(head) < len(body):
        head_lines = head_lines[:-1]
    for k, raw in enumerate(head_lines, start=first_line + 1):
        tokens = fields(raw)
        if not tokens:
            continue
        if _INTEGER.fullmatch(tokens[0]) and len(tokens) == 1:
            break
        names.append(tokens[0])
        if tokens[0] not in dof_count:
            raise FormatError(f"unknown bone {tokens[0]!r}", path, k)
        if len(tokens) - 1 != dof_count[tokens[0]]:
            raise FormatError(
                f"bone {tokens[0]!r} needs {dof_count[tokens[0]]} values, got {len(tokens) - 1}",
                path,
                k,
            )
    listed = set(names)
    missing = [n for n, c in dof_count.items() if c and n not in listed]
    if missing:
        raise FormatError(f"frame 1 lacks bones {missing}", path, first_line)
    if len(set(names)) != len(names):
        raise FormatError("frame 1 lists a bone twice", path, first_line)
    return names, [dof_count[n] for n in names]


def _amc_values_fast(body: str, names: list[str], counts: list[int]) -> NDArray[np.float64] | None:
    """Values ``(T, sum(counts))`` if every frame has exactly the first one's layout.

    One compiled scan of the text, then vectorised checks of every frame's names, value counts,
    line structure and frame numbers. Returns None when anything differs; the line-by-line
    parser then either accepts the file (blank lines, comments, other bone orders) or names
    the offending line.
    """
    values, numeric, hashes, lines = scan_tokens(body)
    K = 1 + len(names) + sum(counts)
    if values.size == 0 or values.size % K:
        return None
    T = values.size // K
    values, numeric, hashes, lines = (a.reshape(T, K) for a in (values, numeric, hashes, lines))
    name_columns = np.cumsum([0] + [1 + c for c in counts])[:-1] + 1
    is_value = np.ones(K, dtype=bool)
    is_value[name_columns] = False
    is_value[0] = False
    expected_hashes = np.array([token_hash(n) for n in names], dtype=np.uint64)
    line_in_frame = np.zeros(K, dtype=np.int64)
    for b, column in enumerate(name_columns):
        line_in_frame[column:] = b + 1
    frames = values[:, 0]
    ok = (
        numeric[:, 0].all()
        and numeric[:, is_value].all()
        and not numeric[:, name_columns].any()
        and np.array_equal(
            hashes[:, name_columns], np.broadcast_to(expected_hashes, (T, len(names)))
        )
        and np.array_equal(lines - lines[:, :1], np.broadcast_to(line_in_frame, (T, K)))
        and np.all(np.diff(lines[:, 0]) == 1 + len(names))
        and np.array_equal(frames, frames[0] + np.arange(T))
        and np.isfinite(values).all()
    )
    return values[:, is_value] if ok else None


def _amc_values_careful(
    body: str, names: list[str], counts: list[int], path: Path, first_line: int, skeleton: Skeleton
) -> NDArray[np.float64]:
    """Line-by-line AMC frame parser: accepts any bone order per frame, names every error."""
    dof_count = {b["name"]: len(b["dof"]) for b in skeleton.extras["asf_bones"]}
    dof_count["root"] = len(skeleton.channels[0])
    start = {}
    column = 0
    for name, count in zip(names, counts, strict=True):
        start[name] = column
        column += count
    rows: list[NDArray[np.float64]] = []
    row: NDArray[np.float64] | None = None
    seen: set[str] = set()
    frame_line = first_line
    expected_frame: int | None = None

    def close_frame() -> None:
        if row is not None:
            missing = [n for n in names if n not in seen]
            if missing:
                raise FormatError(f"frame lacks bones {missing}", path, frame_line)
            rows.append(row)

    for line, raw in enumerate(body.split("\n"), start=first_line):
        tokens = fields(raw)
        if not tokens or tokens[0].startswith("#"):
            continue
        if len(tokens) == 1 and _INTEGER.fullmatch(tokens[0]):
            close_frame()
            number = int(tokens[0])
            if expected_frame is not None and number != expected_frame:
                raise FormatError(f"frame number {number}, expected {expected_frame}", path, line)
            expected_frame = number + 1
            row, seen, frame_line = np.zeros(column), set(), line
            continue
        name = tokens[0]
        if name not in dof_count:
            raise FormatError(f"unknown bone {name!r} (or a malformed frame number)", path, line)
        if name not in start:
            if dof_count[name] == 0 and len(tokens) == 1:
                continue
            raise FormatError(f"bone {name!r} was not in the first frame", path, line)
        if name in seen:
            raise FormatError(f"bone {name!r} listed twice in one frame", path, line)
        if len(tokens) - 1 != dof_count[name]:
            raise FormatError(
                f"bone {name!r} needs {dof_count[name]} values, got {len(tokens) - 1}", path, line
            )
        assert row is not None
        row[start[name] : start[name] + dof_count[name]] = parse_floats(
            tokens[1:], path, line, "angle"
        )
        seen.add(name)
    close_frame()
    return np.asarray(rows).reshape(len(rows), column)


def read_amc(
    path: str | Path,
    skeleton: Skeleton | str | Path | None = None,
    fps: float = DEFAULT_AMC_FPS,
    *,
    units: str | float | None = None,
) -> Motion:
    """Read an Acclaim AMC motion.

    Parameters
    ----------
    path : str or Path
    skeleton : Skeleton, str, Path or None
        The skeleton (read with :func:`read_asf`) or the path of its ASF. ``None`` looks for it
        by the CMU / HDM05 naming conventions (:func:`find_asf_for_amc`).
    fps : float
        Frame rate (AMC files do not store it); 120 for CMU and HDM05.
    units : str, float or None
        A length unit replacing the one the ASF states (see :func:`read_asf`); not with a
        ``Skeleton`` given (read it with the unit instead).

    Returns
    -------
    Motion
        ``rotations (T, J, 4)`` local ``C M C^-1``, ``root_translation (T, 3)`` centimetres.

    Raises
    ------
    FormatError
        Naming the file and line: unknown bones, wrong value counts, bad or non-finite
        numbers, missing bones in a frame, out-of-sequence frame numbers, no frames.
    """
    path = Path(path)
    if skeleton is None:
        skeleton = read_asf(find_asf_for_amc(path), units)
    elif not isinstance(skeleton, Skeleton):
        skeleton = read_asf(skeleton, units)
    elif units is not None:
        raise ValueError("a unit applies when the ASF is read: pass its path, not a Skeleton")
    _require_asf(skeleton, "read_amc")
    return parse_amc(read_text(path), path, skeleton, fps)


def parse_amc(
    text: str, path: str | Path, skeleton: Skeleton, fps: float = DEFAULT_AMC_FPS
) -> Motion:
    """Parse the text of an AMC file: :func:`read_amc` without reading a file.

    Parameters
    ----------
    text : str
        The whole AMC text.
    path : str or Path
        The name messages give and whose stem names the motion (it is not opened).
    skeleton : Skeleton
        Its ASF skeleton (:func:`read_asf` or :func:`parse_asf`).
    fps : float
        Frame rate (AMC files do not store it).

    Returns
    -------
    Motion
        As :func:`read_amc` returns it.
    """
    path = Path(path)
    _require_asf(skeleton, "parse_amc")
    limits.check("fps", fps, path, "the frame rate given")
    offset, first_line, degrees = _amc_header(text, path)
    if degrees is None:
        degrees = skeleton.extras["angle_unit"] == "deg"
    body = text[offset:]
    if not body.strip():
        names = ["root"] + [b["name"] for b in skeleton.extras["asf_bones"] if b["dof"]]
        counts = [len(skeleton.channels[0])] + [
            len(b["dof"]) for b in skeleton.extras["asf_bones"] if b["dof"]
        ]
        values = np.zeros((0, sum(counts)))
        return _motion_from_values(skeleton, values, names, counts, True, fps, path.stem)
    names, counts = _amc_layout(skeleton, body, path, first_line)
    values = _amc_values_fast(body, names, counts)
    if values is None:
        values = _amc_values_careful(body, names, counts, path, first_line, skeleton)
    limits.check("frames", len(values), path, "the frames")
    limits.check("joint_frames", len(values) * skeleton.n_joints, path, "frames x joints")
    limits.check("duration", len(values) / fps, path, f"the frames at {fps:g} frames/s")
    try:
        # As in read_bvh: the Motion checks name values that overflow once scaled.
        with np.errstate(over="ignore", invalid="ignore"):
            return _motion_from_values(skeleton, values, names, counts, degrees, fps, path.stem)
    except ValueError as error:  # e.g. translations so large they overflow once scaled
        raise FormatError(str(error), path) from error


def _motion_from_values(
    skeleton: Skeleton,
    values: NDArray[np.float64],
    names: Sequence[str],
    counts: Sequence[int],
    degrees: bool,
    fps: float,
    name: str,
) -> Motion:
    T = values.shape[0]
    J = skeleton.n_joints
    to_rad = np.pi / 180.0 if degrees else 1.0
    to_cm = skeleton.extras["length_scale"]
    dofs = {b["name"]: b["dof"] for b in skeleton.extras["asf_bones"]}
    dofs["root"] = skeleton.channels[0]
    root_translation = np.repeat(skeleton.offsets[:1], T, axis=0)
    columns = np.full((J, 3), -1, dtype=np.int64)
    letters = [""] * J
    column = 0
    index = {name: j for j, name in enumerate(skeleton.joint_names)}
    for bone, count in zip(names, counts, strict=True):
        j = index[bone]
        for k, d in enumerate(dofs[bone]):
            if d in _ROTATION_DOFS:
                columns[j, len(letters[j])] = column + k
                letters[j] += _ROTATION_DOFS[d]
            elif d in ("tx", "ty", "tz"):
                root_translation[:, "xyz".index(d[1])] += values[:, column + k] * to_cm
        column += count
    rotations = compose_joint_channels(values * to_rad, columns, letters, False, skeleton.axes)
    return Motion(
        skeleton=skeleton,
        fps=fps,
        root_translation=root_translation,
        rotations=rotations,
        name=name,
    )


# --------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------


def _g(value: float) -> str:
    return f"{value:.10g}"


def write_asf(skeleton: Skeleton, path: str | Path) -> None:
    """Write a skeleton read from an ASF back to an ASF file (atomically).

    The bones, units, ids, limits and hierarchy come from ``skeleton.extras`` (see the module
    docstring), so a read-write trip reproduces the file's content.

    Parameters
    ----------
    skeleton : Skeleton
        Read with :func:`read_asf` (``extras["format"] == "asf"``); ``ValueError`` otherwise.
    path : str or Path
    """
    atomic_write(path, asf_text(skeleton))


def asf_text(skeleton: Skeleton) -> str:
    """The ASF text :func:`write_asf` writes for ``skeleton`` (read from an ASF)."""
    names = _asf_names(skeleton, "write_asf")
    ex = skeleton.extras
    out = [f":version {ex['asf_version']}", f":name {ex['asf_name'] or skeleton.name}", ":units"]
    out += [f"  {k} {v}" for k, v in ex["asf_units"]]
    if ex["asf_documentation"]:
        out.append(":documentation")
        out += [f"  {d}" for d in ex["asf_documentation"]]
    root = ex["asf_root"]
    out += [
        ":root",
        f"   order {' '.join(root['order'])}",
        f"   axis {root['axis'].upper()}",
        f"   position {' '.join(_g(v) for v in root['position'])}",
        f"   orientation {' '.join(_g(v) for v in root['orientation'])}",
        ":bonedata",
    ]
    for bone in ex["asf_bones"]:
        out.append("  begin")
        if bone["id"] is not None:
            out.append(f"     id {bone['id']}")
        out.append(f"     name {names[bone['name']]}")
        out.append(f"     direction {' '.join(_g(v) for v in bone['direction'])}")
        out.append(f"     length {_g(bone['length'])}")
        out.append(
            f"     axis {' '.join(_g(v) for v in bone['axis'])} {bone['axis_order'].upper()}"
        )
        if bone["dof"]:
            out.append(f"    dof {' '.join(bone['dof'])}")
        for k, (lo, hi) in enumerate(bone["limits"]):
            out.append(f"    {'limits ' if k == 0 else '       '}({lo} {hi})")
        out += [f"     {o}" for o in bone["other"]]
        out.append("  end")
    out += [":hierarchy", "  begin"]
    out += [f"    {' '.join(names[n] for n in h)}" for h in ex["asf_hierarchy"]]
    out += ["  end", ""]
    return "\n".join(out)


def amc_channel_values(
    motion: Motion, degrees: bool = True
) -> tuple[list[str], list[int], NDArray[np.float64]]:
    """The AMC values of every frame of a motion on an ASF skeleton.

    Parameters
    ----------
    motion : Motion
        On a skeleton read with :func:`read_asf` (``ValueError`` otherwise).
    degrees : bool
        Angles in degrees (else radians).

    Returns
    -------
    names : list of str
        ``"root"`` then the bones with dofs, in ASF file order.
    counts : list of int
        Number of values of each.
    values : ndarray, shape (T, sum(counts))
        File units: angles in degrees (or radians), root translation in ASF length units
        (relative to the root ``position``); ``l`` dofs are 0.
    """
    sk = motion.skeleton
    renamed = _asf_names(sk, "write_amc")
    to_deg = 180.0 / np.pi if degrees else 1.0
    to_cm = sk.extras["length_scale"]
    T = motion.n_frames
    names = ["root"] + [renamed[b["name"]] for b in sk.extras["asf_bones"] if b["dof"]]
    dofs = {renamed[b["name"]]: b["dof"] for b in sk.extras["asf_bones"]}
    dofs["root"] = sk.channels[0]
    counts = [len(dofs[n]) for n in names]
    values = np.zeros((T, sum(counts)))
    c = sk.axes
    local_m = quat.multiply(quat.multiply(quat.conjugate(c), motion.rotations), c)
    groups: dict[str, tuple[list[int], list[list[int]]]] = {}
    column = 0
    for bone in names:
        letters = ""
        columns = []
        for k, d in enumerate(dofs[bone]):
            if d in _ROTATION_DOFS:
                letters += _ROTATION_DOFS[d]
                columns.append(column + k)
            elif d in ("tx", "ty", "tz"):
                axis = "xyz".index(d[1])
                values[:, column + k] = (
                    motion.root_translation[:, axis] - sk.offsets[0, axis]
                ) / to_cm
        column += len(dofs[bone])
        if letters:
            joints, cols = groups.setdefault(letters, ([], []))
            joints.append(0 if bone == "root" else sk.index(bone))
            cols.append(columns)
    for letters, (joints, cols) in groups.items():
        values[:, cols] = decompose_channels(local_m[:, joints], letters, intrinsic=False) * to_deg
    return names, counts, values


def write_amc(motion: Motion, path: str | Path) -> None:
    """Write a motion on an ASF skeleton as an AMC file (atomically), angles in degrees.

    Only the AMC is written; write the skeleton with :func:`write_asf` if it is needed too.
    Values are written with 10 significant digits (far below 1e-4 degree); each joint's
    angles are extracted for exactly its dofs (principal range: a file's angles within
    ``(-180, 180]``, the middle of three within ``[-90, 90]``, come back unchanged).

    Parameters
    ----------
    motion : Motion
        On a skeleton read with :func:`read_asf` (``ValueError`` otherwise).
    path : str or Path
    """
    names, counts, values = amc_channel_values(motion)
    frame_format = "%d\n" + "".join(
        f"{n}{' %.10g' * c}\n" for n, c in zip(names, counts, strict=True)
    )
    T = motion.n_frames
    table = np.concatenate((np.arange(1, T + 1, dtype=np.float64)[:, None], values), axis=1)
    header = "#!OML:ASF written by quatmotion\n:FULLY-SPECIFIED\n:DEGREES\n"
    body = (frame_format * T) % tuple(table.ravel().tolist()) if T else ""
    atomic_write(path, header + body)


# --------------------------------------------------------------------------------------------
# Reference layout
# --------------------------------------------------------------------------------------------


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
    renamed = _asf_names(sk, "asf_bone_end_positions")
    if world is None:
        world = forward_kinematics(motion, include_sites=False)
    joints = [sk.index(renamed[b["name"]]) for b in sk.extras["asf_bones"]]
    vectors = np.asarray(sk.extras["bone_vectors_cm"])[joints]
    ends = world.positions[:, joints] + quat.rotate(world.rotations[:, joints], vectors)
    return np.concatenate((world.positions[:, :1], ends), axis=1)
