"""Recursive filter-error maximum likelihood (summary Sec. 5.3, Eq. 5.10-5.13 with the extended
Kalman filter's prediction errors): the parameters of a :class:`casest.DynamicModel` with
process noise, estimated online.

Each sample's prediction error ``e = y - h(x(k|k-1), u, theta)`` and its covariance
``Lambda = H P(k|k-1) H' + R`` come from the EKF run with the current estimate; their parameter
derivatives from the filter's state and covariance sensitivities ``dx(k|k-1)/dtheta`` and
``dP(k|k-1)/dtheta``, propagated beside the filter through the exact CasADi derivatives of one
EKF step (update and prediction). The sample adds ``de' Lambda^-1 e + 1/2 (eta - mu)`` to the
gradient (Eq. 5.10) and ``de' Lambda^-1 de + 1/2 tr(Lambda^-1 dLambda_i Lambda^-1 dLambda_j)``
to the information (Eq. 5.11's Fisher form; one output: the summary's ``1/2 eta eta'``), and
one Newton step moves the estimate. The process-noise intensity and R are given (the batch
:func:`casest.filter_error_estimate` estimates them).
"""

from __future__ import annotations

from typing import Mapping

import casadi as ca
import numpy as np

from .._casadi.memory import StructureCache
from ..checks import covariance_argument, finite_array, information_argument
from ..data.dataset import Dataset
from ..estimation.uncertainty import std_from_information
from ..models import OptionError
from ..models.dynamic import DynamicModel
from ..filters.ekf_model import ekf_step_functions
from ..filters.model_filter import process_noise_matrix

__all__ = ["RecursiveFilterErrorML"]

#: one filter sample with its parameter derivatives, per model structure
_SAMPLE_FUNCTIONS = StructureCache()


def _sample_function(model: DynamicModel) -> ca.Function:
    """One sample of the filter with the total parameter derivatives of its innovation, innovation
    covariance, and next state and covariance (cached on the model)."""
    cache = _SAMPLE_FUNCTIONS.setdefault(model, {})
    if "sample" in cache:
        return cache["sample"]
    propagate, measure = ekf_step_functions(model)
    n, ny, nu, q = model.n_states, model.n_outputs, len(model.inputs), model.n_parameters
    nuk = model.step_function.size1_in(1)
    x, P, theta = ca.SX.sym("x", n), ca.SX.sym("P", n, n), ca.SX.sym("theta", q)
    Sx, SP = ca.SX.sym("Sx", n, q), ca.SX.sym("SP", n * n, q)
    y, m, u = ca.SX.sym("y", ny), ca.SX.sym("m", ny), ca.SX.sym("u", nu)
    ua, ub, dt = ca.SX.sym("u_a", nuk), ca.SX.sym("u_b", nuk), ca.SX.sym("dt")
    Qc, R = ca.SX.sym("Qc", n, n), ca.SX.sym("R", ny, ny)
    h, H = measure(x, u, theta)
    M = ca.diag(m)
    Hm = ca.mtimes(M, H)
    e = m * (y - h)
    Rm = ca.mtimes([M, R, M]) + ca.diag(1 - m)
    Lam = ca.mtimes([Hm, P, Hm.T]) + Rm
    K = ca.solve(Lam, ca.mtimes(Hm, P)).T
    I_KH = ca.SX.eye(n) - ca.mtimes(K, Hm)
    P_post = ca.mtimes([I_KH, P, I_KH.T]) + ca.mtimes([K, Rm, K.T])
    x_next, P_next, _ = propagate(x + ca.mtimes(K, e), 0.5 * (P_post + P_post.T), ua, ub, dt, theta, Qc, u,
                                  ca.SX.zeros(nu))
    z = ca.vertcat(x, ca.vec(P))

    def total(expr):  # d expr / d theta through x(theta), P(theta) and theta itself
        return ca.mtimes(ca.jacobian(expr, z), ca.vertcat(Sx, SP)) + ca.jacobian(expr, theta)

    P_next = 0.5 * (P_next + P_next.T)
    cache["sample"] = ca.Function(
        "rfem_sample", [x, P, Sx, SP, theta, y, m, u, ua, ub, dt, Qc, R],
        [e, Lam, total(e), total(ca.vec(Lam)), x_next, P_next, total(x_next), total(ca.vec(P_next))])
    return cache["sample"]


