"""The ``.qmz`` file kind as users call it: :class:`Archive`, the reader
(:class:`~quatmotion.codec.archive.ArchiveReader`: open, clips, read, sample) with the
collection surface's ``build``/``add`` (:mod:`~quatmotion.codec.writer`, the writer) on top:
a thin facade above both, so the reader imports no writer and decoding stays importable
without it (the writer is imported by :meth:`Archive.build` and :meth:`Archive.add`, when a
file is written: ``import quatmotion.codec`` loads no compressor).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from quatmotion.codec.archive import ArchiveReader

if TYPE_CHECKING:
    from quatmotion.codec.settings import CompressSettings
    from quatmotion.collection import BuildReport
    from quatmotion.io import Doubt
    from quatmotion.parallel import Runner

__all__ = ["Archive"]


class Archive(ArchiveReader):
    """An open ``.qmz`` file (or bytes); use as a context manager or call :meth:`close`.

    :meth:`build` writes one, :meth:`add` extends one, :meth:`open` reads one (everything
    read is :class:`~quatmotion.codec.archive.ArchiveReader`'s).
    """

    @classmethod
    def build(
        cls,
        sources: Iterable[Any],
        out: str | Path | None,
        settings: CompressSettings | None = None,
        *,
        runner: Runner | None = None,
        progress: Callable[[str, int, int], None] | None = None,
        on_doubt: Callable[[str, Doubt], None] | None = None,
    ) -> BuildReport:
        """Compress clips (files, folders, motions, :class:`~quatmotion.collection.ClipSource`)
        into one ``.qmz`` library at ``out`` (atomically; None: bytes only, in
        ``report.details["data"]``). See :func:`quatmotion.codec.writer.build_library`."""
        from quatmotion.codec.writer import build_library

        return build_library(
            sources, out, settings, runner=runner, progress=progress, on_doubt=on_doubt
        )

    @classmethod
    def add(
        cls,
        path: str | Path,
        sources: Iterable[Any],
        settings: CompressSettings | None = None,
        *,
        runner: Runner | None = None,
        progress: Callable[[str, int, int], None] | None = None,
        on_doubt: Callable[[str, Doubt], None] | None = None,
        labels: Any = None,
    ) -> BuildReport:
        """Add clips to an existing ``.qmz`` file (rewritten atomically), the clips already in
        it kept byte for byte (re-coded without loss from an older format version:
        :meth:`ArchiveReader.clip_payloads`; :func:`quatmotion.codec.writer.add_to_library`)."""
        if labels is not None:
            raise ValueError("a .qmz library stores no labels (give them to the clip index)")
        from quatmotion.codec.writer import add_to_library

        return add_to_library(
            path, sources, settings, runner=runner, progress=progress, on_doubt=on_doubt
        )
