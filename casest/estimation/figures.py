"""Figures of an estimate, as a flight-test report shows them: measured against estimated
outputs per manoeuvre, the residuals with their autocorrelation, the convergence of each
parameter and its std over the iterations, and the match on a held-out record ("proof of
match"). Each returns a matplotlib ``Figure`` (``pip install 'casest[plot]'``); the
:class:`casest.Estimate` methods ``plot_fit``, ``plot_residuals`` and ``plot_convergence``
call them, and :func:`save_figure` writes one atomically.
"""

from __future__ import annotations

import io
import os
from typing import Mapping

import numpy as np

from ..data.files import atomic_write_bytes, stream_descriptor
from ..errors import MissingExtraError, OptionError
from .validation import Validation, by_name, parameter_vector


__all__ = ["fit_figure", "residuals_figure", "convergence_figure", "validation_figure", "correlation_figure",
           "save_figure", "named_records", "figure_grid", "autocorrelation_bars"]


def figure_grid(rows: int, cols: int, figsize):
    """A figure and its axes grid (always 2-D), without pyplot's global state: never shown by
    accident, never kept alive by it.

    Parameters
    ----------
    rows, cols : int
    figsize : (float, float)
        Inches.

    Returns
    -------
    matplotlib.figure.Figure
    ndarray of Axes, shape (rows, cols)

    Raises
    ------
    MissingExtraError
        matplotlib is not installed.
    """
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise MissingExtraError("figures need matplotlib, which is not installed: pip install 'casest[plot]'") from exc
    fig = Figure(figsize=figsize)
    return fig, fig.subplots(rows, cols, squeeze=False)


def save_figure(fig, path: str | os.PathLike, dpi: int = 120) -> str:
    """Write a figure atomically (a temporary file renamed into place; ``-`` or an open
    descriptor's path such as ``/dev/stdout`` written in place,
    :func:`casest.data.files.atomic_write_bytes`), in the format its name's extension says
    (PNG without one, or to a stream).

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    path : str or os.PathLike
    dpi : int

    Returns
    -------
    str
        ``path``.

    Raises
    ------
    OptionError
        An extension matplotlib does not write (``fig.xyz``).
    """
    path = os.fspath(path)
    suffix = os.path.splitext(path)[1].lower().lstrip(".")
    kind = "png" if stream_descriptor(path) is not None or not suffix else suffix
    supported = fig.canvas.get_supported_filetypes()
    if kind not in supported:
        raise OptionError(f"{path!r}: matplotlib writes no {suffix!r} files; name the figure .png (or one of "
                          f"{sorted(supported)})")
    buffer = io.BytesIO()
    fig.savefig(buffer, dpi=dpi, format=kind)
    atomic_write_bytes(path, buffer.getvalue())
    return path


def named_records(records) -> dict:
    """One record, a sequence of them (named e1, e2, ... as the estimator names them) or a mapping.

    Parameters
    ----------
    records : Dataset, sequence of Dataset or mapping of str to Dataset

    Returns
    -------
    dict of str to Dataset
    """
    if isinstance(records, Mapping):
        return dict(records)
    if isinstance(records, (list, tuple)):
        return {f"e{k + 1}": r for k, r in enumerate(records)}
    return {"record": records}


def _record_theta(model, parameters, name: str) -> np.ndarray:
    """The parameters for one manoeuvre: its own initial states (``x0@name``) where estimated per manoeuvre."""
    values = by_name(parameters)
    if isinstance(values, Mapping):
        values = {p: values.get(f"{p}@{name}", values.get(p)) for p in model.parameter_names
                  if f"{p}@{name}" in values or p in values}
    return parameter_vector(model, values)


def _prediction(model, theta, data) -> tuple[np.ndarray, np.ndarray, str]:
    """(x axis, predicted outputs, x label) of one record."""
    if hasattr(model, "states"):
        return data.signals[:, 0], model.predict_data(theta, data), "t (s)"
    for name in ("t", "time"):  # a static model's record in time keeps its time among the extra columns
        if getattr(data, "time_ordered", False) and name in data.extra:
            return data.extra[name], model.predict(theta, data.signals), "t (s)"
    return np.arange(data.n_samples), model.predict(theta, data.signals), "sample"


