"""Tests of label generation (transition, retrieval) and of the evaluation measures."""

from __future__ import annotations

import numpy as np
import pytest

from quatmotion.pose import evaluate
from quatmotion.pose import labels as lab
from quatmotion.pose.skeleton16 import rotate_about_y

# ---------------------------------------------------------------------------------------------
# Evaluation (Eq. 36-37, precision@s)
# ---------------------------------------------------------------------------------------------


def _brute_transition_precision(d: np.ndarray, y: np.ndarray) -> float:
    best = 0.0
    for delta in np.r_[np.unique(d), np.inf]:
        n = np.count_nonzero(y & (d < delta)) + np.count_nonzero(~y & (d >= delta))
        best = max(best, n / len(d))
    return best


def test_transition_precision_known_values() -> None:
    p, thr = evaluate.transition_precision([1.0, 2.0, 3.0, 4.0], [True, True, False, False])
    assert p == 1.0 and 2.0 < thr <= 3.0
    # reversed order: nothing beats calling everything one class
    assert evaluate.transition_precision([1.0, 2.0, 3.0, 4.0], [False, False, True, True])[0] == 0.5
    # ties cannot be split by a threshold
    assert evaluate.transition_precision([1.0, 1.0], [True, False])[0] == 0.5


def test_transition_precision_matches_exhaustive_search_and_its_threshold() -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        n = int(rng.integers(1, 40))
        d = rng.integers(0, 8, size=n).astype(float)  # many ties
        y = rng.random(n) < 0.5
        p, thr = evaluate.transition_precision(d, y)
        assert p == pytest.approx(_brute_transition_precision(d, y))
        achieved = (np.count_nonzero(y & (d < thr)) + np.count_nonzero(~y & (d >= thr))) / n
        assert achieved == pytest.approx(p)


def test_transition_precision_validates() -> None:
    with pytest.raises(ValueError):
        evaluate.transition_precision([1.0, 2.0], [True])
    with pytest.raises(ValueError):
        evaluate.transition_precision([np.nan], [True])


def test_ranked_correct_and_precision_at() -> None:
    dist = np.array([[0.5, 0.1, 0.9, 0.3], [0.2, 0.4, 0.6, 0.8]])
    correct = np.array([[True, False, True, True], [False, True, True, False]])
    ranked = evaluate.ranked_correct(dist, correct, max_scope=3)
    np.testing.assert_array_equal(ranked, [[False, True, True], [False, True, True]])
    excl = np.zeros_like(correct)
    excl[0, 1] = True  # query 0 may not return base 1
    ranked = evaluate.ranked_correct(dist, correct, max_scope=3, exclude=excl)
    np.testing.assert_array_equal(ranked[0], [True, True, True])
    prec = evaluate.precision_at(ranked, [1, 2, 3])
    np.testing.assert_allclose(prec, [0.5, 0.75, 5 / 6])
    with pytest.raises(ValueError):
        evaluate.precision_at(ranked, [4])


# ---------------------------------------------------------------------------------------------
# Kovar's point-cloud distance
# ---------------------------------------------------------------------------------------------


def test_point_cloud_distance_ignores_yaw_and_floor_translation() -> None:
    rng = np.random.default_rng(1)
    a = rng.normal(scale=30, size=(6, 48, 3))
    theta = rng.uniform(-np.pi, np.pi, size=6)
    t = np.zeros((6, 1, 3))
    t[..., [0, 2]] = rng.normal(scale=200, size=(6, 1, 2))
    b = rotate_about_y(a, theta) + t
    d, th, tt = lab.point_cloud_distance(a, b, return_alignment=True)
    np.testing.assert_allclose(d, 0.0, atol=1e-5)
    np.testing.assert_allclose(rotate_about_y(b, th) + tt[:, None], a, atol=1e-8)
    # a vertical offset is not aligned away: it is the whole distance
    np.testing.assert_allclose(lab.point_cloud_distance(a, a + [0.0, 7.0, 0.0]), 7.0)


