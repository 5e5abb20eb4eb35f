"""Spline codecs: weighted channels, cubic B-splines over frames, prediction, range coding.

One coder, two configurations: ``best`` (the default) and ``spline`` (the issue's strong
simple baseline). What both do:

* **Channels** (:mod:`quatmotion.codec.channels`) scaled by a per-channel factor ``s_c``, so a
  unit step moves the body by about the same amount in every channel;
* **cubic B-splines** per segment (:mod:`quatmotion.codec.spline`), least-squares fit, knot
  spacing ``k`` frames chosen per clip; where the decoded clip misses the requested bound,
  knots are inserted in the middle of the knot intervals that hold the failing frames (the fit
  is "halved where it misses"), a few rounds;
* **uniform quantisation** of the coefficients with one step per clip (on a 1/8-octave grid),
  **prediction** along the rows, and **range coding** of the residuals with backward-adaptive
  Laplace models (:mod:`quatmotion.codec.entropy`);
* **per-clip rate control**: the smallest payload over a few (spacing, step) pairs whose
  decoded maximum joint error (forward kinematics of every frame) meets the bound.

What only ``best`` does (each measured in ``docs/performance.md``):

* ``s_c`` from the measured metric ``w_c + lever_c^2 / P`` (the mean squared displacement of all
  points plus the largest one spread over the ``P`` points: the max bound binds at the
  extremities) instead of the largest lever arm alone;
* order-2 linear prediction with coefficients fitted once per library (gait sampled at 5
  knots per cycle is far from linear, so a plain delta predicts poorly);
* the first row of each segment predicted from the library's mean, with its own scale;
* **hierarchical compensation** (encoder only): joints are coded parents first and each
  joint's target is the original global rotation seen from its decoded parent, so a parent's
  error is taken up by its children instead of adding up towards the hands and feet;
* **breaks** at glitches (a pose jumping far more than its neighbours), so the spline does not
  smear a 91 cm jump over a second of frames;
* the rotations relative to the library's reference pose (shared), not each clip's mean.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from quatmotion.codec import entropy, rans
from quatmotion.codec.binary import Reader, Writer
from quatmotion.codec.channels import joint_channels, joint_rotations
from quatmotion.codec.library import LayoutInfo, PreparedLibrary, decode_log2, encode_log2
from quatmotion.codec.methods._base import ClipContext, CodingOptions, Method
from quatmotion.codec.metrics import frame_errors
from quatmotion.codec.spline import (
    MIN_SPLINE_FRAMES,
    SplineBasis,
    evaluate_channels,
    fit_segments,
    knot_vector,
    n_rows,
    segment_bounds,
    segment_tables,
)
from quatmotion.errors import FormatError
from quatmotion.quat import conjugate, multiply

__all__ = ["GROUP_ROWS", "RowStreams", "SplineMethod", "SplineSettings", "detect_breaks"]

_STEP_GRID = 8  # steps per octave
_STEP_FLOOR = 2.0**-12
_LPC_UNIT = 64.0
_REFERENCE_FPS = 120.0
_MEAN_UNIT = 16.0
GROUP_ROWS = 64
"""Format 3: coefficient rows per group, the unit that decodes alone (prediction restarts
at each group's first row); the size each length costs is in docs/performance.md."""
_MAX_OFFSET = 255  # a clip's scale-code offsets, 1/8 octaves


def step_value(code: int) -> float:
    """The quantiser step (weighted cm) of a step code."""
    return _STEP_FLOOR * 2.0 ** (code / _STEP_GRID)


def step_code(step: float) -> int:
    return int(np.clip(np.round(_STEP_GRID * np.log2(max(step, 1e-12) / _STEP_FLOOR)), 0, 255))


@dataclass(frozen=True)
class SplineSettings:
    """One configuration of the spline coder (see the module docstring)."""

    scaling: str  # "metric" or "lever"
    predictor: str  # "lpc" or "delta"
    spacings: tuple[float, ...]
    """Knot spacings in frames at 120 fps (scaled to each clip's rate: 24 is 0.2 s)."""
    glitch_breaks: bool
    mean_start: bool
    refine_rounds: int = 6
    steps_tried: int = 5
    gamma: float = 1.0
    compensate: bool = False


# Knots every 0.2 s, or 0.27 s where that codes a clip smaller: the second spacing pays where
# tight bounds floor the first at few frames (30 fps libraries), for more encoding time; the
# gains and the cost per library are in docs/performance.md (0.4.0, "knot spacings of best").
BEST = SplineSettings(
    "metric", "lpc", (24.0, 32.0), True, True, steps_tried=3, gamma=8.0, compensate=True
)
BASELINE = SplineSettings("lever", "delta", (16.0, 24.0, 32.0), False, False)


def detect_breaks(positions: NDArray[np.float64], bound: float) -> list[int]:
    """Frames where the pose jumps far more than in the frames around: ``(T, N, 3) -> list``.

    A jump is the largest point displacement between consecutive frames. Frame ``t`` starts a
    new segment when its jump exceeds ``max(2 bound, 8 cm)`` and four times both neighbouring
    jumps.
    """
    if len(positions) < 3:
        return []
    jump = np.linalg.norm(np.diff(positions, axis=0), axis=2).max(axis=1)
    nb = np.maximum(np.r_[jump[1:], 0.0], np.r_[0.0, jump[:-1]])
    big = (jump > max(2.0 * bound, 8.0)) & (jump > 4.0 * nb)
    return [int(t) + 1 for t in np.flatnonzero(big)]


@dataclass(frozen=True)
class SplineModel:
    """A layout's model: channel scales, predictor, residual scales, start mean and scale."""

    scale: NDArray[np.float64]
    a1: NDArray[np.float64]
    a2: NDArray[np.float64]
    initial: NDArray[np.float64]
    start_mean: NDArray[np.float64]
    start_scale: NDArray[np.float64]

    def to_bytes(self) -> bytes:
        w = Writer()
        w.array(encode_log2(self.scale), "<u1")
        w.array(np.round(self.a1 * _LPC_UNIT), "<i1").array(np.round(self.a2 * _LPC_UNIT), "<i1")
        w.array(encode_log2(self.initial), "<u1").array(encode_log2(self.start_scale), "<u1")
        for v in np.round(self.start_mean * _MEAN_UNIT).astype(np.int64):
            w.svarint(int(v))
        return w.bytes()

    @classmethod
    def from_bytes(cls, data: bytes, C: int) -> SplineModel:
        r = Reader(data, what="spline model")
        scale = decode_log2(r.array(C, "<u1"))
        a1 = r.array(C, "<i1") / _LPC_UNIT
        a2 = r.array(C, "<i1") / _LPC_UNIT
        initial = decode_log2(r.array(C, "<u1"))
        start_scale = decode_log2(r.array(C, "<u1"))
        start_mean = np.array([r.svarint() for _ in range(C)], dtype=np.float64) / _MEAN_UNIT
        r.end()
        return cls(scale, a1, a2, initial, start_mean, start_scale)

    def quantised(self) -> SplineModel:
        """The model as the decoder will read it."""
        return SplineModel.from_bytes(self.to_bytes(), len(self.scale))


@dataclass(frozen=True)
class ClipPlan:
    """Per-clip choices: knot spacing, step, breaks, inserted knots per segment."""

    spacing: int
    step: int
    breaks: tuple[int, ...]
    inserted: dict[int, tuple[int, ...]]

    def to_bytes(self) -> bytes:
        w = Writer().u8(self.spacing).u8(self.step).uvarint(len(self.breaks))
        prev = 0
        for b in self.breaks:
            w.uvarint(b - prev)
            prev = b
        segments = len(self.breaks) + 1
        for s in range(segments):
            knots = self.inserted.get(s, ())
            w.uvarint(len(knots))
            prev = 0
            for k in knots:
                w.uvarint(k - prev)
                prev = k
        return w.bytes()

    @classmethod
    def read(cls, r: Reader, n_frames: int) -> ClipPlan:
        spacing = r.u8()
        step = r.u8()
        if spacing < 1:
            raise FormatError("clip: knot spacing 0")
        breaks = []
        pos = 0
        for _ in range(r.uvarint(n_frames)):
            pos += r.uvarint(n_frames)
            breaks.append(pos)
        if breaks and (breaks[-1] >= n_frames or len(set(breaks)) != len(breaks) or breaks[0] <= 0):
            raise FormatError("clip: segment breaks out of range")
        inserted = {}
        for s in range(len(breaks) + 1):
            deltas = r.uvarints(r.uvarint(n_frames))
            if len(deltas):
                if deltas.max() > n_frames:
                    raise FormatError(f"clip: an inserted knot exceeds {n_frames}")
                inserted[s] = tuple(int(k) for k in np.cumsum(deltas.astype(np.int64)))
        return cls(spacing, step, tuple(breaks), inserted)


def _segment_starts(n_frames: int, plan: ClipPlan) -> NDArray[np.bool_]:
    """Which coefficient rows start a segment."""
    flags = []
    for s, (a, b) in enumerate(segment_bounds(n_frames, plan.breaks)):
        L = b - a
        n = n_rows(L, plan.spacing, plan.inserted.get(s, ()))
        f = np.zeros(n, dtype=bool)
        f[0] = True
        flags.append(f)
    return np.concatenate(flags) if flags else np.zeros(0, dtype=bool)


def _residuals(
    Q: NDArray[np.int64], starts, model: SplineModel, step: float, cols
) -> NDArray[np.int64]:
    """Closed-loop prediction residuals of quantised rows ``Q`` ``(n, c)``."""
    R = Q.copy()
    mean = np.round(model.start_mean[cols] / step).astype(np.int64)
    a1, a2 = model.a1[cols], model.a2[cols]
    for i in range(len(Q)):
        if starts[i]:
            R[i] = Q[i] - mean
        elif i >= 2 and not starts[i - 1]:
            R[i] = Q[i] - np.round(a1 * Q[i - 1] + a2 * Q[i - 2]).astype(np.int64)
        else:
            R[i] = Q[i] - Q[i - 1]
    return R


@numba.njit(cache=True)
def _unpredict_kernel(R, starts, mean, a1, a2, step):  # pragma: no cover - compiled
    """Inverse of :func:`_residuals`, the rows ``Q`` returned as ``Q step`` (weighted units):
    ``(n, c)`` float."""
    n, c = R.shape
    Q = np.empty((n, c), dtype=np.int64)
    P = np.empty((n, c))
    for i in range(n):
        for k in range(c):
            if starts[i]:
                Q[i, k] = R[i, k] + mean[k]
            elif i >= 2 and not starts[i - 1]:
                Q[i, k] = R[i, k] + np.int64(np.round(a1[k] * Q[i - 1, k] + a2[k] * Q[i - 2, k]))
            else:
                Q[i, k] = R[i, k] + Q[i - 1, k]
            P[i, k] = Q[i, k] * step
    return P


# ---------------------------------------------------------------------------- format 3
def _row_starts(n_frames: int, plan: ClipPlan, group_rows: int) -> NDArray[np.bool_]:
    """Format 3's start rows: each spline segment's first row and each group's first row."""
    starts = _segment_starts(n_frames, plan)
    starts[::group_rows] = True
    return starts


def _scale_codes(model: SplineModel, cols, step: int) -> tuple:
    """The channels' rANS scale codes (1/8 octaves of symbol units) before the clip's offsets:
    the layout's ``initial`` and ``start_scale`` (quarter-octave bytes) over the clip's step
    (an eighth-octave code), ``2 byte - step - 160`` exactly."""
    key = (id(model), np.asarray(cols).tobytes())
    hit = _CODES.get(key)
    if hit is None or hit[0] is not model:
        main = 2 * encode_log2(model.initial[cols]).astype(np.int64) - 160
        start = 2 * encode_log2(model.start_scale[cols]).astype(np.int64) - 160
        if len(_CODES) > 256:
            _CODES.clear()
        hit = _CODES[key] = (model, main, start)
    return hit[1] - step, hit[2] - step


_CODES: dict[tuple, tuple] = {}


def _best_offsets(R, starts, main, start) -> tuple[int, int]:
    """The clip's offsets to the layout's scale codes (other rows, start rows) that code ``R``
    smallest: each by a coarse search, then its neighbours."""
    best = [0, 0]

    def size(o: list[int]) -> int:
        return rans.stream_bytes(R, starts, rans.model_of(main + o[0], start + o[1]))

    for which in (0, 1):
        for grid in (range(-32, 33, 8), range(-6, 7, 2), (-1, 1)):
            centre = best[which]
            trials = {}
            for d in grid:
                o = list(best)
                o[which] = centre + d if grid != range(-32, 33, 8) else d
                trials[o[which]] = size(o)
            best[which] = min(trials, key=lambda v: (trials[v], abs(v)))
    return best[0], best[1]


def encode_rows_v3(
    n_frames: int, plan: ClipPlan, Q: NDArray[np.int64], model: SplineModel, cols,
    group_rows: int = GROUP_ROWS,
) -> bytes:  # fmt: skip
    """A clip's format 3 payload from its plan and quantised coefficient rows ``Q`` ``(n, c)``
    (docs/format.md, *Clip payload, format 3*)."""
    step = step_value(plan.step)
    starts = _row_starts(n_frames, plan, group_rows)
    R = _residuals(Q, starts, model, step, cols)
    main, start = _scale_codes(model, cols, plan.step)
    o_main, o_start = _best_offsets(R, starts, main, start)
    coder = rans.model_of(main + o_main, start + o_start)
    streams = [
        rans.encode_rows(R[a : a + group_rows], starts[a : a + group_rows], coder)
        for a in range(0, len(R), group_rows)
    ]
    w = Writer().raw(plan.to_bytes())
    w.uvarint(group_rows).svarint(o_main).svarint(o_start)
    for stream in streams[:-1]:
        w.uvarint(len(stream))
    return w.bytes() + b"".join(streams)


@dataclass(frozen=True)
class RowStreams:
    """A format 3 clip payload parsed, its rows not yet decoded: what decoding any group of
    rows needs (:meth:`decode`). Rows ``[g G, (g + 1) G)`` are group ``g``; its stream is
    ``buf[ends[g] : ends[g + 1]]``."""

    plan: ClipPlan
    tables: Any  # quatmotion.codec.spline.SegmentTables
    group_rows: int
    buf: NDArray[np.uint8]
    ends: NDArray[np.int64]
    starts: NDArray[np.bool_]
    coder: rans.Model
    mean: NDArray[np.int64]
    a1: NDArray[np.float64]
    a2: NDArray[np.float64]
    step: float

    @property
    def n_groups(self) -> int:
        return len(self.ends) - 1

    def decode(self, P: NDArray[np.float64], first: int = 0, stop: int | None = None) -> None:
        """Groups ``first..stop - 1`` (all by default) into their rows of ``P`` ``(n, c)``,
        weighted units.

        Raises
        ------
        FormatError
            A group's stream is corrupt (its words or final state).
        """
        tab = rans.load_tables()
        stop = self.n_groups if stop is None else stop
        status = _rows_v3_kernel(
            self.buf, self.ends, self.group_rows, first, stop, self.starts, *self.coder.args(),
            tab.M, tab.dec, self.mean, self.a1, self.a2, self.step, P,
        )  # fmt: skip
        if status:
            raise FormatError(f"corrupt coefficient rows (group {status - 1})")


def read_rows_v3(model: SplineModel, payload: bytes, context: ClipContext) -> tuple:
    """A format 3 payload parsed: its :class:`RowStreams`, the ``c`` active channels and
    their scales (channel = weighted / scale).

    Raises
    ------
    FormatError
        The payload is malformed.
    """
    r = Reader(payload, what="clip")
    T = context.n_frames
    plan = ClipPlan.read(r, T)
    tables = segment_tables(T, plan.breaks, plan.spacing, plan.inserted)
    G = r.uvarint(1 << 30)
    if G < 1:
        raise FormatError("0 rows per group")
    o_main, o_start = r.svarint(), r.svarint()
    if max(abs(o_main), abs(o_start)) > _MAX_OFFSET:
        raise FormatError("a scale offset out of range")
    n_groups = -(-tables.n_rows // G)
    ends = [0] * (n_groups + 1)
    for g in range(1, n_groups):  # most clips are one group or a few
        ends[g] = ends[g - 1] + r.uvarint(r.remaining)
    body = r.take(r.remaining)
    ends[n_groups] = len(body)
    if any(ends[g + 1] - ends[g] < 4 for g in range(n_groups)):
        raise FormatError("a group's stream is shorter than its state or past the payload")
    starts = np.zeros(tables.n_rows, dtype=np.bool_)
    starts[tables.rows[tables.length > 0]] = True
    starts[::G] = True
    cols, a1, a2, scale, mean, coder = _clip_coder(model, context.active, plan.step, o_main,
                                                   o_start)  # fmt: skip
    buf = np.frombuffer(body, dtype=np.uint8)
    streams = RowStreams(plan, tables, G, buf, np.array(ends, dtype=np.int64), starts, coder,
                         mean, a1, a2, step_value(plan.step))  # fmt: skip
    return streams, cols, scale


_CODERS: dict[tuple, tuple] = {}


def _clip_coder(model: SplineModel, active, step: int, o_main: int, o_start: int) -> tuple:
    """What decoding a clip's rows needs from its layout's model, its step and offsets: the
    active channels, predictor, scales, start means in steps and the rANS model (cached: a
    library's clips share a few of these)."""
    key = (id(model), active.tobytes(), step, o_main, o_start)
    hit = _CODERS.get(key)
    if hit is not None and hit[0] is model:
        return hit[1]
    cols, _, _, a1, a2, scale, start_mean = _columns(model, active)
    main, start = _scale_codes(model, cols, step)
    mean = np.round(start_mean / step_value(step)).astype(np.int64)
    out = (cols, a1, a2, scale, mean, rans.model_of(main + o_main, start + o_start))
    if len(_CODERS) > 1024:
        _CODERS.clear()
    _CODERS[key] = (model, out)
    return out


@numba.njit(cache=True)
def _rows_v3_kernel(
    buf, ends, G, first, stop, starts, t_start, k_start, t_ctx, k_ctx, thr, M, dec, mean, a1,
    a2, step, P,
):  # pragma: no cover - compiled  # fmt: skip
    """Decode groups ``first..stop - 1`` (entropy, then prediction: each group's first row
    is a start row, so :func:`_unpredict_kernel` runs on it alone) into ``P``; 0, or ``1 + g``
    for a corrupt group ``g``."""
    n, c = P.shape
    R = np.empty((min(G, n), c), dtype=np.int64)
    for g in range(first, stop):
        a = g * G
        b = min(n, a + G)
        Rg = R[: b - a]
        status = rans.decode_span(buf, ends[g], ends[g + 1], Rg, 0, b - a, starts[a:b],
                                  t_start, k_start, t_ctx, k_ctx, thr, M, dec)  # fmt: skip
        if status:
            return 1 + g
        P[a:b] = _unpredict_kernel(Rg, starts[a:b], mean, a1, a2, step)
    return 0


class SplineMethod(Method):
    """The spline coder in one configuration."""

    default_quality = 2.0
    controls_bound = True

    def __init__(self, name: str, settings: SplineSettings):
        self.name = name
        self.settings = settings
        self.group_rows = GROUP_ROWS

    # ---------------------------------------------------------------------------- model
    def _channel_scale(self, info: LayoutInfo) -> NDArray[np.float64]:
        if self.settings.scaling == "lever":
            return np.maximum(info.lever, 1e-6)
        return np.sqrt(info.weights + self.settings.gamma * info.lever**2 / info.n_points)

    def _breaks(self, library: PreparedLibrary, i: int, bound: float | None) -> tuple[int, ...]:
        """Where clip ``i``'s spline breaks: at its glitches (``best``), else nowhere."""
        if not self.settings.glitch_breaks:
            return ()
        return tuple(detect_breaks(library.clips[i].positions, bound if bound else 5.0))

    def _fit_model(
        self,
        library: PreparedLibrary,
        k: int,
        members: list[int],
        bound: float | None,
        quality: float,
    ) -> SplineModel:
        """The layout's model, fitted on the spline coefficients of its clips at the knot
        spacing the rate control will start from (prediction depends on the spacing: at 0.2 s
        knots a gait cycle is 5 samples, at 0.05 s twenty)."""
        info = library.layouts[k]
        scale = decode_log2(encode_log2(self._channel_scale(info)))
        C = info.layout.n_channels
        rows, firsts = [], []
        for i in members:
            clip = library.clips[i]
            Y = clip.channels * scale
            spacing = self._spacings(bound, quality, clip.motion.fps)[0]
            for c in fit_segments(Y, self._breaks(library, i, bound), spacing):
                firsts.append(c[0])
                if len(c) > 2:
                    rows.append(c)
        a1 = np.ones(C)
        a2 = np.zeros(C)
        if self.settings.predictor == "lpc" and rows:
            A1 = np.concatenate([c[1:-1] for c in rows])
            A2 = np.concatenate([c[:-2] for c in rows])
            y = np.concatenate([c[2:] for c in rows])
            for ch in range(C):
                A = np.stack((A1[:, ch], A2[:, ch]), axis=1)
                if np.ptp(A) > 0:
                    sol = np.linalg.lstsq(A, y[:, ch], rcond=None)[0]
                    a1[ch], a2[ch] = np.clip(np.round(sol * _LPC_UNIT) / _LPC_UNIT, -1.98, 1.98)
        res = [np.abs(c[2:] - (a1 * c[1:-1] + a2 * c[:-2])) for c in rows]
        initial = np.mean(np.concatenate(res), axis=0) if res else np.ones(C)
        firsts = np.asarray(firsts) if firsts else np.zeros((1, C))
        start_mean = firsts.mean(axis=0) if self.settings.mean_start else np.zeros(C)
        start_scale = np.mean(np.abs(firsts - start_mean), axis=0) + 1e-3
        return SplineModel(scale, a1, a2, initial + 1e-4, start_mean, start_scale).quantised()

    # ---------------------------------------------------------------------------- encoding
    def fit_layout(
        self, library: PreparedLibrary, k: int, members: list[int], options: CodingOptions
    ) -> Any:
        return self._fit_model(library, k, members, options.max_error, options.quality)

    def model_bytes(self, model: Any, layout: LayoutInfo) -> bytes:
        return model.to_bytes()

    def encode_clip(
        self, library: PreparedLibrary, i: int, model: Any, options: CodingOptions
    ) -> bytes:
        breaks = self._breaks(library, i, options.max_error)
        return self._encode_clip(library, i, model, breaks, options.quality, options.max_error)

    def _active(self, library: PreparedLibrary, i: int) -> NDArray[np.bool_]:
        clip = library.clips[i]
        layout = library.layouts[clip.layout].layout
        active = np.ones(layout.n_channels, dtype=bool)
        for k in range(len(layout.translation_joints)):
            if clip.at_rest[k]:
                active[layout.translation_columns(k)] = False
        return active

    def _spacings(self, bound: float | None, quality: float, fps: float) -> tuple[float, ...]:
        """Knot spacings (frames of this clip) to try: the configured ones at the clip's frame
        rate, shortened for tight bounds (a spline with 0.2 s knots cannot follow a capture to
        a millimetre), and the raw frames below half a centimetre. Without a bound the step
        stands for one (a step of 0.4 times the bound is where the rate control starts)."""
        if bound is None:
            bound = quality / 0.4
        factor = fps / _REFERENCE_FPS * min(1.0, np.sqrt(bound / 5.0))
        spacings = tuple(max(3.0, round(k * factor)) for k in self.settings.spacings)
        return spacings + ((1.0,) if bound < 0.5 else ())

    def _encode_clip(self, library, i, model, breaks, quality, bound) -> bytes:
        clip = library.clips[i]
        active = self._active(library, i)
        cols = np.flatnonzero(active)
        T = clip.motion.n_frames
        # the first step: the cap, or 0.4 of the bound (weighted cm) if smaller
        top = step_code(min(quality, 0.4 * bound) if bound else quality)
        best = None
        for spacing in self._spacings(bound, quality, clip.motion.fps):
            fits: dict[tuple, SplineBasis] = {}

            def trial(code: int, spacing=spacing, fits=fits):
                step = step_value(code)
                plan = ClipPlan(int(round(spacing)), code, breaks, {})
                for _round in range(self.settings.refine_rounds + 1):
                    key = (plan.breaks, tuple(sorted(plan.inserted.items())))
                    if key not in fits:
                        fits[key] = SplineBasis(T, plan.breaks, plan.spacing, plan.inserted)
                    Q, Xh = self._code_columns(library, i, fits[key], model, cols, step)
                    bad = self._bad_frames(library, i, Xh, bound)
                    if len(bad) == 0:
                        break
                    refined = self._refine(plan, bad, T)
                    if refined is None:
                        break
                    plan = refined
                payload = encode_rows_v3(T, plan, Q, model, cols, self.group_rows)
                # frames still over the bound go to the orchestrator's repair: about three
                # bytes for each channel that moves a point by more than an eighth of the bound
                lever = library.layouts[clip.layout].lever
                off = np.abs(clip.channels[bad] - Xh[bad]) * lever > bound / 8.0 if len(bad) else 0
                repair = 3.0 * np.sum(off) + 2.0 * len(bad)
                return len(payload) + repair, payload, len(bad)

            # halve the step while more than 1 % of the frames miss the bound, then try the
            # neighbours of the best step on the 1/8-octave grid
            code = top
            tried = {}
            for _ in range(10):
                tried[code] = trial(code)
                if tried[code][2] <= max(1, T // 100) or code < 8:
                    break
                code -= 8
            centre = min(tried, key=lambda c: tried[c][0])
            for offset in (-3, 3)[: max(0, self.settings.steps_tried - 1)]:
                c = centre + offset
                if 0 <= c <= 255 and c not in tried and (offset < 0 or c <= top):
                    tried[c] = trial(c)
            for cost, payload, _ in tried.values():
                if best is None or cost < best[0]:
                    best = (cost, payload)
        return best[1]

    def _code_columns(self, library, i, basis: SplineBasis, model, cols, step):
        """Quantised coefficients ``(n, len(cols))`` and the decoded channels ``(T, C)``.

        With compensation, joints are coded parents first and each joint's target is the
        original global rotation seen from its decoded parent, so the quantisation error of
        a parent is taken up by its children instead of adding up along the chain.
        """
        clip = library.clips[i]
        X = clip.channels
        scale = model.scale
        Xh = X.copy()
        Q = np.zeros((basis.n_rows, X.shape[1]), dtype=np.int64)

        def code(columns, target):
            c = basis.fit(target * scale[columns])
            q = np.round(c / step).astype(np.int64)
            Q[:, columns] = q
            Xh[:, columns] = basis.evaluate(q * step) / scale[columns]

        active = np.zeros(X.shape[1], dtype=bool)
        active[cols] = True
        if not self.settings.compensate:
            code(cols, X[:, cols])
            return Q[:, cols], Xh
        info = library.layouts[clip.layout]
        layout, ref, sk = info.layout, info.reference, clip.motion.skeleton
        G = clip.world.rotations
        Gh = np.empty_like(G)
        rest = [c for c in cols if c < 3 or c >= layout.starts[-1] + layout.counts[-1]]
        if rest:
            code(np.asarray(rest), X[:, rest])
        for j in range(sk.n_joints):
            a, n = int(layout.starts[j]), int(layout.counts[j])
            columns = np.arange(a, a + n)
            p = int(sk.parents[j])
            if n:
                if j > 0:
                    local = multiply(conjugate(Gh[:, p]), G[:, j])
                    target = joint_channels(local, j, sk, layout, ref, X[:, columns])
                else:
                    target = X[:, columns]
                code(columns, target)
            q = joint_rotations(Xh[:, columns], j, sk, layout, ref)
            Gh[:, j] = q if j == 0 else multiply(Gh[:, p], q)
        return Q[:, cols], Xh

    def _bad_frames(self, library, i, Xh, bound) -> NDArray[np.int64]:
        if bound is None:
            return np.zeros(0, dtype=np.int64)
        err = frame_errors(
            library.clips[i].world, library.motion_of(i, Xh), vertices=library.vertices
        )
        return np.flatnonzero(err > bound)

    @staticmethod
    def _refine(plan: ClipPlan, bad: NDArray[np.int64], T: int) -> ClipPlan | None:
        # knot intervals stay at least a quarter of the spacing (and 2 frames) wide
        """Insert a knot in the middle of each knot interval holding a failing frame."""
        inserted = {s: list(v) for s, v in plan.inserted.items()}
        changed = False
        for s, (a, b) in enumerate(segment_bounds(T, plan.breaks)):
            L = b - a
            local = bad[(bad >= a) & (bad < b)] - a
            if len(local) == 0 or L < MIN_SPLINE_FRAMES or plan.spacing < 2:
                continue
            inner = np.unique(knot_vector(L, plan.spacing, inserted.get(s, ()))[3:-3])
            idx = np.clip(np.searchsorted(inner, local, side="right") - 1, 0, len(inner) - 2)
            for j in np.unique(idx):
                lo, hi = inner[j], inner[j + 1]
                if hi - lo >= max(4.0, plan.spacing / 2.0):
                    inserted.setdefault(s, []).append(int((lo + hi) // 2))
                    changed = True
        if not changed:
            return None
        return ClipPlan(
            plan.spacing,
            plan.step,
            plan.breaks,
            {s: tuple(sorted(set(v))) for s, v in inserted.items() if v},
        )

    # ---------------------------------------------------------------------------- decoding
    def load_model(self, data: bytes, layout: LayoutInfo) -> Any:
        return SplineModel.from_bytes(data, layout.layout.n_channels)

    def decode_coefficients(self, model: Any, payload: bytes, context: ClipContext) -> tuple:
        """A clip's plan, its :class:`~quatmotion.codec.spline.SegmentTables`, the coefficient
        rows ``P`` ``(n, c)`` in weighted units, the ``c`` active channels and their scales
        (channel = weighted / scale): what the frames
        and the spline between them are evaluated from (no frame evaluated yet)."""
        if context.version >= 3:
            streams, cols, scale = read_rows_v3(model, payload, context)
            P = np.empty((streams.tables.n_rows, len(cols)))
            streams.decode(P)
            return streams.plan, streams.tables, P, cols, scale
        r = Reader(payload, what=f"{self.name} clip")
        T = context.n_frames
        plan = ClipPlan.read(r, T)
        step = step_value(plan.step)
        tables = segment_tables(T, plan.breaks, plan.spacing, plan.inserted)
        starts = np.zeros(tables.n_rows, dtype=np.bool_)
        starts[tables.rows[tables.length > 0]] = True
        cols, initial, start_scale, a1, a2, scale, start_mean = _columns(model, context.active)
        try:
            R = entropy.decode_rows(
                r.take(r.remaining), len(starts), initial / step, start_scale / step, starts
            )
        except ValueError as error:
            raise FormatError(f"{self.name} clip: {error}") from None
        mean = np.round(start_mean / step).astype(np.int64)
        P = _unpredict_kernel(R, starts, mean, a1, a2, step)
        return plan, tables, P, cols, scale

    def upgrade_payload(self, model: Any, payload: bytes, context: ClipContext) -> bytes:
        """A format 1 or 2 payload re-coded in format 3: the same quantised rows, so the same
        decoded channels to the bit."""
        if context.version >= 3:
            return payload
        plan, _, P, cols, _ = self.decode_coefficients(model, payload, context)
        Q = np.round(P / step_value(plan.step)).astype(np.int64)
        return encode_rows_v3(context.n_frames, plan, Q, model, cols, self.group_rows)

    def decode_segments(
        self, model: Any, payload: bytes, context: ClipContext
    ) -> tuple[ClipPlan, list[NDArray[np.float64]], NDArray[np.int64], NDArray[np.float64]]:
        """A clip's plan, each segment's coefficient rows ``(n_s, c)`` in weighted units, the
        ``c`` active channel indices and their scales (channel = weighted / scale)."""
        plan, tables, P, cols, scale = self.decode_coefficients(model, payload, context)
        rows = [
            P[a : a + n]
            for a, n in zip(tables.rows, np.diff(np.r_[tables.rows, tables.n_rows]), strict=True)
        ]
        return plan, rows, cols, scale

    def decode(self, model: Any, payload: bytes, context: ClipContext) -> NDArray[np.float64]:
        T = context.n_frames
        _, tables, P, cols, scale = self.decode_coefficients(model, payload, context)
        X = np.zeros((T, context.layout.layout.n_channels))
        evaluate_channels(tables, P, cols, scale, X)
        return X


_COLUMNS: dict[tuple, tuple] = {}


def _columns(model: SplineModel, active: NDArray[np.bool_]) -> tuple:
    """The model's tables restricted to the active channels, contiguous (cached per model and
    active set: a library's clips share a few)."""
    key = (id(model), active.tobytes())
    hit = _COLUMNS.get(key)
    if hit is not None and hit[0] is model:
        return hit[1]
    cols = np.flatnonzero(active)
    out = (cols,) + tuple(
        np.ascontiguousarray(a[cols], dtype=np.float64)
        for a in (model.initial, model.start_scale, model.a1, model.a2, model.scale,
                  model.start_mean)
    )  # fmt: skip
    if len(_COLUMNS) > 256:
        _COLUMNS.clear()
    _COLUMNS[key] = (model, out)
    return out
