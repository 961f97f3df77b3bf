"""Experiment design: which manoeuvres to fly, and which inputs to apply, before flying.

The information an experiment carries about the parameters (:mod:`casest.information`)
depends on the signals, which the engineer chooses, and on the parameters themselves, which
are only guessed before the flight. Two designs, each one IPOPT problem:

- :func:`design_experiment`: how often to fly each candidate manoeuvre (wind circles at
  several bank angles, a pushover-pullup, multisines, doublets, ...) under a flight-time
  budget; the information is additive over manoeuvres, so the problem is convex in the
  repetitions for the D, A, c and E criteria (an approximate design, Pukelsheim 1993),
  rounded to whole repetitions afterwards.
- :func:`design_inputs`: the input time histories of a dynamic model (or the signals of a
  static one) within bounds and rate limits, with the exact derivatives of the criterion
  with respect to the inputs.

Both take several parameter guesses: the design then optimises the average criterion or
the worst one over the guesses (robust design).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import casadi as ca
import numpy as np

from ..data.dataset import Dataset
from ..models import Model, OptionError
from ..models.dynamic import DynamicModel
from .information import cholesky_lower, information_function, information_matrix, ldl_pivots, lower_triangular_inverse


__all__ = ["ExperimentDesign", "design_experiment", "InputDesign", "design_inputs"]

_ROBUST = ("average", "worst")


def _guesses(model, theta) -> list[np.ndarray]:
    """One or several parameter guesses as physical vectors."""
    if isinstance(theta, Mapping) or np.ndim(theta) == 1 and not isinstance(theta[0], (Mapping, list, tuple, np.ndarray)):
        return [model.vector(theta)]
    guesses = [model.vector(t) for t in theta]
    if not guesses:
        raise OptionError("give at least one parameter guess")
    return guesses


def _check_criterion(criterion: str, robust: str, c, n: int):
    if criterion not in ("D", "A", "E", "c"):
        raise OptionError(f"criterion must be 'D', 'A', 'E' or 'c', got {criterion!r}")
    if robust not in _ROBUST:
        raise OptionError(f"robust must be one of {_ROBUST}, got {robust!r}")
    if criterion == "c":
        if c is None:
            raise OptionError("the c criterion needs c, the linear combination c' theta whose variance is minimised")
        c = np.asarray(c, dtype=float).reshape(-1)
        if c.size != n:
            raise OptionError(f"c needs {n} entries (one per parameter), got {c.size}")
    return c


def _criterion_terms(F: ca.SX, criterion: str, c_scaled, t: ca.SX | None):
    """(objective term to minimise, constraints >= 0) of one guess's scaled information F."""
    if criterion == "E":
        n = F.size1()
        return -t, ldl_pivots(F - t * ca.SX.eye(n))
    L = cholesky_lower(F)
    if criterion == "D":
        return -2 * ca.sum1(ca.log(ca.diag(L))), ca.SX(0, 1)
    M = lower_triangular_inverse(L)
    if criterion == "A":
        return ca.sumsqr(M), ca.SX(0, 1)
    return ca.sumsqr(ca.mtimes(M, ca.DM(c_scaled))), ca.SX(0, 1)


def _unidentified(F: np.ndarray, names) -> str:
    """Words for the parameter combination a (near-)singular information leaves undetermined."""
    values, vectors = np.linalg.eigh(F)
    v = vectors[:, 0]
    top = np.argsort(-np.abs(v))[:3]
    combo = " + ".join(f"{v[i]:.2f} {names[i]}" for i in top if abs(v[i]) > 0.05)
    return f"{combo} (smallest eigenvalue {values[0]:.3g}, largest {values[-1]:.3g})"


