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

import numpy as np

from ..checks import flag_argument, whole_number
from ..data.dataset import Dataset
from ..models import ModelError, OptionError
from ..models.dynamic import DynamicModel
from .compiled_passes import ekf_pass, ekf_sample_function, rts_pass
from .ekf_model import ekf_step_functions
from .filter_records import FilterResult, SmootherResult, measurement_update
from .kalman import KalmanFilter
from .model_filter import ModelFilter, process_noise_matrix
from .smoothing import process_noise_smoothing, rts_loop


__all__ = ["FilterResult", "SmootherResult", "KalmanFilter", "ExtendedKalmanFilter", "rts_smoother",
           "process_noise_matrix", "measurement_update"]


def rts_smoother(result: FilterResult, compiled: bool = True, process_noise=None, noise_input=None) -> SmootherResult:
    """Fixed-interval smoothing of a filter pass (Rauch-Tung-Striebel, Eq. 2.20 and 2.22).

    ``C_k = P(k|k) Phi' P(k+1|k)^-1``, ``x(k|N) = x(k|k) - C_k (x(k+1|k) - x(k+1|N))``,
    ``P(k|N) = P(k|k) - C_k (P(k+1|k) - P(k+1|N)) C_k'``, from k = N-2 down to 0.

    Parameters
    ----------
    result : FilterResult
    compiled : bool
        The backward recursion as one CasADi pass (:func:`casest.filters.compiled_passes.rts_pass`);
        False: a NumPy loop. The same arrays either way.
    process_noise, noise_input : array_like, optional
        Q(k), shape (p, p) or (N-1, p, p), and Gamma(k), shape (n, p) or (N-1, n, p) (default
        identity): also smooth the process noise (:func:`casest.filters.smoothing.process_noise_smoothing`).

    Returns
    -------
    SmootherResult
        x(k|N), shape (N, n), and P(k|N), shape (N, n, n); w(k|N) and Q(k|N) with ``process_noise``.

    Raises
    ------
    OptionError
        Not a filter pass; a predicted covariance P(k+1|k) that is not positive definite (the
        gain divides by it), with the first such sample named.
    """
    if not isinstance(result, FilterResult):
        raise OptionError(f"rts_smoother takes the FilterResult of a filter pass (KalmanFilter.filter or "
                          f"ExtendedKalmanFilter.filter), got {type(result).__name__}")
    _check_predicted_covariances(result)
    xs, Ps = rts_pass(result) if flag_argument(compiled, "compiled") else rts_loop(result)
    w = Qs = None
    if process_noise is not None:
        w, Qs = process_noise_smoothing(result, xs, Ps, process_noise, noise_input)
    return SmootherResult(xs, Ps, result.state_names, w, Qs)


def _check_predicted_covariances(result: FilterResult) -> None:
    """Refuse a pass whose P(k+1|k) is not positive definite at some sample (the RTS gain would be
    NaN or a singular solve), naming the first."""
    P = np.asarray(result.P_predicted[1:], dtype=float)
    if P.size == 0:
        return
    try:
        np.linalg.cholesky(P)
        return
    except np.linalg.LinAlgError:
        pass
    for k in range(P.shape[0]):
        try:
            np.linalg.cholesky(P[k])
        except np.linalg.LinAlgError:
            raise OptionError(f"the predicted covariance P(k+1|k) at sample {k + 1} is not positive definite (a "
                              "state with no uncertainty left: no process noise on it and a transition or initial "
                              "covariance that vanishes): the RTS smoother divides by it; give that state some "
                              "process noise or initial covariance, or smooth a model without it") from None


# ----------------------------------------------------------------------------- EKF / IEKF
def _input_noise_intensities(model: DynamicModel, input_noise) -> np.ndarray:
    """Each input's noise intensity (0 where not named), finite and >= 0."""
    names = [s.name for s in model.inputs]
    input_noise = dict(input_noise or {})
    unknown = [k for k in input_noise if k not in names]
    if unknown:
        raise ModelError(f"input noise for {unknown}, which are not inputs of {model.name!r}: {names}")
    intensities = np.array([float(input_noise.get(k, 0.0)) for k in names])
    if np.any(intensities < 0) or not np.all(np.isfinite(intensities)):
        raise OptionError("input-noise intensities must be finite and >= 0")
    return intensities


