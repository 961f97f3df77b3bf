"""Filter-error ML with the steady-state Kalman gain (flight-test practice; summary Sec. 5).

The time-varying form (:mod:`casest.filter_error.estimator`) runs the extended Kalman filter
with its covariance P(k|k-1) over the record: the exact likelihood of the EKF's prediction
errors. Flight-test programs instead use one gain for the whole record: the system is
linearised at a reference point (state and input), giving Phi = d step / dx (the same RK4
step), C = dh/dx and the discrete process noise Q_d of the EKF's propagation (trapezoidal
Van Loan integral of the intensities), and the a-priori covariance P solves the algebraic
Riccati equation::

    P = Phi P Phi' - Phi P C' (C P C' + R)^-1 C P Phi' + Q_d,   S = C P C' + R,   K = P C' S^-1

The states are still propagated by the nonlinear model, corrected by the constant gain::

    e_k = y_k - h(x(k|k-1), u_k),   x(k|k) = x(k|k-1) + K e_k,   x(k+1|k) = step(x(k|k))
    V = 1/2 sum_k e_k' S^-1 e_k + N/2 ln det S

The Riccati equation is solved inside the CasADi graph by the structure-preserving doubling
algorithm (``DOUBLINGS`` doublings: 2^30 Riccati steps), so IPOPT differentiates V exactly
through the gain. Between solves the system is relinearised at the time-average of the
predicted states and inputs of the last solve (an outer loop that ends when V changes by
less than 1e-9 relative; a linear model needs one pass).

The two forms differ where P(k|k-1) is far from its steady state (the start of a record,
around missing samples) and where the system is far from the reference point: each
estimate is optimal for its own likelihood, and on records with strong process noise and a
nonlinear model they can differ by several std. The steady-state form needs a uniform
sampling interval and complete outputs.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from .._casadi.memory import StructureCache
from ..data.dataset import Dataset
from ..errors import DataError
from ..models.dynamic import DynamicModel
from ..filters.ekf_model import ekf_step_functions
from .scoring import InnovationGraph

__all__ = ["DOUBLINGS", "riccati_by_doubling", "doubling", "steady_cost_graph", "steady_state_gain", "reference_point",
           "steady_filter_error_cost", "steady_record_columns",
           "check_steady_data", "steady_step"]

#: doublings of the Riccati iteration (each squares the number of steps it stands for)
DOUBLINGS = 16

_FUNCTIONS = StructureCache()


def riccati_by_doubling(Phi, C, Qd, R, doublings: int = DOUBLINGS):
    """The stabilising a-priori covariance of the filter's algebraic Riccati equation.

    Structure-preserving doubling on the dual (control) form with ``A = Phi'``, ``B = C'``:
    ``A <- A W^-1 A``, ``G <- G + A W^-1 G A'``, ``H <- H + A' H W^-1 A`` with ``W = I + G H``
    from ``G = C' R^-1 C`` and ``H = Q_d``; H converges to P quadratically.

    Parameters
    ----------
    Phi : casadi.SX, shape (n, n)
    C : casadi.SX, shape (n_y, n)
    Qd : casadi.SX, shape (n, n)
    R : casadi.SX, shape (n_y,)
        Measurement-noise variances (diagonal R).

    Returns
    -------
    casadi.SX, shape (n, n)
    """
    return doubling(Phi.T, ca.mtimes([C.T, ca.diag(1 / R), C]), Qd, doublings)


def doubling(A, G, H, doublings: int = DOUBLINGS):
    """The structure-preserving doubling iteration from ``(A, G, H)``; its H converges to the
    stabilising solution of the Riccati equation (``A = Phi'``, ``G = C' R^-1 C``, ``H = Q_d``).

    Parameters
    ----------
    A, G, H : casadi.SX, shape (n, n)
    doublings : int

    Returns
    -------
    casadi.SX, shape (n, n)
    """
    eye = ca.SX.eye(A.size1())
    for _ in range(doublings):
        W = eye + ca.mtimes(G, H)
        WA, WG = ca.solve(W, A), ca.solve(W, G)
        A, G, H = ca.mtimes(A, WA), G + ca.mtimes([A, WG, A.T]), H + ca.mtimes([A.T, H, WA])
        H = 0.5 * (H + H.T)
    return H


def steady_state_gain(model: DynamicModel) -> ca.Function:
    """``(theta, q, r, x_ref, u_ref, dt) -> (K, S, P)``: the steady-state gain, innovation covariance
    and a-priori covariance of the model linearised at the reference state and input (held)."""
    cache = _FUNCTIONS.setdefault(model, {})
    if "steady_gain" in cache:
        return cache["steady_gain"]
    propagate, measure = ekf_step_functions(model)
    n, nu, ny = model.n_states, len(model.inputs), model.n_outputs
    theta, q, r = ca.SX.sym("theta", model.n_parameters), ca.SX.sym("q", n), ca.SX.sym("r", ny)
    x_ref, u_ref, dt = ca.SX.sym("x_ref", n), ca.SX.sym("u_ref", nu), ca.SX.sym("dt")
    n_step_u = model.step_function.size1_in(1)
    # the input held at u_ref (a cubic hold takes two samples on each side: all equal)
    u_held = ca.repmat(u_ref, n_step_u // nu, 1) if nu else ca.SX(0, 1)
    _, Qd, Phi = propagate(x_ref, ca.SX.zeros(n, n), u_held, u_held, dt, theta, ca.diag(q), u_ref, ca.SX.zeros(nu))
    _, C = measure(x_ref, u_ref, theta)
    P = riccati_by_doubling(Phi, C, Qd, r)
    S = ca.mtimes([C, P, C.T]) + ca.diag(r)
    S = 0.5 * (S + S.T)
    K = ca.mtimes(P, ca.solve(S, C).T)
    gain = ca.Function("steady_gain", [theta, q, r, x_ref, u_ref, dt], [K, S, P],
                       ["theta", "q", "r", "x_ref", "u_ref", "dt"], ["K", "S", "P"])
    cache["steady_gain"] = gain
    return gain


def steady_step(model: DynamicModel) -> tuple[ca.Function, ca.Function]:
    """One sample of the constant-gain filter, ``(x-, d_k, theta, K, S^-1) -> (x- next, e' S^-1 e / 2)``
    with ``d_k = [u_a; u_b; dt; u_k; y_k]``, and the last sample's term alone."""
    cache = _FUNCTIONS.setdefault(model, {})
    if "steady_step" in cache:
        return cache["steady_step"], cache["steady_last"]
    n, nu, ny = model.n_states, len(model.inputs), model.n_outputs
    nuk = model.step_function.size1_in(1)
    _, measure = ekf_step_functions(model)
    x, theta = ca.SX.sym("x", n), ca.SX.sym("theta", model.n_parameters)
    K, Sinv = ca.SX.sym("K", n, ny), ca.SX.sym("Sinv", ny, ny)
    ua, ub, dt, u, y = (ca.SX.sym(name, size) for name, size in (("u_a", nuk), ("u_b", nuk), ("dt", 1), ("u", nu),
                                                                  ("y", ny)))
    h, _ = measure(x, u, theta)
    e = y - h
    term = 0.5 * ca.mtimes([e.T, Sinv, e])
    th_rhs = ca.vertcat(*[theta[i] for i in model.rhs_parameter_index]) if model.rhs_parameter_index else ca.SX(0, 1)
    x_next = model.step_function(x + ca.mtimes(K, e), ua, ub, dt, th_rhs)
    d = ca.vertcat(ua, ub, dt, u, y)
    step = ca.Function("steady_filter_step", [x, d, theta, K, Sinv], [x_next, term, e])
    last = ca.Function("steady_filter_last", [x, ca.vertcat(u, y), theta, Sinv], [term, e])
    cache["steady_step"], cache["steady_last"] = step, last
    return step, last


def steady_cost_graph(model: DynamicModel, N: int):
    """The :class:`InnovationGraph` of the steady gain at an operating point over N samples (with
    the predicted states X, n_states x N).

    ``D`` holds the per-step data ``[u_a; u_b; dt; u_k; y_k]`` (n_d x N-1), ``last`` the last
    sample's ``[u; y]``; the operating point ``(x_ref, u_ref, dt)`` is the graph's ``point``.
    """
    step, last_fn = steady_step(model)
    gain = steady_state_gain(model)
    n, nu, ny = model.n_states, len(model.inputs), model.n_outputs
    theta, q, r = ca.MX.sym("theta", model.n_parameters), ca.MX.sym("q", n), ca.MX.sym("r", ny)
    nd = step.size1_in(1)
    D, last = ca.MX.sym("D", nd, max(N - 1, 1)), ca.MX.sym("last", nu + ny)
    d0 = ca.MX.sym("x0_data", len(model.initial_from_data))
    x_ref, u_ref, dt = ca.MX.sym("x_ref", n), ca.MX.sym("u_ref", nu), ca.MX.sym("dt")
    K, S, _ = gain(theta, q, r, x_ref, u_ref, dt)
    Sinv = ca.inv(S)
    x0 = model.initial_function(theta, d0)
    acc, dk = ca.MX.sym("acc", n + 1), ca.MX.sym("d", nd)
    th_s, K_s, Si_s = ca.MX.sym("th", model.n_parameters), ca.MX.sym("K", n, ny), ca.MX.sym("Si", ny, ny)
    xn, term, ek = step(acc[:n], dk, th_s, K_s, Si_s)
    advance = ca.Function("steady_advance", [acc, dk, th_s, K_s, Si_s], [ca.vertcat(xn, acc[n] + term), ek])
    start = ca.vertcat(x0, 0)
    if N > 1:
        run = advance.mapaccum("steady_filter_run", N - 1)
        path, E = run(start, D, ca.repmat(theta, 1, N - 1), ca.repmat(K, 1, N - 1), ca.repmat(Sinv, 1, N - 1))
        final, X = path[:, -1], ca.horzcat(x0, path[:n, :])
    else:
        final, X, E = start, x0, ca.MX(ny, 0)
    term, e_last = last_fn(final[:n], last, theta, Sinv)
    V = final[n] + term + 0.5 * N * ca.log(ca.det(S))
    return InnovationGraph((theta, q, r, D, last, d0), V, ca.horzcat(E, e_last), ca.vec(S), X, (x_ref, u_ref, dt),
                           (theta, K, x0) if N > 1 else ())


def check_steady_data(model: DynamicModel, data: Dataset) -> float:
    """The uniform sampling interval of a record fit for the steady-state form (complete outputs)."""
    if not np.all(np.isfinite(data.outputs)):
        raise DataError("the steady-state filter-error form needs complete outputs (one gain for every sample); "
                        "use formulation='time-varying' for records with missing samples")
    t = data.signals[:, 0]
    if t.size < 2:
        raise DataError("the steady-state filter-error form needs at least two samples")
    steps = np.diff(t)
    positive = steps[steps > 0]  # a new manoeuvre restarts with a zero-length interval
    dt = float(np.median(positive))
    if np.any(np.abs(positive - dt) > 1e-6 * dt):
        raise DataError(f"the steady-state filter-error form needs a uniform sampling interval (steps from "
                        f"{positive.min():g} to {positive.max():g} s); resample the record or use "
                        "formulation='time-varying'")
    return dt


def steady_record_columns(model: DynamicModel, data: Dataset) -> tuple[np.ndarray, np.ndarray]:
    """Per-step data D (n_d x N-1) and the last sample's [u; y] of the steady-state graph."""
    t, U, Y = data.signals[:, 0], data.signals[:, 1:], data.outputs
    Ua, Ub = model.interval_input_values(U)
    if data.n_samples > 1:
        D = np.hstack([Ua, Ub, np.diff(t)[:, None], U[:-1], Y[:-1]]).T
    else:
        D = np.zeros((2 * model.step_function.size1_in(1) + 1 + U.shape[1] + Y.shape[1], 1))
    return D, np.concatenate([U[-1], Y[-1]])


def reference_point(data: Dataset, states: np.ndarray, first: bool) -> tuple[np.ndarray, np.ndarray]:
    """The linearisation point: with ``first`` the first sample's state and input (the trim of the
    manoeuvre), else the time-average of ``states`` (N x n_states) and of the inputs."""
    U = data.signals[:, 1:]
    if first:
        return np.asarray(states[0], dtype=float), U[0].copy()
    return np.mean(states, axis=0), np.mean(U, axis=0)


def steady_filter_error_cost(model: DynamicModel, data: Dataset, theta, process_noise, R, x_ref=None,
                             u_ref=None) -> float:
    """V of the steady-state form (no constants) at given parameters, intensities and R.

    Parameters
    ----------
    model : DynamicModel
    data : Dataset
        Uniformly sampled, complete outputs.
    theta : array_like, shape (n_parameters,)
    process_noise : array_like, shape (n_states,)
        Continuous intensities per state.
    R : array_like, shape (n_outputs,)
    x_ref, u_ref : array_like, optional
        The linearisation point; default the initial state at theta and the first input.

    Returns
    -------
    float
    """
    dt = check_steady_data(model, data)
    theta = np.asarray(theta, dtype=float)
    if x_ref is None or u_ref is None:
        x0 = np.asarray(model.initial_function(theta, model.initial_values(data))).reshape(-1)
        ref_x, ref_u = reference_point(data, x0[None, :], first=True)
        x_ref = ref_x if x_ref is None else x_ref
        u_ref = ref_u if u_ref is None else u_ref
    graph = steady_cost_graph(model, data.n_samples)
    D, last = steady_record_columns(model, data)
    f = ca.Function("V_steady", list(graph.symbols) + list(graph.point), [graph.V])
    return float(f(theta, np.asarray(process_noise, dtype=float), np.asarray(R, dtype=float), D, last,
                   model.initial_values(data), np.asarray(x_ref, dtype=float), np.asarray(u_ref, dtype=float), dt))
