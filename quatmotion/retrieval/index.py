"""The clip index: a SQLite file (``.qidx``) of clips, their labels and their features.

Conventions
-----------
* One SQLite database (the standard library's :mod:`sqlite3`). Table ``meta`` holds the format
  name, its version and the feature parameters; ``clips`` one row per clip (name, path, content
  hash, label, frames, fps, skeleton fingerprint); ``features`` one row per clip and feature
  array, the array as ``.npy`` bytes (``numpy.save``, no pickles).
* A clip and all its feature rows are written in one transaction, and transactions are
  committed in batches: a build that is killed leaves a readable index of the clips committed
  so far, and :meth:`ClipIndex.contains` lets the next build skip them.
* The content hash is SHA-256 of the motion file's bytes, followed for an AMC by its ASF's:
  the same clip under another skeleton is another clip.
* Opening checks the format and version (:class:`~quatmotion.errors.FormatError` for a file
  that is not SQLite, a truncated database, another format, or a newer version) and that
  the feature parameters are the ones this code computes (else: rebuild).
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import io
import json
import sqlite3
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from quatmotion.errors import FormatError
from quatmotion.io.names import match_clip
from quatmotion.retrieval import features as feat
from quatmotion.retrieval.methods import Library

__all__ = ["FORMAT_NAME", "FORMAT_VERSION", "ClipIndex", "ClipRecord", "ClipRow", "content_hash"]

FORMAT_NAME = "quatmotion-retrieval-index"
FORMAT_VERSION = 1
_SQLITE_MAGIC = b"SQLite format 3\x00"

FEATURE_PARAMETERS = {
    "feature_fps": feat.FEATURE_FPS,
    "height_cm": feat.HEIGHT_CM,
    "horizon_s": feat.HORIZON_S,
    "yaw_radius_cm": feat.YAW_RADIUS_CM,
    "dictionary_atoms": feat.DICTIONARY_ATOMS,
    "dictionary_sparsity": feat.DICTIONARY_SPARSITY,
    "dictionary_max_fps": feat.DICTIONARY_MAX_FPS,
    "dictionary_max_iter": feat.DICTIONARY_MAX_ITER,
}
"""What the stored features depend on; an index built with other values must be rebuilt."""

_SCHEMA = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE clips (
    id INTEGER PRIMARY KEY,
    name TEXT NOT NULL,
    path TEXT NOT NULL UNIQUE,
    sha256 TEXT NOT NULL,
    label TEXT NOT NULL DEFAULT '',
    frames INTEGER NOT NULL,
    fps REAL NOT NULL,
    skeleton TEXT NOT NULL
);
CREATE INDEX clips_name ON clips (name);
CREATE TABLE features (
    clip INTEGER NOT NULL REFERENCES clips (id) ON DELETE CASCADE,
    key TEXT NOT NULL,
    data BLOB NOT NULL,
    PRIMARY KEY (clip, key)
);
"""


def content_hash(path: str | Path, skeleton: str | Path | None = None) -> str:
    """SHA-256 (hex) of a motion file's bytes, then of its skeleton file's if given."""
    h = hashlib.sha256()
    for p in (path, skeleton):
        if p is not None:
            with open(p, "rb") as f:
                for chunk in iter(lambda: f.read(1 << 20), b""):
                    h.update(chunk)
    return h.hexdigest()


@dataclass(frozen=True)
class ClipRecord:
    """A clip ready to be stored: what :meth:`ClipIndex.add` writes."""

    name: str
    path: str
    sha256: str
    label: str
    frames: int
    fps: float
    skeleton: str
    arrays: dict[str, np.ndarray]


@dataclass(frozen=True)
class ClipRow:
    """One indexed clip (without its features)."""

    id: int
    name: str
    path: str
    sha256: str
    label: str
    frames: int
    fps: float
    skeleton: str


def _to_blob(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(a), allow_pickle=False)
    return buf.getvalue()


def _from_blob(b: bytes) -> np.ndarray:
    return np.load(io.BytesIO(b), allow_pickle=False)


@contextlib.contextmanager
def _writing(path: Path) -> Iterator[None]:
    """SQLite's write errors as an ``OSError`` naming the index file ("unable to open database
    file", "attempt to write a readonly database", "database or disk is full")."""
    try:
        yield
    except sqlite3.OperationalError as error:
        raise OSError(errno.EIO, f"cannot write the index ({error})", str(path)) from None


