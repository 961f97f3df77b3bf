"""The limit of two merging terms: a probe for a cost that falls towards no attained minimum.

Two exchangeable terms of a sum, ``a0 f(x; b0) + a1 f(x; b1)``, can approach each other
(``b1 -> b0``) while their amplitudes grow with opposite signs: the sum then tends to
``c f(x; b0) + d df/db0(x; b0)``, a term and its derivative term, which no point of the box
attains when the amplitudes are unbounded. When that limit fits the data better than every
point a solver can stop at, the cost has no minimum in the box: an estimate is only where a
solver stopped on the way.

:func:`fit_merged_limit` fits that limit (one two-stage estimate of :func:`limit_model`) when
an estimate of a model with exchangeable terms shows the signs of such a path (terms merging,
a lower cost no start finished at, parameters the data do not separate, a minimum not
verified). When the limit fits better, the estimate is not the lowest cost of the box: the
pipeline runs stage 2 from further minima of the stage-1 ranking, and when none of them goes
below the limit, :func:`with_merged_limit` records it on the estimate (:class:`MergedLimit`)
with a ``MERGING`` note.
"""

from __future__ import annotations

import contextvars
import math
import warnings
from dataclasses import dataclass, replace

import casadi as ca
import numpy as np

from .._casadi.array_json import decode_array, encode_array
from ..backend.tolerances import cost_tolerance
from ..errors import ModelError, OptionError, ResultFileError
from ..models import Model, Parameter
from ..status import Note, NoteCode
from .symmetry import exchanged_pairs, model_symmetries

__all__ = ["MergedLimit", "limit_model", "merging_exchanges", "fit_merged_limit", "limit_is_lower", "with_merged_limit",
           "PROBE_EVIDENCE"]

#: the notes on an estimate that call for the probe: a path towards a limit leaves them behind
PROBE_EVIDENCE = frozenset({NoteCode.MERGING, NoteCode.LOWER_UNFINISHED, NoteCode.NOT_IDENTIFIABLE,
                            NoteCode.NOT_VERIFIED})
# an estimate of a limit model does not probe its own limits
_PROBING = contextvars.ContextVar("casest_probing_merged_limit", default=False)


@dataclass(frozen=True)
class MergedLimit:
    """The fit of the limit two merging terms tend to (module docstring).

    Attributes
    ----------
    merged : tuple of (str, str)
        The nonlinear parameters set equal: (kept, removed) per pair, names of the model.
    amplitudes : (str, str)
        The exchanged amplitudes (linear parameters): (kept, removed).
    parameter_names : tuple of str
        The limit model's parameters (:func:`limit_model`): the model's without the removed ones,
        the derivative terms' amplitudes after the kept term's amplitude.
    theta : ndarray, shape (n_limit_parameters,)
        The limit model's estimate, physical units.
    std : ndarray, shape (n_limit_parameters,)
        Its standard deviations (NaN where unavailable, as on an :class:`Estimate`).
    cost : float
        Its ML cost (paper Eq. 6, constants dropped), comparable with the estimate's.
    estimate_cost : float
        The estimate's cost.
    """

    merged: tuple
    amplitudes: tuple
    parameter_names: tuple
    theta: np.ndarray
    std: np.ndarray
    cost: float
    estimate_cost: float

    def limit_model(self, model: Model) -> Model:
        """The limit model of ``model`` this record was fitted with (:func:`limit_model`).

        Parameters
        ----------
        model : Model
            The estimated model (without fixed parameters).

        Returns
        -------
        Model
        """
        names = list(model.parameter_names)
        used = [n for pair in self.merged for n in pair] + list(self.amplitudes)
        unknown = [n for n in used if n not in names]
        if unknown or len(self.amplitudes) != 2 or any(len(pair) != 2 for pair in self.merged):
            raise OptionError(f"this merged limit names {unknown or list(self.amplitudes)}: it needs two amplitudes and "
                              f"pairs of nonlinear parameters of the model ({names}); use the model it was fitted with")
        rates = [(names.index(k), names.index(j)) for k, j in self.merged]
        return limit_model(model, rates, tuple(names.index(a) for a in self.amplitudes))

    def to_dict(self) -> dict:
        """Plain-Python form for JSON."""
        return {"merged": [list(pair) for pair in self.merged], "amplitudes": list(self.amplitudes),
                "parameter_names": list(self.parameter_names), "theta": encode_array(self.theta),
                "std": encode_array(self.std),
                "cost": float(self.cost), "estimate_cost": float(self.estimate_cost)}

    @classmethod
    def from_dict(cls, data: dict) -> "MergedLimit":
        """Inverse of :meth:`to_dict`."""
        try:
            return cls(tuple(tuple(pair) for pair in data["merged"]), tuple(data["amplitudes"]),
                       tuple(data["parameter_names"]), decode_array(data["theta"]), decode_array(data["std"]),
                       float(data["cost"]), float(data["estimate_cost"]))
        except (KeyError, TypeError, ValueError) as err:
            raise ResultFileError(f"a merged limit record with a missing or damaged field ({type(err).__name__}: "
                                  f"{err}); write it again with MergedLimit.to_dict") from None


