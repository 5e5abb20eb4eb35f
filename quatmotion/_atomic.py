"""Atomic file output: every file quatmotion writes appears whole or not at all.

The data go to a temporary file in the target's folder (same file system, so the final
:func:`os.replace` is atomic); on any error the temporary file is removed and the target is
left as it was.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

__all__ = [
    "WRITE_ERRNOS",
    "atomic_output",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "output_lock",
]


WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG})
"""Errors only writing raises (a full disk, a quota, a file too large): an ``OSError`` of these
that names no file is about the file being written."""


@contextlib.contextmanager
def atomic_output(path: str | Path, suffix: str = ".tmp") -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it over ``path`` when the block succeeds.

    For writers that want a file name (``savefig``, an index's ``save``). ``suffix`` lets such
    writers pick the format from the name (``".png"``). Missing parent folders are created.
    """
    path = Path(path)
    temp = ""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, temp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=suffix)
        os.close(handle)
        yield Path(temp)
        # mkstemp creates the file readable by its owner only; give it the permissions a plain
        # open() would (the umask's), or those of the file it replaces.
        os.chmod(temp, _permissions(path))
        os.replace(temp, path)
    except OSError as error:
        # The temporary file is no name the user knows: errors name the target instead; so
        # do the errors of writing that name no file (a full disk: ``write`` says ENOSPC).
        named = getattr(error, "filename", None)
        ours = bool(named) and Path(named).name.startswith(f".{path.name}.")
        if error.errno is None or not (ours or (not named and error.errno in WRITE_ERRNOS)):
            raise
        raise type(error)(error.errno, error.strerror, str(path)) from error
    finally:
        if temp:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(temp)


def _permissions(path: Path) -> int:
    try:
        return path.stat().st_mode & 0o7777
    except FileNotFoundError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


class OutputBusyError(OSError):
    """Another process is writing the file (it holds the file's :func:`output_lock`)."""


@contextlib.contextmanager
def output_lock(path: str | Path) -> Iterator[None]:
    """Hold the write lock of ``path`` for the block: an exclusive ``flock`` on
    ``.NAME.lock`` beside it, removed when the block ends.

    Two writers of one file (two ``append`` to a library, two ``compress`` to one ``-o``) would
    each read the old file and rename their own over it, one losing the other's work: the
    second is refused at once instead.

    Raises
    ------
    OutputBusyError
        Naming ``path``: another process holds its lock.
    """
    import fcntl

    path = Path(path)
    lock = path.parent / f".{path.name}.lock"
    path.parent.mkdir(parents=True, exist_ok=True)
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise OutputBusyError(
                errno.EBUSY,
                f"is being written by another quatmotion process (lock {lock.name}); try again "
                "when it has finished",
                str(path),
            ) from None
        try:  # the lock file may have been removed by the holder just before: lock the new one
            if os.fstat(fd).st_ino == os.stat(lock).st_ino:
                break
        except FileNotFoundError:
            pass
        os.close(fd)
    try:
        yield
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(lock)
        os.close(fd)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_output(path) as temp:
        temp.write_bytes(data)


def atomic_write_text(path: str | Path, text: str, encoding: str = "utf-8") -> None:
    """Write ``text`` to ``path`` atomically in ``encoding``."""
    atomic_write_bytes(path, text.encode(encoding))


def atomic_write_json(path: str | Path, payload: Any) -> None:
    """Write ``payload`` as indented JSON atomically; NumPy scalars become floats."""
    atomic_write_text(path, json.dumps(payload, indent=2, default=float) + "\n")
