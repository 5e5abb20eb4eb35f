"""Baselines of sections 5.3-5.4 and the method registry."""

from __future__ import annotations

import numpy as np
import pytest

from quatmotion.pose import methods
from quatmotion.pose.baselines import (
    LEE_WEIGHTS,
    LMS,
    SDA,
    JointDistance,
    Xing,
    joint_coordinate_features,
    joint_orientation_features,
    joint_relative_features,
)
from quatmotion.pose.data import PoseData
from quatmotion.pose.skeleton16 import JOINTS_16

J = {name: k for k, name in enumerate(JOINTS_16)}
T_POSE = np.array([
    (0, 0, 0), (0, 20, 0), (0, 45, 0), (0, 60, 0), (15, 40, 0), (45, 40, 0), (75, 40, 0),
    (-15, 40, 0), (-45, 40, 0), (-75, 40, 0), (10, 0, 0), (10, -45, 0), (10, -90, 0),
    (-10, 0, 0), (-10, -45, 0), (-10, -90, 0),
], dtype=np.float64)  # fmt: skip


def clips(n_clips: int, length: int, seed: int) -> list[PoseData]:
    """Smoothly wandering poses around a T-pose, 30 fps."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n_clips):
        drift = np.cumsum(rng.normal(scale=1.0, size=(length, 16, 3)), axis=0)
        drift -= drift[:, :1]
        height = 95 + np.cumsum(rng.normal(scale=0.3, size=length))
        out.append(PoseData.from_clip(T_POSE + drift, 30.0, hip_height=height))
    return out


@pytest.fixture(scope="module")
def pose_sets() -> dict[str, object]:
    unlabeled = PoseData.concat(clips(6, 40, seed=0))
    pool = PoseData.concat(clips(6, 30, seed=1))
    rng = np.random.default_rng(2)
    a = rng.choice(len(pool), 80)
    b = rng.choice(len(pool), 80)
    # Similar pairs: the same pose; dissimilar: two random poses. Labels are then learnable.
    labels = np.arange(80) < 40
    b[labels] = a[labels]
    pa, pb = pool[a], pool[b]
    jitter = np.where(labels[:, None, None], 0.3, 0.0)
    pb = PoseData(pb.positions + jitter * rng.normal(size=pb.positions.shape), pb.velocities,
                  pb.accelerations, pb.hip_height)  # fmt: skip
    return {"unlabeled": unlabeled, "a": pa, "b": pb, "labels": labels}


def test_registry_names_every_method() -> None:
    expected = {"JOD", "WJOD", "LJOD", "JCD", "WJCD", "LJCD", "JRF+LMS", "GPD+RDSR", "L2",
                "L2+LMS", "Xing", "SDA", "RDSR"}  # fmt: skip
    expected |= {f"{f}+{lrn}" for f in ("JO", "JC", "JRF", "GPD") for lrn in methods.LEARNERS}
    assert expected <= set(methods.METHODS)
    assert set(methods.FIG5_METHODS) <= set(methods.METHODS)
    rdsr = methods.METHODS["GPD+RDSR"](n_components=7, random_state=0)
    assert rdsr.learner_.model.n_components == 7
    with pytest.raises(ValueError, match="feature"):
        methods.FeatureMetric("XYZ", "L2")


@pytest.mark.parametrize("name", sorted(methods.METHODS))
def test_every_method_fits_and_measures_consistently(name: str, pose_sets: dict) -> None:
    kwargs = {"n_components": 10} if name.endswith(("RDSR", "SDA")) else {}
    if name.endswith("Xing"):
        kwargs = {"n_pca": 10}
    method = methods.METHODS[name](random_state=0, **kwargs)
    assert isinstance(method, methods.PoseMethod)
    u, a, b, labels = (pose_sets[k] for k in ("unlabeled", "a", "b", "labels"))
    assert method.fit(u, a, b, labels) is method
    d = method.distances(a, b)
    assert d.shape == (len(a),) and np.all(np.isfinite(d)) and np.all(d >= 0)
    np.testing.assert_allclose(method.distances(b, a), d, rtol=1e-9, atol=1e-9)
    if name == "PAIR-GBT":  # a classifier of pairs, no metric: a self-transition is judged
        # good, not at distance 0
        assert method.distances(a, a).mean() < d[~labels].mean()
    else:
        np.testing.assert_allclose(method.distances(a, a), 0.0, atol=1e-9)
    pw = method.pairwise(a[:5], b[:7])
    assert pw.shape == (5, 7)
    np.testing.assert_allclose(np.diag(pw[:5, :5]), d[:5], rtol=1e-7, atol=1e-7)
    # Every method separates these easy labels: similar pairs are the closer ones on average.
    assert d[labels].mean() < d[~labels].mean()


def _static(positions: np.ndarray) -> PoseData:
    zeros = np.zeros_like(positions)
    return PoseData(positions, zeros, zeros, np.full(len(positions), 95.0))


def test_joint_distances_known_values() -> None:
    base = _static(T_POSE[None])
    moved = T_POSE.copy()
    moved[J["LKnee"]] += (0.0, 0.0, 3.0)
    moved[J["RHand"]] += (4.0, 0.0, 0.0)
    other = _static(moved[None])
    jcd = JointDistance("coordinate", "uniform").fit(base, base, base, [True])
    assert jcd.distances(base, other)[0] == pytest.approx(9.0 + 16.0)
    wjcd = JointDistance("coordinate", "lee").fit(base, base, base, [True])
    assert wjcd.distances(base, other)[0] == pytest.approx(9.0)  # hands weigh 0 (Lee et al.)
    assert LEE_WEIGHTS[J["LKnee"]] == 1 and LEE_WEIGHTS[J["RHand"]] == 0
    # Bending the left elbow by theta rotates only the elbow: JOD = theta^2 (Eq. 40).
    theta = 0.6
    bent = T_POSE.copy()
    bent[J["LHand"]] = bent[J["LElbow"]] + 30 * np.array([np.cos(theta), np.sin(theta), 0.0])
    jod = JointDistance("orientation", "uniform").fit(base, base, base, [True])
    assert jod.distances(base, _static(bent[None]))[0] == pytest.approx(theta**2)
    # The hip term: a 10 cm height difference is 0.1 m, squared.
    lower = PoseData(base.positions, base.velocities, base.accelerations, np.array([85.0]))
    assert jod.distances(base, lower)[0] == pytest.approx(0.01)
    # The velocity term (lambda = 1): 30 cm/s is 1 cm per 1/30 s frame.
    vel = np.zeros((1, 16, 3))
    vel[0, J["LKnee"]] = (30.0, 0.0, 0.0)
    moving = PoseData(base.positions, vel, vel, base.hip_height)
    assert jcd.distances(base, moving)[0] == pytest.approx(1.0)


def test_learned_joint_weights_favour_the_joint_that_decides(pose_sets: dict) -> None:
    rng = np.random.default_rng(5)
    n = 200
    a = _static(T_POSE + rng.normal(scale=2.0, size=(n, 16, 3)))
    noise = rng.normal(scale=2.0, size=(n, 16, 3))
    labels = rng.random(n) < 0.5
    # Dissimilar pairs differ a lot at the left knee only; all joints carry equal noise.
    noise[~labels, J["LKnee"]] += rng.normal(scale=15.0, size=((~labels).sum(), 3))
    b = _static(a.positions + noise)
    ljcd = JointDistance("coordinate", "learned").fit(a, a, b, labels)
    jcd = JointDistance("coordinate", "uniform").fit(a, a, b, labels)
    assert np.all(ljcd.weights_ >= 0)
    # The knee's share of the learned distance of dissimilar pairs dominates...
    share = ljcd.weights_ * ljcd._terms(a, b)[~labels].mean(axis=0)
    assert share[1 + J["LKnee"]] > 0.8 * share.sum()
    # ... and the learned weights separate the labels better than uniform ones.
    assert _separation(ljcd, a, b, labels) > 1.5 * _separation(jcd, a, b, labels)


def test_feature_shapes() -> None:
    data = clips(1, 12, seed=3)[0]
    assert joint_orientation_features(data).shape == (12, 113)
    assert joint_coordinate_features(data).shape == (12, 92)
    jrf = joint_relative_features(data)
    assert jrf.shape == (12, 120)
    assert jrf[0, 0] == pytest.approx(np.linalg.norm(data.positions[0, 1] - data.positions[0, 0]))


def _labelled_arrays(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Pairs where dissimilarity lives on axis 0 and similar pairs wobble along axis 1."""
    rng = np.random.default_rng(seed)
    n, d = 300, 8
    U = rng.normal(size=(400, d))
    A = rng.normal(size=(n, d))
    labels = np.arange(n) < n // 2
    diff = rng.normal(scale=0.3, size=(n, d))
    diff[labels, 1] += rng.normal(scale=2.0, size=labels.sum())
    diff[~labels, 0] += rng.normal(scale=2.0, size=(~labels).sum())
    return U, A, A + diff, labels