def limit_model(model: Model, rates, amplitudes) -> Model:
    """The model with two exchangeable terms replaced by their merged limit, a term and its
    derivative terms.

    ``a_k f(x; b_k) + a_j f(x; b_j)`` becomes ``a_k f(x; b_k) + sum_l d_l df/db_kl(x; b_k)``:
    the rates ``b_j`` and the amplitude ``a_j`` leave, one amplitude ``d_l`` per merged
    nonlinear parameter enters (named ``<a_k>_d<b_kl>``, unbounded, after ``a_k``).

    Parameters
    ----------
    model : Model
    rates : sequence of (int, int)
        (kept, removed) indices of the exchanged nonlinear parameters.
    amplitudes : (int, int)
        (kept, removed) indices of the exchanged amplitudes (linear parameters).

    Returns
    -------
    Model
        Same signals and outputs.

    Raises
    ------
    ModelError
        An output not linear in the kept amplitude.
    OptionError
        Not a static model, indices out of range or repeated, no pair of rates, or terms that are
        not exchangeable (swapping them changes the outputs).
    """
    rates, amplitudes = _checked_exchange(model, rates, amplitudes)
    theta, names = model.theta, model.parameter_names
    kept_amplitude, removed_amplitude = amplitudes
    column = ca.jacobian(model.h, theta[kept_amplitude])
    if ca.depends_on(column, theta[kept_amplitude]):
        raise ModelError(f"the outputs are not linear in {names[kept_amplitude]!r}: no merged limit")
    removed = [j for _, j in rates] + [removed_amplitude]
    old = ca.vertcat(*[theta[j] for _, j in rates], theta[removed_amplitude])
    new = ca.vertcat(*[theta[k] for k, _ in rates], 0)
    h = ca.substitute(model.h, old, new)
    taken = set(names)
    derivative_parameters = []
    amplitude_parameter = model.parameters[kept_amplitude]
    for k, _ in rates:
        name = f"{names[kept_amplitude]}_d{names[k]}"
        while name in taken:
            name += "_"
        taken.add(name)
        d = ca.SX.sym(name)
        h = h + d * ca.substitute(ca.jacobian(column, theta[k]), old, new)
        rate = model.parameters[k]
        unit = f"{amplitude_parameter.unit}*{rate.unit}" if amplitude_parameter.unit and rate.unit else ""
        derivative_parameters.append(Parameter(name, nominal=0.0, unit=unit,
                                               scale=float(model.scales[kept_amplitude] * model.scales[k])))
    parameters = []
    for i, p in enumerate(model.parameters):
        if i not in removed:
            parameters.append(p)
        if i == kept_amplitude:
            parameters.extend(derivative_parameters)
    outputs = {name: h[j] for j, name in enumerate(model.output_names)}
    return Model(parameters, model.signals, outputs, name=f"{model.name} (merged limit)",
                 output_units=dict(zip(model.output_names, model.output_units)))


