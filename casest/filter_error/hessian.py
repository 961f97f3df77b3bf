"""The exact Hessian of the time-varying filter-error likelihood by the adjoint of the filter.

The filter's state ``s_k = (x_k, vec P_k)`` (before sample k's update) moves as
``s_k+1 = F_k(s_k, p)`` and contributes ``V_k(s_k, p)`` (the step of
:func:`casest.filter_error.nlp.filter_error_step`), ``p = [theta; q; r]`` a function of
the decision vector w. With the adjoint ``lambda_N-1 = dV_N-1/ds``,
``lambda_k = d(V_k + lambda_k+1' F_k)/ds`` and ``Z_k = [ds_k/dw; dp/dw]`` (the compiled pass's
forward sensitivities, :mod:`casest.filter_error.sensitivities`), the Hessian of
``V = sum_k V_k`` is that of the Lagrangian on the null space of the recursion::

    H = sum_k Z_k' d2(V_k + lambda_k+1' F_k) Z_k + d2(lambda_0' x0(w)) + sum_i g_i d2 p_i(w)

with ``g`` the explicit partial derivatives of the Lagrangian in p (the last term carries the
curvature of w -> p, e.g. the exponential of ln q). Two compiled C loops over the record: the
backward pass for the adjoint and the per-sample curvature, ``n_w`` Hessian-vector products of
the step a sample. Equal to CasADi's Hessian of the record's graph to rounding.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from .._casadi.memory import StructureCache
from .._casadi.record_loop import RecordLoop
from ..models.dynamic import DynamicModel
from .sensitivities import FilterPassDerivatives

__all__ = ["FilterPassHessian", "filter_hessian_loops"]

_LOOPS = StructureCache()


def _lagrangian(one: ca.Function) -> tuple:
    """Symbols ``(s, p, lambda, d)`` and ``V_k + lambda' F_k`` of one step (SX)."""
    x, P, d, theta, q, r = one.sx_in()
    x_next, P_next, cost, _, _ = one(x, P, d, theta, q, r)
    lam = ca.SX.sym("lambda", x.numel() + P.numel())
    L = cost + ca.dot(lam, ca.vertcat(x_next, ca.vec(P_next)))
    return ca.vertcat(x, ca.vec(P)), ca.vertcat(theta, q, r), lam, d, L


def _adjoint_step(one: ca.Function) -> ca.Function:
    """``(lambda_k+1, [s_k; d_k], p) -> (lambda_k, dL_k/dp)``: one step of the backward pass."""
    s, p, lam, d, L = _lagrangian(one)
    row = ca.vertcat(s, d)
    return ca.Function("filter_adjoint_step", [lam, row, p], [ca.gradient(L, s), ca.gradient(L, p)])


def _curvature_step(one: ca.Function, n_w: int) -> ca.Function:
    """``(H, [s_k; vec ds_k/dw; lambda_k+1; d_k], [p; vec dp/dw]) -> H + Z_k' d2 L_k Z_k`` (MX: the
    Hessian-vector product of L_k mapped over the n_w directions)."""
    s, p, lam, d, L = _lagrangian(one)
    v = ca.vertcat(s, p)
    z = ca.SX.sym("z", v.numel())
    product = ca.Function("filter_curvature_direction", [s, p, lam, d, z],
                          [ca.cse(ca.jtimes(ca.gradient(L, v), v, z))])
    ns, n_p = s.numel(), p.numel()
    H = ca.MX.sym("H", n_w * n_w)
    row = ca.MX.sym("row", ns + ns * n_w + ns + d.numel())
    c = ca.MX.sym("c", n_p + n_p * n_w)
    s_k, ds, lam_next, d_k = ca.vertsplit(row, np.cumsum([0, ns, ns * n_w, ns, d.numel()]).tolist())
    p_k, dp = ca.vertsplit(c, [0, n_p, n_p + n_p * n_w])
    # the pass's accumulator holds vec dx/dw then vec dP/dw: each direction's [dx; dP] from both
    n = one.numel_in(0)
    dx, dP = ca.reshape(ds[:n * n_w], n, n_w), ca.reshape(ds[n * n_w:], n * n, n_w)
    Z = ca.vertcat(dx, dP, ca.reshape(dp, n_p, n_w))
    HZ = product.map(n_w)(s_k, p_k, lam_next, d_k, Z)
    return ca.Function("filter_curvature_sample", [H, row, c], [H + ca.vec(ca.mtimes(Z.T, HZ))])


