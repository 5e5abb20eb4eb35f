"""File formats and their versions: one policy for every kind of file quatmotion writes.

Conventions
-----------
* A format has a name, the version this code writes and the oldest version it still reads
  (:class:`FileFormat`). A version number, once assigned and released, never changes meaning:
  a change to the bytes or the schema is a new version, and the reader of every version from
  ``oldest_readable`` up stays (a reader per version, as the Animation Compression Library
  keeps a decoder per version).
* Reading checks the name and the version with :meth:`FileFormat.check`, which raises
  :class:`~quatmotion.errors.FormatError` in the same words for every kind: another format,
  a newer version (upgrade quatmotion), or a version too old to be read any more.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

from quatmotion.errors import FormatError

__all__ = ["FileFormat", "npy_header"]


@dataclass(frozen=True)
class FileFormat:
    """A file kind's name and versions.

    Attributes
    ----------
    name : str
        Stored in the file (its magic or its meta record), e.g. ``quatmotion-pose-library``.
    version : int
        The version this code writes.
    oldest_readable : int
        The oldest version this code reads (``<= version``).
    description : str
        What the file is, for messages ("a quatmotion pose library").
    """

    name: str
    version: int
    oldest_readable: int
    description: str

    def __post_init__(self) -> None:
        if not 1 <= self.oldest_readable <= self.version:
            raise ValueError(
                f"{self.name}: oldest_readable must be from 1 to {self.version}, "
                f"got {self.oldest_readable}"
            )

    @property
    def readable(self) -> range:
        """Every version this code reads."""
        return range(self.oldest_readable, self.version + 1)

    def versions_text(self) -> str:
        if self.oldest_readable == self.version:
            return f"version {self.version}"
        return f"versions {self.oldest_readable} to {self.version}"

    def check(self, name: object, version: object, path: str | Path | None = None) -> int:
        """The file's version if this code reads it.

        Parameters
        ----------
        name, version
            As found in the file (any type: a damaged file may hold anything).
        path
            Named in the message.

        Raises
        ------
        FormatError
            Another format, a version that is not an integer, newer than :attr:`version` or
            older than :attr:`oldest_readable`.
        """
        if name != self.name:
            raise FormatError(
                f"not {self.description} (format {name!r}, expected {self.name!r})", path
            )
        try:
            number = int(version)  # type: ignore[call-overload]
        except (TypeError, ValueError):
            raise FormatError(
                f"{self.description} with an unreadable format version {version!r}", path
            ) from None
        if number > self.version:
            raise FormatError(
                f"written by a newer quatmotion ({self.name} version {number}; this one reads "
                f"{self.versions_text()}): upgrade quatmotion to read it",
                path,
            )
        if number < self.oldest_readable:
            raise FormatError(
                f"{self.name} version {number} is no longer read (this quatmotion reads "
                f"{self.versions_text()}): rebuild the file from its sources",
                path,
            )
        return number


def npy_header(fh: BinaryIO) -> tuple[tuple[int, ...], Any]:
    """The shape and dtype a stored ``.npy`` stream declares, from its header alone (nothing
    allocated; ``fh`` is left at the data), so that a reader checks a declared size against the
    bytes there are before NumPy allocates it.

    Raises
    ------
    ValueError
        A stream that is no ``.npy`` (NumPy's message).
    """
    import tokenize

    import numpy as np  # here: the module is imported where no array is read

    version = np.lib.format.read_magic(fh)
    read_header = (
        np.lib.format.read_array_header_1_0
        if version == (1, 0)
        else np.lib.format.read_array_header_2_0
    )
    try:
        shape, _, dtype = read_header(fh)
    except (SyntaxError, tokenize.TokenError) as error:  # NumPy tokenises the header's text
        raise ValueError(f"the .npy header is no Python literal ({error})") from None
    return shape, dtype
