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
    a, b = rng.integers(0, len(poses), (2, 1800))
    good = _worst_foot_labels(poses, a, b)
    assert 0.1 < good.mean() < 0.9
    train, test = slice(0, 1200), slice(1200, None)
    model = TransitionClassifier(random_state=0).fit(
        poses[a[:500]], poses[a[train]], poses[b[train]], good[train]
    )
    p = model.distances(poses[a[test]], poses[b[test]])
    assert p.shape == (600,) and np.all((p >= 0) & (p <= 1))
    precision, _ = evaluate.transition_precision(p, good[test])
    assert precision > 0.9
    # same seed, same numbers; pairwise agrees with the aligned pairs
    again = TransitionClassifier(random_state=0).fit(
        poses[a[:500]], poses[a[train]], poses[b[train]], good[train]
    )
    np.testing.assert_array_equal(again.distances(poses[a[test]], poses[b[test]]), p)
    grid = model.pairwise(poses[a[1200:1203]], poses[b[1200:1205]])
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


def test_stored_arrays_score_as_the_fitted_trees(poses: PoseData) -> None:
    """A library stores the classifier as arrays (no pickle); read back, it gives the fitted
    estimator's probabilities."""
    rng = np.random.default_rng(4)
    a, b = rng.integers(0, len(poses), (2, 1500))
    good = _worst_foot_labels(poses, a, b)
    model = TransitionClassifier(random_state=0).fit(poses[a[:400]], poses[a], poses[b], good)
    arrays = model.to_arrays()
    back = TransitionClassifier.from_arrays(arrays)
    q, r = rng.integers(0, len(poses), (2, 600))
    np.testing.assert_allclose(
        back.distances(poses[q], poses[r]), model.distances(poses[q], poses[r]), atol=1e-12
    )
    np.testing.assert_array_equal(back.describe(poses[:3]), model.describe(poses[:3]))
    with pytest.raises(KeyError, match="node_left"):
        TransitionClassifier.from_arrays({k: v for k, v in arrays.items() if k != "node_left"})


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> tuple:
    """A library of generated BVH clips written by ``quatmotion pose index``."""
    from typer.testing import CliRunner

    from quatmotion.cli import app
    from quatmotion.io import write_bvh

    folder = tmp_path_factory.mktemp("judged")
    paths = []
    for seed, kind in enumerate(["walk", "run", "squat", "walk", "jump"]):
        paths.append(folder / f"{kind}_{seed}.bvh")
        write_bvh(generate_clip(kind, seed, n_frames=150, fps=30.0), paths[-1])
    out = folder / "poses.idx"
    res = CliRunner().invoke(
        app, ["pose", "index", *map(str, paths[:4]), "-o", str(out), "--workers", "1"]
    )
    assert res.exit_code == 0, res.output
    return out, paths


def test_a_library_stores_its_transition_judge_and_re_ranks_by_it(built) -> None:
    from quatmotion.io import read_motion
    from quatmotion.pose.library import PoseLibrary, transition_judge

    out, paths = built
    lib = PoseLibrary.open(out)
    judge = transition_judge(lib.model)
    assert judge is not None and lib.meta["transitions"]["good"] >= 10
    assert lib.pose_rows is not None and len(lib.pose_rows) == len(lib.clip_of)
    # the stored rows are the judge's description of the indexed poses
    clip = lib.prepare_query(read_motion(paths[1]))
    np.testing.assert_allclose(lib.pose_rows[lib.clip_of == 1], judge.describe(clip.poses),
                               rtol=1e-5, atol=1e-3)  # fmt: skip
    query, own, _ = lib.pose_query(1, 60)
    start = lib.transition_start(60, clip=1)
    plain = lib.nearest(query, 40)
    judged = lib.nearest(query, 40, transition_from=start, candidates=40)
    # the same candidates, now ordered by the judge's probability of a bad transition
    assert {(m.clip, m.frame) for m in plain} == {(m.clip, m.frame) for m in judged}
    p = [m.distance for m in judged]
    assert p == sorted(p) and all(0.0 <= x <= 1.0 for x in p)
    rows = lib.pose_rows[[lib.find(m.clip, m.frame) for m in judged]]
    np.testing.assert_allclose(p, judge.score_rows(np.repeat(start, len(rows), 0), rows))
    # a clip added later is described as the built ones were
    report = PoseLibrary.add(out, [paths[4]])
    grown = report.details["library"]
    assert len(grown.pose_rows) == len(grown.clip_of) > len(lib.clip_of)


def test_pose_search_transitions_from_the_shell(built) -> None:
    from typer.testing import CliRunner

    from quatmotion.cli import app
    from quatmotion.pose.data import PoseClip
    from quatmotion.pose.library import PoseLibrary, PoseSettings

    out, paths = built
    res = CliRunner().invoke(
        app, ["pose", "search", str(out), "-c", "0", "-f", "30", "--transitions", "-k", "3"]
    )
    assert res.exit_code == 0, res.output
    assert "poses to jump to from" in res.output and "P(bad transition)" in res.output
    # a library without a judge (one clip: no transitions between clips) says so
    one = PoseLibrary.build_in_memory([PoseClip.from_motion(generate_clip("walk", 1, n_frames=600),
                                                            fps=15, height=170)],
                                      PoseSettings(n_pairs=20))  # fmt: skip
    assert one.pose_rows is None and "one clip" in one.meta["transitions"]
    path = out.with_name("one.idx")
    one.save(path)
    res = CliRunner().invoke(
        app, ["pose", "search", str(path), "-c", "0", "-f", "30", "--transitions"]
    )
    assert res.exit_code != 0 and "no transition judge (not learned: one clip)" in res.output
