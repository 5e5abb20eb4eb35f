"""The codec's names before 0.4.0 (docs/migration-0.4.md), each warning with a
DeprecationWarning that names its replacement: :func:`compress` and :func:`append`, thin
wrappers of :meth:`Archive.build <quatmotion.codec.Archive.build>` and
:meth:`Archive.add <quatmotion.codec.Archive.add>` that return a :class:`CompressionResult`;
:func:`open` and :func:`open_archive`, :meth:`Archive.open <quatmotion.codec.Archive.open>`.

``quatmotion.codec`` loads this module when one of these names is first asked for: importing
the codec loads no compressor.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from quatmotion._deprecated import warn_renamed
from quatmotion.codec.metrics import ClipErrors
from quatmotion.codec.qmz import Archive
from quatmotion.codec.settings import CompressSettings
from quatmotion.codec.writer import add_to_library, build_library
from quatmotion.codec.writer.runner import OnDoubt, Progress
from quatmotion.collection import BuildReport, ReadSettings
from quatmotion.motion import Motion, Skeleton
from quatmotion.parallel import Runner, Scheduler

__all__ = ["CompressionResult", "append", "compress", "open", "open_archive"]


@dataclass
class CompressionResult:
    """What :func:`compress` made (the return before 0.4.0; :class:`BuildReport` now).

    Attributes
    ----------
    data : bytes
        The whole ``.qmz`` file.
    path : Path or None
        Where it was written.
    method : str
    clip_errors : list of ClipErrors
        Per clip, as decoded from ``data``.
    clip_bytes : list of int
        Per clip, its chunk's payload bytes.
    source_bytes : list of int
        Per clip, its source file's size (0 if unknown).
    raw_bytes : list of int
        Per clip, ``4 * dofs * frames``.
    seconds : float
        Wall time of the whole compression.
    quality : float
        The method's quality knob as used.
    """

    data: bytes
    path: Path | None
    method: str
    clip_errors: list[ClipErrors]
    clip_bytes: list[int]
    source_bytes: list[int]
    raw_bytes: list[int]
    seconds: float
    quality: float
    corrections: list[int] = field(default_factory=list)
    failed: list[tuple[str, str]] = field(default_factory=list)
    """Inputs left out (``on_error="skip"``): (file or clip, one-line reason)."""

    @property
    def size(self) -> int:
        return len(self.data)

    @classmethod
    def from_report(cls, report: BuildReport) -> CompressionResult:
        d = report.details
        data = d["data"] if "data" in d else Path(report.path).read_bytes()
        return cls(
            data, report.path, d["method"], d["clip_errors"], d["clip_bytes"],
            d["source_bytes"], d["raw_bytes"], d["seconds"], d["quality"], d["corrections"],
            [(str(f.item), f.message) for f in report.failures],
        )  # fmt: skip


def compress(
    clips: Sequence[Motion | str | Path],
    out: str | Path | None = None,
    *,
    max_error: float | None = None,
    ratio: float | None = None,
    method: str = "best",
    quality: float | None = None,
    bound_on: str = "joints",
    skeleton: Skeleton | str | Path | None = None,
    units: str | float | None = None,
    sources: Sequence[tuple[int, str]] | None = None,
    seed: int = 0,
    progress: Progress | None = None,
    workers: int | None = None,
    scheduler: str | Scheduler | None = None,
    on_error: str = "raise",
    on_doubt: OnDoubt | None = None,
) -> CompressionResult:
    """The name before 0.4.0: :meth:`Archive.build` with a :class:`CompressSettings` made of
    the keywords (``max_error`` and ``ratio`` both None: no bound, as before). ``skeleton`` may
    only be a path now (an ASF file or a folder)."""
    warn_renamed("codec.compress", "codec.Archive.build with CompressSettings")
    if isinstance(skeleton, Skeleton):
        raise TypeError("skeleton must be the path of an ASF file or folder")
    settings = CompressSettings(
        max_error=max_error, ratio=ratio, method=method, quality=quality, bound_on=bound_on,
        seed=seed, on_error=on_error,
        read=ReadSettings(units=units, skeleton=None if skeleton is None else str(skeleton)),
    )  # fmt: skip
    report = build_library(
        clips, out, settings, runner=Runner.of(workers, scheduler), progress=progress,
        on_doubt=on_doubt, source_sizes=sources,
    )  # fmt: skip
    return CompressionResult.from_report(report)


def append(
    path: str | Path,
    clips: Sequence[Motion | str | Path],
    *,
    max_error: float | None = None,
    quality: float | None = None,
    skeleton: Skeleton | str | Path | None = None,
    units: str | float | None = None,
    seed: int = 0,
    progress: Progress | None = None,
    workers: int | None = None,
    scheduler: str | Scheduler | None = None,
    on_doubt: OnDoubt | None = None,
) -> CompressionResult:
    """The name before 0.4.0: :meth:`Archive.add` with the keywords as settings."""
    warn_renamed("codec.append", "codec.Archive.add with CompressSettings")
    if isinstance(skeleton, Skeleton):
        raise TypeError("skeleton must be the path of an ASF file or folder")
    settings = CompressSettings(
        max_error=max_error, quality=quality, seed=seed,
        read=ReadSettings(units=units, skeleton=None if skeleton is None else str(skeleton)),
    )  # fmt: skip
    report = add_to_library(
        path, clips, settings, runner=Runner.of(workers, scheduler), progress=progress,
        on_doubt=on_doubt,
    )  # fmt: skip
    if not report.added:
        raise ValueError(f"{path}: already holds every clip given")
    return CompressionResult.from_report(report)


def open(source: str | Path | bytes, *, recover: bool = False) -> Archive:  # noqa: A001
    """The name before 0.4.0: :meth:`Archive.open`."""
    warn_renamed("codec.open", "codec.Archive.open")
    return Archive.open(source, recover=recover)


def open_archive(source: str | Path | bytes, *, recover: bool = False) -> Archive:
    """The name before 0.4.0: :meth:`Archive.open`."""
    warn_renamed("codec.open_archive", "codec.Archive.open")
    return Archive.open(source, recover=recover)
