"""Residual analysis of a record in time (a dynamic model's output error; summary Sec. 5).

Three things flight-test practice reads from the residuals ``r_kj = z_kj - y_kj`` of an
output-error fit:

- **autocorrelation** of each channel up to ``max_lag`` samples, with the band
  ``+/- 1.96 / sqrt(N_j)`` that white residuals stay inside at 95 % per lag;
- the **Ljung-Box** statistic of the same lags (:mod:`casest.estimation.diagnostics`);
- the **colored-residual std** (Morelli and Klein's correction): the ML std assume white
  residuals; with residuals correlated in time (turbulence, an unmodelled mode) the
  covariance of theta is the sandwich::

      Cov = M^-1 [ sum_j sum_{|l| <= L} a_j(l) / R_j^2  sum_k s_kj s_(k+l)j' ] M^-1,
      M = sum_j sum_k s_kj s_kj' / R_j

  with ``s_kj = dy_kj/dtheta``, ``a_j(l)`` the residuals' autocovariance at lag l (zero
  beyond L). The ratio of the colored std to the ML std says how far the white-noise
  figures understate the uncertainty (1 for white residuals; 2-5 is common in flight data).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._casadi.array_json import decode_array, encode_array

__all__ = ["ResidualAnalysis", "residual_analysis", "autocorrelation"]


@dataclass(frozen=True)
class ResidualAnalysis:
    """The residual analysis of an estimate from a record in time.

    Attributes
    ----------
    output_names : tuple of str
    parameter_names : tuple of str
        The estimated parameters (``colored_std`` and ``ratio`` are theirs).
    max_lag : int
        L, samples.
    autocorrelation : ndarray, shape (n_outputs, max_lag + 1)
        rho_j(l), l = 0 ... L (rho_j(0) = 1).
    band : ndarray, shape (n_outputs,)
        1.96 / sqrt(N_j): the 95 % band of a white channel.
    outside : ndarray, shape (n_outputs,)
        Share of the lags 1 ... L outside the band (about 5 % for white residuals).
    colored_std : ndarray, shape (n_parameters,)
        Standard deviations allowing for the residuals' correlation in time (NaN where the
        information matrix is singular).
    ratio : ndarray, shape (n_parameters,)
        colored_std / the estimate's std.
    """

    output_names: tuple
    parameter_names: tuple
    max_lag: int
    autocorrelation: np.ndarray
    band: np.ndarray
    outside: np.ndarray
    colored_std: np.ndarray
    ratio: np.ndarray

    def describe(self) -> list[str]:
        """Report lines: per channel the share of lags outside the band; the largest std ratios."""
        lines = [f"autocorrelation of the residuals, lags 1-{self.max_lag} (95 % band of white noise):"]
        for name, share, band in zip(self.output_names, self.outside, self.band):
            lines.append(f"  {name}: {share:.0%} of lags outside +/-{band:.3f}"
                         + (" (correlated in time)" if share > 0.2 else ""))
        finite = np.isfinite(self.ratio)
        if finite.any():
            order = np.argsort(-np.where(finite, self.ratio, -np.inf))[:3]
            worst = ", ".join(f"{self.parameter_names[i]} x{self.ratio[i]:.2f}" for i in order if finite[i])
            lines.append(f"colored-residual std / ML std: median {np.median(self.ratio[finite]):.2f}, largest {worst}")
        return lines

    def to_dict(self) -> dict:
        return {"output_names": list(self.output_names), "parameter_names": list(self.parameter_names),
                "max_lag": self.max_lag,
                **{k: encode_array(getattr(self, k)) for k in ("autocorrelation", "band", "outside", "colored_std",
                                                                 "ratio")}}

    @classmethod
    def from_dict(cls, data: dict) -> "ResidualAnalysis":
        arrays = {k: decode_array(data[k]) for k in ("autocorrelation", "band", "outside", "colored_std", "ratio")}
        return cls(output_names=tuple(data["output_names"]), parameter_names=tuple(data["parameter_names"]),
                   max_lag=int(data["max_lag"]), **arrays)


def autocorrelation(residuals: np.ndarray, max_lag: int) -> np.ndarray:
    """Biased autocorrelation of each column (NaN = not measured, left out), shape (n_columns, max_lag + 1)."""
    r = np.where(np.isfinite(residuals), residuals, 0.0)
    r = r - np.sum(r, axis=0) / np.maximum(np.sum(np.isfinite(residuals), axis=0), 1) * np.isfinite(residuals)
    N = r.shape[0]
    acov = np.array([[r[: N - k, j] @ r[k:, j] for k in range(max_lag + 1)] for j in range(r.shape[1])])
    return acov / np.where(acov[:, :1] > 0, acov[:, :1], 1.0)


def _banded_toeplitz_product(acov: np.ndarray, J: np.ndarray) -> np.ndarray:
    """``C J`` with ``C[i, k] = acov[|i - k|]`` up to lag ``L = len(acov) - 1`` (zero beyond): the
    convolution of J's columns with ``[acov[L] ... acov[1], acov[0], acov[1] ... acov[L]]`` by FFT."""
    N, L = J.shape[0], acov.size - 1
    kernel = np.concatenate([acov[:0:-1], acov])
    n = 1 << int(np.ceil(np.log2(N + 2 * L)))
    full = np.fft.irfft(np.fft.rfft(J, n, axis=0) * np.fft.rfft(kernel, n)[:, None], n, axis=0)
    return full[L:L + N]


