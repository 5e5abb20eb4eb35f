"""Labels for pose-distance evaluation, derived from the motion itself (no human labellers).

The GPD paper had people judge pose pairs. We have none, so the labels come from criteria the
learned pose metrics cannot see directly (they see one frame's body-local joints and
derivatives):

**Transition labels** (paper section 5.1, Kovar et al., "Motion Graphs", SIGGRAPH 2002):

1. Candidates are pose pairs from *different clips* whose mean joint distance (Eq. 35) in the
   body-local frame is under ``max_mean_distance`` (10 cm, the paper's ``tau``): the "easy"
   negatives are filtered out first, as in the paper.
2. Each candidate is scored by Kovar's windowed point-cloud distance: the 16 world joint
   positions over a window of frames centred on each pose (``2 * half_window + 1`` frames,
   edge frames repeated at clip ends), after the rigid 2D transform (rotation about the
   vertical axis and a floor-plane translation) that best aligns the second cloud to the first
   (closed form). The score is the root mean square point distance in centimetres.
3. A pair is **positive** below a low threshold, **negative** above a high one, and discarded
   in between. Thresholds are quantiles of the candidates' scores (fitted once, on training
   candidates, and reused for the test candidates).
4. Train and test pairs come from disjoint subjects; each set is balanced, 500/500 by default.

**Retrieval labels** (paper section 6): database poses are the actual frames nearest to the
centres of a k-means clustering (in the body-local frame, so every pose faces the same way) of
each clip set (a subject). Every clip of a class is aligned by dynamic time warping (DTW) to a
reference clip of its class (the clip of median length), which gives each frame a *phase* in
[0, 1]: its aligned position in the reference. A result is correct when its clip has the
query's class and its phase is within ``phase_tolerance`` (0.1) of the query's.

Pose indices
------------
Clips are lists of arrays; a pose is addressed by ``(clip, frame)``. ``ClipOffsets`` turns
those into indices into the concatenation of all clips (the order of ``PoseData.concat``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray
from sklearn.cluster import KMeans

IntArray = NDArray[np.int64]
FloatArray = NDArray[np.float64]


# --------------------------------------------------------------------------------------------
# Distances
# --------------------------------------------------------------------------------------------


def mean_joint_distance(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """Mean Euclidean distance between corresponding joints (paper Eq. 35).

    Parameters
    ----------
    a, b : array_like, shape (..., J, 3)
        Joint positions, centimetres (broadcast against each other).

    Returns
    -------
    ndarray, shape (...)
        Centimetres.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    return np.linalg.norm(a - b, axis=-1).mean(axis=-1)


def point_cloud_distance(
    cloud_a: ArrayLike, cloud_b: ArrayLike, return_alignment: bool = False
) -> FloatArray | tuple[FloatArray, FloatArray, FloatArray]:
    """Kovar et al.'s point-cloud distance after the optimal rigid 2D alignment.

    Finds, for each pair of clouds, the rotation ``theta`` about Y and the floor translation
    ``(t_x, t_z)`` minimising ``sum_k ||a_k - (R_y(theta) b_k + t)||^2`` (closed form: centre
    both clouds in XZ; ``theta = atan2(S, C)`` with ``C = sum(a_x b_x + a_z b_z)`` and
    ``S = sum(a_x b_z - a_z b_x)`` over centred coordinates), and returns the root mean square
    residual. Heights are not aligned: a crouch stays different from a stand.

    Parameters
    ----------
    cloud_a, cloud_b : array_like, shape (..., K, 3)
        Point clouds with corresponding points (K = frames x joints), centimetres, Y up.
    return_alignment : bool
        Also return ``theta`` (radians) and ``t`` (shape (..., 3), centimetres, ``t_y = 0``).

    Returns
    -------
    distance : ndarray, shape (...)
        Root mean square distance between ``a_k`` and the aligned ``b_k``, centimetres.
    theta, translation : ndarray
        Only with ``return_alignment``: ``aligned_b = R_y(theta) b + translation``.
    """
    a = np.asarray(cloud_a, dtype=np.float64)
    b = np.asarray(cloud_b, dtype=np.float64)
    if a.shape != b.shape or a.shape[-1] != 3 or a.ndim < 2:
        raise ValueError(f"clouds must share a shape (..., K, 3), got {a.shape} and {b.shape}")
    axz = a[..., [0, 2]]
    bxz = b[..., [0, 2]]
    ma, mb = axz.mean(axis=-2, keepdims=True), bxz.mean(axis=-2, keepdims=True)
    ca, cb = axz - ma, bxz - mb
    C = np.sum(ca[..., 0] * cb[..., 0] + ca[..., 1] * cb[..., 1], axis=-1)
    S = np.sum(ca[..., 0] * cb[..., 1] - ca[..., 1] * cb[..., 0], axis=-1)
    # With R_y(theta): (x, z) -> (x cos + z sin, -x sin + z cos), sum a'.(R b') equals
    # C cos(theta) + S sin(theta), at most hypot(C, S), reached at theta = atan2(S, C).
    horizontal = np.sum(ca**2, axis=(-1, -2)) + np.sum(cb**2, axis=(-1, -2)) - 2 * np.hypot(C, S)
    vertical = np.sum((a[..., 1] - b[..., 1]) ** 2, axis=-1)
    K = a.shape[-2]
    dist = np.sqrt(np.maximum(horizontal + vertical, 0.0) / K)
    if not return_alignment:
        return dist
    theta = np.arctan2(S, C)
    c, s = np.cos(theta), np.sin(theta)
    mbx, mbz = mb[..., 0, 0], mb[..., 0, 1]
    t = np.zeros((*dist.shape, 3))
    t[..., 0] = ma[..., 0, 0] - (mbx * c + mbz * s)
    t[..., 2] = ma[..., 0, 1] - (-mbx * s + mbz * c)
    return dist, theta, t


