"""Frame data for the viewer: a clip's joint positions over time, compact, as a JSON payload.

Conventions
-----------
* A clip's *points* are its joints then its end sites, in the order of
  :meth:`quatmotion.motion.WorldTransforms.all_positions`: ``P = J + S`` points, centimetres,
  Y up. Frames count from 0.
* A payload is a JSON-ready ``dict`` (format ``quatmotion-frames/1``) that ``viewer.js``
  decodes (``QuatmotionViewer.decodeClip``) and :func:`decode_clip` decodes in Python. The
  standalone page embeds payloads; a web server returns the same ``dict`` from its API.
* Arrays travel as *blocks*: a 2-D array ``(T, C)`` compressed with zlib (deflate, which
  browsers inflate natively with ``DecompressionStream``), then base64.

  - ``float32-planes``: float32 little-endian, its four byte planes one after another (the
    high bytes of neighbouring values repeat, so deflate finds them).
  - ``uint16-delta-planes``: values quantised to ``offset + step * k`` with ``k`` a uint16;
    ``offset`` and ``step`` have ``L`` entries applying to columns ``c % L``. Stored as the
    frame-to-frame differences of ``k`` modulo 2**16, low-byte plane then high-byte plane.
    Decoding error at most ``step / 2`` per value.
* Positions are the root trajectory (float32, ``(T, 3)``) plus every point relative to the
  root (``uint16-delta-planes``, one offset and step per axis over the clip). Relative
  coordinates span a body's size whatever distance the clip travels, so the step stays a few
  thousandths of a centimetre for a person. Every payload states its bound,
  ``max_quantisation_cm``.
* Framing (:mod:`quatmotion.viz.framing`): ``bones`` lists the bones drawn, ``follow`` the
  point the viewer follows and frames (the body's centre), ``hidden`` the points not drawn (a
  root the body leaves behind). Positions and errors still cover every point.
* Why not float32 throughout: four bytes per coordinate, then base64, would fill the 6 MB
  budget of a 10,000-frame page with frame data alone; quantised frame deltas under deflate
  take a fraction of that (docs/performance.md).
"""

from __future__ import annotations

import base64
import zlib
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quatmotion.motion import Motion, forward_kinematics
from quatmotion.viz.framing import BodyFraming, body_framing, skeleton_bones

__all__ = [
    "FORMAT",
    "clip_points",
    "comparison_obstacle",
    "decode_block",
    "decode_clip",
    "encode_clip",
    "encode_comparison",
    "encode_float32",
    "encode_uint16",
    "point_errors",
]

FORMAT = "quatmotion-frames/1"
_UINT16_LEVELS = 65535
ERROR_STEP_CM = 0.001
"""Finest step of shipped point errors, cm: the viewer prints them to 0.01 cm, and coarser
levels compress better (ARMS and the maximum are computed before quantising)."""
_ZLIB_LEVEL = 6  # level 9 barely shrinks mocap deltas further, at many times the time


def encode_float32(values: NDArray[np.floating]) -> dict[str, Any]:
    """A ``float32-planes`` block of ``values``, shape ``(T, C)``."""
    array = np.ascontiguousarray(values, dtype="<f4")
    if array.ndim != 2:
        raise ValueError(f"values has shape {array.shape}, expected (T, C)")
    planes = array.view(np.uint8).reshape(-1, 4).T
    return {
        "encoding": "float32-planes",
        "shape": list(array.shape),
        "data": _pack(planes.tobytes()),
    }


