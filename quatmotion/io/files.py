"""Motion files by extension: the suffixes quatmotion reads, finding them, reading and writing.

The one place that maps a file name to a reader or writer, and that walks folders for clips:
the command line, the benchmarks, the demo and every batch job use these.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Literal, NamedTuple

import numpy as np

from quatmotion.errors import FormatError
from quatmotion.io._text import decode_text
from quatmotion.io.asf_amc import parse_amc, parse_asf, read_amc, write_amc
from quatmotion.io.bvh import (
    BVH_UNITS,
    PLAUSIBLE_FIGURE_CM,
    TYPICAL_HEIGHT_CM,
    parse_bvh,
    read_bvh,
    write_bvh,
)
from quatmotion.motion import Motion, Skeleton, forward_kinematics

__all__ = [
    "FAR_CM",
    "MOTION_SUFFIXES",
    "PLAUSIBLE_FPS",
    "Doubt",
    "find_motion_files",
    "implausible_values",
    "parse_motion",
    "posed_size_cm",
    "read_motion",
    "write_motion",
]

MOTION_SUFFIXES = (".amc", ".bvh")
"""File suffixes of motion clips (compared case-insensitively)."""


def find_motion_files(paths: Iterable[str | Path]) -> list[Path]:
    """Every motion file given, or found (recursively) under the given folders.

    Parameters
    ----------
    paths : iterable of str or Path
        Files (kept whatever their suffix: the reader will name a wrong one) or folders
        (searched recursively for files with a suffix of :data:`MOTION_SUFFIXES`).

    Returns
    -------
    list of Path
        In argument order, each folder's files sorted, without duplicates.

    Raises
    ------
    FileNotFoundError
        If a path does not exist (naming it).
    ValueError
        If nothing is found.
    """
    paths = [Path(p) for p in paths]
    found: list[Path] = []
    for path in paths:
        if path.is_dir():
            found.extend(
                sorted(
                    f
                    for f in path.rglob("*")
                    if f.suffix.lower() in MOTION_SUFFIXES and f.is_file()
                )
            )
        elif path.exists():
            found.append(path)
        else:
            raise FileNotFoundError(f"{path}: no such file or folder")
    unique = list(dict.fromkeys(found))
    if not unique:
        listed = ", ".join(str(p) for p in paths) or "no paths"
        raise ValueError(f"no {' or '.join(MOTION_SUFFIXES)} files in {listed}")
    return unique


FAR_CM = 1e5
"""A kilometre: coordinates or bones beyond it are not human motion capture."""


def read_motion(
    path: str | Path,
    skeleton: Skeleton | str | Path | None = None,
    *,
    units: str | float | None = None,
) -> Motion:
    """Read a motion file, choosing the reader by extension.

    Parameters
    ----------
    path : str or Path
        ``.amc`` (Acclaim; the skeleton is found by naming convention unless given) or
        ``.bvh``.
    skeleton : Skeleton, str, Path or None
        For ``.amc`` only: the skeleton or its ASF path (see :func:`read_amc`).
    units : str, float or None
        For ``.bvh`` only: the file's length unit, a name of :data:`BVH_UNITS` or centimetres
        per unit; ``None`` guesses it (see :func:`read_bvh`). An ASF states its own.

    Returns
    -------
    Motion

    Raises
    ------
    ValueError
        For another extension, a skeleton given for a BVH file, a unit given for an AMC file,
        or an unknown unit.
    FormatError
        For a malformed file.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".amc":
        if units is not None:
            raise ValueError("an AMC's length unit is the one its ASF states; do not pass one")
        return read_amc(path, skeleton)
    if suffix == ".bvh":
        if skeleton is not None:
            raise ValueError("a BVH file carries its own skeleton; do not pass one")
        return read_bvh(path, "auto" if units is None else units)
    raise ValueError(
        f"unknown motion file type {path.suffix!r} (expected one of {MOTION_SUFFIXES})"
    )