def window_frames(frames: ArrayLike, n_frames: ArrayLike, half_window: int) -> IntArray:
    """Frame indices of windows centred on ``frames``, clamped to each clip.

    Parameters
    ----------
    frames : array_like of int, shape (P,)
    n_frames : array_like of int, shape (P,)
        Length of the clip each frame belongs to.
    half_window : int

    Returns
    -------
    ndarray of int, shape (P, 2 * half_window + 1)
    """
    f = np.asarray(frames, dtype=np.int64)[:, None]
    n = np.asarray(n_frames, dtype=np.int64)[:, None]
    offsets = np.arange(-half_window, half_window + 1)[None, :]
    return np.clip(f + offsets, 0, n - 1)


def windowed_cloud_distance(
    world: Sequence[FloatArray], pairs: ArrayLike, half_window: int
) -> FloatArray:
    """Kovar's distance of pose pairs over windows of frames around both poses.

    Parameters
    ----------
    world : sequence of ndarray, each shape (T_c, 16, 3)
        World joint positions of every clip, centimetres, Y up.
    pairs : array_like of int, shape (P, 4)
        Rows ``(clip_a, frame_a, clip_b, frame_b)``.
    half_window : int
        The window has ``2 * half_window + 1`` frames (edge frames repeated at clip ends).

    Returns
    -------
    ndarray, shape (P,)
        Root mean square point distance after the optimal 2D alignment, centimetres.
    """
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 4)
    lengths = np.array([len(w) for w in world], dtype=np.int64)
    out = np.empty(len(pairs))
    for start in range(0, len(pairs), 4096):  # bounded memory
        chunk = pairs[start : start + 4096]
        clouds = []
        for col in (0, 2):
            clip, frame = chunk[:, col], chunk[:, col + 1]
            win = window_frames(frame, lengths[clip], half_window)
            cloud = np.stack([world[c][w] for c, w in zip(clip, win, strict=True)])
            clouds.append(cloud.reshape(len(chunk), -1, 3))
        out[start : start + len(chunk)] = point_cloud_distance(clouds[0], clouds[1])
    return out


@numba.njit(cache=True, parallel=True)
def _mean_distance_block(query: FloatArray, base: FloatArray) -> FloatArray:  # pragma: no cover
    Q, B, J = query.shape[0], base.shape[0], query.shape[1]
    out = np.empty((Q, B))
    for q in numba.prange(Q):
        for b in range(B):
            acc = 0.0
            for j in range(J):
                dx = query[q, j, 0] - base[b, j, 0]
                dy = query[q, j, 1] - base[b, j, 1]
                dz = query[q, j, 2] - base[b, j, 2]
                acc += np.sqrt(dx * dx + dy * dy + dz * dz)
            out[q, b] = acc / J
    return out


