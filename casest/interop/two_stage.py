"""The two-stage estimator as a ``casadi.Function``: data in; theta, R, covariance and a
success flag out, with derivatives with respect to the data from the implicit function
theorem at the optimum."""

from __future__ import annotations

import threading
from collections import OrderedDict

import casadi as ca
import numpy as np

from ..backend.ipopt import SolverSettings, active_bounds
from ..data import Dataset
from ..two_stage import SweepSettings, estimate
from ..models import Model, OptionError
from ..problem import Problem, ml_cost_expression


__all__ = ["two_stage_function"]


# callbacks live as long as the process: CasADi holds raw pointers to them
_ESTIMATORS: list = []
#: distinct data inputs whose estimates a two-stage Function remembers (an Opti evaluates it at
#: the same parameters in every iteration, and again for its derivatives)
REMEMBERED_INPUTS = 16


class _TwoStageEstimator(ca.Callback):
    """``(data inputs) -> (theta, R, cov, success)`` by :func:`casest.estimate`, with
    derivatives from the implicit function theorem (see :func:`two_stage_function`).

    ``inputs``: the data arguments' names and MX symbols; ``cost``: J (paper Eq. 6, with a
    MAP penalty) as an expression of ``(theta, rho, *inputs)``; ``problem_of``: the Problem
    of numeric data arguments, which :func:`casest.estimate` solves.
    """

    def __init__(self, name: str, model, inputs: list, cost, problem_of, sweep_settings, solver_settings,
                 options: dict):
        ca.Callback.__init__(self)
        self.model, self.inputs, self.problem_of = model, inputs, problem_of
        self.sweep_settings, self.solver_settings, self.options = sweep_settings, solver_settings, options
        n, ny = model.n_parameters, model.n_outputs
        self.theta = ca.MX.sym("theta", n)
        self.rho = ca.MX.sym("rho", ny)
        w = ca.vertcat(self.theta, self.rho)
        J = cost(self.theta, self.rho, *[sym for _, sym in inputs])
        self.g = ca.gradient(J, w)
        self.H = ca.jacobian(self.g, w)
        self.newton = ca.Function("two_stage_newton", [w] + [sym for _, sym in inputs], [self.g, self.H])
        self._lock = threading.Lock()
        self._remembered: OrderedDict = OrderedDict()  # the inputs' bytes -> the outputs
        self.construct(name, {})
        _ESTIMATORS.append(self)

    def get_n_in(self):
        return len(self.inputs)

    def get_n_out(self):
        return 4

    def get_name_in(self, i):
        return self.inputs[i][0]

    def get_name_out(self, i):
        return ("theta", "R", "cov", "success")[i]

    def get_sparsity_in(self, i):
        return self.inputs[i][1].sparsity()

    def get_sparsity_out(self, i):
        n, ny = self.model.n_parameters, self.model.n_outputs
        return [ca.Sparsity.dense(n, 1), ca.Sparsity.dense(ny, 1), ca.Sparsity.dense(n, n), ca.Sparsity.dense(1, 1)][i]

    def free_mask(self, theta: np.ndarray) -> np.ndarray:
        """1 for a parameter inside its bounds (and for every ln R_j), 0 for one on a bound."""
        active = active_bounds(theta, self.model.lower_bounds, self.model.upper_bounds, self.model.scales)
        return np.concatenate([[0.0 if a else 1.0 for a in active], np.ones(self.model.n_outputs)])

    def eval(self, args):
        # one evaluation at a time: a thread map calls this from several threads, and the CasADi
        # Functions it calls (estimate's cached solvers, the Newton function) keep one work buffer
        with self._lock:
            key = tuple(np.asarray(a, dtype=float).tobytes() for a in args)
            if key not in self._remembered:
                self._remembered[key] = self._evaluate(args)
                if len(self._remembered) > REMEMBERED_INPUTS:
                    self._remembered.popitem(last=False)
            self._remembered.move_to_end(key)
            return [ca.DM(v) for v in self._remembered[key]]

    def _evaluate(self, args):
        values = [np.asarray(a, dtype=float) for a in args]
        est = estimate(self.problem_of(*values), sweep_settings=self.sweep_settings,
                       solver_settings=self.solver_settings, **self.options)
        n = self.model.n_parameters
        w = np.concatenate([est.theta, np.log(est.R)])
        free = self.free_mask(est.theta).astype(bool)
        # polish with exact Newton steps on the free variables: the derivatives below hold
        # at the exact stationary point, and differences of nearby solves become smooth
        for _ in range(3):
            g, H = (np.asarray(v, dtype=float) for v in self.newton(w, *values))
            try:
                step = np.linalg.solve(H[np.ix_(free, free)], -g.reshape(-1)[free])
            except np.linalg.LinAlgError:
                break
            trial = w.copy()
            trial[free] += step
            theta = trial[:n]
            if np.any(theta < self.model.lower_bounds) or np.any(theta > self.model.upper_bounds):
                break
            w = trial
            if np.linalg.norm(step, np.inf) < 1e-15 * max(1.0, np.linalg.norm(w, np.inf)):
                break
        cov = self._covariance(w, values, free)
        return [ca.DM(w[:n]), ca.DM(np.exp(w[n:])), ca.DM(cov), ca.DM(float(bool(est.success)))]

    def _covariance(self, w, values, free) -> np.ndarray:
        n = self.model.n_parameters
        _, H = self.newton(w, *values)
        H = np.asarray(H, dtype=float)
        cov = np.zeros_like(H)
        try:
            cov[np.ix_(free, free)] = np.linalg.inv(H[np.ix_(free, free)])
        except np.linalg.LinAlgError:
            cov[:] = np.nan
        return cov[:n, :n]

    def has_jacobian(self):
        return True

    def get_jacobian(self, name, inames, onames, opts):
        n, ny = self.model.n_parameters, self.model.n_outputs
        theta_o, R_o = ca.MX.sym("theta_o", n), ca.MX.sym("R_o", ny)
        cov_o, success_o = ca.MX.sym("cov_o", n, n), ca.MX.sym("success_o")
        w_o = ca.vertcat(theta_o, ca.log(R_o))
        # parameters on a bound stay there under small changes of the data (zero derivative)
        inside = []
        for i, (lo, hi, sc) in enumerate(zip(self.model.lower_bounds, self.model.upper_bounds, self.model.scales)):
            flag = ca.MX(1)  # the same test as active_bounds, on the bounds that are finite
            if np.isfinite(lo):
                flag = flag * (theta_o[i] - lo > 1e-7 * max(sc, abs(lo)))
            if np.isfinite(hi):
                flag = flag * (hi - theta_o[i] > 1e-7 * max(sc, abs(hi)))
            inside.append(flag)
        mask = ca.vertcat(*inside, ca.DM.ones(ny))
        w = ca.vertcat(self.theta, self.rho)
        D = ca.diag(mask)
        H_masked = ca.mtimes(ca.mtimes(D, self.H), D) + ca.diag(1 - mask)
        cov_w = ca.mtimes(ca.mtimes(D, ca.inv(H_masked)), D)[:n, :n]
        blocks = {}
        for label, data in self.inputs:
            dw_sym = -ca.solve(H_masked, ca.mtimes(D, ca.jacobian(self.g, data)))
            dw = ca.substitute(dw_sym, w, w_o)
            dcov = ca.jacobian(ca.vec(cov_w), data) + ca.mtimes(ca.jacobian(ca.vec(cov_w), w), dw_sym)
            blocks[("cov", label)] = ca.substitute(dcov, w, w_o)
            blocks[("theta", label)] = dw[:n, :]
            blocks[("R", label)] = ca.mtimes(ca.diag(R_o), dw[n:, :])
            blocks[("success", label)] = ca.MX.zeros(1, data.numel())
        outputs = [blocks[(o, label)] for o in ("theta", "R", "cov", "success") for label, _ in self.inputs]
        arguments = [sym for _, sym in self.inputs] + [theta_o, R_o, cov_o, success_o]
        return ca.Function(name, arguments, outputs, inames, onames)


