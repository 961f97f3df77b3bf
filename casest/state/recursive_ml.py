"""Recursive maximum likelihood (summary Sec. 5.3, Eq. 5.10-5.13) for a static measurement model.

The parameters theta and the noise covariance R (diagonal, as ``rho = ln R``) are estimated
online: each new sample adds its terms to the gradient and to the Gauss-Newton / Fisher matrix
of the ML cost V (Eq. 5.7), and one Newton step (Eq. 5.8 with alpha = 1) moves the estimate.
For a static model the prediction error is ``e = y - h(x, theta)`` and ``Lambda = R = diag(exp
rho)``, so Eq. 5.12-5.13 are ``eta_j = 1`` and ``mu_j = e_j^2 / R_j`` on the ``rho_j`` entries,
and ``1/2 eta eta'`` of Eq. 5.11 is the Fisher information of ``rho`` (one half per sample and
channel). As in every recursive prediction-error method, the gradient of the past samples at
the current estimate is taken as zero (the estimate minimised it), so only the new sample's
gradient drives the step; after many samples the estimate approaches the batch ML one.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from ..backend.sums import prediction_and_jacobian
from ..data.dataset import Dataset
from ..models import Model, OptionError

__all__ = ["RecursiveML"]


class RecursiveML:
    """Online ML of theta and a diagonal R from one sample (or a block) at a time.

    Parameters
    ----------
    model : Model
    theta0 : array_like, shape (n_parameters,)
        The start (physical units).
    R0 : array_like, shape (n_outputs,)
        The start of the noise variances (unit of each output squared), > 0.
    information0 : array_like, shape (n + n_outputs,) or (n + n_outputs, n + n_outputs), optional
        The initial information matrix of [theta; ln R] (the inverse of the start's covariance);
        default 1e-6 on the diagonal (an almost flat prior).

    Attributes
    ----------
    theta : ndarray, shape (n_parameters,)
    R : ndarray, shape (n_outputs,)
    information : ndarray
        The accumulated Gauss-Newton matrix of Eq. 5.11 (its inverse: the covariance of [theta; ln R]).
    n_samples : int
    """

    def __init__(self, model: Model, theta0, R0, information0=None):
        if not isinstance(model, Model):
            raise OptionError("RecursiveML takes a static casest.Model (h(x, theta) per sample)")
        self.model = model
        n, ny = model.n_parameters, model.n_outputs
        self.theta = np.asarray(model.vector(theta0) if isinstance(theta0, Mapping) else theta0, dtype=float).copy()
        R0 = np.broadcast_to(np.asarray(R0, dtype=float), (ny,))
        if self.theta.shape != (n,) or not np.all(np.isfinite(self.theta)):
            raise OptionError(f"theta0 must be {n} finite values")
        if np.any(~np.isfinite(R0)) or np.any(R0 <= 0):
            raise OptionError("R0 must be positive and finite for every output")
        self.rho = np.log(R0)
        info = np.full(n + ny, 1e-6) if information0 is None else np.asarray(information0, dtype=float)
        self.information = np.diag(info) if info.ndim == 1 else info.copy()
        if self.information.shape != (n + ny, n + ny):
            raise OptionError(f"information0 must be ({n + ny},) or ({n + ny}, {n + ny})")
        self.n_samples = 0

    @property
    def R(self) -> np.ndarray:
        """The current noise variances, shape (n_outputs,)."""
        return np.exp(self.rho)

    @property
    def std(self) -> np.ndarray:
        """Standard deviations of theta from the accumulated information, shape (n_parameters,)."""
        cov = np.linalg.inv(self.information)
        return np.sqrt(np.maximum(np.diag(cov)[: self.model.n_parameters], 0.0))

    def update(self, signals: np.ndarray, outputs: np.ndarray) -> None:
        """Add samples (rows of ``signals``, shape (m, n_signals); ``outputs`` (m, n_outputs)) and take one
        Newton step of Eq. 5.8 with the gradient (Eq. 5.10) and information (Eq. 5.11) of the new samples."""
        X = np.atleast_2d(np.asarray(signals, dtype=float))
        Y = np.atleast_2d(np.asarray(outputs, dtype=float))
        n, ny = self.model.n_parameters, self.model.n_outputs
        h, J = prediction_and_jacobian(self.model, X, self.theta)
        e = (Y - h.reshape(-1, ny))                             # prediction errors (Eq. 5.3), (m, ny)
        de = -J.reshape(-1, ny, n)                                # d e / d theta
        R = self.R
        grad = np.zeros(n + ny)
        grad[:n] = np.einsum("kjn,kj->n", de, e / R)             # d e' Lambda^-1 e / 2 d theta
        grad[n:] = 0.5 * np.sum(1.0 - e**2 / R, axis=0)          # 1/2 (eta - mu) on ln R_j (Eq. 5.12-5.13)
        self.information[:n, :n] += np.einsum("kjn,kjm,j->nm", de, de, 1.0 / R)
        self.information[n:, n:] += np.diag(np.full(ny, 0.5 * len(e)))   # 1/2 eta eta' per sample
        step = np.linalg.solve(self.information, grad)
        self.theta = np.clip(self.theta - step[:n], self.model.lower_bounds, self.model.upper_bounds)
        self.rho = self.rho - step[n:]
        self.n_samples += len(e)

    def run(self, data: Dataset, block: int = 1) -> np.ndarray:
        """Feed a record ``block`` samples at a time; returns theta after each block, shape (n_blocks, n)."""
        history = []
        for start in range(0, data.n_samples, block):
            self.update(data.signals[start:start + block], data.outputs[start:start + block])
            history.append(self.theta.copy())
        return np.array(history)
