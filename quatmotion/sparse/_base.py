"""The fit loop and parameter checks QSSD and K-SVD share (scikit-learn's estimator style).

Both alternate a sparse-coding stage and a dictionary stage (Algorithm 1 / Algorithm 4) until
the objective after coding stops improving by ``tol`` or ``max_iter`` iterations have run. The
base class owns the loop, the timing and the fitted attributes common to both; a subclass
supplies the start (:meth:`DictionaryLearner._start`), one iteration
(:meth:`DictionaryLearner._iterate`) and the end (:meth:`DictionaryLearner._finish`).
"""

from __future__ import annotations

import time
from numbers import Integral, Real
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.utils import check_random_state

from quatmotion._settings import Interval, validate_parameters
from quatmotion.sparse._common import check_quaternion_samples

__all__ = ["DictionaryLearner"]


class DictionaryLearner(TransformerMixin, BaseEstimator):
    """Base of the dictionary learners: ``fit(X, y=None)`` runs the alternating loop.

    Parameters
    ----------
    n_atoms : int
        ``K``, number of dictionary atoms.
    sparsity : int
        ``L``, largest number of atoms per sample (at most ``n_atoms``).
    max_iter : int
        Largest number of coding + dictionary iterations.
    tol : float
        Stop when the objective after coding improves by less than ``tol`` times its value;
        ``0`` runs all ``max_iter`` iterations.
    random_state : int, RandomState or None
        Seeds the initial atoms.
    verbose : bool
        Print one line per iteration.

    Attributes
    ----------
    n_iter_ : int
        Iterations run.
    errors_ : ndarray, shape (n_iter_,)
        Training reconstruction error after each coding stage: mean rotation angle between
        sample and reconstruction, degrees per quaternion (Eq. 11 with the factor 2 of the
        rotation angle; halve it for the paper's ``arccos``).
    objective_ : ndarray, shape (n_iter_,)
        The learner's objective after each coding stage.
    iteration_seconds_ : ndarray, shape (n_iter_,)
        Wall time of each iteration (coding + dictionary update).
    iteration_cpu_seconds_ : ndarray, shape (n_iter_,)
        Processor time of each iteration summed over threads (robust to a shared machine).
    n_features_in_ : int
        ``n``, quaternions per sample.
    """

    _parameter_constraints: ClassVar[dict[str, list[Any]]] = {
        "n_atoms": [Interval(Integral, 1, None, closed="left")],
        "sparsity": [Interval(Integral, 1, None, closed="left")],
        "max_iter": [Interval(Integral, 1, None, closed="left")],
        "tol": [Interval(Real, 0, None, closed="left")],
        "random_state": ["random_state"],
        "verbose": ["boolean"],
    }

    def __init__(
        self,
        n_atoms: int = 20,
        *,
        sparsity: int = 5,
        max_iter: int = 50,
        tol: float = 1e-6,
        random_state: int | np.random.RandomState | None = None,
        verbose: bool = False,
    ) -> None:
        self.n_atoms = n_atoms
        self.sparsity = sparsity
        self.max_iter = max_iter
        self.tol = tol
        self.random_state = random_state
        self.verbose = verbose

    # Subclass hooks ---------------------------------------------------------------------------
    def _start(self, Y: NDArray[np.float64], rng: np.random.RandomState) -> Any:
        """The learner's state before the first iteration (initial atoms included)."""
        raise NotImplementedError

    def _iterate(self, state: Any) -> tuple[float, float, str]:
        """One coding + dictionary iteration on ``state``: ``(error_deg, objective, note)``,
        the error and objective of the coding stage and a note for ``verbose``."""
        raise NotImplementedError

    def _finish(self, state: Any) -> None:
        """Set the fitted dictionary attributes from the final ``state``."""
        raise NotImplementedError

    # The loop ---------------------------------------------------------------------------------
    def fit(self, X: ArrayLike, y: object = None) -> DictionaryLearner:
        """Learn the dictionary from ``X``.

        Parameters
        ----------
        X : array_like, shape (N, n, 4)
            ``N`` samples of ``n`` unit quaternions (w first).
        y : ignored

        Returns
        -------
        self
        """
        validate_parameters(
            self._parameter_constraints, self.get_params(deep=False), type(self).__name__
        )
        if self.sparsity > self.n_atoms:
            raise ValueError(f"sparsity ({self.sparsity}) cannot exceed n_atoms ({self.n_atoms})")
        Y = check_quaternion_samples(X, "X")
        state = self._start(Y, check_random_state(self.random_state))
        errors: list[float] = []
        objectives: list[float] = []
        seconds: list[float] = []
        cpu_seconds: list[float] = []
        previous = np.inf
        for it in range(self.max_iter):
            t0 = time.perf_counter()
            c0 = time.process_time()
            error, objective, note = self._iterate(state)
            seconds.append(time.perf_counter() - t0)
            cpu_seconds.append(time.process_time() - c0)
            errors.append(error)
            objectives.append(objective)
            if self.verbose:
                print(
                    f"{type(self).__name__} iter {it + 1}: error {error:.6g} deg, "
                    f"objective {objective:.6g}, {note}{seconds[-1]:.3f} s"
                )
            if self.tol > 0 and it > 0 and abs(previous - objective) <= self.tol * previous:
                break
            previous = objective
        self._finish(state)
        self.n_iter_ = len(errors)
        self.errors_ = np.asarray(errors)
        self.objective_ = np.asarray(objectives)
        self.iteration_seconds_ = np.asarray(seconds)
        self.iteration_cpu_seconds_ = np.asarray(cpu_seconds)
        self.n_features_in_ = Y.shape[1]
        return self

    def _check_samples(self, X: ArrayLike) -> NDArray[np.float64]:
        """Validated samples of a fitted learner, with as many quaternions as it was fitted on."""
        Y = check_quaternion_samples(X, "X")
        if Y.shape[1] != self.n_features_in_:
            raise ValueError(
                f"X has {Y.shape[1]} quaternions per sample, the model {self.n_features_in_}"
            )
        return Y
