"""The filter-error likelihood as an NLP: the time-varying EKF's graph, the checked inputs of an
estimate, and the decision vector with its bounds.

The symbolic part (V and the innovations in the decision vector, their derivatives, the exact
Hessian, IPOPT's solver) depends on the model's structure, the number of samples, the
formulation and which intensities and variances are estimated, not on the record: the record
(and, for the steady-state form, the operating point) is the NLP's parameter vector. It is built
once per such key (a :class:`casest._casadi.memory.StructureCache`), so a second estimate with
the same model and record length skips the build.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import casadi as ca
import numpy as np

from ..checks import noise_variances
from .._casadi.memory import StructureCache
from ..backend.ipopt import SolverSettings
from ..data.dataset import Dataset
from ..errors import ModelError, OptionError
from ..models.dynamic import DynamicModel
from ..filters.ekf_model import ekf_step_functions
from ..filters.model_filter import process_noise_matrix
from .hessian import FilterPassHessian, filter_hessian_loops
from .sensitivities import FilterPassDerivatives, filter_pass_derivatives
from .gain_sensitivities import gain_pass_derivatives
from .scoring import InnovationDerivatives, InnovationGraph, fisher_information
from .steady import steady_cost_graph

__all__ = ["FormulationOptions", "filter_error_step", "time_varying_columns", "time_varying_graph", "intensity_vector", "FilterErrorSetup",
           "filter_error_setup", "FilterErrorNLP"]

_STEPS = StructureCache()
_SYMBOLIC = StructureCache()


def _cholesky(S):
    """Lower Cholesky factor of a small symmetric SX matrix, written out (n <= ~10)."""
    n = S.size1()
    L = [[ca.SX(0)] * n for _ in range(n)]
    for j in range(n):
        d = S[j, j] - sum((L[j][k] ** 2 for k in range(j)), ca.SX(0))
        L[j][j] = ca.sqrt(d)
        for i in range(j + 1, n):
            L[i][j] = (S[i, j] - sum((L[i][k] * L[j][k] for k in range(j)), ca.SX(0))) / L[j][j]
    return L


def _solve_lower(L, B):
    """L^-1 B for the written-out factor L and an SX matrix B."""
    n = len(L)
    rows = []
    for i in range(n):
        r = B[i, :]
        for k in range(i):
            r = r - L[i][k] * rows[k]
        rows.append(r / L[i][i])
    return ca.vertcat(*rows)


def _solve_upper(L, B):
    """L'^-1 B."""
    n = len(L)
    rows = [None] * n
    for i in range(n - 1, -1, -1):
        r = B[i, :]
        for k in range(i + 1, n):
            r = r - L[k][i] * rows[k]
        rows[i] = r / L[i][i]
    return ca.vertcat(*rows)


def filter_error_step(model: DynamicModel) -> tuple[ca.Function, ca.Function]:
    """One EKF sample as SX: (x-, P-, d_k, theta, q, r) -> (x- next, P- next, V_k), and the
    last sample's update alone: (x-, P-, u, y, mask, theta, r) -> V_k.

    ``d_k`` = [u_a; u_b; dt; u_k; y_k (0 where missing); mask_k].
    """
    cache = _STEPS.setdefault(model, {})
    if "filter_error_step" in cache:
        return cache["filter_error_step"], cache["filter_error_last"]
    step = model.step_function
    if not step.is_a("SXFunction"):
        raise OptionError("filter-error ML needs the RK4 discretisation (integrator='rk4'): its derivatives are "
                          "taken through the filter recursion")
    n, nu, ny = model.n_states, len(model.inputs), model.n_outputs
    nuk = step.size1_in(1)
    x, P = ca.SX.sym("x", n), ca.SX.sym("P", n, n)
    theta = ca.SX.sym("theta", model.n_parameters)
    q, r = ca.SX.sym("q", n), ca.SX.sym("r", ny)
    u, y, m = ca.SX.sym("u", nu), ca.SX.sym("y", ny), ca.SX.sym("mask", ny)
    propagate, measure = ekf_step_functions(model)  # the EKF's own step, Jacobians and discretisation
    h, H = measure(x, u, theta)
    M = ca.diag(m)
    e = m * (y - h)
    S = M @ (H @ P @ H.T + ca.diag(r)) @ M + ca.diag(1 - m)
    L = _cholesky(S)
    w = _solve_lower(L, e)
    cost = 0.5 * (ca.sumsqr(w) + 2 * sum((ca.log(L[i][i]) for i in range(ny)), ca.SX(0)))
    Kt = _solve_upper(L, _solve_lower(L, M @ H @ P))  # (M S M + I - M)^-1 M H P = K'
    K = Kt.T
    I_KH = ca.SX.eye(n) - K @ M @ H
    x_post = x + K @ e
    P_post = I_KH @ P @ I_KH.T + K @ M @ ca.diag(r) @ M @ K.T
    last = ca.Function("filter_error_last", [x, P, u, y, m, theta, r], [cost, e, ca.vec(S)])
    ua, ub, dt = ca.SX.sym("u_a", nuk), ca.SX.sym("u_b", nuk), ca.SX.sym("dt")
    x_next, P_next, _ = propagate(x_post, P_post, ua, ub, dt, theta, ca.diag(q), u, ca.SX.zeros(nu))
    P_next = 0.5 * (P_next + P_next.T)
    d = ca.vertcat(ua, ub, dt, u, y, m)
    one = ca.Function("filter_error_step", [x, P, d, theta, q, r], [x_next, P_next, cost, e, ca.vec(S)])
    cache["filter_error_step"], cache["filter_error_last"] = one, last
    return one, last


