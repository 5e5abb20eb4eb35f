"""The clip index's file: a SQLite database (``.qidx``) of clips, their labels and their
features, read and written; what the build (:mod:`~quatmotion.retrieval.build`) writes and the
search (:mod:`~quatmotion.retrieval.search`) reads, importing neither. Users open it as
:class:`quatmotion.retrieval.ClipIndex` (:mod:`~quatmotion.retrieval.index`), which adds
``build``/``add``/``search`` on top.

Conventions
-----------
* One SQLite database (the standard library's :mod:`sqlite3`); the schema of every version is
  in docs/format.md. Table ``meta`` holds the format name, its version, the feature parameters
  and the :class:`IndexSettings` the index was built with; ``clips`` one row per clip: its
  :class:`~quatmotion.collection.ClipRef` (unique name, content hash, absolute paths, skeleton
  fingerprint, units), label, frames, fps and the rotation key the dictionary methods compare
  (:func:`~quatmotion.retrieval.features.skeleton_fingerprint`); ``features`` one row per clip
  and feature array, the array as ``.npy`` bytes (``numpy.save``, no pickles); ``blobs`` what
  the whole index shares (a learned model...), a key to bytes, so a method can store its own
  without a new format version.
* A clip and all its feature rows are written in one transaction, and transactions are
  committed in batches: a build that is killed leaves a readable index of the clips committed
  so far, and the next build skips them (same path and content hash).
* Versions (:data:`FORMAT`): 3 adds the take of a clip that is one take of a file of several
  (``clips.take``: :attr:`ClipRef.take`); 2 writes the clip references and the settings, is
  read with no takes and, opened for writing, is made a version 3 in place (the column added,
  the version changed, in one transaction); 1 (quatmotion 0.3.0, paths as given, names the
  file stems) is still read, its clips given references on reading (names made unique, paths
  resolved against the index's folder), and is extended only after a rebuild. What differs
  between them is one reader per version (:data:`_READERS`), chosen once when the file is
  opened.
* Opening checks the format and version (:class:`~quatmotion.errors.FormatError` for a file
  that is not SQLite, a truncated database, another format, or a version this code does not
  read) and that the feature parameters are the ones this code computes (else: rebuild).
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import io
import json
import os
import sqlite3
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from numbers import Integral
from pathlib import Path
from typing import Any, ClassVar, Self

import numpy as np

from quatmotion._atomic import atomic_output
from quatmotion._format import FileFormat
from quatmotion._settings import Interval, Settings
from quatmotion.collection import ClipRef, ReadSettings, unique_names
from quatmotion.collection.refs import content_hash
from quatmotion.errors import ClipNameError, FormatError
from quatmotion.io.names import match_clip
from quatmotion.retrieval.features_fused import streams_mismatch
from quatmotion.retrieval.methods import FEATURE_KINDS, Library
from quatmotion.retrieval.stored import FEATURE_PARAMETERS, FORMAT, check_index, read_array

__all__ = [
    "FORMAT",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "ClipRecord",
    "ClipRow",
    "IndexFile",
    "IndexSettings",
    "content_hash",
    "match_row",
]

FORMAT_NAME = FORMAT.name
FORMAT_VERSION = FORMAT.version
_SQLITE_MAGIC = b"SQLite format 3\x00"


@dataclass(frozen=True)
class IndexSettings(Settings):
    """How a clip index is built (stored in its ``meta`` table, shown by ``index ls``).

    Attributes
    ----------
    kinds : tuple of str
        Feature kinds computed (:data:`~quatmotion.retrieval.methods.FEATURE_KINDS`): ``motion``
        serves the default method and ``--within``; ``qssd``/``ksvd`` the paper's dictionaries,
        computed only when asked for (they cost several times ``motion`` and only the
        ``paper-*`` methods read them).
    batch : int
        Clips per committed transaction (what a killed build keeps).
    label_folders : bool
        Label a clip without another label by its folder's name (HDM05's ``CLASS/file.amc``).
    label_sidecars : bool
        Read labels from the clips' sidecars (bandai's JSON, ``K_label.txt``).
    read : ReadSettings
        How the clips are read (BVH unit, the AMC skeletons...).
    """

    kinds: tuple[str, ...] = ("motion",)
    batch: int = 16
    label_folders: bool = False
    label_sidecars: bool = True
    read: ReadSettings = dataclasses.field(default_factory=ReadSettings)

    _parameter_constraints: ClassVar[dict[str, list[Any]]] = {
        "kinds": [tuple],
        "batch": [Interval(Integral, 1, None, closed="left")],
        "label_folders": ["boolean"],
        "label_sidecars": ["boolean"],
        "read": [ReadSettings],
    }

    def _check(self) -> None:
        unknown = [k for k in self.kinds if k not in FEATURE_KINDS]
        if unknown or not self.kinds:
            raise ValueError(
                f"unknown feature kinds {list(unknown)}; choose from {', '.join(FEATURE_KINDS)}"
            )


_SCHEMA = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE clips (
    id INTEGER PRIMARY KEY,
    name TEXT NOT NULL UNIQUE,
    sha256 TEXT NOT NULL,
    path TEXT,
    skeleton_path TEXT,
    skeleton TEXT NOT NULL DEFAULT '',
    units TEXT NOT NULL DEFAULT '',
    units_guessed INTEGER NOT NULL DEFAULT 0,
    take TEXT,
    label TEXT NOT NULL DEFAULT '',
    frames INTEGER NOT NULL,
    fps REAL NOT NULL,
    rotation_key TEXT NOT NULL
);
CREATE INDEX clips_sha256 ON clips (sha256);
CREATE INDEX clips_path ON clips (path);
CREATE TABLE features (
    clip INTEGER NOT NULL REFERENCES clips (id) ON DELETE CASCADE,
    key TEXT NOT NULL,
    data BLOB NOT NULL,
    PRIMARY KEY (clip, key)
);
CREATE TABLE blobs (key TEXT PRIMARY KEY, data BLOB NOT NULL);
"""


