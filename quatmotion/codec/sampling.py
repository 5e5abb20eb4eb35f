"""Sampling poses of a compressed clip at arbitrary times (the runtime decoder).

Conventions
-----------
* Time ``t`` seconds is frame position ``u = t fps``; frame ``f`` is at ``f / fps``.
* **Clamp** holds ``u`` in ``[0, T - 1]``; **loop** takes ``u`` modulo ``T`` (period
  ``T / fps``): between frame ``T - 1`` and ``T`` (= frame 0) the pose is interpolated from
  the last frame to the first.
* **Between frames** the clip's model decides. Spline methods (``best``, ``spline``) evaluate the
  decoded cubic B-spline of each segment in channel space, then turn channels into rotations;
  a clip's per-frame corrections (:mod:`quatmotion.codec.repair`) are added, linearly
  interpolated between frames, so the value at a frame time is exactly the decoded frame.
  Where no spline spans ``u`` (segments of a few frames kept frame by frame, the gap between
  two segments, the loop's wrap) and for every other method, the pose is the normalised lerp
  (shorter arc) of the two decoded frames' rotations and the lerp of their root translations.
* A clip is decoded whole on its first sample (its residuals are one adaptive range-coded
  stream, so no part decodes alone) and kept by the archive for later samples; a joint subset
  evaluates only the channels of those joints.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quatmotion.codec._decode_kernels import sample_poses
from quatmotion.codec.channels import _kernel_tables, _rotations_kernel
from quatmotion.codec.spline import MIN_SPLINE_FRAMES, knot_vector, segment_bounds
from quatmotion.errors import FormatError

__all__ = ["ClipSampler", "MODES", "sampler_for"]

MODES = ("clamp", "loop")
_CACHED_CLIPS = 16


@dataclass(frozen=True)
class _Spline:
    """A clip's spline segments flattened for the sampling kernel."""

    cols: NDArray[np.int64]  # active channels (coefficient columns)
    scale: NDArray[np.float64]  # (c,) channel = weighted / scale
    knots: NDArray[np.float64]
    knot_start: NDArray[np.int64]  # (S + 1,) over spline segments only
    coef: NDArray[np.float64]  # (rows, c), weighted units
    row_start: NDArray[np.int64]  # (S,)
    seg_first: NDArray[np.int64]  # (S,) first frame of each spline segment
    seg_last: NDArray[np.int64]  # (S,) last frame of each spline segment
    correction: NDArray[np.float64] | None  # (T, C) corrections per frame, or None