def parse_motion(
    data: bytes,
    name: str,
    skeleton: Skeleton | bytes | None = None,
    skeleton_name: str = "skeleton.asf",
) -> Motion:
    """Read a motion from the bytes of a file: :func:`read_motion` without a file (an upload).

    Nothing is opened or written: ``name`` and ``skeleton_name`` only choose the parser (by
    suffix), name the motion (stem) and the skeleton, and appear in error messages.

    Parameters
    ----------
    data : bytes
        The whole ``.amc`` or ``.bvh`` file.
    name : str
        Its file name.
    skeleton : Skeleton, bytes or None
        For ``.amc`` only, and required there (an AMC holds no skeleton): the skeleton, or the
        bytes of its ASF file.
    skeleton_name : str
        The ASF's file name, when ``skeleton`` is bytes.

    Returns
    -------
    Motion

    Raises
    ------
    ValueError
        For another suffix, or a skeleton given for a BVH file.
    FormatError
        For malformed bytes (binary content included), or an AMC without its skeleton.
    """
    suffix = Path(name).suffix.lower()
    if suffix == ".bvh":
        if skeleton is not None:
            raise ValueError("a BVH file carries its own skeleton; do not pass one")
        return parse_bvh(decode_text(data, name), name)
    if suffix == ".amc":
        if skeleton is None:
            raise FormatError("an AMC holds no skeleton: give its ASF file too", name)
        if not isinstance(skeleton, Skeleton):
            skeleton = parse_asf(decode_text(skeleton, skeleton_name), skeleton_name)
        return parse_amc(decode_text(data, name), name, skeleton)
    raise ValueError(
        f"{name}: unknown motion file type {suffix!r} (expected one of {MOTION_SUFFIXES})"
    )


