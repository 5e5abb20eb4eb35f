"""The decoding runtime on its own (issue 32): rows and a rig made by hand, decoded to known
rotations (checked against :mod:`quatmotion.quat`, an independent implementation), the
spline between rows, and the sampler's poses equal to the whole clip's frames to the bit."""

from __future__ import annotations

import numpy as np
import pytest

from quatmotion import quat
from quatmotion.runtime.clip import ClipRows, Rig, clip_rotations
from quatmotion.runtime.sampler import ClipSampler

# joints: 0 root (heading + rotation vector), 1 Euler x then z (intrinsic), 2 rotation
# vector, 3 fixed, 4 Euler y alone
KINDS = np.array([3, 1, 2, 0, 1])
COUNTS = np.array([4, 2, 3, 0, 1])
STARTS = np.array([3, 7, 9, 12, 12])
AXES = np.array([[0, 0, 0], [0, 2, 0], [0, 0, 0], [0, 0, 0], [1, 0, 0]])
C = 13


def _rig(seed: int = 0) -> Rig:
    rng = np.random.default_rng(seed)
    ref = quat.normalize(rng.normal(size=(5, 4)))
    pre = np.zeros((5, 4, 3))
    pre[:, :3] = np.eye(3)  # the joints' axes unrotated
    pre[:, 3, 0] = 1.0  # intrinsic
    return Rig(("root", "a", "b", "c", "d"), KINDS, STARTS, COUNTS, AXES, pre, ref, C)


def _frames(X: np.ndarray, fixes=((), (), ())) -> ClipRows:
    """A clip kept frame by frame: its rows are its channels."""
    T = len(X)
    segs = np.array([[0, T, 0, 0, 0, 0]], dtype=np.int64)
    types = (np.int64, np.int64, float)
    f, c, v = (np.asarray(a, dtype=t) for a, t in zip(fixes, types, strict=True))
    return ClipRows("clip", T, 30.0, segs, np.zeros(0), np.ascontiguousarray(X),
                    np.arange(C), np.ones(C), f, c, v)  # fmt: skip


def _expected(X: np.ndarray, rig: Rig) -> np.ndarray:
    ref = rig.ref
    q = np.empty((len(X), 5, 4))
    y = quat.about_axis(X[:, 3], "y")
    q[:, 0] = quat.multiply(y, quat.multiply(ref[0], quat.exp(X[:, 4:7] / 2.0)))
    q[:, 1] = quat.multiply(quat.about_axis(X[:, 7], "x"), quat.about_axis(X[:, 8], "z"))
    q[:, 2] = quat.multiply(ref[2], quat.exp(X[:, 9:12] / 2.0))
    q[:, 3] = (1.0, 0.0, 0.0, 0.0)
    q[:, 4] = quat.about_axis(X[:, 12], "y")
    return q


def test_rows_decode_to_the_rotations_they_name():
    rng = np.random.default_rng(1)
    X = rng.uniform(-4.0, 4.0, size=(70, C))  # angles past a half turn, every quadrant
    X[5, 4:7] = 0.0  # a rotation vector of length zero: the reference itself
    rig = _rig()
    root, rot = clip_rotations(_frames(X), rig)
    assert np.array_equal(root, X[:, :3])
    assert quat.angle(rot, _expected(X, rig)).max() < 1e-12
    assert np.allclose(np.linalg.norm(rot, axis=-1), 1.0, atol=1e-14)


def test_corrections_add_to_their_frame_and_channel():
    X = np.random.default_rng(2).uniform(-1.0, 1.0, size=(10, C))
    fixed = X.copy()
    fixed[3, 7] += 0.25
    fixed[3, 7] += -0.5  # two on one channel of one frame, in order
    fixed[8, 1] += 2.0
    rig = _rig()
    root, rot = clip_rotations(_frames(X, ([3, 3, 8], [7, 7, 1], [0.25, -0.5, 2.0])), rig)
    want_root, want_rot = clip_rotations(_frames(fixed), rig)
    assert np.array_equal(root, want_root) and np.array_equal(rot, want_rot)