class RecursiveFilterErrorML:
    """Online filter-error ML of a dynamic model's parameters, one sample at a time (module docstring).

    Parameters
    ----------
    model : DynamicModel
    theta0 : mapping or array_like, shape (n_parameters,)
        The start (physical units, inside the bounds).
    process_noise : mapping, array_like (n,) or (n, n)
        Continuous process-noise intensity on the states' rhs (held).
    R : array_like, shape (n_outputs,) or (n_outputs, n_outputs)
        Measurement-noise covariance (held).
    P0 : array_like, shape (n,) or (n, n), optional
        Covariance of the initial state (default zero).
    information0 : array_like, shape (n_parameters,) or (n_parameters, n_parameters), optional
        Initial information of theta (default 1e-6 on the diagonal, an almost flat prior).
    forgetting, forgetting_rate : float, optional
        lambda(0) and r of the schedule lambda(k+1) = r lambda(k) + 1 - r that discounts the first
        samples' information (as :class:`casest.recursive.RecursiveML`); default none.

    Attributes
    ----------
    theta : ndarray, shape (n_parameters,)
    information : ndarray, shape (n_parameters, n_parameters)
    n_samples : int
    """

    def __init__(self, model: DynamicModel, theta0, process_noise, R, P0=None, information0=None,
                 forgetting=None, forgetting_rate: float = 0.99):
        if not isinstance(model, DynamicModel):
            raise OptionError("RecursiveFilterErrorML needs a casest.DynamicModel (states, rhs, outputs)")
        self.model = model
        q, n = model.n_parameters, model.n_states
        theta = model.vector(theta0) if isinstance(theta0, Mapping) else theta0
        self.theta = finite_array(theta, "theta0", shape=(q,), error=OptionError).copy()
        outside = [nm for nm, v, lo, hi in zip(model.parameter_names, self.theta, model.lower_bounds,
                                                model.upper_bounds) if not lo <= v <= hi]
        if outside:
            raise OptionError(f"theta0 of {outside} lies outside the bounds; start inside them")
        self.Qc = process_noise_matrix(model, process_noise)
        self.R = covariance_argument(R, model.n_outputs, "R")
        self.P0 = np.zeros((n, n)) if P0 is None else covariance_argument(P0, n, "P0")
        self.information = information_argument(information0, q)
        self.forgetting = 1.0 if forgetting is None else float(forgetting)
        self.forgetting_rate = float(forgetting_rate)
        self._sample = _sample_function(model)
        self.n_samples = 0
        self.x = self.P = self.Sx = self.SP = None

    @property
    def std(self) -> np.ndarray:
        """Standard deviations of theta from the accumulated information, shape (n_parameters,):
        NaN while the information is singular or indefinite."""
        return std_from_information(self.information)

    def start(self, data: Dataset) -> None:
        """Set the filter at the record's first sample (the model's initial state at the current theta).

        Parameters
        ----------
        data : Dataset

        Returns
        -------
        None
        """
        n, q = self.model.n_states, self.model.n_parameters
        self.x = np.asarray(self.model.initial_function(self.theta, self.model.initial_values(data))).reshape(-1)
        self.P = self.P0.copy()
        self.Sx, self.SP = np.zeros((n, q)), np.zeros((n * n, q))

    def run(self, data: Dataset) -> np.ndarray:
        """Feed a record sample by sample from its start.

        Parameters
        ----------
        data : Dataset
            The model's record (time, inputs, outputs; NaN outputs are skipped).

        Returns
        -------
        ndarray, shape (N, n_parameters)
            The estimate after each sample.
        """
        model = self.model
        model.check_data(data)
        self.start(data)
        t, U, Y = data.signals[:, 0], data.signals[:, 1:], data.outputs
        N, nuk = data.n_samples, model.step_function.size1_in(1)
        Ua, Ub, dt = np.zeros((N, nuk)), np.zeros((N, nuk)), np.zeros(N)  # the last sample: a step of length 0
        if N > 1:
            Ua[:-1], Ub[:-1] = model.interval_input_values(U)
            dt[:-1] = np.diff(t)
        history = np.empty((N, model.n_parameters))
        for k in range(N):
            history[k] = self.update(Y[k], U[k], Ua[k], Ub[k], dt[k])
        return history

    def update(self, y, u, u_a, u_b, dt: float) -> np.ndarray:
        """One sample: its gradient and information terms, one Newton step, and the filter (with
        its sensitivities) moved to the next sample over ``dt``.

        Parameters
        ----------
        y : array_like, shape (n_outputs,)
            NaN: a channel not measured.
        u : array_like, shape (n_inputs,)
        u_a, u_b : array_like
            The integration step's inputs for the interval to the next sample.
        dt : float
            The interval (s).

        Returns
        -------
        ndarray, shape (n_parameters,)
            The estimate after the sample.
        """
        if self.x is None:
            raise OptionError("call start(data) or run(data) first: the filter needs the record's initial state")
        y = np.asarray(y, dtype=float).reshape(-1)
        seen = np.isfinite(y)
        ny, q = self.model.n_outputs, self.model.n_parameters
        out = self._sample(self.x, self.P, self.Sx, self.SP, self.theta, np.where(seen, y, 0.0), seen.astype(float),
                           np.asarray(u, dtype=float).reshape(-1), u_a, u_b, float(dt), self.Qc, self.R)
        e, Lam, de, dLam, x_next, P_next, Sx_next, SP_next = (np.asarray(v) for v in out)
        e = e.reshape(-1)
        Lam_inv = np.linalg.inv(Lam)
        dL = dLam.reshape(ny, ny, q, order="F")
        Li_dL = np.einsum("ab,bcq->acq", Lam_inv, dL)
        eta = np.einsum("aaq->q", Li_dL)                                    # Eq. 5.12
        mu = np.einsum("a,abq,b->q", e, np.einsum("acq,cb->abq", Li_dL, Lam_inv), e)  # Eq. 5.13
        grad = de.T @ Lam_inv @ e + 0.5 * (eta - mu)                        # Eq. 5.10's new terms
        self.information *= self.forgetting
        self.forgetting = self.forgetting_rate * self.forgetting + (1.0 - self.forgetting_rate)
        self.information += de.T @ Lam_inv @ de + 0.5 * np.einsum("abq,bar->qr", Li_dL, Li_dL)  # Eq. 5.11
        step = np.linalg.solve(self.information, grad)
        self.theta = np.clip(self.theta - step, self.model.lower_bounds, self.model.upper_bounds)
        self.x, self.P, self.Sx, self.SP = x_next.reshape(-1), P_next, Sx_next, SP_next
        self.n_samples += 1
        return self.theta
