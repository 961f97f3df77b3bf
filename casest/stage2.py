"""Stage 2: the maximum-likelihood NLP solved by IPOPT with exact CasADi Hessians.

The cost is paper Eq. (6) with R diagonal and unknown::

    J(theta, R) = 1/2 sum_k sum_j (z_kj - h_j(x_k, theta))**2 / R_j + N/2 sum_j ln R_j

R is log-parametrised: the decision variables are ``rho_j = ln R_j``, bounded below by
a noise floor ``R_j >= noise_floor * mean_k(z_kj**2)`` so that exactly fitting data
(ln R -> -inf) stay well posed. Parameters are scaled to order one
(``theta = scale * s``). IPOPT minimises ``J / N``. Sums over samples are CasADi
map-reduce nodes with the data as NLP parameters, so the expression graph does not grow
with N and a solver built once is reused for every data set of the same length.

Modes
-----
``full``
    Decision variables: all of theta and rho.
``reduced``
    Decision variables: xi2 and rho; xi1 is the weighted least-squares solution inside
    the NLP (normal equations, differentiated exactly) and is recovered afterwards by QR.
``alternating``
    The paper's outer loop (Eq. 26): xi2 with R fixed, then R from the residuals, until
    every R_j changes by less than ``alternating_tol`` (5 %).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import casadi as ca
import numpy as np

from .data import Dataset
from .model import Model, OptionError
from .noise import CorrelatedNoise, KnownNoise
from .numerics import StructureCache, evaluate
from .output_error import dynamic_data_views, output_error_sums
from .problem import Problem, as_problem, sum_data_symbols
from .separate import Partition
from .ipopt import ACCEPTABLE_STATUSES, SolverSettings, active_bounds, newton_step_accepts, noise_floor
from .noise import n_cholesky
from .penalty import GaussianPenalty
from .sums import bound_sum, data_outside_graph, map_sum, ml_sums, per_sample_cost, symmetric
from .status import Note, NoteCode, Outcome, note_code

__all__ = [
    "SolverSettings",
    "Stage2Result",
    "solve_stage2",
    "MODES",
    "active_bounds",
    "noise_floor",
    "weighted_linear_parameters",
]

MODES = ("full", "reduced", "alternating")

@dataclass
class Stage2Result:
    """Raw outcome of stage 2 (the public result is :class:`casest.Estimate`).

    Attributes
    ----------
    theta : ndarray, shape (n_parameters,)
    R : ndarray, shape (n_outputs,)
    cost : float
        J(theta, R) of Eq. 6 (constants dropped).
    success : bool
    status : str
        IPOPT's return status (or the loop's, in alternating mode).
    message : str
    n_iterations : int
        IPOPT iterations (summed over solves).
    mode : str
        Mode that produced the result (may differ from the one asked, see notes).
    notes : list of str
    seconds : float
    outcome : Outcome
        How it ended, as a code.
    R_full : ndarray, shape (n_outputs, n_outputs), or None
        The estimated full R (``CorrelatedNoise``); ``R`` is its diagonal.
    """

    theta: np.ndarray
    R: np.ndarray
    cost: float
    success: bool
    status: str
    message: str
    n_iterations: int
    mode: str
    notes: list = field(default_factory=list)
    seconds: float = 0.0
    outcome: Outcome = Outcome.NOT_CONVERGED
    R_full: np.ndarray | None = None


# ----------------------------------------------------------------------------- symbolic parts
def _normal_equations(model: Model, partition: Partition, n_samples: int, threads: int = 1, jit: bool = False,
                      jit_flags=("-O2",), masked: bool = False, outside: bool = False) -> ca.Function:
    """(X, Z, xi2, w) -> (sum A'WA, sum A'W(z-b)) with W = diag(w); A'WA as vec (n1^2); with
    ``outside`` (record, xi2, w), the data (X, Z) in the :class:`casest.sums.Record` bound
    under ``record``.

    ``masked``: Z holds ``[z; m]`` per sample (2 n_y rows) and W = diag(w * m).
    """
    ny = model.n_outputs
    z = ca.SX.sym("z", 2 * ny if masked else ny)
    xi2 = ca.SX.sym("xi2", partition.n_nonlinear)
    w = ca.SX.sym("w", ny)
    A = partition.A(model.x, xi2)
    b = partition.b(model.x, xi2)
    weight = w * z[ny:] if masked else w
    WA = A * ca.repmat(weight, 1, partition.n_linear)
    per_sample = ca.Function(
        "ne", [model.x, z, xi2, w], [ca.vec(ca.mtimes(A.T, WA)), ca.mtimes(WA.T, z[:ny] - b)], ["x", "z", "xi2", "w"],
        ["AtWA", "AtWr"]
    )
    return (bound_sum if outside else map_sum)(per_sample, n_samples, threads, "ne_sum", jit, jit_flags)


class _NLP:
    """One stage-2 NLP (mode, model, partition, N), built once and reused.

    IPOPT gets the cost, its gradient and the upper triangle of its Hessian as sums of
    per-sample exact derivatives (:mod:`casest.sums`) through nlpsol's ``grad_f`` and
    ``hess_lag`` options, so CasADi never differentiates through the N-sample graph.
    In ``reduced`` mode xi1 = xi1*(xi2, R) solves the weighted normal equations, the
    gradient is the full one at that point (dJ/dxi1 = 0 there) and the Hessian is the
    Schur complement ``H_uu - H_u1 H_11^-1 H_1u`` of the full Hessian, which is the exact
    Hessian of the reduced cost.
    """

    def __init__(self, model: Model, partition: Partition, n_samples: int, mode: str, settings: SolverSettings,
                 penalty: tuple | None = None, masked: bool = False, full_noise: bool = False):
        self.model, self.partition, self.n_samples, self.mode = model, partition, n_samples, mode
        n, N = model.n_parameters, n_samples
        # the noise block of w: ln R_j (diagonal R), or the log-Cholesky vector of a full R
        ny = n_cholesky(model.n_outputs) if full_noise else model.n_outputs
        if full_noise and (mode != "full" or masked):
            raise ValueError("a full unknown R needs the full stage-2 mode and complete data")
        # long records: the data stay outside the graph (a Record's handle), so the build does
        # not grow with N; short ones: an N-long parameter, evaluated without leaving C. The
        # parameter's value is Problem.data_argument(), which makes the same choice
        self.outside = data_outside_graph(N)
        p, data = sum_data_symbols(model, N, masked)
        sums = ml_sums(model, N, model.scales, settings.resolved_threads(N), settings.resolved_jit(N), settings.jit_flags,
                       masked, full_noise, bound=self.outside)  # the same sums as Problem.cost_hessian
        if mode == "full":
            self.scale = model.scales
            w = ca.MX.sym("w", n + ny)
            theta = w[:n] * ca.DM(self.scale)
            f = sums.cost(w, *data)
            f_g, g = sums.gradient(w, *data)
            H = sums.hessian(w, *data)
            if penalty is not None:  # Gaussian priors as penalties (MAP), over N like the cost
                term, dterm, d2term = GaussianPenalty.coerce(penalty).scaled_terms(theta, self.scale, N, ny)
                f, f_g, g, H = f + term, f_g + term, g + dterm, H + d2term
        else:
            if penalty is not None:
                raise ValueError("Gaussian priors as penalties need the full stage-2 mode")
            idx1, idx2 = list(partition.linear_index), list(partition.nonlinear_index)
            self.scale = model.scales[idx2]
            w = ca.MX.sym("w", len(idx2) + ny)
            xi2 = w[: len(idx2)] * ca.DM(self.scale)
            rho = w[len(idx2) :]
            if partition.n_linear:
                n1 = partition.n_linear
                M, rhs = _normal_equations(
                    model, partition, N, settings.resolved_threads(N), settings.resolved_jit(N), settings.jit_flags,
                    masked, self.outside,
                )(*data, xi2, ca.exp(-rho))
                xi1 = ca.solve(ca.reshape(M, n1, n1), rhs)
            else:
                xi1 = ca.MX(0, 1)
            theta = partition.assemble_symbolic(xi1, xi2)
            w_full = ca.vertcat(theta / ca.DM(model.scales), rho)
            keep = idx2 + list(range(n, n + ny))
            f = sums.cost(w_full, *data)
            f_g, g_full = sums.gradient(w_full, *data)
            g = g_full[keep]
            H_full = symmetric(sums.hessian(w_full, *data))
            H = H_full[keep, keep]
            if idx1:
                H = H - ca.mtimes(H_full[keep, idx1], ca.solve(H_full[idx1, idx1], H_full[idx1, keep]))
            H = ca.triu(H)
        self.n_s = w.numel() - ny
        lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", 0)
        grad_f = ca.Function("grad_f", [w, p], [f_g, g], ["x", "p"], ["f", "grad"])
        hess_lag = ca.Function("hess_lag", [w, p, lam_f, lam_g], [lam_f * H], ["x", "p", "lam_f", "lam_g"], ["hess"])
        self._nlp = {"x": w, "p": p, "f": f}
        self._options = settings.nlpsol_options()
        # no_nlp_grad: the gradient comes from grad_f; CasADi would otherwise differentiate the graph
        self._options.update({"grad_f": grad_f, "hess_lag": hess_lag, "calc_lam_p": False, "no_nlp_grad": True})
        self._solvers: dict = {}
        self.theta_of = ca.Function("theta_of", [w, p], [theta])
        self.newton = ca.Function("newton", [w, p], [g, symmetric(H)])

    def solver(self, max_iter: int) -> ca.Function:
        """The IPOPT solver with this iteration limit (the derivative Functions are shared)."""
        if max_iter not in self._solvers:
            options = dict(self._options, **{"ipopt.max_iter": int(max_iter)})
            solver = ca.nlpsol(f"casest_{self.mode}", "ipopt", self._nlp, options)
            # the buffer allocates the solver's work memory (about 1 s at N = 1e6): made once
            self._solvers[max_iter] = (solver, solver.buffer())
        return self._solvers[max_iter]

    def solve(self, w0: np.ndarray, lbw: np.ndarray, ubw: np.ndarray, p: np.ndarray, max_iter: int = 1000
              ) -> tuple[np.ndarray, dict]:
        """Run IPOPT through the solver's buffer interface (the data are read in place).

        Returns the solution ``w`` and IPOPT's statistics.
        """
        _, (buffer, run) = self.solver(max_iter)
        self._args = [np.ascontiguousarray(a, dtype=float) for a in (w0, p, lbw, ubw)]
        w, f = np.zeros(len(self._args[0])), np.zeros(1)
        for k, arr in enumerate(self._args):  # x0, p, lbx, ubx
            buffer.set_arg(k, memoryview(arr))
        buffer.set_res(0, memoryview(w))
        buffer.set_res(1, memoryview(f))
        run()
        return w, dict(buffer.stats())


class _OutputErrorNLP(_NLP):
    """Stage 2 of a dynamic model: output-error ML by single shooting.

    The states are simulated from theta inside the NLP. IPOPT gets the cost, its gradient
    and its exact Hessian from forward sensitivities of the simulation
    (:class:`casest.problem.OutputErrorSums`; a CVODES model: CasADi's AD through the
    integrator). Decision vector ``w = [theta / scale; noise vector]``.
    """

    def __init__(self, problem: Problem, settings: SolverSettings):
        model = problem.model
        n, N = model.n_parameters, problem.n_samples
        self.model, self.mode, self.n_samples = model, "full", N
        self.scale = model.scales
        self.n_s = n
        w = ca.MX.sym("w", n + problem.n_noise)
        p = ca.MX.sym("data", problem.data_vector().size)
        theta = w[:n] * ca.DM(self.scale)
        self._options = settings.nlpsol_options()
        self._options["calc_lam_p"] = False
        if model.integrator == "rk4":
            sums = output_error_sums(model, N, model.scales, problem.masked, problem.full_noise,
                                     settings.resolved_jit(N))
            f = sums.cost(w, p)
            f_g, g = sums.gradient(w, p)
            H = symmetric(sums.hessian(w, p))
            if problem.penalty is not None:  # Gaussian priors as penalties, over N like the cost
                term, dterm, d2term = problem.penalty.scaled_terms(theta, self.scale, N, problem.n_noise)
                f, f_g, g, H = f + term, f_g + term, g + dterm, H + d2term
            lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", 0)
            self._options["grad_f"] = ca.Function("grad_f", [w, p], [f_g, g], ["x", "p"], ["f", "grad"])
            self._options["hess_lag"] = ca.Function("hess_lag", [w, p, lam_f, lam_g], [lam_f * ca.triu(H)],
                                                    ["x", "p", "lam_f", "lam_g"], ["hess"])
        else:  # an integrator: CasADi's AD through it
            f = problem.cost_expression(theta, w[n:], p) / N
            H, g = ca.hessian(f, w)
        self._nlp = {"x": w, "p": p, "f": f}
        self._solvers: dict = {}
        self.theta_of = ca.Function("theta_of", [w, p], [theta])
        self.newton = ca.Function("newton", [w, p], [g, H])


class _MultipleShootingNLP(_NLP):
    """Output error of a dynamic model by multiple shooting.

    The record is cut into intervals of ``shooting_interval`` samples; the states at the
    start of every interval but the first are decision variables (``w = [theta / scale;
    noise vector; nodes]``), each interval is simulated from its node, and the end of each
    interval must equal the next node (equality constraints). IPOPT gets CasADi's exact
    Hessian of the Lagrangian.
    """

    def __init__(self, problem: Problem, settings: SolverSettings):
        model = problem.model
        n, N, nx = model.n_parameters, problem.n_samples, model.n_states
        K = int(settings.shooting_interval)
        self.model, self.mode, self.n_samples = model, "full", N
        self.scale = model.scales
        self.n_s, self.n_noise = n, problem.n_noise
        bounds = list(range(0, N - 1, K)) + [N - 1]  # sample indices of the interval ends
        self.node_samples = bounds[1:-1]
        n_nodes = len(self.node_samples)
        w = ca.MX.sym("w", n + problem.n_noise + nx * n_nodes)
        p = ca.MX.sym("data", problem.data_vector().size)
        theta = w[:n] * ca.DM(self.scale)
        noise = w[n:n + problem.n_noise]
        nodes = ca.reshape(w[n + problem.n_noise:], nx, n_nodes) if n_nodes else ca.MX(nx, 0)
        T, U, Z, d0 = dynamic_data_views(model, N, problem.masked, p)
        theta_rhs = ca.vertcat(*[theta[i] for i in model.rhs_parameter_index]) if model.rhs_parameter_index \
            else ca.MX(0, 1)
        x_start = model.initial_function(theta, d0)
        columns, gaps = [x_start], []
        T_cols = ca.horzsplit(T)
        Ua_all, Ub_all = model.interval_inputs(U)
        Ua_cols, Ub_cols = ca.horzsplit(Ua_all), ca.horzsplit(Ub_all)
        for k, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
            start = x_start if k == 0 else nodes[:, k - 1]
            L = b - a  # this interval's samples a+1 .. b, simulated from its start
            run = model.step_function.mapaccum(f"interval_{L}", L)
            Ta, Tb = ca.horzcat(*T_cols[a:b]), ca.horzcat(*T_cols[a + 1:b + 1])
            X = run(start, ca.horzcat(*Ua_cols[a:b]), ca.horzcat(*Ub_cols[a:b]), Tb - Ta,
                    ca.repmat(theta_rhs, 1, L))
            if k < n_nodes:  # continuity: the end of this interval is the next node
                gaps.append(X[:, -1] - nodes[:, k])
            columns.append(X)
        X_all = ca.horzcat(*columns)
        f_i = per_sample_cost(model.output_model, problem.masked, problem.full_noise)
        J = ca.sum2(f_i.map(N)(ca.vertcat(X_all, U), Z, ca.vertcat(theta, noise)))
        if problem.penalty is not None:
            J = J + problem.penalty.expression(theta)
        g = ca.vertcat(*gaps) if gaps else ca.MX(0, 1)
        self.n_constraints = g.numel()
        self._nlp = {"x": w, "p": p, "f": J / N, "g": g}
        self._options = settings.nlpsol_options()
        self._options["calc_lam_p"] = False
        self._solvers: dict = {}
        self.theta_of = ca.Function("theta_of", [w, p], [theta])
        self.newton = None  # constrained: the stop is accepted by IPOPT's own tests only

    def extend(self, w0: np.ndarray, lbw: np.ndarray, ubw: np.ndarray, problem: Problem, theta0: np.ndarray):
        """Append the node states (from a single-shooting simulation at ``theta0``) and their free bounds."""
        states, _ = problem.model.simulate(theta0, problem.data)
        nodes = states[self.node_samples].reshape(-1)
        return (np.concatenate([w0, nodes]), np.concatenate([lbw, np.full(nodes.size, -np.inf)]),
                np.concatenate([ubw, np.full(nodes.size, np.inf)]))

    def solve(self, w0, lbw, ubw, p, max_iter: int = 1000):
        _, (buffer, run) = self.solver(max_iter)
        zeros = np.zeros(self.n_constraints)
        self._args = [np.ascontiguousarray(a, dtype=float) for a in (w0, p, lbw, ubw, zeros, zeros)]
        w, f = np.zeros(len(self._args[0])), np.zeros(1)
        for k, arr in enumerate(self._args):  # x0, p, lbx, ubx, lbg, ubg
            buffer.set_arg(k, memoryview(arr))
        buffer.set_res(0, memoryview(w))
        buffer.set_res(1, memoryview(f))
        run()
        return w, dict(buffer.stats())


def _full_nlp(problem: Problem, partition: Partition, settings: SolverSettings) -> _NLP:
    """The full-mode NLP of a problem (static: per-sample sums; dynamic: output error), cached."""
    if not problem.dynamic:
        return _nlp(problem.model, partition, problem.n_samples, "full", settings, problem.penalty, problem.masked,
                    problem.full_noise)
    key = ("output-error", problem.n_samples, repr(replace(settings, max_iter=0)),
           None if problem.penalty is None else problem.penalty.key(), problem.masked,
           problem.full_noise)
    per_model = _CACHE.setdefault(problem.model, {})
    if key not in per_model:
        multiple = settings.shooting == "multiple"
        per_model[key] = (_MultipleShootingNLP if multiple else _OutputErrorNLP)(problem, settings)
    return per_model[key]


_CACHE = StructureCache()


def _nlp(model: Model, partition: Partition, n_samples: int, mode: str, settings: SolverSettings,
             penalty: tuple | None = None, masked: bool = False, full_noise: bool = False) -> _NLP:
    # the iteration limit selects one of the problem's solvers, not a new build
    key = (partition.linear, mode, n_samples, repr(replace(settings, max_iter=0)),
           None if penalty is None else GaussianPenalty.coerce(penalty).key(), masked, full_noise)
    per_model = _CACHE.setdefault(model, {})
    if key not in per_model:
        per_model[key] = _NLP(model, partition, n_samples, mode, settings, penalty, masked, full_noise)
    return per_model[key]


def weighted_linear_parameters(model: Model, partition: Partition, data: Dataset, xi2, R) -> np.ndarray:
    """xi1 = argmin sum_k ||z_k - A_k xi1 - b_k||^2_{R^-1} by QR (paper Eq. 27), shape (n1,)."""
    from .stage1 import batched_least_squares

    if partition.n_linear == 0:
        return np.zeros(0)
    N, ny = data.n_samples, model.n_outputs
    xi2 = np.asarray(xi2, dtype=float)
    (A,) = evaluate(partition.A.map("A_all", "serial", N, [1], []), data.signals.T, xi2)
    (b,) = evaluate(partition.b.map("b_all", "serial", N, [1], []), data.signals.T, xi2)
    A = A.reshape(ny, N, -1).transpose(1, 0, 2)
    b = b.reshape(ny, N).T
    w = data.output_mask() / np.sqrt(np.asarray(R, dtype=float).reshape(1, ny))  # rows not measured: weight 0
    Aw = (A * w[:, :, None]).reshape(1, N * ny, -1)
    yw = ((data.filled_outputs() - b) * w).reshape(1, N * ny)
    x, ok = batched_least_squares(Aw, yw)
    if not ok[0]:
        from .stage1 import IdentifiabilityError

        raise IdentifiabilityError(
            f"A(xi2) is rank-deficient at xi2 = {np.asarray(xi2).tolist()}: the linear "
            f"parameters {list(partition.linear)} cannot be separated by these data"
        )
    return x[0]


# ----------------------------------------------------------------------------- solve
def _check_start(model: Model, theta0: np.ndarray) -> None:
    lb, ub = model.lower_bounds, model.upper_bounds
    bad = [
        f"{n} = {t:g} not in [{lo:g}, {hi:g}]"
        for n, t, lo, hi in zip(model.parameter_names, theta0, lb, ub)
        if not (lo <= t <= hi)
    ]
    if bad:
        raise OptionError(
            "the start lies outside the parameter bounds: " + "; ".join(bad) + ". Move the "
            "start inside the bounds or widen them"
        )
    if not np.all(np.isfinite(theta0)):
        raise OptionError(f"the start has non-finite values: {theta0.tolist()}")


def _run(nlp: _NLP, w0, lbw, ubw, p, settings: SolverSettings) -> tuple[np.ndarray, str, bool, int, list]:
    """Solve, and accept a short-of-tolerance stop only at a verified stationary point."""
    w, stats = nlp.solve(w0, lbw, ubw, p, settings.max_iter)
    status = str(stats.get("return_status", "unknown"))
    success = bool(stats.get("success", False))
    notes = []
    if not success and status in ACCEPTABLE_STATUSES and np.all(np.isfinite(w)) and nlp.newton is not None:
        grad, hess = evaluate(nlp.newton, w, p)
        span = np.maximum(1.0, np.abs(w))
        free = ~((np.abs(w - lbw) <= 1e-8 * span) | (np.abs(w - ubw) <= 1e-8 * span))
        step = newton_step_accepts(grad, hess, free, settings.newton_acceptance)
        if step is not None:
            success = True
            notes.append(Note(
                f"IPOPT stopped with {status}; accepted because the exact Newton step there is "
                f"{step:.1e} (scaled units) and the Hessian is positive definite", NoteCode.ACCEPTED))
    return w, status, success, int(stats.get("iter_count", 0)), notes


def solve_stage2(
    model: Model | Problem,
    data: Dataset | None = None,
    theta0=None,
    partition: Partition | None = None,
    mode: str = "full",
    settings: SolverSettings | None = None,
    R0=None,
    known_R=None,
    prior_penalty: bool = False,
    full_R: bool = False,
) -> Stage2Result:
    """Minimise the ML cost of Eq. 6 over theta and the noise R with IPOPT.

    Parameters
    ----------
    model : Model or Problem
        A :class:`casest.Problem` carries the data, noise model, priors and fixed
        parameters (then leave ``data``, ``known_R``, ``prior_penalty`` and ``full_R`` out);
        a Model is the problem with ``data`` and the options below.
    data : Dataset
    theta0 : array_like, shape (n_parameters,) or mapping
        Start (physical units); must lie inside the bounds. In ``reduced`` and
        ``alternating`` mode only its xi2 part is used.
    partition : Partition, optional
        Default :func:`casest.separate` of the (problem's) model.
    mode : {"full", "reduced", "alternating"}
    settings : SolverSettings, optional
    R0 : array_like, shape (n_outputs,), optional
        Start of R; default: the residual mean square at ``theta0``.
    known_R : array_like, shape (n_outputs,), optional
        Known noise variances: R is held at them (no ln|R| term to estimate), so the
        solution is the weighted least squares with weights 1/R.
    prior_penalty : bool
        Add the parameters' Gaussian priors to the cost as ``(theta - mean)^2 / (2 std^2)``
        (MAP; full mode, which is used whatever ``mode`` says). ``cost`` then includes them.
    full_R : bool
        R full and unknown (correlated channels), log-Cholesky parametrised, estimated with
        theta in full mode; ``R_full`` of the result holds it, ``R`` its diagonal.

    Returns
    -------
    Stage2Result
        For the problem's model (parameters declared or given fixed are not in it).
    """
    t0 = time.perf_counter()
    if mode not in MODES:
        raise OptionError(f"mode must be one of {MODES}, got {mode!r}")
    if isinstance(model, Problem):
        if known_R is not None or prior_penalty or full_R:
            raise OptionError("with a casest.Problem give the noise model and the priors to the Problem, "
                              "not to solve_stage2")
        problem = as_problem(model, data)
    else:
        problem = Problem(model, data, noise=_noise_option(model, known_R, full_R), prior_penalty=prior_penalty)
    if theta0 is None:
        raise OptionError("solve_stage2 needs a start theta0 (a mapping or a vector of the parameters)")
    return _solve(problem, problem.vector(theta0), partition, mode, settings or SolverSettings(), R0, t0)


def _noise_option(model: Model, known_R, full_R: bool):
    if full_R:
        return CorrelatedNoise()
    if known_R is None:
        return None
    known_R = np.asarray(known_R, dtype=float).reshape(-1)
    if known_R.size != model.n_outputs or not np.all(np.isfinite(known_R) & (known_R > 0)):
        raise OptionError(f"known_R needs {model.n_outputs} positive finite variances, got {known_R.tolist()}")
    return KnownNoise(dict(zip(model.output_names, np.sqrt(known_R).tolist())))


def _solve(problem: Problem, theta0: np.ndarray, partition, mode: str, settings: SolverSettings, R0, t0
           ) -> Stage2Result:
    from .separate import separate

    model, data = problem.model, problem.data
    partition = partition or separate(model)
    _check_start(model, theta0)
    N = data.n_samples
    floor = noise_floor(data, settings)
    if problem.full_noise:
        return _solve_full_noise(problem, theta0, partition, settings, floor, t0)
    known = not problem.noise.estimated
    notes: list[str] = []
    if problem.dynamic and mode != "full":
        notes.append(Note(f"output-error stage 2 of a dynamic model runs in full mode (asked: {mode})",
                          NoteCode.MODE_SWITCH))
        mode = "full"
    if known and mode == "alternating":
        mode = "reduced"  # with R known there is nothing to alternate
    penalty = problem.penalty
    if penalty is not None and mode != "full":
        notes.append(Note(f"Gaussian priors as penalties: stage 2 in full mode instead of {mode}", NoteCode.NOISE_MODEL))
        mode = "full"
    start_cost, R0 = problem.start_point(theta0, floor, R0)
    lo_rho, hi_rho = problem.noise.stage2_bounds(floor, R0)  # a held R: equal bounds, which IPOPT fixes

    if mode == "full":
        nlp = _full_nlp(problem, partition, settings)
        w0 = np.concatenate([theta0 / nlp.scale, np.log(R0)])
        lbw = np.concatenate([model.lower_bounds / nlp.scale, lo_rho])
        ubw = np.concatenate([model.upper_bounds / nlp.scale, hi_rho])
        if isinstance(nlp, _MultipleShootingNLP):
            w0, lbw, ubw = nlp.extend(w0, lbw, ubw, problem, theta0)
        with problem.data_argument() as p:
            w, status, success, iters, run_notes = _run(nlp, w0, lbw, ubw, p, settings)
            (theta,) = evaluate(nlp.theta_of, w, p)
        notes += run_notes
        R = np.exp(w[nlp.n_s : nlp.n_s + model.n_outputs])
        used_mode = "full"
    else:
        nlp = _nlp(model, partition, N, "reduced", settings, None, problem.masked)
        idx2 = list(partition.nonlinear_index)
        lb2, ub2 = model.lower_bounds[idx2], model.upper_bounds[idx2]
        s0 = theta0[idx2] / nlp.scale
        lbs, ubs = lb2 / nlp.scale, ub2 / nlp.scale
        if mode == "reduced":
            w0 = np.concatenate([s0, np.log(R0)])
            lbw = np.concatenate([lbs, lo_rho])
            ubw = np.concatenate([ubs, hi_rho])
            with problem.data_argument() as p:
                w, status, success, iters, run_notes = _run(nlp, w0, lbw, ubw, p, settings)
            notes += run_notes
            R = np.exp(w[nlp.n_s :])
        else:
            with problem.data_argument() as p:
                w, R, status, success, iters, loop_notes = _alternate(nlp, s0, lbs, ubs, R0, floor, p, problem,
                                                                      settings)
            notes += loop_notes
        xi2 = w[: nlp.n_s] * nlp.scale
        xi1 = weighted_linear_parameters(model, partition, data, xi2, R)
        theta = partition.assemble(xi1, xi2)
        used_mode = mode
        lin_idx = list(partition.linear_index)
        lb1, ub1 = model.lower_bounds[lin_idx], model.upper_bounds[lin_idx]
        violated = [n for n, v, lo, hi in zip(partition.linear, xi1, lb1, ub1) if not lo <= v <= hi]
        if violated:
            notes.append(Note(
                f"{mode} stage 2 put linear parameter(s) {violated} outside their bounds; "
                "re-solved in full mode from that point with them clipped to the bounds", NoteCode.BOUNDS))
            start = np.clip(theta, model.lower_bounds, model.upper_bounds)
            inner = _solve(problem, start, partition, "full", settings, R, t0)
            inner.notes = notes + inner.notes
            inner.n_iterations += iters
            return inner
    # IPOPT may end a hair outside a bound through rounding; the result must respect them
    theta = np.clip(theta, model.lower_bounds, model.upper_bounds)
    outcome = Outcome.ACCEPTED_NEWTON if success and any(note_code(n) is NoteCode.ACCEPTED for n in notes) else None
    if known:
        R = R0.copy()  # exactly the given variances (not exp(log(R)))
    if not success and not known:
        exact, R_exact, note = _exact_fit(problem, theta, floor, settings)
        if exact:
            success, R = True, R_exact
            notes.append(Note(f"IPOPT stopped with {status}; " + note, NoteCode.ACCEPTED))
            outcome = Outcome.EXACT_FIT
    cost = problem.cost(theta, R)
    success, status, outcome = _check_climb(cost, start_cost, success, status, outcome, used_mode, notes)
    if outcome is None:
        outcome = Outcome.CONVERGED if success else Outcome.NOT_CONVERGED
    message = ("converged" if success else "ended above the cost of its start" if status == "Climbed"
               else f"IPOPT did not converge ({status})")
    at_floor = [c for c, r, f in zip(model.output_names, R, floor) if r <= f * (1 + 1e-6)] if not known else []
    if at_floor:
        notes.append(Note(
            f"noise variance of {at_floor} is at the floor ({settings.noise_floor:g} x mean square): "
            "the model fits these data (almost) exactly, so R is not determined", NoteCode.NOISE_FLOOR))
    return Stage2Result(
        theta=theta,
        R=R,
        cost=cost,
        success=success,
        status=status,
        message=message,
        n_iterations=iters,
        mode=used_mode,
        notes=notes,
        seconds=time.perf_counter() - t0,
        outcome=outcome,
    )


def _check_climb(cost, start_cost, success, status, outcome, mode, notes):
    """A converged solve above its start is a stationary point it climbed to (a plateau or
    saddle), not an improvement: never reported as a success."""
    if success and cost > start_cost + 1e-9 * max(1.0, abs(start_cost)):
        notes.append(Note(f"stage 2 ({mode}) ended at J = {cost:.10g}, above its start's J = {start_cost:.10g}: "
                          "it stopped on a plateau or saddle; the start is better", NoteCode.CLIMBED))
        return False, "Climbed", Outcome.CLIMBED
    return success, status, outcome


def _solve_full_noise(problem: Problem, theta0, partition, settings, floor, t0) -> Stage2Result:
    """Stage 2 with R full and unknown: theta and the log-Cholesky factor of R, in full mode."""
    model = problem.model
    start_cost, S0 = problem.start_point(theta0, floor)
    nlp = _full_nlp(problem, partition, settings)
    ell0 = problem.noise_vector(S0)
    w0 = np.concatenate([theta0 / nlp.scale, ell0])
    lo_ell, hi_ell = problem.noise.stage2_bounds(floor, S0)
    lbw = np.concatenate([model.lower_bounds / nlp.scale, lo_ell])
    ubw = np.concatenate([model.upper_bounds / nlp.scale, hi_ell])
    if isinstance(nlp, _MultipleShootingNLP):
        w0, lbw, ubw = nlp.extend(w0, lbw, ubw, problem, theta0)
    with problem.data_argument() as p:
        w, status, success, iters, notes = _run(nlp, w0, lbw, ubw, p, settings)
        (theta,) = evaluate(nlp.theta_of, w, p)
    theta = np.clip(theta, model.lower_bounds, model.upper_bounds)
    R_full = problem.noise_of(w[nlp.n_s:nlp.n_s + len(ell0)])
    cost = problem.cost(theta, R_full)
    outcome = Outcome.ACCEPTED_NEWTON if success and notes else (Outcome.CONVERGED if success else Outcome.NOT_CONVERGED)
    success, status, outcome = _check_climb(cost, start_cost, success, status, outcome, "full R", notes)
    result = Stage2Result(theta=theta, R=np.diag(R_full).copy(), cost=cost, success=success, status=status,
                          message="converged" if success else f"IPOPT did not converge ({status})", n_iterations=iters,
                          mode="full", notes=notes, seconds=time.perf_counter() - t0, outcome=outcome, R_full=R_full)
    return result


def _exact_fit(problem: Problem, theta: np.ndarray, floor: np.ndarray, settings: SolverSettings):
    """Recognise an exact fit (every R_j at the floor) at a least-squares point.

    With data that the model reproduces exactly the likelihood has no maximum
    (R -> 0); IPOPT then stalls on round-off amplified by the weights 1/R. The point
    is accepted when the residual mean square is below the floor in every channel and a
    Gauss-Newton step on the free parameters is shorter than ``newton_acceptance``
    (in units of the parameters' scales).
    """
    model = problem.model
    resid = np.nan_to_num(problem.residuals(theta))  # 0 where not measured
    ms = np.sum(resid**2, axis=0) / problem.data.observed_counts()
    if np.any(ms > floor):
        return False, None, ""
    active = active_bounds(theta, model.lower_bounds, model.upper_bounds, model.scales)
    free = [i for i, a in enumerate(active) if a is None]
    J = problem.jacobian(theta)[:, free] * model.scales[free]
    step, *_ = np.linalg.lstsq(J, resid.reshape(-1), rcond=None)
    size = float(np.max(np.abs(step))) if step.size else 0.0
    if size >= settings.newton_acceptance:
        return False, None, ""
    return True, floor.copy(), (
        f"the data are fitted exactly (residual mean square below the noise floor); accepted "
        f"because a Gauss-Newton step there is {size:.1e} (scaled units)"
    )


def _alternate(nlp, s0, lbs, ubs, R0, floor, p, problem: Problem, settings):
    """Paper Eq. 26: xi2 with R fixed, then R from the residuals, until R settles."""
    R = R0.copy()
    s = s0.copy()
    iters = 0
    notes: list[str] = []
    status, success = "Maximum_Alternations_Exceeded", False
    for k in range(settings.max_alternations):
        rho = np.log(R)
        w0 = np.concatenate([s, rho])
        lbw = np.concatenate([lbs, rho])
        ubw = np.concatenate([ubs, rho])
        w, ipopt_status, ok, it, run_notes = _run(nlp, w0, lbw, ubw, p, settings)
        iters += it
        if not ok:
            return w, R, ipopt_status, False, iters, notes + run_notes
        s = w[: nlp.n_s]
        (theta,) = evaluate(nlp.theta_of, w, p)
        R_new = np.maximum(problem.residual_mean_square(theta), floor)
        change = np.abs(R_new - R) / R_new
        R = R_new
        if np.all(change < settings.alternating_tol):
            status, success = "Solve_Succeeded", True
            notes.append(Note(f"alternating loop: R settled within {settings.alternating_tol:.0%} after {k + 1} passes"))
            break
    w = np.concatenate([s, np.log(R)])
    return w, R, status, success, iters, notes
