"""The pose library's file: one ``.npz`` holding the serialised HNSW graph, the projection model
and the pose catalogue (clip names, frame numbers, fps), with a ``meta`` record naming the
format (:data:`FORMAT`) and its version; written to a temporary file and then renamed, so a
reader never sees half a library. Reading (:func:`read_library`) checks every member's declared
size before NumPy allocates it and every stored count and shape against the others before
anything is searched, raising :class:`~quatmotion.FormatError`.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import pathlib
import zipfile
from collections.abc import Iterator
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quatmotion._atomic import atomic_output
from quatmotion._format import FileFormat, npy_header
from quatmotion.collection import ClipRef, content_hash, find_skeleton, unique_names
from quatmotion.errors import FormatError
from quatmotion.limits import check, load_json
from quatmotion.pose.index import HNSWIndex
from quatmotion.pose.library.settings import PoseSettings
from quatmotion.pose.library.transitions import TRANSITION_PREFIX
from quatmotion.pose.transition import TransitionClassifier

__all__ = ["FORMAT", "derived_refs", "read_library", "read_settings", "write_library"]

FORMAT = FileFormat("quatmotion-pose-library", 4, 2, "a quatmotion pose library")
"""4: a clip's reference carries its take (``take``: one take of a file of several); 3 (0.4.0,
still read, every clip a whole file): the clips' references and the settings in ``meta``; 2
(0.3.0, still read): poses on the canonical body, features clipped to the library's range."""
_FORMAT = FORMAT.name
_VERSION = FORMAT.version
_NOT_A_LIBRARY = (
    f"not a quatmotion pose library (expected a file written by 'quatmotion pose index': "
    f"format {_FORMAT}, {FORMAT.versions_text()})"
)


def read_library(path: str | os.PathLike[str], ef_search: int = 64) -> dict[str, Any]:
    """The fields of the :class:`~quatmotion.pose.library.PoseLibrary` stored at ``path`` (any
    version from :data:`FORMAT`'s ``oldest_readable``).

    Raises
    ------
    FormatError
        Not a quatmotion pose library, or a version this code does not read.
    """
    with _reading(path):
        arrays = _load_arrays(path)
        meta = _meta(arrays, path)
        version = FORMAT.check(meta.get("format"), meta.get("version"), path)
        refs = [ClipRef.from_dict(r, path) for r in meta.pop("clips", [])]
        stored = meta.pop("settings", None)
        settings = None if stored is None else PoseSettings.from_dict(stored, path)
        model = {k[6:]: arrays[k] for k in arrays if k.startswith("model_")}
        n_items, dim = _check_catalogue(arrays, meta, model, refs)
        index = HNSWIndex.from_bytes(
            arrays["index"].tobytes(), dim=dim, ef_search=ef_search, n_items=n_items
        )
        return dict(
            pose_rows=arrays.get("pose_rows"),
            index=index,
            clip_names=[str(n) for n in arrays["clip_names"]],
            clip_of=arrays["clip_of"].astype(np.int64),
            frame_of=arrays["frame_of"].astype(np.int64),
            model=model,
            meta=meta,
            refs=refs,
            settings=settings,
            version=version,
            path=pathlib.Path(path),
        )


def read_settings(path: str | os.PathLike[str]) -> PoseSettings | None:
    """The settings stored in the library at ``path`` (None for a version-2 library), its
    ``meta`` alone read and checked.

    Raises
    ------
    FormatError
        Not a quatmotion pose library, or a version this code does not read.
    """
    with _reading(path):
        meta = _meta(_load_arrays(path, only="meta"), path)
        stored = meta.get("settings")
        return None if stored is None else PoseSettings.from_dict(stored, path)


@contextlib.contextmanager
def _reading(path: str | os.PathLike[str]) -> Iterator[None]:
    """Reading the library at ``path``: what goes wrong is a :class:`FormatError` saying what
    the file should have been (a missing or unreadable file stays an ``OSError``)."""
    try:
        yield
    except FormatError:
        raise
    except (IsADirectoryError, FileNotFoundError, PermissionError):
        raise
    except _MalformedError as exc:
        raise FormatError(f"malformed pose library: {exc}", path) from None
    except (KeyError, ValueError, TypeError, OSError, EOFError, zipfile.BadZipFile) as exc:
        # np.load's own message (pickled data, a bad zip...) says nothing about what the
        # file should have been.
        raise FormatError(_NOT_A_LIBRARY, path) from exc


def _meta(arrays: dict[str, np.ndarray], path: str | os.PathLike[str]) -> dict[str, Any]:
    """A library's ``meta`` record, its format and version checked."""
    meta = load_json(str(arrays.get("meta", "null")), path, "meta")
    if not isinstance(meta, dict) or meta.get("format") != _FORMAT:
        raise FormatError(_NOT_A_LIBRARY, path)
    FORMAT.check(meta.get("format"), meta.get("version"), path)
    return meta


def write_library(
    path: str | os.PathLike[str],
    *,
    index: HNSWIndex,
    clip_names: list[str],
    clip_of: NDArray[np.int64],
    frame_of: NDArray[np.int64],
    model: dict[str, Any],
    meta: dict[str, Any],
    refs: list[ClipRef],
    settings: PoseSettings | None,
    pose_rows: NDArray[np.float32] | None,
) -> None:
    """Write a library's fields to ``path`` (one ``.npz``; temporary file, then rename)."""
    path = pathlib.Path(path)
    meta = dict(meta)
    meta.update(format=_FORMAT, version=_VERSION, dim=index.dim_)
    if refs:  # a library built from files (a version-2 one's are derived on reading)
        meta["clips"] = [r.to_dict() for r in refs]
    if settings is not None:
        meta["settings"] = settings.to_dict()
    payload = {
        "index": np.frombuffer(index.to_bytes(), dtype=np.uint8),
        "clip_names": np.asarray(clip_names, dtype=str),
        "clip_of": clip_of,
        "frame_of": frame_of,
        "meta": np.asarray(json.dumps(meta)),
    }
    payload.update({f"model_{k}": v for k, v in model.items()})
    if pose_rows is not None:
        payload["pose_rows"] = pose_rows
    with atomic_output(path) as temp, temp.open("wb") as fh:
        np.savez(fh, **payload)


