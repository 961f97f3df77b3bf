"""Filter-error ML by scoring: first derivatives of the innovations only (summary Sec. 5.2).

The filter-error likelihood of either formulation is a function of the innovations ``e_k``
and their covariances ``S_k``::

    V = 1/2 sum_k [ e_k' S_k^-1 e_k + ln det S_k ]

Its gradient and Fisher information need only ``de_k/dw`` and ``dS_k/dw`` (forward
sensitivities through the filter, by CasADi's AD of the recursion)::

    dV/dw_i = sum_k [ a_k' de_k,i - 1/2 a_k' dS_k,i a_k + 1/2 tr(S_k^-1 dS_k,i) ],   a_k = S_k^-1 e_k
    F_ij    = sum_k [ de_k,i' S_k^-1 de_k,j + 1/2 tr(S_k^-1 dS_k,i S_k^-1 dS_k,j) ]

Scoring (Gauss-Newton for a likelihood with parameter-dependent covariance) takes the
Levenberg-Marquardt step ``(F + lambda diag F) delta = -dV/dw`` within the bounds, keeps it
when V falls, and stops when the decrement ``g' F^-1 g`` is below 1e-12 (1e-6 std from the
optimum); when no step lowers V any more (its rounding) and the decrement is below 1e-8 (1e-4
std), the point is accepted as ``"Solved_To_Rounding"``. The inverse of F is the Cramer-Rao bound that flight-test programs report; the
exact gradient makes the optimum that of the exact-Hessian path.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..backend.ipopt import IpoptRun
from ..estimation.gauss_newton import (DECREMENT_TOL, ROUNDING_DECREMENT, damped_step, decrement,
                                             free_parameters, levenberg_marquardt_step)

__all__ = ["InnovationGraph", "InnovationDerivatives", "score", "fisher_information", "polish", "likelihood_terms"]

#: a polish stops when the decrement is below this (1e-9 std from the optimum) ...
POLISH_DECREMENT = 1e-18
#: ... or after this many full steps
POLISH_STEPS = 6



@dataclass
class InnovationGraph:
    """A filter-error likelihood as a CasADi graph.

    Attributes
    ----------
    symbols : tuple of casadi.MX
        ``(theta, q, r, D, last, x0_data)``.
    V : casadi.MX
        The likelihood (no constants).
    E : casadi.MX, shape (n_y, N)
        The innovations (0 in missing channels).
    S : casadi.MX, shape (n_y^2, N) or (n_y^2, 1)
        vec of each sample's innovation covariance (identity rows and columns in missing
        channels), or one column when it is the same for every sample (the steady-state form).
    X : casadi.MX or None
        The predicted states (n_states x N), where the formulation needs them.
    point : tuple of casadi.MX
        Further parameters of the graph after the record's (the steady-state form's operating
        point ``(x_ref, u_ref, dt)``).
    gain_pass : tuple of casadi.MX
        ``(theta, K, x0)`` of a constant-gain pass (the steady-state form), whose innovations'
        derivatives a compiled loop can give (:mod:`casest.filter_error.gain_sensitivities`); empty
        otherwise.
    filter_pass : tuple
        ``(theta, q, r, x0, P0)`` of the time-varying filter (P0 numeric), whose innovations'
        derivatives a compiled loop can give (:mod:`casest.filter_error.sensitivities`); empty
        otherwise.
    """

    symbols: tuple
    V: ca.MX
    E: ca.MX
    S: ca.MX
    X: ca.MX | None = None
    point: tuple = ()
    gain_pass: tuple = ()
    filter_pass: tuple = ()


class InnovationDerivatives:
    """``(w, p) -> (E, S, dE/dw, dS/dw)`` of a graph whose E and S are expressions of the decision vector w."""

    def __init__(self, w: ca.MX, p: ca.MX, E: ca.MX, S: ca.MX):
        self.ny, self.N, self.nw = E.size1(), E.size2(), w.numel()
        self.constant_S = S.size2() == 1 and self.N > 1  # one covariance for all samples: broadcast
        self.function = ca.Function("innovation_derivatives", [w, p],
                                    [E, S, ca.jacobian(ca.vec(E), w), ca.jacobian(ca.vec(S), w)])
        self.innovations = ca.Function("innovations", [w, p], [E, S])

    def value(self, w: np.ndarray, p: np.ndarray) -> float:
        """V at ``w`` from the innovations alone (no derivatives): inf where the filter diverges or
        an innovation covariance is not positive definite."""
        E, S = (np.asarray(ca.densify(v), dtype=float) for v in self.innovations(w, p))
        ny, N = self.ny, self.N
        S = S.T.reshape(-1, ny, ny)
        if not (np.all(np.isfinite(E)) and np.all(np.isfinite(S))):
            return np.inf
        try:
            L = np.linalg.cholesky(S)
        except np.linalg.LinAlgError:  # not positive definite
            return np.inf
        if self.constant_S:
            a = np.linalg.solve(L[0], E)
            return 0.5 * float(np.sum(a * a)) + N * float(np.sum(np.log(np.diagonal(L[0]))))
        a = np.linalg.solve(L, E.T[:, :, None])[..., 0]
        return 0.5 * float(np.sum(a * a)) + float(np.sum(np.log(np.diagonal(L, axis1=1, axis2=2))))

    def __call__(self, w: np.ndarray, p: np.ndarray) -> tuple:
        """The innovations and their derivatives at ``w``.

        Returns
        -------
        E : ndarray, shape (N, n_y)
        S : ndarray, shape (N, n_y, n_y)
        dE : ndarray, shape (N, n_y, n_w)
        dS : ndarray, shape (N, n_y, n_y, n_w)
        """
        E, S, dE, dS = (np.asarray(ca.densify(v), dtype=float) for v in self.function(w, p))
        ny, N, nw = self.ny, self.N, self.nw
        if self.constant_S:
            S, dS = np.repeat(S.T, N, axis=0), np.broadcast_to(dS[None], (N,) + dS.shape)
        else:
            S = S.T
        # vec(E) is column-major: sample k's channels together
        return (E.T, S.reshape(N, ny, ny), dE.reshape(N, ny, nw), dS.reshape(N, ny, ny, nw))


def _value_gradient_information(E, S, dE, dS):
    """V, dV/dw and the Fisher information from the innovations and their derivatives (the sums over
    samples as matrix products: ``einsum`` of the same was the largest cost after the filter pass)."""
    N, ny, nw = dE.shape
    Si = np.linalg.inv(S)
    a = np.matmul(Si, E[:, :, None])[:, :, 0]
    _, logdet = np.linalg.slogdet(S)
    V = 0.5 * float(np.sum(a * E) + np.sum(logdet))
    B = np.matmul(Si, np.reshape(dS, (N, ny, ny * nw))).reshape(N, ny, ny, nw)  # S^-1 dS_i
    outer = (a[:, :, None] * a[:, None, :]).reshape(1, N * ny * ny)
    grad = (a.reshape(1, N * ny) @ dE.reshape(N * ny, nw) - 0.5 * outer @ np.reshape(dS, (N * ny * ny, nw)))[0]
    grad = grad + 0.5 * np.trace(B, axis1=1, axis2=2).sum(axis=0)
    SidE = np.matmul(Si, dE)
    F = dE.reshape(N * ny, nw).T @ SidE.reshape(N * ny, nw)
    F = F + 0.5 * B.reshape(N * ny * ny, nw).T @ B.transpose(0, 2, 1, 3).reshape(N * ny * ny, nw)
    return V, grad, 0.5 * (F + F.T)


def likelihood_terms(derivatives: InnovationDerivatives, w: np.ndarray, p: np.ndarray) -> tuple:
    """V, its gradient and the Fisher information at ``w``.

    Returns
    -------
    V : float
    gradient : ndarray, shape (n_w,)
    information : ndarray, shape (n_w, n_w)
    """
    return _value_gradient_information(*derivatives(w, p))


def fisher_information(derivatives: InnovationDerivatives, w: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The Fisher information of the decision vector at ``w``, shape (n_w, n_w)."""
    return _value_gradient_information(*derivatives(w, p))[2]


