"""Frequency-domain estimation (Klein and Morelli, *Aircraft System Identification*, Ch. 7):
equation error and output error on the finite Fourier transforms of a record over a chosen band,
for linear(ised) :class:`casest.DynamicModel` s, and the recursive Fourier transform for online use.

The model is linearised about its initial state and the record's first input (exact for linear
models): ``A = df/dx``, ``B = df/du``, ``C = dh/dx``, ``D = dh/du``, functions of theta. With
``X(w) = sum_k x(t_k) exp(-j w t_k) dt`` the finite Fourier transform at the chosen frequencies:

- **output error** fits ``Y(w) = (C (jw I - A)^-1 B + D) U(w)``, the measured outputs' transform
  against the model's transfer function (the record must start and end near rest, or the
  transient's ends enter as error);
- **equation error** fits ``jw X(w) = A X(w) + B U(w)``, with the states measured (outputs named
  like the states, or ``states=``).

Both minimise ``sum_w sum_j |v_j(w)|^2 / S_j`` with the residual spectra ``S_j`` re-estimated as
their mean square until they settle (the frequency-domain analogue of output error's R), by
IPOPT with the exact Hessian inside the parameters' bounds; the covariance is the inverse of
``2 Re sum_w J^H S^-1 J`` (the residuals' real and imaginary parts each carry half of S: on 30
simulated short-period records its std were 0.81-1.23 of the Monte-Carlo spread). The transforms
at frequencies ``2 pi k / T`` (T the record's length) are independent; closer ones are not, and
their std come out too small (a note says so). Parameters that act only at zero
frequency (an output bias) drop out: they are held at their nominal values and named.

The residuals are then tested (:mod:`casest.frequency.spectral_checks`): a spectrum that is not
flat across the band but independent of the inputs is coloured noise (the std reported become
the sandwich colored-residual std); residuals coherent with an input or the fitted transform are
a model error, and a delay of the inputs that explains them is diagnosed
(:mod:`casest.frequency.delay_diagnosis`) and refitted by ``casest.refit`` (``delay=`` estimates
``U(w) exp(-j w d)`` with ``d`` a parameter).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Mapping, Sequence

import casadi as ca
import numpy as np

from ..backend.ipopt import SolverSettings
from ..checks import finite_array
from ..data.dataset import Dataset
from ..errors import DataError, OptionError
from ..models.dynamic import DynamicModel
from ..problem.problem import Problem
from ..status import Note, NoteCode
from ..options import FrequencyMethod
from ..estimation.refit import delay_name
from .fit import residual_expressions
from .judgement import Band, DelaySymbols, judged_fit
from .result import FrequencyEstimate

__all__ = ["fourier_transform", "RecursiveFourierTransform", "FrequencyEstimate", "frequency_domain_estimate",
           "frequency_residuals"]

def fourier_transform(values, time, frequencies) -> np.ndarray:
    """The finite Fourier transform ``X(w) = sum_k x(t_k) exp(-j w t_k) dt_k`` at chosen frequencies.

    Parameters
    ----------
    values : array_like, shape (N,) or (N, channels)
    time : array_like, shape (N,)
        Sample times (s); ``dt_k`` is the interval to the next sample (the last repeats).
    frequencies : array_like, shape (F,)
        Angular frequencies (rad/s).

    Returns
    -------
    ndarray, complex, shape (F,) or (F, channels)
    """
    x = np.asarray(values, dtype=float)
    t = np.asarray(time, dtype=float).reshape(-1)
    w = np.asarray(frequencies, dtype=float).reshape(-1)
    dt = np.diff(t, append=t[-1] + (t[-1] - t[-2] if t.size > 1 else 1.0))
    kernel = np.exp(-1j * np.outer(w, t)) * dt  # (F, N)
    return kernel @ x


class RecursiveFourierTransform:
    """The finite Fourier transform updated sample by sample, for online estimation: after each
    sample the transform of the record so far (one complex multiply-add per frequency and channel).

    Parameters
    ----------
    frequencies : array_like, shape (F,)
        Angular frequencies (rad/s).
    dt : float
        Sample interval (s).
    channels : int
    """

    def __init__(self, frequencies, dt: float, channels: int = 1):
        self.frequencies = finite_array(frequencies, "frequencies", shape=(None,), error=OptionError)
        self.dt = float(dt)
        if not self.dt > 0:
            raise OptionError(f"dt must be a positive number of seconds, got {dt!r}")
        self._rotation = np.exp(-1j * self.frequencies * self.dt)
        self._phase = np.ones_like(self._rotation)
        self.transform = np.zeros((self.frequencies.size, int(channels)), dtype=complex)
        self.n_samples = 0

    def update(self, sample) -> np.ndarray:
        """Add one sample (at time ``n_samples * dt``).

        Parameters
        ----------
        sample : array_like, shape (channels,)

        Returns
        -------
        ndarray, complex, shape (F, channels)
            The transform so far.
        """
        x = np.asarray(sample, dtype=float).reshape(-1)
        self.transform += np.outer(self._phase, x) * self.dt
        self._phase *= self._rotation
        self.n_samples += 1
        return self.transform


def _linearisation(model: DynamicModel, data: Dataset):
    """``(A, B, C, D)`` as an SX function of theta, at the initial state and first input."""
    n, nu = model.n_states, len(model.inputs)
    x, u, theta = ca.SX.sym("x", n), ca.SX.sym("u", nu), ca.SX.sym("theta", model.n_parameters)
    f = model.rhs_function(x, u, theta)
    h = model.output_model.function(ca.vertcat(x, u), theta)
    x0 = np.asarray(model.initial_function(model.nominal, model.initial_values(data))).reshape(-1)
    u0 = data.signals[0, 1:] if nu else np.zeros(0)
    fun = ca.Function("ABCD", [x, u, theta], [ca.jacobian(f, x), ca.jacobian(f, u), ca.jacobian(h, x),
                                              ca.jacobian(h, u)])
    return [ca.substitute(M, ca.vertcat(x, u), ca.vertcat(ca.DM(x0), ca.DM(u0))) for M in fun(x, u, theta)], theta


def _state_columns(model: DynamicModel, states) -> list:
    names = list(model.output_names)
    mapping = dict(states) if states is not None else {s: s for s in model.state_names if s in names}
    _check_state_mapping(model, mapping)
    return [names.index(mapping[s]) for s in model.state_names]


def _check_state_mapping(model: DynamicModel, mapping: dict) -> None:
    """Every state named, each to an output the model has."""
    names = list(model.output_names)
    missing = [s for s in model.state_names if s not in mapping]
    if missing:
        raise OptionError(f"equation error needs every state measured: give states={{state: output column}} for "
                          f"{missing} (outputs: {names})")
    unknown = [c for c in mapping.values() if c not in names]
    if unknown:
        raise OptionError(f"states= names outputs {unknown}, which the model does not have ({names})")


def frequency_domain_estimate(model: DynamicModel | Problem, data: Dataset | None, frequencies: Sequence[float],
                              method: FrequencyMethod = "output-error", states: Mapping | None = None,
                              settings: SolverSettings | None = None, delay: Sequence[str] = (),
                              delay_start: float = 0.0) -> FrequencyEstimate:
    """Estimate a linear(ised) dynamic model's parameters in the frequency domain.

    Parameters
    ----------
    model : DynamicModel or Problem
        A :class:`casest.Problem` (with ``data`` None) brings its record and its fixed
        parameters (its noise model unknown and diagonal: the method weights each channel by
        its own residual spectrum).
    data : Dataset or None
        The model's record (time, inputs, outputs), without missing samples.
    frequencies : sequence of float
        Angular frequencies (rad/s) of the band, all positive (a plain DFT at each).
    method : {"output-error", "equation-error"}
        See the module docstring.
    states : mapping of state name to output name, optional
        Equation error: which measured output is each state (default: outputs named like the states).
    settings : SolverSettings, optional
        IPOPT's settings for each reweighted solve (default: casest's, with ``tol=1e-12``).
    delay : sequence of str, optional
        Inputs delayed together by one more parameter (seconds; ``delay_NAME``, or ``delay`` for
        several): they enter as ``U(w) exp(-j w d)``, with ``|d| <= pi / w_max``.
    delay_start : float
        The delay's start value (s).

    Returns
    -------
    FrequencyEstimate
        With its family of residual tests (:mod:`casest.frequency.spectral_checks`), its
        colored-residual std where the residual spectrum is not flat, and a diagnosed delay where
        the residuals are coherent with the inputs (:mod:`casest.frequency.delay_diagnosis`).

    Raises
    ------
    OptionError
        Not a DynamicModel, an unknown method, frequencies that are not positive, states not
        measured, an unknown input to delay.
    DataError
        Missing samples.
    """
    if isinstance(model, Problem):
        model, data = _problem_parts(model, data)
    w = _checked_request(model, data, frequencies, method, settings)
    delayed = _delayed_inputs(model, delay, delay_start, w)
    t, U_t = data.signals[:, 0], data.signals[:, 1:]
    U = fourier_transform(U_t, t, w).reshape(w.size, -1)
    Y = fourier_transform(data.outputs, t, w).reshape(w.size, -1)
    X = Y[:, _state_columns(model, states)] if method == "equation-error" else None
    ABCD, theta = _linearisation(model, data)
    acting = [i for i in range(model.n_parameters)
              if any(ca.depends_on(M, theta[i]) for M in (ABCD if method == "output-error" else ABCD[:2]))]
    channels = len(_state_columns(model, states)) if method == "equation-error" else model.n_outputs
    unknowns = len(acting) + channels + bool(delayed)  # the parameters and each channel's residual spectrum
    if 2 * w.size * channels <= unknowns:
        raise OptionError(f"{w.size} frequencies give {2 * w.size * channels} real residuals for "
                          f"{unknowns - channels} parameters and {channels} residual spectra: give more than "
                          f"{unknowns // (2 * channels)} frequencies across the band the record excites")
    resolution = 2 * np.pi / (t[-1] - t[0] + (t[1] - t[0]))
    spaced = w.size < 2 or np.min(np.diff(np.sort(w))) >= 0.999 * resolution
    band = Band(method, w, U, Y if method == "output-error" else None, float(np.median(np.diff(t))),
                bool(spaced), _channel_names(model, method), tuple(s.name for s in model.inputs))
    delays = DelaySymbols.of([s.name for s in model.inputs], delayed)
    estimate = judged_fit(model, band, residual_expressions(method, ABCD, w, U, Y, X, delays.expression), theta,
                          acting, delays, delay_start, settings or SolverSettings(tol=1e-12))
    if _nonlinear(model):
        note = Note("the model is nonlinear: the frequency domain fits its linearisation about the initial state "
                    "and the first input, which a manoeuvre away from that point does not follow; check the estimate "
                    "by output error in the time domain (casest.estimate)", NoteCode.FREQUENCIES)
        estimate = replace(estimate, notes=estimate.notes + (note,))
    if not spaced:
        note = Note(f"frequencies closer than the record's resolution 2 pi / T = {resolution:.4g} rad/s have "
                    "correlated transforms: the std are too small and the residual tests are not run; space them by "
                    "at least that", NoteCode.FREQUENCIES)
        estimate = replace(estimate, notes=estimate.notes + (note,))
    return estimate


def frequency_residuals(estimate: FrequencyEstimate, model: DynamicModel, data: Dataset,
                        states: Mapping | None = None) -> tuple:
    """The residuals of a frequency-domain estimate on its record, at its frequencies.

    Parameters
    ----------
    estimate : FrequencyEstimate
    model : DynamicModel
        The model estimated.
    data : Dataset
        Its record.
    states : mapping, optional
        Equation error: which output is each state (as for the estimate).

    Returns
    -------
    U : ndarray, complex, shape (F, n_inputs)
        The inputs' transforms.
    V : ndarray, complex, shape (F, channels)
        The residuals ``v_j(w_k)``.
    channel_names : tuple of str
    """
    w = np.asarray(estimate.frequencies, dtype=float)
    t = data.signals[:, 0]
    U = fourier_transform(data.signals[:, 1:], t, w).reshape(w.size, -1)
    Y = fourier_transform(data.outputs, t, w).reshape(w.size, -1)
    X = Y[:, _state_columns(model, states)] if estimate.method == "equation-error" else None
    ABCD, theta = _linearisation(model, data)
    names = [s.name for s in model.inputs]
    values = dict(zip(estimate.parameter_names, np.asarray(estimate.theta, dtype=float)))
    delay = values.get(delay_name(list(estimate.delayed)), 0.0) if estimate.delayed else 0.0
    tau = ca.DM([delay if n in estimate.delayed else 0.0 for n in names])
    rr, ri = residual_expressions(estimate.method, ABCD, w, U, Y, X, tau)
    at = ca.DM([values[n] for n in model.parameter_names])
    vr, vi = (np.asarray(ca.evalf(ca.substitute(part, theta, at))) for part in (rr, ri))
    return U, (vr + 1j * vi).T, _channel_names(model, estimate.method)


def _checked_request(model, data, frequencies, method, settings) -> np.ndarray:
    """The band, after the model, method, settings, band and record are checked."""
    if not isinstance(model, DynamicModel):
        raise OptionError("frequency_domain_estimate needs a casest.DynamicModel (states, rhs, outputs)")
    if settings is not None and not isinstance(settings, SolverSettings):
        raise OptionError(f"settings must be a casest.SolverSettings (or left out), got {type(settings).__name__}")
    if method not in ("output-error", "equation-error"):
        raise OptionError(f"method must be 'output-error' or 'equation-error', got {method!r}")
    w = finite_array(frequencies, "frequencies", shape=(None,), error=OptionError)
    if w.size == 0:
        raise OptionError("frequencies is empty: give the band's angular frequencies (rad/s), e.g. "
                          "numpy.linspace(0.5, 10.0, 40)")
    if np.any(w <= 0):
        raise OptionError("frequencies must be positive angular frequencies (rad/s): zero frequency carries the "
                          "biases and trim, which the frequency domain leaves out")
    model.check_data(data)
    if not np.all(np.isfinite(data.outputs)):
        raise DataError("the frequency domain needs every sample of every output; fill or cut the missing ones")
    _check_band(w, data.signals[:, 0])
    return w


def _delayed_inputs(model: DynamicModel, delay, delay_start: float, w: np.ndarray) -> tuple:
    """The indices of the inputs to delay, after their names and the start are checked."""
    names = [s.name for s in model.inputs]
    delay = (delay,) if isinstance(delay, str) else tuple(delay)
    unknown = [d for d in delay if d not in names]
    if unknown:
        raise OptionError(f"delay= names {unknown}, which are not inputs of the model (inputs: {names})")
    bound = np.pi / float(w.max())
    if delay and not abs(float(delay_start)) < bound:
        raise OptionError(f"delay_start = {delay_start!r} s is outside the delay's bounds +/- pi / w_max = "
                          f"{bound:.4g} s (a larger delay turns the phase at the top of the band past half a turn)")
    return tuple(names.index(d) for d in dict.fromkeys(delay))


def _channel_names(model: DynamicModel, method: str) -> tuple:
    """The residual channels: the outputs (output error) or the states' equations (equation error)."""
    if method == "output-error":
        return tuple(model.output_names)
    return tuple(f"d{s}/dt" for s in model.state_names)


