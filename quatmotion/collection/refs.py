"""Clip identity: the reference every collection file stores, and the names users see.

Conventions
-----------
* A clip is identified by its **content hash** (:attr:`ClipRef.sha256`): SHA-256 of the motion
  file's bytes followed, for an AMC, by its ASF's bytes (the same motion under another skeleton
  is another clip); for a clip made in memory, of its arrays and skeleton. Two files of any
  kind (``.qmz``, ``.qidx``, pose library) hold the same clip exactly when their references'
  hashes are equal: that is the key the web app joins them on.
* :attr:`ClipRef.name` is what a user types and reads, unique within one collection: the file
  stem, or where stems collide, the path relative to the sources' common folder without its
  suffix (``s1/take_001`` and ``s2/take_001``), with the suffix too where only it differs.
* **Takes.** A file of several takes (an FBX file's animation stacks) is a clip per take: its
  reference carries the take's name (:attr:`ClipRef.take`), its hash is the file's bytes'
  then the take's name (:func:`content_hash`), and its name is the file's name then the
  take's short name (``walk/run``: :func:`quatmotion.io.fbx.take_labels`). A file of one take
  is one clip, as any other file (no take, the file's hash): reading it reads its take.
* Paths are stored absolute and resolved (``path``, ``skeleton_path``). A reader that does not
  find a stored path tries it relative to the collection file's folder
  (:meth:`ClipRef.locate`), so a folder moved whole with its library still finds its sources.
"""

from __future__ import annotations

import hashlib
import os
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np

from quatmotion.errors import FormatError
from quatmotion.motion import Motion

__all__ = [
    "ClipRef",
    "content_hash",
    "file_digest",
    "motion_hash",
    "named_for_file",
    "take_hash",
    "unique_names",
]


@dataclass(frozen=True)
class ClipRef:
    """A clip's identity and provenance, as every collection file stores it.

    Attributes
    ----------
    name : str
        Unique within its collection (module conventions).
    sha256 : str
        Content hash, 64 hex digits (module conventions): the identity.
    path : str or None
        The motion file, absolute; None for a clip made in memory.
    skeleton_path : str or None
        The ASF of an AMC, absolute; None otherwise.
    skeleton : str
        :meth:`quatmotion.motion.Skeleton.fingerprint` of the skeleton it was read with
        ("" where not known yet).
    units : str
        The length unit it was read with: a BVH unit name (``"cm"``, ``"in"``...) or centimetres
        per unit (``"2.54 cm"``); ``"asf"`` for an AMC (its ASF states the unit); "" unknown.
    units_guessed : bool
        Whether ``units`` was guessed from the skeleton's size (a BVH read without a unit).
    take : str or None
        The take of a file of several (an FBX animation stack's name) this clip is; None for
        a file of one take or none.
    """

    name: str
    sha256: str
    path: str | None = None
    skeleton_path: str | None = None
    skeleton: str = ""
    units: str = ""
    units_guessed: bool = False
    take: str | None = None

    def __post_init__(self) -> None:
        if not self.name:
            raise ValueError("a clip reference needs a name")
        if len(self.sha256) != 64 or any(c not in "0123456789abcdef" for c in self.sha256):
            raise ValueError(
                f"clip {self.name!r}: sha256 must be 64 hex digits, got {self.sha256!r}"
            )

    @property
    def stem(self) -> str:
        """The last part of the name (the file stem for clips read from files)."""
        return PurePosixPath(self.name).name

    @property
    def file_name(self) -> str | None:
        """The motion file's name (``walk.bvh``), None for a clip made in memory."""
        return Path(self.path).name if self.path else None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields (what the files store)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, values: Mapping[str, Any], source: str | Path | None = None) -> ClipRef:
        """The reference :meth:`to_dict` stored.

        Raises
        ------
        FormatError
            Naming ``source`` for a missing or malformed field.
        """
        try:
            return cls(**dict(values))
        except (TypeError, ValueError) as error:
            raise FormatError(
                f"malformed clip reference {dict(values)!r}: {error}", source
            ) from None

    def with_reading(self, motion: Motion) -> ClipRef:
        """This reference completed by what reading the clip told: fingerprint and unit."""
        extras = motion.skeleton.extras
        if extras.get("format") == "asf":
            units, guessed = "asf", False
        elif "bvh_scale" in extras:
            units = extras.get("bvh_unit") or f"{float(extras['bvh_scale']):g} cm"
            guessed = bool(extras.get("bvh_unit_guessed"))
        else:
            units, guessed = self.units, self.units_guessed
        return replace(
            self, skeleton=motion.skeleton.fingerprint(), units=units, units_guessed=guessed
        )

    def locate(self, base: str | Path | None = None) -> tuple[Path | None, Path | None]:
        """The motion file and ASF as found now: the stored absolute paths, else the same paths
        relative to ``base`` (the folder of the collection file that stored this reference)
        when those exist; None for what is found neither way."""
        return _locate(self.path, base), _locate(self.skeleton_path, base)


