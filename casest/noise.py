"""Noise models of the measurement ``z = h + v``: unknown diagonal R (the default) or known R."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from .model import Model, ModelError

__all__ = ["KnownNoise", "CorrelatedNoise"]


@dataclass(frozen=True)
class KnownNoise:
    """Known, independent measurement noise: one standard deviation per output channel.

    With a known R the ML cost has no ln|R| term to estimate: stage 1 ranks candidates by
    the weighted residuals (weights 1/R), stage 2 is the weighted least squares, and the
    standard deviations come from the given R.

    Parameters
    ----------
    std : mapping of str to float
        Output name -> noise standard deviation (output unit, > 0). Every output must be
        given.

    Examples
    --------
    >>> casest.estimate(model, data, noise=casest.KnownNoise({"z": 0.3}))  # doctest: +SKIP
    """

    std: Mapping[str, float]

    def variances(self, model: Model) -> np.ndarray:
        """The diagonal of R in the model's output order, shape (n_outputs,), output unit squared.

        Raises
        ------
        ModelError
            A missing or unknown output name, or a std that is not positive and finite.
        """
        std = dict(self.std)
        unknown = [k for k in std if k not in model.output_names]
        missing = [k for k in model.output_names if k not in std]
        if unknown or missing:
            raise ModelError(
                f"KnownNoise needs one std per output {list(model.output_names)}"
                + (f"; unknown: {unknown}" if unknown else "") + (f"; missing: {missing}" if missing else "")
            )
        values = []
        for name in model.output_names:
            value = std[name]
            if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)) \
                    or not math.isfinite(value) or value <= 0:
                raise ModelError(f"KnownNoise: the std of {name!r} must be a positive finite number, got {value!r}")
            values.append(float(value) ** 2)
        return np.array(values)

    def describe(self, model: Model) -> str:
        """One line for reports."""
        return "known R (" + ", ".join(f"{n}: std {s:.6g}" for n, s in zip(model.output_names, np.sqrt(self.variances(model)))) + ")"


@dataclass(frozen=True)
class CorrelatedNoise:
    """Unknown noise with a full covariance R (correlated channels), estimated with theta.

    R = L L' with L lower triangular and log-parametrised diagonal (log-Cholesky); stage 2
    runs in full mode with the exact Hessian in (theta, L), and the standard deviations
    account for R being estimated. Needs complete data (no missing outputs).
    """

    def describe(self, model: Model) -> str:
        """One line for reports."""
        return "unknown full R (estimated, log-Cholesky)"

