"""The innovation formulation's result: what it estimated under its own names.

The formulation estimates theta, the process-noise distribution F and the innovation
covariance R; the measurement noise ``G G' = R - C P C'`` is implied, not estimated. The
result holds R as ``innovation_covariance`` with its large-sample std, the implied measurement
noise as ``R`` (NaN where ``R - C P C'`` has a negative variance, with a note) with no std, and
every state's intensity ``F_i^2`` (NaN with a note where F is not finite).
"""

from __future__ import annotations

import numpy as np

from ..data.dataset import Dataset, undeclared_units_note
from ..estimation.residual_family import series_checks, tested_signals
from ..status import Note, NoteCode, Outcome, StdReason
from .one_step import gain_predictions
from .result import FilterErrorEstimate
from .uncertainty import parameter_fields

__all__ = ["innovation_result", "covariance_std", "innovation_whiteness"]


def covariance_std(R: np.ndarray, N: int, diagonal: bool) -> np.ndarray:
    """Large-sample std of the closed-form innovation covariance ``sum e e' / N`` of zero-mean
    Gaussian innovations: ``sqrt((R_ii R_jj + R_ij^2) / N)`` (``R_ii sqrt(2 / N)`` on the diagonal);
    0 off the diagonal of the diagonal form (not estimated).

    Parameters
    ----------
    R : ndarray, shape (n_y, n_y)
    N : int
        Samples.
    diagonal : bool

    Returns
    -------
    ndarray, shape (n_y, n_y)
    """
    d = np.diag(R)
    std = np.sqrt((np.outer(d, d) + R**2) / N)
    return np.diag(np.diag(std)) if diagonal else std


def _std_reasons(uncertainty, npar: int) -> tuple[list, list]:
    reasons, codes = [], []
    for s, side in zip(uncertainty.std[:npar], uncertainty.active[:npar]):
        if not np.isfinite(s):
            reasons.append("singular information"), codes.append(StdReason.SINGULAR)
        else:
            reasons.append(None), codes.append(None)
    return reasons, codes


def _noise_notes(model, f: np.ndarray, implied: np.ndarray, uncertainty, noisy: list) -> list:
    """Notes on the process noise (not finite, on its bound) and the implied measurement noise."""
    notes = []
    bad = [model.state_names[i] for i in range(model.n_states) if not np.isfinite(f[i])]
    if bad:
        notes.append(Note(f"the process noise of {bad} is not finite: the relaxation left them NaN; start closer or "
                          "hold their intensity", NoteCode.NOT_FINITE))
    npar = model.n_parameters
    at_zero = [model.state_names[i] for i, side in zip(noisy, uncertainty.active[npar:]) if side == "lower"]
    if at_zero:
        notes.append(Note(f"the process noise of {at_zero} is at its bound 0 (no std): the record shows no process "
                          "noise on these states", NoteCode.BOUNDS))
    negative = [n for n, v in zip(model.output_names, implied) if not v >= 0]
    if negative:
        notes.append(Note(f"the implied measurement noise R - C P C' has a negative variance for {negative} (reported "
                          "as NaN): the process noise takes more than the innovations hold", NoteCode.NOISE_FLOOR))
    if uncertainty.singular:
        notes.append(Note("the information matrix is singular: some parameters are not identifiable from this record; "
                          "fix them or add excitation", NoteCode.NOT_IDENTIFIABLE))
    return notes


def innovation_whiteness(E: np.ndarray, R: np.ndarray, outputs: tuple, model=None, data=None) -> tuple:
    """The residual tests of each channel's innovations ``e_kj / sqrt(R_jj)`` in time order:
    whiteness, independence from the past inputs, no change in time
    (:func:`casest.estimation.residual_family.series_checks`, one Holm family).

    Parameters
    ----------
    E : ndarray, shape (n_y, N)
    R : ndarray, shape (n_y, n_y)
    outputs : tuple of str
    model : DynamicModel, optional
    data : Dataset, optional
        With ``model``: the record whose inputs the innovations must not depend on.

    Returns
    -------
    tuple of ResidualCheck
    """
    if not np.all(np.isfinite(E)):
        return ()
    names, inputs = tested_signals(model, data) if model is not None else ([], np.zeros((E.shape[1], 0)))
    return series_checks((E / np.sqrt(np.diag(R))[:, None]).T, outputs, inputs, names, in_time=True, dynamic=True)


def innovation_result(problem, data: Dataset, state, f_all: np.ndarray, uncertainty, values: list, notes: list,
                      status: str, seconds: float) -> FilterErrorEstimate:
    """The :class:`FilterErrorEstimate` of a relaxation.

    Parameters
    ----------
    problem : InnovationProblem
    data : Dataset
    state : the relaxation's state
        ``w``, ``R``, ``rounds``, ``iterations``, ``settled``, ``failure``.
    f_all : ndarray, shape (n_states,)
        F of every state at the start (the fixed ones as they are).
    uncertainty : HeldCovariance
    values : list of ndarray
        ``problem.values`` at the estimate: ``(E, diag(K C), C, P, X, K)``.
    notes : list of Note
        The relaxation's notes.
    status : str
    seconds : float

    Returns
    -------
    FilterErrorEstimate
    """
    model, noisy = problem.model, list(problem.noisy)
    npar, N = model.n_parameters, data.n_samples
    E, _, C, P, _, K = values
    diagonal = bool(np.all(state.R == np.diag(np.diag(state.R))))
    f = f_all.copy()
    f[noisy] = state.w[npar:]
    implied = np.diag(state.R - C @ P @ C.T).copy()
    notes = list(notes) + _noise_notes(model, f, implied, uncertainty, noisy)
    units_note = undeclared_units_note(data.undeclared_units)
    notes += [units_note] if units_note else []
    implied[~(implied >= 0)] = np.nan
    reasons, codes = _std_reasons(uncertainty, npar)
    success = (status == "Solve_Succeeded" and bool(np.all(np.isfinite(uncertainty.std[~uncertainty.held])))
               and not uncertainty.singular and bool(np.all(np.isfinite(f))))
    logdet = float(np.linalg.slogdet(state.R)[1])
    ny = model.n_outputs
    return FilterErrorEstimate(
        **parameter_fields(model, state.w[:npar] * model.scales, uncertainty, reasons, codes),
        process_noise={model.state_names[i]: float(f[i] ** 2) for i in range(model.n_states)
                       if i in noisy or f[i] > 0},
        process_noise_std={model.state_names[i]: float(2 * abs(f[i]) * s)
                           for i, s in zip(noisy, uncertainty.std[npar:])},
        R=implied, R_std=np.full(ny, np.nan), R_estimated=False,
        cost=0.5 * N * ny + 0.5 * N * logdet,
        log_likelihood=-0.5 * N * ny * (1 + np.log(2 * np.pi)) - 0.5 * N * logdet,
        success=success, status=status, outcome=Outcome.CONVERGED if success else Outcome.NOT_CONVERGED,
        n_iterations=state.iterations, n_samples=N, seconds=seconds, filter=None, notes=notes,
        formulation="innovation", residual_checks=innovation_whiteness(E, state.R, tuple(model.output_names), model, data),
        innovation_covariance=state.R.copy(),
        innovation_covariance_std=covariance_std(state.R, N, diagonal), n_rounds=state.rounds,
        predictions=gain_predictions(model, data, E.T, state.R, K, C))
