"""Gaussian priors as a penalty of the ML cost (MAP estimation): the one implementation.

``P(theta) = 1/2 sum_i p_i (theta_i - mu_i)^2`` with the precisions ``p_i = 1 / std_i^2``
of the parameters' Gaussian priors (0 for parameters without one). The problem's cost,
stage 2's NLPs (static and output error), the covariance and the embedding all add it
through this class.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np


__all__ = ["GaussianPenalty"]


@dataclass(frozen=True, eq=False)
class GaussianPenalty:
    """The prior penalty of MAP estimation.

    Attributes
    ----------
    mean : ndarray, shape (n_parameters,)
        The priors' means (physical units; 0 where a parameter has no Gaussian prior).
    precision : ndarray, shape (n_parameters,)
        ``1 / std^2`` (0 where a parameter has no Gaussian prior).
    """

    mean: np.ndarray
    precision: np.ndarray

    @classmethod
    def of(cls, model) -> "GaussianPenalty":
        """The penalty of a model's Gaussian priors (:meth:`casest.Model.gaussian_prior_terms`).

        Parameters
        ----------
        model : Model or DynamicModel

        Returns
        -------
        GaussianPenalty
        """
        mean, precision = model.gaussian_prior_terms()
        return cls(np.asarray(mean, dtype=float), np.asarray(precision, dtype=float))

    @classmethod
    def coerce(cls, penalty) -> "GaussianPenalty | None":
        """None, a GaussianPenalty, or a ``(means, precisions)`` pair as a GaussianPenalty.

        Parameters
        ----------
        penalty : GaussianPenalty, tuple of two ndarray, or None

        Returns
        -------
        GaussianPenalty or None
        """
        if penalty is None or isinstance(penalty, GaussianPenalty):
            return penalty
        mean, precision = penalty
        return cls(np.asarray(mean, dtype=float).reshape(-1), np.asarray(precision, dtype=float).reshape(-1))

    def __iter__(self):  # ``mean, precision = penalty``
        return iter((self.mean, self.precision))

    def key(self) -> tuple:
        """A hashable form, for caches.

        Returns
        -------
        tuple
        """
        return tuple(self.mean.tolist()), tuple(self.precision.tolist())

    def value(self, theta) -> float:
        """P at a numeric theta (physical units).

        Parameters
        ----------
        theta : ndarray, shape (n_parameters,)

        Returns
        -------
        float
        """
        return float(0.5 * np.sum(self.precision * (np.asarray(theta, dtype=float) - self.mean) ** 2))

    def expression(self, theta):
        """P as a CasADi expression of theta (physical units, shape (n_parameters, 1)).

        Parameters
        ----------
        theta : casadi.MX or casadi.SX, shape (n_parameters, 1)

        Returns
        -------
        casadi.MX or casadi.SX
        """
        return 0.5 * ca.sum1(ca.DM(self.precision) * (theta - ca.DM(self.mean)) ** 2)

    def scaled_terms(self, theta, scale: np.ndarray, n_samples: int, n_noise: int) -> tuple:
        """P / N, its gradient and its Hessian in ``w = [theta / scale; noise block]``.

        Returns
        -------
        value : casadi.MX
        gradient : casadi.MX, shape (n_parameters + n_noise, 1)
        hessian : casadi.DM, shape (n_parameters + n_noise,) squared (diagonal)

        Parameters
        ----------
        theta : casadi.MX, shape (n_parameters, 1)
            Scaled parameters.
        scale : ndarray, shape (n_parameters,)
        n_samples : int
        n_noise : int
            Length of the noise block.
        """
        precision, scale = ca.DM(self.precision), ca.DM(scale)
        deviation = theta - ca.DM(self.mean)
        value = 0.5 * ca.sum1(precision * deviation**2) / n_samples
        gradient = ca.vertcat(precision * deviation * scale / n_samples, ca.MX.zeros(n_noise))
        hessian = ca.diag(ca.vertcat(precision * scale**2 / n_samples, ca.DM.zeros(n_noise)))
        return value, gradient, hessian
