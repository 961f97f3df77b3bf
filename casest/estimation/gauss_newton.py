"""Output error by Gauss-Newton with Levenberg-Marquardt damping and bounds (summary Sec. 5.2).

Flight-test practice (the summary's Eq. 5.8-5.9): with R diagonal, each iteration takes R
as the residual mean square at the current theta (the ML R there) and a Gauss-Newton step
on theta for that R::

    (sum_k S_k' R^-1 S_k + lambda diag) delta = sum_k S_k' R^-1 (z_k - y_k)

with ``S_k = dy_k/dtheta`` from first-order forward sensitivities only
(:class:`casest.backend.sensitivities.OutputSensitivities`). Parameters on a bound whose
step points outward are held (bounded-variable Gauss-Newton); a step is kept only if it
lowers the weighted cost, otherwise lambda grows. At a fixed point the gradient of the
full ML cost of Eq. 6 in theta and ln R vanishes (R is its own minimiser, so the weighted
least-squares gradient is the ML gradient): the optimum is the one IPOPT's exact-Hessian
path reaches. It stops when the Gauss-Newton decrement ``b' M^-1 b`` (the squared distance
to the optimum in standard deviations, as M is the information) is below
``DECREMENT_TOL`` = 1e-12, i.e. within 1e-6 std of it, a criterion free of the parameters'
units and the weights' size; or when the largest free component of the gradient of J/N in
scaled parameters is below ``SolverSettings.tol`` (IPOPT's test).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..backend.ipopt import SolverSettings
from ..backend.linalg import single_threaded_blas
from ..backend.output_error import sensitivity_flags
from ..backend.sensitivities import output_sensitivities
from ..problem.problem import Problem
from ..status import Note, NoteCode
from .history import ConvergenceHistory


__all__ = ["GaussNewtonRun", "gauss_newton_output_error", "gauss_newton_applies", "damped_step", "decrement",
           "free_parameters", "levenberg_marquardt_step"]

#: damping limits: beyond MAX_DAMPING no step lowers the cost (a stop at rounding level)
MIN_DAMPING, MAX_DAMPING = 1e-12, 1e12
#: converged: the Gauss-Newton decrement (squared distance to the optimum in std) below this
DECREMENT_TOL = 1e-12
#: a stop at rounding level is still accepted when the decrement is below this (1e-4 std)
ROUNDING_DECREMENT = 1e-8


def gauss_newton_applies(problem: Problem) -> bool:
    """Whether :func:`gauss_newton_output_error` solves this problem: single-shooting output error
    of an RK4 model with a diagonal R (estimated or known); asked for dynamic models
    (:mod:`casest.two_stage.solve.solver_choice`)."""
    return bool(problem.model.integrator == "rk4" and problem.noise_term.per_channel)


@dataclass
class GaussNewtonRun:
    """How a Gauss-Newton solve ended.

    Attributes
    ----------
    theta : ndarray, shape (n_parameters,)
    R : ndarray, shape (n_outputs,)
    success : bool
    status : str
        ``"Solve_Succeeded"``, ``"Maximum_Iterations_Exceeded"`` or ``"Stalled"``.
    iterations : int
        Accepted steps.
    evaluations : int
        Points simulated (the start and every trial point; the sensitivities only where a step is
        taken).
    notes : list of Note
    history : ConvergenceHistory or None
        The iterates (parameters, their std, cost) from the start to the end.
    cost : float or None
        J of paper Eq. 6 at ``theta`` with ``R`` when the solver evaluated it there (None: not).
    """

    theta: np.ndarray
    R: np.ndarray
    success: bool
    status: str
    iterations: int
    evaluations: int
    notes: list = field(default_factory=list)
    history: ConvergenceHistory | None = None
    cost: float | None = None


class _Evaluation:
    """Residuals and weighted sensitivities at one theta (for a given R)."""

    def __init__(self, problem: Problem, sens, p, theta: np.ndarray, sensitivities: bool = True):
        # without sensitivities: the outputs alone (a trial point, whose cost decides if it is taken)
        y, self.jacobian = sens(theta, p) if sensitivities else (sens.outputs(theta, p), None)
        mask = problem.data.output_mask()
        with np.errstate(over="ignore", invalid="ignore"):  # a simulation that ran away: not finite, refused
            self.residuals = (problem.data.filled_outputs() - y) * mask  # 0 where not measured
            if sensitivities:
                self.jacobian *= mask[:, :, None]
        self.theta = theta
        self.finite = bool(np.all(np.isfinite(self.residuals))
                           and (not sensitivities or np.all(np.isfinite(self.jacobian))))

    def weighted_cost(self, R: np.ndarray, penalty) -> float:
        with np.errstate(over="ignore", invalid="ignore"):  # a trial step whose simulation ran away: inf, refused
            value = 0.5 * float(np.sum(self.residuals**2 / R))
        return value + (0.0 if penalty is None else penalty.value(self.theta))

    def normal_equations(self, R: np.ndarray, scale: np.ndarray, penalty) -> tuple[np.ndarray, np.ndarray]:
        """``(M, b)``: the Gauss-Newton matrix and minus the gradient of the weighted cost, scaled units."""
        w = 1.0 / np.sqrt(R)
        Jw = (self.jacobian * w[None, :, None]).reshape(-1, scale.size) * scale
        M = Jw.T @ Jw
        b = Jw.T @ (self.residuals * w).reshape(-1)
        if penalty is not None:
            M = M + np.diag(penalty.precision * scale**2)
            b = b - penalty.precision * (self.theta - penalty.mean) * scale
        return M, b


def gauss_newton_output_error(problem: Problem, theta0: np.ndarray, R0: np.ndarray, floor: np.ndarray,
                              settings: SolverSettings) -> GaussNewtonRun:
    """Minimise the output-error ML cost by bounded Gauss-Newton / Levenberg-Marquardt.

    Parameters
    ----------
    problem : Problem
        A dynamic problem for which :func:`gauss_newton_applies`.
    theta0 : ndarray, shape (n_parameters,)
        Start, physical units, inside the bounds.
    R0 : ndarray, shape (n_outputs,)
        The known R (held), or the start of an estimated R (replaced by the ML R at each iterate).
    floor : ndarray, shape (n_outputs,)
        Lower bound of an estimated R (:func:`casest.backend.ipopt.noise_floor`).
    settings : SolverSettings
        ``tol`` (on the scaled gradient of J/N), ``max_iter`` (accepted steps), ``jit``.

    Returns
    -------
    GaussNewtonRun
    """
    with single_threaded_blas():  # its products are small: BLAS threads would only spin
        return _gauss_newton(problem, theta0, R0, floor, settings)


def _gauss_newton(problem: Problem, theta0: np.ndarray, R0: np.ndarray, floor: np.ndarray,
                  settings: SolverSettings) -> GaussNewtonRun:
    """:func:`gauss_newton_output_error`'s iterations."""
    model, N = problem.model, problem.n_samples
    scale, lb, ub = model.scales, model.lower_bounds, model.upper_bounds
    estimated, penalty = problem.noise.estimated, problem.penalty
    counts = problem.data.observed_counts()
    sens = output_sensitivities(model, N, problem.masked, settings.resolved_jit(N),
                                sensitivity_flags(settings.jit_flags))
    p = problem.data_vector()

    def ml_noise(ev: _Evaluation) -> np.ndarray:
        return np.maximum(np.sum(ev.residuals**2, axis=0) / counts, floor) if estimated else R0

    current = _Evaluation(problem, sens, p, np.asarray(theta0, dtype=float))
    if not current.finite:
        return GaussNewtonRun(current.theta, R0, False, "Invalid_Start", 0, 1, [Note(
            "the simulation from the start is not finite (the model diverges there): start closer, "
            "or use multiple shooting (SolverSettings(shooting='multiple'))", NoteCode.SIMULATION)])
    R, damping, iterations, evaluations = ml_noise(current), 1e-3, 0, 1
    status, notes, iterates = "Maximum_Iterations_Exceeded", [], []
    while iterations < settings.max_iter:
        M, b = current.normal_equations(R, scale, penalty)
        iterates.append(_iterate(current, R, M, scale, counts, penalty))
        s = current.theta / scale
        free = free_parameters(s, lb / scale, ub / scale, b)
        if decrement(M, b, free) <= DECREMENT_TOL or np.max(np.abs(b[free]), initial=0.0) / N <= settings.tol:
            status = "Solve_Succeeded"
            break
        base = current.weighted_cost(R, penalty)

        def lowers_the_cost(trial_s):
            trial = _Evaluation(problem, sens, p, trial_s * scale, sensitivities=False)
            if not (trial.finite and trial.weighted_cost(R, penalty) < base):
                return None
            taken = _Evaluation(problem, sens, p, trial.theta)  # the sensitivities where the step is taken
            return taken if taken.finite else None

        trial, damping, tried = damped_step(s, M, b, free, (lb / scale, ub / scale), damping, lowers_the_cost)
        evaluations += tried
        if trial is None:
            status = "Stalled"
            break
        current, iterations = trial, iterations + 1
        R = ml_noise(current)
    stalled_at_optimum = status == "Stalled" and _stall_accepted(current, R, model, penalty, notes)
    success = status == "Solve_Succeeded" or stalled_at_optimum
    if not np.array_equal(iterates[-1][0], current.theta):  # the last step's point, not yet recorded
        iterates.append(_iterate(current, R, current.normal_equations(R, scale, penalty)[0], scale, counts, penalty))
    history = ConvergenceHistory.stacked(model.parameter_names, iterates)
    return GaussNewtonRun(current.theta, R, success, status, iterations, evaluations, notes, history)


