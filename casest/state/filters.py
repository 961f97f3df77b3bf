"""State estimation: Kalman filter, prediction and smoothing; EKF and IEKF on a DynamicModel.

Reference summary Sec. 2-3:

- :class:`KalmanFilter`: the discrete-time linear system of Eq. 2.1-2.2 with the filter of
  Eq. 2.7-2.11 (Joseph form of Eq. 2.10), prediction ahead (Eq. 2.12-2.13), batch or step by
  step.
- :class:`ExtendedKalmanFilter`: a :class:`casest.DynamicModel` (states, rhs, outputs) with
  continuous white process noise ``G w`` of intensity ``Q`` on the rhs (Eq. 3.1-3.2),
  linearised by CasADi Jacobians. The state is predicted by the model's integration step
  (Eq. 3.10); the transition matrix Phi is the Jacobian of that step, which equals
  ``exp(F_x dt)`` of Eq. 3.9 to the integrator's order; the discrete process noise is the
  trapezoidal rule of its integral, ``Q_d = dt/2 (Phi G Q G' Phi' + G Q G')``. The iterated
  filter (``iterated=True``) repeats the measurement update of Eq. 3.15 until the
  relative change of Eq. 3.16 is below ``tol`` and uses the covariance of Eq. 3.18.
- :func:`rts_smoother`: the fixed-interval (Rauch-Tung-Striebel) smoother of Eq. 2.20 and
  2.22 on any :class:`FilterResult`.

Measurements that are missing (NaN) are skipped channel by channel: the update uses the
measured channels of the sample only, and a sample with none is a pure prediction.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from ..data.dataset import DataError, Dataset
from ..models import ModelError, OptionError
from ..models.dynamic import DynamicModel
from .compiled_passes import compiled_pass_applies, ekf_pass, kf_pass, rts_pass, singular_innovation
from .arguments import covariance_argument as _covariance, matrix_argument as _matrix
from .ekf_model import ekf_step_functions
from .smoothing import process_noise_smoothing, rts_loop


__all__ = ["FilterResult", "SmootherResult", "KalmanFilter", "ExtendedKalmanFilter", "rts_smoother",
           "process_noise_matrix", "measurement_update"]

LOG_2PI = float(np.log(2.0 * np.pi))


@dataclass
class FilterResult:
    """A filter's pass over a record of N samples.

    Attributes
    ----------
    x_predicted, P_predicted : ndarray, shapes (N, n) and (N, n, n)
        x(k|k-1) and P(k|k-1); row 0 is the initial (prior) state.
    x_filtered, P_filtered : ndarray, shapes (N, n) and (N, n, n)
        x(k|k) and P(k|k).
    transition : ndarray, shape (N-1, n, n)
        Phi(k+1, k) used from sample k to k+1.
    innovation : ndarray, shape (N, n_outputs)
        y(k) - y(k|k-1) (NaN where the channel is missing).
    innovation_covariance : ndarray, shape (N, n_outputs, n_outputs)
        Its covariance H P(k|k-1) H' + R (all channels).
    iterations : ndarray, shape (N,)
        Measurement-update iterations (1 for the plain filters, 0 without a measurement).
    log_likelihood : float
        ln p(y_0 .. y_N-1) of the measured channels from the prediction errors (Eq. 5.6 with
        its constants): ``-1/2 sum (e' S^-1 e + ln det S + q_k ln 2 pi)``.
    """

    x_predicted: np.ndarray
    P_predicted: np.ndarray
    x_filtered: np.ndarray
    P_filtered: np.ndarray
    transition: np.ndarray
    innovation: np.ndarray
    innovation_covariance: np.ndarray
    iterations: np.ndarray
    log_likelihood: float
    state_names: tuple = ()
    output_names: tuple = ()
    time: np.ndarray | None = field(default=None, repr=False)

    @property
    def std(self) -> np.ndarray:
        """Filtered state standard deviations, shape (N, n)."""
        return np.sqrt(np.maximum(np.diagonal(self.P_filtered, axis1=1, axis2=2), 0.0))

    def nees(self, truth: np.ndarray) -> np.ndarray:
        """Normalised estimation error squared of the filtered states, shape (N,).

        ``truth`` (N, n): the true states. For a consistent filter each value is chi-square
        distributed with n degrees of freedom.
        """
        return _nees(self.x_filtered, self.P_filtered, truth)


@dataclass
class SmootherResult:
    """x(k|N) and P(k|N) of the fixed-interval smoother, shapes (N, n) and (N, n, n); with the
    process noise given, also its smoothed values w(k|N), shape (N-1, p), and covariances
    Q(k|N), shape (N-1, p, p) (Eq. 2.21, 2.23; None otherwise)."""

    x: np.ndarray
    P: np.ndarray
    state_names: tuple = ()
    w: np.ndarray | None = None
    Q: np.ndarray | None = None

    @property
    def std(self) -> np.ndarray:
        """Smoothed state standard deviations, shape (N, n)."""
        return np.sqrt(np.maximum(np.diagonal(self.P, axis1=1, axis2=2), 0.0))

    def nees(self, truth: np.ndarray) -> np.ndarray:
        """Normalised estimation error squared of the smoothed states, shape (N,)."""
        return _nees(self.x, self.P, truth)


def _nees(x: np.ndarray, P: np.ndarray, truth: np.ndarray) -> np.ndarray:
    err = np.asarray(truth, dtype=float) - x
    if err.shape != x.shape:
        raise OptionError(f"truth must have shape {x.shape}, got {np.shape(truth)}")
    return np.einsum("ki,ki->k", err, np.linalg.solve(P, err[:, :, None])[:, :, 0])


def _joseph_update(x, P, y, h, H, R):
    """Measurement update with the measured channels of one sample (NaN in y: skipped).

    Returns x(k|k), P(k|k), the innovation (NaN where missing), S (all channels) and the
    sample's log-likelihood term.
    """
    ny = len(y)
    e = y - h
    S_full = H @ P @ H.T + R
    seen = np.isfinite(y)
    if not seen.any():
        return x, P, np.full(ny, np.nan), S_full, 0.0
    Ho, eo = H[seen], e[seen]
    S = S_full[np.ix_(seen, seen)]
    sign, logdet = np.linalg.slogdet(S)
    if sign <= 0 or not np.isfinite(logdet):
        raise singular_innovation()
    K = np.linalg.solve(S, Ho @ P).T  # P H' S^-1 (S symmetric)
    x_new = x + K @ eo
    I_KH = np.eye(len(x)) - K @ Ho
    P_new = I_KH @ P @ I_KH.T + K @ R[np.ix_(seen, seen)] @ K.T
    loglik = -0.5 * (eo @ np.linalg.solve(S, eo) + logdet + seen.sum() * LOG_2PI)
    return x_new, 0.5 * (P_new + P_new.T), np.where(seen, e, np.nan), S_full, loglik


def measurement_update(prior, P_prior, y, measure, R, iterated: bool = False, tol: float = 1e-8,
                       max_iterations: int = 20):
    """The EKF / IEKF measurement update (Eq. 3.12-3.14, or 3.15-3.18), NaN channels skipped.

    Parameters
    ----------
    prior : ndarray, shape (n,)
        x(k|k-1).
    P_prior : ndarray, shape (n, n)
    y : ndarray, shape (q,)
        Measurements (NaN: missing).
    measure : callable
        ``measure(x) -> (h, H)``: the predicted measurement (q,) and its Jacobian (q, n).
    R : ndarray, shape (q, q)
    iterated : bool
        Repeat the update linearised at the last iterate until the relative change of
        Eq. 3.16 is at most ``tol``; the covariance is Eq. 3.18's at the last iterate.

    Returns
    -------
    x, P, innovation (q,), S (q, q), log-likelihood term, iterations (0: nothing measured)
    """
    h, H = measure(prior)
    if not np.isfinite(y).any():
        return prior, P_prior, np.full(y.size, np.nan), H @ P_prior @ H.T + R, 0.0, 0
    x, P, e, S, ll = _joseph_update(prior, P_prior, y, h, H, R)
    iterations = 1
    if iterated:
        eta = prior
        for iterations in range(1, max_iterations + 1):
            h_i, H_i = measure(eta)
            # Eq. 3.15: the measurement linearised at eta, applied to the prior
            new, P, _, _, _ = _joseph_update(prior, P_prior, y, h_i + H_i @ (prior - eta), H_i, R)
            change = np.linalg.norm(new - eta) / max(np.linalg.norm(eta), 1e-300)
            eta = new
            if change <= tol:
                break
        h_l, H_l = measure(eta)  # Eq. 3.18 at the last iterate
        _, P, _, _, _ = _joseph_update(prior, P_prior, y, h_l + H_l @ (prior - eta), H_l, R)
        x = eta
    return x, P, e, S, ll, iterations


# ----------------------------------------------------------------------------- linear KF
class KalmanFilter:
    """The discrete-time Kalman filter of Eq. 2.1-2.11.

    ::

        x(k+1) = Phi x(k) + Psi u(k) + Gamma w(k),   cov w = Q
        y(k)   = C x(k) + D u(k) + v(k),             cov v = R

    Parameters
    ----------
    Phi : array_like, shape (n, n)
    C : array_like, shape (q, n)
    Q : array_like, shape (p, p) or (p,)
        Process-noise covariance (a vector: its diagonal).
    R : array_like, shape (q, q) or (q,)
        Measurement-noise covariance.
    x0 : array_like, shape (n,)
        Prior mean of the state at the first sample, x(0|-1).
    P0 : array_like, shape (n, n) or (n,)
        Its covariance.
    Psi : array_like, shape (n, m), optional
        Input matrix (default: no input).
    D : array_like, shape (q, m), optional
        Feed-through.
    Gamma : array_like, shape (n, p), optional
        Process-noise input (default identity, p = n).

    Notes
    -----
    Step by step: :meth:`update` with y(k) then :meth:`predict` with u(k) gives
    x(k+1|k); :meth:`filter` runs a whole record the same way (the first sample is updated
    from the prior ``x0, P0``).
    """

    def __init__(self, Phi, C, Q, R, x0, P0, Psi=None, D=None, Gamma=None):
        self.Phi = np.atleast_2d(np.asarray(Phi, dtype=float))
        n = self.Phi.shape[0]
        self.Phi = _matrix(self.Phi, (n, n), "Phi")
        self.C = np.atleast_2d(np.asarray(C, dtype=float))
        q = self.C.shape[0]
        self.C = _matrix(self.C, (q, n), "C")
        self.Gamma = np.eye(n) if Gamma is None else _matrix(np.atleast_2d(Gamma), (n, np.atleast_2d(Gamma).shape[1]),
                                                              "Gamma")
        self.Q = _covariance(Q, self.Gamma.shape[1], "Q")
        self.R = _covariance(R, q, "R")
        m = 0 if Psi is None else np.atleast_2d(np.asarray(Psi, dtype=float)).reshape(n, -1).shape[1]
        self.Psi = np.zeros((n, m)) if Psi is None else _matrix(np.asarray(Psi, dtype=float).reshape(n, m), (n, m), "Psi")
        self.D = np.zeros((q, m)) if D is None else _matrix(np.asarray(D, dtype=float).reshape(q, m), (q, m), "D")
        self.n_states, self.n_outputs, self.n_inputs = n, q, m
        self.x = _matrix(np.asarray(x0, dtype=float).reshape(-1), (n,), "x0").copy()
        self.P = _covariance(P0, n, "P0").copy()

    def _u(self, u) -> np.ndarray:
        if self.n_inputs == 0:
            return np.zeros(0)
        arr = np.asarray(u, dtype=float).reshape(-1)
        if arr.size != self.n_inputs:
            raise OptionError(f"u must have {self.n_inputs} values, got {arr.size}")
        return arr

    def predict(self, u=None) -> tuple[np.ndarray, np.ndarray]:
        """Time update (Eq. 2.7-2.8): x(k+1|k), P(k+1|k) from x(k|k), P(k|k) and u(k)."""
        self.x = self.Phi @ self.x + self.Psi @ self._u(u)
        self.P = self.Phi @ self.P @ self.Phi.T + self.Gamma @ self.Q @ self.Gamma.T
        return self.x, self.P

    def update(self, y, u=None) -> tuple[np.ndarray, np.ndarray]:
        """Measurement update (Eq. 2.9-2.11, Joseph form); NaN channels of y are skipped."""
        y = np.asarray(y, dtype=float).reshape(-1)
        h = self.C @ self.x + self.D @ self._u(u)
        self.x, self.P, *_ = _joseph_update(self.x, self.P, y, h, self.C, self.R)
        return self.x, self.P

    def predict_ahead(self, steps: int, u=None) -> tuple[np.ndarray, np.ndarray]:
        """Prediction i = 1..steps samples ahead of the current state (Eq. 2.12-2.13).

        ``u``: shape (steps, m) future inputs, or one input (m,) held (the summary's
        u(k+i) = u(k)), default zero. Returns means (steps, n) and covariances
        (steps, n, n); the filter's state is left unchanged.
        """
        U = np.zeros((steps, self.n_inputs)) if u is None else np.asarray(u, dtype=float)
        U = np.broadcast_to(U.reshape(-1, self.n_inputs) if U.ndim > 1 else U.reshape(1, -1), (steps, self.n_inputs))
        x, P = self.x.copy(), self.P.copy()
        xs, Ps = [], []
        GQG = self.Gamma @ self.Q @ self.Gamma.T
        for i in range(steps):
            x = self.Phi @ x + self.Psi @ U[i]
            P = self.Phi @ P @ self.Phi.T + GQG
            xs.append(x)
            Ps.append(P)
        return np.array(xs), np.array(Ps)

    def filter(self, y, u=None, compiled: bool = True) -> FilterResult:
        """Run over a record from the current state (the prior of the first sample).

        Parameters
        ----------
        y : array_like, shape (N, q)
            Measurements (NaN: missing channel).
        u : array_like, shape (N, m), optional
            Inputs; u(k) enters y(k) through D and x(k+1) through Psi.
        compiled : bool
            One compiled recursion over the record (:func:`casest.state.compiled_passes.kf_pass`);
            False: :meth:`update` and :meth:`predict` from Python. The same arrays either way.

        Returns
        -------
        FilterResult
            The filter's state afterwards is the last sample's x(k|k), P(k|k).
        """
        Y = np.atleast_2d(np.asarray(y, dtype=float))
        N = Y.shape[0]
        if Y.shape[1] != self.n_outputs:
            raise OptionError(f"y must have shape (N, {self.n_outputs}), got {Y.shape}")
        U = np.zeros((N, 0)) if self.n_inputs == 0 else np.asarray(u, dtype=float).reshape(N, self.n_inputs)
        if not np.all(np.isfinite(U)):
            raise DataError("the inputs u contain NaN or inf: the state cannot be propagated without them")
        if compiled and N:
            arrays = kf_pass(self, Y, U)
            self.x, self.P = arrays["x_filtered"][-1].copy(), arrays["P_filtered"][-1].copy()
            return FilterResult(**arrays)
        rec = _Recorder(N, self.n_states, self.n_outputs)
        for k in range(N):
            rec.prior(k, self.x, self.P)
            h = self.C @ self.x + self.D @ U[k]
            self.x, self.P, e, S, ll = _joseph_update(self.x, self.P, Y[k], h, self.C, self.R)
            rec.posterior(k, self.x, self.P, e, S, ll, int(np.isfinite(Y[k]).any()))
            if k < N - 1:
                rec.transition[k] = self.Phi
                self.predict(U[k])
        return rec.result()


class _Recorder:
    """Arrays of a filter pass, filled sample by sample."""

    def __init__(self, N: int, n: int, q: int, state_names=(), output_names=(), time=None):
        self.xp, self.Pp = np.empty((N, n)), np.empty((N, n, n))
        self.xf, self.Pf = np.empty((N, n)), np.empty((N, n, n))
        self.transition = np.empty((max(N - 1, 0), n, n))
        self.e, self.S = np.empty((N, q)), np.empty((N, q, q))
        self.iterations = np.zeros(N, dtype=int)
        self.loglik = 0.0
        self.names = (tuple(state_names), tuple(output_names))
        self.time = time

    def prior(self, k, x, P):
        self.xp[k], self.Pp[k] = x, P

    def posterior(self, k, x, P, e, S, loglik, iterations):
        self.xf[k], self.Pf[k], self.e[k], self.S[k] = x, P, e, S
        self.loglik += loglik
        self.iterations[k] = iterations

    def result(self) -> FilterResult:
        return FilterResult(self.xp, self.Pp, self.xf, self.Pf, self.transition, self.e, self.S, self.iterations,
                            float(self.loglik), self.names[0], self.names[1], self.time)


def rts_smoother(result: FilterResult, compiled: bool = True, process_noise=None, noise_input=None) -> SmootherResult:
    """Fixed-interval smoothing of a filter pass (Rauch-Tung-Striebel, Eq. 2.20 and 2.22).

    ``C_k = P(k|k) Phi' P(k+1|k)^-1``, ``x(k|N) = x(k|k) - C_k (x(k+1|k) - x(k+1|N))``,
    ``P(k|N) = P(k|k) - C_k (P(k+1|k) - P(k+1|N)) C_k'``, from k = N-2 down to 0.

    Parameters
    ----------
    result : FilterResult
    compiled : bool
        The backward recursion as one CasADi pass (:func:`casest.state.compiled_passes.rts_pass`);
        False: a NumPy loop. The same arrays either way.
    process_noise, noise_input : array_like, optional
        Q(k), shape (p, p) or (N-1, p, p), and Gamma(k), shape (n, p) or (N-1, n, p) (default
        identity): also smooth the process noise (:func:`casest.state.smoothing.process_noise_smoothing`).

    Returns
    -------
    SmootherResult
        x(k|N), shape (N, n), and P(k|N), shape (N, n, n); w(k|N) and Q(k|N) with ``process_noise``.
    """
    if not isinstance(result, FilterResult):
        raise OptionError(f"rts_smoother takes the FilterResult of a filter pass (KalmanFilter.filter or "
                          f"ExtendedKalmanFilter.filter), got {type(result).__name__}")
    xs, Ps = rts_pass(result) if compiled else rts_loop(result)
    w = Qs = None
    if process_noise is not None:
        w, Qs = process_noise_smoothing(result, xs, Ps, process_noise, noise_input)
    return SmootherResult(xs, Ps, result.state_names, w, Qs)


# ----------------------------------------------------------------------------- EKF / IEKF
def process_noise_matrix(model: DynamicModel, process_noise) -> np.ndarray:
    """The continuous process-noise intensity G Q G' as an (n, n) matrix.

    ``process_noise``: a mapping state name -> intensity (units of the state's rate squared
    per hertz; states not named get none), a vector (n,) of intensities, or a full (n, n)
    matrix.
    """
    n, names = model.n_states, list(model.state_names)
    if isinstance(process_noise, Mapping):
        unknown = [k for k in process_noise if k not in names]
        if unknown:
            raise ModelError(f"process noise for {unknown}, which are not states of {model.name!r}: {names}")
        q = np.array([float(process_noise.get(k, 0.0)) for k in names])
        if np.any(q < 0) or not np.all(np.isfinite(q)):
            raise OptionError(f"process-noise intensities must be finite and >= 0, got {q.tolist()}")
        return np.diag(q)
    arr = np.asarray(process_noise, dtype=float)
    if arr.ndim == 1:
        if np.any(arr < 0):
            raise OptionError("process-noise intensities must be >= 0")
        return _matrix(arr, (n, n), "process_noise")
    return _covariance(arr, n, "process_noise")


class ExtendedKalmanFilter:
    """EKF / iterated EKF on the states of a :class:`casest.DynamicModel` (summary Sec. 3).

    The parameters are given (``theta``); the states carry the uncertainty. Augmented
    states (sensor biases, wind) are declared as states with a zero rhs and process noise
    if they drift.

    Parameters
    ----------
    model : DynamicModel
    theta : mapping or array_like, shape (n_parameters,)
        Parameter values.
    process_noise : mapping, array_like (n,) or (n, n)
        Continuous white-noise intensity on the rhs (see :func:`process_noise_matrix`).
    R : array_like, shape (n_outputs,) or (n_outputs, n_outputs)
        Measurement-noise covariance.
    P0 : array_like, shape (n,) or (n, n)
        Covariance of the initial state.
    x0 : array_like, shape (n,), optional
        Initial state mean; default the model's initial state (fixed values, parameters,
        or the data's first values).
    iterated : bool
        Iterated measurement update (Eq. 3.15-3.18).
    tol : float
        Relative stopping tolerance of the iterations (Eq. 3.16).
    max_iterations : int
    input_noise : mapping input name -> intensity, optional
        White noise on measured inputs (an IMU driving the kinematics, say), as continuous
        intensities (a sampled white noise of std s at interval dt: s^2 dt). It enters the
        states through the rhs: ``Q = process_noise + B diag(input_noise) B'`` with
        ``B = df/du`` at the current state, so its effect follows the state (gyro noise
        times the airspeed on the velocity rates).
    """

    def __init__(self, model: DynamicModel, theta, process_noise, R, P0, x0=None, iterated: bool = False,
                 tol: float = 1e-8, max_iterations: int = 20, input_noise=None):
        if not isinstance(model, DynamicModel):
            raise OptionError("ExtendedKalmanFilter needs a casest.DynamicModel (states, rhs and outputs); for a "
                              "static model use casest.ParameterEKF")
        self.model = model
        self.theta = model.vector(theta) if isinstance(theta, Mapping) else np.asarray(theta, dtype=float).reshape(-1)
        if self.theta.size != model.n_parameters:
            raise OptionError(f"theta must have {model.n_parameters} values, got {self.theta.size}")
        n, q = model.n_states, model.n_outputs
        self.Qc = process_noise_matrix(model, process_noise)
        names = [s.name for s in model.inputs]
        input_noise = dict(input_noise or {})
        unknown = [k for k in input_noise if k not in names]
        if unknown:
            raise ModelError(f"input noise for {unknown}, which are not inputs of {model.name!r}: {names}")
        self.input_noise = np.array([float(input_noise.get(k, 0.0)) for k in names])
        if np.any(self.input_noise < 0) or not np.all(np.isfinite(self.input_noise)):
            raise OptionError("input-noise intensities must be finite and >= 0")
        self.R = _covariance(R, q, "R")
        self.P0 = _covariance(P0, n, "P0")
        self.x0 = None if x0 is None else _matrix(np.asarray(x0, dtype=float).reshape(-1), (n,), "x0")
        self.iterated, self.tol, self.max_iterations = bool(iterated), float(tol), int(max_iterations)
        self._propagate, self._measure = ekf_step_functions(model)
        self.x = None if self.x0 is None else self.x0.copy()
        self.P = self.P0.copy()

    # -- step by step
    def reset(self, x0=None, P0=None) -> None:
        """Set the state and covariance (default: the constructor's)."""
        self.x = (self.x0 if x0 is None else np.asarray(x0, dtype=float).reshape(-1)).copy()
        self.P = (self.P0 if P0 is None else _covariance(P0, self.model.n_states, "P0")).copy()

    def predict(self, dt: float, u_start, u_end=None, u_now=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Time update over ``dt`` seconds (Eq. 3.10-3.11); returns x(k+1|k), P(k+1|k), Phi.

        ``u_start, u_end``: the step function's input arguments for the interval (the inputs
        at both ends for linear interpolation; ``u_end`` defaults to ``u_start``; for
        ``input_hold="cubic"`` the pairs of :meth:`DynamicModel.interval_inputs`).
        ``u_now``: the input at the interval's start, for ``input_noise`` (default: the
        last ``n_inputs`` values of ``u_start``).
        """
        if self.x is None:
            raise OptionError("no state yet: give x0 to the filter or call reset(x0)")
        ua = np.asarray(u_start, dtype=float).reshape(-1)
        ub = ua if u_end is None else np.asarray(u_end, dtype=float).reshape(-1)
        nu = len(self.model.inputs)
        uk = ua[len(ua) - nu:] if u_now is None else np.asarray(u_now, dtype=float).reshape(-1)
        x, P, Phi = self._propagate(self.x, self.P, ua, ub, float(dt), self.theta, self.Qc, uk, self.input_noise)
        self.x, self.P = np.asarray(x).reshape(-1), _symmetric(np.asarray(P))
        return self.x, self.P, np.asarray(Phi)

    def predict_ahead(self, steps: int, dt: float, u=None) -> tuple[np.ndarray, np.ndarray]:
        """Prediction i = 1 ... steps intervals of ``dt`` s ahead of the current state (Eq. 3.10-3.11
        repeated, the summary's Eq. 2.12-2.13 for the EKF); the filter's state is left unchanged.

        Parameters
        ----------
        steps : int
        dt : float
            Interval (s).
        u : array_like, optional
            Future inputs, shape (steps + 1, n_inputs) (the samples at both ends of every
            interval), or one input (n_inputs,) held (the summary's u(k+i) = u(k)); default zero.

        Returns
        -------
        x : ndarray, shape (steps, n_states)
        P : ndarray, shape (steps, n_states, n_states)
        """
        nu = len(self.model.inputs)
        U = np.zeros((steps + 1, nu)) if u is None else np.asarray(u, dtype=float)
        U = np.broadcast_to(U.reshape(1, nu) if U.ndim == 1 else U, (steps + 1, nu))
        Ua, Ub = self.model.interval_input_values(np.asarray(U))
        saved = (self.x, self.P)
        try:
            out = [self.predict(dt, Ua[i], Ub[i], U[i])[:2] for i in range(steps)]
        finally:
            self.x, self.P = saved
        return np.array([x for x, _ in out]), np.array([P for _, P in out])

    def update(self, y, u) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, int]:
        """Measurement update with y(k) (NaN channels skipped) and the input u(k).

        Returns x(k|k), P(k|k), the innovation, its covariance, the log-likelihood term and
        the iterations used.
        """
        if self.x is None:
            raise OptionError("no state yet: give x0 to the filter or call reset(x0)")
        y = np.asarray(y, dtype=float).reshape(-1)
        u = np.asarray(u, dtype=float).reshape(-1)

        def measure(x):
            h, H = self._measure(x, u, self.theta)
            return np.asarray(h).reshape(-1), np.asarray(H)

        x, P, e, S, ll, iterations = measurement_update(self.x.copy(), self.P, y, measure, self.R, self.iterated,
                                                        self.tol, self.max_iterations)
        self.x, self.P = x, P
        return x, P, e, S, ll, iterations

    # -- a whole record
    def filter(self, data: Dataset, compiled: bool | None = None) -> FilterResult:
        """Run the filter over a record of the model's data (time, inputs, outputs).

        Parameters
        ----------
        data : Dataset
            NaN outputs are missing (skipped channel by channel).
        compiled : bool, optional
            One compiled recursion over the record (:func:`casest.state.compiled_passes.ekf_pass`),
            the default for RK4 models; False: step by step from Python (as :meth:`predict` and
            :meth:`update`), the only way for a CVODES model. Both give the same arrays.

        Returns
        -------
        FilterResult
            Starting from ``x0`` (or the model's initial state for this record) and ``P0``; the
            filter's state afterwards is the last sample's x(k|k), P(k|k).
        """
        model = self.model
        model.check_data(data)
        x0 = self.x0 if self.x0 is not None else _initial_state(model, self.theta, data)
        if compiled is None:
            compiled = compiled_pass_applies(model)
        if compiled:
            arrays = ekf_pass(self, data, np.asarray(x0, dtype=float))
            self.x, self.P = arrays["x_filtered"][-1].copy(), arrays["P_filtered"][-1].copy()
            return FilterResult(**arrays, state_names=model.state_names, output_names=model.output_names,
                                time=data.signals[:, 0].copy())
        self.reset(x0, self.P0)
        t, U, Y = data.signals[:, 0], data.signals[:, 1:], data.outputs
        Ua, Ub = model.interval_input_values(U)
        N = data.n_samples
        rec = _Recorder(N, model.n_states, model.n_outputs, model.state_names, model.output_names, t.copy())
        for k in range(N):
            rec.prior(k, self.x, self.P)
            x, P, e, S, ll, its = self.update(Y[k], U[k])
            rec.posterior(k, x, P, e, S, ll, its)
            if k < N - 1:
                _, _, rec.transition[k] = self.predict(t[k + 1] - t[k], Ua[k], Ub[k], U[k])
        return rec.result()

    def smooth(self, data: Dataset) -> tuple[FilterResult, SmootherResult]:
        """The filter pass and its RTS smoothing (Eq. 2.20-2.23) over a record; the smoothed process
        noise is that of the discrete step, Q_d(k) = P(k+1|k) - Phi P(k|k) Phi' on the states."""
        result = self.filter(data)
        Phi = result.transition
        Qd = result.P_predicted[1:] - Phi @ result.P_filtered[:-1] @ Phi.transpose(0, 2, 1)
        return result, rts_smoother(result, process_noise=0.5 * (Qd + Qd.transpose(0, 2, 1)))


def _symmetric(P: np.ndarray) -> np.ndarray:
    return 0.5 * (P + P.T)


def _initial_state(model: DynamicModel, theta: np.ndarray, data: Dataset) -> np.ndarray:
    return np.asarray(model.initial_function(theta, model.initial_values(data))).reshape(-1)
