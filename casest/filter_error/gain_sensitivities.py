"""The innovations of a constant-gain filter and their derivatives as one compiled C loop.

The innovation formulation of filter-error ML (Jategaonkar's, summary Sec. 5.3) runs the filter
``x(k+1) = f(x(k) + K e(k))``, ``e(k) = y(k) - h(x(k))`` with one gain K for the whole record,
and Gauss-Newton (scoring) needs ``dE/dw`` at every step. The CasADi graph of the record
differentiates the whole ``mapaccum`` (:class:`casest.filter_error.scoring.InnovationDerivatives`);
here the state carries its forward sensitivities ``dx/dw`` through the same step, chained with
the derivatives of theta, K, the innovation covariance and the initial state in w (computed
once per evaluation from the small graph of the gain), and the loop writes each sample's ``e``
and ``de/dw`` in place (:class:`casest._casadi.record_loop.RecordLoop`). The innovation form
and the steady-state form (whose gain and covariance depend on w) use it. Same numbers as the
graph to rounding.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from .._casadi.memory import StructureCache
from .._casadi.record_loop import RecordLoop
from ..models.dynamic import DynamicModel
from .scoring import InnovationDerivatives
from .steady import steady_step

__all__ = ["GainPassDerivatives", "gain_pass_loop", "gain_pass_derivatives"]

_LOOPS = StructureCache()


def _sensitivity_step(model: DynamicModel, n_w: int) -> tuple[ca.Function, ca.Function]:
    """``([x; vec dx/dw], d_k, [theta; vec K; vec dtheta/dw; vec dK/dw]) -> (next, [e; vec de/dw])`` and
    the last sample's ``([x; vec dx/dw], [u; y], [theta; vec dtheta/dw]) -> (e, vec de/dw)``."""
    step, last = steady_step(model)
    n, ny, npar = model.n_states, model.n_outputs, model.n_parameters
    acc, d = ca.SX.sym("acc", n + n * n_w), ca.SX.sym("d", step.size1_in(1))
    c = ca.SX.sym("c", npar + n * ny + (npar + n * ny) * n_w)
    x, dx = acc[:n], ca.reshape(acc[n:], n, n_w)
    theta, K, dtheta, dK = ca.vertsplit(c, np.cumsum([0, npar, n * ny, npar * n_w, n * ny * n_w]).tolist())
    K, dtheta, dK = ca.reshape(K, n, ny), ca.reshape(dtheta, npar, n_w), ca.reshape(dK, n * ny, n_w)
    x_next, _, e = step(x, d, theta, K, ca.SX.zeros(ny, ny))  # S^-1 enters the cost term only
    arguments, tangents = ca.vertcat(x, theta, ca.vec(K)), ca.vertcat(dx, dtheta, dK)
    advance = ca.Function("gain_pass_sample", [acc, d, c],
                          [ca.vertcat(x_next, ca.vec(ca.jtimes(x_next, arguments, tangents))),
                           ca.vertcat(e, ca.vec(ca.jtimes(e, arguments, tangents)))])
    lastd, theta_l, dtheta_l = ca.SX.sym("last", last.size1_in(1)), ca.SX.sym("theta", npar), ca.SX.sym("dth", npar, n_w)
    _, e_last = last(x, lastd, theta_l, ca.SX.zeros(ny, ny))
    final = ca.Function("gain_pass_last", [acc, lastd, theta_l, dtheta_l],
                        [e_last, ca.vec(ca.jtimes(e_last, ca.vertcat(x, theta_l), ca.vertcat(dx, dtheta_l)))])
    return advance, final


def gain_pass_loop(model: DynamicModel, n_w: int):
    """The compiled loop of the constant-gain pass with its sensitivities in ``n_w`` directions and
    its last sample's function, or ``(None, None)`` without a compiler (cached per model structure).

    Parameters
    ----------
    model : DynamicModel
    n_w : int
        The decision vector's length.

    Returns
    -------
    loop : RecordLoop or None
    last : casadi.Function or None
    """
    cache = _LOOPS.setdefault(model, {})
    if n_w not in cache:
        advance, final = _sensitivity_step(model, n_w)
        # a sensitivity body: -O1, as the output-error passes (its -O3 compile costs seconds)
        loop = RecordLoop.build(advance, widths=(model.n_outputs, model.n_outputs * n_w), optimisation=("-O1",))
        cache[n_w] = (loop, final if loop is not None else None)
    return cache[n_w]