def _stall_accepted(current: _Evaluation, R: np.ndarray, model, penalty, notes: list) -> bool:
    """Whether a point where no step lowers the cost is the optimum to rounding (a note says so)."""
    scale, lb, ub = model.scales, model.lower_bounds, model.upper_bounds
    M, b = current.normal_equations(R, scale, penalty)
    left = decrement(M, b, free_parameters(current.theta / scale, lb / scale, ub / scale, b))
    if left > ROUNDING_DECREMENT:
        return False
    notes.append(Note(f"Gauss-Newton: no step lowers the cost any more (rounding level); accepted because the point "
                      f"is {np.sqrt(left):.1e} std from the optimum that the Gauss-Newton step predicts",
                      NoteCode.ACCEPTED))
    return True


def _iterate(ev: _Evaluation, R: np.ndarray, M: np.ndarray, scale: np.ndarray, counts, penalty) -> tuple:
    """(theta, std, ML cost) at one iterate: std from the Gauss-Newton matrix M (scaled units)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        try:
            std = np.sqrt(np.diag(np.linalg.inv(M))) * scale
        except np.linalg.LinAlgError:
            std = np.full(scale.size, np.nan)
    cost = ev.weighted_cost(R, penalty) + 0.5 * float(np.sum(counts * np.log(R)))
    return ev.theta.copy(), np.where(np.isfinite(std), std, np.nan), cost


def free_parameters(s: np.ndarray, lower: np.ndarray, upper: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The parameters free to move: not on a bound that the descent direction ``b`` pushes against."""
    span = np.maximum(1.0, np.abs(s))
    at_lower = (s - lower <= 1e-10 * span) & (b < 0)
    at_upper = (upper - s <= 1e-10 * span) & (b > 0)
    return ~(at_lower | at_upper)