def encode_uint16(
    values: NDArray[np.floating], groups: int = 1, *, min_step: float = 0.0
) -> dict[str, Any]:
    """A ``uint16-delta-planes`` block of ``values``, shape ``(T, C)``.

    Columns ``c % groups`` share an offset and a step: their minimum and
    ``(max - min) / 65535``, or ``min_step`` if larger (a coarser step compresses better where
    the finest one is not needed). ``C`` must be a multiple of ``groups``.
    """
    array = np.asarray(values, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] % groups:
        raise ValueError(
            f"values has shape {array.shape}, expected (T, C), C a multiple of {groups}"
        )
    if not np.all(np.isfinite(array)):
        raise ValueError("values must be finite")
    T, C = array.shape
    grouped = array.reshape(T, C // groups, groups)
    if T:
        offset = grouped.min(axis=(0, 1))
        span = grouped.max(axis=(0, 1)) - offset
    else:
        offset = span = np.zeros(groups)
    # A constant group still needs a positive step for the decoder's multiply.
    step = np.where(span > 0, np.maximum(span / _UINT16_LEVELS, min_step), 1.0)
    levels = np.rint((grouped - offset) / step).astype(np.uint16).reshape(T, C)
    deltas = np.diff(levels, axis=0, prepend=np.zeros((1, C), np.uint16))  # wraps mod 2**16
    planes = deltas.astype("<u2").view(np.uint8).reshape(-1, 2).T
    return {
        "encoding": "uint16-delta-planes",
        "shape": [T, C],
        "offset": offset.tolist(),
        "step": step.tolist(),
        "data": _pack(planes.tobytes()),
    }


def decode_block(block: dict[str, Any]) -> NDArray[np.float64]:
    """The ``(T, C)`` array of a block (float64): the reference decoder, for tests and tools.

    Raises ``ValueError`` saying which field is wrong when the block is malformed.
    """
    try:
        encoding = block["encoding"]
        T, C = (int(n) for n in block["shape"])
        raw = np.frombuffer(zlib.decompress(base64.b64decode(block["data"])), dtype=np.uint8)
    except (KeyError, TypeError, ValueError, zlib.error) as error:
        raise ValueError(f"malformed frame-data block: {error!r}") from None
    width = {"float32-planes": 4, "uint16-delta-planes": 2}.get(encoding)
    if width is None:
        raise ValueError(f"unknown block encoding {encoding!r}")
    if raw.size != width * T * C:
        raise ValueError(f"{encoding} block of shape ({T}, {C}) holds {raw.size} bytes")
    if encoding == "float32-planes":
        return raw.reshape(4, T * C).T.copy().view("<f4").reshape(T, C).astype(np.float64)
    deltas = raw.reshape(2, T * C).T.copy().view("<u2").reshape(T, C)
    levels = np.cumsum(deltas, axis=0, dtype=np.uint16)  # the wrap undoes the encoder's
    offset = np.asarray(block.get("offset"), dtype=np.float64).ravel()
    step = np.asarray(block.get("step"), dtype=np.float64).ravel()
    L = offset.size
    if L == 0 or step.size != L or C % L:
        raise ValueError(f"block offset/step of length {L}/{step.size} do not divide {C} columns")
    return (offset + step * levels.reshape(T, C // L, L)).reshape(T, C)


def clip_points(motion: Motion) -> tuple[NDArray[np.float64], list[str], list[list[int]]]:
    """Positions ``(T, P, 3)`` cm of every joint and end site, their names, and the bones.

    A bone is a pair of point indices ``[parent, child]``: one per non-root joint and one per
    end site.
    """
    sk = motion.skeleton
    positions = forward_kinematics(motion).all_positions()
    names = [*sk.joint_names, *sk.site_names]
    return positions, names, [list(b) for b in skeleton_bones(sk)]


def encode_clip(motion: Motion, name: str | None = None) -> dict[str, Any]:
    """The viewer payload of ``motion``: its points' positions over every frame, and which of
    them are the body (:func:`quatmotion.viz.framing.body_framing`).

    Parameters
    ----------
    motion : Motion
        ``T`` frames of ``J`` joints and ``S`` end sites.
    name : str, optional
        Label shown in the viewer (default ``motion.name``).

    Returns
    -------
    dict
        JSON-ready: ``format``, ``name``, ``fps``, ``n_frames``, ``point_names`` (``P``),
        ``n_joints``, ``bones`` (those drawn), ``follow`` (the point followed), ``hidden``
        (points not drawn), ``root`` (a ``(T, 3)`` block), ``relative`` (a ``(T, 3P)``
        block) and ``max_quantisation_cm``, the largest decoding error of a coordinate.
    """
    positions, names, _ = clip_points(motion)
    framing = body_framing(motion.skeleton, positions)
    return _payload(motion, positions, names, framing, name)


def _payload(
    motion: Motion,
    positions: NDArray[np.float64],
    names: Sequence[str],
    framing: BodyFraming,
    name: str | None,
) -> dict[str, Any]:
    T, P, _ = positions.shape
    root = positions[:, 0, :]
    root_block = encode_float32(root)
    relative = encode_uint16((positions - root[:, None, :]).reshape(T, P * 3), groups=3)
    root_error = float(np.max(np.abs(root - root.astype(np.float32)), initial=0.0))
    return {
        "format": FORMAT,
        "name": motion.name if name is None else name,
        "fps": motion.fps,
        "n_frames": T,
        "n_joints": motion.n_joints,
        "point_names": list(names),
        "bones": [list(b) for b in framing.bones],
        "follow": framing.centre,
        "hidden": list(framing.hidden),
        "root": root_block,
        "relative": relative,
        "max_quantisation_cm": root_error + max(relative["step"]) / 2,
    }


def decode_clip(payload: dict[str, Any]) -> NDArray[np.float64]:
    """Positions ``(T, P, 3)`` cm of a payload from :func:`encode_clip`."""
    if payload.get("format") != FORMAT:
        raise ValueError(f"not a {FORMAT} payload: format {payload.get('format')!r}")
    root = decode_block(payload["root"])
    relative = decode_block(payload["relative"])
    T = root.shape[0]
    return relative.reshape(T, -1, 3) + root[:, None, :]


def point_errors(positions: NDArray[np.float64], other: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distance ``(T, P)`` cm between corresponding points of two ``(T, P, 3)`` arrays."""
    if positions.shape != other.shape:
        raise ValueError(f"cannot compare positions {positions.shape} with {other.shape}")
    return np.linalg.norm(positions - other, axis=-1)


def comparison_obstacle(reference: Motion, compared: Motion) -> str | None:
    """Why no per-frame error can be shown between two clips (None when it can).

    A per-frame error pairs frame ``t`` of one clip with frame ``t`` of the other and point
    ``p`` with point ``p``: it needs the same skeleton (joint and end-site names and
    hierarchy), the same frame rate and the same frame count. Nothing here aligns two takes
    in time (resampling to one duration would pair frames that show different moments).
    """
    sa, sb = reference.skeleton, compared.skeleton
    same_names = (sa.joint_names, sa.site_names) == (sb.joint_names, sb.site_names)
    if not (
        same_names
        and np.array_equal(sa.parents, sb.parents)
        and np.array_equal(sa.site_parents, sb.site_parents)
    ):
        shape = f"{sa.n_joints} and {sb.n_joints} joints, {sa.n_sites} and {sb.n_sites} end sites"
        return f"their skeletons differ ({shape}{'' if same_names else ', other names'})"
    if reference.fps != compared.fps:
        return f"their frame rates differ ({reference.fps:g} and {compared.fps:g} fps)"
    if reference.n_frames != compared.n_frames:
        return (
            f"their lengths differ ({reference.n_frames} and {compared.n_frames} frames); "
            "a per-frame error needs the same skeleton and frame count"
        )
    return None


def encode_comparison(
    reference: Motion, compared: Motion, reference_name: str = "", compared_name: str = ""
) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any]]:
    """Payloads of two clips of one skeleton and the per-point error between them.

    The error of a point is the distance between its two positions, cm, over every joint and
    end site (docs/metrics.md: positions of the full skeleton); ``arms_cm`` is the paper's ARMS on
    them (Eq. 12: RMS over points per frame, mean over frames). Both payloads are framed as
    the reference is (:func:`quatmotion.viz.framing.body_framing`), so the two figures show
    the same points.

    Parameters
    ----------
    reference, compared : Motion
        ``T`` frames each, the same skeleton (joint and end-site names) and frame rate.
    reference_name, compared_name : str
        Labels (default: the clips' names).

    Returns
    -------
    (reference payload, compared payload, errors)
        ``errors`` holds ``block`` (``(T, P)`` cm, ``uint16-delta-planes``), ``arms_cm`` (mean
        over frames of the RMS over points), ``max_cm`` and ``max_quantisation_cm``.

    Raises
    ------
    ValueError
        When :func:`comparison_obstacle` finds one, saying which.
    """
    reason = comparison_obstacle(reference, compared)
    if reason:
        raise ValueError(f"cannot compare {compared.name!r} with {reference.name!r}: {reason}")
    a, names, _ = clip_points(reference)
    b, _, _ = clip_points(compared)
    framing = body_framing(reference.skeleton, a)
    errors = point_errors(a, b)
    block = encode_uint16(errors, min_step=ERROR_STEP_CM)
    summary = {
        "block": block,
        "arms_cm": float(np.mean(np.sqrt(np.mean(errors**2, axis=1)))) if errors.size else 0.0,
        "max_cm": float(errors.max(initial=0.0)),
        "max_quantisation_cm": block["step"][0] / 2,
    }
    return (
        _payload(reference, a, names, framing, reference_name or None),
        _payload(compared, b, names, framing, compared_name or None),
        summary,
    )


def _pack(data: bytes) -> str:
    return base64.b64encode(zlib.compress(data, _ZLIB_LEVEL)).decode("ascii")
