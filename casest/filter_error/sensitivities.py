"""The time-varying filter's innovations and their derivatives as one compiled C loop.

The time-varying form of filter-error ML runs the extended Kalman filter over the record
(:func:`casest.filter_error.nlp.filter_error_step`: the update with ``S_k = H P H' + R``
and the gain ``K_k``, then the prediction of ``x`` and ``P``), and scoring needs ``de_k/dw``
and ``dS_k/dw`` at every sample. Here the filter's state ``(x, P)`` carries its forward
sensitivities ``(dx/dw, dP/dw)`` through the same step, one direction of w at a time (the
step's forward derivative mapped over the directions, so the compiled body is a few times
the step's size, not ``n_w`` times), chained with the derivatives of theta, q, r and the
initial state in w; the loop writes each sample's ``e``, ``S`` and their derivatives in place
(:class:`casest._casadi.record_loop.RecordLoop`). Same numbers as CasADi's Jacobian of the
record's graph (:class:`casest.filter_error.scoring.InnovationDerivatives`) to rounding.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from .._casadi.memory import StructureCache
from .._casadi.record_loop import RecordLoop
from ..models.dynamic import DynamicModel
from .scoring import InnovationDerivatives

__all__ = ["FilterPass", "FilterPassDerivatives", "filter_pass_loop", "filter_pass_derivatives"]

_LOOPS = StructureCache()


def _direction(one: ca.Function) -> ca.Function:
    """``(x, P, d, theta, q, r, dx, dP, dtheta, dq, dr) -> (dx_next, dP_next, de, dS)``: the step's forward
    derivative along one direction (SX)."""
    x, P, d, theta, q, r = one.sx_in()
    tangents = [ca.SX.sym("d" + one.name_in(k), one.numel_in(k)) for k in (0, 1, 3, 4, 5)]  # vec of each
    x_next, P_next, _, e, S = one(x, P, d, theta, q, r)
    arguments = ca.vertcat(x, ca.vec(P), theta, q, r)
    seed = ca.vertcat(*tangents)
    derivatives = [ca.jtimes(ca.vec(v), arguments, seed) for v in (x_next, P_next, e, S)]
    return ca.Function("filter_pass_direction", [x, P, d, theta, q, r, *tangents], [ca.cse(ca.vertcat(*derivatives))])


def _sensitivity_step(one: ca.Function, n_w: int) -> ca.Function:
    """``([x; vec P; vec dx/dw; vec dP/dw], d_k, [theta; q; r; vec dtheta/dw; vec dq/dw; vec dr/dw]) ->
    (next, [e; vec S; vec de/dw; vec dS/dw])`` (MX: the direction mapped over the n_w directions)."""
    n, npar, ny = one.size1_in(0), one.size1_in(3), one.size1_in(5)
    nq = one.size1_in(4)
    acc, d = ca.MX.sym("acc", n + n * n + (n + n * n) * n_w), ca.MX.sym("d", one.size1_in(2))
    c = ca.MX.sym("c", (npar + nq + ny) * (1 + n_w))
    x, P, dx, dP = ca.vertsplit(acc, np.cumsum([0, n, n * n, n * n_w, n * n * n_w]).tolist())
    theta, q, r, dtheta, dq, dr = ca.vertsplit(c, np.cumsum([0, npar, nq, ny, npar * n_w, nq * n_w,
                                                             ny * n_w]).tolist())
    P = ca.reshape(P, n, n)
    x_next, P_next, _, e, S = one(x, P, d, theta, q, r)
    tangents = [ca.reshape(v, rows, n_w) for v, rows in ((dx, n), (dP, n * n), (dtheta, npar), (dq, nq), (dr, ny))]
    moved = _direction(one).map(n_w)(x, P, d, theta, q, r, *tangents)
    dx_next, dP_next, de, dS = ca.vertsplit(moved, np.cumsum([0, n, n * n, ny, ny * ny]).tolist())
    return ca.Function("filter_pass_sample", [acc, d, c],
                       [ca.vertcat(x_next, ca.vec(P_next), ca.vec(dx_next), ca.vec(dP_next)),
                        ca.vertcat(e, ca.vec(S), ca.vec(de), ca.vec(dS))])


def _last_sample(last: ca.Function, n_w: int) -> ca.Function:
    """``(x, P, dx, dP, [u; y; mask], theta, r, dtheta, dr) -> (e, vec S, vec de, vec dS)`` of the last
    sample's update (SX)."""
    x, P, u, y, m, theta, r = last.sx_in()
    dx, dP = ca.SX.sym("dx", x.numel(), n_w), ca.SX.sym("dP", P.numel(), n_w)
    dtheta, dr = ca.SX.sym("dtheta", theta.numel(), n_w), ca.SX.sym("dr", r.numel(), n_w)
    _, e, S = last(x, P, u, y, m, theta, r)
    arguments, tangents = ca.vertcat(x, ca.vec(P), theta, r), ca.vertcat(dx, dP, dtheta, dr)
    data = ca.vertcat(u, y, m)
    return ca.Function("filter_pass_last", [x, P, dx, dP, data, theta, r, dtheta, dr],
                       [e, S, ca.vec(ca.jtimes(e, arguments, tangents)), ca.vec(ca.jtimes(S, arguments, tangents))])


