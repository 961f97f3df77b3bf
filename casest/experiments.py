"""Several experiments (data sets) that share the model's parameters.

Each experiment is a :class:`~casest.Dataset` for the same model, with its own length.
With one noise R for all of them the samples are simply stacked. With a separate R per
experiment every output becomes one channel per experiment (``z@name``), and each
experiment's rows leave the other experiments' channels unmeasured (missing), so the
likelihood is exactly the sum of the experiments' likelihoods, each with its own R and
its own ln|R| count.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from .data import DataError, Dataset
from .model import Model

__all__ = ["stack_experiments"]


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
    named = dict(experiments) if isinstance(experiments, Mapping) else {
        f"e{k + 1}": d for k, d in enumerate(experiments)}
    if not named:
        raise DataError("no experiment given")
    for name, data in named.items():
        if not isinstance(data, Dataset):
            raise DataError(f"experiment {name!r} is a {type(data).__name__}, not a casest.Dataset")
        data.check_model(model)
    signals = np.vstack([d.signals for d in named.values()])
    columns = {s: signals[:, i] for i, s in enumerate(model.signal_names)}
    if not separate_noise:
        outputs = np.vstack([d.outputs for d in named.values()])
        columns.update({o: outputs[:, j] for j, o in enumerate(model.output_names)})
        return model, Dataset(model, columns, missing="allow"), tuple(named)
    expanded = {f"{o}@{name}": model.h[j] for name in named for j, o in enumerate(model.output_names)}
    units = {f"{o}@{name}": u for name in named for o, u in zip(model.output_names, model.output_units)}
    stacked = Model(model.parameters, model.signals, expanded, name=model.name, output_units=units)
    total = signals.shape[0]
    start = 0
    for name, data in named.items():
        for j, o in enumerate(model.output_names):
            column = np.full(total, np.nan)  # the other experiments' rows: not measured on this channel
            column[start:start + data.n_samples] = data.outputs[:, j]
            columns[f"{o}@{name}"] = column
        start += data.n_samples
    return stacked, Dataset(stacked, columns, missing="allow"), tuple(named)