def test_a_channel_that_is_not_finite_is_refused():
    X = np.zeros((4, C))
    X[2, 8] = np.inf
    assert clip_rotations(_frames(X), _rig()) is None


def test_the_spline_between_rows_and_the_sampler_at_frames():
    """A spline segment of 40 frames on 8 rows: at a frame position the sampler's pose is the
    whole clip's frame to the bit, between frames the spline's channels (an affine map of
    the rows: rows all equal give that value everywhere)."""
    from quatmotion.codec.spline import knot_vector

    T, n = 40, 8
    knots = knot_vector(T, (T - 1) / (n - 3))
    assert len(knots) - 4 == n
    rng = np.random.default_rng(3)
    P = rng.uniform(-2.0, 2.0, size=(n, C))
    segs = np.array([[0, T, 0, 1, 0, len(knots)]], dtype=np.int64)
    none = np.zeros(0, dtype=np.int64)
    rows = ClipRows("s", T, 30.0, segs, knots, P, np.arange(C), np.full(C, 2.0), none, none,
                    np.zeros(0))  # fmt: skip
    rig = _rig()
    root, rot = clip_rotations(rows, rig)
    sampler = ClipSampler(rows, rig).bound()
    for f in (0, 7, 20, 39):
        if f / 30.0 * 30.0 == f:  # a time that is exactly the frame
            r, q = sampler.pose(f / 30.0)
            assert np.array_equal(r, root[f]) and np.array_equal(q, rot[f])
    s_root, s_rot = sampler.poses_at(np.arange(T, dtype=np.float64))
    assert np.array_equal(s_root, root) and np.array_equal(s_rot, rot)
    flat = ClipRows("flat", T, 30.0, segs, knots, np.tile(P[:1], (n, 1)), np.arange(C),
                    np.full(C, 2.0), none, none, np.zeros(0))  # fmt: skip
    f_root, _ = ClipSampler(flat, rig).bound().poses_at(np.linspace(0.0, T - 1.0, 57))
    assert np.allclose(f_root, P[0, :3] / 2.0, rtol=0, atol=1e-12)


def test_rotation_channels_not_coded_are_refused():
    X = np.zeros((3, C))
    rows = _frames(X)
    short = ClipRows("short", 3, 30.0, rows.segs, rows.knots, X[:, :5].copy(), np.arange(5),
                     np.ones(5), rows.fix_frames, rows.fix_channels, rows.fix_values)  # fmt: skip
    with pytest.raises(ValueError, match="rotation channels"):
        clip_rotations(short, _rig())


def test_a_first_pose_decodes_only_the_groups_it_needs():
    """Format 3's rows decode by group: a sampler's first pose decodes the one or two groups
    its rows lie in, and every pose equals the pose from rows all decoded, to the bit."""
    from quatmotion import codec
    from quatmotion.synthetic import generate_clip

    clip = generate_clip("walk", 4, n_frames=1200)
    data = codec.Archive.build(
        [clip], None, codec.CompressSettings(max_error=0.05, method="best")
    ).details["data"]
    archive = codec.Archive.open(data)
    rows = archive.clip_rows(0, lazy=True)
    assert rows.decode_groups is not None and rows.n_groups >= 3
    lazy = ClipSampler(rows, archive.rig(0)).bound()
    full = ClipSampler(archive.clip_rows(0), archive.rig(0)).bound()
    t = 0.5 * (clip.n_frames - 1) / clip.fps
    root, rot = lazy.pose(t)
    assert 1 <= lazy._flags.sum() <= 2  # the groups of this pose's rows, no more
    f_root, f_rot = full.pose(t)
    assert np.array_equal(root, f_root) and np.array_equal(rot, f_rot)
    times = np.random.default_rng(0).uniform(-0.5, clip.n_frames / clip.fps, 60)
    for t in times:
        root, rot = lazy.pose(t)
        f_root, f_rot = full.pose(t)
        assert np.array_equal(root, f_root) and np.array_equal(rot, f_rot)
    b_root, b_rot = lazy.poses(times)  # a batch decodes every group
    assert lazy._flags.all()
    f_root, f_rot = full.poses(times)
    assert np.array_equal(b_root, f_root) and np.array_equal(b_rot, f_rot)
