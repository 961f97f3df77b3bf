"""Stage 2: the maximum-likelihood NLP solved by IPOPT with exact CasADi Hessians.

The cost is paper Eq. (6) with R diagonal and unknown::

    J(theta, R) = 1/2 sum_k sum_j (z_kj - h_j(x_k, theta))**2 / R_j + N/2 sum_j ln R_j

R is log-parametrised: the decision variables are ``rho_j = ln R_j``, bounded below by
a noise floor ``R_j >= noise_floor * mean_k(z_kj**2)`` so that exactly fitting data
(ln R -> -inf) stay well posed. Parameters are scaled to order one
(``theta = scale * s``). IPOPT minimises ``J / N``. Sums over samples are CasADi
map-reduce nodes with the data as NLP parameters, so the expression graph does not grow
with N and a solver built once is reused for every data set of the same length.

Modes
-----
``full``
    Decision variables: all of theta and rho.
``reduced``
    Decision variables: xi2 and rho; xi1 is the weighted least-squares solution inside
    the NLP (normal equations, differentiated exactly) and is recovered afterwards by QR.
``alternating``
    The paper's outer loop (Eq. 26): xi2 with R fixed, then R from the residuals, until
    every R_j changes by less than ``alternating_tol`` (5 %).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from ...options import Mode, check_option
from ..._casadi.evaluation import evaluate
from ..._casadi.sample_blocks import evaluate_samples
from ...backend.linalg import variances_of
from ...backend.ipopt import SolverSettings, active_bounds, noise_floor
from ...backend.tolerances import cost_tolerance
from ...data.dataset import Dataset
from ...models import Model, ModelError, OptionError
from ...problem.problem import Problem, as_problem
from ...status import Note, NoteCode, Outcome, note_code
from ...problem.separate import Partition
from ...estimation.gauss_newton import gauss_newton_output_error
from ...estimation.history import iterate_history
from .levenberg_marquardt import WeightedResiduals, levenberg_marquardt_least_squares
from .nlps import MultipleShootingNLP, full_nlp, run_nlp, sums_nlp
from .result import Stage2Result
from .solver_choice import dedicated_solver


__all__ = ["weighted_linear_parameters", "check_start", "solve_stage2", "full_mode_note"]



def weighted_linear_parameters(model: Model, partition: Partition, data: Dataset, xi2, R) -> np.ndarray:
    """xi1 = argmin sum_k ||z_k - A_k xi1 - b_k||^2_{R^-1} by QR (paper Eq. 27).

    Parameters
    ----------
    model : Model
    partition : Partition
    data : Dataset
    xi2 : array_like, shape (n2,)
        The nonlinear parameters.
    R : array_like, shape (n_outputs,)
        Noise variances weighting the outputs.

    Returns
    -------
    ndarray, shape (n1,)
        The linear parameters.
    """
    from ...backend.least_squares import batched_least_squares

    if partition.n_linear == 0:
        return np.zeros(0)
    N, ny = data.n_samples, model.n_outputs
    xi2 = np.asarray(xi2, dtype=float)
    (A,) = evaluate_samples(partition.A, [data.signals], [xi2])
    (b,) = evaluate_samples(partition.b, [data.signals], [xi2])
    A = A.reshape(N, -1, ny).transpose(0, 2, 1)  # each sample's A (ny x n1) is stored column-major
    w = data.output_mask() / np.sqrt(np.asarray(R, dtype=float).reshape(1, ny))  # rows not measured: weight 0
    Aw = (A * w[:, :, None]).reshape(1, N * ny, -1)
    yw = ((data.filled_outputs() - b) * w).reshape(1, N * ny)
    x, ok = batched_least_squares(Aw, yw)
    if not ok[0]:
        from ...errors import IdentifiabilityError

        raise IdentifiabilityError(
            f"A(xi2) is rank-deficient at xi2 = {np.asarray(xi2).tolist()}: the linear "
            f"parameters {list(partition.linear)} cannot be separated by these data"
        )
    return x[0]


# ----------------------------------------------------------------------------- solve
def check_start(model: Model, theta0: np.ndarray) -> None:
    lb, ub = model.lower_bounds, model.upper_bounds
    bad = [
        f"{n} = {t:g} not in [{lo:g}, {hi:g}]"
        for n, t, lo, hi in zip(model.parameter_names, theta0, lb, ub)
        if not (lo <= t <= hi)
    ]
    if bad:
        raise OptionError(
            "the start lies outside the parameter bounds: " + "; ".join(bad) + ". Move the "
            "start inside the bounds or widen them"
        )
    if not np.all(np.isfinite(theta0)):
        raise OptionError(f"the start has non-finite values: {theta0.tolist()}")


def solve_stage2(
    model: Model | Problem,
    data: Dataset | None = None,
    theta0=None,
    partition: Partition | None = None,
    mode: Mode = "full",
    settings: SolverSettings | None = None,
    R0=None,
) -> Stage2Result:
    """Minimise the ML cost of Eq. 6 over theta and the noise R with IPOPT.

    Parameters
    ----------
    model : Model or Problem
        A :class:`casest.Problem` carries the data, noise model, priors and fixed
        parameters (then leave ``data`` out); a Model is the problem of ``data`` with R
        unknown and diagonal.
    data : Dataset
    theta0 : array_like, shape (n_parameters,) or mapping
        Start (physical units); must lie inside the bounds. In ``reduced`` and
        ``alternating`` mode only its xi2 part is used.
    partition : Partition, optional
        Default :func:`casest.separate` of the (problem's) model.
    mode : {"full", "reduced", "alternating"}
    settings : SolverSettings, optional
    R0 : array_like, shape (n_outputs,), optional
        Start of R; default: the residual mean square at ``theta0``.

    Returns
    -------
    Stage2Result
        For the problem's model (parameters declared or given fixed are not in it).

    Examples
    --------
    Stage 2 alone, from the best stage-1 candidate:

    >>> import casest
    >>> m = casest.load_model_file("scalar2")
    >>> model, data = m.model(), m.simulate(seed=0)
    >>> part = casest.separate(model)
    >>> landscape = casest.sweep(model, data, part)
    >>> result = casest.solve_stage2(model, data, part.assemble(landscape.best_xi1, landscape.best_xi2), part)
    >>> result.success, result.theta.shape
    (True, (4,))

    """
    t0 = time.perf_counter()
    check_option("mode", mode, Mode)
    problem = as_problem(model, data) if isinstance(model, Problem) else Problem(model, data)
    if theta0 is None:
        raise OptionError("solve_stage2 needs a start theta0 (a mapping or a vector of the parameters)")
    return _solve(problem, problem.vector(theta0), partition, mode, settings or SolverSettings(), R0, t0)


def _solve(problem: Problem, theta0: np.ndarray, partition, mode: str, settings: SolverSettings, R0, t0
           ) -> Stage2Result:
    from ...problem.separate import separate

    model = problem.model
    partition = partition or separate(model)
    check_start(model, theta0)
    floor = noise_floor(problem.data, settings)
    notes: list = []
    mode = _effective_mode(problem, mode, notes)
    # the least-squares path evaluates its compiled residuals for the start's and the end's cost too
    residuals = WeightedResiduals(problem, settings) if mode == "full" and \
        dedicated_solver(problem, settings) == "levenberg-marquardt" else None
    start_cost, R0 = _start_point(problem, theta0, floor, R0, residuals)
    if not problem.dynamic and not np.isfinite(start_cost):
        notes.append(_non_finite_start(problem, theta0))
    bounds = problem.noise.stage2_bounds(floor, R0)  # a held R: equal bounds, which IPOPT fixes
    if mode == "full":
        solved = _solve_full(problem, partition, settings, theta0, R0, bounds, residuals)
    else:
        solved = _solve_projected(problem, partition, settings, mode, theta0, R0, bounds, floor)
        violated = _linear_outside_bounds(model, partition, solved.theta)
        if violated:
            outside = Note(f"{mode} stage 2 put linear parameter(s) {violated} outside their bounds; "
                           "re-solved in full mode from that point with them clipped to the bounds", NoteCode.BOUNDS)
            start = np.clip(solved.theta, model.lower_bounds, model.upper_bounds)
            inner = _solve(problem, start, partition, "full", settings, solved.R, t0)
            return replace(inner, notes=notes + solved.notes + [outside] + inner.notes,
                           n_iterations=inner.n_iterations + solved.iterations)
    return _finish(problem, solved, notes, start_cost, R0, floor, settings, t0)


@dataclass
class _Solved:
    """A mode's solve before the checks: the point, R, IPOPT's status and notes."""

    theta: np.ndarray
    R: np.ndarray
    status: str
    success: bool
    iterations: int
    mode: str
    notes: list
    history: object = None  # ConvergenceHistory of a Gauss-Newton solve
    cost: float | None = None  # J at (theta, R) when the solver evaluated it there
    shooting_cost: float | None = None  # multiple shooting: J with each interval simulated from its node
    label: str = ""  # multiple shooting: where this solve started


def full_mode_note(problem: Problem, asked: str) -> Note:
    """The note of a stage 2 asked for a mode other than full where only full applies.

    Parameters
    ----------
    problem : Problem
        Its :attr:`Problem.full_mode_reason` is not None.
    asked : str
        The mode asked for.

    Returns
    -------
    Note
    """
    return Note(f"{problem.full_mode_reason}: stage 2 in full mode (asked: {asked})", NoteCode.MODE_SWITCH)


def _effective_mode(problem: Problem, mode: str, notes: list) -> str:
    """The mode that can solve this problem (:attr:`Problem.full_mode_reason`: output error, a
    full R and MAP priors need full mode); with a known R there is nothing to alternate."""
    if problem.full_mode_reason is not None and mode != "full":
        notes.append(full_mode_note(problem, mode))
        return "full"
    return problem.noise.stage2_mode(mode)


def _start_point(problem: Problem, theta0, floor, R0, residuals) -> tuple:
    """:meth:`Problem.start_point`, from the compiled residuals where a least-squares solve has them."""
    if residuals is None:
        return problem.start_point(theta0, floor, R0)
    if R0 is None and problem.noise.estimated:
        R = np.maximum(residuals.mean_square(theta0), floor)
    else:  # a known R or a given one: no residuals needed
        R = problem.noise.start(problem, theta0, floor, R0)
    return residuals.cost(theta0, R), R


def _solve_full(problem: Problem, partition, settings, theta0, R0, bounds, residuals=None) -> _Solved:
    """All of theta and ln R in one NLP (static sums, output error or multiple shooting), or output
    error by Gauss-Newton, or least squares by Levenberg-Marquardt first (:func:`dedicated_solver`)."""
    model = problem.model
    solver = dedicated_solver(problem, settings)  # the one registered for the measurement's kind
    if solver == "gauss-newton":
        run = gauss_newton_output_error(problem, theta0, R0, np.exp(bounds[0]), settings)
        return _Solved(run.theta, run.R, run.status, run.success, run.iterations, "full", run.notes, run.history)
    if solver == "levenberg-marquardt":
        run = levenberg_marquardt_least_squares(problem, theta0, R0, np.exp(bounds[0]), settings, residuals)
        if run.success:
            return _Solved(run.theta, run.R, run.status, run.success, run.iterations, "full", run.notes, cost=run.cost)
        # IPOPT takes over from the start with the same budget, as if Levenberg-Marquardt had not
        # run: where it could not verify its point it has often wandered far (NIST MGH09 from start
        # 1), and a multi-start continues a short budget's point better from IPOPT's (NIST Bennett5:
        # from MINPACK's point after 150 evaluations IPOPT needed 1104 iterations, from the start 403 in all)
    nlp = full_nlp(problem, partition, settings)
    w0 = np.concatenate([theta0 / nlp.scale, problem.noise_vector(R0)])
    lbw = np.concatenate([model.lower_bounds / nlp.scale, bounds[0]])
    ubw = np.concatenate([model.upper_bounds / nlp.scale, bounds[1]])
    if isinstance(nlp, MultipleShootingNLP):
        return _solve_shooting(nlp, problem, settings, theta0, (w0, lbw, ubw))
    with problem.data_argument() as p:
        w, status, success, iters, notes = run_nlp(nlp, w0, lbw, ubw, p, settings)
        (theta,) = evaluate(nlp.theta_of, w, p)
        iterates = [evaluate(nlp.theta_of, x, p)[0] for x, _ in nlp.recorder.iterates] if nlp.recorder else []
    return _Solved(theta, problem.noise_of(w[nlp.n_s : nlp.n_s + problem.n_noise]), status, success, iters, "full",
                   notes, iterate_history(problem, iterates))


def _solve_shooting(nlp: MultipleShootingNLP, problem: Problem, settings, theta0, start: tuple) -> _Solved:
    """Multiple shooting from the start and, where the measured outputs give every node, also from
    the fit with the nodes held there (:meth:`MultipleShootingNLP.anchored_start`): the lower of the
    converged solutions is kept, and two different minima are named in a note. The shooting NLP's
    own cost is kept for :func:`_finish`'s comparison with the output-error cost of the parameters."""
    w0, lbw, ubw, anchored = nlp.extend(*start, problem, theta0)
    with problem.data_argument() as p:
        runs = [_shooting_run(nlp, problem, w0, lbw, ubw, p, settings, "the start")]
        if anchored:
            w1, stats = nlp.anchored_start(w0, lbw, ubw, p, settings.max_iter)
            runs.append(_shooting_run(nlp, problem, w1, lbw, ubw, p, settings, "the fit to the data at the nodes",
                                      int(stats.get("iter_count", 0))))
    kept = min(runs, key=lambda run: (not run.success, run.shooting_cost))
    others = [r for r in runs if r is not kept and r.success and kept.success
              and r.shooting_cost > kept.shooting_cost + cost_tolerance(kept.shooting_cost)]
    notes = list(kept.notes)
    if others:
        notes.append(Note(f"multiple shooting from {others[0].label} ended in another minimum (J = "
                          f"{others[0].shooting_cost:.10g}) than from {kept.label} (J = {kept.shooting_cost:.10g}); "
                          "the lower is kept: the output-error cost of this record has several minima", NoteCode.STARTS))
    return replace(kept, iterations=sum(r.iterations for r in runs), notes=notes)


def _shooting_run(nlp: MultipleShootingNLP, problem: Problem, w0, lbw, ubw, p, settings, label: str,
                  pre_iterations: int = 0) -> _Solved:
    """One multiple-shooting solve from ``w0``, with the NLP's own cost at its end."""
    w, status, success, iters, notes = run_nlp(nlp, w0, lbw, ubw, p, settings)
    (theta,) = evaluate(nlp.theta_of, w, p)
    shooting_cost = float(np.asarray(evaluate(nlp.shooting_cost, w, p)[0]).reshape(-1)[0])
    iterates = [evaluate(nlp.theta_of, x, p)[0] for x, _ in nlp.recorder.iterates] if nlp.recorder else []
    return _Solved(theta, problem.noise_of(w[nlp.n_s: nlp.n_s + problem.n_noise]), status, success,
                   iters + pre_iterations, "full", notes, iterate_history(problem, iterates),
                   shooting_cost=shooting_cost if np.isfinite(shooting_cost) else np.inf, label=label)


def _solve_projected(problem: Problem, partition, settings, mode: str, theta0, R0, bounds, floor) -> _Solved:
    """xi2 and ln R with xi1 by weighted least squares (reduced: the paper's variable projection;
    alternating: paper Eq. 26)."""
    model = problem.model
    nlp = sums_nlp(model, partition, problem.n_samples, "reduced", settings, None, problem.masked)
    idx2 = list(partition.nonlinear_index)
    s0 = theta0[idx2] / nlp.scale
    lbs, ubs = model.lower_bounds[idx2] / nlp.scale, model.upper_bounds[idx2] / nlp.scale
    with problem.data_argument() as p:
        if mode == "reduced":
            w, status, success, iters, notes = run_nlp(nlp, np.concatenate([s0, np.log(R0)]),
                                                       np.concatenate([lbs, bounds[0]]),
                                                       np.concatenate([ubs, bounds[1]]), p, settings)
            R = np.exp(w[nlp.n_s:])
        else:
            w, R, status, success, iters, notes = _alternate(nlp, s0, lbs, ubs, R0, floor, p, problem, settings)
    xi2 = w[: nlp.n_s] * nlp.scale
    xi1 = weighted_linear_parameters(model, partition, problem.data, xi2, R)
    iterates = []
    for x, _ in (nlp.recorder.iterates if nlp.recorder and mode == "reduced" else []):
        xi2_k, R_k = x[: nlp.n_s] * nlp.scale, np.exp(x[nlp.n_s:])
        iterates.append(partition.assemble(weighted_linear_parameters(model, partition, problem.data, xi2_k, R_k),
                                           xi2_k))
    return _Solved(partition.assemble(xi1, xi2), R, status, success, iters, mode, notes,
                   iterate_history(problem, iterates))


def _linear_outside_bounds(model, partition, theta) -> list:
    """The linear parameters that the projection put outside their bounds."""
    idx = list(partition.linear_index)
    return [n for n, v, lo, hi in zip(partition.linear, theta[idx], model.lower_bounds[idx], model.upper_bounds[idx])
            if not lo <= v <= hi]


def _finish(problem: Problem, solved: _Solved, notes: list, start_cost, R0, floor, settings, t0) -> Stage2Result:
    """The checks after a solve: an exact fit, a climb above the start, R at the noise floor."""
    model = problem.model
    notes = notes + solved.notes
    # IPOPT may end a hair outside a bound through rounding; the result must respect them
    theta = np.clip(solved.theta, model.lower_bounds, model.upper_bounds)
    success, status, R = solved.success, solved.status, problem.noise.solved_covariance(R0, solved.R)
    outcome = Outcome.ACCEPTED_NEWTON if success and any(note_code(n) is NoteCode.ACCEPTED for n in notes) else None
    if not success and problem.noise.profiled_per_channel:  # an exact fit's R is at the floor, channel by channel
        exact, R_exact, note = _exact_fit(problem, theta, floor, settings)
        if exact:
            success, R = True, R_exact
            notes.append(Note(f"IPOPT stopped with {status}; " + note, NoteCode.ACCEPTED))
            outcome = Outcome.EXACT_FIT
    same_point = solved.cost is not None and np.array_equal(theta, solved.theta) and \
        np.array_equal(variances_of(R), solved.R)
    cost = solved.cost if same_point else problem.cost(theta, R)
    success, status, outcome = _check_shooting(cost, solved.shooting_cost, success, status, outcome, notes)
    success, status, outcome = _check_climb(cost, start_cost, success, status, outcome, solved.mode, notes)
    if outcome is None:
        outcome = Outcome.CONVERGED if success else Outcome.NOT_CONVERGED
    message = ("converged" if success else "ended above the cost of its start" if status == "Climbed"
               else f"IPOPT did not converge ({status})")
    variances = variances_of(R)
    at_floor = [c for c, r, f in zip(model.output_names, variances, floor) if r <= f * (1 + 1e-6)] \
        if problem.noise.profiled_per_channel else []
    if at_floor:
        notes.append(Note(
            f"noise variance of {at_floor} is at the floor ({settings.noise_floor:g} x mean square): "
            "the model fits these data (almost) exactly, so R is not determined", NoteCode.NOISE_FLOOR))
    return Stage2Result(theta=theta, R=variances.copy(), cost=cost, success=success, status=status, message=message,
                        n_iterations=solved.iterations, mode=solved.mode, notes=notes,
                        seconds=time.perf_counter() - t0, outcome=outcome, history=solved.history,
                        R_full=R if R.ndim == 2 else None)


def _non_finite_start(problem: Problem, theta0: np.ndarray) -> Note:
    """The note of a start where the ML cost is NaN or infinite (the solve then fails, it does not raise:
    in a multi-start the other starts go on)."""
    from ...problem.measurement import check_predictions

    try:
        check_predictions(problem.model, problem.data, theta0, "start")
    except ModelError as err:
        return Note(str(err), NoteCode.NOT_FINITE)
    return Note("the ML cost is NaN or infinite at the start although the model is finite there (a residual "
                "too large to square?): start closer to the data", NoteCode.NOT_FINITE)


def _check_shooting(cost, shooting_cost, success, status, outcome, notes):
    """A multiple-shooting solution is an output-error estimate only where the model simulated from
    its initial state over the whole record fits as its intervals did: on an unstable model the
    nodes' continuity defects, within IPOPT's tolerance, grow along the record, and then the
    parameters are not an optimum of the output-error cost ``cost`` (which the result reports)."""
    if shooting_cost is None or not success or cost <= shooting_cost + cost_tolerance(shooting_cost):
        return success, status, outcome
    notes.append(Note(
        f"multiple shooting converged with its intervals at J = {shooting_cost:.10g}, but the model simulated from "
        f"the estimated initial state over the whole record gives the output-error cost J = {cost:.10g}: its "
        "trajectory leaves the nodes (the model diverges along the record), so these parameters are not an "
        "output-error optimum. Use casest.artificially_stabilised(...) or filter_error_estimate(...), or shorter "
        "records", NoteCode.SIMULATION))
    return False, "Shooting_Mismatch", Outcome.NOT_CONVERGED


def _check_climb(cost, start_cost, success, status, outcome, mode, notes):
    """A converged solve above its start is a stationary point it climbed to (a plateau or
    saddle), not an improvement: never reported as a success."""
    if success and cost > start_cost + cost_tolerance(start_cost):
        notes.append(Note(f"stage 2 ({mode}) ended at J = {cost:.10g}, above its start's J = {start_cost:.10g}: "
                          "it stopped on a plateau or saddle; the start is better", NoteCode.CLIMBED))
        return False, "Climbed", Outcome.CLIMBED
    return success, status, outcome


def _exact_fit(problem: Problem, theta: np.ndarray, floor: np.ndarray, settings: SolverSettings):
    """Recognise an exact fit (every R_j at the floor) at a least-squares point.

    With data that the model reproduces exactly the likelihood has no maximum
    (R -> 0); IPOPT then stalls on round-off amplified by the weights 1/R. The point
    is accepted when the residual mean square is below the floor in every channel and a
    Gauss-Newton step on the free parameters is shorter than ``newton_acceptance``
    (in units of the parameters' scales).
    """
    model = problem.model
    # 0 where not measured; where the model is not finite, no exact fit (inf)
    resid = np.nan_to_num(np.where(problem.data.output_mask() > 0, problem.residuals(theta), 0.0), nan=np.inf)
    ms = np.sum(resid**2, axis=0) / problem.data.observed_counts()
    if not np.all(ms <= floor):
        return False, None, ""
    active = active_bounds(theta, model.lower_bounds, model.upper_bounds, model.scales)
    free = [i for i, a in enumerate(active) if a is None]
    J = problem.jacobian(theta)[:, free] * model.scales[free]
    if not np.all(np.isfinite(J)):
        return False, None, ""
    step, *_ = np.linalg.lstsq(J, resid.reshape(-1), rcond=None)
    size = float(np.max(np.abs(step))) if step.size else 0.0
    if size >= settings.newton_acceptance:
        return False, None, ""
    return True, floor.copy(), (
        f"the data are fitted exactly (residual mean square below the noise floor); accepted "
        f"because a Gauss-Newton step there is {size:.1e} (scaled units)"
    )


def _alternate(nlp, s0, lbs, ubs, R0, floor, p, problem: Problem, settings):
    """Paper Eq. 26: xi2 with R fixed, then R from the residuals, until R settles."""
    R = R0.copy()
    s = s0.copy()
    iters = 0
    notes: list[str] = []
    status, success = "Maximum_Alternations_Exceeded", False
    for k in range(settings.max_alternations):
        rho = np.log(R)
        w0 = np.concatenate([s, rho])
        lbw = np.concatenate([lbs, rho])
        ubw = np.concatenate([ubs, rho])
        w, ipopt_status, ok, it, run_notes = run_nlp(nlp, w0, lbw, ubw, p, settings)
        iters += it
        if not ok:
            return w, R, ipopt_status, False, iters, notes + run_notes
        s = w[: nlp.n_s]
        (theta,) = evaluate(nlp.theta_of, w, p)
        R_new = np.maximum(problem.residual_mean_square(theta), floor)
        change = np.abs(R_new - R) / R_new
        R = R_new
        if np.all(change < settings.alternating_tol):
            status, success = "Solve_Succeeded", True
            notes.append(Note(f"alternating loop: R settled within {settings.alternating_tol:.0%} after {k + 1} passes"))
            break
    w = np.concatenate([s, np.log(R)])
    return w, R, status, success, iters, notes
