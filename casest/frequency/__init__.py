"""The frequency domain: Fourier transforms of records (batch and recursive) and output-error
estimation of a linear model from them, with its residual tests and a diagnosed delay."""

from .domain import RecursiveFourierTransform, fourier_transform, frequency_domain_estimate, frequency_residuals
from .figures import spectral_figure
from .refit import refit_delay
from .result import FrequencyEstimate


__all__ = ["FrequencyEstimate", "RecursiveFourierTransform", "fourier_transform", "frequency_domain_estimate", "refit_delay",
           "frequency_residuals", "spectral_figure"]
