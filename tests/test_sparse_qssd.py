"""QSSD estimator: exact coding of small known cases, combination formula, monotone dictionary
stage, reproducibility and input validation."""

from __future__ import annotations

import numpy as np
import pytest

from quatmotion import quat
from quatmotion.sparse import QSSD, make_sparse_quaternion_data, quaternion_combination
from quatmotion.sparse._common import Codes, check_quaternion_samples, matrix_to_codes
from quatmotion.sparse.qssd import sparse_code, update_dictionary


def _unit_logs(rng: np.random.Generator, K: int, n: int) -> np.ndarray:
    logs = rng.standard_normal((K, n * 3))
    return (logs / np.linalg.norm(logs, axis=1, keepdims=True)).reshape(K, n, 3)


@pytest.mark.parametrize("solver", ["gauss-newton", "weighted", "paper"])
def test_one_atom_sample_is_coded_exactly(solver: str) -> None:
    rng = np.random.default_rng(1)
    Dlog = _unit_logs(rng, 6, 5)
    Y = quat.canonicalize(quat.exp(0.7 * Dlog[2]))[None]
    codes, objective = sparse_code(Y, Dlog, 3, coef_solver=solver)
    assert codes.count[0] == 1  # the residual vanished: coding stopped after one atom
    assert codes.idx[0, 0] == 2
    assert codes.coef[0, 0] == pytest.approx(0.7, abs=1e-10)
    assert objective[0] < 1e-14


@pytest.mark.parametrize("refit", ["final", "every"])
def test_two_atom_sample_is_coded_exactly_in_descending_order(refit: str) -> None:
    rng = np.random.default_rng(2)
    Dlog = _unit_logs(rng, 8, 6)
    # Eq. 2: the larger |weight| on the left.
    Y = quat.canonicalize(quat.multiply(quat.exp(0.9 * Dlog[1]), quat.exp(-0.5 * Dlog[4])))[None]
    codes, objective = sparse_code(Y, Dlog, 2, coef_solver="gauss-newton", n_sweeps=10, refit=refit)
    assert list(codes.idx[0, : codes.count[0]]) == [1, 4]
    np.testing.assert_allclose(codes.coef[0, :2], [0.9, -0.5], atol=1e-9)
    assert objective[0] < 1e-14


def test_true_dictionary_codes_simulated_data_exactly() -> None:
    data = make_sparse_quaternion_data(60, 8, 10, 3, weight_scale=0.5, random_state=3)
    codes, objective = sparse_code(
        data.Y, data.dictionary_log, 3, coef_solver="gauss-newton", n_sweeps=10
    )
    for i in range(60):
        assert set(codes.idx[i, : codes.count[i]]) == set(data.weights[i].indices)
    assert np.max(objective) < 1e-12


def test_inverse_transform_of_transform_matches_combination_formula() -> None:
    data = make_sparse_quaternion_data(40, 5, 8, 3, random_state=4)
    model = QSSD(n_atoms=8, sparsity=3, max_iter=3, random_state=0).fit(data.Y)
    W = model.transform(data.Y)
    assert W.shape == (40, 8)
    assert np.all(np.diff(W.indptr) <= 3)
    Yhat = model.inverse_transform(W)
    D = model.dictionary_
    for i in range(40):
        row = W[i]
        order = np.argsort(-np.abs(row.data), kind="stable")
        expected = quat.identity((5,))
        for k, x in zip(row.indices[order], row.data[order], strict=True):
            expected = quat.multiply(expected, quat.power(D[k], np.full(5, x)))
        np.testing.assert_allclose(Yhat[i], expected, atol=1e-12)
    # Dense weights give the same combination as sparse ones.
    np.testing.assert_allclose(model.inverse_transform(W.toarray()), Yhat, atol=1e-14)


