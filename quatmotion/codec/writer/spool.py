"""Step 4c, spooling: one pass of the library at one quality (:class:`Job`: fit, then code every
clip in a worker), the clips' chunks spooled to a temporary file in clip order
(:class:`Coded`) so that the caller never holds them all.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

from quatmotion.codec.methods import Method
from quatmotion.codec.metrics import ClipErrors
from quatmotion.codec.settings import CompressSettings
from quatmotion.codec.writer.code import CodedClip, clip_tasks, code_clip
from quatmotion.codec.writer.fit import SharedModels, fit_shared_models
from quatmotion.codec.writer.plan import Plan
from quatmotion.codec.writer.runner import StepRunner
from quatmotion.codec.writer.scan import Inputs


@dataclass
class Coded:
    """A library coded at one quality: the clips' chunks spooled to a temporary file (prefix
    then payload, in clip order), the models, and after verification every clip's errors."""

    models: SharedModels
    blobs: list[bytes]
    spool: Any  # a named temporary file
    spans: list[tuple[int, int, int]] = field(default_factory=list)  # offset, prefix, payload
    corrections: list[int] = field(default_factory=list)
    errors: list[ClipErrors] = field(default_factory=list)

    @property
    def chunk_sizes(self) -> list[int]:
        return [p + n for _, p, n in self.spans]

    def payload_ref(self, i: int) -> tuple[str, int, int]:
        offset, prefix, length = self.spans[i]
        return self.spool.name, offset + prefix, length

    def chunks(self) -> Iterator[bytes]:
        """Every clip's chunk payload, read back from the spool in order."""
        self.spool.flush()
        with open(self.spool.name, "rb") as file:
            for offset, prefix, length in self.spans:
                file.seek(offset)
                yield file.read(prefix + length)

    def close(self) -> None:
        self.spool.close()


def spool_clips(models: SharedModels, blobs: list[bytes], coded: Iterable[CodedClip]) -> Coded:
    import tempfile

    from quatmotion.parallel import scratch

    out = Coded(models, blobs, tempfile.NamedTemporaryFile(prefix=scratch.prefix("spool")))  # noqa: SIM115 (closed by Coded.close)
    try:
        offset = 0
        for clip in coded:
            out.spool.write(clip.prefix)
            out.spool.write(clip.payload)
            out.spans.append((offset, len(clip.prefix), len(clip.payload)))
            offset += len(clip.prefix) + len(clip.payload)
            out.corrections.append(clip.corrections)
            if clip.errors is not None:
                out.errors.append(clip.errors)
        out.spool.flush()
    except BaseException:
        out.close()
        raise
    return out


@dataclass
class Job:
    """One build or add: the method, the clips planned, where their jobs run."""

    method: Method
    inputs: Inputs
    plan: Plan
    settings: CompressSettings
    runner: StepRunner

    def encode(self, quality: float, max_error: float | None, *, verify: bool) -> Coded:
        """Learn the shared models on the sample, then code every clip in a worker."""
        self.runner.report("learn", 0, 1)
        models, blobs = fit_shared_models(
            self.method, self.plan, quality, max_error, self.settings.seed, self.settings.read
        )
        tasks = clip_tasks(self.inputs, self.plan, verify=verify)
        return spool_clips(models, blobs, self.runner.each("encode", code_clip, tasks, models))

    def verify(self, coded: Coded, max_error: float | None) -> Coded:
        """Decode, measure and repair every clip of a library coded without verification."""
        from dataclasses import replace

        models = replace(coded.models, quality=0.0, max_error=max_error)
        tasks = [
            replace(task, payload=coded.payload_ref(i))
            for i, task in enumerate(clip_tasks(self.inputs, self.plan, verify=True))
        ]
        try:
            return spool_clips(
                models, coded.blobs, self.runner.each("verify", code_clip, tasks, models)
            )
        finally:
            coded.close()
