"""Finding and reading the clips of a collection: one set of rules for every file kind.

Conventions
-----------
* :func:`find_clips` turns what a user names (files, folders, clips in memory) into
  :class:`ClipSource` items: folders searched recursively (:func:`quatmotion.io.find_motion_files`),
  every clip given a unique name (:func:`~quatmotion.collection.refs.unique_names`), every AMC
  its ASF (:func:`find_skeleton`), every file its content hash, every take of an FBX file of
  several a clip of its own (:func:`file_takes`; ``ReadSettings.take`` picks one). Nothing is
  parsed there but an FBX file's list of takes: the clips are read where they are used, in
  the batch workers, by :func:`read_clip`.
* The ASF of an AMC (:func:`find_skeleton`), in order: ``ReadSettings.skeleton`` when it is a
  file (it is the skeleton of every AMC read with these settings); when it is a folder, the ASF
  there named as the conventions below name it, else the folder's only ASF; with no skeleton
  given, the conventions beside the AMC (``NAME.asf``, CMU's ``SS.asf``, HDM05's
  ``skeletons/HDM_AA.asf``: :func:`quatmotion.io.find_asf_for_amc`), else the only ASF in the
  AMC's folder. Several candidates and no rule to choose: an error naming them.
* :class:`ReadSettings` (the length unit of BVH input, the ASF of AMC input, whether
  coordinates beyond a kilometre are refused) is part of every file kind's settings and is
  stored with them, so a collection says how its clips were read.
"""

from __future__ import annotations

import errno
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from numbers import Real
from pathlib import Path
from typing import Any, ClassVar, NamedTuple

from quatmotion._settings import Interval, Settings, StrOptions
from quatmotion.collection.refs import (
    ClipRef,
    content_hash,
    duplicates,
    file_digest,
    motion_hash,
    take_hash,
    unique_names,
)
from quatmotion.errors import FormatError
from quatmotion.io import LENGTH_UNITS, TRANSLATION_MODES
from quatmotion.motion import Motion

__all__ = [
    "ClipSource",
    "ReadClip",
    "ReadSettings",
    "file_hash",
    "file_takes",
    "find_clips",
    "find_skeleton",
    "read_clip",
    "with_joint_map",
]


@dataclass(frozen=True)
class ReadSettings(Settings):
    """How the clips of a collection are read.

    Attributes
    ----------
    units : str, float or None
        Length unit of the BVH and glTF input: a name of :data:`quatmotion.io.LENGTH_UNITS` or
        centimetres per unit; None guesses a BVH's from the figure's stature (and says so in
        every clip's reference) and takes glTF's metre. An ASF's stated unit is kept in a
        collection (a mixed library's BVH unit never rescales its CMU skeletons); one AMC read
        alone takes a unit (:func:`quatmotion.io.read_motion`).
    skeleton : str or None
        An ASF file (the skeleton of every AMC) or a folder of ASF files; None finds each
        AMC's by the conventions of :func:`find_skeleton`.
    strict : bool
        Refuse a clip with coordinates beyond a kilometre (not human motion capture) instead of
        reporting it as a doubt.
    translations : str
        What position channels on BVH joints other than the root mean: ``"auto"`` (detected),
        or one of :data:`quatmotion.io.TRANSLATION_MODES` (see :func:`quatmotion.io.read_bvh`).
    joint_map : tuple of str
        A user's humanoid map, ``"Canonical=file joint"`` entries
        (:func:`quatmotion.io.joint_map_pairs`): every clip read carries it
        (:func:`quatmotion.motion.with_joint_map`), and search maps its skeleton by it before
        names and structure (:func:`quatmotion.motion.map_humanoid`). Empty: names and
        structure alone.
    take : str or None
        The take every FBX file is read at (a glTF file's animation), by name, short name or
        position (:func:`quatmotion.io.fbx.take_index`); a file without it is refused. None:
        every take of an FBX file of several is a clip (:func:`file_takes`).
    """

    units: str | float | None = None
    skeleton: str | None = None
    strict: bool = True
    translations: str = "auto"
    joint_map: tuple[str, ...] = ()
    take: str | None = None

    _parameter_constraints: ClassVar[dict[str, list[Any]]] = {
        "units": [None, Interval(Real, 0, None, closed="neither"), StrOptions(set(LENGTH_UNITS))],
        "skeleton": [str, None],
        "strict": ["boolean"],
        "translations": [StrOptions({"auto", *TRANSLATION_MODES})],
        "joint_map": [tuple],
        "take": [str, None],
    }

    def _check(self) -> None:
        from quatmotion.io import joint_map_dict

        joint_map_dict(self.joint_map)  # a ValueError naming a malformed entry

    def __post_init__(self) -> None:
        if isinstance(self.skeleton, os.PathLike):
            object.__setattr__(self, "skeleton", os.fspath(self.skeleton))
        super().__post_init__()


