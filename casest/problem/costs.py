"""The ML cost of paper Eq. 6 of a model and data, given R or with R at its optimum (the
:class:`casest.Problem` methods, for callers with a model and data in hand)."""

from __future__ import annotations

from ..data.dataset import Dataset
from ..models import Model
from .problem import as_problem


__all__ = ["ml_cost", "concentrated_cost"]


def ml_cost(model: Model, data: Dataset, theta, R) -> float:
    """J(theta, R) of paper Eq. 6 without constants (see :meth:`Problem.cost`).

    Parameters
    ----------
    model : Model
    data : Dataset
    theta : array_like, shape (n_parameters,), or mapping
    R : array_like, shape (n_outputs,)
        Noise variances (diagonal of R), unit of z squared; or a full R, shape
        (n_outputs, n_outputs).

    Returns
    -------
    float
        ``1/2 sum_k ||z_k - h_k||^2_{R^-1} + sum_j N_j/2 ln R_j`` (dimensionless).
    """
    return as_problem(model, data).cost(theta, R)


def concentrated_cost(model: Model, data: Dataset, theta) -> float:
    """Paper Eq. 6 minimised over the diagonal R at theta (see :meth:`Problem.profile_cost`).

    Parameters
    ----------
    model : Model
    data : Dataset
    theta : array_like, shape (n_parameters,), or mapping

    Returns
    -------
    float
        ``sum_j N_j/2 ln(S_j / N_j) + (sum_j N_j) / 2``, S_j the residual sum of squares of
        output j and N_j its number of measurements.
    """
    return as_problem(model, data).profile_cost(theta)
