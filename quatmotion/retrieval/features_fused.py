"""The default method's per-frame streams and the per-library model that scales them.

Conventions
-----------
* Built from the stored motion frames and path frames
  (:mod:`quatmotion.retrieval.features`), so an index of the ``motion`` kind needs nothing
  new. Six parts per frame (:data:`PARTS`); a part of weight 0 is left out of the stream:

  - ``posture`` (48): the 16 joints in each frame's own body frame (the motion frames' first
    columns, cm): what the body does, blind to where it faces;
  - ``travel`` (4): the Hip's velocity in the body frame and the yaw rate (the motion frames'
    last columns): the gait and the *sense* of a turn (the yaw rate's sign);
  - ``body`` (48): the 16 joints relative to the Hip in the *first* frame's heading, in leg
    lengths (the path frames' first columns): the posture as it turns during the clip;
  - ``route`` (3): the Hip's trajectory from its first-frame position in that heading, in
    leg lengths: the path travelled, a turn left against a turn right;
  - ``direction`` (2): the direction of travel relative to the body's facing: the Hip's
    horizontal velocity in the body frame (the travel part's left and forward columns)
    smoothed over :data:`DIRECTION_SIGMA_S`, divided by ``sqrt(speed^2 + v0^2)`` with ``v0 =``
    :data:`DIRECTION_SPEED_CM_S` (a unit vector at walking speed, 0 standing still), times the
    clip's locomotion gate ``min(1, R /`` :data:`LOCOMOTION_LEG_LENGTHS` ``)`` with ``R`` the
    farthest the Hip gets from its first-frame position, in leg lengths (in-place motions that
    shift their weight get no direction). Unitless: what a walk forward, backward or sideways
    is, whatever the speed, the clip's length and the size of the stage;
  - ``shape`` (3): the route over the farthest the Hip gets from its start, or over
    :data:`LOCOMOTION_LEG_LENGTHS` when that is less: the shape of the path (straight, curving
    left or right, diagonal) whatever its length; a motion in place keeps its small route.
* Invariances: the clip's start heading and position (every part is relative to the first
  frame or to the body's own frame), body size (``body`` and ``route`` divided by the leg
  length; ``posture`` and ``travel`` on a body scaled to one stature; ``direction`` and
  ``shape`` unitless). *Not* invariant, on purpose: left against right (a mirror changes the sign of
  the X coordinates), the sense of a turn (the yaw rate's sign, the trajectory's X), the
  order and rhythm of frames (DTW).
* The **fused stream** ``(T, D)``: each part of non-zero weight over its scale, times its
  weight (:data:`WEIGHTS`: ``D = 57``; :data:`ROUTE_WEIGHTS`, the 0.4.0 stream: ``D = 103``).
  ``posture`` and ``travel`` (centimetres) are divided by a scale fixed per library
  (:func:`fit_fused_model`): the median, over the frames of at most :data:`FIT_CLIPS` clips
  drawn with a seeded generator, of the Euclidean norm of the part minus its clip's mean (its
  spread within a clip; the raw norm is mostly the body's size). ``body`` and ``route`` are in
  leg lengths already and ``direction`` and ``shape`` are unitless: scale 1 (a library median
  of the route follows how many of the sampled clips stand still). Fixed scales make a
  distance independent of the query, and one DTW compares the parts.
* **Across studios** (issue 31): the default (:data:`WEIGHTS`) leaves out ``body`` and
  ``route`` and takes ``direction`` and ``shape``. How far the Hip travels in leg lengths is
  the stage's size and the clip's length as much as its content; the direction of travel
  relative to the facing and the path's shape are the content alone. The 0.4.0 stream
  (:data:`ROUTE_WEIGHTS`, the route at weight 2) is the method ``dtw-fused-route``, for a
  library captured on one stage.
* The model also holds :data:`N_COMPONENTS` principal directions of the fused frames
  (orthonormal rows): the projection on which the exact search's lower bounds are computed
  (an orthonormal projection never lengthens a difference, so a bound on the projection
  bounds the full distance).
* **Learned from labels** (``dtw-fused-labels``, off by default): where a library has labels,
  a linear discriminant projection of the fused frames (at most :data:`N_COMPONENTS`
  directions, frames labelled by their clip; :func:`fit_label_projection`) scaled to the
  stream's spread, appended to the stream times :data:`LEARNED_WEIGHT`. It keeps every
  invariance above (a linear map of the same frames).
* Stored in an index's ``blobs`` table under :data:`MODEL_KEY` as ``.npz`` bytes (no pickles):
  a JSON header (format version, scales, weights, the number of clips fitted on, a SHA-256
  digest of the header and the projection) and the projection. Bytes that do not read or
  fail the digest raise :class:`~quatmotion.errors.FormatError`, another version or other
  weights ``ValueError``; the method then refits (:meth:`FusedModel.from_bytes`).
"""

