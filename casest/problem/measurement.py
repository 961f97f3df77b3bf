"""The measurement-model interface: what the stages need of a model, for both kinds.

A static :class:`casest.Model` and a :class:`casest.DynamicModel` differ in how their
outputs are obtained (a function of the measured signals, or of states simulated from
theta), so in how predictions, Jacobians, the data vector and the ML cost's CasADi graph
are built. :func:`measurement_of` wraps either in a :class:`Measurement` with one set of
methods; the Problem, stage 1, stage 2 and the embedding call those methods and never test
the model's type. It is the one place that does.
"""


from __future__ import annotations

from ..models import Model, OptionError
from ..models.dynamic import DynamicModel
from .data_graph import data_symbols, data_vector, ml_cost_expression, sum_data_symbols
from .dynamic_measurement import DynamicMeasurement
from .measurement_base import Measurement
from .static_measurement import StaticMeasurement


__all__ = ["Measurement", "StaticMeasurement", "DynamicMeasurement", "measurement_of", "ml_cost_expression",
           "data_vector", "data_symbols", "sum_data_symbols"]


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
