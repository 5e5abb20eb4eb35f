"""Motion files by extension: the suffixes quatmotion reads, finding them, reading and writing.

The one place that maps a file name to a reader or writer, and that walks folders for clips:
the command line, the benchmarks, the demo and every batch job use these.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable
from pathlib import Path
from typing import Literal, NamedTuple

import numpy as np

from quatmotion.errors import FormatError, FormatWarning
from quatmotion.io._text import decode_text
from quatmotion.io.asf_amc import parse_amc, parse_asf, read_amc, write_amc
from quatmotion.io.bvh import parse_bvh, read_bvh, write_bvh
from quatmotion.io.fbx import FBX_SUFFIXES, parse_fbx, read_fbx
from quatmotion.io.gltf import GLTF_SUFFIXES, parse_gltf, read_gltf, write_gltf
from quatmotion.io.units import (
    LENGTH_UNITS,
    PLAUSIBLE_FIGURE_CM,
    TYPICAL_HEIGHT_CM,
    body_size,
    find_body,
    posed_extent,
    unit_name,
)
from quatmotion.motion import Motion, Skeleton, forward_kinematics

__all__ = [
    "BELOW_FLOOR",
    "FAR_CM",
    "MOTION_SUFFIXES",
    "PLAUSIBLE_FPS",
    "WRITTEN_SUFFIXES",
    "Doubt",
    "feet_below_floor",
    "find_motion_files",
    "implausible_values",
    "parse_motion",
    "posed_size_cm",
    "read_motion",
    "read_motion_checked",
    "unit_reading",
    "write_motion",
]

MOTION_SUFFIXES = (".amc", ".bvh", *GLTF_SUFFIXES, *FBX_SUFFIXES)
"""File suffixes of motion clips (compared case-insensitively)."""
WRITTEN_SUFFIXES = (".amc", ".bvh", *GLTF_SUFFIXES)
"""File suffixes :func:`write_motion` writes (FBX is read, not written)."""


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
    translations: str = "auto",
    animation: str | int | None = None,
) -> Motion:
    """Read a motion file, choosing the reader by extension.

    Parameters
    ----------
    path : str or Path
        ``.amc`` (Acclaim; the skeleton is found by naming convention unless given),
        ``.bvh``, glTF 2.0 ``.glb`` / ``.gltf`` (:func:`quatmotion.io.gltf.read_gltf`) or
        ``.fbx`` (:func:`quatmotion.io.fbx.read_fbx`).
    skeleton : Skeleton, str, Path or None
        For ``.amc`` only: the skeleton or its ASF path (see :func:`read_amc`).
    units : str, float or None
        The file's length unit, a name of :data:`LENGTH_UNITS` or centimetres per unit.
        ``None``: a BVH's is guessed (see :func:`read_bvh`), an ASF's and an FBX's is the one
        it states, glTF's is the metre; given, it replaces the stated one (an exporter that
        wrote ``:units length 0.01`` for metres, or centimetres into a glTF).
    translations : str
        For ``.bvh`` only: what position channels mean (:data:`TRANSLATION_MODES` or
        ``"auto"``, see :func:`read_bvh`).
    animation : str, int or None
        For glTF and FBX: the animation's (an FBX take's) name or position (the first when
        None).

    Returns
    -------
    Motion

    Raises
    ------
    ValueError
        For another extension, a skeleton given for a BVH file, or an unknown unit.
    FormatError
        For a malformed file.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".amc":
        return read_amc(path, skeleton, units=units)
    if suffix == ".bvh":
        if skeleton is not None:
            raise ValueError("a BVH file carries its own skeleton; do not pass one")
        return read_bvh(path, "auto" if units is None else units, translations)
    if suffix in GLTF_SUFFIXES:
        if skeleton is not None:
            raise ValueError("a glTF file carries its own skeleton; do not pass one")
        return read_gltf(path, animation, units=units)
    if suffix in FBX_SUFFIXES:
        if skeleton is not None:
            raise ValueError("an FBX file carries its own skeleton; do not pass one")
        return read_fbx(path, animation, units=units)
    raise ValueError(
        f"unknown motion file type {path.suffix!r} (expected one of {MOTION_SUFFIXES})"
    )


