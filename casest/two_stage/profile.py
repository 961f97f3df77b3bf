"""Profile-likelihood intervals of every parameter by re-optimisation.

For parameter i held at a value v, the profile cost ``J_p(v)`` is the ML cost minimised over the
other parameters and R (paper Eq. 6; the stage-2 NLP with theta_i's bounds set to v, IPOPT with
the exact Hessian, warm-started from the nearest value already solved). The interval of level p
is where the deviance ``2 (J_p(v) - J_hat)`` stays below ``chi2_p(1)``: from the estimate, each
end is bracketed by steps of the Wald half-width (doubled until the deviance exceeds the
threshold, or the bound is reached) and then found by Brent's method to a relative tolerance.
Static and dynamic models alike (the stage-2 NLP of the problem's kind).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .._casadi.evaluation import evaluate
from ..backend.ipopt import SolverSettings, noise_floor
from ..checks import noise_covariance, noise_variances
from ..errors import OptionError
from ..problem import Problem
from ..estimation.intervals import ProfileInterval
from ..problem.separate import separate
from .solve.nlps import MultipleShootingNLP, full_nlp

__all__ = ["ProfileInterval", "profile_intervals", "with_profile_intervals"]


class _Profile:
    """The profile cost of one problem, parameter by parameter, with warm starts."""

    def __init__(self, problem: Problem, theta_hat: np.ndarray, R_hat, settings: SolverSettings):
        self.problem, self.settings = problem, settings
        model = problem.model
        self.nlp = full_nlp(problem, separate(model), settings)
        if isinstance(self.nlp, MultipleShootingNLP):  # its decision vector holds the shooting nodes too
            raise OptionError("profile intervals re-optimise by single shooting: give SolverSettings(shooting='single')")
        # the stage-2 NLP's noise block and its bounds (a known R: held by equal bounds)
        lo, hi = problem.noise.stage2_bounds(noise_floor(problem.data, settings), np.asarray(R_hat, dtype=float))
        self.lbw = np.concatenate([model.lower_bounds / self.nlp.scale, lo])
        self.ubw = np.concatenate([model.upper_bounds / self.nlp.scale, hi])
        self.w_hat = np.concatenate([theta_hat / self.nlp.scale, problem.noise_vector(R_hat)])
        self.J_hat = problem.profile_cost(theta_hat)
        self.solves = 0

    def deviance(self, i: int, value: float, warm: dict) -> float:
        """``2 (J_p(value) - J_hat)`` for parameter i; ``warm`` (value -> solution) is read and extended.

        From the nearest value solved, exact Newton steps on the other variables (the stage-2
        NLP's gradient and Hessian) when they converge inside the bounds with a positive
        definite Hessian; IPOPT with the parameter's bounds set to the value otherwise."""
        nearest = min(warm, key=lambda v: abs(v - value)) if warm else None
        w0 = (warm[nearest] if nearest is not None else self.w_hat).copy()
        s = value / self.nlp.scale[i]
        w0[i] = s
        lbw, ubw = self.lbw.copy(), self.ubw.copy()
        lbw[i] = ubw[i] = s
        with self.problem.data_argument() as p:
            w = self._newton(i, np.clip(w0, lbw, ubw), lbw, ubw, p)
            if w is None:
                w, _ = self.nlp.solve(np.clip(w0, lbw, ubw), lbw, ubw, p, self.settings.max_iter)
            (theta,) = evaluate(self.nlp.theta_of, w, p)
        self.solves += 1
        warm[float(value)] = w
        return 2.0 * (self.problem.profile_cost(theta) - self.J_hat)

    def _newton(self, i: int, w: np.ndarray, lbw: np.ndarray, ubw: np.ndarray, p, steps: int = 12):
        """The profile point by exact Newton steps on every variable but ``i``, or None when they do
        not settle (gradient below 1e-9 of its scale) inside the bounds with a positive definite Hessian."""
        if self.nlp.newton is None:
            return None
        free = np.ones(w.size, dtype=bool)
        free[i] = False
        w = w.copy()
        for _ in range(steps):
            g, H = evaluate(self.nlp.newton, w, p)
            g, H = np.asarray(g, dtype=float).reshape(-1), np.asarray(H, dtype=float)
            Hf = H[np.ix_(free, free)]
            try:
                np.linalg.cholesky(Hf)
                step = np.linalg.solve(Hf, -g[free])
            except np.linalg.LinAlgError:
                return None
            w[free] += step
            if not (np.all(np.isfinite(w)) and np.all(w >= lbw) and np.all(w <= ubw)):
                return None
            if np.max(np.abs(step)) <= 1e-10 * max(1.0, np.max(np.abs(w))):
                return w
        return None


def profile_intervals(problem: Problem, theta_hat, R_hat, std=None, level: float = 0.95, names=None,
                      rtol: float = 1e-6, settings: SolverSettings | None = None) -> dict:
    """Profile-likelihood intervals of the parameters of a problem at its ML estimate.

    Parameters
    ----------
    problem : Problem
        A static or dynamic problem (full-mode stage 2).
    theta_hat : array_like, shape (n_parameters,)
        The ML estimate (physical units).
    R_hat : array_like
        R at the estimate (the problem's noise model's form).
    std : array_like, shape (n_parameters,), optional
        Standard deviations: the first step from the estimate is ``sqrt(chi2_p(1))`` of them
        (default 1 % of the parameter's magnitude).
    level : float
        Confidence level, in (0, 1).
    names : sequence of str, optional
        The parameters (default all).
    rtol : float
        Relative tolerance of each end (of the interval's half-width).
    settings : SolverSettings, optional

    Returns
    -------
    dict of str to ProfileInterval
    """
    from scipy.optimize import brentq
    from scipy.stats import chi2

    if not 0.0 < float(level) < 1.0:
        raise OptionError(f"the confidence level must lie in (0, 1), got {level!r}")
    model = problem.model
    theta_hat = _checked_estimate(problem, theta_hat)
    R_hat = _checked_noise(problem, R_hat)
    names = list(model.parameter_names if names is None else names)
    fixed = [n for n in names if n in problem.held]
    if fixed:
        raise OptionError(f"{fixed} are held fixed in this problem (at {[problem.held[n] for n in fixed]}): a fixed "
                          "parameter has no interval; leave it out of names")
    unknown = [n for n in names if n not in model.parameter_names]
    if unknown:
        raise OptionError(f"no parameter {unknown} in {model.name} (its parameters: {list(model.parameter_names)})")
    settings = settings or SolverSettings()
    profile = _Profile(problem, theta_hat, R_hat, settings)
    q = float(chi2.ppf(level, 1))
    std = np.asarray(std, dtype=float) if std is not None else 0.01 * np.maximum(np.abs(theta_hat), 1e-8)
    out = {}
    for name in names:
        i = list(model.parameter_names).index(name)
        warm: dict = {}
        first = np.sqrt(q) * (std[i] if np.isfinite(std[i]) and std[i] > 0 else 0.01 * max(abs(theta_hat[i]), 1e-8))
        ends, at_bound = [], []
        for direction, bound in ((-1.0, model.lower_bounds[i]), (1.0, model.upper_bounds[i])):
            inside, far = float(theta_hat[i]), float(theta_hat[i] + direction * first)
            reached = False
            for _ in range(60):
                far = max(far, bound) if direction < 0 else min(far, bound)
                if profile.deviance(i, far, warm) >= q:
                    break
                if far == bound:
                    reached = True
                    break
                inside, far = far, far + direction * 2 * abs(far - inside)
            if reached:
                ends.append(float(bound))
                at_bound.append(True)
                continue
            scale = max(abs(far - theta_hat[i]), 1e-300)
            ends.append(float(brentq(lambda v: profile.deviance(i, v, warm) - q, inside, far, xtol=rtol * scale,
                                     rtol=4 * np.finfo(float).eps)))
            at_bound.append(False)
        out[name] = ProfileInterval(name, float(theta_hat[i]), ends[0], ends[1], tuple(at_bound), float(level),
                                    profile.solves)
        profile.solves = 0
    return out


def _checked_estimate(problem: Problem, theta_hat) -> np.ndarray:
    """The estimate as the problem's parameter vector, finite, of the problem's model."""
    model = problem.model
    names = getattr(theta_hat, "parameter_names", None)
    if names is not None and tuple(names) != tuple(model.parameter_names):
        raise OptionError(f"the estimate is of parameters {list(names)}, the problem's model {model.name} has "
                          f"{list(model.parameter_names)}: give the estimate of this problem")
    try:
        theta = np.asarray(problem.vector(getattr(theta_hat, "theta", theta_hat)), dtype=float)
    except (ValueError, TypeError) as err:
        raise OptionError(f"theta_hat is not an estimate of {model.name}'s parameters {list(model.parameter_names)} "
                          f"({err})") from None
    if not np.all(np.isfinite(theta)):
        raise OptionError(f"theta_hat must be finite, got {theta.tolist()}: profile intervals start at an estimate")
    return theta


def _checked_noise(problem: Problem, R_hat) -> np.ndarray:
    """R at the estimate: positive variances (or a positive definite full R)."""
    R = np.asarray(R_hat, dtype=float)
    if R.ndim == 2:
        return noise_covariance(R, problem.model.output_names, "R_hat")
    return noise_variances(R, problem.model.output_names, "R_hat")


def with_profile_intervals(estimate, problem: Problem, level: float = 0.95, names=None, rtol: float = 1e-6,
                           settings: SolverSettings | None = None, sweep_sets: bool = True):
    """The estimate with the profile-likelihood intervals of its parameters attached and, from its
    stage-1 landscape, the likelihood-ratio sets of the swept parameters (its report shows those
    that differ from the std's or come in pieces; its file keeps them).

    Parameters
    ----------
    estimate : Estimate
        ``casest.estimate(problem)``'s result.
    problem : Problem
        The problem it estimates.
    level, names, rtol, settings
        As :func:`profile_intervals` takes them.
    sweep_sets : bool
        Also the sweep's likelihood-ratio sets (when the estimate has its landscape and the
        problem's noise allows them: R unknown and diagonal, or known), refined to ``rtol`` of
        each parameter's box.

    Returns
    -------
    Estimate
    """
    from .sweep.confidence import confidence_sets

    found = profile_intervals(problem, estimate.theta, estimate.R, estimate.std, level, names, rtol, settings)
    sets = ()
    known = problem.stage1_inputs()[2]
    landscape = estimate.landscape
    if sweep_sets and landscape is not None and landscape.nonlinear and (known or problem.noise.profiled_per_channel):
        model = problem.model
        spans = [model.parameters[model.parameter_names.index(n)] for n in landscape.nonlinear]
        tol = rtol * min((p.ub - p.lb) if np.isfinite(p.ub - p.lb) else max(abs(p.nominal), 1.0) for p in spans)
        lr = confidence_sets(problem, level=level, landscape=landscape, tol=tol)
        sets = tuple(lr.parameters.values())
    return replace(estimate, intervals=tuple(found.values()), likelihood_sets=sets)
