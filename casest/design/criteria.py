"""The design criteria on the Fisher information (D, A, E, c), the parameter guesses of a
robust design, and words for an unidentified parameter combination."""

from __future__ import annotations

from typing import Mapping

import casadi as ca
import numpy as np

from ..checks import noise_covariance, noise_variances
from ..options import Criterion, Robust, check_option, choices
from ..errors import OptionError
from .information import cholesky_lower, ldl_pivots, lower_triangular_inverse


__all__ = ["ROBUST", "parameter_guesses", "check_criterion", "check_noise", "criterion_terms", "unidentified_combination"]

ROBUST = choices(Robust)


def parameter_guesses(model, theta) -> list[np.ndarray]:
    """One or several parameter guesses as physical vectors."""
    if isinstance(theta, Mapping) or np.ndim(theta) == 1 and not isinstance(theta[0], (Mapping, list, tuple, np.ndarray)):
        return [model.vector(theta)]
    guesses = [model.vector(t) for t in theta]
    if not guesses:
        raise OptionError("give at least one parameter guess")
    return guesses


def check_criterion(criterion: str, robust: str, c, n: int):
    check_option("criterion", criterion, Criterion)
    check_option("robust", robust, Robust)
    if criterion == "c":
        if c is None:
            raise OptionError("the c criterion needs c, the linear combination c' theta whose variance is minimised")
        c = np.asarray(c, dtype=float).reshape(-1)
        if c.size != n:
            raise OptionError(f"c needs {n} entries (one per parameter), got {c.size}")
    return c


def criterion_terms(F: ca.SX, criterion: str, c_scaled, t: ca.SX | None):
    """(objective term to minimise, constraints >= 0) of one guess's scaled information F."""
    if criterion == "E":
        n = F.size1()
        return -t, ldl_pivots(F - t * ca.SX.eye(n))
    L = cholesky_lower(F)
    if criterion == "D":
        return -2 * ca.sum1(ca.log(ca.diag(L))), ca.SX(0, 1)
    M = lower_triangular_inverse(L)
    if criterion == "A":
        return ca.sumsqr(M), ca.SX(0, 1)
    return ca.sumsqr(ca.mtimes(M, ca.DM(c_scaled))), ca.SX(0, 1)


def unidentified_combination(F: np.ndarray, names) -> str:
    """Words for the parameter combination a (near-)singular information leaves undetermined."""
    values, vectors = np.linalg.eigh(F)
    v = vectors[:, 0]
    top = np.argsort(-np.abs(v))[:3]
    combo = " + ".join(f"{v[i]:.2f} {names[i]}" for i in top if abs(v[i]) > 0.05)
    return f"{combo} (smallest eigenvalue {values[0]:.3g}, largest {values[-1]:.3g})"


def check_noise(R, outputs) -> None:
    """Refuse noise variances that are not positive and finite (a diagonal, or a full covariance;
    one per experiment as a list).

    Parameters
    ----------
    R : array_like, shape (n_outputs,) or (n_outputs, n_outputs), or a list of them
    outputs : sequence of str
        The model's outputs, in order.

    Returns
    -------
    None

    Raises
    ------
    OptionError
        Naming R, the outputs and the values (the checks of :mod:`casest.checks`).
    """
    outputs = list(outputs)
    for R_e in (R if isinstance(R, (list, tuple)) and np.ndim(R[0]) > 0 and len(R) != len(outputs) else [R]):
        if np.ndim(R_e) == 2:
            noise_covariance(R_e, outputs)
        else:
            noise_variances(R_e, outputs)
