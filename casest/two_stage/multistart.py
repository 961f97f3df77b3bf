"""Stage 2 from several starts, as data: one :class:`StartRecord` per start, and the decisions
that pick the estimate among them.

The policy (monotone: never return a cost above a start's without saying so):

1. every start is solved in the primary mode with a short iteration budget when there are
   several starts (once a start has converged, the later ones get at most ``EXPLORE_FACTOR``
   times its iterations, at least ``EXPLORE_MIN_ITER``: a start still running then is
   continued below only if it is below every converged solution); a solve that fails, or
   ends above its start's cost, is re-solved in the other mode (**switch**) unless it only
   ran out of the short budget;
2. unfinished starts below every converged solution get the full budget (**continue**);
3. among the solves that converged at or below their start, the lowest cost wins; equal
   costs (1e-9 relative) are **ties**: one representative per distinct minimum, and the one
   nearest the nominal values is kept, the others named as symmetries (**pick**);
4. a reduced-mode winner is **polished** in full mode (the reduced NLP's xi1 comes from
   normal equations, which lose digits when A is ill-conditioned: NIST Kirby2, Lanczos3);
5. when no solve converged at or below the lowest start cost, the best point seen is
   returned, flagged (**nothing beats the start**).

The decisions are pure functions of the runs (:func:`needs_other_mode`,
:func:`next_to_continue`, :func:`pick`, :func:`best_point_seen`); :func:`run_starts` drives
them through a :class:`StartSolver`, so they are tested without IPOPT.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from ..backend.tolerances import cost_tolerance
from ..errors import IdentifiabilityError
from ..status import Note, NoteCode, Outcome
from ..estimation.history import merged_history
from .solve.result import Stage2Result
from .symmetry import related


__all__ = ["StartRecord", "StartSolver", "MultiStartResult", "run_starts", "needs_other_mode", "next_to_continue",
           "pick", "best_point_seen", "cost_tolerance", "is_valid", "distinct_minima", "differing_parameters",
           "exploring_budget"]

#: IPOPT's status when the iteration budget ran out
OUT_OF_ITERATIONS = "Maximum_Iterations_Exceeded"

#: once a start has converged, later exploratory starts get this multiple of its iterations,
#: and at least EXPLORE_MIN_ITER (never more than ``SolverSettings.start_max_iter``)
EXPLORE_FACTOR, EXPLORE_MIN_ITER = 5, 30


def is_valid(result, start_cost: float) -> bool:
    """Converged, and not above the cost of its own start."""
    return bool(result.success) and result.cost <= start_cost + cost_tolerance(start_cost)


@dataclass(frozen=True)
class StartRecord:
    """One stage-2 start, as kept on :attr:`casest.Estimate.starts`.

    Attributes
    ----------
    label : str
        Where the start came from ("the best stage-1 candidate", "the nominal values", ...).
    theta0 : tuple of float, length n_parameters
        The start, physical units (of the estimated parameters).
    start_cost : float
        J of paper Eq. 6 at the start (R at its ML value there).
    mode : str
        The stage-2 mode of the solve kept for this start ("none": it could not start).
    outcome : Outcome or None
        How that solve ended; None when the start left the linear parameters unidentifiable.
    cost : float
        J at the solve's end (NaN when it could not start).
    n_iterations : int
        IPOPT iterations spent from this start (all its solves).
    switched : bool
        Re-solved in the other mode (the first solve failed or climbed).
    continued : bool
        Given the full iteration budget after the short exploratory one.
    kept : bool
        The estimate is this start's solution.
    """

    label: str
    theta0: tuple
    start_cost: float
    mode: str
    outcome: Outcome | None
    cost: float
    n_iterations: int
    switched: bool = False
    continued: bool = False
    kept: bool = False

    @property
    def started(self) -> bool:
        return self.outcome is not None

    def to_dict(self) -> dict:
        """Plain-Python form for JSON (non-finite costs as strings).

        Returns
        -------
        dict
        """
        def num(x):
            return float(x) if np.isfinite(x) else str(float(x))
        return {"label": self.label, "theta0": [float(v) for v in self.theta0], "start_cost": num(self.start_cost),
                "mode": self.mode, "outcome": None if self.outcome is None else self.outcome.value,
                "cost": num(self.cost), "n_iterations": int(self.n_iterations), "switched": self.switched,
                "continued": self.continued, "kept": self.kept}

    @classmethod
    def from_dict(cls, data: dict) -> "StartRecord":
        """The StartRecord of :meth:`to_dict`'s form.

        Parameters
        ----------
        data : dict

        Returns
        -------
        StartRecord
        """
        return cls(label=data["label"], theta0=tuple(float(v) for v in data["theta0"]),
                   start_cost=float(data["start_cost"]), mode=data["mode"],
                   outcome=None if data["outcome"] is None else Outcome(data["outcome"]), cost=float(data["cost"]),
                   n_iterations=int(data["n_iterations"]), switched=bool(data["switched"]),
                   continued=bool(data["continued"]), kept=bool(data["kept"]))


class StartSolver(Protocol):
    """What :func:`run_starts` needs of stage 2 (the pipeline's is a Problem and a partition)."""

    model: object

    def start_point(self, theta0) -> tuple[float, np.ndarray]:
        """J at ``theta0`` and the R stage 2 starts with."""

    def solve(self, theta0, mode: str, settings):
        """A stage-2 result from ``theta0`` in ``mode``, or None when the start leaves the
        linear parameters unidentifiable."""


@dataclass
class _Run:
    """A start while the policy works on it (its final form is a :class:`StartRecord`)."""

    label: str
    theta0: np.ndarray
    R0: np.ndarray
    start_cost: float
    result: object
    switched: bool = False
    continued: bool = False

    @property
    def valid(self) -> bool:
        return is_valid(self.result, self.start_cost)


@dataclass(frozen=True)
class MultiStartResult:
    """What :func:`run_starts` returns.

    Attributes
    ----------
    result : Stage2Result
        The estimate's stage-2 result (``success`` False when nothing beat the starts).
    lowest_start_cost : float
    records : tuple of StartRecord
        Every start, in the order given.
    """

    result: object
    lowest_start_cost: float
    records: tuple


# ----------------------------------------------------------------------------- decisions
def needs_other_mode(result, start_cost: float, out_of_short_budget: bool) -> bool:
    """Re-solve in the other mode: the start could not be solved, failed, or climbed; not when
    it only ran out of the short exploratory budget below its start (it may be continued)."""
    climbed = result is not None and result.cost > start_cost + cost_tolerance(start_cost)
    failed = result is None or not result.success or climbed
    return failed and not (out_of_short_budget and not climbed)


def better(first, second, start_cost: float):
    """The better of two solves from one start: valid first, then the lower cost."""
    if first is None:
        return second
    return min((first, second), key=lambda r: (not is_valid(r, start_cost), r.cost))


def exploring_budget(runs, explore):
    """The settings of the next exploratory start: ``explore``, or, once a start has converged at or
    below its start cost, at most ``EXPLORE_FACTOR`` times the iterations of the best such solve
    (at least ``EXPLORE_MIN_ITER``).

    Parameters
    ----------
    runs : list
        The starts solved so far.
    explore : SolverSettings
        The exploratory settings.

    Returns
    -------
    SolverSettings
    """
    converged = [r for r in runs if r.valid]
    if not converged:
        return explore
    best = min(converged, key=lambda r: r.result.cost)
    limit = max(EXPLORE_MIN_ITER, EXPLORE_FACTOR * int(best.result.n_iterations))
    return explore if limit >= explore.max_iter else replace(explore, max_iter=limit)


def next_to_continue(runs) -> int | None:
    """The run to give the full budget next: stopped by the short budget, not continued yet, and
    below every solve that converged within its budget by more than round-off (a run the Newton
    check accepted included: a tie with a converged solve gains nothing from more iterations);
    the lowest such cost first. None when there is none."""
    converged = min((r.result.cost for r in runs if r.valid and r.result.status != OUT_OF_ITERATIONS),
                    default=np.inf)
    limit = converged - cost_tolerance(converged) if np.isfinite(converged) else np.inf
    pending = [k for k, r in enumerate(runs)
               if r.result.status == OUT_OF_ITERATIONS and not r.continued and r.result.cost < limit]
    return min(pending, key=lambda k: runs[k].result.cost) if pending else None


def differing_parameters(model, theta, other) -> np.ndarray:
    """Parameters that differ by more than 1e-4 of their magnitude (or scale), shape (n,)."""
    return np.abs(theta - other) > 1e-4 * np.maximum(model.scales, np.abs(other))


def distinct_minima(model, runs) -> list:
    """One run per distinct minimum among ``runs`` (sorted by cost: each minimum's lowest)."""
    distinct = []
    for run in sorted(runs, key=lambda r: r.result.cost):
        if not any(not differing_parameters(model, run.result.theta, d.result.theta).any() for d in distinct):
            distinct.append(run)
    return distinct


def pick(model, runs) -> tuple | None:
    """The kept run and the distinct minima tied with it, or None when no valid solve reached
    the lowest start cost. Among distinct minima of equal cost (symmetries) the one nearest
    the nominal values fixes the labelling."""
    lowest_start = min(r.start_cost for r in runs)
    valid = [r for r in runs if r.valid]
    if not valid or min(r.result.cost for r in valid) > lowest_start + cost_tolerance(lowest_start):
        return None
    best_cost = min(r.result.cost for r in valid)
    ties = distinct_minima(model, [r for r in valid if r.result.cost <= best_cost + cost_tolerance(best_cost)])
    return _nearest_nominal(model, ties), ties


def _nearest_nominal(model, runs: list):
    """The run whose estimate is nearest the nominal values (in units of the parameters' scales)."""
    distance = [np.linalg.norm((r.result.theta - model.nominal) / model.scales) for r in runs]
    return runs[int(np.argmin(distance))]


def best_point_seen(runs) -> tuple:
    """``(cost, run, from_solve)``: the lowest cost among the solves' ends and the starts."""
    seen = [(r.result.cost, k, True) for k, r in enumerate(runs)] + [(r.start_cost, k, False) for k, r in enumerate(runs)]
    cost, k, from_solve = min(seen, key=lambda item: item[0])
    return cost, runs[k], from_solve


# ----------------------------------------------------------------------------- the driver
def run_starts(solver: StartSolver, starts, primary: str, other: str | None, settings, explore,
               enough=None) -> tuple:
    """Stage 2 from every start under the policy of this module.

    Parameters
    ----------
    solver : StartSolver
    starts : sequence of (str, ndarray)
        Labels and start points (physical units, inside the bounds).
    primary, other : str
        The mode of the first solve and the mode to switch to (None: no switching).
    settings, explore : SolverSettings
        The full settings and the exploratory ones (``explore is settings``: one budget).
    enough : callable, optional
        ``enough(runs) -> str or None``: after each start, a reason to skip the remaining
        starts (the evidence says one solve suffices), or None to go on. Default: every start.

    Returns
    -------
    MultiStartResult, list of Note
    """
    notes: list = []
    short_budget = explore is not settings
    runs = []
    for index, (label, theta0) in enumerate(starts):
        budget = exploring_budget(runs, explore) if short_budget else explore
        run = _first_solve(solver, label, theta0, (primary, other), budget, short_budget, notes)
        if run is not None:
            runs.append(run)
        reason = enough(runs) if enough is not None and runs else None
        if reason and index + 1 < len(starts):
            notes.append(Note(f"stage 2 ran from {index + 1} of {len(starts)} starts: {reason}", NoteCode.STARTS))
            break
    if not runs:
        raise IdentifiabilityError(
            "stage 2 could not start from any start: A(xi2) is rank-deficient at every one; give nominal values "
            "that make the linear parameters identifiable, or fix some of them")
    if short_budget:
        _continue_promising(solver, primary, settings, runs, notes)
    if len(runs) > 1:
        costs = ", ".join(f"{r.label}: {r.result.cost:.10g}"
                          f"{'' if r.valid else (' (failed)' if not r.result.success else ' (climbed)')}" for r in runs)
        notes.append(Note(f"stage 2 ran from {len(runs)} starts ({costs})", NoteCode.STARTS))
    iterations = sum(r.result.n_iterations for r in runs)
    lowest_start = min(r.start_cost for r in runs)
    choice = pick(solver.model, runs)
    if choice is None:
        result, kept = _nothing_beats_the_starts(runs, lowest_start, notes)
    else:
        kept, ties = choice
        if len(runs) > 1:
            notes.append(Note(f"kept the solution from {kept.label}", NoteCode.STARTS))
        _note_lower_unfinished(kept, runs, notes)
        maps_at = getattr(solver, "symmetries_at", None)
        _note_symmetries(solver.model, kept, ties, notes, maps_at(kept.result.theta) if maps_at and len(ties) > 1 else ())
        result, iterations = _polish(solver, kept.result, settings, iterations)
    records = tuple(_record(r, r is kept) for r in runs)
    return MultiStartResult(replace(result, n_iterations=iterations), lowest_start, records), notes


def _note_lower_unfinished(kept, runs, notes) -> None:
    """A start that did not converge but ended below the kept solution: the cost still falls
    where no solver finishes (typically two terms merging at a bound while their amplitudes grow
    without limit), so the kept minimum is not the lowest point of the box."""
    kept_cost = kept.result.cost
    lower = [r for r in runs if not r.result.success and np.isfinite(r.result.cost)
             and r.result.cost < kept_cost - cost_tolerance(kept_cost)]
    if lower:
        low = min(lower, key=lambda r: r.result.cost)
        notes.append(Note(f"{len(lower)} start(s) ended below the kept solution without converging (lowest: J = "
                          f"{low.result.cost:.10g} from {low.label}, against {kept_cost:.10g}): the cost still falls "
                          "where the solver cannot finish, often where two terms merge or a parameter runs to a bound "
                          "while others grow without limit; the kept solution is the lowest converged one. Bound or "
                          "fix the parameters involved, or reduce the model", NoteCode.LOWER_UNFINISHED))


def _first_solve(solver, label, theta0, modes, explore, short_budget: bool, notes) -> _Run | None:
    """The start's solve in the primary mode, and in the other mode when that one failed."""
    primary, other = modes
    start_cost, R0 = solver.start_point(theta0)
    R0 = np.diag(R0).copy() if R0.ndim == 2 else R0
    res = solver.solve(theta0, primary, explore)
    out_of_budget = short_budget and res is not None and res.status == OUT_OF_ITERATIONS
    switched = False
    if other is not None and needs_other_mode(res, start_cost, out_of_budget):
        climbed = res is not None and res.cost > start_cost + cost_tolerance(start_cost)
        why = (f"climbed from J = {start_cost:.10g} to {res.cost:.10g}" if climbed else
               "has A(xi2) rank-deficient at the start" if res is None else f"did not converge ({res.status})")
        alt = solver.solve(theta0, other, explore)
        if alt is not None:
            spent = res.n_iterations if res is not None else 0
            alt = replace(alt, n_iterations=alt.n_iterations + spent)
            res, switched = better(res, alt, start_cost), True
            notes.append(Note(f"stage 2 from {label} in {primary} mode {why}; re-solved in {other} mode: "
                              f"J = {alt.cost:.10g}{'' if alt.success else ' (did not converge)'}", NoteCode.MODE_SWITCH))
    if res is None:
        notes.append(Note(f"stage 2 could not start from {label}: the linear parameters are not identifiable there",
                          NoteCode.STARTS))
        return None
    return _Run(label, np.asarray(theta0, dtype=float), R0, start_cost, res, switched)


def _continue_promising(solver, mode, settings, runs, notes) -> None:
    """Give the full budget to unfinished starts that are below every converged solution."""
    while (k := next_to_continue(runs)) is not None:
        run = runs[k]
        res = run.result
        more = solver.solve(res.theta, mode if res.mode == "none" else res.mode, settings)
        run.continued = True
        if more is None:
            continue
        more = replace(more, n_iterations=more.n_iterations + res.n_iterations)
        notes.append(Note(f"stage 2 from {run.label} was continued after {res.n_iterations} iterations "
                          f"(J = {res.cost:.10g}, below every converged start): J = {more.cost:.10g}"
                          f"{'' if more.success else ' (did not converge)'}", NoteCode.CONTINUED))
        run.result = better(res, more, run.start_cost)


def _polish(solver, best, settings, iterations: int) -> tuple:
    """A reduced-mode winner re-solved in full mode from its solution, kept if it converged no higher."""
    if best.mode != "reduced":
        return best, iterations
    polished = solver.solve(best.theta, "full", settings)
    if polished is None or not polished.success or polished.cost > best.cost + cost_tolerance(best.cost):
        return best, iterations
    return replace(polished, notes=best.notes + polished.notes, mode="reduced, polished in full mode",
                   history=merged_history(best.history, polished.history)), \
        iterations + polished.n_iterations


def _nothing_beats_the_starts(runs, lowest_start: float, notes) -> tuple:
    """The best point seen, flagged: no solve converged at or below the lowest start cost."""
    cost, run, from_solve = best_point_seen(runs)
    if not from_solve:
        result = Stage2Result(theta=run.theta0.copy(), R=run.R0, cost=cost, success=False, status="No_Improvement",
                              message="", n_iterations=0, mode="none", outcome=Outcome.NO_IMPROVEMENT)
        where = f"{run.label} itself (J = {cost:.10g}); stage 2 did not improve on it"
    else:
        status = run.result.status if run.result.status != "Solve_Succeeded" else "Climbed"
        result = replace(run.result, success=False, status=status,
                         outcome=Outcome.CLIMBED if status == "Climbed" else Outcome.NOT_CONVERGED)
        where = f"the last iterate of the solve from {run.label} (J = {cost:.10g})"
    notes.append(Note(
        f"no stage-2 solve converged at or below the lowest start cost J = {lowest_start:.10g}; the estimate is "
        f"{where}. It is not a verified minimum: try more stage-1 candidates (SweepSettings.n_candidates), other "
        "bounds or scales, or mode='full'", NoteCode.NOT_VERIFIED))
    return replace(result, message="no stage-2 solve converged at or below the cost of its start"), run


def _note_symmetries(model, best, ties, notes, maps=()) -> None:
    """Name the parameters that differ between distinct minima of equal cost (aliases, permutations);
    minima that a known symmetry of the model (``maps``) maps onto each other are the same solution
    relabelled (the estimate's labels are settled afterwards) and not named."""
    for run in ties:
        if run is best:
            continue
        if related(model, run.result.theta, best.result.theta, maps):
            continue
        differ = differing_parameters(model, run.result.theta, best.result.theta)
        if differ.any():
            names = [n for n, d in zip(model.parameter_names, differ) if d]
            other = ", ".join(f"{n} = {v:.6g}" for n, v, d in zip(model.parameter_names, run.result.theta, differ) if d)
            notes.append(Note(
                f"another minimum has the same cost J = {run.result.cost:.10g} ({other}): the model has a symmetry or "
                f"alias in {names}; the data cannot tell the two apart, and the estimate is the one nearest "
                "the nominal values", NoteCode.SYMMETRY))


def _record(run: _Run, kept: bool) -> StartRecord:
    res = run.result
    return StartRecord(label=run.label, theta0=tuple(float(v) for v in run.theta0), start_cost=float(run.start_cost), mode=res.mode,
                       outcome=res.outcome, cost=float(res.cost), n_iterations=int(res.n_iterations),
                       switched=run.switched, continued=run.continued, kept=kept)
