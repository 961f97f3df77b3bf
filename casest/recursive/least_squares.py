"""Recursive estimation from the same symbolic model.

- :class:`ParameterEKF`: an extended (optionally iterated) Kalman filter whose state is the
  parameter vector, constant (xi' = 0) or a random walk, with the measurement model
  linearised by CasADi Jacobians (paper end of Sec. II; reference summary Sec. 3.2-3.3,
  Eq. 3.12-3.18), through the measurement update of the state filters
  (:func:`casest.filters.filter_records.measurement_update`: Joseph form, missing channels skipped). It is
  seeded from an :class:`~casest.Estimate` or from stage 1 on an initial window
  (:func:`casest.two_stage.seed_from_stage1`).
- :class:`RecursiveLeastSquares`: xi1 at fixed xi2 (reference summary Sec. 4.3,
  Eq. 4.12-4.14), inverting either the q x q information matrix (Eq. 4.13) or the n x n
  innovation matrix (Eq. 4.14).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..checks import noise_variances
from ..backend.sums import prediction_and_jacobian
from ..data.dataset import Dataset
from ..errors import OptionError
from ..estimation.uncertainty import std_from_covariance
from ..problem.separate import Partition
from ..models import Model
from ..filters.ekf import measurement_update
from ..options import Inversion


__all__ = ["FilterHistory", "ParameterEKF", "RecursiveLeastSquares"]


@dataclass
class FilterHistory:
    """Estimates after each processed chunk.

    Attributes
    ----------
    index : ndarray, shape (M,)
        Number of samples processed when the row was recorded.
    theta : ndarray, shape (M, n_parameters)
    std : ndarray, shape (M, n_parameters)
    iterations : ndarray, shape (M,)
        Measurement-update iterations used (1 for the plain EKF).
    """

    index: np.ndarray
    theta: np.ndarray
    std: np.ndarray
    iterations: np.ndarray


class ParameterEKF:
    """EKF / iterated EKF over the parameter vector of a casest model.

    State: theta (n_parameters). Time update: theta^- = theta, P^- = P + Q, with Q the
    random-walk variance per processed sample (zero for constant parameters).
    Measurement update for a chunk of m samples (stacked, R block-diagonal):
    the EKF step Eq. 3.12-3.14, or the iterated step Eq. 3.15 repeated until
    ``|eta_l - eta_{l-1}| / |eta_{l-1}| <= tol`` (Eq. 3.16), with the Joseph-form
    covariance Eq. 3.18 at the last iterate.

    Parameters
    ----------
    model : Model
    theta0 : array_like, shape (n_parameters,)
        Initial estimate (physical units).
    P0 : array_like, shape (n_parameters, n_parameters)
        Initial covariance.
    R : array_like, shape (n_outputs,)
        Measurement-noise variances.
    process_noise : array_like, shape (n_parameters,), optional
        Random-walk variance added to P per sample (slowly drifting parameters).
    iterated : bool
        Iterated EKF (default) or plain EKF.
    tol : float
        Relative stopping tolerance of the iterations (Eq. 3.16).
    max_iterations : int
    """

    def __init__(self, model: Model, theta0, P0, R, process_noise=None, iterated: bool = True,
                 tol: float = 1e-10, max_iterations: int = 20):
        self.model = model
        self.theta = model.vector(theta0).copy()
        self.P = np.array(P0, dtype=float).reshape(model.n_parameters, model.n_parameters)
        self.R = noise_variances(R, model.output_names)
        q = np.zeros(model.n_parameters) if process_noise is None else np.asarray(process_noise, dtype=float)
        self.Q = np.diag(q.reshape(model.n_parameters))
        self.iterated, self.tol, self.max_iterations = iterated, tol, max_iterations
        self.n_processed = 0

    @classmethod
    def from_estimate(cls, model: Model, estimate, R=None, inflate: float = 1.0, **kw) -> "ParameterEKF":
        """Seed with an :class:`~casest.Estimate`'s values and covariance (times ``inflate``).

        Parameters without a std (on a bound) get the variance of their prior spread.

        Parameters
        ----------
        model : Model
        estimate : Estimate
        R : array_like, shape (n_outputs,), optional
            Default the estimate's R.
        inflate : float
            Factor on the covariance.
        **kw
            Further arguments of :class:`ParameterEKF`.

        Returns
        -------
        ParameterEKF
        """
        names = tuple(getattr(estimate, "parameter_names", ()))
        if names != tuple(model.parameter_names) or tuple(estimate.output_names) != tuple(model.output_names):
            raise OptionError(f"the estimate is of parameters {list(names)} and outputs {list(estimate.output_names)}, "
                              f"the model has {list(model.parameter_names)} and {list(model.output_names)}: seed the "
                              "filter with an estimate of this model")
        P = np.array(estimate.covariance, dtype=float)
        missing = ~np.isfinite(np.diag(P))
        P[~np.isfinite(P)] = 0.0
        P[missing, missing] = model.scales[missing] ** 2
        return cls(model, estimate.theta, inflate * P, estimate.R if R is None else R, **kw)

    def _evaluate(self, signals: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return prediction_and_jacobian(self.model, signals, theta)  # sample-major rows

    def update(self, signals: np.ndarray, outputs: np.ndarray) -> int:
        """Process a chunk of samples; returns the iterations used (0: nothing measured).

        Missing outputs (NaN) are skipped channel by channel.

        Parameters
        ----------
        signals : ndarray, shape (m, n_signals)
        outputs : ndarray, shape (m, n_outputs)

        Returns
        -------
        int
        """
        signals = np.atleast_2d(np.asarray(signals, dtype=float))
        outputs = np.atleast_2d(np.asarray(outputs, dtype=float))
        m = signals.shape[0]
        if not np.all(np.isfinite(signals)):
            raise OptionError("the signals contain NaN or inf: the measurement model cannot be evaluated there")
        P_prior = self.P + m * self.Q
        self.theta, self.P, _, _, _, iterations = measurement_update(
            self.theta.copy(), P_prior, outputs.reshape(-1), lambda theta: self._evaluate(signals, theta),
            np.diag(np.tile(self.R, m)), self.iterated, self.tol, self.max_iterations)
        self.n_processed += m
        return iterations

    def run(self, data: Dataset, chunk: int = 1, record_every: int = 1) -> FilterHistory:
        """Process a whole dataset in chunks of ``chunk`` samples and record the estimates.

        Parameters
        ----------
        data : Dataset
        chunk : int
            Samples per update.
        record_every : int
            Record the estimate every this many updates.

        Returns
        -------
        FilterHistory
        """
        data.check_model(self.model)
        idx, thetas, stds, its = [], [], [], []
        for k, start in enumerate(range(0, data.n_samples, chunk)):
            stop = min(start + chunk, data.n_samples)
            it = self.update(data.signals[start:stop], data.outputs[start:stop])
            if k % record_every == 0 or stop == data.n_samples:
                idx.append(self.n_processed)
                thetas.append(self.theta.copy())
                stds.append(std_from_covariance(self.P))
                its.append(it)
        return FilterHistory(np.array(idx), np.array(thetas), np.array(stds), np.array(its))

    @property
    def std(self) -> np.ndarray:
        """Current standard deviations, shape (n_parameters,) (NaN where rounding has made P indefinite)."""
        return std_from_covariance(self.P)


class RecursiveLeastSquares:
    """Recursive least squares for xi1 at fixed xi2 (reference summary Eq. 4.12-4.14).

    The measurement of sample k is ``y_k = z_k - b(x_k, xi2) = A(x_k, xi2) xi1 + e_k`` with
    weight ``W = diag(weights)`` (e.g. R). Until the information matrix
    ``R_info(k) = sum H' W^-1 H`` has full rank, information is accumulated and the
    estimate is the batch solution; from then on each sample updates it by Eq. 4.12 with
    ``R_info^-1`` from Eq. 4.13 (``inversion="parameters"``, a q x q inverse) or Eq. 4.14
    (``inversion="measurements"``, an n x n inverse).

    Parameters
    ----------
    model : Model
    partition : Partition
    xi2 : array_like, shape (n2,)
    weights : array_like, shape (n_outputs,)
        Diagonal of W.
    inversion : {"parameters", "measurements"}
    """

    def __init__(self, model: Model, partition: Partition, xi2, weights=None, inversion: Inversion = "parameters"):
        if inversion not in ("parameters", "measurements"):
            raise OptionError("inversion must be 'parameters' (Eq. 4.13) or 'measurements' (Eq. 4.14)")
        self.model, self.partition, self.inversion = model, partition, inversion
        self.xi2 = np.asarray(xi2, dtype=float).reshape(partition.n_nonlinear)
        w = np.ones(model.n_outputs) if weights is None else np.asarray(weights, dtype=float)
        self.W_inv = 1.0 / w
        q = partition.n_linear
        self.info = np.zeros((q, q))
        self.info_rhs = np.zeros(q)
        self.p = np.full(q, np.nan)
        self.info_inv = None
        self.n_processed = 0

    def _rows(self, signals):
        A = np.asarray(self.partition.A(signals, self.xi2)).reshape(self.model.n_outputs, -1)
        b = np.asarray(self.partition.b(signals, self.xi2)).reshape(-1)
        return A, b

    def update(self, signals: np.ndarray, outputs: np.ndarray) -> np.ndarray:
        """Process one sample (signals (n_signals,), outputs (n_outputs,)); returns xi1.

        Parameters
        ----------
        signals : ndarray, shape (n_signals,)
        outputs : ndarray, shape (n_outputs,)

        Returns
        -------
        ndarray, shape (n1,)
        """
        H, b = self._rows(np.asarray(signals, dtype=float))
        y = np.asarray(outputs, dtype=float).reshape(-1) - b
        self.n_processed += 1
        if self.info_inv is None:
            self.info += (H.T * self.W_inv) @ H
            self.info_rhs += (H.T * self.W_inv) @ y
            if np.linalg.matrix_rank(self.info) == len(self.p):
                self.info_inv = np.linalg.inv(self.info)
                self.p = self.info_inv @ self.info_rhs
            return self.p
        if self.inversion == "parameters":  # Eq. 4.13: q x q inverse
            self.info = self.info + (H.T * self.W_inv) @ H
            self.info_inv = np.linalg.inv(self.info)
        else:  # Eq. 4.14: n x n inverse
            Rinv = self.info_inv
            S = H @ Rinv @ H.T + np.diag(1.0 / self.W_inv)
            self.info_inv = Rinv - Rinv @ H.T @ np.linalg.solve(S, H @ Rinv)
        self.p = self.p + self.info_inv @ (H.T * self.W_inv) @ (y - H @ self.p)  # Eq. 4.12
        return self.p

    def run(self, data: Dataset) -> np.ndarray:
        """Process every sample; returns the final xi1, shape (n1,).

        Parameters
        ----------
        data : Dataset

        Returns
        -------
        ndarray, shape (n1,)
        """
        for k in range(data.n_samples):
            self.update(data.signals[k], data.outputs[k])
        return self.p
