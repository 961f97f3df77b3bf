"""The one call: separate, sweep (stage 1), solve (stage 2), uncertainty."""

from __future__ import annotations

import time
import warnings
from typing import Mapping, Sequence

import numpy as np

from .data import Dataset
from .model import Model
from .result import Estimate
from .separate import Partition, separate
from .stage1 import SweepSettings, sweep
from .stage2 import SolverSettings, active_bounds, noise_floor, solve_stage2
from .uncertainty import parameter_uncertainty, correlation

__all__ = ["estimate", "finish_estimate", "package_estimate"]


def estimate(
    model: Model,
    data: Dataset,
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
    max_starts: int = 4,
) -> Estimate:
    """Estimate the model's parameters and noise with the two-stage algorithm.

    Stage 1 sweeps xi2 on ``stage1_data`` (default ``data``) and solves a linear least
    squares for xi1 at every candidate; its verdict picks the stage-2 mode when
    ``mode="auto"``. Stage 2 maximises the likelihood of ``data`` (paper Eq. 6) with
    IPOPT, started from the best candidate.

    Parameters
    ----------
    model : Model
    data : Dataset
        Stage-2 data, N samples.
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
        When stage 1 does not find one clear minimum, stage 2 also starts from the next
        best local minima of Tr[R] and from the nominal values (up to this many starts
        in all) and keeps the lowest ML cost; equal costs (1e-9 relative) go to the
        start nearest the nominal values, which fixes the labelling of symmetric models.

    Returns
    -------
    Estimate
        ``success`` is False (with a warning) when IPOPT did not converge.
    """
    timings = {}
    t0 = time.perf_counter()
    data.check_model(model)
    if stage1_data is not None:
        stage1_data.check_model(model)
    if mode not in ("auto", "reduced", "full", "alternating"):
        raise ValueError(f"mode must be 'auto', 'reduced', 'full' or 'alternating', got {mode!r}")
    if partition is None:
        partition = separate(model, linear=linear, nonlinear=nonlinear)
    timings["separate"] = time.perf_counter() - t0

    notes = []
    landscape = None
    if start is None:
        landscape = sweep(model, stage1_data or data, partition, sweep_settings)
        timings["stage1"] = landscape.seconds
        theta0 = partition.assemble(landscape.best_xi1, landscape.best_xi2)
        clipped = np.clip(theta0, model.lower_bounds, model.upper_bounds)
        moved = [n for n, a, b in zip(model.parameter_names, theta0, clipped) if a != b]
        if moved:
            notes.append(f"stage-1 start of {moved} clipped into the bounds")
        theta0 = clipped
        chosen = landscape.recommended_mode if mode == "auto" else mode
    else:
        theta0 = model.vector(start)
        chosen = "full" if mode == "auto" else mode
    starts = [("the best stage-1 candidate", theta0)]
    if landscape is not None and landscape.verdict not in ("unique", "linear"):
        starts += _other_starts(model, partition, landscape, max_starts - 1)
    stage2 = _best_of(model, data, partition, chosen, solver_settings, starts, notes)
    timings["stage2"] = time.perf_counter() - t0 - sum(timings.values())
    return finish_estimate(model, data, partition, stage2, landscape, covariance, solver_settings, notes, timings)


def _other_starts(model, partition, landscape, count: int) -> list:
    """Further stage-2 starts: next-best local minima of Tr[R], then the nominal values."""
    out = []
    for m in landscape.local_minima[1:]:
        if len(out) >= max(count - 1, 0):
            break
        if np.all(np.isfinite(landscape.xi1[m])):
            out.append((f"local minimum {len(out) + 2} of Tr[R]", partition.assemble(landscape.xi1[m], landscape.candidates[m])))
    if count > 0:
        out.append(("the nominal values", model.nominal.copy()))
    return [(label, np.clip(theta, model.lower_bounds, model.upper_bounds)) for label, theta in out]


def _best_of(model, data, partition, mode, settings, starts, notes):
    """Solve stage 2 from every start; keep the lowest cost, ties to the start nearest the nominal."""
    results = []
    for label, theta0 in starts:
        res = solve_stage2(model, data, theta0, partition, mode, settings)
        results.append((label, res))
    if len(results) == 1:
        return results[0][1]
    good = [(label, r) for label, r in results if r.success] or results
    best_cost = min(r.cost for _, r in good)
    tol = 1e-9 * max(1.0, abs(best_cost))
    ties = [(label, r) for label, r in good if r.cost <= best_cost + tol]
    distance = [np.linalg.norm((r.theta - model.nominal) / model.scales) for _, r in ties]
    label, best = ties[int(np.argmin(distance))]
    costs = ", ".join(f"{lab}: {r.cost:.10g}{'' if r.success else ' (failed)'}" for lab, r in results)
    notes.append(f"stage 2 ran from {len(results)} starts ({costs}); kept the one from {label}")
    best.n_iterations = sum(r.n_iterations for _, r in results)
    return best


def finish_estimate(model, data, partition, stage2, landscape, covariance, solver_settings, notes, timings) -> Estimate:
    """Uncertainty and packaging of a stage-2 result into an :class:`Estimate`."""
    t0 = time.perf_counter()
    settings = solver_settings or SolverSettings()
    active = active_bounds(stage2.theta, model.lower_bounds, model.upper_bounds, model.scales)
    at_floor = stage2.R <= noise_floor(data, settings) * (1 + 1e-6)
    unc = parameter_uncertainty(model, data, stage2.theta, stage2.R, active, at_floor, covariance)
    timings["uncertainty"] = time.perf_counter() - t0
    timings["total"] = sum(v for k, v in timings.items() if k != "total")
    all_notes = list(notes) + list(stage2.notes)
    on_bound = [f"{n} ({side})" for n, side in zip(model.parameter_names, active) if side]
    if on_bound:
        all_notes.append(
            f"parameter(s) on a bound: {', '.join(on_bound)}; their std is not available and the "
            "others' std are conditional on them"
        )
    unidentified = [n for n, r in zip(model.parameter_names, unc.reasons) if r and "not identifiable" in r]
    if unidentified:
        message = (
            f"parameters {unidentified} are not identifiable from these data (the ML cost is flat "
            "along a combination of them); fix some of them, reparametrise, or collect data that "
            "separate them"
        )
        all_notes.append(message)
        warnings.warn(message, RuntimeWarning, stacklevel=3)
    if not stage2.success:
        warnings.warn(
            f"stage 2 did not converge ({stage2.status}); the estimate is the last iterate. "
            "Try mode='full', a better start, or more iterations (SolverSettings.max_iter)",
            RuntimeWarning,
            stacklevel=3,
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
    )
