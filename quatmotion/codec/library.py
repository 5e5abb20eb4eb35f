"""A collection prepared for encoding, and the per-layout information every method shares.

Conventions
-----------
* Clips whose skeletons share a structure (:func:`~quatmotion.codec.channels.layout_key`) share
  one **layout**: joint kinds, reference pose and channel weights, stored once in the file
  (the common part of an ``L`` chunk, :meth:`LayoutInfo.to_bytes`).
* The file stores per layout the joint kinds (one byte each), the reference pose (rotation
  vectors in steps of 1/40 rad, int8: it only centres the channels) and the lever arms
  (unsigned bytes on a quarter-octave grid, ``2 ** ((code - 128) / 4)`` cm per unit). The
  metric weights are the encoder's (methods store what their decoders need).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from quatmotion.codec.binary import Reader, Writer
from quatmotion.codec.channels import (
    ChannelLayout,
    default_kinds,
    dequantize_reference,
    from_channels,
    layout_key,
    make_layout,
    measure_weights,
    quantize_reference,
    reference_pose,
    to_channels,
)
from quatmotion.codec.metrics import VIRTUAL_VERTEX_CM
from quatmotion.errors import FormatError
from quatmotion.motion import Motion, Skeleton, WorldTransforms, forward_kinematics

__all__ = [
    "LayoutInfo",
    "PreparedClip",
    "PreparedLibrary",
    "decode_log2",
    "encode_log2",
    "prepare_library",
]


def encode_log2(values: NDArray[np.float64]) -> NDArray[np.uint8]:
    """Positive values as bytes on a quarter-octave grid (``2 ** ((code - 128) / 4)``)."""
    v = np.log2(np.maximum(np.asarray(values, dtype=np.float64), 2.0**-32))
    return np.clip(np.round(4 * v) + 128, 0, 255).astype(np.uint8)


def decode_log2(codes: NDArray[np.uint8]) -> NDArray[np.float64]:
    """Inverse of :func:`encode_log2`."""
    return 2.0 ** ((np.asarray(codes, dtype=np.float64) - 128) / 4)


@dataclass(frozen=True, eq=False)
class LayoutInfo:
    """Shared by all clips of one skeleton structure: channels, reference pose, weights.

    Attributes
    ----------
    skeleton : Skeleton
        A skeleton of this structure (the first one seen).
    layout : ChannelLayout
    reference : ndarray, shape (J, 4)
        Quantised reference pose.
    weights : ndarray, shape (C,), or None
        Metric weights (cm^2 per unit^2), quantised; ``None`` when read from a file.
    lever : ndarray, shape (C,)
        Lever arms (cm per unit), quantised.
    """

    skeleton: Skeleton
    layout: ChannelLayout
    reference: NDArray[np.float64]
    weights: NDArray[np.float64] | None
    lever: NDArray[np.float64]

    @property
    def n_points(self) -> int:
        return self.skeleton.n_joints + self.skeleton.n_sites

    def to_bytes(self) -> bytes:
        J = self.skeleton.n_joints
        w = Writer()
        w.array(self.layout.kinds, "<u1")
        w.array(quantize_reference(self.reference).reshape(J * 3), "<i1")
        w.array(encode_log2(self.lever), "<u1")
        return w.bytes()

    @classmethod
    def read(cls, r: Reader, skeleton: Skeleton) -> LayoutInfo:
        J = skeleton.n_joints
        kinds = r.array(J, "<u1").astype(np.int64)
        try:
            layout = make_layout(skeleton, kinds)
        except ValueError as error:
            raise FormatError(f"library: joint kinds do not fit the skeleton ({error})") from None
        reference = dequantize_reference(r.array(J * 3, "<i1").reshape(J, 3))
        lever = decode_log2(r.array(layout.n_channels, "<u1"))
        return cls(skeleton, layout, reference, None, lever)


@dataclass(eq=False)
class PreparedClip:
    """One clip ready for encoding: its channels and the original's world transforms."""

    motion: Motion
    layout: int
    channels: NDArray[np.float64]
    at_rest: NDArray[np.bool_]
    world: WorldTransforms
    source_bytes: int = 0
    source_format: str = ""

    @property
    def positions(self) -> NDArray[np.float64]:
        return self.world.all_positions()


