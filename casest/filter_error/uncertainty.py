"""The covariance path and the parameter fields every filter-error formulation shares.

Each formulation hands over its decision vector at the estimate (scaled parameters, then the
process-noise and noise variables), the information whose inverse is their covariance (the
exact Hessian of V, the Fisher information, or the innovation form's Cramer-Rao information,
optionally with a sandwich's middle), the box, and which variables on a bound it holds;
:func:`held_covariance` inverts the free block (:func:`casest.estimation.uncertainty.covariance_from_hessian`,
bounds by :func:`casest.backend.ipopt.active_bounds`) and returns natural units.
:func:`parameter_fields` gives the fields of a :class:`FilterErrorEstimate` that describe the
model's parameters, the same for every formulation.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..backend.ipopt import active_bounds
from ..estimation.uncertainty import covariance_from_hessian


__all__ = ["HeldCovariance", "held_covariance", "parameter_fields"]


@dataclass(frozen=True)
class HeldCovariance:
    """The covariance of a filter-error decision vector in natural units.

    Attributes
    ----------
    covariance : ndarray, shape (n_w, n_w)
        NaN in the rows and columns of held variables, and everywhere when ``singular``.
    std : ndarray, shape (n_w,)
    active : list of (str or None)
        ``"lower"``/``"upper"`` for a variable on its bound.
    held : ndarray of bool, shape (n_w,)
        The variables held (no std).
    singular : bool
        The free block of the information is singular, indefinite or not finite.
    """

    covariance: np.ndarray
    std: np.ndarray
    active: list
    held: np.ndarray
    singular: bool


def held_covariance(w: np.ndarray, information: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                    to_natural: np.ndarray, holds: Callable[[int, str | None], bool],
                    middle: np.ndarray | None = None) -> HeldCovariance:
    """The inverse information of the free variables (or the sandwich ``M^-1 B M^-1``), in natural units.

    Parameters
    ----------
    w : ndarray, shape (n_w,)
        The decision vector at the estimate (solver units).
    information : ndarray, shape (n_w, n_w)
        The matrix whose inverse is the covariance.
    lower, upper : ndarray, shape (n_w,)
        The box of ``w``.
    to_natural : ndarray, shape (n_w,)
        The factor from solver to natural units of each variable.
    holds : callable (index, side) -> bool
        Whether a variable on a bound (``side`` ``"lower"``/``"upper"``, or None off its bounds)
        is held: the formulation's rule.
    middle : ndarray, shape (n_w, n_w), optional
        The sandwich's middle ``B``; the covariance is then ``M^-1 B M^-1``.

    Returns
    -------
    HeldCovariance
    """
    active = active_bounds(w, lower, upper, np.maximum(1.0, np.abs(w)), tol=1e-8)
    held = np.array([holds(i, side) for i, side in enumerate(active)], dtype=bool)
    free = ~held
    covariance = np.full(information.shape, np.nan)
    block = information[np.ix_(free, free)]
    if not np.all(np.isfinite(block)):  # the filter diverges at the estimate: no covariance to give
        return HeldCovariance(covariance, np.full(w.size, np.nan), active, held, True)
    C, null = covariance_from_hessian(block)
    singular = bool(null.shape[1]) or not np.all(np.isfinite(C))
    if middle is not None and not singular:
        C = C @ middle[np.ix_(free, free)] @ C
    if not singular:
        covariance[np.ix_(free, free)] = C
    covariance = covariance * np.outer(to_natural, to_natural)
    return HeldCovariance(covariance, np.sqrt(np.abs(np.diag(covariance))), active, held, singular)


def parameter_fields(model, theta: np.ndarray, uncertainty: HeldCovariance, reasons: list, codes: list) -> dict:
    """The fields of a :class:`~casest.filter_error.result.FilterErrorEstimate` that
    describe the model's parameters (the first ``n_parameters`` of the decision vector).

    Parameters
    ----------
    model : DynamicModel
    theta : ndarray, shape (n_parameters,)
        The estimate in natural units.
    uncertainty : HeldCovariance
    reasons : list of (str or None), length n_parameters
        Why a std is missing.
    codes : list of (StdReason or None), length n_parameters

    Returns
    -------
    dict
    """
    npar = model.n_parameters
    return dict(model_name=model.name, parameter_names=tuple(model.parameter_names), theta=theta,
                std=uncertainty.std[:npar], std_reasons=list(reasons), std_reason_codes=list(codes),
                active_bounds=list(uncertainty.active[:npar]), lower_bounds=model.lower_bounds,
                upper_bounds=model.upper_bounds, parameter_units=tuple(p.unit for p in model.parameters),
                output_names=tuple(model.output_names), output_units=tuple(model.output_units),
                covariance=uncertainty.covariance)