def _last_terms(last: ca.Function) -> ca.Function:
    """``(s, [u; y; mask], [theta; r]) -> (dV/ds, dV/d[theta; r], d2V/d(s, theta, r)2)`` of the last
    sample's update (SX; it reads no process noise)."""
    x, P, u, y, m, theta, r = last.sx_in()
    cost, _, _ = last(x, P, u, y, m, theta, r)
    s, data, theta_r = ca.vertcat(x, ca.vec(P)), ca.vertcat(u, y, m), ca.vertcat(theta, r)
    return ca.Function("filter_last_terms", [s, data, theta_r],
                       [ca.gradient(cost, s), ca.gradient(cost, theta_r), ca.hessian(cost, ca.vertcat(s, theta_r))[0]])


def filter_hessian_loops(model: DynamicModel, steps: tuple, n_w: int):
    """The compiled backward and curvature loops of the time-varying filter (cached per model
    structure), or None without a compiler.

    Parameters
    ----------
    model : DynamicModel
    steps : tuple of casadi.Function
        :func:`casest.filter_error.nlp.filter_error_step`'s ``(step, last)``.
    n_w : int

    Returns
    -------
    tuple of (RecordLoop, RecordLoop, casadi.Function) or None
        The backward loop, the curvature loop and the last sample's terms.
    """
    cache = _LOOPS.setdefault(model, {})
    if n_w not in cache:
        one, last = steps
        n_p = one.numel_in(3) + one.numel_in(4) + one.numel_in(5)
        backward = RecordLoop.build(_adjoint_step(one), widths=(n_p,), optimisation=("-O1",))
        curvature = RecordLoop.build(_curvature_step(one, n_w), optimisation=("-O1",))
        cache[n_w] = (backward, curvature, _last_terms(last)) if backward and curvature else None
    return cache[n_w]


class FilterPassHessian:
    """The exact Hessian of the time-varying filter's V in w, by the adjoint of the filter.

    Parameters
    ----------
    derivatives : FilterPassDerivatives
        The compiled forward pass and its constants.
    w, p : casadi.MX
        The decision vector and the parameter vector.
    filter_pass : tuple
        ``(theta, q, r, x0, P0)`` as expressions of w and p
        (:class:`casest.filter_error.sensitivities.FilterPassDerivatives`).
    loops : tuple
        :func:`filter_hessian_loops`' result.
    """

    def __init__(self, derivatives: FilterPassDerivatives, w: ca.MX, p: ca.MX, filter_pass: tuple, loops: tuple):
        theta, q, r, x0, _ = filter_pass
        self._derivatives, (self._backward, self._curvature, self._last) = derivatives, loops
        lam, g = ca.MX.sym("lambda", x0.numel()), ca.MX.sym("g", theta.numel() + q.numel() + r.numel())
        self._initial = ca.Function("filter_initial_curvature", [w, p, lam], [ca.hessian(ca.dot(lam, x0), w)[0]])
        self._chain = ca.Function("filter_chain_curvature", [w, p, g],
                                  [ca.hessian(ca.dot(g, ca.vertcat(theta, q, r)), w)[0]])

    def __call__(self, w: np.ndarray, p: np.ndarray) -> np.ndarray:
        """The Hessian of V (not V / N) at ``w``, shape (n_w, n_w)."""
        run = self._derivatives.sensitivity_pass(w, p, keep_states=True)
        n, nw, states = run.n_states, self._derivatives.nw, run.states
        ns = n + n * n
        theta_size, q_size, _ = run.sizes
        without_q = np.s_[theta_size:theta_size + q_size]  # the last sample's update reads no process noise
        lam_last, g_last, H_last = (np.asarray(ca.densify(v), dtype=float)
                                    for v in self._last(states[-1, :ns], run.last, np.delete(run.values, without_q)))
        # the backward pass over the reversed steps: lambda_N-2 ... lambda_0, and dL_k/dp
        back_rows = np.hstack([states[:-1, :ns], run.rows])[::-1]
        lambdas, (g_steps,) = self._backward(lam_last.ravel(), back_rows, run.values)
        lambdas = lambdas[::-1]  # lambda_0 ... lambda_N-1
        g = g_steps.sum(axis=0)
        g[:theta_size] += g_last.ravel()[:theta_size]
        g[theta_size + q_size:] += g_last.ravel()[theta_size:]
        curvature_rows = np.hstack([states[:-1], lambdas[1:], run.rows])
        c = np.concatenate([run.values, run.dvalues.reshape(-1, order="F")])
        H_steps, _ = self._curvature(np.zeros(nw * nw), curvature_rows, c, keep_accumulators=False)
        H = H_steps[0].reshape(nw, nw, order="F")
        _, _, dx, dP = run.state(-1)
        Z_last = np.vstack([dx, dP, np.delete(run.dvalues, without_q, axis=0)])
        H = H + Z_last.T @ H_last @ Z_last
        H = H + np.asarray(self._initial(w, p, lambdas[0, :n])) + np.asarray(self._chain(w, p, g))
        return 0.5 * (H + H.T)
