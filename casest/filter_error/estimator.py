"""Filter-error maximum likelihood: parameters (and process-noise intensities) from the
prediction errors of an extended Kalman filter (reference summary Sec. 5, Eq. 5.3-5.7).

Output error assumes deterministic states; with process noise (turbulence) the states
wander away from any simulation, and where the inputs respond to the noise (a pilot or a
controller in the loop) the output-error estimates are biased. Filter error instead
minimises the negative log-likelihood of the filter's one-step prediction errors::

    V(theta, q, R) = 1/2 sum_k [ e_k' S_k^-1 e_k + ln det S_k ]              (Eq. 5.7)
    e_k = y_k - h(x(k|k-1), u_k, theta),   S_k = H P(k|k-1) H' + R

with the filter of :class:`casest.ExtendedKalmanFilter` (the same step, Jacobians and
discretisation) written as one CasADi recursion, so that IPOPT gets the exact gradient and
Hessian through the filter. Missing channels (NaN) drop out of e_k and S_k. Decision
variables: the model's parameters (box-bounded, scaled), the logarithms of the estimated
process-noise intensities and of the measurement-noise variances R (diagonal).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Mapping

import casadi as ca
import numpy as np

from ..options import (FilterErrorCovariance, FilterErrorFormulation, FilterErrorSolver, InnovationCovariance,
                       OperatingPoint, check_option)
from ..backend.ipopt import SolverSettings, run_ipopt
from ..backend.tolerances import cost_tolerance
from ..data.dataset import Dataset, undeclared_units_note
from ..errors import OptionError
from ..models.dynamic import DynamicModel
from ..problem.problem import Problem
from ..estimation.residual_family import series_checks, tested_signals
from ..status import Note, NoteCode, Outcome, StdReason
from .nlp import (FilterErrorNLP, FilterErrorSetup, filter_error_setup, intensity_vector,
                               time_varying_columns, time_varying_graph)
from .result import FilterErrorEstimate
from ..filters.ekf import ExtendedKalmanFilter
from .scoring import score
from .relaxation import MAX_ROUNDS, innovation_estimate
from .steady import check_steady_data, reference_point, steady_record_columns, steady_state_gain
from .uncertainty import held_covariance, parameter_fields


__all__ = ["FilterErrorEstimate", "filter_error_estimate", "filter_error_cost"]

LOG_2PI = float(np.log(2.0 * np.pi))



def filter_error_cost(model: DynamicModel, data: Dataset, theta, process_noise, R, P0=None) -> float:
    """V of summary Eq. 5.7 (no constants) at given parameters, intensities and R, by the
    symbolic filter recursion.

    Parameters
    ----------
    model : DynamicModel
    data : Dataset
    theta : mapping or array_like, shape (n_parameters,)
    process_noise : mapping or array_like (n_states,)
        Continuous intensities per state.
    R : array_like, shape (n_outputs,)
        Measurement-noise variances.
    P0 : array_like, shape (n_states, n_states), optional
        Initial state covariance (default zero: x0 known).

    Returns
    -------
    float
        ``1/2 sum_k (e_k' S_k^-1 e_k + ln det S_k)`` over the record.
    """
    model.check_data(data)
    n = model.n_states
    q = intensity_vector(model, process_noise)
    P0 = np.zeros((n, n)) if P0 is None else np.asarray(P0, dtype=float).reshape(n, n)
    graph = time_varying_graph(model, data.n_samples, P0)
    syms, V = graph.symbols, graph.V
    D, last = time_varying_columns(model, data)
    th = model.vector(theta) if isinstance(theta, Mapping) else np.asarray(theta, dtype=float)
    f = ca.Function("V", list(syms), [V])
    return float(f(th, q, np.asarray(R, dtype=float), D, last, model.initial_values(data)))


def filter_error_estimate(
    model: DynamicModel | Problem,
    data: Dataset | None,
    process_noise: Mapping[str, float],
    *,
    estimate_process_noise: bool = True,
    R=None,
    start: Mapping[str, float] | np.ndarray | None = None,
    P0=None,
    max_iter: int = 300,
    tol: float = 1e-10,
    print_level: int = 0,
    settings: SolverSettings | None = None,
    formulation: FilterErrorFormulation = "time-varying",
    solver: FilterErrorSolver = "scoring",
    covariance: FilterErrorCovariance = "hessian",
    operating_point: OperatingPoint | None = None,
    innovation_covariance: InnovationCovariance = "diagonal",
    max_rounds: int = MAX_ROUNDS,
) -> FilterErrorEstimate:
    """Filter-error maximum likelihood (summary Sec. 5) on a dynamic model with process noise.

    Parameters
    ----------
    model : DynamicModel or Problem
        Integrator ``"rk4"``; every parameter is estimated within its bounds. A
        :class:`casest.Problem` (with ``data`` None) brings its record, its fixed parameters and
        its noise model: ``KnownNoise`` gives ``R``, ``DiagonalNoise`` estimates it.
    data : Dataset or None
        The model's record (time, inputs, outputs; NaN outputs are missing).
    process_noise : mapping state name -> intensity
        The states with continuous white process noise on their rhs and its intensity (state
        rate squared per hertz): the start, or fixed. States not named get none.
    estimate_process_noise : bool
        Estimate the named intensities (default) or hold them.
    R : array_like, shape (n_outputs,), optional
        Known measurement-noise variances; default: estimated.
    start : mapping or array_like, optional
        Parameter start (default the model's nominal values).
    P0 : array_like, shape (n_states, n_states), optional
        Initial-state covariance (default zero: the initial state is known or a parameter); the
        time-varying formulation only.
    max_iter, tol, print_level, settings
        The solver's settings (tol on V / N) over casest's :class:`SolverSettings`.
    formulation : {"time-varying", "steady-state", "innovation"}
        The EKF with P(k|k-1) over the record (exact likelihood, missing samples allowed);
        one gain at an operating point with R estimated
        (:mod:`~casest.filter_error.steady`); flight-test practice, the innovation
        covariance in closed form (:mod:`~casest.filter_error.innovation`; leave ``R``
        out). The one-gain forms need uniform sampling and complete outputs.
    solver : {"scoring", "ipopt"}
        Levenberg-Marquardt on the Fisher information (first derivatives only,
        :mod:`~casest.filter_error.scoring`), or IPOPT with the exact Hessian: the same optimum.
    covariance : {"hessian", "fisher", "sandwich"}
        The inverse exact Hessian of V, or the inverse Fisher information (the Cramer-Rao
        bound); the innovation form reports the latter (with ``"hessian"`` too) and ignores
        ``solver``. ``"sandwich"`` (innovation form only): ``M^-1 B M^-1`` with M the
        information of the diagonal weighting and B its products with the full innovation
        covariance, the estimator's own covariance where the channels' innovations are
        correlated (the Cramer-Rao bound of the diagonal form then overstates the std: 1-7
        times on ``models/turbulent_longitudinal.py``, the sandwich 0.7-1.9 times the
        Monte-Carlo spread).
    operating_point : {"first", "mean"}, optional
        Where the one-gain forms linearise: the first state and input, or the mean predicted
        state and input, renewed until the estimate settles (default ``"mean"`` for
        ``"steady-state"``, ``"first"`` for ``"innovation"``).
    innovation_covariance : {"diagonal", "full"}
        The innovation form's closed-form innovation covariance: its diagonal
        ``diag(sum e e' / N)``, as flight-test practice takes it (default), or the full matrix
        ``sum e e' / N``, a different estimator where the channels' innovations are correlated.
    max_rounds : int
        The innovation form's relaxation rounds (R update, F compensation) before the estimate
        is reported as not settled; ``max_iter`` bounds the Gauss-Newton steps of one round.

    Returns
    -------
    FilterErrorEstimate
    """
    t0 = time.perf_counter()
    if isinstance(model, Problem):
        model, data, R = _problem_parts(model, data, R)
    _check_forms(formulation, solver, covariance, operating_point, R is None and estimate_process_noise)
    check_option("innovation_covariance", innovation_covariance, InnovationCovariance)
    if not (isinstance(max_rounds, (int, np.integer)) and max_rounds >= 1):
        raise OptionError(f"max_rounds must be a positive integer, got {max_rounds!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise OptionError(f"max_iter must be a whole number of solver steps >= 1, got {max_iter!r}")
    if P0 is not None and formulation != "time-varying":
        raise OptionError(f"P0 is not used by the {formulation!r} formulation (its one gain does not depend on the "
                          "initial covariance): leave P0 out, or use formulation='time-varying'")
    setup = filter_error_setup(model, data, process_noise, estimate_process_noise, R, start, P0)
    settings = replace(settings or SolverSettings(), max_iter=int(max_iter), tol=float(tol),
                       print_level=int(print_level))
    options = _FormulationOptions(solver, covariance, operating_point, innovation_covariance, int(max_rounds), t0)
    return FORMULATIONS[formulation](model, data, setup, settings, options)


def _problem_parts(problem: Problem, data, R) -> tuple:
    """The model (fixed parameters substituted), the record and the known R of a Problem."""
    if data is not None or problem.experiments or problem.stage1_data is not None:
        raise OptionError("filter_error_estimate(problem, None, process_noise) takes the problem's one record: give "
                          "the data to the Problem (one Dataset, no experiments or stage-1 data), not here")
    if problem.noise.estimated and not problem.noise.profiled_per_channel:  # a full R
        raise OptionError(f"filter error estimates a diagonal R or takes a known one; this problem has "
                          f"{problem.describe_noise()}: use DiagonalNoise() or KnownNoise(...)")
    if R is not None and problem.known_R is not None:
        raise OptionError("give R once: in the Problem's KnownNoise or as R=, not both")
    return problem.model, problem.data, R if R is not None else problem.known_R


@dataclass(frozen=True)
class _FormulationOptions:
    """What a formulation takes besides the model, the data, the setup and the solver's settings."""

    solver: str
    covariance: str
    operating_point: str | None
    innovation_covariance: str
    max_rounds: int
    t0: float


def _innovation(model: DynamicModel, data: Dataset, setup: FilterErrorSetup, settings: SolverSettings,
                options: _FormulationOptions) -> FilterErrorEstimate:
    """The practice formulation (:mod:`casest.filter_error.relaxation`)."""
    return innovation_estimate(model, data, setup.q_start, list(setup.noisy), setup.theta0, settings,
                               options.operating_point or "first", options.innovation_covariance, options.max_rounds,
                               sandwich=options.covariance == "sandwich")


def _steady_state(model: DynamicModel, data: Dataset, setup: FilterErrorSetup, settings: SolverSettings,
                  options: _FormulationOptions) -> FilterErrorEstimate:
    """One gain at an operating point, R estimated (:mod:`casest.filter_error.steady`)."""
    nlp, run, p_num, notes = _solve_steady(model, data, setup, settings, options.solver,
                                           options.operating_point or "mean")
    return _finish(nlp, data, run, p_num, notes, options, "steady-state")


def _time_varying(model: DynamicModel, data: Dataset, setup: FilterErrorSetup, settings: SolverSettings,
                  options: _FormulationOptions) -> FilterErrorEstimate:
    """The EKF with P(k|k-1) over the record: the exact likelihood."""
    nlp = FilterErrorNLP(model, setup, data.n_samples)
    D_num, last_num = time_varying_columns(model, data)
    p_num = np.concatenate([D_num.reshape(-1, order="F"), last_num, model.initial_values(data)])
    run = _solve_nlp(nlp, p_num, settings, data.n_samples, solver=options.solver)
    return _finish(nlp, data, run, p_num, [], options, "time-varying")


def _finish(nlp: FilterErrorNLP, data: Dataset, run, p_num: np.ndarray, notes: list, options: _FormulationOptions,
            formulation: str) -> FilterErrorEstimate:
    """The covariance (exact Hessian or Fisher information) and the result of a likelihood solve."""
    N = data.n_samples
    hessian = nlp.information(run.x, p_num) if options.covariance == "fisher" else nlp.hessian_of_v(run.x, p_num, N)
    values, to_natural = nlp.natural(run.x)
    result = _assemble(nlp, data, run, values, _uncertainty(nlp, run.x, hessian, to_natural),
                       time.perf_counter() - options.t0)
    return replace(result, formulation=formulation, notes=notes + result.notes)


#: the formulations by name (``formulation=``): each a strategy of the same signature
FORMULATIONS = {"time-varying": _time_varying, "steady-state": _steady_state, "innovation": _innovation}


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


def _check_forms(formulation: str, solver: str, covariance: str, operating_point: str | None,
                 noise_estimated: bool) -> None:
    """Refuse option values filter-error ML does not know, or that the formulation does not take."""
    check_option("formulation", formulation, FilterErrorFormulation)
    check_option("solver", solver, FilterErrorSolver)
    check_option("covariance", covariance, FilterErrorCovariance)
    if covariance == "sandwich" and formulation != "innovation":
        raise OptionError("covariance='sandwich' is the innovation formulation's (formulation='innovation'); the "
                          "other forms estimate R with the parameters: use 'hessian' or 'fisher'")
    if formulation == "innovation" and not noise_estimated:
        raise OptionError("formulation='innovation' estimates the process noise and the innovation covariance "
                          "itself: leave R out and estimate_process_noise at True")
    if operating_point is None:
        return
    if formulation == "time-varying":
        raise OptionError("operating_point is for formulation='steady-state' or 'innovation': the time-varying form "
                          "linearises at every sample's own state; leave it out")
    check_option("operating_point", operating_point, OperatingPoint)


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
