"""The innovation formulation's relaxation as flight-test practice runs it (Jategaonkar, *Flight
Vehicle System Identification*, Sec. 5.5; Maine and Iliff 1981).

The unknowns are theta and the process-noise distribution F; the innovation covariance R is not
a decision variable but the closed form of the innovations. Each round:

1. with R held, Gauss-Newton steps on ``V = 1/2 sum e' R^-1 e`` under the bounds and the
   constraint ``diag(K C) <= 1`` (:func:`casest.filter_error.practice_steps.practice_step`: the exact
   quadratic programme, then step halving; a trial point with a non-finite value is rejected).
   Early rounds take one step, as the textbook's program does, each F within a factor
   ``F_FACTOR`` of its value, so that a first R far from the final one cannot drive F away or
   onto its bound 0 (where F's gradient vanishes and no later round moves it); once a round
   moves the estimate by less than ``POLISH_FROM`` (relative), the steps continue with R held
   until the step's predicted decrease is at rounding level, which makes the fixed point exact;
2. R from the innovations at the new point: its diagonal ``diag(sum e e' / N)`` (practice, the
   default) or the full matrix (a different estimator where the channels' innovations are
   correlated);
3. F compensated for the change of R (Jategaonkar's Eq. 5.41).

The first R is that of the output-error residuals at the start (the innovations with F = 0),
as the practice algorithm takes it (where that simulation is not finite, an unstable model, the
outputs' spread), then updated at the start from the innovations of its own gain until it
settles: output-error residuals on a turbulent record are 10-100 times the innovations, and a
first step weighted by them drives the process noise of the channels they inflate to its bound
0, where its gradient vanishes and no later round moves it. The relaxation has settled when two
successive rounds move every estimate by at most ``settle_std`` (default ``SETTLE_STD``, 0.01) of
its standard deviation, the second with the true bounds, and that second round moves
``J = N/2 ln det R`` by at most ``settle_std`` (a likelihood change no test resolves): further
rounds move nothing a user can resolve. With ``settle_std = 0`` it continues to the fixed point's
rounding: ``J`` changing by less than ``SETTLE_COST`` (relative) and no value by more than
``SETTLE_STEP``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..backend.ipopt import SolverSettings
from ..data.dataset import Dataset
from ..estimation.gauss_newton import ROUNDING_DECREMENT
from ..models.dynamic import DynamicModel
from ..status import Note, NoteCode
from .result import FilterErrorEstimate
from .innovation import InnovationProblem, compensate_process_noise
from .nlp import FilterErrorSetup, FormulationOptions
from .innovation_result import innovation_result
from .practice_steps import CONVERGED_DECREMENT, StepOutcome, practice_step
from .scoring import likelihood_terms
from .steady import check_steady_data, reference_point
from .uncertainty import HeldCovariance, held_covariance

__all__ = ["innovation_formulation", "innovation_estimate", "MAX_ROUNDS", "SETTLE_STD", "closed_form_covariance",
           "sandwich_middle"]

#: relaxation rounds (R update, F compensation) before the estimate is reported as not settled
MAX_ROUNDS = 100
#: by default the relaxation settles when two successive rounds move every estimate by at most
#: this fraction of its std and the second moves J = N/2 ln det R by at most this much
SETTLE_STD = 0.01
#: with settle_std = 0 it settles when J = N/2 ln det R changes by less than this, relative ...
SETTLE_COST = 1e-10
#: ... and no estimated value moves by more than this, relative
SETTLE_STEP = 1e-9
#: updates of R at the start before the first step, and the relative change at which they stop
START_UPDATES, START_SETTLE = 50, 1e-3
#: the share of |V| below which a step's predicted decrease is V's rounding (seen: 1e-11 of |V|)
ROUNDING_RELATIVE = 1e-10
#: innovations correlated beyond this (|r|) get a note on the diagonal form's Cramer-Rao std
CORRELATED = 0.5
#: a late round's steps (R held) continue until the predicted decrease is below this (1e-9 std)
POLISH_DECREMENT = 1e-18
#: an early round moves each F within this factor of its value (:func:`_early_bounds`)
F_FACTOR = 10.0
#: rounds continue their steps (R held) to convergence once the last round moved less than this
POLISH_FROM = 1e-4

#: what an inner step's outcome means for the relaxation: the status and the note's code
_FAILURES = {
    StepOutcome.NOT_FINITE: ("Not_Finite", NoteCode.NOT_FINITE,
                             "every trial point of a step, down to the last halving, made the filter's values NaN or "
                             "infinite (the filter diverges there): the estimate is the last finite point; start "
                             "closer (an output-error estimate) or bound the parameters more tightly"),
    StepOutcome.NO_DECREASE: ("Stalled", NoteCode.NOT_VERIFIED,
                              "no step, down to the last halving, lowered the cost: the estimate is the last point "
                              "reached, not a verified optimum"),
    StepOutcome.INFEASIBLE: ("Infeasible", NoteCode.BOUNDS,
                             "the bounds and the linearised constraint diag(K C) <= 1 admit no step: widen the "
                             "bounds of the process noise or of the parameters that set the gain"),
}


def innovation_formulation(model: DynamicModel, data: Dataset, setup: FilterErrorSetup, settings: SolverSettings,
                options: FormulationOptions) -> FilterErrorEstimate:
    """The practice formulation's entry in :data:`casest.filter_error.estimator.FORMULATIONS`:
    :func:`innovation_estimate` with the estimator's setup and options.

    Parameters
    ----------
    model : DynamicModel
    data : Dataset
    setup : FilterErrorSetup
        The start, the noisy states and their intensities' start.
    settings : SolverSettings
    options : FormulationOptions

    Returns
    -------
    FilterErrorEstimate
    """
    return innovation_estimate(model, data, setup.q_start, list(setup.noisy), setup.theta0, settings,
                               options.operating_point or "first", options.innovation_covariance, options.max_rounds,
                               sandwich=options.covariance == "sandwich", settle_std=options.settle_std)


def closed_form_covariance(E: np.ndarray, diagonal: bool) -> np.ndarray:
    """The innovation covariance of innovations ``E`` (n_y x N): ``sum e e' / N``, or its diagonal.

    Parameters
    ----------
    E : ndarray, shape (n_y, N)
    diagonal : bool

    Returns
    -------
    ndarray, shape (n_y, n_y)
    """
    R = E @ E.T / E.shape[1]
    return np.diag(np.diag(R)) if diagonal else R


@dataclass
class _Relaxation:
    """Where the relaxation stands: the decision vector, R, and what the rounds took."""

    w: np.ndarray
    R: np.ndarray
    x_ref: np.ndarray
    u_ref: np.ndarray
    rounds: int = 0
    iterations: int = 0
    halvings: int = 0
    constrained_rounds: int = 0
    settled: bool = False
    failure: StepOutcome | None = None
    information: np.ndarray | None = None
    settle_rule: str = ""
    moved_std: float = np.inf


def innovation_estimate(model: DynamicModel, data: Dataset, process_noise: np.ndarray, noisy: list, theta0: np.ndarray,
                        settings: SolverSettings, operating_point: str = "first",
                        innovation_covariance: str = "diagonal", max_rounds: int = MAX_ROUNDS,
                        sandwich: bool = False, settle_std: float = SETTLE_STD) -> FilterErrorEstimate:
    """The innovation formulation's relaxation (module docstring).

    Parameters
    ----------
    model : DynamicModel
    data : Dataset
        Uniformly sampled, complete outputs.
    process_noise : ndarray, shape (n_states,)
        Start of the intensities (F_i^2), fixed for the states not in ``noisy``.
    noisy : list of int
        The states whose F is estimated.
    theta0 : ndarray, shape (n_parameters,)
    settings : SolverSettings
        ``max_iter`` bounds the Gauss-Newton steps of one round.
    operating_point : {"first", "mean"}
        Where the gain is linearised.
    innovation_covariance : {"diagonal", "full"}
        The closed-form R: its diagonal (practice) or the full matrix.
    max_rounds : int
        Relaxation rounds before the estimate is reported as not settled.
    sandwich : bool
        Report the sandwich covariance ``M^-1 B M^-1`` (:func:`sandwich_middle`) instead of the
        Cramer-Rao bound ``M^-1``.
    settle_std : float
        The relaxation settles when two successive rounds move every estimate by at most this
        fraction of its std (the information of the round's last step) and the second moves
        ``J = N/2 ln det R`` by at most this much; 0: at the fixed point's rounding
        (``SETTLE_COST``, ``SETTLE_STEP``).

    Returns
    -------
    FilterErrorEstimate
    """
    t0 = time.perf_counter()
    check_steady_data(model, data)
    problem = InnovationProblem.of(model, data.n_samples, tuple(noisy))
    diagonal, N, npar = innovation_covariance == "diagonal", data.n_samples, model.n_parameters
    f_all = np.sqrt(np.asarray(process_noise, dtype=float))
    x0 = np.asarray(model.initial_function(theta0, model.initial_values(data))).reshape(-1)
    record = problem.record_part(data)
    lower = np.concatenate([model.lower_bounds / model.scales, np.zeros(len(noisy))])
    upper = np.concatenate([model.upper_bounds / model.scales, np.full(len(noisy), np.inf)])
    w0 = np.clip(np.concatenate([theta0 / model.scales, f_all[noisy]]), lower, upper)
    x_ref, u_ref = reference_point(data, x0[None, :], first=True)
    spread = np.atleast_2d(np.cov(data.outputs.T, bias=True))
    state = _Relaxation(w0, _first_covariance(problem, record, spread, w0, x_ref, u_ref, f_all, diagonal), x_ref, u_ref)

    def parameters(R: np.ndarray) -> np.ndarray:
        return problem.parameters(record, R, state.x_ref, state.u_ref, f_all)

    J_prev, moved = np.inf, np.inf
    while state.rounds < max_rounds and not state.settled:
        state.rounds += 1
        p = parameters(state.R)
        # the true bounds (an F may reach 0) and steps to convergence once the estimate has nearly stopped
        near = moved < POLISH_FROM or state.moved_std <= settle_std
        w = _inner_steps(problem, state, p, (lower, upper) if near else _early_bounds(state.w, lower, upper, npar),
                         settings.max_iter if near else 1, max(POLISH_DECREMENT, (0.1 * settle_std) ** 2))
        if state.failure is not None:
            break
        E, _, C, _, X, _ = (np.asarray(v) for v in problem.values(w, p))
        R_new = closed_form_covariance(E, diagonal)
        f = f_all.copy()
        f[noisy] = w[model.n_parameters:]
        w[model.n_parameters:] = compensate_process_noise(f, C, state.R, R_new)[noisy]
        J = 0.5 * N * float(np.linalg.slogdet(R_new)[1])
        moved = np.max(np.abs(w - state.w) / np.maximum(np.abs(w), 1e-8), initial=0.0)
        state.settled = _settled(state, w, J, J_prev, moved, settle_std, npar)
        state.w, state.R, J_prev = w, R_new, J
        if operating_point == "mean":
            state.x_ref, state.u_ref = reference_point(data, X.T, first=False)
    p = parameters(state.R)
    E, _, dE, _ = problem.derivatives(state.w, p)
    information, middle = sandwich_middle(E, dE, state.R)
    uncertainty = _uncertainty(state.w, information, lower, upper, np.concatenate([model.scales, np.ones(len(noisy))]),
                               npar, middle if sandwich else None)
    values = [np.asarray(v) for v in problem.values(state.w, p)]
    notes = [_formulation_note(state, operating_point, diagonal)] + _relaxation_notes(state, max_rounds)
    notes += _correlation_notes(E, model.output_names, diagonal, sandwich)
    return innovation_result(problem, data, state, f_all, uncertainty, values, notes, relaxation_status(state),
                             time.perf_counter() - t0)


def _first_covariance(problem: InnovationProblem, record: tuple, spread: np.ndarray, w0: np.ndarray, x_ref, u_ref,
                      f_all: np.ndarray, diagonal: bool) -> np.ndarray:
    """The first R: the output-error residuals' at the start (F = 0: no gain), or where that
    simulation is not finite, the outputs' spread; then R's own fixed point at the start (the
    innovations of the gain of R, to ``START_SETTLE`` relative, at most ``START_UPDATES`` updates,
    none whose gain breaks ``diag(K C) <= 1``), so that the first step does not weigh the
    channels by residuals that are not the start's innovations."""
    npar = problem.model.n_parameters
    quiet = w0.copy()
    quiet[npar:] = 0.0
    E = np.asarray(problem.values(quiet, problem.parameters(record, spread, x_ref, u_ref, np.zeros_like(f_all)))[0])
    R = closed_form_covariance(E, diagonal) if np.all(np.isfinite(E)) else spread
    for _ in range(START_UPDATES):
        E = np.asarray(problem.values(w0, problem.parameters(record, R, x_ref, u_ref, f_all))[0])
        R_new = closed_form_covariance(E, diagonal)
        kc = np.asarray(problem.values(w0, problem.parameters(record, R_new, x_ref, u_ref, f_all))[1])
        if not (np.all(np.isfinite(R_new)) and np.all(kc <= 1.0)):
            break  # the next R's gain breaks diag(K C) <= 1 at the start: the steps must first restore it
        change = np.max(np.abs(np.diag(R_new) / np.diag(R) - 1.0))
        R = R_new
        if change <= START_SETTLE:
            break
    return R


def _early_bounds(w: np.ndarray, lower: np.ndarray, upper: np.ndarray, npar: int) -> tuple:
    """The bounds of an early round's step: F within a factor ``F_FACTOR`` of its value. F = 0 is
    a stationary point of every F (F enters as F F'), so an F that an early R drives to its bound
    0 would stay there for good; the last rounds take the true bounds."""
    lo, hi = lower.copy(), upper.copy()
    lo[npar:] = np.maximum(lower[npar:], w[npar:] / F_FACTOR)
    hi[npar:] = np.minimum(upper[npar:], w[npar:] * F_FACTOR)
    return lo, hi


def _inner_steps(problem: InnovationProblem, state: _Relaxation, p: np.ndarray, bounds: tuple, steps: int,
                 polish: float = POLISH_DECREMENT) -> np.ndarray:
    """Up to ``steps`` constrained Gauss-Newton steps with R held, continued (``steps`` > 1) until
    the predicted decrease ``d' M d`` (the step's squared length in std) is below ``polish``; a
    failed step ends the relaxation unless the predicted decrease left is at rounding level."""
    constraint, w = problem.constraint(), state.w.copy()

    def evaluate(trial):
        kc, _ = constraint(trial, p)
        return problem.derivatives.value(trial, p), np.asarray(kc).reshape(-1)

    for taken in range(max(int(steps), 1)):
        V, g, M = likelihood_terms(problem.derivatives, w, p)
        state.information = M
        kc, J = (np.asarray(v) for v in constraint(w, p))
        if not (np.isfinite(V) and np.all(np.isfinite(g)) and np.all(np.isfinite(M)) and np.all(np.isfinite(J))):
            state.failure = StepOutcome.NOT_FINITE  # the filter diverges at the round's own point (R changed)
            break
        step = practice_step(w, V, g, M, kc.reshape(-1), J, bounds, evaluate,
                             # a polishing round's first step is taken however small: it lands an F on 0
                             converged=(polish if taken else POLISH_DECREMENT) if steps > 1 else CONVERGED_DECREMENT)
        state.halvings += step.halvings
        if step.outcome is StepOutcome.CONVERGED:
            break
        if step.outcome is not StepOutcome.TAKEN:
            # V's own rounding (the filter's sums) is some 1e-11 of |V|: a predicted decrease below it
            # cannot be resolved, the point is as stationary as V can tell; above, a real failure
            if not step.decrement <= max(ROUNDING_DECREMENT, ROUNDING_RELATIVE * abs(V)):
                state.failure = step.outcome
            break
        w = step.w
        state.iterations += 1
        if np.any(step.kc >= 1.0 - 1e-9):
            state.constrained_rounds += 1
    return w


def _settled(state: _Relaxation, w: np.ndarray, J: float, J_prev: float, moved: float, settle_std: float,
             npar: int) -> bool:
    """Whether the round that led to ``w`` settles the relaxation: it and the round before moved
    every estimate by at most ``settle_std`` of its std (so this round had the true bounds) and it
    moved ``J`` by at most ``settle_std`` (a likelihood change no test resolves), or with
    ``settle_std`` 0, ``J`` by ``SETTLE_COST`` and every value by ``SETTLE_STEP``
    (relative: the fixed point to rounding). Records the rule that settled it."""
    if settle_std > 0.0:
        in_std = _move_in_std(w - state.w, state.information, w, npar)
        # only a round with the true bounds settles: an early round holds each F within a factor of its value
        settles = state.moved_std <= settle_std and in_std <= settle_std and abs(J - J_prev) <= settle_std
        state.moved_std = in_std
        if settles:
            state.settle_rule = (f"settled when every estimate moved by {in_std:.2g} std at most over the last round "
                                 f"(settle_std={settle_std:g}) and J = N/2 ln det R by {abs(J - J_prev):.2g}; "
                                 "settle_std=0 continues to the fixed point's rounding")
            return True
        return False
    if abs(J - J_prev) <= SETTLE_COST * max(1.0, abs(J)) and moved <= SETTLE_STEP:
        state.settle_rule = (f"settled at the fixed point's rounding (J by {SETTLE_COST:g} and every value by "
                             f"{SETTLE_STEP:g}, relative: settle_std=0)")
        return True
    return False


def _move_in_std(move: np.ndarray, information: np.ndarray, w: np.ndarray, npar: int) -> float:
    """The largest entry of a round's ``move`` in units of its standard deviation, from the
    information matrix of the round's last step (R held); a process-noise F on its bound 0 (no
    information there) is left out."""
    free = np.ones(w.size, dtype=bool)
    free[npar:] = w[npar:] > 0.0
    std = np.sqrt(np.abs(np.diag(np.linalg.pinv(information[np.ix_(free, free)]))))
    return float(np.max(np.abs(move[free]) / np.maximum(std, 1e-300), initial=0.0))


def _uncertainty(w: np.ndarray, information: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                 to_natural: np.ndarray, n_parameters: int, middle: np.ndarray | None = None) -> HeldCovariance:
    """The inverse information (the Cramer-Rao bounds), or with ``middle`` the sandwich
    ``M^-1 B M^-1``: the Cramer-Rao bounds as the textbook reports them, of every parameter (on a
    bound or not); only a process-noise F at its bound 0 is held (its derivative vanishes there, so
    it has no information)."""
    return held_covariance(w, information, lower, upper, to_natural,
                           lambda i, side: i >= n_parameters and side == "lower", middle)


def sandwich_middle(E: np.ndarray, dE: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The information ``M = sum de' R^-1 de`` of the weighting R and the sandwich's middle
    ``B = sum de' R^-1 S R^-1 de`` with S the innovations' full covariance ``sum e e' / N``
    (innovations white in time); ``M^-1 B M^-1`` is the estimator's covariance, ``M^-1`` where
    R is the innovations' covariance.

    Parameters
    ----------
    E : ndarray, shape (N, n_y)
    dE : ndarray, shape (N, n_y, n_w)
    R : ndarray, shape (n_y, n_y)

    Returns
    -------
    M, B : ndarray, shape (n_w, n_w)
    """
    N, ny, nw = dE.shape
    Ri = np.linalg.inv(R)
    weighted = np.matmul(Ri, dE).reshape(N * ny, nw)  # R^-1 de per sample
    M = dE.reshape(N * ny, nw).T @ weighted
    S = E.T @ E / N
    B = weighted.T @ np.matmul(S, np.matmul(Ri, dE)).reshape(N * ny, nw)
    return 0.5 * (M + M.T), 0.5 * (B + B.T)


def _correlation_notes(E: np.ndarray, outputs: tuple, diagonal: bool, sandwich: bool) -> list:
    """A note where the diagonal form's Cramer-Rao std ignore strongly correlated innovations."""
    if not diagonal or sandwich or E.shape[1] < 2 or not np.all(np.isfinite(E)):
        return []
    corr = np.corrcoef(E.T)
    np.fill_diagonal(corr, 0.0)
    i, j = np.unravel_index(np.argmax(np.abs(corr)), corr.shape)
    if not abs(corr[i, j]) > CORRELATED:
        return []
    return [Note(f"the innovations of {outputs[i]} and {outputs[j]} are correlated (r = {corr[i, j]:.2f}): the "
                 "Cramer-Rao std of the diagonal form ignore it and can overstate the spread several times; "
                 "covariance='sandwich' gives the estimator's own covariance", NoteCode.NOISE_MODEL)]


def _relaxation_notes(state: _Relaxation, max_rounds: int) -> list:
    """Coded notes of a relaxation that failed or did not settle."""
    if state.failure is not None:
        _, code, text = _FAILURES[state.failure]
        return [Note(f"round {state.rounds}: {text}", code)]
    if not state.settled:
        return [Note(f"the relaxation (R update, F compensation) did not settle in {max_rounds} rounds: the estimate "
                     "is the last round's; raise max_rounds or start closer", NoteCode.NOT_VERIFIED)]
    return []


def relaxation_status(state: _Relaxation) -> str:
    """The status word of a relaxation: settled, failed (its cause) or out of rounds."""
    if state.failure is not None:
        return _FAILURES[state.failure][0]
    return "Solve_Succeeded" if state.settled else "Maximum_Rounds_Exceeded"


def _formulation_note(state: _Relaxation, operating_point: str, diagonal: bool) -> Note:
    where = ("the first state and input" if operating_point == "first" else
             "the mean predicted state and input, renewed every round")
    constrained = (f"; diag(K C) <= 1 was active in {state.constrained_rounds} step(s)"
                   if state.constrained_rounds else "")
    kind = "its diagonal diag(sum e e' / N)" if diagonal else "the full matrix sum e e' / N"
    return Note(f"innovation formulation: theta and F by constrained Gauss-Newton with the innovation covariance R in "
                f"closed form ({kind}), F compensated after each update of R (Jategaonkar Eq. 5.41); one gain "
                f"linearised at {where}; {state.rounds} round(s), {state.iterations} Gauss-Newton iterations in all, "
                f"{state.halvings} step halving(s){constrained}"
                + (f"; {state.settle_rule}" if state.settled else ""), NoteCode.NOISE_MODEL)