def damped_step(x: np.ndarray, M: np.ndarray, b: np.ndarray, free: np.ndarray, bounds: tuple, damping: float,
                accept) -> tuple:
    """Levenberg-Marquardt's search for an accepted step: damping x10 until ``accept`` takes the clipped
    trial point (it returns what it evaluated there, or None), /10 after a success.

    Parameters
    ----------
    x : ndarray, shape (n,)
    M, b : ndarray, shapes (n, n) and (n,)
        The Gauss-Newton matrix and the descent direction (minus the gradient).
    free : ndarray of bool, shape (n,)
    bounds : (ndarray, ndarray)
        Lower and upper bounds of x.
    damping : float
    accept : callable
        ``accept(trial_x) -> object or None``.

    Returns
    -------
    accepted : object or None
        What ``accept`` returned for the step taken; None when no damping up to ``MAX_DAMPING`` helps.
    damping : float
        The damping for the next iteration.
    tried : int
        Trial points evaluated.
    """
    tried = 0
    while damping <= MAX_DAMPING:
        tried += 1
        accepted = accept(np.clip(x + levenberg_marquardt_step(M, b, free, damping), *bounds))
        if accepted is not None:
            return accepted, max(damping / 10.0, MIN_DAMPING), tried
        damping *= 10.0
    return None, damping, tried


def decrement(M: np.ndarray, b: np.ndarray, free: np.ndarray) -> float:
    """``b' M^-1 b`` on the free parameters: twice the cost decrease the full Gauss-Newton step predicts."""
    if not np.any(free):
        return 0.0
    return float(b[free] @ levenberg_marquardt_step(M, b, free, 0.0)[free])


def levenberg_marquardt_step(M: np.ndarray, b: np.ndarray, free: np.ndarray, damping: float) -> np.ndarray:
    """The Levenberg-Marquardt step on the free parameters (Marquardt's scaling by diag M)."""
    step = np.zeros_like(b)
    if not np.any(free):
        return step
    Mf = M[np.ix_(free, free)]
    diag = np.maximum(np.diag(Mf), 1e-12 * max(1.0, float(np.max(np.diag(Mf)))))
    try:
        step[free] = np.linalg.solve(Mf + damping * np.diag(diag), b[free])
    except np.linalg.LinAlgError:
        step[free] = np.linalg.lstsq(Mf + damping * np.diag(diag), b[free], rcond=None)[0]
    return step