def write_motion(motion: Motion, path: str | Path) -> None:
    """Write a motion, choosing the writer by extension (atomically).

    ``.amc`` writes only the AMC (the motion's skeleton must come from an ASF; write the
    skeleton with :func:`write_asf` where it is needed). ``.bvh`` writes any motion (an ASF
    motion goes through :func:`to_bvh_skeleton`).

    Parameters
    ----------
    motion : Motion
    path : str or Path
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".amc":
        write_amc(motion, path)
    elif suffix == ".bvh":
        write_bvh(motion, path)
    else:
        raise ValueError(
            f"unknown motion file type {path.suffix!r} (expected one of {MOTION_SUFFIXES})"
        )


class Doubt(NamedTuple):
    """Something unlikely in a clip that was read without error."""

    kind: Literal["unit", "far", "rate"]
    """``"unit"``: a guessed unit makes an implausible figure, or another unit a likelier one;
    ``"far"``: beyond 1 km; ``"rate"``: a frame rate motion capture does not run at."""
    message: str
    """One sentence, without the file name."""


PLAUSIBLE_FPS = (1.0, 1000.0)
"""Frame rates of motion capture, frames per second: a frame time outside (a second or more
per frame, or under a millisecond) is a unit mistake (milliseconds for seconds) or a typo."""


def implausible_values(motion: Motion) -> list[Doubt]:
    """What in a clip that was read without error is unlikely for human motion capture.

    Three checks:

    * a BVH length unit that was guessed (the file has no unit field) and is doubtful: the
      posed figure's size (:func:`posed_size_cm`: the height standing, the length lying) falls
      outside :data:`PLAUSIBLE_FIGURE_CM`, or another unit of :data:`BVH_UNITS` makes it a
      plausible figure nearer a typical adult's 170 cm: a figure near a unit boundary (a
      135 cm figure in inches read as 53 cm, a child's torso, when its rest pose is no
      standing pose). The message names the other readings. Every wrong guess that reads a
      plausible figure too small (the error bounds of the codec then hold in the wrong unit,
      too loose) meets the second test;
    * coordinates or bones beyond :data:`FAR_CM`;
    * a frame rate outside :data:`PLAUSIBLE_FPS`.

    Readers accept all of these (the numbers are valid); a caller shows the messages as
    warnings.

    Parameters
    ----------
    motion : Motion

    Returns
    -------
    list of Doubt
        Empty when nothing is doubtful.
    """
    doubts = []
    sk = motion.skeleton
    with np.errstate(over="ignore", invalid="ignore"):
        root = float(np.max(np.abs(motion.root_translation), initial=0.0))
        bones = float(np.max(np.abs(sk.offsets), initial=0.0))
        if motion.joint_translations is not None:
            bones = max(bones, float(np.max(np.abs(motion.joint_translations))))
    if root > FAR_CM:
        doubts.append(Doubt("far", f"the root is {root:.3g} cm from the origin, over 1 km"))
    if bones > FAR_CM:
        doubts.append(Doubt("far", f"a bone is {bones:.3g} cm long, over 1 km"))
    if sk.extras.get("bvh_unit_guessed") and bones <= FAR_CM:
        doubt = _unit_doubt(sk, posed_size_cm(motion))
        if doubt is not None:
            doubts.append(doubt)
    low, high = PLAUSIBLE_FPS
    if not low <= motion.fps <= high:
        doubts.append(
            Doubt(
                "rate",
                f"the frame time is {1.0 / motion.fps:.4g} s ({motion.fps:.4g} frames per "
                f"second); motion capture runs at {low:g} to {high:g} frames per second",
            )
        )
    return doubts


def _unit_doubt(skeleton: Skeleton, size: float) -> Doubt | None:
    """The doubt about a guessed unit that reads the figure ``size`` cm large, if any."""
    low, high = PLAUSIBLE_FIGURE_CM
    cm = skeleton.extras["bvh_scale"]

    def typicality(value: float) -> float:  # distance from a typical adult, as a ratio
        return abs(np.log(value / TYPICAL_HEIGHT_CM))

    readings = {
        name: size / cm * other
        for name, other in BVH_UNITS.items()
        if other != cm and low <= size / cm * other <= high
    }
    plausible = low <= size <= high
    likelier = {n: v for n, v in readings.items() if typicality(v) < typicality(size)}
    if plausible and not likelier:
        return None
    shown = likelier if plausible else readings
    others = " or ".join(f"{value:.3g} cm read in {name}" for name, value in shown.items())
    unit = skeleton.extras.get("bvh_unit") or f"{cm:g} cm"
    said = f"; it would be {others}" if others else ""
    if plausible:
        return Doubt(
            "unit",
            f"the figure is {size:.3g} cm tall or long with the length unit guessed as {unit}, "
            f"small for an adult and near a unit boundary{said}",
        )
    return Doubt(
        "unit",
        f"the figure is {size:.3g} cm tall or long with the length unit guessed as {unit}; a "
        f"human figure is {low:g} to {high:g} cm{said}",
    )


def posed_size_cm(motion: Motion, n_frames: int = 30) -> float:
    """The figure's size as posed: the median over frames of its largest extent, cm.

    Unlike the rest pose's extent (what :func:`quatmotion.io.detect_bvh_scale` measures), this
    holds for skeletons whose rest pose is no pose at all (Bandai's lies along X, 4.5 m long).
    A root that stays put while position channels of other joints carry the body is a
    reference node, not part of the figure, and is left out (Bandai's stays on the floor at the
    origin while its Hips walk away). ``n_frames`` evenly spaced frames are measured.
    """
    clip = motion.slice(0, None, max(1, motion.n_frames // n_frames))
    with np.errstate(over="ignore", invalid="ignore"):
        points = forward_kinematics(clip).all_positions()
        carried = clip.joint_translations is not None and np.any(
            np.ptp(clip.joint_translations[:, 1:], axis=0) > 0
        )
        if carried and np.all(points[:, 0] == points[:1, 0]):
            points = points[:, 1:]
        return float(np.median(np.max(np.ptp(points, axis=1), axis=-1)))
