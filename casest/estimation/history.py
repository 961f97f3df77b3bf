"""The convergence history of a stage-2 solve: each iterate's parameters, their std and the cost."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._casadi.array_json import decode_array, encode_array


__all__ = ["ConvergenceHistory", "iterate_history", "merged_history"]


@dataclass(frozen=True)
class ConvergenceHistory:
    """Stage 2's iterates, from the start to the estimate (the Gauss-Newton output-error solver
    records them always, IPOPT with ``SolverSettings(record_iterates=True)``, Levenberg-Marquardt never).

    Attributes
    ----------
    parameter_names : tuple of str
    theta : ndarray, shape (n_iterates, n_parameters)
        The parameters at the start and after each accepted step (physical units).
    std : ndarray, shape (n_iterates, n_parameters)
        Their standard deviations from the Gauss-Newton information at each iterate (the
        Cramer-Rao bound with R at that iterate, or at its ML value there for IPOPT's
        iterates; NaN where singular).
    cost : ndarray, shape (n_iterates,)
        The ML cost (paper Eq. 6 with the iterate's R, or R profiled out for IPOPT's).
    """

    parameter_names: tuple
    theta: np.ndarray
    std: np.ndarray
    cost: np.ndarray

    def to_dict(self) -> dict:
        """Plain-Python form (arrays via :func:`encode_array`).

        Returns
        -------
        dict
        """
        return {"parameter_names": list(self.parameter_names), "theta": encode_array(self.theta),
                "std": encode_array(self.std), "cost": encode_array(self.cost)}

    @classmethod
    def from_dict(cls, data: dict) -> "ConvergenceHistory":
        """The history of :meth:`to_dict`'s form.

        Parameters
        ----------
        data : dict

        Returns
        -------
        ConvergenceHistory
        """
        return cls(tuple(data["parameter_names"]), decode_array(data["theta"]), decode_array(data["std"]),
                   decode_array(data["cost"]))

    @classmethod
    def stacked(cls, parameter_names, iterates: list) -> "ConvergenceHistory":
        """From a list of (theta, std, cost) tuples.

        Parameters
        ----------
        parameter_names : sequence of str
        iterates : list of (ndarray (n,), ndarray (n,), float)

        Returns
        -------
        ConvergenceHistory
        """
        return cls(tuple(parameter_names), np.array([i[0] for i in iterates], dtype=float),
                   np.array([i[1] for i in iterates], dtype=float), np.array([i[2] for i in iterates], dtype=float))


def iterate_history(problem, thetas: list) -> ConvergenceHistory | None:
    """The history of a solver that gives only its iterates' parameters (IPOPT): at each one the
    cost (R profiled, or the known R) and the Gauss-Newton std (R at its ML value there).

    Parameters
    ----------
    problem : Problem
    thetas : list of ndarray, shape (n_parameters,) each

    Returns
    -------
    ConvergenceHistory or None
        None when there are no iterates.
    """
    if not thetas:
        return None
    model = problem.model
    iterates = []
    for theta in thetas:
        R = problem.noise.profile(problem, theta)  # the ML R there (a known R: the given one)
        cost = problem.cost(theta, R)
        M = problem.noise_term.information(problem.jacobian(theta), R)
        with np.errstate(invalid="ignore", divide="ignore"):
            try:
                std = np.sqrt(np.diag(np.linalg.inv(M)))
            except np.linalg.LinAlgError:
                std = np.full(model.n_parameters, np.nan)
        iterates.append((np.asarray(theta, dtype=float), np.where(np.isfinite(std), std, np.nan), cost))
    return ConvergenceHistory.stacked(model.parameter_names, iterates)


def merged_history(first: ConvergenceHistory | None, second: ConvergenceHistory | None) -> ConvergenceHistory | None:
    """Two solves' histories one after the other (a reduced solve polished in full mode).

    Parameters
    ----------
    first, second : ConvergenceHistory or None

    Returns
    -------
    ConvergenceHistory or None
    """
    if first is None or second is None or first.parameter_names != second.parameter_names:
        return second if second is not None else first
    return ConvergenceHistory(first.parameter_names, np.vstack([first.theta, second.theta]),
                              np.vstack([first.std, second.std]), np.concatenate([first.cost, second.cost]))