from __future__ import annotations

import hashlib
import io
import json
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quatmotion.errors import FormatError
from quatmotion.retrieval.features import FRAME_DIM, PATH_DIM

__all__ = [
    "DIRECTION_SIGMA_S",
    "DIRECTION_SPEED_CM_S",
    "FIT_CLIPS",
    "FUSED_DIM",
    "LEARNED_WEIGHT",
    "MODEL_KEY",
    "MODEL_KEY_LABELS",
    "N_COMPONENTS",
    "PARTS",
    "ROUTE_WEIGHTS",
    "WEIGHTS",
    "FusedModel",
    "fit_fused_model",
    "fit_label_projection",
    "stream_parts",
]

MODEL_KEY = "model:dtw-fused"
MODEL_KEY_LABELS = "model:dtw-fused-labels"
LEARNED_WEIGHT = 0.5
"""Weight of the learned projection appended to the fused stream."""
LABEL_FRAMES = 20_000
"""Frames the label projection is fitted on, at most (drawn with the seed)."""
MODEL_VERSION = 2
"""2: the direction and shape parts of issue 31 (a model of version 1 is refitted)."""
FIT_CLIPS = 48
"""Clips the scales and the projection are fitted on, at most."""
N_COMPONENTS = 16
"""Principal directions of the projection the lower bounds use."""
PARTS: tuple[tuple[str, int], ...] = (
    ("posture", 48),
    ("travel", 4),
    ("body", 48),
    ("route", 3),
    ("direction", 2),
    ("shape", 3),
)
"""The fused stream's parts and their widths, in order."""
WEIGHTS: tuple[float, ...] = (1.0, 0.3, 0.0, 0.0, 4.0, 2.0)
"""Weight of each part after its scale, the default's (docs/performance.md, 0.5.0, gives the
trials across studios and within them)."""
ROUTE_WEIGHTS: tuple[float, ...] = (1.0, 0.3, 2.0, 2.0, 0.0, 0.0)
"""The 0.4.0 default's weights (``dtw-fused-route``): body and route, no direction or shape."""
DIRECTION_SIGMA_S = 0.5
"""Standard deviation of the Gaussian that smooths the Hip's velocity for the direction,
seconds (about half a gait cycle: the sway of each step averages out)."""
DIRECTION_SPEED_CM_S = 20.0
"""Speed at which the direction's length is ``1/sqrt(2)``, cm/s on the scaled body (a slow
walk is 50 or more)."""
LOCOMOTION_LEG_LENGTHS = 3.0
"""How far the Hip must get from where it started (leg lengths) for the direction to count
in full: about two strides; less scales it down in proportion (a kick or a reach that shifts
the weight is no walk)."""
_FITTED = (True, True, False, False, False, False)
"""Which parts get a library scale (the others are in leg lengths or unitless: scale 1)."""


def stream_dim(weights: tuple[float, ...] = WEIGHTS) -> int:
    """Columns of the fused stream with ``weights`` (parts of weight 0 are left out)."""
    return sum(width for (_, width), w in zip(PARTS, weights, strict=True) if w != 0)


FUSED_DIM = stream_dim(WEIGHTS)
"""Columns of the default's fused stream (its first columns, with a learned projection)."""


def _smoothed(x: NDArray[np.float64], sigma: float) -> NDArray[np.float64]:
    """``x`` ``(T, c)`` convolved along axis 0 with a Gaussian of ``sigma`` frames (truncated
    at 4 sigma, ends repeated), each output a sum over the taps in order (the same bits on
    every processor)."""
    radius = int(np.ceil(4.0 * sigma))
    if radius == 0 or x.shape[0] < 2:
        return x.copy()
    taps = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma) ** 2)
    taps /= taps.sum()
    padded = np.concatenate((np.repeat(x[:1], radius, 0), x, np.repeat(x[-1:], radius, 0)))
    out = np.zeros_like(x)
    for k, t in enumerate(taps):
        out += t * padded[k : k + x.shape[0]]
    return out