def residual_analysis(problem, theta: np.ndarray, R: np.ndarray, std: np.ndarray,
                      max_lag: int | None = None) -> ResidualAnalysis:
    """The residual analysis of an estimate of a dynamic model (see the module docstring).

    Parameters
    ----------
    problem : Problem
        A problem whose outputs come from a simulation (records in time).
    theta : ndarray, shape (n_parameters,)
    R : ndarray, shape (n_outputs,)
        The noise variances of the estimate.
    std : ndarray, shape (n_parameters,)
        The estimate's std (the ratio's denominator).
    max_lag : int, optional
        L; default ``min(50, N // 10)``.

    Returns
    -------
    ResidualAnalysis
    """
    data = problem.data
    N, ny = data.n_samples, problem.model.n_outputs
    L = int(max_lag if max_lag is not None else max(1, min(50, N // 10)))
    residuals = data.outputs - problem.predict(theta)
    rho = autocorrelation(residuals, L)
    counts = np.sum(np.isfinite(residuals), axis=0)
    band = 1.96 / np.sqrt(np.maximum(counts, 1))
    outside = np.mean(np.abs(rho[:, 1:]) > band[:, None], axis=1)
    J = problem.jacobian(theta).reshape(N, ny, -1) * np.isfinite(residuals)[:, :, None]
    r = np.where(np.isfinite(residuals), residuals, 0.0)
    R = np.asarray(R, dtype=float).reshape(-1)
    M = np.zeros((J.shape[2], J.shape[2]))
    middle = np.zeros_like(M)
    for j in range(ny):
        Jj, rj = np.ascontiguousarray(J[:, j, :]), r[:, j]
        M += Jj.T @ Jj / R[j]
        # J' C J with C the banded Toeplitz matrix of the autocovariance up to lag L
        acov = np.array([rj[:N - lag] @ rj[lag:] / N for lag in range(L + 1)])
        middle += Jj.T @ _banded_toeplitz_product(acov, Jj) / R[j] ** 2
    try:
        Minv = np.linalg.inv(M)
        colored = np.sqrt(np.maximum(np.diag(Minv @ middle @ Minv), 0.0))
    except np.linalg.LinAlgError:
        colored = np.full(M.shape[0], np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = colored / np.asarray(std, dtype=float)
    return ResidualAnalysis(tuple(problem.model.output_names), tuple(problem.model.parameter_names), L, rho, band,
                            outside, colored, ratio)
