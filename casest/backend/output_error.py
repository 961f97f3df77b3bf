"""Output error of a dynamic model: its ML cost through the simulated states, with exact
derivatives by forward sensitivities (summary Sec. 5, Eq. 5.7 with deterministic states;
paper Eq. 6 for the outputs).

:class:`OutputErrorSums` carries the first- and second-order sensitivities of the states
through the same RK4 step the simulation uses; :func:`dynamic_cost_expression` is the same
cost as a plain CasADi graph (CasADi's AD through the simulation, also for CVODES).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from .._casadi.numerics import StructureCache, compile_function
from ..models.dynamic import DynamicModel
from .linalg import n_cholesky
from .penalty import GaussianPenalty
from .sums import map_sum, per_sample_cost, symmetric


__all__ = ["OutputErrorSums", "output_error_sums", "dynamic_data_views", "dynamic_cost_expression"]


class OutputErrorSums:
    """Output-error J/N of a dynamic model, its gradient and exact Hessian, by forward sensitivities.

    The simulation carries the derivatives of the states with respect to the parameters of
    the dynamics (first order ``S = dx/dtheta_D`` for the gradient, and second order
    ``T = d2x/dtheta_D2`` for the Hessian): each interval's step is applied to the jet
    ``x + S d + d' T d / 2`` and differentiated symbolically (SX), one ``mapaccum`` over the
    samples. Each sample's cost (:func:`casest.sums.per_sample_cost` of the output equation)
    is differentiated the same way, with the jet of its states, and summed with a
    map-reduce. The result is the exact gradient and Hessian of the discretised cost, for
    RK4 models (a CVODES model uses CasADi's AD through the integrator). With ``jit`` the
    step and per-sample functions (small SX bodies) are compiled to C; the loops over the
    samples call them.

    Attributes
    ----------
    cost, gradient, hessian : casadi.Function
        ``(w, p) -> J/N``, ``(w, p) -> (J/N, dJ/dw / N)``, ``(w, p) -> triu(d2J/dw2) / N``
        with ``w = [theta / scale; noise vector]`` and ``p`` the data vector
        (:meth:`Problem.data_vector`).
    """

    def __init__(self, model: DynamicModel, n_samples: int, scale, masked: bool = False, full_noise: bool = False,
                 jit: bool = False, jit_flags=("-O1",)):
        N, n, ny, nu = n_samples, model.n_parameters, model.n_outputs, len(model.inputs)
        self.model, self.n_samples = model, N
        self._D = [i for i, name in enumerate(model.parameter_names) if name in model.dynamic_parameters]
        self._masked, self._full_noise = masked, full_noise
        self._jit, self._jit_flags = jit, tuple(jit_flags)
        n_noise = n_cholesky(ny) if full_noise else ny
        nz = 2 * ny if masked else ny
        p = ca.MX.sym("data", N + nu * N + nz * N + len(model.initial_from_data))
        Tm, Um, Zm, d0m = dynamic_data_views(model, N, masked, p)
        ws = ca.MX.sym("w", n + n_noise)
        scale_all = ca.DM(np.concatenate([np.asarray(scale, dtype=float), np.ones(n_noise)]))
        w_phys = ws * scale_all
        sums = []
        for order in (0, 1, 2):
            step, initial, per_sample = self._jet_functions(order)
            th = w_phys[:n]
            a0 = initial(th, d0m)
            if N > 1:
                T0, T1 = ca.horzsplit(Tm, [0, N - 1, N])[0], ca.horzsplit(Tm, [0, 1, N])[1]
                Ua, Ub = model.interval_inputs(Um)
                th_D = ca.vertcat(*[th[i] for i in self._D]) if self._D else ca.MX(0, 1)
                run = step.mapaccum(f"jet{order}_simulate", N - 1)
                A = ca.horzcat(a0, run(a0, Ua, Ub, T1 - T0, ca.repmat(th_D, 1, N - 1)))
            else:
                A = a0
            out = map_sum(per_sample, N, 1, f"oe{order}_sum")(ca.vertcat(A, Um), Zm, w_phys)
            sums.append(out if isinstance(out, (list, tuple)) else [out])
        (cost,), (value, grad), (hess,) = sums
        Ds = ca.diag(scale_all)
        grad = grad * scale_all
        hess = ca.triu(ca.mtimes(ca.mtimes(Ds, symmetric(hess)), Ds))
        self.cost = ca.Function("oe_cost", [ws, p], [cost / N], ["w", "p"], ["f"])
        self.gradient = ca.Function("oe_gradient", [ws, p], [value / N, grad / N], ["w", "p"], ["f", "g"])
        self.hessian = ca.Function("oe_hessian", [ws, p], [hess / N], ["w", "p"], ["H"])

    def _jet_functions(self, order: int) -> tuple:
        """The step, initial state and per-sample function with jets of ``order`` (0, 1 or 2)."""
        model, D = self.model, self._D
        n, nx, nu, ny = model.n_parameters, model.n_states, len(model.inputs), model.n_outputs
        nD = len(D) if order else 0
        n_noise = n_cholesky(ny) if self._full_noise else ny
        x, S = ca.SX.sym("x", nx), ca.SX.sym("S", nx, nD)
        T = ca.SX.sym("T", nx * nD * nD if order == 2 else 0)
        n_step_u = model.step_function.size1_in(1)  # 2 n_u for cubic interpolation
        uk, uk1, dt = ca.SX.sym("uk", n_step_u), ca.SX.sym("uk1", n_step_u), ca.SX.sym("dt")
        theta_D, d = ca.SX.sym("theta_D", len(D)), ca.SX.sym("d", nD)
        x_jet = _jet(x, S, T, d, nx, nD)
        rhs_pos = [D.index(i) for i in model.rhs_parameter_index]
        shifted = theta_D + d if nD else theta_D
        theta_rhs = ca.vertcat(*[shifted[k] for k in rhs_pos]) if rhs_pos else ca.SX(0, 1)
        x_next = model.step_function(x_jet, uk, uk1, dt, theta_rhs)
        aug = ca.vertcat(x, ca.vec(S), T)
        step = ca.Function(f"jet{order}_step", [aug, uk, uk1, dt, theta_D],
                           [ca.cse(_jet_coefficients(x_next, d, nx, nD, order))])
        theta, d0 = ca.SX.sym("theta", n), ca.SX.sym("x0_data", len(model.initial_from_data))
        shift = ca.SX.zeros(n)
        for k, i in enumerate(D[:nD]):
            shift[i] = d[k]
        initial = ca.Function(f"jet{order}_initial", [theta, d0],
                              [_jet_coefficients(model.initial_function(theta + shift, d0), d, nx, nD, order)])
        a_k, u_k = ca.SX.sym("aug", aug.numel()), ca.SX.sym("u", nu)
        z, w = ca.SX.sym("z", 2 * ny if self._masked else ny), ca.SX.sym("w", n + n_noise)
        f_i = per_sample_cost(model.output_model, self._masked, self._full_noise)
        names = ["s", "z", "w"]
        if order == 0:
            per_sample = ca.Function("oe0_i", [ca.vertcat(a_k, u_k), z, w], [f_i(ca.vertcat(a_k, u_k), z, w)], names,
                                     ["f"])
        else:
            delta = ca.SX.sym("delta", n + n_noise)
            xk, Sk = a_k[:nx], ca.reshape(a_k[nx:nx + nx * nD], nx, nD)
            Tk = a_k[nx + nx * nD:]
            states = _jet(xk, Sk, Tk, ca.vertcat(*[delta[i] for i in D]) if D else ca.SX(0, 1), nx, nD)
            f = f_i(ca.vertcat(states, u_k), z, w + delta)
            zero = ca.DM.zeros(n + n_noise)
            f0 = ca.substitute(f, delta, zero)
            if order == 1:
                g = ca.substitute(ca.gradient(f, delta), delta, zero)
                outputs, out_names = [f0, ca.cse(g)], ["f", "g"]
            else:
                outputs, out_names = [ca.cse(ca.substitute(ca.triu(ca.hessian(f, delta)[0]), delta, zero))], ["H"]
            per_sample = ca.Function(f"oe{order}_i", [ca.vertcat(a_k, u_k), z, w], outputs, names, out_names)
        if self._jit:  # the small SX bodies are compiled; the loops over samples call them
            step, per_sample = compile_function(step, self._jit_flags), compile_function(per_sample, self._jit_flags)
        return step, initial, per_sample


def _jet(x, S, T, d, nx: int, nD: int):
    """``x + S d + d' T_i d / 2`` per state (T stacked as nx blocks of nD x nD, or empty: first order)."""
    if nD == 0:
        return x
    out = x + ca.mtimes(S, d)
    if T.numel():
        quad = [ca.mtimes([d.T, ca.reshape(T[i * nD * nD:(i + 1) * nD * nD], nD, nD), d]) for i in range(nx)]
        out = out + 0.5 * ca.vertcat(*quad)
    return out


def _jet_coefficients(y, d, nx: int, nD: int, order: int):
    """``[y; vec(dy/dd); d2y_i/dd2 ...]`` at d = 0, up to ``order``: the jet of y in d."""
    if nD == 0 or order == 0:
        return ca.substitute(y, d, ca.DM.zeros(d.numel())) if d.numel() else y
    zero = ca.DM.zeros(nD)
    parts = [y, ca.vec(ca.jacobian(y, d))]
    if order == 2:
        parts += [ca.vec(ca.hessian(y[i], d)[0]) for i in range(nx)]
    return ca.substitute(ca.vertcat(*parts), d, zero)


_OE_SUMS = StructureCache()


def output_error_sums(model: DynamicModel, n_samples: int, scale=None, masked: bool = False,
                      full_noise: bool = False, jit: bool = False, jit_flags=("-O1",)) -> OutputErrorSums:
    """Cached :class:`OutputErrorSums` for (model, N, scale, masked, full noise, jit)."""
    scale = tuple(np.asarray(model.scales if scale is None else scale, dtype=float))
    key = (n_samples, scale, bool(masked), bool(full_noise), bool(jit), tuple(jit_flags))
    cache = _OE_SUMS.setdefault(model, {})
    if key not in cache:
        cache[key] = OutputErrorSums(model, n_samples, np.array(scale), masked, full_noise, jit, jit_flags)
    return cache[key]


def dynamic_data_views(model: DynamicModel, n_samples: int, masked: bool, p):
    """Views of a dynamic model's data vector ``[t; vec(U); vec(Z); x0_data]``: T (1 x N), U (n_u x N),
    Z (n_z x N; with ``masked`` [z; m]) and x0_data (offsets only, no N-long index vectors)."""
    N, nu = n_samples, len(model.inputs)
    nz = model.n_outputs * (2 if masked else 1)
    T, U, Z, d0 = ca.vertsplit(p, [0, N, N + nu * N, N + (nu + nz) * N, p.numel()])
    return ca.reshape(T, 1, N), ca.reshape(U, nu, N), ca.reshape(Z, nz, N), d0


def dynamic_cost_expression(model: DynamicModel, n_samples: int, theta, noise, p, masked: bool = False,
                            full_noise: bool = False, penalty: tuple | None = None) -> ca.MX:
    """Output-error J of a dynamic model as a CasADi expression (summary Sec. 5, Eq. 5.7 with
    deterministic states; paper Eq. 6 for the outputs).

    The states are simulated from theta (:meth:`DynamicModel.trajectory_symbols`) and the
    per-sample cost of :mod:`casest.sums` (the output equation's) is mapped over the
    samples. ``p`` is ``[t; vec(U); vec(Z); x0_data]`` (:meth:`Problem.data_vector`).
    """
    N = n_samples
    T, U, Z, d0 = dynamic_data_views(model, N, masked, p)
    X = model.trajectory_symbols(theta, d0, T, U)
    f_i = per_sample_cost(model.output_model, masked, full_noise)
    J = ca.sum2(f_i.map(N)(ca.vertcat(X, U), Z, ca.vertcat(theta, noise)))
    penalty = GaussianPenalty.coerce(penalty)
    return J if penalty is None else J + penalty.expression(theta)
