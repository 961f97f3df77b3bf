"""What one stage-2 solve returns."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...options import Mode, choices
from ...status import Outcome


__all__ = ["MODES", "Stage2Result"]


MODES = choices(Mode)


@dataclass
class Stage2Result:
    """Raw outcome of stage 2 (the public result is :class:`casest.Estimate`).

    Attributes
    ----------
    theta : ndarray, shape (n_parameters,)
    R : ndarray, shape (n_outputs,)
    cost : float
        J(theta, R) of Eq. 6 (constants dropped).
    success : bool
    status : str
        IPOPT's return status (or the loop's, in alternating mode).
    message : str
    n_iterations : int
        IPOPT iterations (summed over solves).
    mode : str
        Mode that produced the result (may differ from the one asked, see notes).
    notes : list of str
    seconds : float
    outcome : Outcome
        How it ended, as a code.
    R_full : ndarray, shape (n_outputs, n_outputs), or None
        The estimated full R (``CorrelatedNoise``); ``R`` is its diagonal.
    history : ConvergenceHistory or None
        The iterates of a Gauss-Newton output-error solve (None for the other solvers).
    """

    theta: np.ndarray
    R: np.ndarray
    cost: float
    success: bool
    status: str
    message: str
    n_iterations: int
    mode: str
    notes: list = field(default_factory=list)
    seconds: float = 0.0
    outcome: Outcome = Outcome.NOT_CONVERGED
    R_full: np.ndarray | None = None
    history: object = None