@dataclass
class ExperimentDesign:
    """The result of :func:`design_experiment`.

    Attributes
    ----------
    names : list of str
        The candidate manoeuvres.
    repeats : ndarray, shape (n_candidates,)
        The optimal (continuous) number of times each candidate is flown.
    rounded : ndarray of int, shape (n_candidates,)
        Whole repetitions within the budget (:attr:`repeats` rounded, then the remaining
        time given greedily to the candidate that improves the criterion most).
    durations : ndarray, shape (n_candidates,)
        Each candidate's duration (the budget's unit, e.g. s).
    budget : float
    criterion, robust : str
    value : float
        The optimised criterion of the continuous design, in the parameters' scales
        (``theta / model.scales``): D ``-ln det``, A the covariance's trace, E the smallest
        eigenvalue of the information, c the variance of ``c' theta``; averaged or worst
        over the guesses.
    covariance : list of ndarray, each (n_parameters, n_parameters)
        Predicted covariance of the estimates under the rounded design, at each guess.
    std : ndarray, shape (n_parameters,)
        Predicted standard deviations at the first guess (rounded design).
    success : bool
    status : str
    notes : list of str
    parameter_names : tuple of str
    seconds : float
    """

    names: list
    repeats: np.ndarray
    rounded: np.ndarray
    durations: np.ndarray
    budget: float
    criterion: str
    robust: str
    value: float
    covariance: list
    std: np.ndarray
    success: bool
    status: str
    parameter_names: tuple
    notes: list = field(default_factory=list)
    seconds: float = 0.0

    def schedule(self) -> dict:
        """Candidate name -> whole repetitions, for the candidates flown at least once."""
        return {n: int(k) for n, k in zip(self.names, self.rounded) if k > 0}

    def report(self) -> str:
        """A table of the design: repetitions, time used and the predicted std."""
        lines = [f"Experiment design ({self.criterion}-optimal, {self.robust} over guesses): "
                 f"{'success' if self.success else 'FAILED: ' + self.status}",
                 f"{'candidate':<24} {'optimal':>8} {'flown':>6} {'time':>8}"]
        for n, r, k, d in zip(self.names, self.repeats, self.rounded, self.durations):
            lines.append(f"{n:<24} {r:8.2f} {int(k):6d} {k * d:8.1f}")
        lines.append(f"time used {float(self.rounded @ self.durations):.1f} of {self.budget:g}")
        lines.append("predicted std at the first guess:")
        lines += [f"  {p:<14} {s:.4g}" for p, s in zip(self.parameter_names, self.std)]
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines)