@dataclass(frozen=True)
class ClipRecord:
    """A clip ready to be stored: what :meth:`IndexFile.store` writes.

    ``rotation_key`` is :func:`~quatmotion.retrieval.features.skeleton_fingerprint` (the
    rotating joints, what the dictionary methods compare); ``ref.skeleton`` the skeleton's
    full fingerprint.
    """

    ref: ClipRef
    label: str
    frames: int
    fps: float
    rotation_key: str
    arrays: dict[str, np.ndarray]


@dataclass(frozen=True)
class ClipRow:
    """One indexed clip (without its features).

    ``path`` is where the clip's file is now (:meth:`ClipRef.locate` against the index's
    folder), else the stored path; ``skeleton`` the rotation key the methods compare.
    """

    id: int
    ref: ClipRef
    label: str
    frames: int
    fps: float
    rotation_key: str
    path: str

    @property
    def name(self) -> str:
        return self.ref.name

    @property
    def sha256(self) -> str:
        return self.ref.sha256

    @property
    def skeleton(self) -> str:
        return self.rotation_key

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready: the reference's fields, then the row's."""
        return {
            **self.ref.to_dict(),
            "path": self.path,
            "label": self.label,
            "frames": self.frames,
            "fps": self.fps,
            "rotation_key": self.rotation_key,
        }


def _to_blob(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(a), allow_pickle=False)
    return buf.getvalue()


@contextlib.contextmanager
def _writing(path: Path) -> Iterator[None]:
    """SQLite's write errors as an ``OSError`` naming the index file ("unable to open database
    file", "attempt to write a readonly database", "database or disk is full")."""
    try:
        yield
    except sqlite3.OperationalError as error:
        raise OSError(errno.EIO, f"cannot write the index ({error})", str(path)) from None


