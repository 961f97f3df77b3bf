"""The exact Hessian of output error by the adjoint of the simulation (the reduced Hessian).

With the discretised states ``x_k+1 = F_k(x_k, theta)``, ``x_0 = x0(theta)``, the cost
``J(w) = sum_k l_k(x_k, w)``, the states' first-order sensitivities ``S_k = dx_k/dtheta_D``
and the adjoint ``lambda_N-1 = dl_N-1/dx``, ``lambda_k = dl_k/dx + F_x,k' lambda_k+1``, the
Hessian of J is that of the Lagrangian on the null space of the simulation,
``Z_k = [S_k; I]``::

    H = sum_k Z_k' d2 l_k Z_k + sum_k<N-1 Z_k' d2(lambda_k+1' F_k) Z_k + d2(lambda_0' x0)

(summary Sec. 5: output error's exact second derivatives). Per sample it costs ``n_D``
Hessian-vector products of ``lambda' F`` (forward over reverse) where the states' second-order
sensitivities cost ``n_D^2`` second directional derivatives of F, and its compiled bodies
are a few times the size of one step, not ``n_D`` times.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from .._casadi.numerics import available_cores, compile_function, prefetch_compile
from ..models.dynamic import DynamicModel
from .sums import map_sum


__all__ = ["adjoint_hessian", "curvature_direction"]


def _rhs_parameters(model: DynamicModel, D: list, theta_D):
    """The step's ``theta_rhs`` from the dynamic parameters ``theta_D`` (positions ``D``)."""
    positions = [D.index(i) for i in model.rhs_parameter_index]
    return ca.vertcat(*[theta_D[k] for k in positions]) if positions else ca.SX(0, 1)


def _step_symbols(model: DynamicModel, nD: int) -> tuple:
    n_step_u = model.step_function.size1_in(1)  # 2 n_u for cubic interpolation
    return (ca.SX.sym("x", model.n_states), ca.SX.sym("uk", n_step_u), ca.SX.sym("uk1", n_step_u), ca.SX.sym("dt"),
            ca.SX.sym("theta_D", nD))


def curvature_direction(model: DynamicModel, D: list) -> ca.Function:
    """``(x, S, lambda, u_k, u_k+1, dt, theta_D, e) -> Z' d2(lambda' F) Z e``, one column of a step's term.

    Parameters
    ----------
    model : DynamicModel
    D : list of int
        Positions of the dynamic parameters (:func:`casest.backend.output_error.dynamic_indices`).

    Returns
    -------
    casadi.Function
        SX; ``x``, ``lambda``: (n_x,); ``S``: (n_x, n_D); ``e``: (n_D,), the direction in theta_D;
        output (n_D,).
    """
    nD = len(D)
    x, uk, uk1, dt, theta_D = _step_symbols(model, nD)
    S, lam, e = ca.SX.sym("S", model.n_states, nD), ca.SX.sym("lambda", model.n_states), ca.SX.sym("e", nD)
    v = ca.vertcat(x, theta_D)
    weighted = ca.dot(lam, model.step_function(x, uk, uk1, dt, _rhs_parameters(model, D, theta_D)))
    Hz = ca.jtimes(ca.gradient(weighted, v), v, ca.vertcat(ca.mtimes(S, e), e))
    out = ca.mtimes(S.T, Hz[:model.n_states]) + Hz[model.n_states:]
    return ca.Function("oe_curvature_direction", [x, S, lam, uk, uk1, dt, theta_D, e], [ca.cse(out)],
                       ["x", "S", "lambda", "uk", "uk1", "dt", "theta_D", "e"], ["Hz"])


def _adjoint_step(model: DynamicModel, D: list) -> ca.Function:
    """``(lambda_k+1, x_k, u_k, u_k+1, dt, theta_D, dl_k/dx) -> lambda_k``."""
    x, uk, uk1, dt, theta_D = _step_symbols(model, len(D))
    lam, l_x = ca.SX.sym("lambda", model.n_states), ca.SX.sym("l_x", model.n_states)
    F = model.step_function(x, uk, uk1, dt, _rhs_parameters(model, D, theta_D))
    return ca.Function("oe_adjoint_step", [lam, x, uk, uk1, dt, theta_D, l_x], [l_x + ca.jtimes(F, x, lam, True)])


