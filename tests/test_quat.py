"""Property tests of the quaternion algebra against its definitions and SciPy."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from quatmotion import quat

finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)


@st.composite
def unit_quats(draw, n: int = 8) -> np.ndarray:
    raw = draw(arrays(np.float64, (n, 4), elements=st.floats(-1, 1)))
    raw[np.linalg.norm(raw, axis=1) < 1e-3] = (1.0, 0.0, 0.0, 0.0)
    return quat.normalize(raw)


def as_scipy(q: np.ndarray) -> Rotation:
    return Rotation.from_quat(np.roll(q.reshape(-1, 4), -1, axis=-1))


def same_rotation(p: np.ndarray, q: np.ndarray, atol: float = 1e-9) -> bool:
    return bool(np.all(np.abs(np.abs(quat.dot(p, q)) - 1.0) < atol))


@given(unit_quats())
@example(np.array([[-1.0, 1.8e-161, 1.8e-161, 1.8e-161]]))  # subnormal squares near 180 deg
def test_exp_inverts_log(q):
    np.testing.assert_allclose(quat.exp(quat.log(q)), q, atol=1e-12)


@given(
    unit_quats(),
    arrays(np.float64, (8,), elements=st.floats(-3, 3)),
    arrays(np.float64, (8,), elements=st.floats(-3, 3)),
)
def test_powers_of_one_axis_add(q, a, b):
    np.testing.assert_allclose(
        quat.multiply(quat.power(q, a), quat.power(q, b)), quat.power(q, a + b), atol=1e-10
    )


@given(unit_quats(), arrays(np.float64, (8,), elements=st.floats(-3, 3)))
def test_inverse_of_power_is_negative_power(q, t):
    np.testing.assert_allclose(quat.inverse(quat.power(q, t)), quat.power(q, -t), atol=1e-10)


@given(unit_quats(), unit_quats())
def test_multiply_matches_scipy_composition(p, q):
    expected = (as_scipy(p) * as_scipy(q)).as_matrix()
    np.testing.assert_allclose(quat.to_matrix(quat.multiply(p, q)), expected, atol=1e-12)


@given(unit_quats(), arrays(np.float64, (8, 3), elements=finite))
def test_rotate_matches_scipy(q, v):
    np.testing.assert_allclose(quat.rotate(q, v), as_scipy(q).apply(v), atol=1e-9)


@given(unit_quats())
def test_matrix_round_trip(q):
    assert same_rotation(quat.from_matrix(quat.to_matrix(q)), q)
    np.testing.assert_allclose(quat.to_matrix(q), as_scipy(q).as_matrix(), atol=1e-12)


@pytest.mark.parametrize("order", ["XYZ", "ZXY", "ZYX", "YZX", "xyz", "zxy", "zyx", "xzy"])
@settings(max_examples=30)
@given(angles=arrays(np.float64, (8, 3), elements=st.floats(-np.pi, np.pi)))
def test_euler_matches_scipy_and_round_trips(order, angles):
    q = quat.from_euler(angles, order)
    assert same_rotation(q, np.roll(Rotation.from_euler(order, angles).as_quat(), 1, axis=-1))
    assert same_rotation(quat.from_euler(quat.to_euler(q, order), order), q)


def test_euler_principal_range_gives_back_the_angles():
    rng = np.random.default_rng(1)
    angles = rng.uniform(-0.95, 0.95, (100, 3)) * np.array([np.pi, np.pi / 2, np.pi])
    for order in ("XYZ", "xyz", "ZXY"):
        back = quat.to_euler(quat.from_euler(angles, order), order)
        np.testing.assert_allclose(back, angles, atol=1e-10)
        np.testing.assert_allclose(
            quat.to_euler(
                quat.from_euler(np.rad2deg(angles), order, degrees=True), order, degrees=True
            ),
            np.rad2deg(angles),
            atol=1e-8,
        )


def test_identity_and_half_turn_have_no_nan():
    half_turns = np.array([[0.0, 1, 0, 0], [0.0, 0, 1, 0], [0.0, 0, 0, 1], [-1.0, 0, 0, 0]])
    special = np.concatenate((quat.identity((1,)), half_turns))
    for f in (quat.log, lambda q: quat.power(q, 0.5), lambda q: quat.power(q, -2.0)):
        assert np.all(np.isfinite(f(special)))
    np.testing.assert_array_equal(quat.log(quat.identity()), np.zeros(3))
    np.testing.assert_allclose(quat.exp(quat.log(special)), special, atol=1e-12)
    # The square root of a half turn about x is a quarter turn about x.
    np.testing.assert_allclose(
        quat.power(half_turns[0], 0.5), [np.cos(np.pi / 4), np.sin(np.pi / 4), 0, 0], atol=1e-12
    )
    np.testing.assert_allclose(quat.angle(special[1:4], quat.identity()), np.pi, atol=1e-12)
    assert np.all(np.isfinite(quat.slerp(special, special[::-1], 0.3)))


def test_tiny_rotations_keep_precision():
    q = quat.exp(np.array([1e-9, 0.0, 0.0]))
    np.testing.assert_allclose(quat.log(q), [1e-9, 0, 0], rtol=1e-9)
    np.testing.assert_allclose(quat.angle(q, quat.identity()), 2e-9, rtol=1e-9)


@given(unit_quats(), unit_quats())
def test_angle_is_geodesic_and_sign_blind(p, q):
    expected = (as_scipy(p).inv() * as_scipy(q)).magnitude()
    np.testing.assert_allclose(quat.angle(p, q), expected, atol=1e-7)
    np.testing.assert_allclose(quat.angle(p, -q), quat.angle(p, q), atol=1e-12)


@given(unit_quats(), unit_quats(), st.floats(0, 1))
def test_slerp_ends_and_constant_speed(p, q, t):
    assert same_rotation(quat.slerp(p, q, 0.0), p)
    assert same_rotation(quat.slerp(p, q, 1.0), q, atol=1e-8)
    mid = quat.slerp(p, q, t)
    total = quat.angle(p, q)
    np.testing.assert_allclose(quat.angle(p, mid), t * total, atol=1e-6)


def test_canonicalize_and_continuity():
    rng = np.random.default_rng(2)
    q = quat.normalize(rng.normal(size=(50, 3, 4)))
    c = quat.canonicalize(q)
    assert np.all(c[..., 0] >= 0)
    assert same_rotation(c, q)
    # A smooth path with random sign flips becomes continuous again.
    path = quat.exp(np.linspace(0, 3, 200)[:, None] * np.array([0.3, 0.5, -0.2]))
    flipped = path * rng.choice([-1.0, 1.0], size=(200, 1))
    cont = quat.make_continuous(flipped)
    assert np.all(quat.dot(cont[1:], cont[:-1]) > 0)
    assert same_rotation(cont, path)


def test_bad_shapes_are_value_errors():
    with pytest.raises(ValueError, match="length 4"):
        quat.multiply(np.ones(3), np.ones(4))
    with pytest.raises(ValueError, match="Euler order"):
        quat.from_euler(np.zeros(3), "XXY")
    with pytest.raises(ValueError, match="zero"):
        quat.normalize(np.zeros(4))