class IndexFile:
    """An open clip index file (use as a context manager, or call :meth:`close`): its rows,
    features and blobs, read and written. :meth:`open` reads one (writes with ``write``);
    :class:`~quatmotion.retrieval.index.ClipIndex` is this class with the build and the search.
    """

    def __init__(
        self,
        connection: sqlite3.Connection,
        path: Path,
        version: int = FORMAT_VERSION,
        settings: IndexSettings | None = None,
    ) -> None:
        self._db = connection
        self.path = path
        self.version = version
        self._reader = _READERS[version]
        self.settings = settings or IndexSettings()

    @property
    def format(self) -> FileFormat:
        """The format, with the version this file was written in."""
        return dataclasses.replace(FORMAT, version=self.version)

    @property
    def holds_blobs(self) -> bool:
        """Whether the file has the ``blobs`` table (a version-1 index has none)."""
        return self._reader.blobs

    @classmethod
    def create(cls, path: str | Path, settings: IndexSettings | None = None) -> Self:
        """:meth:`_create` (the name before 0.4.0; warns): build with :meth:`build`."""
        from quatmotion._deprecated import warn_renamed

        warn_renamed("ClipIndex.create", "ClipIndex.build (or open)")
        return cls._create(path, settings)

    @classmethod
    def _create(cls, path: str | Path, settings: IndexSettings | None = None) -> Self:
        """A new, empty index at ``path``, open for writing.

        Raises
        ------
        FileExistsError
            A non-empty file is there (resume it with :meth:`build` or :meth:`add`).
        """
        path = Path(path)
        if path.exists() and path.stat().st_size > 0:
            raise FileExistsError(errno.EEXIST, "an index is already there", str(path))
        settings = settings or IndexSettings()
        # The schema and the meta table go into a temporary file renamed into place: a new
        # index appears whole or not at all (sqlite3's executescript commits each statement).
        with atomic_output(path) as temp:
            db = sqlite3.connect(temp)
            try:
                with _writing(path), db:
                    db.executescript(_SCHEMA)
                    db.executemany(
                        "INSERT INTO meta VALUES (?, ?)",
                        [
                            ("format", FORMAT_NAME),
                            ("version", str(FORMAT_VERSION)),
                            ("features", json.dumps(FEATURE_PARAMETERS, sort_keys=True)),
                            ("settings", json.dumps(settings.to_dict(), sort_keys=True)),
                        ],
                    )
            finally:
                db.close()
        db = sqlite3.connect(path)
        db.execute("PRAGMA foreign_keys = ON")
        return cls(db, path, FORMAT_VERSION, settings)

    @classmethod
    def open(cls, path: str | Path, write: bool = False) -> Self:
        """Open an index (read-only unless ``write``), checking its format, version and
        feature parameters.

        Raises
        ------
        FileNotFoundError
            No such file.
        FormatError
            Not a SQLite file, a damaged one, another format, a version this code does not
            read, features computed with other parameters, or ``write`` on a version-1 index.
        """
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(2, "no such index file", str(path))
        with open(path, "rb") as f:
            head = f.read(len(_SQLITE_MAGIC))
        if head != _SQLITE_MAGIC:
            raise FormatError("not a quatmotion index (not an SQLite database)", path)
        uri = f"{path.resolve().as_uri()}?mode={'rw' if write else 'ro'}"
        db = sqlite3.connect(uri, uri=True)
        try:
            version, meta = check_index(db, path)
            reader = _READERS[version]
            if write and reader.read_only is not None:
                raise FormatError(reader.read_only, path)
            settings = reader.settings(meta, path)
            if write and version == 2:
                version = _upgrade_v2(db, path)
        except (FormatError, ValueError, TypeError) as error:
            db.close()
            if isinstance(error, FormatError):
                raise
            raise FormatError(f"malformed index meta table ({error})", path) from None
        if write:
            db.execute("PRAGMA foreign_keys = ON")
        return cls(db, path, version, settings)

    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- reading -------------------------------------------------------------------------
    def rows(self) -> list[ClipRow]:
        """Every clip with its label, frames and fps, in insertion order."""
        return self._reader.rows(self._db, self.path)

    def clips(self) -> tuple[ClipRef, ...]:
        """Every clip's reference, in insertion order (what the collection kinds share)."""
        return tuple(r.ref for r in self.rows())

    def labels(self) -> dict[str, str]:
        """Clip name -> label ("" for none)."""
        return {r.name: r.label for r in self.rows()}

    def __len__(self) -> int:
        return int(self._db.execute("SELECT count(*) FROM clips").fetchone()[0])

    def contains(self, path: str | Path, sha256: str) -> bool:
        """Whether ``path`` is indexed with this content hash."""
        stored = self._reader.stored_path(path)
        row = self._db.execute(
            "SELECT 1 FROM clips WHERE path = ? AND sha256 = ?", (stored, sha256)
        ).fetchone()
        return row is not None

    def feature_keys(self) -> dict[int, set[str]]:
        """Per clip id, the feature arrays stored."""
        out: dict[int, set[str]] = {}
        for clip, key in self._db.execute("SELECT clip, key FROM features"):
            out.setdefault(int(clip), set()).add(key)
        return out

    def find(self, name: str) -> ClipRow:
        """The clip ``name`` names: its name, a unique end of it (stem, trailing folders), its
        number (:func:`quatmotion.io.names.match_clip`, every command's rule) or its path.

        Raises
        ------
        ValueError
            (:class:`~quatmotion.errors.ClipNameError`) No such clip, or several (naming them).
        """
        rows = self.rows()
        return rows[match_row(name, rows, str(self.path))]

    def load(self, keys: Iterable[str]) -> tuple[list[ClipRow], Library]:
        """The clips that have every feature array in ``keys``, and a :class:`Library` of them."""
        keys = tuple(keys)
        rows = self.rows()
        arrays: dict[int, dict[str, np.ndarray]] = {r.id: {} for r in rows}
        if keys:
            marks = ",".join("?" * len(keys))
            for clip, key, data in self._db.execute(
                f"SELECT clip, key, data FROM features WHERE key IN ({marks})", keys
            ):
                arrays[int(clip)][key] = read_array(data, self.path, f"feature {key!r}")
        rows = [r for r in rows if all(k in arrays[r.id] for k in keys)]
        for r in rows:
            a = arrays[r.id]
            if "frames" in a and "path" in a and (why := streams_mismatch(a["frames"], a["path"])):
                raise FormatError(f"clip {r.name!r}: {why}", self.path)
        stored = {}
        if self._reader.blobs:
            for key, data in self._db.execute(
                "SELECT key, data FROM blobs WHERE key LIKE 'model:%'"
            ):
                if not isinstance(data, bytes):  # bytes(10**9) would make a gigabyte
                    what = f"stored model {key!r} is a {type(data).__name__}, not bytes"
                    raise FormatError(what, self.path)
                stored[str(key)] = data
        library = Library(
            [arrays[r.id] for r in rows],
            [r.rotation_key for r in rows],
            stored,
            [r.label for r in rows],
        )
        return rows, library

    def blob(self, key: str) -> bytes | None:
        """What :meth:`set_blob` stored under ``key`` (None: nothing; a version-1 index has
        none)."""
        if not self._reader.blobs:
            return None
        row = self._db.execute("SELECT data FROM blobs WHERE key = ?", (key,)).fetchone()
        return None if row is None else bytes(row[0])

    # -- writing (an index opened with write=True, or made by create) ----------------------
    def store(self, records: Iterable[ClipRecord]) -> int:
        """Store clips in one transaction (a clip already at the same path, or of the same
        name, is replaced).

        Returns
        -------
        int
            Clips written.
        """
        n = 0
        with _writing(self.path), self._db:
            for r in records:
                ref = r.ref
                if ref.path is not None:  # the file's old clip, or that take's (and a whole file's)
                    self._db.execute(
                        "DELETE FROM clips WHERE path = ? AND (? IS NULL OR take IS NULL "
                        "OR take = ?)",
                        (ref.path, ref.take, ref.take),
                    )
                self._db.execute("DELETE FROM clips WHERE name = ?", (ref.name,))
                cur = self._db.execute(
                    "INSERT INTO clips (name, sha256, path, skeleton_path, skeleton, units, "
                    "units_guessed, take, label, frames, fps, rotation_key) "
                    "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                    (
                        ref.name,
                        ref.sha256,
                        ref.path,
                        ref.skeleton_path,
                        ref.skeleton,
                        ref.units,
                        int(ref.units_guessed),
                        ref.take,
                        r.label,
                        r.frames,
                        r.fps,
                        r.rotation_key,
                    ),
                )
                self._db.executemany(
                    "INSERT INTO features (clip, key, data) VALUES (?, ?, ?)",
                    [(cur.lastrowid, k, _to_blob(a)) for k, a in r.arrays.items()],
                )
                n += 1
        return n

    def rename(self, names: dict[str, str]) -> None:
        """Rename clips (old name -> new), in one transaction (names stay unique)."""
        if not names:
            return
        with _writing(self.path), self._db:
            for old in names:  # through temporary names: a new name may be another's old one
                self._db.execute("UPDATE clips SET name = ? WHERE name = ?", (f"\0{old}", old))
            for old, new in names.items():
                self._db.execute("UPDATE clips SET name = ? WHERE name = ?", (new, f"\0{old}"))

    def write_settings(self, settings: IndexSettings) -> None:
        """Store the settings of the latest build (what ``index ls`` shows)."""
        with _writing(self.path), self._db:
            self._db.execute(
                "INSERT OR REPLACE INTO meta VALUES ('settings', ?)",
                (json.dumps(settings.to_dict(), sort_keys=True),),
            )
        self.settings = settings

    def set_blob(self, key: str, data: bytes) -> None:
        """Store bytes the whole index shares under ``key`` (a learned model...)."""
        with _writing(self.path), self._db:
            self._db.execute("INSERT OR REPLACE INTO blobs VALUES (?, ?)", (key, data))

    def remove(self, names: Iterable[str]) -> list[str]:
        """Remove the clips named (as :meth:`find` reads a name; nothing is removed when one
        of them names no clip or several); returns the names removed."""
        rows = [self.find(name) for name in names]
        with _writing(self.path), self._db:
            for row in rows:
                self._db.execute("DELETE FROM clips WHERE id = ?", (row.id,))
        return list(dict.fromkeys(row.name for row in rows))

    def set_labels(self, labels: dict[str, str]) -> int:
        """Set the label of the clips named in ``labels`` (by name); returns how many
        changed."""
        n = 0
        with _writing(self.path), self._db:
            for row in self.rows():
                label = labels.get(row.name)
                if label is not None and label != row.label:
                    self._db.execute("UPDATE clips SET label = ? WHERE id = ?", (label, row.id))
                    n += 1
        return n