def two_stage_function(model: Model | Problem, n_samples: int | None = None,
                       sweep_settings: SweepSettings | None = None, solver_settings: SolverSettings | None = None,
                       name: str = "two_stage", **options) -> ca.Function:
    """The two-stage estimator as a ``casadi.Function`` that can sit inside CasADi graphs.

    From a static Model: ``two_stage(signals[n_signals x N], outputs[n_outputs x N]) ->
    (theta[n], R[n_y], cov[n x n], success)``. From a :class:`casest.Problem` (a static or
    dynamic model, its experiments, fixed parameters, priors, missing outputs; R unknown and
    diagonal): ``two_stage(data[n_p]) -> (...)`` with ``data`` in the layout of
    :meth:`casest.Problem.data_vector`. Its evaluation runs :func:`casest.estimate` (stage 1,
    then stage 2 from the best candidates) and polishes the optimum with exact Newton steps;
    the Function remembers the outputs of its last 16 distinct inputs, so an ``Opti`` whose
    data are parameters estimates once, not in every iteration. Its derivatives with respect to the data come from the implicit function theorem at the
    optimum: with ``w = [theta; ln R]`` and ``g(w, data) = dJ/dw = 0`` there, ``dw/d data =
    -H^-1 dg/d data`` (H the exact Hessian of J; parameters on a bound held there). ``cov`` is
    the theta block of ``H^-1`` (zero rows and columns on a bound); its derivative follows the
    same chain. ``success`` is 1.0 when casest stands behind the estimate (derivative zero).

    Parameters
    ----------
    model : Model or Problem
    n_samples : int
        N (a Model only; a Problem brings its own).
    sweep_settings, solver_settings
        As in :func:`casest.estimate`.
    **options
        Passed on to :func:`casest.estimate` (e.g. ``mode``, ``max_starts``).

    Returns
    -------
    casadi.Function
        Callable numerically and on MX symbols (first derivatives exact at the optimum;
        second derivatives are not offered).
    """
    if isinstance(model, Problem):
        inputs, cost, problem_of = _problem_layout(model)
        model = model.model
    elif isinstance(model, Model) and n_samples is not None:
        inputs, cost, problem_of = _static_layout(model, int(n_samples))
    else:
        raise OptionError("two_stage_function takes a static casest.Model and N, or a casest.Problem (any model)")
    callback = _TwoStageEstimator(name + "_callback", model, inputs, cost, problem_of, sweep_settings,
                                  solver_settings, options)
    symbols = [ca.MX.sym(label, sym.sparsity()) for label, sym in inputs]
    return ca.Function(name, symbols, list(callback(*symbols)), [label for label, _ in inputs],
                       ["theta", "R", "cov", "success"])


