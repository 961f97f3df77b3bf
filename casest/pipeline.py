"""The one call: separate, sweep (stage 1), solve (stage 2), uncertainty."""

from __future__ import annotations

import time
import warnings
from dataclasses import replace
from typing import Mapping, Sequence

import numpy as np

from .data import Dataset
from .model import Model, OptionError
from .noise import CorrelatedNoise, KnownNoise
from .problem import Problem
from .result import Estimate
from .separate import Partition, separate
from .status import Note, NoteCode, Outcome, StdReason
from .stage1 import IdentifiabilityError, SweepSettings, sweep
from .stage2 import (
    SolverSettings,
    Stage2Result,
    active_bounds,
    noise_floor,
    solve_stage2,
)
from .uncertainty import parameter_uncertainty, correlation

__all__ = ["estimate", "finish_estimate", "package_estimate"]


def estimate(
    model: Model | Problem,
    data: Dataset | Sequence[Dataset] | Mapping[str, Dataset] | None = None,
    *,
    stage1_data: Dataset | None = None,
    mode: str = "auto",
    sweep_settings: SweepSettings | None = None,
    solver_settings: SolverSettings | None = None,
    partition: Partition | None = None,
    linear: Sequence[str] = (),
    nonlinear: Sequence[str] = (),
    start: Mapping[str, float] | np.ndarray | None = None,
    covariance: str = "hessian",
    max_starts: int = 6,
    fixed: Mapping[str, float] | None = None,
    noise: KnownNoise | CorrelatedNoise | None = None,
    prior_penalty: bool = False,
    separate_noise: bool = True,
) -> Estimate:
    """Estimate the model's parameters and noise with the two-stage algorithm.

    Stage 1 sweeps xi2 on ``stage1_data`` (default ``data``) and solves a linear least
    squares for xi1 at every candidate; its verdict picks the stage-2 mode when
    ``mode="auto"``. Stage 2 maximises the likelihood of ``data`` (paper Eq. 6) with
    IPOPT, started from the best candidate.

    Parameters
    ----------
    model : Model or Problem
        A :class:`casest.Problem` carries the data, experiments, noise model, priors and
        fixed parameters: ``casest.estimate(problem)``, with those options left out.
    data : Dataset, or sequence / mapping of Dataset
        Stage-2 data, N samples; several data sets are experiments that share the
        parameters (see ``separate_noise``), stacked for both stages.
    stage1_data : Dataset, optional
        Data for the sweep (paper Table 5 uses other manoeuvres than stage 2).
    mode : {"auto", "reduced", "full", "alternating"}
    sweep_settings : SweepSettings, optional
    solver_settings : SolverSettings, optional
    partition : Partition, optional
        A precomputed split; otherwise :func:`casest.separate` with ``linear`` and
        ``nonlinear`` as pins.
    linear, nonlinear : sequence of str
        Parameters pinned to xi1 / xi2.
    start : mapping or array, optional
        Skip stage 1 and start stage 2 here (must lie inside the bounds).
    covariance : {"hessian", "hessian-dof", "gauss-newton", "gauss-newton-dof"}
    max_starts : int
        Budget of stage-2 starts: the best stage-1 candidate, the next-best local minima
        of Tr[R] and the nominal values, this many in all. Each start is solved in the
        ``mode`` (``auto``: ``reduced``, the paper's variable projection, when there are
        linear and nonlinear parameters, and, when that solve fails or ends above its
        start's cost, the other mode; an explicit mode is kept). The lowest converged cost wins; equal costs
        (1e-9 relative) go to the solution nearest the nominal values, and distinct
        minima of equal cost are named in a note (symmetries, aliases).

    fixed : mapping of str to float, optional
        Parameters held at these values (with those declared ``Parameter(fixed=True)``,
        held at their nominal values). They are substituted into the model, so they drop
        out of every stage; the estimate lists them with their value, no std, and the
        reason.
    noise : KnownNoise or CorrelatedNoise, optional
        ``KnownNoise``: known std per output: stage 1 ranks by the weighted residuals,
        stage 2 is the weighted least squares with R held, and the std follow from the
        given R. ``CorrelatedNoise()``: R full and unknown (correlated channels),
        estimated with the parameters (full mode). Default: R unknown and diagonal,
        estimated with the parameters (paper Eq. 6).
    separate_noise : bool
        With several experiments: one noise R per experiment (outputs reported as
        ``output@experiment``), or one R for all (False).
    prior_penalty : bool
        MAP: the parameters' Gaussian priors also enter the cost as
        ``(theta - mean)^2 / (2 std^2)`` (stage 2 in full mode from every start), and the
        covariance includes them. Default False: priors only steer stage 1's sampling.

    Returns
    -------
    Estimate
        ``success`` is False (with a warning and a note) when no stage-2 solve converged
        at or below the lowest cost of its starts (``Estimate.start_cost``); the estimate is
        then the best point seen.
    """
    if isinstance(model, Problem):
        if data is not None or stage1_data is not None or fixed or noise is not None or prior_penalty \
                or not separate_noise:
            raise OptionError("estimate(problem) takes the data, noise model, priors and fixed parameters from the "
                              "Problem; give them to casest.Problem(...) instead")
        problem = model
    else:
        problem = Problem(model, data, stage1_data=stage1_data, noise=noise, fixed=fixed,
                          prior_penalty=prior_penalty, separate_noise=separate_noise)
    if problem.held and partition is not None:
        raise OptionError("give either a partition or fixed parameters: the partition of the model with "
                          "parameters fixed is computed from the reduced model")
    est = _estimate(problem, mode, sweep_settings, solver_settings, partition,
                    [n for n in linear if n not in problem.held], [n for n in nonlinear if n not in problem.held],
                    start, covariance, max_starts)
    if problem.held:
        est = _with_fixed_parameters(problem.full_model, est, problem.held)
    if problem.experiments:
        names = problem.experiments
        est.experiments = names
        est.notes.append(Note(f"{len(names)} experiments {list(names)} share the parameters; "
                              + ("each has its own noise R" if problem.separate_noise else "one noise R for all"),
                              NoteCode.NOISE_MODEL))
    return est


