"""Atomic output: whole files with ordinary permissions."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from quatmotion._atomic import atomic_output, atomic_write_bytes, atomic_write_text


def test_new_file_gets_the_umask_permissions(tmp_path: Path) -> None:
    umask = os.umask(0o022)
    try:
        target = tmp_path / "out.json"
        atomic_write_text(target, "{}")
        assert stat.S_IMODE(target.stat().st_mode) == 0o644
    finally:
        os.umask(umask)


def test_replaced_file_keeps_its_permissions(tmp_path: Path) -> None:
    target = tmp_path / "out.txt"
    target.write_text("old")
    target.chmod(0o640)
    atomic_write_text(target, "new")
    assert target.read_text() == "new"
    assert stat.S_IMODE(target.stat().st_mode) == 0o640


def test_failed_write_leaves_the_target_and_no_temporary(tmp_path: Path) -> None:
    target = tmp_path / "out.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError), atomic_output(target) as temp:
        temp.write_text("half")
        raise RuntimeError("writer failed")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_a_write_error_names_the_target_not_the_temporary_file(tmp_path, monkeypatch):
    """Issue 17: a write that failed named '.x.qmz.uppijxpq.tmp', a file the user never saw."""
    import tempfile as tempfile_module

    def refuse(dir, prefix, suffix):  # noqa: A002 (mkstemp's keyword)
        raise PermissionError(13, "Permission denied", f"{dir}/{prefix}abc123{suffix}")

    monkeypatch.setattr(tempfile_module, "mkstemp", refuse)
    with pytest.raises(PermissionError) as caught:
        atomic_write_bytes(tmp_path / "x.qmz", b"data")
    assert caught.value.filename == str(tmp_path / "x.qmz")


def test_an_index_that_cannot_be_written_names_its_file(tmp_path):
    """SQLite's "attempt to write a readonly database" (or "unable to open database file")
    becomes an OSError naming the index, which the command line turns into one error line."""
    from quatmotion.collection import ClipRef
    from quatmotion.retrieval.index import ClipIndex, ClipRecord

    path = tmp_path / "x.qidx"
    ClipIndex._create(path).close()
    record = ClipRecord(ClipRef("walk", "0" * 64, "/walk.bvh"), "", 10, 30.0, "s", {})
    with ClipIndex.open(path) as index, pytest.raises(OSError) as caught:  # opened read-only
        index.store([record])
    assert caught.value.filename == str(path) and "readonly" in caught.value.strerror