def _locate(stored: str | None, base: str | Path | None) -> Path | None:
    if not stored:
        return None
    path = Path(stored)
    if _is_file(path):
        return path
    if base is not None:
        # the sources moved with the collection file: keep the stored path's last parts
        parts = path.parts[1:] if path.is_absolute() else path.parts
        for k in range(len(parts)):
            candidate = Path(base, *parts[k:])
            if _is_file(candidate):
                return candidate
    return None


def _is_file(path: Path) -> bool:
    """Whether ``path`` is a file; a stored path no file system takes (a name too long, a
    NUL) is none."""
    try:
        return path.is_file()
    except (OSError, ValueError):
        return False


def content_hash(
    path: str | Path, skeleton: str | Path | None = None, take: str | None = None
) -> str:
    """SHA-256 (hex) of a motion file's bytes, then of its skeleton file's if given, then of
    the take's name if given (one take of a file of several)."""
    return take_hash(file_digest(path, skeleton), take)


def file_digest(path: str | Path, skeleton: str | Path | None = None) -> Any:
    """The running SHA-256 of a motion file's bytes and its skeleton file's (the part of
    :func:`content_hash` every take of a file shares)."""
    h = hashlib.sha256()
    for p in (path, skeleton):
        if p is not None:
            with open(p, "rb") as f:
                for chunk in iter(lambda: f.read(1 << 20), b""):
                    h.update(chunk)
    return h


def take_hash(digest: Any, take: str | None) -> str:
    """:func:`content_hash` from :func:`file_digest`'s ``digest`` (not changed) and a take."""
    if take is None:
        return digest.hexdigest()
    h = digest.copy()
    h.update(b"\0quatmotion-take\0" + take.encode("utf-8", "surrogatepass"))
    return h.hexdigest()


def motion_hash(motion: Motion) -> str:
    """SHA-256 (hex) of a clip made in memory: its frames, rate and skeleton fingerprint."""
    h = hashlib.sha256(b"quatmotion-motion\0")
    h.update(motion.skeleton.fingerprint().encode())
    h.update(np.float64(motion.fps).tobytes())
    for array in (motion.root_translation, motion.rotations, motion.joint_translations):
        if array is not None:
            a = np.ascontiguousarray(array, dtype=np.float64)
            h.update(str(a.shape).encode())
            h.update(a.tobytes())
    return h.hexdigest()


def unique_names(paths: Sequence[Path]) -> list[str]:
    """Names for clips read from ``paths``: the stem, or where stems collide, the path relative
    to the common folder of the colliding files, without the suffix (with it where only the
    suffix differs), ``/``-separated."""
    paths = [Path(os.path.abspath(p)) for p in paths]
    stems = Counter(p.stem for p in paths)
    names = [p.stem for p in paths]
    colliding = [i for i, p in enumerate(paths) if stems[p.stem] > 1]
    if colliding:
        root = Path(os.path.commonpath([str(paths[i].parent) for i in colliding]))
        for i in colliding:
            names[i] = paths[i].relative_to(root).with_suffix("").as_posix()
        counts = Counter(names)
        for i in colliding:
            if counts[names[i]] > 1:
                names[i] = paths[i].relative_to(root).as_posix()
    return names


def named_for_file(name: str, file_name: str, take: str | None) -> str:
    """The name of a clip called ``name`` once its file is named ``file_name``
    (:func:`unique_names`): that name, and for one take of a file of several (``take`` not
    None), the take's short name after it (the last part of ``name``: ``walk/run``)."""
    return file_name if take is None else f"{file_name}/{PurePosixPath(name).name}"


def duplicates(names: Iterable[str]) -> list[str]:
    """The names that occur more than once, sorted."""
    return sorted(n for n, c in Counter(names).items() if c > 1)


def name_apart(ref: ClipRef, held: Sequence[ClipRef], path: Path | str) -> ClipRef:
    """A new clip's reference named apart from the clips a file at ``path`` holds: where its
    name is taken by another file's clip, :func:`unique_names` over the two paths names it; a
    clip given in memory (no path) with a taken name is an error.

    Raises
    ------
    ValueError
        The name is taken and no path tells the two clips apart.
    """
    names = {r.name: r for r in held}
    if ref.name not in names:
        return ref
    other = names[ref.name]
    if ref.path is not None and other.path is not None and other.path != ref.path:
        renamed = named_for_file(
            ref.name, unique_names([Path(other.path), Path(ref.path)])[1], ref.take
        )
        if renamed not in names:
            return replace(ref, name=renamed)
    raise ValueError(f"{path}: already holds a clip named {ref.name!r}")
