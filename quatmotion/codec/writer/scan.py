"""Step 1, scanning: every clip read once in a worker (:func:`scan_clip`), the caller keeping
only what planning needs (:class:`ScannedClip`: reference, layout key, length, skeleton; no
frames), every clip named by :func:`quatmotion.collection.unique_names`; then the clips that
can be stored admitted (:func:`admit`: frames, a skeleton the format records exactly).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from quatmotion.codec.channels import layout_key
from quatmotion.codec.settings import CompressSettings
from quatmotion.codec.writer.runner import OnDoubt, StepRunner
from quatmotion.codec.writer.skeleton_table import SkeletonTable
from quatmotion.collection import (
    ClipRef,
    ClipSource,
    ReadSettings,
    find_clips,
    read_clip,
)
from quatmotion.errors import FormatError
from quatmotion.io import Doubt
from quatmotion.motion import Motion, Skeleton
from quatmotion.parallel import Failure


@dataclass(frozen=True)
class ScannedClip:
    """What the caller keeps of one clip: :func:`scan_clip`'s result, read in a worker.

    Small (no frames): the reference, the layout key and the skeleton, the clip's length and
    its source's size and format, so that a library of any number of clips is planned in the
    caller's memory while the workers read the frames.

    Attributes
    ----------
    ref : ClipRef
    name : str
        The clip's name (the collection's rule, :func:`quatmotion.collection.unique_names`).
    key : tuple
        :func:`quatmotion.codec.channels.layout_key` of its skeleton.
    skeleton : Skeleton
    n_frames : int
    fps : float
    source : (int, str)
        The source file's size in bytes and its format (``(0, "")`` for a clip in memory).
    text_bytes : int
        The size of the AMC or BVH text the writers would produce (only when asked: a
        ``ratio`` target of a clip without a source size), else 0.
    doubts : tuple of Doubt
    """

    ref: ClipRef
    name: str
    key: tuple
    skeleton: Skeleton
    n_frames: int
    fps: float
    source: tuple[int, str]
    text_bytes: int = 0
    doubts: tuple[Doubt, ...] = ()

    @property
    def raw_bytes(self) -> int:
        """``4 * dofs * frames``: the clip as float32 channels."""
        return 4 * sum(len(ch) for ch in self.skeleton.channels) * self.n_frames


@dataclass(frozen=True)
class Unread:
    """A clip :func:`scan_clip` could not read: the reason in one line (the caller reads it
    again to raise the error itself, or notes the failure)."""

    message: str


@dataclass(frozen=True)
class ScanOptions:
    read: ReadSettings
    text_bytes: bool = False


def scan_clip(source: ClipSource, options: ScanOptions) -> ScannedClip | Unread:
    """Read one clip and keep what planning the library needs (a worker's job: the frames
    stay in the worker)."""
    try:
        motion, ref, doubts = read_clip(source, options.read)
        size = (0, "") if source.path is None else _source_size(source.path)
        if source.take is not None:  # a take's share of its file: no byte counted twice
            takes = max(1, len(motion.skeleton.extras.get("fbx_takes") or ()))
            size = (size[0] // takes, size[1])
        text = _text_bytes(motion) if options.text_bytes and not size[0] else 0
    except (FormatError, OSError, ValueError) as error:
        return Unread(one_line(error))
    return ScannedClip(
        ref, motion.name, layout_key(motion.skeleton), motion.skeleton, motion.n_frames,
        motion.fps, size, text, tuple(doubts),
    )  # fmt: skip


def one_line(error: BaseException) -> str:
    message = getattr(error, "reason", None) or str(error) or type(error).__name__
    if isinstance(error, FormatError):
        message = str(error)
    return str(message).splitlines()[0]


@dataclass
class Inputs:
    """The clips scanned (step 1): each clip's source (what a worker reads) and its scan."""

    sources: list[ClipSource] = field(default_factory=list)
    scans: list[ScannedClip] = field(default_factory=list)
    failures: list[Failure] = field(default_factory=list)
    doubts: list[tuple[ClipRef, str]] = field(default_factory=list)

    @property
    def refs(self) -> list[ClipRef]:
        return [s.ref for s in self.scans]

    def keep(self, source: ClipSource, scan: ScannedClip) -> None:
        self.sources.append(source)
        self.scans.append(scan)

    def fail(self, item: object, message: str) -> None:
        self.failures.append(Failure(len(self.failures), item, message))

    def select(self, keep: Sequence[int]) -> None:
        self.sources = [self.sources[i] for i in keep]
        self.scans = [self.scans[i] for i in keep]


