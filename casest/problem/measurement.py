"""The measurement-model interface: what the stages need of a model, for both kinds.

A static :class:`casest.Model` and a :class:`casest.DynamicModel` differ in how their
outputs are obtained (a function of the measured signals, or of states simulated from
theta), so in how predictions, Jacobians, the data vector and the ML cost's CasADi graph
are built. :func:`measurement_of` wraps either in a :class:`Measurement` with one set of
methods; the Problem, stage 1, stage 2 and the embedding call those methods and never test
the model's type. It is the one place that does.
"""


from __future__ import annotations

import numpy as np

from ..data.dataset import Dataset
from ..models import Model, ModelError, OptionError
from ..models.dynamic import DynamicModel
from .data_graph import data_symbols, data_vector, ml_cost_expression, sum_data_symbols
from .dynamic_measurement import DynamicMeasurement
from .measurement_base import Measurement
from .static_measurement import StaticMeasurement


__all__ = ["Measurement", "StaticMeasurement", "DynamicMeasurement", "measurement_of", "as_measurement",
           "ml_cost_expression",
           "data_vector", "data_symbols", "sum_data_symbols", "check_predictions"]


def measurement_of(model) -> Measurement:
    """The :class:`Measurement` of a model: the one place that tells the kinds apart.

    Parameters
    ----------
    model : Model or DynamicModel

    Returns
    -------
    Measurement
        A :class:`StaticMeasurement` or :class:`DynamicMeasurement`.

    Raises
    ------
    OptionError
        Anything else.
    """
    if isinstance(model, DynamicModel):
        return DynamicMeasurement(model)
    if isinstance(model, Model):
        return StaticMeasurement(model)
    raise OptionError(f"a casest.Model or casest.DynamicModel is needed, got {type(model).__name__}")


def as_measurement(model_or_measurement) -> Measurement:
    """A :class:`Measurement` handed down as it is (a Problem's ``problem.measurement``), or the
    adapter of a model (:func:`measurement_of`).

    Parameters
    ----------
    model_or_measurement : Measurement, Model or DynamicModel

    Returns
    -------
    Measurement
    """
    if isinstance(model_or_measurement, Measurement):
        return model_or_measurement
    return measurement_of(model_or_measurement)


def check_predictions(model: Model, data: Dataset, theta: np.ndarray, label: str) -> None:
    """Raise a :class:`ModelError` naming the output and samples where the model is NaN or infinite.

    Parameters
    ----------
    model : Model or DynamicModel
    data : Dataset
    theta : ndarray, shape (n_parameters,)
    label : str
        What ``theta`` is, for the message (e.g. "nominal values").

    Returns
    -------
    None
        Returns only when every prediction is finite.

    Raises
    ------
    ModelError
        Naming the output, the rows and the signals of the first bad row.
    """
    with np.errstate(all="ignore"):
        pred = measurement_of(model).predict(theta, data)
    bad = ~np.isfinite(pred)
    if not bad.any():
        return
    j = int(np.flatnonzero(bad.any(axis=0))[0])
    rows = np.flatnonzero(bad[:, j])
    shown = ", ".join(str(r) for r in rows[:5]) + (" ..." if rows.size > 5 else "")
    where = ", ".join(f"{n} = {v:.6g}" for n, v in zip(model.signal_names, data.signals[rows[0]]))
    raise ModelError(
        f"output {model.output_names[j]!r} is NaN or infinite at {rows.size} of {data.n_samples} samples (rows "
        f"{shown}, 0-based) at the {label}; at row {rows[0]}: {where or 'no signals'}. The model is not defined "
        "there (a log or sqrt of a negative number, a division by zero?): drop those samples, or change the model "
        f"or the {label}"
    )
