"""A saved, searchable pose library: "poses like frame F of clip C".

Every pose of a motion library is described by the GPD, scaled (min-max, clipped to the library's
range, then unit length), projected by a learned metric ``W`` (RDSR by default, rank 50), and put
in an HNSW graph (:class:`~quatmotion.pose.index.HNSWIndex`). In the projected space the learned
distance ``sqrt((x - y)^T W W^T (x - y))`` is plain Euclidean distance, so an L2 index answers
learned-metric queries. :meth:`PoseLibrary.build` learns the metric from the library itself:
positive pairs are good transitions labelled by Kovar's windowed point-cloud distance, the
unlabeled poses a random sample. A library of a single clip has no cross-clip pairs: then
consecutive frames serve as the positive pairs.

Conventions
-----------
* Clips are prepared by :meth:`PoseClip.from_motion` (resampled, put on the canonical body of
  one stature); queries go through :meth:`PoseLibrary.prepare_query`, so they are described
  alike whatever their skeleton.
* Features are clipped to the library's range after the min-max step: a query from another
  body or motion may exceed the range in a few features (nearly constant ones, such as the
  spread of a rigid pelvis), and unclipped they would dominate its unit-length vector, so that
  every such query lands on the same few poses.
* Frame numbers count from 0 in the clip's file, before any resampling (an AMC file's frame 1
  is frame 0). Asking for a frame outside a clip, or a clip that is not there, is an error
  naming what there is.
* A library file is one ``.npz`` holding the serialised HNSW graph, the projection model and the
  pose catalogue (clip names, frame numbers, fps), with a ``meta`` record naming the format
  (``quatmotion-pose-library``) and its version; it is written to a temporary file and then
  renamed, so a reader never sees half a library. Reading checks both, raising
  :class:`~quatmotion.FormatError`.
"""

from __future__ import annotations

import difflib
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
from quatmotion.pose.data import PoseClip, PoseData
from quatmotion.pose.index import HNSWIndex
from quatmotion.pose.metric import RDSR
from quatmotion.pose.scaler import MinMaxUnitScaler

