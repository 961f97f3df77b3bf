"""The frequency domain: Fourier transforms of records (batch and recursive) and output-error
estimation of a linear model from them."""

from .domain import FrequencyEstimate, RecursiveFourierTransform, fourier_transform, frequency_domain_estimate


__all__ = ["FrequencyEstimate", "RecursiveFourierTransform", "fourier_transform", "frequency_domain_estimate"]
