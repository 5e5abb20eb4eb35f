"""Sparse per-frame corrections that bring every frame within the error bound, for any method.

Conventions
-----------
* A correction adds ``value * quantum / lever_c`` to channel ``c`` of one frame (``lever_c``, the
  layout's stored lever arm in cm per unit, at least 1, so ``quantum`` is in centimetres of
  largest point displacement). ``quantum`` is ``bound / 32`` (a corrected channel is left
  about ``bound / 64`` of displacement from the original), quartered for the whole clip while
  some frame still misses the bound with every channel corrected.
* Per failing frame the channels are corrected greedily in order of ``|x - x_hat| lever`` (4,
  then 8, 16, ... channels) until forward kinematics of that frame meets ``0.98 bound``.
* Stored in each clip chunk's shared prefix (:func:`write_clip_prefix`): from format 3 the
  clip's frame count (checked against the header's), then a bitmask of the translation
  joints at rest, the correction count, then ``quantum`` (f32) and each correction
  as (frame delta, channel, value) varints.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quatmotion.codec.binary import Reader, Writer
from quatmotion.codec.channels import from_channels
from quatmotion.codec.library import LayoutInfo
from quatmotion.codec.metrics import frame_errors
from quatmotion.errors import FormatError
from quatmotion.motion import Skeleton, WorldTransforms

__all__ = [
    "Corrections",
    "check_frames",
    "correction_lever",
    "find_corrections",
    "read_clip_prefix",
    "write_clip_prefix",
]

_QUANTA_PER_BOUND = 32.0


@dataclass(frozen=True)
class Corrections:
    """``(frame, channel, value)`` triples and their quantum (cm)."""

    quantum: float
    frames: NDArray[np.int64]
    channels: NDArray[np.int64]
    values: NDArray[np.int64]

    @classmethod
    def empty(cls) -> Corrections:
        z = np.zeros(0, dtype=np.int64)
        return cls(0.0, z, z, z)

    def __len__(self) -> int:
        return len(self.frames)

    def apply(self, X: NDArray[np.float64], lever: NDArray[np.float64]) -> None:
        """Add the corrections to channels ``X`` ``(T, C)`` in place."""
        if len(self):
            np.add.at(
                X, (self.frames, self.channels), self.values * self.quantum / lever[self.channels]
            )


def correction_lever(info: LayoutInfo) -> NDArray[np.float64]:
    """The lever arms corrections are scaled by: the layout's, at least 1 cm per unit.

    A stored lever arm is a mean over frames; a channel that moves nothing in most frames
    (a rotation vector component that is a twist about the bone in most poses) can still move
    a point in a few, and a floor keeps its corrections from rounding to zero there.
    """
    return np.maximum(info.lever, 1.0)


def find_corrections(
    X: NDArray[np.float64],
    X_hat: NDArray[np.float64],
    world: WorldTransforms,
    skeleton: Skeleton,
    info: LayoutInfo,
    at_rest: NDArray[np.bool_],
    active: NDArray[np.bool_],
    bound: float,
    vertices: bool = False,
) -> Corrections:
    """Corrections that bring every frame of ``X_hat`` within ``bound`` of ``positions``.

    Parameters
    ----------
    X, X_hat : ndarray, shape (T, C)
        Original and decoded channels.
    world : WorldTransforms
        The original's forward kinematics.
    skeleton, info, at_rest, active
        The clip's skeleton, layout, translation-at-rest flags and coded channels.
    bound : float
        Centimetres.
    vertices : bool
        Bound the virtual vertices too (:func:`~quatmotion.codec.metrics.frame_errors`).
    """
    layout, ref = info.layout, info.reference

    def errors_of(rows: NDArray[np.float64], frames: slice) -> NDArray[np.float64]:
        m = from_channels(rows, skeleton, layout, ref, at_rest, 1.0)
        part = WorldTransforms(
            world.positions[frames], world.rotations[frames], world.site_positions[frames]
        )
        return frame_errors(part, m, vertices=vertices)

    err = errors_of(X_hat, slice(None))
    bad = np.flatnonzero(err > bound)
    if len(bad) == 0:
        return Corrections.empty()
    lever = correction_lever(info)
    quantum = bound / _QUANTA_PER_BOUND
    # A frame whose every channel is corrected can still miss the bound when the stored lever
    # arms (means over frames) understate that frame's: then the whole clip's quantum is
    # quartered and the corrections found again, until every frame passes.
    for _ in range(12):
        frames, channels, values = [], [], []
        missed = False
        for f in bad:
            r = (X[f] - X_hat[f]) * active
            order = np.argsort(-np.abs(r) * lever, kind="stable")
            n = 2
            while True:
                n = min(2 * n, len(order))
                sel = order[:n]
                v = np.round(r[sel] * lever[sel] / quantum).astype(np.int64)
                row = X_hat[f].copy()
                row[sel] += v * quantum / lever[sel]
                error = errors_of(row[None], slice(f, f + 1))[0]
                if error <= 0.98 * bound or n == len(order):
                    missed = missed or error > bound
                    break
            keep = v != 0
            frames += [int(f)] * int(keep.sum())
            channels += sel[keep].tolist()
            values += v[keep].tolist()
        if not missed:
            break
        quantum /= 4.0
    return Corrections(
        quantum,
        np.asarray(frames, dtype=np.int64),
        np.asarray(channels, dtype=np.int64),
        np.asarray(values, dtype=np.int64),
    )


def check_frames(stored: int, n_frames: int) -> None:
    """Refuse a clip chunk whose frame count is not its header entry's."""
    if stored != n_frames:
        raise FormatError(f"its chunk holds {stored} frames, its header entry {n_frames}")