def _reach(route: NDArray[np.float64]) -> float:
    """The farthest the Hip gets from its first-frame position (leg lengths), horizontally."""
    return float(np.max(np.sqrt(route[:, 0] ** 2 + route[:, 2] ** 2))) if len(route) else 0.0


def direction_part(travel: NDArray[np.float64], route: NDArray[np.float64]) -> NDArray[np.float64]:
    """The ``direction`` part ``(T, 2)`` (module conventions) of a clip's travel columns
    ``(T, 4)`` (the motion frames' last four) and route ``(T, 3)`` (the path frames' last
    three)."""
    from quatmotion.retrieval.features import FEATURE_FPS, HORIZON_S

    velocity = _smoothed(travel[:, [0, 2]] / HORIZON_S, DIRECTION_SIGMA_S * FEATURE_FPS)
    speed2 = velocity[:, :1] ** 2 + velocity[:, 1:] ** 2
    gate = min(1.0, _reach(route) / LOCOMOTION_LEG_LENGTHS)
    return velocity / np.sqrt(speed2 + DIRECTION_SPEED_CM_S**2) * gate


def shape_part(route: NDArray[np.float64]) -> NDArray[np.float64]:
    """The ``shape`` part ``(T, 3)`` (module conventions) of a clip's route ``(T, 3)``."""
    return route / max(_reach(route), LOCOMOTION_LEG_LENGTHS)


def streams_mismatch(frames: NDArray[np.floating], path: NDArray[np.floating]) -> str | None:
    """Why a clip's motion and path frames cannot make one fused stream, for a message about a
    stored clip (None: they can): :func:`stream_parts` reads ``(T, 52)`` and ``(T, 51)`` of
    one ``T`` and trusts them."""
    shapes = f"{tuple(np.shape(frames))} and {tuple(np.shape(path))}"
    expected = f"(T, {FRAME_DIM}) and (T, {PATH_DIM}) of one T"
    if np.ndim(frames) != 2 or np.ndim(path) != 2:
        return f"its motion and path frames are {shapes}, not {expected}"
    if frames.shape[1] != FRAME_DIM or path.shape[1] != PATH_DIM or len(frames) != len(path):
        return f"its motion and path frames are {shapes}, not {expected}"
    return None


def stream_parts(
    frames: NDArray[np.floating], path: NDArray[np.floating]
) -> list[NDArray[np.float64]]:
    """The six parts (:data:`PARTS`) of a clip's motion frames ``(T, 52)`` and path frames
    ``(T, 51)``."""
    f = np.asarray(frames, dtype=np.float64)
    p = np.asarray(path, dtype=np.float64)
    route = p[:, 48:]
    return [
        f[:, :48],
        f[:, 48:],
        p[:, :48],
        route,
        direction_part(f[:, 48:], route),
        shape_part(route),
    ]


def _ordered_product(x: NDArray[np.float64], w: NDArray[np.floating]) -> NDArray[np.float64]:
    """``x @ w`` ``(T, c)``, each sum over the columns of ``x`` in order: BLAS orders a sum as
    the processor's kernel does, and a stream is ranked (the same bits on every processor)."""
    out = np.zeros((x.shape[0], w.shape[1]))
    for k in range(x.shape[1]):
        out += x[:, k, None] * w[k].astype(np.float64)
    return out


def _positive(x: float) -> float:
    return x if np.isfinite(x) and x > 0 else 1.0


