"""The residual tests of a frequency-domain fit, and its colored-residual covariance.

At frequencies spaced by at least ``2 pi / T`` the residuals ``v_j(w_k)`` of a right model are
independent circular complex variables of variance ``S_j(w_k)``, the noise spectrum (flat for
white noise). The tests:

- **flatness** (:attr:`CheckCode.FLATNESS`, the whiteness of the frequency domain), one for
  every channel together: the score test that each periodogram ``|v_j(w_k)|^2`` has one mean
  across the band, against a log-spectrum that follows the band's Legendre polynomials of degree
  ``1 ... DEGREE`` (each ``|v|^2`` carries two degrees of freedom). Failing it alone says
  coloured noise.
- **coherence** (:attr:`CheckCode.COHERENCE`, the independence of the frequency domain), per
  channel and input: the residuals regressed on each input ``U_i(w) P_m(w)`` (and, for output error, on the channel's
  fitted transform ``Yhat_j(w) P_m(w)``), ``P_m`` the Legendre polynomials of degree
  ``0 ... DEGREE`` over the band, with complex coefficients: a transfer-function error that
  varies smoothly across the band (a gain, a phase, a delay) makes the residuals coherent with
  the input. The fit's own Jacobian directions are projected out first, and each frequency is
  weighted by the residual spectrum fitted across the band (:func:`spectrum_trend`, smooth: a
  spectrum estimated frequency by frequency would lend its own noise to the test), so that
  coloured noise is not read as coherence. F-test.

The tests of one fit form one family (Holm, :func:`casest.estimation.diagnostics.family_adjusted`).
The colored-residual covariance is the sandwich ``G^-1 V G^-1`` of the reweighted least squares,
``V`` built with the fitted spectrum ``S_j(w)`` instead of the flat ``S_j``.
"""

from __future__ import annotations

import numpy as np
from numpy.polynomial import legendre
from scipy.special import chdtrc, fdtrc

from ..estimation.diagnostics import ResidualCheck, family_adjusted
from ..status import CheckCode

__all__ = ["spectral_checks", "flatness_check", "coherence_check", "spectrum_trend", "colored_covariance",
           "whitened_channel", "orthonormal", "DEGREE", "MIN_FREQUENCIES"]

#: highest Legendre degree of the coherence regressors (0: a gain, 1: a delay's phase slope, 2: curvature)
DEGREE = 2
#: fewer frequencies than this per channel leave the tests without power: none is run
MIN_FREQUENCIES = 12


def spectrum_trend(power: np.ndarray, polynomials: np.ndarray, iterations: int = 8) -> np.ndarray:
    """The residual spectrum across the band: ``exp`` of the band's Legendre polynomials fitted to
    the periodogram by maximum likelihood (each ``|v|^2`` exponential with that mean).

    Parameters
    ----------
    power : ndarray, shape (F,)
        ``|v(w_k)|^2``.
    polynomials : ndarray, shape (F, DEGREE + 1)
        :func:`band_polynomials` of the band.
    iterations : int
        Fisher scoring steps (with the log link every step is one least squares of equal weights).

    Returns
    -------
    ndarray, shape (F,)
        The fitted spectrum at each frequency; smooth, so that weighting by it does not make
        the weights' own noise look like coherence.
    """
    mean = max(float(power.mean()), 1e-300)
    eta = np.full(power.shape, np.log(mean))
    for _ in range(iterations):
        working = eta + power / np.exp(eta) - 1.0
        step = polynomials @ np.linalg.lstsq(polynomials, working, rcond=None)[0]
        eta = np.clip(step, np.log(mean) - 20.0, np.log(mean) + 20.0)
    return np.exp(eta)


