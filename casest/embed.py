"""The estimator as plain CasADi objects, for use inside larger CasADi workflows.

Three ways in:

- :func:`ml_problem`: the stage-2 NLP (full mode) as symbols: decision vector, data
  parameter, objective with ln|R|, bounds, and the map back to named parameters and R.
  Build a solver once and re-solve it on new data of the same length.
- :func:`add_to_opti`: the same problem inside a user's ``casadi.Opti``, returning Opti
  variables for the parameters and R, so that users add constraints, variables and cost
  terms and pick their own solver.
- :func:`estimator_function`: the whole estimator as a ``casadi.Function``
  (data in, estimates out), callable numerically and inside other CasADi graphs;
  :func:`ml_cost_function` is the cost as a named Function, and ``Model.function`` the
  per-sample model.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from .data import DataError, Dataset
from .model import Model
from .stage2 import (
    SolverSettings,
    residual_square_sum,
    active_bounds,
    data_symbols,
    data_vector,
    ml_objective,
    noise_floor,
)
from .uncertainty import Uncertainty, parameter_uncertainty

__all__ = ["MLProblem", "ml_problem", "OptiEstimation", "add_to_opti", "estimator_function", "ml_cost_function"]


@dataclass
class MLProblem:
    """The full-mode stage-2 NLP as CasADi symbols.

    Decision vector ``x = [s; rho]`` with ``theta = scale * s`` (physical parameters)
    and ``rho_j = ln R_j``; NLP parameter ``p = [vec(X); vec(Z)]`` (the data).

    Attributes
    ----------
    model : Model
    n_samples : int
    x : casadi.MX, shape (n_parameters + n_outputs, 1)
        Decision variables.
    x_names : list of str
        Names of the entries of ``x`` (parameter names, then ``ln_R[channel]``).
    p : casadi.MX, shape ((n_signals + n_outputs) * N, 1)
        The data as NLP parameters (see :meth:`data_vector`).
    f : casadi.MX
        The ML objective J of Eq. 6 (with N/2 ln|R|, constants dropped).
    theta : casadi.MX, shape (n_parameters, 1)
        Physical parameters as an expression of ``x``.
    R : casadi.MX, shape (n_outputs, 1)
        Noise variances as an expression of ``x``.
    scale : ndarray, shape (n_parameters,)
        theta = scale * s.
    """

    model: Model
    n_samples: int
    x: ca.MX
    x_names: list
    p: ca.MX
    f: ca.MX
    theta: ca.MX
    R: ca.MX
    scale: np.ndarray

    def nlp(self, objective_scale: float | None = None) -> dict:
        """``{"x", "p", "f"}`` for ``casadi.nlpsol``; ``f`` divided by N unless told otherwise."""
        scale = 1.0 / self.n_samples if objective_scale is None else objective_scale
        return {"x": self.x, "p": self.p, "f": self.f * scale}

    def solver(self, settings: SolverSettings | None = None, options: dict | None = None) -> ca.Function:
        """An IPOPT solver for this problem (exact Hessian), built once, re-solvable on new data."""
        opts = (settings or SolverSettings()).nlpsol_options()
        opts.update(options or {})
        return ca.nlpsol(f"casest_ml_{self.model.name}", "ipopt", self.nlp(), opts)

    def data_vector(self, data: Dataset) -> np.ndarray:
        """Numeric value of ``p`` for a dataset of N samples."""
        data.check_model(self.model)
        if data.has_missing:
            raise DataError("the embedding API does not take data with missing outputs yet; use casest.estimate, "
                            "or drop the samples with missing outputs")
        if data.n_samples != self.n_samples:
            raise ValueError(f"this problem was built for N = {self.n_samples} samples, the data have {data.n_samples}")
        return data_vector(data)

    def bounds(self, data: Dataset, settings: SolverSettings | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(lbx, ubx)``: parameter boxes (scaled) and ln of the noise floor for rho."""
        floor = noise_floor(data, settings or SolverSettings())
        m = self.model
        lbx = np.concatenate([m.lower_bounds / self.scale, np.log(floor)])
        ubx = np.concatenate([m.upper_bounds / self.scale, np.full(m.n_outputs, np.inf)])
        return lbx, ubx

    def x0(self, theta, R) -> np.ndarray:
        """Decision vector for physical ``theta`` (mapping or array) and variances ``R``."""
        theta = self.model.vector(theta)
        return np.concatenate([theta / self.scale, np.log(np.asarray(R, dtype=float).reshape(-1))])

    def unpack(self, x) -> tuple[np.ndarray, np.ndarray]:
        """``(theta, R)`` from a numeric decision vector: shapes (n_parameters,), (n_outputs,)."""
        x = np.asarray(x, dtype=float).reshape(-1)
        n = self.model.n_parameters
        return x[:n] * self.scale, np.exp(x[n:])

    def named(self, x) -> dict:
        """Parameters and R by name from a numeric decision vector."""
        theta, R = self.unpack(x)
        out = dict(zip(self.model.parameter_names, theta.tolist()))
        out.update({f"R[{c}]": float(r) for c, r in zip(self.model.output_names, R)})
        return out