def design_experiment(model: Model | DynamicModel, candidates: Mapping[str, Dataset], theta, R, budget: float,
                      durations: Mapping[str, float] | None = None, criterion: str = "D", c=None,
                      robust: str = "average", prior_information=None, max_repeats: float | None = None,
                      ipopt_options: dict | None = None) -> ExperimentDesign:
    """Choose how often to fly each candidate manoeuvre, for the most precise estimates.

    Parameters
    ----------
    model : Model or DynamicModel
    candidates : mapping of name to Dataset
        Each candidate manoeuvre's signals (noise-free simulated, or recorded; the outputs
        are not used).
    theta : mapping or array_like, or a sequence of them
        Parameter guess(es), physical units. Several guesses: robust design.
    R : array_like, shape (n_outputs,)
        Noise variances of the outputs (output units squared); or a full covariance.
    budget : float
        Total time available (same unit as ``durations``).
    durations : mapping of name to float, optional
        Each candidate's duration; default its number of samples (the budget then counts
        samples).
    criterion : {"D", "A", "E", "c"}
        See :mod:`casest.information` (A, E in the parameters' scales).
    c : array_like, shape (n_parameters,)
        For ``criterion="c"``: minimise the variance of ``c' theta``.
    robust : {"average", "worst"}
        With several guesses: optimise the average criterion or the worst one.
    prior_information : ndarray, shape (n_parameters, n_parameters), optional
        Information already available (e.g. from an earlier flight), added to every design.
    max_repeats : float, optional
        Upper bound on each candidate's repetitions.

    Returns
    -------
    ExperimentDesign

    Raises
    ------
    OptionError
        Unknown criterion, no candidate, a budget too small for any candidate, or candidates
        that together leave some parameter combination unidentified (the error names it).
    """
    t0 = time.perf_counter()
    names = list(candidates)
    if not names:
        raise OptionError("no candidate manoeuvre given")
    n = model.n_parameters
    c = _check_criterion(criterion, robust, c, n)
    guesses = _guesses(model, theta)
    if durations is not None and set(durations) != set(names):
        raise OptionError(f"durations must name every candidate: missing {sorted(set(names) - set(durations))}")
    d = np.array([float(durations[k]) if durations is not None else float(candidates[k].n_samples) for k in names])
    if np.any(d <= 0):
        raise OptionError("every candidate needs a positive duration")
    if budget < d.min():
        raise OptionError(f"the budget {budget:g} is shorter than the shortest candidate ({d.min():g})")
    S = np.diag(model.scales)
    P = np.zeros((n, n)) if prior_information is None else np.asarray(prior_information, dtype=float)
    # per guess and candidate: the information of one repetition, in scaled parameters
    info = [[S @ information_matrix(model, candidates[k], g, R) @ S for k in names] for g in guesses]
    P_s = S @ P @ S
    lam0 = np.full(len(names), budget / d.sum())
    for g, per in zip(guesses, info):
        F0 = P_s + sum(l * Fk for l, Fk in zip(lam0, per))
        if np.linalg.eigvalsh(F0)[0] <= 1e-12 * max(np.abs(F0).max(), 1e-300):
            raise OptionError("all the candidates together leave a parameter combination unidentified at guess "
                              f"{dict(zip(model.parameter_names, np.round(g, 6)))}: "
                              f"{_unidentified(F0, model.parameter_names)}. Add a manoeuvre that excites it, "
                              "fix a parameter (Model.with_fixed), or give prior_information")
    lam = ca.SX.sym("repeats", len(names))
    n_g = len(guesses)
    t = ca.SX.sym("t", n_g) if criterion == "E" else None
    c_scaled = None if c is None else model.scales * c
    terms, cons = [], []
    for k, per in enumerate(info):
        F = ca.DM(P_s) + sum((lam[m] * ca.DM(Fk) for m, Fk in enumerate(per)), ca.SX.zeros(n, n))
        term, g_k = _criterion_terms(F, criterion, c_scaled, None if t is None else t[k])
        terms.append(term)
        cons.append(g_k)
    # normalise by the uniform design's value, so that IPOPT sees numbers of order one
    start_terms = ca.Function("terms", [lam] + ([t] if t is not None else []), terms)
    x_extra, x0_extra, lb_extra, ub_extra = [], [], [], []
    if criterion == "E":
        t_start = [0.5 * np.linalg.eigvalsh(P_s + sum(l * Fk for l, Fk in zip(lam0, per)))[0] for per in info]
        x_extra, x0_extra = [t], t_start
        lb_extra, ub_extra = [0.0] * n_g, [np.inf] * n_g
        norm = max(abs(np.mean(t_start)), 1e-300)
    else:
        values = np.array([float(v) for v in start_terms(lam0)]) if n_g > 1 else np.array([float(start_terms(lam0))])
        norm = max(np.abs(values).max(), 1e-300) if criterion != "D" else 1.0
    if robust == "worst" and n_g > 1:
        tau = ca.SX.sym("tau")
        objective = tau
        cons += [tau - term / norm for term in terms]
        x_extra.append(tau)
        if criterion == "E":
            x0_extra += [-np.min(x0_extra) / norm]
        else:
            x0_extra += [float(np.max(values)) / norm]
        lb_extra.append(-np.inf)
        ub_extra.append(np.inf)
    else:
        objective = sum(terms, ca.SX(0)) / (n_g * norm)
    g = ca.vertcat(d.reshape(1, -1) @ lam, *cons)
    x = ca.vertcat(lam, *x_extra)
    n_budget = 1
    lbg = np.concatenate([[-np.inf], np.zeros(g.numel() - n_budget)])
    ubg = np.concatenate([[budget], np.full(g.numel() - n_budget, np.inf)])
    upper = np.full(len(names), np.inf if max_repeats is None else float(max_repeats))
    options = {"print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.tol": 1e-10}
    options.update(ipopt_options or {})
    solver = ca.nlpsol("design_allocation", "ipopt", {"x": x, "f": objective, "g": g}, options)
    lam_start = np.minimum(lam0, upper)
    sol = solver(x0=np.concatenate([lam_start, x0_extra]), lbx=np.concatenate([np.zeros(len(names)), lb_extra]),
                 ubx=np.concatenate([upper, ub_extra]), lbg=lbg, ubg=ubg)
    stats = solver.stats()
    repeats = np.maximum(np.asarray(sol["x"]).reshape(-1)[:len(names)], 0.0)
    notes = []

    def criterion_value(lams: np.ndarray) -> float:
        vals = []
        for per in info:
            F = P_s + sum(l * Fk for l, Fk in zip(lams, per))
            w = np.linalg.eigvalsh(F)
            if w[0] <= 0:
                return np.inf
            Finv = np.linalg.inv(F)
            vals.append({"D": -np.sum(np.log(w)), "A": np.trace(Finv), "E": -w[0],
                         "c": float(c_scaled @ Finv @ c_scaled) if c_scaled is not None else 0.0}[criterion])
        return float(np.max(vals) if robust == "worst" else np.mean(vals))

    rounded = _round_design(repeats, d, budget, upper, criterion_value)
    covs = []
    for per in info:
        F = P_s + sum(k * Fk for k, Fk in zip(rounded, per))
        try:
            covs.append(S @ np.linalg.inv(F) @ S)
        except np.linalg.LinAlgError:
            covs.append(np.full((n, n), np.nan))
    if not np.all(np.isfinite(covs[0])) or np.linalg.eigvalsh(covs[0])[0] <= 0:
        notes.append("the rounded design leaves some parameter combination unidentified: give a larger budget")
    success = bool(stats.get("success", False))
    if not success:
        notes.append(f"IPOPT stopped with {stats.get('return_status')}: the design is not optimal")
    value = criterion_value(repeats)
    if criterion in ("E",):
        value = -value
    return ExperimentDesign(names, repeats, rounded, d, float(budget), criterion, robust, value, covs,
                            np.sqrt(np.abs(np.diag(covs[0]))), success, str(stats.get("return_status")),
                            tuple(model.parameter_names), notes, time.perf_counter() - t0)


