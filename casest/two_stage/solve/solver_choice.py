"""Which solver runs a stage-2 full-mode solve: the dedicated least-squares solver of the
measurement's kind where it applies, IPOPT otherwise.

Each kind registers its own (``functools.singledispatch`` on the measurement): a static model's
is casest's Levenberg-Marquardt (``SolverSettings.least_squares_solver``), a dynamic model's
is Gauss-Newton output error (``SolverSettings.output_error_solver``). A new kind of model
registers its solver here instead of a test of which kind it is.
"""

from __future__ import annotations

import functools

from ...backend.ipopt import SolverSettings
from ...errors import OptionError
from ...problem.measurement import DynamicMeasurement, Measurement, StaticMeasurement
from ...problem.problem import Problem
from ...estimation.gauss_newton import gauss_newton_applies
from .levenberg_marquardt import least_squares_applies, small_enough


__all__ = ["dedicated_solver", "uses_gauss_newton", "uses_levenberg_marquardt"]

LEVENBERG_MARQUARDT_REFUSED = ("least_squares_solver='levenberg-marquardt' needs a static model with a diagonal R "
                               "and no priors as penalties; use 'auto' or 'ipopt' for this problem")


def dedicated_solver(problem: Problem, settings: SolverSettings) -> str | None:
    """The least-squares solver that runs this problem's full-mode stage 2 before (or instead of) IPOPT.

    Parameters
    ----------
    problem : Problem
    settings : SolverSettings

    Returns
    -------
    str or None
        ``"levenberg-marquardt"``, ``"gauss-newton"``, or None (IPOPT alone).

    Raises
    ------
    OptionError
        A solver asked for explicitly that cannot solve this problem.
    """
    return _solver_of(problem.measurement, problem, settings)


def uses_gauss_newton(problem: Problem, settings: SolverSettings) -> bool:
    """Whether stage 2 of this problem runs Gauss-Newton output error (``SolverSettings.output_error_solver``).

    Parameters
    ----------
    problem : Problem
    settings : SolverSettings

    Returns
    -------
    bool
    """
    return dedicated_solver(problem, settings) == "gauss-newton"


def uses_levenberg_marquardt(problem: Problem, settings: SolverSettings) -> bool:
    """Whether stage 2 of this problem runs Levenberg-Marquardt first (``SolverSettings.least_squares_solver``).

    Parameters
    ----------
    problem : Problem
    settings : SolverSettings

    Returns
    -------
    bool
    """
    return dedicated_solver(problem, settings) == "levenberg-marquardt"


@functools.singledispatch
def _solver_of(measurement: Measurement, problem: Problem, settings: SolverSettings) -> str | None:
    # a new kind registers its choice (None: IPOPT); an unregistered one is a casest bug, said as such
    raise TypeError(f"no stage-2 solver choice is registered for the measurement kind {type(measurement).__name__}")


@_solver_of.register
def _(measurement: StaticMeasurement, problem: Problem, settings: SolverSettings) -> str | None:
    if settings.least_squares_solver == "ipopt":
        return None
    applies = least_squares_applies(problem)
    if settings.least_squares_solver == "levenberg-marquardt" and not applies:
        raise OptionError(LEVENBERG_MARQUARDT_REFUSED)
    chosen = applies and (settings.least_squares_solver == "levenberg-marquardt" or small_enough(problem))
    return "levenberg-marquardt" if chosen else None


@_solver_of.register
def _(measurement: DynamicMeasurement, problem: Problem, settings: SolverSettings) -> str | None:
    if settings.least_squares_solver == "levenberg-marquardt":
        raise OptionError(LEVENBERG_MARQUARDT_REFUSED)
    if settings.output_error_solver == "ipopt" or settings.shooting == "multiple":
        return None
    applies = gauss_newton_applies(problem)
    if settings.output_error_solver == "gauss-newton" and not applies:
        raise OptionError("output_error_solver='gauss-newton' needs single-shooting output error of an RK4 "
                          "DynamicModel with a diagonal R; use 'auto' or 'ipopt' for this problem")
    return "gauss-newton" if applies else None
