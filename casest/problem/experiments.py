"""Several experiments (data sets) that share the model's parameters.

Each experiment is a :class:`~casest.Dataset` for the same model, with its own length.
With one noise R for all of them the samples are simply stacked. With a separate R per
experiment every output becomes one channel per experiment (``z@name``), and each
experiment's rows leave the other experiments' channels unmeasured (missing), so the
likelihood is exactly the sum of the experiments' likelihoods, each with its own R and
its own ln|R| count.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Mapping, Sequence

import casadi as ca
import numpy as np

from ..data.dataset import DataError, Dataset
from ..models import Model, OptionError, Signal
from ..models.dynamic import DynamicModel, Segments, State


__all__ = ["stack_experiments", "stack_dynamic_experiments"]


def stack_experiments(model: Model, experiments: Sequence[Dataset] | Mapping[str, Dataset],
                      separate_noise: bool = True) -> tuple[Model, Dataset, tuple]:
    """One model and one data set for several experiments sharing the parameters.

    Parameters
    ----------
    model : Model
    experiments : sequence of Dataset, or mapping of name to Dataset
        Each one for ``model`` (same signals and outputs), any length; missing outputs
        (``missing="allow"``) stay missing. Unnamed experiments are called ``e1, e2, ...``.
    separate_noise : bool
        One R per experiment (True) or one R for all (False).

    Returns
    -------
    model : Model
        ``model`` itself (shared R), or the model with outputs ``{output}@{experiment}``.
    data : Dataset
        The experiments' samples one after the other (N = sum of their lengths).
    names : tuple of str
        The experiments' names, in order.

    Raises
    ------
    DataError
        No experiment, or an experiment built for another model.
    """
    named = _named(experiments)
    for data in named.values():
        data.check_model(model)
    signals = np.vstack([d.signals for d in named.values()])
    columns = {s: signals[:, i] for i, s in enumerate(model.signal_names)}
    columns.update(_output_columns(model.output_names, named, separate_noise))
    if not separate_noise:
        return model, Dataset(model, columns, missing="allow"), tuple(named)
    expanded = {f"{o}@{name}": model.h[j] for name in named for j, o in enumerate(model.output_names)}
    units = {f"{o}@{name}": u for name in named for o, u in zip(model.output_names, model.output_units)}
    stacked = Model(model.parameters, model.signals, expanded, name=model.name, output_units=units)
    return stacked, Dataset(stacked, columns, missing="allow"), tuple(named)


def _output_columns(output_names, named: dict, separate_noise: bool) -> dict:
    """The experiments' outputs one after the other: one column per output (shared noise), or one
    per output and experiment, ``{output}@{experiment}``, NaN (not measured) in the other
    experiments' rows (separate noise)."""
    if not separate_noise:
        return {o: np.concatenate([d.outputs[:, j] for d in named.values()]) for j, o in enumerate(output_names)}
    sizes = [d.n_samples for d in named.values()]
    first, total = np.cumsum([0] + sizes[:-1]), int(sum(sizes))
    columns = {}
    for k, (name, data) in enumerate(named.items()):
        for j, o in enumerate(output_names):
            column = np.full(total, np.nan)
            column[first[k]:first[k] + sizes[k]] = data.outputs[:, j]
            columns[f"{o}@{name}"] = column
    return columns


def stack_dynamic_experiments(model: DynamicModel, experiments: Sequence[Dataset] | Mapping[str, Dataset],
                              separate_noise: bool = True) -> tuple[DynamicModel, Dataset, tuple]:
    """One dynamic model and one record for several manoeuvres (or time segments) that share
    the parameters, each with its own initial state.

    The records follow each other in one data set (each experiment's times shifted after the
    previous one's); the stacked model restarts its simulation at every experiment's first
    sample (:class:`casest.models.discretisation.Segments`), from that experiment's initial state: a
    number (the same in all), a parameter (estimated per experiment: parameter ``x0``
    becomes ``x0@name`` for each experiment) or the experiment's own data. The likelihood is
    the sum of the experiments' likelihoods.

    Parameters
    ----------
    model : DynamicModel
    experiments : sequence of Dataset, or mapping of name to Dataset
        Each one for ``model`` (:meth:`DynamicModel.dataset`), any length and time axis.
    separate_noise : bool
        One R per experiment (outputs ``{output}@{experiment}``) or one R for all.

    Returns
    -------
    model : DynamicModel
        The stacked model (inputs ``@start``, ``@in:NAME`` and ``@x0:STATE`` carry the restarts).
    data : Dataset
    names : tuple of str

    Raises
    ------
    DataError
        No experiment, or one that does not fit the model.
    OptionError
        An initial-state parameter that also enters the equations (it could not be one per
        experiment), or a model that is already stacked.
    """
    named = _named(experiments)
    for data in named.values():
        model.check_data(data)
    if model.segments is not None:
        raise OptionError("this model already stacks several experiments; give the experiments of the original model")
    names = tuple(named)
    per_experiment = _initial_state_parameters(model)
    segments = Segments(names, "@start", tuple(f"@in:{e}" for e in names), _restart_states(model, names, per_experiment),
                        tuple(int(named[e].n_samples) for e in names))
    spec = dict(model._spec)
    # the declared inputs and the restart columns (the model adds the lags again)
    inputs = list(spec["inputs"]) + [Signal(segments.start)] + [Signal(n) for n in segments.indicators] + [
        Signal(f"@x0:{n}") for n in model.initial_from_data]
    spec.update(inputs=inputs, segments=segments, **_initial_state_spec(model, names, per_experiment))
    if separate_noise:
        spec.update(_separate_outputs_spec(model, names))
    stacked = DynamicModel(**spec)
    return stacked, _stacked_record(model, stacked, named, separate_noise), names


