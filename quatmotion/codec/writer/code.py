"""Step 4b, coding one clip: :func:`code_clip` of a :class:`ClipTask` (read it in the worker,
encode it, decode it back, measure it and repair it), the per-clip job that
:mod:`quatmotion.parallel` runs with the :class:`~quatmotion.codec.writer.fit.SharedModels`
as the batch's context.
"""

from __future__ import annotations

from dataclasses import dataclass

from quatmotion.codec.channels import to_channels
from quatmotion.codec.library import PreparedClip, PreparedLibrary
from quatmotion.codec.methods import CodingOptions
from quatmotion.codec.metrics import ClipErrors
from quatmotion.codec.repair import (
    Corrections,
    write_clip_prefix,
)
from quatmotion.codec.writer.fit import SharedModels
from quatmotion.codec.writer.plan import Plan
from quatmotion.codec.writer.scan import Inputs
from quatmotion.codec.writer.verify import verify_clip
from quatmotion.collection import (
    ClipSource,
    read_clip,
)
from quatmotion.motion import forward_kinematics


@dataclass(frozen=True)
class ClipTask:
    """One clip's share of the encoding, without its frames (the worker reads them) and
    without the models (:class:`SharedModels`, the batch's context).

    Attributes
    ----------
    source : ClipSource
        What the worker reads (a file, or a motion given in memory).
    name : str
        The clip's name in the library.
    layout : int
    verify : bool
        Decode the payload, measure it and repair the frames over the bound.
    payload : (str, int, int) or None
        Already coded (verify only): the spool file, offset and length of its bytes.
    """

    source: ClipSource
    name: str
    layout: int
    verify: bool
    payload: tuple[str, int, int] | None = None

    def __str__(self) -> str:  # how a failure names the task
        return f"clip {self.name!r}"


@dataclass(frozen=True)
class CodedClip:
    """:func:`code_clip`'s result: the clip chunk's prefix (rest flags, corrections) and the
    method's payload, and after verification its errors (``None`` without)."""

    prefix: bytes
    payload: bytes
    corrections: int
    errors: ClipErrors | None


def _prepared(task: ClipTask, models: SharedModels) -> PreparedLibrary:
    """The task's clip read and prepared alone, with every layout (its index stays valid)."""
    motion = read_clip(task.source, models.read).motion
    if motion.name != task.name:
        motion = motion.renamed(task.name)
    info = models.layouts[task.layout]
    X, at_rest = to_channels(motion, info.layout, info.reference)
    clip = PreparedClip(motion, task.layout, X, at_rest, forward_kinematics(motion))
    members = [[0] if k == task.layout else [] for k in range(len(models.layouts))]
    return PreparedLibrary(models.layouts, [clip], members, models.vertices)


def code_clip(task: ClipTask, models: SharedModels) -> CodedClip:
    """Read one clip, encode it (unless its payload is given), then decode it from its bytes,
    measure it and correct the frames over the bound: the per-clip job of
    :func:`build_library` and :func:`add_to_library`, run by :mod:`quatmotion.parallel` with
    ``models`` as the batch's context."""
    library = _prepared(task, models)
    method = models.method
    if task.payload is None:
        options = CodingOptions(models.quality, models.max_error)
        payload = method.encode_clip(library, 0, models.models[task.layout], options)
    else:
        spool, offset, length = task.payload
        with open(spool, "rb") as file:
            file.seek(offset)
            payload = file.read(length)
    fix, errors = Corrections.empty(), None
    if task.verify:
        max_error = models.max_error
        fix, errors = verify_clip(
            method, library, 0, payload, models.decoder_models[task.layout], max_error
        )
    clip = library.clips[0]
    prefix = write_clip_prefix(clip.at_rest, fix, clip.motion.n_frames)
    return CodedClip(prefix, payload, len(fix), errors)


def clip_tasks(inputs: Inputs, plan: Plan, *, verify: bool) -> list[ClipTask]:
    return [
        ClipTask(source, scan.name, k, verify)
        for source, scan, k in zip(inputs.sources, inputs.scans, plan.layout_of, strict=True)
    ]
