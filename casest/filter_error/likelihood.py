"""Filter error's two likelihood formulations, solved as NLPs: the time-varying EKF over the record (the
exact likelihood of Eq. 5.7) and the steady-state form (one gain at an operating point), each by IPOPT or
scoring, with their covariance from the exact Hessian or the Fisher information and their result.
:data:`casest.filter_error.estimator.FORMULATIONS` names :func:`time_varying_formulation` and
:func:`steady_state_formulation`; the practice formulation is :mod:`casest.filter_error.relaxation`'s."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import casadi as ca
import numpy as np

from ..backend.ipopt import SolverSettings, run_ipopt
from ..backend.tolerances import cost_tolerance
from ..data.dataset import Dataset, undeclared_units_note
from ..estimation.residual_family import series_checks, tested_signals
from ..filters.ekf import ExtendedKalmanFilter
from ..models.dynamic import DynamicModel
from ..status import Note, NoteCode, Outcome, StdReason
from .one_step import OneStepPredictions, gain_predictions, output_jacobian, time_varying_predictions
from .nlp import FilterErrorNLP, FilterErrorSetup, FormulationOptions, time_varying_columns
from .result import FilterErrorEstimate
from .scoring import score
from .steady import check_steady_data, reference_point, steady_record_columns, steady_state_gain
from .uncertainty import held_covariance, parameter_fields


__all__ = ["time_varying_formulation", "steady_state_formulation", "innovation_checks", "MAX_RELINEARISATIONS"]


def steady_state_formulation(model: DynamicModel, data: Dataset, setup: FilterErrorSetup, settings: SolverSettings,
                  options: FormulationOptions) -> FilterErrorEstimate:
    """The steady-state formulation: one gain at an operating point, R estimated
    (:mod:`casest.filter_error.steady`), relinearised until the likelihood settles.

    Parameters
    ----------
    model : DynamicModel
    data : Dataset
    setup : FilterErrorSetup
    settings : SolverSettings
    options : FormulationOptions

    Returns
    -------
    FilterErrorEstimate
    """
    nlp, run, p_num, notes = _solve_steady(model, data, setup, settings, options.solver,
                                           options.operating_point or "mean")
    return _finish(nlp, data, run, p_num, notes, options, "steady-state")


def time_varying_formulation(model: DynamicModel, data: Dataset, setup: FilterErrorSetup, settings: SolverSettings,
                  options: FormulationOptions) -> FilterErrorEstimate:
    """The time-varying formulation: the EKF with P(k|k-1) over the record, the exact likelihood.

    Parameters
    ----------
    model : DynamicModel
    data : Dataset
    setup : FilterErrorSetup
    settings : SolverSettings
    options : FormulationOptions

    Returns
    -------
    FilterErrorEstimate
    """
    nlp = FilterErrorNLP(model, setup, data.n_samples)
    D_num, last_num = time_varying_columns(model, data)
    p_num = np.concatenate([D_num.reshape(-1, order="F"), last_num, model.initial_values(data)])
    run = _solve_nlp(nlp, p_num, settings, data.n_samples, solver=options.solver)
    return _finish(nlp, data, run, p_num, [], options, "time-varying")


def _finish(nlp: FilterErrorNLP, data: Dataset, run, p_num: np.ndarray, notes: list, options: FormulationOptions,
            formulation: str) -> FilterErrorEstimate:
    """The covariance (exact Hessian or Fisher information) and the result of a likelihood solve."""
    N = data.n_samples
    hessian = nlp.information(run.x, p_num) if options.covariance == "fisher" else nlp.hessian_of_v(run.x, p_num, N)
    values, to_natural = nlp.natural(run.x)
    result = _assemble(nlp, data, run, values, _uncertainty(nlp, run.x, hessian, to_natural),
                       time.perf_counter() - options.t0)
    model = nlp.model
    if formulation == "steady-state":
        predictions = _steady_predictions(nlp, data, run.x, p_num, result)
    else:
        predictions = time_varying_predictions(model, data, result.theta, result.filter)
    return replace(result, formulation=formulation, notes=notes + result.notes, predictions=predictions)


def _steady_predictions(nlp: FilterErrorNLP, data: Dataset, w: np.ndarray, p_num: np.ndarray,
                        result: FilterErrorEstimate) -> OneStepPredictions:
    """The steady-state filter's own innovations and its one gain at the operating point that ends ``p_num``."""
    model = nlp.model
    n, nu = model.n_states, len(model.inputs)
    x_ref, u_ref, dt = p_num[-(n + nu + 1):-(nu + 1)], p_num[-(nu + 1):-1], p_num[-1]
    E, S = (np.asarray(ca.densify(v), dtype=float) for v in nlp.derivatives().innovations(w, p_num))
    q = np.array([result.process_noise.get(name, 0.0) for name in model.state_names])
    K = np.asarray(steady_state_gain(model)(result.theta, q, result.R, x_ref, u_ref, dt)[0], dtype=float)
    S = S[:, 0].reshape(model.n_outputs, model.n_outputs, order="F")
    return gain_predictions(model, data, E.T, S, K, output_jacobian(model, x_ref, u_ref, result.theta))


