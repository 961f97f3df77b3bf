"""Whether the fit is consistent with the noise model: tests of the residuals at the estimate.

Two tests, each per output channel, with its statistic and p-value:

- **chi-square** (a known R only): ``S_j = sum_k r_kj^2 / R_j`` against chi-square with
  ``N_j - n / n_y`` degrees of freedom, two-sided: residuals far larger than the given noise
  (the noise given too small, or a model error) or far smaller (the noise given too large).
- **whiteness** (Ljung-Box portmanteau): the first ``h`` autocorrelations of the residuals,
  ``Q = N (N + 2) sum_k rho_k^2 / (N - k)``. Its chi-square(h) law is asymptotic: on white
  noise of N = 100 samples and h = 20 lags it rejects 0.72 % of records at p < 1e-3 (20000
  draws). Up to ``EXACT_UP_TO`` samples the p-value is therefore taken from Q's law under
  white Gaussian noise, drawn once per (N, h) per process with a fixed seed (``NULL_DRAWS``
  records, about a second);
  longer records use chi-square(h) (rate 0.18 % at p < 1e-3 for N = 1000).
  A record in time (a dynamic model, or a static model's data flagged ``time_ordered``) is
  tested in time order; other static models' residuals are tested twice: in the order of the
  channel's fitted values, where a model error (a parameter held at a wrong value, a missing
  term) leaves a smooth trend that white noise does not, and in the record's own order, valid
  under white noise whatever the order of the samples, where a change during the record (a
  step: a magnet taken away from a magnetometer, a sensor's bias jumping) leaves a run of
  residuals of one sign. Static calibrations are mostly recorded in time, and a record built
  from arrays or a CSV file does not say so. A static model's residuals are also tested in the
  order of each measured signal (``"signal x"``): a term missing in one signal (a calibration
  curve one order short, a cross-axis coupling left out) leaves a smooth trend along that
  signal, white noise does not. An order equal to one already tested (or its reverse, which has
  the same autocorrelations), but for ties, is not tested again.

Under the model and noise model each p-value is uniform, so a test fails (``passed`` False)
at the rate ``ALPHA`` by chance alone; the trust line names every failed test.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..status import CheckCode


__all__ = ["ALPHA", "ResidualCheck", "residual_checks", "chi_square_check", "whiteness_check", "ljung_box"]

#: significance level of every residual test (two-sided for the chi-square test)
ALPHA = 1e-3
#: records up to this length get the Ljung-Box p-value from draws of Q under white noise
EXACT_UP_TO = 2000
#: white-noise records drawn per (N, h): p-values resolve down to 1 / (NULL_DRAWS + 1)
NULL_DRAWS = 19999


@dataclass(frozen=True)
class ResidualCheck:
    """One residual test of one output channel.

    Attributes
    ----------
    code : CheckCode
        The test (:attr:`CheckCode.CHI_SQUARE` or :attr:`CheckCode.WHITENESS`).
    channel : str
        The output.
    statistic : float
        S_j (chi-square) or Q (Ljung-Box).
    dof : float
        Degrees of freedom of the reference chi-square distribution.
    p_value : float
    order : str
        What the residuals were ordered by (whiteness): ``"time"``, ``"fitted value"``,
        ``"record"`` (the samples' order in a record not flagged as one in time) or
        ``"signal NAME"`` (a static model's measured signal NAME).
    null_draws : int
        White-noise draws of the statistic the p-value comes from (0: the chi-square law);
        a p-value of ``1 / (null_draws + 1)`` is an upper bound.
    """

    code: CheckCode
    channel: str
    statistic: float
    dof: float
    p_value: float
    order: str = ""
    null_draws: int = 0

    @property
    def passed(self) -> bool:
        return bool(self.p_value >= ALPHA)

    def describe(self) -> str:
        """One line for reports."""
        if self.code is CheckCode.CHI_SQUARE:
            what = (f"chi-square of the residuals with the given noise: S = {self.statistic:.4g} on {self.dof:.4g} "
                    f"degrees of freedom (S / dof = {self.statistic / max(self.dof, 1e-300):.3g})")
        else:
            what = (f"whiteness (Ljung-Box, residuals in {self.order} order): Q = {self.statistic:.4g} on "
                    f"{self.dof:.4g} lags")
        beyond_draws = self.null_draws and self.p_value * (self.null_draws + 1) <= 1.0 + 1e-9
        p = f"p < {self.p_value:.3g}" if beyond_draws else f"p = {self.p_value:.3g}"
        return f"{self.channel}: {what}, {p} ({'passed' if self.passed else 'FAILED'})"

    def to_dict(self) -> dict:
        return {"code": self.code.value, "channel": self.channel, "statistic": float(self.statistic),
                "dof": float(self.dof), "p_value": float(self.p_value), "order": self.order,
                "null_draws": int(self.null_draws)}

    @classmethod
    def from_dict(cls, data: dict) -> "ResidualCheck":
        return cls(CheckCode(data["code"]), data["channel"], float(data["statistic"]), float(data["dof"]),
                   float(data["p_value"]), data.get("order", ""), int(data.get("null_draws", 0)))


def chi_square_check(residuals: np.ndarray, variance: float, n_fitted: float, channel: str) -> ResidualCheck:
    """The two-sided chi-square test of one channel's measured residuals against a known variance."""
    from scipy.special import chdtr, chdtrc

    r = residuals[np.isfinite(residuals)]
    dof = max(r.size - n_fitted, 1.0)
    S = float(np.sum(r**2) / variance)
    p = float(min(1.0, 2.0 * min(chdtr(dof, S), chdtrc(dof, S))))
    return ResidualCheck(CheckCode.CHI_SQUARE, channel, S, dof, p)


def ljung_box(residuals: np.ndarray, lags: int | None = None) -> tuple[float, int, float]:
    """Ljung-Box ``(Q, h, p)`` of a sequence (NaN dropped); ``h = min(20, N // 5)``; p from
    white-noise draws of Q up to ``EXACT_UP_TO`` samples, else chi-square(h)."""
    from scipy.special import chdtrc

    r = residuals[np.isfinite(residuals)]
    r = r - r.mean()
    N = r.size
    h = int(lags if lags is not None else min(20, N // 5))
    denominator = float(np.sum(r**2))
    if h < 1 or denominator <= 0.0:
        return 0.0, 0, 1.0
    rho = np.array([np.sum(r[k:] * r[:-k]) for k in range(1, h + 1)]) / denominator
    Q = float(N * (N + 2) * np.sum(rho**2 / (N - np.arange(1, h + 1))))
    if N > EXACT_UP_TO:
        return Q, h, float(chdtrc(h, Q))
    null = _white_noise_q(N, h)
    exceed = null.size - np.searchsorted(null, Q, side="left")
    return Q, h, float((1 + exceed) / (null.size + 1))


def whiteness_check(sequence: np.ndarray, channel: str, order: str) -> ResidualCheck | None:
    """The Ljung-Box whiteness test of one channel's residuals (NaN dropped), already in
    ``order`` ("time", "fitted value" or "record"); None when the sequence is too short to test."""
    Q, h, p = ljung_box(sequence)
    if not h:
        return None
    n = int(np.isfinite(sequence).sum())
    return ResidualCheck(CheckCode.WHITENESS, channel, Q, h, p, order, NULL_DRAWS if n <= EXACT_UP_TO else 0)


@functools.lru_cache(maxsize=64)
def _white_noise_q(N: int, h: int) -> np.ndarray:
    """Sorted Ljung-Box Q of ``NULL_DRAWS`` white Gaussian records of N samples (fixed seed)."""
    rng = np.random.default_rng([N, h, 2026])
    size = 1 << (2 * N - 1).bit_length()  # zero padding: linear, not circular, autocorrelation
    weights = 1.0 / (N - np.arange(1, h + 1))
    out = []
    for start in range(0, NULL_DRAWS, 2000):  # chunks bound the memory
        x = rng.standard_normal((min(2000, NULL_DRAWS - start), N))
        x -= x.mean(axis=1, keepdims=True)
        spectrum = np.fft.rfft(x, size, axis=1)
        acf = np.fft.irfft(spectrum.real**2 + spectrum.imag**2, size, axis=1)[:, : h + 1]
        rho = acf[:, 1:] / acf[:, :1]
        out.append(N * (N + 2) * (rho**2 @ weights))
    return np.sort(np.concatenate(out))


def residual_checks(problem, theta: np.ndarray, min_samples: int = 20) -> tuple:
    """The residual tests of an estimate (see the module docstring).

    Parameters
    ----------
    problem : Problem
        The problem estimated (its noise model decides the chi-square test; whether its
        outputs come from a simulation decides the order of the whiteness test).
    theta : ndarray, shape (n_parameters,)
        The estimate.
    min_samples : int
        Channels with fewer measurements are not tested.

    Returns
    -------
    tuple of ResidualCheck
    """
    model = problem.model
    predicted = problem.predict(theta)
    residuals = problem.data.outputs - predicted
    known = problem.known_R
    n_fitted = model.n_parameters / model.n_outputs
    in_time = problem.measurement.simulated or bool(getattr(problem.data, "time_ordered", False))
    checks = []
    for j, channel in enumerate(model.output_names):
        r = residuals[:, j]
        measured = np.isfinite(r)
        if measured.sum() < min_samples:
            continue
        if known is not None:
            checks.append(chi_square_check(r, float(known[j]), n_fitted, channel))
        orders = [(np.arange(r.size), "time")] if in_time else \
            [(np.argsort(predicted[:, j], kind="stable"), "fitted value"), (np.arange(r.size), "record")]
        if not problem.measurement.simulated:
            orders += _signal_orders(problem, orders)
        for order, label in orders:
            check = whiteness_check(r[order], channel, label)
            checks += [check] if check else []
    return tuple(checks)


def _same_order(order: np.ndarray, seen: np.ndarray) -> bool:
    """Whether two orders give the same test: equal, or reversed (the same autocorrelations), but
    for at most 1 % of the samples moved by more than one place (near-ties, such as the values of a
    sine at mirrored times, swapped by rounding)."""
    where = np.empty_like(seen)
    where[seen] = np.arange(seen.size)  # each sample's place in ``seen``
    places, k = where[order], np.arange(order.size)
    return bool(np.mean(np.abs(places - k) > 1) <= 0.01 or np.mean(np.abs(places - (order.size - 1 - k)) > 1) <= 0.01)


def _signal_orders(problem, tested: list) -> list:
    """``(order, "signal NAME")`` of each measured signal of a static model that varies and orders
    the samples differently from every order in ``tested``."""
    out = []
    for i, name in enumerate(problem.model.signal_names):
        x = problem.data.signals[:, i]
        if not np.all(np.isfinite(x)) or np.ptp(x) == 0:
            continue
        order = np.argsort(x, kind="stable")
        if not any(_same_order(order, seen) for seen, _ in tested + out):
            out.append((order, f"signal {name}"))
    return out
