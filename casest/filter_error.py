"""Filter-error maximum likelihood: parameters (and process-noise intensities) from the
prediction errors of an extended Kalman filter (reference summary Sec. 5, Eq. 5.3-5.7).

Output error assumes deterministic states; with process noise (turbulence) the states
wander away from any simulation, and where the inputs respond to the noise (a pilot or a
controller in the loop) the output-error estimates are biased. Filter error instead
minimises the negative log-likelihood of the filter's one-step prediction errors::

    V(theta, q, R) = 1/2 sum_k [ e_k' S_k^-1 e_k + ln det S_k ]              (Eq. 5.7)
    e_k = y_k - h(x(k|k-1), u_k, theta),   S_k = H P(k|k-1) H' + R

with the filter of :class:`casest.ExtendedKalmanFilter` (the same step, Jacobians and
discretisation) written as one CasADi recursion, so that IPOPT gets the exact gradient and
Hessian through the filter. Missing channels (NaN) drop out of e_k and S_k. Decision
variables: the model's parameters (box-bounded, scaled), the logarithms of the estimated
process-noise intensities and of the measurement-noise variances R (diagonal).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import casadi as ca
import numpy as np

from .data import Dataset
from .dynamic import DynamicModel
from .filters import ExtendedKalmanFilter, FilterResult, ekf_step_functions, process_noise_matrix
from .model import ModelError, OptionError

__all__ = ["FilterErrorEstimate", "filter_error_estimate", "filter_error_cost"]

LOG_2PI = float(np.log(2.0 * np.pi))


@dataclass
class FilterErrorEstimate:
    """Result of :func:`filter_error_estimate`.

    Attributes
    ----------
    parameter_names : tuple of str
    theta : ndarray, shape (n_parameters,)
    std : ndarray, shape (n_parameters,)
        From the inverse of the exact Hessian of V (NaN on an active bound).
    process_noise : dict
        State name -> intensity (estimated or fixed).
    process_noise_std : dict
        State name -> std of the intensity (estimated ones only).
    R, R_std : ndarray, shape (n_outputs,)
    covariance : ndarray
        Of all decision variables in natural units (theta, estimated intensities, R).
    cost : float
        V at the optimum (Eq. 5.7 without constants).
    log_likelihood : float
        ln p(y) with the constants.
    success : bool
    status : str
        IPOPT's return status.
    n_iterations : int
    seconds : float
    filter : FilterResult
        The EKF pass at the optimum (states, covariances, innovations).
    notes : list of str
    """

    parameter_names: tuple
    theta: np.ndarray
    std: np.ndarray
    process_noise: dict
    process_noise_std: dict
    R: np.ndarray
    R_std: np.ndarray
    covariance: np.ndarray
    cost: float
    log_likelihood: float
    success: bool
    status: str
    n_iterations: int
    seconds: float
    filter: FilterResult | None = field(default=None, repr=False)
    notes: list = field(default_factory=list)

    @property
    def values(self) -> dict:
        return dict(zip(self.parameter_names, self.theta.tolist()))

    @property
    def stds(self) -> dict:
        return dict(zip(self.parameter_names, self.std.tolist()))

    def report(self) -> str:
        lines = [f"filter-error ML: success {self.success} ({self.status}), {self.n_iterations} iterations, "
                 f"{self.seconds:.2f} s, V = {self.cost:.10g}"]
        for n, v, s in zip(self.parameter_names, self.theta, self.std):
            lines.append(f"  {n:>14s} = {v:.6g} (std {s:.2g})")
        for n, v in self.process_noise.items():
            s = self.process_noise_std.get(n)
            lines.append(f"  q[{n}] = {v:.6g}" + ("" if s is None else f" (std {s:.2g})"))
        lines.append("  R = " + ", ".join(f"{v:.4g} (std {s:.2g})" for v, s in zip(self.R, self.R_std)))
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)


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


def _filter_step(model: DynamicModel) -> tuple[ca.Function, ca.Function]:
    """One EKF sample as SX: (x-, P-, d_k, theta, q, r) -> (x- next, P- next, V_k), and the
    last sample's update alone: (x-, P-, u, y, mask, theta, r) -> V_k.

    ``d_k`` = [u_a; u_b; dt; u_k; y_k (0 where missing); mask_k].
    """
    cache = model.__dict__.setdefault("_ekf_cache", {})
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
    last = ca.Function("filter_error_last", [x, P, u, y, m, theta, r], [cost])
    ua, ub, dt = ca.SX.sym("u_a", nuk), ca.SX.sym("u_b", nuk), ca.SX.sym("dt")
    x_next, P_next, _ = propagate(x_post, P_post, ua, ub, dt, theta, ca.diag(q), u, ca.SX.zeros(nu))
    P_next = 0.5 * (P_next + P_next.T)
    d = ca.vertcat(ua, ub, dt, u, y, m)
    one = ca.Function("filter_error_step", [x, P, d, theta, q, r], [x_next, P_next, cost])
    cache["filter_error_step"], cache["filter_error_last"] = one, last
    return one, last


def _record_columns(model: DynamicModel, data: Dataset) -> tuple[np.ndarray, np.ndarray]:
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


def _cost_graph(model: DynamicModel, N: int, P0: np.ndarray):
    """Symbols (theta, q, r, D, last, d0) and the expression of V over N samples."""
    one, last_fn = _filter_step(model)
    n, nu, ny = model.n_states, len(model.inputs), model.n_outputs
    theta, q, r = ca.MX.sym("theta", model.n_parameters), ca.MX.sym("q", n), ca.MX.sym("r", ny)
    nd = one.size1_in(2)
    D, last = ca.MX.sym("D", nd, max(N - 1, 1)), ca.MX.sym("last", nu + 2 * ny)
    d0 = ca.MX.sym("x0_data", len(model.initial_from_data))
    x0 = model.initial_function(theta, d0)
    acc = ca.MX.sym("acc", n + n * n + 1)
    dk = ca.MX.sym("d", nd)
    th_s, q_s, r_s = ca.MX.sym("th", model.n_parameters), ca.MX.sym("qs", n), ca.MX.sym("rs", ny)
    xn, Pn, Vk = one(acc[:n], ca.reshape(acc[n:n + n * n], n, n), dk, th_s, q_s, r_s)
    advance = ca.Function("filter_error_advance", [acc, dk, th_s, q_s, r_s],
                          [ca.vertcat(xn, ca.vec(Pn), acc[-1] + Vk)])
    start = ca.vertcat(x0, ca.vec(ca.DM(P0)), 0)
    if N > 1:
        # fold over the samples: the parameters ride along as non-accumulated inputs
        run = advance.mapaccum("filter_error_run", N - 1)
        final = run(start, D, ca.repmat(theta, 1, N - 1), ca.repmat(q, 1, N - 1), ca.repmat(r, 1, N - 1))[:, -1]
    else:
        final = start
    xN, PN = final[:n], ca.reshape(final[n:n + n * n], n, n)
    V = final[-1] + last_fn(xN, PN, last[:nu], last[nu:nu + ny], last[nu + ny:], theta, r)
    return (theta, q, r, D, last, d0), V


def filter_error_cost(model: DynamicModel, data: Dataset, theta, process_noise, R, P0=None) -> float:
    """V of Eq. 5.7 (no constants) at given parameters, intensities and R, by the symbolic recursion.

    Parameters
    ----------
    process_noise : mapping or array_like (n_states,)
        Continuous intensities per state.
    R : array_like, shape (n_outputs,)
    P0 : array_like, shape (n_states, n_states), optional
        Initial state covariance (default zero: x0 known).
    """
    model.check_data(data)
    n = model.n_states
    q = _intensity_vector(model, process_noise)
    P0 = np.zeros((n, n)) if P0 is None else np.asarray(P0, dtype=float).reshape(n, n)
    syms, V = _cost_graph(model, data.n_samples, P0)
    D, last = _record_columns(model, data)
    th = model.vector(theta) if isinstance(theta, Mapping) else np.asarray(theta, dtype=float)
    f = ca.Function("V", list(syms), [V])
    return float(f(th, q, np.asarray(R, dtype=float), D, last, model.initial_values(data)))


def _intensity_vector(model: DynamicModel, process_noise) -> np.ndarray:
    """Per-state intensities, shape (n_states,), from a mapping or a vector (diagonal noise only)."""
    Q = process_noise_matrix(model, process_noise)
    if np.any(Q != np.diag(np.diag(Q))):
        raise ValueError("filter-error ML estimates independent intensities per state: give a mapping or a vector")
    return np.diag(Q).copy()


def filter_error_estimate(
    model: DynamicModel,
    data: Dataset,
    process_noise: Mapping[str, float],
    *,
    estimate_process_noise: bool = True,
    R=None,
    start: Mapping[str, float] | np.ndarray | None = None,
    P0=None,
    max_iter: int = 300,
    tol: float = 1e-10,
    print_level: int = 0,
) -> FilterErrorEstimate:
    """Filter-error maximum likelihood (summary Sec. 5) on a dynamic model with process noise.

    Parameters
    ----------
    model : DynamicModel
        Integrator ``"rk4"``; every parameter is estimated within its bounds.
    data : Dataset
        The model's record (time, inputs, outputs; NaN outputs are missing).
    process_noise : mapping state name -> intensity
        The states that receive continuous white process noise on their rhs and the
        intensity (state-rate units squared per hertz): the start when
        ``estimate_process_noise``, else fixed. States not named get none.
    estimate_process_noise : bool
        Estimate the named intensities (default) or hold them.
    R : array_like, shape (n_outputs,), optional
        Known measurement-noise variances; default: estimated.
    start : mapping or array_like, optional
        Parameter start (default the model's nominal values).
    P0 : array_like, shape (n_states, n_states), optional
        Initial-state covariance (default zero: the initial state is known or a parameter).
    max_iter, tol, print_level
        IPOPT's settings (tol on V / N).

    Returns
    -------
    FilterErrorEstimate
    """
    import time

    if not isinstance(model, DynamicModel):
        raise OptionError("filter_error_estimate needs a casest.DynamicModel")
    model.check_data(data)
    t0 = time.perf_counter()
    n, ny, N = model.n_states, model.n_outputs, data.n_samples
    q_start = _intensity_vector(model, process_noise)
    if np.any(q_start < 0) or not np.all(np.isfinite(q_start)):
        raise ValueError(f"process-noise intensities must be finite and >= 0, got {q_start.tolist()}")
    noisy = np.flatnonzero(q_start > 0) if estimate_process_noise else np.array([], dtype=int)
    if estimate_process_noise and len(noisy) == 0:
        raise ValueError("give a positive starting intensity for each state whose process noise is estimated")
    P0 = np.zeros((n, n)) if P0 is None else np.asarray(P0, dtype=float).reshape(n, n)
    (theta, q, r, D, last, d0), V = _cost_graph(model, N, P0)
    scales = model.scales
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
    estimate_R = R is None
    if estimate_R:
        diffs = np.array([np.var(np.diff(data.outputs[observed[:, j], j])) / 2 for j in range(ny)])
        r_start = np.maximum(diffs, 1e-12 * np.maximum(z_var, 1e-300))
    else:
        r_start = np.asarray(R, dtype=float).reshape(-1)
        if r_start.size != ny or np.any(r_start <= 0):
            raise ValueError(f"R must hold {ny} positive variances")
    # decision variables: theta / scale, ln q (estimated), ln r (estimated)
    w_theta = ca.MX.sym("w_theta", model.n_parameters)
    w_q = ca.MX.sym("w_q", len(noisy))
    w_r = ca.MX.sym("w_r", ny if estimate_R else 0)
    q_expr = ca.MX(q_start)
    if len(noisy):
        parts = [ca.exp(w_q[list(noisy).index(i)]) if i in noisy else ca.MX(q_start[i]) for i in range(n)]
        q_expr = ca.vertcat(*parts)
    r_expr = ca.exp(w_r) if estimate_R else ca.MX(r_start)
    V_w = ca.substitute([V], [theta, q, r], [w_theta * scales, q_expr, r_expr])[0]
    w = ca.vertcat(w_theta, w_q, w_r)
    p = ca.vertcat(ca.vec(D), last, d0)
    floor = np.log(np.maximum(1e-20 * np.maximum(z_var, 1e-300), 1e-300))
    w_lb = np.concatenate([lb / scales, np.log(q_start[noisy]) - 30, floor if estimate_R else []])
    w_ub = np.concatenate([ub / scales, np.log(q_start[noisy]) + 30, np.log(np.maximum(z_var, 1e-300)) + 10
                           if estimate_R else []])
    w0 = np.concatenate([theta0 / scales, np.log(q_start[noisy]), np.log(r_start) if estimate_R else []])
    solver = ca.nlpsol("filter_error", "ipopt", {"x": w, "f": V_w / N, "p": p},
                       {"ipopt.print_level": print_level, "print_time": False, "ipopt.tol": tol,
                        "ipopt.max_iter": max_iter, "ipopt.sb": "yes"})
    D_num, last_num = _record_columns(model, data)
    p_num = np.concatenate([D_num.reshape(-1, order="F"), last_num, model.initial_values(data)])
    sol = solver(x0=w0, lbx=w_lb, ubx=w_ub, p=p_num)
    stats = solver.stats()
    w_opt = np.asarray(sol["x"]).reshape(-1)
    hess = ca.Function("filter_error_hessian", [w, p], [ca.hessian(V_w, w)[0]])
    Hw = np.asarray(hess(w_opt, p_num))
    # natural units: theta = scale w, q = exp(w), r = exp(w)
    nat = np.concatenate([w_opt[:model.n_parameters] * scales, np.exp(w_opt[model.n_parameters:])])
    jac = np.concatenate([scales, nat[model.n_parameters:]])
    notes = []
    active = (np.abs(w_opt - w_lb) <= 1e-8 * np.maximum(1, np.abs(w_lb))) | (
        np.abs(w_opt - w_ub) <= 1e-8 * np.maximum(1, np.abs(w_ub)))
    cov_w = np.full_like(Hw, np.nan)
    free = ~active
    try:
        Hf = 0.5 * (Hw[np.ix_(free, free)] + Hw[np.ix_(free, free)].T)
        if np.linalg.eigvalsh(Hf)[0] <= 0:
            notes.append("the Hessian of V is not positive definite at the solution: the standard deviations are "
                         "not available (the parameters are not all identifiable from these data)")
        else:
            cov_w[np.ix_(free, free)] = np.linalg.inv(Hf)
    except np.linalg.LinAlgError:
        notes.append("the Hessian of V is singular at the solution: no standard deviations")
    if active.any():
        names = list(model.parameter_names) + [f"q[{model.state_names[i]}]" for i in noisy] + (
            [f"R[{o}]" for o in model.output_names] if estimate_R else [])
        notes.append(f"on a bound (no std): {[nm for nm, a in zip(names, active) if a]}")
    cov = cov_w * np.outer(jac, jac)
    std = np.sqrt(np.diag(cov))
    npar = model.n_parameters
    theta_opt = nat[:npar]
    q_opt = q_start.copy()
    q_opt[noisy] = nat[npar:npar + len(noisy)]
    R_opt = nat[npar + len(noisy):] if estimate_R else r_start
    R_std = std[npar + len(noisy):] if estimate_R else np.zeros(ny)
    status = str(stats.get("return_status", ""))
    success = bool(stats.get("success", False)) and np.all(np.isfinite(std[free]))
    if not stats.get("success", False):
        notes.append(f"IPOPT did not converge ({status}): the estimate is not a stationary point of V")
    ekf = ExtendedKalmanFilter(model, theta_opt, q_opt, R_opt, P0 if np.any(P0) else np.zeros((n, n)))
    result = ekf.filter(data)
    cost = float(sol["f"]) * N
    return FilterErrorEstimate(
        parameter_names=tuple(model.parameter_names), theta=theta_opt, std=std[:npar],
        process_noise={model.state_names[i]: float(q_opt[i]) for i in range(n) if q_opt[i] > 0},
        process_noise_std={model.state_names[i]: float(s) for i, s in zip(noisy, std[npar:npar + len(noisy)])},
        R=np.asarray(R_opt, dtype=float), R_std=np.asarray(R_std, dtype=float), covariance=cov, cost=cost,
        log_likelihood=result.log_likelihood, success=success, status=status,
        n_iterations=int(stats.get("iter_count", -1)), seconds=time.perf_counter() - t0, filter=result, notes=notes)
