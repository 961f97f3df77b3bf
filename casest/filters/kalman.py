"""The discrete-time linear Kalman filter of the reference summary Sec. 2 (Eq. 2.1-2.13),
with constant or time-varying Phi(k), Psi(k), Gamma(k), Q(k), C(k), D(k) and R(k)."""

from __future__ import annotations

import numpy as np

from ..data.dataset import DataError
from ..models import OptionError
from ..checks import LARGEST_MAGNITUDE, covariance_argument as _covariance, finite_array, flag_argument, matrix_argument as _matrix, whole_number
from .compiled_passes import kf_pass
from .filter_records import FilterRecorder, FilterResult, joseph_update


__all__ = ["KalmanFilter"]


class KalmanFilter:
    """The discrete-time Kalman filter of Eq. 2.1-2.11, with constant or time-varying matrices.

    ::

        x(k+1) = Phi(k) x(k) + Psi(k) u(k) + Gamma(k) w(k),   cov w(k) = Q(k)
        y(k)   = C(k) x(k) + D(k) u(k) + v(k),                cov v(k) = R(k)

    Parameters
    ----------
    Phi : array_like, shape (n, n) or (K, n, n)
        The transition matrix, or one per sample: ``Phi[k]`` takes x(k) to x(k+1).
    C : array_like, shape (q, n) or (K, q, n)
        The output matrix, or one per sample: ``C[k]`` measures x(k).
    Q : array_like, shape (p, p), (p,) or (K, p, p)
        Process-noise covariance (a vector: its diagonal), or one per sample: ``Q[k]`` drives
        x(k) to x(k+1).
    R : array_like, shape (q, q), (q,) or (K, q, q)
        Measurement-noise covariance, or one per sample: ``R[k]`` is y(k)'s.
    x0 : array_like, shape (n,)
        Prior mean of the state at the first sample, x(0|-1).
    P0 : array_like, shape (n, n) or (n,)
        Its covariance.
    Psi : array_like, shape (n, m) or (K, n, m), optional
        Input matrix, or one per sample (default: no input).
    D : array_like, shape (q, m) or (K, q, m), optional
        Feed-through, or one per sample.
    Gamma : array_like, shape (n, p) or (K, n, p), optional
        Process-noise input (default identity, p = n), or one per sample.

    Notes
    -----
    Step by step: :meth:`update` with y(k) then :meth:`predict` with u(k) gives
    x(k+1|k); :meth:`filter` runs a whole record the same way (the first sample is updated
    from the prior ``x0, P0``). Time-varying matrices are indexed by the sample counter
    :attr:`sample` (0 at the start): :meth:`update` uses ``C``, ``D`` and ``R[sample]``,
    :meth:`predict` uses ``Phi``, ``Psi``, ``Gamma`` and ``Q[sample]`` and then advances the
    counter; a record of N samples needs N of the measurement's matrices and N - 1 of the
    transition's from the counter on.

    Examples
    --------
    A constant-velocity track measured in position:

    >>> import numpy as np
    >>> import casest
    >>> kf = casest.KalmanFilter(Phi=[[1.0, 0.1], [0.0, 1.0]], C=[[1.0, 0.0]], Q=[1e-4, 1e-4], R=[0.01],
    ...                          x0=[0.0, 0.0], P0=[1.0, 1.0])
    >>> y = 0.1 * np.arange(50)[:, None] * 0.1 + 0.1 * np.random.default_rng(0).standard_normal((50, 1))
    >>> result = kf.filter(y)
    >>> result.x_filtered.shape, result.P_filtered.shape
    ((50, 2), (50, 2, 2))
    >>> smoothed = casest.rts_smoother(result)

    """

    def __init__(self, Phi, C, Q, R, x0, P0, Psi=None, D=None, Gamma=None):
        self._Phi = _sequence(Phi, None, None, "Phi")  # square: checked there
        n = self._Phi.shape[1]
        self._C = _sequence(C, None, n, "C")
        q = self._C.shape[1]
        self._Gamma = np.eye(n)[None] if Gamma is None else _sequence(Gamma, n, None, "Gamma")
        self._Q = _covariances(Q, self._Gamma.shape[2], "Q")
        self._R = _covariances(R, q, "R")
        self._Psi = np.zeros((1, n, 0)) if Psi is None else _sequence(Psi, n, None, "Psi")
        m = self._Psi.shape[2]
        self._D = np.zeros((1, q, m)) if D is None else _sequence(D, q, m, "D")
        self.n_states, self.n_outputs, self.n_inputs = n, q, m
        self.x = _matrix(np.asarray(x0, dtype=float).reshape(-1), (n,), "x0").copy()
        self.P = _covariance(P0, n, "P0").copy()
        #: index k of the next measurement update (the time-varying matrices' sample)
        self.sample = 0

    @property
    def time_varying(self) -> bool:
        """Whether any matrix is given per sample."""
        return any(len(M) > 1 for M in (self._Phi, self._C, self._Psi, self._Gamma, self._Q, self._R, self._D))

    @property
    def Gamma(self) -> np.ndarray:
        """The process-noise input, shape (n, p), or the sequence, shape (K, n, p)."""
        return self._Gamma[0] if len(self._Gamma) == 1 else self._Gamma

    @property
    def Q(self) -> np.ndarray:
        """The process-noise covariance, shape (p, p), or the sequence, shape (K, p, p)."""
        return self._Q[0] if len(self._Q) == 1 else self._Q

    @property
    def R(self) -> np.ndarray:
        """The measurement-noise covariance, shape (q, q), or the sequence, shape (K, q, q)."""
        return self._R[0] if len(self._R) == 1 else self._R

    @property
    def D(self) -> np.ndarray:
        """The feed-through, shape (q, m), or the sequence, shape (K, q, m)."""
        return self._D[0] if len(self._D) == 1 else self._D

    def process_noise(self, first: int, count: int) -> np.ndarray:
        """``Gamma(k) Q(k) Gamma(k)'`` for ``count`` samples from ``first``, shape (count, n, n).

        Parameters
        ----------
        first, count : int

        Returns
        -------
        ndarray, shape (count, n, n)
        """
        G, Q = self.matrices(first, count, "Gamma"), self.matrices(first, count, "Q")
        return G @ Q @ G.transpose(0, 2, 1)

    @property
    def Phi(self) -> np.ndarray:
        """The transition matrix, shape (n, n), or the sequence, shape (K, n, n)."""
        return self._Phi[0] if len(self._Phi) == 1 else self._Phi

    @property
    def C(self) -> np.ndarray:
        """The output matrix, shape (q, n), or the sequence, shape (K, q, n)."""
        return self._C[0] if len(self._C) == 1 else self._C

    @property
    def Psi(self) -> np.ndarray:
        """The input matrix, shape (n, m), or the sequence, shape (K, n, m)."""
        return self._Psi[0] if len(self._Psi) == 1 else self._Psi

    def matrices(self, first: int, count: int, which: str) -> np.ndarray:
        """``count`` consecutive matrices from sample ``first`` of ``"Phi"``, ``"C"``, ``"Psi"``,
        ``"Gamma"``, ``"Q"``, ``"R"`` or ``"D"``.

        Parameters
        ----------
        first, count : int
            The first sample and how many.
        which : str
            The matrix.

        Returns
        -------
        ndarray, shape (count, rows, columns)
            A constant matrix repeated, or the slice of the sequence.

        Raises
        ------
        OptionError
            The sequence ends before sample ``first + count - 1``.
        """
        seq = {"Phi": self._Phi, "C": self._C, "Psi": self._Psi, "Gamma": self._Gamma, "Q": self._Q, "R": self._R,
               "D": self._D}[which]
        if len(seq) == 1:
            return np.broadcast_to(seq[0], (count,) + seq.shape[1:])
        if first + count > len(seq):
            raise OptionError(f"{which} is given for samples 0 ... {len(seq) - 1}, but sample {first + count - 1} is "
                              f"asked for: give {which} for every sample of the record (a transition matrix for each "
                              "but the last)")
        return seq[first:first + count]

    def _u(self, u) -> np.ndarray:
        if self.n_inputs == 0 or u is None:  # no input given: zero
            return np.zeros(self.n_inputs)
        arr = np.asarray(u, dtype=float).reshape(-1)
        if arr.size != self.n_inputs:
            raise OptionError(f"u must have {self.n_inputs} values, got {arr.size}")
        return arr

    def predict(self, u=None) -> tuple[np.ndarray, np.ndarray]:
        """Time update (Eq. 2.7-2.8): x(k+1|k), P(k+1|k) from x(k|k), P(k|k) and u(k).

        Parameters
        ----------
        u : array_like, shape (m,), optional
            The input u(k) (default zero).

        Returns
        -------
        x : ndarray, shape (n,)
        P : ndarray, shape (n, n)
        """
        Phi, Psi = self.matrices(self.sample, 1, "Phi")[0], self.matrices(self.sample, 1, "Psi")[0]
        self.x = Phi @ self.x + Psi @ self._u(u)
        self.P = Phi @ self.P @ Phi.T + self.process_noise(self.sample, 1)[0]
        self.sample += 1
        return self.x, self.P

    def update(self, y, u=None) -> tuple[np.ndarray, np.ndarray]:
        """Measurement update (Eq. 2.9-2.11, Joseph form); NaN channels of y are skipped.

        Parameters
        ----------
        y : array_like, shape (q,)
            The measurement y(k) (NaN: a channel not measured).
        u : array_like, shape (m,), optional
            The input u(k), through D (default zero).

        Returns
        -------
        x : ndarray, shape (n,)
        P : ndarray, shape (n, n)
        """
        y = measurements(np.asarray(y, dtype=float).reshape(1, -1), self.n_outputs)[0]
        C, D, R = (self.matrices(self.sample, 1, which)[0] for which in ("C", "D", "R"))
        h = C @ self.x + D @ self._u(u)
        self.x, self.P, *_ = joseph_update(self.x, self.P, y, h, C, R)
        return self.x, self.P

    def predict_ahead(self, steps: int, u=None) -> tuple[np.ndarray, np.ndarray]:
        """Prediction i = 1..steps samples ahead of the current state (Eq. 2.12-2.13).

        Parameters
        ----------
        steps : int
            How many samples ahead.
        u : array_like, shape (steps, m) or (m,), optional
            Future inputs, or one input held (the summary's u(k+i) = u(k)); default zero.

        Returns
        -------
        x : ndarray, shape (steps, n)
        P : ndarray, shape (steps, n, n)
            The filter's state is left unchanged.
        """
        steps = whole_number(steps, "steps must be a whole number of samples >= 1")
        U = np.zeros((steps, self.n_inputs)) if u is None else np.asarray(u, dtype=float)
        U = np.broadcast_to(U.reshape(-1, self.n_inputs) if U.ndim > 1 else U.reshape(1, -1), (steps, self.n_inputs))
        Phis, Psis = self.matrices(self.sample, steps, "Phi"), self.matrices(self.sample, steps, "Psi")
        GQG = self.process_noise(self.sample, steps)
        x, P = self.x.copy(), self.P.copy()
        xs, Ps = [], []
        for i in range(steps):
            x = Phis[i] @ x + Psis[i] @ U[i]
            P = Phis[i] @ P @ Phis[i].T + GQG[i]
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
            Inputs; u(k) enters y(k) through D and x(k+1) through Psi(k).
        compiled : bool
            One compiled recursion over the record (:func:`casest.filters.compiled_passes.kf_pass`);
            False: :meth:`update` and :meth:`predict` from Python. The same arrays either way.

        Returns
        -------
        FilterResult
            The filter's state afterwards is the last sample's x(k|k), P(k|k), and
            :attr:`sample` that sample's index.
        """
        compiled = flag_argument(compiled, "compiled")
        Y = measurements(y, self.n_outputs)
        N = Y.shape[0]
        U = np.zeros((N, 0)) if self.n_inputs == 0 else np.asarray(u, dtype=float).reshape(N, self.n_inputs)
        if not np.all(np.isfinite(U)):
            raise DataError("the inputs u contain NaN or inf: the state cannot be propagated without them")
        first, transitions = self.sample, max(N - 1, 0)
        Phis, Psis = self.matrices(first, transitions, "Phi"), self.matrices(first, transitions, "Psi")
        GQGs = self.process_noise(first, transitions)
        Cs, Ds, Rs = (self.matrices(first, N, which) for which in ("C", "D", "R"))
        if compiled and N:
            arrays = kf_pass(self, Y, U, (Phis, Cs, Psis, GQGs, Rs, Ds))
            self.x, self.P = arrays["x_filtered"][-1].copy(), arrays["P_filtered"][-1].copy()
            self.sample = first + N - 1
            return FilterResult(**arrays)
        rec = FilterRecorder(N, self.n_states, self.n_outputs)
        for k in range(N):
            rec.prior(k, self.x, self.P)
            h = Cs[k] @ self.x + Ds[k] @ U[k]
            self.x, self.P, e, S, ll = joseph_update(self.x, self.P, Y[k], h, Cs[k], Rs[k])
            rec.posterior(k, self.x, self.P, e, S, ll, int(np.isfinite(Y[k]).any()))
            if k < N - 1:
                rec.transition[k] = Phis[k]
                self.predict(U[k])
        return rec.result()


def measurements(y, n_outputs: int) -> np.ndarray:
    """The measurements (N, q) of a filter, checked: NaN marks a channel not measured; an
    infinite value or one whose square overflows double precision is refused (it is neither a
    measurement the filter can weigh nor a missing one).

    Parameters
    ----------
    y : array_like, shape (N, q) or (q,)
    n_outputs : int

    Returns
    -------
    ndarray, shape (N, q)
    """
    try:
        Y = np.atleast_2d(np.asarray(y, dtype=float))
    except (TypeError, ValueError):
        raise DataError(f"y must be an array of numbers, got {type(y).__name__}") from None
    if Y.ndim != 2 or Y.shape[1] != n_outputs:
        raise OptionError(f"y must have shape (N, {n_outputs}) (one row per sample), got {np.shape(y)}")
    finite_array(Y, "the measurements y", allow_nan=True, error=DataError)
    rows = np.flatnonzero((np.abs(np.nan_to_num(Y)) > LARGEST_MAGNITUDE).any(axis=1))
    if rows.size:
        raise DataError(f"the measurements y reach {np.nanmax(np.abs(Y)):.3g} at rows {rows[:5].tolist()}: their "
                        "squares overflow double precision; express them in a larger unit (or mark a bad sample "
                        "NaN: not measured)")
    return Y


def _sequence(value, rows, cols, name) -> np.ndarray:
    """A matrix, or one per sample, as a finite (K, rows, cols) array (K = 1: constant)."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim < 3:
        arr = np.atleast_2d(arr)
        if rows is not None and arr.shape[0] != rows and arr.size % rows == 0 and (cols is None or arr.size == rows * cols):
            arr = arr.reshape(rows, -1)  # a vector Psi of one input
        arr = arr[None]
    if arr.ndim != 3 or (name == "Phi" and arr.shape[1] != arr.shape[2]):
        raise OptionError(f"{name} must be a square matrix (n, n) or one per sample (K, n, n), got "
                          f"{np.asarray(value).shape}" if name == "Phi" else
                          f"{name} must be a matrix or one per sample (K, rows, columns), got {np.asarray(value).shape}")
    shape = (rows if rows is not None else arr.shape[1], cols if cols is not None else arr.shape[2])
    if arr.shape[1:] != shape:
        raise OptionError(f"{name} must have shape {shape} or (K, {shape[0]}, {shape[1]}) (one per sample), got "
                          f"{np.asarray(value).shape}")
    if not np.all(np.isfinite(arr)):
        raise OptionError(f"{name} has non-finite entries")
    return arr


def _covariances(value, n: int, name: str) -> np.ndarray:
    """A covariance (n, n) or its diagonal (n,), or one per sample (K, n, n), as a (K, n, n) array
    of symmetric positive semi-definite matrices (K = 1: constant)."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim < 3:
        return _covariance(arr, n, name)[None]
    if arr.shape[1:] != (n, n):
        raise OptionError(f"{name} must have shape ({n}, {n}), ({n},) or (K, {n}, {n}) (one per sample), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise OptionError(f"{name} has non-finite entries")
    sym = 0.5 * (arr + arr.transpose(0, 2, 1))
    if not np.allclose(arr, sym, rtol=1e-10, atol=1e-14 * max(1.0, float(np.abs(arr).max()))):
        raise OptionError(f"{name} must be symmetric at every sample")
    lowest = np.linalg.eigvalsh(sym)[:, 0]
    bad = np.flatnonzero(lowest < -1e-12 * max(1.0, float(np.abs(arr).max())))
    if bad.size:
        raise OptionError(f"{name} must be positive semi-definite at every sample; it is not at samples "
                          f"{bad[:5].tolist()} (a variance cannot be negative)")
    return sym
