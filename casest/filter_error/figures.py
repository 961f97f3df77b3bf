"""The figures of a filter-error estimate: what its filter predicted one step ahead against what
was measured, and the innovations with their autocorrelation (the residuals whose whiteness the
estimate's checks test). A free simulation of the model is not what filter error fits: with
process noise it wanders off the record, and its residuals say nothing of the estimate."""

from __future__ import annotations

import numpy as np

from ..estimation.figures import autocorrelation_bars, figure_grid
from .one_step import OneStepPredictions

__all__ = ["one_step_figure"]


def one_step_figure(predictions: OneStepPredictions, output_units=(), title: str | None = None,
                    max_lag: int = 50):
    """One row per output: the measured output and the filter's one-step prediction in time; the
    normalised innovation ``e_k / sqrt(S_k,jj)`` with its +/-2 band; its autocorrelation with the
    95 % band of white noise.

    Parameters
    ----------
    predictions : OneStepPredictions
        A :class:`~casest.FilterErrorEstimate`'s ``predictions``.
    output_units : sequence of str, optional
        Each output's unit, for the axis labels.
    title : str, optional
    max_lag : int
        Lags of the autocorrelation (samples).

    Returns
    -------
    matplotlib.figure.Figure
    """
    names = predictions.output_names
    units = list(output_units) + [""] * (len(names) - len(output_units))
    fig, axes = figure_grid(len(names), 3, figsize=(13.0, 1.9 * len(names) + 0.6))
    t, normalised = predictions.time, predictions.normalised_innovation
    for j, name in enumerate(names):
        label = name + (f" ({units[j]})" if units[j] else "")
        axes[j, 0].plot(t, predictions.measured[:, j], color="0.35", lw=0.8, label="measured")
        axes[j, 0].plot(t, predictions.predicted[:, j], color="C3", lw=0.9, label="one-step prediction")
        axes[j, 0].set_ylabel(label, fontsize=8)
        axes[j, 1].plot(t, normalised[:, j], color="C0", lw=0.6)
        axes[j, 1].axhspan(-2.0, 2.0, color="0.85", zorder=0)
        axes[j, 1].axhline(0.0, color="0.5", lw=0.6)
        axes[j, 1].set_ylabel("e / std", fontsize=8)
        finite = normalised[np.isfinite(normalised[:, j]), j]
        autocorrelation_bars(axes[j, 2], finite if finite.size else np.zeros(1), max_lag)
    axes[0, 0].legend(loc="best", fontsize=7)
    axes[0, 0].set_title("measured and predicted one step ahead", fontsize=9)
    axes[0, 1].set_title("normalised innovations (band +/-2)", fontsize=9)
    axes[0, 2].set_title("their autocorrelation (95 % band of white noise)", fontsize=9)
    for col, label in enumerate(("time (s)", "time (s)", "lag (samples)")):
        axes[-1, col].set_xlabel(label)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig
