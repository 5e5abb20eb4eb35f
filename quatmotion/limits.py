"""The limits every reader enforces before it allocates: one place, documented defaults, a way
to raise them.

A file (or an upload) says how much it holds: a frame count, a joint count, a frame rate, a
buffer's length, a compressed chunk's size. A reader trusts none of it: it checks each number
against :func:`current` limits *before* it allocates or loops on it, and a number over a limit
is a :class:`~quatmotion.errors.FormatError` naming the file and the field, never a
``MemoryError``, a ``RecursionError`` or minutes of CPU.

Conventions
-----------
* The defaults are far beyond any real library (CMU's longest clip has some 20,000 frames and
  31 joints; a game rig with fingers and a face some hundreds of joints) and far below what
  exhausts a machine: a clip over them is a hostile or broken file, or an unusual library
  that raises them on purpose.
* Raise them for a block with :func:`raised` (this thread and what it starts with the context
  copied, such as ``asyncio``/``anyio`` tasks), or for every process of a run with the
  environment variable ``QUATMOTION_LIMITS``, comma-separated ``field=value`` pairs
  (``QUATMOTION_LIMITS="frames=5e6,joints=20000"``), read when first needed and inherited by
  worker processes.
* Validity is no limit: a negative count, a frame rate that is zero, negative or not finite is
  refused by :func:`check` whatever the limits.
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import json
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from quatmotion.errors import FormatError

__all__ = ["ENV_VAR", "Limits", "check", "current", "json_depth", "load_json", "raised"]

ENV_VAR = "QUATMOTION_LIMITS"

_GIB = 1 << 30


@dataclass(frozen=True)
class Limits:
    """The largest value of each quantity a file may declare or hold.

    Attributes
    ----------
    frames : int
        Frames of one clip (1,000,000: 2.3 hours at 120 frames/s).
    joints : int
        Joints (bones, skin joints, hierarchy nodes read as joints) of one skeleton (10,000).
    joint_frames : int
        Frames times joints of one clip, the size of its arrays (8,000,000: 36 minutes at 120
        frames/s of CMU's 31 joints; some 450 MB of rotations and translations in float64),
        and keyframes of all a clip's channels together.
    fps : float
        Frame rate in frames per second (10,000; high-speed capture runs at some thousands).
    duration : float
        Seconds from a clip's first frame to its last (86,400: a day).
    decompressed_bytes : int
        Bytes one compressed chunk or stream may expand to (1 GiB).
    file_bytes : int
        Bytes of one file a reader loads whole, or one buffer a file declares (1 GiB).
    depth : int
        Nesting depth of a hierarchy, a JSON document or a settings record (200; a human
        skeleton is some 10 deep, a glTF document 8).
    """

    frames: int = 1_000_000
    joints: int = 10_000
    joint_frames: int = 8_000_000
    fps: float = 10_000.0
    duration: float = 86_400.0
    decompressed_bytes: int = _GIB
    file_bytes: int = _GIB
    depth: int = 200

    def __post_init__(self) -> None:
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise TypeError(f"Limits.{field.name} must be a number, got {value!r}")
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"Limits.{field.name} must be positive and finite, got {value}")
            if field.type == "int" and value != int(value):
                raise ValueError(f"Limits.{field.name} must be a whole number, got {value}")
            object.__setattr__(self, field.name, int(value) if field.type == "int" else value)

    @classmethod
    def from_text(cls, text: str, base: Limits | None = None) -> Limits:
        """Limits from ``field=value`` pairs separated by commas (the environment variable's
        form), the others from ``base`` (the defaults). ``ValueError`` naming a bad pair."""
        names = {f.name for f in dataclasses.fields(cls)}
        changes: dict[str, float] = {}
        for pair in filter(None, (p.strip() for p in text.split(","))):
            name, _, value = pair.partition("=")
            name = name.strip()
            if name not in names:
                raise ValueError(f"{ENV_VAR}: no limit {name!r}; the limits: {', '.join(names)}")
            try:
                changes[name] = float(value.replace("_", ""))
            except ValueError:
                raise ValueError(f"{ENV_VAR}: {pair!r} is no number") from None
        return dataclasses.replace(base or cls(), **changes)


_current: contextvars.ContextVar[Limits | None] = contextvars.ContextVar(
    "quatmotion_limits", default=None
)
_from_env: dict[str, Limits] = {}


def current() -> Limits:
    """The limits in force: those of the innermost :func:`raised` block, else the defaults
    changed by ``QUATMOTION_LIMITS``."""
    limits = _current.get()
    if limits is not None:
        return limits
    text = os.environ.get(ENV_VAR, "")
    if text not in _from_env:
        _from_env[text] = Limits.from_text(text)
    return _from_env[text]


@contextlib.contextmanager
def raised(limits: Limits | None = None, /, **changes: float) -> Iterator[Limits]:
    """Use other limits inside the block: ``with raised(frames=5_000_000): ...``, or a whole
    :class:`Limits`. Changes apply to the limits in force (nested blocks compose)."""
    new = dataclasses.replace(limits or current(), **changes)
    token = _current.set(new)
    try:
        yield new
    finally:
        _current.reset(token)


_UNITS = {
    "frames": "frames",
    "joints": "joints",
    "joint_frames": "joint-frames",
    "fps": "frames/s",
    "duration": "s",
    "decompressed_bytes": "bytes",
    "file_bytes": "bytes",
    "depth": "levels",
}


def check(
    limit: str,
    value: float,
    source: str | Path | None,
    field: str,
    line: int | None = None,
) -> None:
    """Refuse ``value`` of ``field`` when it is over the ``limit`` in force or not valid.

    Parameters
    ----------
    limit : str
        A field of :class:`Limits` (``"frames"``, ``"fps"``...).
    value : float
        The number the file declares or implies.
    source : str, Path or None
        The file, for the message (``FormatError.path``).
    field : str
        What the number is in the file (``"Frames:"``, ``"accessors[3].count"``).
    line : int, optional
        Where, when the format has lines.

    Raises
    ------
    FormatError
        ``value`` is not a number, not finite, negative (zero or negative for ``fps``), or over
        the limit; the message names the field and how to raise the limit.
    """
    limits = current()
    ceiling = getattr(limits, limit)  # AttributeError: a limit that does not exist is a bug
    unit = _UNITS[limit]
    try:
        if isinstance(value, bool | str | bytes):
            raise TypeError("a truth value or a text is no number")
        number = float(value)
    except (TypeError, ValueError, OverflowError):
        raise FormatError(f"{field} is {value!r}, not a number", source, line) from None
    if not math.isfinite(number) or number < 0 or (limit == "fps" and number == 0):
        least = "positive" if limit == "fps" else "0 or more"
        raise FormatError(f"{field} is {_show(number)}: must be {least} and finite", source, line)
    if number > ceiling:
        raise FormatError(
            f"{field} is {_show(value)} {unit}, over the limit of {_show(ceiling)} "
            f"(raise it with {ENV_VAR}={limit}=N or quatmotion.limits.raised({limit}=N))",
            source,
            line,
        )


def _show(value: float) -> str:
    number = float(value)
    whole = math.isfinite(number) and number.is_integer() and abs(number) < 1e18
    return f"{int(number):,}" if whole else f"{number:g}"


def json_depth(data: bytes | str) -> int:
    """How deep arrays and objects nest in a JSON text (0 for a scalar), in linear time and
    without recursion; brackets inside strings do not count."""
    raw = data.encode("utf-8", "surrogatepass") if isinstance(data, str) else data
    codes = np.frombuffer(raw, dtype=np.uint8)
    # A quote is escaped when an odd run of backslashes ends just before it; a bracket after an
    # odd count of unescaped quotes is text. Vectorised over those bytes only (a regular
    # expression removing the strings took 2 s over the 12 MB of a stored skeleton of 200,000
    # joints, this 0.4 s; a 40 MB data URI 1.2 s, this 0.4 s).
    quotes = np.flatnonzero(codes == ord('"'))
    slashes = np.flatnonzero(codes == ord("\\"))
    if len(slashes) and len(quotes):
        starts = np.ones(len(slashes), dtype=bool)
        starts[1:] = np.diff(slashes) != 1
        first = np.maximum.accumulate(np.where(starts, slashes, 0))  # where each run began
        odd = (slashes - first) % 2 == 0  # an odd count of backslashes up to this one
        before = np.searchsorted(slashes, quotes - 1)
        found = before < len(slashes)
        escaped = np.zeros(len(quotes), dtype=bool)
        escaped[found] = (slashes[before[found]] == quotes[found] - 1) & odd[before[found]]
        quotes = quotes[~escaped]
    brackets = np.flatnonzero((codes == ord("[")) | (codes == ord("{")))
    closing = np.flatnonzero((codes == ord("]")) | (codes == ord("}")))
    at = np.concatenate((brackets, closing))
    steps = np.concatenate((np.ones(len(brackets), np.int64), -np.ones(len(closing), np.int64)))
    steps = steps[np.argsort(at, kind="stable")]
    at = np.sort(at)
    steps[np.searchsorted(quotes, at) % 2 == 1] = 0  # an odd count of quotes before: text
    return int(np.cumsum(steps).max(initial=0))


def load_json(data: bytes | str, source: str | Path | None, field: str = "document") -> Any:
    """``json.loads`` of a file's text, its nesting depth checked first (no ``RecursionError``):
    a :class:`~quatmotion.errors.FormatError` naming ``source`` and ``field`` for text that is
    no JSON or nests too deep."""
    check("depth", json_depth(data), source, f"{field} nesting depth")
    try:
        return json.loads(data)
    except (ValueError, RecursionError) as error:  # UnicodeDecodeError is a ValueError
        raise FormatError(f"{field} is not valid JSON ({error})", source) from None
