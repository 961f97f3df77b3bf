"""Joint state and parameter estimation with the EKF (summary Sec. 1.2): parameters appended to the state.

Parameters of a :class:`casest.DynamicModel` that are to be estimated with the states become
states themselves, with a zero right-hand side (constant) or a random walk (their own process
noise), their prior mean and variance as the initial state; the EKF of the augmented model then
estimates states and parameters together, online or over a record. The other parameters keep
the given values.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from ..models import ModelError, OptionError
from ..models.dynamic import DynamicModel, State
from ..checks import covariance_argument
from ..filters.ekf import ExtendedKalmanFilter
from ..filters.model_filter import process_noise_matrix

__all__ = ["augmented_model", "joint_filter"]


def augmented_model(model: DynamicModel, initial: Mapping[str, float]) -> DynamicModel:
    """``model`` with the parameters named in ``initial`` as constant states (zero rhs) starting there.

    Parameters
    ----------
    model : DynamicModel
    initial : mapping of str to float
        Parameter name -> the initial value of its state (physical unit).

    Returns
    -------
    DynamicModel
        States: the model's, then the parameters in the order given; its parameters: the others.
    """
    spec = dict(model._spec)
    names = list(initial)
    declared = [p.name for p in spec["parameters"]]
    unknown = [n for n in names if n not in declared]
    if unknown:
        raise ModelError(f"joint estimation of {unknown}, which are not parameters of {model.name!r}: {declared}")
    if any(isinstance(s, State) and s.initial in names for s in spec["states"]):
        raise ModelError("a parameter that is a state's initial value cannot also be a state: estimate the initial "
                         "state through P0 instead")
    if spec.get("delays") and set(names) & set(dict(spec["delays"]).values()):
        raise ModelError("a delay parameter cannot be estimated as a state: estimate it by output error")
    by_name = {p.name: p for p in spec["parameters"]}
    states = list(spec["states"]) + [State(n, float(initial[n]), by_name[n].unit) for n in names]
    rhs = dict(spec["rhs"])
    rhs.update({n: 0.0 for n in names})
    options = {k: v for k, v in spec.items() if k not in ("parameters", "states", "inputs", "rhs", "outputs", "name")}
    return DynamicModel([p for p in spec["parameters"] if p.name not in names], states, spec["inputs"], rhs,
                        spec["outputs"], name=f"{model.name}_joint", **options)


#: the keyword options joint_filter passes on to ExtendedKalmanFilter
EKF_OPTIONS = ("iterated", "tol", "max_iterations", "input_noise")


def _joint_arguments(model: DynamicModel, theta, estimate) -> tuple:
    """(every parameter's value, the names estimated jointly, their prior variances), checked."""
    if not isinstance(theta, Mapping):
        raise OptionError(f"theta must map every parameter name to its value (the initial means of those estimated), "
                          f"got a {type(theta).__name__}; e.g. {dict.fromkeys(model.parameter_names, 0.0)}")
    if not isinstance(estimate, Mapping) or not estimate:
        raise OptionError("estimate must map the jointly estimated parameters to their prior variances (at least one); "
                          "without any, use casest.ExtendedKalmanFilter on the model itself")
    values = {str(k): float(v) for k, v in theta.items()}
    names = [str(n) for n in estimate]
    for what, given in (("theta", list(values)), ("estimate", names)):
        unknown = [n for n in given if n not in model.parameter_names]
        if unknown:
            raise OptionError(f"{what} names {unknown}, which are not parameters of the model "
                              f"{list(model.parameter_names)}")
    missing = [n for n in model.parameter_names if n not in values]
    if missing:
        raise OptionError(f"theta must give every parameter (the initial means of those estimated); missing {missing}")
    bad = [n for n, v in values.items() if not np.isfinite(v)]
    if bad:
        raise OptionError(f"theta of {bad} is not finite")
    variances = np.array([float(estimate[n]) for n in names])
    if np.any(~np.isfinite(variances)) or np.any(variances <= 0):
        raise OptionError("the prior variances of the jointly estimated parameters (estimate) must be positive and finite")
    return values, names, variances


def joint_filter(model: DynamicModel, theta, estimate: Mapping[str, float], process_noise, R, P0,
                 parameter_noise: Mapping[str, float] | None = None, **options) -> ExtendedKalmanFilter:
    """The EKF (or IEKF) of ``model`` with some parameters estimated jointly with the states.

    Parameters
    ----------
    model : DynamicModel
    theta : mapping of str to float
        Values of every parameter: the initial means of those estimated, the values of the others.
    estimate : mapping of str to float
        Parameter name -> prior variance of its initial value (unit squared).
    process_noise : mapping, array_like (n,) or (n, n)
        The states' continuous process noise (:func:`casest.filters.ekf.process_noise_matrix`).
    R : array_like, shape (n_outputs,) or (n_outputs, n_outputs)
    P0 : array_like, shape (n,) or (n, n)
        Covariance of the initial states (the model's states only).
    parameter_noise : mapping of str to float, optional
        Random-walk intensity of an estimated parameter (unit squared per second): lets it drift;
        default 0 (constant).
    **options
        ``iterated``, ``tol``, ``max_iterations``, ``input_noise`` of :class:`ExtendedKalmanFilter`.

    Returns
    -------
    ExtendedKalmanFilter
        On :func:`augmented_model`: its states are the model's, then the estimated parameters.
    """
    values, names, variances = _joint_arguments(model, theta, estimate)
    augmented = augmented_model(model, {n: values[n] for n in names})
    n = model.n_states
    P_states = covariance_argument(P0, n, "P0")
    P_all = np.zeros((n + len(names), n + len(names)))
    P_all[:n, :n], P_all[n:, n:] = P_states, np.diag(variances)
    Q_states = process_noise_matrix(model, process_noise)
    walk = dict(parameter_noise or {})
    unknown = [k for k in walk if k not in names]
    if unknown:
        raise OptionError(f"parameter_noise names {unknown}, which are not estimated jointly ({names})")
    bad = [k for k, v in walk.items() if not (np.isfinite(float(v)) and float(v) >= 0)]
    if bad:
        raise OptionError(f"parameter_noise of {bad} must be a finite intensity >= 0 (unit squared per second)")
    unknown_options = sorted(set(options) - set(EKF_OPTIONS))
    if unknown_options:
        raise OptionError(f"joint_filter takes the options {list(EKF_OPTIONS)} of ExtendedKalmanFilter, not "
                          f"{unknown_options}")
    Q_all = np.zeros_like(P_all)
    Q_all[:n, :n] = Q_states
    Q_all[n:, n:] = np.diag([float(walk.get(k, 0.0)) for k in names])
    rest = {k: v for k, v in values.items() if k not in names}
    return ExtendedKalmanFilter(augmented, augmented.vector(rest) if rest else np.zeros(0), Q_all, R, P_all,
                                **options)