def _estimate(problem: Problem, mode, sweep_settings, solver_settings, partition, linear, nonlinear, start,
              covariance, max_starts) -> Estimate:
    """The two stages and the covariance on a problem (its model, without fixed parameters)."""
    model = problem.model
    timings = {}
    t0 = time.perf_counter()
    if mode not in ("auto", "reduced", "full", "alternating"):
        raise OptionError(f"mode must be 'auto', 'reduced', 'full' or 'alternating', got {mode!r}")
    if partition is None:
        partition = separate(model, linear=linear, nonlinear=nonlinear)
    timings["separate"] = time.perf_counter() - t0

    notes = []
    landscape = None
    if start is None:
        landscape = sweep(problem, partition=partition, settings=sweep_settings)
        if problem.noise.stage1_weights(model) is not None:
            notes.append(Note("stage 1 ranked candidates by the residuals weighted with the known noise (Tr[R] is "
                              "of the weighted residuals, in units of the known variances)", NoteCode.NOISE_MODEL))
        timings["stage1"] = landscape.seconds
        starts = _starts(model, partition, landscape, max_starts)
    else:
        starts = [("the given start", problem.vector(start))]
    primary = mode if mode != "auto" else ("reduced" if partition.n_linear and partition.n_nonlinear else "full")
    if problem.penalty is not None:
        primary = "full"  # the priors are terms of the full problem
        notes.append(Note("MAP: the Gaussian priors enter the cost as penalties; J includes them", NoteCode.NOISE_MODEL))
    if problem.full_noise:
        primary = "full"  # the full R is estimated with all of theta
    if problem.dynamic:
        if mode not in ("auto", "full"):
            notes.append(Note(f"output-error stage 2 of a dynamic model runs in full mode (asked: {mode})",
                              NoteCode.MODE_SWITCH))
        primary = "full"  # output error: all of theta through the simulation
    # an explicit mode is kept; "auto" may switch a failed or climbing solve to the other mode
    switch = mode == "auto" and problem.penalty is None and not problem.full_noise and not problem.dynamic
    stage2, start_cost = _refine(problem, partition, primary, solver_settings, starts, notes, switch_modes=switch)
    timings["stage2"] = time.perf_counter() - t0 - sum(timings.values())
    est = finish_estimate(problem, partition, stage2, landscape, covariance, solver_settings, notes, timings)
    est.R_full = getattr(stage2, "R_full", None)
    est.start_cost = start_cost
    est.noise_model = problem.describe_noise()
    est.noise_estimated = problem.noise.estimated
    return est


