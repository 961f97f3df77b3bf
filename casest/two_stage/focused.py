"""A second look when the first estimate's residuals fail: stage 1 again where the data inform.

The first sweep draws its candidates from the parameters' priors over their boxes. A box
spanning decades around a peak's centre or width (NIST's protocol box, a user's "somewhere
between 0.1 and 1e5") puts nearly every candidate where the data say nothing, and stage 2
from the best of them ends in a local minimum: two peaks fitted as one, a peak missed. Such
a minimum leaves structure in the residuals, and the residual tests see it.

When they fail and the model's structure names informative ranges for some of the swept
parameters (:func:`casest.two_stage.sweep.informative.informative_box`: shifts, rates and
scales of a signal), stage 1 sweeps those ranges and stage 2 runs from the best distinct
candidates, stopping once two of them reach the same lowest cost with residuals that pass.
The lower of the two estimates is kept and a note says what the second look found.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..backend.tolerances import cost_tolerance
from ..problem.problem import Problem
from ..status import Note, NoteCode
from .multistart import MultiStartResult, run_starts
from .sweep import IdentifiabilityError, SweepSettings, sweep
from .sweep.informative import InformativeBox, draw_informative, informative_box

__all__ = ["focused_look", "distinct_candidates", "FOCUSED_STARTS", "DISTINCT_SPACING"]

#: at most this many stage-2 starts from the focused sweep
FOCUSED_STARTS = 32
#: the focused starts stop once this many reached the same lowest cost, below the first estimate's,
#: with residuals that pass (one white solve is not enough: two peaks of opposite sign fitted to one
#: can leave white residuals)
AGREEING = 2
#: two starts differ when some parameter differs by this share of its informative range (its
#: logarithm for a rate or a scale)
DISTINCT_SPACING = 0.1


def _unit(candidates: np.ndarray, box: InformativeBox) -> np.ndarray:
    """Candidates as shares of their informative ranges (logarithmic where both ends are positive)."""
    lo, hi = box.lower, box.upper
    logs = np.array([role is not None and role.kind != "shift" and lo[j] > 0 for j, role in enumerate(box.roles)])
    with np.errstate(divide="ignore", invalid="ignore"):
        span = np.where(logs, np.log(np.abs(hi) / np.abs(lo)), hi - lo)
        offset = np.where(logs, np.log(np.abs(candidates) / np.abs(lo)), candidates - lo)
        unit = offset / np.where(span > 0, span, 1.0)
    return np.nan_to_num(unit)


def distinct_candidates(landscape, box: InformativeBox, count: int) -> list[int]:
    """The best-ranked candidates of a landscape at least :data:`DISTINCT_SPACING` apart.

    Parameters
    ----------
    landscape : Landscape
    box : InformativeBox
        The ranges the candidates were drawn in (their distances are measured there).
    count : int

    Returns
    -------
    list of int
        Indices into ``landscape.candidates``, best first (at most ``count``).
    """
    unit = _unit(landscape.candidates, box)
    usable = np.isfinite(landscape.ranking) & np.isfinite(landscape.xi1).all(axis=1)
    chosen: list[int] = []
    for i in np.argsort(np.where(usable, landscape.ranking, np.inf)):
        if not usable[i] or len(chosen) >= count:
            break
        if all(np.max(np.abs(unit[i] - unit[j])) >= DISTINCT_SPACING for j in chosen):
            chosen.append(int(i))
    return chosen


def focused_look(problem, partition, multi: MultiStartResult, solver_of, modes: tuple, settings, explore,
                 sweep_settings, residuals_white) -> tuple[MultiStartResult, list]:
    """Stage 1 and 2 again in the informative ranges when the first estimate's residuals fail.

    Parameters
    ----------
    problem : Problem
    partition : Partition
    multi : MultiStartResult
        The first estimate's multi-start.
    solver_of : callable
        ``Problem -> StartSolver``: solves stage 2 from a start on a problem (the pipeline's).
    modes : (str, str or None)
        The first solve's mode and the mode a failed solve switches to.
    settings, explore : SolverSettings
        The full settings and a start's exploratory ones.
    sweep_settings : SweepSettings or None
        The first sweep's settings (its candidate count and seed).
    residuals_white : callable
        ``theta -> bool``: whether the residual tests pass at ``theta``.

    Returns
    -------
    MultiStartResult
        The first one, or one whose result is the second look's lower estimate (its records
        after the first's).
    list of Note
        What the second look did (empty when it did not run); when its estimate is kept, these
        notes replace the first multi-start's.
    """
    if problem.dynamic:
        return multi, []
    model, data, _ = problem.stage1_inputs()
    # the structure first: most models have no informative range narrower than their box, and then
    # the residual tests (sorting a long record by fitted value) need not run here
    box = informative_box(model, partition, data)
    if box is None or residuals_white(multi.result.theta):
        return multi, []
    sweep_settings = sweep_settings or SweepSettings()
    seed = sweep_settings.seed if isinstance(sweep_settings.seed, (int, np.integer)) else 0
    candidates = draw_informative(model, partition, box, sweep_settings.n_candidates, int(seed))
    landscape = sweep(problem, partition=partition, settings=sweep_settings, candidates=candidates)
    chosen = distinct_candidates(landscape, box, FOCUSED_STARTS)
    narrowed = _narrowed(problem, box)
    # inside the ranges: the sweep's refinement around its best candidate may step beyond them
    starts = [(f"candidate {k + 1} of the focused sweep",
               np.clip(partition.assemble(landscape.xi1[i], landscape.candidates[i]), narrowed.model.lower_bounds,
                       narrowed.model.upper_bounds)) for k, i in enumerate(chosen)]
    first = multi.result.cost

    def enough(runs) -> str | None:
        valid = [r for r in runs if r.valid]
        if not valid:
            return None
        lowest = min(r.result.cost for r in valid)
        reached = [r for r in valid if r.result.cost <= lowest + cost_tolerance(lowest)]
        if lowest < first - cost_tolerance(first) and len(reached) >= AGREEING and residuals_white(reached[0].result.theta):
            return f"{len(reached)} of them reached the lowest cost and its residuals pass their tests"
        return None

    # variable projection where it applies: its basins are wider than those of theta as a whole
    reduced = bool(partition.n_linear and partition.n_nonlinear and problem.full_mode_reason is None)
    focused_modes = ("reduced", "full") if reduced else modes
    try:  # within the informative ranges first (a box of six decades misleads the solvers' steps) ...
        focused, notes = run_starts(solver_of(narrowed), starts, *focused_modes, settings, explore, enough)
    except IdentifiabilityError:  # no focused candidate left the linear parameters identifiable
        return multi, []
    # ... then from the best of them in the whole box, where the optimum may lie outside those ranges
    polish, polish_notes = run_starts(solver_of(problem), [("the focused sweep's best solve", focused.result.theta)],
                                      modes[0], modes[1], settings, settings)
    notes += polish_notes
    second = MultiStartResult(polish.result, min(focused.lowest_start_cost, polish.lowest_start_cost),
                              tuple(replace(r, kept=False) for r in focused.records) + polish.records)
    lower = second.result.success and second.result.cost < first - cost_tolerance(first)
    what = (f"the residuals at the first estimate (J = {first:.10g}) failed their tests; stage 1 swept again where "
            f"the data inform the parameters ({box.describe()}) and stage 2 ran from {len(focused.records)} of its "
            f"best distinct candidates within those ranges, then from the best in the whole box: "
            f"J = {second.result.cost:.10g}, "
            + ("lower: kept" if lower else "not lower: the first estimate kept"))
    if not lower:
        return multi, [Note(what, NoteCode.FOCUSED)]
    notes = [Note(what, NoteCode.FOCUSED)] + notes
    records = tuple(replace(r, kept=False) for r in multi.records) + second.records
    return MultiStartResult(second.result, min(multi.lowest_start_cost, second.lowest_start_cost), records), notes


def _narrowed(problem, box: InformativeBox):
    """The problem with the swept parameters' bounds at their informative ranges (the problem itself
    when it stacks experiments or sweeps other data: their noise models are set per experiment)."""
    if problem.experiments or problem.stage1_data is not None:
        return problem
    model = problem.model.with_bounds({name: (lo, hi) for name, lo, hi in zip(box.names, box.lower, box.upper)})
    return Problem(model, problem.data, noise=problem.noise, prior_penalty=problem.prior_penalty)
