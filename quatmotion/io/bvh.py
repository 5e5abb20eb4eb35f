"""Biovision BVH files: reader and writer.

Conventions
-----------
* Joints are listed in file order (depth first, so parents come first); ``End Site`` blocks
  become end sites named ``<joint>_end``. Any channel order is accepted, with 0 to 6 channels
  per joint (``Xposition``... and ``Xrotation``..., case-insensitive).
* Rotations compose intrinsically in channel order: for ``Zrotation Xrotation Yrotation`` the
  local rotation is ``Rz @ Rx @ Ry`` (``Skeleton.euler == "intrinsic"``). Angles in the file are
  degrees.
* Position channels are the joint's local translation: they replace its ``OFFSET`` (component
  by component). Root position channels give ``Motion.root_translation``; position channels on
  other joints (Bandai: six channels on every joint) give ``Motion.joint_translations``.
* Units: BVH has no unit field. ``read_bvh(path, scale=...)`` takes the number of centimetres
  per file unit; ``scale="auto"`` (the default) looks at the rest skeleton's largest extent
  (the standing height, or the arm span of a T-pose) and picks, among centimetres (1),
  millimetres (0.1), metres (100), inches (2.54) and the CMU/ASF unit of 1/0.45 inch
  (2.54 / 0.45), the one that makes it closest to 170 cm (in ratio). Bandai files come out in
  centimetres, the CMU BVH conversion in the ASF unit. The scale is kept in
  ``Skeleton.extras["bvh_scale"]`` and :func:`write_bvh` writes in the same unit, so a
  read-write trip keeps the file's numbers.
* Frame rate: ``1 / Frame Time``, rounded to the nearest integer when within 0.01 % of it
  (files store ``0.0333333`` for 30 frames/s).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from quatmotion import quat
from quatmotion.errors import FormatError
from quatmotion.io._text import (
    atomic_write,
    compose_joint_channels,
    decompose_channels,
    parse_float,
    parse_floats,
    parse_int,
    read_text,
    scan_tokens,
)
from quatmotion.motion import Motion, Skeleton

__all__ = [
    "bvh_text",
    "detect_bvh_scale",
    "parse_bvh",
    "read_bvh",
    "to_bvh_skeleton",
    "write_bvh",
]

_CHANNEL_TOKENS = {
    "xposition": "tx",
    "yposition": "ty",
    "zposition": "tz",
    "xrotation": "rx",
    "yrotation": "ry",
    "zrotation": "rz",
}
_FILE_CHANNELS = {v: k[0].upper() + k[1:] for k, v in _CHANNEL_TOKENS.items()}
UNIT_CANDIDATES_CM = {"cm": 1.0, "mm": 0.1, "m": 100.0, "inch": 2.54, "asf": 2.54 / 0.45}
TYPICAL_HEIGHT_CM = 170.0
_MAX_DEPTH = 200  # far deeper than any body; keeps recursion bounded on hostile input


class _Tokens:
    """Hierarchy tokens with their line numbers, consumed front to back."""

    def __init__(self, tokens: list[tuple[str, int]], path: Path, end_line: int):
        self.tokens = tokens
        self.position = 0
        self.path = path
        self.end_line = end_line

    def next(self, what: str) -> tuple[str, int]:
        if self.position >= len(self.tokens):
            raise FormatError(
                f"file ends where {what} was expected (truncated?)", self.path, self.end_line
            )
        token = self.tokens[self.position]
        self.position += 1
        return token

    def peek(self) -> str | None:
        return self.tokens[self.position][0] if self.position < len(self.tokens) else None

    def expect(self, word: str) -> int:
        token, line = self.next(repr(word))
        if token.upper() != word.upper():
            raise FormatError(f"expected {word!r}, got {token!r}", self.path, line)
        return line

    def floats(self, n: int, what: str) -> list[float]:
        out = []
        for _ in range(n):
            token, line = self.next(what)
            out.append(parse_float(token, self.path, line, what))
        return out


def _parse_hierarchy(tokens: _Tokens):
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []
    site_names: list[str] = []
    site_parents: list[int] = []
    site_offsets: list[list[float]] = []
    path = tokens.path

    def joint(parent: int, name: str, name_line: int, depth: int = 0) -> None:
        if depth > _MAX_DEPTH:
            raise FormatError(f"joints nested more than {_MAX_DEPTH} deep", path, name_line)
        if name in names:
            raise FormatError(f"joint name {name!r} appears twice", path, name_line)
        j = len(names)
        names.append(name)
        parents.append(parent)
        tokens.expect("{")
        tokens.expect("OFFSET")
        offsets.append(tokens.floats(3, "OFFSET value"))
        chans: tuple[str, ...] = ()
        if (tokens.peek() or "").upper() == "CHANNELS":
            tokens.next("CHANNELS")
            count_token, line = tokens.next("channel count")
            count = parse_int(count_token, path, line, "channel count")
            if not 0 <= count <= 6:
                raise FormatError(f"a joint has 0 to 6 channels, got {count}", path, line)
            listed = []
            for _ in range(count):
                token, line = tokens.next("channel name")
                if token.lower() not in _CHANNEL_TOKENS:
                    raise FormatError(f"unknown channel {token!r}", path, line)
                listed.append(_CHANNEL_TOKENS[token.lower()])
            if len(set(listed)) != len(listed):
                raise FormatError("a channel is listed twice", path, line)
            chans = tuple(listed)
        channels.append(chans)
        while True:
            token, line = tokens.next("JOINT, End Site or '}'")
            upper = token.upper()
            if upper == "}":
                return
            if upper == "JOINT":
                child, child_line = tokens.next("joint name")
                joint(j, child, child_line, depth + 1)
            elif upper == "END":
                tokens.expect("Site")
                tokens.expect("{")
                tokens.expect("OFFSET")
                site_offsets.append(tokens.floats(3, "End Site OFFSET value"))
                tokens.expect("}")
                site_names.append(
                    f"{name}_end"
                    if f"{name}_end" not in site_names
                    else f"{name}_end{len(site_names)}"
                )
                site_parents.append(j)
            else:
                raise FormatError(f"expected JOINT, End Site or '}}', got {token!r}", path, line)

    tokens.expect("HIERARCHY")
    tokens.expect("ROOT")
    root_name, root_line = tokens.next("root name")
    joint(-1, root_name, root_line)
    return names, parents, offsets, channels, site_names, site_parents, site_offsets


def detect_bvh_scale(rest_positions: NDArray[np.float64]) -> float:
    """Centimetres per file unit that make a rest skeleton human-sized.

    Parameters
    ----------
    rest_positions : ndarray, shape (N, 3)
        Joint and end-site positions at rest, in file units.

    Returns
    -------
    float
        The value of :data:`UNIT_CANDIDATES_CM` that brings the largest extent closest (in
        ratio) to 170 cm; 1.0 for a degenerate skeleton.
    """
    extent = float(np.max(np.ptp(rest_positions, axis=0))) if len(rest_positions) else 0.0
    if not np.isfinite(extent) or extent <= 0:
        return 1.0
    scales = np.array(list(UNIT_CANDIDATES_CM.values()))
    return float(scales[np.argmin(np.abs(np.log(extent * scales / TYPICAL_HEIGHT_CM)))])


def _frame_values(
    block: str, first_line: int, n_frames: int, n_channels: int, path: Path
) -> NDArray[np.float64]:
    """The ``(n_frames, n_channels)`` table; bulk path first, line by line to explain errors."""
    values, numeric, _, lines = scan_tokens(block)
    if (
        values.size == n_frames * n_channels
        and n_channels > 0
        and numeric.all()
        and np.isfinite(values).all()
    ):
        lines = lines.reshape(n_frames, n_channels)
        if np.all(lines == lines[:, :1]) and np.all(np.diff(lines[:, 0]) == 1):
            return values.reshape(n_frames, n_channels)
    rows: list[list[float]] = []
    for line, raw in enumerate(block.split("\n"), start=first_line):
        tokens = raw.split()
        if not tokens:
            continue
        if len(tokens) != n_channels:
            raise FormatError(f"frame has {len(tokens)} values, expected {n_channels}", path, line)
        if len(rows) == n_frames:
            raise FormatError(f"more frames than the {n_frames} announced in 'Frames:'", path, line)
        rows.append(parse_floats(tokens, path, line, "channel value"))
    if len(rows) != n_frames:
        raise FormatError(
            f"'Frames:' announces {n_frames} frames but the file has {len(rows)} (truncated?)",
            path,
            first_line + block.count("\n"),
        )
    return np.asarray(rows, dtype=np.float64).reshape(n_frames, n_channels)


def read_bvh(path: str | Path, scale: float | Literal["auto"] = "auto") -> Motion:
    """Read a BVH file.

    Parameters
    ----------
    path : str or Path
    scale : float or "auto"
        Centimetres per file unit; ``"auto"`` detects it from the rest skeleton's size (see
        the module docstring and :func:`detect_bvh_scale`).

    Returns
    -------
    Motion
        Skeleton with ``euler="intrinsic"``, offsets in centimetres, ``extras`` with
        ``format="bvh"`` and ``bvh_scale``; ``joint_translations`` when joints other than the
        root have position channels.

    Raises
    ------
    FormatError
        Naming the file and line: bad hierarchy, unknown channels, missing ``MOTION``,
        frame count or value count mismatches, bad or non-finite numbers.
    """
    path = Path(path)
    return parse_bvh(read_text(path), path, scale)


def parse_bvh(text: str, path: str | Path, scale: float | Literal["auto"] = "auto") -> Motion:
    """Parse the text of a BVH file: :func:`read_bvh` without reading a file.

    Parameters
    ----------
    text : str
        The whole BVH text.
    path : str or Path
        The name messages give and whose stem names the motion (it is not opened).
    scale : float or "auto"
        As for :func:`read_bvh`.

    Returns
    -------
    Motion
    """
    path = Path(path)
    head_end, motion_line, found = _find_motion_keyword(text)
    hierarchy_tokens = [
        (token, number)
        for number, raw in enumerate(text[:head_end].split("\n"), start=1)
        for token in raw.split()
    ]
    tokens = _Tokens(hierarchy_tokens, path, motion_line)
    hierarchy = _parse_hierarchy(tokens)
    names, parents, offsets, channels, site_names, site_parents, site_offsets = hierarchy
    if tokens.peek() is not None:
        token, line = tokens.next("MOTION")
        raise FormatError(f"expected MOTION after the hierarchy, got {token!r}", path, line)
    if not found:
        raise FormatError("no MOTION section (truncated?)", path, motion_line)
    n_frames, frame_time, block = _motion_header(text[head_end:], motion_line, path)
    n_channels = sum(len(c) for c in channels)
    if n_channels == 0:
        raise FormatError("no joint has channels", path, motion_line)
    values = _frame_values(block, motion_line + 3, n_frames, n_channels, path)
    offsets_units = np.asarray(offsets, dtype=np.float64)
    site_units = np.asarray(site_offsets, dtype=np.float64).reshape(-1, 3)
    if scale == "auto":
        cm_per_unit = _detect_file_scale(parents, offsets_units, site_parents, site_units)
    else:
        cm_per_unit = float(scale)
        if not (np.isfinite(cm_per_unit) and cm_per_unit > 0):
            raise ValueError(
                f"scale must be a positive number of cm per unit or 'auto', got {scale!r}"
            )
    try:
        return _build_motion(
            names,
            parents,
            offsets_units,
            channels,
            site_names,
            site_parents,
            site_units,
            cm_per_unit,
            values,
            frame_time,
            path.stem,
        )
    except ValueError as error:  # e.g. values so large they overflow once scaled
        raise FormatError(str(error), path) from error


def _find_motion_keyword(text: str) -> tuple[int, int, bool]:
    """Offset and line number of the ``MOTION`` line (joint names never are 'MOTION'), and
    whether there is one (if not: the end of the text and its last line)."""
    head_end = 0
    line_number = 1
    while head_end < len(text):
        end = text.find("\n", head_end)
        end = len(text) if end < 0 else end
        if text[head_end:end].strip().upper() == "MOTION":
            return head_end, line_number, True
        head_end = end + 1
        line_number += 1
    return head_end, line_number, False


def _motion_header(section: str, motion_line: int, path: Path) -> tuple[int, float, str]:
    """``Frames: N`` and ``Frame Time: dt`` after ``MOTION``: ``(N, dt, frame text)``."""
    rest = section.split("\n", 3)
    if len(rest) < 3:
        raise FormatError(
            "MOTION section lacks 'Frames:' and 'Frame Time:' (truncated?)", path, motion_line
        )
    frames_tokens = rest[1].split()
    if len(frames_tokens) != 2 or frames_tokens[0].lower() != "frames:":
        raise FormatError(f"expected 'Frames: N', got {rest[1].strip()!r}", path, motion_line + 1)
    n_frames = parse_int(frames_tokens[1], path, motion_line + 1, "frame count")
    if n_frames < 1:
        raise FormatError(f"frame count must be positive, got {n_frames}", path, motion_line + 1)
    time_tokens = rest[2].split()
    if len(time_tokens) != 3 or [t.lower() for t in time_tokens[:2]] != ["frame", "time:"]:
        raise FormatError(
            f"expected 'Frame Time: SECONDS', got {rest[2].strip()!r}", path, motion_line + 2
        )
    frame_time = parse_float(time_tokens[2], path, motion_line + 2, "frame time")
    if frame_time <= 0:
        raise FormatError(f"frame time must be positive, got {frame_time}", path, motion_line + 2)
    return n_frames, frame_time, rest[3] if len(rest) > 3 else ""


def _detect_file_scale(
    parents: list[int],
    offsets_units: NDArray[np.float64],
    site_parents: list[int],
    site_units: NDArray[np.float64],
) -> float:
    """:func:`detect_bvh_scale` of the rest skeleton, from offsets in file units."""
    rest = np.zeros((len(parents), 3))
    for j in range(1, len(parents)):  # parents come first in file order
        rest[j] = rest[parents[j]] + offsets_units[j]
    rest = np.concatenate((rest, rest[np.asarray(site_parents, dtype=np.int64)] + site_units))
    with np.errstate(over="ignore", invalid="ignore"):
        return detect_bvh_scale(rest)


def _build_motion(
    names: list[str],
    parents: list[int],
    offsets_units: NDArray[np.float64],
    channels: list[tuple[str, ...]],
    site_names: list[str],
    site_parents: list[int],
    site_units: NDArray[np.float64],
    cm_per_unit: float,
    values: NDArray[np.float64],
    frame_time: float,
    name: str,
) -> Motion:
    skeleton = Skeleton(
        joint_names=tuple(names),
        parents=np.asarray(parents, dtype=np.int64),
        offsets=offsets_units * cm_per_unit,
        channels=tuple(channels),
        euler="intrinsic",
        site_names=tuple(site_names),
        site_parents=np.asarray(site_parents, dtype=np.int64),
        site_offsets=site_units * cm_per_unit,
        name=name,
        extras={"format": "bvh", "bvh_scale": cm_per_unit},
    )
    fps = 1.0 / frame_time
    if abs(fps - round(fps)) <= 1e-4 * fps:
        fps = float(round(fps))
    return _motion_from_table(skeleton, values, fps, name)


def _motion_from_table(
    skeleton: Skeleton, values: NDArray[np.float64], fps: float, name: str
) -> Motion:
    J = skeleton.n_joints
    T = values.shape[0]
    cm = skeleton.extras["bvh_scale"]
    columns = np.full((J, 3), -1, dtype=np.int64)
    letters = [""] * J
    translations = np.repeat(skeleton.offsets[None], T, axis=0)
    moves_joints = False
    column = 0
    for j, chans in enumerate(skeleton.channels):
        for c in chans:
            if c[0] == "r":
                columns[j, len(letters[j])] = column
                letters[j] += c[1]
            else:
                translations[:, j, "xyz".index(c[1])] = values[:, column] * cm
                moves_joints = moves_joints or j > 0
            column += 1
    rotations = compose_joint_channels(np.deg2rad(values), columns, letters, intrinsic=True)
    return Motion(
        skeleton=skeleton,
        fps=fps,
        root_translation=translations[:, 0],
        rotations=rotations,
        joint_translations=translations if moves_joints else None,
        name=name,
    )


def to_bvh_skeleton(skeleton: Skeleton, rotating: Sequence[bool] | None = None) -> Skeleton:
    """A BVH-style twin of a skeleton: same joints, offsets and end sites, no pre-rotations.

    Local rotations (``Motion.rotations``) mean the same on both skeletons, so a motion moves
    to the twin by swapping the skeleton. Channels: the root gets ``tx ty tz rz ry rx``; every
    other joint with rotation channels gets ``rz ry rx``, intrinsic (so ``C M C^-1`` of an
    ASF bone with any dofs is representable); joints without rotation channels keep none (their
    local rotation is the identity) unless ``rotating`` says they turn. Position channels of
    other joints are kept.

    Parameters
    ----------
    skeleton : Skeleton
    rotating : sequence of bool, length J, optional
        Joints that need rotation channels whatever their own channels (:func:`write_bvh` marks
        the joints whose rotation is not the identity in some frame).

    Returns
    -------
    Skeleton
        ``euler="intrinsic"``, identity ``axes``, ``extras = {"format": "bvh", "bvh_scale":
        1.0}`` (written in centimetres) unless it already is a BVH skeleton (returned as is).
    """
    if skeleton.extras.get("format") == "bvh":
        return skeleton
    channels = []
    for j, chans in enumerate(skeleton.channels):
        translation = tuple(c for c in ("tx", "ty", "tz") if j == 0 or c in chans)
        turns = j == 0 or any(c[0] == "r" for c in chans) or bool(rotating and rotating[j])
        rotation = ("rz", "ry", "rx") if turns else ()
        channels.append(translation + rotation)
    return Skeleton(
        joint_names=skeleton.joint_names,
        parents=skeleton.parents,
        offsets=skeleton.offsets,
        channels=tuple(channels),
        euler="intrinsic",
        site_names=skeleton.site_names,
        site_parents=skeleton.site_parents,
        site_offsets=skeleton.site_offsets,
        name=skeleton.name,
        extras={"format": "bvh", "bvh_scale": 1.0},
    )


def _bvh_skeleton_matches(skeleton: Skeleton) -> bool:
    identity_axes = np.allclose(np.abs(skeleton.axes[:, 0]), 1.0, rtol=0, atol=1e-15)
    return (
        skeleton.euler == "intrinsic" and identity_axes and skeleton.extras.get("format") == "bvh"
    )


def bvh_channel_values(motion: Motion) -> NDArray[np.float64]:
    """The BVH frame table of a motion on a BVH-style skeleton: ``(T, C)`` in file units.

    Rotation channels in degrees (extracted for exactly each joint's axes), position channels
    in the skeleton's ``bvh_scale`` units.
    """
    sk = motion.skeleton
    cm = sk.extras.get("bvh_scale", 1.0)
    T = motion.n_frames
    n_channels = sum(len(c) for c in sk.channels)
    values = np.zeros((T, n_channels))
    translations = (
        motion.joint_translations.copy()
        if motion.joint_translations is not None
        else np.repeat(sk.offsets[None], T, axis=0)
    )
    translations[:, 0] = motion.root_translation
    groups: dict[str, tuple[list[int], list[list[int]]]] = {}
    column = 0
    for j, chans in enumerate(sk.channels):
        letters = ""
        cols = []
        for c in chans:
            if c[0] == "r":
                letters += c[1]
                cols.append(column)
            else:
                values[:, column] = translations[:, j, "xyz".index(c[1])] / cm
            column += 1
        if letters:
            joints, group_cols = groups.setdefault(letters, ([], []))
            joints.append(j)
            group_cols.append(cols)
    for letters, (joints, cols) in groups.items():
        values[:, cols] = np.rad2deg(
            decompose_channels(motion.rotations[:, joints], letters, intrinsic=True)
        )
    return values


def write_bvh(motion: Motion, path: str | Path) -> None:
    """Write a motion as a BVH file (atomically).

    A motion on a non-BVH skeleton (ASF: pre-rotations, extrinsic dofs) is written on
    :func:`to_bvh_skeleton` of it, in centimetres. Values have 10 significant digits.

    Parameters
    ----------
    motion : Motion
    path : str or Path
    """
    atomic_write(path, bvh_text(motion))


def bvh_text(motion: Motion) -> str:
    """The BVH text :func:`write_bvh` writes for ``motion`` (a zero-frame motion gives the
    hierarchy alone, with ``Frames: 0``)."""
    sk = motion.skeleton
    if not _bvh_skeleton_matches(sk):
        identity = quat.identity((sk.n_joints,))
        turned = quat.angle(motion.rotations, identity).max(axis=0, initial=0.0) > 1e-12
        sk = to_bvh_skeleton(sk, [bool(t) for t in turned])
        motion = Motion(
            skeleton=sk,
            fps=motion.fps,
            root_translation=motion.root_translation,
            rotations=motion.rotations,
            joint_translations=motion.joint_translations,
            name=motion.name,
        )
    cm = sk.extras.get("bvh_scale", 1.0)
    children: dict[int, list[int]] = {}
    for j in range(1, sk.n_joints):
        children.setdefault(int(sk.parents[j]), []).append(j)
    sites: dict[int, list[int]] = {}
    for s, p in enumerate(sk.site_parents):
        sites.setdefault(int(p), []).append(s)

    def g3(v: NDArray[np.float64]) -> str:
        return " ".join(f"{x:.10g}" for x in v)

    out = ["HIERARCHY"]

    def emit(j: int, depth: int) -> None:
        pad = "  " * depth
        keyword = "ROOT" if j == 0 else "JOINT"
        out.append(f"{pad}{keyword} {sk.joint_names[j]}")
        out.append(f"{pad}{{")
        out.append(f"{pad}  OFFSET {g3(sk.offsets[j] / cm)}")
        if sk.channels[j] or j == 0:
            names = " ".join(_FILE_CHANNELS[c] for c in sk.channels[j])
            out.append(f"{pad}  CHANNELS {len(sk.channels[j])} {names}".rstrip())
        for c in children.get(j, []):
            emit(c, depth + 1)
        for s in sites.get(j, []):
            out.append(f"{pad}  End Site")
            out.append(f"{pad}  {{")
            out.append(f"{pad}    OFFSET {g3(sk.site_offsets[s] / cm)}")
            out.append(f"{pad}  }}")
        out.append(f"{pad}}}")

    emit(0, 0)
    values = bvh_channel_values(motion)
    out += ["MOTION", f"Frames: {motion.n_frames}", f"Frame Time: {1.0 / motion.fps:.10g}", ""]
    row = " ".join(["%.10g"] * values.shape[1]) + "\n"
    body = (row * values.shape[0]) % tuple(values.ravel().tolist()) if values.size else ""
    return "\n".join(out) + body