def flatness_check(power: np.ndarray, polynomials: np.ndarray, channel_names) -> ResidualCheck:
    """The score test of flat residual spectra against ones whose logarithm follows the band's
    Legendre polynomials of degree ``1 ... DEGREE``, over every channel together.

    Each ``|v_j(w_k)|^2`` is exponential with mean ``S_j(w_k)`` (two degrees of freedom); under a
    flat spectrum the score ``U_j = sum_k x_k (P_jk / mean_k(P_jk) - 1)`` (``x_k`` the
    polynomials at ``w_k``) has the information ``I = sum_k (x_k - mean x)(x_k - mean x)'``, and
    ``sum_j U_j' I^-1 U_j`` follows chi-square(DEGREE x channels). A smooth trend of the spectrum
    across the band (the colour of turbulence, a sensor's own dynamics) is what it detects. One
    test for every channel: a band of a few dozen frequencies gives each channel too few
    degrees of freedom to see colour on its own at the family's level (AR(1) 0.9 noise on the
    short-period record: 16 of 40 records with a test per channel, 31 of 40 pooled).

    Parameters
    ----------
    power : ndarray, shape (channels, F)
        ``|v_j(w_k)|^2``.
    polynomials : ndarray, shape (F, DEGREE + 1)
        :func:`band_polynomials` of the band.
    channel_names : sequence of str

    Returns
    -------
    ResidualCheck
        ``channel`` every channel's name joined; ``size`` the largest factor by which a
        channel's spectrum, fitted by one scoring step, varies across the band.
    """
    x = polynomials[:, 1:]
    centred = x - x.mean(axis=0)
    information = centred.T @ centred
    statistic, size = 0.0, 1.0
    for P in power:
        score = centred.T @ (P / max(float(P.mean()), 1e-300) - 1.0)
        step = np.linalg.lstsq(information, score, rcond=None)[0]
        statistic += float(score @ step)
        trend = centred @ step
        size = max(size, float(np.exp(trend.max() - trend.min())))
    dof = x.shape[1] * power.shape[0]
    return ResidualCheck(CheckCode.FLATNESS, ", ".join(channel_names), statistic, dof,
                         float(chdtrc(dof, statistic)), "frequency", size=size)


def complex_columns(values: np.ndarray) -> np.ndarray:
    """The two real columns of a complex regressor with a complex coefficient, rows ``[Re; Im]``.

    Parameters
    ----------
    values : ndarray, shape (F,) complex

    Returns
    -------
    ndarray, shape (2 F, 2)
    """
    return np.column_stack([np.concatenate([values.real, values.imag]), np.concatenate([-values.imag, values.real])])


def band_polynomials(w: np.ndarray) -> np.ndarray:
    """Legendre polynomials of degree ``0 ... DEGREE`` over the band mapped to [-1, 1], shape (F, DEGREE + 1)."""
    span = float(w.max() - w.min())
    x = (2.0 * (w - w.min()) / span - 1.0) if span > 0 else np.zeros_like(w)
    return legendre.legvander(x, DEGREE)


def coherence_check(r: np.ndarray, nuisance: np.ndarray, regressor: np.ndarray, polynomials: np.ndarray,
                    channel: str, signal: str) -> ResidualCheck | None:
    """The F-test of the whitened residuals on one regressor's columns beside the fit's directions.

    Parameters
    ----------
    r : ndarray, shape (2 F,)
        The channel's residuals, real parts then imaginary parts, each divided by its local std.
    nuisance : ndarray, shape (2 F, p)
        The fit's Jacobian rows of the channel, weighted alike.
    regressor : ndarray, shape (F,) complex
        The input's (or fitted value's) transform, weighted alike.
    polynomials : ndarray, shape (F, DEGREE + 1)
        :func:`band_polynomials` of the band: the regressor's multiples tested.
    channel, signal : str

    Returns
    -------
    ResidualCheck or None
        ``size`` the fraction of the residual power the regressor explains; None when the
        regressor adds no direction beyond the fit's own.
    """
    columns = np.hstack([complex_columns(regressor * P) for P in polynomials.T])
    basis = orthonormal(nuisance)
    rest = r - basis @ (basis.T @ r)
    added = orthonormal(columns - basis @ (basis.T @ columns))
    q = added.shape[1]
    dof_left = r.size - basis.shape[1] - q
    if q == 0 or dof_left < 2:
        return None
    explained = float(np.sum((added.T @ rest) ** 2))
    total = float(rest @ rest)
    statistic = (explained / q) / (max(total - explained, 1e-300) / dof_left)
    return ResidualCheck(CheckCode.COHERENCE, channel, float(statistic), q, float(fdtrc(q, dof_left, statistic)),
                         "frequency", signal=signal, size=explained / max(total, 1e-300))


