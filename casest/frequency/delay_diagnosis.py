"""What a frequency-domain fit lacks when its residuals are coherent with the inputs: a delay.

A delay ``d`` of inputs behind the outputs' reference turns ``U(w)`` into ``U(w) exp(-j w d)``;
the residuals and their derivatives in each input's delay are CasADi expressions. The
candidates are each input's delay and, with several inputs, every input delayed together. Each
is fitted together with the model's parameters (Gauss-Newton, weighted by ``1 / S_j``, from the
estimate and no delay) and counts when its F-test is significant at
:data:`~casest.estimation.diagnostics.ALPHA` divided by the number of candidates **and** the
residuals of the delayed model pass every coherence test. The one with
the largest F is the diagnosis (its delay in samples of the record); when none counts there is
none. ``casest.refit(estimate, model, data)`` estimates the delay as a parameter
(:func:`casest.frequency.refit.refit_delay`).
"""

from __future__ import annotations

import numpy as np
from scipy.special import fdtrc

from ..estimation.diagnosis import Diagnosis
from ..estimation.diagnostics import ALPHA
from ..estimation.verdict import residual_verdict
from ..status import DiagnosisCode, ResidualCode
from .spectral_checks import spectral_checks

__all__ = ["diagnose_delay", "MAX_STEPS"]

#: Gauss-Newton steps of a candidate delay together with the model's parameters
MAX_STEPS = 30


def _candidates(input_names: tuple) -> list:
    """The input sets whose common delay is tried: each input, and all of them together."""
    sets = [(i,) for i in range(len(input_names))]
    if len(input_names) > 1:
        sets.append(tuple(range(len(input_names))))
    return sets


def diagnose_delay(band, evaluate, start: np.ndarray, spectra: np.ndarray) -> Diagnosis | None:
    """The delay of the inputs that explains coherent residuals (module docstring), or None.

    Parameters
    ----------
    band : casest.frequency.judgement.Band
    evaluate : callable
        ``(acting values, extra delays) -> (vr, vi, Jr, Ji, Er, Ei)`` of
        :func:`casest.frequency.fit.residual_function`.
    start : ndarray, shape (n_acting,)
        The estimate's acting parameters.
    spectra : ndarray, shape (channels,)
        The fit's weights ``S_j``.

    Returns
    -------
    Diagnosis or None
        A :attr:`DiagnosisCode.LAG` with the delay and its std in samples.
    """
    vr, vi, Jr, _, Er, _ = evaluate(start, np.zeros(len(band.input_names)))
    if Er.shape[1] == 0:
        return None
    weights = np.tile(1.0 / np.sqrt(spectra / 2.0), 2 * band.w.size)
    before = float(np.sum((_stacked(vr, vi) * weights) ** 2))
    dof = weights.size - Jr.shape[1] - 1
    sets = _candidates(band.input_names)
    found = []
    for inputs in sets:
        fitted = _delay_fit(band, evaluate, start, inputs, weights)
        if fitted is None:
            continue
        delay, std, after, (vr_after, vi_after, Jr_after, Ji_after) = fitted
        statistic = (before - after) / max(after / max(dof, 1), 1e-300)
        p_value = float(fdtrc(1, max(dof, 1), statistic))
        if p_value >= ALPHA / len(sets):
            continue
        fitted_transform = None if band.Y is None else band.Y - (vr_after + 1j * vi_after).T
        checks = spectral_checks(vr_after, vi_after, Jr_after, Ji_after, band.w, band.U, fitted_transform,
                                 band.channel_names, band.input_names)
        verdict_after = residual_verdict(checks).code
        if verdict_after is ResidualCode.DEPENDENT:
            continue
        found.append(Diagnosis(DiagnosisCode.LAG, tuple(band.channel_names),
                               tuple(band.input_names[i] for i in inputs), "shift", delay / band.dt, std / band.dt,
                               -1, float(statistic), p_value, np.sqrt(np.mean(vr**2 + vi**2, axis=1)),
                               np.sqrt(np.mean(vr_after**2 + vi_after**2, axis=1)), verdict_after))
    return max(found, key=lambda d: d.statistic) if found else None


def _stacked(vr: np.ndarray, vi: np.ndarray) -> np.ndarray:
    """The residuals as one vector: ``vec`` of the real parts, then of the imaginary parts."""
    return np.concatenate([vr.reshape(-1, order="F"), vi.reshape(-1, order="F")])


def _delay_fit(band, evaluate, start: np.ndarray, inputs: tuple, weights: np.ndarray):
    """Gauss-Newton on the model's parameters and one delay of ``inputs`` (weights fixed).

    Returns
    -------
    tuple or None
        ``(delay s, its std s, weighted residual sum of squares, (vr, vi, Jr, Ji) at the end
        with the delay's column)``; None when the steps do not settle within the delay's bounds.
    """
    mask = np.zeros(len(band.input_names))
    mask[list(inputs)] = 1.0
    bound = np.pi / float(band.w.max())
    theta, delay = np.array(start, dtype=float), 0.0
    for _ in range(MAX_STEPS):
        vr, vi, Jr, Ji, Er, Ei = evaluate(theta, delay * mask)
        A = np.vstack([np.column_stack([Jr, Er @ mask]), np.column_stack([Ji, Ei @ mask])]) * weights[:, None]
        step = -np.linalg.lstsq(A, _stacked(vr, vi) * weights, rcond=None)[0]
        theta, delay = theta + step[:-1], delay + step[-1]
        if abs(delay) >= bound:
            return None
        if abs(step[-1]) <= 1e-6 * bound:
            break
    else:
        return None
    vr, vi, Jr, Ji, Er, Ei = evaluate(theta, delay * mask)
    A = np.vstack([np.column_stack([Jr, Er @ mask]), np.column_stack([Ji, Ei @ mask])]) * weights[:, None]
    after = float(np.sum((_stacked(vr, vi) * weights) ** 2))
    scale = after / max(weights.size - A.shape[1], 1)  # the misfit the weights' S_j still carry
    std = float(np.sqrt(max(np.linalg.pinv(A.T @ A)[-1, -1] * scale, 0.0)))
    return delay, std, after, (vr, vi, np.column_stack([Jr, Er @ mask]), np.column_stack([Ji, Ei @ mask]))
