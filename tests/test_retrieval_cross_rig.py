"""The default clip search compares motion, not the rig or the stage (issue 31): a body scaled
x1.3 retrieves the same list, and the direction of travel says forward, backward or in place
whatever the clip's length."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from quatmotion.motion import Motion
from quatmotion.retrieval.features import clip_features, skeleton_fingerprint
from quatmotion.retrieval.features_fused import (
    PARTS,
    ROUTE_WEIGHTS,
    WEIGHTS,
    direction_part,
    shape_part,
    stream_dim,
)
from quatmotion.retrieval.methods import DEFAULT_METHOD, METHODS, Library, QueryFeatures
from quatmotion.synthetic import KINDS, generate_clip


def _scaled(motion: Motion, factor: float) -> Motion:
    """The same motion on a body ``factor`` times the size (every length, the root's path)."""
    sk = motion.skeleton
    skeleton = dataclasses.replace(
        sk, offsets=sk.offsets * factor, site_offsets=sk.site_offsets * factor
    )
    return Motion(skeleton, motion.fps, motion.root_translation * factor, motion.rotations)


def _reversed(motion: Motion) -> Motion:
    """The clip played backwards: a walk forward becomes a walk backward."""
    return Motion(
        motion.skeleton,
        motion.fps,
        np.ascontiguousarray(motion.root_translation[::-1]),
        np.ascontiguousarray(motion.rotations[::-1]),
    )


def _direction(motion: Motion) -> np.ndarray:
    """The direction part of a clip's features, the middle half of its frames averaged."""
    f = clip_features(motion, ("motion",))
    d = direction_part(f["frames"][:, 48:].astype(np.float64), f["path"][:, 48:])
    n = len(d)
    return d[n // 4 : 3 * n // 4].mean(axis=0)


@pytest.fixture(scope="module")
def clips() -> list[Motion]:
    return [generate_clip(k, s, n_frames=360) for k in KINDS for s in range(2)]


def test_a_scaled_body_retrieves_the_same_list(clips):
    feats = [clip_features(c, ("motion",)) for c in clips]
    prints = [skeleton_fingerprint(c.skeleton) for c in clips]
    library = Library(feats, prints)
    method = METHODS[DEFAULT_METHOD]
    for i in range(0, len(clips), 3):
        big = _scaled(clips[i], 1.3)
        query = QueryFeatures(clip_features(big, ("motion",)), skeleton_fingerprint(big.skeleton))
        original = method.rank(library, QueryFeatures(feats[i], prints[i]), exclude=i)
        scaled = method.rank(library, query, exclude=i)
        assert scaled.clips.tolist() == original.clips.tolist()
        np.testing.assert_allclose(scaled.distances, original.distances, rtol=1e-3, atol=1e-4)
        # and the scaled copy finds the original first, at a distance of nearly nothing
        assert method.rank(library, query).clips[0] == i


def test_the_direction_of_travel_is_forward_backward_or_none():
    walk = generate_clip("walk", 0, n_frames=600)
    forward = _direction(walk)
    assert forward[1] > 0.9 and abs(forward[0]) < 0.2, forward
    backward = _direction(_reversed(walk))
    assert backward[1] < -0.9 and abs(backward[0]) < 0.2, backward
    # in place: the Hip never gets far from where it started, no direction
    for kind in ("squat", "wave", "arm_circles"):
        assert np.linalg.norm(_direction(generate_clip(kind, 0, n_frames=360))) < 0.05, kind


def test_the_direction_does_not_grow_with_the_clip():
    """How far a walk goes depends on how long it is (the stage); its direction does not."""
    short = clip_features(generate_clip("walk", 1, n_frames=360), ("motion",))
    long = clip_features(generate_clip("walk", 1, n_frames=1080), ("motion",))
    reach = [float(np.max(np.linalg.norm(f["path"][:, [48, 50]], axis=1))) for f in (short, long)]
    assert reach[1] > 2.5 * reach[0]  # the route triples
    d_short, d_long = (
        direction_part(f["frames"][:, 48:].astype(np.float64), f["path"][:, 48:])
        for f in (short, long)
    )
    n = len(d_short)
    np.testing.assert_allclose(d_long[n // 4 : 3 * n // 4], d_short[n // 4 : 3 * n // 4], atol=0.05)
    # the path's shape ends where it ends for both: the farthest point at unit length
    ends = [shape_part(f["path"][:, 48:].astype(np.float64))[-1] for f in (short, long)]
    np.testing.assert_allclose(ends[0], ends[1], atol=0.1)
    assert np.linalg.norm(ends[0]) == pytest.approx(1.0, abs=0.05)


def test_the_stream_has_the_parts_of_its_weights():
    assert len(WEIGHTS) == len(ROUTE_WEIGHTS) == len(PARTS)
    assert stream_dim(WEIGHTS) == 48 + 4 + 2 + 3
    assert stream_dim(ROUTE_WEIGHTS) == 48 + 4 + 48 + 3
