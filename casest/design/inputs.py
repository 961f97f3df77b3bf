"""Input design: the time histories of the inputs the engineer controls (a dynamic model's
inputs, or a static model's free signals), within bounds and rate limits, with the exact
derivatives of the criterion with respect to the inputs."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import casadi as ca
import numpy as np

from ..backend.ipopt import SolverSettings, run_ipopt
from ..data import Dataset
from ..errors import OptionError
from ..problem.noise import CorrelatedNoise
from ..problem.measurement import as_measurement, measurement_of
from .criteria import check_criterion, check_noise, criterion_terms, parameter_guesses
from .information import information_function, information_matrix
from ..options import Criterion, Robust


__all__ = ["InputDesign", "design_inputs"]


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


def design_inputs(model, data: Dataset, free: Sequence[str], theta, R,
                  lower: Mapping[str, float], upper: Mapping[str, float], max_rate: Mapping[str, float] | None = None,
                  criterion: Criterion = "D", c=None, robust: Robust = "average", max_iter: int = 200,
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
    c = check_criterion(criterion, robust, c, model.n_parameters)
    if criterion == "E":
        raise OptionError("design_inputs offers D, A and c (E has no second derivative); use design_experiment "
                          "for E-optimal allocations")
    guesses = parameter_guesses(model, theta)
    check_noise(R, model.output_names)
    measurement = measurement_of(model)  # one adapter for the inputs, the information and its graph
    inputs = _FreeInputs(measurement, data, list(free), lower, upper)
    V = ca.MX.sym("free", len(free), data.n_samples)
    terms = _criterion_graph(measurement, data, inputs, V, guesses, R, criterion, c)
    start_fn = ca.Function("terms", [V], terms)
    start_values = _term_values(start_fn, inputs.start, len(terms))
    if not np.all(np.isfinite(start_values)):
        raise OptionError("the starting inputs leave a parameter combination unidentified: start from an input "
                          "that excites every parameter (a doublet or multisine)")
    norm = 1.0 if criterion == "D" else max(np.abs(start_values).max(), 1e-300)
    x_extra, x0_extra, cons = [], [], []
    if robust == "worst" and len(terms) > 1:
        tau = ca.MX.sym("tau")
        objective = tau
        cons += [tau - term / norm for term in terms]
        x_extra, x0_extra = [tau], [float(start_values.max()) / norm]
    else:
        objective = sum(terms) / (len(terms) * norm)
    lbg, ubg = [np.zeros(len(cons))], [np.full(len(cons), np.inf)]
    inputs.rate_limits(V, max_rate or {}, cons, lbg, ubg)
    settings = SolverSettings(tol=1e-8, max_iter=int(max_iter),
                              ipopt={"hessian_approximation": "limited-memory", **dict(ipopt_options or {})})
    solver = ca.nlpsol("design_inputs", "ipopt", {"x": ca.vertcat(ca.vec(V), *x_extra), "f": objective,
                                                  "g": ca.vertcat(*cons) if cons else ca.MX(0, 1)},
                       settings.nlpsol_options())
    run = run_ipopt(solver, x0=np.concatenate([inputs.start.reshape(-1, order="F"), x0_extra]),
                    lbx=np.concatenate([inputs.lower.reshape(-1, order="F"), [-np.inf] * len(x_extra)]),
                    ubx=np.concatenate([inputs.upper.reshape(-1, order="F"), [np.inf] * len(x_extra)]),
                    lbg=np.concatenate(lbg), ubg=np.concatenate(ubg))
    designed = np.clip(run.x[:V.numel()].reshape(len(free), data.n_samples, order="F"), inputs.lower, inputs.upper)
    values = _term_values(start_fn, designed, len(terms))
    new = inputs.dataset_with(designed)
    covs = [np.linalg.inv(information_matrix(measurement, new, g_, R)) for g_ in guesses]
    notes = [] if run.success else [f"IPOPT stopped with {run.status}: the inputs are improved, not optimal"]
    combine = np.max if robust == "worst" else np.mean
    return InputDesign(new, designed.T, float(combine(values)), float(combine(start_values)), covs,
                       np.sqrt(np.diag(covs[0])), run.success, run.status, notes)


def _term_values(terms: ca.Function, values, n_terms: int) -> np.ndarray:
    out = terms(values)
    return np.array([float(v) for v in (out if n_terms > 1 else [out])])


class _FreeInputs:
    """The inputs being designed: where they sit among the model's signals, their start, bounds
    and sample times (a static model's signals are indexed by sample)."""

    def __init__(self, model, data: Dataset, free: list, lower: Mapping, upper: Mapping):
        measurement = as_measurement(model)
        names = list(measurement.controlled_names)
        unknown = [f for f in free if f not in names]
        if unknown:
            noun = "inputs" if measurement.simulated else "signals"
            raise OptionError(f"unknown {noun} {unknown}; the model's are {names}")
        missing = [f for f in free if f not in lower or f not in upper]
        if missing:
            raise OptionError(f"give lower and upper bounds for {missing}")
        self.model, self.data, self.free, self.measurement = measurement.model, data, free, measurement
        self.base, self.times = measurement.controlled_history(data)
        self.rows = [names.index(f) for f in free]
        self.start = self.base[self.rows].copy()
        N = data.n_samples
        self.lower = np.array([lower[f] for f in free])[:, None] * np.ones((1, N))
        self.upper = np.array([upper[f] for f in free])[:, None] * np.ones((1, N))
        outside = [f for f, v, a, b in zip(free, self.start, self.lower, self.upper)
                   if np.any(v < a[0] - 1e-12) or np.any(v > b[0] + 1e-12)]
        if outside:
            raise OptionError(f"the starting {outside} leave their bounds: start from inputs inside them")

    def history(self, V) -> ca.MX:
        """All controlled signals with the free ones replaced by ``V`` (n_free x N)."""
        full = ca.MX(ca.DM(self.base))
        for k, r in enumerate(self.rows):
            full[r, :] = V[k, :]
        return full

    def rate_limits(self, V, max_rate: Mapping, cons: list, lbg: list, ubg: list) -> None:
        """Add ``|v_k+1 - v_k| <= rate * dt`` for the inputs with a rate limit."""
        dt = np.diff(self.times)
        for k, f in enumerate(self.free):
            if f in max_rate:
                limit = float(max_rate[f]) * dt
                cons.append((V[k, 1:] - V[k, :-1]).T)
                lbg.append(-limit)
                ubg.append(limit)
                if np.any(np.abs(np.diff(self.start[k])) > limit + 1e-9):
                    raise OptionError(f"the starting {f} exceeds its rate limit: start from a smoother input")

    def dataset_with(self, designed: np.ndarray) -> Dataset:
        """The experiment with the designed inputs."""
        data, model = self.data, self.model
        columns = {name: data.signals[:, j].copy() for j, name in enumerate(model.signal_names)}
        for k, f in enumerate(self.free):
            columns[f] = designed[k]
        for j, o in enumerate(model.output_names):
            columns[o] = data.outputs[:, j]
        columns.update(data.extra)
        return Dataset(model, columns, extra=list(data.extra), missing="allow")


def _criterion_graph(measurement, data: Dataset, inputs: _FreeInputs, V, guesses, R, criterion: str, c) -> list:
    """The criterion term of each guess as an expression of the free inputs ``V``."""
    model = measurement.model
    n = model.n_parameters
    info = information_function(measurement, data.n_samples, noise=CorrelatedNoise() if np.ndim(R) == 2 else None)
    S = ca.DM(np.diag(model.scales))
    Fsym = ca.SX.sym("F", n, n)
    term, _ = criterion_terms(Fsym, criterion, None if c is None else model.scales * c, None)
    term_of = ca.Function("term", [Fsym], [term])
    terms = []
    for g in guesses:
        args = {"theta": g, "R": np.asarray(R, dtype=float),
                **inputs.measurement.information_arguments(inputs.history(V), inputs.times, data)}
        terms.append(term_of(ca.mtimes(ca.mtimes(S, info(**args)["F"]), S)))
    return terms