@dataclass(frozen=True)
class FusedModel:
    """Scales and projection of the fused stream, fitted on one library."""

    scales: tuple[float, ...]
    projection: NDArray[np.float32]  # (N_COMPONENTS, dim), orthonormal rows
    fitted_clips: int
    weights: tuple[float, ...] = WEIGHTS
    learned: NDArray[np.float32] | None = None  # (dim, c), from labels
    labels_digest: str = ""  # of the labels it was learned from

    def stream(
        self, frames: NDArray[np.floating], path: NDArray[np.floating]
    ) -> NDArray[np.float32]:
        """Fused stream ``(T, dim)`` float32 of a clip's motion and path frames (with a
        learned projection: ``dim + c`` columns)."""
        parts = stream_parts(frames, path)
        out = np.concatenate(
            [
                x * (w / s)
                for x, w, s in zip(parts, self.weights, self.scales, strict=True)
                if w != 0
            ],
            axis=1,
        )
        if self.learned is not None:
            out = np.concatenate(
                (out, LEARNED_WEIGHT * _ordered_product(out, self.learned)), axis=1
            )
        return np.ascontiguousarray(out, dtype=np.float32)

    @property
    def dim(self) -> int:
        """Columns of the stream before a learned projection (:func:`stream_dim`)."""
        return stream_dim(self.weights)

    def project(self, stream: NDArray[np.float32]) -> NDArray[np.float32]:
        """The stream's first ``dim`` columns on the principal directions
        ``(T, N_COMPONENTS)`` (the rows padded with zeros stay orthonormal on a longer
        stream)."""
        return np.ascontiguousarray(stream[:, : self.dim] @ self.projection.T, dtype=np.float32)

    def _header(self) -> dict[str, object]:
        return {
            "version": MODEL_VERSION,
            "scales": [float(x) for x in self.scales],
            "weights": [float(x) for x in self.weights],
            "fitted_clips": int(self.fitted_clips),
            "shape": list(self.projection.shape),
            "learned": None if self.learned is None else list(self.learned.shape),
            "labels_digest": self.labels_digest,
        }

    def _digest(self) -> str:
        h = hashlib.sha256(json.dumps(self._header(), sort_keys=True).encode())
        h.update(np.ascontiguousarray(self.projection, dtype="<f4").tobytes())
        if self.learned is not None:
            h.update(np.ascontiguousarray(self.learned, dtype="<f4").tobytes())
        return h.hexdigest()

    def to_bytes(self) -> bytes:
        """``.npz`` bytes: the header (with its digest) as JSON and the projection."""
        header = dict(self._header(), digest=self._digest())
        buf = io.BytesIO()
        arrays = {"projection": np.ascontiguousarray(self.projection, dtype="<f4")}
        if self.learned is not None:
            arrays["learned"] = np.ascontiguousarray(self.learned, dtype="<f4")
        np.savez(
            buf,
            header=np.frombuffer(json.dumps(header, sort_keys=True).encode(), dtype=np.uint8),
            **arrays,
        )
        return buf.getvalue()

    @classmethod
    def from_bytes(cls, data: bytes, weights: tuple[float, ...] = WEIGHTS) -> FusedModel:
        """Read :meth:`to_bytes`'s bytes of a model of ``weights``.

        Raises
        ------
        FormatError
            Bytes that do not read, or whose digest does not match (damaged).
        ValueError
            Another model version, other weights or shape than this code's (mismatched).
        """
        try:
            with np.load(io.BytesIO(data), allow_pickle=False) as z:
                header = json.loads(bytes(z["header"]).decode())
                projection = np.array(z["projection"], dtype=np.float32)
                learned = np.array(z["learned"], dtype=np.float32) if "learned" in z else None
            model = cls(
                tuple(float(x) for x in header["scales"]),
                projection,
                int(header["fitted_clips"]),
                tuple(float(x) for x in header["weights"]),
                learned,
                str(header["labels_digest"]),
            )
            version, digest = header["version"], header["digest"]
        except Exception as exc:  # noqa: BLE001 - any damage reads as a format error
            raise FormatError(f"{MODEL_KEY}: unreadable model ({exc})") from exc
        if version != MODEL_VERSION:
            raise ValueError(f"{MODEL_KEY}: version {version}, this code reads {MODEL_VERSION}")
        if model._digest() != digest:
            raise FormatError(f"{MODEL_KEY}: digest mismatch (damaged model)")
        if (
            projection.shape != (N_COMPONENTS, stream_dim(weights))
            or len(model.scales) != len(PARTS)
            or model.weights != tuple(weights)
            or (learned is not None and (learned.ndim != 2 or learned.shape[0] != model.dim))
        ):
            raise ValueError(f"{MODEL_KEY}: fitted with other parameters than this code's")
        return model


