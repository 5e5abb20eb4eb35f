"""The collection surface as a type: :class:`Kind`, what every file kind of clips implements
(:class:`quatmotion.codec.Archive`, :class:`quatmotion.retrieval.ClipIndex`,
:class:`quatmotion.pose.library.PoseLibrary`).

Every kind builds, opens and extends its file with one signature: the sources and the
output, the kind's settings object (None: its defaults), then keyword-only where the batch runs
(``runner``), how it reports progress (``progress``) and what it does with a doubt about a
clip (``on_doubt(path, doubt)``). A kind may take further keyword-only options after these
(labels for the clip index...); the shared ones keep their names, order and kinds, which
``tests/test_collection_kind.py`` checks with :func:`inspect.signature`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from quatmotion.collection.report import BuildReport

__all__ = ["Kind"]


@runtime_checkable
class Kind(Protocol):
    """A file kind of clips: ``build`` writes one, ``open`` reads one, ``add`` extends one."""

    @classmethod
    def build(
        cls,
        sources: Iterable[Any],
        out: str | Path,
        settings: Any = None,
        *,
        runner: Any = None,
        progress: Callable[..., None] | None = None,
        on_doubt: Callable[[str, Any], None] | None = None,
    ) -> BuildReport:
        """Read ``sources`` (files, folders, motions, clip sources) into a new file ``out``."""
        ...

    @classmethod
    def open(cls, path: str | Path) -> Any:
        """A reader of the file at ``path``: ``.clips()``, ``.settings``, a context manager."""
        ...

    @classmethod
    def add(
        cls,
        path: str | Path,
        sources: Iterable[Any],
        settings: Any = None,
        *,
        runner: Any = None,
        progress: Callable[..., None] | None = None,
        on_doubt: Callable[[str, Any], None] | None = None,
    ) -> BuildReport:
        """Add ``sources`` to the file at ``path`` (its own settings unless ``settings``)."""
        ...
