"""Smoothing of the process noise and the single-stage smoother (summary Sec. 2.4-2.5), and the
conversion of a continuous linear system to the discrete one the Kalman filter runs on (Sec. 1-2).

- :func:`process_noise_smoothing`: w(k|N) and Q(k|N) of the fixed-interval smoother (Eq. 2.21,
  2.23), from a filter pass and its RTS smoothing: ``B_k = Q(k) Gamma(k)' P(k+1|k)^-1``,
  ``w(k|N) = -B_k (x(k+1|k) - x(k+1|N))`` (w(k|k) = 0: white noise), ``Q(k|N) = Q(k) -
  B_k (P(k+1|k) - P(k+1|N)) B_k'``.
- :func:`single_stage_smoother`: x(k|k+1), P(k|k+1), w(k|k+1), Q(k|k+1) of Eq. 2.16-2.19, with
  the sign of Eq. 2.14-2.15 and 2.20-2.21 (2.16-2.17 as printed reverse the correction).
- :func:`continuous_to_discrete`: Phi = exp(A dt), Psi (zero-order hold of u) and the discrete
  process-noise covariance by Van Loan's matrix exponential, from Eq. 1.1 to Eq. 2.1.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from ..checks import covariance_argument, matrix_argument, positive_number
from ..models import OptionError

__all__ = ["process_noise_smoothing", "single_stage_smoother", "continuous_to_discrete", "noise_sequences", "rts_loop"]


def noise_sequences(result, Q, Gamma=None) -> tuple[np.ndarray, np.ndarray]:
    """Q(k) and Gamma(k) for every interval of a pass, shapes (N-1, p, p) and (N-1, n, p).

    ``Q``: (p, p) for all intervals, or (N-1, p, p); ``Gamma``: (n, p) or (N-1, n, p), default
    the identity (the noise enters every state: p = n).
    """
    N, n = result.x_filtered.shape
    K = max(N - 1, 0)
    if isinstance(Q, Mapping):
        raise OptionError(f"the process noise here is a covariance matrix Q ({n} x {n} for noise on every state), not a "
                          f"mapping of state names ({sorted(Q)}); the filter pass has no state names: give "
                          "casest.filters.ekf.process_noise_matrix(model, mapping) times the interval, or the matrix")
    try:
        Q = np.asarray(Q, dtype=float)
    except (TypeError, ValueError):
        raise OptionError(f"the process noise Q must be an array of numbers, got {type(Q).__name__}") from None
    Q = np.broadcast_to(Q, (K,) + Q.shape[-2:]) if Q.ndim == 2 else Q
    p = Q.shape[-1]
    G = np.eye(n) if Gamma is None else np.asarray(Gamma, dtype=float)
    G = np.broadcast_to(G, (K,) + G.shape[-2:]) if G.ndim == 2 else G
    if Q.shape != (K, p, p) or G.shape != (K, n, p):
        raise OptionError(f"the process noise must be (p, p) or ({K}, p, p) and its input matrix (n, p) or "
                          f"({K}, n, p) with n = {n}; got Q {Q.shape} and Gamma {G.shape}")
    if not np.all(np.isfinite(G)):
        raise OptionError("the process noise input matrix Gamma (noise_input) has non-finite entries")
    for Qk in (np.unique(Q.reshape(-1, p * p), axis=0).reshape(-1, p, p) if K else ()):
        covariance_argument(Qk, p, "the process noise Q (process_noise)")  # negative or NaN: a smoothed Q(k|N) < 0
    return Q, G


def process_noise_smoothing(result, x_smoothed: np.ndarray, P_smoothed: np.ndarray, Q, Gamma=None
                            ) -> tuple[np.ndarray, np.ndarray]:
    """w(k|N) and Q(k|N) for k = 0 ... N-2 (Eq. 2.21, 2.23).

    Parameters
    ----------
    result : FilterResult
        The filter pass (x(k+1|k), P(k+1|k)).
    x_smoothed, P_smoothed : ndarray, shapes (N, n) and (N, n, n)
        x(k|N), P(k|N) of its RTS smoothing.
    Q, Gamma : array_like
        The discrete process noise and its input matrix (:func:`noise_sequences`).

    Returns
    -------
    w : ndarray, shape (N-1, p)
        The smoothed process noise of each interval (unit of w).
    Q_smoothed : ndarray, shape (N-1, p, p)
    """
    Qk, Gk = noise_sequences(result, Q, Gamma)
    xp, Pp = result.x_predicted[1:], result.P_predicted[1:]
    # B_k = Q Gamma' P(k+1|k)^-1, from the solve with P symmetric
    B = np.linalg.solve(Pp, Gk @ Qk).transpose(0, 2, 1)
    w = -np.einsum("kpn,kn->kp", B, xp - x_smoothed[1:])
    Qs = Qk - B @ (Pp - P_smoothed[1:]) @ B.transpose(0, 2, 1)
    return w, 0.5 * (Qs + Qs.transpose(0, 2, 1))


def single_stage_smoother(result, k: int, Q, Gamma=None) -> dict:
    """The single-stage smoother at sample k (Eq. 2.16-2.19): x(k|k+1), P(k|k+1), w(k|k+1), Q(k|k+1).

    Parameters
    ----------
    result : FilterResult
        A filter pass with samples k and k+1.
    k : int
        0 <= k <= N - 2.
    Q, Gamma : array_like
        As for :func:`process_noise_smoothing`.

    Returns
    -------
    dict
        ``x`` (n,), ``P`` (n, n), ``w`` (p,), ``Q`` (p, p).
    """
    N = result.x_filtered.shape[0]
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k <= N - 2:
        raise OptionError(f"the single-stage smoother needs a whole sample index k with samples k and k+1: "
                          f"0 <= k <= {N - 2}, got {k!r}")
    Qk, Gk = noise_sequences(result, Q, Gamma)
    Pf, Pp, Phi = result.P_filtered[k], result.P_predicted[k + 1], result.transition[k]
    dx = result.x_predicted[k + 1] - result.x_filtered[k + 1]
    dP = Pp - result.P_filtered[k + 1]
    C0 = np.linalg.solve(Pp, Phi @ Pf).T
    B0 = np.linalg.solve(Pp, Gk[k] @ Qk[k]).T
    P = Pf - C0 @ dP @ C0.T
    Qs = Qk[k] - B0 @ dP @ B0.T
    # the correction moves x(k|k) towards what sample k+1 taught: -C0 (x(k+1|k) - x(k+1|k+1)); Eq. 2.16-2.17
    # as printed carry the opposite sign, which Eq. 2.14-2.15 and the RTS form 2.20-2.21 contradict
    return {"x": result.x_filtered[k] - C0 @ dx, "P": 0.5 * (P + P.T), "w": -B0 @ dx, "Q": 0.5 * (Qs + Qs.T)}


def continuous_to_discrete(A, B, G, Qc, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The discrete system of Eq. 2.1 from the continuous one of Eq. 1.1 over a sample interval.

    Parameters
    ----------
    A : array_like, shape (n, n)
    B : array_like, shape (n, m)
        Input matrix; the input is held over the interval (zero-order hold).
    G : array_like, shape (n, q)
        Noise input matrix.
    Qc : array_like, shape (q, q)
        Intensity of the continuous white noise w (unit of w squared per hertz).
    dt : float
        Sample interval (s), > 0.

    Returns
    -------
    Phi : ndarray, shape (n, n)
        ``exp(A dt)``.
    Psi : ndarray, shape (n, m)
        ``int_0^dt exp(A s) ds B``.
    Qd : ndarray, shape (n, n)
        ``int_0^dt exp(A s) G Qc G' exp(A' s) ds``, by Van Loan's method (the exponential of
        ``[[-A, G Qc G'], [0, A']] dt``), with Gamma = I in Eq. 2.1.
    """
    from scipy.linalg import expm

    A, B, G, Qc = (np.atleast_2d(np.asarray(v, dtype=float)) for v in (A, B, G, Qc))
    n, m = A.shape[0], B.shape[1]
    if A.shape != (n, n) or B.shape[0] != n or G.shape[0] != n or Qc.shape != (G.shape[1], G.shape[1]):
        raise OptionError(f"continuous_to_discrete needs A (n, n), B (n, m), G (n, q), Qc (q, q); got {A.shape}, "
                          f"{B.shape}, {G.shape}, {Qc.shape}")
    dt = positive_number(dt, "dt", meaning="the sample interval")
    for name, value in (("A", A), ("B", B), ("G", G)):
        matrix_argument(value, value.shape, name)
    covariance_argument(Qc, Qc.shape[0], "the noise intensity Qc")
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is named below
        hold = expm(np.block([[A, B], [np.zeros((m, n + m))]]) * dt)
        Phi, Psi = hold[:n, :n], hold[:n, n:]
        noise = expm(np.block([[-A, G @ Qc @ G.T], [np.zeros((n, n)), A.T]]) * dt)
        Qd = Phi @ noise[:n, n:]
    for name, value in (("Phi", Phi), ("Psi", Psi), ("Qd", Qd)):
        if not np.all(np.isfinite(value)):
            raise OptionError(f"the discretised {name} overflows double precision (A dt, B, G or Qc too large: the "
                              "largest entries of A dt, G and Qc must keep exp(A dt) and G Qc G' finite); express "
                              "the states in other units or take a shorter dt")
    return Phi, Psi, 0.5 * (Qd + Qd.T)


def rts_loop(result) -> tuple[np.ndarray, np.ndarray]:
    """x(k|N), shape (N, n), and P(k|N), shape (N, n, n): the RTS recursion of :func:`casest.filters.ekf.rts_smoother`
    (Eq. 2.20, 2.22) as a NumPy loop over a FilterResult."""
    xf, Pf, xp, Pp, Phi = result.x_filtered, result.P_filtered, result.x_predicted, result.P_predicted, result.transition
    N = xf.shape[0]
    xs, Ps = xf.copy(), Pf.copy()
    for k in range(N - 2, -1, -1):
        Ck = np.linalg.solve(Pp[k + 1], Phi[k] @ Pf[k]).T  # P(k|k) Phi' P(k+1|k)^-1 (P symmetric)
        xs[k] = xf[k] - Ck @ (xp[k + 1] - xs[k + 1])
        Pk = Pf[k] - Ck @ (Pp[k + 1] - Ps[k + 1]) @ Ck.T
        Ps[k] = 0.5 * (Pk + Pk.T)
    return xs, Ps
