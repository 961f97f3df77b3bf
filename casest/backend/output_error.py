"""Output error of a dynamic model: its ML cost through the simulated states, with exact
derivatives by forward sensitivities (summary Sec. 5, Eq. 5.7 with deterministic states;
paper Eq. 6 for the outputs).

:class:`OutputErrorSums` carries the first-order sensitivities of the states through the
same RK4 step the simulation uses, and the adjoint of that simulation for the exact Hessian
(:mod:`casest.backend.second_order`); :func:`dynamic_cost_expression` is the same
cost as a plain CasADi graph (CasADi's AD through the simulation, also for CVODES).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from .._casadi.numerics import compile_function, prefetch_compile
from .._casadi.memory import StructureCache
from ..models.dynamic import DynamicModel
from ..models.priors import Signal
from ..models.static import Model
from .noise_terms import DIAGONAL, NoiseTerm
from .penalty import GaussianPenalty
from .second_order import adjoint_hessian, curvature_direction
from .sums import map_sum, per_sample_cost


__all__ = ["OutputErrorSums", "output_error_sums", "dynamic_data_views", "dynamic_cost_expression",
           "prefetch_second_order", "dynamic_indices", "sensitivity_flags", "prediction_model"]


class OutputErrorSums:
    """Output-error J/N of a dynamic model, its gradient and exact Hessian, by forward sensitivities.

    The simulation carries the derivatives of the states with respect to the parameters of
    the dynamics, ``S = dx/dtheta_D``: the RK4 step applied to the jet ``x + S d`` and
    differentiated symbolically (SX, :func:`state_jets`). Each sample's cost
    (:func:`casest.backend.sums.per_sample_cost` of the output equation) is differentiated with the
    jet of its states and summed with a map-reduce: the gradient. The Hessian adds to the
    per-sample curvature the curvature of the steps weighted by the adjoint of the
    simulation (:func:`casest.backend.second_order.adjoint_hessian`). The result is the exact
    gradient and Hessian of the discretised cost, for RK4 models (a CVODES model uses
    CasADi's AD through the integrator). With ``jit`` the steps and the small per-sample
    functions are compiled to C; the loops over the samples call them.

    Attributes
    ----------
    cost, gradient, hessian : casadi.Function
        ``(w, p) -> J/N``, ``(w, p) -> (J/N, dJ/dw / N)``, ``(w, p) -> triu(d2J/dw2) / N``
        with ``w = [theta / scale; noise vector]`` and ``p`` the data vector
        (:meth:`Problem.data_vector`).
    """

    def __init__(self, model: DynamicModel, n_samples: int, scale, masked: bool = False, noise: NoiseTerm = DIAGONAL,
                 jit: bool = False, jit_flags=("-O1",)):
        N, n, ny, nu = n_samples, model.n_parameters, model.n_outputs, len(model.inputs)
        self.model, self.n_samples = model, N
        self._D = dynamic_indices(model)
        self._masked, self._noise = masked, noise
        self._jit, self._jit_flags = jit, tuple(jit_flags)
        n_noise = noise.block_size(ny)
        nz = 2 * ny if masked else ny
        p = ca.MX.sym("data", N + nu * N + nz * N + len(model.initial_from_data))
        Tm, Um, Zm, d0m = dynamic_data_views(model, N, masked, p)
        ws = ca.MX.sym("w", n + n_noise)
        scale_all = ca.DM(np.concatenate([np.asarray(scale, dtype=float), np.ones(n_noise)]))
        w_phys = ws * scale_all
        step, initial, per_sample = self._jet_functions(0)
        X = simulate_jets(model, step, initial, self._D, w_phys[:n], Tm, Um, d0m, "jet0_simulate")
        cost = map_sum(per_sample, N, 1, "oe0_sum")(ca.vertcat(X, Um), Zm, w_phys)
        step, initial, per_sample = self._jet_functions(1)
        A1 = simulate_jets(model, step, initial, self._D, w_phys[:n], Tm, Um, d0m, "jet1_simulate")
        value, grad = map_sum(per_sample, N, 1, "oe1_sum")(ca.vertcat(A1, Um), Zm, w_phys)
        f_i = per_sample_cost(model.output_model, masked, noise)
        hess = adjoint_hessian(model, self._D, f_i, A1, w_phys, Tm, Um, Zm, d0m, jit, self._jit_flags)
        Ds = ca.diag(scale_all)
        grad = grad * scale_all
        hess = ca.triu(ca.mtimes(ca.mtimes(Ds, hess), Ds))
        self.cost = ca.Function("oe_cost", [ws, p], [cost / N], ["w", "p"], ["f"])
        self.gradient = ca.Function("oe_gradient", [ws, p], [value / N, grad / N], ["w", "p"], ["f", "g"])
        self.hessian = ca.Function("oe_hessian", [ws, p], [hess / N], ["w", "p"], ["H"])

    def _jet_functions(self, order: int) -> tuple:
        """The step, initial state and per-sample function with jets of ``order`` (0: the states'
        values and the cost; 1: also their sensitivities, and the cost's gradient)."""
        model, D = self.model, self._D
        n, nx, nu, ny = model.n_parameters, model.n_states, len(model.inputs), model.n_outputs
        nD = len(D) if order else 0
        n_noise = self._noise.block_size(ny)
        step, initial = state_jets(model, D, order, self._jit, self._jit_flags)
        a_k, u_k = ca.SX.sym("aug", step.size1_in(0)), ca.SX.sym("u", nu)
        z, w = ca.SX.sym("z", 2 * ny if self._masked else ny), ca.SX.sym("w", n + n_noise)
        f_i = per_sample_cost(model.output_model, self._masked, self._noise)
        names = ["s", "z", "w"]
        if order == 0:
            per_sample = ca.Function("oe0_i", [ca.vertcat(a_k, u_k), z, w], [f_i(ca.vertcat(a_k, u_k), z, w)], names,
                                     ["f"])
        else:
            delta = ca.SX.sym("delta", n + n_noise)
            states = _jet(a_k[:nx], ca.reshape(a_k[nx:], nx, nD), ca.vertcat(*[delta[i] for i in D]) if D
                          else ca.SX(0, 1), nD)
            f = f_i(ca.vertcat(states, u_k), z, w + delta)
            zero = ca.DM.zeros(n + n_noise)
            g = ca.substitute(ca.gradient(f, delta), delta, zero)
            per_sample = ca.Function("oe1_i", [ca.vertcat(a_k, u_k), z, w], [ca.substitute(f, delta, zero), ca.cse(g)],
                                     names, ["f", "g"])
        if self._jit:  # the small SX bodies are compiled; the loops over samples call them
            per_sample = compile_function(per_sample, self._jit_flags)
        return step, initial, per_sample


def dynamic_indices(model: DynamicModel) -> list:
    """Positions of the parameters of the dynamics (rhs and initial states): the columns of S."""
    return [i for i, name in enumerate(model.parameter_names) if name in model.dynamic_parameters]


def sensitivity_flags(jit_flags) -> tuple:
    """The compiler flags of the sensitivity bodies: ``-O2`` (casest's default) becomes ``-O1``, since
    these bodies are large and -O2 costs compile time for little speed; explicit flags are kept.
    Every compile of them goes through here, so a background compile and the foreground one agree."""
    flags = tuple(jit_flags)
    return ("-O1",) if flags == ("-O2",) else flags


def state_jets(model: DynamicModel, D: list, order: int, jit: bool = False, jit_flags=("-O1",)) -> tuple:
    """The step and the initial state of a dynamic model carrying the jets of its states.

    ``order`` 0: the states; 1: also ``S = dx/dtheta_D``. Returns ``(step, initial)``:
    ``step(aug_k, u_k, u_k+1, dt, theta_D) -> aug_k+1`` with ``aug = [x; vec(S)]`` and
    ``initial(theta, x0_data) -> aug_0`` (``theta_D``: the parameters at positions ``D``), SX
    Functions (the step compiled with ``jit``).
    """
    nx = model.n_states
    nD = len(D) if order else 0
    x, S = ca.SX.sym("x", nx), ca.SX.sym("S", nx, nD)
    n_step_u = model.step_function.size1_in(1)  # 2 n_u for cubic interpolation
    uk, uk1, dt = ca.SX.sym("uk", n_step_u), ca.SX.sym("uk1", n_step_u), ca.SX.sym("dt")
    theta_D, d = ca.SX.sym("theta_D", len(D)), ca.SX.sym("d", nD)
    x_jet = _jet(x, S, d, nD)
    rhs_pos = [D.index(i) for i in model.rhs_parameter_index]
    shifted = theta_D + d if nD else theta_D
    theta_rhs = ca.vertcat(*[shifted[k] for k in rhs_pos]) if rhs_pos else ca.SX(0, 1)
    x_next = model.step_function(x_jet, uk, uk1, dt, theta_rhs)
    step = ca.Function(f"jet{order}_step", [ca.vertcat(x, ca.vec(S)), uk, uk1, dt, theta_D],
                       [ca.cse(_jet_coefficients(x_next, d, nD))])
    theta, d0 = ca.SX.sym("theta", model.n_parameters), ca.SX.sym("x0_data", len(model.initial_from_data))
    shift = ca.SX.zeros(model.n_parameters)
    for k, i in enumerate(D[:nD]):
        shift[i] = d[k]
    initial = ca.Function(f"jet{order}_initial", [theta, d0],
                          [_jet_coefficients(model.initial_function(theta + shift, d0), d, nD)])
    if jit:
        step = compile_function(step, jit_flags)
    return step, initial


def prefetch_second_order(model: DynamicModel, jit_flags=("-O1",)) -> bool:
    """Start compiling the largest bodies of output error's exact Hessian in background processes:
    the first-order jet step and the steps' curvature direction
    (:func:`casest.backend.second_order.curvature_direction`).

    The exact Hessian (the covariance after Gauss-Newton, IPOPT's path) needs them; separate
    processes compile them into the compile cache while this one runs stage 1 and stage 2;
    :func:`compile_function` then waits for them and loads the libraries. Returns whether a
    compile was started (not when the model has no dynamic parameters or no compile cache is
    usable).
    """
    D = dynamic_indices(model)
    asked = _PREFETCHED.setdefault(model, set())
    if not D or tuple(jit_flags) in asked:  # once per model structure: building the bodies costs 0.1 s
        return False
    asked.add(tuple(jit_flags))
    step, _ = state_jets(model, D, 1)
    started = [prefetch_compile(f, jit_flags) for f in (step, curvature_direction(model, D))]
    return any(started)


def simulate_jets(model: DynamicModel, step, initial, D: list, theta, Tm, Um, d0m, name: str):
    """The jets of the states at every sample, ``[a_0 ... a_N-1]``: the initial jet, then ``step`` over the
    record's intervals, in chunks of about sqrt(N) intervals (:func:`_stepped_in_chunks`)."""
    N = Tm.numel()
    a0 = initial(theta, d0m)
    if N == 1:
        return a0
    T0, T1 = ca.horzsplit(Tm, [0, N - 1, N])[0], ca.horzsplit(Tm, [0, 1, N])[1]
    Ua, Ub = model.interval_inputs(Um)
    th_D = ca.vertcat(*[theta[i] for i in D]) if D else ca.MX(0, 1)
    return ca.horzcat(a0, _stepped_in_chunks(step, name, a0, [Ua, Ub, T1 - T0], th_D))


def _stepped_in_chunks(step: ca.Function, name: str, a0, intervals: list, th_D):
    """``step`` from ``a0`` over the intervals' columns, every state after it: an outer ``mapaccum`` over
    chunks of about sqrt(n) steps of an inner one, each one level deep (CasADi's default, a tower
    of levels of 10, built the aircraft's 3000 steps of a 300-number jet in 0.21 s and 123 MB;
    this in 0.04 s and 34 MB, for 4 ms more a pass)."""
    n = intervals[0].size2()
    K = max(16, int(np.ceil(np.sqrt(n))))
    n_chunks, rest = divmod(n, K)
    flat = {"base": -1}
    if n_chunks <= 1:
        return step.mapaccum(name, n, flat)(a0, *intervals, ca.repmat(th_D, 1, n))
    a, th = ca.MX.sym("a", a0.size1()), ca.MX.sym("theta_D", th_D.size1())  # dense: as the steps make it
    parts = [ca.MX.sym(f"in{k}", v.size1(), K) for k, v in enumerate(intervals)]
    A = step.mapaccum(f"{name}_{K}", K, flat)(a, *parts, ca.repmat(th, 1, K))
    chunk = ca.Function(f"{name}_chunk_{K}", [a, *parts, th], [A[:, -1], A])
    split = [ca.horzsplit(v, [0, K * n_chunks, n])[0] for v in intervals] if rest else intervals
    ends, states = chunk.mapaccum(f"{name}_chunks", n_chunks, flat)(ca.densify(a0), *split,
                                                                    ca.repmat(th_D, 1, n_chunks))
    if not rest:
        return states
    tail = [ca.horzsplit(v, [0, K * n_chunks, n])[1] for v in intervals]
    return ca.horzcat(states, step.mapaccum(f"{name}_{rest}", rest, flat)(ends[:, -1], *tail,
                                                                          ca.repmat(th_D, 1, rest)))


def _jet(x, S, d, nD: int):
    """``x + S d``: the states' first-order jet (``x`` when there are no directions)."""
    return x + ca.mtimes(S, d) if nD else x


def _jet_coefficients(y, d, nD: int):
    """``[y; vec(dy/dd)]`` at d = 0: the first-order jet of y in d (``y`` without directions)."""
    if nD == 0:
        return ca.substitute(y, d, ca.DM.zeros(d.numel())) if d.numel() else y
    return ca.substitute(ca.vertcat(y, ca.vec(ca.jacobian(y, d))), d, ca.DM.zeros(nD))


_OE_SUMS = StructureCache()
_PREFETCHED = StructureCache()  # the flags each model structure's Hessian bodies were prefetched with


def output_error_sums(model: DynamicModel, n_samples: int, scale=None, masked: bool = False,
                      noise: NoiseTerm = DIAGONAL, jit: bool = False, jit_flags=("-O1",)) -> OutputErrorSums:
    """Cached :class:`OutputErrorSums` of a dynamic model.

    Parameters
    ----------
    model : DynamicModel
    n_samples : int
        N.
    scale : array_like, shape (n_parameters,), optional
        Parameter scales (default ``model.scales``).
    masked : bool
        The outputs carry an observation mask.
    noise : NoiseTerm
        R's parametrisation (:mod:`casest.backend.noise_terms`; default diagonal).
    jit : bool
        Compile the sums to C.
    jit_flags : tuple of str
        Compiler flags.

    Returns
    -------
    OutputErrorSums
        Shared by every caller with the same arguments.
    """
    scale = tuple(np.asarray(model.scales if scale is None else scale, dtype=float))
    key = (n_samples, scale, bool(masked), noise, bool(jit), tuple(jit_flags))
    cache = _OE_SUMS.setdefault(model, {})
    if key not in cache:
        cache[key] = OutputErrorSums(model, n_samples, np.array(scale), masked, noise, jit, jit_flags)
    return cache[key]


def dynamic_data_views(model: DynamicModel, n_samples: int, masked: bool, p):
    """Views of a dynamic model's data vector ``[t; vec(U); vec(Z); x0_data]``.

    Parameters
    ----------
    model : DynamicModel
    n_samples : int
        N.
    masked : bool
        Z is ``[z; m]``.
    p : casadi.MX
        The data vector.

    Returns
    -------
    T : casadi.MX, shape (1, N)
    U : casadi.MX, shape (n_inputs, N)
    Z : casadi.MX, shape (n_outputs, N) or (2 n_outputs, N)
    x0_data : casadi.MX, shape (len(initial_from_data),)
    """
    N, nu = n_samples, len(model.inputs)
    nz = model.n_outputs * (2 if masked else 1)
    T, U, Z, d0 = ca.vertsplit(p, [0, N, N + nu * N, N + (nu + nz) * N, p.numel()])
    return ca.reshape(T, 1, N), ca.reshape(U, nu, N), ca.reshape(Z, nz, N), d0


def dynamic_cost_expression(model: DynamicModel, n_samples: int, theta, noise, p, masked: bool = False,
                            noise_term: NoiseTerm = DIAGONAL, penalty: tuple | None = None) -> ca.MX:
    """Output-error J of a dynamic model as a CasADi expression (summary Sec. 5, Eq. 5.7 with
    deterministic states; paper Eq. 6 for the outputs).

    The states are simulated from theta (:meth:`DynamicModel.trajectory_symbols`) and the
    per-sample cost of :mod:`casest.backend.sums` (the output equation's) is mapped over the
    samples.

    Parameters
    ----------
    model : DynamicModel
    n_samples : int
        N.
    theta : casadi.MX, shape (n_parameters,)
    noise : casadi.MX
        The noise block of ``noise_term``: ``ln R`` (diagonal R) or the log-Cholesky vector.
    p : casadi.MX
        ``[t; vec(U); vec(Z); x0_data]`` (:meth:`Problem.data_vector`).
    masked : bool
    noise_term : NoiseTerm
        R's parametrisation (default diagonal).
    penalty : tuple, optional
        A Gaussian prior penalty (mean, std) on theta.

    Returns
    -------
    casadi.MX
        The scalar cost.
    """
    N = n_samples
    T, U, Z, d0 = dynamic_data_views(model, N, masked, p)
    X = model.trajectory_symbols(theta, d0, T, U)
    if model.output_delays:  # the delayed outputs mix samples: the cost of the predicted sequences
        Y = model.output_sequences(X, U, theta)
        f_i = per_sample_cost(prediction_model(model), masked, noise_term)
        J = ca.sum2(f_i.map(N)(Y, Z, ca.vertcat(theta, noise)))
    else:
        f_i = per_sample_cost(model.output_model, masked, noise_term)
        J = ca.sum2(f_i.map(N)(ca.vertcat(X, U), Z, ca.vertcat(theta, noise)))
    penalty = GaussianPenalty.coerce(penalty)
    return J if penalty is None else J + penalty.expression(theta)


_PREDICTION_MODELS = StructureCache()


def prediction_model(model: DynamicModel):
    """A static model whose signals are ``model``'s predicted outputs and whose outputs are those
    signals: the per-sample cost of :mod:`casest.backend.sums` applied to given predictions."""
    cached = _PREDICTION_MODELS.setdefault(model, {})
    if "model" not in cached:
        signals = [Signal(f"predicted_{name}", unit) for name, unit in zip(model.output_names, model.output_units)]
        outputs = {name: ca.SX.sym(s.name) for name, s in zip(model.output_names, signals)}
        cached["model"] = Model(model.parameters, signals, outputs, name=f"{model.name}_predictions",
                                output_units=dict(zip(model.output_names, model.output_units)),
                                require_all_parameters=False)
    return cached["model"]
