"""A user's humanoid joint map: the file ``--joint-map`` names (canonical joint -> file joint).

Conventions
-----------
* JSON: one object, ``{"LHip": "thigh_l", "LKnee": "calf_l", ...}``.
* CSV (any other suffix): two columns per line, canonical joint then file joint; a first line
  naming the columns (``canonical,joint``), blank lines and ``#`` comments are skipped.
* Canonical names are those of :data:`quatmotion.motion.humanoid.JOINTS_16` (``LeftHip`` for
  ``LHip`` too, any case); a joint may be named once. Whether the skeleton has the file joints
  is checked where a clip is read (:func:`quatmotion.motion.with_joint_map`).
* Stored in settings as ``"Canonical=joint"`` strings (:func:`joint_map_pairs`), so that an
  index or pose library says how its clips were mapped.
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Iterable, Mapping
from pathlib import Path

from quatmotion.errors import FormatError
from quatmotion.motion.humanoid import HumanoidError, check_joint_map

__all__ = ["joint_map_dict", "joint_map_pairs", "read_joint_map"]


def read_joint_map(path: str | Path) -> dict[str, str]:
    """The map in ``path`` (JSON or CSV, see the module docstring), canonical names checked.

    Raises
    ------
    FormatError
        Naming the file (and the line of a CSV) for malformed content, an unknown canonical
        joint or one named twice.
    OSError
        A file that cannot be read.
    """
    path = Path(path)
    text = path.read_text(encoding="utf-8-sig")
    pairs: list[tuple[str, str, int | None]] = []
    if path.suffix.lower() == ".json":
        try:
            document = json.loads(text)
        except json.JSONDecodeError as error:
            raise FormatError(f"not JSON: {error.msg}", path, error.lineno) from None
        if not isinstance(document, dict):
            raise FormatError("expected one JSON object, canonical joint -> file joint", path)
        pairs = [(str(k), v, None) for k, v in document.items()]
    else:
        for number, row in enumerate(csv.reader(io.StringIO(text)), start=1):
            cells = [c.strip() for c in row]
            if not any(cells) or cells[0].startswith("#"):
                continue
            if len(cells) != 2 or not all(cells):
                raise FormatError(
                    f"expected two columns (canonical joint, file joint), got {row!r}", path, number
                )
            if not pairs and cells[0].lower() in ("canonical", "joint16", "canonical joint"):
                continue  # the header
            pairs.append((cells[0], cells[1], number))
    out: dict[str, str] = {}
    for key, value, line in pairs:
        try:
            ((canonical, joint),) = check_joint_map({key: value}).items()
        except HumanoidError as error:
            raise FormatError(str(error).removeprefix("joint map: "), path, line) from None
        if canonical in out:
            raise FormatError(f"{canonical} is mapped twice", path, line)
        out[canonical] = joint
    if not out:
        raise FormatError("the joint map is empty", path)
    return out


def joint_map_pairs(joint_map: Mapping[str, str] | None) -> tuple[str, ...]:
    """A map as settings store it: ``("LHip=thigh_l", ...)``, in canonical order."""
    if not joint_map:
        return ()
    clean = check_joint_map(joint_map)
    from quatmotion.motion.humanoid import JOINTS_16

    return tuple(f"{k}={clean[k]}" for k in JOINTS_16 if k in clean)


def joint_map_dict(pairs: Iterable[str]) -> dict[str, str]:
    """The map of :func:`joint_map_pairs`' strings (:class:`ValueError` for a malformed one)."""
    out: dict[str, str] = {}
    for pair in pairs:
        canonical, sep, joint = str(pair).partition("=")
        if not sep:
            raise ValueError(f"joint map entry {pair!r} is not CANONICAL=JOINT")
        out[canonical] = joint
    return check_joint_map(out)
