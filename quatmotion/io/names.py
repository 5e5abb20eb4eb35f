"""Clip names: the one rule every collection (a ``.qmz``, a clip index, a pose library) uses to
find the clip a user names.

A collection names its clips by file stem (``walk``: a ``.qmz``), by path (``clips/walk.bvh``:
a pose library) or both (a clip index keeps the path). A user types any of those: the name, the
file name, the stem, trailing folders, or a clip's number. :func:`match_clip` decides which clip
that is, the same way everywhere, and says so when the answer is none or several.

A name also becomes a file when clips are written out (``decompress``): :func:`relative_path`
is the one rule for that, and a name read from a file is never trusted to stay in its folder.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Sequence
from pathlib import PurePosixPath

from quatmotion._names import bare_parts, rule_matches
from quatmotion.errors import ClipNameError

__all__ = ["match_clip", "relative_path"]

_NOT_IN_FILE_NAMES = re.compile(r"[\x00-\x1f\x7f-\x9f\\:*?\"<>|]")
"""Replaced by ``_`` in a file name made from a clip name: control characters, and what
Windows refuses (a backslash, a drive's colon, wildcards)."""


def relative_path(name: str, suffix: str = "") -> PurePosixPath:
    """The path, relative to an output folder, that the clip ``name`` is written to.

    A clip's name is its file stem or, where stems collide, ``/``-separated trailing folders
    (:func:`quatmotion.collection.unique_names`): those become sub-folders. Characters no file
    name should hold are replaced by ``_``; what no replacement makes safe is refused.

    Raises
    ------
    ValueError
        An empty name, an absolute path, or a component that is empty, ``.`` or ``..`` (a name
        that would leave the folder: never one quatmotion writes).
    """
    parts = name.split("/")
    if not name or not all(parts) or any(p in (".", "..") for p in parts):
        why = "is absolute" if name.startswith("/") else "has an empty, '.' or '..' part"
        if not name:
            why = "is empty"
        raise ValueError(f"clip name {name!r} {why}: it cannot name a file")
    parts = [_NOT_IN_FILE_NAMES.sub("_", p) for p in parts]
    return PurePosixPath(*parts[:-1], parts[-1] + suffix)


def match_clip(query: str | int, names: Sequence[str], where: str = "the collection") -> int:
    """The position in ``names`` of the clip ``query`` names.

    The first rule some name meets decides; two names meeting it is an error (never a silent
    choice):

    1. ``query`` is a name (``clips/walk.bvh``, or ``walk`` in a ``.qmz``);
    2. it is the end of a name's path, whole components (``walk.bvh``, ``clips/walk.bvh``);
    3. without a motion-file suffix, it is the end of a name's path without one (``walk`` for
       ``clips/walk.bvh``, ``walk.bvh`` for a clip named ``walk``);
    4. digits (or an int) are a position from 0, when no clip is named so.

    Parameters
    ----------
    query : str or int
    names : sequence of str
        Every clip's name, in the collection's order.
    where : str
        The collection, for messages (a file name).

    Returns
    -------
    int

    Raises
    ------
    ClipNameError
        No clip matches (naming up to five close names), several match (listing them), or a
        position is out of range.
    """
    n = len(names)
    if not isinstance(query, str):
        if not 0 <= int(query) < n:
            raise ClipNameError(f"clip number {query} is out of range: {where} has 0 to {n - 1}")
        return int(query)
    matches = rule_matches(query, names)
    if len(matches) == 1:
        return matches[0]
    if matches:
        listed = ", ".join(names[i] for i in matches[:5])
        more = f" and {len(matches) - 5} more" if len(matches) > 5 else ""
        raise ClipNameError(
            f"clip {query!r} is ambiguous in {where}: it matches {len(matches)} clips "
            f"({listed}{more}); give more of the path"
        )
    if query.isdigit():
        return match_clip(int(query), names, where)
    stems = [parts[-1] if parts else "" for parts in map(bare_parts, names)]
    key = bare_parts(query)[-1].lower() if bare_parts(query) else query.lower()
    unique = list(dict.fromkeys(stems))
    close = [s for s in unique if key and key in s.lower()][:5]
    close = close or difflib.get_close_matches(key, unique, n=5, cutoff=0.5)
    hint = f"; close names: {', '.join(close)}" if close else ""
    numbered = f", numbered 0 to {n - 1}" if n else ""
    raise ClipNameError(f"no clip named {query!r} in {where} ({n} clips{numbered}){hint}")
