"""Search inside long takes: planted segments are found (subsequence DTW)."""

from __future__ import annotations

import numpy as np
import pytest

from quatmotion import quat
from quatmotion.motion import Motion
from quatmotion.retrieval.distances import find_within
from quatmotion.retrieval.features import feature_step, motion_frames
from quatmotion.synthetic import generate_clip

SEGMENT = 360  # frames at 120 fps: 3 s per planted motion


def _take(kinds: tuple[str, ...], seed: int) -> Motion:
    clips = [generate_clip(k, seed * 100 + i, n_frames=SEGMENT) for i, k in enumerate(kinds)]
    roots, end = [], np.zeros(3)
    for c in clips:  # each segment starts where the previous one stopped
        r = c.root_translation.copy()
        r[:, [0, 2]] += end[[0, 2]] - r[0, [0, 2]]
        end = r[-1]
        roots.append(r)
    rotations = quat.make_continuous(np.concatenate([c.rotations for c in clips]), axis=0)
    return Motion(
        skeleton=clips[0].skeleton,
        fps=clips[0].fps,
        root_translation=np.concatenate(roots),
        rotations=rotations,
        name="take",
    )


@pytest.mark.parametrize("seed", [0, 1])
def test_query_of_another_seed_is_found_in_its_segment(seed):
    kinds = ("squat", "jumping_jack", "kick", "arm_circles")
    take = _take(kinds, seed)
    frames, _ = motion_frames(take)
    step = feature_step(take.fps)
    for i, kind in enumerate(kinds):
        query, _ = motion_frames(generate_clip(kind, 7_000 + 10 * seed + i, n_frames=SEGMENT))
        _, start, stop = find_within(query, frames)
        lo, hi = i * SEGMENT, (i + 1) * SEGMENT
        slack = 0.1 * SEGMENT
        assert lo - slack <= start * step and stop * step <= hi + slack, (kind, start, stop)
        assert (stop - start) * step >= 0.5 * SEGMENT


def test_query_longer_than_twice_the_take_matches_nothing():
    q = np.zeros((30, 3))
    cost, start, stop = find_within(q, np.zeros((10, 3)))
    assert cost == float("inf") and start == stop == 0
