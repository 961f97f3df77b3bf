"""The paper's benchmark estimators (Sec. III.A-B) and a multi-start reference.

- :func:`random_start` (Benchmark 1): the same ML NLP as stage 2 (full mode, same box)
  started from a random guess drawn from user-given distributions.
- :func:`haupt_kasdin` (Benchmark 2): the two-step estimator of Haupt and Kasdin for
  models where the user supplies a change of variables ``h = H(x) y`` with
  ``y = f(theta)`` (paper Eq. 28-32).
- :func:`multistart`: full ML solves from a space-filling design, the yardstick for
  "did a method reach the global minimum".
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass
from typing import Mapping

import casadi as ca
import numpy as np

from ..backend.ipopt import run_ipopt
from ..data.dataset import DataError, Dataset
from ..errors import OptionError
from ..two_stage.pipeline import estimate, package_estimate
from ..two_stage.result import Estimate
from ..problem.separate import Partition, separate
from ..two_stage.solve import SolverSettings, Stage2Result, solve_stage2
from ..two_stage.sweep import SweepSettings, draw_candidates, sweep
from ..estimation.uncertainty import Uncertainty, covariance_from_hessian, std_from_covariance
from ..models import Gaussian, LogUniform, Model, Uniform
from ..problem.costs import concentrated_cost  # noqa: F401 (re-exported)
from ..problem.problem import Problem, as_problem


__all__ = [
    "concentrated_cost",
    "draw_start",
    "random_start",
    "ChangeOfVariables",
    "haupt_kasdin",
    "multistart",
]


def draw_start(model: Model, distributions: Mapping, rng: np.random.Generator) -> np.ndarray:
    """One random start, shape (n_parameters,), clipped into the bounds.

    Parameters
    ----------
    distributions : mapping of parameter name to Gaussian, Uniform or LogUniform
        Parameters not named start at their nominal value.
    """
    model.index(list(distributions))
    theta = model.nominal.copy()
    for i, p in enumerate(model.parameters):
        dist = distributions.get(p.name)
        if dist is None:
            continue
        if isinstance(dist, Gaussian):
            theta[i] = dist.mean + dist.std * rng.standard_normal()
        elif isinstance(dist, (Uniform, LogUniform)):
            theta[i] = float(dist.ppf(rng.random(), p.lb, p.ub))
        else:
            raise OptionError(f"start distribution of {p.name!r} must be Gaussian, Uniform or LogUniform")
    return np.clip(theta, model.lower_bounds, model.upper_bounds)


def random_start(
    model: Model | Problem,
    data: Dataset | None = None,
    distributions: Mapping | None = None,
    seed: int = 0,
    start=None,
    covariance: str = "hessian",
    solver_settings: SolverSettings | None = None,
    dof_correction: bool = False,
) -> Estimate:
    """Benchmark 1: the full ML NLP from a random start, same box constraints.

    Parameters
    ----------
    model, data : Model and Dataset, or Problem and None
    distributions : mapping of name to distribution
        Where starts are drawn from (paper: a, c ~ N(0, 1), b ~ N(0, 0.1^2) for Eq. 21).
    seed : int
        Seed of the draw.
    start : array_like, optional
        A pre-drawn start (shape (n_parameters,)) instead of a draw.
    covariance : {"hessian", "gauss-newton"}
    solver_settings : SolverSettings, optional
    dof_correction : bool
        As for :func:`casest.estimate`.

    Returns
    -------
    Estimate
    """
    problem = as_problem(model, data)
    model = problem.model
    if start is None:
        if distributions is None:
            raise OptionError("random_start needs `distributions` or an explicit `start`")
        start = draw_start(model, distributions, np.random.default_rng(seed))
    start = np.clip(problem.vector(start), model.lower_bounds, model.upper_bounds)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return estimate(problem, mode="full", start=start, covariance=covariance, solver_settings=solver_settings,
                        dof_correction=dof_correction)


@dataclass(frozen=True)
class ChangeOfVariables:
    """A change of variables that makes the model linear in new states y (paper Eq. 28).

    ``h(x, theta) = H(x) @ f(theta)`` for every sample.

    Attributes
    ----------
    H : casadi.Function
        ``signals[n_signals] -> H[n_outputs x n_y]``: known regressors per sample.
    f : casadi.Function
        ``theta[n_parameters] -> y[n_y]``.
    """

    H: ca.Function
    f: ca.Function


def haupt_kasdin(
    model: Model,
    data: Dataset,
    change: ChangeOfVariables,
    start,
    solver_settings: SolverSettings | None = None,
) -> Estimate:
    """Benchmark 2: the Haupt/Kasdin two-step estimator (paper Eq. 28-32).

    Step 1 solves ``Z = H y + v`` for y by linear least squares (minimum-norm solution
    when H is rank-deficient, as Eq. 28's is) with information matrix
    ``P_y^+ = sum_k H_k' R^-1 H_k``. Step 2 minimises
    ``(y_hat - f(theta))' P_y^+ (y_hat - f(theta))`` from ``start`` with IPOPT, without
    bounds (as in the paper). The covariance is ``(F' P_y^+ F)^-1``, F = df/dtheta.

    Returns
    -------
    Estimate
        ``cost`` is the ML cost with R at its optimum for the returned theta.
    """
    t0 = time.perf_counter()
    if data.has_missing:
        raise DataError("Benchmark 2 (Haupt/Kasdin) does not take data with missing outputs; drop those samples")
    settings = solver_settings or SolverSettings()
    N, ny = data.n_samples, model.n_outputs
    H = np.asarray(change.H.map(N)(data.signals.T)).reshape(ny, N, -1).transpose(1, 0, 2)  # (N, ny, m)
    m = H.shape[2]
    Hs = H.reshape(N * ny, m)
    z = data.outputs.reshape(-1)
    y_hat, _, rank, _ = np.linalg.lstsq(Hs, z, rcond=None)
    resid = (z - Hs @ y_hat).reshape(N, ny)
    R = np.sum(resid**2, axis=0) / max(N - rank / ny, 1.0)
    w = np.tile(1.0 / R, N)
    P_info = (Hs * w[:, None]).T @ Hs

    theta_s = ca.MX.sym("s", model.n_parameters)
    scale = model.scales
    e = ca.DM(y_hat) - change.f(theta_s * ca.DM(scale))
    cost2 = 0.5 * ca.bilin(ca.DM(P_info), e, e)
    solver = ca.nlpsol("haupt_kasdin", "ipopt", {"x": theta_s, "f": cost2 / N}, settings.nlpsol_options())
    run = run_ipopt(solver, x0=model.vector(start) / scale)
    theta = run.x * scale
    theta_sym = ca.MX.sym("theta", model.n_parameters)
    F = np.asarray(ca.Function("F", [theta_sym], [ca.jacobian(change.f(theta_sym), theta_sym)])(theta))
    C, null = covariance_from_hessian(F.T @ P_info @ F)
    names = model.parameter_names
    reasons = [None if not null.shape[1] else "second-step information matrix singular" for _ in names]
    problem = Problem(model, data)
    R_ml = np.maximum(problem.residual_mean_square(theta), 1e-300)
    stage2 = Stage2Result(
        theta=theta,
        R=R_ml,
        cost=problem.cost(theta, R_ml),
        success=run.success,
        status=run.status,
        message="converged" if run.success else "second step did not converge",
        n_iterations=run.iterations,
        mode="haupt-kasdin",
        notes=[f"first step: rank {rank} of {m} new states (minimum-norm solution)"] if rank < m else [],
        seconds=time.perf_counter() - t0,
    )
    unc = Uncertainty(covariance=C, std=std_from_covariance(C), reasons=reasons, method="haupt-kasdin")
    return package_estimate(model, data, (), names, stage2, unc, [None] * len(names), None,
                            {"total": stage2.seconds}, stage2.notes)


def multistart(
    model: Model | Problem,
    data: Dataset | None = None,
    n_starts: int = 32,
    seed: int = 0,
    partition: Partition | None = None,
    solver_settings: SolverSettings | None = None,
) -> tuple[Stage2Result, np.ndarray]:
    """Full ML solves from a scrambled Sobol design over xi2 (xi1 by least squares).

    Parameters
    ----------
    model, data : Model and Dataset, or Problem and None

    Returns
    -------
    best : Stage2Result
        The successful solve with the lowest cost (the lowest overall if none succeeded).
    costs : ndarray, shape (n_starts,)
        The problem's cost with the noise at its optimum (:meth:`Problem.profile_cost`) of
        every solve (``inf`` where it failed).
    """
    problem = as_problem(model, data)
    model = problem.model
    partition = partition or separate(model)
    if partition.n_nonlinear:
        cands, _, _ = draw_candidates(model, partition, SweepSettings(design="sobol", n_candidates=n_starts, seed=seed))
        land = sweep(problem, partition=partition, candidates=cands)
        starts = [partition.assemble(np.nan_to_num(land.xi1[i]), cands[i]) for i in range(len(cands))]
    else:
        land = sweep(problem, partition=partition)
        starts = [partition.assemble(land.best_xi1, np.zeros(0))]
    best, costs = None, []
    for theta0 in starts:
        theta0 = np.clip(theta0, model.lower_bounds, model.upper_bounds)
        res = solve_stage2(problem, theta0=theta0, partition=partition, mode="full", settings=solver_settings)
        cost = problem.profile_cost(res.theta) if res.success else np.inf
        costs.append(cost)
        if best is None or (res.success and (not best.success or cost < best.cost)):
            best = res
    return best, np.array(costs)