def _round_design(repeats: np.ndarray, durations: np.ndarray, budget: float, upper: np.ndarray, value) -> np.ndarray:
    """Whole repetitions within the budget: the continuous design rounded down, then the time
    left given, one repetition at a time, to the candidate that lowers the criterion most."""
    rounded = np.floor(repeats + 1e-9).astype(int)
    while True:
        left = budget - rounded @ durations
        best, best_value = None, value(rounded) if np.any(rounded) else np.inf
        for m in range(len(repeats)):
            if durations[m] <= left + 1e-9 and rounded[m] + 1 <= upper[m]:
                trial = rounded.copy()
                trial[m] += 1
                v = value(trial)
                if v < best_value:
                    best, best_value = m, v
        if best is None:
            return rounded
        rounded[best] += 1


@dataclass
class InputDesign:
    """The result of :func:`design_inputs`.

    Attributes
    ----------
    data : Dataset
        The experiment with the designed inputs (or signals).
    inputs : ndarray, shape (N, n_free)
        The designed time histories of the free inputs.
    value, start_value : float
        The criterion (average or worst over the guesses; as minimised, in the parameters'
        scales: D ``-ln det``, A the covariance's trace, c the variance) of the designed and
        of the starting inputs.
    covariance : list of ndarray
        Predicted covariance at each guess (designed inputs).
    std : ndarray, shape (n_parameters,)
        Predicted std at the first guess.
    success : bool
    status : str
    notes : list of str
    """

    data: Dataset
    inputs: np.ndarray
    value: float
    start_value: float
    covariance: list
    std: np.ndarray
    success: bool
    status: str
    notes: list = field(default_factory=list)


