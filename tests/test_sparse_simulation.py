"""Simulated QSSD data (paper section 4.1), recovery metrics (Eq. 10, 11) and a reduced Fig. 1."""

from __future__ import annotations

import numpy as np
import pytest

from quatmotion import quat
from quatmotion.sparse import (
    QSSD,
    angular_error_deg,
    dictionary_distance,
    make_sparse_quaternion_data,
    quaternion_combination,
    restoration_ratio,
)


def test_generated_data_follow_the_model() -> None:
    data = make_sparse_quaternion_data(100, 7, 9, 3, weight_scale=2.0, random_state=0)
    assert data.Y.shape == (100, 7, 4) and data.dictionary.shape == (9, 7, 4)
    np.testing.assert_allclose(np.linalg.norm(data.dictionary_log.reshape(9, -1), axis=1), 1.0)
    assert np.all(np.diff(data.weights.indptr) == 3)
    magnitudes = np.abs(data.weights.data)
    assert magnitudes.min() >= 0.4 and magnitudes.max() <= 2.0
    assert np.any(data.weights.data < 0) and np.any(data.weights.data > 0)
    np.testing.assert_allclose(data.Y, data.clean)
    expected = quat.canonicalize(quaternion_combination(data.dictionary_log, data.weights))
    np.testing.assert_allclose(data.Y, expected, atol=1e-14)


@pytest.mark.parametrize("snr", [40.0, 100.0])
def test_noise_has_the_requested_log_space_snr(snr: float) -> None:
    data = make_sparse_quaternion_data(200, 10, 10, 3, snr_db=snr, random_state=1)
    signal = quat.log(data.clean)
    noise = quat.log(data.Y) - signal
    measured = 10 * np.log10(np.sum(signal**2) / np.sum(noise**2))
    assert measured == pytest.approx(snr, abs=1e-6)


def test_angular_error_known_values() -> None:
    a = quat.from_euler(np.zeros((4, 3)), "xyz")
    b = quat.from_euler(np.tile([np.radians(10.0), 0, 0], (4, 1)), "xyz")
    assert angular_error_deg(a, b) == pytest.approx(10.0)
    assert angular_error_deg(a, b, convention="paper") == pytest.approx(5.0)
    assert angular_error_deg(a, -b) == pytest.approx(10.0)  # q and -q: same rotation


def test_dictionary_distance_is_zero_for_atoms_and_their_inverses() -> None:
    data = make_sparse_quaternion_data(10, 6, 5, 2, random_state=2)
    D = data.dictionary
    np.testing.assert_allclose(dictionary_distance(D, D), 0.0, atol=1e-12)
    np.testing.assert_allclose(dictionary_distance(quat.conjugate(D[::-1]), D), 0.0, atol=1e-12)
    np.testing.assert_allclose(dictionary_distance(-D, D, space="log"), 0.0, atol=1e-12)
    other = make_sparse_quaternion_data(10, 6, 5, 2, random_state=3).dictionary
    assert restoration_ratio(other, D, space="log") == 0.0
    # Eq. 10 by hand for one pair.
    d, t = D[0].ravel() / np.sqrt(6), other[0].ravel() / np.sqrt(6)
    t_inv = quat.conjugate(other[0]).ravel() / np.sqrt(6)
    expected = 1 - max(abs(d @ t), abs(d @ t_inv))
    assert dictionary_distance(other[:1], D[:1])[0] == pytest.approx(expected)


def test_reduced_simulation_recovers_the_dictionary() -> None:
    """Fig. 1 at reduced size: QSSD recovers the generating atoms of noiseless data."""
    data = make_sparse_quaternion_data(200, 20, 20, 5, random_state=0)
    model = QSSD(n_atoms=20, sparsity=5, max_iter=20, tol=0, random_state=0).fit(data.Y)
    assert model.init == "log-ksvd"  # the default initialisation (module docstring)
    assert model.errors_[-1] < model.errors_[0]
    assert restoration_ratio(model.dictionary_, data.dictionary) >= 0.9
    assert restoration_ratio(model.dictionary_, data.dictionary, space="log") >= 0.9