def test_dictionary_update_never_increases_objective() -> None:
    data = make_sparse_quaternion_data(120, 6, 10, 3, random_state=5)
    rng = np.random.default_rng(0)
    Y = check_quaternion_samples(data.Y)
    for trial in range(3):
        Dlog = _unit_logs(rng, 10, 6)
        codes, objective = sparse_code(Y, Dlog, 3)
        result = update_dictionary(Y, Dlog, codes, safeguard=True, objective=objective)
        assert result.objective.sum() <= objective.sum() + 1e-9, trial
        assert result.n_accepted > 0
        # The reported objective is that of the returned model (slots re-sorted by magnitude).
        Yhat = quaternion_combination(result.dictionary_log, _to_matrix(result.codes, 10))
        recomputed = np.sum(1 - np.abs(np.sum(Y * Yhat, -1)), axis=-1)
        np.testing.assert_allclose(result.objective, recomputed, atol=1e-10)
        norms = np.linalg.norm(result.dictionary_log.reshape(10, -1), axis=1)
        np.testing.assert_allclose(norms, 1.0, atol=1e-12)


def _to_matrix(codes: Codes, K: int):  # noqa: ANN202
    from quatmotion.sparse._common import codes_to_matrix

    return codes_to_matrix(codes, K)


@pytest.mark.parametrize("robust", [True, False])
def test_true_model_is_a_fixed_point_of_the_dictionary_update(robust: bool) -> None:
    # Exact data with their true codes: for every slot, E = P^-1 Y S^-1 is exactly that slot's
    # power, so Algorithm 3 must return every atom and weight unchanged. Five atoms per
    # sample at weight scale 1 do not commute, so the order of the inverse factors matters.
    data = make_sparse_quaternion_data(80, 6, 7, 5, random_state=11)
    codes = matrix_to_codes(data.weights, 7)
    assert np.all(codes.count == 5)
    result = update_dictionary(data.Y, data.dictionary_log, codes, safeguard=False, robust=robust)
    np.testing.assert_allclose(result.dictionary_log, data.dictionary_log, atol=1e-10)
    np.testing.assert_allclose(result.codes.coef, codes.coef, atol=1e-10)
    np.testing.assert_array_equal(result.codes.idx, codes.idx)
    assert np.max(result.objective) < 1e-12


def test_unused_atoms_are_reseeded_from_worst_fit_samples() -> None:
    data = make_sparse_quaternion_data(30, 4, 6, 2, random_state=6)
    Y = check_quaternion_samples(data.Y)
    rng = np.random.default_rng(1)
    Dlog = _unit_logs(rng, 6, 4)
    codes, objective = sparse_code(Y, Dlog[:1], 1)  # every code uses atom 0 only
    codes = Codes(codes.idx, codes.coef, codes.count)
    result = update_dictionary(Y, Dlog, codes, objective=objective)
    assert result.n_reseeded == 5
    worst = np.argmax(objective)
    from quatmotion.sparse.qssd import _from_soa, _residual_logs, _to_soa

    row = slice(worst, worst + 1)
    sub = Codes(codes.idx[row], codes.coef[row], codes.count[row])
    rlog = _from_soa(_residual_logs(_to_soa(Y[row]), _to_soa(Dlog), sub))
    np.testing.assert_allclose(result.dictionary_log[1], rlog[0] / np.linalg.norm(rlog), atol=1e-12)


def test_fit_learns_unit_atoms_and_lowers_error() -> None:
    data = make_sparse_quaternion_data(150, 6, 8, 2, random_state=7)
    model = QSSD(n_atoms=8, sparsity=2, max_iter=8, tol=0, random_state=1).fit(data.Y)
    assert model.n_iter_ == 8 and model.errors_.shape == (8,)
    assert model.errors_[-1] < model.errors_[0]
    np.testing.assert_allclose(np.linalg.norm(model.dictionary_, axis=-1), 1.0, atol=1e-12)
    assert np.all(model.dictionary_[..., 0] > 0)
    np.testing.assert_allclose(
        np.linalg.norm(model.dictionary_log_.reshape(8, -1), axis=1), 1.0, atol=1e-12
    )