def time_varying_columns(model: DynamicModel, data: Dataset) -> tuple[np.ndarray, np.ndarray]:
    """Per-step data D (n_d x N-1) and the last sample's [u; y; mask]."""
    t, U = data.signals[:, 0], data.signals[:, 1:]
    mask = np.isfinite(data.outputs).astype(float)
    Y = np.where(mask > 0, data.outputs, 0.0)
    Ua, Ub = model.interval_input_values(U)
    N = data.n_samples
    if N > 1:
        D = np.hstack([Ua, Ub, np.diff(t)[:, None], U[:-1], Y[:-1], mask[:-1]]).T
    else:
        D = np.zeros((2 * model.step_function.size1_in(1) + 1 + U.shape[1] + 2 * Y.shape[1], 1))
    return D, np.concatenate([U[-1], Y[-1], mask[-1]])


def time_varying_graph(model: DynamicModel, N: int, P0: np.ndarray) -> InnovationGraph:
    """Symbols (theta, q, r, D, last, d0), V over N samples and the innovations with their covariances."""
    one, last_fn = filter_error_step(model)
    n, nu, ny = model.n_states, len(model.inputs), model.n_outputs
    theta, q, r = ca.MX.sym("theta", model.n_parameters), ca.MX.sym("q", n), ca.MX.sym("r", ny)
    nd = one.size1_in(2)
    D, last = ca.MX.sym("D", nd, max(N - 1, 1)), ca.MX.sym("last", nu + 2 * ny)
    d0 = ca.MX.sym("x0_data", len(model.initial_from_data))
    x0 = model.initial_function(theta, d0)
    acc = ca.MX.sym("acc", n + n * n + 1)
    dk = ca.MX.sym("d", nd)
    th_s, q_s, r_s = ca.MX.sym("th", model.n_parameters), ca.MX.sym("qs", n), ca.MX.sym("rs", ny)
    xn, Pn, Vk, ek, Sk = one(acc[:n], ca.reshape(acc[n:n + n * n], n, n), dk, th_s, q_s, r_s)
    advance = ca.Function("filter_error_advance", [acc, dk, th_s, q_s, r_s],
                          [ca.vertcat(xn, ca.vec(Pn), acc[-1] + Vk), ek, Sk])
    start = ca.vertcat(x0, ca.vec(ca.DM(P0)), 0)
    if N > 1:
        # fold over the samples: the parameters ride along as non-accumulated inputs
        run = advance.mapaccum("filter_error_run", N - 1)
        path, E, S = run(start, D, ca.repmat(theta, 1, N - 1), ca.repmat(q, 1, N - 1), ca.repmat(r, 1, N - 1))
        final = path[:, -1]
    else:
        final, E, S = start, ca.MX(ny, 0), ca.MX(ny * ny, 0)
    xN, PN = final[:n], ca.reshape(final[n:n + n * n], n, n)
    V_last, e_last, S_last = last_fn(xN, PN, last[:nu], last[nu:nu + ny], last[nu + ny:], theta, r)
    return InnovationGraph((theta, q, r, D, last, d0), final[-1] + V_last, ca.horzcat(E, e_last),
                           ca.horzcat(S, S_last), filter_pass=(theta, q, r, x0, np.asarray(P0, dtype=float)))



