"""Step 1 of a pose library's build: the distance learned on a sample of clips.

:func:`learn_projection` fits the registered method of the library's metric
(``quatmotion.pose.methods.METHODS[metric]``, whose ``projection_`` the library stores: ``bench
pose`` scores that same code, trained on the same kind of set, as its ``"pose index default"``
row) on :func:`training_set`: transition pairs labelled by Kovar's windowed point-cloud
distance, or consecutive frames (and, for LMS, poses at least a second apart as the dissimilar
ones) when the clips yield too few, as a library of a single clip does.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quatmotion.pose import labels
from quatmotion.pose.data import PoseClip, PoseData
from quatmotion.pose.library.settings import PoseSettings
from quatmotion.pose.library.transitions import MIN_PAIRS
from quatmotion.pose.methods import METHODS, pose_features

__all__ = ["learn_projection", "training_set"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

_FAR_APART_S = 1.0  # fallback dissimilar pairs: poses of one clip at least this far apart


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
            if similar.sum() >= MIN_PAIRS and (not dissimilar or (~similar).sum() >= MIN_PAIRS):
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


def training_set(
    clips: Sequence[PoseClip],
    *,
    n_unlabeled: int,
    n_pairs: int,
    seed: int,
    dissimilar: bool,
    say: Callable[[str], None] = lambda message: None,
) -> tuple[IntArray, IntArray, NDArray[np.bool_], str]:
    """What a library's metric learns from: unlabeled poses (N',), pose pairs (P, 2) (indices
    into the concatenated clips), whether each pair is similar, and where the pairs came from.

    Transition pairs of Kovar's point-cloud distance across clips; consecutive frames (and poses
    a second apart as dissimilar, if ``dissimilar``) when the clips yield too few. Seeded:
    the same clips and seed give the same set.
    """
    rng = np.random.default_rng(seed)
    clip_offsets = labels.ClipOffsets(np.array([len(c) for c in clips]))
    pairs, similar, pairs_from = _labelled_pairs(
        clips, clip_offsets, n_pairs, rng, say, dissimilar=dissimilar
    )
    unlabeled = rng.permutation(clip_offsets.n_poses)[:n_unlabeled]
    return unlabeled, pairs, similar, pairs_from


def learn_projection(
    clips: Sequence[PoseClip],
    settings: PoseSettings,
    *,
    estimator: Any = None,
    say: Callable[[str], None],
) -> tuple[dict[str, FloatArray], dict[str, Any], PoseData]:
    """The GPD scaling and the projection of ``settings.metric`` learned on ``clips``
    (``estimator``: RDSR's, unfitted, for a ``+RDSR`` metric; default
    ``RDSR(n_components=rank)``).

    Returns the model (``scale``, ``offset``, ``W``), the settings for the library's ``meta``
    and the clips' poses joined (their GPD computed, for the next step to reuse).
    """
    metric_name, seed = settings.metric, settings.seed
    fps, height = clips[0].fps, clips[0].height
    if any(c.fps != fps or c.height != height for c in clips):
        raise ValueError("every clip must be prepared at the same frame rate and height")
    poses = PoseData.concat([c.poses for c in clips])
    t0 = time.perf_counter()
    raw = pose_features(poses, metric_name)
    say(f"{metric_name.split('+')[0]} of {len(poses)} poses: {time.perf_counter() - t0:.1f} s")
    # The metric is the registered method of that name (one implementation with the benchmark).
    options: dict[str, Any] = {"random_state": seed}
    if metric_name.endswith("+RDSR"):
        options["n_components"] = min(settings.rank, raw.shape[1])
        if estimator is not None:
            options = {"estimator": estimator}
    method = METHODS[metric_name](**options)
    unlabeled, pairs, similar, pairs_from = training_set(
        clips, n_unlabeled=settings.n_unlabeled, n_pairs=settings.n_pairs, seed=seed,
        dissimilar=method.uses_dissimilar, say=say,
    )  # fmt: skip
    t0 = time.perf_counter()
    method.fit_features(raw[unlabeled], raw[pairs[:, 0]], raw[pairs[:, 1]], similar)
    projection = method.projection_
    W = projection["W"]
    rank = W.shape[1]
    del raw
    say(f"{metric_name} metric of rank {rank}: {time.perf_counter() - t0:.1f} s")
    model = {"scale": projection["scale"], "offset": projection["offset"], "W": W}
    meta = {
        "fps": fps,
        "height_cm": height,
        "rank": rank,
        "n_unlabeled": len(unlabeled),
        "metric": metric_name,
        "n_positive_pairs": int(similar.sum()),
        "n_negative_pairs": int((~similar).sum()),
        "positive_pairs_from": pairs_from,
        "seed": seed,
    }
    return model, meta, poses
