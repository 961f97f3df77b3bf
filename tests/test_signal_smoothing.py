"""Smoothing and differentiation of measured signals (casest.data.smoothing). Truth: the analytic
derivatives of y = sin(2 pi 0.7 t) + 0.3 cos(2 pi 1.9 t) + 0.5 t at 100 Hz over 10 s, with white
noise of std 0.01 (fixed seed) or none; compared over the inner 80 % of the record."""

import numpy as np
import pytest

from casest.data.smoothing import fourier_smooth, noise_floor_cutoff, savitzky_golay, zero_phase_lowpass
from casest.errors import DataError

DT = 0.01
T = np.arange(1000) * DT
W1, W2 = 2 * np.pi * 0.7, 2 * np.pi * 1.9
CLEAN = np.sin(W1 * T) + 0.3 * np.cos(W2 * T) + 0.5 * T
SLOPE = W1 * np.cos(W1 * T) - 0.3 * W2 * np.sin(W2 * T) + 0.5
CURVE = -W1**2 * np.sin(W1 * T) - 0.3 * W2**2 * np.cos(W2 * T)
INNER = slice(100, 900)
NOISY = CLEAN + 0.01 * np.random.default_rng(0).standard_normal(T.size)


def _rms(a):
    return float(np.sqrt(np.mean(a[INNER] ** 2)))


@pytest.mark.parametrize("method", ["savgol", "fourier"])
def test_derivatives_of_a_noise_free_signal_are_exact_inside(method):
    if method == "savgol":
        first, second = (savitzky_golay(CLEAN, DT, window=21, order=5, derivative=d) for d in (1, 2))
        tolerances = (1e-4, 5e-3)
    else:
        first, second = (fourier_smooth(CLEAN, DT, cutoff=5.0, derivative=d) for d in (1, 2))
        tolerances = (5e-3, 2e-2)  # the ends' derivative jump rings into the record, decaying inward
    assert _rms(first - SLOPE) < tolerances[0] * _rms(SLOPE)
    assert _rms(second - CURVE) < tolerances[1] * _rms(CURVE)


@pytest.mark.parametrize("method", ["savgol", "fourier", "zero-phase"])
def test_a_noisy_signal_gives_its_derivative_within_two_percent(method):
    """Central differences of the noisy samples err by about sqrt(2) 0.01 / (2 dt) = 0.7 per second
    (17 % of the slope's rms); the smoothers stay within 2 %."""
    naive = np.gradient(NOISY, DT)
    assert _rms(naive - SLOPE) > 0.1 * _rms(SLOPE)
    smoother = {"savgol": lambda d: savitzky_golay(NOISY, DT, window=51, order=5, derivative=d),
                "fourier": lambda d: fourier_smooth(NOISY, DT, derivative=d),
                "zero-phase": lambda d: zero_phase_lowpass(NOISY, DT, cutoff=4.0, derivative=d)}[method]
    first = smoother(1)
    assert _rms(first - SLOPE) < 0.02 * _rms(SLOPE)
    smoothed = smoother(0)
    assert _rms(smoothed - CLEAN) < 0.01  # below the noise itself


def test_the_zero_phase_lowpass_has_no_lag_and_exact_derivatives_inside():
    """Forward-backward filtering: the filtered noise-free signal equals it inside to the pair's
    passband loss (a 4th-order 5 Hz Butterworth squared loses 4e-4 at 1.9 Hz), with no lag; its
    central-difference derivatives within (w dt)^2 / 6 of the analytic ones."""
    smoothed = zero_phase_lowpass(CLEAN, DT, cutoff=5.0)
    assert _rms(smoothed - CLEAN) < 1e-3 * _rms(CLEAN)
    lags = np.arange(-5, 6)
    periodic = CLEAN - 0.5 * T  # the trend left out: its shifts would dominate the correlation
    corr = [np.dot((smoothed - 0.5 * T)[INNER], np.roll(periodic, k)[INNER]) for k in lags]
    assert lags[int(np.argmax(corr))] == 0
    assert _rms(zero_phase_lowpass(CLEAN, DT, cutoff=5.0, derivative=1) - SLOPE) < 5e-3 * _rms(SLOPE)
    assert _rms(zero_phase_lowpass(CLEAN, DT, cutoff=5.0, derivative=2) - CURVE) < 2e-2 * _rms(CURVE)


def test_the_default_cutoff_lies_between_the_content_and_the_noise():
    cutoff = noise_floor_cutoff(NOISY, DT)
    assert 1.9 <= cutoff < 10.0, cutoff


@pytest.mark.parametrize("call, message", [
    (lambda: savitzky_golay(NOISY, DT, window=20), "window must be an odd number"),
    (lambda: savitzky_golay(np.r_[NOISY[:5], np.nan, NOISY[6:]], DT), "NaN or infinite"),
    (lambda: fourier_smooth(NOISY, DT, cutoff=80.0), "cutoff must lie in"),
    (lambda: fourier_smooth(NOISY, 0.0), "positive number of seconds"),
    (lambda: fourier_smooth(NOISY, DT, derivative=3), "derivative must be 0, 1 or 2"),
    (lambda: zero_phase_lowpass(NOISY, DT, cutoff=50.0), "below the Nyquist frequency"),
    (lambda: zero_phase_lowpass(NOISY, DT, cutoff=5.0, order=0), "order must be an integer from 1 to 10"),
    (lambda: zero_phase_lowpass(NOISY[:12], DT, cutoff=5.0), "give a longer record"),
])
def test_bad_arguments_are_named(call, message):
    with pytest.raises(DataError, match=message):
        call()