def _static_layout(model: Model, N: int) -> tuple:
    """The (signals, outputs) arguments of a static model's two-stage Function."""
    X = ca.MX.sym("signals", model.n_signals, N)
    Z = ca.MX.sym("outputs", model.n_outputs, N)

    def cost(theta, rho, X_, Z_):
        return ml_cost_expression(model, N, theta, rho, ca.vertcat(ca.vec(X_), ca.vec(Z_)))

    def problem_of(X_, Z_):
        return Problem(model, Dataset.from_arrays(model, X_.T, Z_.T))

    return [("signals", X), ("outputs", Z)], cost, problem_of


def _problem_layout(problem: Problem) -> tuple:
    """The data-vector argument of a Problem's two-stage Function (unknown diagonal R only)."""
    if not problem.noise.profiled_per_channel:
        raise OptionError("two_stage_function differentiates through theta and ln R of an unknown diagonal R; "
                          f"a problem with {problem.describe_noise()} is not offered: use estimator_function")
    N, masked = problem.n_samples, problem.masked
    p = ca.MX.sym("data", problem.data_vector().size)

    def problem_of(values):
        data = problem.measurement.dataset_from_vector(values, N, masked)
        return Problem(problem.model, data, noise=problem.noise, prior_penalty=problem.prior_penalty)

    return [("data", p)], problem.cost_expression, problem_of