def mean_joint_distance_matrix(query: ArrayLike, base: ArrayLike) -> FloatArray:
    """Eq. 35 between every query pose and every base pose.

    Parameters
    ----------
    query : array_like, shape (Q, J, 3)
    base : array_like, shape (B, J, 3)

    Returns
    -------
    ndarray, shape (Q, B)
        Centimetres.
    """
    q = np.ascontiguousarray(query, dtype=np.float64)
    b = np.ascontiguousarray(base, dtype=np.float64)
    if q.ndim != 3 or b.ndim != 3 or q.shape[1:] != b.shape[1:] or q.shape[2] != 3:
        raise ValueError(f"need (Q, J, 3) and (B, J, 3) poses, got {q.shape} and {b.shape}")
    return _mean_distance_block(q, b)


# --------------------------------------------------------------------------------------------
# Pose addressing
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ClipOffsets:
    """Where each clip starts in the concatenation of all clips' frames.

    Maps ``(clip, frame)`` to an index into the concatenation (``ClipOffsets(lengths)(c, f)``)
    and back (:meth:`clip_of`, :meth:`frame_of`).

    Parameters
    ----------
    lengths : ndarray of int, shape (C,)
        Frame count of each clip, in concatenation order.
    """

    lengths: IntArray

    def __post_init__(self) -> None:
        lengths = np.asarray(self.lengths, dtype=np.int64)
        if lengths.ndim != 1 or np.any(lengths < 0):
            raise ValueError("lengths must be a 1-D array of non-negative frame counts")
        object.__setattr__(self, "lengths", lengths)

    @property
    def starts(self) -> IntArray:
        """First index of each clip, shape (C,)."""
        return np.r_[0, np.cumsum(self.lengths)[:-1]].astype(np.int64)

    @property
    def n_poses(self) -> int:
        return int(self.lengths.sum())

    def __call__(self, clip: ArrayLike, frame: ArrayLike) -> IntArray:
        """Global indices of ``(clip, frame)`` pairs (arrays of equal shape)."""
        clip = np.asarray(clip, dtype=np.int64)
        frame = np.asarray(frame, dtype=np.int64)
        if np.any(frame < 0) or np.any(frame >= self.lengths[clip]):
            raise ValueError("frame out of range for its clip")
        return self.starts[clip] + frame

    def clip_of(self) -> IntArray:
        """Clip of every global pose index, shape (N,)."""
        return np.repeat(np.arange(len(self.lengths)), self.lengths)

    def frame_of(self) -> IntArray:
        """Frame (within its clip) of every global pose index, shape (N,)."""
        return np.arange(self.n_poses) - np.repeat(self.starts, self.lengths)


# --------------------------------------------------------------------------------------------
# Transition labels
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TransitionPairs:
    """Labelled pose pairs for transition decision.

    Attributes
    ----------
    pairs : ndarray of int, shape (P, 4)
        ``(clip_a, frame_a, clip_b, frame_b)`` rows (clip indices into the caller's clip list).
    labels : ndarray of bool, shape (P,)
        True for a good transition (positive, similar).
    cloud_distance : ndarray, shape (P,)
        Kovar's windowed point-cloud distance that decided the label, centimetres.
    mean_distance : ndarray, shape (P,)
        Eq. 35 mean joint distance of the pair in the body frame, centimetres.
    """

    pairs: IntArray
    labels: NDArray[np.bool_]
    cloud_distance: FloatArray
    mean_distance: FloatArray

    def __len__(self) -> int:
        return len(self.labels)

    def subset(self, idx: ArrayLike) -> TransitionPairs:
        """The pairs at ``idx`` (integer or boolean index)."""
        return TransitionPairs(
            self.pairs[idx], self.labels[idx], self.cloud_distance[idx], self.mean_distance[idx]
        )