def orthonormal(columns: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the columns' span (rank by the singular values, relative 1e-10).

    Parameters
    ----------
    columns : ndarray, shape (n, p)

    Returns
    -------
    ndarray, shape (n, rank)
    """
    if columns.size == 0:
        return np.zeros((columns.shape[0], 0))
    u, s, _ = np.linalg.svd(columns, full_matrices=False)
    return u[:, s > 1e-10 * max(float(s[0]), 1e-300)]


def whitened_channel(j: int, vr: np.ndarray, vi: np.ndarray, Jr: np.ndarray, Ji: np.ndarray,
                     polynomials: np.ndarray) -> tuple:
    """One channel's residuals and Jacobian rows, each frequency divided by its local std.

    Parameters
    ----------
    j : int
        The channel.
    vr, vi : ndarray, shape (channels, F)
        Real and imaginary parts of the residuals.
    Jr, Ji : ndarray, shape (F * channels, p)
        Their Jacobians, rows of ``vec`` (column-major: channels vary fastest).
    polynomials : ndarray, shape (F, DEGREE + 1)
        :func:`band_polynomials` of the band.

    Returns
    -------
    r : ndarray, shape (2 F,)
    J : ndarray, shape (2 F, p)
    weights : ndarray, shape (F,)
        ``1 / sqrt(S(w) / 2)`` per frequency, ``S(w)`` from :func:`spectrum_trend`.
    """
    channels = vr.shape[0]
    power = vr[j] ** 2 + vi[j] ** 2
    weights = 1.0 / np.sqrt(spectrum_trend(power, polynomials) / 2.0)
    twice = np.concatenate([weights, weights])
    r = np.concatenate([vr[j], vi[j]]) * twice
    J = np.vstack([Jr[j::channels], Ji[j::channels]]) * twice[:, None]
    return r, J, weights


def spectral_checks(vr: np.ndarray, vi: np.ndarray, Jr: np.ndarray, Ji: np.ndarray, w: np.ndarray, U: np.ndarray,
                    fitted: np.ndarray | None, channel_names, input_names) -> tuple:
    """The family of residual tests of a frequency-domain fit (module docstring), Holm-adjusted.

    Parameters
    ----------
    vr, vi : ndarray, shape (channels, F)
        Real and imaginary parts of the residuals at the estimate.
    Jr, Ji : ndarray, shape (F * channels, p)
        Their Jacobians in the acting parameters (rows of ``vec``, channels fastest).
    w : ndarray, shape (F,)
        Angular frequencies (rad/s).
    U : ndarray, shape (F, n_inputs) complex
        The inputs' transforms.
    fitted : ndarray, shape (F, channels) complex, or None
        The model's transform of each channel (output error), None for equation error.
    channel_names, input_names : sequence of str

    Returns
    -------
    tuple of ResidualCheck
        Empty below :data:`MIN_FREQUENCIES` frequencies.
    """
    if w.size < MIN_FREQUENCIES:
        return ()
    polynomials = band_polynomials(w)
    checks = [flatness_check(vr**2 + vi**2, polynomials, channel_names)]
    for j, channel in enumerate(channel_names):
        r, J, weights = whitened_channel(j, vr, vi, Jr, Ji, polynomials)
        regressors = [(name, U[:, i]) for i, name in enumerate(input_names)]
        if fitted is not None:
            regressors.append(("", fitted[:, j]))
        for name, values in regressors:
            check = coherence_check(r, J, values * weights, polynomials, channel, name)
            if check is not None:
                checks.append(check)
    return family_adjusted(checks)


def colored_covariance(vr: np.ndarray, vi: np.ndarray, Jr: np.ndarray, Ji: np.ndarray, spectra: np.ndarray,
                       w: np.ndarray) -> np.ndarray:
    """The sandwich covariance of the reweighted least squares with the local residual spectrum.

    Parameters
    ----------
    vr, vi : ndarray, shape (channels, F)
    Jr, Ji : ndarray, shape (F * channels, p)
    spectra : ndarray, shape (channels,)
        The flat weights ``S_j`` the fit used.
    w : ndarray, shape (F,)

    Returns
    -------
    ndarray, shape (p, p)
        ``G^-1 V G^-1``; equals the white-noise ``(2 G)^-1`` when the fitted spectrum is flat.
    """
    polynomials = band_polynomials(w)
    local = np.array([spectrum_trend(vr[j] ** 2 + vi[j] ** 2, polynomials) for j in range(vr.shape[0])])
    per_row = np.tile(1.0 / spectra, w.size)
    noise = local.reshape(-1, order="F") / 2.0  # real and imaginary parts each carry half
    G = Jr.T @ (per_row[:, None] * Jr) + Ji.T @ (per_row[:, None] * Ji)
    scaled = per_row**2 * noise
    V = Jr.T @ (scaled[:, None] * Jr) + Ji.T @ (scaled[:, None] * Ji)
    G_inv = np.linalg.inv(G)
    return G_inv @ V @ G_inv
