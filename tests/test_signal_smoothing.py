"""Smoothing and differentiation of measured signals (casest.data.smoothing). Truth: the analytic
derivatives of y = sin(2 pi 0.7 t) + 0.3 cos(2 pi 1.9 t) + 0.5 t at 100 Hz over 10 s, with white
noise of std 0.01 (fixed seed) or none; compared over the inner 80 % of the record."""

import numpy as np
import pytest

from casest.data.smoothing import fourier_smooth, noise_floor_cutoff, savitzky_golay
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


@pytest.mark.parametrize("method", ["savgol", "fourier"])
def test_a_noisy_signal_gives_its_derivative_within_two_percent(method):
    """Central differences of the noisy samples err by about sqrt(2) 0.01 / (2 dt) = 0.7 per second
    (17 % of the slope's rms); the smoothers stay within 2 %."""
    naive = np.gradient(NOISY, DT)
    assert _rms(naive - SLOPE) > 0.1 * _rms(SLOPE)
    first = savitzky_golay(NOISY, DT, window=51, order=5, derivative=1) if method == "savgol" else \
        fourier_smooth(NOISY, DT, derivative=1)
    assert _rms(first - SLOPE) < 0.02 * _rms(SLOPE)
    smoothed = savitzky_golay(NOISY, DT, 51, 5) if method == "savgol" else fourier_smooth(NOISY, DT)
    assert _rms(smoothed - CLEAN) < 0.01  # below the noise itself


def test_the_default_cutoff_lies_between_the_content_and_the_noise():
    cutoff = noise_floor_cutoff(NOISY, DT)
    assert 1.9 <= cutoff < 10.0, cutoff


@pytest.mark.parametrize("call, message", [
    (lambda: savitzky_golay(NOISY, DT, window=20), "window must be an odd number"),
    (lambda: savitzky_golay(np.r_[NOISY[:5], np.nan, NOISY[6:]], DT), "NaN or infinite"),
    (lambda: fourier_smooth(NOISY, DT, cutoff=80.0), "cutoff must lie in"),
    (lambda: fourier_smooth(NOISY, 0.0), "positive number of seconds"),
    (lambda: fourier_smooth(NOISY, DT, derivative=3), "derivative must be 0, 1 or 2"),
])
def test_bad_arguments_are_named(call, message):
    with pytest.raises(DataError, match=message):
        call()