def _with_fixed_parameters(model: Model, est: Estimate, held: dict) -> Estimate:
    """The estimate of the reduced model, with the held parameters put back (value, no std, reason)."""
    n = model.n_parameters
    where = [model.parameter_names.index(name) for name in est.parameter_names]
    theta = np.array([held.get(name, np.nan) for name in model.parameter_names], dtype=float)
    theta[where] = est.theta
    std = np.full(n, np.nan)
    std[where] = est.std
    cov = np.full((n, n), np.nan)
    cov[np.ix_(where, where)] = est.covariance
    reasons = [f"fixed at {held[name]:.10g} (not estimated)" if name in held else None for name in model.parameter_names]
    codes = [StdReason.FIXED if name in held else None for name in model.parameter_names]
    active = [None] * n
    for k, i in enumerate(where):
        reasons[i], codes[i], active[i] = est.std_reasons[k], est.std_reason_codes[k], est.active_bounds[k]
    est.parameter_names = model.parameter_names
    est.theta, est.std, est.covariance, est.correlation = theta, std, cov, correlation(cov)
    est.std_reasons, est.std_reason_codes, est.active_bounds = reasons, codes, active
    est.lower_bounds, est.upper_bounds = model.lower_bounds, model.upper_bounds
    est.parameter_units = tuple(p.unit for p in model.parameters)
    est.fixed_parameters = tuple(held)
    est.notes = [Note(f"fixed (not estimated): {', '.join(f'{k} = {v:.10g}' for k, v in held.items())}",
                      NoteCode.FIXED)] + list(est.notes)
    return est


def _starts(model, partition, landscape, count: int) -> list:
    """Stage-2 starts: the best candidate, the next-best local minima of Tr[R], the nominal values.

    At most ``count`` in all (the nominal values always get a place unless ``count`` is 1);
    every start is clipped into the bounds (stage 1's xi1 already respects them).
    """
    out = [("the best stage-1 candidate", partition.assemble(landscape.best_xi1, landscape.best_xi2))]
    traces = [landscape.ranking[landscape.best_index]]
    for m in landscape.local_minima:
        if len(out) >= count - 1:
            break
        trace = landscape.ranking[m]
        # minima of the same Tr[R] as one already taken are a plateau (or an exact alias): one start is enough
        if m == landscape.best_index or not np.all(np.isfinite(landscape.xi1[m])) or any(
            abs(trace - t) <= 1e-9 * abs(t) for t in traces
        ):
            continue
        traces.append(trace)
        out.append((f"local minimum {len(out) + 1} of the stage-1 ranking", partition.assemble(landscape.xi1[m], landscape.candidates[m])))
    if count > 1 and not np.allclose(out[0][1], model.nominal):
        out.append(("the nominal values", model.nominal.copy()))
    return [(label, np.clip(theta, model.lower_bounds, model.upper_bounds)) for label, theta in out]


def _tolerance(cost: float) -> float:
    """Cost difference below which two ML costs count as equal (round-off of the solves)."""
    return 1e-9 * max(1.0, abs(cost))


