"""Stage 1: the residual-sampling sweep over xi2 (paper Sec. II.C, Eq. 17-19).

For every candidate xi2 the linear parameters follow from an unweighted linear least
squares problem ``min || Z - A(xi2) xi1 - B(xi2) ||`` (R = I, as in the paper's
Step 3), and the residuals give ``R(xi2)`` (per-channel mean square) and ``Tr[R]``.
The landscape of ``Tr[R]`` tells whether there is one clear minimum.
"""

from __future__ import annotations

import functools
import time
from dataclasses import replace

import numpy as np

from ...data.dataset import Dataset
from ...errors import IdentifiabilityError
from ...models import Model, ModelError, OptionError
from ...problem.measurement import (DynamicMeasurement, Measurement, StaticMeasurement, as_measurement,
                                   check_predictions, measurement_of)
from ...problem.problem import Problem
from ...problem.separate import Partition
from .analysis import (
    descend_to_minimum,
    find_competing_minima,
    find_local_minima,
    profile_cost,
    ranking_values,
    unidentifiable_linear,
    validity_conditions,
)
from .candidates import (design_neighbours, draw_candidates, half_step, local_design, prior_density, sampling_distance,
                         to_unit)
from .candidate_set import candidate_set, in_ball
from .distributed import evaluate_on_cluster
from .error_bound import ErrorBound, paper_error_bound
from .dynamic_evaluators import DynamicBulkEvaluator, DynamicGramEvaluator
from .evaluators import BulkEvaluator, GramEvaluator, evaluate_all_candidates, evaluate_candidates
from .landscape import Deferred, Landscape
from .resolution import unresolved_minima
from .settings import SweepSettings


__all__ = ["sweep", "candidate_evaluator", "linear_parameter_bounds"]


# ----------------------------------------------------------------------------- sweep
def sweep(
    model: Model | Problem,
    data: Dataset | None = None,
    partition: Partition | None = None,
    settings: SweepSettings | None = None,
    candidates: np.ndarray | None = None,
    progress: bool = False,
) -> Landscape:
    """Run stage 1: sample xi2, solve xi1 by linear least squares, judge the landscape.

    Parameters
    ----------
    model : Model, DynamicModel or Problem
        A Problem sweeps its stage-1 data (experiments stacked, fixed parameters out); with
        known noise the residuals are weighted by the known std (Tr[R] in those units).
    data : Dataset
        The sweep's samples (may differ from stage 2's, paper Table 5); not with a Problem.
    partition : Partition, optional
        Default: :func:`casest.separate` of the (problem's) model.
    settings : SweepSettings, optional
    candidates : ndarray, shape (M, n2), optional
        Explicit xi2 candidates (physical units); overrides the design.
    progress : bool
        A progress bar (tqdm, if installed) on large sweeps (more than 5e7 candidate-samples).

    Returns
    -------
    Landscape

    Raises
    ------
    IdentifiabilityError
        ``A(xi2)`` is rank-deficient at every candidate (the message names the parameters).

    Examples
    --------
    >>> import casest
    >>> m = casest.load_model_file("scalar2")
    >>> landscape = casest.sweep(m.model(), m.simulate(seed=0))
    >>> landscape.nonlinear, landscape.verdict
    (('b', 'c'), 'unique')
    >>> landscape.error_bound.side(landscape.error_bound.stage1_cost)
    'inside'
    """
    t0 = time.perf_counter()
    settings = settings or SweepSettings()
    landscape = _sweep_once(model, data, partition, settings, candidates, progress)
    # an unresolved landscape is swept again, denser, while the work stays within the settings' budget
    while candidates is None and len(landscape.unresolved) and settings.resolve_work > 0:
        # half the spacing along every swept axis: 2^n2 times the candidates
        denser = replace(settings, n_candidates=2 ** len(landscape.nonlinear) * settings.n_candidates)
        if (denser.n_candidates > RESOLVE_MAX_CANDIDATES
                or denser.n_candidates * landscape.n_samples * len(landscape.output_names) > settings.resolve_work):
            break
        swept = landscape.n_design
        landscape, settings = _sweep_once(model, data, partition, denser, None, progress), denser
        landscape.reason += (f" (swept again with {landscape.n_design} candidates: the {swept} before did not resolve "
                             "the landscape away from the best)")
    landscape.seconds = time.perf_counter() - t0
    return landscape