# -- the readers, one per version ----------------------------------------------------------
@dataclass(frozen=True)
class _Reader:
    """What reading one format version takes; :meth:`IndexFile.open` picks it once.

    ``rows`` reads the clips table; ``settings`` the stored :class:`IndexSettings` from the
    meta table; ``stored_path`` is how a clip's path is written in the clips table (what
    :meth:`IndexFile.contains` compares); ``blobs`` whether the file has the blobs table;
    ``read_only`` None for a version this code extends, else why it does not.
    """

    rows: Callable[[sqlite3.Connection, Path], list[ClipRow]]
    settings: Callable[[dict[str, str], Path], IndexSettings]
    stored_path: Callable[[str | Path], str]
    blobs: bool
    read_only: str | None


def _settings_v2(meta: dict[str, str], path: Path) -> IndexSettings:
    if "settings" not in meta:
        return IndexSettings()
    return IndexSettings.from_dict(json.loads(meta["settings"]), path)  # check_index's JSON


def _settings_v1(meta: dict[str, str], path: Path) -> IndexSettings:
    return IndexSettings()  # 0.3.0 stored none: the defaults of that release


def _stored_path_v1(path: str | Path) -> str:
    return str(path)  # as given at build time


def _upgrade_v2(db: sqlite3.Connection, path: Path) -> int:
    """A version-2 index opened for writing made a version 3: the ``take`` column added, the
    version changed, in one transaction (a version-2 clip is a whole file: no take)."""
    with _writing(path), db:
        db.execute("ALTER TABLE clips ADD COLUMN take TEXT")
        db.execute("UPDATE meta SET value = '3' WHERE key = 'version'")
    return 3


