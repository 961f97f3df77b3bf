"""The two-stage estimator built from CasADi primitives: a Function that can be saved, loaded and
code-generated (no Python callback inside).

Stage 1 is the paper's sweep over a fixed set of candidates (drawn when the Function is built,
as :func:`casest.estimate`'s sweep draws them): per candidate, the per-channel Gram matrices of
``[A(xi2) y(xi2)]`` summed over the samples (a ``map``), the joint least squares for xi1 and the
residual mean squares R_j; a fold over the candidates keeps the one with the smallest Tr[R]
(the first on ties). Stage 2 is one full maximum-likelihood NLP (paper Eq. 6, R diagonal and
unknown, exact Hessian) from that candidate: IPOPT, or CasADi's ``sqpmethod`` with its QP
solver ``qrqp``, which code-generates to self-contained C. The optimum is polished by exact
Newton steps on the parameters inside their bounds, and the covariance is the inverse of the
Hessian there, as :func:`casest.interop.two_stage_function` computes them.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..backend.ipopt import SolverSettings
from ..two_stage import SweepSettings
from ..problem.separate import separate
from ..two_stage.sweep.candidates import draw_candidates
from ..models import Model, OptionError
from ..problem import ml_cost_expression
from ..options import GraphSolver, choices
from ..checks import whole_number

__all__ = ["two_stage_graph_function", "stage1_function", "stage1_graph", "GRAPH_SOLVERS", "STAGE1_OUTPUTS"]

#: the stage-2 solvers of the graph: IPOPT (the default), or CasADi's SQP method with qrqp
GRAPH_SOLVERS = choices(GraphSolver)
#: exact Newton steps that polish the stage-2 optimum inside the graph
NEWTON_STEPS = 3


def two_stage_graph_function(model: Model, n_samples: int, sweep_settings: SweepSettings | None = None,
                             solver_settings: SolverSettings | None = None, solver: GraphSolver = "ipopt",
                             name: str = "two_stage_graph") -> ca.Function:
    """The two-stage estimator of a static model as a pure CasADi Function.

    ``two_stage_graph(signals[n_signals x N], outputs[n_outputs x N]) -> (theta[n], R[n_y],
    cov[n x n], success)``, the signature of :func:`casest.interop.two_stage_function`; unlike
    that one it holds no Python callback, so it can be serialised (``Function.save`` /
    ``casadi.Function.load``) and, with ``solver="sqpmethod"``, code-generated to C that needs
    neither Python nor IPOPT.

    What it does not do that :func:`casest.estimate` does: the sweep's refinements and checks
    (paper Eq. 17-18), several stage-2 starts, box-constrained least squares for xi1 in stage 1
    (the unconstrained xi1 is clipped into its box for the start), the reduced mode and the
    report. Where ``casest.estimate`` takes one start from the best candidate and that solve
    converges, both give the same optimum.

    Parameters
    ----------
    model : Model
        A static model with at least one nonlinear parameter and bounded xi2.
    n_samples : int
        N.
    sweep_settings : SweepSettings, optional
        The candidates' design, number and seed (``n_candidates``, ``design``, ``seed``).
    solver_settings : SolverSettings, optional
        Tolerance, iterations and noise floor of stage 2.
    solver : {"ipopt", "sqpmethod"}
        Stage 2's NLP solver.
    name : str

    Returns
    -------
    casadi.Function
        ``success`` is 1.0 when stage 2's gradient on the parameters inside their bounds is
        below 1e-6 (relative to the cost) at the polished optimum and every output is finite.
    """
    if not isinstance(model, Model):
        raise OptionError("two_stage_graph_function takes a static casest.Model")
    n_samples = whole_number(n_samples, "two_stage_graph_function(model, n_samples): N must be a positive integer")
    if solver not in GRAPH_SOLVERS:
        raise OptionError(f"solver must be one of {GRAPH_SOLVERS}, got {solver!r}")
    sweep_settings = sweep_settings or SweepSettings()
    solver_settings = solver_settings or SolverSettings()
    partition = separate(model)
    if partition.n_nonlinear == 0:
        raise OptionError(f"{model.name} has no nonlinear parameter: stage 1 has nothing to sweep; use "
                          "estimator_function (one linear least-squares solve)")
    N = int(n_samples)
    candidates, _, _ = draw_candidates(model, partition, sweep_settings)
    X = ca.MX.sym("signals", model.n_signals, N)
    Z = ca.MX.sym("outputs", model.n_outputs, N)
    theta0 = stage1_graph(model, partition, candidates, X, Z)["theta0"]
    theta, R = _stage2(model, N, theta0, X, Z, solver_settings, solver)
    theta, R, cov, success = _polished(model, N, theta, R, X, Z)
    return ca.Function(name, [X, Z], [theta, R, cov, success], ["signals", "outputs"],
                       ["theta", "R", "cov", "success"])


#: the outputs of :func:`stage1_function`, in order
STAGE1_OUTPUTS = ("trace_R", "R", "xi1", "xi2", "best_trace", "best_xi1", "best_xi2", "theta0")


def stage1_function(model: Model, n_samples: int, sweep_settings: SweepSettings | None = None,
                    name: str = "stage1") -> ca.Function:
    """Stage 1 of the paper as a pure CasADi Function of the data: the landscape over a fixed set of
    xi2 candidates and the best of them, callable on numbers or inside another NLP.

    ``stage1(signals[n_signals x N], outputs[n_outputs x N]) -> (trace_R[1 x K], R[n_y x K],
    xi1[n1 x K], xi2[n2 x K], best_trace, best_xi1[n1], best_xi2[n2], theta0[n])``: per candidate
    (drawn when the Function is built, as :func:`casest.sweep` draws them from the same
    ``sweep_settings``) the joint least squares for xi1 and the residual mean square of each
    output (paper Eq. 19, R(xi2p) with R set to the identity), their trace, and the candidate
    with the smallest Tr[R] (the first on ties; NaN or infinite traces never win). ``theta0`` is
    that candidate's parameter vector with xi1 clipped into its bounds, the start of stage 2.
    Everything but the choice of the best candidate is smooth in the data, and CasADi
    differentiates it (``jacobian``, ``forward``, ``reverse``); the choice is piecewise constant.
    Unlike :func:`casest.sweep` it does not refine, check Eq. 17-18 or judge the landscape, and
    its least squares for xi1 is unconstrained.

    Parameters
    ----------
    model : Model
        A static model with at least one nonlinear parameter and bounded xi2.
    n_samples : int
        N.
    sweep_settings : SweepSettings, optional
        The candidates' design, number and seed (``n_candidates``, ``design``, ``seed``).
    name : str

    Returns
    -------
    casadi.Function
        MX, no Python callback: it saves, loads and code-generates.
    """
    if not isinstance(model, Model):
        raise OptionError("stage1_function takes a static casest.Model: a dynamic model's stage 1 runs over "
                          "simulations (casest.sweep)")
    N = whole_number(n_samples, "stage1_function(model, n_samples): N must be a positive integer")
    partition = separate(model)
    if partition.n_nonlinear == 0:
        raise OptionError(f"{model.name} has no nonlinear parameter: stage 1 has nothing to sweep")
    candidates, _, _ = draw_candidates(model, partition, sweep_settings or SweepSettings())
    X, Z = ca.MX.sym("signals", model.n_signals, int(N)), ca.MX.sym("outputs", model.n_outputs, int(N))
    graph = stage1_graph(model, partition, candidates, X, Z)
    graph["xi2"] = ca.MX(ca.DM(candidates.T))
    return ca.Function(name, [X, Z], [graph[key] for key in STAGE1_OUTPUTS], ["signals", "outputs"],
                       list(STAGE1_OUTPUTS))


def stage1_graph(model: Model, partition, candidates: np.ndarray, X, Z) -> dict:
    """Stage 1 over fixed candidates as MX expressions of the data (see :func:`stage1_function`).

    Parameters
    ----------
    model : Model
    partition : Partition
    candidates : ndarray, shape (K, n_nonlinear)
    X, Z : casadi.MX, shapes (n_signals, N) and (n_outputs, N)

    Returns
    -------
    dict of casadi.MX
        ``trace_R`` (1 x K), ``R`` (n_outputs x K), ``xi1`` (n_linear x K), ``best_trace``,
        ``best_xi1``, ``best_xi2``, ``theta0`` (the best candidate's parameters, xi1 clipped into
        its box).
    """
    n1, n2, ny = partition.n_linear, partition.n_nonlinear, model.n_outputs
    N = X.size2()
    x, z, xi2 = ca.SX.sym("x", model.n_signals), ca.SX.sym("z", ny), ca.SX.sym("xi2", n2)
    A = partition.A(x, xi2) if n1 else ca.SX(ny, 0)
    y = z - partition.b(x, xi2)
    rows = ca.horzcat(A, y)  # per channel j: [A_j y_j]
    gram = ca.vertcat(*[ca.vec(ca.mtimes(rows[j, :].T, rows[j, :])) for j in range(ny)])  # ny (n1+1)^2
    per_sample = ca.Function("stage1_gram_sample", [x, z, xi2], [gram])
    xi2_m = ca.MX.sym("xi2", n2)
    G = ca.sum2(per_sample.map(N)(X, Z, xi2_m))
    k = n1 + 1
    blocks = [ca.reshape(G[j * k * k:(j + 1) * k * k], k, k) for j in range(ny)]
    P = sum(b[:n1, :n1] for b in blocks) if n1 else ca.MX(0, 0)
    q = sum(b[:n1, n1] for b in blocks) if n1 else ca.MX(0, 1)
    xi1 = ca.solve(P, q) if n1 else ca.MX(0, 1)
    R = ca.vertcat(*[b[n1, n1] - 2 * ca.dot(b[:n1, n1], xi1) + ca.mtimes([xi1.T, b[:n1, :n1], xi1])
                     if n1 else b[n1, n1] for b in blocks]) / N
    trace = ca.sum1(R)
    ranked = ca.if_else(ca.logic_and(trace == trace, trace < ca.inf), trace, ca.inf)  # NaN or inf: never the best
    stage1 = ca.Function("stage1_candidate", [X, Z, xi2_m], [ranked, xi1, R, trace])
    # every candidate (the data not repeated), then a fold keeping the first smallest Tr[R]
    K = candidates.shape[0]
    ranks, xi1s, Rs, traces = stage1.map("stage1_sweep", "serial", K, [0, 1], [])(X, Z, ca.DM(candidates.T))
    acc, column = ca.MX.sym("acc", 1 + n1 + n2), ca.MX.sym("column", 1 + n1 + n2)
    keep = ca.Function("stage1_keep", [acc, column], [ca.if_else(column[0] < acc[0], column, acc)])
    start = ca.vertcat(ca.inf, ca.DM.zeros(n1 + n2))
    best = keep.mapaccum("stage1_best", K)(start, ca.vertcat(ranks, xi1s, ca.DM(candidates.T)))[:, -1]
    theta0 = []
    for i in range(model.n_parameters):
        if i in partition.linear_index:
            value = best[1 + list(partition.linear_index).index(i)]
            theta0.append(ca.fmin(ca.fmax(value, model.lower_bounds[i]), model.upper_bounds[i]))
        else:
            theta0.append(best[1 + n1 + list(partition.nonlinear_index).index(i)])
    return {"trace_R": traces, "R": Rs, "xi1": xi1s, "best_trace": best[0], "best_xi1": best[1:1 + n1],
            "best_xi2": best[1 + n1:], "theta0": ca.vertcat(*theta0)}


def _stage2(model: Model, N: int, theta0, X, Z, settings: SolverSettings, solver: str) -> tuple:
    """One full-mode ML solve from ``theta0`` (R from its residual mean squares): (theta, R) as MX."""
    from .embed import ml_problem

    problem = ml_problem(model, N)
    if solver == "ipopt":
        nlp_solver = problem.solver(settings, {"min_lam": 1e-10})
    else:
        nlp_solver = ca.nlpsol(f"casest_graph_{model.name}", "sqpmethod", problem.nlp(), settings.sqpmethod_options())
    p = ca.vertcat(ca.vec(X), ca.vec(Z))
    residual_ms = ca.sum2((Z - model.function.map(N)(X, theta0)) ** 2) / N
    floor = settings.noise_floor * ca.fmax(ca.sum2(Z**2) / N, 1e-300)
    rho0 = ca.log(ca.fmax(residual_ms, floor))
    scale = ca.DM(problem.scale)
    lbx = ca.vertcat(ca.DM(model.lower_bounds) / scale, ca.log(floor))
    ubx = ca.vertcat(ca.DM(model.upper_bounds) / scale, ca.DM.inf(model.n_outputs))
    x = nlp_solver(x0=ca.vertcat(theta0 / scale, rho0), p=p, lbx=lbx, ubx=ubx)["x"]
    n = model.n_parameters
    return x[:n] * scale, ca.exp(x[n:])


def _inside(model: Model, theta) -> ca.MX:
    """1 for a parameter off its bounds (:func:`casest.backend.ipopt.active_bounds`'s rule), else 0."""
    flags = []
    for i, (lo, hi, sc) in enumerate(zip(model.lower_bounds, model.upper_bounds, model.scales)):
        flag = ca.MX(1)
        if np.isfinite(lo):
            flag = flag * (ca.fabs(theta[i] - lo) > 1e-7 * max(sc, abs(lo)))
        if np.isfinite(hi):
            flag = flag * (ca.fabs(hi - theta[i]) > 1e-7 * max(sc, abs(hi)))
        flags.append(flag)
    return ca.vertcat(*flags)


def _polished(model: Model, N: int, theta, R, X, Z) -> tuple:
    """Exact Newton steps on the free parameters and every ln R_j, the covariance (the theta block
    of the inverse Hessian, zero on a bound) and the success flag, as MX of the solve's output."""
    n, ny = model.n_parameters, model.n_outputs
    w_sym = ca.MX.sym("w", n + ny)
    Xs, Zs = ca.MX.sym("X", X.sparsity()), ca.MX.sym("Z", Z.sparsity())
    J = ml_cost_expression(model, N, w_sym[:n], w_sym[n:], ca.vertcat(ca.vec(Xs), ca.vec(Zs)))
    g = ca.gradient(J, w_sym)
    H = ca.jacobian(g, w_sym)
    mask = ca.vertcat(_inside(model, w_sym[:n]), ca.DM.ones(ny))
    D = ca.diag(mask)
    H_free = ca.mtimes([D, H, D]) + ca.diag(1 - mask)
    step = -ca.mtimes(D, ca.solve(H_free, ca.mtimes(D, g)))
    trial = w_sym + step
    within = ca.MX(1)
    for i, (lo, hi) in enumerate(zip(model.lower_bounds, model.upper_bounds)):
        if np.isfinite(lo):
            within = within * (trial[i] >= lo)
        if np.isfinite(hi):
            within = within * (trial[i] <= hi)
    newton = ca.Function("two_stage_graph_newton", [w_sym, Xs, Zs], [ca.if_else(within, trial, w_sym)])
    covariance = ca.Function("two_stage_graph_covariance", [w_sym, Xs, Zs], [
        ca.mtimes([D, ca.inv(H_free), D])[:n, :n], ca.norm_inf(ca.mtimes(D, g)) / (1 + ca.fabs(J))])
    w = ca.vertcat(theta, ca.log(R))
    for _ in range(NEWTON_STEPS):
        w = newton(w, X, Z)
    cov, gradient = covariance(w, X, Z)
    finite = ca.logic_and(ca.sum1(ca.vertcat(w, ca.vec(cov))) == ca.sum1(ca.vertcat(w, ca.vec(cov))),
                          ca.fabs(ca.sum1(ca.vertcat(w, ca.vec(cov)))) < ca.inf)
    success = ca.logic_and(finite, gradient <= 1e-6)
    return w[:n], ca.exp(w[n:]), cov, success
