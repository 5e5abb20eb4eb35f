"""Skeletons stored exactly and small: canonical text, deflated against a preset dictionary.

Conventions
-----------
* A skeleton is stored as one of three **records**, the first whose round trip gives back an
  identical :class:`~quatmotion.motion.Skeleton` (names, parents, offsets, channels, Euler
  convention, axes, end sites, name and extras, arrays compared bit for bit):

  - ``RECORD_ASF`` (1): the ASF text of :func:`quatmotion.io.asf_text`, read back with
    :func:`quatmotion.io.parse_asf`;
  - ``RECORD_BVH`` (2): a one-frame BVH text of :func:`quatmotion.io.bvh_text` (identity pose),
    read back with :func:`quatmotion.io.parse_bvh` at the stored scale (cm per file unit, f64);
  - ``RECORD_EXACT`` (3): JSON of every field (floats printed shortest-exact, arrays and tuples
    tagged), for skeletons built in code (the synthetic CMU skeleton).

  A skeleton none of them reproduces (extras that are not numbers, strings, tuples, lists,
  dicts or arrays) cannot be stored: :func:`skeleton_record` raises ``ValueError``.
* The text is deflated (zlib, raw stream, level 9) with a **preset dictionary**: the frozen
  file ``skeleton_dictionary.txt`` of this package (the synthetic CMU skeleton as BVH and ASF:
  keywords, CMU bone names, typical numbers), followed by the text of the library's first
  skeleton of the same record kind when there is one. Changing the dictionary file changes the
  format (it is pinned by the format version).
"""

from __future__ import annotations

import json
import warnings
import zlib
from dataclasses import replace
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from quatmotion import quat
from quatmotion.codec.binary import inflate
from quatmotion.errors import FormatError, FormatWarning
from quatmotion.io import asf_text, bvh_text, parse_asf, parse_bvh
from quatmotion.limits import check, load_json
from quatmotion.motion import Motion, Skeleton

__all__ = [
    "RECORD_ASF",
    "RECORD_BVH",
    "RECORD_BVH_GUESSED",
    "RECORD_EXACT",
    "deflate_text",
    "inflate_text",
    "same_skeleton",
    "skeleton_from_record",
    "skeleton_record",
]

RECORD_ASF, RECORD_BVH, RECORD_EXACT, RECORD_BVH_GUESSED = 1, 2, 3, 4
# A BVH read without a given unit says so (``bvh_unit_guessed``); the record keeps that apart,
# since parsing the text at the stored scale would say the unit was given.
_DICTIONARY = resources.files("quatmotion.codec").joinpath("skeleton_dictionary.txt").read_bytes()


def _equal(a: Any, b: Any) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (
            isinstance(a, np.ndarray)
            and isinstance(b, np.ndarray)
            and a.dtype == b.dtype
            and np.array_equal(a, b)
        )
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_equal(a[k], b[k]) for k in a)
    if isinstance(a, tuple | list) and isinstance(b, tuple | list):
        return type(a) is type(b) and len(a) == len(b) and all(map(_equal, a, b))
    return type(a) is type(b) and a == b


def same_skeleton(a: Skeleton, b: Skeleton) -> bool:
    """Whether two skeletons are identical, arrays bit for bit, extras included."""
    fields = (
        "joint_names", "parents", "offsets", "channels", "euler", "axes", "site_names",
        "site_parents", "site_offsets", "name",
    )  # fmt: skip
    return all(_equal(getattr(a, f), getattr(b, f)) for f in fields) and _equal(
        dict(a.extras), dict(b.extras)
    )