def fit_fused_model(
    frames: list[NDArray[np.floating]],
    paths: list[NDArray[np.floating]],
    seed: int = 0,
    weights: tuple[float, ...] = WEIGHTS,
) -> FusedModel:
    """Fit the scales and the projection on at most :data:`FIT_CLIPS` clips of a library
    (their motion ``frames`` and ``paths`` frames), drawn with ``seed``; an empty library
    gives unit scales; ``weights`` (:data:`WEIGHTS`, :data:`ROUTE_WEIGHTS`) are the model's
    (:meth:`FusedModel.from_bytes` reads it back with the same)."""
    rng = np.random.default_rng(seed)
    picks = (
        np.sort(rng.choice(len(paths), FIT_CLIPS, replace=False))
        if len(paths) > FIT_CLIPS
        else np.arange(len(paths))
    )
    dim = stream_dim(tuple(weights))
    eye = np.eye(N_COMPONENTS, dim, dtype=np.float32)
    if not len(picks):
        return FusedModel((1.0,) * len(PARTS), eye, 0, tuple(weights))
    clips = [stream_parts(frames[int(i)], paths[int(i)]) for i in picks]
    scales = tuple(
        1.0
        if not _FITTED[p]
        else _positive(
            float(
                np.median(
                    np.linalg.norm(np.concatenate([c[p] - c[p].mean(0) for c in clips]), axis=1)
                )
            )
        )
        for p in range(len(PARTS))
    )
    model = FusedModel(scales, eye, len(picks), tuple(weights))
    X = np.concatenate([model.stream(frames[int(i)], paths[int(i)]) for i in picks]).astype(
        np.float64
    )
    X = X - X.mean(axis=0)
    # principal directions; with fewer frames than components, completed to an orthonormal set
    _, _, vt = np.linalg.svd(np.concatenate((X, np.zeros((N_COMPONENTS, dim)))), False)
    return FusedModel(scales, vt[:N_COMPONENTS].astype(np.float32), len(picks), tuple(weights))


def labels_digest(labels: list[str]) -> str:
    """SHA-256 of a library's labels in clip order (what a label projection was learned on)."""
    return hashlib.sha256(json.dumps(list(labels)).encode()).hexdigest()


def fit_label_projection(
    model: FusedModel,
    frames: list[NDArray[np.floating]],
    paths: list[NDArray[np.floating]],
    labels: list[str],
    seed: int = 0,
) -> FusedModel:
    """``model`` with a linear discriminant projection learned from ``labels`` (module
    conventions): clips with an empty label, or of a label no other clip has, are left out;
    fewer than two labels left returns ``model`` unchanged."""
    from sklearn.discriminant_analysis import LinearDiscriminantAnalysis

    counts: dict[str, int] = {}
    for lab in labels:
        counts[lab] = counts.get(lab, 0) + 1
    use = [i for i, lab in enumerate(labels) if lab and counts[lab] >= 2]
    classes = sorted({labels[i] for i in use})
    if len(classes) < 2:
        return model
    base = FusedModel(model.scales, model.projection, model.fitted_clips, model.weights)
    streams = [base.stream(frames[i], paths[i]) for i in use]
    X = np.concatenate(streams).astype(np.float64)
    y = np.concatenate(
        [[classes.index(labels[i])] * len(s) for i, s in zip(use, streams, strict=True)]
    )
    if len(X) > LABEL_FRAMES:
        pick = np.sort(np.random.default_rng(seed).choice(len(X), LABEL_FRAMES, replace=False))
        X, y = X[pick], y[pick]
    c = min(N_COMPONENTS, len(classes) - 1)
    lda = LinearDiscriminantAnalysis(solver="eigen", shrinkage="auto").fit(X, y)
    W = lda.scalings_[:, :c]
    centred = X - X.mean(axis=0)
    spread = np.median(np.linalg.norm(centred, axis=1))
    learned_spread = np.median(np.linalg.norm(centred @ W, axis=1))
    W = W * (_positive(float(spread)) / _positive(float(learned_spread)))
    return FusedModel(
        model.scales,
        model.projection,
        model.fitted_clips,
        model.weights,
        W.astype(np.float32),
        labels_digest(labels),
    )