#: the most candidates a sweep repeated for resolution draws (beyond, judging the landscape costs more than
#: the candidates: 512,000 in seven dimensions take 100 s, most of it on neighbourhoods)
RESOLVE_MAX_CANDIDATES = 2 ** 17


def _sweep_once(model, data, partition, settings: SweepSettings, candidates, progress) -> Landscape:
    """One sweep of the design (or the explicit candidates), judged (:func:`sweep`'s arguments)."""
    t0 = time.perf_counter()
    # Eq. 7 brackets one cost: stage 1 on other data, or another noise model, is not stage 2's J*
    comparable = not isinstance(model, Problem) or (model.stage1_data is None and model.noise.profiled_per_channel)
    model, data, partition, measurement = sweep_inputs(model, data, partition)
    cands, design, grid_shape = _candidates(model, partition, settings, candidates)
    # the nominal xi2 (the user's best guess) is evaluated beside the design, not in it
    nominal = model.nominal[list(partition.nonlinear_index)][None, :] if partition.n_nonlinear else np.zeros((0, 0))
    evaluator = candidate_evaluator(measurement, partition, data, settings, len(cands) + len(nominal))
    bounds = linear_parameter_bounds(model, partition)
    xi1, R, ok = _evaluate_design(evaluator, model, partition, data, settings,
                                  np.vstack([cands, nominal]) if len(nominal) else cands, bounds, progress)
    nominal_xi1, nominal_R = (xi1[-1].copy(), R[-1].copy()) if len(nominal) else (None, None)
    xi1, R, ok = xi1[:len(cands)], R[:len(cands)], ok[:len(cands)]
    if not ok.any():
        _refuse_unidentifiable(model, partition, data, evaluator, cands)
    samples = _Samples(cands, xi1, R, ok, _Ranking(settings.criterion, data.observed_counts()))
    judgement = _judge_landscape(measurement, partition, data, evaluator, samples, grid_shape, settings, bounds,
                                 nominal[0] if len(nominal) else None)
    best, minima = judgement.best, judgement.minima
    bound = _error_bound(partition, data, evaluator, samples, judgement, settings, bounds, comparable)
    return Landscape(
        nonlinear=partition.nonlinear, linear=partition.linear, output_names=model.output_names,
        candidates=samples.cands, xi1=samples.xi1, R=samples.R, trace_R=samples.trace, best_index=best,
        local_minima=np.asarray(minima, dtype=int), competing=judgement.competing, verdict=judgement.verdict,
        reason=judgement.reason, recommended_mode="reduced" if partition.n_linear and partition.n_nonlinear else "full",
        design=design, grid_shape=grid_shape, n_samples=data.n_samples, seconds=time.perf_counter() - t0,
        linearization_ratio=judgement.checks.ratio if judgement.checks else None,
        curvature_min_eig=judgement.checks.eig if judgement.checks else None,
        flat_spread=judgement.checks.spread if judgement.checks else None,
        nominal_xi1=nominal_xi1, nominal_R=nominal_R, n_design=len(cands), criterion=settings.criterion,
        ranking=samples.rank, error_bound=bound, nominal_in_best_basin=judgement.nominal_in_best_basin,
        in_set=samples.in_set, unresolved=judgement.unresolved,
    )


def _refuse_unidentifiable(model, partition: Partition, data: Dataset, evaluator, cands: np.ndarray) -> None:
    """Raise when A(xi2) is rank-deficient at every candidate (after checking the model is finite)."""
    check_predictions(model, data, model.nominal, "nominal values")
    raise IdentifiabilityError(
        f"A(xi2) is rank-deficient at every one of {len(cands)} candidates: the data cannot separate the linear "
        f"parameters {unidentifiable_linear(evaluator, cands[0], partition.linear)}. Fix one of them (remove it "
        "from the model or give it equal bounds) or collect data that excite them differently")


