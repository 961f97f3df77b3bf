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

from .._casadi.numerics import compile_function, prefetch_compile
from .._casadi.memory import StructureCache
from ..models.dynamic import DynamicModel
from ..models.priors import Signal
from ..models.static import Model
from .noise_terms import DIAGONAL, NoiseTerm
from .penalty import GaussianPenalty
from .sums import map_sum, per_sample_cost, symmetric


__all__ = ["OutputErrorSums", "output_error_sums", "dynamic_data_views", "dynamic_cost_expression",
           "prefetch_second_order", "dynamic_indices", "sensitivity_flags", "prediction_model"]


class OutputErrorSums:
    """Output-error J/N of a dynamic model, its gradient and exact Hessian, by forward sensitivities.

    The simulation carries the derivatives of the states with respect to the parameters of
    the dynamics (first order ``S = dx/dtheta_D`` for the gradient, and second order
    ``T = d2x/dtheta_D2`` for the Hessian). The first-order step is the RK4 step applied to
    the jet ``x + S d`` and differentiated symbolically (SX); the second order is propagated
    one parameter direction at a time by the forward derivative of that step
    (:func:`state_jets`), simulated 50 samples at a time (:func:`chunked_jet_sum`). Each
    sample's cost (:func:`casest.sums.per_sample_cost` of the output equation) is
    differentiated with the jet ``x + S d + d' T d / 2`` of its states and summed with a
    map-reduce. The result is the exact gradient and Hessian of the discretised cost, for
    RK4 models (a CVODES model uses CasADi's AD through the integrator). With ``jit`` the
    steps and the first-order per-sample functions are compiled to C; the loops over the
    samples call them.

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
        sums = []
        for order in (0, 1, 2):
            step, initial, per_sample = self._jet_functions(order)
            if order == 2:  # the second-order states are never stored for the whole record
                out = chunked_jet_sum(model, step, initial, per_sample, self._D, w_phys, Tm, Um, Zm, d0m)
            else:
                A = simulate_jets(model, step, initial, self._D, w_phys[:n], Tm, Um, d0m, f"jet{order}_simulate")
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
        if self._jit and order < 2:  # the small SX bodies are compiled; the loops over samples call them
            # (the second-order per-sample body is large and cheap next to the steps: compiling it
            # costs seconds and gains nothing measurable)
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

    ``order`` 0: the states; 1: also ``S = dx/dtheta_D``; 2: also the second derivatives, each
    state's ``nD x nD`` block. Returns ``(step, initial)``: ``step(aug_k, u_k, u_k+1, dt,
    theta_D) -> aug_k+1`` with ``aug = [x; vec(S); T]`` and ``initial(theta, x0_data) -> aug_0``
    (``theta_D``: the parameters at positions ``D``). Orders 0 and 1 are SX Functions
    (compiled with ``jit``). Order 2 is not differentiated symbolically (that body grows as
    nD^2 and takes minutes to compile on big models): its step applies the first-order step
    and, for each parameter direction, the forward derivative of the sensitivities along it
    (:func:`_second_order_step`), evaluated when called.
    """
    nx = model.n_states
    nD = len(D) if order else 0
    x, S = ca.SX.sym("x", nx), ca.SX.sym("S", nx, min(order, 1) * nD)
    n_step_u = model.step_function.size1_in(1)  # 2 n_u for cubic interpolation
    uk, uk1, dt = ca.SX.sym("uk", n_step_u), ca.SX.sym("uk1", n_step_u), ca.SX.sym("dt")
    theta_D, d = ca.SX.sym("theta_D", len(D)), ca.SX.sym("d", nD)
    x_jet = _jet(x, S, ca.SX(0, 1), d, nx, nD)
    rhs_pos = [D.index(i) for i in model.rhs_parameter_index]
    shifted = theta_D + d if nD else theta_D
    theta_rhs = ca.vertcat(*[shifted[k] for k in rhs_pos]) if rhs_pos else ca.SX(0, 1)
    x_next = model.step_function(x_jet, uk, uk1, dt, theta_rhs)
    step = ca.Function(f"jet{min(order, 1)}_step", [ca.vertcat(x, ca.vec(S)), uk, uk1, dt, theta_D],
                       [ca.cse(_jet_coefficients(x_next, d, nx, nD, min(order, 1)))])
    theta, d0 = ca.SX.sym("theta", model.n_parameters), ca.SX.sym("x0_data", len(model.initial_from_data))
    shift = ca.SX.zeros(model.n_parameters)
    for k, i in enumerate(D[:nD]):
        shift[i] = d[k]
    initial = ca.Function(f"jet{order}_initial", [theta, d0],
                          [_jet_coefficients(model.initial_function(theta + shift, d0), d, nx, nD, order)])
    if order == 2 and nD:
        step = _second_order_step(step, nx, nD, jit, jit_flags)
    elif jit:
        step = compile_function(step, jit_flags)
    return step, initial