def _sample_functions(model: DynamicModel, D: list, per_sample: ca.Function, n_w: int) -> tuple:
    """``(x, u, z, w) -> dl/dx`` and ``([x; vec S], u, z, w) -> triu(Z' d2 l Z)`` of one sample's cost."""
    nx, nD, nu = model.n_states, len(D), len(model.inputs)
    x, u, z, w = (ca.SX.sym("x", nx), ca.SX.sym("u", nu), ca.SX.sym("z", per_sample.size1_in(1)),
                  ca.SX.sym("w", n_w))
    state_gradient = ca.Function("oe_state_gradient", [x, u, z, w],
                                 [ca.gradient(per_sample(ca.vertcat(x, u), z, w), x)])
    a1, delta = ca.SX.sym("aug", nx + nx * nD), ca.SX.sym("delta", n_w)
    S = ca.reshape(a1[nx:], nx, nD)
    states = a1[:nx] + (ca.mtimes(S, ca.vertcat(*[delta[i] for i in D])) if nD else 0)
    f = per_sample(ca.vertcat(states, u), z, w + delta)
    H = ca.substitute(ca.triu(ca.hessian(f, delta)[0]), delta, ca.DM.zeros(n_w))
    return state_gradient, ca.Function("oe_sample_curvature", [a1, u, z, w], [ca.cse(H)])


#: samples per block of the Hessian's sums (a map of an uncompiled SX body builds in time and
#: memory growing with its length)
_BLOCK = 64


