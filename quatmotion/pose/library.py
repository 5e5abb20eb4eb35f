"""A saved, searchable pose library: "poses like frame F of clip C".

Every pose of a motion library is described by the GPD, scaled (min-max, then unit length),
projected by a learned metric ``W``, and put in an HNSW graph
(:class:`~quatmotion.pose.index.HNSWIndex`). In the projected space the learned distance
``sqrt((x - y)^T W W^T (x - y))`` is plain Euclidean distance, so an L2 index answers
learned-metric queries. :meth:`PoseLibrary.build` learns the metric from the library itself,
on transition pairs labelled by Kovar's windowed point-cloud distance:

* ``"GPD+LMS"`` (the default: it measures better than the paper's RDSR in ``bench pose``, see
  docs/performance.md): non-negative least-squares weights per GPD dimension from similar and
  dissimilar pairs; ``W`` is the diagonal of their square roots, dimensions of weight 0 left out.
* ``"GPD+RDSR"`` (the GPD paper): RDSR of rank ``rank`` from the similar pairs and an
  unlabeled random sample.

A library of a single clip has no cross-clip pairs: then consecutive frames serve as the
similar pairs, and (for LMS) poses at least a second apart as the dissimilar ones.

Conventions
-----------
* Clips are prepared by :meth:`PoseClip.from_motion` (resampled, scaled to one body height);
  queries go through :meth:`PoseLibrary.prepare_query`, so they are described alike.
* Frame numbers count from 0 in the clip's file, before any resampling.
* A library file is one ``.npz`` holding the serialised HNSW graph, the projection model and the
  pose catalogue (clip names, frame numbers, fps), with a ``meta`` record naming the format
  (``quatmotion-pose-library``) and its version; it is written to a temporary file and then
  renamed, so a reader never sees half a library. Reading checks both, raising
  :class:`~quatmotion.FormatError`.
"""

from __future__ import annotations

import json
import os
import pathlib
import time
import zipfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quatmotion._atomic import atomic_output
from quatmotion.errors import FormatError
from quatmotion.motion import Motion
from quatmotion.pose import labels
from quatmotion.pose.baselines import LMS
from quatmotion.pose.data import PoseClip, PoseData
from quatmotion.pose.index import HNSWIndex
from quatmotion.pose.metric import RDSR
from quatmotion.pose.scaler import MinMaxUnitScaler

