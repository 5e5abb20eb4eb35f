"""Temporary files of a run, named by its process id, and the files of dead runs removed.

A run killed outright (``kill -9``, the machine's out-of-memory killer) cannot remove its
temporary files: a batch's pickled context, a compressor's spool, ``multiprocessing``'s folder
of sockets. Each carries the process id of the run that made it
(``quatmotion-KIND-PID-RANDOM``); :func:`clean_stale` removes those of this user whose process
is gone, and every run calls it when it makes its first.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import re
import shutil
import tempfile
from pathlib import Path

__all__ = ["clean_stale", "prefix", "use_for_multiprocessing"]

_NAME = re.compile(r"^quatmotion-(context|spool|mp)-(\d+)-")
_cleaned: set[str] = set()
_SOCKET_FOLDER_BYTES = 80
"""The longest folder for ``multiprocessing``'s sockets (``listener-RANDOM`` in it): a Unix
socket's path holds 107 bytes on Linux, 103 on macOS."""


def prefix(kind: str) -> str:
    """The name prefix of this run's temporary files of ``kind`` (``context``, ``spool``,
    ``mp``), the stale files of dead runs removed first (once per run and folder)."""
    if kind not in ("context", "spool", "mp"):
        raise ValueError(f"unknown kind of temporary file {kind!r}")
    clean_stale()
    return f"quatmotion-{kind}-{os.getpid()}-"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process: alive
        return True
    return True


def clean_stale(folder: str | Path | None = None) -> list[Path]:
    """Remove the temporary files and folders of this user's dead runs in ``folder`` (the
    temporary folder); returns them. A file of a live process (or of a process id reused since)
    is kept."""
    base = Path(folder or tempfile.gettempdir())
    if str(base) in _cleaned and folder is None:
        return []
    _cleaned.add(str(base))
    removed = []
    with contextlib.suppress(OSError):
        for entry in base.iterdir():
            found = _NAME.match(entry.name)
            if found is None or int(found.group(2)) == os.getpid() or _alive(int(found.group(2))):
                continue
            with contextlib.suppress(OSError):
                if entry.lstat().st_uid != os.getuid():
                    continue
                if entry.is_dir() and not entry.is_symlink():
                    shutil.rmtree(entry)
                else:
                    entry.unlink()
                removed.append(entry)
    return removed


def use_for_multiprocessing() -> None:
    """Make ``multiprocessing``'s temporary folder of this process (its fork server's socket)
    one of :func:`prefix`'s names, so a dead run's is found and removed (it is ``pymp-RANDOM``,
    nobody's, otherwise). Done once, before the first pool starts; a folder already made is
    kept."""
    config = multiprocessing.current_process()._config  # multiprocessing.util.get_temp_dir's
    if config.get("tempdir") is not None:
        return
    from multiprocessing import util

    folder = tempfile.mkdtemp(prefix=prefix("mp"))
    if len(os.fsencode(folder)) > _SOCKET_FOLDER_BYTES:  # its socket's path would not fit
        os.rmdir(folder)
        return
    config["tempdir"] = folder
    # As util.get_temp_dir arranges for its own folder: removed when the process exits.
    util.Finalize(None, shutil.rmtree, args=(folder, True), exitpriority=-100)
