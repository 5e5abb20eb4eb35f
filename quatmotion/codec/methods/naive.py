"""The naive baseline, exactly as issue 10 states it: the floor every codec is measured against.

Every ``s``-th frame (and the last) of every file channel: Euler angles in degrees as the
file's dofs define them, unwrapped over time; translations in centimetres. One uniform
quantiser step for all of them, differences along time, ``lzma`` (raw LZMA2, preset 9e) per
clip. Decoded by cubic interpolation (SciPy's ``CubicSpline``, not-a-knot) between the kept
frames. Where Euler angles flip (gimbal) the interpolation cuts across: ARMS hides it, the
max error shows it.

``quality`` is the step (degrees, or cm); the frame stride follows it,
``s = clip(round(16 sqrt(step)), 4, 32)`` (the measured frontier of good pairs on CMU walks).
"""

from __future__ import annotations

import lzma
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import CubicSpline

from quatmotion.codec.binary import Reader, Writer
from quatmotion.codec.channels import (
    KIND_EULER,
    euler_kinds,
    from_channels,
    make_layout,
    to_channels,
)
from quatmotion.codec.library import LayoutInfo, PreparedLibrary
from quatmotion.codec.methods._base import ClipContext, CodingOptions, Method
from quatmotion.errors import FormatError
from quatmotion.quat import identity

__all__ = ["NaiveMethod"]

_FILTERS = [{"id": lzma.FILTER_LZMA2, "preset": 9 | lzma.PRESET_EXTREME}]


def stride_for(step: float) -> int:
    return int(np.clip(np.round(16.0 * np.sqrt(step)), 4, 32))


def _file_layout(info: LayoutInfo):
    layout = make_layout(info.skeleton, euler_kinds(info.skeleton))
    unit = np.ones(layout.n_channels)
    for j, kind in enumerate(layout.kinds):
        if kind == KIND_EULER:
            unit[layout.starts[j] : layout.starts[j] + layout.counts[j]] = 180.0 / np.pi
    return layout, unit


def _kept(T: int, stride: int) -> NDArray[np.int64]:
    return np.unique(np.r_[np.arange(0, T, stride), T - 1])


class NaiveMethod(Method):
    name = "naive"
    default_quality = 0.8

    def fit_layout(
        self, library: PreparedLibrary, k: int, members: list[int], options: CodingOptions
    ) -> Any:
        return None  # nothing shared: every clip stands alone

    def model_bytes(self, model: Any, layout: LayoutInfo) -> bytes:
        return b""

    def encode_clip(
        self, library: PreparedLibrary, i: int, model: Any, options: CodingOptions
    ) -> bytes:
        step = float(options.quality)
        stride = stride_for(step)
        clip = library.clips[i]
        layout, unit = _file_layout(library.layouts[clip.layout])
        sk = clip.motion.skeleton
        values, _ = to_channels(clip.motion, layout, identity((sk.n_joints,)))
        kept = _kept(len(values), stride)
        q = np.round(values[kept] * unit / step).astype(np.int64)
        deltas = np.diff(q, axis=0, prepend=0)
        if np.abs(deltas).max(initial=0) >= 2**31:
            raise ValueError(f"clip {clip.motion.name!r}: values too large for the naive codec")
        packed = lzma.compress(
            deltas.T.astype("<i4").tobytes(), format=lzma.FORMAT_RAW, filters=_FILTERS
        )
        return Writer().u8(stride).f32(step).raw(packed).bytes()

    def load_model(self, data: bytes, layout: LayoutInfo) -> Any:
        return _file_layout(layout)

    def decode(self, model: Any, payload: bytes, context: ClipContext) -> NDArray[np.float64]:
        layout, unit = model
        info = context.layout
        r = Reader(payload, what="naive clip")
        stride = r.u8()
        step = r.f32()
        if stride < 1 or not (np.isfinite(step) and step > 0):
            raise FormatError("naive clip: invalid stride or step")
        T = context.n_frames
        kept = _kept(T, stride)
        C = layout.n_channels
        expected = 4 * C * len(kept)  # never more is inflated: a bomb stops here
        try:
            inflater = lzma.LZMADecompressor(format=lzma.FORMAT_RAW, filters=_FILTERS)
            raw = inflater.decompress(r.take(r.remaining), max_length=expected + 1)
        except lzma.LZMAError as error:
            raise FormatError(f"naive clip: corrupt lzma stream ({error})") from None
        if len(raw) != expected or not inflater.eof:
            raise FormatError("naive clip: stream size does not match the clip")
        deltas = np.frombuffer(raw, dtype="<i4").reshape(C, len(kept)).T.astype(np.int64)
        values = np.cumsum(deltas, axis=0) * step / unit
        frames = np.arange(T, dtype=np.float64)
        if len(kept) >= 2:
            values = CubicSpline(kept, values, axis=0)(frames)
        else:
            values = np.repeat(values, T, axis=0)
        at_rest = np.zeros(len(layout.translation_joints), dtype=bool)
        for k in range(len(layout.translation_joints)):
            at_rest[k] = not context.active[info.layout.translation_columns(k)].any()
        sk = context.skeleton
        motion = from_channels(values, sk, layout, identity((sk.n_joints,)), at_rest, context.fps)
        X, _ = to_channels(motion, info.layout, info.reference)
        return X
