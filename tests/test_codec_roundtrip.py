"""Codec round trips: the requested bound holds on every frame (forward kinematics of the full
skeleton), and skeleton, fps, frame count, channels and names come back exactly."""

from __future__ import annotations

import numpy as np
import pytest

from quatmotion import codec
from quatmotion.codec.methods import METHODS, SparseMethod
from quatmotion.codec.metrics import VIRTUAL_VERTEX_CM, frame_errors
from quatmotion.codec.skeletons import same_skeleton
from quatmotion.codec.writer import build_library
from quatmotion.datasets import data_root
from quatmotion.io import parse_asf, parse_bvh, read_motion, write_bvh
from quatmotion.io.asf_amc import asf_text
from quatmotion.motion import forward_kinematics
from quatmotion.synthetic import generate_clip

DATA = data_root(must_exist=False)
REAL = {
    "cmu_amc": DATA / "cmu" / "03" / "03_02.amc",  # holds the 91 cm arm jump (frame 49)
    "cmu_bvh": DATA / "cmu_bvh" / "07" / "07_01.bvh",
    "hdm05": DATA / "hdm05" / "clips" / "kickLFront1Reps" / "HDM_bd_kickLFront1Reps_001_120.amc",
    "bandai1": DATA / "bandai1" / "clips" / "dataset-1_walk_normal_001.bvh",
}


def _assert_exact_metadata(original, decoded):
    assert decoded.name == original.name
    assert decoded.n_frames == original.n_frames
    assert decoded.fps == original.fps
    assert same_skeleton(decoded.skeleton, original.skeleton)
    assert decoded.skeleton.channels == original.skeleton.channels
    assert decoded.skeleton.joint_names == original.skeleton.joint_names


def _assert_bound(original, decoded, bound, vertices=False):
    err = frame_errors(forward_kinematics(original), decoded, vertices=vertices)
    assert err.max() <= bound * (1 + 1e-9), f"{original.name}: {err.max():.4f} cm > {bound} cm"


@pytest.fixture(scope="module")
def generated():
    return [generate_clip("walk", 1, n_frames=100), generate_clip("jump", 2, n_frames=90)]


@pytest.mark.parametrize("method", ["best", "spline", "naive"])
def test_generated_clips_meet_the_bound_exactly_described(generated, method):
    result = codec.Archive.build(
        generated, None, codec.CompressSettings(max_error=1.0, method=method)
    )
    with codec.Archive.open(result.details["data"]) as archive:
        assert archive.names() == [m.name for m in generated]
        for original in generated:
            decoded = archive.read(original.name)
            _assert_exact_metadata(original, decoded)
            _assert_bound(original, decoded, 1.0)
    # the declared errors are what a decoder measures
    for entry, original in zip(
        codec.Archive.open(result.details["data"]).entries, generated, strict=True
    ):
        decoded = codec.Archive.open(result.details["data"]).read(entry.name)
        err = frame_errors(forward_kinematics(original), decoded)
        assert entry.max_error == pytest.approx(err.max(), rel=1e-5, abs=1e-6)


@pytest.mark.parametrize("learner", ["qssd", "ksvd"])
def test_sparse_codecs_meet_the_bound_after_repair(generated, learner, monkeypatch, tmp_path):
    monkeypatch.setitem(METHODS, learner, SparseMethod(learner, max_iter=2))
    result = codec.Archive.build(
        generated, None, codec.CompressSettings(max_error=2.0, method=learner)
    )
    with codec.Archive.open(result.details["data"]) as archive:
        for original in generated:
            _assert_bound(original, archive.read(original.name), 2.0)
    # appending codes the new clip on the dictionary stored in the file
    path = tmp_path / f"{learner}.qmz"
    codec.Archive.build(generated[:1], path, codec.CompressSettings(max_error=2.0, method=learner))
    first = codec.Archive.open(path).read(0)
    codec.Archive.add(path, generated[1:], codec.CompressSettings(max_error=2.0))
    with codec.Archive.open(path) as archive:
        assert archive.names() == [m.name for m in generated]
        np.testing.assert_array_equal(archive.read(0).rotations, first.rotations)
        _assert_bound(generated[1], archive.read(1), 2.0)


def test_tight_vertex_bound(generated):
    clip = generated[0].slice(0, 40)
    result = codec.Archive.build(
        [clip], None, codec.CompressSettings(max_error=0.05, bound_on="vertices")
    )
    decoded = codec.Archive.open(result.details["data"]).read(0)
    _assert_bound(clip, decoded, 0.05, vertices=True)
    assert VIRTUAL_VERTEX_CM == 3.0


def test_ratio_mode_reaches_the_size(generated, tmp_path):
    path = tmp_path / "walk.bvh"
    write_bvh(generated[0], path)  # a BVH skeleton record is small, so high ratios are reachable
    clips = [read_motion(path)]
    sizes = [(path.stat().st_size, "bvh")]
    coarse, finer = (
        build_library(
            clips, None, codec.CompressSettings(max_error=None, ratio=ratio), source_sizes=sizes
        ).details
        for ratio in (40.0, 10.0)
    )
    assert len(coarse["data"]) <= sizes[0][0] / 40.0
    assert len(coarse["data"]) < len(finer["data"]) <= sizes[0][0] / 10.0
    assert finer["clip_errors"][0].arms < coarse["clip_errors"][0].arms


@pytest.mark.needs_data
@pytest.mark.parametrize("name", sorted(REAL))
def test_real_clip_round_trip(name, tmp_path):
    clip = read_motion(REAL[name])
    clip = clip.slice(0, min(clip.n_frames, 120 if name != "cmu_amc" else clip.n_frames))
    result = codec.Archive.build([clip], None, codec.CompressSettings(max_error=2.0))
    decoded = codec.Archive.open(result.details["data"]).read(0)
    _assert_exact_metadata(clip, decoded)
    _assert_bound(clip, decoded, 2.0)
    # a decoded clip writes to its format and the reader reads it back
    if clip.skeleton.extras.get("format") == "asf":
        from quatmotion.io import read_amc, write_amc

        write_amc(decoded, tmp_path / "x.amc")
        again = read_amc(tmp_path / "x.amc", parse_asf(asf_text(decoded.skeleton), "x.asf"))
    else:
        from quatmotion.io import write_bvh

        write_bvh(decoded, tmp_path / "x.bvh")
        again = parse_bvh((tmp_path / "x.bvh").read_text(), tmp_path / "x.bvh")
    assert again.n_frames == clip.n_frames
    p = forward_kinematics(again).positions
    assert np.abs(p - forward_kinematics(decoded).positions).max() < 1e-3


def test_repair_meets_the_bound_when_lever_arms_understate(generated, monkeypatch):
    """Stored lever arms are means over frames; a channel that moves nothing in most frames
    still has to be correctable where it matters (a bug once left 5.07 cm for a 5 cm bound)."""
    import quatmotion.codec.library as library

    real = library.measure_weights

    def understated(*args, **kwargs):
        weights, lever = real(*args, **kwargs)
        return weights * 1e-6, lever * 1e-9

    monkeypatch.setattr(library, "measure_weights", understated)
    clip = generated[1]
    result = codec.Archive.build(
        [clip], None, codec.CompressSettings(max_error=1.0, method="spline")
    )
    _assert_bound(clip, codec.Archive.open(result.details["data"]).read(0), 1.0)
