"""The default retrieval keeps what tells motions apart (issue 19): the sense of a turn, the
rhythm of a wave, and the same motion at other speeds and body sizes stays near."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from quatmotion import quat
from quatmotion.motion import Motion
from quatmotion.pose import skeleton16
from quatmotion.retrieval.features import clip_features, skeleton_fingerprint
from quatmotion.retrieval.methods import DEFAULT_METHOD, METHODS, Library, QueryFeatures
from quatmotion.synthetic import cmu_skeleton, generate_clip

FPS = 60.0


def _turned(clip: Motion, degrees_per_s: float) -> Motion:
    """``clip`` walking along a curve: its heading turns at a constant rate (positive: left,
    counter-clockwise seen from above), the root's steps rotated with it."""
    T = clip.rotations.shape[0]
    yaw = np.radians(degrees_per_s) * np.arange(T) / clip.fps
    turn = quat.about_axis(yaw, "y")
    rotations = clip.rotations.copy()
    rotations[:, 0] = quat.multiply(turn, rotations[:, 0])
    steps = np.diff(clip.root_translation, axis=0)
    steps = quat.rotate(turn[:-1], steps)
    root = np.concatenate(
        (clip.root_translation[:1], clip.root_translation[:1] + np.cumsum(steps, 0))
    )
    return replace(clip, rotations=rotations, root_translation=root)


def _held(clip: Motion, seconds: float) -> Motion:
    """``clip`` frozen from ``seconds`` on: for a wave, the same hand raised and held still."""
    k = int(round(seconds * clip.fps))
    rotations = clip.rotations.copy()
    rotations[k:] = rotations[k]
    root = clip.root_translation.copy()
    root[k:] = root[k]
    return replace(clip, rotations=rotations, root_translation=root)


def _library(clips: list[Motion]) -> Library:
    feats = [clip_features(c, ("motion",)) for c in clips]
    return Library(feats, [skeleton_fingerprint(c.skeleton) for c in clips])


def _rank(lib: Library, i: int, method: str = DEFAULT_METHOD) -> list[int]:
    q = QueryFeatures(lib.features[i], lib.fingerprints[i])
    return [int(c) for c in METHODS[method].rank(lib, q, exclude=i).clips]


@pytest.fixture(scope="module")
def turns() -> tuple[list[str], Library]:
    walks = [generate_clip("walk", seed, n_frames=300, fps=FPS) for seed in range(4)]
    clips, labels = [], []
    for k, w in enumerate(walks):
        rate = 35.0 + 5.0 * k
        for label, sign in (("left", 1.0), ("right", -1.0), ("straight", 0.0)):
            clips.append(_turned(w, sign * rate))
            labels.append(label)
    return labels, _library(clips)


@pytest.mark.parametrize("method", [DEFAULT_METHOD, "dtw-heading"])
def test_a_turn_left_never_ranks_a_turn_right_above_the_other_turns_left(turns, method):
    labels, lib = turns
    for i, label in enumerate(labels):
        if label == "straight":
            continue
        ranked = [labels[c] for c in _rank(lib, i, method)]
        opposite = "right" if label == "left" else "left"
        last_same = max(k for k, lab in enumerate(ranked) if lab == label)
        first_opposite = ranked.index(opposite)
        assert last_same < first_opposite, (i, ranked)


def test_the_turn_test_can_fail_a_method_blind_to_heading(turns):
    # posture alone (each frame in its own heading) cannot tell the sense of a turn
    labels, lib = turns
    mixed = 0
    for i, label in enumerate(labels):
        if label == "straight":
            continue
        ranked = [labels[c] for c in _rank(lib, i, "dtw-positions")][:3]
        mixed += ("right" if label == "left" else "left") in ranked
    assert mixed > 0


def _waving_side(clip: Motion) -> str:
    world = skeleton16.world_positions16(clip)
    left, right = (skeleton16.JOINTS_16.index(n) for n in ("LHand", "RHand"))
    return "l" if np.ptp(world[:, left, 1]) > np.ptp(world[:, right, 1]) else "r"


@pytest.mark.xfail(
    strict=True,
    reason="issue 19 shortfall: at 10 frames/s the fused DTW weighs a wave's rocking less than "
    "the differences of style between actors; a held raise of another wave can come first",
)
def test_a_waving_query_ranks_waves_above_raised_and_held_hands():
    # a raise: the same hand lifted the same way, then held still (no rocking)
    waves = [generate_clip("wave", seed, n_frames=240, fps=FPS) for seed in range(8)]
    raises = [_held(w, 0.9) for w in waves]
    sides = [_waving_side(w) for w in waves]
    lib = _library(waves + raises)
    n = len(waves)
    checked = 0
    for i in range(n):
        same = [k for k in range(n) if k != i and sides[k] == sides[i]]
        if not same:
            continue
        ranked = [c for c in _rank(lib, i) if c != n + i]  # its own held copy left out
        pos = {c: r for r, c in enumerate(ranked)}
        held = [n + k for k in same]
        assert max(pos[k] for k in same) < min(pos[h] for h in held), (i, ranked)
        checked += 1
    assert checked >= 4


def test_the_same_motion_faster_slower_and_on_a_taller_body_stays_in_the_top_3():
    kinds = ("walk", "squat", "kick", "jumping_jack", "wave", "punch")
    clips = [generate_clip(k, seed, n_frames=240, fps=FPS) for k in kinds for seed in (1, 2)]
    lib = _library(clips)
    base = generate_clip("squat", 7, n_frames=240, fps=FPS)
    tall = generate_clip("squat", 7, n_frames=240, fps=FPS, skeleton=cmu_skeleton(170.0 * 1.2))
    variants = {
        "0.8x": replace(base, fps=FPS * 0.8),
        "1.2x": replace(base, fps=FPS * 1.2),
        "taller": tall,
    }
    squats = {i for i, c in enumerate(clips) if c.name.startswith("squat")}
    for name, motion in variants.items():
        q = QueryFeatures(clip_features(motion, ("motion",)), skeleton_fingerprint(motion.skeleton))
        top = [int(c) for c in METHODS[DEFAULT_METHOD].rank(lib, q).clips[:3]]
        assert squats <= set(top), (name, top)