def _direction_function(step1: ca.Function, nx: int, nD: int) -> ca.Function:
    """``(aug1, T_j, e_j, u_k, u_k+1, dt, theta_D) -> T_j'``: the forward derivative of the first-order
    step's S along ``(S e_j, T_j, e_j)`` (SX)."""
    aug1 = ca.SX.sym("aug1", nx + nx * nD)
    uk, uk1, dt = (ca.SX.sym(n, step1.size1_in(k)) for k, n in ((1, "uk"), (2, "uk1"), (3, "dt")))
    theta_D, T_j, e_j = ca.SX.sym("theta_D", nD), ca.SX.sym("T_j", nx, nD), ca.SX.sym("e_j", nD)
    S_next = step1(aug1, uk, uk1, dt, theta_D)[nx:]
    S = ca.reshape(aug1[nx:], nx, nD)
    seed = ca.vertcat(ca.mtimes(S, e_j), ca.vec(T_j), e_j)
    dT = ca.jtimes(S_next, ca.vertcat(aug1, theta_D), seed)
    return ca.Function("jet2_direction", [aug1, T_j, e_j, uk, uk1, dt, theta_D], [ca.reshape(dT, nx, nD)])


def prefetch_second_order(model: DynamicModel, jit_flags=("-O1",)) -> bool:
    """Start compiling the second-order direction function of ``model`` in a background process.

    The exact Hessian of output error (the covariance after Gauss-Newton, IPOPT's path) needs
    it; compiling it takes seconds on big models. A separate process compiles it into the
    compile cache while this one runs stage 1 and stage 2; :func:`compile_function` then waits
    for that process and loads the library. Returns whether a compile was started (not when
    the model has no dynamic parameters or no compile cache is usable).
    """
    D = dynamic_indices(model)
    if not D:
        return False
    step1, _ = state_jets(model, D, 1)
    return prefetch_compile(_direction_function(step1, model.n_states, len(D)), jit_flags)


def _second_order_step(step1: ca.Function, nx: int, nD: int, jit: bool, jit_flags) -> ca.Function:
    """The order-2 jet step from the order-1 step ``step1``, by directional derivatives.

    For direction j, ``T_j = dS/dtheta_j`` (nx x nD) moves as the forward derivative of the
    step's S along ``(dx, dS, dtheta) = (S e_j, T_j, e_j)``: one small function mapped over
    the nD directions. The arithmetic is that of second-order sensitivities; the code is
    a few times the first-order step's, not nD times.
    """
    direction = _direction_function(step1, nx, nD)
    if jit:
        step1, direction = compile_function(step1, jit_flags), compile_function(direction, jit_flags)
    # jet layout: state i's block (l, j) at i nD^2 + l + nD j; direction layout: vec(T_j) per column j
    to_dirs = [i * nD * nD + l + nD * j for j in range(nD) for l in range(nD) for i in range(nx)]
    to_jet = np.argsort(to_dirs).tolist()
    aug = ca.MX.sym("aug", nx + nx * nD + nx * nD * nD)
    ukm, uk1m, dtm, thm = (ca.MX.sym(n, step1.size1_in(k)) for k, n in ((1, "uk"), (2, "uk1"), (3, "dt"),
                                                                         (4, "theta_D")))
    a1 = aug[:nx + nx * nD]
    T_dirs = ca.reshape(aug[nx + nx * nD:][to_dirs], nx, nD * nD)
    dT_dirs = direction.map(nD)(a1, T_dirs, ca.DM.eye(nD), ukm, uk1m, dtm, thm)
    out = ca.vertcat(step1(a1, ukm, uk1m, dtm, thm), ca.vec(dT_dirs)[to_jet])
    return ca.Function("jet2_step", [aug, ukm, uk1m, dtm, thm], [out])