def derived_refs(clip_names: list[str], path: pathlib.Path | None) -> tuple[ClipRef, ...]:
    """The clips' references of a version-2 library, which stored none: its clips' paths
    (resolved against the library's folder, ``path``'s) give them, the content hash of the file
    found (of the name, where the file is gone: matching no other clip)."""
    base = None if path is None else path.resolve().parent
    paths = []
    for name in clip_names:
        p = pathlib.Path(name)
        if not p.is_absolute() and base is not None and (base / p).is_file():
            p = base / p
        paths.append(pathlib.Path(os.path.abspath(p)))
    out = []
    for p, name in zip(paths, unique_names(paths), strict=True):
        asf = None
        try:
            if p.suffix.lower() == ".amc":
                asf = find_skeleton(p)
            sha = content_hash(p, asf)
        except (OSError, FormatError):
            sha = hashlib.sha256(f"missing clip {p}".encode()).hexdigest()
        out.append(ClipRef(name, sha, str(p), None if asf is None else str(asf)))
    return tuple(out)


class _MalformedError(ValueError):
    """A pose library whose arrays disagree (the message says which)."""


def _load_arrays(path: str | os.PathLike[str], only: str | None = None) -> dict[str, np.ndarray]:
    """A library's arrays (``only``: that one), each member's declared size checked (against
    the limits and its header's shape) before NumPy allocates it; no objects."""
    with zipfile.ZipFile(path) as archive:
        for info in archive.infolist():
            check("file_bytes", info.file_size, path, f"member {info.filename}")
            with archive.open(info) as fh:
                shape, dtype = npy_header(fh)
            if (
                dtype.hasobject
                or int(np.prod(shape, dtype=object)) * dtype.itemsize > info.file_size
            ):
                raise _MalformedError(f"member {info.filename} declares more data than it holds")
    with np.load(path, allow_pickle=False) as data:
        return {k: data[k] for k in data.files if only is None or k == only}


def _check_catalogue(
    arrays: dict[str, np.ndarray], meta: dict[str, Any], model: dict[str, Any], refs: list
) -> tuple[int, int]:
    """Every stored count and shape against the others (what indexes what), before anything
    is searched; returns the poses and the index's dimension.

    Raises
    ------
    _MalformedError
        Naming the first that disagrees.
    """
    names, clip_of, frame_of = arrays["clip_names"], arrays["clip_of"], arrays["frame_of"]
    n_clips = len(names) if names.ndim == 1 else -1
    if n_clips < 1 or names.dtype.kind != "U":
        raise _MalformedError("it names no clips")
    for key, a in (("clip_of", clip_of), ("frame_of", frame_of)):
        if a.ndim != 1 or a.dtype.kind not in "iu" or len(a) != len(clip_of) or not len(a):
            raise _MalformedError(f"{key} is not one whole number per pose")
    if clip_of.min() < 0 or clip_of.max() >= n_clips:
        raise _MalformedError(f"clip_of names clips outside 0 to {n_clips - 1}")
    if frame_of.min() < 0:
        raise _MalformedError("frame_of holds negative frames")
    dim = meta.get("dim")
    if isinstance(dim, bool) or not isinstance(dim, int) or not 1 <= dim <= 1 << 16:
        raise _MalformedError(f"meta.dim is {dim!r}")
    W, scale, offset = model.get("W"), model.get("scale"), model.get("offset")
    if W is None or scale is None or offset is None:
        raise _MalformedError("the projection model is missing")
    if W.ndim != 2 or W.shape[1] != dim or scale.shape != (W.shape[0],) != offset.shape:
        raise _MalformedError(f"the projection model's shapes disagree with meta.dim {dim}")
    if not all(np.all(np.isfinite(a)) for a in (W, scale, offset)):
        raise _MalformedError("the projection model holds values that are not finite")
    rows = arrays.get("pose_rows")
    if rows is not None and (rows.ndim != 2 or len(rows) != len(clip_of)):
        raise _MalformedError("pose_rows is not one row per pose")
    check("fps", _number(meta.get("fps"), "fps"), None, "meta.fps")
    height = meta.get("height_cm")
    if height is not None and not (math.isfinite(_number(height, "height_cm")) and height > 0):
        raise _MalformedError(f"meta.height_cm is {height!r}")
    for key, least in (("file_frames", 1), ("file_fps", 0)):
        values = meta.get(key)
        if values is None:
            continue
        if not isinstance(values, list) or len(values) != n_clips:
            raise _MalformedError(f"meta.{key} is not one value per clip")
        for v in values:
            if v is not None and not (_number(v, key) > least and math.isfinite(v)):
                raise _MalformedError(f"meta.{key} holds {v!r}")
    if refs and len(refs) != n_clips:
        raise _MalformedError(f"{len(refs)} clip references for {n_clips} clips")
    judge = {k: v for k, v in model.items() if k.startswith(TRANSITION_PREFIX)}
    if judge:
        TransitionClassifier.from_arrays(
            {k[len(TRANSITION_PREFIX) :]: v for k, v in judge.items()},
            n_features=None if rows is None else 2 * rows.shape[1],
        )
    return len(clip_of), dim


def _number(value: object, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _MalformedError(f"meta.{key} is {value!r}, not a number")
    return float(value)
