"""A frequency-domain fit judged: its convergence, its std (white-noise or colored-residual), its
family of residual tests and, where the residuals are coherent with the inputs, a diagnosed delay."""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..backend.ipopt import SolverSettings
from ..estimation.refit import delay_name
from ..estimation.uncertainty import covariance_from_hessian
from ..estimation.verdict import residual_verdict
from ..models.dynamic import DynamicModel
from ..status import Note, NoteCode, ResidualCode
from .delay_diagnosis import diagnose_delay
from .fit import FitParameters, residual_function, reweighted_fit
from .result import FrequencyEstimate
from .spectral_checks import colored_covariance, spectral_checks

__all__ = ["Band", "DelaySymbols", "judged_fit"]


@dataclass(frozen=True)
class Band:
    """What the tests and the diagnosis need of the record's transforms.

    Attributes
    ----------
    method : str
    w : ndarray, shape (F,)
        Angular frequencies (rad/s).
    U : ndarray, complex, shape (F, n_inputs)
    Y : ndarray, complex, shape (F, n_outputs), or None
        The outputs' transforms (output error: the fitted transform is ``Y - v``).
    dt : float
        The record's sample interval (s).
    spaced : bool
        Whether the frequencies are at least ``2 pi / T`` apart (independent transforms: the
        residual tests hold).
    channel_names, input_names : tuple of str
    """

    method: str
    w: np.ndarray
    U: np.ndarray
    Y: np.ndarray | None
    dt: float
    spaced: bool
    channel_names: tuple
    input_names: tuple


@dataclass(frozen=True)
class DelaySymbols:
    """Each input's delay in the residual expressions.

    Attributes
    ----------
    parameter : SX or None
        The estimated delay (s) shared by the delayed inputs, None when none is delayed.
    delayed : tuple of int
        The delayed inputs.
    extra : SX, shape (n_inputs,)
        A further delay of each input, zero in the fit: the diagnosis reads the residuals'
        derivatives in it.
    expression : SX, shape (n_inputs,)
        Each input's delay: ``parameter`` (delayed) or 0, plus ``extra``.
    name : str
        The delay parameter's name.
    """

    parameter: object
    delayed: tuple
    extra: object
    expression: object
    name: str

    @classmethod
    def of(cls, input_names, delayed: tuple) -> "DelaySymbols":
        """The symbols for inputs ``input_names`` with ``delayed`` (indices) delayed together."""
        name = delay_name([input_names[i] for i in delayed]) if delayed else ""
        parameter = ca.SX.sym(name) if delayed else None
        extra = ca.SX.sym("extra_delay", len(input_names))
        base = ca.vertcat(*[parameter if i in delayed else ca.SX(0) for i in range(len(input_names))])
        return cls(parameter, tuple(delayed), extra, base + extra if len(input_names) else extra, name)


def _parameters(model: DynamicModel, theta, acting: list, delays: DelaySymbols, delay_start: float,
                w: np.ndarray) -> tuple:
    """The symbols, start values, bounds and scales of the model's parameters and the delay."""
    names, symbols = tuple(model.parameter_names), theta
    nominal, lower = np.asarray(model.nominal, float), np.asarray(model.lower_bounds, float)
    upper, scales = np.asarray(model.upper_bounds, float), np.asarray(model.scales, float)
    acting = list(acting)
    if delays.parameter is not None:
        bound = np.pi / float(w.max())
        names, symbols = names + (delays.name,), ca.vertcat(theta, delays.parameter)
        nominal, lower = np.append(nominal, delay_start), np.append(lower, -bound)
        upper, scales = np.append(upper, bound), np.append(scales, 1.0 / float(w.max()))
        acting.append(len(names) - 1)
    return symbols, FitParameters(names, nominal, lower, upper, scales), acting


