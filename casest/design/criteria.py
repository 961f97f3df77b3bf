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


__all__ = ["ROBUST", "CRITERION_TERMS", "parameter_guesses", "check_criterion", "check_noise", "criterion_terms",
           "unidentified_combination"]

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
    """(objective term to minimise, constraints >= 0) of one guess's scaled information F: the
    criterion's entry of :data:`CRITERION_TERMS`.

    Parameters
    ----------
    F : casadi.SX, shape (n, n)
        The scaled Fisher information of one parameter guess.
    criterion : {"D", "A", "E", "c"}
    c_scaled : ndarray, shape (n,) or None
        The c criterion's combination, in scaled parameters.
    t : casadi.SX or None
        The E criterion's lower bound on the smallest eigenvalue (a decision variable).

    Returns
    -------
    objective : casadi.SX, scalar
    constraints : casadi.SX, shape (k, 1)
        Each >= 0 at a feasible design.
    """
    return CRITERION_TERMS[criterion](F, c_scaled, t)


def _d_optimal(F, c_scaled, t):
    """ln det F^-1 = -2 sum ln diag(L), L the Cholesky factor of F."""
    return -2 * ca.sum1(ca.log(ca.diag(cholesky_lower(F)))), ca.SX(0, 1)


def _a_optimal(F, c_scaled, t):
    """trace F^-1 = ||L^-1||_F^2."""
    return ca.sumsqr(lower_triangular_inverse(cholesky_lower(F))), ca.SX(0, 1)


def _e_optimal(F, c_scaled, t):
    """Maximise t with F - t I positive semi-definite (its LDL pivots >= 0)."""
    return -t, ldl_pivots(F - t * ca.SX.eye(F.size1()))


def _c_optimal(F, c_scaled, t):
    """c' F^-1 c = ||L^-1 c||^2."""
    return ca.sumsqr(ca.mtimes(lower_triangular_inverse(cholesky_lower(F)), ca.DM(c_scaled))), ca.SX(0, 1)


#: the design criteria by name (``criterion=``), each giving (objective, constraints >= 0) of F
CRITERION_TERMS = {"D": _d_optimal, "A": _a_optimal, "E": _e_optimal, "c": _c_optimal}


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
