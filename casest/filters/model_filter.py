"""What every state filter offers, and what the filters on a :class:`casest.DynamicModel` share.

:class:`StateFilter` is the filter protocol: the state ``x`` and covariance ``P``, the step API
(``predict`` a time update, ``update`` a measurement update, ``predict_ahead`` without changing
the state) and ``filter`` over a record returning a
:class:`~casest.filters.filter_records.FilterResult`. The linear :class:`casest.KalmanFilter`,
the EKF/IEKF and the UKF implement it.

:class:`ModelFilter` is the machinery of the filters on a dynamic model (the EKF/IEKF and the
UKF): the checks of the model, the noise and the start, ``reset``, ``predict_ahead``, and the
pass over a record, either one compiled recursion (each filter's :meth:`ModelFilter._compiled_pass`)
or step by step from Python through the filter's own ``predict`` and ``update``.
"""

from __future__ import annotations

import abc
from typing import Mapping, Protocol, runtime_checkable

import numpy as np

from ..checks import covariance_argument, flag_argument, matrix_argument, whole_number
from ..data.dataset import Dataset
from ..models import ModelError, OptionError
from ..models.dynamic import DynamicModel
from .compiled_passes import compiled_pass_applies
from .ekf_model import filter_parameters
from .filter_records import FilterRecorder, FilterResult


__all__ = ["StateFilter", "ModelFilter", "process_noise_matrix"]


@runtime_checkable
class StateFilter(Protocol):
    """The filter protocol (module docstring).

    Attributes
    ----------
    x : ndarray, shape (n_states,)
        The current state estimate.
    P : ndarray, shape (n_states, n_states)
        Its covariance.
    """

    x: np.ndarray
    P: np.ndarray

    def predict(self, *args, **kwargs):
        """The time update to the next sample.

        Parameters
        ----------
        *args, **kwargs
            The filter's own: the interval and inputs of a filter on a dynamic model, the input
            of the linear Kalman filter.

        Returns
        -------
        tuple
            The predicted state (n_states,) and covariance (n_states, n_states) first.
        """

    def update(self, y, *args, **kwargs):
        """The measurement update with the sample ``y`` (NaN channels skipped).

        Parameters
        ----------
        y : array_like, shape (n_outputs,)
        *args, **kwargs
            The filter's own (the sample's input).

        Returns
        -------
        tuple
            The filtered state (n_states,) and covariance (n_states, n_states) first.
        """

    def predict_ahead(self, steps: int, *args, **kwargs) -> tuple[np.ndarray, np.ndarray]:
        """States and covariances 1 ... ``steps`` samples ahead; the filter's state unchanged.

        Parameters
        ----------
        steps : int
        *args, **kwargs
            The filter's own (interval, future inputs).

        Returns
        -------
        x : ndarray, shape (steps, n_states)
        P : ndarray, shape (steps, n_states, n_states)
        """

    def filter(self, *args, **kwargs) -> FilterResult:
        """The filter over a record.

        Parameters
        ----------
        *args, **kwargs
            The record (a Dataset for a filter on a dynamic model, arrays for the linear
            Kalman filter) and the filter's options.

        Returns
        -------
        FilterResult
        """


