"""Experiment design: how often to fly each candidate manoeuvre under a time budget.

The information is additive over manoeuvres, so the problem is convex in the repetitions
for the D, A, c and E criteria (an approximate design, Pukelsheim 1993), rounded to whole
repetitions afterwards. With several parameter guesses the design optimises the average
criterion or the worst one (robust design).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Mapping

import casadi as ca
import numpy as np

from ..backend.ipopt import SolverSettings, run_ipopt
from ..data import Dataset
from ..checks import covariance_argument
from ..errors import DataError, OptionError
from .criteria import check_criterion, check_noise, criterion_terms, parameter_guesses, unidentified_combination
from .information import information_matrix
from ..problem.measurement import measurement_of
from ..options import Criterion, Robust


__all__ = ["ExperimentDesign", "design_experiment"]


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
        """Candidate name -> whole repetitions, for the candidates flown at least once.

        Returns
        -------
        dict of str to int
        """
        return {n: int(k) for n, k in zip(self.names, self.rounded) if k > 0}

    def report(self) -> str:
        """A table of the design: repetitions, time used and the predicted std.

        Returns
        -------
        str
        """
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


def design_experiment(model, candidates: Mapping[str, Dataset], theta, R, budget: float,
                      durations: Mapping[str, float] | None = None, criterion: Criterion = "D", c=None,
                      robust: Robust = "average", prior_information=None, max_repeats: float | None = None,
                      ipopt_options: dict | None = None) -> ExperimentDesign:
    """Choose how often to fly each candidate manoeuvre, for the most precise estimates.

    Parameters
    ----------
    model : Model or DynamicModel
    candidates : mapping of name to Dataset
        Each candidate manoeuvre's signals (simulated or recorded; outputs not used).
    theta : mapping or array_like, or a sequence of them
        Parameter guess(es), physical units. Several guesses: robust design.
    R : array_like, shape (n_outputs,)
        Noise variances of the outputs (output units squared); or a full covariance.
    budget : float
        Total time available (same unit as ``durations``).
    durations : mapping of name to float, optional
        Each candidate's duration; default its number of samples (the budget counts samples).
    criterion : {"D", "A", "E", "c"}
        See :mod:`casest.design.information` (A, E in the parameters' scales).
    c : array_like, shape (n_parameters,)
        For ``criterion="c"``: minimise the variance of ``c' theta``.
    robust : {"average", "worst"}
        With several guesses: optimise the average criterion or the worst one.
    prior_information : ndarray, shape (n_parameters, n_parameters), optional
        Information already available (e.g. from an earlier flight), added to every design.
    max_repeats : float, optional
        Upper bound on each candidate's repetitions.
    ipopt_options : dict, optional
        Options of the IPOPT solve of the continuous allocation.

    Returns
    -------
    ExperimentDesign

    Raises
    ------
    OptionError
        Unknown criterion, no candidate, a budget too small for any candidate, or candidates that
        together leave some parameter combination unidentified (the error names it).

    Examples
    --------
    How often to fly each half of the short-period record (a 3-2-1-1, a doublet; 10 s each) in 60 s:

    >>> import numpy as np, casest
    >>> m = casest.load_model_file("short_period")
    >>> model, rec = m.model(), m.simulate(seed=0)
    >>> halves = {"3-2-1-1": rec.subset(slice(0, 500)), "doublet": rec.subset(slice(500, None))}
    >>> R = np.array([m.NOISE_STD[n] ** 2 for n in model.output_names])
    >>> design = casest.design_experiment(model, halves, m.TRUTH, R, 60.0, {"3-2-1-1": 10.0, "doublet": 10.0})
    >>> list(design.names), design.repeats.shape
    (['3-2-1-1', 'doublet'], (2,))
    """
    t0 = time.perf_counter()
    names = list(candidates)
    if not names:
        raise OptionError("no candidate manoeuvre given")
    c = check_criterion(criterion, robust, c, model.n_parameters)
    _check_candidates(model, candidates, names)
    durations = _durations(candidates, names, durations, budget)
    allocation = _Allocation(model, [candidates[k] for k in names], parameter_guesses(model, theta), R,
                             prior_information, criterion, robust, c)
    allocation.check_identifiable(budget / durations.sum() * np.ones(len(names)))
    if max_repeats is not None and not (np.isfinite(max_repeats) and max_repeats > 0):
        raise OptionError(f"max_repeats must be a positive number (or None: no limit), got {max_repeats!r}")
    upper = np.full(len(names), np.inf if max_repeats is None else float(max_repeats))
    run = _solve_allocation(allocation.nlp(durations, budget, upper), ipopt_options)
    repeats = np.maximum(run.x[:len(names)], 0.0)
    rounded = _round_design(repeats, durations, budget, upper, allocation.criterion_value)
    covariances = allocation.covariances(rounded)
    notes = _design_notes(covariances[0], run)
    value = allocation.criterion_value(repeats)
    return ExperimentDesign(names, repeats, rounded, durations, float(budget), criterion, robust,
                            -value if criterion == "E" else value, covariances,
                            np.sqrt(np.abs(np.diag(covariances[0]))), run.success, run.status,
                            tuple(model.parameter_names), notes, time.perf_counter() - t0)


def _solve_allocation(nlp: dict, ipopt_options: dict | None):
    """IPOPT on the continuous allocation NLP (:meth:`_Allocation.nlp`); the :class:`IpoptRun`."""
    settings = SolverSettings(tol=1e-10, ipopt=ipopt_options)
    solver = ca.nlpsol("design_allocation", "ipopt", {"x": nlp["x"], "f": nlp["f"], "g": nlp["g"]},
                       settings.nlpsol_options())
    return run_ipopt(solver, **{k: nlp[k] for k in ("x0", "lbx", "ubx", "lbg", "ubg")})


def _design_notes(covariance: np.ndarray, run) -> list:
    """What the design's user must know: an unidentified combination after rounding, a failed solve."""
    notes = []
    if not np.all(np.isfinite(covariance)) or np.linalg.eigvalsh(covariance)[0] <= 0:
        notes.append("the rounded design leaves some parameter combination unidentified: give a larger budget")
    if not run.success:
        notes.append(f"IPOPT stopped with {run.status}: the design is not optimal")
    return notes


def _check_candidates(model, candidates: Mapping, names: list) -> None:
    """Each candidate a record of this model (its columns), named in the message where not."""
    for name in names:
        record = candidates[name]
        if not isinstance(record, Dataset):
            raise OptionError(f"candidate {name!r} must be a casest.Dataset of the model's record, got "
                              f"{type(record).__name__}")
        try:
            record.check_model(model)
        except DataError as error:
            raise DataError(f"candidate {name!r} is not a record of model {model.name!r}: {error}") from None


def _durations(candidates: Mapping, names: list, durations, budget: float) -> np.ndarray:
    """Each candidate's duration (default its number of samples), checked against the budget."""
    if durations is not None and set(durations) != set(names):
        raise OptionError(f"durations must name every candidate: missing {sorted(set(names) - set(durations))}")
    if isinstance(budget, bool) or not isinstance(budget, (int, float, np.integer, np.floating)) \
            or not np.isfinite(budget) or budget <= 0:
        raise OptionError(f"the budget must be a positive finite number, got {budget!r}")
    d = np.array([float(durations[k]) if durations is not None else float(candidates[k].n_samples) for k in names])
    if np.any(~np.isfinite(d) | (d <= 0)):
        raise OptionError("every candidate needs a positive finite duration")
    if budget < d.min():
        raise OptionError(f"the budget {budget:g} is shorter than the shortest candidate ({d.min():g})")
    return d


class _Allocation:
    """The information of one repetition of each candidate at each guess, in scaled parameters,
    and the convex program over the repetitions."""

    def __init__(self, model, candidates: list, guesses: list, R, prior_information, criterion: str, robust: str, c):
        n = model.n_parameters
        check_noise(R, model.output_names)
        self.model, self.guesses, self.criterion, self.robust = model, guesses, criterion, robust
        self.S = np.diag(model.scales)
        P = np.zeros((n, n)) if prior_information is None else \
            covariance_argument(prior_information, n, "prior_information")  # n x n, finite, PSD
        self.P_s = self.S @ P @ self.S
        measurement = measurement_of(model)  # one adapter for every candidate and guess
        self.info = [[self.S @ information_matrix(measurement, k, g, R) @ self.S for k in candidates] for g in guesses]
        self.c_scaled = None if c is None else model.scales * c

    def information(self, per_guess: list, repeats) -> np.ndarray:
        return self.P_s + sum(r * Fk for r, Fk in zip(repeats, per_guess))

    def check_identifiable(self, repeats: np.ndarray) -> None:
        """Refuse candidates that together leave a parameter combination unidentified (named)."""
        for g, per in zip(self.guesses, self.info):
            F0 = self.information(per, repeats)
            if np.linalg.eigvalsh(F0)[0] <= 1e-12 * max(np.abs(F0).max(), 1e-300):
                names = self.model.parameter_names
                raise OptionError("all the candidates together leave a parameter combination unidentified at guess "
                                  f"{dict(zip(names, np.round(g, 6)))}: {unidentified_combination(F0, names)}. Add a "
                                  "manoeuvre that excites it, fix a parameter (Model.with_fixed), or give "
                                  "prior_information")

    def criterion_value(self, repeats: np.ndarray) -> float:
        """The criterion (as minimised) of an allocation: average or worst over the guesses."""
        values = []
        for per in self.info:
            F = self.information(per, repeats)
            w = np.linalg.eigvalsh(F)
            if w[0] <= 0:
                return np.inf
            Finv = np.linalg.inv(F)
            values.append({"D": -np.sum(np.log(w)), "A": np.trace(Finv), "E": -w[0],
                           "c": float(self.c_scaled @ Finv @ self.c_scaled) if self.c_scaled is not None else 0.0
                           }[self.criterion])
        return float(np.max(values) if self.robust == "worst" else np.mean(values))

    def covariances(self, repeats) -> list:
        """Predicted covariance (physical units) at each guess."""
        out = []
        for per in self.info:
            try:
                out.append(self.S @ np.linalg.inv(self.information(per, repeats)) @ self.S)
            except np.linalg.LinAlgError:
                out.append(np.full(self.S.shape, np.nan))
        return out

    def nlp(self, durations: np.ndarray, budget: float, upper: np.ndarray) -> dict:
        """The convex program: its symbols, start and bounds (E by the epigraph with LDL pivots;
        worst case by an epigraph variable), normalised so that IPOPT sees numbers of order one."""
        n, n_g, m = self.model.n_parameters, len(self.guesses), len(durations)
        lam = ca.SX.sym("repeats", m)
        lam0 = np.full(m, budget / durations.sum())
        t = ca.SX.sym("t", n_g) if self.criterion == "E" else None
        terms, cons = [], []
        for k, per in enumerate(self.info):
            F = ca.DM(self.P_s) + sum((lam[j] * ca.DM(Fk) for j, Fk in enumerate(per)), ca.SX.zeros(n, n))
            term, g_k = criterion_terms(F, self.criterion, self.c_scaled, None if t is None else t[k])
            terms.append(term)
            cons.append(g_k)
        x_extra, x0_extra, lb_extra, ub_extra = [], [], [], []
        if self.criterion == "E":
            t_start = [0.5 * np.linalg.eigvalsh(self.information(per, lam0))[0] for per in self.info]
            x_extra, x0_extra, lb_extra, ub_extra = [t], list(t_start), [0.0] * n_g, [np.inf] * n_g
            norm, start_values = max(abs(np.mean(t_start)), 1e-300), None
        else:
            start = ca.Function("terms", [lam], terms)(lam0)
            start_values = np.array([float(v) for v in (start if n_g > 1 else [start])])
            norm = max(np.abs(start_values).max(), 1e-300) if self.criterion != "D" else 1.0
        if self.robust == "worst" and n_g > 1:
            tau = ca.SX.sym("tau")
            objective = tau
            cons += [tau - term / norm for term in terms]
            x_extra.append(tau)
            x0_extra.append(-np.min(x0_extra) / norm if self.criterion == "E" else float(np.max(start_values)) / norm)
            lb_extra.append(-np.inf)
            ub_extra.append(np.inf)
        else:
            objective = sum(terms, ca.SX(0)) / (n_g * norm)
        g = ca.vertcat(durations.reshape(1, -1) @ lam, *cons)
        return {"x": ca.vertcat(lam, *x_extra), "f": objective, "g": g,
                "x0": np.concatenate([np.minimum(lam0, upper), x0_extra]),
                "lbx": np.concatenate([np.zeros(m), lb_extra]), "ubx": np.concatenate([upper, ub_extra]),
                "lbg": np.concatenate([[-np.inf], np.zeros(g.numel() - 1)]),
                "ubg": np.concatenate([[budget], np.full(g.numel() - 1, np.inf)])}


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