def _judge_landscape(measurement: Measurement, partition: Partition, data: Dataset, evaluator, samples: "_Samples",
                     grid_shape, settings: SweepSettings, bounds, nominal_xi2: np.ndarray | None = None) -> "_Judgement":
    """The minima, the competing ones, the refinement around the best candidate, the verdict, and
    whether the nominal xi2 lies in the best candidate's basin."""
    model = measurement.model
    cands = samples.cands
    nonlin_params = [model.parameters[i] for i in partition.nonlinear_index]
    unit = to_unit(cands, nonlin_params)  # neighbourhoods of scattered designs, in prior-probability coordinates
    neighbours = (design_neighbours(unit, settings.resolved_threads(len(cands)))
                  if grid_shape is None and partition.n_nonlinear else None)
    spacing = sampling_distance(unit, neighbours) if neighbours is not None else None
    if partition.n_nonlinear:
        centre = model.nominal[list(partition.nonlinear_index)]
        samples.restrict(candidate_set(measurement, partition, data, samples, settings, unit, grid_shape,
                                       nonlin_params, spacing, centre), lambda cands: in_ball(cands, centre,
                                                                                               settings.radius))
    minima = _minima_best_first(unit, samples.rank, grid_shape, partition.n_nonlinear, neighbours)
    best = int(minima[0])
    if partition.n_nonlinear == 0:
        judgement = _Judgement("linear", "no parameter is swept: stage 1 is one linear least squares",
                               np.array([], dtype=int))
        judgement.best, judgement.minima = best, minima
        return judgement
    in_best_basin = _in_best_basin(unit, samples.rank, grid_shape, neighbours, best, nominal_xi2, nonlin_params)
    competing = find_competing_minima(evaluator, data.outputs, cands, samples.R, minima, data.observed_counts(),
                                      settings.confidence, bounds, unit, spacing)
    step = half_step(cands, unit, grid_shape, nonlin_params, best, spacing)
    checks, best = _refine_around_best(measurement, partition, data, evaluator, samples, best, step, settings, bounds)
    minima = np.concatenate([[best], minima[1:]]).astype(int)
    unresolved = (unresolved_minima(measurement, partition, data, samples, minima, unit, grid_shape, nonlin_params,
                                    spacing, settings) if grid_shape is not None else [])
    judgement = _judge(model, partition, samples, best, competing, minima, checks, settings, unresolved)
    judgement.best, judgement.minima, judgement.step = best, minima, step
    judgement.nominal_in_best_basin = in_best_basin
    judgement.unresolved = np.array([u.index for u in unresolved], dtype=int)
    return judgement


def _in_best_basin(unit, rank, grid_shape, neighbours, best: int, nominal_xi2, params) -> bool | None:
    """Whether steepest descent over the design from the candidate nearest the nominal xi2 (in prior-probability
    coordinates) ends at the best candidate; None without a nominal xi2 or where that candidate is not a fit."""
    if nominal_xi2 is None:
        return None
    nearest = int(np.argmin(np.sum((unit - to_unit(nominal_xi2[None, :], params)) ** 2, axis=1)))
    if not np.isfinite(rank[nearest]):
        return None
    return descend_to_minimum(rank, nearest, grid_shape, neighbours) == best


def _error_bound(partition: Partition, data: Dataset, evaluator, samples: "_Samples", judgement: "_Judgement",
                 settings: SweepSettings, bounds, comparable: bool):
    """The paper's error bound at the best candidate, computed when first read (:class:`Deferred`),
    when the settings ask for it (else None)."""
    if not partition.n_nonlinear or not settings.wants_error_bound(len(samples.cands), data.n_samples,
                                                                   data.outputs.shape[1], partition.n_linear):
        return None
    cands, xi1, R, best, step = samples.cands, samples.xi1, samples.R, judgement.best, judgement.step

    def compute() -> ErrorBound:
        bulk = evaluator.bulk if isinstance(evaluator, GramEvaluator) else evaluator
        bound = paper_error_bound(bulk, data, cands, xi1, R, best, step, bounds)
        return bound if comparable else replace(bound, comparable=False)

    return Deferred(compute)


def _evaluate_design(evaluator, model, partition, data, settings, cands, bounds, progress) -> tuple:
    """xi1, R and the full-rank mask of the design's candidates: here, or on ``settings.scheduler``."""
    if settings.scheduler:
        return evaluate_on_cluster(candidate_evaluator, model, partition, data, settings, cands, bounds)
    return evaluate_all_candidates(evaluator, data.outputs, cands, bounds, progress)


def _minima_best_first(unit: np.ndarray, rank: np.ndarray, grid_shape, n_nonlinear: int,
                       neighbours: np.ndarray | None) -> np.ndarray:
    """The local minima of the ranking, the best candidate first."""
    minima = find_local_minima(unit, rank, grid_shape, neighbours) if n_nonlinear else np.array([0])
    best = int(minima[0]) if len(minima) else int(np.argmin(rank))
    if len(minima) == 0 or minima[0] != best:
        minima = np.concatenate([[best], minima[minima != best]]).astype(int)
    return minima


