"""Filter error as flight-test practice formulates it (Maine and Iliff, SIAM J. Appl. Math. 41,
1981; Jategaonkar, *Flight Vehicle System Identification*, Ch. 5): the innovation formulation.

The unknowns are the model's parameters theta and the process-noise distribution F (diagonal,
``F F' = Q_c`` on the named states); the measurement noise is not a decision variable. Instead
the *innovation* covariance R is estimated in closed form, ``R = sum e e' / N`` (as output error
estimates its R), and the relaxation alternates:

1. with R held, theta and F by IPOPT on ``1/2 sum e' R^-1 e``, subject to ``diag(K C) <= 1`` (the
   textbook's constraint that keeps ``G G' = R - C P C'`` a covariance);
2. R from the innovations at the new estimate;
3. F compensated for the change of R (Jategaonkar's Eq. 5.41):
   ``F_i <- F_i sum_j C_ji^2 R_old,jj^-1 sqrt(R_new,jj / R_old,jj) / sum_j C_ji^2 R_old,jj^-1``,

until ``J = 1/2 sum e' R^-1 e + N/2 ln det R`` and the estimate settle (1e-12 and 1e-9 relative). The gain is the steady-state one of the
model linearised once, at the first state and input, as the textbook's program does: ``P`` solves
the textbook's continuous Riccati equation ``A P + P A' - P C' R^-1 C P / dt + F F' = 0`` (Newton-
Kleinman steps from the discrete equation's solution), and ``K = P C' R^-1``. The states are propagated by the nonlinear model and
corrected by K. The std are the Cramer-Rao bounds of step 1 at the optimum (the inverse of
``sum de' R^-1 de``). The implied measurement noise ``G G' = R - C P C'`` is reported as R.
"""

from __future__ import annotations

import time

import casadi as ca
import numpy as np

from ..backend.ipopt import SolverSettings
from ..data.dataset import Dataset
from ..models.dynamic import DynamicModel
from ..status import Note, NoteCode, Outcome, StdReason
from .ekf_model import ekf_step_functions
from .filter_error_result import FilterErrorEstimate
from .steady_filter_error import steady_step, check_steady_data, reference_point, steady_record_columns

__all__ = ["innovation_gain", "innovation_estimate", "compensate_process_noise"]

#: relaxation rounds (R update, F compensation) before the estimate is reported as not settled
MAX_ROUNDS = 200
#: Riccati doublings (each squares the steps it stands for) of the discrete start
DOUBLINGS = 16
#: Newton-Kleinman steps on the continuous Riccati equation (quadratic convergence from the start)
NEWTON_STEPS = 8


