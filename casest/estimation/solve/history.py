"""The convergence history of a stage-2 solve: each iterate's parameters, their std and the cost."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..._casadi.numerics import decode_array, encode_array


__all__ = ["ConvergenceHistory"]


@dataclass(frozen=True)
class ConvergenceHistory:
    """Stage 2's iterates, from the start to the estimate (the Gauss-Newton output-error solver
    records them; the others do not).

    Attributes
    ----------
    parameter_names : tuple of str
    theta : ndarray, shape (n_iterates, n_parameters)
        The parameters at the start and after each accepted step (physical units).
    std : ndarray, shape (n_iterates, n_parameters)
        Their standard deviations from the Gauss-Newton information at each iterate (the
        Cramer-Rao bound with R at that iterate; NaN on a bound or where singular).
    cost : ndarray, shape (n_iterates,)
        The ML cost (paper Eq. 6 with the iterate's R).
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
