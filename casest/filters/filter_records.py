"""The records of a filter pass and the measurement updates shared by the filters: the
:class:`FilterResult` and :class:`SmootherResult` of a record, the Joseph-form update with
missing channels skipped (summary Eq. 2.9-2.11) and the EKF / IEKF update (Eq. 3.12-3.18)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..models import OptionError
from .compiled_passes import singular_innovation


__all__ = ["FilterResult", "SmootherResult", "measurement_update", "joseph_update", "FilterRecorder", "LOG_2PI"]

LOG_2PI = float(np.log(2.0 * np.pi))

@dataclass
class FilterResult:
    """A filter's pass over a record of N samples.

    Attributes
    ----------
    x_predicted, P_predicted : ndarray, shapes (N, n) and (N, n, n)
        x(k|k-1) and P(k|k-1); row 0 is the initial (prior) state.
    x_filtered, P_filtered : ndarray, shapes (N, n) and (N, n, n)
        x(k|k) and P(k|k).
    transition : ndarray, shape (N-1, n, n)
        Phi(k+1, k) used from sample k to k+1.
    innovation : ndarray, shape (N, n_outputs)
        y(k) - y(k|k-1) (NaN where the channel is missing).
    innovation_covariance : ndarray, shape (N, n_outputs, n_outputs)
        Its covariance H P(k|k-1) H' + R (all channels).
    iterations : ndarray, shape (N,)
        Measurement-update iterations (1 for the plain filters, 0 without a measurement).
    log_likelihood : float
        ln p(y_0 .. y_N-1) of the measured channels from the prediction errors (Eq. 5.6 with
        its constants): ``-1/2 sum (e' S^-1 e + ln det S + q_k ln 2 pi)``.
    buffers : tuple or None
        The compiled pass's own arrays, which the arrays above view (``(accs, fields)``); a
        later pass over a record of the same length writes into them when this result is given
        as its ``out`` (:meth:`casest.filters.model_filter.ModelFilter.filter`). None for a
        pass step by step.
    """

    x_predicted: np.ndarray
    P_predicted: np.ndarray
    x_filtered: np.ndarray
    P_filtered: np.ndarray
    transition: np.ndarray
    innovation: np.ndarray
    innovation_covariance: np.ndarray
    iterations: np.ndarray
    log_likelihood: float
    state_names: tuple = ()
    output_names: tuple = ()
    time: np.ndarray | None = field(default=None, repr=False)
    buffers: tuple | None = field(default=None, repr=False, compare=False)

    @property
    def std(self) -> np.ndarray:
        """Filtered state standard deviations, shape (N, n)."""
        return np.sqrt(np.maximum(np.diagonal(self.P_filtered, axis1=1, axis2=2), 0.0))

    def nees(self, truth: np.ndarray) -> np.ndarray:
        """Normalised estimation error squared of the filtered states, shape (N,).

        ``truth`` (N, n): the true states. For a consistent filter each value is chi-square
        distributed with n degrees of freedom.

        Parameters
        ----------
        truth : ndarray, shape (N, n)

        Returns
        -------
        ndarray, shape (N,)
        """
        return _nees(self.x_filtered, self.P_filtered, truth)


@dataclass
class SmootherResult:
    """x(k|N) and P(k|N) of the fixed-interval smoother, shapes (N, n) and (N, n, n); with the
    process noise given, also its smoothed values w(k|N), shape (N-1, p), and covariances
    Q(k|N), shape (N-1, p, p) (Eq. 2.21, 2.23; None otherwise).

    Attributes
    ----------
    x : ndarray, shape (N, n)
        x(k|N).
    P : ndarray, shape (N, n, n)
        P(k|N).
    state_names : tuple of str
    w : ndarray, shape (N-1, p), or None
        w(k|N).
    Q : ndarray, shape (N-1, p, p), or None
        Q(k|N).
    """

    x: np.ndarray
    P: np.ndarray
    state_names: tuple = ()
    w: np.ndarray | None = None
    Q: np.ndarray | None = None

    @property
    def std(self) -> np.ndarray:
        """Smoothed state standard deviations, shape (N, n)."""
        return np.sqrt(np.maximum(np.diagonal(self.P, axis1=1, axis2=2), 0.0))

    def nees(self, truth: np.ndarray) -> np.ndarray:
        """Normalised estimation error squared of the smoothed states, shape (N,).

        Parameters
        ----------
        truth : ndarray, shape (N, n)

        Returns
        -------
        ndarray, shape (N,)
        """
        return _nees(self.x, self.P, truth)


def _nees(x: np.ndarray, P: np.ndarray, truth: np.ndarray) -> np.ndarray:
    err = np.asarray(truth, dtype=float) - x
    if err.shape != x.shape:
        raise OptionError(f"truth must have shape {x.shape}, got {np.shape(truth)}")
    return np.einsum("ki,ki->k", err, np.linalg.solve(P, err[:, :, None])[:, :, 0])


def joseph_update(x, P, y, h, H, R):
    """Measurement update with the measured channels of one sample (NaN in y: skipped).

    Returns x(k|k), P(k|k), the innovation (NaN where missing), S (all channels) and the
    sample's log-likelihood term.
    """
    ny = len(y)
    e = y - h
    S_full = H @ P @ H.T + R
    seen = np.isfinite(y)
    if not seen.any():
        return x, P, np.full(ny, np.nan), S_full, 0.0
    Ho, eo = H[seen], e[seen]
    S = S_full[np.ix_(seen, seen)]
    sign, logdet = np.linalg.slogdet(S)
    if sign <= 0 or not np.isfinite(logdet):
        raise singular_innovation()
    K = np.linalg.solve(S, Ho @ P).T  # P H' S^-1 (S symmetric)
    x_new = x + K @ eo
    I_KH = np.eye(len(x)) - K @ Ho
    P_new = I_KH @ P @ I_KH.T + K @ R[np.ix_(seen, seen)] @ K.T
    loglik = -0.5 * (eo @ np.linalg.solve(S, eo) + logdet + seen.sum() * LOG_2PI)
    return x_new, 0.5 * (P_new + P_new.T), np.where(seen, e, np.nan), S_full, loglik


def measurement_update(prior, P_prior, y, measure, R, iterated: bool = False, tol: float = 1e-8,
                       max_iterations: int = 20):
    """The EKF / IEKF measurement update (Eq. 3.12-3.14, or 3.15-3.18), NaN channels skipped.

    Parameters
    ----------
    prior : ndarray, shape (n,)
        x(k|k-1).
    P_prior : ndarray, shape (n, n)
    y : ndarray, shape (q,)
        Measurements (NaN: missing).
    measure : callable
        ``measure(x) -> (h, H)``: the predicted measurement (q,) and its Jacobian (q, n).
    R : ndarray, shape (q, q)
    iterated : bool
        Repeat the update linearised at the last iterate until the relative change of
        Eq. 3.16 is at most ``tol``; the covariance is Eq. 3.18's at the last iterate.

    Returns
    -------
    x, P, innovation (q,), S (q, q), log-likelihood term, iterations (0: nothing measured)
    """
    h, H = measure(prior)
    if not np.isfinite(y).any():
        return prior, P_prior, np.full(y.size, np.nan), H @ P_prior @ H.T + R, 0.0, 0
    x, P, e, S, ll = joseph_update(prior, P_prior, y, h, H, R)
    iterations = 1
    if iterated:
        eta = prior
        for iterations in range(1, max_iterations + 1):
            h_i, H_i = measure(eta)
            # Eq. 3.15: the measurement linearised at eta, applied to the prior
            new, P, _, _, _ = joseph_update(prior, P_prior, y, h_i + H_i @ (prior - eta), H_i, R)
            change = np.linalg.norm(new - eta) / max(np.linalg.norm(eta), 1e-300)
            eta = new
            if change <= tol:
                break
        h_l, H_l = measure(eta)  # Eq. 3.18 at the last iterate
        _, P, _, _, _ = joseph_update(prior, P_prior, y, h_l + H_l @ (prior - eta), H_l, R)
        x = eta
    return x, P, e, S, ll, iterations


class FilterRecorder:
    """Arrays of a filter pass, filled sample by sample."""

    def __init__(self, N: int, n: int, q: int, state_names=(), output_names=(), time=None):
        self.xp, self.Pp = np.empty((N, n)), np.empty((N, n, n))
        self.xf, self.Pf = np.empty((N, n)), np.empty((N, n, n))
        self.transition = np.empty((max(N - 1, 0), n, n))
        self.e, self.S = np.empty((N, q)), np.empty((N, q, q))
        self.iterations = np.zeros(N, dtype=int)
        self.loglik = 0.0
        self.names = (tuple(state_names), tuple(output_names))
        self.time = time

    def prior(self, k, x, P):
        self.xp[k], self.Pp[k] = x, P

    def posterior(self, k, x, P, e, S, loglik, iterations):
        self.xf[k], self.Pf[k], self.e[k], self.S[k] = x, P, e, S
        self.loglik += loglik
        self.iterations[k] = iterations

    def result(self) -> FilterResult:
        return FilterResult(self.xp, self.Pp, self.xf, self.Pf, self.transition, self.e, self.S, self.iterations,
                            float(self.loglik), self.names[0], self.names[1], self.time)
