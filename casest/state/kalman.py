"""The discrete-time linear Kalman filter of the reference summary Sec. 2 (Eq. 2.1-2.13),
with constant or time-varying Phi(k), Psi(k) and C(k)."""

from __future__ import annotations

import numpy as np

from ..data.dataset import DataError
from ..models import OptionError
from .arguments import covariance_argument as _covariance, matrix_argument as _matrix
from .compiled_passes import kf_pass
from .filter_records import FilterRecorder, FilterResult, joseph_update


__all__ = ["KalmanFilter"]


class KalmanFilter:
    """The discrete-time Kalman filter of Eq. 2.1-2.11.

    ::

        x(k+1) = Phi x(k) + Psi u(k) + Gamma w(k),   cov w = Q
        y(k)   = C x(k) + D u(k) + v(k),             cov v = R

    Parameters
    ----------
    Phi : array_like, shape (n, n)
    C : array_like, shape (q, n)
    Q : array_like, shape (p, p) or (p,)
        Process-noise covariance (a vector: its diagonal).
    R : array_like, shape (q, q) or (q,)
        Measurement-noise covariance.
    x0 : array_like, shape (n,)
        Prior mean of the state at the first sample, x(0|-1).
    P0 : array_like, shape (n, n) or (n,)
        Its covariance.
    Psi : array_like, shape (n, m), optional
        Input matrix (default: no input).
    D : array_like, shape (q, m), optional
        Feed-through.
    Gamma : array_like, shape (n, p), optional
        Process-noise input (default identity, p = n).

    Notes
    -----
    Step by step: :meth:`update` with y(k) then :meth:`predict` with u(k) gives
    x(k+1|k); :meth:`filter` runs a whole record the same way (the first sample is updated
    from the prior ``x0, P0``).
    """

    def __init__(self, Phi, C, Q, R, x0, P0, Psi=None, D=None, Gamma=None):
        self.Phi = np.atleast_2d(np.asarray(Phi, dtype=float))
        n = self.Phi.shape[0]
        self.Phi = _matrix(self.Phi, (n, n), "Phi")
        self.C = np.atleast_2d(np.asarray(C, dtype=float))
        q = self.C.shape[0]
        self.C = _matrix(self.C, (q, n), "C")
        self.Gamma = np.eye(n) if Gamma is None else _matrix(np.atleast_2d(Gamma), (n, np.atleast_2d(Gamma).shape[1]),
                                                              "Gamma")
        self.Q = _covariance(Q, self.Gamma.shape[1], "Q")
        self.R = _covariance(R, q, "R")
        m = 0 if Psi is None else np.atleast_2d(np.asarray(Psi, dtype=float)).reshape(n, -1).shape[1]
        self.Psi = np.zeros((n, m)) if Psi is None else _matrix(np.asarray(Psi, dtype=float).reshape(n, m), (n, m), "Psi")
        self.D = np.zeros((q, m)) if D is None else _matrix(np.asarray(D, dtype=float).reshape(q, m), (q, m), "D")
        self.n_states, self.n_outputs, self.n_inputs = n, q, m
        self.x = _matrix(np.asarray(x0, dtype=float).reshape(-1), (n,), "x0").copy()
        self.P = _covariance(P0, n, "P0").copy()

    def _u(self, u) -> np.ndarray:
        if self.n_inputs == 0:
            return np.zeros(0)
        arr = np.asarray(u, dtype=float).reshape(-1)
        if arr.size != self.n_inputs:
            raise OptionError(f"u must have {self.n_inputs} values, got {arr.size}")
        return arr

    def predict(self, u=None) -> tuple[np.ndarray, np.ndarray]:
        """Time update (Eq. 2.7-2.8): x(k+1|k), P(k+1|k) from x(k|k), P(k|k) and u(k)."""
        self.x = self.Phi @ self.x + self.Psi @ self._u(u)
        self.P = self.Phi @ self.P @ self.Phi.T + self.Gamma @ self.Q @ self.Gamma.T
        return self.x, self.P

    def update(self, y, u=None) -> tuple[np.ndarray, np.ndarray]:
        """Measurement update (Eq. 2.9-2.11, Joseph form); NaN channels of y are skipped."""
        y = np.asarray(y, dtype=float).reshape(-1)
        h = self.C @ self.x + self.D @ self._u(u)
        self.x, self.P, *_ = joseph_update(self.x, self.P, y, h, self.C, self.R)
        return self.x, self.P

    def predict_ahead(self, steps: int, u=None) -> tuple[np.ndarray, np.ndarray]:
        """Prediction i = 1..steps samples ahead of the current state (Eq. 2.12-2.13).

        ``u``: shape (steps, m) future inputs, or one input (m,) held (the summary's
        u(k+i) = u(k)), default zero. Returns means (steps, n) and covariances
        (steps, n, n); the filter's state is left unchanged.
        """
        U = np.zeros((steps, self.n_inputs)) if u is None else np.asarray(u, dtype=float)
        U = np.broadcast_to(U.reshape(-1, self.n_inputs) if U.ndim > 1 else U.reshape(1, -1), (steps, self.n_inputs))
        x, P = self.x.copy(), self.P.copy()
        xs, Ps = [], []
        GQG = self.Gamma @ self.Q @ self.Gamma.T
        for i in range(steps):
            x = self.Phi @ x + self.Psi @ U[i]
            P = self.Phi @ P @ self.Phi.T + GQG
            xs.append(x)
            Ps.append(P)
        return np.array(xs), np.array(Ps)

    def filter(self, y, u=None, compiled: bool = True) -> FilterResult:
        """Run over a record from the current state (the prior of the first sample).

        Parameters
        ----------
        y : array_like, shape (N, q)
            Measurements (NaN: missing channel).
        u : array_like, shape (N, m), optional
            Inputs; u(k) enters y(k) through D and x(k+1) through Psi.
        compiled : bool
            One compiled recursion over the record (:func:`casest.state.compiled_passes.kf_pass`);
            False: :meth:`update` and :meth:`predict` from Python. The same arrays either way.

        Returns
        -------
        FilterResult
            The filter's state afterwards is the last sample's x(k|k), P(k|k).
        """
        Y = np.atleast_2d(np.asarray(y, dtype=float))
        N = Y.shape[0]
        if Y.shape[1] != self.n_outputs:
            raise OptionError(f"y must have shape (N, {self.n_outputs}), got {Y.shape}")
        U = np.zeros((N, 0)) if self.n_inputs == 0 else np.asarray(u, dtype=float).reshape(N, self.n_inputs)
        if not np.all(np.isfinite(U)):
            raise DataError("the inputs u contain NaN or inf: the state cannot be propagated without them")
        if compiled and N:
            arrays = kf_pass(self, Y, U)
            self.x, self.P = arrays["x_filtered"][-1].copy(), arrays["P_filtered"][-1].copy()
            return FilterResult(**arrays)
        rec = FilterRecorder(N, self.n_states, self.n_outputs)
        for k in range(N):
            rec.prior(k, self.x, self.P)
            h = self.C @ self.x + self.D @ U[k]
            self.x, self.P, e, S, ll = joseph_update(self.x, self.P, Y[k], h, self.C, self.R)
            rec.posterior(k, self.x, self.P, e, S, ll, int(np.isfinite(Y[k]).any()))
            if k < N - 1:
                rec.transition[k] = self.Phi
                self.predict(U[k])
        return rec.result()
