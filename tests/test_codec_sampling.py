"""``Archive.sample``: poses at arbitrary times, exact at frame times, the model between them."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import BSpline

from quatmotion import codec, quat
from quatmotion.codec.channels import channel_rotations
from quatmotion.codec.repair import correction_lever
from quatmotion.codec.spline import MIN_SPLINE_FRAMES, knot_vector, segment_bounds
from quatmotion.synthetic import generate_clip


@pytest.fixture(scope="module")
def clips():
    return [generate_clip("walk", 1, n_frames=100), generate_clip("jump", 2, n_frames=90)]


@pytest.fixture(scope="module", params=["best", "spline", "naive"])
def archive(request, clips):
    return codec.Archive.open(
        codec.Archive.build(
            clips, None, codec.CompressSettings(max_error=1.0, method=request.param)
        ).details["data"]
    )


def _nlerp(a, b, f):
    sign = np.where(np.sum(a * b, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    return quat.normalize((1 - f) * a + f * sign * b)


def test_frame_times_give_the_decoded_frames(archive):
    for i, entry in enumerate(archive.entries):
        root, rot = archive.read_rotations(i)
        times = np.arange(entry.n_frames) / entry.fps
        s_root, s_rot = archive.sample(i, times)
        assert s_rot.shape == rot.shape and s_root.shape == root.shape
        assert quat.angle(s_rot, rot).max() < 1e-9
        assert np.abs(s_root - root).max() < 1e-9
        assert np.allclose(np.linalg.norm(s_rot, axis=-1), 1.0, atol=1e-12)


def test_random_times_follow_the_model(archive):
    """Between frames: the spline itself (checked against SciPy's evaluation of the decoded
    coefficients) for spline methods, else the normalised lerp of the decoded frames; either way
    close to the lerp of the neighbouring frames."""
    rng = np.random.default_rng(0)
    for i, entry in enumerate(archive.entries):
        root, rot = archive.read_rotations(i)
        T = entry.n_frames
        times = rng.uniform(0, (T - 1) / entry.fps, 200)
        s_root, s_rot = archive.sample(i, times)
        u = times * entry.fps
        a = np.floor(u).astype(int)
        b = np.minimum(a + 1, T - 1)
        f = (u - a)[:, None]
        lerp_rot = _nlerp(rot[a], rot[b], f[:, :, None])
        lerp_root = (1 - f) * root[a] + f * root[b]
        if archive.header.method == "naive":
            assert quat.angle(s_rot, lerp_rot).max() < 1e-9
            assert np.abs(s_root - lerp_root).max() < 1e-9
            continue
        # close to the frames' lerp (a spline is smooth at 30-120 fps) but not equal to it
        assert quat.angle(s_rot, lerp_rot).max() < 0.05
        assert np.abs(s_root - lerp_root).max() < 1.0
        assert quat.angle(s_rot, lerp_rot).max() > 1e-6
        expected_root, expected_rot = _scipy_spline(archive, i, u)
        assert quat.angle(s_rot, expected_rot).max() < 1e-9
        assert np.abs(s_root - expected_root).max() < 1e-9


def _scipy_spline(archive, i, u):
    parts = archive.clip_parts(i)
    plan, rows, cols, scale = archive.method.decode_segments(
        parts.model, parts.payload, parts.context
    )
    C = parts.layout.layout.n_channels
    X = np.zeros((len(u), C))
    for s, ((a, b), c) in enumerate(
        zip(segment_bounds(parts.entry.n_frames, plan.breaks), rows, strict=True)
    ):
        inside = (u >= a) & (u <= b - 1)
        assert b - a >= MIN_SPLINE_FRAMES  # the generated clips have no short segments
        t = knot_vector(b - a, plan.spacing, plan.inserted.get(s, ()))
        X[np.ix_(inside, cols)] = BSpline(t, c, 3)(u[inside] - a) / scale
    # the clip's corrections, a tent over each corrected frame
    D = np.zeros((parts.entry.n_frames, C))
    parts.corrections.apply(D, correction_lever(parts.layout))
    f0 = np.floor(u).astype(int)
    f1 = np.minimum(f0 + 1, parts.entry.n_frames - 1)
    w = (u - f0)[:, None]
    X += (1 - w) * D[f0] + w * D[f1]
    rot = channel_rotations(X, parts.skeleton, parts.layout.layout, parts.layout.reference)
    return X[:, :3], rot


def test_clamp_and_loop_edges(archive):
    root, rot = archive.read_rotations(0)
    entry = archive.entries[0]
    T, fps = entry.n_frames, entry.fps
    r, q = archive.sample(0, [-5.0, -1e-3, 1e3, (T - 1) / fps + 1e-3])
    assert quat.angle(q[:2], rot[[0, 0]]).max() < 1e-9
    assert quat.angle(q[2:], rot[[T - 1, T - 1]]).max() < 1e-9
    assert np.abs(r[2:] - root[[T - 1, T - 1]]).max() < 1e-9
    # loop: period T / fps; between the last frame and the first, their lerp
    times = np.array([T / fps, 3 * T / fps + 2 / fps, -1 / fps, (T - 0.5) / fps])
    r, q = archive.sample(0, times, mode="loop")
    assert quat.angle(q[0], rot[0]).max() < 1e-9
    assert quat.angle(q[1], rot[2]).max() < 1e-9
    assert quat.angle(q[2], rot[T - 1]).max() < 1e-9
    assert quat.angle(q[3], _nlerp(rot[T - 1], rot[0], 0.5)).max() < 1e-9
    assert np.abs(r[3] - 0.5 * (root[T - 1] + root[0])).max() < 1e-9


def test_joint_subsets_and_scalar_times(archive):
    sk = archive.skeleton(archive.entries[1].skeleton)
    times = np.array([0.1, 0.25, 0.5])
    root, rot = archive.sample(1, times)
    pick = [5, 2, sk.n_joints - 1]
    r, q = archive.sample(1, times, joints=pick)
    assert q.shape == (3, 3, 4)
    assert np.abs(q - rot[:, pick]).max() < 1e-12 and np.abs(r - root).max() < 1e-12
    names = [sk.joint_names[j] for j in pick]
    _, q_named = archive.sample(1, times, joints=names)
    assert np.array_equal(q_named, q)
    r1, q1 = archive.sample(1, 0.25, joints=sk.joint_names[2])
    assert r1.shape == (3,) and q1.shape == (1, 4)
    assert np.abs(q1[0] - rot[1, 2]).max() < 1e-12
    by_name, _ = archive.sample(archive.entries[1].name, 0.25)
    assert np.array_equal(by_name, root[1])


def test_bad_arguments_are_named(archive):
    with pytest.raises(ValueError, match="mode"):
        archive.sample(0, 0.0, mode="bounce")
    with pytest.raises(ValueError, match="finite"):
        archive.sample(0, [0.0, np.nan])
    with pytest.raises(ValueError, match="1-D"):
        archive.sample(0, np.zeros((2, 2)))
    with pytest.raises(ValueError, match="times"):
        archive.sample(0, "soon")
    with pytest.raises(ValueError, match="no joint named 'tail'"):
        archive.sample(0, 0.0, joints=["tail"])
    with pytest.raises(ValueError, match="out of range"):
        archive.sample(0, 0.0, joints=[999])
    with pytest.raises(ValueError, match="joint names or indices"):
        archive.sample(0, 0.0, joints=[1.5])
    with pytest.raises(KeyError):
        archive.sample("no such clip", 0.0)


def test_corrections_are_exact_at_frames(clips, monkeypatch):
    """A clip the orchestrator repaired: its corrections are part of every sampled frame."""
    import quatmotion.codec.library as library

    real = library.measure_weights

    def understated(*args, **kwargs):
        weights, lever = real(*args, **kwargs)
        return weights * 1e-6, lever * 1e-9

    monkeypatch.setattr(library, "measure_weights", understated)
    archive = codec.Archive.open(
        codec.Archive.build(
            [clips[1]], None, codec.CompressSettings(max_error=1.0, method="spline")
        ).details["data"]
    )
    assert len(archive.clip_parts(0).corrections) > 0
    entry = archive.entries[0]
    root, rot = archive.read_rotations(0)
    s_root, s_rot = archive.sample(0, np.arange(entry.n_frames) / entry.fps)
    assert quat.angle(s_rot, rot).max() < 1e-9
    assert np.abs(s_root - root).max() < 1e-9
    _assert_one_arithmetic(archive)  # the corrections added where the channels add them


def _channels_path(archive, i):
    d = archive.read_channels(i)
    return d.channels[:, :3], channel_rotations(
        d.channels, d.skeleton, d.layout.layout, d.layout.reference
    )


def _assert_one_arithmetic(archive):
    """``read_rotations`` (one compiled call from the coefficient rows), the channels'
    rotations (what the encoder measures its bound on) and poses sampled at the frames are
    the same bits."""
    for i, entry in enumerate(archive.entries):
        root, rot = archive.read_rotations(i)
        c_root, c_rot = _channels_path(archive, i)
        assert np.array_equal(root, c_root) and np.array_equal(rot, c_rot)
        sampler = archive.sampler(i)
        frames = np.arange(entry.n_frames, dtype=np.float64)
        s_root, s_rot = sampler.poses_at(frames)
        assert np.array_equal(s_root, root) and np.array_equal(s_rot, rot)
        for f in (0, entry.n_frames // 3, entry.n_frames - 1):
            if f / entry.fps * entry.fps == f:  # a time that is exactly the frame
                r, q = sampler.pose(f / entry.fps)
                assert np.array_equal(r, root[f]) and np.array_equal(q, rot[f])


def test_one_arithmetic_from_rows_to_rotations(archive):
    _assert_one_arithmetic(archive)


def test_bench_resampling_keeps_the_shared_frames(clips):
    from quatmotion.bench.decode import resample

    clip = clips[0]  # 100 frames
    slow = resample(clip, clip.fps / 5)
    assert slow.n_frames == 20 and slow.fps == clip.fps / 5
    assert quat.angle(slow.rotations, clip.rotations[::5]).max() < 1e-9
    assert np.abs(slow.root_translation - clip.root_translation[::5]).max() < 1e-9
    half = resample(clip, clip.fps * 2)
    assert half.n_frames == 199
    mid = quat.slerp(clip.rotations[3], clip.rotations[4], 0.5)
    assert quat.angle(half.rotations[7], mid).max() < 1e-9


def test_a_bound_sampler_equals_sample(archive):
    """``Archive.sampler``: every pose, batch and joint subset is ``sample``'s to the bit, in
    both modes; ``pose`` writes into the sampler's own buffers."""
    entry = archive.entries[1]
    T, fps = entry.n_frames, entry.fps
    rng = np.random.default_rng(3)
    times = np.r_[np.arange(T) / fps, rng.uniform(-1.0, (T + 5) / fps, 40)]
    sk = archive.skeleton(entry.skeleton)
    for joints in (None, [4, 0, sk.joint_names[-1]]):
        for mode in ("clamp", "loop"):
            sampler = archive.sampler(entry.name, joints, mode=mode)
            root, rot = archive.sample(1, times, joints, mode=mode)
            b_root, b_rot = sampler.poses(times)
            assert np.array_equal(b_root, root) and np.array_equal(b_rot, rot)
            for k, t in enumerate(times):
                r, q = sampler.pose(t)
                assert np.abs(r - root[k]).max() < 1e-9 and quat.angle(q, rot[k]).max() < 1e-9
                if mode == "clamp":  # the same arithmetic: to the bit
                    assert np.array_equal(r, root[k]) and np.array_equal(q, rot[k])
    r, q = sampler.pose(0.0)
    kept = q.copy()
    assert sampler.pose(0.5)[1] is q and not np.array_equal(q, kept)  # one buffer, reused
    with pytest.raises(ValueError, match="finite"):
        sampler.pose(float("inf"))
    with pytest.raises(ValueError, match="mode"):
        archive.sampler(0, mode="bounce")


def test_a_clip_name_is_resolved_once(archive, monkeypatch):
    import quatmotion.codec.archive as archive_module

    name = archive.entries[1].name
    expected = archive.sample(1, 0.3)
    calls = []
    real = archive_module.match_clip
    monkeypatch.setattr(
        archive_module, "match_clip", lambda *a: calls.append(a) or real(*a)
    )  # a name that is no clip's own still goes through the matcher
    for _ in range(3):
        got = archive.sample(name, 0.3)
        assert np.array_equal(got[0], expected[0]) and np.array_equal(got[1], expected[1])
    assert calls == []
    with pytest.raises(KeyError):
        archive.sample("no such clip", 0.0)
    assert len(calls) == 1
