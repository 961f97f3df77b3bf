"""Likelihood-ratio confidence sets for xi2 straight from the stage-1 sweep.

At every candidate xi2 the sweep holds R(xi2) with xi1 and R at their optimum, so the profile
ML cost ``J(xi2) = sum_j N_j/2 ln R_j(xi2)`` (paper Eq. 6, 19) is known there (with R known,
the cost ``sum_j N_j/2 R_j`` of the weighted residuals); its deviance
``D(xi2) = 2 (J(xi2) - J_min)`` is asymptotically chi-square. The joint set of level ``p`` holds
the candidates with ``D < chi2_p(n2)``; the interval of one parameter is the projection of the
candidates with ``D < chi2_p(1)`` on its axis (the set of values where the profile over the
other xi2 is below the threshold), split where the candidates inside are separated by a gap
wider than the design's spacing: several intervals where the set is not connected.

Resolution: with one swept parameter the profile is the sweep itself, and an endpoint taken
from the candidates lies within one design spacing of the threshold crossing (the spacing at
the endpoint). With several, the candidates sample the profile over the other parameters too,
and only from above (the set they give lies inside the true one by an amount the design does
not bound): their resolution is not stated (NaN) until :func:`refine_intervals` moves every
endpoint to the threshold crossing of the profile deviance (the stage-1 least squares at that
value, minimised over the other swept parameters, warm-started from the nearest value already
profiled) by Brent's method, with its tolerance as resolution.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ...errors import OptionError
from ...estimation.intervals import ParameterInterval
from .analysis import profile_cost

__all__ = ["ParameterInterval", "LikelihoodRatioSet", "likelihood_ratio_set", "refine_intervals", "confidence_sets",
           "sweep_cost"]


@dataclass
class LikelihoodRatioSet:
    """Likelihood-ratio confidence sets of the swept parameters at one level.

    Attributes
    ----------
    level : float
    deviance : ndarray, shape (M,)
        ``2 (J(xi2) - J_min)`` per candidate (inf where there is no fit).
    inside : ndarray of bool, shape (M,)
        The joint set: ``deviance < chi2_level(n2)``.
    threshold_joint, threshold_single : float
        ``chi2_level(n2)`` and ``chi2_level(1)``.
    parameters : dict of str to ParameterInterval
    J_min : float
        The profile cost the deviance is measured from.
    """

    level: float
    deviance: np.ndarray
    inside: np.ndarray
    threshold_joint: float
    threshold_single: float
    parameters: dict = field(default_factory=dict)
    J_min: float = np.nan

    def lines(self) -> list:
        """The report's lines: each parameter's intervals with their resolution.

        Returns
        -------
        list of str
        """
        out = [f"likelihood-ratio sets at {100 * self.level:g} % (from the sweep: {int(self.inside.sum())} candidates "
               f"in the joint set)"]
        for p in self.parameters.values():
            parts = [f"[{a:.6g}, {b:.6g}]" for a, b in p.intervals]
            worst = max(max(r) for r in p.resolution) if p.resolution else 0.0
            ends = (f"ends within {worst:.2g}" if np.isfinite(worst) else
                    "ends not resolved by the design: refine them (confidence_sets(..., tol=...))")
            out.append(f"  {p.name}: {' U '.join(parts)} ({ends})")
        return out


def sweep_cost(R: np.ndarray, counts, known_noise: bool = False) -> np.ndarray:
    """The ML cost at each candidate from its R, constants dropped: with R unknown, the profile
    ``sum_j N_j/2 ln R_j``; with R known (the sweep ran on outputs divided by the known std, so its
    R_j are mean squares of weighted residuals), ``sum_j N_j/2 R_j``.

    Parameters
    ----------
    R : ndarray, shape (M, n_outputs)
    counts : array_like, shape (n_outputs,)
        Measured samples per channel.
    known_noise : bool

    Returns
    -------
    ndarray, shape (M,)
    """
    if known_noise:
        return 0.5 * np.sum(np.asarray(counts) * R, axis=-1)
    return profile_cost(R, counts)


def likelihood_ratio_set(landscape, level: float = 0.95, counts=None, J_min: float | None = None,
                         bounds=None, optimum=None, known_noise: bool = False) -> LikelihoodRatioSet:
    """The likelihood-ratio sets of the swept parameters from a landscape.

    Parameters
    ----------
    landscape : Landscape
        A sweep's result (R at every candidate).
    level : float
        Confidence level, in (0, 1).
    counts : array_like, shape (n_outputs,), optional
        Measured samples per channel (default N each; give ``data.observed_counts()`` with
        missing outputs).
    J_min : float, optional
        The profile cost to measure from (default the smallest over the candidates; give stage
        2's optimum when it is lower).
    bounds : sequence of (float, float), optional
        The swept parameters' bounds (to flag intervals that reach them).
    optimum : array_like, shape (n2,), optional
        The xi2 where ``J_min`` is reached, if it is not a candidate: it belongs to every
        parameter's set (a sparse design may have no candidate below the threshold).
    known_noise : bool
        The sweep ran with R known (outputs weighted by it): the cost difference, not the
        profile over R (:func:`sweep_cost`).

    Returns
    -------
    LikelihoodRatioSet
    """
    from scipy.stats import chi2

    if not 0.0 < float(level) < 1.0:
        raise OptionError(f"the confidence level must lie in (0, 1), got {level!r}")
    cands = np.asarray(landscape.candidates, dtype=float)
    n2 = cands.shape[1]
    if n2 == 0:
        raise OptionError("no parameter was swept: a landscape of a linear problem has no xi2 to bound")
    counts = np.full(landscape.R.shape[1], landscape.n_samples) if counts is None else np.asarray(counts, dtype=float)
    fitted = np.isfinite(landscape.ranking) & np.all(np.isfinite(landscape.R), axis=1)
    J = np.where(fitted, sweep_cost(np.where(fitted[:, None], landscape.R, 1.0), counts, known_noise), np.inf)
    J_min = float(np.min(J)) if J_min is None else min(float(J_min), float(np.min(J)))
    deviance = 2.0 * (J - J_min)
    joint, single = float(chi2.ppf(level, n2)), float(chi2.ppf(level, 1))
    out = LikelihoodRatioSet(level=float(level), deviance=deviance, inside=deviance < joint, threshold_joint=joint,
                             threshold_single=single, J_min=J_min)
    spacing = _axis_spacing(cands, landscape.grid_shape)
    if n2 > 1:  # the profile over the other parameters is sampled from above: no stated bound
        spacing = np.full_like(spacing, np.nan)
    points, below = cands, deviance < single
    if optimum is not None:  # the optimum is in every set; its spacing is not the design's
        points = np.vstack([cands, np.asarray(optimum, dtype=float).reshape(1, n2)])
        below = np.concatenate([below, [True]])
        spacing = np.hstack([spacing, np.full((n2, 1), np.nan)])
    for i, name in enumerate(landscape.nonlinear):
        lo, hi = (bounds[i] if bounds is not None else (-np.inf, np.inf))
        out.parameters[name] = replace(_intervals(name, points[:, i], below, spacing[i], lo, hi), level=float(level))
    return out


def _axis_spacing(cands: np.ndarray, grid_shape) -> np.ndarray:
    """Per candidate and axis, the design's spacing there: a grid's step between neighbouring
    values; a scattered design's, the axis range over M^(1/n2) scaled by the local density."""
    M, n2 = cands.shape
    spacing = np.empty((n2, M))
    for i in range(n2):
        values = np.unique(cands[:, i])
        if grid_shape is not None and len(values) > 1:
            steps = np.diff(values)
            left = np.concatenate([[steps[0]], steps])
            right = np.concatenate([steps, [steps[-1]]])
            where = np.searchsorted(values, cands[:, i])
            spacing[i] = np.maximum(left[where], right[where])
        else:
            # the M^(1/n2) values a scattered design puts along an axis, at the local density
            order = np.sort(cands[:, i])
            per_axis = max(M ** (1.0 / n2), 2.0)
            rank = np.searchsorted(order, cands[:, i])
            window = max(1, int(M / per_axis))
            a = order[np.clip(rank - window, 0, M - 1)]
            b = order[np.clip(rank + window, 0, M - 1)]
            spacing[i] = np.maximum(b - a, 1e-300) / 2.0
    return spacing


def _intervals(name: str, values: np.ndarray, inside: np.ndarray, spacing: np.ndarray, lo: float, hi: float
               ) -> ParameterInterval:
    """The projection of the candidates inside on one axis, split at gaps wider than the spacing."""
    if not inside.any():
        return ParameterInterval(name, (), (), ())
    order = np.argsort(values[inside], kind="stable")
    v, s = values[inside][order], spacing[inside][order]
    # a gap between two inside values wider than both spacings there holds candidates outside
    outside_values = np.sort(values[~inside])
    cuts = []
    for k in range(len(v) - 1):
        a, b = v[k], v[k + 1]
        between = np.searchsorted(outside_values, b, side="left") - np.searchsorted(outside_values, a, side="right")
        if between > 0 and not b - a <= 1.5 * max(s[k], s[k + 1]):  # NaN spacing: any gap with candidates outside
            cuts.append(k + 1)
    pieces = np.split(np.arange(len(v)), cuts)
    intervals = tuple((float(v[p[0]]), float(v[p[-1]])) for p in pieces)
    resolution = tuple((float(s[p[0]]), float(s[p[-1]])) for p in pieces)
    at_bound = tuple((bool(np.isclose(a, lo)), bool(np.isclose(b, hi))) for a, b in intervals)
    return ParameterInterval(name, intervals, resolution, at_bound)


def refine_intervals(lr_set: LikelihoodRatioSet, deviance_at, names, bounds, tol: float,
                     max_bisections: int = 60) -> LikelihoodRatioSet:
    """Move every endpoint of the per-parameter intervals to the threshold crossing (bracketed
    outward from the sweep's end, then Brent's method).

    Parameters
    ----------
    lr_set : LikelihoodRatioSet
    deviance_at : callable
        ``(i, value) -> D``: the profile deviance with swept parameter ``i`` held at ``value``
        (minimised over the other swept parameters).
    names : sequence of str
        The swept parameters, in order.
    bounds : sequence of (float, float)
    tol : float
        Largest bracket (physical units) an endpoint is left with.
    max_bisections : int
        Limit of the outward steps and of Brent's iterations.

    Returns
    -------
    LikelihoodRatioSet
        The same sets with refined endpoints and their brackets as resolution.
    """
    q = lr_set.threshold_single
    refined = {}
    for i, name in enumerate(names):
        p = lr_set.parameters[name]
        lo_bound, hi_bound = bounds[i]
        intervals, resolution, at_bound = [], [], []
        for (a, b), (ra, rb) in zip(p.intervals, p.resolution):
            at_i = lambda v, i=i: deviance_at(i, v)  # noqa: E731
            # the first step outward: the design's spacing there, else a twentieth of the interval
            first = 0.05 * max(b - a, 1e-9 * max(abs(a), abs(b), 1.0))
            step_a, step_b = (ra if np.isfinite(ra) else first), (rb if np.isfinite(rb) else first)
            new_a, bracket_a = _crossing(at_i, a, -max(step_a, tol), lo_bound, q, tol, max_bisections)
            new_b, bracket_b = _crossing(at_i, b, max(step_b, tol), hi_bound, q, tol, max_bisections)
            intervals.append((new_a, new_b))
            resolution.append((bracket_a, bracket_b))
            at_bound.append((bool(np.isclose(new_a, lo_bound)), bool(np.isclose(new_b, hi_bound))))
        intervals, resolution, at_bound = _merge_connected(lambda v, i=i: deviance_at(i, v), intervals, resolution,
                                                           at_bound, q)
        refined[name] = ParameterInterval(name, tuple(intervals), tuple(resolution), tuple(at_bound), lr_set.level)
    return LikelihoodRatioSet(level=lr_set.level, deviance=lr_set.deviance, inside=lr_set.inside,
                              threshold_joint=lr_set.threshold_joint, threshold_single=q, parameters=refined,
                              J_min=lr_set.J_min)


def _merge_connected(deviance, intervals: list, resolution: list, at_bound: list, q: float) -> tuple:
    """Join consecutive intervals whose gap is not a real one: they overlap once refined, or the
    profile deviance dips below ``q`` inside the gap (a coarse design can miss a thin, slanted
    part of the set in its projection; the gap's minimum is searched by bounded Brent)."""
    from scipy.optimize import minimize_scalar

    if not intervals:
        return intervals, resolution, at_bound
    out_i, out_r, out_b = [intervals[0]], [resolution[0]], [at_bound[0]]
    for (a, b), r, flags in zip(intervals[1:], resolution[1:], at_bound[1:]):
        prev_a, prev_b = out_i[-1]
        joined = a <= prev_b
        if not joined:
            dip = minimize_scalar(deviance, bounds=(prev_b, a), method="bounded",
                                  options={"xatol": 1e-6 * (a - prev_b)})
            joined = bool(dip.fun < q)
        if joined:
            out_i[-1] = (prev_a, max(prev_b, b))
            out_r[-1] = (out_r[-1][0], r[1])
            out_b[-1] = (out_b[-1][0], flags[1])
        else:
            out_i.append((a, b))
            out_r.append(r)
            out_b.append(flags)
    return out_i, out_r, out_b


def _crossing(deviance, inside: float, step: float, bound: float, q: float, tol: float, max_bisections: int) -> tuple:
    """The threshold crossing beyond a value inside the set, searched in the direction of ``step``:
    (value, bracket). Steps outward (doubling) until the deviance reaches ``q``; where the set
    reaches ``bound`` first, the bound with bracket 0."""
    a, far = inside, inside + step
    for _ in range(max_bisections):
        far = min(far, bound) if step > 0 else max(far, bound)
        if deviance(far) >= q:
            break
        if far == bound:
            return float(bound), 0.0
        a, step = far, 2 * step
        far = a + step
    from scipy.optimize import brentq

    # Brent's method on the bracket [a inside, far outside]: the bracket it ends with is below tol
    root = brentq(lambda v: deviance(v) - q, a, far, xtol=tol, rtol=4 * np.finfo(float).eps, maxiter=max_bisections)
    return float(root), float(tol)


class _SweepProfile:
    """The profile ML cost of xi2 through the stage-1 least squares (xi1 and R at their optimum),
    and its profile over the other swept parameters with one held, warm-started."""

    def __init__(self, model, partition, data, settings, landscape, known_noise: bool = False):
        from .evaluators import evaluate_candidates
        from .orchestration import candidate_evaluator, linear_parameter_bounds

        self.landscape, self.data, self.known_noise = landscape, data, known_noise
        self.counts = data.observed_counts()
        params = [model.parameters[i] for i in partition.nonlinear_index]
        self.bounds = [(p.lb, p.ub) for p in params]
        self.lows, self.highs = np.array([b[0] for b in self.bounds]), np.array([b[1] for b in self.bounds])
        self.spans = np.where(np.isfinite(self.highs - self.lows), self.highs - self.lows, 1.0)
        # sized like the sweep's (the same compile decision): the refinement calls it thousands of times
        self.evaluator = candidate_evaluator(model, partition, data, settings, max(len(landscape.candidates), 64))
        self.box = linear_parameter_bounds(model, partition)
        self._evaluate = evaluate_candidates
        self.solved: dict = {}  # (parameter, value) -> the other swept parameters at the profile's minimum

    def costs(self, xi2: np.ndarray) -> np.ndarray:
        """The profile cost at each row of ``xi2`` (inf where there is no fit)."""
        _, R, ok = self._evaluate(self.evaluator, self.data.outputs, np.atleast_2d(xi2), *self.box)
        fine = ok & np.all(np.isfinite(R), axis=1)
        return np.where(fine, sweep_cost(np.where(fine[:, None], R, 1.0), self.counts, self.known_noise), np.inf)

    def cost(self, xi2: np.ndarray) -> float:
        return float(self.costs(xi2)[0])

    def minimum(self) -> tuple:
        """``(J, xi2)`` at the profile's minimum between the candidates (from the best one), or
        ``(None, None)`` when the search does not improve on the best candidate."""
        from scipy.optimize import minimize

        best = self.landscape.best_xi2
        found = minimize(self.cost, best, method="L-BFGS-B", bounds=self.bounds)
        if np.isfinite(found.fun) and found.fun < self.cost(best):
            return float(found.fun), found.x
        return None, None

    def held(self, i: int, value: float, deviance: np.ndarray) -> float:
        """The profile cost with parameter ``i`` held at ``value``, minimised over the others
        (L-BFGS-B with central differences in one evaluation), from the nearest value solved."""
        from scipy.optimize import minimize

        n2 = len(self.bounds)
        if n2 == 1:
            return self.cost(np.array([value]))
        others = [j for j in range(n2) if j != i]
        mine = [v for (k, v) in self.solved if k == i]
        if mine:
            start = self.solved[(i, min(mine, key=lambda v: abs(v - value)))]
        else:
            near = np.argsort(np.abs(self.landscape.candidates[:, i] - value))[:20]
            start = self.landscape.candidates[near[np.argmin(deviance[near])], others]

        def with_gradient(rest):
            h = 1e-6 * np.maximum(np.abs(rest), 1e-3 * self.spans[others])
            points = np.tile(rest, (1 + 2 * len(rest), 1))
            for k in range(len(rest)):
                points[1 + 2 * k, k] += h[k]
                points[2 + 2 * k, k] -= h[k]
            xi2 = np.empty((len(points), n2))
            xi2[:, i], xi2[:, others] = value, points
            J = self.costs(np.clip(xi2, self.lows, self.highs))
            return J[0], (J[1::2] - J[2::2]) / (2 * h)

        found = minimize(with_gradient, start, jac=True, method="L-BFGS-B", bounds=[self.bounds[j] for j in others])
        at_start = with_gradient(np.asarray(start, dtype=float))[0]
        self.solved[(i, float(value))] = np.asarray(found.x if found.fun <= at_start else start, dtype=float)
        return float(min(found.fun, at_start))


def confidence_sets(model, data=None, level: float = 0.95, landscape=None, tol: float | None = None,
                    settings=None, J_min: float | None = None) -> LikelihoodRatioSet:
    """Likelihood-ratio confidence sets of the swept parameters, from a sweep and refined.

    Parameters
    ----------
    model : Model, DynamicModel or Problem
        As :func:`casest.sweep` takes it; R unknown and diagonal (the sweep's profile over R) or,
        for a Problem, known (the cost difference); a full unknown R is refused.
    data : Dataset, optional
        The sweep's samples (not with a Problem).
    level : float
        Confidence level, in (0, 1).
    landscape : Landscape, optional
        The sweep already run on these data (default: run it with ``settings``).
    tol : float, optional
        Refine every end to the threshold crossing of the profile deviance, to ``tol`` (physical
        units of each parameter); default: the sweep's own sets, unrefined.
    settings : SweepSettings, optional
    J_min : float, optional
        The profile cost to measure from (default: the profile minimised over xi2 from the
        sweep's best candidate, or the sweep's smallest if lower).

    Returns
    -------
    LikelihoodRatioSet
    """
    from ...problem import Problem
    from .orchestration import sweep, sweep_inputs
    from .settings import SweepSettings

    known_noise = isinstance(model, Problem) and model.stage1_inputs()[2]  # swept on outputs weighted by R
    if isinstance(model, Problem) and not (known_noise or model.noise.profiled_per_channel):
        raise OptionError(f"likelihood-ratio sets from the sweep need R unknown and diagonal, or known; this problem "
                          f"has {model.describe_noise()}: use profile_intervals, which re-optimises its own cost")
    settings = settings or SweepSettings()
    landscape = landscape if landscape is not None else sweep(model, data, settings=settings)
    model, data, partition, _ = sweep_inputs(model, data, None)
    profile = _SweepProfile(model, partition, data, settings, landscape, known_noise)
    optimum = None
    if J_min is None:  # the profile's minimum between the candidates: the deviance is measured from it
        J_min, optimum = profile.minimum()
    lr = likelihood_ratio_set(landscape, level, profile.counts, J_min, profile.bounds, optimum, known_noise)
    if tol is None:
        return lr
    return refine_intervals(lr, lambda i, v: 2.0 * (profile.held(i, v, lr.deviance) - lr.J_min), landscape.nonlinear,
                            profile.bounds, float(tol))
