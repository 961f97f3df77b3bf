"""The discretisation of a dynamic model: inputs between samples (linear, cubic, held), one
sample interval of the ODE (fixed-step RK4 with substeps, or CVODES), and the restarts of
several experiments stacked in one record (:class:`Segments`).

The functions take the :class:`casest.DynamicModel` they discretise; the model calls them
once (its ``step_function``) and its users call :meth:`DynamicModel.interval_inputs`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import casadi as ca
import numpy as np


__all__ = ["Segments", "restart_value", "input_at", "interval_inputs", "interval_input_values", "build_step",
           "with_restarts"]


@dataclass(frozen=True)
class Segments:
    """Several experiments in one record: the simulation restarts at each experiment's first sample.

    Built by :func:`casest.problem.experiments.stack_dynamic_experiments`; the stacked model's inputs
    carry the flags, so every consumer of the step function (simulation, sensitivities,
    stage 1, multiple shooting) restarts at the same samples.

    Attributes
    ----------
    names : tuple of str
        The experiments, in record order.
    start : str
        The input column that is 1 at an experiment's first sample (0 elsewhere).
    indicators : tuple of str
        One input column per experiment, 1 on its samples.
    initial : tuple of (str, tuple)
        Per state, its initial value in each experiment: a number, the name of a parameter
        (estimated), or the name of an input column holding it (from the data).
    lengths : tuple of int
        Each experiment's number of samples, in record order (where output delays, which
        mix neighbouring samples, must stop at the boundaries); empty when not known.
    """

    names: tuple
    start: str
    indicators: tuple
    initial: tuple
    lengths: tuple = ()

    def parameters(self) -> tuple:
        """The parameters that are some experiment's initial state.

        Returns
        -------
        tuple of str
        """
        return tuple(v for _, values in self.initial for v in values if isinstance(v, str) and not v.startswith("@"))

    def with_values(self, values: Mapping[str, float]) -> "Segments":
        """The same segments with some initial-state parameters replaced by numbers (fixed).

        Parameters
        ----------
        values : mapping of str to float

        Returns
        -------
        Segments
        """
        initial = tuple((state, tuple(values.get(v, v) if isinstance(v, str) else v for v in per))
                        for state, per in self.initial)
        return Segments(self.names, self.start, self.indicators, initial, self.lengths)


def restart_value(value, parameters: dict, u_next, inputs: list):
    """A state's initial value in one experiment, as an expression of the step's arguments."""
    if not isinstance(value, str):
        return float(value)
    return u_next[inputs.index(value)] if value.startswith("@") else parameters[value]


def input_at(model, uk, uk1, fraction):
    """The input at ``fraction`` of the interval; for "cubic" uk = [u_k-1; u_k], uk1 = [u_k+1; u_k+2]."""
    if model.input_hold == "zoh":
        return uk
    if model.input_hold == "cubic":
        nu = len(model.inputs)
        p0, p1, p2, p3 = uk[:nu], uk[nu:], uk1[:nu], uk1[nu:]
        s = fraction
        return 0.5 * (2 * p1 + (p2 - p0) * s + (2 * p0 - 5 * p1 + 4 * p2 - p3) * s**2
                      + (3 * p1 - p0 - 3 * p2 + p3) * s**3)
    return uk + fraction * (uk1 - uk)

def interval_inputs(model, U):
    """The step function's input arguments for every interval, shape (n, N-1) each.

    ``U`` (n_inputs x N, CasADi): ``(U[:, :-1], U[:, 1:])``, or for cubic interpolation
    the pairs ``[u_k-1; u_k]`` and ``[u_k+1; u_k+2]`` (ends extrapolated linearly).
    """
    N = U.size2()
    Ua, Ub = ca.horzsplit(U, [0, N - 1, N])[0], ca.horzsplit(U, [0, 1, N])[1]
    if model.input_hold != "cubic":
        return Ua, Ub
    if N < 3:
        return ca.vertcat(Ua, Ua), ca.vertcat(Ub, Ub)
    # offsets only (a split into N columns would put N nodes into the graph)
    first, second, _ = ca.horzsplit(U, [0, 1, 2, N])
    _, last2, last = ca.horzsplit(U, [0, N - 2, N - 1, N])
    head = ca.horzsplit(U, [0, N - 2, N])[0]  # u_0 .. u_N-3
    tail = ca.horzsplit(U, [0, 2, N])[1]  # u_2 .. u_N-1
    prev = ca.horzcat(2 * first - second, head)
    nxt = ca.horzcat(tail, 2 * last - last2)
    if model.segments is not None:  # each experiment's ends extrapolate linearly, as the record's do
        row = [u.name for u in model.inputs].index(model.segments.start)
        starts = U[row, :]
        at_first = ca.repmat(ca.horzsplit(starts, [0, N - 1, N])[0], U.size1(), 1)  # interval k starts one
        before_next = ca.repmat(ca.horzcat(ca.horzsplit(starts, [0, 2, N])[1], ca.MX(1, 1) if isinstance(U, ca.MX)
                                           else ca.SX(1, 1)), U.size1(), 1)  # sample k + 2 starts one
        prev = prev + at_first * (2 * Ua - Ub - prev)
        nxt = nxt + before_next * (2 * Ub - Ua - nxt)
    return ca.vertcat(prev, Ua), ca.vertcat(Ub, nxt)

def interval_input_values(model, U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Numeric :meth:`interval_inputs`: the step function's input arguments per interval.

    Parameters
    ----------
    U : ndarray, shape (N, n_inputs)

    Returns
    -------
    u_a, u_b : ndarray, shape (N-1, n) each
    """
    U = np.asarray(U, dtype=float).reshape(U.shape[0], -1)
    N = U.shape[0]
    width = len(model.inputs) * (2 if model.input_hold == "cubic" else 1)
    if N < 2:
        return np.zeros((0, width)), np.zeros((0, width))
    if model.input_hold != "cubic":  # each interval's ends (interval_inputs without a graph)
        return U[:-1].copy(), U[1:].copy()
    if model.segments is None:  # the neighbours of each interval, the record's ends extrapolated linearly
        if N < 3:
            return np.hstack([U[:-1], U[:-1]]), np.hstack([U[1:], U[1:]])
        before = np.vstack([2 * U[:1] - U[1:2], U[:-2]])
        after = np.vstack([U[2:], 2 * U[-1:] - U[-2:-1]])
        return np.hstack([before, U[:-1]]), np.hstack([U[1:], after])
    Um = ca.MX.sym("u", U.shape[1], N)
    a, b = ca.Function("interval_inputs", [Um], list(interval_inputs(model, Um)))(U.T)
    return np.asarray(a).T.reshape(N - 1, -1), np.asarray(b).T.reshape(N - 1, -1)