def process_noise_matrix(model: DynamicModel, process_noise) -> np.ndarray:
    """The continuous process-noise intensity G Q G' of a dynamic model as a matrix.

    Parameters
    ----------
    model : DynamicModel
    process_noise : mapping, array_like (n_states,) or (n_states, n_states)
        A mapping state name -> intensity (units of the state's rate squared per hertz;
        states not named get none), a vector of intensities, or a full matrix.

    Returns
    -------
    ndarray, shape (n_states, n_states)

    Raises
    ------
    OptionError
        An unknown state name, a negative intensity or a wrong shape.
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
        return matrix_argument(arr, (n, n), "process_noise")
    return covariance_argument(arr, n, "process_noise")


class ModelFilter(abc.ABC):
    """The machinery the filters on a :class:`casest.DynamicModel` share (module docstring).

    Parameters
    ----------
    model : DynamicModel
    theta : mapping or array_like, shape (n_parameters,)
        Parameter values.
    process_noise : mapping, array_like (n,) or (n, n)
        Continuous white-noise intensity on the rhs (:func:`process_noise_matrix`).
    R : array_like, shape (n_outputs,) or (n_outputs, n_outputs)
        Measurement-noise covariance.
    P0 : array_like, shape (n,) or (n, n)
        Covariance of the initial state.
    x0 : array_like, shape (n,), optional
        Initial state mean; default the model's initial state for the record.
    """

    #: the filter's name in messages
    kind = "a filter"

    def __init__(self, model: DynamicModel, theta, process_noise, R, P0, x0=None):
        if not isinstance(model, DynamicModel):
            raise OptionError(f"{type(self).__name__} needs a casest.DynamicModel (states, rhs and outputs)"
                              + self._static_model_hint())
        if model.output_delays:
            raise OptionError(f"the filters measure each sample's own state, and the model delays outputs "
                              f"{list(model.output_delays.delays)}: estimate the delays by output error "
                              "(casest.estimate), then shift those measured outputs back by the estimated delays "
                              "and filter a model without output delays")
        n = model.n_states
        self.model = model
        self.theta = filter_parameters(model, theta)
        self.Qc = process_noise_matrix(model, process_noise)
        self.R = covariance_argument(R, model.n_outputs, "R")
        self.P0 = covariance_argument(P0, n, "P0")
        self.x0 = None if x0 is None else matrix_argument(np.asarray(x0, dtype=float).reshape(-1), (n,), "x0")
        self.x = None if self.x0 is None else self.x0.copy()
        self._initial_cache = None  # (theta and the record's initial values, the initial state)
        self.P = self.P0.copy()

    @staticmethod
    def _static_model_hint() -> str:
        """What to use instead for a static model (empty: nothing to suggest)."""
        return ""

    # -- the step API each filter implements
    @abc.abstractmethod
    def predict(self, dt: float, u_start, u_end=None, u_now=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Time update over ``dt`` seconds.

        Parameters
        ----------
        dt : float
            Interval (s).
        u_start, u_end : array_like
            The step function's input arguments for the interval (``u_end`` defaults to
            ``u_start``).
        u_now : array_like, shape (n_inputs,), optional
            The input at the interval's start (for input noise).

        Returns
        -------
        x : ndarray, shape (n_states,)
            x(k+1|k).
        P : ndarray, shape (n_states, n_states)
            P(k+1|k).
        Phi : ndarray, shape (n_states, n_states)
            The (linearised) transition.
        """

    @abc.abstractmethod
    def update(self, y, u) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, int]:
        """Measurement update with y(k) (NaN channels skipped) and the input u(k).

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

    @abc.abstractmethod
    def sample_function(self):
        """The filter's sample as one CasADi Function: ``(acc, d, c) -> (acc_next, record)`` with
        ``acc = [x(k|k-1); vec P(k|k-1)]``, ``d = [y (NaN as 0); mask; u; u_start; u_end; dt]``,
        ``record = [x(k|k); vec P(k|k); e; vec S; ll; ...]`` (its compiled pass and its C export).

        Returns
        -------
        casadi.Function
        """

    @abc.abstractmethod
    def _compiled_pass(self, data: Dataset, x0: np.ndarray, out: tuple | None = None) -> FilterResult:
        """The whole record as one compiled recursion (leaving ``x``, ``P`` at the last sample),
        written into ``out`` (an earlier result's ``buffers``) where given."""

    def _require_state(self) -> None:
        if self.x is None:
            raise OptionError("no state yet: give x0 to the filter or call reset(x0)")

    def _sample(self, y, u) -> tuple[np.ndarray, np.ndarray]:
        """One sample's measurements and inputs as flat vectors of the model's sizes (named where not)."""
        model = self.model
        y, u = np.asarray(y, dtype=float), np.asarray(u, dtype=float)
        if y.size != model.n_outputs:
            raise OptionError(f"y must hold one sample of the {model.n_outputs} outputs {list(model.output_names)} "
                              f"(NaN where not measured), got shape {y.shape}")
        if u.size != len(model.inputs):
            raise OptionError(f"u must hold one sample of the {len(model.inputs)} inputs "
                              f"{[s.name for s in model.inputs]}, got shape {u.shape}")
        return y.reshape(-1), u.reshape(-1)

    # -- shared
    def reset(self, x0=None, P0=None) -> None:
        """Set the state and covariance (default: the constructor's).

        Parameters
        ----------
        x0 : array_like, shape (n_states,), optional
        P0 : array_like, shape (n_states, n_states) or (n_states,), optional

        Returns
        -------
        None
        """
        self.x = (self.x0 if x0 is None else np.asarray(x0, dtype=float).reshape(-1)).copy()
        self.P = (self.P0 if P0 is None else covariance_argument(P0, self.model.n_states, "P0")).copy()

    def predict_ahead(self, steps: int, dt: float, u=None) -> tuple[np.ndarray, np.ndarray]:
        """Prediction i = 1 ... steps intervals of ``dt`` s ahead of the current state (the time
        update repeated, the summary's Eq. 2.12-2.13 for a nonlinear filter); the filter's state is
        left unchanged.

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
        steps = whole_number(steps, "steps must be a whole number of samples >= 1")
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

    def _initial_state(self, values: np.ndarray) -> np.ndarray:
        """The model's initial state at theta and a record's initial values, computed once per pair (a
        model without values from the record: once per theta, whatever the record)."""
        key = (np.asarray(self.theta, dtype=float).tobytes(), np.asarray(values, dtype=float).tobytes())
        cached = self._initial_cache
        if cached is None or cached[0] != key:
            cached = self._initial_cache = (key, np.asarray(self.model.initial_function(self.theta, values)).reshape(-1))
        return cached[1].copy()

    def filter(self, data: Dataset, compiled: bool | None = None, out: FilterResult | None = None) -> FilterResult:
        """Run the filter over a record of the model's data (time, inputs, outputs).

        Parameters
        ----------
        data : Dataset
            NaN outputs are missing (skipped channel by channel).
        compiled : bool, optional
            One compiled recursion over the record (:mod:`casest.filters.compiled_passes`), the
            default for RK4 models; False: step by step from Python (as :meth:`predict` and
            :meth:`update`), the only way for a CVODES model. Both give the same arrays.
        out : FilterResult, optional
            An earlier compiled pass of this filter over a record of the same length: the new
            pass is written into its arrays (no fresh memory for a long record, as in a
            Monte-Carlo loop), so that ``out``'s arrays then hold the new pass (its
            ``log_likelihood`` and ``iterations`` stay the earlier pass's). Where the compiled
            loop does not run (no C compiler), the new pass has arrays of its own.

        Returns
        -------
        FilterResult
            Starting from ``x0`` (or the model's initial state for this record) and ``P0``; the
            filter's state afterwards is the last sample's x(k|k), P(k|k).
        """
        model = self.model
        compiled = flag_argument(compiled, "compiled", allow_none=True)
        if not isinstance(data, Dataset):
            raise OptionError(f"filter takes the model's record (a casest.Dataset: time, inputs, outputs), got "
                              f"{type(data).__name__}" + ("; a FilterResult is a filter pass already: smooth it with "
                                                          "rts_smoother" if isinstance(data, FilterResult) else ""))
        model.check_data(data)
        x0 = self.x0 if self.x0 is not None else self._initial_state(model.initial_values(data))
        if compiled is None:
            compiled = compiled_pass_applies(model)
        if compiled:
            return self._compiled_pass(data, np.asarray(x0, dtype=float), _reusable(out, data.n_samples))
        self.reset(x0, self.P0)
        t, U, Y = data.signals[:, 0], data.signals[:, 1:], data.outputs
        Ua, Ub = model.interval_input_values(U)
        N = data.n_samples
        rec = FilterRecorder(N, model.n_states, model.n_outputs, model.state_names, model.output_names, t.copy())
        for k in range(N):
            rec.prior(k, self.x, self.P)
            rec.posterior(k, *self.update(Y[k], U[k]))
            if k < N - 1:
                _, _, rec.transition[k] = self.predict(t[k + 1] - t[k], Ua[k], Ub[k], U[k])
        return rec.result()


def _reusable(out: FilterResult | None, n_samples: int) -> tuple | None:
    """The buffers of ``out`` for a pass over ``n_samples`` samples, or None for none given.

    Raises
    ------
    OptionError
        ``out`` is not a compiled pass's result (step by step, or not a FilterResult) or holds
        another number of samples.
    """
    if out is None:
        return None
    if not isinstance(out, FilterResult) or out.buffers is None:
        raise OptionError("out takes the FilterResult of an earlier compiled pass of this filter (filter(data) with "
                          f"the default compiled=None), got {type(out).__name__}"
                          + (" from a pass step by step" if isinstance(out, FilterResult) else ""))
    if len(out.x_filtered) != n_samples:
        raise OptionError(f"out holds a pass over {len(out.x_filtered)} samples, this record has {n_samples}: give "
                          "the result of a pass over a record of the same length, or no out")
    return out.buffers