def read_motion_checked(
    path: str | Path,
    skeleton: Skeleton | str | Path | None = None,
    *,
    units: str | float | None = None,
    translations: str = "auto",
    animation: str | int | None = None,
) -> tuple[Motion, list[Doubt]]:
    """:func:`read_motion`, and what is doubtful in the clip: what the reader tolerated or
    assumed (its :class:`~quatmotion.errors.FormatWarning`, as doubts of kind ``"read"``)
    followed by :func:`implausible_values`. What every command and batch job reads with."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", FormatWarning)
        motion = read_motion(
            path, skeleton, units=units, translations=translations, animation=animation
        )
    doubts = []
    for warning in caught:
        message = warning.message
        if isinstance(message, FormatWarning):
            where = f"line {message.line}: " if message.line is not None else ""
            doubts.append(Doubt("read", f"{where}{message.reason}"))
        else:  # not ours: on to the caller's filters
            warnings.warn_explicit(message, warning.category, warning.filename, warning.lineno)
    return motion, doubts + implausible_values(motion)


def parse_motion(
    data: bytes,
    name: str,
    skeleton: Skeleton | bytes | None = None,
    skeleton_name: str = "skeleton.asf",
    *,
    animation: str | int | None = None,
) -> Motion:
    """Read a motion from the bytes of a file: :func:`read_motion` without a file (an upload).

    Nothing is opened or written: ``name`` and ``skeleton_name`` only choose the parser (by
    suffix), name the motion (stem) and the skeleton, and appear in error messages.

    Parameters
    ----------
    data : bytes
        The whole ``.amc``, ``.bvh``, ``.glb``, ``.gltf`` (its data embedded) or ``.fbx``
        file.
    name : str
        Its file name.
    skeleton : Skeleton, bytes or None
        For ``.amc`` only, and required there (an AMC holds no skeleton): the skeleton, or the
        bytes of its ASF file.
    skeleton_name : str
        The ASF's file name, when ``skeleton`` is bytes.
    animation : str, int or None
        For glTF and FBX: the animation (take) by name or position, the first when None.

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
    if suffix in GLTF_SUFFIXES:
        if skeleton is not None:
            raise ValueError("a glTF file carries its own skeleton; do not pass one")
        return parse_gltf(data, name, animation)
    if suffix in FBX_SUFFIXES:
        if skeleton is not None:
            raise ValueError("an FBX file carries its own skeleton; do not pass one")
        return parse_fbx(data, name, animation)
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
    motion goes through :func:`to_bvh_skeleton`); so do ``.glb`` and ``.gltf``
    (:func:`quatmotion.io.gltf.write_gltf`, in metres).

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
    elif suffix in GLTF_SUFFIXES:
        write_gltf(motion, path)
    else:
        raise ValueError(
            f"cannot write motion file type {path.suffix!r} (written: {WRITTEN_SUFFIXES})"
        )


class Doubt(NamedTuple):
    """Something unlikely in a clip that was read without error."""

    kind: Literal["unit", "far", "rate", "read", "floor"]
    """``"unit"``: a guessed or stated unit makes an implausible figure, or another unit a
    likelier one, or a skeleton that is no body gave no ground to guess; ``"far"``: beyond
    1 km; ``"rate"``: a frame rate motion capture does not run at; ``"read"``: something the
    reader tolerated or assumed (:func:`read_motion_checked`); ``"floor"``: the feet below the
    floor for the whole clip (:func:`feet_below_floor`)."""
    message: str
    """One sentence, without the file name."""
    likely_unit: str | None = None
    """For a ``"unit"`` doubt whose unit makes no plausible human while another unit of
    :data:`LENGTH_UNITS` does: that unit's name (the reading nearest a typical adult). What a
    command that declares lengths (``compress``'s error bound) refuses to go on without."""


