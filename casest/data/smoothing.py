"""Smoothing and differentiation of measured signals, for regressors that are not measured (the
angular accelerations of an equation-error model, say).

- :func:`savitzky_golay`: a local polynomial of ``order`` fitted over a window of samples
  around each one (SciPy's ``savgol_filter``), its value or derivative at the centre. Good
  inside the record; the ends use the polynomial of the end window.
- :func:`fourier_smooth`: the record less the straight line through its end points (so that its
  periodic extension has no jump), transformed, cut off above ``cutoff`` Hz with a cosine taper
  over the last 10 % of the band, differentiated by ``(2 pi i f)^d`` and transformed back, the
  line's own derivative added. The default cutoff is the highest frequency whose power exceeds
  the noise floor (the median power of the upper half of the spectrum, where white
  measurement noise dominates a record sampled well above its content) times ten, or times
  log2(n / 0.05) for n bins where that is larger, so that no noise bin sets it by chance:
  the signal's band, not the noise's.
- :func:`zero_phase_lowpass`: the flight-test textbooks' pre-processing (Jategaonkar, *Flight
  Vehicle System Identification*, Sec. 10.2; Klein and Morelli, Sec. 11.4): a Butterworth
  low-pass run forwards and backwards over the record (no phase lag, the magnitude response
  squared), then central differences for the derivatives (second order inside, one-sided at
  the ends). It keeps a signal's band without a model of its spectrum; the ends are padded by
  odd reflection of the record, so a record should start and end in steady flight.

All need uniform sampling (time stamps within 5 % of a sample of the grid, as the delays do).
"""

from __future__ import annotations

import numpy as np

from ..checks import check_magnitude, finite_array, positive_number
from ..errors import DataError

__all__ = ["savitzky_golay", "fourier_smooth", "noise_floor_cutoff", "zero_phase_lowpass"]


def _checked(y, dt) -> tuple[np.ndarray, float]:
    if np.iscomplexobj(y):
        raise DataError("the signal y is complex: smooth its real and imaginary parts apart (y.real, y.imag)")
    y = finite_array(y, "the signal y", shape=(None,), min_rows=5)
    check_magnitude("the signal y", y)
    return y, positive_number(dt, "dt", error=DataError, meaning="the sample interval")


def savitzky_golay(y, dt: float, window: int = 21, order: int = 3, derivative: int = 0) -> np.ndarray:
    """The local-polynomial smoothing of a uniformly sampled signal, or its derivative.

    Parameters
    ----------
    y : array_like, shape (N,)
    dt : float
        Sample interval (s).
    window : int
        Samples per local fit (odd, > ``order``); the smoothing's time span is ``window * dt``.
    order : int
        Degree of the local polynomial.
    derivative : int
        0 for the smoothed signal, 1 for its first derivative (unit of y per second), 2 ...

    Returns
    -------
    ndarray, shape (N,)

    Raises
    ------
    DataError
        A signal that is not one finite column, a window that is even, not above the order or
        longer than the record; a ``dt`` whose power ``derivative`` leaves double precision.
    """
    from scipy.signal import savgol_filter

    y, dt = _checked(y, dt)
    if window % 2 == 0 or window <= order or window > y.size:
        raise DataError(f"window must be an odd number of samples above the order ({order}) and at most the record's "
                        f"{y.size}, got {window}")
    if not 0 <= derivative <= order:
        raise DataError(f"derivative must be between 0 and the order {order}, got {derivative}")
    if derivative and not -300 < derivative * np.log10(dt) < 300:  # 1 / dt^d scales the derivative
        raise DataError(f"dt = {dt:g} s to the power {derivative} leaves double precision: give the sample interval "
                        "in a unit that keeps it near 1")
    return savgol_filter(y, window, order, deriv=derivative, delta=dt, mode="interp")


