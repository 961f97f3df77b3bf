"""Estimate a static model again with the change a diagnosis names (:mod:`casest.estimation.diagnosis`;
``casest.refit(estimate, model, data)`` is the one call).

- **lag**: :func:`shifted_signal_model` replaces a signal ``x`` (or several) by ``x(t - d)`` with the delay
  ``d`` (samples) a parameter estimated like any other: ``x(t - d)`` is the quartic Lagrange
  interpolation of the five samples around ``t - m`` (``m`` the diagnosed lag rounded), exact for
  polynomials of degree four and smooth in ``d`` on ``[m - 2, m + 2]``, its bounds. The record
  loses ``|m| + 2`` samples at each end (:func:`shifted_dataset`).
- **bias, scale, term, step**: one parameter more times the term (1, the output's own model,
  the signals' product, or the indicator of the samples from the step on) in the named output.

The misfit before (the first estimate on the same samples) and after is in the :class:`Refit`.
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..data.dataset import Dataset
from ..errors import OptionError
from ..models.priors import Parameter, Signal
from ..models.static import Model
from ..status import DiagnosisCode

__all__ = ["Refit", "refit_with", "shifted_signal_model", "shifted_dataset", "STENCIL_HALF_WIDTH", "REFITTERS",
           "register_refitter"]

#: the interpolation of a shifted signal uses the samples t - m - 2 ... t - m + 2
STENCIL_HALF_WIDTH = 2
#: result type -> ``(result, model, data, **options) -> Refit`` for results whose estimator refits
#: in its own way (the frequency domain's delay); ``casest.refit`` looks here first
REFITTERS: dict = {}


def register_refitter(result_type: type):
    """Decorator: register the refit of results of ``result_type`` in :data:`REFITTERS`.

    Parameters
    ----------
    result_type : type

    Returns
    -------
    callable
        The decorator (it returns the function unchanged).
    """
    def register(function):
        REFITTERS[result_type] = function
        return function
    return register


@dataclass(frozen=True)
class Refit:
    """The model estimated again with the diagnosed change.

    Attributes
    ----------
    estimate : Estimate
        The estimate of the changed model.
    parameter : str
        The change's parameter (``delay_x``, ``bias_z``, ...).
    value, std : float
        Its estimate and standard deviation (the delay in samples).
    rms_before, rms_after : ndarray, shape (n_outputs,)
        Each output's residual rms on the samples of the refit: the first estimate's and the
        refit's.
    """

    estimate: object
    parameter: str
    value: float
    std: float
    rms_before: np.ndarray
    rms_after: np.ndarray

    def describe(self) -> str:
        """One line: the parameter with its std, the misfit before and after, the new conclusion.

        Returns
        -------
        str
        """
        code, _ = self.estimate.conclusion()
        fall = ", ".join(f"{b:.4g} -> {a:.4g}" for b, a in zip(self.rms_before, self.rms_after))
        return (f"refit: {self.parameter} = {self.value:.5g} +/- {self.std:.2g}; residual rms {fall}; "
                f"conclusion {code.value}")


def _stencil(lag: float) -> np.ndarray:
    """The integer offsets of the interpolation around the rounded lag."""
    m = int(round(lag))
    return np.arange(m - STENCIL_HALF_WIDTH, m + STENCIL_HALF_WIDTH + 1)


def _column(signal: str, offset: int) -> str:
    return f"{signal}[t{-offset:+d}]" if offset else f"{signal}[t]"


def delay_name(signals) -> str:
    """The delay parameter's name: ``delay_<signal>``, or ``delay`` for several signals shifted together."""
    return f"delay_{signals[0]}" if len(signals) == 1 else "delay"


def shifted_signal_model(model: Model, signals, lag: float) -> Model:
    """``model`` with ``signals`` delayed together by one parameter (samples, module docstring).

    Parameters
    ----------
    model : Model
    signals : str or sequence of str
        The signal(s) to shift.
    lag : float
        The expected delay (samples): the interpolation's centre; the delay's bounds are
        ``round(lag) -/+ 2``.

    Returns
    -------
    Model
        Its parameters and ``delay_<signal>`` (``delay`` for several); its signals the others
        and ``x[t-k]`` of each shifted signal for each sample of the stencil.
    """
    signals = (signals,) if isinstance(signals, str) else tuple(signals)
    unknown = [s for s in signals if s not in model.signal_names]
    if unknown or not signals:
        raise OptionError(f"{unknown or signals} are not signals of model {model.name!r} (signals: "
                          f"{list(model.signal_names)})")
    offsets = _stencil(lag)
    d = ca.SX.sym(delay_name(signals))
    bases = []
    for k in offsets:  # Lagrange basis polynomial of node k at d
        basis = 1
        for q in offsets:
            if q != k:
                basis = basis * (d - float(q)) / float(k - q)
        bases.append(basis)
    h, new = model.h, []
    for signal in signals:
        taps = [ca.SX.sym(_column(signal, int(k))) for k in offsets]
        h = ca.substitute(h, model.x[model.signal_names.index(signal)], sum(b * t for b, t in zip(bases, taps)))
        unit = next(s.unit for s in model.signals if s.name == signal)
        new += [Signal(_column(signal, int(k)), unit=unit) for k in offsets]
    delay = Parameter(delay_name(signals), lb=float(offsets[0]), ub=float(offsets[-1]), nominal=float(lag))
    return Model(list(model.parameters) + [delay], [s for s in model.signals if s.name not in signals] + new,
                 {n: h[j] for j, n in enumerate(model.output_names)}, name=f"{model.name}+{delay_name(signals)}",
                 output_units=dict(zip(model.output_names, model.output_units)))


