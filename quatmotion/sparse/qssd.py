"""Quaternion space sparse decomposition (QSSD, Zhu, Sun & Deng 2012, section 3).

A sample is ``n`` unit quaternions (one per joint, w first). It is modelled as the quaternion
combination (Eq. 2) of at most ``L`` dictionary atoms, each an ``n``-tuple of unit quaternions
raised to a real weight::

    Y_i  ~  D_{o1} ** x_{o1}  D_{o2} ** x_{o2}  ...  D_{om} ** x_{om}      (per joint)

with the atoms ordered by descending ``|x|`` (largest on the left). ``q ** x = exp(x ln q)``.

Conventions and what the paper leaves open
------------------------------------------
* **Atom normalisation.** An atom is stored by its logarithm, an ``(n, 3)`` array whose
  flattened ``3n``-vector has unit norm (the first left singular vector of Algorithm 3). Scaling
  a log by ``c`` and its weight by ``1/c`` is the same model, so this fixes the scale. Every
  joint's half angle is then at most 1 rad, so atoms have ``w > 0`` and ``exp``/``ln`` are
  inverse to each other on them.
* **Double cover.** Data and every residual are taken on the ``w >= 0`` hemisphere before a log
  (the shortest-arc log), and the objective uses ``|<q, q_hat>|``. An atom and its inverse with
  negated weights are the same model; the SVD sign is fixed so that an atom does not flip
  between iterations.
* **Zero-angle logs.** ``ln`` of the identity is exactly 0 and a joint whose atom half angle is
  0 carries no information about the weight: it is skipped in Eq. 6 (it would divide 0 by 0).
  A residual whose log vanishes stops the coding of that sample (Algorithm 2 "convergence").
* **Unused atoms.** An atom no sample uses is re-seeded, before the dictionary update, with the
  normalised log residual of the worst-fit sample not yet used for re-seeding.
* **Objective.** ``sum_i sum_j 1 - |<Y_ji, Yhat_ji>|``: Eq. 4 turned into a minimisation.
  ``errors_`` reports Eq. 11 (mean angle per quaternion, degrees) after each coding stage.

Changes to the algorithm as printed (each switchable, to measure its effect)
----------------------------------------------------------------------------
The defaults are the changes; the printed algorithm is ``init="samples", residual="right",
coef_solver="paper", refit="every"``. ``quatmotion bench qssd`` measures each change alone and
together on the paper's simulation: the figures are in ``docs/performance.md`` (0.2.0, QSSD
ablation and the measurements behind these defaults). Together they matter more than apart.

* ``residual="left"``: Algorithm 2 line 8 prints ``R = Y (D_P (x) X_P)^-1``. The next atom is
  appended on the right of the combination (its weight is smaller), so what it must explain is
  ``C^-1 Y``; ``Y C^-1 = C (C^-1 Y) C^-1`` is that residual rotated by ``C``, whose log points
  the wrong way once ``C`` is far from the identity, so the printed rule picks a wrong atom more
  often as weights grow. ``residual="right"`` is the printed rule.
* ``coef_solver="gauss-newton"``: block coordinate descent with Eq. 6 (``"paper"``; or
  ``"weighted"``, each joint's square weighted by the amplitude ``rho_j`` of its term
  ``rho_j cos(x a_j - b_j)`` of Eq. 5) converges slowly when atoms do not commute, and leaves
  error even with the true dictionary and support. A joint Gauss-Newton step on all chosen
  weights (the residual log is linear in them to first order, the Jacobian columns are the atom
  logs rotated by the suffix products) is exact on exact data. The descending-order constraint
  makes the objective discontinuous where two weights are nearly tied; a fit that stays poor
  also tries the swapped order of the two closest pairs. A refit stops early once a step's
  predicted gain is below ``_kernels.GN_STEP_TOL`` of ``|r|^2`` (exact data converge before
  that, so only noisy and real data are cut short).
* ``refit="final"``: the paper refits all weights after every added atom; refitting only after
  the last one (the others get their Eq. 6 weight against the residual, and the residual
  advances by one product per joint) costs O(L) instead of O(L^2) refits for the same support
  recovery at moderate weight scales. ``refit="every"`` is the printed schedule.
* ``init="log-ksvd"``: random samples (Algorithm 4 line 1, ``init="samples"``) are mixtures of
  atoms, and QSSD learns slowly from them. To first order ``ln(A^a B^b) = a ln A + b ln B``, so
  ``init_iter`` iterations of linear K-SVD on the sample logs, started from the random samples,
  give atoms that QSSD then refines in a few iterations.
* ``robust=True``: samples coded with a wrong atom set (greedy coding misses the true set of
  some samples even with the true dictionary) leave large unrelated residuals in ``ln E``;
  each atom is refit once without the samples whose rank-1 misfit exceeds three times the
  median. With it the true dictionary is a fixed point of the update; without, it drifts.
* ``safeguard=True`` (off by default): the rank-1 SVD of ``ln E`` minimises a log-space
  surrogate and new weights may reorder the product; with the safeguard an atom update is kept
  only if the objective over its samples (with the re-sorted order) does not increase, so the
  dictionary stage is monotone. It slows recovery (updates that first increase the objective
  are needed to leave poor starting atoms), hence off; on real data it made no difference.
* ``keep_best=True``: neither greedy coding nor the log-space dictionary update is guaranteed
  to lower the objective; the estimator returns the dictionary whose coding had the lowest
  training objective (a guard).
* ``n_sweeps``: Gauss-Newton steps (or coordinate-descent sweeps) per refit. Three by
  default: fewer are faster per iteration but end the simulation at a higher error.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from numbers import Integral
from typing import Any, ClassVar

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray
from sklearn.utils.validation import check_is_fitted

from quatmotion import quat
from quatmotion._settings import Interval, StrOptions
from quatmotion.sparse import _kernels as kern
from quatmotion.sparse._base import DictionaryLearner
from quatmotion.sparse._common import (
    Codes,
    codes_to_matrix,
    compute_threads,
    group_by_atom,
    matrix_to_codes,
    rank1,
)
from quatmotion.sparse.ksvd import learn_linear_dictionary

__all__ = [
    "QSSD",
    "DictionaryUpdateResult",
    "quaternion_combination",
    "sparse_code",
    "update_dictionary",
]

# Samples per projection block: (block, K) projections stay in cache at K = 2000.
_PROJECTION_CHUNK = 1024
_CODE_TOL = 1e-10
_SOLVERS = {"paper": 0, "weighted": 1, "gauss-newton": 2}


# The kernels work on a structure-of-arrays layout (see :mod:`quatmotion.sparse._kernels`):
# samples ``(N, 4, n)``, logs ``(..., 3, n)``. The public functions take and return the
# ``(..., n, 4)`` / ``(..., n, 3)`` layout of the rest of the package and convert at the boundary.


def _to_soa(Q: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(..., n, c) -> (..., c, n)``, contiguous."""
    return np.ascontiguousarray(np.swapaxes(Q, -1, -2))