def filter_pass_loop(model: DynamicModel, steps: tuple, n_w: int):
    """The compiled loop of the time-varying filter with its sensitivities in ``n_w`` directions and its
    last sample's function, or ``(None, None)`` without a compiler (cached per model structure).

    Parameters
    ----------
    model : DynamicModel
    steps : tuple of casadi.Function
        :func:`casest.filter_error.nlp.filter_error_step`'s ``(step, last)``.
    n_w : int
        The decision vector's length.

    Returns
    -------
    loop : RecordLoop or None
    last : casadi.Function or None
    """
    cache = _LOOPS.setdefault(model, {})
    if n_w not in cache:
        one, last = steps
        ny = model.n_outputs
        # a sensitivity body: -O1, as the other sensitivity passes
        loop = RecordLoop.build(_sensitivity_step(one, n_w), widths=(ny, ny * ny, ny * n_w, ny * ny * n_w),
                                optimisation=("-O1",))
        cache[n_w] = (loop, _last_sample(last, n_w) if loop is not None else None)
    return cache[n_w]


def _vec(a: np.ndarray) -> np.ndarray:
    """CasADi's column-major vec of an array."""
    return np.asarray(a).reshape(-1, order="F")


@dataclass
class FilterPass:
    """One run of the compiled sensitivity pass (:meth:`FilterPassDerivatives.sensitivity_pass`).

    Attributes
    ----------
    values, dvalues : ndarray
        ``[theta; q; r]`` (natural units) and its Jacobian in w, shapes (n_p,), (n_p, n_w).
    sizes : tuple of int
        The lengths of theta, q and r.
    n_states : int
    states : ndarray, shape (N, n_acc) or (1, n_acc)
        ``[x; vec P; vec dx/dw; vec dP/dw]`` before each sample's update (the last row: after the
        last step), or only the last row.
    fields : list of ndarray
        Every step's ``e``, ``vec S``, ``vec de/dw``, ``vec dS/dw`` (N - 1 rows each).
    rows, last : ndarray
        The steps' data (N - 1, n_d) and the last sample's ``[u; y; mask]``.
    """

    values: np.ndarray
    dvalues: np.ndarray
    sizes: tuple
    n_states: int
    states: np.ndarray
    fields: list
    rows: np.ndarray
    last: np.ndarray

    def parts(self, stacked: np.ndarray) -> list:
        """``stacked`` split into its theta, q and r rows."""
        return np.split(stacked, np.cumsum(self.sizes[:2]), axis=0)

    def state(self, k: int) -> tuple:
        """``(x, P, dx/dw, dP/dw)`` of row ``k`` of :attr:`states`, shapes (n,), (n, n), (n, n_w), (n^2, n_w)."""
        n, acc = self.n_states, self.states[k]
        nw = (acc.size - n - n * n) // (n + n * n)
        return (acc[:n], acc[n:n + n * n].reshape(n, n, order="F"),
                acc[n + n * n:n + n * n + n * nw].reshape(n, nw, order="F"),
                acc[n + n * n + n * nw:].reshape(n * n, nw, order="F"))