def _same_gain(model: DynamicModel, nlp: FilterErrorNLP, w: np.ndarray, old: tuple, new: tuple, dt: float) -> bool:
    """Whether the steady gain and innovation covariance at two reference points agree to 1e-12."""
    values, _ = nlp.natural(w)
    npar, setup = model.n_parameters, nlp.setup
    q = setup.q_start.copy()
    q[setup.noisy] = values[npar:npar + len(setup.noisy)]
    r = values[npar + len(setup.noisy):] if setup.estimate_R else setup.r_start
    gain = steady_state_gain(model)
    K0, S0, _ = (np.asarray(v) for v in gain(values[:npar], q, r, old[0], old[1], dt))
    K1, S1, _ = (np.asarray(v) for v in gain(values[:npar], q, r, new[0], new[1], dt))
    return bool(np.allclose(K0, K1, rtol=1e-12, atol=1e-14) and np.allclose(S0, S1, rtol=1e-12, atol=1e-300))


#: outer passes of the steady-state form (relinearisations)
MAX_RELINEARISATIONS = 8


def _solve_nlp(nlp: FilterErrorNLP, p_num: np.ndarray, settings: SolverSettings, N: int, start=None,
               solver: str = "ipopt"):
    if solver == "scoring":
        run, nlp.fisher = score(nlp.derivatives(), p_num, nlp.start if start is None else start, nlp.lower,
                                nlp.upper, settings.max_iter)
        nlp.fisher_at = run.x
        return run
    return run_ipopt(nlp.ipopt(settings, N), x0=nlp.start if start is None else start, lbx=nlp.lower, ubx=nlp.upper, p=p_num)


def _solve_steady(model: DynamicModel, data: Dataset, setup: FilterErrorSetup, settings: SolverSettings, solver: str,
                  operating_point: str):
    """The steady-state form: solve at the first state and input; with ``operating_point="mean"``
    relinearise at the mean predicted state and repeat until V settles (1e-9 relative)."""
    dt = check_steady_data(model, data)
    N = data.n_samples
    D_num, last_num = steady_record_columns(model, data)
    record = np.concatenate([D_num.reshape(-1, order="F"), last_num, model.initial_values(data)])
    states, _ = model.simulate(setup.theta0, data)
    x_ref, u_ref = reference_point(data, states, first=True)
    w, previous, run, iterations = None, None, None, 0
    nlp = FilterErrorNLP(model, setup, N, "steady-state")
    for passes in range(1, MAX_RELINEARISATIONS + 1):
        p_num = np.concatenate([record, x_ref, u_ref, [dt]])
        run = _solve_nlp(nlp, p_num, settings, N, w, solver)
        iterations += run.iterations  # every pass's iterations, not the last pass's alone
        w = run.x
        value = run.f * N
        if previous is not None and abs(value - previous) <= cost_tolerance(value):
            break
        previous = value
        if operating_point == "first":
            break
        new_x, new_u = reference_point(data, nlp.predicted_states(w, p_num), first=False)
        if _same_gain(model, nlp, w, (x_ref, u_ref), (new_x, new_u), dt):
            break  # the linearisation does not depend on the point (a linear model): nothing to redo
        x_ref, u_ref = new_x, new_u
    where = "the first state and input" if operating_point == "first" else "the mean predicted state and input"
    note = Note(f"steady-state filter-error form: one Kalman gain from the Riccati equation linearised at "
                f"x_ref = {np.array2string(x_ref, precision=4)}, u_ref = {np.array2string(u_ref, precision=4)} "
                f"({where}), {passes} relinearisation pass(es), {iterations} iterations in all", NoteCode.NOISE_MODEL)
    return nlp, replace(run, iterations=iterations), p_num, [note]