def ml_problem(model: Model, n_samples: int) -> MLProblem:
    """Build the stage-2 ML problem for data of ``n_samples`` samples (see :class:`MLProblem`)."""
    p, X, Z = data_symbols(model, n_samples)
    scale = model.scales
    s = ca.MX.sym("s", model.n_parameters)
    rho = ca.MX.sym("rho", model.n_outputs)
    theta = s * ca.DM(scale)
    f = ml_objective(residual_square_sum(model, n_samples)(X, Z, theta), rho, n_samples)
    names = list(model.parameter_names) + [f"ln_R[{c}]" for c in model.output_names]
    return MLProblem(model, n_samples, ca.vertcat(s, rho), names, p, f, theta, ca.exp(rho), scale)


@dataclass
class OptiEstimation:
    """The estimation problem inside a user's ``casadi.Opti``.

    Attributes
    ----------
    opti : casadi.Opti
    theta : casadi.MX, shape (n_parameters, 1)
        Physical parameters (an expression of the scaled Opti variable ``s``).
    s : casadi.MX
        The Opti variable, theta / scale.
    R : casadi.MX, shape (n_outputs, 1)
        Noise variances, exp(rho).
    rho : casadi.MX
        The Opti variable ln R.
    data : casadi.MX
        Opti parameter holding the data vector (set with :meth:`set_data`).
    floor : casadi.MX
        Opti parameter holding ln of the noise floor (set with the data).
    J : casadi.MX
        The ML cost of Eq. 6.
    problem : MLProblem
    """

    opti: ca.Opti
    theta: ca.MX
    s: ca.MX
    R: ca.MX
    rho: ca.MX
    data: ca.MX
    floor: ca.MX
    J: ca.MX
    problem: MLProblem

    def parameter(self, name: str) -> ca.MX:
        """The Opti expression of one parameter, by name."""
        return self.theta[self.problem.model.index(name)[0]]

    def set_data(self, data: Dataset, settings: SolverSettings | None = None) -> None:
        """Give the data parameter its value (and the noise floor its bound)."""
        self.opti.set_value(self.data, self.problem.data_vector(data))
        self.opti.set_value(self.floor, np.log(noise_floor(data, settings or SolverSettings())))

    def set_initial(self, theta, R) -> None:
        """Initial guess: physical theta (mapping or array), variances R."""
        x0 = self.problem.x0(theta, R)
        n = self.problem.model.n_parameters
        self.opti.set_initial(self.s, x0[:n])
        self.opti.set_initial(self.rho, x0[n:])

    def minimize(self, extra=0) -> None:
        """Set the objective J / N + ``extra`` (the user's own terms, in the same scale)."""
        self.opti.minimize(self.J / self.problem.n_samples + extra)

    def values(self, sol) -> tuple[np.ndarray, np.ndarray]:
        """``(theta, R)`` at an Opti solution."""
        theta = np.asarray(sol.value(self.theta), dtype=float).reshape(-1)
        R = np.asarray(sol.value(self.R), dtype=float).reshape(-1)
        return theta, R

    def standard_deviations(self, sol, data: Dataset, method: str = "hessian") -> Uncertainty:
        """Covariance from the exact Hessian of J at the solution (see :mod:`casest.uncertainty`).

        User constraints are not taken into account: this is the covariance of the
        unconstrained ML problem at the returned point (with parameters on their box
        bounds held fixed).
        """
        theta, R = self.values(sol)
        m = self.problem.model
        active = active_bounds(theta, m.lower_bounds, m.upper_bounds, m.scales)
        at_floor = R <= noise_floor(data, SolverSettings()) * (1 + 1e-6)
        return parameter_uncertainty(m, data, theta, R, active, at_floor, method)