def scan_step(
    sources: Iterable[Any],
    settings: CompressSettings,
    skip: bool,
    known: Sequence[tuple[int, str]] | None,
    on_doubt: OnDoubt | None,
    runner: StepRunner,
) -> Inputs:
    """Every clip of ``sources`` scanned by :func:`scan_clip` through the runner, named by the
    collection's rules. With ``skip``, a file that cannot be found, hashed or read is noted in
    the failures and left out instead of raising; progress hears ``("read", done, total)``."""
    out = Inputs()
    read = settings.read
    found_errors: list[tuple[str, str]] = []
    items = [Path(s) if isinstance(s, str) else s for s in sources]
    found = find_clips(items, read, on_error=found_errors if skip else None)
    for path, reason in found_errors:
        out.failures.append(Failure(len(out.failures), path, reason))
    in_memory = [s for s in found if s.path is None]
    if known is not None and len(known) != len(in_memory):
        raise ValueError(f"sources gives {len(known)} sizes for {len(in_memory)} clips")
    sizes = iter(known or ())
    options = ScanOptions(read, text_bytes=settings.ratio is not None)
    for source, scan in zip(found, runner.each("read", scan_clip, found, options), strict=True):
        if isinstance(scan, Unread):
            if not skip:
                read_clip(source, read)  # raises the error itself
                raise ValueError(scan.message)
            out.fail(source, scan.message)
            continue
        if source.path is None and known is not None:
            from dataclasses import replace

            scan = replace(scan, source=tuple(next(sizes)))
        for doubt in scan.doubts:
            out.doubts.append((scan.ref, doubt.message))
            if on_doubt is not None:
                on_doubt(str(source), doubt)
        out.keep(source, scan)
    if not out.scans and not out.failures:
        raise ValueError("nothing to compress: no clips given")
    return out


def _source_size(path: Path) -> tuple[int, str]:
    return path.stat().st_size, path.suffix.lower().lstrip(".")


def admit(inputs: Inputs, table: SkeletonTable, skip: bool) -> None:
    """Keep the clips that can be stored (frames, a skeleton the format can record); the others
    are noted in the failures (``skip``) or raise."""
    keep = []
    for i, scan in enumerate(inputs.scans):
        try:
            if scan.n_frames == 0:
                raise ValueError(f"clip {scan.name!r} has no frames")
            table.index(scan.skeleton)
        except ValueError as error:
            if not skip:
                raise
            inputs.fail(scan.ref.path or scan.ref.name, one_line(error))
            continue
        keep.append(i)
    inputs.select(keep)
    if not inputs.scans:
        first = inputs.failures[0] if inputs.failures else None
        raise ValueError(f"nothing to compress: every input failed ({first})")


def _text_bytes(motion: Motion) -> int:
    """Size of the AMC (ASF skeletons) or BVH text the writers would produce."""
    from quatmotion.io import bvh_text
    from quatmotion.io.asf_amc import amc_channel_values

    if motion.skeleton.extras.get("format") == "asf":
        names, counts, values = amc_channel_values(motion)
        per_frame = sum(len(n) + 1 for n in names) + sum(len(f"{v:.6g}") + 1 for v in values[0])
        return per_frame * motion.n_frames
    return len(bvh_text(motion))
