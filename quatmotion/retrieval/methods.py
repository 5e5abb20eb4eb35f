"""Every clip-retrieval method behind one interface, by a stable name.

``METHODS[name]`` is a :class:`RetrievalMethod`: the feature kinds it needs per clip
(:data:`FEATURE_KINDS`) and ``rank(library, query)``, the full ranking of a :class:`Library`
for a query's features. The benchmark scores every method in one run; the index stores the
features of every method it was built for.

- ``"paper-qssd"``: the QSSD paper's section 5.2: a K = 5, L = 2 QSSD dictionary per clip,
  clip distance the optimal one-to-one matching of atoms under Eq. 10. Clips of another
  skeleton (fingerprint) are not ranked: rotations of different joints do not compare.
- ``"paper-ksvd"``: the same with K-SVD dictionaries, the paper's comparison.
- ``"dtw-positions"``: DTW over the 16 body-frame joint positions, Sakoe-Chiba band 0.1: the
  baseline a user would try first.
- ``"dtw-motion"``: DTW over the motion frames (positions and the Hip's travel), band 0.2,
  every clip.
- ``"dtw-heading"``: the plain baseline of issue 19: unbanded DTW over the path frames (the
  16 joints relative to the Hip and the Hip's trajectory, in the first frame's heading, in leg
  lengths), Euclidean frame cost, path cost divided by ``n + m``, every clip.
- ``"pooled"``: Euclidean distance of the pooled embeddings (blind to temporal order).
- ``"dtw-fused"`` (the default, :data:`DEFAULT_METHOD`): one DTW over the fused stream of
  :mod:`quatmotion.retrieval.features_fused` (posture, travel and the direction of travel
  in each frame's heading, the path's shape in the first frame's, posture and travel over a
  scale fixed per library), Euclidean
  frame cost, band :data:`FUSED_RADIUS` frames (:class:`FusedDTW`): it sees posture, rhythm,
  a walk forward, backward or sideways and the sense of a turn, not how far the clip
  travels (the stage's size: compared across studios). Exact over every
  clip: with ``k`` given, LB_Keogh on the model's projection and the projection's DTW prune
  clips that cannot be among the ``k`` nearest, the full DTW abandons early; ``k=None``
  computes every distance. The model (scales, projection) is stored in an index
  (:func:`quatmotion.retrieval.build.store_models`) and refitted when missing, damaged or of
  other parameters.
- ``"dtw-fused-labels"``: ``dtw-fused`` with a projection learned from the library's labels
  appended to its stream (:func:`quatmotion.retrieval.features_fused.fit_label_projection`);
  without labels, ``dtw-fused`` itself. Not the default: measured on actors and styles it was
  not trained on (docs/performance.md).
- ``"dtw-fused-route"`` (the default of 0.4.0): ``dtw-fused`` with the body and the route
  in the first frame's heading, in leg lengths, instead of the direction
  (:data:`~quatmotion.retrieval.features_fused.ROUTE_WEIGHTS`): how far a clip travels
  counts, which helps within a library captured on one stage and hurts across studios.
- ``"pooled+dtw"`` (the default before 0.4.0): the pooled embedding shortlists
  ``K = 64`` clips, DTW over the motion frames (band 0.2, at most :data:`MAX_WARP_S`)
  re-ranks them, and the two distances, each
  divided by its median over the shortlist, are added. The shortlist comes first, ordered by
  that sum (its ``distance``); the other clips follow by embedding distance, with distance NaN.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from quatmotion.retrieval import _kernels
from quatmotion.retrieval import distances as dist
from quatmotion.retrieval.features import FEATURE_FPS, POSITION_DIM
from quatmotion.retrieval.features_fused import (
    MODEL_KEY,
    MODEL_KEY_LABELS,
    ROUTE_WEIGHTS,
    WEIGHTS,
    FusedModel,
    fit_fused_model,
    fit_label_projection,
)

__all__ = [
    "DEFAULT_METHOD",
    "FEATURE_KINDS",
    "METHODS",
    "Library",
    "QueryFeatures",
    "Ranking",
    "RetrievalMethod",
    "fit_labels",
    "stored_model",
]

FloatArray = NDArray[np.float64]

FEATURE_KINDS: tuple[str, ...] = ("motion", "qssd", "ksvd")
"""Per-clip feature kinds: ``motion`` (frames ``(T, 52)`` and embedding ``(156,)``), ``qssd``
and ``ksvd`` (dictionaries ``(5, n, 4)``); see :mod:`quatmotion.retrieval.features`."""


@dataclass(frozen=True)
class QueryFeatures:
    """A clip's features: any of ``frames``, ``embedding``, ``qssd``, ``ksvd``, and the
    skeleton fingerprint (for the dictionary methods)."""

    arrays: dict[str, np.ndarray]
    fingerprint: str = ""


@dataclass(frozen=True)
class Ranking:
    """Clip numbers of a :class:`Library`, best first, and their distances (NaN: ranked but not
    scored by the method's final distance). Clips a method cannot compare are left out."""

    clips: NDArray[np.int64]
    distances: FloatArray


@dataclass
class Library:
    """The features of ``C`` clips in memory, packed for the distances.

    Parameters
    ----------
    features : list of dict
        Per clip, the arrays of :class:`QueryFeatures` (every clip needs the kinds of the
        methods that will rank it).
    fingerprints : list of str
        Per clip, its skeleton fingerprint.
    stored : dict of str to bytes
        What an index stores for the whole library (its ``blobs``: models by key).
    labels : list of str, optional
        Per clip, its label ("" for none): what ``dtw-fused-labels`` learns from.
    """

    features: list[dict[str, np.ndarray]]
    fingerprints: list[str]
    stored: dict[str, bytes] = field(default_factory=dict)
    labels: list[str] | None = None
    _cache: dict[str, object] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if len(self.features) != len(self.fingerprints):
            raise ValueError("features and fingerprints must list the same clips")

    def __len__(self) -> int:
        return len(self.features)

    def _need(self, key: str) -> list[np.ndarray]:
        missing = [i for i, f in enumerate(self.features) if key not in f]
        if missing:
            raise ValueError(f"{len(missing)} clips lack the {key!r} features (clip {missing[0]})")
        return [f[key] for f in self.features]

    def _need_one(self, clip: int, key: str) -> np.ndarray:
        if key not in self.features[clip]:
            raise ValueError(f"clip {clip} lacks the {key!r} features")
        return self.features[clip][key]

    @property
    def frames(self) -> tuple[NDArray[np.float32], NDArray[np.int64]]:
        """Concatenated motion frames and offsets (:func:`distances.pack_sequences`)."""
        if "frames" not in self._cache:
            self._cache["frames"] = dist.pack_sequences(self._need("frames"))
        return self._cache["frames"]  # type: ignore[return-value]

    def packed(self, key: str) -> tuple[NDArray[np.float32], NDArray[np.int64]]:
        """Concatenated per-frame arrays ``key`` of every clip and their offsets."""
        if key == "frames":
            return self.frames
        cache_key = f"packed:{key}"
        if cache_key not in self._cache:
            self._cache[cache_key] = dist.pack_sequences(self._need(key))
        return self._cache[cache_key]  # type: ignore[return-value]

    @property
    def embeddings(self) -> NDArray[np.float32]:
        """Pooled embeddings, shape (C, 156), float32."""
        if "embedding" not in self._cache:
            rows = self._need("embedding")
            self._cache["embedding"] = np.ascontiguousarray(np.stack(rows), dtype=np.float32)
        return self._cache["embedding"]  # type: ignore[return-value]

    def atoms(self, kind: str, fingerprint: str) -> tuple[NDArray[np.int64], FloatArray]:
        """Clip numbers with skeleton ``fingerprint`` and their ``kind`` atoms stacked."""
        key = f"{kind}:{fingerprint}"
        if key not in self._cache:
            ids = np.array(
                [i for i, f in enumerate(self.fingerprints) if f == fingerprint], dtype=np.int64
            )
            stack = np.stack([self._need_one(i, kind) for i in ids]) if ids.size else np.zeros((0,))
            self._cache[key] = (ids, stack)
        return self._cache[key]  # type: ignore[return-value]


class RetrievalMethod(Protocol):
    """A clip distance and how it ranks a library."""

    name: str
    kinds: tuple[str, ...]

    def rank(
        self, library: Library, query: QueryFeatures, exclude: int = -1, k: int | None = None
    ) -> Ranking:
        """The library's clips best first (``exclude``: a clip number left out, e.g. the
        query; ``k``: the first ``k`` only, None: every clip)."""
        ...


def _sorted(ids: NDArray[np.int64], d: FloatArray, exclude: int, k: int | None = None) -> Ranking:
    keep = ids != exclude
    ids, d = ids[keep], d[keep]
    order = np.argsort(d, kind="stable")[:k]
    return Ranking(ids[order], d[order])


@dataclass(frozen=True)
class DictionaryMatching:
    """The paper's atom-matching distance on ``qssd`` or ``ksvd`` dictionaries."""

    name: str
    kind: str

    @property
    def kinds(self) -> tuple[str, ...]:
        return (self.kind,)

    def rank(
        self, library: Library, query: QueryFeatures, exclude: int = -1, k: int | None = None
    ) -> Ranking:
        ids, stack = library.atoms(self.kind, query.fingerprint)
        if ids.size == 0:
            return Ranking(np.zeros(0, dtype=np.int64), np.zeros(0))
        d = dist.atom_matching_distances(
            query.arrays[self.kind], stack, quaternion=self.kind == "qssd"
        )
        return _sorted(ids, d, exclude, k)


@dataclass(frozen=True)
class SequenceDTW:
    """Banded DTW over the first ``dims`` columns of the motion frames, every clip."""

    name: str
    dims: int
    band: float
    kinds: tuple[str, ...] = ("motion",)

    def rank(
        self, library: Library, query: QueryFeatures, exclude: int = -1, k: int | None = None
    ) -> Ranking:
        frames, offsets = library.frames
        d = dist.dtw_to_library(
            query.arrays["frames"], frames, offsets, band=self.band, dims=self.dims
        )
        return _sorted(np.arange(len(library), dtype=np.int64), d, exclude, k)


@dataclass(frozen=True)
class PathDTW:
    """Unbanded Euclidean DTW over the ``path`` frames (features module), every clip: an exact
    ranking of the whole library."""

    name: str
    kinds: tuple[str, ...] = ("motion",)
    keys: tuple[str, ...] = ("path",)

    def rank(
        self, library: Library, query: QueryFeatures, exclude: int = -1, k: int | None = None
    ) -> Ranking:
        frames, offsets = library.packed("path")
        d = dist.dtw_euclidean_to_library(query.arrays["path"], frames, offsets)
        return _sorted(np.arange(len(library), dtype=np.int64), d, exclude, k)


FUSED_RADIUS = 8
"""Sakoe-Chiba radius of the default's DTW, frames at :data:`FEATURE_FPS` (0.8 s; radii 6, 8
and 11 measured the same mAP, a smaller one is cheaper): at least half the length ratio plus
one, so that a path exists."""


def fused_model(
    library: Library, learned: bool = False, weights: tuple[float, ...] = WEIGHTS
) -> FusedModel:
    """The library's :class:`FusedModel`: the one its index stores, or (missing, damaged or of
    other parameters) fitted on the library, once per :class:`Library`. ``learned``: the
    model of ``dtw-fused-labels`` (learned from ``library.labels`` when fitted here; without
    labels, the plain model). ``weights`` other than the default's: fitted here, never
    stored."""
    key = MODEL_KEY_LABELS if learned else MODEL_KEY
    if tuple(weights) != WEIGHTS:
        key = f"{key}@{','.join(f'{w:g}' for w in weights)}"
    if key not in library._cache:
        model = None
        data = library.stored.get(key)
        if data is not None:
            try:
                model = FusedModel.from_bytes(data, weights)
            except ValueError:  # FormatError included: refit
                model = None
        if model is None and learned:
            model = fit_labels(library, fused_model(library, weights=weights))
        elif model is None:
            model = fit_fused_model(
                library._need("frames"), library._need("path"), weights=tuple(weights)
            )
        library._cache[key] = model
    return library._cache[key]  # type: ignore[return-value]


def fit_labels(library: Library, model: FusedModel, seed: int = 0) -> FusedModel:
    """``model`` with a projection learned from ``library.labels`` (``model`` itself when the
    library has no labels)."""
    if not library.labels:
        return model
    return fit_label_projection(
        model, library._need("frames"), library._need("path"), list(library.labels), seed
    )


@dataclass(frozen=True)
class FusedDTW:
    """One banded Euclidean DTW over the fused stream (module docstring), exact over every
    clip; with ``k``, pruned by lower bounds."""

    name: str
    radius: int = FUSED_RADIUS
    learned: bool = False
    weights: tuple[float, ...] = WEIGHTS
    kinds: tuple[str, ...] = ("motion",)
    keys: tuple[str, ...] = ("frames", "path")

    def _packed(self, library: Library) -> tuple[np.ndarray, ...]:
        key = f"fused:{self.radius}:{self.learned}:{self.weights}"
        if key not in library._cache:
            model = fused_model(library, self.learned, self.weights)
            streams = [
                model.stream(f, p)
                for f, p in zip(library._need("frames"), library._need("path"), strict=True)
            ]
            frames, offsets = dist.pack_sequences(streams)
            if len(streams):
                projected = model.project(frames)
                upper, lower = _kernels.envelopes(projected, offsets, self.radius + 1)
            else:
                projected = upper = lower = np.zeros((0, model.projection.shape[0]), np.float32)
            # the kernel reads frames as columns (a cell's sum in order, the cells vectorised)
            frames_t = np.ascontiguousarray(frames.T)
            projected_t = np.ascontiguousarray(projected.T)
            library._cache[key] = (frames_t, projected_t, upper, lower, offsets)
        return library._cache[key]  # type: ignore[return-value]

    def distances(
        self, library: Library, query: QueryFeatures, exclude: int = -1, k: int | None = None
    ) -> tuple[FloatArray, int]:
        """Every clip's distance (``inf``: pruned, never one of the ``k`` nearest, or
        ``exclude``) and the number of full DTWs computed."""
        frames_t, projected_t, upper, lower, offsets = self._packed(library)
        model = fused_model(library, self.learned, self.weights)
        q = dist._as_frames(model.stream(query.arrays["frames"], query.arrays["path"]), "query")
        kk = len(library) if k is None else k  # checked at the public entry
        qp = model.project(q)
        return _kernels.fused_search(
            q, qp, frames_t, projected_t, upper, lower, offsets, self.radius, kk, exclude
        )

    def rank(
        self, library: Library, query: QueryFeatures, exclude: int = -1, k: int | None = None
    ) -> Ranking:
        if len(library) == 0:
            return Ranking(np.zeros(0, dtype=np.int64), np.zeros(0))
        d, _ = self.distances(library, query, exclude, k)
        ids = np.arange(len(library), dtype=np.int64)
        keep = np.isfinite(d) if k is not None else ids != exclude
        return _sorted(ids[keep], d[keep], exclude, k)


def stored_model(data: bytes | None) -> FusedModel | None:
    """The model stored as ``data``; None when there is none or it is damaged (refit it)."""
    if data is None:
        return None
    try:
        return FusedModel.from_bytes(data)
    except ValueError:
        return None


@dataclass(frozen=True)
class PooledEmbedding:
    """Euclidean distance of the pooled embeddings."""

    name: str
    kinds: tuple[str, ...] = ("motion",)

    def rank(
        self, library: Library, query: QueryFeatures, exclude: int = -1, k: int | None = None
    ) -> Ranking:
        d = dist.embedding_distances(library.embeddings, query.arrays["embedding"])
        return _sorted(np.arange(len(library), dtype=np.int64), d, exclude, k)


@dataclass(frozen=True)
class ShortlistThenDTW:
    """Pooled-embedding shortlist of ``shortlist`` clips, DTW re-rank, fused (module docstring)."""

    name: str
    shortlist: int = 64
    band: float = 0.2
    max_radius: float = 0.0
    dtw_weight: float = 1.0
    kinds: tuple[str, ...] = ("motion",)

    def rank(
        self, library: Library, query: QueryFeatures, exclude: int = -1, k: int | None = None
    ) -> Ranking:
        d_emb = dist.embedding_distances(library.embeddings, query.arrays["embedding"])
        if 0 <= exclude < len(d_emb):
            d_emb[exclude] = np.inf
        n = int(np.isfinite(d_emb).sum())
        if n == 0:
            return Ranking(np.zeros(0, dtype=np.int64), np.zeros(0))
        # The ranking is the shortlist alone (the clips after it have no DTW to rank them by):
        # its first k when k is given.
        size = min(self.shortlist, n)
        short = (
            np.argpartition(d_emb, size - 1)[:size] if size < len(d_emb) else np.arange(len(d_emb))
        )
        short = short[np.isfinite(d_emb[short])].astype(np.int64)
        frames, offsets = library.frames
        d_dtw = dist.dtw_to_library(
            query.arrays["frames"],
            frames,
            offsets,
            short,
            band=self.band,
            max_radius=self.max_radius,
        )
        fused = d_emb[short] / _positive_median(d_emb[short]) + self.dtw_weight * (
            d_dtw / _positive_median(d_dtw)
        )
        order = np.argsort(fused, kind="stable")
        return Ranking(short[order][:k], fused[order][:k])


def _positive_median(x: FloatArray) -> float:
    """The median of ``x``, or 1 when it is not positive (identical clips only)."""
    m = float(np.median(x))
    return m if m > 0 else 1.0


DEFAULT_METHOD = "dtw-fused"
MAX_WARP_S = 1.0
"""Largest time shift of the default's DTW re-rank from the rescaled diagonal, seconds: it
bounds the cost of long clips, and measured no loss of accuracy (docs/performance.md)."""

METHODS: dict[str, RetrievalMethod] = {
    "paper-qssd": DictionaryMatching("paper-qssd", "qssd"),
    "paper-ksvd": DictionaryMatching("paper-ksvd", "ksvd"),
    "dtw-positions": SequenceDTW("dtw-positions", dims=POSITION_DIM, band=0.1),
    "dtw-motion": SequenceDTW("dtw-motion", dims=52, band=0.2),
    "dtw-heading": PathDTW("dtw-heading"),
    "pooled": PooledEmbedding("pooled"),
    DEFAULT_METHOD: FusedDTW(DEFAULT_METHOD),
    "dtw-fused-labels": FusedDTW("dtw-fused-labels", learned=True),
    "dtw-fused-route": FusedDTW("dtw-fused-route", weights=ROUTE_WEIGHTS),
    "pooled+dtw": ShortlistThenDTW("pooled+dtw", max_radius=MAX_WARP_S * FEATURE_FPS),
}
"""Name -> method; every method the benchmark scores."""
