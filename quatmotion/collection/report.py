"""What building or extending a collection file did: one report for every file kind."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from quatmotion.collection.refs import ClipRef
from quatmotion.parallel import BatchStats, Failure

__all__ = ["BuildReport"]


@dataclass
class BuildReport:
    """The outcome of ``Kind.build`` or ``Kind.add`` (codec, clip index, pose library).

    Attributes
    ----------
    path : Path or None
        The file written (None when only bytes were made).
    added : list of ClipRef
        Clips written, in input order.
    skipped : list of ClipRef
        Clips left out because the file already held them (same content hash).
    failures : list of Failure
        Inputs that could not be read or stored, each with a one-line reason; the others
        were written.
    doubts : list of (ClipRef, str)
        Clips read with something doubtful (a guessed unit making an implausible figure...),
        one message each; they were written.
    labels_changed : int
        Clips whose label a label option set or changed.
    unmatched_labels : list of str
        Keys of a given label mapping that named no clip.
    stats : BatchStats or None
        The batch's counts and times, from :mod:`quatmotion.parallel`.
    settings : object
        The settings object used (stored in the file).
    details : dict
        What the file kind adds (the codec's sizes and errors...).
    """

    path: Path | None = None
    added: list[ClipRef] = field(default_factory=list)
    skipped: list[ClipRef] = field(default_factory=list)
    failures: list[Failure] = field(default_factory=list)
    doubts: list[tuple[ClipRef, str]] = field(default_factory=list)
    labels_changed: int = 0
    unmatched_labels: list[str] = field(default_factory=list)
    stats: BatchStats | None = None
    settings: Any = None
    details: dict[str, Any] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """Whether every input was written or already there."""
        return not self.failures
