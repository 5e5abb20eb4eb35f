"""Where the motion-capture data lives, and what clips it holds.

Conventions
-----------
* The data folder is ``$QUATMOTION_DATA`` when set, else ``../shared/data`` relative to the
  project root (the directory holding ``pyproject.toml``: found from the package's location,
  else from the current directory upwards). Code only reads it.
* Collections and their layouts (see the data folder's README):

  - ``cmu``: ``cmu/SS/SS_TT.amc`` with skeleton ``cmu/SS/SS.asf``; labels ``subject``,
    ``trial`` and, from the database index, ``description``.
  - ``cmu_bvh``: ``cmu_bvh/SS/SS_TT.bvh``; same labels.
  - ``hdm05``: ``hdm05/clips/CLASS/HDM_AA_CLASS_NNN_120.amc`` with skeleton
    ``hdm05/skeletons/HDM_AA.asf``; labels ``class``, ``actor``, ``take``.
  - ``bandai1``: ``bandai1/clips/dataset-1_CONTENT_STYLE_NNN.bvh`` with a JSON beside it giving
    0-based indices into ``content_label.txt`` and ``style_label.txt``; labels ``content``,
    ``style``, ``take``.

* Every label value is a string. ``ClipEntry.label`` is the one label a classifier would use
  (HDM05 class, Bandai content, CMU description).
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from quatmotion.motion import Motion

__all__ = [
    "COLLECTIONS",
    "DATA_ENV_VAR",
    "ClipEntry",
    "DataNotFoundError",
    "catalogue",
    "cmu_index",
    "data_root",
    "project_root",
]

DATA_ENV_VAR = "QUATMOTION_DATA"
"""Environment variable naming the data folder."""

COLLECTIONS: tuple[str, ...] = ("cmu", "cmu_bvh", "hdm05", "bandai1")
"""The collections :func:`catalogue` knows, in listing order."""

CMU_INDEX_RELPATH = Path("cmu_bvh") / "cmu-mocap-index-text.txt"
"""The CMU database's index of trial descriptions, relative to the data folder."""

_DEFAULT_RELATIVE = Path("..") / "shared" / "data"
_CMU_TRIAL = re.compile(r"^(\d+)_(\d+)$")
_HDM05 = re.compile(r"^HDM_([A-Za-z]+)_(.+)_(\d+)_(\d+)$")
_BANDAI = re.compile(r"^dataset-1_(.+)_(\d+)$")
_INDEX_LINE = re.compile(r"^(\d+)_(\d+)\s+(.*\S)\s*$")


class DataNotFoundError(FileNotFoundError):
    """The motion-capture data folder does not exist (the message says how to point to it)."""


@dataclass(frozen=True)
class ClipEntry:
    """One clip of the data folder.

    Attributes
    ----------
    path : pathlib.Path
        The motion file (absolute).
    format : {"amc", "bvh"}
    collection : {"cmu", "cmu_bvh", "hdm05", "bandai1"}
    skeleton_path : pathlib.Path or None
        The ASF an AMC needs (``None`` for BVH, or when the ASF is missing).
    labels : mapping of str to str
        Read-only labels, see the module docstring.
    """

    path: Path
    format: str
    collection: str
    skeleton_path: Path | None
    labels: Mapping[str, str] = field(default_factory=dict, hash=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "labels", MappingProxyType(dict(self.labels)))

    @property
    def name(self) -> str:
        """The file stem, e.g. ``"02_01"``."""
        return self.path.stem

    def load(self) -> Motion:
        """Read the clip (with its ASF for AMC) through :func:`quatmotion.io.read_motion`."""
        from quatmotion.io import read_motion

        return read_motion(self.path, self.skeleton_path if self.format == "amc" else None)

    @property
    def label(self) -> str:
        """The main class label: HDM05 class, Bandai content, CMU description (or ``""``)."""
        for key in ("class", "content", "description"):
            if key in self.labels:
                return self.labels[key]
        return ""


def project_root() -> Path:
    """The project directory (holding ``pyproject.toml``).

    Looked for above the installed package first (an editable install or a source checkout),
    then from the current directory upwards; the current directory if neither has one.
    """
    starts = [Path(__file__).resolve().parent, Path.cwd().resolve()]
    for start in starts:
        for folder in (start, *start.parents):
            if (folder / "pyproject.toml").is_file() and (folder / "quatmotion").is_dir():
                return folder
    return Path.cwd().resolve()


def data_root(must_exist: bool = True) -> Path:
    """The motion-capture data folder.

    Parameters
    ----------
    must_exist : bool
        Raise :class:`DataNotFoundError` when the folder is absent (else just return the path).

    Returns
    -------
    pathlib.Path
        ``$QUATMOTION_DATA`` if set, else ``<project root>/../shared/data``, resolved.
    """
    configured = os.environ.get(DATA_ENV_VAR)
    root = Path(configured).expanduser() if configured else project_root() / _DEFAULT_RELATIVE
    root = root.resolve()
    if must_exist and not root.is_dir():
        how = (
            f"{DATA_ENV_VAR}={configured!r} is not a folder"
            if configured
            else f"the default {root} does not exist; set {DATA_ENV_VAR} to the data folder"
        )
        raise DataNotFoundError(f"motion-capture data not found: {how}")
    return root