def _threads(n_terms: int) -> int:
    """Threads for the Hessian's sums: one per core from 256 terms a thread (each term costs tens of
    microseconds, where the cost's terms cost tens of nanoseconds)."""
    return int(max(1, min(available_cores(), n_terms // 256)))


def _selection(rows: list, n: int) -> ca.DM:
    """The (len(rows), n) matrix that picks ``rows`` out of an n-vector."""
    E = ca.DM(len(rows), n)
    for k, i in enumerate(rows):
        E[k, i] = 1
    return E


def adjoint_hessian(model: DynamicModel, D: list, per_sample: ca.Function, A1, w, Tm, Um, Zm, d0m,
                    jit: bool = False, jit_flags=("-O1",)) -> ca.MX:
    """The exact Hessian of ``sum_k per_sample([x_k; u_k], z_k, w)`` with respect to w (MX).

    Parameters
    ----------
    model : DynamicModel
        An RK4 model (its ``step_function``).
    D : list of int
        Positions of the dynamic parameters.
    per_sample : casadi.Function
        ``([x; u], z, w) -> l`` (:func:`casest.backend.sums.per_sample_cost`).
    A1 : casadi.MX, shape (n_x + n_x n_D, N)
        The states and their first-order sensitivities at every sample
        (:func:`casest.backend.output_error.simulate_jets`, order 1).
    w : casadi.MX, shape (n_w,)
        ``[theta; noise block]``, physical theta.
    Tm, Um, Zm, d0m : casadi.MX
        The record's views (:func:`casest.backend.output_error.dynamic_data_views`).
    jit : bool
        Compile the per-sample bodies to C.
    jit_flags : tuple of str

    Returns
    -------
    casadi.MX, shape (n_w, n_w)
        The Hessian, symmetric and dense.
    """
    nx, nD, N, n_w = model.n_states, len(D), Tm.numel(), w.numel()
    state_gradient, sample_curvature = _sample_functions(model, D, per_sample, n_w)
    H = ca.MX(map_sum(sample_curvature, N, _threads(N), n_data=3, block=_BLOCK)(A1, Um, Zm, w))
    H = H + H.T - ca.diag(ca.diag(H))
    if not nD:
        return H
    if jit:
        state_gradient = compile_function(state_gradient, jit_flags)
    # splits keep offsets; a slice A1[:, a:b] would hold an index per entry of the jets
    X, theta = ca.vertsplit(A1, [0, nx, A1.size1()])[0], w[:model.n_parameters]
    theta_D = ca.vertcat(*[theta[i] for i in D])
    L_x = state_gradient.map("oe_state_gradients", "serial", N, [3], [])(X, Um, Zm, w)
    lambdas = _adjoints(model, D, X, L_x, theta_D, Tm, Um, jit, jit_flags)
    if N > 1:
        E_D = _selection(D, n_w)
        H = H + ca.mtimes([E_D.T, _steps_term(model, D, A1, lambdas, theta_D, Tm, Um, jit, jit_flags), E_D])
    lam0, th, d0 = ca.SX.sym("lambda", nx), ca.SX.sym("theta", model.n_parameters), ca.SX.sym("x0_data", d0m.numel())
    initial = ca.Function("oe_initial_curvature", [lam0, th, d0],
                          [ca.hessian(ca.dot(lam0, model.initial_function(th, d0)), th)[0]])
    E_theta = _selection(list(range(model.n_parameters)), n_w)
    return H + ca.mtimes([E_theta.T, initial(lambdas[:, 0], theta, d0m), E_theta])


def _intervals(model: DynamicModel, Tm, Um) -> tuple:
    """The step's inputs ``(u_k, u_k+1, dt)`` for the record's N - 1 intervals."""
    N = Tm.numel()
    T0, T1 = ca.horzsplit(Tm, [0, N - 1, N])[0], ca.horzsplit(Tm, [0, 1, N])[1]
    Ua, Ub = model.interval_inputs(Um)
    return Ua, Ub, T1 - T0


def _adjoints(model: DynamicModel, D: list, X, L_x, theta_D, Tm, Um, jit: bool, jit_flags):
    """``[lambda_0 ... lambda_N-1]`` (n_x, N): the backward pass, one ``mapaccum`` over the reversed record."""
    N = Tm.numel()
    if N == 1:
        return L_x
    step = _adjoint_step(model, D)
    if jit:
        step = compile_function(step, jit_flags)
    back = list(range(N - 2, -1, -1))
    Ua, Ub, dt = _intervals(model, Tm, Um)
    earlier = step.mapaccum("oe_adjoints", N - 1)(L_x[:, N - 1], X[:, back], Ua[:, back], Ub[:, back], dt[:, back],
                                                  ca.repmat(theta_D, 1, N - 1), L_x[:, back])
    return ca.horzcat(earlier[:, back], L_x[:, N - 1])


def _steps_term(model: DynamicModel, D: list, A1, lambdas, theta_D, Tm, Um, jit: bool, jit_flags):
    """``sum_k<N-1 Z_k' d2(lambda_k+1' F_k) Z_k`` (n_D, n_D): per interval, the curvature direction
    mapped over the n_D unit directions, summed over the intervals."""
    nx, nD, N = model.n_states, len(D), Tm.numel()
    direction = curvature_direction(model, D)
    if jit:
        direction = compile_function(direction, jit_flags)
    a1, lam = ca.MX.sym("aug", nx + nx * nD), ca.MX.sym("lambda", nx)
    uk, uk1, dt = (ca.MX.sym(name, direction.size1_in(k)) for k, name in ((3, "uk"), (4, "uk1"), (5, "dt")))
    th = ca.MX.sym("theta_D", nD)
    columns = direction.map(nD)(a1[:nx], ca.reshape(a1[nx:], nx, nD), lam, uk, uk1, dt, th, ca.DM.eye(nD))
    interval = ca.Function("oe_step_curvature", [a1, lam, uk, uk1, dt, th], [columns])
    Ua, Ub, dts = _intervals(model, Tm, Um)
    return map_sum(interval, N - 1, _threads(N - 1), n_data=5, block=_BLOCK)(ca.horzsplit(A1, [0, N - 1, N])[0], ca.horzsplit(lambdas, [0, 1, N])[1], Ua, Ub,
                                                                           dts, theta_D)