def design_inputs(model: Model | DynamicModel, data: Dataset, free: Sequence[str], theta, R,
                  lower: Mapping[str, float], upper: Mapping[str, float], max_rate: Mapping[str, float] | None = None,
                  criterion: str = "D", c=None, robust: str = "average", max_iter: int = 200,
                  ipopt_options: dict | None = None) -> InputDesign:
    """Optimise the time histories of the inputs the engineer controls.

    Parameters
    ----------
    model : Model or DynamicModel
    data : Dataset
        The experiment to start from: its times (dynamic model) and every signal; the free
        ones are the start of the design, the others stay as they are.
    free : sequence of str
        The inputs (dynamic model) or signals (static model) to design.
    theta, R, criterion, c, robust
        As in :func:`design_experiment`.
    lower, upper : mapping of name to float
        Bounds of each free input (its unit).
    max_rate : mapping of name to float, optional
        Rate limits: a dynamic model's in input units per second (from the time column);
        a static model's per sample.
    max_iter : int
        IPOPT iterations (limited-memory Hessian).

    Returns
    -------
    InputDesign
    """
    n = model.n_parameters
    c = _check_criterion(criterion, robust, c, n)
    if criterion == "E":
        raise OptionError("design_inputs offers D, A and c (E has no second derivative); use design_experiment "
                          "for E-optimal allocations")
    guesses = _guesses(model, theta)
    dynamic = isinstance(model, DynamicModel)
    names = [s.name for s in model.inputs] if dynamic else list(model.signal_names)
    unknown = [f for f in free if f not in names]
    if unknown:
        raise OptionError(f"unknown {'inputs' if dynamic else 'signals'} {unknown}; the model's are {names}")
    missing = [f for f in free if f not in lower or f not in upper]
    if missing:
        raise OptionError(f"give lower and upper bounds for {missing}")
    N = data.n_samples
    rows = [names.index(f) for f in free]
    if dynamic:
        base = data.signals[:, 1:].T.copy()  # inputs x N
        times = data.signals[:, 0]
    else:
        base = data.signals.T.copy()
        times = np.arange(N, dtype=float)
    start = base[rows].copy()
    lo = np.array([lower[f] for f in free])[:, None] * np.ones((1, N))
    hi = np.array([upper[f] for f in free])[:, None] * np.ones((1, N))
    outside = [f for f, s, a, b in zip(free, start, lo, hi) if np.any(s < a[0] - 1e-12) or np.any(s > b[0] + 1e-12)]
    if outside:
        raise OptionError(f"the starting {outside} leave their bounds: start from inputs inside them")
    info = information_function(model, N, np.ndim(R) == 2)
    Rm = np.asarray(R, dtype=float)
    V = ca.MX.sym("free", len(free), N)
    full = ca.MX(ca.DM(base))
    for k, r in enumerate(rows):
        full[r, :] = V[k, :]
    S = np.diag(model.scales)
    terms = []
    for g in guesses:
        args = {"theta": g, "R": Rm}
        if dynamic:
            args.update(t=ca.DM(times).T, inputs=full)
            if model.initial_from_data:
                args["x0_data"] = ca.DM(model.initial_values(data))
        else:
            args.update(signals=full)
        F = info(**args)["F"]
        Fs = ca.mtimes(ca.mtimes(ca.DM(S), F), ca.DM(S))
        Fsym = ca.SX.sym("F", n, n)
        term, _ = _criterion_terms(Fsym, criterion, None if c is None else model.scales * c, None)
        terms.append(ca.Function("term", [Fsym], [term])(Fs))
    start_fn = ca.Function("terms", [V], terms)
    start_values = np.array([float(v) for v in (start_fn(start) if len(terms) > 1 else [start_fn(start)])])
    if not np.all(np.isfinite(start_values)):
        raise OptionError("the starting inputs leave a parameter combination unidentified: start from an input "
                          "that excites every parameter (a doublet or multisine)")
    norm = 1.0 if criterion == "D" else max(np.abs(start_values).max(), 1e-300)
    x_extra, x0_extra = [], []
    cons = []
    if robust == "worst" and len(terms) > 1:
        tau = ca.MX.sym("tau")
        objective = tau
        cons += [tau - term / norm for term in terms]
        x_extra, x0_extra = [tau], [float(start_values.max()) / norm]
    else:
        objective = sum(terms) / (len(terms) * norm)
    lbg, ubg = [np.zeros(len(cons))], [np.full(len(cons), np.inf)]
    if max_rate:
        dt = np.diff(times)
        for k, f in enumerate(free):
            if f in max_rate:
                step = V[k, 1:] - V[k, :-1]
                limit = float(max_rate[f]) * dt
                cons.append(step.T)
                lbg.append(-limit)
                ubg.append(limit)
                if np.any(np.abs(np.diff(start[k])) > limit + 1e-9):
                    raise OptionError(f"the starting {f} exceeds its rate limit: start from a smoother input")
    x = ca.vertcat(ca.vec(V), *x_extra)
    g = ca.vertcat(*cons) if cons else ca.MX(0, 1)
    options = {"print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.max_iter": int(max_iter),
               "ipopt.hessian_approximation": "limited-memory", "ipopt.tol": 1e-8}
    options.update(ipopt_options or {})
    solver = ca.nlpsol("design_inputs", "ipopt", {"x": x, "f": objective, "g": g}, options)
    lbx = np.concatenate([lo.reshape(-1, order="F"), [-np.inf] * len(x_extra)])
    ubx = np.concatenate([hi.reshape(-1, order="F"), [np.inf] * len(x_extra)])
    sol = solver(x0=np.concatenate([start.reshape(-1, order="F"), x0_extra]), lbx=lbx, ubx=ubx,
                 lbg=np.concatenate(lbg), ubg=np.concatenate(ubg))
    stats = solver.stats()
    designed = np.asarray(sol["x"]).reshape(-1)[:len(free) * N].reshape(len(free), N, order="F")
    designed = np.clip(designed, lo, hi)
    values = np.array([float(v) for v in (start_fn(designed) if len(terms) > 1 else [start_fn(designed)])])
    columns = {name: data.signals[:, j].copy() for j, name in enumerate(model.signal_names)}
    for k, f in enumerate(free):
        columns[f] = designed[k]
    for j, o in enumerate(model.output_names):
        columns[o] = data.outputs[:, j]
    columns.update(data.extra)
    new = Dataset(model, columns, extra=list(data.extra), missing="allow")
    covs = [np.linalg.inv(information_matrix(model, new, g_, R)) for g_ in guesses]
    notes = []
    success = bool(stats.get("success", False))
    if not success:
        notes.append(f"IPOPT stopped with {stats.get('return_status')}: the inputs are improved, not optimal")
    combine = np.max if robust == "worst" else np.mean
    return InputDesign(new, designed.T, float(combine(values)), float(combine(start_values)), covs,
                       np.sqrt(np.diag(covs[0])), success, str(stats.get("return_status")), notes)
