"""What a clip index file must hold, checked once for every reader of it.

:class:`~quatmotion.retrieval.index.ClipIndex` opens an index through :func:`check_index`, and
so does the single query without Numba (:mod:`quatmotion.retrieval.quick`): a file one of them
refuses, the other refuses too. This module imports SQLite, NumPy and the limits only (the
quick path's budget).

A feature array is ``.npy`` bytes; :func:`read_array` reads one, its header's shape checked
against the bytes before anything is allocated, numbers only.
"""

from __future__ import annotations

import io
import sqlite3
from pathlib import Path
from typing import Any

import numpy as np

from quatmotion._format import FileFormat, npy_header
from quatmotion.errors import FormatError
from quatmotion.limits import current, load_json
from quatmotion.retrieval import features as feat

__all__ = ["FEATURE_PARAMETERS", "FORMAT", "check_index", "read_array"]

FORMAT = FileFormat("quatmotion-retrieval-index", 3, 1, "a quatmotion clip index")

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

_TABLES = {
    1: ("meta", "clips", "features"),
    2: ("meta", "clips", "features", "blobs"),
    3: ("meta", "clips", "features", "blobs"),
}


def check_index(db: sqlite3.Connection, path: Path) -> tuple[int, dict[str, str]]:
    """The index's format version and meta table, once everything a reader trusts is checked:
    its tables, SQLite's own check, the format and version, the feature parameters, the
    settings' JSON (depth first), every clip's frames and frame rate, every feature row's clip.

    Raises
    ------
    FormatError
        Naming ``path`` and what is wrong (a half-made index says so: delete and rebuild).
    """
    try:
        tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        missing = [t for t in _TABLES[1] if t not in tables]
        if missing:
            raise FormatError(
                f"not a whole quatmotion index (no {', '.join(missing)} table: a build that "
                "never finished?); delete it and build it again",
                path,
            )
        meta = {str(k): str(v) for k, v in db.execute("SELECT key, value FROM meta")}
        if db.execute("PRAGMA quick_check").fetchone()[0] != "ok":
            raise FormatError("the index's database is damaged (SQLite's quick_check)", path)
        version = FORMAT.check(meta.get("format"), meta.get("version"), path)
        missing = [t for t in _TABLES[version] if t not in tables]
        if missing:
            raise FormatError(f"not a whole quatmotion index (no {missing[0]} table)", path)
        if load_json(meta.get("features", "{}"), path, "meta: features") != FEATURE_PARAMETERS:
            raise FormatError(
                "index built with other feature parameters; rebuild it (quatmotion index build)",
                path,
            )
        if "settings" in meta and not isinstance(
            load_json(meta["settings"], path, "meta: settings"), dict
        ):
            raise FormatError("meta: settings are not a JSON object", path)
        _check_clips(db, path)
    except sqlite3.DatabaseError as error:
        raise FormatError(f"not a readable quatmotion index ({error})", path) from None
    return version, meta


def _check_clips(db: sqlite3.Connection, path: Path) -> None:
    limits = current()
    bad = db.execute(
        "SELECT name, frames, fps FROM clips WHERE typeof(frames) != 'integer' OR frames < 1 "
        "OR frames > ? OR typeof(fps) NOT IN ('real', 'integer') OR NOT fps > 0 OR fps > ? "
        "OR typeof(name) != 'text' OR typeof(label) != 'text' LIMIT 1",
        (limits.frames, limits.fps),
    ).fetchone()
    if bad is not None:
        name, frames, fps = bad
        raise FormatError(
            f"clip {name!r}: {frames!r} frames at {fps!r} frames/s (frames must be from 1 to "
            f"{limits.frames:,}, the rate positive up to {limits.fps:g})",
            path,
        )
    orphan = db.execute(
        "SELECT clip FROM features WHERE clip NOT IN (SELECT id FROM clips) LIMIT 1"
    ).fetchone()
    if orphan is not None:
        raise FormatError(f"a feature row names clip {orphan[0]!r}, which is not there", path)


def read_array(data: Any, path: Path | None = None, what: str = "a feature array") -> np.ndarray:
    """A stored ``.npy`` array (numbers only), its declared size checked against its bytes.

    Raises
    ------
    FormatError
        Naming ``path`` and ``what``: no bytes, no array of numbers, a size its bytes do not
        hold, values that are not finite.
    """
    if not isinstance(data, bytes | bytearray | memoryview):  # bytes(10**9) makes a gigabyte
        raise FormatError(f"{what} is a {type(data).__name__}, not a stored array", path)
    data = bytes(data)
    fh = io.BytesIO(data)
    try:
        shape, dtype = npy_header(fh)
        if dtype.hasobject or dtype.kind not in "biufc":
            raise ValueError(f"an array of {dtype}")
        if int(np.prod(shape, dtype=object)) * dtype.itemsize != len(data) - fh.tell():
            raise ValueError(f"shape {shape} does not match its {len(data)} bytes")
        fh.seek(0)
        array = np.load(fh, allow_pickle=False)
        if dtype.kind in "fc" and not np.all(np.isfinite(array)):
            raise ValueError("values that are not finite")  # no feature has them
        return array
    except (ValueError, OSError, EOFError) as error:
        raise FormatError(f"{what} is not a stored array ({error})", path) from None