__all__ = ["PoseLibrary"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

_FORMAT = "quatmotion-pose-library"
_VERSION = 2  # 2: poses on the canonical body, features clipped to the library's range
_NOT_A_LIBRARY = (
    f"not a quatmotion pose library (expected a file written by 'quatmotion pose index': "
    f"format {_FORMAT}, version {_VERSION})"
)
# Fewer transition pairs than this teach a metric too little: use consecutive frames instead.
_MIN_TRANSITION_PAIRS = 10


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
        ``unit(clip(scale * gpd + offset, 0, 1)) @ W``.
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
        log: Callable[[str], None] | None = None,
    ) -> PoseLibrary:
        """Learn a pose distance on the clips' own poses, project every pose and index it.

        The steps: GPD of every pose; positive pairs (good transitions by Kovar's windowed
        point-cloud distance, :func:`~quatmotion.pose.labels.transition_labels`, or
        consecutive frames when the clips yield fewer than 10); the min-max (clipped) + unit-length
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
            Unfitted, with ``fit(X_unlabeled, positive_pairs)`` and ``components_`` of shape
            ``(rank, D)`` after fitting; default ``RDSR(n_components=rank)``.
        log : callable, optional
            Called with progress messages.

        Returns
        -------
        PoseLibrary
        """
        say = log or (lambda _msg: None)
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
        positive, pairs_from = _positive_pairs(clips, clip_offsets, n_pairs, rng, say)
        unlabeled = rng.permutation(len(poses))[:n_unlabeled]
        sample = np.unique(np.r_[unlabeled, positive.ravel()])
        scaler = MinMaxUnitScaler(clip=True).fit(raw[sample])
        X = scaler.transform(raw)
        rank = min(rank, X.shape[1])
        t0 = time.perf_counter()
        learner = RDSR(n_components=rank, random_state=seed) if metric is None else metric
        learner.fit(X[unlabeled], np.stack([X[positive[:, 0]], X[positive[:, 1]]], axis=1))
        say(f"metric of rank {rank}: {time.perf_counter() - t0:.1f} s")
        W = learner.components_.T
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
                "file_frames": [c.file_frames for c in clips],
                "rank": rank,
                "n_unlabeled": len(unlabeled),
                "n_positive_pairs": len(positive),
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
        x = np.clip(x * self.model["scale"] + self.model["offset"], 0.0, 1.0)
        norm = np.linalg.norm(x, axis=1, keepdims=True)
        x = x / np.where(norm > 0, norm, 1.0)
        return x @ self.model["W"]

    def find(self, clip: str | int, frame: int) -> int:
        """Catalogue number of the indexed pose nearest in time to ``frame`` of ``clip``.

        Parameters
        ----------
        clip : str or int
            See :meth:`clip_number`.
        frame : int
            Frame number in the clip's file, from 0.

        Raises
        ------
        ValueError
            For a clip that is not there (naming close names) or a frame outside the clip
            (naming its frames).
        """
        c = self.clip_number(clip)
        n_frames = self.file_frames(c)
        if not 0 <= frame < n_frames:
            raise ValueError(
                f"frame {frame} is out of range: {self.clip_names[c]} has frames 0 to "
                f"{n_frames - 1} (frames count from 0; an AMC file's frame 1 is frame 0)"
            )
        rows = np.flatnonzero(self.clip_of == c)
        if len(rows) == 0:
            raise ValueError(f"clip {self.clip_names[c]!r} has no indexed pose")
        return int(rows[np.argmin(np.abs(self.frame_of[rows] - frame))])

    def file_frames(self, clip: int) -> int:
        """Frames of clip number ``clip``'s file (its last indexed frame + 1 in libraries that
        did not record it)."""
        recorded = self.meta.get("file_frames")
        if recorded and recorded[clip] is not None:
            return int(recorded[clip])
        return int(self.frame_of[self.clip_of == clip].max(initial=-1)) + 1

    def clip_number(self, clip: str | int) -> int:
        """The number of an indexed clip.

        Parameters
        ----------
        clip : str or int
            The clip's name (its path as indexed), a unique end of it (the file name, its stem,
            or trailing folders), or its number from 0; digits are read as a number only when
            no clip is named so.

        Raises
        ------
        ValueError
            Naming up to five close names when none matches, or the matches when several do.
        """
        names = self.clip_names
        if isinstance(clip, (int, np.integer)):
            if not 0 <= clip < len(names):
                raise ValueError(f"clip number {clip} is out of range 0 to {len(names) - 1}")
            return int(clip)
        text = str(clip)
        matches = [i for i, n in enumerate(names) if n == text]
        if not matches:
            matches = [i for i, n in enumerate(names) if _names_end(n, text)]
        if not matches and text.isdigit():
            return self.clip_number(int(text))
        if len(matches) == 1:
            return matches[0]
        if matches:
            listed = ", ".join(names[i] for i in matches[:5])
            more = f" and {len(matches) - 5} more" if len(matches) > 5 else ""
            raise ValueError(
                f"clip {text!r} matches {len(matches)} indexed clips ({listed}{more}); "
                "give more of the path"
            )
        stems = [pathlib.PurePath(n).stem for n in names]
        close = [m for m in stems if text.lower() in m.lower()][:5]
        close = close or difflib.get_close_matches(text, stems, n=5, cutoff=0.5)
        hint = f"; close names: {', '.join(close)}" if close else ""
        raise ValueError(
            f"no indexed clip is named {text!r} ({len(names)} clips, numbered 0 to "
            f"{len(names) - 1}){hint}"
        )

    def search(self, vectors: ArrayLike, k: int = 10) -> tuple[IntArray, FloatArray]:
        """Approximate nearest indexed poses of projected query vectors, ``(Q, k)`` each."""
        return self.index.query(vectors, k)

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
                    raise FormatError(_NOT_A_LIBRARY, path)
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
        except (IsADirectoryError, FileNotFoundError, PermissionError):
            raise
        except (KeyError, ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
            # np.load's own message (pickled data, a bad zip...) says nothing about what the
            # file should have been.
            raise FormatError(_NOT_A_LIBRARY, path) from exc


def _names_end(name: str, text: str) -> bool:
    """Whether ``text`` is the end of path ``name`` (whole components) or its file's stem."""
    path, tail = pathlib.PurePath(name), pathlib.PurePath(text)
    return path.stem == text or path.parts[-len(tail.parts) :] == tail.parts


def _positive_pairs(
    clips: Sequence[PoseClip],
    clip_offsets: labels.ClipOffsets,
    n_pairs: int,
    rng: np.random.Generator,
    say: Callable[[str], None],
) -> tuple[IntArray, str]:
    """Pose pairs ``(P, 2)`` (indices into the concatenated clips) the metric should call near,
    and where they came from."""
    positive = np.zeros((0, 2), dtype=np.int64)
    if len(clips) >= 2:
        try:
            pairs, thresholds = labels.transition_labels(
                [c.local for c in clips],
                [c.world for c in clips],
                clips[0].fps,
                n_positive=n_pairs,
                n_negative=0,
                n_queries=max(2000, 4 * n_pairs),
                random_state=rng,
            )
            p = pairs.pairs[pairs.labels]
            positive = np.stack([clip_offsets(p[:, 0], p[:, 1]), clip_offsets(p[:, 2], p[:, 3])], 1)
            say(f"{len(positive)} positive pairs below {thresholds[0]:.2f} cm")
        except ValueError as exc:
            say(f"no transition pairs ({exc})")
    if len(positive) >= _MIN_TRANSITION_PAIRS:
        return positive, "transition pairs (Kovar point-cloud distance)"
    n_poses = clip_offsets.n_poses
    within = np.flatnonzero(np.isin(np.arange(n_poses - 1) + 1, clip_offsets.starts, invert=True))
    take = rng.permutation(within)[:n_pairs]
    if len(take) == 0:
        raise ValueError("the library needs a clip of at least two frames to learn a pose distance")
    return np.stack([take, take + 1], axis=1), "consecutive frames"