def _checked_exchange(model, rates, amplitudes) -> tuple:
    """``(rates, amplitudes)`` as index pairs, after checking they name an exchange of two terms."""
    if not isinstance(model, Model):
        raise OptionError(f"limit_model takes a static casest.Model, got {type(model).__name__}")
    n = model.n_parameters
    try:
        rates = [(int(k), int(j)) for k, j in rates]
        amplitudes = (int(amplitudes[0]), int(amplitudes[1]))
    except (TypeError, ValueError, IndexError):
        raise OptionError("rates must be (kept, removed) index pairs and amplitudes one (kept, removed) pair") from None
    used = [i for pair in rates for i in pair] + list(amplitudes)
    if not rates or len(amplitudes) != 2 or any(i < 0 or i >= n for i in used) or len(set(used)) != len(used):
        raise OptionError(f"limit_model needs at least one (kept, removed) pair of rates and one pair of amplitudes, "
                          f"distinct indices below {n} (the model's parameters {list(model.parameter_names)}); got "
                          f"rates {rates}, amplitudes {amplitudes}")
    swap = list(range(n))
    for k, j in rates + [amplitudes]:
        swap[k], swap[j] = j, k
    f = ca.Function("h", [model.x, model.theta], [model.h])
    rng = np.random.default_rng(0)
    for _ in range(3):  # exchangeable terms: the outputs stay when the pairs swap, at any point
        x, th = rng.uniform(0.5, 1.5, model.n_signals), rng.uniform(0.5, 1.5, n)
        a, b = np.asarray(f(x, th)).ravel(), np.asarray(f(x, th[swap])).ravel()
        scale = max(1.0, float(np.nanmax(np.abs(a), initial=0.0)))
        if not np.allclose(a, b, rtol=1e-9, atol=1e-12 * scale, equal_nan=True):
            names = model.parameter_names
            raise OptionError(f"swapping {[(names[k], names[j]) for k, j in rates + [amplitudes]]} changes the "
                              "outputs: these terms are not exchangeable, so they have no merged limit")
    return rates, amplitudes


def merging_exchanges(model: Model, maps, linear_index) -> list:
    """The exchanges of two terms that could merge: pure transpositions with one pair of
    unbounded amplitudes and at least one pair of nonlinear parameters.

    Parameters
    ----------
    model : Model
    maps : tuple of ParameterMap
        The model's symmetries (:func:`casest.two_stage.symmetry.model_symmetries`).
    linear_index : iterable of int
        The linear parameters.

    Returns
    -------
    list of (list of (int, int), list of (int, int))
        Per exchange: its (kept, removed) nonlinear and linear index pairs.
    """
    linear, out = set(int(i) for i in linear_index), []
    for m in maps:
        rates, amplitudes = exchanged_pairs(m, linear)
        unbounded = all(math.isinf(model.parameters[i].lb) and math.isinf(model.parameters[i].ub)
                        for pair in amplitudes for i in pair)
        if len(amplitudes) == 1 and rates and unbounded:
            out.append((rates, amplitudes))
    return out


def _one_per_class(exchanges, theta: np.ndarray, scales: np.ndarray) -> list:
    """Of exchanges among terms that are all exchangeable with each other, the pair whose
    nonlinear parameters are nearest: merging any two of them gives the same limit model, up to
    labels."""
    groups: list[tuple[set, tuple]] = []
    for rates, amplitudes in exchanges:
        terms = {amplitudes[0][0], amplitudes[0][1]}
        gap = max(abs(theta[k] - theta[j]) / scales[k] for k, j in rates)
        for i, (members, best) in enumerate(groups):
            if members & terms:
                members |= terms
                if gap < best[0]:
                    groups[i] = (members, (gap, rates, amplitudes))
                break
        else:
            groups.append((set(terms), (gap, rates, amplitudes)))
    return [(rates, amplitudes) for _, (_, rates, amplitudes) in groups]


