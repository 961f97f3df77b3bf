"""The innovation formulation's inner step: one Gauss-Newton step under linear inequalities, with
step halving, as the flight-test programs take it (Jategaonkar, *Flight Vehicle System
Identification*, Sec. 5.5).

With the innovation covariance R held, the step minimises the quadratic model of
``V = 1/2 sum e' R^-1 e``::

    min_d  1/2 d' M d + g' d    subject to    lower <= w + d <= upper,
                                              diag(K C)(w) + J d <= 1

(``M`` the information matrix, ``J`` the Jacobian of ``diag(K C)``, the textbook's constraint
that keeps ``G G' = R - C P C'`` a covariance). The quadratic programme is solved exactly, as a
least-distance programme, with feasibility judged relative to each row's terms
(:mod:`casest.filter_error.least_distance`). A bound is a constraint like any other, so a process-noise
distribution can sit on its bound 0 and ``diag(K C)`` on 1, with no interior push away from
either. The step is then halved until the l1 merit ``V + mu sum max(0, diag(K C) - 1)`` falls;
a trial point where the filter diverges or any value is not finite is rejected like one that
does not lower the merit.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import Callable

import numpy as np

from .least_distance import least_distance_step

__all__ = ["StepOutcome", "PracticeStep", "least_distance_step", "practice_step", "MAX_HALVINGS", "CONVERGED_DECREMENT"]

#: halvings of a step before it is given up (the textbook's programs allow ten)
MAX_HALVINGS = 10
#: a step whose predicted decrease d' M d is below this is converged, whatever its merit does (1e-6 std)
CONVERGED_DECREMENT = 1e-12


class StepOutcome(str, Enum):
    """How one inner step ended."""

    TAKEN = "taken"  # a trial point lowered the merit
    CONVERGED = "converged"  # the predicted decrease is at rounding level: nothing left to take
    NOT_FINITE = "not_finite"  # every trial point down to the last halving had a non-finite value
    NO_DECREASE = "no_decrease"  # finite trial points, none lowering the merit
    INFEASIBLE = "infeasible"  # the linearised constraints and the bounds admit no step


@dataclass
class PracticeStep:
    """One inner step.

    Attributes
    ----------
    w : ndarray, shape (n_w,)
        The accepted point (the start where nothing was accepted).
    outcome : StepOutcome
    halvings : int
        How often the step was halved.
    decrement : float
        ``d' M d`` of the full step: twice the decrease the quadratic model predicts.
    kc : ndarray, shape (n_states,)
        ``diag(K C)`` at ``w`` (the start's where nothing was accepted).
    """

    w: np.ndarray
    outcome: StepOutcome
    halvings: int
    decrement: float
    kc: np.ndarray


def _constraint_rows(w: np.ndarray, lower: np.ndarray, upper: np.ndarray, kc: np.ndarray, J: np.ndarray) -> tuple:
    """``A d <= b`` of the finite bounds and the linearised ``diag(K C) <= 1``, the size of the terms
    each ``b`` is computed from, and the index of the latter's rows."""
    eye = np.eye(w.size)
    lo, hi = np.isfinite(lower), np.isfinite(upper)
    A = np.vstack([-eye[lo], eye[hi], J])
    b = np.concatenate([w[lo] - lower[lo], upper[hi] - w[hi], 1.0 - kc])
    b_scale = np.concatenate([np.abs(w[lo]) + np.abs(lower[lo]), np.abs(upper[hi]) + np.abs(w[hi]), 1.0 + np.abs(kc)])
    return A, b, b_scale, np.arange(A.shape[0] - kc.size, A.shape[0])


def practice_step(w: np.ndarray, V: float, g: np.ndarray, M: np.ndarray, kc: np.ndarray, J: np.ndarray,
                  bounds: tuple, evaluate: Callable, max_halvings: int = MAX_HALVINGS,
                  converged: float = CONVERGED_DECREMENT) -> PracticeStep:
    """One Gauss-Newton step under the bounds and ``diag(K C) <= 1``, halved until the merit falls.

    Parameters
    ----------
    w : ndarray, shape (n_w,)
        The current point (within its bounds).
    V : float
        The cost at ``w``.
    g : ndarray, shape (n_w,)
        Its gradient.
    M : ndarray, shape (n_w, n_w)
        The information matrix (Gauss-Newton's Hessian).
    kc : ndarray, shape (n_states,)
        ``diag(K C)`` at ``w``.
    J : ndarray, shape (n_states, n_w)
        Its Jacobian.
    bounds : tuple of ndarray
        ``(lower, upper)``, shape (n_w,) each.
    evaluate : callable
        ``evaluate(w) -> (V, kc)`` at a trial point (non-finite values where the filter diverges).
    max_halvings : int
    converged : float
        The predicted decrease ``d' M d`` below which the point is returned as converged.

    Returns
    -------
    PracticeStep
    """
    lower, upper = bounds
    A, b, b_scale, kc_rows = _constraint_rows(w, lower, upper, kc, J)
    d, multipliers = least_distance_step(M, g, A, b, b_scale)
    if d is None:
        return PracticeStep(w, StepOutcome.INFEASIBLE, 0, np.nan, kc)
    predicted = float(d @ M @ d)
    if predicted <= converged:
        return PracticeStep(w, StepOutcome.CONVERGED, 0, predicted, kc)
    # the l1 merit's weight above the largest multiplier of diag(K C) <= 1: an exact penalty
    mu = 2.0 * float(np.max(multipliers[kc_rows], initial=0.0)) + 1e-8 * max(1.0, abs(V))
    merit = V + mu * float(np.sum(np.maximum(kc - 1.0, 0.0)))
    finite_seen = False
    for halvings in range(max_halvings + 1):
        trial = np.clip(w + d * 0.5**halvings, lower, upper)
        V_t, kc_t = evaluate(trial)
        if not (np.isfinite(V_t) and np.all(np.isfinite(kc_t))):
            continue
        finite_seen = True
        if V_t + mu * float(np.sum(np.maximum(kc_t - 1.0, 0.0))) < merit:
            return PracticeStep(trial, StepOutcome.TAKEN, halvings, predicted, kc_t)
    outcome = StepOutcome.NO_DECREASE if finite_seen else StepOutcome.NOT_FINITE
    return PracticeStep(w, outcome, max_halvings, predicted, kc)