PLAUSIBLE_FPS = (1.0, 1000.0)
"""Frame rates of motion capture, frames per second: a frame time outside (a second or more
per frame, or under a millisecond) is a unit mistake (milliseconds for seconds) or a typo."""


def implausible_values(motion: Motion) -> list[Doubt]:
    """What in a clip that was read without error is unlikely for human motion capture.

    Three checks:

    * the stature, whatever the format and wherever the length unit came from (guessed for a
      BVH, stated by the file, or given by the user: a unit given is checked as hard as one
      guessed): the body's size (:func:`quatmotion.io.units.body_size`: the stature chain from
      an ankle to the head, or the posed figure's extent) falls outside
      :data:`PLAUSIBLE_FIGURE_CM`, or, for a guessed unit, another unit of
      :data:`LENGTH_UNITS` makes it a plausible figure nearer a typical adult's 170 cm. The
      message names the other readings, and :attr:`Doubt.likely_unit` the likeliest. A guessed
      unit of a skeleton that is not a body (a lone hand) is a doubt too: nothing could be
      guessed from its size;
    * coordinates or bones beyond :data:`FAR_CM`;
    * a frame rate outside :data:`PLAUSIBLE_FPS`;
    * the feet below the floor for the whole clip (:func:`feet_below_floor`).

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
        if motion.joint_translations is not None and motion.n_frames:
            bones = max(bones, float(np.max(np.abs(motion.joint_translations))))
    if root > FAR_CM:
        doubts.append(Doubt("far", f"the root is {root:.3g} cm from the origin, over 1 km"))
    if bones > FAR_CM:
        doubts.append(Doubt("far", f"a bone is {bones:.3g} cm long, over 1 km"))
    if bones <= FAR_CM:
        doubt = _unit_doubt(motion)
        if doubt is not None:
            doubts.append(doubt)
    if bones <= FAR_CM and root <= FAR_CM:
        doubt = feet_below_floor(motion)
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


BELOW_FLOOR = 0.1
"""Feet deeper than this share of the figure's size under the floor at every frame are no
floor contact (a foot in a hole, a jump down): the clip is placed under the floor."""


def feet_below_floor(motion: Motion, n_frames: int = 60) -> Doubt | None:
    """The ``"floor"`` doubt of a clip whose feet stay under the floor (Y = 0, Y up) for the
    whole clip, at best :data:`BELOW_FLOOR` of the figure's size under it, or None.

    A markerless capture's BVH puts the root's rest height in its ``OFFSET`` and near-zero
    values in its position channels; read as absolute (as a root's channels are), the figure
    stands half under the floor. When the root's offset would lift the feet to the floor, the
    message names that reading: ``--bvh-translations relative`` (the root's channels too).
    ``n_frames`` evenly spaced frames are measured; the feet are the ankles
    (:func:`~quatmotion.io.units.find_body`), else the figure's lowest point.
    """
    if motion.n_frames == 0:
        return None
    body = find_body(motion.skeleton)
    size = body_size(motion)
    if body is None or size is None or not (np.isfinite(size) and size > 0):
        return None
    clip = motion.slice(0, None, max(1, motion.n_frames // n_frames))
    with np.errstate(over="ignore", invalid="ignore"):
        heights = forward_kinematics(clip).all_positions()[..., 1]
        feet = heights[:, list(body.ankles)] if body.ankles else heights
        highest_low = float(np.max(np.min(feet, axis=1)))  # the least deep frame
    if not highest_low < -BELOW_FLOOR * size:
        return None
    message = (
        f"the feet stay below the floor for the whole clip (Y up, at least "
        f"{-highest_low:.3g} cm under it)"
    )
    sk = motion.skeleton
    lift = float(sk.offsets[0, 1])
    relative = sk.extras.get("bvh_root_relative") or sk.extras.get("bvh_translations") == (
        "relative"
    )
    if sk.extras.get("format") == "bvh" and not relative and lift > 0:
        lifted = highest_low + lift
        if -BELOW_FLOOR * size <= lifted <= 0.5 * size:  # on the floor, not floating
            message += (
                f"; the root's OFFSET ({lift:.3g} cm up) would put them on it: the root's "
                "position channels may be relative to it (--bvh-translations relative)"
            )
    return Doubt("floor", message)


def unit_reading(skeleton: Skeleton) -> tuple[float, str, str]:
    """How a skeleton's lengths were read: ``(cm per file unit, source, unit text)``, the
    source one of ``"guessed"`` (a BVH's unit, from the figure's size), ``"given"`` (by the
    user), ``"stated"`` (by the file: an ASF's ``:units length``, glTF's metres) or ``"cm"``
    (a skeleton made in code)."""
    extras = skeleton.extras
    kind = extras.get("format")
    if kind == "bvh":
        cm = float(extras.get("bvh_scale", 1.0))
        source = "guessed" if extras.get("bvh_unit_guessed") else "given"
        return cm, source, unit_name(cm) or f"{cm:g} cm"
    if "length_scale" in extras:  # an ASF, a glTF
        cm = float(extras["length_scale"])
        source = "given" if extras.get("length_unit_given") else "stated"
        if kind == "asf" and source == "stated":
            length = dict((k.lower(), v) for k, v in extras.get("asf_units", ())).get("length")
            said = f":units length {length}" if length else "no :units length (inches)"
            return cm, source, f"the unit its ASF states ({said}: {cm:.4g} cm a unit)"
        return cm, source, unit_name(cm) or f"{cm:g} cm"
    return 1.0, "cm", "cm"


def _unit_doubt(motion: Motion) -> Doubt | None:
    """The doubt about the unit a clip was read in, if any (see :func:`implausible_values`)."""
    cm, source, unit = unit_reading(motion.skeleton)
    if source == "cm":  # made in code, in centimetres: no file unit to doubt
        return None
    size = body_size(motion)
    if size is None:
        if source != "guessed":
            return None
        return Doubt(
            "unit",
            "the skeleton is not a body (no head or legs found), so its size cannot tell the "
            f"length unit: read in {unit}",
        )
    low, high = PLAUSIBLE_FIGURE_CM

    def typicality(value: float) -> float:  # distance from a typical adult, as a ratio
        return abs(np.log(value / TYPICAL_HEIGHT_CM))

    readings = {
        name: size / cm * other
        for name, other in LENGTH_UNITS.items()
        if abs(other - cm) > 1e-9 * cm and low <= size / cm * other <= high
    }
    plausible = low <= size <= high
    likelier = {n: v for n, v in readings.items() if typicality(v) < typicality(size)}
    if plausible and (source != "guessed" or not likelier):
        return None
    shown = likelier if plausible else readings
    others = " or ".join(f"{value:.3g} cm read in {name}" for name, value in shown.items())
    said = f"; it would be {others}" if others else ""
    how = {
        "guessed": f"with the length unit guessed as {unit}",
        "given": f"in {unit}, the unit given",
    }.get(source, f"in {unit}")
    if plausible:
        return Doubt(
            "unit",
            f"the figure is {size:.3g} cm tall {how}, small for an adult and near a unit "
            f"boundary{said}",
        )
    likely = min(readings, key=lambda n: typicality(readings[n])) if readings else None
    return Doubt(
        "unit",
        f"the figure is {size:.3g} cm tall {how}; a human figure is {low:g} to {high:g} cm{said}",
        likely,
    )


def posed_size_cm(motion: Motion, n_frames: int = 30) -> float:
    """The figure's size as posed, cm: :func:`quatmotion.io.units.posed_extent`."""
    return posed_extent(motion, n_frames)
