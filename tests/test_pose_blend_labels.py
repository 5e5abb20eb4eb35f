"""Blended-transition labels (issue 20, part 2): sanity of the synthesis and the judgement."""

from __future__ import annotations

import numpy as np
import pytest

from quatmotion.pose import blend_labels as bl
from quatmotion.pose.data import PoseClip
from quatmotion.synthetic import generate_clip

FPS = 30.0


@pytest.fixture(scope="module")
def clips() -> list[PoseClip]:
    kinds = ["walk", "run", "squat", "jump", "walk", "kick"]
    return [
        PoseClip.from_motion(generate_clip(k, s, n_frames=480), fps=FPS, height=170)
        for s, k in enumerate(kinds)
    ]


def _lying(standing: np.ndarray, n: int = 60) -> np.ndarray:
    """A body lying on its back on the floor, held still: a standing pose turned 90 degrees
    about the x axis and lowered so its lowest joint touches the floor."""
    centred = standing - standing[0]
    turned = centred @ np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]).T
    turned[:, 1] += 10.0 - turned[:, 1].min()
    return np.repeat(turned[None], n, axis=0)


def test_identity_transition_is_natural_motion_exactly(clips: list[PoseClip]) -> None:
    world = clips[0].world
    motion, contact, floors = bl.synthesise(world, 40, world, 40, FPS)
    c = int(round(bl.BlendSettings().context_s * FPS))
    n = len(motion)
    natural = world[40 - c : 40 - c + n]
    # the root-offset clean-up may remove the natural motion's own small foot slides, so the
    # body (relative to the root) is exact and the root within a few cm
    np.testing.assert_allclose(motion - motion[:, :1], natural - natural[:, :1], atol=1e-9)
    assert np.abs(motion[:, 0] - natural[:, 0]).max() < 5.0
    assert contact.shape == (n, 2) and floors.shape == (n,)


def test_same_and_next_frame_transitions_are_good_unrelated_poses_bad(
    clips: list[PoseClip],
) -> None:
    world = [c.world for c in clips]
    ref = bl.natural_reference(world, FPS, n_windows=150, random_state=1)
    rng = np.random.default_rng(0)
    same = []
    for c in range(len(clips)):
        for f in rng.integers(10, len(world[c]) - 20, 6):
            same += [[c, f, c, f], [c, f, c, f + 1]]
    artefact, _ = bl.judge(world, same, FPS, ref)
    assert np.all(artefact <= bl.GOOD_RATIO), artefact.max()
    # a lying pose into a jump, and a jump's flight into lying: bad
    lying = _lying(clips[0].world[30])
    world2 = [*world, lying]
    jump = 3
    take_off = int(np.argmax(world[jump][:, 0, 1]))
    bad = [[len(world), 30, jump, take_off], [jump, take_off, len(world), 30]]
    artefact, quantities = bl.judge(world2, bad, FPS, ref)
    assert np.all(artefact >= bl.BAD_RATIO), (artefact, quantities)


def test_good_share_is_stable_across_seeds_and_seeded(clips: list[PoseClip]) -> None:
    local = [c.local for c in clips]
    world = [c.world for c in clips]
    shares = []
    for seed in range(3):
        cand, _ = bl.candidate_pairs(local, n_queries=50, random_state=seed)
        ref = bl.natural_reference(world, FPS, n_windows=60, random_state=seed)
        artefact, _ = bl.judge(world, cand, FPS, ref)
        decided = (artefact <= bl.GOOD_RATIO) | (artefact >= bl.BAD_RATIO)
        shares.append(np.mean(artefact[decided] <= bl.GOOD_RATIO))
    assert min(shares) > 0.05 and max(shares) < 0.95  # both labels occur
    assert max(shares) - min(shares) < 0.15, shares
    a, _ = bl.blended_transition_labels(
        local, world, FPS, reference=ref, n_queries=30, random_state=4
    )
    b, _ = bl.blended_transition_labels(
        local, world, FPS, reference=ref, n_queries=30, random_state=4
    )
    np.testing.assert_array_equal(a.pairs, b.pairs)
    np.testing.assert_array_equal(a.labels, b.labels)
    assert a.labels.any() and (~a.labels).any()


def test_settings_refuse_nonsense() -> None:
    with pytest.raises(ValueError, match="blend_s"):
        bl.BlendSettings(blend_s=0)
    with pytest.raises(ValueError, match="natural_percentile"):
        bl.BlendSettings(natural_percentile=100)


def test_batched_quantities_equal_pair_by_pair(clips: list[PoseClip]) -> None:
    local = [c.local for c in clips]
    world = [c.world for c in clips]
    cand, _ = bl.candidate_pairs(local, n_queries=60, random_state=3)
    rng = np.random.default_rng(3)
    edges = np.array([[0, 0, 1, len(world[1]) - 1], [2, len(world[2]) - 1, 3, 0], [4, 5, 4, 5]])
    pairs = np.concatenate((cand[rng.permutation(len(cand))[:150]], edges))
    settings = bl.BlendSettings()
    one = bl._quantities_one_by_one(world, pairs, FPS, settings)
    np.testing.assert_allclose(
        bl._quantities(world, pairs, FPS, settings), one, rtol=1e-9, atol=1e-9
    )
    ref = bl.natural_reference(world, FPS, n_windows=60, random_state=0)
    artefact, _ = bl.judge(world, pairs, FPS, ref)
    own_pairs = np.concatenate((pairs[:, [0, 1, 0, 1]], pairs[:, [2, 3, 2, 3]]))
    own = bl._quantities_one_by_one(world, own_pairs, FPS, settings)
    scale = np.maximum(np.maximum(own[: len(pairs)], own[len(pairs) :]), ref[None])
    p = bl.QUANTITIES.index("penetration")
    scale[:, p] = np.maximum(scale[:, p], settings.penetration_floor_cm)
    expected = (one / np.maximum(scale, 1e-9)).max(axis=1)
    good = lambda a: a <= bl.GOOD_RATIO  # noqa: E731
    bad = lambda a: a >= bl.BAD_RATIO  # noqa: E731
    np.testing.assert_array_equal(good(artefact), good(expected))
    np.testing.assert_array_equal(bad(artefact), bad(expected))