def _refine(problem: Problem, partition, primary, settings, starts, notes, switch_modes: bool = True):
    """Stage 2 from every start, monotone: never return a cost above a start's without saying so.

    Each start is solved in ``primary`` mode; with ``switch_modes`` a solve that fails or
    ends above its start's cost is repeated in the other mode. Among the solves that converged below their start
    the lowest cost wins (equal costs: the one nearest the nominal values). If none of them
    is at or below the lowest start cost, the best point seen is returned with
    ``success=False`` and the reason.

    Returns
    -------
    Stage2Result, float
        The chosen result and the lowest cost among the starts.
    """
    settings = settings or SolverSettings()
    model = problem.model
    floor = noise_floor(problem.data, settings)
    other = {"reduced": "full", "full": "reduced", "alternating": "full"}[primary]
    if not switch_modes or (not (partition.n_linear and partition.n_nonlinear) and other == "reduced"):
        other = None  # reduced is the same problem as full without linear or nonlinear parameters
    # several starts: each first gets a short iteration budget (see SolverSettings.start_max_iter)
    explore = settings if len(starts) == 1 else replace(settings, max_iter=min(settings.max_iter, settings.start_max_iter))
    runs = []
    for label, theta0 in starts:
        start_cost, R0 = problem.start_point(theta0, floor)
        R0 = np.diag(R0).copy() if R0.ndim == 2 else R0
        res = _solve(problem, theta0, partition, primary, explore)
        climbed = res is not None and res.cost > start_cost + _tolerance(start_cost)
        # a start stopped by the short budget is continued later if it is promising
        out_of_budget = res is not None and explore is not settings and res.status == "Maximum_Iterations_Exceeded"
        if (res is None or not res.success or climbed) and not (out_of_budget and not climbed) and other is not None:
            why = ("climbed from J = {:.10g} to {:.10g}".format(start_cost, res.cost) if climbed else
                   "has A(xi2) rank-deficient at the start" if res is None else f"did not converge ({res.status})")
            alt = _solve(problem, theta0, partition, other, explore)
            if alt is not None:
                alt.n_iterations += res.n_iterations if res is not None else 0
                res = alt if res is None else min((res, alt), key=lambda r: (not _valid(r, start_cost), r.cost))
                notes.append(Note(f"stage 2 from {label} in {primary} mode {why}; re-solved in {other} mode: "
                                  f"J = {alt.cost:.10g}{'' if alt.success else ' (did not converge)'}", NoteCode.MODE_SWITCH))
        if res is None:
            notes.append(Note(f"stage 2 could not start from {label}: the linear parameters are not identifiable there",
                              NoteCode.STARTS))
            continue
        runs.append((label, theta0, R0, start_cost, res))
    if not runs:
        raise IdentifiabilityError(
            "stage 2 could not start from any start: A(xi2) is rank-deficient at every one; give nominal values "
            "that make the linear parameters identifiable, or fix some of them"
        )
    if explore is not settings:
        _continue_promising(problem, partition, primary, settings, runs, notes)
    lowest_start = min(run[3] for run in runs)
    valid = [run for run in runs if _valid(run[4], run[3])]
    if len(runs) > 1:
        costs = ", ".join(f"{label}: {r.cost:.10g}{'' if _valid(r, s) else (' (failed)' if not r.success else ' (climbed)')}"
                          for label, _, _, s, r in runs)
        notes.append(Note(f"stage 2 ran from {len(runs)} starts ({costs})", NoteCode.STARTS))
    iterations = sum(run[4].n_iterations for run in runs)
    if valid and min(run[4].cost for run in valid) <= lowest_start + _tolerance(lowest_start):
        best_cost = min(run[4].cost for run in valid)
        ties = sorted((run for run in valid if run[4].cost <= best_cost + _tolerance(best_cost)),
                      key=lambda run: run[4].cost)
        # one representative (its lowest cost) per distinct minimum; among distinct minima of
        # equal cost (symmetries) the one nearest the nominal values fixes the labelling
        distinct = []
        for run in ties:
            if not any(_same_minimum(model, run[4].theta, d[4].theta) for d in distinct):
                distinct.append(run)
        distance = [np.linalg.norm((run[4].theta - model.nominal) / model.scales) for run in distinct]
        label, *_, best = distinct[int(np.argmin(distance))]
        if len(runs) > 1:
            notes.append(Note(f"kept the solution from {label}", NoteCode.STARTS))
        _note_symmetries(model, best, distinct, notes)
        if best.mode == "reduced":
            # the reduced NLP's xi1 comes from normal equations, which lose digits when A is
            # ill-conditioned (NIST Kirby2, Lanczos3): a full-mode polish from the solution
            polished = _solve(problem, best.theta, partition, "full", settings)
            if polished is not None and polished.success and polished.cost <= best.cost + _tolerance(best.cost):
                iterations += polished.n_iterations
                polished.notes = best.notes + polished.notes
                polished.mode = "reduced, polished in full mode"
                best = polished
        best.n_iterations = iterations
        return best, lowest_start
    # nothing converged at or below the starts: return the best point seen, flagged
    seen = [(r.cost, label, r) for label, _, _, _, r in runs]
    seen += [(s, label, None) for label, _, _, s, _ in runs]
    cost, label, result = min(seen, key=lambda item: item[0])
    if result is None:
        theta0, R0 = next((t, R) for lab, t, R, _, _ in runs if lab == label)
        result = Stage2Result(theta=theta0.copy(), R=R0, cost=cost, success=False, status="No_Improvement",
                              message="no stage-2 solve improved on the starts", n_iterations=0, mode="none",
                              outcome=Outcome.NO_IMPROVEMENT)
        where = f"{label} itself (J = {cost:.10g}); stage 2 did not improve on it"
    else:
        result.success = False
        result.status = result.status if result.status != "Solve_Succeeded" else "Climbed"
        result.outcome = Outcome.CLIMBED if result.status == "Climbed" else Outcome.NOT_CONVERGED
        where = f"the last iterate of the solve from {label} (J = {cost:.10g})"
    result.message = "no stage-2 solve converged at or below the cost of its start"
    notes.append(Note(
        f"no stage-2 solve converged at or below the lowest start cost J = {lowest_start:.10g}; the estimate is "
        f"{where}. It is not a verified minimum: try more stage-1 candidates (SweepSettings.n_candidates), other "
        "bounds or scales, or mode='full'", NoteCode.NOT_VERIFIED))
    result.n_iterations = iterations
    return result, lowest_start


