"""Verification: a clip decoded from its bytes, the frames over the bound corrected
(:mod:`~quatmotion.codec.repair`), its errors measured (:func:`verify_clip`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from quatmotion.codec.library import PreparedLibrary
from quatmotion.codec.methods import ClipContext, Method
from quatmotion.codec.metrics import ClipErrors, clip_errors
from quatmotion.codec.repair import (
    Corrections,
    correction_lever,
    find_corrections,
)


def _clip_context(library: PreparedLibrary, i: int) -> ClipContext:
    clip = library.clips[i]
    info = library.layouts[clip.layout]
    active = np.ones(info.layout.n_channels, dtype=bool)
    for k in range(len(info.layout.translation_joints)):
        if clip.at_rest[k]:
            active[info.layout.translation_columns(k)] = False
    return ClipContext(info, clip.motion.skeleton, clip.motion.n_frames, clip.motion.fps, active)


def verify_clip(
    method: Method,
    library: PreparedLibrary,
    i: int,
    payload: bytes,
    model: Any,
    max_error: float | None,
) -> tuple[Corrections, ClipErrors]:
    """Decode clip ``i`` from its bytes, correct the frames over the bound, measure it."""
    clip = library.clips[i]
    info = library.layouts[clip.layout]
    context = _clip_context(library, i)
    X = method.decode(model, payload, context)
    fix = Corrections.empty()
    if max_error is not None:
        fix = find_corrections(
            clip.channels,
            X,
            clip.world,
            clip.motion.skeleton,
            info,
            clip.at_rest,
            context.active,
            max_error,
            library.vertices,
        )
        fix.apply(X, correction_lever(info))
    return fix, clip_errors(clip.world, library.motion_of(i, X))
