"""How a pose library is built: :class:`PoseSettings` (stored in the file), the distances it can
learn (:data:`METRICS`) and the ranges its values are checked against, once, here."""

from __future__ import annotations

import dataclasses
from numbers import Integral, Real
from typing import Any, ClassVar

from quatmotion._settings import Interval, Settings, StrOptions
from quatmotion.collection import ReadSettings
from quatmotion.pose.ranges import DEFAULT_METRIC, DEFAULTS, FPS_RANGE

__all__ = ["DEFAULT_METRIC", "FPS_RANGE", "HEIGHT_RANGE", "METRICS", "PoseSettings"]

HEIGHT_RANGE = (50.0, 300.0)  # cm: a stature from a small child to beyond the tallest adult

METRICS: tuple[str, ...] = ("GPDR+LOGIT", "GPDR+LMS", "GPD+LMS", "GPD+LOGIT", "GPD+RDSR")
"""The pose distances :meth:`PoseLibrary.build` can learn."""


def _at_least(n: int) -> Interval:
    return Interval(Integral, n, None, closed="left")


@dataclasses.dataclass(frozen=True)
class PoseSettings(Settings):
    """How a pose library is built (stored in its ``meta``, shown by ``pose ls``).

    Attributes
    ----------
    fps : float
        Frame rate the poses are sampled at (:data:`FPS_RANGE`).
    height : float
        Stature of the canonical body every skeleton is put on, cm (:data:`HEIGHT_RANGE`).
    metric : str
        The pose distance learned (:data:`METRICS`).
    rank : int
        Rank of RDSR's projection.
    n_unlabeled : int
        Unlabeled poses for RDSR's sparse-representation term.
    n_pairs : int
        Transition pairs wanted (similar, and as many dissimilar for LMS).
    seed : int
        Of the sample, the pairs and the graph.
    fit_poses : int
        Poses (of clips drawn at random) the distance is learned on.
    M, ef_construction : int
        HNSW graph parameters.
    flush_poses : int
        Vectors per insertion into the graph.
    index_threads : int
        Threads inserting into the graph, in the building process. One keeps the library the
        same bytes whatever ran the jobs; more insert faster (the insertion is the part of the
        build that does not spread over workers), but the graph then depends on thread
        timing (its search results barely).
    chunk_size : int or None
        Clips per task of the index pass. Each task carries the projection model (its size:
        docs/performance.md), so by default (None) eight clips share one once there are at
        least 64 clips, else every clip is a task. The learn pass sends clips one by one.
    read : ReadSettings
        How the clips are read (``strict``: a clip beyond a kilometre is refused).
    """

    fps: float = DEFAULTS["fps"]
    height: float = DEFAULTS["height"]
    metric: str = DEFAULTS["metric"]
    rank: int = DEFAULTS["rank"]
    n_unlabeled: int = DEFAULTS["n_unlabeled"]
    n_pairs: int = DEFAULTS["n_pairs"]
    seed: int = DEFAULTS["seed"]
    fit_poses: int = DEFAULTS["fit_poses"]
    M: int = 16
    ef_construction: int = 100
    flush_poses: int = 4096
    index_threads: int = DEFAULTS["index_threads"]
    chunk_size: int | None = None
    read: ReadSettings = dataclasses.field(default_factory=ReadSettings)

    _parameter_constraints: ClassVar[dict[str, list[Any]]] = {
        "fps": [Interval(Real, *FPS_RANGE, closed="both")],
        "height": [Interval(Real, *HEIGHT_RANGE, closed="both")],
        "metric": [StrOptions(set(METRICS))],
        "rank": [_at_least(1)],
        "n_unlabeled": [_at_least(1)],
        "n_pairs": [_at_least(1)],
        "seed": [_at_least(0)],
        "fit_poses": [_at_least(1)],
        "M": [_at_least(2)],
        "ef_construction": [_at_least(1)],
        "flush_poses": [_at_least(1)],
        "index_threads": [_at_least(1)],
        "chunk_size": [_at_least(1), None],
        "read": [ReadSettings],
    }