def build_step(model) -> ca.Function:
    """The step function of :attr:`DynamicModel.step_function` (RK4 with substeps, or CVODES)."""
    nx, n = model.n_states, len(model.rhs_parameter_index)
    nu = len(model.inputs) * (2 if model.input_hold == "cubic" else 1)
    theta_rhs = ca.SX.sym("theta_rhs", n)
    full = ca.SX.zeros(model.n_parameters)  # the rhs does not depend on the other entries
    for k, i in enumerate(model.rhs_parameter_index):
        full[i] = theta_rhs[k]
    f = ca.Function("f_rhs", [model.rhs_function.sx_in(0), model.rhs_function.sx_in(1), theta_rhs],
                    [model.rhs_function(model.rhs_function.sx_in(0), model.rhs_function.sx_in(1), full)])
    if model.integrator == "cvodes":
        x, uk, uk1 = ca.SX.sym("x", nx), ca.SX.sym("uk", nu), ca.SX.sym("uk1", nu)
        dt, theta, tau = ca.SX.sym("dt"), ca.SX.sym("theta", n), ca.SX.sym("tau")
        p = ca.vertcat(uk, uk1, dt, theta)
        dae = {"x": x, "p": p, "t": tau, "ode": dt * f(x, input_at(model, uk, uk1, tau), theta)}
        tol = model.cvodes_tolerance
        F = ca.integrator("interval", "cvodes", dae, 0.0, 1.0, {"abstol": tol, "reltol": tol})
        xm, ukm, uk1m = ca.MX.sym("x", nx), ca.MX.sym("uk", nu), ca.MX.sym("uk1", nu)
        dtm, thm = ca.MX.sym("dt"), ca.MX.sym("theta", n)
        base = ca.Function("interval_step", [xm, ukm, uk1m, dtm, thm],
                           [F(x0=xm, p=ca.vertcat(ukm, uk1m, dtm, thm))["xf"]])
        return with_restarts(model, base, xm, ukm, uk1m, dtm, thm, lambda e: e)
    x, uk, uk1 = ca.SX.sym("x", nx), ca.SX.sym("uk", nu), ca.SX.sym("uk1", nu)
    dt, theta = ca.SX.sym("dt"), ca.SX.sym("theta", n)
    m = model.substeps
    h = dt / m
    xs = x
    for i in range(m):
        a, mid, b = i / m, (i + 0.5) / m, (i + 1) / m
        k1 = f(xs, input_at(model, uk, uk1, a), theta)
        k2 = f(xs + 0.5 * h * k1, input_at(model, uk, uk1, mid), theta)
        k3 = f(xs + 0.5 * h * k2, input_at(model, uk, uk1, mid), theta)
        k4 = f(xs + h * k3, input_at(model, uk, uk1, b), theta)
        xs = xs + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    base = ca.Function("interval_step", [x, uk, uk1, dt, theta], [xs])
    return with_restarts(model, base, x, uk, uk1, dt, theta, ca.cse)

def with_restarts(model, base: ca.Function, x, uk, uk1, dt, theta_rhs, simplify) -> ca.Function:
    """The step function: ``base`` over one interval, or with :attr:`segments` the restart at an
    experiment's first sample (the interval into it has length 0 and ends at that
    experiment's initial state)."""
    names = (["x", "uk", "uk1", "dt", "theta"], ["x_next"])
    if model.segments is None:
        return ca.Function("step", [x, uk, uk1, dt, theta_rhs], [simplify(base(x, uk, uk1, dt, theta_rhs))], *names)
    inputs = [u.name for u in model.inputs]
    u_next = uk1[:len(inputs)]  # the inputs at the interval's end sample
    restart = u_next[inputs.index(model.segments.start)]
    x_end = base(x, uk, uk1, dt * (1 - restart), theta_rhs)
    full = {model.parameter_names[i]: theta_rhs[k] for k, i in enumerate(model.rhs_parameter_index)}
    x0 = []
    for state, values in model.segments.initial:
        terms = [u_next[inputs.index(ind)] * restart_value(v, full, u_next, inputs)
                 for ind, v in zip(model.segments.indicators, values)]
        x0.append(sum(terms[1:], terms[0]))
    x_next = x_end + restart * (ca.vertcat(*x0) - x_end)
    return ca.Function("step", [x, uk, uk1, dt, theta_rhs], [simplify(x_next)], *names)