__all__ = ["DEFAULT_METRIC", "METRICS", "PoseLibrary", "PoseMatch"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

_FORMAT = "quatmotion-pose-library"
_VERSION = 1
# Fewer transition pairs than this teach a metric too little: use consecutive frames instead.
_MIN_TRANSITION_PAIRS = 10
_FAR_APART_S = 1.0  # fallback dissimilar pairs: poses of one clip at least this far apart

METRICS: tuple[str, ...] = ("GPD+LMS", "GPD+RDSR")
"""The pose distances :meth:`PoseLibrary.build` can learn."""
DEFAULT_METRIC = "GPD+LMS"


@dataclass(frozen=True)
class PoseMatch:
    """One pose found by :meth:`PoseLibrary.nearest`.

    Attributes
    ----------
    rank : int
        From 1, nearest first.
    clip : int
        Clip number (into ``PoseLibrary.clip_names``).
    name : str
        The clip's name as indexed.
    frame : int
        Frame number in the clip's file, from 0.
    seconds : float or None
        ``frame`` over the file's frame rate (None for a library that does not store it).
    distance : float
        Learned pose distance to the query.
    """

    rank: int
    clip: int
    name: str
    frame: int
    seconds: float | None
    distance: float


@dataclass
class PoseLibrary:
    """A searchable pose library: projection model, HNSW index and pose catalogue.

    Attributes
    ----------
    index : HNSWIndex
        Over the projected poses; item ``i`` is pose ``i`` of the catalogue.
    clip_names : list of str
        One per clip (file paths as given when indexing).
    clip_of : ndarray of int, shape (N,)
        Clip of every indexed pose.
    frame_of : ndarray of int, shape (N,)
        Frame number of every indexed pose, in the clip's file (before any subsampling).
    model : dict of str to ndarray
        The projection: ``scale`` and ``offset`` (shape (D,), the GPD normalisation of Eq. 38),
        ``W`` (shape (D, r), the metric's projection); poses map to
        ``unit(scale * gpd + offset) @ W``.
    meta : dict
        JSON-serialisable settings (fps, frame step, height, method, labels used...).
    """

    index: HNSWIndex
    clip_names: list[str]
    clip_of: IntArray
    frame_of: IntArray
    model: dict[str, FloatArray]
    meta: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def build(
        cls,
        clips: Sequence[PoseClip],
        *,
        rank: int = 50,
        n_unlabeled: int = 5000,
        n_pairs: int = 500,
        seed: int = 0,
        M: int = 16,
        ef_construction: int = 100,
        metric: Any = None,
        metric_name: str = DEFAULT_METRIC,
        log: Callable[[str], None] | None = None,
    ) -> PoseLibrary:
        """Learn a pose distance on the clips' own poses, project every pose and index it.

        The steps: GPD of every pose; positive pairs (good transitions by Kovar's windowed
        point-cloud distance, :func:`~quatmotion.pose.labels.transition_labels`, or
        consecutive frames when the clips yield fewer than 10); the min-max + unit-length
        scaling fitted on the unlabeled sample and the pairs; the metric learned from them;
        every pose projected by it into an HNSW index.

        Parameters
        ----------
        clips : sequence of PoseClip
            All prepared at the same frame rate and height (:meth:`PoseClip.from_motion`).
        rank : int
            Rank of the projection ``W`` (its dimensions).
        n_unlabeled : int
            Unlabeled poses for the metric's sparse-representation term.
        n_pairs : int
            Positive transition pairs wanted.
        seed : int
        M, ef_construction : int
            HNSW graph parameters.
        metric : estimator, optional
            For ``"GPD+RDSR"``: unfitted, with ``fit(X_unlabeled, positive_pairs)`` and
            ``components_`` of shape ``(rank, D)`` after fitting; default
            ``RDSR(n_components=rank)``.
        metric_name : {"GPD+LMS", "GPD+RDSR"}
            The pose distance to learn (module docstring); ``rank`` applies to RDSR only.
        log : callable, optional
            Called with progress messages.

        Returns
        -------
        PoseLibrary
        """
        say = log or (lambda _msg: None)
        if metric_name not in METRICS:
            raise ValueError(
                f"unknown pose metric {metric_name!r}; choose from {', '.join(METRICS)}"
            )
        if not clips:
            raise ValueError("no clips to index")
        for name, value in (("rank", rank), ("n_unlabeled", n_unlabeled), ("n_pairs", n_pairs)):
            if value < 1:
                raise ValueError(f"{name} must be at least 1, got {value}")
        fps, height = clips[0].fps, clips[0].height
        if any(c.fps != fps or c.height != height for c in clips):
            raise ValueError("every clip must be prepared at the same frame rate and height")
        rng = np.random.default_rng(seed)
        poses = PoseData.concat([c.poses for c in clips])
        clip_offsets = labels.ClipOffsets(np.array([len(c) for c in clips]))
        t0 = time.perf_counter()
        raw = poses.gpd
        say(f"GPD of {len(poses)} poses: {time.perf_counter() - t0:.1f} s")
        lms = metric_name == "GPD+LMS"
        pairs, similar, pairs_from = _labelled_pairs(
            clips, clip_offsets, n_pairs, rng, say, dissimilar=lms
        )
        unlabeled = rng.permutation(len(poses))[:n_unlabeled]
        scaler = MinMaxUnitScaler().fit(raw[np.unique(np.r_[unlabeled, pairs.ravel()])])
        X = scaler.transform(raw)
        t0 = time.perf_counter()
        if lms:
            weights = LMS(power=2).fit(None, X[pairs[:, 0]], X[pairs[:, 1]], similar).weights_
            kept = np.flatnonzero(weights > 0)
            W = np.zeros((X.shape[1], kept.size))
            W[kept, np.arange(kept.size)] = np.sqrt(weights[kept])
            rank = kept.size
        else:
            rank = min(rank, X.shape[1])
            positive = pairs[similar]
            learner = RDSR(n_components=rank, random_state=seed) if metric is None else metric
            learner.fit(X[unlabeled], np.stack([X[positive[:, 0]], X[positive[:, 1]]], axis=1))
            W = learner.components_.T
        say(f"{metric_name} metric of rank {rank}: {time.perf_counter() - t0:.1f} s")
        t0 = time.perf_counter()
        index = HNSWIndex(M=M, ef_construction=ef_construction, random_state=seed).fit(X @ W)
        say(f"HNSW index of {len(X)} poses: {time.perf_counter() - t0:.1f} s")
        steps = np.repeat([c.step for c in clips], clip_offsets.lengths)
        return cls(
            index=index,
            clip_names=[c.name for c in clips],
            clip_of=clip_offsets.clip_of(),
            frame_of=clip_offsets.frame_of() * steps,
            model={"scale": scaler.scale_, "offset": scaler.offset_, "W": W},
            meta={
                "fps": fps,
                "height_cm": height,
                "file_fps": [c.fps * c.step for c in clips],
                "rank": rank,
                "n_unlabeled": len(unlabeled),
                "metric": metric_name,
                "n_positive_pairs": int(similar.sum()),
                "n_negative_pairs": int((~similar).sum()),
                "positive_pairs_from": pairs_from,
                "seed": seed,
            },
        )

    def prepare_query(self, motion: Motion) -> PoseClip:
        """``motion`` prepared as the indexed clips were (same frame rate and body height)."""
        return PoseClip.from_motion(motion, fps=self.meta["fps"], height=self.meta.get("height_cm"))

    def project(self, raw_gpd: ArrayLike) -> FloatArray:
        """Map raw GPD features to the index space.

        Parameters
        ----------
        raw_gpd : array_like, shape (N, D)
            :func:`quatmotion.pose.gpd.gpd_features` output.

        Returns
        -------
        ndarray, shape (N, r)
        """
        x = np.asarray(raw_gpd, dtype=np.float64)
        x = x * self.model["scale"] + self.model["offset"]
        norm = np.linalg.norm(x, axis=1, keepdims=True)
        x = x / np.where(norm > 0, norm, 1.0)
        return x @ self.model["W"]

    def find(self, clip: str | int, frame: int) -> int:
        """Catalogue number of the indexed pose nearest in time to ``frame`` of ``clip``.

        Parameters
        ----------
        clip : str or int
            Clip number, full name, or a unique suffix of the name (e.g. the file name).
        frame : int
            Frame number in the clip's file.
        """
        c = self._clip_number(clip)
        rows = np.flatnonzero(self.clip_of == c)
        if len(rows) == 0:
            raise ValueError(f"clip {self.clip_names[c]!r} has no indexed pose")
        return int(rows[np.argmin(np.abs(self.frame_of[rows] - frame))])

    def _clip_number(self, clip: str | int) -> int:
        if isinstance(clip, (int, np.integer)):
            if not 0 <= clip < len(self.clip_names):
                raise ValueError(f"clip number {clip} out of range 0..{len(self.clip_names) - 1}")
            return int(clip)
        matches = [i for i, n in enumerate(self.clip_names) if n == clip]
        if not matches:
            matches = [
                i
                for i, n in enumerate(self.clip_names)
                if n.endswith(clip) or pathlib.Path(n).stem == clip
            ]
        if len(matches) != 1:
            raise ValueError(
                f"clip {clip!r} matches {len(matches)} indexed clips; give a longer name"
            )
        return matches[0]

    def search(self, vectors: ArrayLike, k: int = 10) -> tuple[IntArray, FloatArray]:
        """Approximate nearest indexed poses of projected query vectors, ``(Q, k)`` each."""
        return self.index.query(vectors, k)

    def pose_query(self, clip: str | int, frame: int) -> tuple[FloatArray, int, int]:
        """The projected vector ``(1, r)`` of an indexed pose, its clip number and frame.

        The pose is the one indexed nearest in time to ``frame`` of ``clip`` (:meth:`find`).
        """
        item = self.find(clip, frame)
        return self.index.vectors([item]), int(self.clip_of[item]), int(self.frame_of[item])

    def motion_query(self, motion: Motion, frame: int) -> tuple[FloatArray, int]:
        """The projected vector ``(1, r)`` of a clip's pose near ``frame`` and that pose's
        frame number (the query prepared as the library was, :meth:`prepare_query`)."""
        clip = self.prepare_query(motion)
        row = min(max(int(round(frame / clip.step)), 0), len(clip) - 1)
        return self.project(clip.poses[row : row + 1].gpd), row * clip.step

    def nearest(
        self, query: ArrayLike, k: int = 10, *, exclude_clip: int | None = None
    ) -> list[PoseMatch]:
        """The ``k`` indexed poses nearest to one projected query vector.

        Parameters
        ----------
        query : array_like, shape (1, r)
            From :meth:`pose_query`, :meth:`motion_query` or :meth:`project`.
        k : int
            Poses wanted, at least 1 (fewer when the library holds fewer).
        exclude_clip : int, optional
            Leave out the poses of this clip (e.g. the query's own).

        Returns
        -------
        list of PoseMatch
        """
        if k < 1:
            raise ValueError(f"k must be at least 1, got {k}")
        n_items = self.index.n_items_
        own = 0 if exclude_clip is None else int(np.sum(self.clip_of == exclude_clip))
        ids, dist = self.search(query, min(n_items, k + own))
        ids, dist = ids[0], dist[0]
        if exclude_clip is not None:
            keep = self.clip_of[ids] != exclude_clip
            ids, dist = ids[keep], dist[keep]
        file_fps = self.meta.get("file_fps")
        out = []
        for rank, (i, d) in enumerate(zip(ids[:k], dist[:k], strict=True), start=1):
            c, f = int(self.clip_of[i]), int(self.frame_of[i])
            seconds = f / file_fps[c] if file_fps else None
            out.append(PoseMatch(rank, c, self.clip_names[c], f, seconds, float(d)))
        return out

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the library to ``path`` (one ``.npz``; temporary file, then rename)."""
        path = pathlib.Path(path)
        meta = dict(self.meta)
        meta.update(format=_FORMAT, version=_VERSION, dim=self.index.dim_)
        payload = {
            "index": np.frombuffer(self.index.to_bytes(), dtype=np.uint8),
            "clip_names": np.asarray(self.clip_names, dtype=str),
            "clip_of": self.clip_of,
            "frame_of": self.frame_of,
            "meta": np.asarray(json.dumps(meta)),
        }
        payload.update({f"model_{k}": v for k, v in self.model.items()})
        with atomic_output(path) as temp, temp.open("wb") as fh:
            np.savez(fh, **payload)

    @classmethod
    def load(cls, path: str | os.PathLike[str], ef_search: int = 64) -> PoseLibrary:
        """Read a library written by :meth:`save`.

        Raises
        ------
        FormatError
            If the file is not a quatmotion pose library, or one of another format version.
        """
        try:
            with np.load(path, allow_pickle=False) as data:
                meta = json.loads(str(data["meta"]))
                if not isinstance(meta, dict) or meta.get("format") != _FORMAT:
                    raise FormatError(f"not a quatmotion pose library (expected {_FORMAT})", path)
                version = meta.get("version")
                if version != _VERSION:
                    newer = isinstance(version, int) and version > _VERSION
                    raise FormatError(
                        f"pose library format version {version!r} "
                        f"{'is newer than' if newer else 'differs from'} the version this "
                        f"quatmotion reads ({_VERSION}); rebuild it with 'quatmotion pose index'",
                        path,
                    )
                index = HNSWIndex.from_bytes(
                    data["index"].tobytes(), dim=int(meta["dim"]), ef_search=ef_search
                )
                model = {k[6:]: data[k] for k in data.files if k.startswith("model_")}
                return cls(
                    index=index,
                    clip_names=[str(n) for n in data["clip_names"]],
                    clip_of=data["clip_of"].astype(np.int64),
                    frame_of=data["frame_of"].astype(np.int64),
                    model=model,
                    meta=meta,
                )
        except FormatError:
            raise
        except (KeyError, ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
            # np.load raises ValueError (pickled or unknown content), OSError, BadZipFile...
            raise FormatError(
                f"not a readable quatmotion pose library ({type(exc).__name__}: {exc})", path
            ) from exc


def _labelled_pairs(
    clips: Sequence[PoseClip],
    clip_offsets: labels.ClipOffsets,
    n_pairs: int,
    rng: np.random.Generator,
    say: Callable[[str], None],
    dissimilar: bool,
) -> tuple[IntArray, NDArray[np.bool_], str]:
    """Pose pairs ``(P, 2)`` (indices into the concatenated clips), whether each is similar,
    and where they came from; dissimilar pairs only if ``dissimilar``."""
    if len(clips) >= 2:
        try:
            found, thresholds = labels.transition_labels(
                [c.local for c in clips],
                [c.world for c in clips],
                clips[0].fps,
                n_positive=n_pairs,
                n_negative=n_pairs if dissimilar else 0,
                n_queries=max(2000, 4 * n_pairs),
                random_state=rng,
            )
            p = found.pairs
            pairs = np.stack([clip_offsets(p[:, 0], p[:, 1]), clip_offsets(p[:, 2], p[:, 3])], 1)
            similar = np.asarray(found.labels, dtype=bool)
            say(f"{int(similar.sum())} similar pairs below {thresholds[0]:.2f} cm")
            if similar.sum() >= _MIN_TRANSITION_PAIRS and (
                not dissimilar or (~similar).sum() >= _MIN_TRANSITION_PAIRS
            ):
                return pairs, similar, "transition pairs (Kovar point-cloud distance)"
        except ValueError as exc:
            say(f"no transition pairs ({exc})")
    n_poses = clip_offsets.n_poses
    within = np.flatnonzero(np.isin(np.arange(n_poses - 1) + 1, clip_offsets.starts, invert=True))
    take = rng.permutation(within)[:n_pairs]
    if len(take) == 0:
        raise ValueError("the library needs a clip of at least two frames to learn a pose distance")
    pairs = np.stack([take, take + 1], axis=1)
    if not dissimilar:
        return pairs, np.ones(len(pairs), dtype=bool), "consecutive frames"
    clip_of = clip_offsets.clip_of()
    frame_of = clip_offsets.frame_of()
    gap = max(1, int(round(_FAR_APART_S * clips[0].fps)))
    a = rng.integers(0, n_poses, 20 * n_pairs)
    b = rng.integers(0, n_poses, 20 * n_pairs)
    far = (clip_of[a] != clip_of[b]) | (np.abs(frame_of[a] - frame_of[b]) >= gap)
    apart = np.stack([a[far], b[far]], axis=1)[:n_pairs]
    if len(apart) == 0:
        raise ValueError("the library is too short to learn a pose distance with dissimilar pairs")
    both = np.concatenate((pairs, apart))
    similar = np.r_[np.ones(len(pairs), dtype=bool), np.zeros(len(apart), dtype=bool)]
    return both, similar, f"consecutive frames; poses {_FAR_APART_S:g} s apart as dissimilar"