def _to_json(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return {"__array__": _to_json(value.tolist()), "dtype": value.dtype.str}
    if isinstance(value, tuple):
        return {"__tuple__": [_to_json(v) for v in value]}
    if isinstance(value, list):
        return [_to_json(v) for v in value]
    if isinstance(value, dict):
        if not all(isinstance(k, str) for k in value):
            raise TypeError("dictionary keys must be strings")
        return {"__dict__": {k: _to_json(v) for k, v in value.items()}}
    if isinstance(value, bool | int | float | str) or value is None:
        return value
    raise TypeError(f"cannot store a {type(value).__name__}")


def _from_json(value: Any) -> Any:
    if isinstance(value, dict):
        if "__array__" in value:
            dtype = np.dtype(value["dtype"])
            if dtype.kind not in "biuf":  # numbers only: never objects from a file
                raise ValueError(f"an array of {dtype} in a skeleton")
            return np.asarray(_from_json(value["__array__"]), dtype=dtype)
        if "__tuple__" in value:
            return tuple(_from_json(v) for v in value["__tuple__"])
        return {k: _from_json(v) for k, v in value["__dict__"].items()}
    if isinstance(value, list):
        return [_from_json(v) for v in value]
    return value


def _exact_text(skeleton: Skeleton) -> str:
    fields = {
        "joint_names": skeleton.joint_names,
        "parents": skeleton.parents,
        "offsets": skeleton.offsets,
        "channels": skeleton.channels,
        "euler": skeleton.euler,
        "axes": skeleton.axes,
        "site_names": skeleton.site_names,
        "site_parents": skeleton.site_parents,
        "site_offsets": skeleton.site_offsets,
        "name": skeleton.name,
        "extras": dict(skeleton.extras),
    }
    return json.dumps(_to_json(fields), separators=(",", ":"), allow_nan=False)


def _bvh_text(skeleton: Skeleton) -> str:
    rest = Motion(skeleton, 30.0, skeleton.offsets[None, 0], quat.identity((1, skeleton.n_joints)))
    return bvh_text(rest)


def skeleton_from_record(
    kind: int, text: str, scale: float, source: str | Path | None = None
) -> Skeleton:
    """The skeleton of a record (see the module docstring)."""
    try:
        if kind == RECORD_ASF:
            return parse_asf(text, "record.asf")
        if kind in (RECORD_BVH, RECORD_BVH_GUESSED):
            with warnings.catch_warnings():  # what the clip's reading said was said then
                warnings.simplefilter("ignore", FormatWarning)
                skeleton = parse_bvh(text, "record.bvh", scale=scale).skeleton
            if kind == RECORD_BVH_GUESSED:
                extras = {**skeleton.extras, "bvh_unit_guessed": True}
                skeleton = replace(skeleton, extras=extras)
            return skeleton
        if kind == RECORD_EXACT:
            raw = load_json(text, source, "stored skeleton")
            # counted before a value is converted: 200,000 joints took seconds to convert
            names = raw["__dict__"]["joint_names"]
            names = names["__tuple__"] if isinstance(names, dict) else names
            check("joints", len(names), source, "stored skeleton: joints")
            return Skeleton(**_from_json(raw))
    except FormatError as error:
        raise FormatError(f"stored skeleton does not parse: {error.reason}", source) from None
    except (ValueError, TypeError, KeyError) as error:
        raise FormatError(f"stored skeleton is invalid: {error}", source) from None
    raise FormatError(f"unknown skeleton record kind {kind}", source)


def _with_name(skeleton: Skeleton, name: str) -> Skeleton:
    if skeleton.name == name:
        return skeleton
    return replace(skeleton, name=name)


def skeleton_record(skeleton: Skeleton) -> tuple[int, str, float]:
    """``(kind, text, scale)`` of the smallest record that reproduces ``skeleton`` exactly.

    Raises
    ------
    ValueError
        If no record reproduces it (the message names the skeleton).
    """
    candidates = []
    fmt = skeleton.extras.get("format")
    if fmt == "asf":
        candidates.append((RECORD_ASF, lambda: asf_text(skeleton), 0.0))
    if fmt == "bvh":
        scale = float(skeleton.extras.get("bvh_scale", 1.0))
        kind = RECORD_BVH_GUESSED if skeleton.extras.get("bvh_unit_guessed") else RECORD_BVH
        candidates.append((kind, lambda: _bvh_text(skeleton), scale))
    candidates.append((RECORD_EXACT, lambda: _exact_text(skeleton), 0.0))
    for kind, make, scale in candidates:
        try:
            text = make()
            back = _with_name(skeleton_from_record(kind, text, scale), skeleton.name)
        except (ValueError, TypeError, KeyError):
            continue
        if same_skeleton(skeleton, back):
            return kind, text, scale
    raise ValueError(
        f"skeleton {skeleton.name!r} cannot be stored exactly (its extras hold values other "
        "than numbers, strings, tuples, lists, dicts and arrays)"
    )


def deflate_text(text: str, extra_dictionary: str = "") -> bytes:
    """Raw deflate of ``text`` against the preset dictionary (plus ``extra_dictionary``)."""
    zdict = _DICTIONARY + extra_dictionary.encode("utf-8")
    compressor = zlib.compressobj(9, zlib.DEFLATED, -15, 9, zlib.Z_DEFAULT_STRATEGY, zdict[-32768:])
    return compressor.compress(text.encode("utf-8")) + compressor.flush()


def inflate_text(data: bytes, extra_dictionary: str = "", source: str | Path | None = None) -> str:
    """Inverse of :func:`deflate_text`."""
    zdict = _DICTIONARY + extra_dictionary.encode("utf-8")
    raw = inflate(data, "stored skeleton text", source, zdict=zdict[-32768:])
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as error:
        raise FormatError(f"stored skeleton text is corrupt ({error})", source) from None