@dataclass(frozen=True)
class ClipSource:
    """A clip to read: a file (with the ASF of an AMC, the take of a file of several) or a
    motion in memory, with its name in the collection and its content hash."""

    name: str
    sha256: str
    path: Path | None = None
    skeleton_path: Path | None = None
    motion: Motion | None = field(default=None, repr=False, compare=False)
    take: str | None = None

    def ref(self) -> ClipRef:
        """The reference before reading (fingerprint and unit not known yet)."""
        return ClipRef(
            self.name,
            self.sha256,
            None if self.path is None else str(self.path),
            None if self.skeleton_path is None else str(self.skeleton_path),
            take=self.take,
        )

    def __str__(self) -> str:  # how a batch failure names it
        return str(self.path) if self.path is not None else self.name


class ReadClip(NamedTuple):
    """What :func:`read_clip` gives: the motion (named by its collection name), its completed
    reference, and what in it is doubtful (:class:`quatmotion.io.Doubt`)."""

    motion: Motion
    ref: ClipRef
    doubts: list[Any]


def find_skeleton(amc: Path, skeleton: str | Path | None = None) -> Path:
    """The ASF of an AMC by the rules of the module's conventions.

    Raises
    ------
    FileNotFoundError
        A ``skeleton`` given that does not exist.
    FormatError
        Naming the AMC, where it looked, and the candidates when several fit.
    """
    from quatmotion.io import find_asf_for_amc

    if skeleton is None:
        return find_asf_for_amc(amc)
    given = Path(skeleton)
    if given.is_file():
        return given
    if not given.is_dir():
        raise FileNotFoundError(2, "no such skeleton file or folder", str(given))
    return find_asf_for_amc(amc, given)


def file_hash(
    path: str | Path, skeleton: str | Path | None = None, take: str | int | None = None
) -> str:
    """A motion file's identity as a collection stores it (:func:`content_hash` of the file,
    and of an AMC's ASF, found by :func:`find_skeleton` from ``skeleton``); for an FBX file of
    several takes, of the take ``take`` names (the first when None, as reading it reads).

    Raises
    ------
    FormatError, OSError
        As :func:`find_skeleton`; a file that cannot be read; no such take.
    """
    path = Path(path)
    asf = find_skeleton(path, skeleton) if path.suffix.lower() == ".amc" else None
    takes = file_takes(path, take)
    return content_hash(path, asf, takes[0][0])


def file_takes(path: Path, wanted: str | int | None = None) -> list[tuple[str | None, str | None]]:
    """The clips a motion file makes, as (the take a reference stores, the short name its
    clip name ends with): for an FBX file of several takes, each take (the one ``wanted``
    names, :func:`quatmotion.io.fbx.take_index`); for any other file ``[(None, None)]`` (an
    FBX file of one take or none too, ``wanted`` checked against it).

    Raises
    ------
    FormatError
        An FBX file that cannot be read, or without the take ``wanted`` names.
    """
    from quatmotion.io.fbx import FBX_SUFFIXES, read_fbx_takes, take_index, take_labels

    if path.suffix.lower() not in FBX_SUFFIXES:
        return [(None, None)]
    names = read_fbx_takes(path)
    picked = None if wanted is None else take_index(names, wanted, path)
    if len(names) < 2:
        return [(None, None)]
    labels = take_labels(names)
    chosen = range(len(names)) if picked is None else [picked]
    return [(names[k], labels[k]) for k in chosen]