def intensity_vector(model: DynamicModel, process_noise) -> np.ndarray:
    """Per-state intensities, shape (n_states,), from a mapping or a vector (diagonal noise only)."""
    Q = process_noise_matrix(model, process_noise)
    if np.any(Q != np.diag(np.diag(Q))):
        raise OptionError("filter-error ML estimates independent intensities per state: give a mapping or a vector")
    return np.diag(Q).copy()


@dataclass(frozen=True)
class FilterErrorSetup:
    """The checked inputs of a filter-error estimate."""

    theta0: np.ndarray
    q_start: np.ndarray
    noisy: np.ndarray  # states whose intensity is estimated
    r_start: np.ndarray
    estimate_R: bool
    P0: np.ndarray
    output_variance: np.ndarray


def filter_error_setup(model: DynamicModel, data: Dataset, process_noise, estimate_process_noise: bool, R, start,
                       P0) -> FilterErrorSetup:
    """Check the options against the model and data; the starts of theta, q and R."""
    if not isinstance(model, DynamicModel):
        raise OptionError("filter_error_estimate needs a casest.DynamicModel")
    model.check_data(data)
    n, ny = model.n_states, model.n_outputs
    q_start = intensity_vector(model, process_noise)
    if np.any(q_start < 0) or not np.all(np.isfinite(q_start)):
        raise OptionError(f"process-noise intensities must be finite and >= 0, got {q_start.tolist()}")
    noisy = np.flatnonzero(q_start > 0) if estimate_process_noise else np.array([], dtype=int)
    if estimate_process_noise and len(noisy) == 0:
        raise OptionError("give a positive starting intensity for each state whose process noise is estimated")
    P0 = np.zeros((n, n)) if P0 is None else np.asarray(P0, dtype=float).reshape(n, n)
    lb, ub = model.lower_bounds, model.upper_bounds
    theta0 = model.nominal.copy() if start is None else (
        model.vector(start) if isinstance(start, Mapping) else np.asarray(start, dtype=float).reshape(-1))
    if np.any(theta0 < lb) or np.any(theta0 > ub):
        bad = [p for p, v, lo, hi in zip(model.parameter_names, theta0, lb, ub) if not lo <= v <= hi]
        raise ModelError(f"the start of {bad} lies outside the parameter bounds")
    observed = np.isfinite(data.outputs)
    if np.any(observed.sum(axis=0) < 2):
        raise ModelError("every output needs at least two measured samples")
    z_var = np.array([np.var(data.outputs[observed[:, j], j]) for j in range(ny)])
    if R is None:
        diffs = np.array([np.var(np.diff(data.outputs[observed[:, j], j])) / 2 for j in range(ny)])
        r_start = np.maximum(diffs, 1e-12 * np.maximum(z_var, 1e-300))
    else:
        r_start = noise_variances(R, model.output_names)
    return FilterErrorSetup(theta0, q_start, noisy, r_start, R is None, P0, z_var)