def _separation(model: object, A: np.ndarray, B: np.ndarray, labels: np.ndarray) -> float:
    d = model.distances(A, B)  # type: ignore[attr-defined]
    return float(np.median(d[~labels]) / np.median(d[labels]))


def test_learners_find_the_discriminative_axis() -> None:
    U, A, B, labels = _labelled_arrays(0)
    l2 = np.linalg.norm(A - B, axis=1)
    baseline = float(np.median(l2[~labels]) / np.median(l2[labels]))
    lms = LMS(power=2).fit(U, A, B, labels)
    share = lms.weights_ * ((A - B)[~labels] ** 2).mean(axis=0)
    assert share[0] > 0.5 * share.sum()
    xing = Xing(n_pca=8, random_state=0).fit(U, A, B, labels)
    diff = A - B
    # MMC's constraint is active at its optimum: sum over similar pairs of ||x - y||_M^2 = 1.
    assert np.sum((diff[labels] @ xing.projection_) ** 2) == pytest.approx(1.0, rel=1e-6)
    sda = SDA(n_components=2, n_neighbors=5).fit(U, A, B, labels)
    for model in (lms, xing, sda):
        assert _separation(model, A, B, labels) > 1.5 * baseline, type(model).__name__
    with pytest.raises(ValueError, match="dissimilar"):
        Xing().fit(U, A, B, np.ones(len(A), dtype=bool))
    with pytest.raises(ValueError, match="power"):
        LMS(power=3)


def test_pair_logistic_weights_the_feature_that_separates_good_from_bad() -> None:
    from quatmotion.pose.metric import PairLogistic

    rng = np.random.default_rng(0)
    a = rng.normal(size=(400, 5))
    b = a + rng.normal(scale=0.5, size=a.shape)  # every feature differs by noise
    good = np.arange(400) < 200
    b[~good, 2] += rng.choice([-3.0, 3.0], size=200)  # bad pairs differ in feature 2
    model = PairLogistic().fit(np.zeros((0, 5)), a, b, good)
    assert np.argmax(model.weights_) == 2 and np.all(model.weights_ >= 0)
    d = model.distances(a, b)
    assert d[~good].min() > np.median(d[good])
    np.testing.assert_allclose(model.pairwise(a[:3], b[:3]).diagonal(), d[:3])
    with pytest.raises(ValueError, match="both"):
        PairLogistic().fit(None, a, b, np.ones(400, bool))
