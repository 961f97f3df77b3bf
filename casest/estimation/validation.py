"""Validation on a record the estimate did not use: the model's prediction with the estimated
parameters against the measurements, per output (flight-test practice's "proof of match").

Metrics per output channel j, over its measured samples (Klein and Morelli, Aircraft System
Identification, Sec. 11; Jategaonkar, Flight Vehicle System Identification, Sec. 11):

- the prediction error ``rms_j = sqrt(mean((z_j - y_j)^2))``, in the output's unit;
- Theil's inequality coefficient ``U_j = rms_j / (sqrt(mean(z_j^2)) + sqrt(mean(y_j^2)))``,
  0 for a perfect match, 1 for none (practice reads U < 0.25-0.3 as a good match);
- the coefficient of determination ``R^2_j = 1 - sum (z_j - y_j)^2 / sum (z_j - mean z_j)^2``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from ..data.dataset import Dataset
from ..models import ModelError


__all__ = ["Validation", "theil_inequality", "validate"]


def theil_inequality(measured: np.ndarray, predicted: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Theil's inequality coefficient per column.

    Parameters
    ----------
    measured, predicted : ndarray, shape (N, n)
    mask : ndarray of bool, shape (N, n), optional
        The samples to use (default: all).

    Returns
    -------
    ndarray, shape (n,)
        ``sqrt(mean((z - y)^2)) / (sqrt(mean(z^2)) + sqrt(mean(y^2)))`` per column, in [0, 1];
        NaN where both signals are zero.
    """
    z, y = np.atleast_2d(np.asarray(measured, dtype=float)), np.atleast_2d(np.asarray(predicted, dtype=float))
    use = np.ones_like(z, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    n = use.sum(axis=0)
    rms = lambda v: np.sqrt(np.sum(np.where(use, v, 0.0) ** 2, axis=0) / n)  # noqa: E731
    with np.errstate(invalid="ignore", divide="ignore"):
        return rms(z - y) / (rms(z) + rms(y))


@dataclass(frozen=True)
class Validation:
    """How the model with given parameters predicts a record.

    Attributes
    ----------
    output_names : tuple of str
    n_samples : int
    rms_error : ndarray, shape (n_outputs,)
        Prediction error per output, its unit.
    theil : ndarray, shape (n_outputs,)
        Theil's inequality coefficient per output (0 perfect, 1 no match).
    r_squared : ndarray, shape (n_outputs,)
        Coefficient of determination per output.
    measured, predicted : ndarray, shape (N, n_outputs)
        The record's outputs (NaN where not measured) and the model's prediction.
    time : ndarray, shape (N,)
        The record's time (a dynamic model's time column, or a ``time_ordered`` static
        record's extra column ``t`` or ``time``), else the sample index.
    """

    output_names: tuple
    n_samples: int
    rms_error: np.ndarray
    theil: np.ndarray
    r_squared: np.ndarray
    measured: np.ndarray
    predicted: np.ndarray
    time: np.ndarray

    def report(self, title: str = "Validation") -> str:
        """A fixed-section text: one line per output with its three metrics.

        Parameters
        ----------
        title : str

        Returns
        -------
        str
        """
        lines = [f"[[{title}]] (prediction on {self.n_samples} samples; Theil U: 0 perfect, < 0.3 a good match)"]
        for k, name in enumerate(self.output_names):
            lines.append(f"    {name}: rms error = {self.rms_error[k]:.4g}, Theil U = {self.theil[k]:.3f}, "
                         f"R^2 = {self.r_squared[k]:.3f}")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """The metrics as plain lists (JSON-ready).

        Returns
        -------
        dict
        """
        return {"output_names": list(self.output_names), "n_samples": self.n_samples,
                "rms_error": self.rms_error.tolist(), "theil": self.theil.tolist(),
                "r_squared": self.r_squared.tolist()}


def by_name(parameters):
    """An estimate's values by name; a mapping or an array as they are."""
    if isinstance(parameters, Mapping) or not hasattr(parameters, "parameter_names"):
        return parameters
    return dict(zip(parameters.parameter_names, np.asarray(parameters.theta, dtype=float)))


def parameter_vector(model, parameters) -> np.ndarray:
    """The model's parameter vector from an Estimate (by name), a mapping or an array.

    Parameters
    ----------
    model : Model or DynamicModel
    parameters : Estimate, mapping of str to float, or array_like, shape (n_parameters,)

    Returns
    -------
    ndarray, shape (n_parameters,)

    Raises
    ------
    ModelError
        A parameter of the model that the estimate or mapping does not give (for example an
        initial state estimated per manoeuvre: start the validation record's states from its
        data, ``State(name, "data")``, or give the value).
    """
    values = by_name(parameters)
    if isinstance(values, Mapping):
        missing = [n for n in model.parameter_names if n not in values]
        if missing:
            raise ModelError(f"no value for parameter(s) {missing} of model {model.name!r}: an initial state "
                             "estimated per manoeuvre does not carry over to another record; start that state "
                             "from the data (State(name, 'data')) or give its value in a mapping")
        return np.array([float(values[n]) for n in model.parameter_names])
    return model.vector(values)


def validate(model, parameters, data: Dataset) -> Validation:
    """Predict a record with the given parameters and measure the match, per output.

    Parameters
    ----------
    model : Model or DynamicModel
        The model of ``data`` (a dynamic model simulates the record from its initial state).
    parameters : Estimate, mapping of str to float, or array_like, shape (n_parameters,)
        Usually the estimate from other records.
    data : Dataset
        The held-out record.

    Returns
    -------
    Validation
    """
    data.check_model(model)
    theta = parameter_vector(model, parameters)
    if hasattr(model, "states"):
        model.check_data(data)
        predicted, time = model.predict_data(theta, data), data.signals[:, 0]
    else:
        predicted, time = model.predict(theta, data.signals), np.arange(data.n_samples, dtype=float)
        stamps = [data.extra[n] for n in ("t", "time") if n in data.extra]
        if getattr(data, "time_ordered", False) and stamps:  # a record in time keeps its time as an extra column
            time = stamps[0]
    mask = data.output_mask().astype(bool)
    measured = np.where(mask, data.outputs, np.nan)
    error = np.where(mask, data.outputs - predicted, 0.0)
    n = mask.sum(axis=0)
    centred = np.where(mask, data.outputs - np.nanmean(measured, axis=0), 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        r_squared = 1.0 - np.sum(error**2, axis=0) / np.sum(centred**2, axis=0)
    return Validation(tuple(model.output_names), int(data.n_samples), np.sqrt(np.sum(error**2, axis=0) / n),
                      theil_inequality(np.where(mask, data.outputs, 0.0), predicted, mask), r_squared,
                      measured, np.asarray(predicted, dtype=float), np.asarray(time, dtype=float))