def _continue_promising(problem, partition, mode, settings, runs, notes) -> None:
    """Give the full ``max_iter`` to unfinished starts that are below every converged solution."""
    while True:
        best_valid = min((r.cost for _, _, _, s, r in runs if _valid(r, s)), default=np.inf)
        # unfinished and below every converged start, or the best itself stopped by the short
        # budget (accepted by the Newton check, but polished with the full budget)
        pending = [k for k, (_, _, _, s, r) in enumerate(runs)
                   if r.status == "Maximum_Iterations_Exceeded" and not getattr(r, "continued", False)
                   and (r.cost < best_valid if not r.success else r.cost <= best_valid + _tolerance(best_valid))]
        if not pending:
            return
        k = min(pending, key=lambda i: runs[i][4].cost)
        label, theta0, R0, start_cost, res = runs[k]
        more = _solve(problem, res.theta, partition, mode if res.mode == "none" else res.mode, settings)
        if more is None:
            res.continued = True
            continue
        more.n_iterations += res.n_iterations
        more.continued = True
        notes.append(Note(f"stage 2 from {label} was continued after {res.n_iterations} iterations (J = {res.cost:.10g}, "
                          f"below every converged start): J = {more.cost:.10g}"
                          f"{'' if more.success else ' (did not converge)'}", NoteCode.CONTINUED))
        runs[k] = (label, theta0, R0, start_cost, min((res, more), key=lambda r: (not _valid(r, start_cost), r.cost)))
        runs[k][4].continued = True


def _solve(problem, theta0, partition, mode, settings):
    """:func:`solve_stage2`, or ``None`` where the start leaves the linear parameters unidentifiable."""
    try:
        return solve_stage2(problem, theta0=theta0, partition=partition, mode=mode, settings=settings)
    except IdentifiabilityError:
        return None


def _valid(result, start_cost: float) -> bool:
    """Converged, and not above the cost of its own start."""
    return bool(result.success) and result.cost <= start_cost + _tolerance(start_cost)


def _differing(model, theta, other) -> np.ndarray:
    """Parameters that differ by more than 1e-4 of their magnitude (or scale), shape (n,)."""
    return np.abs(theta - other) > 1e-4 * np.maximum(model.scales, np.abs(other))


def _same_minimum(model, theta, other) -> bool:
    return not _differing(model, theta, other).any()


