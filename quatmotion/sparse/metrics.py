"""Reconstruction error (paper Eq. 9/11) and dictionary recovery (Eq. 10).

Angles are returned in degrees. The paper's Eq. 11 writes ``arccos(<q, q_hat>)``, which is half
the rotation angle between the two rotations; the project's metric (docs/metrics.md) is the rotation
angle ``2 arccos(|<q, q_hat>|)``. Both are available through ``convention``.

Atoms are compared as unit ``4n``-vectors (each of the ``n`` quaternions unit, the whole divided
by ``sqrt(n)``). An atom and its inverse with negated weights are the same model
(``D ** x = (D ** -1) ** -x``), so Eq. 10 takes the nearer of the two. A true atom counts as
recovered when some learned atom is within the threshold of it; counting per true atom means
two learned copies of one true atom cannot inflate the ratio.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quatmotion import quat

__all__ = ["angular_error_deg", "dictionary_distance", "restoration_ratio"]


def angular_error_deg(Y: ArrayLike, Y_hat: ArrayLike, convention: str = "rotation") -> float:
    """Mean angular error per quaternion (Eq. 11), degrees.

    Parameters
    ----------
    Y, Y_hat : array_like, shape (..., 4)
        Unit quaternions, w first.
    convention : {"rotation", "paper"}
        ``"rotation"``: ``2 arccos(|<q, q_hat>|)``, the angle of the rotation between them.
        ``"paper"``: ``arccos(|<q, q_hat>|)`` as printed in Eq. 11 (half of it).

    Returns
    -------
    float
    """
    Y = np.asarray(Y, dtype=np.float64)
    Y_hat = np.asarray(Y_hat, dtype=np.float64)
    if Y.shape != Y_hat.shape or Y.shape[-1:] != (4,):
        raise ValueError(
            f"need two arrays of the same shape (..., 4), got {Y.shape} and {Y_hat.shape}"
        )
    if convention not in ("rotation", "paper"):
        raise ValueError(f"convention must be 'rotation' or 'paper', got {convention!r}")
    angles = quat.angle(Y, Y_hat)
    if convention == "paper":
        angles = angles / 2.0
    return float(np.degrees(np.mean(angles)))


def _as_atoms(D: ArrayLike, name: str) -> NDArray[np.float64]:
    D = np.asarray(D, dtype=np.float64)
    if D.ndim != 3 or D.shape[-1] != 4:
        raise ValueError(f"{name} must have shape (K, n, 4), got {D.shape}")
    return D


def dictionary_distance(
    D: ArrayLike, D_true: ArrayLike, space: str = "quaternion"
) -> NDArray[np.float64]:
    """For every true atom, the distance to the nearest learned atom (Eq. 10).

    Parameters
    ----------
    D : array_like, shape (K, n, 4)
        Learned atoms, unit quaternions.
    D_true : array_like, shape (K_true, n, 4)
        True atoms.
    space : {"quaternion", "log"}
        ``"quaternion"``: ``1 - |<d, d_true>|`` of unit ``4n``-vectors, the nearer of ``d`` and
        its inverse (conjugate). ``"log"``: ``1 - |cos|`` of the atoms' ``3n``-vector logs.

    Returns
    -------
    ndarray, shape (K_true,)
    """
    D = quat.canonicalize(_as_atoms(D, "D"))
    T = quat.canonicalize(_as_atoms(D_true, "D_true"))
    if D.shape[1] != T.shape[1]:
        raise ValueError(f"atoms have {D.shape[1]} and {T.shape[1]} quaternions")
    n = D.shape[1]
    if space == "quaternion":
        Df = D.reshape(len(D), -1) / np.sqrt(n)
        Dinv = quat.conjugate(D).reshape(len(D), -1) / np.sqrt(n)
        Tf = T.reshape(len(T), -1) / np.sqrt(n)
        sim = np.maximum(np.abs(Tf @ Df.T), np.abs(Tf @ Dinv.T))
    elif space == "log":
        Dl = quat.log(D).reshape(len(D), -1)
        Tl = quat.log(T).reshape(len(T), -1)
        Dl = Dl / np.maximum(np.linalg.norm(Dl, axis=1, keepdims=True), 1e-300)
        Tl = Tl / np.maximum(np.linalg.norm(Tl, axis=1, keepdims=True), 1e-300)
        sim = np.abs(Tl @ Dl.T)
    else:
        raise ValueError(f"space must be 'quaternion' or 'log', got {space!r}")
    return np.clip(1.0 - np.max(sim, axis=1), 0.0, None)


def restoration_ratio(
    D: ArrayLike, D_true: ArrayLike, threshold: float = 0.01, space: str = "quaternion"
) -> float:
    """Fraction of true atoms recovered: nearest learned atom within ``threshold`` (Eq. 10)."""
    return float(np.mean(dictionary_distance(D, D_true, space) < threshold))