def shifted_dataset(shifted: Model, data: Dataset, signals, lag: float) -> tuple[Dataset, np.ndarray]:
    """The record of :func:`shifted_signal_model`: the shifted copies of ``signal``, ends trimmed.

    Parameters
    ----------
    shifted : Model
        The model of :func:`shifted_signal_model`.
    data : Dataset
        The record of the original model.
    signals : str or sequence of str
    lag : float
        As given to :func:`shifted_signal_model`.

    Returns
    -------
    Dataset
    rows : ndarray of int
        The original record's samples it keeps.
    """
    signals = (signals,) if isinstance(signals, str) else tuple(signals)
    offsets = _stencil(lag)
    reach = int(np.max(np.abs(offsets)))
    rows = np.arange(reach, data.n_samples - reach)
    columns = {name: data.column(name)[rows] for name in list(data.signal_names) + list(data.output_names)
               if name not in signals}
    for signal in signals:
        x = data.column(signal)
        columns.update({_column(signal, int(k)): x[rows - k] for k in offsets})
    new = Dataset(shifted, columns, missing="allow")
    new.time_ordered = bool(getattr(data, "time_ordered", False))
    return new, rows


def _with_term(model: Model, data: Dataset, diagnosis) -> tuple[Model, Dataset, str]:
    """The model with one parameter more times the diagnosed term in its output, and its record."""
    channel = diagnosis.channels[0]
    j = model.output_names.index(channel)
    name = f"{diagnosis.code.value}_{channel}"
    c = ca.SX.sym(name)
    symbols = {s: model.x[i] for i, s in enumerate(model.signal_names)}
    signals, columns = list(model.signals), {n: data.column(n) for n in list(data.signal_names) + list(data.output_names)}
    if diagnosis.code is DiagnosisCode.BIAS:
        term = 1
    elif diagnosis.code is DiagnosisCode.SCALE:
        term = model.h[j]
    elif diagnosis.code is DiagnosisCode.STEP:
        step = ca.SX.sym("step_indicator")
        signals.append(Signal("step_indicator"))
        columns["step_indicator"] = (np.arange(data.n_samples) >= diagnosis.location).astype(float)
        term = step
    else:
        term = 1
        for factor in diagnosis.term.replace("^2", "*" + diagnosis.term.split("^")[0]).split("*"):
            term = term * symbols[factor]
    h = ca.vertcat(*[model.h[k] + (c * term if k == j else 0) for k in range(model.n_outputs)])
    new = Model(list(model.parameters) + [Parameter(name)], signals,
                {n: h[k] for k, n in enumerate(model.output_names)}, name=f"{model.name}+{name}",
                output_units=dict(zip(model.output_names, model.output_units)))
    dataset = Dataset(new, columns, missing="allow")
    dataset.time_ordered = bool(getattr(data, "time_ordered", False))
    return new, dataset, name


def refit_with(diagnosis, model: Model, data: Dataset, estimator, first=None, first_theta=None, **options) -> Refit:
    """Estimate ``model`` with the change ``diagnosis`` names (module docstring).

    Parameters
    ----------
    diagnosis : Diagnosis
    model : Model
        The model diagnosed.
    data : Dataset
        Its record.
    estimator : callable
        ``(model, data, **options) -> Estimate``: :func:`casest.estimate` (``casest.refit`` passes it).
    first : Estimate, optional
        The first estimate (its residuals give ``rms_before``); default: estimated here.
    first_theta : ndarray, optional
        The first estimate's values instead of ``first``: the refit then starts from them and
        the change's diagnosed size (a local solve).
    **options
        Passed to :func:`casest.estimate`.

    Returns
    -------
    Refit
    """
    if not isinstance(model, Model):
        raise OptionError("a refit needs the static casest.Model the diagnosis was made for")
    theta = np.asarray(first_theta if first_theta is not None else
                       (first if first is not None else estimator(model, data, **options)).theta, dtype=float)
    if first_theta is not None:
        options.setdefault("start", np.append(theta[:model.n_parameters], diagnosis.value))
    if diagnosis.code is DiagnosisCode.LAG:
        changed = shifted_signal_model(model, diagnosis.signals, diagnosis.value)
        dataset, rows = shifted_dataset(changed, data, diagnosis.signals, diagnosis.value)
        parameter = delay_name(diagnosis.signals)
    else:
        changed, dataset, parameter = _with_term(model, data, diagnosis)
        rows = np.arange(data.n_samples)
    new = estimator(changed, dataset, **options)
    before = data.outputs[rows] - model.predict(theta[:model.n_parameters], data.signals[rows])
    after = dataset.outputs - changed.predict(new.theta, dataset.signals)
    index = list(new.parameter_names).index(parameter)
    return Refit(new, parameter, float(new.theta[index]), float(new.std[index]),
                 np.sqrt(np.nanmean(before**2, axis=0)), np.sqrt(np.nanmean(after**2, axis=0)))