class ExtendedKalmanFilter(ModelFilter):
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

    Examples
    --------
    The short-period aircraft model filtered at its true parameters, with process noise on
    the pitch rate:

    >>> import numpy as np
    >>> import casest
    >>> m = casest.load_model_file("short_period")
    >>> model, data = m.model(), m.simulate(seed=0)
    >>> R = [m.NOISE_STD[n] ** 2 for n in model.output_names]
    >>> ekf = casest.ExtendedKalmanFilter(model, m.TRUTH, {"q": 1e-4}, R, np.eye(2) * 1e-6)
    >>> result = ekf.filter(data)
    >>> result.x_filtered.shape
    (1001, 2)

    """

    kind = "the EKF"

    def __init__(self, model: DynamicModel, theta, process_noise, R, P0, x0=None, iterated: bool = False,
                 tol: float = 1e-8, max_iterations: int = 20, input_noise=None):
        super().__init__(model, theta, process_noise, R, P0, x0)
        self.input_noise = _input_noise_intensities(model, input_noise)
        self.iterated = flag_argument(iterated, "iterated")
        max_iterations = whole_number(max_iterations,
                                      "max_iterations must be a whole number of measurement updates >= 1")
        if not (isinstance(tol, (int, float, np.floating)) and np.isfinite(tol) and tol > 0):
            raise OptionError(f"tol must be a positive finite step size at which the iterations stop, got {tol!r}")
        self.tol, self.max_iterations = float(tol), int(max_iterations)
        self._propagate, self._measure = ekf_step_functions(model)

    @staticmethod
    def _static_model_hint() -> str:
        return "; for a static model use casest.ParameterEKF"

    # -- step by step
    def predict(self, dt: float, u_start, u_end=None, u_now=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Time update over ``dt`` seconds (Eq. 3.10-3.11); returns x(k+1|k), P(k+1|k), Phi.

        ``u_start, u_end``: the step function's input arguments for the interval (the inputs
        at both ends for linear interpolation; ``u_end`` defaults to ``u_start``; for
        ``input_hold="cubic"`` the pairs of :meth:`DynamicModel.interval_inputs`).
        ``u_now``: the input at the interval's start, for ``input_noise`` (default: the
        last ``n_inputs`` values of ``u_start``).

        Parameters
        ----------
        dt : float
            Interval (s).
        u_start, u_end : array_like
        u_now : array_like, shape (n_inputs,), optional

        Returns
        -------
        x : ndarray, shape (n_states,)
        P : ndarray, shape (n_states, n_states)
        Phi : ndarray, shape (n_states, n_states)
        """
        self._require_state()
        ua = np.asarray(u_start, dtype=float).reshape(-1)
        ub = ua if u_end is None else np.asarray(u_end, dtype=float).reshape(-1)
        nu = len(self.model.inputs)
        uk = ua[len(ua) - nu:] if u_now is None else np.asarray(u_now, dtype=float).reshape(-1)
        x, P, Phi = self._propagate(self.x, self.P, ua, ub, float(dt), self.theta, self.Qc, uk, self.input_noise)
        self.x, self.P = np.asarray(x).reshape(-1), _symmetric(np.asarray(P))
        return self.x, self.P, np.asarray(Phi)

    def update(self, y, u) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, int]:
        """Measurement update with y(k) (NaN channels skipped) and the input u(k).

        Returns x(k|k), P(k|k), the innovation, its covariance, the log-likelihood term and
        the iterations used.

        Parameters
        ----------
        y : array_like, shape (n_outputs,)
        u : array_like, shape (n_inputs,)

        Returns
        -------
        x : ndarray, shape (n_states,)
        P : ndarray, shape (n_states, n_states)
        innovation : ndarray, shape (n_outputs,)
        S : ndarray, shape (n_outputs, n_outputs)
        log_likelihood : float
        iterations : int
        """
        self._require_state()
        y, u = self._sample(y, u)

        def measure(x):
            h, H = self._measure(x, u, self.theta)
            return np.asarray(h).reshape(-1), np.asarray(H)

        x, P, e, S, ll, iterations = measurement_update(self.x.copy(), self.P, y, measure, self.R, self.iterated,
                                                        self.tol, self.max_iterations)
        self.x, self.P = x, P
        return x, P, e, S, ll, iterations

    def sample_function(self):
        """The EKF's (IEKF's) sample as one CasADi Function (:meth:`ModelFilter.sample_function`;
        ``c = [theta; vec Qc; input noise; vec R]``, the record ends with the iterations and vec Phi).

        Returns
        -------
        casadi.Function
        """
        return ekf_sample_function(self)

    def _compiled_pass(self, data: Dataset, x0: np.ndarray, out: tuple | None = None) -> FilterResult:
        """The record as one compiled recursion (:func:`casest.filters.compiled_passes.ekf_pass`)."""
        arrays = ekf_pass(self, data, x0, out)
        self.x, self.P = arrays["x_filtered"][-1].copy(), arrays["P_filtered"][-1].copy()
        return FilterResult(**arrays, state_names=self.model.state_names, output_names=self.model.output_names,
                            time=data.signals[:, 0].copy())

    def smooth(self, data: Dataset) -> tuple[FilterResult, SmootherResult]:
        """The filter pass and its RTS smoothing (Eq. 2.20-2.23) over a record; the smoothed process
        noise is that of the discrete step, Q_d(k) = P(k+1|k) - Phi P(k|k) Phi' on the states.

        Parameters
        ----------
        data : Dataset

        Returns
        -------
        FilterResult
        SmootherResult
            With the smoothed process noise w(k|N) and Q(k|N).
        """
        result = self.filter(data)
        Phi = result.transition
        Qd = result.P_predicted[1:] - Phi @ result.P_filtered[:-1] @ Phi.transpose(0, 2, 1)
        return result, rts_smoother(result, process_noise=0.5 * (Qd + Qd.transpose(0, 2, 1)))


def _symmetric(P: np.ndarray) -> np.ndarray:
    return 0.5 * (P + P.T)
