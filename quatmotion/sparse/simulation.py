"""Synthetic QSSD data with a known dictionary (paper section 4.1, Fig. 1).

Ground-truth atoms follow the normalisation dictionary learning imposes on learned atoms: an
atom's log, as one ``3n``-vector, has unit norm (``D ** x`` and ``(D ** c) ** (x / c)`` are the
same combination, so only normalised atoms can be recovered in the sense of Eq. 10). Logs are
drawn isotropically (Gaussian, then normalised). Each sample combines ``L`` distinct atoms with
weights of random sign and magnitude uniform in ``weight_scale * [0.2, 1]``, multiplied in
descending magnitude order (Eq. 2). Noise is added in log space at a given SNR:
``Y = exp(ln Y_clean + e)`` with ``10 log10(|ln Y_clean|^2 / |e|^2) = snr_db`` over the data set.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from sklearn.utils import check_random_state

from quatmotion import quat
from quatmotion.sparse._common import check_positive_int
from quatmotion.sparse.qssd import quaternion_combination

__all__ = ["SimulatedData", "make_sparse_quaternion_data"]


@dataclass(frozen=True)
class SimulatedData:
    """Samples and the model that generated them.

    Attributes
    ----------
    Y : ndarray, shape (N, n, 4)
        Unit quaternions (``w >= 0``), noisy if an SNR was given.
    clean : ndarray, shape (N, n, 4)
        The noiseless combinations.
    dictionary : ndarray, shape (K, n, 4)
        True atoms, unit quaternions.
    dictionary_log : ndarray, shape (K, n, 3)
        Their logs, unit norm as ``3n``-vectors.
    weights : scipy.sparse.csr_matrix, shape (N, K)
        True weights, ``L`` non-zeros per row.
    """

    Y: NDArray[np.float64]
    clean: NDArray[np.float64]
    dictionary: NDArray[np.float64]
    dictionary_log: NDArray[np.float64]
    weights: sp.csr_matrix


def make_sparse_quaternion_data(
    n_samples: int = 500,
    n_quaternions: int = 20,
    n_atoms: int = 20,
    sparsity: int = 5,
    *,
    weight_range: tuple[float, float] = (0.2, 1.0),
    weight_scale: float = 1.0,
    snr_db: float | None = None,
    random_state: int | np.random.RandomState | None = None,
) -> SimulatedData:
    """Draw a QSSD data set with a known dictionary (paper section 4.1).

    Parameters
    ----------
    n_samples, n_quaternions, n_atoms, sparsity : int
        ``N``, ``n``, ``K``, ``L`` (the paper: 500, 20, 20, 5).
    weight_range : (float, float)
        Range of weight magnitudes before scaling, ``0 < low <= high``.
    weight_scale : float
        Multiplies every weight: larger means larger rotations, products further from
        commuting.
    snr_db : float or None
        Log-space signal-to-noise ratio in dB; ``None`` for noiseless data.
    random_state : int, RandomState or None

    Returns
    -------
    SimulatedData
    """
    N = check_positive_int(n_samples, "n_samples")
    n = check_positive_int(n_quaternions, "n_quaternions")
    K = check_positive_int(n_atoms, "n_atoms")
    L = check_positive_int(sparsity, "sparsity")
    if L > K:
        raise ValueError(f"sparsity ({L}) cannot exceed n_atoms ({K})")
    low, high = (float(v) for v in weight_range)
    if not (0.0 < low <= high) or not (np.isfinite(weight_scale) and weight_scale > 0):
        raise ValueError("weight_range must satisfy 0 < low <= high and weight_scale must be > 0")
    rng = check_random_state(random_state)
    logs = rng.standard_normal((K, 3 * n))
    logs /= np.linalg.norm(logs, axis=1, keepdims=True)
    Dlog = logs.reshape(K, n, 3)
    atoms = np.argsort(rng.random_sample((N, K)), axis=1)[:, :L]
    magnitude = weight_scale * rng.uniform(low, high, size=(N, L))
    sign = np.where(rng.random_sample((N, L)) < 0.5, -1.0, 1.0)
    W = sp.csr_matrix(
        (np.ravel(sign * magnitude), (np.repeat(np.arange(N), L), np.ravel(atoms))), shape=(N, K)
    )
    clean = quat.canonicalize(quaternion_combination(Dlog, W))
    Y = clean
    if snr_db is not None:
        clean_log = quat.log(clean)
        noise = rng.standard_normal(clean_log.shape)
        power_ratio = np.sum(clean_log**2) / np.sum(noise**2)
        noise *= np.sqrt(power_ratio / 10.0 ** (float(snr_db) / 10.0))
        Y = quat.canonicalize(quat.exp(clean_log + noise))
    return SimulatedData(Y, clean, quat.exp(Dlog), Dlog, W)
