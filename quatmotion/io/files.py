"""Motion files by extension: the suffixes quatmotion reads, finding them, reading and writing.

The one place that maps a file name to a reader or writer, and that walks folders for clips:
the command line, the benchmarks, the demo and every batch job use these.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from quatmotion.errors import FormatError
from quatmotion.io._text import decode_text
from quatmotion.io.asf_amc import parse_amc, parse_asf, read_amc, write_amc
from quatmotion.io.bvh import parse_bvh, read_bvh, write_bvh
from quatmotion.motion import Motion, Skeleton

__all__ = ["MOTION_SUFFIXES", "find_motion_files", "parse_motion", "read_motion", "write_motion"]

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