def _check_band(w: np.ndarray, t: np.ndarray) -> None:
    """Refuse frequencies at or above the record's Nyquist frequency (their transforms alias)."""
    dt = float(np.median(np.diff(t))) if t.size > 1 else np.inf
    nyquist = np.pi / dt
    above = w[w >= nyquist]
    if above.size:
        raise OptionError(f"{above.size} of the frequencies reach or pass the record's Nyquist frequency pi / dt = "
                          f"{nyquist:.4g} rad/s (the highest {float(w.max()):.4g}): their transforms alias lower "
                          "frequencies; keep the band below it, where the inputs excite the model")


def _nonlinear(model: DynamicModel) -> bool:
    """Whether the model's rhs or outputs depend on the states or inputs other than linearly."""
    x, u = model.rhs_function.sx_in(0), model.rhs_function.sx_in(1)
    theta = model.rhs_function.sx_in(2)
    z = ca.vertcat(x, u)
    rhs = model.rhs_function(x, u, theta)
    out = model.output_model.function(z, theta)
    return any(ca.depends_on(ca.jacobian(e, z), z) for e in (rhs, out))


def _problem_parts(problem: Problem, data) -> tuple:
    """The model (fixed parameters substituted) and the one record of a Problem."""
    if data is not None or problem.experiments or problem.stage1_data is not None:
        raise OptionError("frequency_domain_estimate(problem, None, frequencies) takes the problem's one record: give "
                          "the data to the Problem (one Dataset, no experiments or stage-1 data), not here")
    if not problem.noise.estimated or not problem.noise.profiled_per_channel:
        raise OptionError(f"the frequency domain weights each channel by its own residual spectrum; this problem has "
                          f"{problem.describe_noise()}: use the default DiagonalNoise()")
    return problem.model, problem.data