def find_clips(
    sources: Iterable[Motion | str | os.PathLike[str] | ClipSource],
    read: ReadSettings | None = None,
    *,
    on_error: list[tuple[str, str]] | None = None,
) -> list[ClipSource]:
    """The clips named by ``sources``, each with a unique name, its ASF and its content hash.

    Parameters
    ----------
    sources : iterable
        Files, folders (searched recursively), motions in memory, or sources already found.
    read : ReadSettings, optional
        Where AMC skeletons come from.
    on_error : list, optional
        Where a file whose skeleton is not found or that cannot be hashed is noted, as
        ``(file, one-line reason)``, and left out; without it the error is raised.

    Raises
    ------
    FileNotFoundError
        A named path that does not exist.
    ValueError
        Nothing found, or two motions in memory with one name.
    FormatError
        An AMC without a skeleton (when ``on_error`` is None).
    """
    from quatmotion.io import find_motion_files

    read = read or ReadSettings()
    items = list(sources)
    given = [s for s in items if isinstance(s, ClipSource)]
    motions = [m for m in items if isinstance(m, Motion)]
    paths = [Path(p) for p in items if not isinstance(p, Motion | ClipSource)]
    files = find_motion_files(paths) if paths else []
    found: list[ClipSource] = list(given)
    names = unique_names(files)
    for path, name in zip(files, names, strict=True):
        path = Path(os.path.abspath(path))
        try:
            asf = find_skeleton(path, read.skeleton) if path.suffix.lower() == ".amc" else None
            asf = None if asf is None else Path(os.path.abspath(asf))
            takes = file_takes(path, read.take)
            digest = file_digest(path, asf)
        except (FormatError, OSError) as error:
            if on_error is None:
                raise
            on_error.append((str(path), _one_line(error)))
            continue
        for take, label in takes:
            clip = name if label is None else f"{name}/{label}"
            found.append(ClipSource(clip, take_hash(digest, take), path, asf, take=take))
    for motion in motions:
        if not motion.name:
            raise ValueError("a clip given in memory needs a name (Motion.name)")
        found.append(ClipSource(motion.name, motion_hash(motion), motion=motion))
    repeated = duplicates(s.name for s in found)
    if repeated:
        raise ValueError(f"clip names must be unique; repeated: {', '.join(repeated[:5])}")
    if not found and not (on_error and len(on_error)):
        raise ValueError("no clips given")
    return found


def read_clip(source: ClipSource | ClipRef, read: ReadSettings | None = None) -> ReadClip:
    """Read one clip of a collection (a batch job's first step, in the worker).

    Raises
    ------
    FormatError
        A malformed file (naming it and the line).
    ValueError
        A clip beyond a kilometre with ``read.strict`` (naming it).
    FileNotFoundError
        A reference whose file is gone.
    """
    from quatmotion.io import implausible_values, read_motion_checked

    read = read or ReadSettings()
    if isinstance(source, ClipRef):
        path = None if source.path is None else Path(source.path)
        asf = None if source.skeleton_path is None else Path(source.skeleton_path)
        source = ClipSource(source.name, source.sha256, path, asf, take=source.take)
    if source.motion is not None:
        motion, doubts = source.motion, implausible_values(source.motion)
    else:
        if source.path is None:  # a reference stored without its file (a crafted index)
            raise FileNotFoundError(errno.ENOENT, "no file is stored for this clip", source.name)
        amc = source.path.suffix.lower() == ".amc"
        bvh = source.path.suffix.lower() == ".bvh"
        motion, doubts = read_motion_checked(
            source.path,
            source.skeleton_path if amc else None,
            units=None if amc else read.units,
            translations=read.translations if bvh else "auto",
            animation=None if amc or bvh else (source.take or read.take),
        )
    if motion.name != source.name:
        motion = motion.renamed(source.name)
    if read.joint_map:
        motion = with_joint_map(motion, read.joint_map)
    if read.strict:
        for doubt in doubts:
            if doubt.kind == "far":
                raise ValueError(f"{source}: {doubt.message}: not human motion capture")
    return ReadClip(motion, source.ref().with_reading(motion), doubts)


def with_joint_map(
    motion: Motion, joint_map: Sequence[str] | dict[str, str], *, if_fits: bool = False
) -> Motion:
    """``motion`` whose skeleton carries a user's humanoid map (``"Canonical=joint"``
    entries or a mapping), checked against its joints
    (:class:`quatmotion.motion.HumanoidError` naming what does not fit); with ``if_fits``,
    ``motion`` as it is when its skeleton lacks a joint the map names (a collection's stored
    map and a query of another rig)."""
    import copy

    from quatmotion.io import joint_map_dict
    from quatmotion.motion import with_joint_map as skeleton_with

    mapping = dict(joint_map) if isinstance(joint_map, dict) else joint_map_dict(joint_map)
    names = set(motion.skeleton.joint_names) | set(motion.skeleton.site_names)
    if if_fits and not set(mapping.values()) <= names:
        return motion
    skeleton = skeleton_with(motion.skeleton, mapping)
    if skeleton is motion.skeleton:
        return motion
    out = copy.copy(motion)
    object.__setattr__(out, "skeleton", skeleton)
    return out


def _one_line(error: BaseException) -> str:
    text = getattr(error, "reason", None) or str(error) or type(error).__name__
    return str(text).splitlines()[0]


def names_of(sources: Sequence[ClipSource]) -> list[str]:
    """The names of ``sources``, in order."""
    return [s.name for s in sources]