def _label(model, j: int) -> str:
    units = getattr(model, "output_units", None) or ()
    unit = units[j] if j < len(units) else ""
    return model.output_names[j] + (f" ({unit})" if unit else "")


def fit_figure(model, parameters, records, analysis=None, title: str | None = None):
    """Measured against estimated outputs, one column per record (manoeuvre), one row per output.

    Parameters
    ----------
    model : Model or DynamicModel
    parameters : Estimate, mapping or array_like, shape (n_parameters,)
    records : Dataset, sequence or mapping of Dataset
    analysis : ResidualAnalysis, optional
        Adds a row with each channel's residual autocorrelation and its 95 % band.
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    records = named_records(records)
    ny = model.n_outputs
    rows = ny + (1 if analysis is not None else 0)
    fig, axes = figure_grid(rows, len(records), figsize=(4.5 * len(records) + 1.5, 1.8 * rows + 0.4))
    for col, (name, data) in enumerate(records.items()):
        x, predicted, xlabel = _prediction(model, _record_theta(model, parameters, name), data)
        for j in range(ny):
            ax = axes[j, col]
            ax.plot(x, data.outputs[:, j], color="0.35", lw=0.8, label="measured")
            ax.plot(x, predicted[:, j], color="C3", lw=1.0, label="estimated")
            if col == 0:
                ax.set_ylabel(_label(model, j), fontsize=8)
            if j == 0 and len(records) > 1:
                ax.set_title(name, fontsize=9)
        axes[ny - 1, col].set_xlabel(xlabel)
    axes[0, 0].legend(loc="best", fontsize=7)
    if analysis is not None:
        _autocorrelation_row(axes[ny], analysis)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def _autocorrelation_row(axes, analysis) -> None:
    for col, ax in enumerate(axes):
        if col:
            ax.axis("off")
            continue
        lags = np.arange(analysis.max_lag + 1)
        for j, channel in enumerate(analysis.output_names):
            ax.plot(lags[1:], analysis.autocorrelation[j, 1:], lw=0.8, label=channel)
        band = float(np.max(analysis.band))
        ax.axhspan(-band, band, color="0.85", zorder=0)
        ax.set_xlabel("lag (samples)")
        ax.set_ylabel("residual autocorr.", fontsize=8)
        ax.legend(fontsize=6, ncol=2)


def residuals_figure(model, parameters, records, max_lag: int = 50):
    """Residual time histories per record and output, with each output's autocorrelation over
    all records and the 95 % band of white noise, and (as MATLAB's ``resid`` draws them) the
    cross-correlation of the prewhitened residuals with each signal and its 95 % band of
    independence (:mod:`casest.estimation.independence`): lags of both signs for a static model,
    past inputs for a dynamic one.

    Parameters
    ----------
    model : Model or DynamicModel
    parameters : Estimate, mapping or array_like
    records : Dataset, sequence or mapping of Dataset
    max_lag : int
        Lags of the autocorrelation (samples).

    Returns
    -------
    matplotlib.figure.Figure
    """
    records = named_records(records)
    ny = model.n_outputs
    dynamic = hasattr(model, "states")
    names = [s.name for s in model.inputs] if dynamic else list(model.signal_names)
    cols = len(records) + 1 + bool(names)
    fig, axes = figure_grid(ny, cols, figsize=(4.0 * cols, 1.8 * ny + 0.4))
    pooled, pooled_signals, pooled_directions = [[] for _ in range(ny)], [], []
    for col, (name, data) in enumerate(records.items()):
        theta = _record_theta(model, parameters, name)
        x, predicted, xlabel = _prediction(model, theta, data)
        residuals = data.outputs - predicted
        pooled_signals.append(np.column_stack([data.column(n) for n in names]) if names else None)
        pooled_directions.append(None if dynamic else _fit_directions(model, theta, data))
        for j in range(ny):
            axes[j, col].plot(x, residuals[:, j], color="C0", lw=0.7)
            axes[j, col].axhline(0.0, color="0.5", lw=0.6)
            pooled[j].append(residuals[:, j])
            if col == 0:
                axes[j, col].set_ylabel("res. " + _label(model, j), fontsize=8)
            if j == 0 and len(records) > 1:
                axes[j, col].set_title(name, fontsize=9)
        axes[ny - 1, col].set_xlabel(xlabel)
    auto = len(records)
    for j in range(ny):
        r = np.concatenate(pooled[j])
        autocorrelation_bars(axes[j, auto], r[np.isfinite(r)] if np.isfinite(r).any() else np.zeros(1), max_lag)
        if names:
            directions = None if dynamic else np.vstack(pooled_directions)[:, j, :]
            _cross_correlation_lines(axes[j, auto + 1], r, np.vstack(pooled_signals), names, dynamic, directions)
    axes[0, auto].set_title("autocorrelation", fontsize=9)
    axes[ny - 1, auto].set_xlabel("lag (samples)")
    if names:
        axes[0, auto + 1].set_title("cross-correlation with the signals (prewhitened)", fontsize=9)
        axes[ny - 1, auto + 1].set_xlabel("lag (samples; > 0: the residual follows the signal)")
    fig.tight_layout()
    return fig


#: signals drawn in a cross-correlation panel (those with the largest peaks)
MAX_DRAWN_SIGNALS = 6


def _fit_directions(model, theta, data) -> np.ndarray:
    """A static model's Jacobian at ``theta`` on a record, shape (N, n_outputs, n_parameters)."""
    from .._casadi.sample_blocks import evaluate_samples

    _, jacobian = evaluate_samples(model.jacobian_function, [data.signals], [np.asarray(theta, dtype=float)])
    return jacobian.reshape(data.n_samples, model.n_parameters, model.n_outputs).transpose(0, 2, 1)


def _cross_correlation_lines(ax, residuals: np.ndarray, signals: np.ndarray, names: list, dynamic: bool,
                             directions: np.ndarray | None = None) -> None:
    """One channel's prewhitened cross-correlation with each signal (what the independence test
    reads: the fit's own directions left aside), the largest few drawn, with the 95 % band of
    independence."""
    from .independence import independence_test, nuisance_basis, prewhitener
    from .residual_family import cross_lags

    filled = np.where(np.isfinite(residuals), residuals, np.nanmean(residuals) if np.isfinite(residuals).any() else 0)
    whitener = prewhitener(filled)
    e = whitener.apply(filled - filled.mean())
    lags = cross_lags(filled.size, dynamic)
    nuisance = None if directions is None else np.column_stack([whitener.apply(c) for c in directions.T])
    basis = nuisance_basis(nuisance, e.size, lags)
    tests = [(n, independence_test(e, whitener.apply(signals[:, i]), lags, basis=basis)) for i, n in enumerate(names)
             if np.ptp(signals[:, i]) > 0]
    curves = [(n, test.correlation) for n, test in tests if test is not None]
    curves.sort(key=lambda item: -float(np.max(np.abs(item[1]))))
    for name, rho in curves[:MAX_DRAWN_SIGNALS]:
        ax.plot(lags, rho, marker="o", ms=2.5, lw=0.8, label=name)
    band = 1.96 / np.sqrt(max(e.size, 1))
    ax.axhspan(-band, band, color="0.85", zorder=0)
    ax.axhline(0.0, color="0.5", lw=0.6)
    ax.set_ylim(-1, 1)
    ax.set_ylabel("cross-corr.", fontsize=8)
    if curves:
        ax.legend(fontsize=6, loc="upper right", ncol=2)


def autocorrelation_bars(ax, residuals: np.ndarray, max_lag: int) -> None:
    """One channel's pooled residual autocorrelation as bars, with the 95 % band of white noise.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    residuals : ndarray, shape (N,)
        Finite values, in time order.
    max_lag : int
        The last lag drawn (samples).
    """
    r = residuals - residuals.mean()
    lags = np.arange(1, min(max_lag, max(r.size - 1, 1)) + 1)
    denominator = float(np.dot(r, r)) or 1.0
    ax.bar(lags, [np.dot(r[:-lag], r[lag:]) / denominator for lag in lags], width=0.8, color="C0")
    band = 1.96 / np.sqrt(max(r.size, 1))
    ax.axhspan(-band, band, color="0.85", zorder=0)
    ax.set_ylim(-1, 1)
    ax.set_ylabel("autocorr.", fontsize=8)


def convergence_figure(history, parameter_names, units=()):
    """Each parameter and its std (Gauss-Newton's Cramer-Rao bound at that iterate) over the
    iterations of stage 2, and the cost.

    Parameters
    ----------
    history : ConvergenceHistory
    parameter_names : sequence of str
    units : sequence of str, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    n = len(parameter_names)
    cols = min(4, n + 1)
    rows = int(np.ceil((n + 1) / cols))
    fig, axes = figure_grid(rows, cols, figsize=(3.2 * cols, 2.2 * rows))
    it = np.arange(history.theta.shape[0])
    for k, name in enumerate(parameter_names):
        ax = axes.flat[k]
        value, std = history.theta[:, k], history.std[:, k]
        ax.plot(it, value, "o-", ms=3, color="C0")
        finite = np.isfinite(std)
        ax.fill_between(it[finite], (value - std)[finite], (value + std)[finite], color="C0", alpha=0.2, lw=0)
        unit = units[k] if k < len(units) and units[k] else ""
        ax.set_title(name + (f" ({unit})" if unit else ""), fontsize=8)
    ax = axes.flat[n]
    ax.semilogy(it, history.cost - np.min(history.cost) + 1e-12 * max(1.0, abs(float(np.min(history.cost)))),
                "o-", ms=3, color="C3")
    ax.set_title("cost above its minimum", fontsize=8)
    for ax in axes.flat[n + 1:]:
        ax.axis("off")
    for ax in axes[-1]:
        ax.set_xlabel("iteration")
    fig.tight_layout()
    return fig


def validation_figure(validation: Validation, title: str = "held-out record"):
    """Proof of match: the held-out record's measured and predicted outputs, Theil's U per output.

    Parameters
    ----------
    validation : Validation
    title : str

    Returns
    -------
    matplotlib.figure.Figure
    """
    ny = len(validation.output_names)
    fig, axes = figure_grid(ny, 1, figsize=(7.5, 1.9 * ny + 0.5))
    for j, name in enumerate(validation.output_names):
        ax = axes[j, 0]
        ax.plot(validation.time, validation.measured[:, j], color="0.35", lw=0.8, label="measured")
        ax.plot(validation.time, validation.predicted[:, j], color="C2", lw=1.0, label="predicted")
        ax.set_ylabel(name, fontsize=8)
        ax.set_title(f"{name}: Theil U = {validation.theil[j]:.3f}, rms error = {validation.rms_error[j]:.3g}",
                     fontsize=8)
    axes[0, 0].legend(loc="best", fontsize=7)
    axes[-1, 0].set_xlabel("t (s)")
    fig.suptitle(f"Proof of match: {title}", fontsize=10)
    fig.tight_layout()
    return fig


def correlation_figure(correlation: np.ndarray, parameter_names, title: str | None = None):
    """The correlation matrix of the estimates as a colour map, each entry written in its cell.

    Parameters
    ----------
    correlation : ndarray, shape (n, n)
    parameter_names : sequence of str
    title : str, optional

    Returns
    -------
    matplotlib.figure.Figure
    """
    n = len(parameter_names)
    size = 1.0 + 0.45 * n
    fig, axes = figure_grid(1, 1, figsize=(size + 1.2, size))
    ax = axes[0, 0]
    image = ax.imshow(np.nan_to_num(correlation), vmin=-1, vmax=1, cmap="RdBu_r")
    ax.set_xticks(range(n), parameter_names, rotation=90, fontsize=7)
    ax.set_yticks(range(n), parameter_names, fontsize=7)
    for i in range(n):
        for j in range(n):
            value = correlation[i, j]
            if i != j and np.isfinite(value):
                ax.text(j, i, f"{value:.2f}", ha="center", va="center", fontsize=5 if n > 12 else 6,
                        color="white" if abs(value) > 0.7 else "black")
    fig.colorbar(image, ax=ax, shrink=0.8)
    if title:
        ax.set_title(title, fontsize=9)
    fig.tight_layout()
    return fig
