"""Biovision BVH files: reader and writer.

Conventions
-----------
* Joints are listed in file order (depth first, so parents come first); ``End Site`` blocks
  become end sites named ``<joint>_end``. Any channel order is accepted, with 0 to 6 channels
  per joint (``Xposition``... and ``Xrotation``..., case-insensitive).
* Rotations compose intrinsically in channel order: for ``Zrotation Xrotation Yrotation`` the
  local rotation is ``Rz @ Rx @ Ry`` (``Skeleton.euler == "intrinsic"``). Angles in the file are
  degrees.
* Joint names are the rest of their ``ROOT``/``JOINT`` line: ``Bip01 L Thigh`` (3ds Max's
  Biped) keeps its spaces, runs of white space made one space, and is written back so.
* Position channels are the joint's local translation. Root position channels give
  ``Motion.root_translation``; position channels on other joints (Bandai: six channels on every
  joint) give ``Motion.joint_translations``. Exporters mean two things by them (see
  :data:`TRANSLATION_MODES`): ``absolute``, the translation itself, replacing the ``OFFSET``
  component by component (Truebones and Bandai write the offsets there), or ``relative``, added
  to the ``OFFSET`` (MakeHuman writes zeros); ``root-only`` ignores them on every joint but the
  root. The root's own channels are relative in relative mode only when they hold values near
  zero too (a T-pose's), else they are its position. ``translations="auto"`` (the default)
  detects the mode when joints other than the root have position channels: values near zero
  (their median under a tenth of the offsets') are relative,
  since read as absolute they would put every joint on its parent; any others are absolute
  (values equal to the offsets, or a studio's bones under offsets that only lay the skeleton
  out). A relative reading detected is said in a :class:`~quatmotion.errors.FormatWarning`. The
  mode is kept in ``Skeleton.extras`` (``bvh_translations``, ``bvh_translations_guessed``,
  ``bvh_root_relative``) and the writer writes in it.
* Units: BVH has no unit field. ``read_bvh(path, scale=...)`` takes the unit, by name
  (:data:`BVH_UNITS`: ``mm``, ``cm``, ``dm``, ``m``, ``in`` and ``asf``, the CMU/ASF unit of 1/0.45
  inch) or as centimetres per file unit; ``scale="auto"`` (the default) weighs every named unit
  against a plausible human stature (:func:`quatmotion.io.units.guess_length_unit`: the stature
  chain from an ankle to the head, whatever the pose), and keeps centimetres for a skeleton that
  is not a body (a lone hand). Bandai files come out in centimetres, the CMU BVH conversion in the
  ASF unit, MakeHuman's in decimetres. :func:`quatmotion.io.implausible_values` says when even
  the best reading is no human. The scale is kept in ``Skeleton.extras`` (``bvh_scale``, cm per
  unit; ``bvh_unit``, its name or None; ``bvh_unit_guessed``) and :func:`write_bvh` writes in the
  same unit, so a read-write trip keeps the file's numbers.
* The ``MOTION`` header: blank lines before and between ``Frames:`` and ``Frame Time:`` are
  allowed, and so is no space after their colons. ``Frames: 0`` is a clip of no frames (the
  writer writes it for one). A frame line more than announced is read, with a warning (an
  exporter's off-by-one); fewer is an error naming both numbers.
* Frame rate: ``1 / Frame Time``, rounded to the nearest integer when within 0.01 % of it
  (files store ``0.0333333`` for 30 frames/s).
* Bounds: ``ROOT``/``JOINT`` lines are counted before the hierarchy is tokenised, and it is
  parsed in linear time without recursion; joints, nesting depth, ``Frames:``, the frame rate,
  the duration and frames x joints are checked against :func:`quatmotion.limits.current`
  before the frames are read (a ``FormatError`` naming the line).
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from quatmotion import limits, quat
from quatmotion.errors import FormatError, FormatWarning
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
)
from quatmotion.io.units import (
    LENGTH_UNITS,
    PLAUSIBLE_FIGURE_CM,
    body_size,
    guess_length_unit,
    length_unit,
    rescaled,
    unit_name,
)
from quatmotion.motion import Motion, Skeleton

__all__ = [
    "BVH_UNITS",
    "PLAUSIBLE_FIGURE_CM",
    "TRANSLATION_MODES",
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
BVH_UNITS = LENGTH_UNITS
"""Length units a BVH file may be in, by name: centimetres per file unit
(:data:`quatmotion.io.units.LENGTH_UNITS`)."""
TRANSLATION_MODES = ("absolute", "relative", "root-only")
"""What position channels mean (see the module docstring); ``"auto"`` detects it."""
_NEAR_ZERO = 0.1  # position values this small against the offsets (medians) are relative


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

    def name(self, what: str) -> tuple[str, int]:
        """A joint name: the tokens left on the keyword's line (up to a ``{``), one space
        between them (``Bip01 L Thigh``)."""
        token, line = self.next(what)
        if token == "{" or token == "}":
            raise FormatError(f"expected {what}, got {token!r}", self.path, line)
        words = [token]
        while self.position < len(self.tokens):
            following, following_line = self.tokens[self.position]
            if following_line != line or following == "{":
                break
            words.append(following)
            self.position += 1
        return " ".join(words), line

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
    """The joints, their channels and end sites, parents first: in time linear in the file,
    without recursion, and no more joints or levels than :func:`quatmotion.limits.current`."""
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[tuple[str, ...]] = []
    site_names: list[str] = []
    site_parents: list[int] = []
    site_offsets: list[list[float]] = []
    taken: set[str] = set()
    site_taken: set[str] = set()
    path = tokens.path
    open_joints: list[int] = []  # the joints whose '}' is still to come, innermost last

    def begin_joint(name: str, line: int) -> None:
        limits.check("joints", len(names) + 1, path, "the joints of the hierarchy", line)
        limits.check("depth", len(open_joints) + 1, path, "the hierarchy's nesting", line)
        if name in taken:
            raise FormatError(f"joint name {name!r} appears twice", path, line)
        taken.add(name)
        names.append(name)
        parents.append(open_joints[-1] if open_joints else -1)
        open_joints.append(len(names) - 1)
        tokens.expect("{")
        tokens.expect("OFFSET")
        offsets.append(tokens.floats(3, "OFFSET value"))
        chans: tuple[str, ...] = ()
        if (tokens.peek() or "").upper() == "CHANNELS":
            tokens.next("CHANNELS")
            count_token, count_line = tokens.next("channel count")
            count = parse_int(count_token, path, count_line, "channel count")
            if not 0 <= count <= 6:
                raise FormatError(f"a joint has 0 to 6 channels, got {count}", path, count_line)
            listed = []
            for _ in range(count):
                token, count_line = tokens.next("channel name")
                if token.lower() not in _CHANNEL_TOKENS:
                    raise FormatError(f"unknown channel {token!r}", path, count_line)
                listed.append(_CHANNEL_TOKENS[token.lower()])
            if len(set(listed)) != len(listed):
                raise FormatError("a channel is listed twice", path, count_line)
            chans = tuple(listed)
        channels.append(chans)

    tokens.expect("HIERARCHY")
    tokens.expect("ROOT")
    begin_joint(*tokens.name("root name"))
    while open_joints:
        token, line = tokens.next("JOINT, End Site or '}'")
        upper = token.upper()
        if upper == "}":
            open_joints.pop()
        elif upper == "JOINT":
            begin_joint(*tokens.name("joint name"))
        elif upper == "END":
            tokens.expect("Site")
            tokens.expect("{")
            tokens.expect("OFFSET")
            site_offsets.append(tokens.floats(3, "End Site OFFSET value"))
            tokens.expect("}")
            j = open_joints[-1]
            site = f"{names[j]}_end"
            if site in site_taken:
                site = f"{names[j]}_end{len(site_names)}"
            site_taken.add(site)
            site_names.append(site)
            site_parents.append(j)
        else:
            raise FormatError(f"expected JOINT, End Site or '}}', got {token!r}", path, line)
    return names, parents, offsets, channels, site_names, site_parents, site_offsets


def detect_bvh_scale(rest_positions: NDArray[np.float64]) -> float:
    """Centimetres per file unit that make a figure of these points a plausible human, by the
    points' largest extent (:func:`quatmotion.io.units.guess_length_unit`).

    The reader weighs the stature chain of the clip instead (whatever the pose); this is the
    same guess for a bare cloud of points.

    Parameters
    ----------
    rest_positions : ndarray, shape (N, 3)
        Joint and end-site positions, in file units.

    Returns
    -------
    float
        A value of :data:`BVH_UNITS`; 1.0 for a degenerate skeleton.
    """
    extent = float(np.max(np.ptp(rest_positions, axis=0))) if len(rest_positions) else 0.0
    return guess_length_unit(extent) or 1.0


def _frame_values(
    block: str, first_line: int, n_frames: int, n_channels: int, path: Path
) -> NDArray[np.float64]:
    """The ``(T, n_channels)`` table of every frame line; bulk path first, line by line to
    explain errors. More lines than ``n_frames``: read, with a warning; fewer: an error."""
    values, numeric, _, lines = scan_tokens(block)
    table = None
    if values.size % n_channels == 0 and numeric.all() and np.isfinite(values).all():
        T = values.size // n_channels
        lines = lines.reshape(T, n_channels)
        if np.all(lines == lines[:, :1]) and np.all(np.diff(lines[:, 0]) == 1):
            table = values.reshape(T, n_channels)
            last_line = first_line + (int(lines[-1, 0]) if T else 0)
    if table is None:
        rows: list[list[float]] = []
        last_line = first_line
        for line, raw in enumerate(block.split("\n"), start=first_line):
            tokens = fields(raw)
            if not tokens:
                continue
            if len(tokens) != n_channels:
                raise FormatError(
                    f"frame has {len(tokens)} values, expected {n_channels}", path, line
                )
            rows.append(parse_floats(tokens, path, line, "channel value"))
            last_line = line
        table = np.asarray(rows, dtype=np.float64).reshape(len(rows), n_channels)
    found = table.shape[0]
    if found < n_frames:
        raise FormatError(
            f"'Frames:' announces {n_frames} frames but the file has {found} (truncated?)",
            path,
            first_line + block.count("\n"),
        )
    if found > n_frames:
        warnings.warn(
            FormatWarning(
                f"'Frames:' announces {n_frames} frames but the file has {found} frame lines: "
                f"read all {found}",
                path,
                last_line,
            ),
            stacklevel=2,
        )
    return table


def read_bvh(path: str | Path, scale: float | str = "auto", translations: str = "auto") -> Motion:
    """Read a BVH file.

    Parameters
    ----------
    path : str or Path
    scale : float, str or "auto"
        The file's length unit: a name of :data:`BVH_UNITS` or centimetres per file unit;
        ``"auto"`` guesses it from the figure's stature (see the module docstring).
    translations : {"auto", "absolute", "relative", "root-only"}
        What position channels on joints other than the root mean (see the module docstring).

    Returns
    -------
    Motion
        Skeleton with ``euler="intrinsic"``, offsets in centimetres, ``extras`` with
        ``format="bvh"``, ``bvh_scale`` (cm per file unit), ``bvh_unit`` (its name in
        :data:`BVH_UNITS`, or None) and ``bvh_unit_guessed``; ``joint_translations`` when
        joints other than the root have position channels (and then ``bvh_translations``).

    Raises
    ------
    FormatError
        Naming the file and line: bad hierarchy, unknown channels, missing ``MOTION``,
        fewer frames than announced, value count mismatches, bad or non-finite numbers.
    ValueError
        For an unknown unit name, a scale that is not a positive number, or an unknown
        translations mode.

    Warns
    -----
    FormatWarning
        More frame lines than announced; position channels detected as relative.
    """
    path = Path(path)
    return parse_bvh(read_text(path), path, scale, translations)


def parse_bvh(
    text: str, path: str | Path, scale: float | str = "auto", translations: str = "auto"
) -> Motion:
    """Parse the text of a BVH file: :func:`read_bvh` without reading a file.

    Parameters
    ----------
    text : str
        The whole BVH text.
    path : str or Path
        The name messages give and whose stem names the motion (it is not opened).
    scale : float, str or "auto"
        As for :func:`read_bvh`.
    translations : str
        As for :func:`read_bvh`.

    Returns
    -------
    Motion
    """
    path = Path(path)
    cm_per_unit = None if isinstance(scale, str) and scale == "auto" else length_unit(scale)
    if translations != "auto" and translations not in TRANSLATION_MODES:
        raise ValueError(
            f"unknown translations mode {translations!r}; choose from auto, "
            f"{', '.join(TRANSLATION_MODES)}"
        )
    head_end, motion_line, found = _find_motion_keyword(text)
    hierarchy = _hierarchy(text[:head_end], motion_line, found, path)
    names, parents, offsets, channels, site_names, site_parents, site_offsets = hierarchy
    n_frames, frame_time, block, block_line = _motion_header(text[head_end:], motion_line, path)
    n_channels = sum(len(c) for c in channels)
    if n_channels == 0:
        raise FormatError("no joint has channels", path, motion_line)
    joints = f"'Frames:' x {len(names):,} joints"
    limits.check("joint_frames", n_frames * len(names), path, joints, block_line - 2)
    values = _frame_values(block, block_line, n_frames, n_channels, path)
    if len(values) > n_frames:  # frame lines beyond those announced: read, so bounded too
        limits.check("frames", len(values), path, "frame lines", block_line)
        limits.check("joint_frames", len(values) * len(names), path, "frame lines x joints")
    offsets_units = np.asarray(offsets, dtype=np.float64)
    mode, mode_guessed, root_relative = _translation_mode(
        translations, channels, offsets_units, values, path
    )
    try:
        # Huge values overflow once scaled: the Skeleton and Motion checks then name them, so
        # NumPy's own warning (with its internal file paths) would only be noise.
        with np.errstate(over="ignore", invalid="ignore"):
            skeleton = Skeleton(
                joint_names=tuple(names),
                parents=np.asarray(parents, dtype=np.int64),
                offsets=offsets_units,
                channels=tuple(channels),
                euler="intrinsic",
                site_names=tuple(site_names),
                site_parents=np.asarray(site_parents, dtype=np.int64),
                site_offsets=np.asarray(site_offsets, dtype=np.float64).reshape(-1, 3),
                name=path.stem,
                extras={"format": "bvh", "bvh_scale": 1.0},
            )
            in_file_units = _motion_from_table(
                skeleton, values, _fps(frame_time), path.stem, mode, root_relative
            )
            guessed = cm_per_unit is None
            if cm_per_unit is None:
                cm_per_unit = guess_length_unit(body_size(in_file_units)) or 1.0
            extras: dict[str, object] = {
                "bvh_scale": cm_per_unit,
                "bvh_unit": unit_name(cm_per_unit),
                "bvh_unit_guessed": guessed,
            }
            if mode_guessed is not None:
                extras |= {"bvh_translations": mode, "bvh_translations_guessed": mode_guessed}
            if root_relative:
                extras["bvh_root_relative"] = True
            return rescaled(in_file_units, cm_per_unit, extras)
    except ValueError as error:  # e.g. values so large they overflow once scaled
        raise FormatError(str(error), path) from error


def _hierarchy(head: str, motion_line: int, found: bool, path: Path) -> tuple:
    """The HIERARCHY section (``head``: the text before the MOTION keyword, its joints counted
    against :func:`quatmotion.limits.current` before a line is split): names, parents,
    offsets, channels, end sites' names, parents and offsets (:func:`_parse_hierarchy`)."""
    check_count(head, _JOINT_LINE, "joints", limits.current().joints, path, "joints")
    hierarchy_tokens = [
        (token, number)
        for number, raw in enumerate(head.split("\n"), start=1)
        for token in fields(raw)
    ]
    tokens = _Tokens(hierarchy_tokens, path, motion_line)
    hierarchy = _parse_hierarchy(tokens)
    if tokens.peek() is not None:
        token, line = tokens.next("MOTION")
        raise FormatError(f"expected MOTION after the hierarchy, got {token!r}", path, line)
    if not found:
        raise FormatError("no MOTION section (truncated?)", path, motion_line)
    return hierarchy