class FilterPassDerivatives(InnovationDerivatives):
    """:class:`InnovationDerivatives` of the time-varying filter, computed by the compiled loop
    (:func:`filter_pass_loop`) instead of the graph's Jacobian.

    Parameters
    ----------
    w, p : casadi.MX
        The decision vector and the parameter vector, which holds ``[vec(D); last]`` from
        ``d_offset`` on (D: the steps' data, n_d x N-1; last: the last sample's ``[u; y; mask]``).
    E, S : casadi.MX
        The innovations (n_y, N) and vec of their covariances (n_y^2, N) (for :meth:`value`).
    filter_pass : tuple
        ``(theta, q, r, x0, P0)``: the filter's parameters, noise intensities and variances and
        initial state as expressions of w and p, and the initial covariance (n_x, n_x).
    loop : tuple
        :func:`filter_pass_loop`'s ``(RecordLoop, last)``.
    d_offset : int
        Where vec(D) starts in p.
    """

    def __init__(self, w: ca.MX, p: ca.MX, E: ca.MX, S: ca.MX, filter_pass: tuple, loop: tuple, d_offset: int):
        # not InnovationDerivatives.__init__: the loop replaces the graph's Jacobian it builds
        self.ny, self.N, self.nw = E.size1(), E.size2(), w.numel()
        self.constant_S = False
        self.innovations = ca.Function("innovations", [w, p], [E, S])
        theta, q, r, x0, P0 = filter_pass
        self._P0 = np.asarray(P0, dtype=float)
        self._loop, self._last = loop
        self._d_offset, self._n_last = int(d_offset), self._last.size1_in(4)
        self._constants = ca.Function("filter_pass_constants", [w, p],
                                      [ca.vertcat(theta, q, r), ca.jacobian(ca.vertcat(theta, q, r), w), x0,
                                       ca.jacobian(x0, w)])
        self._sizes = (theta.numel(), q.numel(), r.numel())

    def sensitivity_pass(self, w: np.ndarray, p: np.ndarray, keep_states: bool = False) -> FilterPass:
        """The compiled pass at ``w``: its constants, the states' sensitivities and every sample's record.

        Parameters
        ----------
        w : ndarray, shape (n_w,)
        p : ndarray
            The parameter vector.
        keep_states : bool
            Keep the filter's state and its sensitivities before every sample's update (the
            exact Hessian needs them), not only after the last.

        Returns
        -------
        FilterPass
        """
        N, nw = self.N, self.nw
        p = np.asarray(p, dtype=float).reshape(-1)
        values, dvalues, x0, dx0 = (np.asarray(ca.densify(v), dtype=float) for v in self._constants(w, p))
        values, n = values.reshape(-1), x0.size
        npar, nq, _ = self._sizes
        constants = np.concatenate([values] + [_vec(part) for part in np.split(dvalues, np.cumsum([npar, nq]), axis=0)])
        acc0 = np.concatenate([_vec(x0), _vec(self._P0), _vec(dx0), np.zeros(n * n * nw)])
        n_d, start = self._loop.n_d, self._d_offset
        rows = p[start:start + n_d * (N - 1)].reshape(N - 1, n_d)  # vec(D): one step's data together
        last = p[start + n_d * (N - 1):start + n_d * (N - 1) + self._n_last]
        states, fields = self._loop(acc0, rows, constants, keep_accumulators=keep_states)
        return FilterPass(values, dvalues, self._sizes, n, states, fields, rows, last)

    def __call__(self, w: np.ndarray, p: np.ndarray) -> tuple:
        """The innovations and their derivatives at ``w`` (as :meth:`InnovationDerivatives.__call__`)."""
        ny, N, nw = self.ny, self.N, self.nw
        run = self.sensitivity_pass(w, p)
        x, P, dx, dP = run.state(-1)
        theta, _, r = run.parts(run.values)
        dtheta, _, dr = run.parts(run.dvalues)
        tail = [np.asarray(v, dtype=float).reshape(1, -1) for v in self._last(x, P, dx, dP, run.last, theta, r, dtheta,
                                                                               dr)]
        E, S, dE, dS = (np.vstack([a, b]) for a, b in zip(run.fields, tail))
        # vec(de/dw) and vec(dS/dw) are column-major: direction by direction
        dE = dE.reshape(N, nw, ny).transpose(0, 2, 1)
        dS = dS.reshape(N, nw, ny * ny).transpose(0, 2, 1).reshape(N, ny, ny, nw)
        return E, S.reshape(N, ny, ny), dE, dS


def filter_pass_derivatives(model: DynamicModel, w: ca.MX, p: ca.MX, E: ca.MX, S: ca.MX, filter_pass: tuple,
                            steps: tuple, d_offset: int) -> InnovationDerivatives:
    """The innovations' derivatives of the time-varying filter: by the compiled loop where a C compiler
    is (:class:`FilterPassDerivatives`), else by the graph's Jacobian (:class:`InnovationDerivatives`).

    Parameters
    ----------
    model : DynamicModel
    w, p, E, S : casadi.MX
        As for :class:`FilterPassDerivatives`.
    filter_pass : tuple
        ``(theta, q, r, x0, P0)`` (:class:`FilterPassDerivatives`).
    steps : tuple of casadi.Function
        :func:`casest.filter_error.nlp.filter_error_step`'s ``(step, last)``.
    d_offset : int
        Where vec(D) starts in p.

    Returns
    -------
    InnovationDerivatives
    """
    loop = filter_pass_loop(model, steps, w.numel()) if E.size2() > 1 else (None, None)
    if loop[0] is None:
        return InnovationDerivatives(w, p, E, S)
    return FilterPassDerivatives(w, p, E, S, filter_pass, loop, d_offset)
