"""Filter-error maximum likelihood: parameters (and process-noise intensities) from the
prediction errors of an extended Kalman filter (reference summary Sec. 5, Eq. 5.3-5.7).

Output error assumes deterministic states; with process noise (turbulence) the states
wander away from any simulation, and where the inputs respond to the noise (a pilot or a
controller in the loop) the output-error estimates are biased. Filter error instead
minimises the negative log-likelihood of the filter's one-step prediction errors::

    V(theta, q, R) = 1/2 sum_k [ e_k' S_k^-1 e_k + ln det S_k ]              (Eq. 5.7)
    e_k = y_k - h(x(k|k-1), u_k, theta),   S_k = H P(k|k-1) H' + R

with the filter of :class:`casest.ExtendedKalmanFilter` (the same step, Jacobians and
discretisation) written as one CasADi recursion, so that IPOPT gets the exact gradient and
Hessian through the filter. Missing channels (NaN) drop out of e_k and S_k. Decision
variables: the model's parameters (box-bounded, scaled), the logarithms of the estimated
process-noise intensities and of the measurement-noise variances R (diagonal).
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Mapping

import casadi as ca
import numpy as np

from ..options import (FilterErrorCovariance, FilterErrorFormulation, FilterErrorSolver, InnovationCovariance,
                       OperatingPoint, check_option)
from ..backend.ipopt import SolverSettings
from ..backend.linalg import single_threaded_blas
from ..data.dataset import Dataset
from ..errors import OptionError
from ..models.dynamic import DynamicModel
from ..problem.problem import Problem
from . import likelihood, relaxation
from .nlp import FormulationOptions, filter_error_setup, intensity_vector, time_varying_columns, time_varying_graph
from .relaxation import MAX_ROUNDS, SETTLE_STD
from .result import FilterErrorEstimate
from ..checks import whole_number


__all__ = ["FilterErrorEstimate", "filter_error_estimate", "filter_error_cost"]

LOG_2PI = float(np.log(2.0 * np.pi))



def filter_error_cost(model: DynamicModel, data: Dataset, theta, process_noise, R, P0=None) -> float:
    """V of summary Eq. 5.7 (no constants) at given parameters, intensities and R, by the
    symbolic filter recursion.

    Parameters
    ----------
    model : DynamicModel
    data : Dataset
    theta : mapping or array_like, shape (n_parameters,)
    process_noise : mapping or array_like (n_states,)
        Continuous intensities per state.
    R : array_like, shape (n_outputs,)
        Measurement-noise variances.
    P0 : array_like, shape (n_states, n_states), optional
        Initial state covariance (default zero: x0 known).

    Returns
    -------
    float
        ``1/2 sum_k (e_k' S_k^-1 e_k + ln det S_k)`` over the record.
    """
    model.check_data(data)
    n = model.n_states
    q = intensity_vector(model, process_noise)
    P0 = np.zeros((n, n)) if P0 is None else np.asarray(P0, dtype=float).reshape(n, n)
    graph = time_varying_graph(model, data.n_samples, P0)
    syms, V = graph.symbols, graph.V
    D, last = time_varying_columns(model, data)
    th = model.vector(theta) if isinstance(theta, Mapping) else np.asarray(theta, dtype=float)
    f = ca.Function("V", list(syms), [V])
    return float(f(th, q, np.asarray(R, dtype=float), D, last, model.initial_values(data)))


def filter_error_estimate(
    model: DynamicModel | Problem,
    data: Dataset | None,
    process_noise: Mapping[str, float],
    *,
    estimate_process_noise: bool = True,
    R=None,
    start: Mapping[str, float] | np.ndarray | None = None,
    P0=None,
    max_iter: int = 300,
    tol: float = 1e-10,
    print_level: int = 0,
    settings: SolverSettings | None = None,
    formulation: FilterErrorFormulation = "time-varying",
    solver: FilterErrorSolver = "scoring",
    covariance: FilterErrorCovariance = "hessian",
    operating_point: OperatingPoint | None = None,
    innovation_covariance: InnovationCovariance = "diagonal",
    max_rounds: int = MAX_ROUNDS,
    settle_std: float = SETTLE_STD,
) -> FilterErrorEstimate:
    """Filter-error maximum likelihood (summary Sec. 5) on a dynamic model with process noise.

    Parameters
    ----------
    model : DynamicModel or Problem
        Integrator ``"rk4"``; every parameter is estimated within its bounds. A
        :class:`casest.Problem` (with ``data`` None) brings its record, its fixed parameters and
        its noise model: ``KnownNoise`` gives ``R``, ``DiagonalNoise`` estimates it.
    data : Dataset or None
        The model's record (time, inputs, outputs; NaN outputs are missing).
    process_noise : mapping state name -> intensity
        The states with continuous white process noise on their rhs and its intensity (state
        rate squared per hertz): the start, or fixed. States not named get none.
    estimate_process_noise : bool
        Estimate the named intensities (default) or hold them.
    R : array_like, shape (n_outputs,), optional
        Known measurement-noise variances; default: estimated.
    start : mapping or array_like, optional
        Parameter start (default the model's nominal values).
    P0 : array_like, shape (n_states, n_states), optional
        Initial-state covariance (default zero: the initial state is known or a parameter); the
        time-varying formulation only.
    max_iter, tol, print_level, settings
        The solver's settings (tol on V / N) over casest's :class:`SolverSettings`.
    formulation : {"time-varying", "steady-state", "innovation"}
        The EKF with P(k|k-1) over the record (exact likelihood, missing samples allowed);
        one gain at an operating point with R estimated
        (:mod:`~casest.filter_error.steady`); flight-test practice, the innovation
        covariance in closed form (:mod:`~casest.filter_error.innovation`; leave ``R``
        out). The one-gain forms need uniform sampling and complete outputs.
    solver : {"scoring", "ipopt"}
        Levenberg-Marquardt on the Fisher information (first derivatives only,
        :mod:`~casest.filter_error.scoring`), or IPOPT with the exact Hessian: the same optimum.
    covariance : {"hessian", "fisher", "sandwich"}
        The inverse exact Hessian of V, or the inverse Fisher information (the Cramer-Rao
        bound); the innovation form reports the latter (with ``"hessian"`` too) and ignores
        ``solver``. ``"sandwich"`` (innovation form only): ``M^-1 B M^-1`` with M the
        information of the diagonal weighting and B its products with the full innovation
        covariance, the estimator's own covariance where the channels' innovations are
        correlated (the Cramer-Rao bound of the diagonal form then overstates the std: 1-7
        times on ``models/turbulent_longitudinal.py``, the sandwich 0.7-1.9 times the
        Monte-Carlo spread).
    operating_point : {"first", "mean"}, optional
        Where the one-gain forms linearise: the first state and input, or the mean predicted
        state and input, renewed until the estimate settles (default ``"mean"`` for
        ``"steady-state"``, ``"first"`` for ``"innovation"``).
    innovation_covariance : {"diagonal", "full"}
        The innovation form's closed-form innovation covariance: its diagonal
        ``diag(sum e e' / N)``, as flight-test practice takes it (default), or the full matrix
        ``sum e e' / N``, a different estimator where the channels' innovations are correlated.
    max_rounds : int
        The innovation form's relaxation rounds (R update, F compensation) before the estimate
        is reported as not settled; ``max_iter`` bounds the Gauss-Newton steps of one round.
    settle_std : float
        The innovation form's relaxation settles when two successive rounds move every estimate
        by at most this fraction of its standard deviation and the second moves
        ``N/2 ln det R`` by at most this much (default 0.01: further rounds move nothing the std
        resolves); 0 continues to the fixed
        point's rounding (the fully converged answer). The rule that settled it is in the
        formulation's note.

    Returns
    -------
    FilterErrorEstimate
    """
    t0, cpu0 = time.perf_counter(), time.process_time()
    if isinstance(model, Problem):
        model, data, R = _problem_parts(model, data, R)
    _check_forms(formulation, solver, covariance, operating_point, R is None and estimate_process_noise)
    check_option("innovation_covariance", innovation_covariance, InnovationCovariance)
    max_rounds = whole_number(max_rounds, "max_rounds must be a positive integer")
    if not (isinstance(settle_std, (int, float)) and np.isfinite(settle_std) and 0.0 <= settle_std < 1.0):
        raise OptionError(f"settle_std must be a fraction of a standard deviation in [0, 1), got {settle_std!r}: "
                          "0.01 (the default) stops where further rounds move nothing the std resolves, 0 runs to "
                          "the fixed point's rounding")
    max_iter = whole_number(max_iter, "max_iter must be a whole number of solver steps >= 1")
    if P0 is not None and formulation != "time-varying":
        raise OptionError(f"P0 is not used by the {formulation!r} formulation (its one gain does not depend on the "
                          "initial covariance): leave P0 out, or use formulation='time-varying'")
    setup = filter_error_setup(model, data, process_noise, estimate_process_noise, R, start, P0)
    settings = replace(settings or SolverSettings(), max_iter=int(max_iter), tol=float(tol),
                       print_level=int(print_level))
    options = FormulationOptions(solver, covariance, operating_point, innovation_covariance, int(max_rounds), t0,
                                 float(settle_std))
    with single_threaded_blas():  # small matrices: BLAS threads would only spin (half the CPU time of a solve)
        result = FORMULATIONS[formulation](model, data, setup, settings, options)
    return replace(result, seconds=time.perf_counter() - t0, cpu_seconds=time.process_time() - cpu0)


#: the formulations by name (``formulation=``): each its module's entry function, of one signature
#: ``(model, data, setup, settings, options) -> FilterErrorEstimate``
FORMULATIONS = {"time-varying": likelihood.time_varying_formulation,
                "steady-state": likelihood.steady_state_formulation,
                "innovation": relaxation.innovation_formulation}


def _problem_parts(problem: Problem, data, R) -> tuple:
    """The model (fixed parameters substituted), the record and the known R of a Problem."""
    if data is not None or problem.experiments or problem.stage1_data is not None:
        raise OptionError("filter_error_estimate(problem, None, process_noise) takes the problem's one record: give "
                          "the data to the Problem (one Dataset, no experiments or stage-1 data), not here")
    if problem.noise.estimated and not problem.noise.profiled_per_channel:  # a full R
        raise OptionError(f"filter error estimates a diagonal R or takes a known one; this problem has "
                          f"{problem.describe_noise()}: use DiagonalNoise() or KnownNoise(...)")
    if R is not None and problem.known_R is not None:
        raise OptionError("give R once: in the Problem's KnownNoise or as R=, not both")
    return problem.model, problem.data, R if R is not None else problem.known_R


def _check_forms(formulation: str, solver: str, covariance: str, operating_point: str | None,
                 noise_estimated: bool) -> None:
    """Refuse option values filter-error ML does not know, or that the formulation does not take."""
    check_option("formulation", formulation, FilterErrorFormulation)
    check_option("solver", solver, FilterErrorSolver)
    check_option("covariance", covariance, FilterErrorCovariance)
    if covariance == "sandwich" and formulation != "innovation":
        raise OptionError("covariance='sandwich' is the innovation formulation's (formulation='innovation'); the "
                          "other forms estimate R with the parameters: use 'hessian' or 'fisher'")
    if formulation == "innovation" and not noise_estimated:
        raise OptionError("formulation='innovation' estimates the process noise and the innovation covariance "
                          "itself: leave R out and estimate_process_noise at True")
    if operating_point is None:
        return
    if formulation == "time-varying":
        raise OptionError("operating_point is for formulation='steady-state' or 'innovation': the time-varying form "
                          "linearises at every sample's own state; leave it out")
    check_option("operating_point", operating_point, OperatingPoint)


