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
- ``"dtw-fused"`` (the default, :data:`DEFAULT_METHOD`): ``dtw-motion``'s distance (band 0.2,
  at most :data:`MAX_WARP_S`) and ``dtw-heading``'s, each divided by its median over the
  library, added with weights 1 and 2 (:class:`FusedDTW`): an exact ranking of every clip
  that sees posture, rhythm, path and the sense of a turn.
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

from quatmotion.retrieval import distances as dist
from quatmotion.retrieval.features import FEATURE_FPS, POSITION_DIM

__all__ = [
    "DEFAULT_METHOD",
    "FEATURE_KINDS",
    "METHODS",
    "Library",
    "QueryFeatures",
    "Ranking",
    "RetrievalMethod",
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
    """

    features: list[dict[str, np.ndarray]]
    fingerprints: list[str]
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

    def rank(self, library: Library, query: QueryFeatures, exclude: int = -1) -> Ranking:
        """The library's clips best first (``exclude``: a clip number left out, e.g. the query)."""
        ...


def _sorted(ids: NDArray[np.int64], d: FloatArray, exclude: int) -> Ranking:
    keep = ids != exclude
    ids, d = ids[keep], d[keep]
    order = np.argsort(d, kind="stable")
    return Ranking(ids[order], d[order])


@dataclass(frozen=True)
class DictionaryMatching:
    """The paper's atom-matching distance on ``qssd`` or ``ksvd`` dictionaries."""

    name: str
    kind: str

    @property
    def kinds(self) -> tuple[str, ...]:
        return (self.kind,)

    def rank(self, library: Library, query: QueryFeatures, exclude: int = -1) -> Ranking:
        ids, stack = library.atoms(self.kind, query.fingerprint)
        if ids.size == 0:
            return Ranking(np.zeros(0, dtype=np.int64), np.zeros(0))
        d = dist.atom_matching_distances(
            query.arrays[self.kind], stack, quaternion=self.kind == "qssd"
        )
        return _sorted(ids, d, exclude)


@dataclass(frozen=True)
class SequenceDTW:
    """Banded DTW over the first ``dims`` columns of the motion frames, every clip."""

    name: str
    dims: int
    band: float
    kinds: tuple[str, ...] = ("motion",)

    def rank(self, library: Library, query: QueryFeatures, exclude: int = -1) -> Ranking:
        frames, offsets = library.frames
        d = dist.dtw_to_library(
            query.arrays["frames"], frames, offsets, band=self.band, dims=self.dims
        )
        return _sorted(np.arange(len(library), dtype=np.int64), d, exclude)


@dataclass(frozen=True)
class PathDTW:
    """Unbanded Euclidean DTW over the ``path`` frames (features module), every clip: an exact
    ranking of the whole library."""

    name: str
    kinds: tuple[str, ...] = ("motion",)
    keys: tuple[str, ...] = ("path",)

    def rank(self, library: Library, query: QueryFeatures, exclude: int = -1) -> Ranking:
        frames, offsets = library.packed("path")
        d = dist.dtw_euclidean_to_library(query.arrays["path"], frames, offsets)
        return _sorted(np.arange(len(library), dtype=np.int64), d, exclude)


@dataclass(frozen=True)
class FusedDTW:
    """Two exact DTW distances over every clip, each divided by its median over the library
    and added: banded DTW over the motion frames (posture in each frame's own heading, the
    Hip's velocity and the yaw rate) and unbanded DTW over the path frames (the first frame's
    heading: where the body went and which way it turned). The first is blind to the path,
    the second to the body's heading within a turn; the sum keeps both."""

    name: str
    band: float = 0.2
    max_radius: float = 0.0
    path_weight: float = 2.0
    kinds: tuple[str, ...] = ("motion",)
    keys: tuple[str, ...] = ("frames", "path")

    def rank(self, library: Library, query: QueryFeatures, exclude: int = -1) -> Ranking:
        frames, offsets = library.frames
        d_motion = dist.dtw_to_library(
            query.arrays["frames"], frames, offsets, band=self.band, max_radius=self.max_radius
        )
        paths, path_offsets = library.packed("path")
        d_path = dist.dtw_euclidean_to_library(query.arrays["path"], paths, path_offsets)
        keep = np.arange(len(library)) != exclude
        fused = d_motion / _positive_median(d_motion[keep]) + self.path_weight * (
            d_path / _positive_median(d_path[keep])
        )
        return _sorted(np.arange(len(library), dtype=np.int64), fused, exclude)


@dataclass(frozen=True)
class PooledEmbedding:
    """Euclidean distance of the pooled embeddings."""

    name: str
    kinds: tuple[str, ...] = ("motion",)

    def rank(self, library: Library, query: QueryFeatures, exclude: int = -1) -> Ranking:
        d = dist.embedding_distances(library.embeddings, query.arrays["embedding"])
        return _sorted(np.arange(len(library), dtype=np.int64), d, exclude)


@dataclass(frozen=True)
class ShortlistThenDTW:
    """Pooled-embedding shortlist of ``shortlist`` clips, DTW re-rank, fused (module docstring)."""

    name: str
    shortlist: int = 64
    band: float = 0.2
    max_radius: float = 0.0
    dtw_weight: float = 1.0
    kinds: tuple[str, ...] = ("motion",)

    def rank(self, library: Library, query: QueryFeatures, exclude: int = -1) -> Ranking:
        d_emb = dist.embedding_distances(library.embeddings, query.arrays["embedding"])
        if 0 <= exclude < len(d_emb):
            d_emb[exclude] = np.inf
        n = int(np.isfinite(d_emb).sum())
        if n == 0:
            return Ranking(np.zeros(0, dtype=np.int64), np.zeros(0))
        k = min(self.shortlist, n)
        short = np.argpartition(d_emb, k - 1)[:k] if k < len(d_emb) else np.arange(len(d_emb))
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
        rest_mask = np.isfinite(d_emb)
        rest_mask[short] = False
        rest = np.flatnonzero(rest_mask)
        rest = rest[np.argsort(d_emb[rest], kind="stable")]
        return Ranking(
            np.concatenate((short[order], rest)).astype(np.int64),
            np.concatenate((fused[order], np.full(rest.size, np.nan))),
        )


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
    DEFAULT_METHOD: FusedDTW(DEFAULT_METHOD, max_radius=MAX_WARP_S * FEATURE_FPS),
    "pooled+dtw": ShortlistThenDTW("pooled+dtw", max_radius=MAX_WARP_S * FEATURE_FPS),
}
"""Name -> method; every method the benchmark scores."""
