"""Sparse decompositions of quaternion arrays: QSSD (quaternion combination) and K-SVD.

Samples are ``(N, n, 4)`` arrays of unit quaternions (w first); weights are
``scipy.sparse.csr_matrix`` ``(N, K)``. See :mod:`quatmotion.sparse.qssd` for the model and its
conventions.
"""

from quatmotion.sparse.ksvd import KSVD
from quatmotion.sparse.metrics import angular_error_deg, dictionary_distance, restoration_ratio
from quatmotion.sparse.qssd import QSSD, quaternion_combination
from quatmotion.sparse.simulation import SimulatedData, make_sparse_quaternion_data

__all__ = [
    "KSVD",
    "QSSD",
    "SimulatedData",
    "angular_error_deg",
    "dictionary_distance",
    "make_sparse_quaternion_data",
    "quaternion_combination",
    "restoration_ratio",
]
