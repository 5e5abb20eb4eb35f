"""Tests of the streamed pose-library build (``PoseLibrary.build_streamed``) and of ``pose
index`` on the execution layer: the same library on every scheduler, bad clips skipped and
reported, the model of a small library equal to the in-memory build's."""

from __future__ import annotations

import functools
import pathlib

import numpy as np
import pytest
from sklearn.decomposition import PCA

from quatmotion.bench.scale import generated_pose_clip
from quatmotion.parallel import Runner
from quatmotion.pose.library import PoseLibrary, PoseSettings

# RDSR's fit takes minutes (tested in test_pose_rdsr.py); the plumbing is under test here, so a
# PCA projection of the same interface (fit(X, pairs), components_ (rank, D)) stands in.
RANK = 8
LOAD = functools.partial(generated_pose_clip, fps=30.0, height=170.0)
SPECS = [(kind, seed, 40 + 7 * seed) for seed, kind in enumerate(["walk", "squat", "kick"] * 3)]


def _build(specs: list, workers: int, fit_poses: int = 20_000) -> tuple[PoseLibrary, list]:
    settings = PoseSettings(rank=RANK, n_unlabeled=200, n_pairs=40, flush_poses=100,
                            fit_poses=fit_poses)  # fmt: skip
    return PoseLibrary.build_streamed(
        specs, LOAD, settings, runner=Runner.resolve(workers=workers),
        estimator=PCA(n_components=RANK, random_state=0),
    )  # fmt: skip


def test_streamed_build_is_the_same_inline_and_on_two_workers() -> None:
    inline, failures = _build(SPECS, fit_poses=200, workers=1)
    pooled, _ = _build(SPECS, fit_poses=200, workers=2)
    assert failures == []
    assert inline.meta["fit_clips"] < len(SPECS)  # learned on a sample
    assert inline.index.to_bytes() == pooled.index.to_bytes()
    np.testing.assert_array_equal(inline.clip_of, pooled.clip_of)
    np.testing.assert_array_equal(inline.frame_of, pooled.frame_of)
    for key in inline.model:
        np.testing.assert_array_equal(inline.model[key], pooled.model[key])
    lengths = [s[2] for s in SPECS]
    assert inline.index.n_items_ == sum(lengths)
    np.testing.assert_array_equal(np.bincount(inline.clip_of), lengths)
    # every pose finds itself: the vectors went in under their own catalogue numbers
    clip = LOAD(SPECS[4])
    query = inline.project_poses(clip.poses[10:11])
    ids, dist = inline.search(query, 1)
    assert inline.clip_of[ids[0, 0]] == 4 and inline.frame_of[ids[0, 0]] == 10
    assert dist[0, 0] < 1e-3


def test_a_small_library_gets_the_model_of_the_in_memory_build() -> None:
    streamed, _ = _build(SPECS[:4], fit_poses=10**6, workers=2)
    clips = [LOAD(s) for s in SPECS[:4]]
    built = PoseLibrary.build_in_memory(
        clips,
        PoseSettings(rank=RANK, n_unlabeled=200, n_pairs=40),
        estimator=PCA(n_components=RANK, random_state=0),
    )
    for key in built.model:
        np.testing.assert_array_equal(streamed.model[key], built.model[key])
    assert streamed.clip_names == built.clip_names
    np.testing.assert_array_equal(streamed.frame_of, built.frame_of)


def test_bad_clips_are_reported_and_the_rest_indexed() -> None:
    specs = list(SPECS)
    specs[2] = ("moonwalk", 2, 50)  # generate_clip refuses an unknown kind
    specs[6] = ("walk", 6, 0)  # and an empty clip
    library, failures = _build(specs, fit_poses=200, workers=2)
    assert [f.index for f in failures] == [2, 6]
    assert "unknown motion kind 'moonwalk'" in failures[0].message
    assert all("\n" not in f.message for f in failures)
    assert library.clip_names == [
        f"{k}_{s}" for i, (k, s, _) in enumerate(specs) if i not in (2, 6)
    ]
    with pytest.raises(
        ValueError, match="none of the 2 clips could be read: .*unknown motion kind"
    ):
        _build([("moonwalk", 0, 40), ("moonwalk", 1, 40)], workers=1)


def test_pose_index_cli_skips_a_bad_file_and_exits_1(
    tmp_path: pathlib.Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from typer.testing import CliRunner

    from quatmotion.cli import app
    from quatmotion.io import write_bvh
    from quatmotion.pose import methods
    from quatmotion.synthetic import generate_clip

    monkeypatch.setattr(methods, "RDSR", lambda n_components, random_state: PCA(n_components))
    for seed, kind in enumerate(["walk", "squat", "kick"]):
        write_bvh(generate_clip(kind, seed, n_frames=120, fps=60.0), tmp_path / f"{kind}.bvh")
    (tmp_path / "broken.bvh").write_text("HIERARCHY\nROOT Hips\n{\n")
    out = tmp_path / "poses.idx"
    args = ["pose", "index", str(tmp_path), "-o", str(out), "--rank", "6", "--workers", "2"]
    res = CliRunner().invoke(app, [*args, "--unlabeled", "100", "--pairs", "20"])
    assert res.exit_code == 1, res.output
    assert "skipped" in res.output and "broken.bvh" in res.output
    assert "1 of 4 clips failed" in res.output
    built = PoseLibrary.open(out)
    assert sorted(pathlib.Path(n).name for n in built.clip_names) == [
        "kick.bvh",
        "squat.bvh",
        "walk.bvh",
    ]
    res = CliRunner().invoke(app, [*args, "--scheduler", "http://nowhere:1"])
    assert res.exit_code == 2 and "unsupported protocol 'http'" in res.output