def sweep_inputs(model, data, partition) -> tuple:
    """The model, data and partition the sweep runs on: a Problem's stage-1 inputs (weighted by a
    known noise, with the problem's split), or the model and data given.

    Parameters
    ----------
    model : Model, DynamicModel or Problem
    data : Dataset or None
        Not with a Problem.
    partition : Partition or None
        Default :func:`casest.separate` of the model.

    Returns
    -------
    model, data, partition, measurement
        ``measurement`` is the model's :class:`~casest.problem.measurement.Measurement` (a
        Problem's own where the sweep runs on the problem's model).
    """
    from ...problem.separate import separate

    if isinstance(model, Problem):
        if data is not None:
            raise OptionError("sweep(problem) takes its data from the problem (Problem(..., stage1_data=...))")
        problem = model
        model, data, weighted = problem.stage1_inputs()
        partition = partition or separate(problem.measurement)
        if not weighted:  # the problem's own model, whose data the Problem checked
            return model, data, partition, problem.measurement
        # the weighted outputs keep the split of the problem's model
        measurement = measurement_of(model)
        return model, data, separate(measurement, linear=partition.linear, nonlinear=partition.nonlinear), measurement
    elif data is None:
        raise OptionError("sweep needs the data (or a casest.Problem)")
    measurement = measurement_of(model)
    measurement.check_data(data)
    return model, data, partition or separate(measurement), measurement


def _candidates(model, partition: Partition, settings: SweepSettings, candidates) -> tuple:
    """``(candidates, design name, grid shape)``: the explicit candidates (inside the bounds) or the design's."""
    if candidates is None:
        return draw_candidates(model, partition, settings)
    params = [model.parameters[i] for i in partition.nonlinear_index]
    cands = np.asarray(candidates, dtype=float)
    if cands.ndim != 2 or cands.shape[1] != partition.n_nonlinear or not np.all(np.isfinite(cands)):
        raise OptionError(f"explicit candidates must be a finite (M, {partition.n_nonlinear}) array of "
                          f"{list(partition.nonlinear)}, got shape {cands.shape}")
    lb, ub = np.array([p.lb for p in params]), np.array([p.ub for p in params])
    outside = np.any((cands < lb) | (cands > ub), axis=0)
    if np.any(outside):
        raise ModelError(f"explicit candidates for {[p.name for p in np.array(params)[outside]]} "
                         "lie outside the parameter bounds")
    return cands, "explicit", None


def candidate_evaluator(model, partition: Partition, data: Dataset, settings: SweepSettings, n_eval: int):
    """The evaluator of A and b over the data for ``n_eval`` candidates: the one registered for the
    model's measurement kind.

    Parameters
    ----------
    model : Model, DynamicModel or Measurement
    partition : Partition
    data : Dataset
    settings : SweepSettings
    n_eval : int
        The number of candidates it evaluates at once.

    Returns
    -------
    GramEvaluator, BulkEvaluator, DynamicGramEvaluator or DynamicBulkEvaluator
    """
    return _evaluator_of(as_measurement(model), partition, data, settings, n_eval)


@functools.singledispatch
def _evaluator_of(measurement: Measurement, partition: Partition, data: Dataset, settings: SweepSettings, n_eval: int):
    raise TypeError(f"no stage-1 evaluator is registered for the measurement kind {type(measurement).__name__}")


@_evaluator_of.register
def _(measurement: DynamicMeasurement, partition: Partition, data: Dataset, settings: SweepSettings, n_eval: int):
    model = measurement.model  # the states are simulated per candidate
    jit, threads = settings.resolved_jit(data.n_samples, n_eval), settings.resolved_threads(n_eval)
    if model.output_delays:  # delayed outputs mix samples: A and b of the whole record, one candidate at a time
        return DynamicBulkEvaluator(model, partition, data, jit, n_eval, settings.memory_mb)
    return DynamicGramEvaluator(model, partition, data, n_eval, jit, threads, condition_limit=settings.condition_limit)