def _restart_states(model: DynamicModel, names: tuple, per_experiment: list) -> tuple:
    """Each state's initial value in each experiment: its parameter ``x0@name``, the experiment's
    data (input ``@x0:STATE``) or the declared number."""
    def initial(state, experiment):
        if state.initial in per_experiment:
            return f"{state.initial}@{experiment}"
        return f"@x0:{state.name}" if state.initial == "data" else state.initial

    return tuple((s.name, tuple(initial(s, e) for e in names)) for s in model.states)


def _initial_state_spec(model: DynamicModel, names: tuple, per_experiment: list) -> dict:
    """The stacked model's parameters and states: an initial-state parameter ``x0`` becomes
    ``x0@name`` for each experiment (the states start from the first experiment's)."""
    parameters = [replace(p, name=f"{p.name}@{e}") for p in model.parameters if p.name in per_experiment for e in names]
    parameters = [p for p in model.parameters if p.name not in per_experiment] + parameters
    states = [State(s.name, f"{s.initial}@{names[0]}" if s.initial in per_experiment else s.initial, s.unit)
              for s in model.states]
    return {"parameters": parameters, "states": states}


def _separate_outputs_spec(model: DynamicModel, names: tuple) -> dict:
    """The stacked model's outputs, units and output delays with one R per experiment: ``{output}@{experiment}``."""
    spec, units = model._spec, dict(zip(model.output_names, model.output_units))
    renamed = [(o, f"{o}@{e}") for e in names for o in model.output_names]
    return {"outputs": {new: spec["outputs"][o] for o, new in renamed},
            "output_units": {new: units[o] for o, new in renamed},
            "delays": _renamed_delays(dict(spec["delays"] or {}), model.output_names, renamed) or None}


def _renamed_delays(given: dict, output_names, renamed: list) -> dict:
    """The delays with each output's moved to its per-experiment names (the inputs' kept)."""
    delays = {k: v for k, v in given.items() if k not in output_names}
    delays.update((new, given[o]) for o, new in renamed if o in given)
    return delays


def _initial_state_parameters(model: DynamicModel) -> list:
    """The parameters that are a state's initial value (one per experiment once stacked)."""
    names = [s.initial for s in model.states if isinstance(s.initial, str) and s.initial != "data"]
    index = [model.parameter_names.index(n) for n in names]
    in_equations = [n for n, i in zip(names, index) if i in model.rhs_parameter_index
                    or ca.depends_on(model.output_model.h, model.output_model.theta[i])]
    if in_equations:
        raise OptionError(f"parameter(s) {in_equations} are initial states and also enter the rhs or the outputs: "
                          "with several experiments each initial state is estimated per experiment; declare a "
                          "separate parameter for the initial state")
    return names


def _stacked_record(model: DynamicModel, stacked: DynamicModel, named: dict, separate_noise: bool) -> Dataset:
    """The experiments' samples one after the other, with the restart columns."""
    sizes = [d.n_samples for d in named.values()]
    first = np.cumsum([0] + sizes[:-1])
    total = int(sum(sizes))
    columns = {model.time: _joined_time(named)}
    for j, u in enumerate(model.inputs):
        columns[u.name] = np.concatenate([d.signals[:, 1 + j] for d in named.values()])
    columns["@start"] = np.zeros(total)
    columns["@start"][first] = 1.0
    for k, (name, data) in enumerate(named.items()):
        columns[f"@in:{name}"] = np.zeros(total)
        columns[f"@in:{name}"][first[k]:first[k] + sizes[k]] = 1.0
    for s in model.initial_from_data:
        values = np.concatenate([np.full(d.n_samples, float(d.extra[s][0])) for d in named.values()])
        columns[f"@x0:{s}"] = values
        columns[s] = values
    columns.update(_output_columns(model.output_names, named, separate_noise))
    return stacked.dataset(columns, missing="allow")


def _joined_time(named: dict) -> np.ndarray:
    """The experiments' time axes one after the other, each shifted to start 1 s after the previous one ends."""
    axes, offset = [], 0.0
    for data in named.values():
        t = data.signals[:, 0]
        axes.append(t - t[0] + offset)
        offset = axes[-1][-1] + 1.0
    return np.concatenate(axes)


def _named(experiments) -> dict:
    named = dict(experiments) if isinstance(experiments, Mapping) else {
        f"e{k + 1}": d for k, d in enumerate(experiments)}
    if not named:
        raise DataError("no experiment given")
    for name, data in named.items():
        if not isinstance(data, Dataset):
            raise DataError(f"experiment {name!r} is a {type(data).__name__}, not a casest.Dataset")
    _refuse_repeated_records(named)
    return named


def _refuse_repeated_records(named: dict) -> None:
    """The same record given twice would count its information twice (std / sqrt 2)."""
    seen: dict = {}
    for name, data in named.items():
        key = (data.signals.shape, data.outputs.shape, data.signals.tobytes(), np.nan_to_num(data.outputs).tobytes())
        if key in seen:
            raise DataError(f"experiments {seen[key]!r} and {name!r} are the same record (equal signals and outputs): "
                            "each record counts once; give it once, or give the other record you meant")
        seen[key] = name