def candidate_pairs(
    local: Sequence[FloatArray],
    clips: ArrayLike | None = None,
    max_mean_distance: float = 10.0,
    n_queries: int = 2000,
    max_per_query: int = 4,
    random_state: int | np.random.Generator | None = 0,
) -> tuple[IntArray, FloatArray]:
    """Pose pairs from different clips closer than ``max_mean_distance`` (Eq. 35).

    Parameters
    ----------
    local : sequence of ndarray, each shape (T_c, 16, 3)
        Body-local joint positions of every clip, centimetres.
    clips : array_like of int, optional
        The clips to draw from (default all); both poses of a pair come from this set.
    max_mean_distance : float
        The paper's ``tau``, centimetres.
    n_queries : int
        Query poses drawn at random; each is compared with every pose of the other clips.
    max_per_query : int
        At most this many candidates (drawn at random) are kept per query pose, so that long
        stretches of near-identical frames do not dominate.
    random_state : int or Generator

    Returns
    -------
    pairs : ndarray of int, shape (P, 4)
        ``(clip_a, frame_a, clip_b, frame_b)`` with ``clip_a != clip_b``.
    mean_distance : ndarray, shape (P,)
        Centimetres.
    """
    rng = np.random.default_rng(random_state)
    clips = np.arange(len(local)) if clips is None else np.asarray(clips, dtype=np.int64)
    if len(clips) < 2:
        raise ValueError("need at least two clips to form cross-clip pairs")
    poses = np.concatenate([local[c] for c in clips]).astype(np.float64)
    clip_of = np.concatenate([np.full(len(local[c]), c) for c in clips])
    frame_of = np.concatenate([np.arange(len(local[c])) for c in clips])
    n = len(poses)
    queries = rng.choice(n, size=min(n_queries, n), replace=False)
    rows, dists = [], []
    for start in range(0, len(queries), 256):
        qi = queries[start : start + 256]
        d = mean_joint_distance_matrix(poses[qi], poses)
        for k, q in enumerate(qi):
            ok = np.flatnonzero((d[k] < max_mean_distance) & (clip_of != clip_of[q]))
            if ok.size > max_per_query:
                ok = rng.choice(ok, size=max_per_query, replace=False)
            for b in ok:
                rows.append((clip_of[q], frame_of[q], clip_of[b], frame_of[b]))
                dists.append(d[k, b])
    pairs = np.array(rows, dtype=np.int64).reshape(-1, 4)
    return pairs, np.array(dists, dtype=np.float64)


def label_thresholds(
    cloud_distances: ArrayLike, low_quantile: float = 0.3, high_quantile: float = 0.6
) -> tuple[float, float]:
    """Low and high thresholds on Kovar distances, as quantiles of the candidates' scores.

    Parameters
    ----------
    cloud_distances : array_like, shape (P,)
        Centimetres.
    low_quantile, high_quantile : float
        ``0 < low < high < 1``; the pairs between the two are discarded as ambiguous.

    Returns
    -------
    low, high : float
        Centimetres.
    """
    if not 0 < low_quantile < high_quantile < 1:
        raise ValueError("need 0 < low_quantile < high_quantile < 1")
    d = np.asarray(cloud_distances, dtype=np.float64)
    if d.size == 0:
        raise ValueError("no candidate distances to take quantiles of")
    low, high = np.quantile(d, [low_quantile, high_quantile])
    return float(low), float(high)


def transition_labels(
    local: Sequence[FloatArray],
    world: Sequence[FloatArray],
    fps: float,
    clips: ArrayLike | None = None,
    thresholds: tuple[float, float] | None = None,
    n_positive: int = 500,
    n_negative: int = 500,
    window_seconds: float = 1 / 3,
    max_mean_distance: float = 10.0,
    n_queries: int = 4000,
    low_quantile: float = 0.3,
    high_quantile: float = 0.6,
    random_state: int | np.random.Generator | None = 0,
) -> tuple[TransitionPairs, tuple[float, float]]:
    """Balanced positive/negative transition pairs from ``clips`` (see the module docstring).

    Parameters
    ----------
    local : sequence of ndarray, each shape (T_c, 16, 3)
        Body-local joint positions of every clip, centimetres.
    world : sequence of ndarray, each shape (T_c, 16, 3)
        World joint positions of the same clips, centimetres, Y up.
    fps : float
        Frame rate of the clips (all equal), for the window length.
    clips : array_like of int, optional
        Clips to draw pairs from (default all), e.g. the clips of the training subjects.
    thresholds : (float, float), optional
        ``(low, high)`` in centimetres; by default the ``low_quantile`` and ``high_quantile``
        of these candidates' Kovar distances.
    n_positive, n_negative : int
        Wanted counts; fewer are returned (with a smaller balanced count) if not available.
    window_seconds : float
        Length of Kovar's window (centred on the pose).
    max_mean_distance : float
        Eq. 35 filter, centimetres.
    n_queries : int
        Query poses drawn to find candidates (see :func:`candidate_pairs`).
    low_quantile, high_quantile : float
        Used when ``thresholds`` is not given.
    random_state : int or Generator

    Returns
    -------
    pairs : TransitionPairs
        Positives first, then negatives, each in random order; balanced to
        ``min(n_positive, n_negative, available)`` per side when ``n_positive == n_negative``.
    thresholds : (float, float)
        The thresholds used (to reuse on the test subjects).
    """
    if fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    if len(local) != len(world):
        raise ValueError("local and world must list the same clips")
    rng = np.random.default_rng(random_state)
    cand, mean_d = candidate_pairs(
        local, clips, max_mean_distance, n_queries=n_queries, random_state=rng
    )
    if len(cand) == 0:
        raise ValueError(f"no pose pairs from different clips are within {max_mean_distance} cm")
    half = max(1, int(round(window_seconds * fps / 2)))
    cloud = windowed_cloud_distance(world, cand, half)
    if thresholds is None:
        thresholds = label_thresholds(cloud, low_quantile, high_quantile)
    low, high = thresholds
    pos = np.flatnonzero(cloud < low)
    neg = np.flatnonzero(cloud > high)
    keep, labels = balanced_sample(pos, neg, n_positive, n_negative, rng)
    return TransitionPairs(cand[keep], labels, cloud[keep], mean_d[keep]), (low, high)


