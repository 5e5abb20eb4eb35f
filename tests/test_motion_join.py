"""motion.join: clips one after the other, each starting where and as the previous stopped."""

from __future__ import annotations

import numpy as np
import pytest

from quatmotion.motion import join
from quatmotion.motion.clip import _heading
from quatmotion.synthetic import generate_clip


def test_each_clip_starts_where_and_facing_as_the_previous_one_stopped():
    a, b = generate_clip("walk", 1, n_frames=120), generate_clip("squat", 2, n_frames=90)
    take = join([a, b], "take")
    assert take.n_frames == 210 and take.name == "take" and take.fps == a.fps
    np.testing.assert_allclose(take.root_translation[:120], a.root_translation)
    np.testing.assert_allclose(take.root_translation[120, [0, 2]], a.root_translation[-1, [0, 2]])
    np.testing.assert_allclose(take.root_translation[120:, 1], b.root_translation[:, 1])
    assert abs(_heading(take.rotations[120, 0]) - _heading(a.rotations[-1, 0])) < 1e-9
    # the second clip's own motion is kept: its path only turned, and its body untouched
    step = np.linalg.norm(np.diff(take.root_translation[120:], axis=0), axis=1)
    np.testing.assert_allclose(step, np.linalg.norm(np.diff(b.root_translation, axis=0), axis=1))
    np.testing.assert_allclose(np.abs(take.rotations[120:, 1:]), np.abs(b.rotations[:, 1:]))


def test_join_refuses_what_does_not_concatenate():
    a = generate_clip("walk", 1, n_frames=30)
    with pytest.raises(ValueError, match="at least one"):
        join([])
    with pytest.raises(ValueError, match="fps"):
        join([a, generate_clip("walk", 2, n_frames=30, fps=60.0)])
