"""The ML estimation inside a user's ``casadi.Opti``: :func:`add_to_opti` puts the variables,
data parameter, bounds and start there and returns an :class:`OptiEstimation` that reads the
solution back."""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..backend.linalg import variances_of
from ..backend.ipopt import SolverSettings, active_bounds, noise_floor
from ..data.dataset import Dataset
from ..problem.separate import separate
from ..two_stage.sweep import sweep
from ..estimation.uncertainty import Uncertainty, parameter_uncertainty
from ..models import Model, OptionError
from ..problem.problem import Problem, as_problem
from .embed import MLProblem, ml_problem
from ..options import CovarianceMethod, OptiStart


__all__ = ["OptiEstimation", "add_to_opti"]


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
    R : casadi.MX, shape (n_outputs, 1), or (n_outputs, n_outputs) for a full R
        Noise variances (a constant for known noise).
    rho : casadi.MX or None
        The Opti variable of the noise block: ln R, or the log-Cholesky vector of a full R;
        None for known noise.
    data : casadi.MX
        Opti parameter holding the data vector (set with :meth:`set_data`).
    floor : casadi.MX or None
        Opti parameter holding ln of the noise floor (set with the data); None for known noise.
    J : casadi.MX
        The ML cost of Eq. 6 (MAP: with the prior penalties).
    problem : MLProblem
    settings : SolverSettings
        The settings it was built with (the noise floor of the bounds and of the std).
    """

    opti: ca.Opti
    theta: ca.MX
    s: ca.MX
    R: ca.MX
    rho: ca.MX | None
    data: ca.MX
    floor: ca.MX | None
    J: ca.MX
    problem: MLProblem
    settings: SolverSettings | None = None

    @property
    def objective(self) -> ca.MX:
        """The estimation's cost term ``J / N`` for the user's objective:
        ``opti.minimize(est.objective + my_terms)`` (add_to_opti sets no objective itself)."""
        return self.J / self.problem.n_samples

    def parameter(self, name: str) -> ca.MX:
        """The Opti expression of one parameter, by name.

        Parameters
        ----------
        name : str

        Returns
        -------
        casadi.MX
        """
        return self.theta[self.problem.model.index(name)[0]]

    def set_data(self, data: Dataset | None = None, settings: SolverSettings | None = None) -> None:
        """Give the data parameter its value (and the noise floor its bound); default the problem's data.

        Parameters
        ----------
        data : Dataset, optional
        settings : SolverSettings, optional

        Returns
        -------
        None
        """
        self.opti.set_value(self.data, self.problem.data_vector(data))
        if self.floor is not None:
            data = data if data is not None else self.problem.problem.data
            self.opti.set_value(self.floor, np.log(noise_floor(data, settings or SolverSettings())))

    def set_initial(self, theta, R) -> None:
        """Initial guess: physical theta (mapping or array), variances R (a full R: a matrix).

        Parameters
        ----------
        theta : mapping or array_like, shape (n_parameters,)
        R : array_like

        Returns
        -------
        None
        """
        x0 = self.problem.x0(theta, R)
        n = self.problem.model.n_parameters
        self.opti.set_initial(self.s, x0[:n])
        if self.rho is not None:
            self.opti.set_initial(self.rho, x0[n:])

    def minimize(self, extra=0) -> None:
        """Set the Opti objective to ``J / N + extra`` (the user's own terms, in the same scale);
        the same as ``opti.minimize(est.objective + extra)``.

        Parameters
        ----------
        extra : casadi.MX or float
            Further cost terms.

        Returns
        -------
        None
        """
        self.opti.minimize(self.objective + extra)

    def values(self, sol) -> tuple[np.ndarray, np.ndarray]:
        """``(theta, R)`` at an Opti solution (R: the diagonal, or the full matrix for a full R).

        Parameters
        ----------
        sol : casadi.OptiSol

        Returns
        -------
        theta : ndarray, shape (n_parameters,)
        R : ndarray
        """
        theta = np.asarray(sol.value(self.theta), dtype=float).reshape(-1)
        R = np.asarray(sol.value(self.R), dtype=float)
        return theta, R if R.ndim == 2 and R.shape[1] > 1 else R.reshape(-1)

    def standard_deviations(self, sol, data: Dataset | None = None, method: CovarianceMethod = "hessian",
                            dof_correction: bool = False) -> Uncertainty:
        """Covariance from the exact Hessian of J at the solution (see :mod:`casest.estimation.uncertainty`).

        User constraints are not taken into account: this is the covariance of the
        unconstrained ML problem at the returned point (with parameters on their box
        bounds held fixed).

        Parameters
        ----------
        sol : casadi.OptiSol
        data : Dataset, optional
        method : {"hessian", "gauss-newton"}
        dof_correction : bool
            Multiply the covariance by N m / (N m - p), as :func:`casest.estimate` does.

        Returns
        -------
        Uncertainty
        """
        theta, R = self.values(sol)
        m = self.problem.model
        problem = self.problem.problem
        problem = as_problem(problem, data) if problem is not None else as_problem(m, data)
        active = active_bounds(theta, m.lower_bounds, m.upper_bounds, m.scales)
        at_floor = variances_of(R) <= noise_floor(problem.data, self.settings or SolverSettings()) * (1 + 1e-6)
        return parameter_uncertainty(problem, None, theta, R, active, at_floor, method,
                                     dof_correction=dof_correction)


def add_to_opti(opti: ca.Opti, model: Model | Problem, data: Dataset | None = None,
                settings: SolverSettings | None = None, start: OptiStart = "nominal", sweep_settings=None) -> OptiEstimation:
    """Put the ML estimation problem for ``data`` into ``opti``.

    Creates the Opti variables (scaled parameters and the noise block), a data parameter
    set to the data, the parameters' box constraints and the noise floor, and an initial
    guess. It sets no objective: add the estimation's cost term to yours,
    ``opti.minimize(est.objective + my_terms)`` (or ``est.minimize(my_terms)``). The user
    picks the solver (``opti.solver("ipopt", ...)``) and may add constraints and variables.

    Parameters
    ----------
    opti : casadi.Opti
    model : Model or Problem
        A :class:`casest.Problem` brings its data (leave ``data`` out), experiments, noise
        model, prior penalties, fixed parameters and missing outputs.
    data : Dataset
        With a Model.
    settings : SolverSettings, optional
        Its noise floor bounds R here and in :meth:`OptiEstimation.standard_deviations`.
    start : {"nominal", "stage1"}
        The initial guess: the parameters' nominal values (R the residual mean square
        there), or the best candidate of a stage-1 sweep (:func:`casest.sweep`, with
        ``sweep_settings``; its xi1, xi2 and R), so that a local solver starts in the
        basin of the global minimum.

    Returns
    -------
    OptiEstimation

    Examples
    --------
    The estimation inside your own Opti, with a constraint between two parameters:

    >>> import casadi as ca, casest
    >>> from casest.interop import add_to_opti
    >>> m, opti = casest.load_model_file("scalar2"), ca.Opti()
    >>> est = add_to_opti(opti, m.model(), m.simulate(seed=0), start="stage1")
    >>> opti.subject_to(est.parameter("d") == est.parameter("a"))
    >>> opti.minimize(est.objective)
    >>> opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "sb": "yes"})  # sb: no banner
    >>> theta, R = est.values(opti.solve())
    """
    if not isinstance(opti, ca.Opti):
        raise OptionError(f"add_to_opti needs a casadi.Opti, got {type(opti).__name__}")
    problem = model if isinstance(model, Problem) else Problem(model, data)
    if isinstance(model, Problem) and data is not None:
        raise OptionError("add_to_opti(opti, problem) takes the data from the problem; leave data out")
    model = problem.model
    ml = ml_problem(problem)
    s = opti.variable(model.n_parameters)
    p = opti.parameter(ml.p.numel())
    n_noise = ml.x.numel() - model.n_parameters
    rho = opti.variable(n_noise) if n_noise else None
    x = ca.vertcat(s, rho) if n_noise else s
    J, R = ca.substitute([ml.f, ml.R], [ml.x, ml.p], [x, p])
    theta = s * ca.DM(ml.scale)
    floor = _constrain(opti, problem, ml.scale, s, rho)
    if start not in ("nominal", "stage1"):
        raise OptionError(f"start must be 'nominal' or 'stage1', got {start!r}")
    settings = settings or SolverSettings()
    est = OptiEstimation(opti, theta, s, R, rho, p, floor, J, ml, settings)
    est.set_data(None, settings)
    theta0 = _initial_parameters(problem, start, sweep_settings)
    _, R0 = problem.start_point(theta0, noise_floor(problem.data, settings))
    est.set_initial(theta0, R0)
    return est


def _constrain(opti: ca.Opti, problem: Problem, scale: np.ndarray, s, rho):
    """The parameters' boxes on the scaled variables ``s`` and the noise floor on ``rho``; returns the
    floor's Opti parameter (None when R is held)."""
    for i, prm in enumerate(problem.model.parameters):
        if np.isfinite(prm.lb):
            opti.subject_to(s[i] >= prm.lb / scale[i])
        if np.isfinite(prm.ub):
            opti.subject_to(s[i] <= prm.ub / scale[i])
    if rho is None:
        return None
    floor = opti.parameter(problem.model.n_outputs)  # ln R_j >= ln floor_j (a full R: ln L_jj >= ln(floor_j) / 2)
    opti.subject_to(problem.noise.floor_constraint(rho, floor) >= 0)
    return floor


def _initial_parameters(problem: Problem, start: str, sweep_settings) -> np.ndarray:
    """The nominal values, or stage 1's best candidate (inside the bounds)."""
    model = problem.model
    if start == "nominal":
        return model.nominal
    partition = separate(model)
    land = sweep(problem, partition=partition, settings=sweep_settings)
    return np.clip(partition.assemble(land.best_xi1, land.best_xi2), model.lower_bounds, model.upper_bounds)
