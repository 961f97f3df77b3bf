"""Whether the residuals depend on the signals or on time: the companions of the whiteness test.

Whiteness alone cannot tell noise correlated in time (turbulence, a sensor's own dynamics)
from a model error: both colour the residuals. The practice of system identification (Ljung,
*System Identification*, 2nd ed., Sec. 16.6; MATLAB's ``resid``) checks a second thing, the
residuals' independence from the inputs. Residuals that are coloured but independent of every
signal mean the model is right and the noise coloured; residuals that depend on a signal mean
the model is wrong. This module gives the tests of dependence, each valid when the residuals
are coloured:

- **prewhitening**: an autoregression ``r_t = sum_i a_i r_(t-i) + e_t`` fitted to the residuals
  in time order (order by BIC, at most :data:`MAX_AR_ORDER`); its filter ``A(q)`` turns
  coloured noise into white innovations ``e``. The same filter applied to a signal keeps any
  relation between the two: ``r = G(q) x + n`` becomes ``e = G(q) A(q) x + A(q) n``.
- **cross-correlation** of ``e`` with the filtered signal ``A(q) x`` at lags ``k`` (both signs
  for a static model, whose reference and sensor may lag either way; ``k >= 1``, past inputs,
  for a dynamic model, which feedback leaves valid): the regression of ``e`` on the lagged filtered signal gives
  ``Q = n R^2``, chi-square with as many degrees of freedom as independent lags when ``e``
  is white and independent of the signal, whatever the signal's own colour (the Lagrange
  multiplier form of Box and Jenkins' prewhitened cross-correlation test). The
  cross-correlations themselves, with the band ``+/- 1.96 / sqrt(n)``, are what the figure draws.
- **a change in time** (a step or drift: a bias that jumps, a magnet taken away): the
  cumulative sum of the residuals ``max_k |S_k| / sqrt(N sigma_LR^2)`` with the long-run
  variance ``sigma_LR^2 = sigma_e^2 / (1 - sum a_i)^2`` of an autoregression fitted to the
  residuals less each side's mean of the sum's peak (estimated under the alternative, so that a
  step does not pass for slow noise and hide itself); its law under stationary noise is
  Kolmogorov's (Ploberger and Kraemer's OLS-CUSUM test).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MAX_AR_ORDER", "CROSS_LAGS", "Prewhitener", "prewhitener", "independence_test",
           "nuisance_basis", "step_test", "projected_out"]

#: largest order of the prewhitening autoregression
MAX_AR_ORDER = 10
#: lags of the cross-correlation test (each sign for a static model)
CROSS_LAGS = 10


@dataclass(frozen=True)
class Prewhitener:
    """The autoregressive filter that whitens one channel's residuals in time.

    Attributes
    ----------
    coefficients : ndarray, shape (p,)
        ``a_1 ... a_p`` of ``r_t = sum a_i r_(t-i) + e_t`` (empty: the residuals are white).
    innovation_variance : float
        ``sigma_e^2``, the variance of the innovations ``e``.
    """

    coefficients: np.ndarray
    innovation_variance: float

    def apply(self, x: np.ndarray) -> np.ndarray:
        """``A(q) x``: ``x_t - sum a_i x_(t-i)``, the record's start taken as zero initial
        conditions, shape ``(N,)`` (every filtered series has the record's length)."""
        x = np.asarray(x, dtype=float)
        full = x.copy()
        for i, a in enumerate(self.coefficients, start=1):
            full[i:] -= a * x[:-i]
        return full

    @property
    def long_run_variance(self) -> float:
        """``sigma_e^2 / (1 - sum a)^2``: the spectrum at frequency zero times 2 pi (infinite at a unit root)."""
        gain = 1.0 - float(np.sum(self.coefficients))
        return float(self.innovation_variance / gain**2) if gain > 1e-12 else float("inf")


def _centred(x: np.ndarray) -> np.ndarray:
    """``x`` less its mean over the finite entries, NaN (not measured) set to zero."""
    finite = np.isfinite(x)
    out = np.where(finite, x, 0.0)
    return np.where(finite, out - (out.sum() / max(int(finite.sum()), 1)), 0.0)


def prewhitener(residuals: np.ndarray, max_order: int | None = None) -> Prewhitener:
    """The autoregression that whitens ``residuals`` (one channel, time order; NaN as the mean).

    Parameters
    ----------
    residuals : ndarray, shape (N,)
    max_order : int, optional
        Largest order tried; default ``min(MAX_AR_ORDER, N // 20)``.

    Returns
    -------
    Prewhitener
        The order with the least BIC, every order fitted by least squares on the same samples.
    """
    r = _centred(np.asarray(residuals, dtype=float))
    N = r.size
    top = int(max_order if max_order is not None else min(MAX_AR_ORDER, N // 20))
    top = max(0, min(top, N // 4))
    y = r[top:]
    n = y.size
    total = float(y @ y)
    if top == 0 or total <= 0:
        return Prewhitener(np.zeros(0), total / max(n, 1))
    lagged = np.column_stack([r[top - i:N - i] for i in range(1, top + 1)])
    Q, R = np.linalg.qr(lagged)  # nested orders: the residual sum of order p is total - sum of the first p
    along = Q.T @ y
    diagonal = np.abs(np.diag(R))
    usable = int(np.argmax(diagonal <= 1e-10 * max(diagonal[0], 1e-300))) if np.any(diagonal <= 1e-10 * max(
        diagonal[0], 1e-300)) else top  # orders up to the first dependent lag
    rss = total - np.concatenate([[0.0], np.cumsum(along[:usable] ** 2)])
    bic = n * np.log(np.maximum(rss / n, 1e-300)) + np.arange(usable + 1) * np.log(n)
    p = int(np.argmin(bic))
    a = np.linalg.solve(R[:p, :p], along[:p]) if p else np.zeros(0)
    return Prewhitener(np.asarray(a, dtype=float), float(max(rss[p], 1e-300 * n) / n))


@dataclass(frozen=True)
class IndependenceTest:
    """The prewhitened cross-correlation test of one channel against one signal.

    Attributes
    ----------
    statistic : float
        ``Q = n R^2`` of the regression of the whitened residuals on the lagged filtered signal.
    dof : int
        Independent lags (the rank of the lagged signal).
    p_value : float
    lags : ndarray of int
    correlation : ndarray
        ``rho(k)`` at ``lags``.
    band : float
        ``1.96 / sqrt(n)``: the 95 % band of ``rho(k)`` under independence.
    peak_lag : int
        The lag of the largest ``|rho(k)|``.
    """

    statistic: float
    dof: int
    p_value: float
    lags: np.ndarray
    correlation: np.ndarray
    band: float
    peak_lag: int


def nuisance_basis(nuisance: np.ndarray | None, n: int, lags: np.ndarray) -> np.ndarray:
    """An orthonormal basis of a constant and the nuisance columns on the samples the lagged
    regression uses (``reach ... n - reach``), shape (rows, rank): computed once per channel."""
    reach = int(np.max(np.abs(lags))) if len(lags) else 0
    rows = max(n - 2 * reach, 0)
    design = np.ones((rows, 1))
    if nuisance is not None and nuisance.size:
        design = np.column_stack([design, nuisance[reach:n - reach]])
    return _orthonormal(design)


def independence_test(whitened: np.ndarray, filtered_signal: np.ndarray, lags: np.ndarray,
                      nuisance: np.ndarray | None = None, basis: np.ndarray | None = None) -> IndependenceTest | None:
    """Test of the whitened residuals' independence from one filtered signal (module docstring).

    Parameters
    ----------
    whitened : ndarray, shape (n,)
        ``A(q) r`` (:meth:`Prewhitener.apply`).
    filtered_signal : ndarray, shape (n,)
        ``A(q) x`` with the same filter.
    lags : ndarray of int
        The lags k of ``x_(t-k)``.
    nuisance : ndarray, shape (n, n_parameters), optional
        ``A(q) J``: the filtered Jacobian of the fitted model. Residuals of a fit carry its
        estimation error ``-J delta``, which with coloured noise is larger than the white
        innovations and depends on the signals; the test counts only what the lagged signal
        explains beyond these columns (the Lagrange multiplier test with nuisance parameters).
    basis : ndarray, optional
        :func:`nuisance_basis` of ``nuisance`` (given, it is not computed again).

    Returns
    -------
    IndependenceTest or None
        None where the signal does not vary or the record is too short for the lags.
    """
    from scipy.special import chdtrc

    lags = np.asarray(lags, dtype=int)
    e, u = _centred(whitened), _centred(filtered_signal)
    n, reach = e.size, int(np.max(np.abs(lags))) if lags.size else 0
    if n - 2 * reach < 4 * lags.size or not np.any(u):
        return None
    window = np.lib.stride_tricks.sliding_window_view(u, 2 * reach + 1)  # window[i] = u[i ... i + 2 reach]
    U, y = window[:, reach - lags], e[reach:n - reach]  # U[:, j] = u[t - lags[j]], t = reach ... n - reach - 1
    basis = nuisance_basis(nuisance, n, lags) if basis is None else basis
    U, y = U - basis @ (basis.T @ U), y - basis @ (basis.T @ y)
    gram, projected, total = U.T @ U, U.T @ y, float(y @ y)
    values, vectors = np.linalg.eigh(gram)
    keep = values > 1e-12 * max(float(values[-1]), 1e-300)
    rank = int(keep.sum())
    if rank == 0 or total <= 0:
        return None
    along = vectors[:, keep].T @ projected
    Q = float(y.size * np.sum(along**2 / values[keep]) / total) / bartlett_factor(y, U)  # n R^2, colour allowed
    rho = projected / np.sqrt(np.maximum(np.diag(gram), 1e-300) * total)  # at each lag, of what the fit leaves
    return IndependenceTest(Q, int(rank), float(chdtrc(int(rank), Q)), lags, rho, 1.96 / np.sqrt(n),
                            int(lags[int(np.argmax(np.abs(rho)))]))


def hac_bandwidth(n: int) -> int:
    """Newey and West's lag window for ``n`` samples: ``floor(4 (n / 100)^(2/9))``."""
    return int(4 * (max(n, 1) / 100.0) ** (2.0 / 9.0))


def bartlett_factor(y: np.ndarray, U: np.ndarray) -> float:
    """How much the colour left in ``y`` inflates the variance of its correlation with the columns
    of ``U``: Bartlett's ``1 + 2 sum_m w_m rho_y(m) rho_u(m)`` (weights ``1 - m / (L + 1)`` up to
    :func:`hac_bandwidth`), the largest over the columns, at least 1. It is 1 for white ``y``
    whatever ``U``, and near the long-run variance ratio of ``y`` for a slowly varying column.

    Parameters
    ----------
    y : ndarray, shape (n,)
    U : ndarray, shape (n, k)

    Returns
    -------
    float
    """
    L, n = hac_bandwidth(y.size), y.size
    if L < 1 or n <= L + 1:
        return 1.0
    def autocorrelation(v):  # noqa: E306 - lags 1 ... L of each column (einsum: no product array)
        v = v - v.mean(axis=0)
        energy = np.maximum(np.einsum("ij,ij->j", v, v), 1e-300)
        return np.array([np.einsum("ij,ij->j", v[m:], v[:-m]) for m in range(1, L + 1)]) / energy
    weights = 1.0 - np.arange(1, L + 1) / (L + 1.0)
    factor = 1.0 + 2.0 * np.max((weights * autocorrelation(y[:, None])[:, 0]) @ autocorrelation(U))
    return float(max(factor, 1.0))


def _orthonormal(design: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the columns' span (singular values below 1e-10 of the largest left out)."""
    U, sv, _ = np.linalg.svd(design, full_matrices=False)
    return U[:, sv > sv[0] * 1e-10] if sv.size and sv[0] > 0 else U[:, :0]


def projected_out(values: np.ndarray, nuisance: np.ndarray | None) -> np.ndarray:
    """``values`` less their least-squares fit on the columns of ``nuisance`` (shape (n, k))."""
    if nuisance is None or not nuisance.size:
        return values
    basis = _orthonormal(nuisance)
    return values - basis @ (basis.T @ values)


@dataclass(frozen=True)
class StepTest:
    """The cumulative-sum test of one channel's residuals for a change in time.

    Attributes
    ----------
    statistic : float
        ``max_k |S_k| / sqrt(N sigma_LR^2)``.
    p_value : float
        From Kolmogorov's law.
    location : int
        The sample where ``|S_k|`` peaks (where the level changes).
    size : float
        The mean after ``location`` less the mean before (the step, in the output's unit).
    """

    statistic: float
    p_value: float
    location: int
    size: float


def step_test(residuals: np.ndarray, whitener: Prewhitener | None = None) -> StepTest | None:
    """The OLS-CUSUM test of a change in the residuals' level over the record (module docstring).

    Parameters
    ----------
    residuals : ndarray, shape (N,)
        One channel in time order (NaN as the mean).
    whitener : Prewhitener, optional
        Not used: the long-run variance comes from an autoregression fitted to the residuals
        less the two sides' means at the sum's peak.

    Returns
    -------
    StepTest or None
        None where the long-run variance is zero or unbounded (a unit root: no level to test).
    """
    from scipy.special import kolmogorov

    r = _centred(np.asarray(residuals, dtype=float))
    N = r.size
    if N < 8:
        return None
    S = np.cumsum(r)
    k = int(np.argmax(np.abs(S[:-1])))
    split = r.copy()
    split[:k + 1] -= split[:k + 1].mean()
    split[k + 1:] -= split[k + 1:].mean()
    lrv = prewhitener(split).long_run_variance
    if not np.isfinite(lrv) or lrv <= 0:
        return None
    statistic = float(abs(S[k]) / np.sqrt(N * lrv))
    size = float(np.mean(r[k + 1:]) - np.mean(r[:k + 1]))
    return StepTest(statistic, float(kolmogorov(statistic)), k + 1, size)