class ClipIndex:
    """An open clip index (use as a context manager, or call :meth:`close`).

    Use :meth:`create` for a new file and :meth:`open` for an existing one.
    """

    def __init__(self, connection: sqlite3.Connection, path: Path) -> None:
        self._db = connection
        self.path = path

    # -- opening -------------------------------------------------------------------------
    @classmethod
    def create(cls, path: str | Path) -> ClipIndex:
        """A new, empty index at ``path``; an existing index there is opened for writing
        instead (so that a build resumes), after the checks of :meth:`open`."""
        path = Path(path)
        if path.exists() and path.stat().st_size > 0:
            return cls.open(path, write=True)
        path.parent.mkdir(parents=True, exist_ok=True)
        db = sqlite3.connect(path)
        try:
            with _writing(path), db:
                db.executescript(_SCHEMA)
                db.executemany(
                    "INSERT INTO meta VALUES (?, ?)",
                    [
                        ("format", FORMAT_NAME),
                        ("version", str(FORMAT_VERSION)),
                        ("features", json.dumps(FEATURE_PARAMETERS, sort_keys=True)),
                    ],
                )
        except BaseException:
            db.close()
            raise
        db.execute("PRAGMA foreign_keys = ON")
        return cls(db, path)

    @classmethod
    def open(cls, path: str | Path, write: bool = False) -> ClipIndex:
        """Open an index, checking its format, version and feature parameters.

        Raises
        ------
        FileNotFoundError
            No such file.
        FormatError
            Not a SQLite file, a damaged one, another format, a newer version, or features
            computed with other parameters.
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
            meta = dict(db.execute("SELECT key, value FROM meta").fetchall())
            db.execute("SELECT count(*) FROM clips").fetchone()
            db.execute("SELECT count(*) FROM features").fetchone()
            db.execute("PRAGMA quick_check").fetchone()
        except sqlite3.DatabaseError as error:
            db.close()
            raise FormatError(f"not a readable quatmotion index ({error})", path) from None
        if meta.get("format") != FORMAT_NAME:
            db.close()
            raise FormatError(f"not a quatmotion index (format {meta.get('format')!r})", path)
        try:
            version = int(meta.get("version", ""))
        except ValueError:
            version = -1
        if version != FORMAT_VERSION:
            db.close()
            newer = version > FORMAT_VERSION
            raise FormatError(
                f"index format version {meta.get('version')!r} "
                + ("is newer than this quatmotion reads" if newer else "is not supported")
                + f" (reads version {FORMAT_VERSION})",
                path,
            )
        if json.loads(meta.get("features", "{}")) != FEATURE_PARAMETERS:
            db.close()
            raise FormatError(
                "index built with other feature parameters; rebuild it (quatmotion index build)",
                path,
            )
        if write:
            db.execute("PRAGMA foreign_keys = ON")
        return cls(db, path)

    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> ClipIndex:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- reading -------------------------------------------------------------------------
    def clips(self) -> list[ClipRow]:
        """Every clip, in insertion order."""
        rows = self._db.execute(
            "SELECT id, name, path, sha256, label, frames, fps, skeleton FROM clips ORDER BY id"
        ).fetchall()
        return [ClipRow(*r) for r in rows]

    def __len__(self) -> int:
        return int(self._db.execute("SELECT count(*) FROM clips").fetchone()[0])

    def contains(self, path: str | Path, sha256: str) -> bool:
        """Whether ``path`` is indexed with this content hash."""
        row = self._db.execute(
            "SELECT 1 FROM clips WHERE path = ? AND sha256 = ?", (str(path), sha256)
        ).fetchone()
        return row is not None

    def feature_keys(self) -> dict[int, set[str]]:
        """Per clip id, the feature arrays stored."""
        out: dict[int, set[str]] = {}
        for clip, key in self._db.execute("SELECT clip, key FROM features"):
            out.setdefault(int(clip), set()).add(key)
        return out

    def find(self, name: str) -> ClipRow:
        """The clip ``name`` names: its path, a unique end of it (file name, stem, trailing
        folders) or its number (:func:`quatmotion.io.names.match_clip`, every command's rule).

        Raises
        ------
        ValueError
            (:class:`~quatmotion.errors.ClipNameError`) No such clip, or several.
        """
        rows = self.clips()
        return rows[match_clip(name, [r.path for r in rows], str(self.path))]

    def load(self, keys: Iterable[str]) -> tuple[list[ClipRow], Library]:
        """The clips that have every feature array in ``keys``, and a :class:`Library` of them."""
        keys = tuple(keys)
        rows = self.clips()
        arrays: dict[int, dict[str, np.ndarray]] = {r.id: {} for r in rows}
        if keys:
            marks = ",".join("?" * len(keys))
            for clip, key, data in self._db.execute(
                f"SELECT clip, key, data FROM features WHERE key IN ({marks})", keys
            ):
                arrays[int(clip)][key] = _from_blob(data)
        rows = [r for r in rows if all(k in arrays[r.id] for k in keys)]
        library = Library([arrays[r.id] for r in rows], [r.skeleton for r in rows])
        return rows, library

    # -- writing -------------------------------------------------------------------------
    def add(self, records: Iterable[ClipRecord]) -> int:
        """Store clips in one transaction (a clip already at the same path is replaced).

        Returns
        -------
        int
            Clips written.
        """
        n = 0
        with _writing(self.path), self._db:
            for r in records:
                self._db.execute("DELETE FROM clips WHERE path = ?", (r.path,))
                cur = self._db.execute(
                    "INSERT INTO clips (name, path, sha256, label, frames, fps, skeleton) "
                    "VALUES (?, ?, ?, ?, ?, ?, ?)",
                    (r.name, r.path, r.sha256, r.label, r.frames, r.fps, r.skeleton),
                )
                self._db.executemany(
                    "INSERT INTO features (clip, key, data) VALUES (?, ?, ?)",
                    [(cur.lastrowid, k, _to_blob(a)) for k, a in r.arrays.items()],
                )
                n += 1
        return n

    def remove(self, names: Iterable[str]) -> list[str]:
        """Remove the clips named (as :meth:`find` reads a name; nothing is removed when one
        of them names no clip or several); returns the paths removed."""
        rows = [self.find(name) for name in names]
        with _writing(self.path), self._db:
            for row in rows:
                self._db.execute("DELETE FROM clips WHERE id = ?", (row.id,))
        return list(dict.fromkeys(row.path for row in rows))

    def set_labels(self, labels: dict[str, str]) -> int:
        """Set the label of clips named in ``labels`` (by name or path); returns the count."""
        n = 0
        with _writing(self.path), self._db:
            for row in self.clips():
                label = labels.get(row.path, labels.get(row.name))
                if label is not None and label != row.label:
                    self._db.execute("UPDATE clips SET label = ? WHERE id = ?", (label, row.id))
                    n += 1
        return n