class ClipSampler:
    """One decoded clip, ready to sample (made by :func:`sampler_for`)."""

    def __init__(self, archive, clip: int | str):
        parts = archive.clip_parts(clip)
        self.entry = parts.entry
        self.skeleton = parts.skeleton
        self.fps = float(parts.entry.fps)
        self.n_frames = int(parts.entry.n_frames)
        layout = parts.layout.layout
        self._layout = layout
        self._ref = np.ascontiguousarray(parts.layout.reference)
        self._dof_axes, self._pre = _kernel_tables(parts.skeleton, layout)
        method = archive.method
        spline = None
        try:
            if hasattr(method, "decode_segments"):
                plan, rows, cols, scale = method.decode_segments(
                    parts.model, parts.payload, parts.context
                )
                X = np.zeros((self.n_frames, layout.n_channels))
                from quatmotion.codec.spline import evaluate_segments

                X[:, cols] = (
                    evaluate_segments(rows, self.n_frames, plan.breaks, plan.spacing, plan.inserted)
                    / scale
                )
                spline = self._flatten(plan, rows, cols, scale)
            else:
                X = method.decode(parts.model, parts.payload, parts.context)
        except FormatError as error:
            raise archive.method_error(parts, error) from None
        raw = X.copy() if spline is not None and len(parts.corrections) else None
        self.channels = archive.checked_channels(parts, X)
        if raw is not None:
            spline = _Spline(**{**spline.__dict__, "correction": self.channels - raw})
        self._spline = spline
        self._frame_rotations: NDArray[np.float64] | None = None
        self._names = {n: j for j, n in enumerate(parts.skeleton.joint_names)}
        self._all = np.arange(parts.skeleton.n_joints, dtype=np.int64)
        self._selections: dict[bytes, tuple] = {}

    def _flatten(self, plan, rows, cols, scale) -> _Spline | None:
        knots, knot_start, coef, row_start, first, last = [], [0], [], [], [], []
        n_rows = 0
        for s, ((a, b), c) in enumerate(
            zip(segment_bounds(self.n_frames, plan.breaks), rows, strict=True)
        ):
            L = b - a
            if L < MIN_SPLINE_FRAMES or plan.spacing < 2:
                n_rows += len(c)
                continue
            t = knot_vector(L, plan.spacing, plan.inserted.get(s, ()))
            knots.append(t)
            knot_start.append(knot_start[-1] + len(t))
            coef.append(c)
            row_start.append(sum(len(x) for x in coef[:-1]))
            first.append(a)
            last.append(b - 1)
        if not coef:
            return None
        return _Spline(
            np.asarray(cols, dtype=np.int64),
            np.asarray(scale, dtype=np.float64),
            np.concatenate(knots),
            np.asarray(knot_start, dtype=np.int64),
            np.ascontiguousarray(np.concatenate(coef), dtype=np.float64),
            np.asarray(row_start, dtype=np.int64),
            np.asarray(first, dtype=np.int64),
            np.asarray(last, dtype=np.int64),
            None,
        )

    # ------------------------------------------------------------------ arguments
    def _joints(self, joints) -> NDArray[np.int64]:
        J = self.skeleton.n_joints
        if joints is None:
            return np.arange(J, dtype=np.int64)
        items = [joints] if isinstance(joints, str | int | np.integer) else list(joints)
        out = np.empty(len(items), dtype=np.int64)
        for k, j in enumerate(items):
            if isinstance(j, str):
                if j not in self._names:
                    raise ValueError(
                        f"clip {self.entry.name!r}: no joint named {j!r} "
                        f"(joints: {', '.join(self.skeleton.joint_names)})"
                    )
                out[k] = self._names[j]
            elif isinstance(j, int | np.integer) and not isinstance(j, bool):
                if not 0 <= j < J:
                    raise ValueError(
                        f"clip {self.entry.name!r}: joint index {j} out of range 0..{J - 1}"
                    )
                out[k] = j
            else:
                raise ValueError(f"joints: expected joint names or indices, got {j!r}")
        return out

    def _positions(self, times, mode: str) -> tuple[NDArray[np.float64], bool]:
        if isinstance(times, float | int) and mode == "clamp" and np.isfinite(times):
            u = min(max(float(times) * self.fps, 0.0), self.n_frames - 1.0)  # the one-pose path
            return np.array([u]), True
        if mode not in MODES:
            raise ValueError(f"mode must be one of {', '.join(map(repr, MODES))}, not {mode!r}")
        try:
            t = np.asarray(times, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError("times: expected seconds as a number or a 1-D array") from None
        scalar = t.ndim == 0
        if t.ndim > 1:
            raise ValueError(f"times: expected a number or a 1-D array, got shape {t.shape}")
        t = np.atleast_1d(t)
        if not np.all(np.isfinite(t)):
            raise ValueError("times: every time must be finite (seconds)")
        u = t * self.fps
        T = self.n_frames
        u = np.clip(u, 0.0, T - 1.0) if mode == "clamp" else np.mod(u, float(T))
        return u, scalar

    # ------------------------------------------------------------------ sampling
    def frame_rotations(self) -> NDArray[np.float64]:
        """Local rotations of every decoded frame ``(T, J, 4)`` (computed once)."""
        if self._frame_rotations is None:
            self._frame_rotations = self._rotations(
                self.channels, np.arange(self.skeleton.n_joints)
            )
        return self._frame_rotations

    def _rotations(self, X, sel) -> NDArray[np.float64]:
        L = self._layout
        return _rotations_kernel(
            X, L.kinds[sel], L.starts[sel], L.counts[sel], self._dof_axes[sel], self._pre[sel],
            self._ref[sel],
        )  # fmt: skip

    def _tables(self, sel: NDArray[np.int64]) -> tuple:
        """The kernel's arguments that depend on the joint selection (cached per selection)."""
        key = sel.tobytes()
        cached = self._selections.get(key)
        if cached is not None:
            return cached
        L = self._layout
        sp = self._spline
        if sp is None:
            cols_at = np.zeros(0, dtype=np.int64)
            spline = (_NO_INT, _NO_INT, _NO_FLOAT, np.zeros(1, dtype=np.int64),
                      np.zeros((0, 0)), _NO_INT, _NO_INT, _NO_FLOAT, np.zeros((0, 0)))  # fmt: skip
        else:
            cols_at = np.flatnonzero(np.isin(sp.cols, self._needed_columns(sel)))
            corr = sp.correction if sp.correction is not None else np.zeros((0, 0))
            spline = (
                sp.seg_first, sp.seg_last, sp.knots, sp.knot_start,
                np.ascontiguousarray(sp.coef[:, cols_at]), sp.row_start,
                np.ascontiguousarray(sp.cols[cols_at]), np.ascontiguousarray(sp.scale[cols_at]),
                corr,
            )  # fmt: skip
        rotation = tuple(
            np.ascontiguousarray(a[sel])
            for a in (L.kinds, L.starts, L.counts, self._dof_axes, self._pre, self._ref)
        )
        cached = (spline, sel, rotation)
        if len(self._selections) > 32:
            self._selections.clear()
        self._selections[key] = cached
        return cached

    def sample(self, times, joints=None, *, mode: str = "clamp"):
        """See :meth:`quatmotion.codec.archive.Archive.sample`."""
        sel = self._all if joints is None else self._joints(joints)
        u, scalar = self._positions(times, mode)
        spline, sel, rotation = self._tables(sel)
        root = np.empty((len(u), 3))
        rot = np.empty((len(u), len(sel), 4))
        sample_poses(
            u, mode == "loop", *spline, self.channels, self.frame_rotations(), sel, *rotation,
            root, rot,
        )  # fmt: skip
        if scalar:
            return root[0], rot[0]
        return root, rot

    def _needed_columns(self, sel) -> NDArray[np.int64]:
        L = self._layout
        cols = [np.arange(3)]
        for j in sel:
            cols.append(np.arange(L.starts[j], L.starts[j] + L.counts[j]))
        return np.unique(np.concatenate(cols))


_NO_INT = np.zeros(0, dtype=np.int64)
_NO_FLOAT = np.zeros(0)


def sampler_for(archive, clip: int | str) -> ClipSampler:
    """The archive's sampler of ``clip``, decoded on first use (the last few are kept)."""
    i = archive.index_of(clip)
    cache = archive._samplers
    sampler = cache.get(i)
    if sampler is None:
        sampler = ClipSampler(archive, i)
        cache[i] = sampler
        if len(cache) > _CACHED_CLIPS:
            cache.popitem(last=False)
    else:
        cache.move_to_end(i)
    return sampler
