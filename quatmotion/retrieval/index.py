"""The clip index as users call it: :class:`ClipIndex`, the file
(:class:`~quatmotion.retrieval.index_file.IndexFile`: open, rows, features, versions) with the
collection surface's ``build``/``add`` (:mod:`~quatmotion.retrieval.build`, the writer) and
``search`` (:mod:`~quatmotion.retrieval.search`, the reader) on top: a thin facade above both,
so neither imports the other nor this module. They are imported when called: opening an
index to read it loads neither the build's workers nor the search's kernels.

The file's names (:data:`FORMAT`, :class:`IndexSettings`, :class:`ClipRecord`,
:class:`ClipRow`...) are re-exported here, where they were before 0.5.0.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from quatmotion.retrieval.index_file import (
    FEATURE_PARAMETERS,
    FORMAT,
    FORMAT_NAME,
    FORMAT_VERSION,
    ClipRecord,
    ClipRow,
    IndexFile,
    IndexSettings,
    content_hash,
)
from quatmotion.retrieval.ranges import DEFAULT_TOP

if TYPE_CHECKING:
    from quatmotion.collection import BuildReport
    from quatmotion.io import Doubt
    from quatmotion.motion import Motion
    from quatmotion.parallel import Runner, Scheduler
    from quatmotion.retrieval.search import SearchResult

__all__ = [
    "FEATURE_PARAMETERS",
    "FORMAT",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "ClipIndex",
    "ClipRecord",
    "ClipRow",
    "IndexSettings",
    "content_hash",
]


class ClipIndex(IndexFile):
    """An open clip index (use as a context manager, or call :meth:`close`).

    :meth:`build` writes one (or resumes one, saying so), :meth:`add` extends one,
    :meth:`open` reads one, :meth:`search` ranks its clips.
    """

    @classmethod
    def build(
        cls,
        sources: Iterable[Any],
        out: str | Path,
        settings: IndexSettings | None = None,
        *,
        runner: Runner | str | Scheduler | None = None,
        progress: Callable[[int, int], None] | None = None,
        on_doubt: Callable[[str, Doubt], None] | None = None,
        workers: int | None = None,
        labels: Mapping[str, str] | None = None,
    ) -> BuildReport:
        """Index ``sources`` into ``out``: a new file, or an existing index resumed (its clips
        with the same path and content hash skipped; ``report.details["resumed"]`` says so).

        See :func:`quatmotion.retrieval.build.build` for the parameters.
        """
        return _write("build", out, sources, settings, runner, workers, progress, labels, on_doubt)

    @classmethod
    def add(
        cls,
        path: str | Path,
        sources: Iterable[Any],
        settings: IndexSettings | None = None,
        *,
        runner: Runner | str | Scheduler | None = None,
        progress: Callable[[int, int], None] | None = None,
        on_doubt: Callable[[str, Doubt], None] | None = None,
        workers: int | None = None,
        labels: Mapping[str, str] | None = None,
    ) -> BuildReport:
        """Add ``sources`` to the existing index ``path`` (with its stored settings unless
        ``settings`` is given); ``labels`` also relabels clips already there
        (:func:`quatmotion.retrieval.build.add`).

        Raises
        ------
        FileNotFoundError
            No index at ``path``.
        """
        return _write("add", path, sources, settings, runner, workers, progress, labels, on_doubt)

    def search(
        self, query: Motion | str, k: int = DEFAULT_TOP, *, method: str | None = None
    ) -> list[SearchResult]:
        """The ``k`` clips most like ``query`` (:func:`quatmotion.retrieval.search.search`)."""
        from quatmotion.retrieval.search import search

        return search(self, query, method=method, k=k)


def _write(
    step: str,
    where: Any,
    sources: Iterable[Any],
    settings: IndexSettings | None,
    runner: Runner | str | Scheduler | None,
    workers: int | None,
    progress: Callable[[int, int], None] | None,
    labels: Mapping[str, str] | None,
    on_doubt: Callable[[str, Doubt], None] | None,
) -> BuildReport:
    """:meth:`ClipIndex.build` and :meth:`ClipIndex.add` as :mod:`~quatmotion.retrieval.build`
    writes them (imported when called: opening an index to read it loads no build)."""
    from quatmotion.retrieval import build

    options = {"runner": runner, "workers": workers, "progress": progress}
    options.update(labels=labels, on_doubt=on_doubt, settings=settings)
    if step == "build":
        return build.build(sources, where, **options)
    return build.add(where, sources, **options)
