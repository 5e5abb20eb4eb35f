"""A full disk (ENOSPC) under every writing command (issue 30): one ``error:`` line naming the
output, exit 2, no traceback, no half-written output (the target as it was, no temporary file
left beside it).

The fault is injected without root, in-process (Typer's runner calls ``quatmotion.cli``):

* files written through Python (``.qmz``, BVH, the pose library's ``.npz``): every file opened
  for writing in the output folder accepts ``ALLOWED`` bytes, then each ``write`` fails with
  ``OSError(ENOSPC)`` and no file name, as the kernel's ``write(2)`` does on a full disk (the
  bytes before it are on the disk: a real half-written temporary file);
* SQLite's clip index: ``PRAGMA max_page_count`` caps the database at its size when opened,
  so SQLite itself reports ``SQLITE_FULL`` ("database or disk is full") on the next page.
"""

from __future__ import annotations

import builtins
import errno
import io
import os
import sqlite3
import tempfile
from pathlib import Path

import pytest
from typer.testing import CliRunner

from quatmotion.cli import app
from quatmotion.io import write_bvh
from quatmotion.synthetic import generate_clip

runner = CliRunner()
ALLOWED = 1000
"""Bytes a file in the full folder takes before the disk is full."""


def _invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def _one_error(result) -> str:
    assert result.exit_code == 2, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    assert "Traceback" not in result.output
    lines = [line for line in result.stderr.splitlines() if line.startswith("error:")]
    assert len(lines) == 1, result.stderr
    return lines[0]


class _FullFile(io.RawIOBase):
    """A file being written on a full disk: ``ALLOWED`` bytes in, then ENOSPC."""

    def __init__(self, raw: io.FileIO) -> None:
        self.raw = raw
        self.room = ALLOWED

    def writable(self) -> bool:
        return True

    def readable(self) -> bool:
        return self.raw.readable()

    def seekable(self) -> bool:
        return True

    def seek(self, offset: int, whence: int = 0) -> int:
        return self.raw.seek(offset, whence)

    def tell(self) -> int:
        return self.raw.tell()

    def readinto(self, buffer) -> int:
        return self.raw.readinto(buffer)

    def write(self, data) -> int:
        if self.room <= 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        n = self.raw.write(bytes(memoryview(data)[: self.room]))
        self.room -= n
        return n

    def fileno(self) -> int:
        return self.raw.fileno()

    def close(self) -> None:
        self.raw.close()
        super().close()


