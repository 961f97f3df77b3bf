"""Whether the fit is consistent with the noise model: tests of the residuals at the estimate.

The tests, each per output channel, with its statistic and p-value:

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
  The same statistic on the prewhitened residuals sorted by a signal or by the fitted value
  is the trend test (:attr:`CheckCode.TREND`) of :mod:`casest.estimation.residual_family`.

The tests of one fit form one family (:func:`family_adjusted`): Holm's step-down adjustment
keeps the chance that any of them fails on a right model with white noise at ``ALPHA``,
however many signals and outputs the fit has. :mod:`casest.estimation.residual_family` runs the
family (with the tests of independence from the signals, :mod:`casest.estimation.independence`)
and :mod:`casest.estimation.verdict` reads it.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import numpy as np

from ..status import CheckCode


__all__ = ["ALPHA", "ResidualCheck", "chi_square_check", "whiteness_check", "ljung_box", "ljung_box_p",
           "family_adjusted"]

#: level of the family of residual tests of one fit (Holm), and of a test on its own
ALPHA = 1e-3
#: records up to this length get the Ljung-Box p-value from draws of Q under white noise
EXACT_UP_TO = 2000
#: white-noise records drawn per (N, h): p-values resolve down to 1 / (NULL_DRAWS + 1), and
#: below that follow the chi-square tail scaled to the draws' own tail at the TAIL_ANCHOR-th largest Q
NULL_DRAWS = 19999
TAIL_ANCHOR = 20


@dataclass(frozen=True)
class ResidualCheck:
    """One residual test of one output channel.

    Attributes
    ----------
    code : CheckCode
        The test (:class:`~casest.status.CheckCode`).
    channel : str
        The output.
    statistic : float
        S_j (chi-square), Q (Ljung-Box, cross-correlation), the score statistic (flatness) or F (coherence).
    dof : float
        Degrees of freedom of the reference chi-square distribution (coherence: the numerator's
        of the F law).
    p_value : float
    order : str
        What the residuals were ordered by (whiteness): ``"time"``, ``"fitted value"``,
        ``"record"`` (the samples' order in a record not flagged as one in time),
        ``"signal NAME"`` (a static model's measured signal NAME) or ``"frequency"`` (the
        frequency domain's tests).
    null_draws : int
        White-noise draws of the statistic the p-value comes from (0: the chi-square law);
        a p-value of ``1 / (null_draws + 1)`` is an upper bound.
    adjusted_p : float or None
        Holm's adjusted p-value within the fit's family of tests (None: the test on its own).
    signal : str
        The signal a cross-correlation or trend test is against ("" for the fitted value or time).
    lag : float or None
        Cross-correlation: the lag of the largest correlation (samples; positive: the residual
        follows the signal). Step: the sample where the level changes. None otherwise.
    size : float or None
        Cross-correlation: the largest correlation. Step: the change of level (the output's
        unit). Flatness: the factor by which the fitted spectrum varies across the band. Coherence: the
        fraction of the residual power explained. None otherwise.
    """

    code: CheckCode
    channel: str
    statistic: float
    dof: float
    p_value: float
    order: str = ""
    null_draws: int = 0
    adjusted_p: float | None = None
    signal: str = ""
    lag: float | None = None
    size: float | None = None

    @property
    def family_p(self) -> float:
        """The p-value the verdict uses: Holm's adjusted one where the test is part of a family."""
        return float(self.p_value if self.adjusted_p is None else self.adjusted_p)

    @property
    def passed(self) -> bool:
        return bool(self.family_p >= ALPHA)

    def describe(self) -> str:
        """One line for reports."""
        beyond_draws = self.null_draws and self.p_value * (self.null_draws + 1) <= 1.0 + 1e-9
        p = f"p < {self.p_value:.3g}" if beyond_draws else f"p = {self.p_value:.3g}"
        if self.adjusted_p is not None:
            p += f", {self.adjusted_p:.3g} in the family"
        return f"{self.channel}: {self.what()}, {p} ({'passed' if self.passed else 'FAILED'})"

    def what(self) -> str:
        """The test and its statistic, in words."""
        if self.code is CheckCode.CHI_SQUARE:
            return (f"chi-square of the residuals with the given noise: S = {self.statistic:.4g} on {self.dof:.4g} "
                    f"degrees of freedom (S / dof = {self.statistic / max(self.dof, 1e-300):.3g})")
        if self.code is CheckCode.CROSS_CORRELATION:
            return (f"independence from signal {self.signal} (prewhitened cross-correlation): Q = {self.statistic:.4g} "
                    f"on {self.dof:.4g} lags, largest {self.size:+.3f} at lag {self.lag:+.0f}")
        if self.code is CheckCode.STEP:
            return (f"no change in time (cumulative sum): {self.statistic:.3g}, the level changes by "
                    f"{self.size:+.4g} at sample {self.lag:.0f}")
        if self.code is CheckCode.FLATNESS:
            return (f"flat residual spectrum across the band (score test): {self.statistic:.4g} on {self.dof:.4g} "
                    f"degrees of freedom, the fitted spectrum varies by x{self.size:.3g}")
        if self.code is CheckCode.COHERENCE:
            against = f"input {self.signal}" if self.signal else "the fitted transform"
            return (f"independence from {against} across the band (F-test): F = {self.statistic:.4g} on "
                    f"{self.dof:.4g} directions, {100 * self.size:.3g} % of the residual power explained")
        if self.code is CheckCode.TREND:
            return (f"no trend along the {self.order} (Ljung-Box, prewhitened residuals): Q = {self.statistic:.4g} on "
                    f"{self.dof:.4g} lags")
        return f"whiteness (Ljung-Box, residuals in {self.order} order): Q = {self.statistic:.4g} on {self.dof:.4g} lags"

    def to_dict(self) -> dict:
        out = {"code": self.code.value, "channel": self.channel, "statistic": float(self.statistic),
               "dof": float(self.dof), "p_value": float(self.p_value), "order": self.order,
               "null_draws": int(self.null_draws), "signal": self.signal}
        out.update({k: float(getattr(self, k)) for k in ("adjusted_p", "lag", "size") if getattr(self, k) is not None})
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "ResidualCheck":
        code, order = CheckCode(data["code"]), data.get("order", "")
        if code is CheckCode.WHITENESS and order not in ("", "time", "record"):
            code = CheckCode.TREND  # files written before the trend tests had a code of their own
        signal = data.get("signal", order[len("signal "):] if order.startswith("signal ") else "")
        optional = {k: (None if data.get(k) is None else float(data[k])) for k in ("adjusted_p", "lag", "size")}
        return cls(code, data["channel"], float(data["statistic"]), float(data["dof"]), float(data["p_value"]),
                   order, int(data.get("null_draws", 0)), signal=signal, **optional)


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
    r = residuals[np.isfinite(residuals)]
    r = r - r.mean()
    N = r.size
    h = int(lags if lags is not None else min(20, N // 5))
    denominator = float(np.sum(r**2))
    if h < 1 or denominator <= 0.0:
        return 0.0, 0, 1.0
    rho = np.array([np.sum(r[k:] * r[:-k]) for k in range(1, h + 1)]) / denominator
    Q = float(N * (N + 2) * np.sum(rho**2 / (N - np.arange(1, h + 1))))
    return Q, h, ljung_box_p(Q, N, h)


def ljung_box_p(Q: float, N: int, h: int) -> float:
    """The p-value of a Ljung-Box ``Q`` of ``N`` samples and ``h`` lags under white noise (the
    draws up to ``EXACT_UP_TO`` samples and their calibrated tail, else chi-square(h))."""
    from scipy.special import chdtrc

    if N > EXACT_UP_TO:
        return float(chdtrc(h, Q))
    null = _white_noise_q(N, h)
    exceed = null.size - np.searchsorted(null, Q, side="left")
    if exceed == 0:  # beyond every draw: the chi-square tail, scaled to meet the draws' own tail
        anchor = null[-TAIL_ANCHOR]
        scale = (TAIL_ANCHOR / (null.size + 1)) / max(float(chdtrc(h, anchor)), 1e-300)
        return float(min(chdtrc(h, Q) * scale, 1.0 / (null.size + 1)))
    return float((1 + exceed) / (null.size + 1))


def whiteness_check(sequence: np.ndarray, channel: str, order: str) -> ResidualCheck | None:
    """The Ljung-Box whiteness test of one channel's residuals (NaN dropped), already in
    ``order`` ("time", "fitted value" or "record"); None when the sequence is too short to test."""
    Q, h, p = ljung_box(sequence)
    if not h:
        return None
    n = int(np.isfinite(sequence).sum())
    from_draws = n <= EXACT_UP_TO and p >= 1.0 / (NULL_DRAWS + 1)
    return ResidualCheck(CheckCode.WHITENESS, channel, Q, h, p, order, NULL_DRAWS if from_draws else 0)


def family_adjusted(checks, level: float = ALPHA) -> tuple:
    """The checks of one fit with Holm's step-down adjusted p-values (``adjusted_p``).

    A test of the family fails when its adjusted p-value is below ``level``: on a right model
    with white noise, the chance that any test of the family fails is at most ``level``, however
    many tests there are (Holm 1979).

    Parameters
    ----------
    checks : sequence of ResidualCheck
    level : float
        Not used in the adjustment; stated for the reader (the family's level is :data:`ALPHA`).

    Returns
    -------
    tuple of ResidualCheck
        In the given order.
    """
    checks = list(checks)
    m = len(checks)
    order = np.argsort([c.p_value for c in checks], kind="stable")
    adjusted, running = [0.0] * m, 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * checks[i].p_value))
        adjusted[i] = running
    return tuple(replace(c, adjusted_p=a) for c, a in zip(checks, adjusted))


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
