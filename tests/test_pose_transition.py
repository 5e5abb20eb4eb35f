"""Issue 20 (3): the transition classifier learned from good and bad pairs."""

from __future__ import annotations

import numpy as np
import pytest

from quatmotion.pose import evaluate, methods
from quatmotion.pose.data import PoseClip, PoseData
from quatmotion.pose.transition import TransitionClassifier, pose_rows
from quatmotion.synthetic import generate_clip


@pytest.fixture(scope="module")
def poses() -> PoseData:
    clips = [
        PoseClip.from_motion(generate_clip(k, 3, n_frames=300), fps=15, height=170)
        for k in ("walk", "run", "squat", "jump")
    ]
    return PoseData.concat([c.poses for c in clips])


def _worst_foot_labels(poses: PoseData, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Good when *each* foot moves less than 20 cm: the worst of two terms decides, as a
    blended transition's worst artefact does."""
    feet = np.asarray(poses.positions)[:, (12, 15)]
    per_foot = np.linalg.norm(feet[a] - feet[b], axis=-1)  # (P, 2)
    return per_foot.max(axis=1) < 20.0


def test_learns_a_worst_of_rule_and_ranks_held_out_pairs(poses: PoseData) -> None:
    rng = np.random.default_rng(1)
    a, b = rng.integers(0, len(poses), (2, 3000))
    good = _worst_foot_labels(poses, a, b)
    assert 0.1 < good.mean() < 0.9
    train, test = slice(0, 2000), slice(2000, None)
    model = TransitionClassifier(random_state=0).fit(
        poses[a[:500]], poses[a[train]], poses[b[train]], good[train]
    )
    p = model.distances(poses[a[test]], poses[b[test]])
    assert p.shape == (1000,) and np.all((p >= 0) & (p <= 1))
    precision, _ = evaluate.transition_precision(p, good[test])
    assert precision > 0.9
    # same seed, same numbers; pairwise agrees with the aligned pairs
    again = TransitionClassifier(random_state=0).fit(
        poses[a[:500]], poses[a[train]], poses[b[train]], good[train]
    )
    np.testing.assert_array_equal(again.distances(poses[a[test]], poses[b[test]]), p)
    grid = model.pairwise(poses[a[2000:2003]], poses[b[2000:2005]])
    assert grid.shape == (3, 5)
    np.testing.assert_allclose(np.diag(grid[:, :3]), p[:3])


def test_registered_and_refuses_one_sided_labels(poses: PoseData) -> None:
    assert methods.METHODS["PAIR-GBT"] is TransitionClassifier
    n = 40
    with pytest.raises(ValueError, match="both good and bad"):
        TransitionClassifier().fit(poses[:n], poses[:n], poses[1 : n + 1], np.ones(n, bool))
    with pytest.raises(ValueError, match="disagree"):
        TransitionClassifier().fit(poses[:n], poses[:n], poses[:n], np.ones(n - 1, bool))
    rows = pose_rows(poses[:5], None, None)
    assert rows.shape == (5, 16)  # feet positions 6, velocities 6, hip height 1, root 3
