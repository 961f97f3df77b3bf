"""The linearised model an extended Kalman filter runs on: one step of a :class:`casest.DynamicModel`
with its transition matrix and discrete process noise, and the measurement with its Jacobian
(summary Eq. 3.9-3.11 and 3.12), shared by the filters, their compiled passes and filter-error ML.
"""

from __future__ import annotations

from typing import Mapping

import casadi as ca
import numpy as np

from .._casadi.memory import StructureCache
from .._casadi.symbolic_algebra import symmetric_product
from ..models import OptionError
from ..models.dynamic import DynamicModel

__all__ = ["ekf_step_functions", "filter_parameters"]

_EKF_FUNCTIONS = StructureCache()


def filter_parameters(model: DynamicModel, theta) -> np.ndarray:
    """The parameter vector a filter runs with.

    Parameters
    ----------
    model : DynamicModel
    theta : mapping of str to float, or array_like, shape (n_parameters,)

    Returns
    -------
    ndarray, shape (n_parameters,)

    Raises
    ------
    OptionError
        A vector of another length (a mapping is checked by :meth:`DynamicModel.vector`).
    """
    vector = model.vector(theta) if isinstance(theta, Mapping) else np.asarray(theta, dtype=float).reshape(-1)
    if vector.size != model.n_parameters:
        raise OptionError(f"theta must have {model.n_parameters} values, got {vector.size}")
    return vector


def ekf_step_functions(model: DynamicModel) -> tuple[ca.Function, ca.Function]:
    """The CasADi functions of one EKF step (cached on the model), shared by the filters and
    filter-error ML.

    propagate(x, P, u_a, u_b, dt, theta, Qc, u, input_noise) -> (x_next, P_next, Phi) and
    measure(x, u, theta) -> (h, H).
    """
    if model.output_delays:
        raise OptionError(f"the filters measure each sample's own state, and the model delays outputs "
                          f"{list(model.output_delays.delays)}: estimate the delays by output error "
                          "(casest.estimate), then shift those measured outputs back by the estimated delays "
                          "and filter a model without output delays")
    cache = _EKF_FUNCTIONS.setdefault(model, {})
    if "propagate" not in cache:
        step = model.step_function
        Sym = ca.SX if step.is_a("SXFunction") else ca.MX
        n = model.n_states
        x, P, Qc = Sym.sym("x", n), Sym.sym("P", n, n), Sym.sym("Qc", n, n)
        ua, ub = Sym.sym("u_a", step.size1_in(1)), Sym.sym("u_b", step.size1_in(2))
        nu = len(model.inputs)
        dt, theta, uk, su = Sym.sym("dt"), Sym.sym("theta", model.n_parameters), Sym.sym("u", nu), Sym.sym("su", nu)
        th = ca.vertcat(*[theta[i] for i in model.rhs_parameter_index]) if model.rhs_parameter_index else Sym(0, 1)
        x_next = step(x, ua, ub, dt, th)
        Phi = ca.jacobian(x_next, x)
        B = ca.jacobian(model.rhs_function(x, uk, theta), uk)
        Q = Qc + B @ ca.diag(su) @ B.T
        Qd = 0.5 * dt * (symmetric_product(Phi, Q) + Q)  # trapezoidal rule of the Van Loan integral
        P_next = symmetric_product(Phi, P) + Qd
        cache["propagate"] = ca.Function("ekf_propagate", [x, P, ua, ub, dt, theta, Qc, uk, su], [x_next, P_next, Phi])
        out = model.output_model.function
        xs, us = ca.SX.sym("x", n), ca.SX.sym("u", len(model.inputs))
        theta = ca.SX.sym("theta", model.n_parameters)
        h = out(ca.vertcat(xs, us), theta)
        cache["measure"] = ca.Function("ekf_measure", [xs, us, theta], [h, ca.jacobian(h, xs)])
    return cache["propagate"], cache["measure"]