class GainPassDerivatives(InnovationDerivatives):
    """:class:`InnovationDerivatives` of a constant-gain pass, computed by the compiled loop
    (:func:`gain_pass_loop`) instead of the graph's Jacobian.

    Parameters
    ----------
    model : DynamicModel
    w, p : casadi.MX
        The decision vector and the parameter vector, which holds ``[vec(D); last]`` from
        ``d_offset`` on (D: the steps' data, n_d x N-1; last: the last sample's ``[u; y]``).
    E : casadi.MX, shape (n_y, N)
        The innovations (for :meth:`value`).
    S : casadi.MX, shape (n_y^2, 1)
        vec of the innovation covariance, the same for every sample (of w, or a part of p).
    theta, K, x0 : casadi.MX
        The pass's parameters, gain and initial state as expressions of w and p.
    loop : tuple
        :func:`gain_pass_loop`'s ``(RecordLoop, last)``.
    d_offset : int
        Where vec(D) starts in p.
    """

    def __init__(self, model: DynamicModel, w: ca.MX, p: ca.MX, E: ca.MX, S: ca.MX, theta: ca.MX, K: ca.MX,
                 x0: ca.MX, loop: tuple, d_offset: int):
        # not InnovationDerivatives.__init__: the loop replaces the graph's Jacobian it builds
        self.ny, self.N, self.nw = E.size1(), E.size2(), w.numel()
        self.constant_S = True
        self.innovations = ca.Function("innovations", [w, p], [E, S])
        self._loop, self._last = loop
        self._d_offset, self._n_last = int(d_offset), self._last.size1_in(1)
        self._constants = ca.Function("gain_pass_constants", [w, p],
                                      [theta, ca.vec(K), ca.jacobian(theta, w), ca.jacobian(ca.vec(K), w), x0,
                                       ca.jacobian(x0, w), S, ca.jacobian(S, w)])

    def __call__(self, w: np.ndarray, p: np.ndarray) -> tuple:
        """The innovations and their derivatives at ``w`` (as :meth:`InnovationDerivatives.__call__`)."""
        ny, N, nw = self.ny, self.N, self.nw
        p = np.asarray(p, dtype=float).reshape(-1)
        theta, K, dtheta, dK, x0, dx0, S, dS = (np.asarray(ca.densify(v), dtype=float) for v in self._constants(w, p))
        vec = lambda a: a.reshape(-1, order="F")  # noqa: E731  (CasADi's column-major vec)
        constants = np.concatenate([vec(theta), vec(K), vec(dtheta), vec(dK)])
        n_d, start = self._loop.n_d, self._d_offset
        rows = p[start:start + n_d * (N - 1)].reshape(N - 1, n_d)  # vec(D): one step's data together
        last = p[start + n_d * (N - 1):start + n_d * (N - 1) + self._n_last]
        final, (E, dE) = self._loop(np.concatenate([vec(x0), vec(dx0)]), rows, constants, keep_accumulators=False)
        e_last, de_last = (np.asarray(v, dtype=float).reshape(1, -1) for v in self._last(final[0], last, theta, dtheta))
        E, dE = np.vstack([E, e_last]), np.vstack([dE, de_last])
        # the layout of InnovationDerivatives' broadcast of one covariance
        S = np.repeat(S.reshape(1, ny, ny), N, axis=0)
        dS = np.broadcast_to(dS.reshape(1, ny, ny, nw), (N, ny, ny, nw))
        return E, S, dE.reshape(N, nw, ny).transpose(0, 2, 1), dS


def gain_pass_derivatives(model: DynamicModel, w: ca.MX, p: ca.MX, E: ca.MX, S: ca.MX, gain_pass: tuple,
                          d_offset: int) -> InnovationDerivatives:
    """The innovations' derivatives of a constant-gain pass: by the compiled loop where a C compiler
    is (:class:`GainPassDerivatives`), else by the graph's Jacobian (:class:`InnovationDerivatives`).

    Parameters
    ----------
    model : DynamicModel
    w, p, E, S : casadi.MX
        As for :class:`GainPassDerivatives`.
    gain_pass : tuple of casadi.MX
        ``(theta, K, x0)``; empty for a pass that is not constant-gain (the graph's Jacobian).
    d_offset : int
        Where vec(D) starts in p.

    Returns
    -------
    InnovationDerivatives
    """
    loop = gain_pass_loop(model, w.numel()) if gain_pass else (None, None)
    if loop[0] is None:
        return InnovationDerivatives(w, p, E, S)
    return GainPassDerivatives(model, w, p, E, S, *gain_pass, loop, d_offset)