def score(derivatives: InnovationDerivatives, p: np.ndarray, w0: np.ndarray, lower: np.ndarray, upper: np.ndarray,
          max_iter: int) -> tuple[IpoptRun, np.ndarray]:
    """Minimise V by bounded scoring from ``w0``.

    Returns
    -------
    run : IpoptRun
        The last iterate, V / N there, ``"Solve_Succeeded"`` / ``"Maximum_Iterations_Exceeded"`` /
        ``"Stalled"``, success and the accepted steps.
    information : ndarray, shape (n_w, n_w)
        The Fisher information at the last iterate.
    """
    N = derivatives.N
    w = np.clip(np.asarray(w0, dtype=float), lower, upper)
    V, g, F = _value_gradient_information(*derivatives(w, p))
    damping, iterations, status = 1e-3, 0, "Maximum_Iterations_Exceeded"
    while iterations < max_iter:
        free = free_parameters(w, lower, upper, -g)
        if decrement(F, -g, free) <= DECREMENT_TOL:
            status = "Solve_Succeeded"
            break

        def lowers_v(trial, V=V):
            if not derivatives.value(trial, p) < V:  # the cheap test first: most trials of a search fail it
                return None
            parts = derivatives(trial, p)
            if not (np.all(np.isfinite(parts[0])) and np.all(np.linalg.eigvalsh(parts[1]) > 0)):
                return None  # a diverging filter or an indefinite innovation covariance
            V_t, g_t, F_t = _value_gradient_information(*parts)
            return (trial, V_t, g_t, F_t) if np.isfinite(V_t) and V_t < V else None

        accepted, damping, _ = damped_step(w, F, -g, free, (lower, upper), damping, lowers_v)
        if accepted is None:
            status = "Stalled"
            break
        (w, V, g, F), iterations = accepted, iterations + 1
    success = status == "Solve_Succeeded"
    if status == "Stalled" and decrement(F, -g, free_parameters(w, lower, upper, -g)) <= ROUNDING_DECREMENT:
        # V (some 1e4 here) cannot resolve a decrease below ~1e-11: the point is within 1e-4 std of the optimum
        status, success = "Solved_To_Rounding", True
    return IpoptRun(x=w, f=V / N, status=status, success=success, iterations=iterations), F