@pytest.fixture
def full_disk(monkeypatch):
    """``full_disk(folder)``: from now on, files opened for writing under ``folder`` fill up."""
    real_open = io.open
    folders: list[Path] = []

    def open_on_full_disk(file, mode="r", buffering=-1, *args, **kwargs):
        if not any(m in mode for m in "wax+"):
            return real_open(file, mode, buffering, *args, **kwargs)
        # opened as the caller asks, unbuffered; a descriptor is named by its link in /proc
        opening = {k: kwargs.pop(k) for k in ("closefd", "opener") if k in kwargs}
        raw = real_open(file, mode.replace("t", "").replace("b", "") + "b", 0, **opening)
        path = Path(os.readlink(f"/proc/self/fd/{raw.fileno()}"))
        if not any(path.is_relative_to(f) for f in folders):
            raw.close()
            return real_open(file, mode, buffering, *args, **kwargs, **opening)
        buffered = io.BufferedRandom(_FullFile(raw)) if "+" in mode else None
        buffered = buffered or io.BufferedWriter(_FullFile(raw))
        if "b" in mode:
            return buffered
        return io.TextIOWrapper(buffered, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", open_on_full_disk)
    monkeypatch.setattr(io, "open", open_on_full_disk)

    def fill(folder: Path) -> None:
        folders.append(Path(folder).resolve())

    return fill


@pytest.fixture(scope="module")
def clips(tmp_path_factory) -> list[Path]:
    folder = tmp_path_factory.mktemp("clips")
    out = []
    for kind, seed in (("walk", 1), ("run", 2), ("jump", 3)):
        path = folder / f"{kind}.bvh"
        write_bvh(generate_clip(kind, seed, n_frames=60), path)
        out.append(path)
    return out


def _listing(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def test_the_fault_is_a_full_disk(tmp_path, full_disk):
    full_disk(tmp_path)
    with pytest.raises(OSError) as raised, open(tmp_path / "x", "wb") as fh:
        fh.write(b"\0" * 5000)
    assert raised.value.errno == errno.ENOSPC and raised.value.filename is None
    assert (tmp_path / "x").stat().st_size == ALLOWED
    assert (tmp_path.parent / "elsewhere").write_text("fine") == 4


def test_compress_to_a_full_disk(clips, tmp_path, full_disk):
    out = tmp_path / "out" / "lib.qmz"
    out.parent.mkdir()
    full_disk(out.parent)
    line = _one_error(_invoke("compress", *clips, "-o", out, "--workers", "1"))
    assert "lib.qmz" in line and "no space left" in line
    assert _listing(out.parent) == {}


def test_compress_with_a_full_temporary_folder(clips, tmp_path, full_disk, monkeypatch):
    """The coded clips are spooled to a temporary file before the library is written: a full
    temporary folder is named as the output's failure (the spool is no name the user knows)."""
    spool = tmp_path / "tmp"
    spool.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(spool))
    full_disk(spool)
    out = tmp_path / "lib.qmz"
    line = _one_error(_invoke("compress", *clips, "-o", out, "--workers", "1"))
    assert "lib.qmz" in line and "no space left" in line
    assert not out.exists() and _listing(spool) == {}


def test_append_on_a_full_disk_leaves_the_library_as_it_was(clips, tmp_path, full_disk):
    lib = tmp_path / "lib" / "lib.qmz"
    result = _invoke("compress", *clips[:2], "-o", lib, "--workers", "1")
    assert result.exit_code == 0, result.output
    before = _listing(lib.parent)
    full_disk(lib.parent)
    line = _one_error(_invoke("append", lib, clips[2], "--workers", "1"))
    assert "lib.qmz" in line and "no space left" in line
    assert _listing(lib.parent) == before


def test_decompress_to_a_full_disk(clips, tmp_path, full_disk):
    lib = tmp_path / "lib.qmz"
    result = _invoke("compress", *clips, "-o", lib, "--workers", "1")
    assert result.exit_code == 0, result.output
    out = tmp_path / "out"
    out.mkdir()
    full_disk(out)
    line = _one_error(_invoke("decompress", lib, "-o", out))
    assert "no space left" in line and str(out) in line
    assert _listing(out) == {}  # no clip half written (none whole either: the first fails)


def test_pose_index_to_a_full_disk(clips, tmp_path, full_disk):
    out = tmp_path / "out" / "poses.npz"
    out.parent.mkdir()
    full_disk(out.parent)
    args = ["--rank", "4", "--unlabeled", "50", "--pairs", "10", "--workers", "1"]
    line = _one_error(_invoke("pose", "index", *clips, "-o", out, *args))
    assert "poses.npz" in line and "no space left" in line
    assert _listing(out.parent) == {}


def _full_database(monkeypatch, pages: int | None) -> None:
    """Every SQLite database opened from now on is full at ``pages`` pages (None: at its size
    when opened)."""
    real_connect = sqlite3.connect

    def connect(*args, **kwargs):
        db = real_connect(*args, **kwargs)
        (now,) = db.execute("PRAGMA page_count").fetchone()
        db.execute(f"PRAGMA max_page_count = {now if pages is None else pages}")
        return db

    monkeypatch.setattr(sqlite3, "connect", connect)


def _names(index: Path) -> list[str]:
    db = sqlite3.connect(index)
    try:
        return [name for (name,) in db.execute("SELECT name FROM clips ORDER BY name")]
    finally:
        db.close()


@pytest.mark.parametrize("pages", [5, 12])
def test_index_build_on_a_full_disk(clips, tmp_path, monkeypatch, pages):
    """Full before the schema is made (11 pages: nothing appears at the path) or after: what
    is there is an index of whole clips, those committed before the disk filled (none here:
    a batch of 16 clips is committed at once), which a build resumes."""
    out = tmp_path / "out" / "a.qidx"
    _full_database(monkeypatch, pages)
    line = _one_error(_invoke("index", "build", *clips, "-o", out, "--workers", "1"))
    assert "a.qidx" in line and "full" in line
    monkeypatch.undo()
    if pages < 11:
        assert not out.parent.exists() or _listing(out.parent) == {}
    else:
        assert _opens(out) and len(_names(out)) < len(clips)
        assert sorted(p.name for p in out.parent.iterdir()) == ["a.qidx"]


def test_index_add_on_a_full_disk_keeps_the_index(clips, tmp_path, monkeypatch):
    out = tmp_path / "a.qidx"
    result = _invoke("index", "build", *clips[:2], "-o", out, "--workers", "1")
    assert result.exit_code == 0, result.output
    before = _names(out)
    _full_database(monkeypatch, None)
    line = _one_error(_invoke("index", "add", out, clips[2], "--workers", "1"))
    assert "a.qidx" in line and "full" in line
    monkeypatch.undo()
    assert _names(out) == before
    assert _opens(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.qidx"]


def _opens(path: Path) -> bool:
    result = _invoke("index", "ls", path)
    assert result.exit_code == 0, result.output
    return True