def test_point_cloud_distance_is_the_optimum_over_rotations() -> None:
    rng = np.random.default_rng(2)
    a = rng.normal(scale=30, size=(40, 3))
    b = rotate_about_y(a + rng.normal(scale=5, size=a.shape), 1.1) + [50.0, 0.0, -20.0]
    d = lab.point_cloud_distance(a, b)
    thetas = np.linspace(-np.pi, np.pi, 7201)
    rb = rotate_about_y(np.broadcast_to(b, (len(thetas), 40, 3)), thetas)
    tr = a.mean(0) - rb.mean(1)
    tr[:, 1] = 0.0
    scan = np.sqrt(np.sum((rb + tr[:, None] - a) ** 2, -1).mean(-1))
    assert d <= scan.min() + 1e-9
    assert d == pytest.approx(scan.min(), abs=1e-3)


def test_windowed_distance_clamps_at_clip_ends_and_is_zero_for_moved_copies() -> None:
    rng = np.random.default_rng(3)
    clip = np.cumsum(rng.normal(size=(30, 16, 3)), axis=0)
    moved = rotate_about_y(clip, 0.8) + [10.0, 0.0, 5.0]
    pairs = np.array([[0, 0, 1, 0], [0, 15, 1, 15], [0, 29, 1, 29], [0, 3, 1, 20]])
    d = lab.windowed_cloud_distance([clip, moved], pairs, half_window=4)
    np.testing.assert_allclose(d[:3], 0.0, atol=1e-6)
    assert d[3] > 1.0
    np.testing.assert_array_equal(
        lab.window_frames([0, 29], [30, 30], 2), [[0, 0, 0, 1, 2], [27, 28, 29, 29, 29]]
    )


# ---------------------------------------------------------------------------------------------
# Transition labels
# ---------------------------------------------------------------------------------------------


def _walk_clips(rng: np.random.Generator, n_clips: int = 6, T: int = 60) -> tuple[list, list]:
    """Clips of a swinging 16-point body with clip-specific speed and noise."""
    base = rng.normal(scale=20, size=(16, 3))
    local, world = [], []
    for c in range(n_clips):
        speed = 0.1 + 0.05 * c
        t = np.arange(T)[:, None, None]
        swing = np.sin(speed * t + rng.uniform(0, 6)) * rng.normal(scale=8, size=(1, 16, 3))
        pose = base + swing + rng.normal(scale=0.5, size=(T, 16, 3))
        local.append(pose)
        root = np.zeros((T, 1, 3))
        root[..., 2] = 3.0 * np.arange(T)[:, None]
        world.append(rotate_about_y(pose, 0.3 * c) + root)
    return local, world


def test_candidate_pairs_are_cross_clip_and_close() -> None:
    rng = np.random.default_rng(4)
    local, _ = _walk_clips(rng)
    pairs, dist = lab.candidate_pairs(local, max_mean_distance=6.0, n_queries=200, random_state=0)
    assert len(pairs) > 0
    assert np.all(pairs[:, 0] != pairs[:, 2])
    recomputed = lab.mean_joint_distance(
        np.stack([local[c][f] for c, f in pairs[:, :2]]),
        np.stack([local[c][f] for c, f in pairs[:, 2:]]),
    )
    np.testing.assert_allclose(dist, recomputed)
    assert np.all(dist < 6.0)
    only = lab.candidate_pairs(local, clips=[1, 3], max_mean_distance=6.0, n_queries=200)[0]
    assert set(np.unique(only[:, [0, 2]])) <= {1, 3}


def test_transition_labels_follow_thresholds_and_balance() -> None:
    rng = np.random.default_rng(5)
    local, world = _walk_clips(rng)
    pairs, (low, high) = lab.transition_labels(
        local, world, fps=30.0, n_positive=40, n_negative=40, max_mean_distance=8.0, n_queries=300
    )
    assert low < high
    assert pairs.labels.sum() == (~pairs.labels).sum() > 0
    assert np.all(pairs.cloud_distance[pairs.labels] < low)
    assert np.all(pairs.cloud_distance[~pairs.labels] > high)
    assert np.all(pairs.mean_distance < 8.0)
    half = int(round(30.0 / 3 / 2))
    np.testing.assert_allclose(
        pairs.cloud_distance, lab.windowed_cloud_distance(world, pairs.pairs, half)
    )
    # given thresholds are used as is
    again, thr = lab.transition_labels(
        local,
        world,
        fps=30.0,
        thresholds=(low, high),
        n_positive=10,
        n_negative=10,
        max_mean_distance=8.0,
    )
    assert thr == (low, high)
    assert np.all(again.cloud_distance[again.labels] < low)


