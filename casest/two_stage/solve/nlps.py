"""The stage-2 NLPs, built once per structure and reused: per-sample sums with exact derivatives
(full and reduced mode), output error through the simulation, and multiple shooting."""

from __future__ import annotations

import contextlib
import functools
import hashlib
import os
from dataclasses import replace

import casadi as ca
import numpy as np

from ..._casadi.evaluation import evaluate
from ..._casadi.numerics import cache_dir, cache_usable, compiling_ahead
from ..._casadi.memory import StructureCache
from ...backend.ipopt import ACCEPTABLE_STATUSES, IterateRecorder, SolverSettings, newton_step_accepts
from ...backend.noise_terms import DIAGONAL, NoiseTerm
from ...backend.output_error import dynamic_data_views, output_error_sums
from ...backend.penalty import GaussianPenalty
from ...backend.sums import MLSums, bound_sum, data_outside_graph, map_sum, ml_sums, per_sample_cost, symmetric
from ...models import Model
from ...problem.measurement import DynamicMeasurement, Measurement, StaticMeasurement
from ...problem.problem import Problem, sum_data_symbols
from ...errors import OptionError
from ...status import Note, NoteCode
from ...problem.separate import Partition


__all__ = ["compile_sums_ahead", "normal_equations", "SumsNLP", "OutputErrorNLP", "MultipleShootingNLP", "full_nlp", "NLP_CACHE", "sums_nlp", "run_nlp",
           "states_from_outputs"]


# ----------------------------------------------------------------------------- symbolic parts
def compile_sums_ahead(problem: Problem, partition: Partition, settings: SolverSettings) -> bool:
    """Start the compiles of the sums a static problem's stage 2 will build (the ML cost, its
    gradient and Hessian; reduced mode's normal equations) in background processes, so that they
    overlap stage 1 instead of following it. The functions are built here without being kept
    (:func:`~casest._casadi.numerics.compiling_ahead`); stage 2 builds them again and loads the
    compiled libraries from the cache (waiting for a compile still running).

    Parameters
    ----------
    problem : Problem
    partition : Partition
    settings : SolverSettings
        Stage 2's settings (threads, JIT and its flags).

    Returns
    -------
    bool
        Whether the sums were built ahead: not for a dynamic model, sums that are not compiled,
        a structure whose NLPs this process has built already, or sums an earlier process built
        ahead (a marker file in the compile cache says so).
    """
    N = problem.n_samples
    if problem.dynamic or not settings.resolved_jit(N):
        return False
    model = problem.model
    if any(key[2] == N for key in NLP_CACHE.setdefault(model, {})):
        return False
    threads, outside = settings.resolved_threads(N), data_outside_graph(N)
    marker = _ahead_marker(model, partition, N, threads, settings.jit_flags, problem.masked, problem.noise_term.name)
    if marker is None or os.path.exists(marker):  # compiled ahead by an earlier process: the cache has them
        return False
    with compiling_ahead():
        sums = MLSums(model, N, model.scales, threads, True, settings.jit_flags, problem.masked, problem.noise_term,
                      outside)
        _ = (sums.gradient, sums.hessian)  # built on first use: here, to compile them ahead
        if partition.n_linear and partition.n_nonlinear and problem.noise_term.per_channel:  # the reduced mode's
            normal_equations(model, partition, N, threads, True, settings.jit_flags, problem.masked, outside)
    with contextlib.suppress(OSError):
        open(marker, "a").close()
    return True


def _ahead_marker(model: Model, partition: Partition, *arguments) -> str | None:
    """A file in the compile cache that says these sums were compiled ahead once (building them
    ahead costs 0.1-0.2 s, worth it only while the cache lacks them); None without a usable cache
    or a structure key."""
    key = getattr(model, "structure_key", None)
    if key is None or not cache_usable():
        return None
    digest = hashlib.sha256(repr((key, partition.linear, arguments)).encode()).hexdigest()[:32]
    return os.path.join(cache_dir(), f"ahead_{digest}")