def polish(derivatives: InnovationDerivatives, p: np.ndarray, w: np.ndarray, lower: np.ndarray,
           upper: np.ndarray) -> tuple[np.ndarray, int]:
    """Full Gauss-Newton steps from a scoring optimum while its decrement falls, to 1e-9 std.

    Scoring stops at a decrement of 1e-12 (1e-6 std) or where V, rounded, no longer falls; an
    algorithm that alternates such solves with other updates (the innovation formulation's
    relaxation) needs its fixed point more exactly. Near the optimum the undamped step is safe;
    it is taken while the decrement it leaves is smaller than the one before.

    Parameters
    ----------
    derivatives : InnovationDerivatives
    p : ndarray
        The graph's parameters.
    w : ndarray, shape (n_w,)
        The scoring optimum.
    lower, upper : ndarray, shape (n_w,)

    Returns
    -------
    w : ndarray, shape (n_w,)
    steps : int
        The steps taken.
    """
    _, g, F = _value_gradient_information(*derivatives(w, p))
    free = free_parameters(w, lower, upper, -g)
    left, steps = decrement(F, -g, free), 0
    while left > POLISH_DECREMENT and steps < POLISH_STEPS:
        trial = np.clip(w + levenberg_marquardt_step(F, -g, free, 0.0), lower, upper)
        parts = derivatives(trial, p)
        if not np.all(np.isfinite(parts[0])):
            break
        _, g_t, F_t = _value_gradient_information(*parts)
        free_t = free_parameters(trial, lower, upper, -g_t)
        left_t = decrement(F_t, -g_t, free_t)
        if not left_t < left:
            break
        w, g, F, free, left, steps = trial, g_t, F_t, free_t, left_t, steps + 1
    return w, steps