def write_clip_prefix(at_rest: NDArray[np.bool_], corrections: Corrections, n_frames: int) -> bytes:
    """The shared start of a clip chunk (format 3): frame count, rest flags, corrections."""
    w = Writer().uvarint(n_frames)
    w.raw(np.packbits(np.asarray(at_rest, dtype=bool), bitorder="little").tobytes())
    w.uvarint(len(corrections))
    if len(corrections):
        w.f32(corrections.quantum)
        prev = 0
        for f, c, v in zip(
            corrections.frames, corrections.channels, corrections.values, strict=True
        ):
            w.uvarint(int(f) - prev).uvarint(int(c)).svarint(int(v))
            prev = int(f)
    return w.bytes()


def read_clip_prefix(
    r: Reader, n_translation_joints: int, n_frames: int, n_channels: int, version: int
) -> tuple[NDArray[np.bool_], Corrections]:
    """Inverse of :func:`write_clip_prefix` in format ``version`` (before 3: no frame
    count); checks every index, and the frame count against the header's ``n_frames``."""
    if version >= 3:
        check_frames(r.uvarint(), n_frames)
    flags = np.frombuffer(r.take((n_translation_joints + 7) // 8), dtype=np.uint8)
    at_rest = np.unpackbits(flags, bitorder="little")[:n_translation_joints].astype(bool)
    n = r.uvarint(n_frames * max(n_channels, 1))
    if n == 0:
        return at_rest, Corrections.empty()
    quantum = r.f32()
    if not (np.isfinite(quantum) and quantum > 0):
        raise FormatError("clip: invalid correction quantum")
    triples = r.uvarints(3 * n).reshape(n, 3)
    deltas, channel, zigzag = triples[:, 0], triples[:, 1], triples[:, 2]
    if deltas.max() > n_frames or channel.max() > n_channels - 1:
        raise FormatError("clip: a correction's frame or channel is out of range")
    frames = np.cumsum(deltas.astype(np.int64))
    channels = channel.astype(np.int64)
    half = (zigzag >> np.uint64(1)).astype(np.int64)
    values = np.where(zigzag & np.uint64(1), -half - 1, half)
    f = int(frames[-1])
    if f >= n_frames:
        raise FormatError("clip: a correction lies beyond the last frame")
    return at_rest, Corrections(quantum, frames, channels, values)