def _assemble(nlp: FilterErrorNLP, data: Dataset, run, values: np.ndarray, unc, seconds: float) -> FilterErrorEstimate:
    """The estimate in natural units, with the EKF pass at the optimum."""
    model, setup = nlp.model, nlp.setup
    npar, k_q = model.n_parameters, len(setup.noisy)
    q_opt = setup.q_start.copy()
    q_opt[setup.noisy] = values[npar:npar + k_q]
    R_opt = values[npar + k_q:] if setup.estimate_R else setup.r_start
    notes = list(unc.notes)
    units_note = undeclared_units_note(data.undeclared_units)
    notes += [units_note] if units_note else []
    at_floor = [o for o, side in zip(model.output_names, unc.active[npar + k_q:]) if side == "lower"] \
        if setup.estimate_R else []
    if at_floor:
        notes.append(Note(
            f"the measurement-noise variance of {at_floor} went to its floor: under this likelihood the channel's "
            "noise cannot be told from the process noise (it measures a combination of noisy states), and the std "
            "of what that channel alone determines (its bias, say) are far too small. Give R for it (R=...), "
            "or use formulation='steady-state'", NoteCode.NOISE_FLOOR))
    if not run.success:
        notes.append(Note(f"the solver did not converge ({run.status}): the estimate is not a stationary point of V",
                          NoteCode.NOT_VERIFIED))
    free = np.array([side is None for side in unc.active])
    success = run.success and bool(np.all(np.isfinite(unc.std[free])))
    result = ExtendedKalmanFilter(model, values[:npar], q_opt, R_opt, setup.P0).filter(data)
    return FilterErrorEstimate(
        **parameter_fields(model, values[:npar], unc, unc.reasons[:npar], list(unc.codes[:npar])),
        process_noise={model.state_names[i]: float(q_opt[i]) for i in range(model.n_states) if q_opt[i] > 0},
        process_noise_std={model.state_names[i]: float(s) for i, s in zip(setup.noisy, unc.std[npar:npar + k_q])},
        R=np.asarray(R_opt, dtype=float), R_std=unc.std[npar + k_q:] if setup.estimate_R else np.zeros(model.n_outputs),
        R_estimated=setup.estimate_R, cost=run.f * data.n_samples,
        log_likelihood=result.log_likelihood, success=success, status=run.status,
        outcome=Outcome.CONVERGED if success else Outcome.NOT_CONVERGED, n_iterations=run.iterations,
        n_samples=data.n_samples, seconds=seconds, filter=result, notes=notes,
        residual_checks=innovation_checks(result, model, data))


def innovation_checks(result, model, data) -> tuple:
    """The residual tests of each channel's normalised innovations ``e_kj / sqrt(S_kjj)`` in time
    order: whiteness, independence from the past inputs, no change in time (one Holm family)."""
    scale = np.sqrt(np.maximum(np.einsum("kjj->kj", result.innovation_covariance), 1e-300))
    names, inputs = tested_signals(model, data)
    return series_checks(result.innovation / scale, result.output_names, inputs, names, in_time=True, dynamic=True)


@dataclass(frozen=True)
class _FilterErrorUncertainty:
    covariance: np.ndarray
    std: np.ndarray
    reasons: list
    codes: np.ndarray
    active: list
    notes: list


def _uncertainty(nlp: FilterErrorNLP, w: np.ndarray, hessian: np.ndarray, to_natural: np.ndarray):
    """Covariance of the decision variables in natural units from the exact Hessian of V (or the
    Fisher information), every variable on a bound held (:func:`held_covariance`, the path all
    formulations share), with the reasons and notes of this likelihood's form."""
    held = held_covariance(w, hessian, nlp.lower, nlp.upper, to_natural, lambda i, side: side is not None)
    notes, reasons = [], [None] * len(w)
    codes = np.array([None] * len(w), dtype=object)
    if held.singular:
        notes.append(Note("the Hessian of V is not positive definite at the solution: the standard deviations are "
                          "not available (the parameters are not all identifiable from these data)",
                          NoteCode.NOT_IDENTIFIABLE))
        for i in np.flatnonzero(~held.held):
            reasons[i], codes[i] = "Hessian of V not positive definite", StdReason.SINGULAR
    for i, side in enumerate(held.active):
        if side:
            reasons[i], codes[i] = f"on its {side} bound", StdReason.ACTIVE_BOUND
    if held.held.any():
        notes.append(Note(f"on a bound (no std): {[nm for nm, a in zip(nlp.names, held.active) if a]}",
                          NoteCode.BOUNDS))
    return _FilterErrorUncertainty(held.covariance, held.std, reasons, codes, held.active, notes)