@_evaluator_of.register
def _(measurement: StaticMeasurement, partition: Partition, data: Dataset, settings: SweepSettings, n_eval: int):
    jit, threads = settings.resolved_jit(data.n_samples, n_eval), settings.resolved_threads(n_eval)
    if settings.method == "gram":  # jit=None below its threshold: the compiled sums if already cached
        return GramEvaluator(partition, data, n_eval, jit, threads, condition_limit=settings.condition_limit,
                             cached=settings.jit is None)
    return BulkEvaluator(partition, data, settings.memory_mb, n_eval, jit)


def linear_parameter_bounds(model, partition: Partition) -> tuple:
    """The boxes of xi1, or (None, None) when it has none. Candidates are ranked by the best
    *feasible* xi1: an alias that needs xi1 outside its box (a scale factor 1 + s = -1, say)
    must not win stage 1."""
    lin = list(partition.linear_index)
    lb1, ub1 = model.lower_bounds[lin], model.upper_bounds[lin]
    return (lb1, ub1) if np.any(np.isfinite(lb1) | np.isfinite(ub1)) else (None, None)


class _Ranking:
    """How candidates are ranked: Tr[R] (the paper's) or the profile ML cost (unit-invariant)."""

    def __init__(self, criterion: str, counts: np.ndarray):
        self.criterion, self.counts = criterion, counts
        self.name = "Tr[R]" if criterion == "trace" else "the profile ML cost"

    def __call__(self, R: np.ndarray, ok: np.ndarray) -> np.ndarray:
        return ranking_values(self.criterion, R, ok, self.counts)


class _Samples:
    """The evaluated candidates, growing as the sweep is refined around its best one."""

    def __init__(self, cands, xi1, R, ok, ranking: _Ranking):
        self.cands, self.xi1, self.R, self.ranking = cands, xi1, R, ranking
        self.trace = np.where(ok, R.sum(axis=1), np.inf)
        self.rank = ranking(R, ok)
        self.in_set, self._ball = None, None

    def restrict(self, in_set: np.ndarray | None, ball) -> None:
        """Only the candidates of ``in_set`` compete (the others ranked ``inf``); ``ball(cands)`` says which
        candidates added later are in the set."""
        if in_set is None:
            return
        self.in_set, self._ball = in_set, ball
        self.rank = np.where(in_set, self.rank, np.inf)

    def add(self, cands, xi1, R, ok) -> None:
        self.cands, self.xi1, self.R = np.vstack([self.cands, cands]), np.vstack([self.xi1, xi1]), np.vstack([self.R, R])
        self.trace = np.concatenate([self.trace, np.where(ok, R.sum(axis=1), np.inf)])
        rank = self.ranking(R, ok)
        if self.in_set is not None:
            inside = self._ball(cands)
            self.in_set, rank = np.concatenate([self.in_set, inside]), np.where(inside, rank, np.inf)
        self.rank = np.concatenate([self.rank, rank])


class _Checks:
    """The paper's validity conditions at the best candidate (Eq. 17: ``ratio``; Eq. 18: ``eig``),
    the weakly determined xi2 combination and its spread in prior mass."""

    def __init__(self, ratio, eig, weak, spread, refinements: int):
        self.ratio, self.eig, self.weak, self.spread, self.refinements = ratio, eig, weak, spread, refinements


def _refine_around_best(measurement: Measurement, partition, data, evaluator, samples: _Samples, best: int, step,
                        settings, bounds):
    """Eq. 17 fails: refine the sweep around the best candidate (half the step each time)."""
    model = measurement.model
    params = [model.parameters[i] for i in partition.nonlinear_index]
    lb2, ub2 = np.array([p.lb for p in params]), np.array([p.ub for p in params])

    def conditions(k):
        density = prior_density(params, samples.cands[k])
        return validity_conditions(measurement, partition, data, samples.xi1[k], samples.cands[k], step, samples.R[k],
                                   density)

    ratio, eig, weak, spread = conditions(best)
    refinements = 0
    while ratio > settings.linearization_tol and refinements < settings.max_refinements and np.any(step > 0):
        local = local_design(samples.cands[best], step, lb2, ub2)
        step = 0.5 * step
        refinements += 1
        moved = False
        if len(local):
            xi1_l, R_l, ok_l = evaluate_candidates(evaluator, data.outputs, local, *bounds)
            samples.add(local, xi1_l, R_l, ok_l)
            if np.min(samples.rank[-len(local):]) < samples.rank[best]:
                best = len(samples.rank) - len(local) + int(np.argmin(samples.rank[-len(local):]))
                moved = True
        if moved:
            ratio, eig, weak, spread = conditions(best)
        else:  # the same candidate: Eq. 17's ratio is linear in the step (halving is exact), the rest unchanged
            ratio = 0.5 * ratio
    return _Checks(ratio, eig, weak, spread, refinements), best