def _note_symmetries(model, best, ties, notes) -> None:
    """Name the parameters that differ between distinct minima of equal cost (aliases, permutations)."""
    for *_, r in ties:
        if r is best:
            continue
        differ = _differing(model, r.theta, best.theta)
        if differ.any():
            names = [n for n, d in zip(model.parameter_names, differ) if d]
            other = ", ".join(f"{n} = {v:.6g}" for n, v, d in zip(model.parameter_names, r.theta, differ) if d)
            notes.append(Note(
                f"another minimum has the same cost J = {r.cost:.10g} ({other}): the model has a symmetry or alias "
                f"in {names}; the data cannot tell the two apart, and the estimate is the one nearest "
                "the nominal values", NoteCode.SYMMETRY))


def finish_estimate(problem: Problem, partition, stage2, landscape, covariance, solver_settings, notes,
                    timings) -> Estimate:
    """Uncertainty and packaging of a stage-2 result into an :class:`Estimate`."""
    t0 = time.perf_counter()
    model, data = problem.model, problem.data
    settings = solver_settings or SolverSettings()
    active = active_bounds(stage2.theta, model.lower_bounds, model.upper_bounds, model.scales)
    at_floor = stage2.R <= noise_floor(data, settings) * (1 + 1e-6)
    R = getattr(stage2, "R_full", None)
    unc = parameter_uncertainty(problem, None, stage2.theta, stage2.R if R is None else R, active, at_floor, covariance)
    timings["uncertainty"] = time.perf_counter() - t0
    timings["total"] = sum(v for k, v in timings.items() if k != "total")
    all_notes = list(notes) + list(stage2.notes) + list(unc.notes)
    on_bound = [f"{n} ({side})" for n, side in zip(model.parameter_names, active) if side]
    if on_bound:
        all_notes.append(Note(
            f"parameter(s) on a bound: {', '.join(on_bound)}; their std is not available and the "
            "others' std are conditional on them", NoteCode.BOUNDS))
    unidentified = [n for n, c in zip(model.parameter_names, unc.reason_codes) if c is StdReason.NOT_IDENTIFIABLE]
    if unidentified:
        message = Note(
            f"parameters {unidentified} are not identifiable from these data (the ML cost is flat "
            "along a combination of them); fix some of them, reparametrise, or collect data that "
            "separate them", NoteCode.NOT_IDENTIFIABLE)
        all_notes.append(message)
        warnings.warn(message, RuntimeWarning, stacklevel=4)
    if not stage2.success:
        warnings.warn(
            f"stage 2 did not converge ({stage2.status}); the estimate is the last iterate. "
            "Try mode='full', a better start, or more iterations (SolverSettings.max_iter)",
            RuntimeWarning,
            stacklevel=4,
        )
    return package_estimate(model, data, partition.linear, partition.nonlinear, stage2, unc, active, landscape,
                            timings, all_notes)


def package_estimate(model, data, linear, nonlinear, stage2, unc, active, landscape, timings, notes) -> Estimate:
    """Assemble an :class:`Estimate` from a stage-2 result and its uncertainty."""
    return Estimate(
        model_name=model.name,
        parameter_names=model.parameter_names,
        output_names=model.output_names,
        theta=stage2.theta,
        std=unc.std,
        std_reasons=unc.reasons,
        std_reason_codes=list(unc.reason_codes) or [None] * model.n_parameters,
        outcome=stage2.outcome,
        covariance=unc.covariance,
        correlation=correlation(unc.covariance),
        covariance_method=unc.method,
        R=stage2.R,
        cost=stage2.cost,
        n_samples=data.n_samples,
        lower_bounds=model.lower_bounds,
        upper_bounds=model.upper_bounds,
        active_bounds=active,
        linear=tuple(linear),
        nonlinear=tuple(nonlinear),
        mode=stage2.mode,
        success=stage2.success,
        status=stage2.status,
        message=stage2.message,
        n_iterations=stage2.n_iterations,
        landscape=landscape,
        timings=timings,
        notes=list(notes),
        parameter_units=tuple(p.unit for p in model.parameters),
        n_measured=int(data.observed_counts().sum()),
        output_units=tuple(getattr(model, "output_units", ())),
    )