def _fps(frame_time: float) -> float:
    fps = 1.0 / frame_time
    return float(round(fps)) if abs(fps - round(fps)) <= 1e-4 * fps else fps


def _position_table(
    channels: list[tuple[str, ...]], values: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Every joint's position channels as ``(T, J, 3)`` (0 where a component has none), and
    which components have one ``(J, 3)``."""
    T, J = values.shape[0], len(channels)
    table = np.zeros((T, J, 3))
    present = np.zeros((J, 3), dtype=bool)
    column = 0
    for j, chans in enumerate(channels):
        for c in chans:
            if c[0] == "t":
                axis = "xyz".index(c[1])
                table[:, j, axis] = values[:, column]
                present[j, axis] = True
            column += 1
    return table, present


def _near_zero_joints(
    table: NDArray[np.float64], present: NDArray[np.bool_], offsets: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per joint: the length of its offset's components that have channels, and the median
    length over frames of those channels' values."""
    with np.errstate(over="ignore", invalid="ignore"):  # absurd values: a doubt of their own
        size = np.linalg.norm(np.where(present, offsets, 0.0), axis=1)
        if not len(table):
            return size, np.zeros_like(size)
        return size, np.median(np.linalg.norm(table, axis=2), axis=0)


def _translation_mode(
    given: str,
    channels: list[tuple[str, ...]],
    offsets: NDArray[np.float64],
    values: NDArray[np.float64],
    path: Path,
) -> tuple[str, bool | None, bool]:
    """The translations mode, whether it was detected (None: no joint but the root has
    position channels, so the mode does not matter and is not recorded), and whether the
    root's channels are relative too (relative mode, and values near zero: a T-pose's)."""
    table, present = _position_table(channels, values)
    moved = np.flatnonzero(present[1:].any(axis=1)) + 1
    size, typical = _near_zero_joints(table, present, offsets)
    root_relative = bool(present[0].any() and size[0] and typical[0] < _NEAR_ZERO * size[0])
    if not len(moved):
        mode = "absolute" if given == "auto" else given
        return mode, None, mode == "relative" and root_relative
    if given != "auto":
        return given, False, given == "relative" and root_relative
    evidence = moved[size[moved] > 0]  # a zero offset: both readings agree
    # Values near zero read as absolute would put every joint on its parent: no figure at all.
    near_zero = (
        len(evidence) > 0
        and len(values) > 0
        and np.median(typical[evidence]) < _NEAR_ZERO * np.median(size[evidence])
    )
    if near_zero:
        warnings.warn(
            FormatWarning(
                f"position channels on {len(moved)} joints hold values near zero, not near "
                "their offsets: read as relative to the offsets (--bvh-translations relative)",
                path,
            ),
            stacklevel=3,
        )
        return "relative", True, root_relative
    return "absolute", True, False


def _find_motion_keyword(text: str) -> tuple[int, int, bool]:
    """Offset and line number of the ``MOTION`` line (joint names never are 'MOTION'), and
    whether there is one (if not: the end of the text and its last line)."""
    found = _MOTION_LINE.search(text)
    if found is not None:
        return found.start(), text.count("\n", 0, found.start()) + 1, True
    lines = text.count("\n") + (0 if not text or text.endswith("\n") else 1)
    return len(text), lines + 1, False


_MOTION_LINE = re.compile(r"^[^\S\n]*MOTION[^\S\n]*$", re.IGNORECASE | re.MULTILINE)
_JOINT_LINE = re.compile(r"^[ \t]*(?:ROOT|JOINT)\b", re.IGNORECASE | re.MULTILINE)
_FRAMES = re.compile(r"frames\s*:\s*(\S*)", re.IGNORECASE)
_FRAME_TIME = re.compile(r"frame\s*time\s*:\s*(\S*)", re.IGNORECASE)


def _motion_header(section: str, motion_line: int, path: Path) -> tuple[int, float, str, int]:
    """``Frames: N`` and ``Frame Time: dt`` after ``MOTION`` (blank lines around them and no
    space after a colon allowed): ``(N, dt, frame text, its first line number)``."""
    lines = section.split("\n")
    k = 1
    found = []
    for pattern, what in ((_FRAMES, "'Frames: N'"), (_FRAME_TIME, "'Frame Time: SECONDS'")):
        while k < len(lines) and not lines[k].strip():
            k += 1
        if k >= len(lines):
            raise FormatError(f"MOTION section lacks {what} (truncated?)", path, motion_line)
        match = pattern.fullmatch(lines[k].strip())
        if match is None or not match.group(1):
            raise FormatError(f"expected {what}, got {lines[k].strip()!r}", path, motion_line + k)
        found.append((match.group(1), motion_line + k))
        k += 1
    (count_token, count_line), (time_token, time_line) = found
    n_frames = parse_int(count_token, path, count_line, "frame count")
    if n_frames < 0:
        raise FormatError(f"frame count must be 0 or more, got {n_frames}", path, count_line)
    limits.check("frames", n_frames, path, "'Frames:'", count_line)
    frame_time = parse_float(time_token, path, time_line, "frame time")
    if frame_time <= 0:
        raise FormatError(f"frame time must be positive, got {frame_time}", path, time_line)
    with np.errstate(over="ignore"):
        fps = np.float64(1.0) / frame_time
    limits.check("fps", fps, path, f"'Frame Time: {time_token}' (a frame rate)", time_line)
    limits.check("duration", n_frames * frame_time, path, "'Frames:' x 'Frame Time:'", time_line)
    offset = sum(len(line) + 1 for line in lines[:k])
    return n_frames, frame_time, section[offset:], motion_line + k


def _motion_from_table(
    skeleton: Skeleton,
    values: NDArray[np.float64],
    fps: float,
    name: str,
    mode: str,
    root_relative: bool = False,
) -> Motion:
    """The clip of a frame table in the skeleton's units, position channels read per ``mode``
    (:data:`TRANSLATION_MODES`); the root's are never ignored, and relative only with
    ``root_relative``."""
    J = skeleton.n_joints
    T = values.shape[0]
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
            elif j == 0 or mode != "root-only":
                axis = "xyz".index(c[1])
                relative = mode == "relative" and (j > 0 or root_relative)
                base = skeleton.offsets[j, axis] if relative else 0.0
                translations[:, j, axis] = base + values[:, column]
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
    in the skeleton's ``bvh_scale`` units, relative to the offsets when the file's were
    (``bvh_translations``).
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
    if sk.extras.get("bvh_translations") == "relative":
        root = translations[:, 0].copy()
        translations -= sk.offsets
        if not sk.extras.get("bvh_root_relative"):
            translations[:, 0] = root
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
