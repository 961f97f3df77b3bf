"""The residual figure of a frequency-domain estimate (the frequency domain's ``resid``): per
channel, the residual periodogram with the spectrum the flatness test fits, and the residuals'
response to each input with the band the noise alone would stay inside."""

from __future__ import annotations

import numpy as np

from ..estimation.figures import figure_grid
from ..estimation.html_report import register_data_figures
from .domain import frequency_residuals
from .result import FrequencyEstimate
from .spectral_checks import band_polynomials, spectrum_trend

__all__ = ["spectral_figure", "NOISE_BAND_FACTOR", "EXCITED"]

#: the band of the residual response: ``|v| <= sqrt(3 S(w))`` holds for 95 % of the frequencies
#: under the noise alone (``|v|^2 / S`` is exponential: ``P(> 3) = exp(-3) = 5 %``)
NOISE_BAND_FACTOR = 3.0
#: the response to an input is drawn where its transform reaches this fraction of its largest
EXCITED = 1e-2


def spectral_figure(estimate: FrequencyEstimate, model, data, states=None):
    """Per channel: the residual periodogram ``|v_j(w)|^2`` with the fitted spectrum ``S_j(w)``
    and the flat ``S_j`` the fit weighted by; the residual response ``|v_j(w) / U_i(w)|`` to each
    input with the noise's 95 % band ``sqrt(3 S_j(w)) / |U_i(w)|``, at the frequencies where the
    input's transform reaches :data:`EXCITED` of its largest.

    Parameters
    ----------
    estimate : FrequencyEstimate
    model : DynamicModel
        The model estimated.
    data : Dataset
        Its record.
    states : mapping, optional
        Equation error: which output is each state.

    Returns
    -------
    matplotlib.figure.Figure
        Rows the channels; columns the periodogram and the response to the inputs. The band is
        where noise of the residuals' own spectrum would scatter (a misfit widens it too): a
        response that runs smoothly along the frequencies, or above the band, is what the
        coherence test detects; a fitted spectrum far from flat, with a scattered response, is
        coloured noise.
    """
    U, V, channels = frequency_residuals(estimate, model, data, states)
    w = np.asarray(estimate.frequencies, dtype=float)
    order = np.argsort(w)
    polynomials = band_polynomials(w)
    inputs = [s.name for s in model.inputs]
    fig, axes = figure_grid(len(channels), 2, (10.0, 2.4 * len(channels) + 0.6))
    for j, channel in enumerate(channels):
        power = np.abs(V[:, j]) ** 2
        trend = spectrum_trend(power, polynomials)
        left, right = axes[j]
        left.semilogy(w[order], power[order], ".", label="|v|^2")
        left.semilogy(w[order], trend[order], "-", label="fitted spectrum")
        left.axhline(float(estimate.spectra[j]), linestyle="--", color="gray", label="flat S (the fit's weight)")
        left.set_ylabel(channel)
        for i, name in enumerate(inputs):
            magnitude = np.abs(U[:, i])
            excited = order[magnitude[order] >= EXCITED * magnitude.max()]  # the ratio means nothing elsewhere
            if excited.size == 0:
                continue
            response = np.abs(V[excited, j]) / magnitude[excited]
            band = np.sqrt(NOISE_BAND_FACTOR * trend[excited]) / magnitude[excited]
            floor = 0.3 * float(np.min(np.concatenate([response[response > 0], band])))
            line, = right.semilogy(w[excited], response, ".-", label=f"|v / {name}|")
            right.fill_between(w[excited], floor, band, color=line.get_color(), alpha=0.15,
                               label="95 % band of noise of the residuals' spectrum")
    axes[0][0].set_title("residual spectrum")
    axes[0][1].set_title("residual response to the inputs")
    for ax in axes[-1]:
        ax.set_xlabel("w (rad/s)")
    axes[0][0].legend(fontsize=7)
    axes[0][1].legend(fontsize=7)
    fig.tight_layout()
    return fig


@register_data_figures(FrequencyEstimate)
def _page_figures(estimate: FrequencyEstimate, model, data) -> list:
    """The page's figures of a frequency-domain estimate (its spectra, not a simulation in time)."""
    return [spectral_figure(estimate, model, data)]
