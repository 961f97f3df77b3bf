"""What the filter of a filter-error estimate did at the optimum: its one-step predictions of the
outputs, the innovations with their std, and the gain, as a record saved with the estimate.

A filter-error estimate fits the one-step predictions ``y(k|k-1)``, not a free simulation of the
model: its figures and its residual checks are these predictions and the innovations
``e_k = y_k - y(k|k-1)``. The gain ``K`` is the time-varying filter's at the last sample, or the
one gain of the steady-state and innovation forms; ``diag(K C)`` is what the innovation form
constrains below 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._casadi.array_json import decode_array, encode_array
from ..estimation.result_schema import register_record
from ..filters.ekf_model import ekf_step_functions

__all__ = ["OneStepPredictions", "time_varying_predictions", "gain_predictions", "output_jacobian"]

#: the record's array fields, saved exactly
_ARRAYS = ("time", "measured", "predicted", "innovation_std", "gain", "kc_diagonal")


@register_record
@dataclass(frozen=True, eq=False)
class OneStepPredictions:
    """The filter's pass at the estimate over a record of N samples.

    Attributes
    ----------
    time : ndarray, shape (N,)
        Sample times (s).
    measured : ndarray, shape (N, n_outputs)
        The record's outputs (NaN where missing).
    predicted : ndarray, shape (N, n_outputs)
        The one-step predictions ``y(k|k-1)`` (output units).
    innovation_std : ndarray, shape (N, n_outputs)
        ``sqrt(S_k,jj)``: each innovation's std under the model (output units).
    gain : ndarray, shape (n_states, n_outputs)
        The Kalman gain K (the last sample's in the time-varying form).
    kc_diagonal : ndarray, shape (n_states,)
        ``diag(K C)`` with C the output Jacobian where K was formed.
    gain_at : str
        Where K was formed, in words (``"the last sample"``, ``"the operating point"``).
    state_names, output_names : tuple of str
    """

    time: np.ndarray
    measured: np.ndarray
    predicted: np.ndarray
    innovation_std: np.ndarray
    gain: np.ndarray
    kc_diagonal: np.ndarray
    gain_at: str
    state_names: tuple
    output_names: tuple

    def __eq__(self, other) -> bool:
        """Equal fields, arrays equal entry for entry (NaN equal to NaN: a missing sample)."""
        if not isinstance(other, OneStepPredictions):
            return NotImplemented
        return all(np.array_equal(getattr(self, key), getattr(other, key), equal_nan=True) for key in _ARRAYS) and (
            (self.gain_at, self.state_names, self.output_names) == (other.gain_at, other.state_names,
                                                                   other.output_names))

    __hash__ = None  # mutable arrays inside

    @property
    def innovation(self) -> np.ndarray:
        """``y_k - y(k|k-1)``, shape (N, n_outputs) (NaN where the output is missing)."""
        return self.measured - self.predicted

    @property
    def normalised_innovation(self) -> np.ndarray:
        """Each innovation over its std, shape (N, n_outputs): white with unit variance for a right model."""
        return self.innovation / self.innovation_std

    def to_dict(self) -> dict:
        """Plain-Python form (arrays exact).

        Returns
        -------
        dict
        """
        arrays = {key: encode_array(getattr(self, key)) for key in _ARRAYS}
        return {**arrays, "gain_at": self.gain_at, "state_names": list(self.state_names),
                "output_names": list(self.output_names)}

    @classmethod
    def from_dict(cls, data: dict) -> "OneStepPredictions":
        """The record of :meth:`to_dict`'s form.

        Parameters
        ----------
        data : dict

        Returns
        -------
        OneStepPredictions
        """
        arrays = {key: decode_array(data[key]) for key in _ARRAYS}
        return cls(**arrays, gain_at=str(data["gain_at"]), state_names=tuple(data["state_names"]),
                   output_names=tuple(data["output_names"]))


def output_jacobian(model, x: np.ndarray, u: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """C = dh/dx at a state and input.

    Parameters
    ----------
    model : DynamicModel
    x : ndarray, shape (n_states,)
    u : ndarray, shape (n_inputs,)
    theta : ndarray, shape (n_parameters,)

    Returns
    -------
    ndarray, shape (n_outputs, n_states)
    """
    _, measure = ekf_step_functions(model)
    return np.asarray(measure(x, u, theta)[1], dtype=float).reshape(model.n_outputs, model.n_states)


def time_varying_predictions(model, data, theta: np.ndarray, result) -> OneStepPredictions:
    """The record of an EKF pass (:class:`~casest.filters.filter_records.FilterResult`) at the estimate,
    K formed at the last sample from ``P(N|N-1)`` and ``S_N`` of every channel.

    Parameters
    ----------
    model : DynamicModel
    data : Dataset
    theta : ndarray, shape (n_parameters,)
    result : FilterResult

    Returns
    -------
    OneStepPredictions
    """
    measured, U = np.asarray(data.outputs, dtype=float), data.signals[:, 1:]
    S = np.asarray(result.innovation_covariance, dtype=float)
    _, measure = ekf_step_functions(model)
    h = np.asarray(measure.map(data.n_samples)(result.x_predicted.T, U.T, theta)[0], dtype=float).T
    C = output_jacobian(model, result.x_predicted[-1], U[-1], theta)
    K = result.P_predicted[-1] @ C.T @ np.linalg.inv(S[-1])
    return OneStepPredictions(data.signals[:, 0].copy(), measured, h,
                              np.sqrt(np.einsum("kjj->kj", S)), K, np.diag(K @ C).copy(), "the last sample",
                              tuple(model.state_names), tuple(model.output_names))


def gain_predictions(model, data, innovations: np.ndarray, S: np.ndarray, K: np.ndarray,
                     C: np.ndarray) -> OneStepPredictions:
    """The record of a one-gain filter (steady-state or innovation form): its innovations, one
    innovation covariance for every sample, and its gain with the Jacobian it was formed with.

    Parameters
    ----------
    model : DynamicModel
    data : Dataset
    innovations : ndarray, shape (N, n_outputs)
    S : ndarray, shape (n_outputs, n_outputs)
        The innovation covariance.
    K : ndarray, shape (n_states, n_outputs)
    C : ndarray, shape (n_outputs, n_states)

    Returns
    -------
    OneStepPredictions
    """
    measured = np.asarray(data.outputs, dtype=float)
    N = measured.shape[0]
    std = np.tile(np.sqrt(np.diag(np.asarray(S, dtype=float))), (N, 1))
    K, C = np.asarray(K, dtype=float), np.asarray(C, dtype=float)
    return OneStepPredictions(data.signals[:, 0].copy(), measured, measured - np.asarray(innovations),
                              std, K, np.diag(K @ C).copy(), "the operating point", tuple(model.state_names),
                              tuple(model.output_names))