def cmu_index(path: str | Path | None = None) -> dict[str, str]:
    """Trial descriptions of the CMU database index: ``{"02_01": "walk", ...}``.

    Parameters
    ----------
    path : str or Path, optional
        The index text file (default: ``cmu_bvh/cmu-mocap-index-text.txt`` in the data folder).
        A missing file gives an empty mapping.

    Returns
    -------
    dict of str to str
        Trial id ``SS_TT`` (as written in the index) to its description.
    """
    if path is None:
        try:
            path = data_root() / CMU_INDEX_RELPATH
        except DataNotFoundError:
            return {}
    path = Path(path)
    if not path.is_file():
        return {}
    out: dict[str, str] = {}
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        match = _INDEX_LINE.match(line)
        if match:
            out[f"{match.group(1)}_{match.group(2)}"] = match.group(3)
    return out


def _cmu_entries(root: Path, collection: str, descriptions: Mapping[str, str]) -> list[ClipEntry]:
    suffix = ".amc" if collection == "cmu" else ".bvh"
    folder = root / collection
    entries = []
    for path in sorted(folder.glob(f"*/*{suffix}")):
        match = _CMU_TRIAL.match(path.stem)
        labels = {}
        if match:
            labels = {"subject": match.group(1), "trial": match.group(2)}
            if path.stem in descriptions:
                labels["description"] = descriptions[path.stem]
        skeleton = None
        if collection == "cmu":
            asf = path.parent / f"{path.parent.name}.asf"
            skeleton = asf if asf.is_file() else None
        entries.append(ClipEntry(path, suffix[1:], collection, skeleton, labels))
    return entries


def _hdm05_entries(root: Path) -> list[ClipEntry]:
    entries = []
    for path in sorted((root / "hdm05" / "clips").glob("*/*.amc")):
        match = _HDM05.match(path.stem)
        labels = {"class": path.parent.name}
        skeleton = None
        if match:
            actor, cls, take, fps = match.groups()
            labels = {"class": cls, "actor": actor, "take": take, "fps": fps}
            asf = root / "hdm05" / "skeletons" / f"HDM_{actor}.asf"
            skeleton = asf if asf.is_file() else None
        entries.append(ClipEntry(path, "amc", "hdm05", skeleton, labels))
    return entries


def _label_lines(path: Path) -> list[str]:
    if not path.is_file():
        return []
    names = [line.strip() for line in path.read_text(encoding="utf-8").splitlines()]
    return [n.removeprefix("dataset-1_") for n in names if n]


def _bandai_entries(root: Path) -> list[ClipEntry]:
    base = root / "bandai1"
    contents = _label_lines(base / "content_label.txt")
    styles = _label_lines(base / "style_label.txt")
    entries = []
    for path in sorted((base / "clips").glob("*.bvh")):
        labels: dict[str, str] = {}
        match = _BANDAI.match(path.stem)
        if match:
            labels["take"] = match.group(2)
        meta = path.with_suffix(".json")
        if meta.is_file():
            try:
                info = json.loads(meta.read_text(encoding="utf-8"))
                if 0 <= int(info["content"]) < len(contents):
                    labels["content"] = contents[int(info["content"])]
                if 0 <= int(info["style"]) < len(styles):
                    labels["style"] = styles[int(info["style"])]
            except (ValueError, KeyError, TypeError):
                pass  # an unreadable sidecar leaves the clip unlabelled rather than hidden
        entries.append(ClipEntry(path, "bvh", "bandai1", None, labels))
    return entries


def catalogue(
    root: str | Path | None = None,
    collection: str | Iterable[str] | None = None,
    labels: Mapping[str, str] | None = None,
    match: str | None = None,
) -> list[ClipEntry]:
    """Every clip in the data folder, optionally filtered.

    Parameters
    ----------
    root : str or Path, optional
        The data folder (default: :func:`data_root`).
    collection : str or iterable of str, optional
        Keep only these collections (names from :data:`COLLECTIONS`).
    labels : mapping, optional
        Keep clips whose labels equal all of these (case-insensitive), e.g. ``{"class":
        "squat1Reps"}`` or ``{"actor": "bd"}``.
    match : str, optional
        Keep clips with a label value or file name containing this text (case-insensitive).

    Returns
    -------
    list of ClipEntry
        Ordered by collection (as in :data:`COLLECTIONS`), then by path.

    Raises
    ------
    DataNotFoundError
        When the data folder does not exist.
    ValueError
        For an unknown collection name.
    """
    base = data_root() if root is None else Path(root).resolve()
    if not base.is_dir():
        raise DataNotFoundError(f"motion-capture data not found: {base} is not a folder")
    wanted = (
        COLLECTIONS
        if collection is None
        else ((collection,) if isinstance(collection, str) else tuple(collection))
    )
    unknown = [c for c in wanted if c not in COLLECTIONS]
    if unknown:
        raise ValueError(f"unknown collection(s) {unknown}; choose from {', '.join(COLLECTIONS)}")
    entries: list[ClipEntry] = []
    for name in COLLECTIONS:
        if name not in wanted or not (base / name).is_dir():
            continue
        if name in ("cmu", "cmu_bvh"):
            entries += _cmu_entries(base, name, cmu_index(base / CMU_INDEX_RELPATH))
        elif name == "hdm05":
            entries += _hdm05_entries(base)
        else:
            entries += _bandai_entries(base)
    if labels:
        want = {k: str(v).lower() for k, v in labels.items()}
        entries = [
            e for e in entries if all(e.labels.get(k, "").lower() == v for k, v in want.items())
        ]
    if match:
        needle = match.lower()
        entries = [
            e
            for e in entries
            if needle in e.name.lower() or any(needle in v.lower() for v in e.labels.values())
        ]
    return entries