def fit_merged_limit(problem, estimate, linear_index, estimate_problem, report=None) -> MergedLimit | None:
    """The fit of the merged limit of an estimate's exchangeable terms, when the estimate shows
    the signs of a path towards one (module docstring).

    Parameters
    ----------
    problem : Problem
        The estimated problem (a single static record without fixed parameters or priors is
        probed; for others the answer is None).
    estimate : Estimate
    linear_index : sequence of int
        The separator's linear parameters (indices into ``problem.model``).
    estimate_problem : callable
        ``Problem -> Estimate``: the two-stage estimate of a problem (the pipeline's).
    report : callable, optional
        ``(stage, text) -> None`` progress.

    Returns
    -------
    MergedLimit or None
        The lowest limit over the classes of exchangeable terms (one fit per class); None when
        nothing called for the probe or no limit was fitted.
    """
    from ..problem.problem import Problem

    if (_PROBING.get() or problem.dynamic or problem.experiments or problem.stage1_data is not None or problem.held
            or problem.prior_penalty or not PROBE_EVIDENCE & set(estimate.note_codes)):
        return None
    model, theta = problem.model, np.asarray(estimate.theta, dtype=float)
    exchanges = merging_exchanges(model, model_symmetries(model, problem.data.signals, theta), linear_index)
    best = None
    for rates, amplitudes in _one_per_class(exchanges, theta, model.scales):
        limit = limit_model(model, rates, amplitudes[0])
        if report is not None:
            report("merged limit", f"fitting {limit.name} ({limit.n_parameters} parameters)")
        token = _PROBING.set(True)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                fit = estimate_problem(Problem(limit, problem.data, noise=problem.noise))
        finally:
            _PROBING.reset(token)
        if np.isfinite(fit.cost) and (best is None or fit.cost < best[0].cost):
            best = (fit, rates, amplitudes[0])
    if best is None:
        return None
    fit, rates, amplitudes = best
    names = model.parameter_names
    return MergedLimit(tuple((names[k], names[j]) for k, j in rates), tuple(names[i] for i in amplitudes),
                       tuple(fit.parameter_names), np.asarray(fit.theta, dtype=float),
                       np.asarray(fit.std, dtype=float), float(fit.cost),
                       float(estimate.cost))


def limit_is_lower(record: MergedLimit | None, cost: float) -> bool:
    """Whether a merged limit fits better than an estimate of cost ``cost`` (beyond round-off).

    Parameters
    ----------
    record : MergedLimit or None
    cost : float
        The estimate's ML cost.

    Returns
    -------
    bool
    """
    return record is not None and record.cost < cost - cost_tolerance(cost)


def with_merged_limit(estimate, record: MergedLimit | None):
    """The estimate with its merged limit and a ``MERGING`` note, when the limit fits better.

    Parameters
    ----------
    estimate : Estimate
    record : MergedLimit or None
        :func:`fit_merged_limit`'s answer.

    Returns
    -------
    Estimate
        ``estimate`` itself when the limit is not lower; otherwise a copy with ``merged_limit``
        set (its ``estimate_cost`` the estimate's) and the note.
    """
    if record is not None and not isinstance(record, MergedLimit):
        raise OptionError(f"with_merged_limit takes a MergedLimit or None, got {type(record).__name__}")
    if not limit_is_lower(record, estimate.cost):
        return estimate
    record = replace(record, estimate_cost=float(estimate.cost))
    merged = " and ".join(f"{k} = {j}" for k, j in record.merged)
    values = ", ".join(f"{n} = {v:.6g}" for n, v in zip(record.parameter_names, record.theta))
    note = Note(f"a limit no point of the box attains fits better than the estimate: with {merged} and the term of "
                f"{record.amplitudes[1]} replaced by derivative terms, J = {record.cost:.10g} against the estimate's "
                f"J = {estimate.cost:.10g} ({values}); along two terms merging with amplitudes of opposite sign the "
                "cost keeps falling, so the estimate is where a solver stopped, not the lowest cost of the box. Fit "
                "the limit model (Estimate.merged_limit.limit_model(model)) or a model with one term fewer",
                NoteCode.MERGING)
    return replace(estimate, merged_limit=record, notes=list(estimate.notes) + [note])