def add_to_opti(opti: ca.Opti, model: Model, data: Dataset, settings: SolverSettings | None = None) -> OptiEstimation:
    """Put the ML estimation problem for ``data`` into ``opti``.

    Creates the Opti variables (scaled parameters and ln R), a data parameter set to
    ``data``, the parameters' box constraints and the noise floor, an initial guess at
    the nominal values, and sets ``J / N`` as the objective (call
    :meth:`OptiEstimation.minimize` again to add terms). The user picks the solver
    (``opti.solver("ipopt", ...)``) and may add constraints and variables.

    Returns
    -------
    OptiEstimation
    """
    data.check_model(model)
    problem = ml_problem(model, data.n_samples)
    s = opti.variable(model.n_parameters)
    rho = opti.variable(model.n_outputs)
    p = opti.parameter(problem.p.numel())
    floor = opti.parameter(model.n_outputs)
    J = ca.substitute([problem.f], [problem.x, problem.p], [ca.vertcat(s, rho), p])[0]
    theta = s * ca.DM(problem.scale)
    for i, prm in enumerate(model.parameters):
        if np.isfinite(prm.lb):
            opti.subject_to(s[i] >= prm.lb / problem.scale[i])
        if np.isfinite(prm.ub):
            opti.subject_to(s[i] <= prm.ub / problem.scale[i])
    opti.subject_to(rho >= floor)
    est = OptiEstimation(opti, theta, s, ca.exp(rho), rho, p, floor, J, problem)
    est.set_data(data, settings)
    resid = data.outputs - model.predict(model.nominal, data.signals)
    est.set_initial(model.nominal, np.maximum(np.mean(resid**2, axis=0), 1e-12))
    est.minimize()
    return est


def estimator_function(
    model: Model, n_samples: int, settings: SolverSettings | None = None, name: str = "estimator"
) -> ca.Function:
    """The ML estimator as a ``casadi.Function``.

    ``estimator(signals[n_signals x N], outputs[n_outputs x N], theta0[n_parameters])
    -> (theta[n_parameters], R[n_outputs])``: a full-mode IPOPT solve from ``theta0``
    (physical units; R starts at the residual mean square there). It can be called
    numerically or on CasADi symbols; derivatives of the outputs with respect to the
    data come from IPOPT's parametric sensitivities. Multipliers below 1e-10 are
    zeroed (``min_lam``) so that inactive bounds do not enter those sensitivities.
    """
    settings = settings or SolverSettings()
    problem = ml_problem(model, n_samples)
    solver = problem.solver(settings, {"min_lam": 1e-10})
    X = ca.MX.sym("signals", model.n_signals, n_samples)
    Z = ca.MX.sym("outputs", model.n_outputs, n_samples)
    theta0 = ca.MX.sym("theta0", model.n_parameters)
    p = ca.vertcat(ca.vec(X), ca.vec(Z))
    S0 = residual_square_sum(model, n_samples)(X, Z, theta0)
    mean_square = ca.sum2(Z**2) / n_samples
    floor = settings.noise_floor * ca.fmax(mean_square, 1e-300)
    rho0 = ca.log(ca.fmax(S0 / n_samples, floor))
    lbx = ca.vertcat(ca.DM(model.lower_bounds / problem.scale), ca.log(floor))
    ubx = ca.vertcat(ca.DM(model.upper_bounds / problem.scale), ca.DM.inf(model.n_outputs))
    sol = solver(x0=ca.vertcat(theta0 / ca.DM(problem.scale), rho0), p=p, lbx=lbx, ubx=ubx)
    x = sol["x"]
    n = model.n_parameters
    theta = x[:n] * ca.DM(problem.scale)
    R = ca.exp(x[n:])
    return ca.Function(name, [X, Z, theta0], [theta, R], ["signals", "outputs", "theta0"], ["theta", "R"])


def ml_cost_function(model: Model, n_samples: int) -> ca.Function:
    """``J(theta[n_p], R[n_y], signals[n_s x N], outputs[n_y x N])``: Eq. 6 as a named Function."""
    theta = ca.MX.sym("theta", model.n_parameters)
    R = ca.MX.sym("R", model.n_outputs)
    X = ca.MX.sym("signals", model.n_signals, n_samples)
    Z = ca.MX.sym("outputs", model.n_outputs, n_samples)
    J = ml_objective(residual_square_sum(model, n_samples)(X, Z, theta), ca.log(R), n_samples)
    return ca.Function("ml_cost", [theta, R, X, Z], [J], ["theta", "R", "signals", "outputs"], ["J"])