def judged_fit(model: DynamicModel, band: Band, parts, theta, acting: list, delays: DelaySymbols,
               delay_start: float, settings: SolverSettings) -> FrequencyEstimate:
    """Fit, then judge: convergence by the Gauss-Newton decrement, the std, the residual tests,
    the colored-residual std when the residual spectrum is coloured, a delay when the residuals
    are coherent with the inputs.

    Parameters
    ----------
    model : DynamicModel
    band : Band
    parts : list of two SX, shape (channels, F)
        The residuals' real and imaginary parts (:func:`casest.frequency.fit.residual_expressions`).
    theta : SX
        The model's parameters.
    acting : list of int
        The model's parameters that act in the band.
    delays : DelaySymbols
    delay_start : float
    settings : SolverSettings

    Returns
    -------
    FrequencyEstimate
    """
    zero = ca.DM.zeros(delays.extra.numel())
    fit_parts = [ca.substitute(p, delays.extra, zero) for p in parts]
    symbols, parameters, acting = _parameters(model, theta, acting, delays, delay_start, band.w)
    fit = reweighted_fit(*fit_parts, symbols, acting, parameters, settings)
    evaluate = residual_function(*parts, symbols, acting, fit.values, delays.extra)
    vr, vi, Jr, Ji, _, _ = evaluate(fit.values[acting], np.zeros(delays.extra.numel()))
    notes = list(fit.notes)
    per_row = np.tile(1.0 / fit.spectra, band.w.size)  # vec is column-major: channels vary fastest
    gauss_newton = Jr.T @ (per_row[:, None] * Jr) + Ji.T @ (per_row[:, None] * Ji)
    success = _converged(gauss_newton, per_row, vr, vi, Jr, Ji, fit.inside, fit.status, notes)
    # circular complex residuals: real and imaginary parts each carry half of S
    white, null = covariance_from_hessian(2.0 * gauss_newton)
    identifiable = not null.shape[1] and np.all(np.isfinite(white))
    checks = spectral_checks(vr, vi, Jr, Ji, band.w, band.U, _fitted(band, vr, vi), band.channel_names,
                             band.input_names) if band.spaced else ()
    verdict = residual_verdict(checks)
    colored = bool(identifiable and verdict.code is ResidualCode.COLOURED)
    chosen = colored_covariance(vr, vi, Jr, Ji, fit.spectra, band.w) if colored else white
    n = len(parameters.names)
    std, std_white, full = np.full(n, np.nan), np.full(n, np.nan), np.full((n, n), np.nan)
    if identifiable:
        std[acting], std_white[acting] = np.sqrt(np.diag(chosen)), np.sqrt(np.diag(white))
        full[np.ix_(acting, acting)] = chosen
    else:
        notes.append(Note("the information matrix is singular: some parameters are not identifiable in this band",
                          NoteCode.NOT_IDENTIFIABLE))
    held = tuple(parameters.names[i] for i in range(n) if i not in acting)
    if held:
        notes.append(Note(f"{list(held)} do not act at nonzero frequencies (biases, trim): held at their nominal "
                          "values", NoteCode.FIXED))
    diagnosis = None
    if verdict.code is ResidualCode.DEPENDENT:
        diagnosis = diagnose_delay(band, evaluate, fit.values[acting], fit.spectra)
    return FrequencyEstimate(band.method, parameters.names, fit.values, std, held, band.w, fit.spectra, success,
                             tuple(notes), covariance=full, std_white=std_white, colored=colored,
                             residual_checks=tuple(checks), diagnosis=diagnosis, sample_interval=band.dt,
                             delayed=tuple(band.input_names[i] for i in delays.delayed))


def _fitted(band: Band, vr: np.ndarray, vi: np.ndarray) -> np.ndarray | None:
    """Output error: the model's transform of each output, ``Y - v``; None for equation error."""
    return None if band.Y is None else band.Y - (vr + 1j * vi).T


def _converged(gauss_newton, per_row, vr, vi, Jr, Ji, inside, status: str, notes: list) -> bool:
    """Whether the Gauss-Newton step on the parameters off their bounds would lower the cost by at
    most 1e-10 (IPOPT's own status can stop at rounding level on these linear-looking sums)."""
    gradient = Jr.T @ (per_row * vr.reshape(-1, order="F")) + Ji.T @ (per_row * vi.reshape(-1, order="F"))
    try:
        decrement = float(gradient[inside] @ np.linalg.solve(gauss_newton[np.ix_(inside, inside)], gradient[inside]))
    except np.linalg.LinAlgError:
        decrement = np.inf
    if decrement <= 1e-10:
        return True
    notes.append(Note(f"not converged: the Gauss-Newton decrement is {decrement:.3g} ({status})", NoteCode.NOT_VERIFIED))
    return False
