"""The exceptions quatmotion raises for bad input."""

from __future__ import annotations

from pathlib import Path


class FormatError(ValueError):
    """A motion file is malformed. The message names the file and, where known, the line.

    Attributes
    ----------
    path : pathlib.Path or None
        The file that failed to parse.
    line : int or None
        1-based line number of the offending text, where one can be named.
    """

    def __init__(self, message: str, path: str | Path | None = None, line: int | None = None):
        self.path = Path(path) if path is not None else None
        self.line = line
        where = ""
        if self.path is not None:
            where = f"{self.path}"
            if line is not None:
                where += f":{line}"
            where += ": "
        super().__init__(f"{where}{message}")
        self.reason = message


class MissingDependencyError(ImportError):
    """An optional package a command needs is not installed; the message says what to install.

    The command line reports it in one line (exit code 2), as bad input: the user can act on it.
    """


class ClipNameError(KeyError, ValueError):
    """A clip name that names no clip of a collection, or several (the message lists them).

    Both a ``KeyError`` (a name looked up, as :meth:`quatmotion.codec.Archive.index_of` raises)
    and a ``ValueError`` (a bad argument, as the pose library and the clip index raise).
    """

    def __str__(self) -> str:  # KeyError's would quote the message
        return str(self.args[0]) if self.args else ""


class FormatWarning(UserWarning):
    """A motion file read despite something in it that a reader tolerated or had to assume (a
    frame line more than ``Frames:`` announces, translation channels whose meaning was
    detected). The message names the file and, where known, the line; ``reason`` is the
    message alone. :func:`quatmotion.io.read_motion_checked` turns them into doubts.
    """

    def __init__(self, message: str, path: str | Path | None = None, line: int | None = None):
        self.path = Path(path) if path is not None else None
        self.line = line
        where = ""
        if self.path is not None:
            where = f"{self.path}" + (f":{line}" if line is not None else "") + ": "
        super().__init__(f"{where}{message}")
        self.reason = message