def test_sign_of_input_quaternions_does_not_matter() -> None:
    data = make_sparse_quaternion_data(50, 5, 6, 2, random_state=8)
    flip = np.where(np.random.default_rng(0).random((50, 5, 1)) < 0.5, -1.0, 1.0)
    model = QSSD(n_atoms=6, sparsity=2, max_iter=2, random_state=0).fit(data.Y)
    np.testing.assert_allclose(
        model.transform(data.Y * flip).toarray(), model.transform(data.Y).toarray()
    )


def test_seeds_reproduce() -> None:
    data = make_sparse_quaternion_data(80, 5, 6, 2, random_state=9)
    a = QSSD(n_atoms=6, sparsity=2, max_iter=3, random_state=11).fit(data.Y)
    b = QSSD(n_atoms=6, sparsity=2, max_iter=3, random_state=11).fit(data.Y)
    c = QSSD(n_atoms=6, sparsity=2, max_iter=3, random_state=12).fit(data.Y)
    np.testing.assert_array_equal(a.dictionary_, b.dictionary_)
    np.testing.assert_array_equal(a.errors_, b.errors_)
    assert not np.allclose(a.dictionary_, c.dictionary_)


def test_bad_input_raises_value_error() -> None:
    good = make_sparse_quaternion_data(20, 3, 4, 2, random_state=0).Y
    with pytest.raises(ValueError, match="shape"):
        QSSD(4, sparsity=2).fit(good[..., :3])
    with pytest.raises(ValueError, match="shape"):
        QSSD(4, sparsity=2).fit(good.reshape(20, 12))
    with pytest.raises(ValueError, match="unit"):
        QSSD(4, sparsity=2).fit(good * 1.01)
    bad = good.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        QSSD(4, sparsity=2).fit(bad)
    with pytest.raises(ValueError, match="sparsity"):
        QSSD(n_atoms=2, sparsity=3).fit(good)
    with pytest.raises(ValueError, match="residual"):
        QSSD(4, sparsity=2, residual="middle").fit(good)
    with pytest.raises(ValueError, match="not fitted"):
        QSSD(4, sparsity=2).transform(good)
    model = QSSD(4, sparsity=2, max_iter=1, random_state=0).fit(good)
    with pytest.raises(ValueError, match="quaternions per sample"):
        model.transform(good[:, :2])
    with pytest.raises(ValueError, match="shape"):
        model.inverse_transform(np.zeros((3, 5)))


def test_keep_best_returns_the_dictionary_with_the_lowest_training_objective() -> None:
    data = make_sparse_quaternion_data(80, 5, 6, 3, weight_scale=2.0, random_state=10)
    model = QSSD(n_atoms=6, sparsity=3, max_iter=6, tol=0, random_state=2).fit(data.Y)
    Yhat = model.inverse_transform(model.transform(data.Y))
    objective = np.sum(1 - np.abs(np.sum(check_quaternion_samples(data.Y) * Yhat, -1)))
    assert objective == pytest.approx(np.min(model.objective_), rel=1e-9)


def test_estimators_follow_scikit_learn_conventions() -> None:
    import inspect

    from sklearn.base import clone

    from quatmotion.sparse import KSVD

    good = make_sparse_quaternion_data(20, 3, 4, 2, random_state=0).Y
    for cls in (QSSD, KSVD):
        with pytest.raises(TypeError):
            cls(4, 2)  # options after the first are keyword-only
        model = cls(4, sparsity=2, max_iter=1, random_state=0)
        assert clone(model).get_params() == model.get_params()
        with pytest.raises(ValueError, match="max_iter"):
            cls(4, sparsity=2, max_iter=0).fit(good)
        fitted = model.fit(good, None)
        assert fitted is model and model.n_features_in_ == 3
    # The function the estimator calls has the estimator's defaults.
    defaults = inspect.signature(update_dictionary).parameters
    assert defaults["safeguard"].default == QSSD().safeguard
    assert defaults["robust"].default == QSSD().robust