def innovation_gain(model: DynamicModel) -> ca.Function:
    """``(theta, f, R_inv, x_ref, u_ref, dt) -> (K, P, C)``: the steady gain of the innovation
    formulation at the reference point (cached on the model).

    Parameters
    ----------
    model : DynamicModel

    Returns
    -------
    casadi.Function
        ``f``: the diagonal of F, shape (n_states,); ``R_inv``: the inverse innovation covariance.
    """
    cache = model.__dict__.setdefault("_ekf_cache", {})
    if "innovation_gain" in cache:
        return cache["innovation_gain"]
    propagate, measure = ekf_step_functions(model)
    n, nu, ny = model.n_states, len(model.inputs), model.n_outputs
    theta, f, Ri = ca.SX.sym("theta", model.n_parameters), ca.SX.sym("f", n), ca.SX.sym("R_inv", ny, ny)
    x_ref, u_ref, dt = ca.SX.sym("x_ref", n), ca.SX.sym("u_ref", nu), ca.SX.sym("dt")
    u_held = ca.repmat(u_ref, model.step_function.size1_in(1) // nu, 1) if nu else ca.SX(0, 1)
    _, Qd, Phi = propagate(x_ref, ca.SX.zeros(n, n), u_held, u_held, dt, theta, ca.diag(f**2), u_ref, ca.SX.zeros(nu))
    _, C = measure(x_ref, u_ref, theta)
    A, G, H = Phi.T, ca.mtimes([C.T, Ri, C]), Qd  # the discrete equation by doubling: the start of Newton's
    eye = ca.SX.eye(n)
    for _ in range(DOUBLINGS):
        W = eye + ca.mtimes(G, H)
        WA, WG = ca.solve(W, A), ca.solve(W, G)
        A, G, H = ca.mtimes(A, WA), G + ca.mtimes([A, WG, A.T]), H + ca.mtimes([A.T, H, WA])
        H = 0.5 * (H + H.T)
    # the textbook's continuous equation A P + P A' - P C' R^-1 C P / dt + F F' = 0 by Newton-Kleinman:
    # each step a Lyapunov equation (A - P M) X + X (A - P M)' = -(F F' + P M P), solved through kron
    Ac = ca.jacobian(model.rhs_function(x_ref, u_ref, theta), x_ref)
    M, FF = ca.mtimes([C.T, Ri, C]) / dt, ca.diag(f**2)
    P = H
    for _ in range(NEWTON_STEPS):
        closed = Ac - ca.mtimes(P, M)
        lyapunov = ca.kron(eye, closed) + ca.kron(closed, eye)
        P = ca.reshape(ca.solve(lyapunov, -ca.vec(FF + ca.mtimes([P, M, P]))), n, n)
        P = 0.5 * (P + P.T)
    H = P
    K = ca.mtimes([H, C.T, Ri])
    cache["innovation_gain"] = ca.Function("innovation_gain", [theta, f, Ri, x_ref, u_ref, dt], [K, H, C],
                                           ["theta", "f", "R_inv", "x_ref", "u_ref", "dt"], ["K", "P", "C"])
    return cache["innovation_gain"]


def compensate_process_noise(f: np.ndarray, C: np.ndarray, R_old: np.ndarray, R_new: np.ndarray) -> np.ndarray:
    """Jategaonkar's Eq. 5.41: F revised for the change of the innovation covariance.

    Parameters
    ----------
    f : ndarray, shape (n_states,)
        The diagonal of F before the revision.
    C : ndarray, shape (n_outputs, n_states)
        The linearised observation matrix.
    R_old, R_new : ndarray, shape (n_outputs, n_outputs)
        The innovation covariance before and after its update.

    Returns
    -------
    ndarray, shape (n_states,)
    """
    ri_old, ri_new = np.diag(np.linalg.inv(R_old)), np.diag(np.linalg.inv(R_new))
    weight = (C**2).T @ ri_old
    with np.errstate(invalid="ignore", divide="ignore"):
        factor = ((C**2).T @ (ri_old * np.sqrt(ri_old / ri_new))) / weight
    return np.where(weight > 0, f * factor, f)


class _Graph:
    """The cost, innovations and ``diag(K C)`` of the innovation formulation over one record."""

    def __init__(self, model: DynamicModel, data: Dataset, x_ref, u_ref, dt: float):
        n, ny, N = model.n_states, model.n_outputs, data.n_samples
        step, last_fn = steady_step(model)
        theta, f = ca.MX.sym("theta", model.n_parameters), ca.MX.sym("f", n)
        Ri = ca.MX.sym("R_inv", ny, ny)
        K, P, C = innovation_gain(model)(theta, f, Ri, ca.DM(x_ref), ca.DM(u_ref), dt)
        D, last = steady_record_columns(model, data)
        x0 = model.initial_function(theta, ca.DM(model.initial_values(data)))
        acc, dk = ca.MX.sym("acc", n + 1), ca.MX.sym("d", D.shape[0])
        th_s, K_s, Ri_s = ca.MX.sym("th", model.n_parameters), ca.MX.sym("K", n, ny), ca.MX.sym("Ri", ny, ny)
        xn, term, ek = step(acc[:n], dk, th_s, K_s, Ri_s)
        advance = ca.Function("innovation_advance", [acc, dk, th_s, K_s, Ri_s], [ca.vertcat(xn, acc[n] + term), ek])
        path, E = advance.mapaccum("innovation_run", N - 1)(ca.vertcat(x0, 0), ca.DM(D), ca.repmat(theta, 1, N - 1),
                                                              ca.repmat(K, 1, N - 1), ca.repmat(Ri, 1, N - 1))
        term_last, e_last = last_fn(path[:n, -1], ca.DM(last), theta, Ri)
        self.cost = path[n, -1] + term_last  # 1/2 sum e' R^-1 e
        self.E = ca.horzcat(E, e_last)
        self.theta, self.f, self.Ri, self.K, self.C, self.P = theta, f, Ri, K, C, P
        self.kc = ca.diag(ca.mtimes(K, C))
        self.functions = ca.Function("innovation_values", [theta, f, Ri], [self.cost, self.E, self.kc, C, P])


def innovation_estimate(model: DynamicModel, data: Dataset, process_noise: np.ndarray, noisy: list, theta0: np.ndarray,
                        settings: SolverSettings) -> FilterErrorEstimate:
    """The innovation formulation's relaxation (module docstring).

    Parameters
    ----------
    model : DynamicModel
    data : Dataset
        Uniformly sampled, complete outputs.
    process_noise : ndarray, shape (n_states,)
        Start of the intensities (F_i^2).
    noisy : list of int
        The states whose F is estimated.
    theta0 : ndarray, shape (n_parameters,)
    settings : SolverSettings
        IPOPT's (``max_iter``, ``tol``) for step 1.

    Returns
    -------
    FilterErrorEstimate
    """
    t0 = time.perf_counter()
    dt = check_steady_data(model, data)
    N, ny, n = data.n_samples, model.n_outputs, model.n_states
    x0 = np.asarray(model.initial_function(theta0, model.initial_values(data))).reshape(-1)
    x_ref, u_ref = reference_point(data, x0[None, :], first=True)
    graph = _Graph(model, data, x_ref, u_ref, dt)
    scale = model.scales
    npar = model.n_parameters
    w = ca.MX.sym("w", npar + len(noisy))
    f_fixed = np.sqrt(np.asarray(process_noise, dtype=float))
    f_expr = ca.vertcat(*[w[npar + noisy.index(i)] if i in noisy else f_fixed[i] for i in range(n)])
    substituted = ca.substitute([graph.cost, graph.kc], [graph.theta, graph.f],
                                [w[:npar] * ca.DM(scale), f_expr])
    solver = ca.nlpsol("innovation_filter_error", "ipopt",
                       {"x": w, "p": ca.vec(graph.Ri), "f": substituted[0] / N, "g": substituted[1]},
                       {**settings.nlpsol_options(), "ipopt.tol": settings.tol})
    lbw = np.concatenate([model.lower_bounds / scale, np.zeros(len(noisy))])
    ubw = np.concatenate([model.upper_bounds / scale, np.full(len(noisy), np.inf)])
    values = np.concatenate([theta0 / scale, f_fixed[noisy]])

    def evaluate(v, Ri):
        f = f_fixed.copy()
        f[noisy] = v[npar:]
        cost, E, kc, C, P = (np.asarray(x) for x in graph.functions(v[:npar] * scale, f, Ri))
        return float(cost.reshape(-1)[0]), E, kc.reshape(-1), C, P, f

    R = np.cov(data.outputs.T, bias=True).reshape(ny, ny)  # the start: the outputs' own spread
    _, E, *_ = evaluate(values, np.linalg.inv(R))
    R = E @ E.T / N
    iterations, J_prev, settled, status, previous = 0, np.inf, False, "", None
    for _ in range(MAX_ROUNDS):
        sol = solver(x0=values, p=np.linalg.inv(R).reshape(-1, order="F"), lbx=lbw, ubx=ubw, lbg=-np.inf, ubg=1.0)
        stats = solver.stats()
        iterations += int(stats.get("iter_count", 0))
        status = stats["return_status"]
        values = np.asarray(sol["x"]).reshape(-1)
        _, E, _, C, _, f = evaluate(values, np.linalg.inv(R))
        R_new = E @ E.T / N
        values[npar:] = compensate_process_noise(f, C, R, R_new)[noisy]
        J = 0.5 * N * ny + 0.5 * N * float(np.linalg.slogdet(R_new)[1])
        moved = np.max(np.abs(values - previous) / np.maximum(np.abs(values), 1e-8)) if previous is not None else np.inf
        R, previous = R_new, values.copy()
        if abs(J - J_prev) <= 1e-12 * max(1.0, abs(J)) and moved <= 1e-9:
            settled = True
            break
        J_prev = J
    return _result(model, data, graph, values, R, noisy, f_fixed, iterations, settled, status,
                   time.perf_counter() - t0)


def _result(model, data, graph, values, R, noisy, f_fixed, iterations, settled, status, seconds) -> FilterErrorEstimate:
    """The estimate with the Cramer-Rao bounds of step 1 and the implied measurement noise."""
    npar, scale, N = model.n_parameters, model.scales, data.n_samples
    f = f_fixed.copy()
    f[noisy] = values[npar:]
    Ri = np.linalg.inv(R)
    jac = ca.Function("innovation_jacobian", [graph.theta, graph.f, graph.Ri],
                      [ca.jacobian(ca.vec(graph.E), graph.theta), ca.jacobian(ca.vec(graph.E), graph.f), graph.C, graph.P])
    J_theta, J_f, C, P = (np.asarray(x) for x in jac(values[:npar] * scale, f, Ri))
    J = np.hstack([J_theta, J_f[:, noisy]])
    J = J.reshape(model.n_outputs, N, -1, order="F")  # rows of vec(E): output i of sample k at i + n_y k
    information = np.einsum("ikp,ij,jkq->pq", J, Ri, J)
    notes = [Note("innovation formulation: theta and F with the innovation covariance R in closed form, F compensated "
                  "after each update of R (Jategaonkar Eq. 5.41), diag(K C) <= 1; one gain from the model linearised "
                  "at the first state and input", NoteCode.NOISE_MODEL)]
    try:
        cov = np.linalg.inv(information)
        std_all = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    except np.linalg.LinAlgError:
        cov, std_all = np.full(information.shape, np.nan), np.full(information.shape[0], np.nan)
        notes.append(Note("the information matrix is singular: some parameters are not identifiable", NoteCode.OTHER))
    if not settled:
        notes.append(Note(f"the relaxation did not settle in {MAX_ROUNDS} rounds", NoteCode.NOT_VERIFIED))
    GG = R - C @ P @ C.T
    if np.any(np.diag(GG) < 0):
        notes.append(Note("the implied measurement noise R - C P C' has a negative variance: the process noise takes "
                          "more than the innovations hold", NoteCode.NOISE_FLOOR))
    success = settled and status in ("Solve_Succeeded", "Solved_To_Acceptable_Level") and bool(np.all(np.isfinite(std_all)))
    theta = values[:npar] * scale
    q = f**2
    return FilterErrorEstimate(
        model_name=model.name, parameter_names=tuple(model.parameter_names), theta=theta, std=std_all[:npar],
        std_reasons=["" if np.isfinite(s) else "singular information" for s in std_all[:npar]],
        std_reason_codes=[None if np.isfinite(s) else StdReason.SINGULAR for s in std_all[:npar]],
        active_bounds=[None] * npar, lower_bounds=model.lower_bounds, upper_bounds=model.upper_bounds,
        parameter_units=tuple(p.unit for p in model.parameters),
        process_noise={model.state_names[i]: float(q[i]) for i in range(model.n_states) if q[i] > 0},
        process_noise_std={model.state_names[i]: float(2 * f[i] * s) for i, s in zip(noisy, std_all[npar:])},
        output_names=tuple(model.output_names), output_units=tuple(model.output_units),
        R=np.diag(GG).copy(), R_std=np.zeros(model.n_outputs), R_estimated=True, covariance=cov,
        cost=0.5 * N * model.n_outputs + 0.5 * N * float(np.linalg.slogdet(R)[1]),
        log_likelihood=-0.5 * N * model.n_outputs * (1 + np.log(2 * np.pi)) - 0.5 * N * float(np.linalg.slogdet(R)[1]),
        success=success, status=status, outcome=Outcome.CONVERGED if success else Outcome.NOT_CONVERGED,
        n_iterations=iterations, n_samples=N, seconds=seconds, filter=None, notes=notes, formulation="innovation")