def balanced_sample(
    pos: IntArray, neg: IntArray, n_positive: int, n_negative: int, rng: np.random.Generator
) -> tuple[IntArray, NDArray[np.bool_]]:
    """Up to ``n_positive`` of the candidates ``pos`` and ``n_negative`` of ``neg``, drawn at
    random (as many of each when the two are asked alike), and their labels (True: positive).
    """
    if n_positive == n_negative:
        n_positive = n_negative = min(n_positive, len(pos), len(neg))
    pos = rng.permutation(pos)[:n_positive]
    neg = rng.permutation(neg)[:n_negative]
    return np.r_[pos, neg], np.r_[np.ones(len(pos), bool), np.zeros(len(neg), bool)]


# --------------------------------------------------------------------------------------------
# Retrieval labels
# --------------------------------------------------------------------------------------------


def kmeans_poses(local: ArrayLike, n_poses: int, random_state: int | None = 0) -> IntArray:
    """Indices of the actual poses nearest to the centres of a k-means clustering.

    Parameters
    ----------
    local : array_like, shape (N, 16, 3)
        Body-local poses (same yaw, so the clustering ignores facing), centimetres.
    n_poses : int
        Number of clusters (``<= N``).
    random_state : int, optional

    Returns
    -------
    ndarray of int, shape (n,)
        Sorted, distinct indices into ``local`` (``n <= n_poses``: two centres can share their
        nearest pose).
    """
    x = np.asarray(local, dtype=np.float64)
    x = x.reshape(len(x), -1)
    if not 1 <= n_poses <= len(x):
        raise ValueError(f"n_poses must lie in 1..{len(x)}, got {n_poses}")
    km = KMeans(n_clusters=n_poses, n_init=1, random_state=random_state).fit(x)
    # nearest actual pose to each centre (squared Euclidean via the Gram trick)
    d = (
        np.sum(km.cluster_centers_**2, axis=1)[:, None]
        - 2 * km.cluster_centers_ @ x.T
        + np.sum(x**2, axis=1)[None, :]
    )
    return np.unique(np.argmin(d, axis=1))


@numba.njit(cache=True)
def _dtw(cost: FloatArray) -> tuple[IntArray, IntArray]:  # pragma: no cover
    n, m = cost.shape
    acc = np.full((n + 1, m + 1), np.inf)
    acc[0, 0] = 0.0
    for i in range(1, n + 1):
        for j in range(1, m + 1):
            best = acc[i - 1, j - 1]
            if acc[i - 1, j] < best:
                best = acc[i - 1, j]
            if acc[i, j - 1] < best:
                best = acc[i, j - 1]
            acc[i, j] = cost[i - 1, j - 1] + best
    ia = np.empty(n + m, np.int64)
    ib = np.empty(n + m, np.int64)
    i, j, k = n, m, 0
    while i > 0 and j > 0:
        ia[k] = i - 1
        ib[k] = j - 1
        k += 1
        diag, up, left = acc[i - 1, j - 1], acc[i - 1, j], acc[i, j - 1]
        if diag <= up and diag <= left:
            i -= 1
            j -= 1
        elif up <= left:
            i -= 1
        else:
            j -= 1
    return ia[:k][::-1].copy(), ib[:k][::-1].copy()