def _rows_v3(db: sqlite3.Connection, path: Path) -> list[ClipRow]:
    return _rows_v2(db, path, take="take")


def _rows_v2(db: sqlite3.Connection, path: Path, take: str = "NULL") -> list[ClipRow]:
    """Version 2's rows (no ``take`` column: every clip a whole file); version 3's with
    ``take="take"``."""
    base = path.resolve().parent
    out = []
    with _row_errors(path):
        for row in db.execute(
            "SELECT id, name, sha256, path, skeleton_path, skeleton, units, units_guessed, "
            f"{take}, label, frames, fps, rotation_key FROM clips ORDER BY id"
        ):
            (clip, name, sha, stored, asf, skeleton, units, guessed, take_name, label, *rest) = row
            frames, fps, key = rest
            _texts(path, clip, name=name, sha256=sha, path=stored, skeleton_path=asf,
                   skeleton=skeleton, units=units, take=take_name, label=label,
                   rotation_key=key)  # fmt: skip
            ref = ClipRef(name, sha, stored, asf, skeleton, units, bool(guessed), take_name)
            found = ref.locate(base)[0]
            where = str(found) if found is not None else (stored or "")
            out.append(ClipRow(int(clip), ref, label, int(frames), float(fps), key, where))
    return out


@contextlib.contextmanager
def _row_errors(path: Path) -> Iterator[None]:
    """A clip row no writer made (text that is no UTF-8, a reference that is no reference) as
    a FormatError naming the index."""
    try:
        yield
    except sqlite3.Error as error:
        raise FormatError(f"the clips table cannot be read ({error})", path) from None
    except (ValueError, TypeError) as error:
        raise FormatError(f"a clip row is invalid: {error}", path) from None


