"""How many uploads the web app takes at once, how much memory their parsing may use, and
the parsing itself (:func:`parse_upload`: whatever the file holds, a 4xx, never a 500).

Conventions
-----------
* An upload is a file parsed in memory (``POST /api/search/upload``). Parsing a motion file
  and searching with it costs many times its size (the text split into numbers, the arrays
  made from them, the query's features, the viewer's payload): the cost is estimated before
  parsing by :data:`PARSE_COST`, by the file's suffix: bytes per byte of the file and, for the
  text formats, bytes per value it may hold (every separator may end a number: a file of
  ``0 0 0`` costs four times more per byte than one of ``12.3456``). The factors are the peaks
  measured on large files of each kind, dense and ordinary, times about 1.5 (1.41 to 1.64:
  ``docs/performance.md``, ``tools/measure-upload-memory.py``).
* Admission, before the body is read: one upload at a time per client (its address; 429
  otherwise) and at most ``slots`` at once overall (503 otherwise), each with
  ``Retry-After``. A client sending slowly keeps its slot as long as it sends: the server
  never drops it, and the slots bound the bodies held in memory (``slots`` times the body
  limit at most).
* Parsing, after the body is read: under a memory budget. An upload whose estimated cost is
  over the whole budget is refused with 413 (with a declared ``Content-Length``, before the
  body is read); the others wait their turn until the budget has room for them, so that at any
  time the parses in flight are estimated to need no more than the budget together.
* Thread safety: every method may be called from any thread (the parses run in the server's
  thread pool; admission in its event loop).
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import PurePosixPath

from starlette.exceptions import HTTPException

from quatmotion.errors import FormatError
from quatmotion.io import parse_motion
from quatmotion.motion import Motion

__all__ = [
    "DEFAULT_UPLOAD_MEMORY",
    "DEFAULT_UPLOAD_SLOTS",
    "PARSE_COST",
    "ParseCost",
    "UploadGate",
    "parse_upload",
]

DEFAULT_UPLOAD_MEMORY = 2_000_000_000
"""Memory the parses of uploads may use together, bytes (2 GB): a 50 MB BVH fits, alone."""

DEFAULT_UPLOAD_SLOTS = 4
"""Uploads taken at once, over every client."""

_SEPARATORS = (b" ", b"\t", b"\n", b"\r", b"\x0b", b"\x0c")  # what str.split() splits on


@dataclass(frozen=True)
class ParseCost:
    """Estimated peak memory of parsing a file of one kind and searching with it:
    ``per_byte`` bytes per byte of the file, plus ``per_value`` bytes per value it may hold
    (a text format's separators, each of which may end a number)."""

    per_byte: int
    per_value: int = 0

    def of(self, data: bytes) -> int:
        """Bytes, for the file ``data``."""
        values = sum(data.count(s) for s in _SEPARATORS) + 1 if self.per_value else 0
        return self.per_byte * len(data) + self.per_value * values


_TEXT = ParseCost(per_byte=8, per_value=115)
PARSE_COST = {
    ".bvh": _TEXT,
    ".amc": _TEXT,
    ".asf": _TEXT,
    ".gltf": ParseCost(24),
    ".glb": ParseCost(27),
    ".fbx": ParseCost(47),
}
"""The estimate of each kind of file, by suffix. Measured (one upload to ``quatmotion
serve``, the server's peak RSS over its RSS before): BVH 12.3 bytes per byte for 10.6
bytes a value (ordinary), 16.2 for 7.8, 41.7 for 2.0 (``0 0 0``), that is about 5.6 bytes
per byte plus 72 per value; AMC 13.3 and 25.6, 2.8 plus 87; glTF 15.7, GLB 17.5, FBX 29.8
and 30.9 bytes per byte."""

_UNKNOWN = ParseCost(max(c.per_byte for c in PARSE_COST.values()), _TEXT.per_value)
_FRAMING = 65_536  # multipart headers, boundaries and form fields, bytes at most
_RETRY_AFTER_S = "2"
_WAIT_S = 600.0  # longest wait for the budget before 503
_log = logging.getLogger("quatmotion.server")


def _busy(status: int, message: str) -> HTTPException:
    return HTTPException(status, message, headers={"Retry-After": _RETRY_AFTER_S})


class UploadGate:
    """Admission and memory budget of uploads (module conventions).

    Parameters
    ----------
    slots : int
        Uploads taken at once over every client (at least 1).
    memory : int
        Bytes the parses in flight may use together (at least 1).
    """

    def __init__(
        self, slots: int = DEFAULT_UPLOAD_SLOTS, memory: int = DEFAULT_UPLOAD_MEMORY
    ) -> None:
        if slots < 1:
            raise ValueError(f"upload slots must be at least 1, got {slots}")
        if memory < 1:
            raise ValueError(f"the upload memory budget must be at least 1 byte, got {memory}")
        self.slots = slots
        self.memory = memory
        self._clients: dict[str, int] = {}
        self._used = 0
        self._lock = threading.Lock()
        self._room = threading.Condition(self._lock)

    @staticmethod
    def cost(name: str, data: bytes) -> int:
        """Estimated memory of parsing the file ``data`` named ``name``, bytes
        (:data:`PARSE_COST`)."""
        return PARSE_COST.get(PurePosixPath(name).suffix.lower(), _UNKNOWN).of(data)

    @staticmethod
    def least_cost(body: int) -> int:
        """The least memory parsing what a request body of ``body`` bytes holds may need
        (all of it one file of the cheapest kind holding a single value, less the multipart
        framing)."""
        return min(c.per_byte for c in PARSE_COST.values()) * max(0, body - _FRAMING)

    def check(self, cost: int, what: str = "the upload") -> None:
        """413 when ``cost`` alone is over the whole budget."""
        if cost > self.memory:
            raise HTTPException(
                413,
                f"{what} would need about {cost / 1e6:,.0f} MB to parse, over the server's "
                f"budget of {self.memory / 1e6:,.0f} MB for uploads (--upload-memory): "
                "upload a shorter clip",
            )

    @contextlib.contextmanager
    def admitted(self, client: str) -> Iterator[None]:
        """Hold a slot for ``client``'s upload: 429 when it has one already, 503 when every
        slot is held."""
        with self._lock:
            if self._clients.get(client):
                raise _busy(429, "one upload at a time per client: wait for the last one's answer")
            if sum(self._clients.values()) >= self.slots:
                raise _busy(503, f"the server is taking {self.slots} uploads already: retry")
            self._clients[client] = 1
        try:
            yield
        finally:
            with self._lock:
                self._clients.pop(client, None)

    @contextlib.contextmanager
    def parsing(self, cost: int) -> Iterator[None]:
        """Hold ``cost`` bytes of the budget while parsing, waiting until it has room
        (``cost`` is first checked against the whole budget: :meth:`check`). Blocks the
        calling thread: call it in a worker thread."""
        self.check(cost)
        with self._room:
            if not self._room.wait_for(lambda: self._used + cost <= self.memory, _WAIT_S):
                raise _busy(503, "the server is busy parsing other uploads: retry")
            self._used += cost
        try:
            yield
        finally:
            with self._room:
                self._used -= cost
                self._room.notify_all()

    @property
    def in_use(self) -> int:
        """Bytes of the budget held now."""
        with self._lock:
            return self._used


def parse_upload(
    data: bytes, name: str, asf_data: bytes | None = None, asf_name: str = "skeleton.asf"
) -> Motion:
    """An uploaded motion file parsed (:func:`quatmotion.io.parse_motion`), every error of
    the file an ``HTTPException`` with a 4xx and one line: the reader's message (400), a
    file too deep or too large for the parser (413), a kind of file whose optional reader is
    not installed (415), any other failure of the reader on these bytes (400, naming the
    error's kind). Nothing the file holds makes a 500."""
    try:
        return parse_motion(data, name, asf_data, asf_name)
    except FormatError as error:  # a limit of quatmotion.limits included; names its file
        raise HTTPException(400, _one_line(error, "" if error.path else name)) from None
    except ValueError as error:
        raise HTTPException(400, _one_line(error, name)) from None
    except (MemoryError, RecursionError) as error:
        raise HTTPException(
            413, f"{name}: too large or too deeply nested to parse ({type(error).__name__})"
        ) from None
    except ImportError as error:  # an optional reader not installed here: the server's lack
        raise HTTPException(415, f"{name}: this server cannot read it ({error})") from None
    except Exception as error:  # a reader's fault on odd bytes is still the file's answer
        # the name as a Python literal: its terminal escapes must not reach the server's console
        _log.warning("upload %r: the reader failed", name, exc_info=True)
        raise HTTPException(
            400, f"{name}: cannot be read ({type(error).__name__}: {_one_line(error, '')})"
        ) from None


def _one_line(error: BaseException, name: str) -> str:
    lines = str(error).strip().splitlines()
    text = lines[0] if lines else type(error).__name__
    return text if not name or text.startswith(name) else f"{name}: {text}"