class _SymbolicNLP:
    """V, the innovations and the decision vector of one key (:func:`_symbolic_nlp`), with the
    functions built from them on first use."""

    def __init__(self, model: DynamicModel, setup: FilterErrorSetup, graph: InnovationGraph):
        (theta, q, r, D, last, d0), V = graph.symbols, graph.V
        noisy, n = setup.noisy, model.n_states
        w_theta = ca.MX.sym("w_theta", model.n_parameters)
        w_q = ca.MX.sym("w_q", len(noisy))
        w_r = ca.MX.sym("w_r", model.n_outputs if setup.estimate_R else 0)
        q_expr = ca.vertcat(*[ca.exp(w_q[list(noisy).index(i)]) if i in noisy else ca.MX(setup.q_start[i])
                              for i in range(n)])
        r_expr = ca.exp(w_r) if setup.estimate_R else ca.MX(setup.r_start)
        self.natural = (w_theta * model.scales, q_expr, r_expr)
        self.V, self.E, self.S = ca.substitute([V, graph.E, graph.S], [theta, q, r], list(self.natural))
        self.X = ca.substitute([graph.X], [theta, q, r], list(self.natural))[0] if graph.X is not None else None
        self.gain_pass = ca.substitute(list(graph.gain_pass), [theta, q, r], list(self.natural)) if graph.gain_pass else []
        self.filter_pass = (tuple(ca.substitute(list(graph.filter_pass[:4]), [theta, q, r], list(self.natural)))
                            + graph.filter_pass[4:]) if graph.filter_pass else ()
        self.model = model
        self.w = ca.vertcat(w_theta, w_q, w_r)
        self.p = ca.vertcat(ca.vec(D), last, d0, *graph.point)
        self._derivatives, self._hessian, self._states, self._solvers = None, None, None, {}
        self._pass_hessian = None

    def derivatives(self) -> InnovationDerivatives:
        if self._derivatives is None:
            # vec(D) leads p
            if self.filter_pass:
                self._derivatives = filter_pass_derivatives(self.model, self.w, self.p, self.E, self.S,
                                                            self.filter_pass, filter_error_step(self.model), 0)
            else:
                self._derivatives = gain_pass_derivatives(self.model, self.w, self.p, self.E, self.S, self.gain_pass, 0)
        return self._derivatives

    def exact_hessian(self, w: np.ndarray, p_num: np.ndarray) -> np.ndarray:
        """The Hessian of V at ``w``: by the adjoint of the compiled filter pass where the derivatives
        come from it (:mod:`casest.filter_error.hessian`), else CasADi's Hessian of the graph."""
        derivatives = self.derivatives()
        if self._pass_hessian is None:
            loops = (filter_hessian_loops(self.model, filter_error_step(self.model), self.w.numel())
                     if isinstance(derivatives, FilterPassDerivatives) else None)
            self._pass_hessian = FilterPassHessian(derivatives, self.w, self.p, self.filter_pass, loops) if loops else False
        if self._pass_hessian:
            return self._pass_hessian(w, p_num)
        return np.asarray(self.hessian()(w, p_num))

    def hessian(self) -> ca.Function:
        if self._hessian is None:
            self._hessian = ca.Function("filter_error_hessian", [self.w, self.p], [ca.hessian(self.V, self.w)[0]])
        return self._hessian

    def states(self) -> ca.Function:
        if self._states is None:
            self._states = ca.Function("filter_error_states", [self.w, self.p], [self.X])
        return self._states

    def solver(self, settings: SolverSettings, N: int) -> ca.Function:
        options = settings.nlpsol_options()
        key = repr(sorted(options.items(), key=lambda item: item[0]))
        if key not in self._solvers:
            self._solvers[key] = ca.nlpsol("filter_error", "ipopt", {"x": self.w, "f": self.V / N, "p": self.p}, options)
        return self._solvers[key]


def _symbolic_nlp(model: DynamicModel, setup: FilterErrorSetup, N: int, formulation: str) -> _SymbolicNLP:
    """The symbolic NLP of this model structure, record length, formulation and noise setup."""
    fixed_q = np.where(np.isin(np.arange(model.n_states), setup.noisy), 0.0, setup.q_start)
    key = (formulation, int(N), setup.P0.tobytes() if formulation == "time-varying" else b"", tuple(setup.noisy),
           bool(setup.estimate_R), fixed_q.tobytes(), b"" if setup.estimate_R else setup.r_start.tobytes())
    cache = _SYMBOLIC.setdefault(model, {})
    if key not in cache:
        graph = (time_varying_graph(model, N, setup.P0) if formulation == "time-varying"
                 else steady_cost_graph(model, N))
        cache[key] = _SymbolicNLP(model, setup, graph)
    return cache[key]