def simulate_jets(model: DynamicModel, step, initial, D: list, theta, Tm, Um, d0m, name: str):
    """The jets of the states at every sample, ``[a_0 ... a_N-1]``: the initial jet, then ``step`` over the
    record's intervals (one ``mapaccum``)."""
    N = Tm.numel()
    a0 = initial(theta, d0m)
    if N == 1:
        return a0
    T0, T1 = ca.horzsplit(Tm, [0, N - 1, N])[0], ca.horzsplit(Tm, [0, 1, N])[1]
    Ua, Ub = model.interval_inputs(Um)
    th_D = ca.vertcat(*[theta[i] for i in D]) if D else ca.MX(0, 1)
    run = step.mapaccum(name, N - 1)
    return ca.horzcat(a0, run(a0, Ua, Ub, T1 - T0, ca.repmat(th_D, 1, N - 1)))


def chunked_jet_sum(model: DynamicModel, step, initial, per_sample, D: list, w, Tm, Um, Zm, d0m,
                    chunk: int = 50) -> ca.MX:
    """The sum over the record of ``per_sample(aug_k; u_k, z_k, w)`` (one output), simulating the jets
    ``chunk`` samples at a time.

    Only one chunk's jets exist at once: the outer ``mapaccum`` carries the jet at each
    chunk's end and the running sum, the inner one steps through the chunk. Second-order
    jets (``n_x n_D^2`` numbers a sample) of a whole record would otherwise be one matrix of
    hundreds of MB, and CasADi's construction of a record-long ``mapaccum`` over them takes
    longer than the evaluation.
    """
    N = Tm.numel()
    theta = w[:model.n_parameters]
    a0 = ca.densify(initial(theta, d0m))  # the carried jet: dense, as the steps make it
    total = per_sample(ca.vertcat(a0, Um[:, 0]), Zm[:, 0], w)
    if N == 1:
        return total
    T0, T1 = ca.horzsplit(Tm, [0, N - 1, N])[0], ca.horzsplit(Tm, [0, 1, N])[1]
    Ua, Ub = model.interval_inputs(Um)
    th_D = ca.vertcat(*[theta[i] for i in D]) if D else ca.MX(0, 1)
    intervals = [Ua, Ub, T1 - T0, Um[:, 1:], Zm[:, 1:]]
    K = min(chunk, N - 1)
    n_chunks, rest = divmod(N - 1, K)
    run = _jet_chunk(step, per_sample, K, a0.sparsity(), total.sparsity(), Um.size1(), Zm.size1())
    split = [v[:, :K * n_chunks] for v in intervals]
    A, S = run.mapaccum(f"jet_chunks_{K}", n_chunks, 2)(a0, total, *split, ca.repmat(th_D, 1, n_chunks),
                                                        ca.repmat(w, 1, n_chunks))
    a_end, total = A[:, -1], S[:, -total.size2():]
    if rest:
        tail = _jet_chunk(step, per_sample, rest, a0.sparsity(), total.sparsity(), Um.size1(), Zm.size1())
        _, total = tail(a_end, total, *[v[:, K * n_chunks:] for v in intervals], th_D, w)
    return total


def _jet_chunk(step, per_sample, K: int, aug_sparsity, sum_sparsity, nu: int, nz: int) -> ca.Function:
    """``(aug, sum, Ua, Ub, dt, U, Z, theta_D, w) -> (aug after K steps, sum + the K samples' terms)``."""
    aug, acc = ca.MX.sym("aug", aug_sparsity), ca.MX.sym("sum", sum_sparsity)
    ua, ub = ca.MX.sym("ua", step.size1_in(1), K), ca.MX.sym("ub", step.size1_in(2), K)
    dt, u, z = ca.MX.sym("dt", 1, K), ca.MX.sym("u", nu, K), ca.MX.sym("z", nz, K)
    th_D, w = ca.MX.sym("theta_D", step.size1_in(4)), ca.MX.sym("w", per_sample.sparsity_in(2))
    A = step.mapaccum(f"jet_steps_{K}", K)(aug, ua, ub, dt, ca.repmat(th_D, 1, K))
    terms = per_sample.map(f"jet_terms_{K}", "serial", K, [2], [0])(ca.vertcat(A, u), z, w)
    return ca.Function(f"jet_chunk_{K}", [aug, acc, ua, ub, dt, u, z, th_D, w], [A[:, -1], acc + terms])


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