def normal_equations(model: Model, partition: Partition, n_samples: int, threads: int = 1, jit: bool = False,
                      jit_flags=("-O2",), masked: bool = False, outside: bool = False) -> ca.Function:
    """(X, Z, xi2, w) -> (sum A'WA, sum A'W(z-b)) with W = diag(w); A'WA as vec (n1^2); with
    ``outside`` (record, xi2, w), the data (X, Z) in the :class:`casest.backend.sums.Record` bound
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


class SumsNLP:
    """One stage-2 NLP (mode, model, partition, N), built once and reused.

    IPOPT gets the cost, its gradient and the upper triangle of its Hessian as sums of
    per-sample exact derivatives (:mod:`casest.backend.sums`) through nlpsol's ``grad_f`` and
    ``hess_lag`` options, so CasADi never differentiates through the N-sample graph.
    In ``reduced`` mode xi1 = xi1*(xi2, R) solves the weighted normal equations, the
    gradient is the full one at that point (dJ/dxi1 = 0 there) and the Hessian is the
    Schur complement ``H_uu - H_u1 H_11^-1 H_1u`` of the full Hessian, which is the exact
    Hessian of the reduced cost.
    """

    def __init__(self, model: Model, partition: Partition, n_samples: int, mode: str, settings: SolverSettings,
                 penalty: tuple | None = None, masked: bool = False, noise: NoiseTerm = DIAGONAL):
        self.model, self.partition, self.n_samples, self.mode = model, partition, n_samples, mode
        n, N = model.n_parameters, n_samples
        # the noise block of w: ln R_j (diagonal R), or the log-Cholesky vector of a full R
        ny = noise.block_size(model.n_outputs)
        if not noise.per_channel and mode != "full":
            raise ValueError(f"the {type(noise).__name__} noise term needs the full stage-2 mode")
        # long records: the data stay outside the graph (a Record's handle), so the build does
        # not grow with N; short ones: an N-long parameter, evaluated without leaving C. The
        # parameter's value is Problem.data_argument(), which makes the same choice
        self.outside = data_outside_graph(N)
        p, data = sum_data_symbols(model, N, masked)
        sums = ml_sums(model, N, model.scales, settings.resolved_threads(N), settings.resolved_jit(N), settings.jit_flags,
                       masked, noise, bound=self.outside)  # the same sums as Problem.cost_hessian
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
                M, rhs = normal_equations(
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
        self.recorder = IterateRecorder(w.numel()) if settings.record_iterates else None
        self.theta_of = ca.Function("theta_of", [w, p], [theta])
        self.newton = ca.Function("newton", [w, p], [g, symmetric(H)])

    def solver(self, max_iter: int) -> ca.Function:
        """The IPOPT solver with this iteration limit (the derivative Functions are shared)."""
        if max_iter not in self._solvers:
            options = dict(self._options, **{"ipopt.max_iter": int(max_iter)})
            if getattr(self, "recorder", None) is not None:
                options["iteration_callback"] = self.recorder
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
        if self.recorder is not None:
            self.recorder.clear()
        self._args = [np.ascontiguousarray(a, dtype=float) for a in (w0, p, lbw, ubw)]
        w, f = np.zeros(len(self._args[0])), np.zeros(1)
        for k, arr in enumerate(self._args):  # x0, p, lbx, ubx
            buffer.set_arg(k, memoryview(arr))
        buffer.set_res(0, memoryview(w))
        buffer.set_res(1, memoryview(f))
        run()
        return w, dict(buffer.stats())


class OutputErrorNLP(SumsNLP):
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
        if problem.measurement.model_has_forward_sensitivities:
            sums = output_error_sums(model, N, model.scales, problem.masked, problem.noise_term,
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
        else:  # an integrator or delayed outputs: CasADi's AD through the simulation
            f = problem.cost_expression(theta, w[n:], p) / N
            H, g = ca.hessian(f, w)
        self._nlp = {"x": w, "p": p, "f": f}
        self._solvers: dict = {}
        self.recorder = IterateRecorder(w.numel()) if settings.record_iterates else None
        self.theta_of = ca.Function("theta_of", [w, p], [theta])
        self.newton = ca.Function("newton", [w, p], [g, H])


def _simulate_intervals(model, theta, nodes, bounds: list, T, U, d0) -> tuple:
    """Multiple shooting's states, each interval simulated from its node (the first from the
    initial state), and the continuity gaps between an interval's end and the next node.

    Returns
    -------
    states : casadi.MX, shape (n_states, N)
    gaps : list of casadi.MX
    """
    n_nodes = nodes.size2()
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
    return ca.horzcat(*columns), gaps


class MultipleShootingNLP(SumsNLP):
    """Output error of a dynamic model by multiple shooting.

    The record is cut into intervals of ``shooting_interval`` samples; the states at the
    start of every interval but the first are decision variables (``w = [theta / scale;
    noise vector; nodes]``), each interval is simulated from its node, and the end of each
    interval must equal the next node (equality constraints). IPOPT gets CasADi's exact
    Hessian of the Lagrangian.
    """

    def __init__(self, problem: Problem, settings: SolverSettings):
        model = problem.model
        if model.output_delays:
            raise OptionError("multiple shooting evaluates each sample's outputs from its own states, and delayed "
                              "outputs mix neighbouring samples: use single shooting (shooting='single') with "
                              "output delays")
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
        X_all, gaps = _simulate_intervals(model, theta, nodes, bounds, T, U, d0)
        f_i = per_sample_cost(model.output_model, problem.masked, problem.noise_term)
        J = ca.sum2(f_i.map(N)(ca.vertcat(X_all, U), Z, ca.vertcat(theta, noise)))
        if problem.penalty is not None:
            J = J + problem.penalty.expression(theta)
        g = ca.vertcat(*gaps) if gaps else ca.MX(0, 1)
        self.n_constraints = g.numel()
        self._nlp = {"x": w, "p": p, "f": J / N, "g": g}
        self._options = settings.nlpsol_options()
        self._options["calc_lam_p"] = False
        self._solvers: dict = {}
        self.recorder = IterateRecorder(w.numel(), g.numel()) if settings.record_iterates else None
        self.theta_of = ca.Function("theta_of", [w, p], [theta])
        #: J as this NLP counts it: each interval simulated from its own node
        self.shooting_cost = ca.Function("shooting_cost", [w, p], [J])
        self.newton = None  # constrained: the stop is accepted by IPOPT's own tests only

    def extend(self, w0: np.ndarray, lbw: np.ndarray, ubw: np.ndarray, problem: Problem, theta0: np.ndarray):
        """Append the node states and their free bounds. Each node starts at the state that fits that
        sample's measured outputs (least squares through the output equation at ``theta0``) where the
        outputs determine the states, else at a single-shooting simulation from ``theta0``: on an
        unstable system the simulation from a poor start drifts far from the record, the data do not.

        Returns
        -------
        w0, lbw, ubw : ndarray
            Extended by the nodes.
        anchored : bool
            Whether the outputs gave every node (then :meth:`anchored_start` applies).
        """
        states, _ = problem.model.simulate(theta0, problem.data)
        fitted = states_from_outputs(problem, theta0, self.node_samples)
        nodes = np.where(np.isfinite(fitted), fitted, states[self.node_samples]).reshape(-1)
        anchored = bool(len(self.node_samples)) and bool(np.all(np.isfinite(fitted)))
        return (np.concatenate([w0, nodes]), np.concatenate([lbw, np.full(nodes.size, -np.inf)]),
                np.concatenate([ubw, np.full(nodes.size, np.inf)]), anchored)

    def anchored_start(self, w0: np.ndarray, lbw: np.ndarray, ubw: np.ndarray, p: np.ndarray, max_iter: int
                       ) -> tuple[np.ndarray, dict]:
        """The parameters and R that fit each interval simulated from its node held at the state the
        measured outputs give, continuity not imposed: a fit to the data over short horizons, which a
        poor start's wrong local minimum of the whole simulation does not hold. Neither start always
        wins: on ``models/unstable.py`` (seeds 0-4, intervals of 5, 10, 25 and 50 samples, the
        pipeline from the nominal values and from ``START``) the full problem from the start alone
        ended at the stable local minimum in 5 of 40 runs, from this start alone in 2 (seed 1 with
        50-sample intervals, from both), and the lower of the two in none; hence both are solved. The nodes are returned as they were.

        Parameters
        ----------
        w0, lbw, ubw : ndarray
            The extended start and bounds (:meth:`extend`).
        p : ndarray
            The data vector.
        max_iter : int

        Returns
        -------
        w : ndarray
            ``w0`` with the parameters and noise of this fit.
        stats : dict
            IPOPT's statistics.
        """
        free = self.n_s + self.n_noise
        lower, upper = lbw.copy(), ubw.copy()
        lower[free:], upper[free:] = w0[free:], w0[free:]  # held: IPOPT takes them as parameters
        w, stats = self.solve(w0, lower, upper, p, max_iter, continuity=False)
        start = w0.copy()
        if np.all(np.isfinite(w[:free])):
            start[:free] = w[:free]
        return start, stats

    def solve(self, w0, lbw, ubw, p, max_iter: int = 1000, continuity: bool = True):
        """Run IPOPT; ``continuity`` False leaves the intervals' ends free of the next nodes.

        Returns
        -------
        w : ndarray
        stats : dict
            IPOPT's statistics.
        """
        _, (buffer, run) = self.solver(max_iter)
        if self.recorder is not None:
            self.recorder.clear()
        bound = 0.0 if continuity else np.inf
        lbg, ubg = np.full(self.n_constraints, -bound), np.full(self.n_constraints, bound)
        self._args = [np.ascontiguousarray(a, dtype=float) for a in (w0, p, lbw, ubw, lbg, ubg)]
        w, f = np.zeros(len(self._args[0])), np.zeros(1)
        for k, arr in enumerate(self._args):  # x0, p, lbx, ubx, lbg, ubg
            buffer.set_arg(k, memoryview(arr))
        buffer.set_res(0, memoryview(w))
        buffer.set_res(1, memoryview(f))
        run()
        return w, dict(buffer.stats())


def states_from_outputs(problem: Problem, theta: np.ndarray, samples: list, iterations: int = 20) -> np.ndarray:
    """The states at ``samples`` that fit each sample's measured outputs at ``theta`` (Gauss-Newton on
    ``z_k - h(x, u_k, theta)`` per sample from x = 0), shape (len(samples), n_states); NaN rows where
    the outputs do not determine the states (fewer measured outputs than states, a singular
    output Jacobian) or the fit does not settle."""
    model = problem.model
    nx = model.n_states
    x, u = ca.SX.sym("x", nx), ca.SX.sym("u", len(model.inputs))
    h = model.output_model.function(ca.vertcat(x, u), ca.DM(theta))
    fit = ca.Function("output_fit", [x, u], [h, ca.jacobian(h, x)])
    out = np.full((len(samples), nx), np.nan)
    for row, k in enumerate(samples):
        z, seen = problem.data.outputs[k], np.isfinite(problem.data.outputs[k])
        xk, ok = np.zeros(nx), False
        for _ in range(iterations):
            hk, Hk = (np.asarray(v) for v in fit(xk, problem.data.signals[k, 1:]))
            Hk, r = Hk[seen], (z - hk.ravel())[seen]
            if Hk.shape[0] < nx or np.linalg.matrix_rank(Hk) < nx:
                break
            step = np.linalg.lstsq(Hk, r, rcond=None)[0]
            xk = xk + step
            if np.max(np.abs(step)) <= 1e-10 * max(1.0, float(np.max(np.abs(xk)))):
                ok = True
                break
        if ok:
            out[row] = xk
    return out


def full_nlp(problem: Problem, partition: Partition, settings: SolverSettings) -> SumsNLP:
    """The full-mode NLP of a problem, cached: the factory registered for its measurement's kind
    (static: per-sample sums; dynamic: output error).

    Parameters
    ----------
    problem : Problem
    partition : Partition
    settings : SolverSettings

    Returns
    -------
    SumsNLP, OutputErrorNLP or MultipleShootingNLP
    """
    return _full_nlp_of(problem.measurement, problem, partition, settings)


@functools.singledispatch
def _full_nlp_of(measurement: Measurement, problem: Problem, partition: Partition, settings: SolverSettings):
    raise TypeError(f"no stage-2 NLP is registered for the measurement kind {type(measurement).__name__}")


@_full_nlp_of.register
def _(measurement: StaticMeasurement, problem: Problem, partition: Partition, settings: SolverSettings) -> SumsNLP:
    return sums_nlp(problem.model, partition, problem.n_samples, "full", settings, problem.penalty, problem.masked,
                    problem.noise_term)


@_full_nlp_of.register
def _(measurement: DynamicMeasurement, problem: Problem, partition: Partition, settings: SolverSettings):
    key = ("output-error", problem.n_samples, repr(replace(settings, max_iter=0)),
           None if problem.penalty is None else problem.penalty.key(), problem.masked,
           problem.noise_term)
    per_model = NLP_CACHE.setdefault(problem.model, {})
    if key not in per_model:
        multiple = settings.shooting == "multiple"
        per_model[key] = (MultipleShootingNLP if multiple else OutputErrorNLP)(problem, settings)
    return per_model[key]


NLP_CACHE = StructureCache()


def sums_nlp(model: Model, partition: Partition, n_samples: int, mode: str, settings: SolverSettings,
             penalty: tuple | None = None, masked: bool = False, noise: NoiseTerm = DIAGONAL) -> SumsNLP:
    # the iteration limit selects one of the problem's solvers, not a new build
    key = (partition.linear, mode, n_samples, repr(replace(settings, max_iter=0)),
           None if penalty is None else GaussianPenalty.coerce(penalty).key(), masked, noise)
    per_model = NLP_CACHE.setdefault(model, {})
    if key not in per_model:
        per_model[key] = SumsNLP(model, partition, n_samples, mode, settings, penalty, masked, noise)
    return per_model[key]


def run_nlp(nlp: SumsNLP, w0, lbw, ubw, p, settings: SolverSettings) -> tuple[np.ndarray, str, bool, int, list]:
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