@dataclass(eq=False)
class PreparedLibrary:
    """Clips grouped by layout."""

    layouts: list[LayoutInfo]
    clips: list[PreparedClip]
    members: list[list[int]] = field(default_factory=list)
    vertices: bool = False
    """Whether the error bound also covers the virtual vertices (joint orientations)."""

    def motion_of(self, i: int, X: NDArray[np.float64]) -> Motion:
        """Clip ``i``'s decoded motion from channels ``X``."""
        clip = self.clips[i]
        info = self.layouts[clip.layout]
        m = clip.motion
        return from_channels(
            X, m.skeleton, info.layout, info.reference, clip.at_rest, m.fps, m.name
        )


def _quantised(values: NDArray[np.float64]) -> NDArray[np.float64]:
    return decode_log2(encode_log2(values))


def prepare_library(
    motions: list[Motion],
    sources: list[tuple[int, str]] | None = None,
    layouts: list[LayoutInfo] | None = None,
    *,
    vertices: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> PreparedLibrary:
    """Group clips by skeleton structure, fit each layout, and compute every clip's channels.

    Parameters
    ----------
    motions : list of Motion
    sources : list of (bytes, format), optional
        The size and format (``"amc"``, ``"bvh"``) of each clip's source file.
    layouts : list of LayoutInfo, optional
        Layouts that already exist (appending to a library): clips of their structure use them
        unchanged; other structures get new layouts after them.
    vertices : bool
        The bound covers the virtual vertices: every rotation channel's lever arm is at least
        their 3 cm (a twist about a bone moves no joint but turns the vertices).
    progress : callable, optional
        Called as ``progress(done, total)`` while the clips' channels are computed.
    """
    existing = list(layouts or [])
    keys = [layout_key(info.skeleton) for info in existing]
    groups: dict[tuple, list[int]] = {}
    for i, m in enumerate(motions):
        groups.setdefault(layout_key(m.skeleton), []).append(i)
    for key, idx in groups.items():
        if key in keys:
            continue
        group = [motions[i] for i in idx]
        sk = group[0].skeleton
        layout = make_layout(sk, default_kinds(sk, group))
        reference = reference_pose(group, layout)
        weights, lever = measure_weights(group, layout, reference)
        if vertices:
            rotation = np.ones(layout.n_channels, dtype=bool)
            rotation[:3] = False
            for k in range(len(layout.translation_joints)):
                rotation[layout.translation_columns(k)] = False
            lever = np.where(rotation, np.maximum(lever, VIRTUAL_VERTEX_CM), lever)
            weights = np.where(rotation, np.maximum(weights, VIRTUAL_VERTEX_CM**2), weights)
        existing.append(LayoutInfo(sk, layout, reference, _quantised(weights), _quantised(lever)))
        keys.append(key)
    clips = []
    members: list[list[int]] = [[] for _ in existing]
    layout_of = {key: k for k, key in reversed(list(enumerate(keys)))}  # first layout wins
    for i, m in enumerate(motions):
        k = layout_of[layout_key(m.skeleton)]
        info = existing[k]
        X, at_rest = to_channels(m, info.layout, info.reference)
        size, fmt = sources[i] if sources else (0, "")
        clips.append(PreparedClip(m, k, X, at_rest, forward_kinematics(m), size, fmt))
        members[k].append(i)
        if progress is not None and (i + 1 == len(motions) or (i + 1) % 16 == 0):
            progress(i + 1, len(motions))
    return PreparedLibrary(existing, clips, members, vertices)