def test_clip_offsets_round_trip() -> None:
    ix = lab.ClipOffsets(np.array([3, 0, 5]))
    np.testing.assert_array_equal(ix([0, 2, 2], [2, 0, 4]), [2, 3, 7])
    np.testing.assert_array_equal(ix.clip_of(), [0, 0, 0, 2, 2, 2, 2, 2])
    np.testing.assert_array_equal(ix.frame_of(), [0, 1, 2, 0, 1, 2, 3, 4])
    with pytest.raises(ValueError):
        ix([1], [0])


# ---------------------------------------------------------------------------------------------
# Retrieval labels
# ---------------------------------------------------------------------------------------------


def test_dtw_recovers_a_known_time_warp() -> None:
    t = np.linspace(0, 1, 80)
    ref = np.stack([np.sin(2 * np.pi * t), np.cos(3 * t), t], 1)
    warp = np.linspace(0, 1, 50) ** 1.5  # the same motion, played unevenly
    warped = np.stack([np.sin(2 * np.pi * warp), np.cos(3 * warp), warp], 1)
    ia, ib = lab.dtw_path(warped, ref)
    assert ia[0] == ib[0] == 0 and ia[-1] == 49 and ib[-1] == 79
    assert np.all(np.diff(ia) >= 0) and np.all(np.diff(ib) >= 0)
    assert np.all(np.diff(ia) + np.diff(ib) >= 1)
    phases = lab.clip_phases([warped, ref], reference=1)
    np.testing.assert_allclose(phases[1], t, atol=1e-12)
    np.testing.assert_allclose(phases[0], warp, atol=0.03)


def test_kmeans_poses_pick_one_pose_per_separated_cluster() -> None:
    rng = np.random.default_rng(6)
    centres = rng.normal(scale=100, size=(5, 16, 3))
    member = rng.integers(0, 5, size=300)
    poses = centres[member] + rng.normal(scale=1.0, size=(300, 16, 3))
    picked = lab.kmeans_poses(poses, 5, random_state=0)
    assert len(picked) == 5 and len(np.unique(member[picked])) == 5


def test_retrieval_set_and_pairs_respect_class_and_phase() -> None:
    rng = np.random.default_rng(7)
    local, classes, groups = [], [], []
    for c in range(8):
        cls = c % 2
        t = np.linspace(0, 1, 40 + 5 * c)[:, None, None]
        shape = np.full((1, 16, 3), 10.0 * (cls + 1))
        local.append(shape * (1 + t) + rng.normal(scale=0.1, size=(len(t), 16, 3)))
        classes.append(cls)
        groups.append(c // 4)
    rset = lab.retrieval_set(local, classes, groups, poses_per_group=20, random_state=0)
    assert np.all(rset.phases >= 0) and np.all(rset.phases <= 1)
    ok = rset.correct(np.arange(len(rset)), np.arange(len(rset)))
    same = rset.classes[:, None] == rset.classes[None, :]
    near = np.abs(rset.phases[:, None] - rset.phases[None, :]) <= 0.1
    np.testing.assert_array_equal(ok, same & near)
    pairs, y = lab.retrieval_pairs(rset, 30, 30, random_state=0)
    assert y.sum() == (~y).sum() > 0
    pos_in_set = {int(p): i for i, p in enumerate(rset.poses)}
    ia = np.array([pos_in_set[int(p)] for p in pairs[:, 0]])
    ib = np.array([pos_in_set[int(p)] for p in pairs[:, 1]])
    assert np.all(ok[ia[y], ib[y]]) and np.all(rset.clips[ia] != rset.clips[ib])
    assert np.all(rset.classes[ia[~y]] != rset.classes[ib[~y]])