def dtw_path(a: ArrayLike, b: ArrayLike) -> tuple[IntArray, IntArray]:
    """Dynamic time warping of two pose sequences (Euclidean frame cost, steps (1,0),(0,1),(1,1)).

    Parameters
    ----------
    a : array_like, shape (Ta, ...)
    b : array_like, shape (Tb, ...)
        Frames are flattened; both must have the same per-frame size.

    Returns
    -------
    ia, ib : ndarray of int, shape (L,)
        The warping path, from ``(0, 0)`` to ``(Ta - 1, Tb - 1)``, monotone in both.
    """
    x = np.asarray(a, dtype=np.float64).reshape(len(a), -1)
    y = np.asarray(b, dtype=np.float64).reshape(len(b), -1)
    if x.shape[1] != y.shape[1] or len(x) == 0 or len(y) == 0:
        raise ValueError(f"cannot align sequences of shapes {x.shape} and {y.shape}")
    cost = np.sqrt(
        np.maximum(np.sum(x**2, 1)[:, None] - 2 * x @ y.T + np.sum(y**2, 1)[None, :], 0.0)
    )
    return _dtw(cost)


def clip_phases(clips: Sequence[ArrayLike], reference: int | None = None) -> list[FloatArray]:
    """Phase of every frame of clips of one class, by DTW to a reference clip.

    Parameters
    ----------
    clips : sequence of array_like, each shape (T_c, 16, 3)
        Body-local poses of the clips of one class.
    reference : int, optional
        Index of the reference clip; default the clip of median length.

    Returns
    -------
    list of ndarray, each shape (T_c,)
        Phase in [0, 1]: the mean reference frame aligned to each frame, divided by the
        reference's last frame index (the reference's own phases are ``t / (T - 1)``).
    """
    if len(clips) == 0:
        return []
    lengths = [len(c) for c in clips]
    if reference is None:
        reference = int(np.argsort(lengths, kind="stable")[len(lengths) // 2])
    ref = np.asarray(clips[reference])
    denom = max(len(ref) - 1, 1)
    phases = []
    for c in clips:
        ia, ib = dtw_path(c, ref)
        total = np.bincount(ia, weights=ib, minlength=len(c))
        count = np.bincount(ia, minlength=len(c))
        phases.append(total / count / denom)
    return phases


@dataclass(frozen=True)
class RetrievalSet:
    """Database poses for retrieval evaluation with their class, phase and clip.

    Attributes
    ----------
    poses : ndarray of int, shape (N,)
        Global pose indices (see :class:`ClipOffsets`).
    classes : ndarray of int, shape (N,)
        Class of each pose's clip.
    phases : ndarray, shape (N,)
        DTW phase of each pose in [0, 1].
    clips : ndarray of int, shape (N,)
        Clip of each pose.
    groups : ndarray of int, shape (N,)
        Clip set (subject) of each pose.
    """

    poses: IntArray
    classes: IntArray
    phases: FloatArray
    clips: IntArray
    groups: IntArray

    def __len__(self) -> int:
        return len(self.poses)

    def subset(self, idx: ArrayLike) -> RetrievalSet:
        """The poses at ``idx``."""
        return RetrievalSet(
            self.poses[idx], self.classes[idx], self.phases[idx], self.clips[idx], self.groups[idx]
        )

    def correct(
        self, query: ArrayLike, base: ArrayLike, phase_tolerance: float = 0.1
    ) -> NDArray[np.bool_]:
        """Whether each base pose is a correct result for each query (same class, near phase).

        Parameters
        ----------
        query, base : array_like of int, shapes (Q,), (B,)
            Positions in this set.
        phase_tolerance : float
            Largest phase difference still correct.

        Returns
        -------
        ndarray of bool, shape (Q, B)
        """
        q, b = np.asarray(query), np.asarray(base)
        same = self.classes[q][:, None] == self.classes[b][None, :]
        near = np.abs(self.phases[q][:, None] - self.phases[b][None, :]) <= phase_tolerance
        return same & near

    def same_clip(self, query: ArrayLike, base: ArrayLike) -> NDArray[np.bool_]:
        """Whether each base pose comes from the query's clip, shape (Q, B)."""
        q, b = np.asarray(query), np.asarray(base)
        return self.clips[q][:, None] == self.clips[b][None, :]


def retrieval_set(
    local: Sequence[FloatArray],
    classes: ArrayLike,
    groups: ArrayLike,
    poses_per_group: int = 200,
    clips: ArrayLike | None = None,
    random_state: int | None = 0,
) -> RetrievalSet:
    """Database poses chosen by k-means per clip set, with classes and DTW phases.

    Parameters
    ----------
    local : sequence of ndarray, each shape (T_c, 16, 3)
        Body-local poses of every clip, centimetres.
    classes : array_like of int, shape (C,)
        Class of each clip.
    groups : array_like of int, shape (C,)
        Clip set (subject) of each clip; k-means runs once per group.
    poses_per_group : int
        k of each k-means (capped by the group's pose count).
    clips : array_like of int, optional
        Restrict to these clips (default all).
    random_state : int, optional

    Returns
    -------
    RetrievalSet
        Phases come from aligning every clip (of *all* listed clips) of a class to that class's
        reference, so phases are comparable across groups.
    """
    classes = np.asarray(classes, dtype=np.int64)
    groups = np.asarray(groups, dtype=np.int64)
    if len(classes) != len(local) or len(groups) != len(local):
        raise ValueError("classes and groups need one entry per clip")
    chosen_clips = np.arange(len(local)) if clips is None else np.asarray(clips, dtype=np.int64)
    clip_offsets = ClipOffsets(np.array([len(c) for c in local]))
    phase_of: dict[int, FloatArray] = {}
    for cls in np.unique(classes[chosen_clips]):
        members = [int(c) for c in chosen_clips if classes[c] == cls]
        for c, ph in zip(members, clip_phases([local[c] for c in members]), strict=True):
            phase_of[c] = ph
    out_poses, out_clips, out_frames = [], [], []
    for g in np.unique(groups[chosen_clips]):
        members = [int(c) for c in chosen_clips if groups[c] == g]
        stacked = np.concatenate([local[c] for c in members])
        clip_ids = np.concatenate([np.full(len(local[c]), c) for c in members])
        frames = np.concatenate([np.arange(len(local[c])) for c in members])
        pick = kmeans_poses(stacked, min(poses_per_group, len(stacked)), random_state)
        out_clips.append(clip_ids[pick])
        out_frames.append(frames[pick])
    clip_arr = np.concatenate(out_clips)
    frame_arr = np.concatenate(out_frames)
    out_poses = clip_offsets(clip_arr, frame_arr)
    phases = np.array([phase_of[c][f] for c, f in zip(clip_arr, frame_arr, strict=True)])
    return RetrievalSet(out_poses, classes[clip_arr], phases, clip_arr, groups[clip_arr])


def retrieval_pairs(
    rset: RetrievalSet,
    n_positive: int = 500,
    n_negative: int = 500,
    phase_tolerance: float = 0.1,
    random_state: int | np.random.Generator | None = 0,
) -> tuple[IntArray, NDArray[np.bool_]]:
    """Balanced training pairs from a retrieval set: correct pairs vs other-class pairs.

    Parameters
    ----------
    rset : RetrievalSet
    n_positive, n_negative : int
    phase_tolerance : float
    random_state : int or Generator

    Returns
    -------
    pairs : ndarray of int, shape (P, 2)
        Global pose indices ``(a, b)`` from different clips.
    labels : ndarray of bool, shape (P,)
        True for same class and phase within tolerance; False for different classes.
    """
    rng = np.random.default_rng(random_state)
    n = len(rset)
    idx = np.arange(n)
    ok = rset.correct(idx, idx, phase_tolerance) & ~rset.same_clip(idx, idx)
    other = rset.classes[:, None] != rset.classes[None, :]
    iu = np.triu_indices(n, k=1)
    pos = np.flatnonzero(ok[iu])
    neg = np.flatnonzero(other[iu])
    n_pos = min(n_positive, len(pos))
    n_neg = min(n_negative, len(neg))
    if n_positive == n_negative:
        n_pos = n_neg = min(n_pos, n_neg)
    pos = rng.choice(pos, size=n_pos, replace=False)
    neg = rng.choice(neg, size=n_neg, replace=False)
    keep = np.r_[pos, neg]
    pairs = np.stack([rset.poses[iu[0][keep]], rset.poses[iu[1][keep]]], axis=1)
    labels = np.r_[np.ones(n_pos, bool), np.zeros(n_neg, bool)]
    return pairs, labels
