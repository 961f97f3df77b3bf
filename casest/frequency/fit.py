"""The frequency domain's residuals and their reweighted least squares (Klein and Morelli, Ch. 7).

The residuals are CasADi expressions of the parameters and of one delay per input (``U(w)
exp(-j w tau)``): the fit holds each delay at zero or at an estimated delay parameter, and the
diagnosis (:mod:`casest.frequency.delay_diagnosis`) reads their derivatives at the estimate.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..backend.ipopt import SolverSettings, active_bounds, run_ipopt
from ..status import Note, NoteCode

__all__ = ["FitParameters", "ReweightedFit", "residual_expressions", "reweighted_fit", "residual_function",
           "MAX_ROUNDS"]

#: reweighting rounds (residual spectra re-estimated) before the estimate is reported as not settled
MAX_ROUNDS = 20


@dataclass(frozen=True)
class FitParameters:
    """The estimated quantities: the model's parameters and, where estimated, the delay.

    Attributes
    ----------
    names : tuple of str
    nominal, lower, upper, scales : ndarray, shape (n,)
        Start values, bounds and scales (the model's, and the delay's in seconds).
    """

    names: tuple
    nominal: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    scales: np.ndarray


@dataclass(frozen=True)
class ReweightedFit:
    """The reweighted least squares at its end.

    Attributes
    ----------
    values : ndarray, shape (n,)
        Every parameter (the held ones at their nominal values).
    spectra : ndarray, shape (channels,)
        The residual spectra ``S_j`` the last round weighted by.
    inside : ndarray of bool, shape (n_acting,)
        The acting parameters off their bounds.
    notes : list of Note
    status : str
        IPOPT's status of the last round.
    """

    values: np.ndarray
    spectra: np.ndarray
    inside: np.ndarray
    notes: list
    status: str


def residual_expressions(method: str, ABCD, w: np.ndarray, U: np.ndarray, Y: np.ndarray, X, tau) -> list:
    """Real and imaginary parts of the residual of each channel at each frequency (SX).

    Parameters
    ----------
    method : {"output-error", "equation-error"}
    ABCD : list of SX
        The linearisation's matrices, functions of the parameters.
    w : ndarray, shape (F,)
    U, Y : ndarray, complex, shape (F, n_inputs), (F, n_outputs)
        The transforms of the inputs and outputs.
    X : ndarray, complex, shape (F, n_states), or None
        Equation error: the measured states' transforms.
    tau : SX, shape (n_inputs,)
        Each input's delay (s): ``U(w)`` enters as ``U(w) exp(-j w tau)``.

    Returns
    -------
    list of two SX, shape (channels, F)
    """
    A, B, C, D = ABCD
    n = A.size1()
    out_r, out_i = [], []
    for k, wk in enumerate(w):
        cos, sin = ca.cos(wk * tau), ca.sin(wk * tau)
        Ur = ca.DM(U[k].real) * cos + ca.DM(U[k].imag) * sin
        Ui = ca.DM(U[k].imag) * cos - ca.DM(U[k].real) * sin
        if method == "output-error":
            # (jw I - A)(Xr + j Xi) = B U, as a real system of twice the size
            M = ca.vertcat(ca.horzcat(-A, -wk * ca.DM.eye(n)), ca.horzcat(wk * ca.DM.eye(n), -A))
            Z = ca.solve(M, ca.vertcat(ca.mtimes(B, Ur), ca.mtimes(B, Ui)))
            Xr, Xi = Z[:n], Z[n:]
            model_r, model_i = ca.mtimes(C, Xr) + ca.mtimes(D, Ur), ca.mtimes(C, Xi) + ca.mtimes(D, Ui)
            out_r.append(ca.DM(Y[k].real) - model_r)
            out_i.append(ca.DM(Y[k].imag) - model_i)
        else:
            Xr, Xi = ca.DM(X[k].real), ca.DM(X[k].imag)
            rhs_r, rhs_i = ca.mtimes(A, Xr) + ca.mtimes(B, Ur), ca.mtimes(A, Xi) + ca.mtimes(B, Ui)
            out_r.append(-wk * Xi - rhs_r)  # jw X = -w Xi + j w Xr
            out_i.append(wk * Xr - rhs_i)
    return [ca.horzcat(*out_r), ca.horzcat(*out_i)]


def reweighted_fit(rr, ri, symbols, acting: list, parameters: FitParameters,
                   settings: SolverSettings) -> ReweightedFit:
    """Minimise ``sum |v_j|^2 / S_j`` by IPOPT (exact Hessian, inside the bounds), ``S_j``
    re-estimated as the mean square of each channel's residuals until they settle.

    Parameters
    ----------
    rr, ri : SX, shape (channels, F)
        The residuals' real and imaginary parts.
    symbols : SX, shape (n,)
        The parameters they depend on.
    acting : list of int
        The parameters estimated (the others are held at their nominal values).
    parameters : FitParameters
    settings : SolverSettings

    Returns
    -------
    ReweightedFit
    """
    free = ca.vertcat(*[symbols[i] for i in acting])
    nominal = np.asarray(parameters.nominal, dtype=float)
    rr, ri = held_at_nominal(rr, ri, symbols, acting, nominal)
    channels = rr.size1()
    weights = ca.SX.sym("weights", channels)
    cost = 0.5 * ca.sum1(ca.sum2((rr**2 + ri**2) * ca.repmat(weights, 1, rr.size2())))
    scale = parameters.scales[acting]
    s = ca.SX.sym("s", len(acting))
    scaled = ca.substitute(cost, free, s * ca.DM(scale))
    solver = ca.nlpsol("frequency_domain", "ipopt", {"x": s, "p": weights, "f": scaled}, settings.nlpsol_options())
    spectra_fn = ca.Function("spectra", [free], [ca.sum2(rr**2 + ri**2) / rr.size2()])
    lb, ub = parameters.lower[acting] / scale, parameters.upper[acting] / scale
    x = np.clip(nominal[acting] / scale, lb, ub)
    S = np.asarray(spectra_fn(x * scale)).reshape(-1)
    notes, run = [], None
    for _ in range(MAX_ROUNDS):
        run = run_ipopt(solver, x0=x, lbx=lb, ubx=ub, p=1.0 / S)
        x = np.asarray(run.x, dtype=float).reshape(-1)
        S_new = np.maximum(np.asarray(spectra_fn(x * scale)).reshape(-1), 1e-300)
        settled = np.all(np.abs(S_new - S) <= 1e-9 * S_new)
        S = S_new
        if settled:
            break
    else:
        notes.append(Note(f"the residual spectra did not settle in {MAX_ROUNDS} rounds", NoteCode.NOT_VERIFIED))
    values = nominal.copy()
    values[acting] = x * scale
    inside = np.array([side is None for side in active_bounds(x * scale, lb * scale, ub * scale, scale, tol=1e-9)],
                      dtype=bool)
    return ReweightedFit(values, S, inside, notes, run.status)


def held_at_nominal(rr, ri, symbols, acting: list, nominal: np.ndarray) -> tuple:
    """The residual expressions with the parameters that do not act substituted by their nominal values."""
    fixed = [i for i in range(symbols.numel()) if i not in acting]
    if not fixed:
        return rr, ri
    held = ca.vertcat(*[symbols[i] for i in fixed])
    return tuple(ca.substitute(part, held, ca.DM(nominal[fixed])) for part in (rr, ri))


def residual_function(rr, ri, symbols, acting: list, values: np.ndarray, extra):
    """The residuals and their Jacobians as a function of the acting parameters and the inputs' extra delays.

    Parameters
    ----------
    rr, ri : SX, shape (channels, F)
    symbols : SX, shape (n,)
    acting : list of int
    values : ndarray, shape (n,)
        The held parameters' values (the acting ones are arguments).
    extra : SX, shape (n_inputs,)
        Each input's extra delay (s).

    Returns
    -------
    callable
        ``(acting values, extra delays) -> (vr, vi, Jr, Ji, Er, Ei)``: the residuals
        (channels, F) and their Jacobians in the acting parameters and in the extra delays,
        rows of ``vec`` (column-major: channels vary fastest).
    """
    rr, ri = held_at_nominal(rr, ri, symbols, acting, values)
    free = ca.vertcat(*[symbols[i] for i in acting])
    fn = ca.Function("residual_function", [free, extra],
                     [rr, ri, ca.jacobian(ca.vec(rr), free), ca.jacobian(ca.vec(ri), free),
                      ca.jacobian(ca.vec(rr), extra), ca.jacobian(ca.vec(ri), extra)])

    def evaluate(free_values, extra_values) -> tuple:
        return tuple(np.asarray(M) for M in fn(free_values, extra_values))
    return evaluate