def _texts(index: Path, clip: Any, **values: Any) -> None:
    """Each of ``values`` (a clip row's text columns) text or NULL, never a blob or a number."""
    for column, value in values.items():
        if value is not None and not isinstance(value, str):
            kind = type(value).__name__
            raise FormatError(f"clip row {clip!r}: {column} is a {kind}, not text", index)


def _rows_v1(db: sqlite3.Connection, path: Path) -> list[ClipRow]:
    """Version 1 (0.3.0): paths as given at build time (relative to where it ran), names the
    stems (not unique), no settings. Paths resolve against the index's folder when they are
    found there; names are made unique as a v2 build would make them."""
    base = path.resolve().parent
    with _row_errors(path):
        raw = db.execute(
            "SELECT id, name, path, sha256, label, frames, fps, skeleton FROM clips ORDER BY id"
        ).fetchall()
    for clip, name, stored, sha, label, *_ in raw:
        _texts(path, clip, name=name, path=stored, sha256=sha, label=label)
    paths = []
    for _, _, stored, *_ in raw:
        p = Path(stored)
        if not p.is_absolute() and (base / p).is_file():
            p = base / p
        paths.append(Path(os.path.abspath(p)))
    names = unique_names(paths)
    out = []
    with _row_errors(path):
        for (clip, _, _, sha, label, frames, fps, key), p, name in zip(
            raw, paths, names, strict=True
        ):
            ref = ClipRef(name, sha, str(p))
            out.append(ClipRow(int(clip), ref, label, int(frames), float(fps), key, str(p)))
    return out


_READERS = {
    1: _Reader(
        _rows_v1,
        _settings_v1,
        _stored_path_v1,
        blobs=False,
        read_only="a version-1 index (quatmotion 0.3.0) is read-only: rebuild it with "
        "quatmotion index build to extend it",
    ),
    2: _Reader(_rows_v2, _settings_v2, os.path.abspath, blobs=True, read_only=None),
    3: _Reader(_rows_v3, _settings_v2, os.path.abspath, blobs=True, read_only=None),
}
"""The reader of each format version this code reads, kept once released."""


def match_row(query: str, rows: list[ClipRow], where: str) -> int:
    """The row ``query`` names: by name (the unique names), else by a path's end, else by
    the absolute path."""
    try:
        return match_clip(query, [r.name for r in rows], where)
    except ClipNameError as by_name:
        if "ambiguous" in str(by_name):
            raise
        try:
            return match_clip(query, [r.path for r in rows], where)
        except ClipNameError:
            absolute = os.path.abspath(query)
            for i, r in enumerate(rows):
                if r.path == absolute or r.ref.path == absolute:
                    return i
            raise by_name from None
