"""Filter error as flight-test practice formulates it (Maine and Iliff, SIAM J. Appl. Math. 41,
1981; Jategaonkar, *Flight Vehicle System Identification*, Ch. 5): the innovation formulation.

The unknowns are the model's parameters theta and the process-noise distribution F (diagonal,
``F F' = Q_c`` on the named states); the measurement noise is not a decision variable. Instead
the *innovation* covariance R is estimated in closed form from the innovations, and a
relaxation alternates Gauss-Newton on theta and F with R held, the update of R and the
compensation of F (:mod:`casest.filter_error.relaxation`). This module holds the pieces:
the gain and the innovations over a record as CasADi functions, and Eq. 5.41's compensation.

The gain is the steady-state one of the model linearised at an operating point: the first state
and input, as the textbook's program does (``operating_point="first"``), or the time-average of
the predicted states and the inputs, renewed after every round (``"mean"``). ``P`` solves the
textbook's continuous Riccati equation ``A P + P A' - P C' R^-1 C P / dt + F F' = 0``
(Newton-Kleinman steps from the discrete equation's solution) and ``K = P C' R^-1``. The states
are propagated by the nonlinear model and corrected by K.

The graph (innovations, their sensitivities, ``diag(K C)`` and its Jacobian) is built once per model
structure, number of samples and set of noisy states; the record, the operating point and R are
its parameters, so a second estimate with the same model skips the build.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..options import OperatingPoint, choices
from .._casadi.memory import StructureCache
from ..data.dataset import Dataset
from ..models.dynamic import DynamicModel
from ..filters.ekf_model import ekf_step_functions
from .gain_sensitivities import gain_pass_derivatives
from .steady import check_steady_data, doubling, steady_record_columns, steady_step

__all__ = ["innovation_gain", "compensate_process_noise", "InnovationProblem", "OPERATING_POINTS"]

#: Riccati doublings (each squares the steps it stands for) of the discrete start
DOUBLINGS = 16
#: Newton-Kleinman steps on the continuous Riccati equation (quadratic convergence from the start)
NEWTON_STEPS = 8
#: where the gain is linearised: the first state and input, or the mean predicted state and input
OPERATING_POINTS = choices(OperatingPoint)

_GAINS = StructureCache()
_PROBLEMS = StructureCache()


def innovation_gain(model: DynamicModel) -> ca.Function:
    """``(theta, f, R_inv, x_ref, u_ref, dt) -> (K, P, C)``: the steady gain of the innovation
    formulation at the reference point (built once per model structure).

    Parameters
    ----------
    model : DynamicModel

    Returns
    -------
    casadi.Function
        ``f``: the diagonal of F, shape (n_states,); ``R_inv``: the inverse innovation covariance,
        shape (n_outputs, n_outputs); ``dt``: the sampling interval (s).
    """
    cache = _GAINS.setdefault(model, {})
    if "gain" not in cache:
        cache["gain"] = _build_gain(model)
    return cache["gain"]


def _build_gain(model: DynamicModel) -> ca.Function:
    propagate, measure = ekf_step_functions(model)
    n, nu, ny = model.n_states, len(model.inputs), model.n_outputs
    theta, f, Ri = ca.SX.sym("theta", model.n_parameters), ca.SX.sym("f", n), ca.SX.sym("R_inv", ny, ny)
    x_ref, u_ref, dt = ca.SX.sym("x_ref", n), ca.SX.sym("u_ref", nu), ca.SX.sym("dt")
    u_held = ca.repmat(u_ref, model.step_function.size1_in(1) // nu, 1) if nu else ca.SX(0, 1)
    _, Qd, Phi = propagate(x_ref, ca.SX.zeros(n, n), u_held, u_held, dt, theta, ca.diag(f**2), u_ref, ca.SX.zeros(nu))
    _, C = measure(x_ref, u_ref, theta)
    H = doubling(Phi.T, ca.mtimes([C.T, Ri, C]), Qd, DOUBLINGS)  # the discrete equation: Newton's start
    eye = ca.SX.eye(n)
    # the textbook's continuous equation A P + P A' - P M P + F F' = 0, M = C' R^-1 C / dt, by
    # Newton-Kleinman: each step the Lyapunov equation (A - P M) X + X (A - P M)' = -(F F' + P M P)
    Ac = ca.jacobian(model.rhs_function(x_ref, u_ref, theta), x_ref)
    M, FF = ca.mtimes([C.T, Ri, C]) / dt, ca.diag(f**2)
    P = H
    for _ in range(NEWTON_STEPS):
        closed = Ac - ca.mtimes(P, M)
        lyapunov = ca.kron(eye, closed) + ca.kron(closed, eye)
        P = ca.reshape(ca.solve(lyapunov, -ca.vec(FF + ca.mtimes([P, M, P]))), n, n)
        P = 0.5 * (P + P.T)
    K = ca.mtimes([P, C.T, Ri])
    return ca.Function("innovation_gain", [theta, f, Ri, x_ref, u_ref, dt], [K, P, C],
                       ["theta", "f", "R_inv", "x_ref", "u_ref", "dt"], ["K", "P", "C"])


def compensate_process_noise(f: np.ndarray, C: np.ndarray, R_old: np.ndarray, R_new: np.ndarray) -> np.ndarray:
    """Jategaonkar's Eq. 5.41: F revised for the change of the innovation covariance.

    Parameters
    ----------
    f : ndarray, shape (n_states,)
        The diagonal of F before the revision.
    C : ndarray, shape (n_outputs, n_states)
        The linearised observation matrix.
    R_old, R_new : ndarray, shape (n_outputs, n_outputs)
        The innovation covariance before and after its update.

    Returns
    -------
    ndarray, shape (n_states,)
    """
    ri_old, ri_new = np.diag(np.linalg.inv(R_old)), np.diag(np.linalg.inv(R_new))
    weight = (C**2).T @ ri_old
    with np.errstate(invalid="ignore", divide="ignore"):
        factor = ((C**2).T @ (ri_old * np.sqrt(ri_old / ri_new))) / weight
    return np.where(weight > 0, f * factor, f)


class InnovationProblem:
    """The innovation formulation over N samples as CasADi functions of ``w`` and ``p``.

    ``w = [theta / scales; f of the noisy states]``;
    ``p = [vec(R); vec(D); last; x0 data; x_ref; u_ref; dt; f of every state]`` (the last used
    where a state is not noisy). Built once per model structure, N and noisy set
    (:meth:`of`).
    """

    def __init__(self, model: DynamicModel, N: int, noisy: tuple):
        step, last_fn = steady_step(model)
        n, nu, ny, npar = model.n_states, len(model.inputs), model.n_outputs, model.n_parameters
        self.model, self.N, self.noisy = model, N, noisy
        w = ca.MX.sym("w", npar + len(noisy))
        R, D = ca.MX.sym("R", ny, ny), ca.MX.sym("D", step.size1_in(1), N - 1)
        last, d0 = ca.MX.sym("last", nu + ny), ca.MX.sym("x0_data", len(model.initial_from_data))
        x_ref, u_ref, dt, f_all = ca.MX.sym("x_ref", n), ca.MX.sym("u_ref", nu), ca.MX.sym("dt"), ca.MX.sym("f", n)
        theta = w[:npar] * ca.DM(model.scales)
        f = ca.vertcat(*[w[npar + noisy.index(i)] if i in noisy else f_all[i] for i in range(n)])
        Ri = ca.inv(R)
        K, P, C = innovation_gain(model)(theta, f, Ri, x_ref, u_ref, dt)
        x0 = model.initial_function(theta, d0)
        acc, dk = ca.MX.sym("acc", n), ca.MX.sym("d", D.shape[0])
        th_s, K_s, Ri_s = ca.MX.sym("th", npar), ca.MX.sym("K", n, ny), ca.MX.sym("Ri", ny, ny)
        xn, _, ek = step(acc, dk, th_s, K_s, Ri_s)
        advance = ca.Function("innovation_advance", [acc, dk, th_s, K_s, Ri_s], [xn, ek])
        X, E = advance.mapaccum("innovation_run", N - 1)(x0, D, ca.repmat(theta, 1, N - 1), ca.repmat(K, 1, N - 1),
                                                          ca.repmat(Ri, 1, N - 1))
        X = ca.horzcat(x0, X)
        _, e_last = last_fn(X[:, -1], last, theta, Ri)
        E = ca.horzcat(E, e_last)
        self.w, self.p = w, ca.vertcat(ca.vec(R), ca.vec(D), last, d0, x_ref, u_ref, dt, f_all)
        self.derivatives = gain_pass_derivatives(model, self.w, self.p, E, ca.vec(R), (theta, K, x0), ny * ny)
        self.values = ca.Function("innovation_values", [self.w, self.p], [E, ca.diag(ca.mtimes(K, C)), C, P, X, K])
        self._kc, self._constraint = ca.diag(ca.mtimes(K, C)), None

    @classmethod
    def of(cls, model: DynamicModel, N: int, noisy: tuple) -> "InnovationProblem":
        """The problem of this model structure, N and noisy set (built on first use).

        Parameters
        ----------
        model : DynamicModel
        N : int
            Samples of the record (at least 2).
        noisy : tuple of int
            The states whose F is estimated.

        Returns
        -------
        InnovationProblem
        """
        cache = _PROBLEMS.setdefault(model, {})
        key = (int(N), tuple(noisy))
        if key not in cache:
            cache[key] = cls(model, int(N), tuple(noisy))
        return cache[key]

    def parameters(self, data, R: np.ndarray, x_ref: np.ndarray, u_ref: np.ndarray,
                   f_all: np.ndarray) -> np.ndarray:
        """The parameter vector ``p`` of a record.

        Parameters
        ----------
        data : Dataset or tuple
            Uniformly sampled, complete outputs, ``N`` samples; or its :meth:`record_part`,
            computed once for the many ``p`` of one estimate.
        R : ndarray, shape (n_outputs, n_outputs)
            The innovation covariance.
        x_ref : ndarray, shape (n_states,)
        u_ref : ndarray, shape (n_inputs,)
            The operating point of the gain.
        f_all : ndarray, shape (n_states,)
            F of every state (used for the states not estimated).

        Returns
        -------
        ndarray
        """
        record, dt = self.record_part(data) if isinstance(data, Dataset) else data
        return np.concatenate([np.asarray(R, dtype=float).reshape(-1, order="F"), record, x_ref, u_ref, [dt], f_all])

    def record_part(self, data: Dataset) -> tuple[np.ndarray, float]:
        """The record's share of ``p`` (``[vec(D); last; x0 data]``) and its sampling interval (s)."""
        dt = check_steady_data(self.model, data)
        D, last = steady_record_columns(self.model, data)
        return np.concatenate([D.reshape(-1, order="F"), last, self.model.initial_values(data)]), dt

    def constraint(self) -> ca.Function:
        """``(w, p) -> (diag(K C), its Jacobian in w)`` (built on first use)."""
        if self._constraint is None:
            self._constraint = ca.Function("innovation_kc", [self.w, self.p], [self._kc, ca.jacobian(self._kc, self.w)])
        return self._constraint