def _from_soa(Q: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(..., c, n) -> (..., n, c)``, contiguous."""
    return np.ascontiguousarray(np.swapaxes(Q, -1, -2))


def _atom_geometry(DlogT: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per-joint half angles ``(..., n)`` and unit axes ``(..., 3, n)`` (zero for a zero log)
    of logs ``(..., 3, n)``."""
    Dnorm = np.linalg.norm(DlogT, axis=-2)
    safe = np.where(Dnorm > 0.0, Dnorm, 1.0)
    DaxisT = np.where(Dnorm[..., None, :] > 0.0, DlogT / safe[..., None, :], 0.0)
    return np.ascontiguousarray(Dnorm), np.ascontiguousarray(DaxisT)


def _empty_codes(N: int, L: int) -> Codes:
    return Codes(np.zeros((N, L), dtype=np.int64), np.zeros((N, L)), np.zeros(N, dtype=np.int64))


def _combine_codes(DlogT: NDArray[np.float64], codes: Codes) -> NDArray[np.float64]:
    """Combinations ``(N, 4, n)`` of ``codes`` on atoms with logs ``DlogT`` ``(K, 3, n)``."""
    Dnorm, DaxisT = _atom_geometry(DlogT)
    out = np.empty((codes.idx.shape[0], 4, DlogT.shape[2]))
    kern.combine(Dnorm, DaxisT, codes.idx, codes.coef, codes.count, out)
    return out


def _objective_rows(YT: NDArray[np.float64], CT: NDArray[np.float64]) -> NDArray[np.float64]:
    """``sum_j 1 - |<Y_j, C_j>|`` per sample, ``(N, 4, n)`` inputs."""
    return np.sum(1.0 - np.minimum(np.abs(np.sum(YT * CT, axis=1)), 1.0), axis=-1)


def _residual_logs(
    YT: NDArray[np.float64], DlogT: NDArray[np.float64], codes: Codes, left: bool = True
) -> NDArray[np.float64]:
    """Residual logs ``(N, 3, n)``: ``ln(C^-1 Y)`` if ``left``, else ``ln(Y C^-1)``."""
    Dnorm, DaxisT = _atom_geometry(DlogT)
    out = np.empty((YT.shape[0], 3, YT.shape[2]))
    kern.residual_logs(YT, Dnorm, DaxisT, codes.idx, codes.coef, codes.count, left, out)
    return out


def _check_dictionary_log(Dlog: ArrayLike, n: int | None = None) -> NDArray[np.float64]:
    D = np.ascontiguousarray(np.asarray(Dlog, dtype=np.float64))
    if D.ndim != 3 or D.shape[-1] != 3:
        raise ValueError(f"dictionary logs must have shape (K, n, 3), got {D.shape}")
    if n is not None and D.shape[1] != n:
        raise ValueError(f"dictionary has {D.shape[1]} quaternions per atom, samples have {n}")
    if not np.all(np.isfinite(D)):
        raise ValueError("dictionary logs contain NaN or infinite values")
    return D


def quaternion_combination(
    dictionary_log: ArrayLike, W: ArrayLike | sp.spmatrix
) -> NDArray[np.float64]:
    """Quaternion combination ``D (x) X`` of Eq. 2-3.

    Parameters
    ----------
    dictionary_log : array_like, shape (K, n, 3)
        Logarithms of the atoms (``atom = exp(log)``, half-angle convention of
        :func:`quatmotion.quat.log`).
    W : array_like or sparse matrix, shape (N, K)
        Weights. Each row's non-zero atoms are multiplied in descending ``|weight|`` order,
        largest on the left; ties keep ascending atom index.

    Returns
    -------
    ndarray, shape (N, n, 4)
        Unit quaternions, w first.
    """
    Dlog = _check_dictionary_log(dictionary_log)
    codes = matrix_to_codes(W, Dlog.shape[0])
    return _from_soa(_combine_codes(_to_soa(Dlog), codes))


def sparse_code(
    Y: NDArray[np.float64],
    dictionary_log: NDArray[np.float64],
    sparsity: int,
    *,
    residual: str = "left",
    coef_solver: str = "gauss-newton",
    n_sweeps: int = 3,
    refit: str = "final",
) -> tuple[Codes, NDArray[np.float64]]:
    """Quaternion sparse coding (Algorithm 2) of all samples at once.

    All residuals advance together: one step computes every sample's log residual (a Numba
    kernel), projects them on the log atoms with one matrix product, and appends the best atom
    and refits the weights of every sample in parallel.

    Parameters
    ----------
    Y : ndarray, shape (N, n, 4)
        Unit quaternions with ``w >= 0`` (as returned by the estimators' validation).
    dictionary_log : ndarray, shape (K, n, 3)
        Atom logs.
    sparsity : int
        ``L``, the largest number of atoms per sample.
    residual, coef_solver, n_sweeps, refit
        See the module docstring and :class:`QSSD`.

    Returns
    -------
    codes : Codes
        Slots sorted by descending ``|weight|``.
    objective : ndarray, shape (N,)
        ``sum_j 1 - |<Y_j, Yhat_j>|`` per sample.
    """
    if Y.ndim != 3 or Y.shape[-1] != 4:
        raise ValueError(f"Y must have shape (N, n, 4), got {Y.shape}")
    Dlog = _check_dictionary_log(dictionary_log, Y.shape[1])
    codes, objective, _ = _sparse_code(
        _to_soa(Y),
        _to_soa(Dlog),
        sparsity,
        residual=residual,
        coef_solver=coef_solver,
        n_sweeps=n_sweeps,
        refit=refit,
    )
    return codes, objective


def _sparse_code(
    YT: NDArray[np.float64],
    DlogT: NDArray[np.float64],
    sparsity: int,
    *,
    residual: str = "left",
    coef_solver: str = "gauss-newton",
    n_sweeps: int = 3,
    refit: str = "final",
) -> tuple[Codes, NDArray[np.float64], NDArray[np.float64]]:
    """:func:`sparse_code` on samples ``YT`` ``(N, 4, n)`` and atom logs ``DlogT``
    ``(K, 3, n)``, also returning the residual logs ``(N, 3, n)``: half the rotation angle
    between each sample quaternion and its reconstruction is their norm."""
    if residual not in ("left", "right"):
        raise ValueError(f"residual must be 'left' or 'right', got {residual!r}")
    if refit not in ("every", "final"):
        raise ValueError(f"refit must be 'every' or 'final', got {refit!r}")
    if coef_solver not in _SOLVERS:
        raise ValueError(f"coef_solver must be one of {sorted(_SOLVERS)}, got {coef_solver!r}")
    N, _, n = YT.shape
    K = DlogT.shape[0]
    L = min(sparsity, K)
    Dnorm, DaxisT = _atom_geometry(DlogT)
    Dflat = DlogT.reshape(K, 3 * n)
    codes = _empty_codes(N, L)
    objective = np.sum(1.0 - YT[:, 0, :], axis=-1)
    Rlog = np.empty((N, 3, n))
    kern.logs(YT, Rlog)
    Rflat = Rlog.reshape(N, 3 * n)
    # Residual quaternions kept beside their logs: the next step needs both, and keeping them
    # saves an exp per joint and step.
    Rq = YT.copy()
    signal = np.einsum("ij,ij->i", Rflat, Rflat)
    resid_sq = signal.copy()
    left = residual == "left"
    solver = _SOLVERS[coef_solver]
    new_atom = np.zeros(N, dtype=np.int64)
    for step in range(L):
        active = (codes.count == step) & (resid_sq > _CODE_TOL**2)
        if not np.any(active):
            break
        # Projections of every row (inactive ones are ignored): slicing, unlike selecting the
        # active rows, copies nothing. An atom appears once per code: its weight is refit,
        # never duplicated.
        for start in range(0, N, _PROJECTION_CHUNK):
            proj = Rflat[start : start + _PROJECTION_CHUNK] @ Dflat.T
            kern.best_atoms(proj, codes.idx, codes.count, start, new_atom)
        do_refit = refit == "every" or step == L - 1
        kern.add_atom_and_refit(
            YT,
            DlogT,
            Dnorm,
            DaxisT,
            codes.idx,
            codes.coef,
            codes.count,
            new_atom,
            active,
            left,
            n_sweeps,
            solver,
            do_refit,
            signal,
            Rq,
            Rlog,
            objective,
            resid_sq,
        )
    return codes, objective, Rlog


@dataclass
class DictionaryUpdateResult:
    """What one pass of Algorithm 3 did.

    Attributes
    ----------
    dictionary_log : ndarray, shape (K, n, 3)
    codes : Codes
        The codes with updated weights (slots re-sorted by magnitude).
    objective : ndarray, shape (N,)
        Per-sample objective after the pass.
    n_accepted, n_rejected, n_reseeded : int
        Atom updates kept, refused by the safeguard, and unused atoms re-seeded.
    """

    dictionary_log: NDArray[np.float64]
    codes: Codes
    objective: NDArray[np.float64]
    n_accepted: int
    n_rejected: int
    n_reseeded: int


def update_dictionary(
    Y: NDArray[np.float64],
    dictionary_log: NDArray[np.float64],
    codes: Codes,
    *,
    safeguard: bool = False,
    objective: NDArray[np.float64] | None = None,
    robust: bool = True,
) -> DictionaryUpdateResult:
    """Quaternion dictionary learning (Algorithm 3): every atom and its weights, in turn.

    For atom ``k`` and each sample ``i`` using it, ``E_i = P_i^-1 Y_i S_i^-1`` with ``P_i`` the
    combination of the atoms left of ``k`` (larger weights) and ``S_i`` of those right of it;
    the rank-1 SVD ``ln E = w u^T`` gives the new atom ``exp(u)`` and weights ``w``. ``E`` costs
    ``O(L n)`` powers and quaternion products per sample.

    Parameters
    ----------
    Y : ndarray, shape (N, n, 4)
        Unit quaternions with ``w >= 0``.
    dictionary_log : ndarray, shape (K, n, 3)
        Atom logs; not modified (a copy is updated).
    codes : Codes
        Current codes; not modified.
    safeguard : bool
        Keep an atom update only if it does not increase the objective (module docstring).
    objective : ndarray, shape (N,), optional
        Current per-sample objective, if known.
    robust : bool
        Refit each atom once without the samples whose rank-1 misfit exceeds three times the
        median (module docstring).

    Returns
    -------
    DictionaryUpdateResult
    """
    Dlog = _check_dictionary_log(dictionary_log, Y.shape[1])
    result = _update_dictionary(
        _to_soa(Y), _to_soa(Dlog), codes, safeguard=safeguard, objective=objective, robust=robust
    )
    return replace(result, dictionary_log=_from_soa(result.dictionary_log))


def _update_dictionary(
    YT: NDArray[np.float64],
    DlogT: NDArray[np.float64],
    codes: Codes,
    *,
    safeguard: bool,
    objective: NDArray[np.float64] | None,
    robust: bool,
) -> DictionaryUpdateResult:
    """:func:`update_dictionary` on ``YT`` ``(N, 4, n)`` and ``DlogT`` ``(K, 3, n)``; the
    result's ``dictionary_log`` is ``(K, 3, n)`` too."""
    DlogT = DlogT.copy()
    codes = Codes(codes.idx.copy(), codes.coef.copy(), codes.count.copy())
    n = YT.shape[2]
    K = DlogT.shape[0]
    if objective is None:
        objective = _objective_rows(YT, _combine_codes(DlogT, codes))
    objective = objective.copy()
    groups = group_by_atom(codes, K)
    n_reseeded = _reseed_unused(YT, DlogT, codes, objective, groups)
    Dnorm, DaxisT = _atom_geometry(DlogT)
    n_accepted = n_rejected = 0
    for k in range(K):
        samples = groups[k]
        if samples.size == 0:
            continue
        positions = np.argmax(codes.idx[samples] == k, axis=1).astype(np.int64)
        lnE = np.empty((samples.size, 3, n))
        kern.atom_residual_logs(
            YT, Dnorm, DaxisT, codes.idx, codes.coef, codes.count, samples, positions, lnE
        )
        lnE_flat = lnE.reshape(samples.size, 3 * n)
        u, w = rank1(lnE_flat, DlogT[k].ravel())
        if robust and samples.size >= 8:
            # Samples coded with a wrong atom set leave large, unrelated residuals in ln E that
            # pull the least-squares atom away from the true one: refit once without them.
            # |row - w u|^2 = |row|^2 - w^2 for unit u and w = row . u: no (M, 3n) temporary.
            misfit = np.sqrt(np.maximum(np.einsum("ij,ij->i", lnE_flat, lnE_flat) - w * w, 0.0))
            keep = misfit <= 3.0 * np.median(misfit) + 1e-12
            if 4 <= np.count_nonzero(keep) < samples.size:
                u, _ = rank1(lnE_flat[keep], u)
                w = lnE_flat @ u
        if not np.all(np.isfinite(u)) or not np.any(u):
            n_rejected += 1
            continue
        atom_logT = np.ascontiguousarray(u.reshape(3, n))
        if safeguard:
            candidate = np.empty(samples.size)
            kern.candidate_objective(
                YT,
                Dnorm,
                DaxisT,
                codes.idx,
                codes.coef,
                codes.count,
                samples,
                positions,
                atom_logT,
                w,
                candidate,
            )
            current = float(np.sum(objective[samples]))
            if float(np.sum(candidate)) > current + 1e-12 * max(current, 1.0):
                n_rejected += 1
                continue
        DlogT[k] = atom_logT
        Dnorm[k], DaxisT[k] = _atom_geometry(atom_logT)
        kern.commit_atom(codes.idx, codes.coef, codes.count, samples, positions, w)
        if safeguard:
            objective[samples] = candidate
        n_accepted += 1
    if not safeguard:
        kern.objectives(YT, Dnorm, DaxisT, codes.idx, codes.coef, codes.count, objective)
    return DictionaryUpdateResult(DlogT, codes, objective, n_accepted, n_rejected, n_reseeded)


def _reseed_unused(
    YT: NDArray[np.float64],
    DlogT: NDArray[np.float64],
    codes: Codes,
    objective: NDArray[np.float64],
    groups: list[NDArray[np.int64]],
) -> int:
    unused = [k for k in range(DlogT.shape[0]) if groups[k].size == 0]
    if not unused:
        return 0
    worst = np.argsort(-objective, kind="stable")[: len(unused)]
    sub = Codes(codes.idx[worst], codes.coef[worst], codes.count[worst])
    Rlog = _residual_logs(np.ascontiguousarray(YT[worst]), DlogT, sub)
    done = 0
    for k, r in zip(unused, Rlog, strict=False):
        norm = np.linalg.norm(r)
        if norm > _CODE_TOL:
            DlogT[k] = r / norm
            done += 1
    return done


@dataclass
class _FitState:
    """What QSSD's fit carries between iterations (kernel layout)."""

    YT: NDArray[np.float64]
    DlogT: NDArray[np.float64]
    work: float
    best_total: float = np.inf
    best_dictionary_log: NDArray[np.float64] | None = None


class QSSD(DictionaryLearner):
    """Quaternion space sparse decomposition (Algorithms 2-4 of the paper).

    Parameters
    ----------
    n_atoms : int
        ``K``, number of dictionary atoms.
    sparsity : int
        ``L``, largest number of atoms per sample.
    max_iter : int
        Largest number of coding + dictionary iterations (Algorithm 4).
    tol : float
        Stop when the objective after coding improves by less than ``tol`` times its value.
        ``0`` runs all ``max_iter`` iterations.
    residual : {"left", "right"}
        Residual for atom selection; see the module docstring.
    coef_solver : {"gauss-newton", "weighted", "paper"}
        Weight refit: joint Gauss-Newton, or coordinate descent with weighted or plain Eq. 6.
    n_sweeps : int
        Gauss-Newton steps or coordinate-descent sweeps per refit.
    refit : {"final", "every"}
        Refit all weights after the last added atom only, or after every one (the paper).
    safeguard : bool
        Monotone dictionary stage (module docstring).
    robust : bool
        Refit each atom without the samples it fits worst (module docstring).
    keep_best : bool
        Return the dictionary whose coding had the lowest training objective, rather than the
        last one (neither stage is guaranteed monotone without the safeguard).
    init : {"log-ksvd", "samples"}
        Initial atoms: random samples (the paper), refined by ``init_iter`` iterations of
        linear K-SVD on the sample logs for ``"log-ksvd"``.
    init_iter : int
        Linear K-SVD iterations of ``init="log-ksvd"``.
    random_state : int, RandomState or None
        Seeds the choice of initial atoms (Algorithm 4 line 1: random samples).
    verbose : bool
        Print one line per iteration.

    Attributes
    ----------
    dictionary_ : ndarray, shape (K, n, 4)
        Atoms, unit quaternions with ``w > 0``.
    dictionary_log_ : ndarray, shape (K, n, 3)
        Their logs, each of unit norm as a ``3n``-vector.
    objective_ : ndarray, shape (n_iter_,)
        The objective ``sum 1 - |<Y, Yhat>|`` after each coding stage.
    n_iter_, errors_, iteration_seconds_, iteration_cpu_seconds_, n_features_in_
        As every :class:`~quatmotion.sparse._base.DictionaryLearner`'s: iterations run, the
        training error after each coding stage (mean rotation angle, degrees per
        quaternion), wall and processor seconds of each iteration, quaternions per sample.
    """

    _parameter_constraints: ClassVar[dict[str, list[Any]]] = {
        **DictionaryLearner._parameter_constraints,
        "residual": [StrOptions({"left", "right"})],
        "coef_solver": [StrOptions(set(_SOLVERS))],
        "n_sweeps": [Interval(Integral, 1, None, closed="left")],
        "refit": [StrOptions({"final", "every"})],
        "safeguard": ["boolean"],
        "robust": ["boolean"],
        "keep_best": ["boolean"],
        "init": [StrOptions({"log-ksvd", "samples"})],
        "init_iter": [Interval(Integral, 1, None, closed="left")],
    }

    def __init__(
        self,
        n_atoms: int = 20,
        *,
        sparsity: int = 5,
        max_iter: int = 50,
        tol: float = 1e-6,
        residual: str = "left",
        coef_solver: str = "gauss-newton",
        n_sweeps: int = 3,
        refit: str = "final",
        safeguard: bool = False,
        robust: bool = True,
        keep_best: bool = True,
        init: str = "log-ksvd",
        init_iter: int = 100,
        random_state: int | np.random.RandomState | None = None,
        verbose: bool = False,
    ) -> None:
        super().__init__(
            n_atoms,
            sparsity=sparsity,
            max_iter=max_iter,
            tol=tol,
            random_state=random_state,
            verbose=verbose,
        )
        self.residual = residual
        self.coef_solver = coef_solver
        self.n_sweeps = n_sweeps
        self.refit = refit
        self.safeguard = safeguard
        self.robust = robust
        self.keep_best = keep_best
        self.init = init
        self.init_iter = init_iter

    def _initial_dictionary(
        self, Y: NDArray[np.float64], rng: np.random.RandomState
    ) -> NDArray[np.float64]:
        """Algorithm 4 line 1: logs of distinct random samples, normalised to unit norm."""
        N, n, _ = Y.shape
        K = self.n_atoms
        logs = quat.log(Y).reshape(N, 3 * n)
        norms = np.linalg.norm(logs, axis=1)
        usable = np.flatnonzero(norms > _CODE_TOL)
        chosen = rng.permutation(usable)[:K]
        D = np.empty((K, 3 * n))
        D[: chosen.size] = logs[chosen] / norms[chosen, None]
        if chosen.size < K:
            # Fewer distinct non-identity samples than atoms: fill with random directions.
            extra = rng.standard_normal((K - chosen.size, 3 * n))
            D[chosen.size :] = extra / np.linalg.norm(extra, axis=1, keepdims=True)
        if self.init == "log-ksvd":
            # First-order model: ln(A^a B^b) = a ln A + b ln B + O(ab [ln A, ln B]), so linear
            # K-SVD on the logs finds atoms close to the quaternion ones at a fraction of the cost.
            D = learn_linear_dictionary(
                np.ascontiguousarray(logs), D, self.sparsity, self.init_iter
            )
        return np.ascontiguousarray(D.reshape(K, n, 3))

    def _start(self, Y: NDArray[np.float64], rng: np.random.RandomState) -> _FitState:
        work = float(Y.shape[0] * Y.shape[1] * self.sparsity * self.n_sweeps)
        return _FitState(_to_soa(Y), _to_soa(self._initial_dictionary(Y, rng)), work)

    def _iterate(self, state: _FitState) -> tuple[float, float, str]:
        # BLAS on one thread here too: the atom projections are tiny products, and idle BLAS
        # threads spinning after each one take the cores from Numba's threads.
        with compute_threads(state.work, blas_single=True):
            codes, objective, Rlog = _sparse_code(
                state.YT,
                state.DlogT,
                self.sparsity,
                residual=self.residual,
                coef_solver=self.coef_solver,
                n_sweeps=self.n_sweeps,
                refit=self.refit,
            )
            total = float(np.sum(objective))
            # The rotation angle between sample and reconstruction is twice the norm of the
            # residual log (left or right residual alike): no second combination.
            error = float(np.degrees(2.0 * np.mean(np.linalg.norm(Rlog, axis=1))))
            if total < state.best_total:
                state.best_total, state.best_dictionary_log = total, state.DlogT
            result = _update_dictionary(
                state.YT,
                state.DlogT,
                codes,
                safeguard=self.safeguard,
                objective=objective,
                robust=self.robust,
            )
        state.DlogT = result.dictionary_log
        note = (
            f"accepted {result.n_accepted}, rejected {result.n_rejected}, "
            f"reseeded {result.n_reseeded}, "
        )
        return error, total, note

    def _finish(self, state: _FitState) -> None:
        DlogT = state.DlogT
        if self.keep_best and state.best_dictionary_log is not None:
            # Greedy coding and the log-space dictionary update are not monotone in the
            # objective; keep the dictionary that coded the training set best.
            DlogT = state.best_dictionary_log
        self.dictionary_log_ = _from_soa(DlogT)
        self.dictionary_ = quat.exp(self.dictionary_log_)

    def transform(self, X: ArrayLike) -> sp.csr_matrix:
        """Sparse weights of ``X`` ``(N, n, 4)`` on the learned dictionary (Algorithm 2).

        Returns
        -------
        scipy.sparse.csr_matrix, shape (N, K)
            At most ``sparsity`` non-zeros per row; their magnitudes give the combination order.
        """
        check_is_fitted(self)
        Y = self._check_samples(X)
        work = float(Y.shape[0] * Y.shape[1] * self.sparsity * self.n_sweeps)
        with compute_threads(work, blas_single=True):
            codes, _ = sparse_code(
                Y,
                self.dictionary_log_,
                self.sparsity,
                residual=self.residual,
                coef_solver=self.coef_solver,
                n_sweeps=self.n_sweeps,
                refit=self.refit,
            )
        return codes_to_matrix(codes, self.n_atoms)

    def inverse_transform(self, X: ArrayLike | sp.spmatrix) -> NDArray[np.float64]:
        """Quaternion combination (Eq. 2-3) of weights ``X`` ``(N, K)``: ``-> (N, n, 4)``."""
        check_is_fitted(self)
        return quaternion_combination(self.dictionary_log_, X)
