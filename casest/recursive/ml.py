"""Recursive maximum likelihood (summary Sec. 5.3, Eq. 5.10-5.13) for a static measurement model
or a :class:`casest.DynamicModel`.

The parameters theta and the noise covariance R (diagonal, as ``rho = ln R``) are estimated
online: each new sample adds its terms to the gradient and to the Gauss-Newton / Fisher matrix
of the ML cost V (Eq. 5.7), and one Newton step (Eq. 5.8 with alpha = 1) moves the estimate.
For a static model the prediction error is ``e = y - h(x, theta)`` and ``Lambda = R = diag(exp
rho)``, so Eq. 5.12-5.13 are ``eta_j = 1`` and ``mu_j = e_j^2 / R_j`` on the ``rho_j`` entries,
and ``1/2 eta eta'`` of Eq. 5.11 is the Fisher information of ``rho`` (one half per sample and
channel). As in every recursive prediction-error method, the gradient of the past samples at
the current estimate is taken as zero (the estimate minimised it), so only the new sample's
gradient drives the step; after many samples the estimate approaches the batch ML one.

For a dynamic model the predictor is the output-error one (Sec. 5.2: the state equations taken
as deterministic, Lambda = R): the state x(k) is simulated with the current estimate and its
sensitivity S(k) = dx(k)/dtheta propagated beside it, S(k+1) = F_x S(k) + F_theta through the
model's integration step, so that de/dtheta = -(h_x S(k) + h_theta) (the recursive
prediction-error method). Its batch counterpart is the output-error estimate of
:func:`casest.estimate`.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from ..backend.sums import prediction_and_jacobian
from ..checks import check_magnitude, information_argument, noise_variances, whole_number
from ..data.dataset import Dataset
from ..errors import DataError
from ..estimation.uncertainty import std_from_information
from ..models import Model, OptionError
from ..models.dynamic import DynamicModel
from .ml_dynamic import OutputErrorPredictor

__all__ = ["RecursiveML"]


class RecursiveML:
    """Online ML of theta and a diagonal R from one sample (or a block) at a time.

    Parameters
    ----------
    model : Model or DynamicModel
        A dynamic model is predicted by output error (see the module docstring); its samples
        must arrive in time order.
    theta0 : mapping or array_like, shape (n_parameters,)
        The start (physical units).
    R0 : array_like, shape (n_outputs,)
        The start of the noise variances (unit of each output squared), > 0.
    information0 : array_like, shape (n + n_outputs,) or (n + n_outputs, n + n_outputs), optional
        The initial information matrix of [theta; ln R] (the inverse of the start's covariance);
        default 1e-6 on the diagonal (an almost flat prior).
    x0 : array_like, shape (n_states,), optional
        A dynamic model's state at the first sample; default: the model's initial state,
        taken at the start of :meth:`run` (needed before :meth:`update` otherwise).
    forgetting : float, optional
        lambda(0) of a forgetting factor that tends to one, lambda(k+1) = r lambda(k) + 1 - r
        with r = ``forgetting_rate`` (Ljung and Soderstrom's schedule): the information of the
        first samples, gathered while the estimate was still far off, is discounted. Default
        none (lambda = 1). A dynamic model started away from the optimum needs it: 0.9 with
        r = 0.995 on the short-period example.
    forgetting_rate : float
        r of the schedule (the memory of the discounting, about 1 / (1 - r) samples).

    Attributes
    ----------
    theta : ndarray, shape (n_parameters,)
    R : ndarray, shape (n_outputs,)
    information : ndarray
        The accumulated Gauss-Newton matrix of Eq. 5.11 (its inverse: the covariance of [theta; ln R]).
    n_samples : int
    """

    def __init__(self, model: Model | DynamicModel, theta0, R0, information0=None, x0=None, forgetting=None,
                 forgetting_rate: float = 0.99):
        if not isinstance(model, (Model, DynamicModel)):
            raise OptionError("RecursiveML takes a static casest.Model (h(x, theta) per sample) or a casest.DynamicModel")
        self.model = model
        self.predictor = OutputErrorPredictor(model, x0) if isinstance(model, DynamicModel) else None
        n, ny = model.n_parameters, model.n_outputs
        self.theta = np.asarray(model.vector(theta0) if isinstance(theta0, Mapping) else theta0, dtype=float).copy()
        if self.theta.shape != (n,) or not np.all(np.isfinite(self.theta)):
            raise OptionError(f"theta0 must be {n} finite values")
        R0 = noise_variances(np.broadcast_to(np.asarray(R0, dtype=float), (ny,)), model.output_names, "R0")
        self.rho = np.log(R0)
        self.information = information_argument(information0, n + ny)
        self.n_samples = 0
        self.forgetting = 1.0 if forgetting is None else float(forgetting)
        self.forgetting_rate = float(forgetting_rate)
        if not 0.0 < self.forgetting <= 1.0:
            raise OptionError(f"forgetting (lambda(0)) must lie in (0, 1] (1: no forgetting), got {forgetting!r}")
        if not 0.0 <= self.forgetting_rate < 1.0:
            raise OptionError(f"forgetting_rate must lie in [0, 1) (lambda(k) tends to 1 at this rate), got "
                              f"{forgetting_rate!r}")

    @property
    def R(self) -> np.ndarray:
        """The current noise variances, shape (n_outputs,)."""
        return np.exp(self.rho)

    @property
    def std(self) -> np.ndarray:
        """Standard deviations of theta from the accumulated information, shape (n_parameters,):
        NaN while the information is singular or indefinite."""
        return std_from_information(self.information)[: self.model.n_parameters]

    def update(self, signals: np.ndarray, outputs: np.ndarray) -> None:
        """Add samples and take one Newton step of Eq. 5.8 with the gradient (Eq. 5.10) and
        information (Eq. 5.11) of the new samples.

        Parameters
        ----------
        signals : ndarray, shape (m, n_signals)
            The samples' signals (a dynamic model's: time and inputs, in time order, continuing
            the previous call's).
        outputs : ndarray, shape (m, n_outputs)
            Their measurements; NaN: a channel not measured (it adds nothing).

        Returns
        -------
        None
        """
        X, Y = self._checked_samples(signals, outputs)
        n, ny = self.model.n_parameters, self.model.n_outputs
        if self.predictor is not None:
            h, J = self.predictor.advance(X, self.theta)
        else:
            h, J = prediction_and_jacobian(self.model, X, self.theta)
        seen = np.isfinite(Y)
        e = np.where(seen, Y - h.reshape(-1, ny), 0.0)          # prediction errors (Eq. 5.3), (m, ny)
        de = -J.reshape(-1, ny, n) * seen[:, :, None]            # d e / d theta
        R = self.R
        self.information *= self.forgetting  # the start's transient forgotten: lambda(k) -> 1
        self.forgetting = self.forgetting_rate * self.forgetting + (1.0 - self.forgetting_rate)
        grad = np.zeros(n + ny)
        grad[:n] = np.einsum("kjn,kj->n", de, e / R)             # d e' Lambda^-1 e / 2 d theta
        grad[n:] = 0.5 * np.sum(seen * (1.0 - e**2 / R), axis=0)  # 1/2 (eta - mu) on ln R_j (Eq. 5.12-5.13)
        self.information[:n, :n] += np.einsum("kjn,kjm,j->nm", de, de, 1.0 / R)
        self.information[n:, n:] += np.diag(0.5 * seen.sum(axis=0))   # 1/2 eta eta' per measured sample
        step = np.linalg.solve(self.information, grad)
        self.theta = np.clip(self.theta - step[:n], self.model.lower_bounds, self.model.upper_bounds)
        self.rho = self.rho - step[n:]
        self.n_samples += len(e)

    def _checked_samples(self, signals, outputs) -> tuple[np.ndarray, np.ndarray]:
        """The samples as (m, n_signals) and (m, n_outputs) arrays, refused with the argument named
        when their shapes, finiteness or magnitude would turn the estimate into NaN."""
        model = self.model
        for value, names, what in ((signals, model.signal_names, "signals"), (outputs, model.output_names, "outputs")):
            if np.ndim(value) == 2 and np.shape(value)[1] != len(names):
                raise DataError(f"{what} must have shape (m, {len(names)}), one column each of {list(names)}, got "
                                f"{np.shape(value)}")
        try:
            X = np.asarray(signals, dtype=float).reshape(-1, model.n_signals) if model.n_signals else \
                np.zeros((np.atleast_2d(outputs).shape[0], 0))
            Y = np.asarray(outputs, dtype=float).reshape(-1, model.n_outputs)
        except (TypeError, ValueError):
            raise DataError(f"signals must have shape (m, {model.n_signals}) {list(model.signal_names)} and outputs "
                            f"(m, {model.n_outputs}) {list(model.output_names)}, numbers only") from None
        if X.shape[0] != Y.shape[0]:
            raise DataError(f"signals have {X.shape[0]} rows but outputs have {Y.shape[0]}")
        if Y.shape[0] == 0:
            raise DataError("no samples given: signals and outputs need at least one row")
        if not np.all(np.isfinite(X)):
            raise DataError(f"signals hold NaN or infinite values at rows {np.flatnonzero(~np.isfinite(X).all(axis=1))[:5].tolist()}; "
                            "every signal must be measured (a missing output may be NaN)")
        if np.any(np.isinf(Y)):
            raise DataError("outputs hold infinite values; NaN marks a channel not measured")
        for j, name in enumerate(model.output_names):
            check_magnitude(name, Y[np.isfinite(Y[:, j]), j])
        for j, name in enumerate(model.signal_names):
            check_magnitude(name, X[:, j])
        return X, Y

    def run(self, data: Dataset, block: int = 1) -> np.ndarray:
        """Feed a record ``block`` samples at a time.

        Parameters
        ----------
        data : Dataset
            The record (a dynamic model's from its first sample: its initial state is set here
            unless ``x0`` was given).
        block : int
            Samples per Newton step.

        Returns
        -------
        ndarray, shape (n_blocks, n_parameters)
            theta after each block.
        """
        if not isinstance(data, Dataset):
            raise DataError(f"run takes a casest.Dataset of the model's record, got {type(data).__name__}")
        data.check_model(self.model)  # another model's record would be read column by column as if it were this one's
        block = whole_number(block, "block must be a positive number of samples")
        if self.predictor is not None:
            self.predictor.start(data, self.theta)
        history = []
        for start in range(0, data.n_samples, block):
            self.update(data.signals[start:start + block], data.outputs[start:start + block])
            history.append(self.theta.copy())
        return np.array(history)