class FilterErrorNLP:
    """The decision vector ``w = [theta / scale; ln q (estimated); ln R (estimated)]``, V in it,
    and its bounds and start, for one estimate.

    Parameters
    ----------
    model : DynamicModel
    setup : FilterErrorSetup
    n_samples : int
    formulation : {"time-varying", "steady-state"}
        Whose likelihood: the EKF's over the record, or the steady gain's at an operating
        point (then the point ``[x_ref; u_ref; dt]`` ends the parameter vector).
    """

    def __init__(self, model: DynamicModel, setup: FilterErrorSetup, n_samples: int,
                 formulation: str = "time-varying"):
        self.model, self.setup = model, setup
        self.symbolic = _symbolic_nlp(model, setup, n_samples, formulation)
        self.w, self.p, self.V = self.symbolic.w, self.symbolic.p, self.symbolic.V
        self.solver, self.fisher, self.fisher_at = None, None, None
        noisy = setup.noisy
        log_q = np.log(setup.q_start[noisy])
        floor = np.log(np.maximum(1e-20 * np.maximum(setup.output_variance, 1e-300), 1e-300))
        ceiling = np.log(np.maximum(setup.output_variance, 1e-300)) + 10
        r_bounds = (floor, ceiling) if setup.estimate_R else ([], [])
        self.lower = np.concatenate([model.lower_bounds / model.scales, log_q - 30, r_bounds[0]])
        self.upper = np.concatenate([model.upper_bounds / model.scales, log_q + 30, r_bounds[1]])
        self.start = np.concatenate([setup.theta0 / model.scales, log_q,
                                     np.log(setup.r_start) if setup.estimate_R else []])
        self.names = list(model.parameter_names) + [f"q[{model.state_names[i]}]" for i in noisy] + (
            [f"R[{o}]" for o in model.output_names] if setup.estimate_R else [])

    def derivatives(self) -> InnovationDerivatives:
        """The innovations, their covariances and first derivatives in ``w`` (built once per key)."""
        return self.symbolic.derivatives()

    def ipopt(self, settings: SolverSettings, N: int) -> ca.Function:
        """IPOPT on V / N (built once per key and options); kept for the Hessian at the optimum."""
        self.solver = self.symbolic.solver(settings, N)
        return self.solver

    def information(self, w: np.ndarray, p_num: np.ndarray) -> np.ndarray:
        """The Fisher information of ``w`` at ``w`` (from the scoring solve, or evaluated)."""
        if self.fisher is not None and np.array_equal(self.fisher_at, w):
            return self.fisher
        return fisher_information(self.derivatives(), w, p_num)

    def hessian_of_v(self, w: np.ndarray, p_num: np.ndarray, N: int) -> np.ndarray:
        """The exact Hessian of V at ``w``: the solver's own Hessian of the Lagrangian (lam_f = 1), which
        IPOPT already built, times N (IPOPT minimises V / N); after scoring, :meth:`_SymbolicNLP.exact_hessian`."""
        if self.solver is None:
            return self.symbolic.exact_hessian(w, p_num)
        hess_l = self.solver.get_function("nlp_hess_l")
        H = np.asarray(ca.densify(hess_l(w, p_num, 1.0, np.zeros(0))), dtype=float) * N
        return np.triu(H) + np.triu(H, 1).T

    def predicted_states(self, w: np.ndarray, p_num: np.ndarray) -> np.ndarray:
        """The predicted states at ``w`` (the steady-state form), shape (N, n_states)."""
        return np.asarray(self.symbolic.states()(w, p_num)).T

    def natural_symbols(self) -> tuple:
        """(theta, q, r) as expressions of the decision vector ``w``."""
        return self.symbolic.natural

    def natural(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The decision vector in natural units (theta, q, R) and d natural / d w, shapes (n_w,)."""
        npar, scales = self.model.n_parameters, self.model.scales
        values = np.concatenate([w[:npar] * scales, np.exp(w[npar:])])
        return values, np.concatenate([scales, values[npar:]])


@dataclass(frozen=True)
class FormulationOptions:
    """What a formulation takes besides the model, the data, the setup and the solver's settings.

    Attributes
    ----------
    solver : {"ipopt", "scoring"}
    covariance : {"hessian", "fisher", "sandwich"}
    operating_point : {"first", "mean"} or None
        None: the formulation's default.
    innovation_covariance : {"diagonal", "full"}
    max_rounds : int
    t0 : float
        ``time.perf_counter()`` when the estimate started (its ``seconds`` count from there).
    settle_std : float
        The innovation form's relaxation settles at this fraction of the std (0: at rounding).
    """

    solver: str
    covariance: str
    operating_point: str | None
    innovation_covariance: str
    max_rounds: int
    t0: float
    settle_std: float = 0.01
