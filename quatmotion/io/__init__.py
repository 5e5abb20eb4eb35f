"""Motion-capture file formats: ASF/AMC and BVH readers and writers.

Every reader raises :class:`quatmotion.FormatError` (naming the file and line) on malformed
input; every writer writes a temporary file and renames it over the target.
"""

from __future__ import annotations

from pathlib import Path

from quatmotion.io.asf_amc import (
    asf_bone_end_positions,
    find_asf_for_amc,
    read_amc,
    read_asf,
    write_amc,
    write_asf,
)
from quatmotion.io.bvh import detect_bvh_scale, read_bvh, to_bvh_skeleton, write_bvh
from quatmotion.motion import Motion, Skeleton

__all__ = [
    "asf_bone_end_positions",
    "detect_bvh_scale",
    "find_asf_for_amc",
    "read_amc",
    "read_asf",
    "read_bvh",
    "read_motion",
    "to_bvh_skeleton",
    "write_amc",
    "write_asf",
    "write_bvh",
    "write_motion",
]

MOTION_SUFFIXES = (".amc", ".bvh")


def read_motion(path: str | Path, skeleton: Skeleton | str | Path | None = None) -> Motion:
    """Read a motion file, choosing the reader by extension.

    Parameters
    ----------
    path : str or Path
        ``.amc`` (Acclaim; the skeleton is found by naming convention unless given) or
        ``.bvh``.
    skeleton : Skeleton, str, Path or None
        For ``.amc`` only: the skeleton or its ASF path (see :func:`read_amc`).

    Returns
    -------
    Motion

    Raises
    ------
    ValueError
        For another extension, or a skeleton given for a BVH file.
    FormatError
        For a malformed file.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".amc":
        return read_amc(path, skeleton)
    if suffix == ".bvh":
        if skeleton is not None:
            raise ValueError("a BVH file carries its own skeleton; do not pass one")
        return read_bvh(path)
    raise ValueError(
        f"unknown motion file type {path.suffix!r} (expected one of {MOTION_SUFFIXES})"
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
