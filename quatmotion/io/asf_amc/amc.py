"""Reading AMC motions against their ASF skeleton (:func:`read_amc`, :func:`parse_amc`) and
finding that ASF (:func:`match_asf_for_amc`); the conventions are :mod:`quatmotion.io.asf_amc`'s.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from quatmotion import limits
from quatmotion.errors import FormatError
from quatmotion.io._text import (
    compose_joint_channels,
    fields,
    parse_floats,
    read_text,
    scan_tokens,
    token_hash,
)
from quatmotion.io.asf_amc.asf import ROTATION_DOFS, read_asf, require_asf
from quatmotion.motion import Motion, Skeleton

DEFAULT_AMC_FPS = 120.0

_INTEGER = re.compile(r"[+-]?\d+")


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
    require_asf(skeleton, "read_amc")
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
    require_asf(skeleton, "parse_amc")
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
            if d in ROTATION_DOFS:
                columns[j, len(letters[j])] = column + k
                letters[j] += ROTATION_DOFS[d]
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