def noise_floor_cutoff(y, dt: float, factor: float = 10.0) -> float:
    """The default cutoff of :func:`fourier_smooth`: the highest frequency whose power exceeds
    the median power of the upper half of the spectrum times ``factor`` (or log2(n / 0.05) for
    n bins, if larger).

    Parameters
    ----------
    y : array_like, shape (N,)
    dt : float
    factor : float

    Returns
    -------
    float
        Hz.
    """
    y, dt = _checked(y, dt)
    power = np.abs(np.fft.rfft(_detrended(y)[0])) ** 2
    freqs = np.fft.rfftfreq(y.size, dt)
    floor = np.median(power[len(power) // 2:])
    # a white-noise bin's power is exponential about its median m: it exceeds m log2(n / 0.05) in
    # fewer than 0.05 of n bins, so no noise bin sets the cutoff by chance
    threshold = floor * max(factor, np.log2(len(power) / 0.05))
    above = np.flatnonzero(power[1:] > threshold) + 1
    return float(freqs[above[-1]]) if above.size else float(freqs[1])


def _detrended(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    line = np.linspace(y[0], y[-1], y.size)
    return y - line, line


def fourier_smooth(y, dt: float, cutoff: float | None = None, derivative: int = 0) -> np.ndarray:
    """The Fourier smoothing of a uniformly sampled signal, or its derivative (module docstring).

    Parameters
    ----------
    y : array_like, shape (N,)
    dt : float
        Sample interval (s).
    cutoff : float, optional
        Highest frequency kept (Hz); default :func:`noise_floor_cutoff`.
    derivative : int
        0, 1 or 2.

    Returns
    -------
    ndarray, shape (N,)

    Raises
    ------
    DataError
        A signal that is not one finite column, a cutoff outside (0, Nyquist], a derivative
        other than 0, 1, 2.
    """
    y, dt = _checked(y, dt)
    nyquist = 0.5 / dt
    cutoff = noise_floor_cutoff(y, dt) if cutoff is None else float(cutoff)
    if not 0 < cutoff <= nyquist:
        raise DataError(f"cutoff must lie in (0, {nyquist:g}] Hz (the Nyquist frequency), got {cutoff!r}")
    if derivative not in (0, 1, 2):
        raise DataError(f"derivative must be 0, 1 or 2, got {derivative!r}")
    residual, line = _detrended(y)
    spectrum = np.fft.rfft(residual)
    freqs = np.fft.rfftfreq(y.size, dt)
    taper = np.clip((cutoff - freqs) / (0.1 * cutoff), 0.0, 1.0)
    taper = 0.5 - 0.5 * np.cos(np.pi * taper)  # 1 below 0.9 cutoff, 0 above the cutoff
    smoothed = np.fft.irfft(spectrum * taper * (2j * np.pi * freqs) ** derivative, n=y.size)
    slope = (y[-1] - y[0]) / ((y.size - 1) * dt)
    return smoothed + (line if derivative == 0 else slope if derivative == 1 else 0.0)


def zero_phase_lowpass(y, dt: float, cutoff: float, order: int = 4, derivative: int = 0) -> np.ndarray:
    """The forward-backward Butterworth low-pass of a uniformly sampled signal, or its derivative
    by central differences (module docstring).

    Parameters
    ----------
    y : array_like, shape (N,)
    dt : float
        Sample interval (s).
    cutoff : float
        The filter's -3 dB frequency of one pass (Hz; the forward-backward pair is -6 dB there),
        in (0, Nyquist).
    order : int
        The Butterworth filter's order (1-10); the pair rolls off at ``2 * order * 20`` dB a decade.
    derivative : int
        0 for the filtered signal, 1 or 2 for its derivatives (unit of y per second, per second
        squared).

    Returns
    -------
    ndarray, shape (N,)

    Raises
    ------
    DataError
        A signal that is not one finite real column, a cutoff outside (0, Nyquist) or too low to
        compute, an order outside 1-10, a derivative other than 0, 1, 2, a record shorter than the
        filter's padding.
    """
    from scipy.signal import butter, sosfiltfilt  # imported here: scipy.signal costs a second to import

    y, dt = _checked(y, dt)
    nyquist = 0.5 / dt
    if not (isinstance(cutoff, (int, float, np.floating)) and 0 < cutoff < nyquist):
        raise DataError(f"cutoff must lie in (0, {nyquist:g}) Hz (below the Nyquist frequency), got {cutoff!r}")
    if not (isinstance(order, (int, np.integer)) and 1 <= order <= 10):
        raise DataError(f"order must be an integer from 1 to 10, got {order!r}")
    if derivative not in (0, 1, 2):
        raise DataError(f"derivative must be 0, 1 or 2, got {derivative!r}")
    sos = butter(int(order), float(cutoff), btype="low", fs=1.0 / dt, output="sos")
    pad = 3 * (2 * sos.shape[0] + 1)
    if y.size <= pad:
        raise DataError(f"the record has {y.size} samples; the filter of order {order} pads {pad} at each end: give a "
                        "longer record or a lower order")
    try:
        smoothed = sosfiltfilt(sos, y, padtype="odd", padlen=pad)
    except np.linalg.LinAlgError:
        smoothed = np.full_like(y, np.nan)
    if not np.all(np.isfinite(smoothed)):  # poles within rounding of 1: the filter's start cannot be solved
        raise DataError(f"a cutoff of {cutoff:g} Hz is too low for samples {dt:g} s apart (cutoff x dt = "
                        f"{cutoff * dt:.3g}): the filter cannot be computed in double precision; decimate the record "
                        "first, or raise the cutoff")
    for _ in range(derivative):
        smoothed = np.gradient(smoothed, dt, edge_order=2)
    return smoothed