class _Judgement:
    """The verdict (see :data:`casest.two_stage.sweep.VERDICTS`), its reason, the competing minima and the checks;
    :func:`_judge_landscape` adds the best candidate, the minima (best first) and the half step of Eq. 17."""

    def __init__(self, verdict: str, reason: str, competing: np.ndarray, checks: _Checks | None = None):
        self.verdict, self.reason, self.competing, self.checks = verdict, reason, competing, checks
        self.best, self.minima, self.step = 0, np.array([0]), None
        self.nominal_in_best_basin = None
        self.unresolved = np.array([], dtype=int)


def _judge(model, partition, samples: _Samples, best: int, competing, minima, checks: _Checks, settings,
           unresolved=()) -> _Judgement:
    """The verdict: competing minima first, then the curvature check (Eq. 18), then the linearisation (Eq. 17)
    at the best candidate, then at the further minima (``unresolved``: :func:`.resolution.unresolved_minima`)."""
    name = samples.ranking.name
    refined = (f" after {checks.refinements} local refinement(s) of the sweep around the best candidate"
               if checks.refinements else "")
    if len(competing):
        where = "; ".join(", ".join(f"{n} = {v:.4g}" for n, v in zip(partition.nonlinear, samples.cands[m]))
                          for m in competing[:3])
        profile = profile_cost(samples.R[np.concatenate([[best], competing])], samples.ranking.counts)
        better = settings.criterion == "trace" and len(model.output_names) > 1 and profile[1:].min() < profile[0]
        hint = ("; by the likelihood one of them fits better than the best Tr[R], which is dominated by the "
                "channels with the largest numbers: rank by SweepSettings(criterion='likelihood') when the "
                "channels are in different units" if better else "")
        return _Judgement("multiple", f"{len(competing)} other local minimum/minima of {name} lie in separate basins "
                          f"and fit as well as the best at the {settings.confidence:.0%} level ({where}){hint}",
                          competing, checks)
    if checks.eig < settings.curvature_tol or checks.spread > settings.flat_spread:
        why = (f"the profile curvature in xi2 is nearly singular (smallest normalised eigenvalue {checks.eig:.3g} < "
               f"{settings.curvature_tol:g})" if checks.eig < settings.curvature_tol else
               f"the data determine xi2 only to a one-sigma interval spanning {checks.spread:.3g} of its swept prior "
               f"mass (> {settings.flat_spread:g})")
        return _Judgement("flat", f"the curvature check (paper Eq. 18) fails at the best candidate: {why}; weakly "
                          f"determined: {checks.weak}", competing, checks)
    if checks.ratio > settings.linearization_tol:
        return _Judgement("coarse", f"the linearisation check (paper Eq. 17) fails{refined}: half a sweep step changes "
                          f"the prediction by {checks.ratio:.3g} (> {settings.linearization_tol:g}) of its norm; use "
                          "more candidates", competing, checks)
    if len(unresolved):
        where = "; ".join(", ".join(f"{n} = {v:.4g}" for n, v in zip(partition.nonlinear, samples.cands[u.index]))
                          + f" (ratio {u.ratio:.3g})" for u in unresolved[:3])
        return _Judgement("unresolved", f"the sweep does not resolve the landscape away from the best candidate: at "
                          f"{len(unresolved)} further local minimum/minima of {name} half a sweep step changes the "
                          f"prediction by more than {settings.linearization_tol:g} of its norm (paper Eq. 17; {where}), "
                          "so a deeper minimum may lie between the candidates there; stage 2 starts from them too. "
                          "More candidates (SweepSettings.n_candidates) or a narrower box resolve it",
                          competing, checks)
    extra = f" ({len(minima) - 1} shallower local minima do not compete)" if len(minima) > 1 else ""
    return _Judgement("unique", f"one clear minimum of {name}{extra}; casest's linearisation and curvature checks "
                      f"(its forms of the paper's Eq. 17 and 18) hold{refined}", competing, checks)
