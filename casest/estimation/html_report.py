"""Any estimate as one self-contained HTML page: the conclusion, the fit statistics its report
lists, the parameter table, the noise, the profile-likelihood intervals and stage 1's
likelihood-ratio sets, the notes and residual checks, and the figures that apply: the
parameters' correlations from the covariance, the convergence history, stage 1's landscape (each
swept parameter against Tr[R] of the candidates), and with the model and its data the fit and
the residuals in time with their autocorrelation (a filter-error estimate draws its own record:
the one-step predictions and the innovations); embedded as PNG (no network, no other file).

:func:`result_html` takes anything that implements the result protocol
(:class:`~casest.estimation.result_protocol.EstimateLike`); the results' ``to_html(path)``
write it atomically and ``_repr_html_`` shows the compact table in a notebook. Figures need
matplotlib (``casest[plot]``); without it the page says so and holds the tables.
"""

from __future__ import annotations

import base64
import importlib.util
import io
import os
from collections.abc import Mapping
from html import escape

import numpy as np

from ..data.files import atomic_write_text
from ..errors import OptionError
from ..status import TrustCode
from .reporting import std_text
from .verdict import summary_lines

__all__ = ["result_html", "compact_html", "write_html", "DATA_FIGURES", "register_data_figures"]

_STYLE = """
body { font-family: sans-serif; max-width: 60em; margin: 2em auto; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; }
th, td { border: 1px solid #bbb; padding: 0.2em 0.6em; text-align: right; }
th:first-child, td:first-child { text-align: left; }
.conclusion { padding: 0.6em 1em; border-left: 0.4em solid; margin: 1em 0; }
.trusted { border-color: #2a7; background: #eef9f2; }
.local { border-color: #27a; background: #eef4fb; }
.caution { border-color: #c70; background: #fdf4e6; }
.coloured { border-color: #87a; background: #f5f1fa; }
.model_error { border-color: #c33; background: #fbeeee; }
details > summary { cursor: pointer; }
img { max-width: 100%; }
"""


def _conclusion(result) -> tuple[str, str]:
    code, reason = result.conclusion()
    css = {TrustCode.TRUSTED: "trusted", TrustCode.LOCAL: "local", TrustCode.COLOURED_NOISE: "coloured",
           TrustCode.MODEL_ERROR: "model_error"}.get(code, "caution")
    return css, f"<div class='conclusion {css}' id='conclusion'><b>{escape(code.value.upper())}</b>: " \
                f"{escape(reason)}</div>"


def _parameter_rows(result) -> str:
    names = list(result.parameter_names)
    units = list(getattr(result, "parameter_units", ()) or [""] * len(names))
    lower = getattr(result, "lower_bounds", None)
    upper = getattr(result, "upper_bounds", None)
    reasons = list(getattr(result, "std_reasons", None) or [None] * len(names))
    shown = result.std_choice().std if hasattr(result, "std_choice") else result.std  # colored-residual std where chosen
    rows = []
    for k, (name, value, std) in enumerate(zip(names, result.theta, shown)):
        bounds = f"[{lower[k]:.6g}, {upper[k]:.6g}]" if lower is not None and upper is not None else ""
        shown_std = std_text(std)
        rows.append(f"<tr><td>{escape(str(name))}</td><td class='value'>{float(value):.10g}</td>"
                    f"<td class='std'>{shown_std}</td><td>{escape(units[k] if k < len(units) else '')}</td>"
                    f"<td>{bounds}</td><td>{escape(reasons[k] or '')}</td></tr>")
    return "".join(rows)


def _parameter_table(result) -> str:
    colored = hasattr(result, "std_choice") and result.std_choice().kind == "colored"
    heading = "colored-residual std (1 sigma)" if colored else "std (1 sigma)"
    return (f"<table id='parameters'><tr><th>parameter</th><th>value</th><th>{heading}</th><th>unit</th>"
            f"<th>bounds</th><th>note</th></tr>{_parameter_rows(result)}</table>")


def _noise_table(result) -> str:
    names, R = getattr(result, "output_names", None), getattr(result, "R", None)
    if names is None or R is None or np.ndim(R) != 1:
        return ""
    rows = "".join(f"<tr><td>{escape(n)}</td><td>{r:.6g}</td><td>{np.sqrt(r):.6g}</td></tr>"
                   for n, r in zip(names, np.asarray(R, dtype=float)))
    implied = getattr(result, "innovation_covariance", None) is not None  # the innovation form: R not estimated
    caption = "<p>implied measurement noise diag(R - C P C'), not estimated</p>" if implied else ""
    return (f"<h2>Noise</h2>{caption}<table id='noise'><tr><th>output</th><th>variance R</th><th>std</th></tr>"
            f"{rows}</table>")


def _fit_statistics_table(result) -> str:
    """The result's ``fit_statistics()`` (what its report lists under ``[[Fit Statistics]]``)."""
    statistics = getattr(result, "fit_statistics", None)
    if not callable(statistics):
        return ""
    rows = "".join(f"<tr><td>{escape(name)}</td><td>{escape(value)}</td></tr>" for name, value in statistics())
    return f"<h2>Fit statistics</h2><table id='fit_statistics'>{rows}</table>"


def _filter_tables(result) -> str:
    """A filter-error estimate's process noise (F and q with their std), its innovation covariance
    where estimated, and its Kalman gain with diag(K C)."""
    F = getattr(result, "process_noise_distribution", None)
    if F is None:
        return ""
    F_std, q_std = result.process_noise_distribution_std, result.process_noise_std
    rows = "".join(f"<tr><td>{escape(n)}</td><td>{F[n]:.6g}</td><td>{std_text(F_std.get(n))}</td>"
                   f"<td>{q:.6g}</td><td>{std_text(q_std.get(n)) if n in q_std else 'given'}</td></tr>"
                   for n, q in result.process_noise.items())
    parts = ["<h2>Process noise</h2><table id='process_noise'><tr><th>state</th><th>F</th><th>std of F</th>"
             f"<th>q = F^2</th><th>std of q</th></tr>{rows}</table>"]
    innovation = getattr(result, "innovation_covariance", None)
    if innovation is not None:
        rows = "".join(f"<tr><td>{escape(n)}</td><td>{innovation[j, j]:.6g}</td>"
                       f"<td>{std_text(result.innovation_covariance_std[j, j], '.3g')}</td></tr>"
                       for j, n in enumerate(result.output_names))
        parts.append("<h2>Innovation covariance</h2><table id='innovation_covariance'><tr><th>output</th>"
                     f"<th>variance</th><th>std of it</th></tr>{rows}</table>")
    record = getattr(result, "predictions", None)
    if record is not None:
        head = "".join(f"<th>{escape(n)}</th>" for n in record.output_names)
        rows = "".join(f"<tr><td>{escape(name)}</td>" + "".join(f"<td>{k:+.5g}</td>" for k in record.gain[i])
                       + f"<td>{record.kc_diagonal[i]:.4g}</td></tr>" for i, name in enumerate(record.state_names))
        parts.append(f"<h2>Kalman gain</h2><p>K at {escape(record.gain_at)}</p><table id='gain'><tr><th>state</th>"
                     f"{head}<th>diag(K C)</th></tr>{rows}</table>")
    return "".join(parts)


def _figure_png(draw) -> str | None:
    """``draw(figure)`` rendered as an embedded PNG ``<img>``; None without matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    fig = plt.figure(figsize=(6.4, 4.8))
    try:
        draw(fig)
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=100, bbox_inches="tight")
    finally:
        plt.close(fig)
    data = base64.b64encode(buffer.getvalue()).decode("ascii")
    return f"<img alt='figure' src='data:image/png;base64,{data}'>"


def _png_of(fig) -> str:
    """A drawn matplotlib figure as an embedded PNG ``<img>`` (the figure closed)."""
    import matplotlib.pyplot as plt

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=100)
    plt.close(fig)
    return f"<img alt='figure' src='data:image/png;base64,{base64.b64encode(buffer.getvalue()).decode()}'>"


#: result type -> ``(result, model, data) -> list of matplotlib figures``, for results whose
#: residuals are not the model's simulation in time (the frequency domain's spectra)
DATA_FIGURES: dict = {}


def register_data_figures(result_type: type):
    """Decorator: register the figures a result of ``result_type`` draws with its model and data.

    Parameters
    ----------
    result_type : type

    Returns
    -------
    callable
        The decorator (it returns the function unchanged).
    """
    def register(function):
        DATA_FIGURES[result_type] = function
        return function
    return register


def _data_figures(result, model, data) -> list:
    """The fit and the residuals (with their autocorrelation) of ``model`` at the result on
    ``data``, or the figures registered for the result's type; a result that holds its own record
    of the fit (``record_figures()``, filter error's one-step predictions) draws that instead."""
    if model is not None:
        _check_model(result, model)
    own_record = getattr(result, "record_figures", None)
    if callable(own_record) and _has_matplotlib():
        figures = own_record()
        if figures:
            return [_png_of(fig) for fig in figures]
    if model is None or data is None:
        return []
    _check_data(data)
    try:
        import matplotlib

        matplotlib.use("Agg", force=False)
    except ImportError:
        return []
    from .figures import fit_figure, residuals_figure

    own = DATA_FIGURES.get(type(result))
    if own is not None:
        return [_png_of(fig) for fig in own(result, model, data)]
    theta = np.asarray(result.theta, dtype=float)
    return [_png_of(fit_figure(model, theta, data, title="measured and estimated")),
            _png_of(residuals_figure(model, theta, data))]


def _has_matplotlib() -> bool:
    return importlib.util.find_spec("matplotlib") is not None


def _check_model(result, model) -> None:
    """Refuse a model whose parameters are not the result's (a parameter of one experiment is ``name@experiment``)."""
    names = list(getattr(result, "parameter_names", ()))
    own = list(getattr(model, "parameter_names", ()))
    estimated = {n.split("@")[0] for n in names}
    missing, extra = [n for n in own if n not in estimated], sorted(estimated - set(own))
    if not own or missing or extra:
        raise OptionError(f"the page's model has parameters {own} and the result {names}"
                          + (f" ({missing} only in the model)" if missing else "")
                          + (f" ({extra} only in the result)" if extra else "")
                          + ": give the model the result was estimated with")


def _check_data(data) -> None:
    """Refuse data that are not records."""
    from ..data.dataset import Dataset

    records = list(data.values()) if isinstance(data, Mapping) else (list(data) if isinstance(data, (list, tuple))
                                                                      else [data])
    wrong = [type(r).__name__ for r in records if not isinstance(r, Dataset)]
    if not records or wrong:
        raise OptionError(f"the page's data must be a casest.Dataset, or a sequence or mapping of them; got "
                          f"{wrong or 'none'}")


def _landscape_figure(result) -> str | None:
    landscape = getattr(result, "landscape", None)
    if landscape is None or not len(landscape.nonlinear) or np.size(landscape.trace_R) < 2:
        return None
    cands, trace = np.asarray(landscape.candidates, dtype=float), np.asarray(landscape.trace_R, dtype=float)
    shown = np.isfinite(trace)

    def draw(fig):
        n = len(landscape.nonlinear)
        for k, name in enumerate(landscape.nonlinear):
            ax = fig.add_subplot(1, n, k + 1)
            ax.scatter(cands[shown, k], trace[shown], s=4, color="0.4")
            ax.scatter(cands[landscape.best_index, k], trace[landscape.best_index], s=30, color="C3", label="best")
            ax.set_yscale("log")
            ax.set_xlabel(name)
            if k == 0:
                ax.set_ylabel("Tr[R] of the candidate")
        fig.suptitle(f"stage 1: {np.count_nonzero(shown)} candidates, verdict {landscape.verdict}")

    return _figure_png(draw)


def _intervals_table(result) -> str:
    intervals = getattr(result, "intervals", ()) or ()
    if not intervals:
        return ""
    rows = "".join(f"<tr><td>{escape(i.name)}</td><td>{i.estimate:.6g}</td><td>{i.lower:.6g}</td><td>{i.upper:.6g}</td>"
                   f"<td>{i.level:.3g}</td></tr>" for i in intervals)
    return ("<h2>Profile-likelihood intervals</h2><table id='intervals'><tr><th>parameter</th><th>estimate</th>"
            f"<th>lower</th><th>upper</th><th>level</th></tr>{rows}</table>")


def _likelihood_sets_table(result) -> str:
    sets = getattr(result, "likelihood_sets", ()) or ()
    if not sets:
        return ""
    rows = "".join(f"<tr><td>{escape(s.name)}</td><td>{escape(', '.join(f'[{a:.6g}, {b:.6g}]' for a, b in s.intervals))}"
                   f"</td><td>{s.level:.3g}</td></tr>" for s in sets)
    return ("<h2>Likelihood-ratio sets (stage 1)</h2><table id='likelihood_sets'><tr><th>parameter</th>"
            f"<th>set (one or more pieces)</th><th>level</th></tr>{rows}</table>")


def _correlation_figure(result) -> str | None:
    n = len(result.parameter_names)
    cov = np.asarray(result.covariance, dtype=float)[:n, :n]
    std = np.sqrt(np.abs(np.diag(cov)))
    keep = np.flatnonzero(np.isfinite(std) & (std > 0))  # the parameters with a std (held ones have none)
    cov, std = cov[np.ix_(keep, keep)], std[keep]
    names = [result.parameter_names[i] for i in keep]
    if keep.size < 2 or not np.all(np.isfinite(cov)):
        return None
    corr = cov / np.outer(std, std)

    def draw(fig):
        ax = fig.add_subplot(111)
        image = ax.imshow(corr, vmin=-1, vmax=1, cmap="RdBu_r")
        ax.set_xticks(range(keep.size), names, rotation=90)
        ax.set_yticks(range(keep.size), names)
        ax.set_title("parameter correlations")
        fig.colorbar(image, ax=ax)

    return _figure_png(draw)


def _convergence_figure(result) -> str | None:
    history = getattr(result, "convergence", None)
    costs = getattr(history, "cost", None) if history is not None else None
    if costs is None or len(costs) < 2:
        return None

    def draw(fig):
        ax = fig.add_subplot(111)
        ax.plot(np.arange(len(costs)), costs, marker="o")
        ax.set_xlabel("iteration")
        ax.set_ylabel("cost")
        ax.set_title("convergence")

    return _figure_png(draw)


def _notes_and_checks(result) -> str:
    parts = []
    checks = getattr(result, "residual_checks", ())
    if checks:  # one line per output; every test folded
        parts.append("<h2>Residual checks</h2><ul>" + "".join(f"<li>{escape(line)}</li>" for line in summary_lines(checks))
                     + f"</ul><details><summary>every test ({len(checks)})</summary><ul>"
                     + "".join(f"<li>{escape(c.describe())}</li>" for c in checks) + "</ul></details>")
    diagnosis = getattr(result, "diagnosis", None)
    if diagnosis is not None:
        refit = getattr(result, "REFIT_CALL", "")
        parts.append(f"<h2>Diagnosis</h2><p id='diagnosis'>{escape(diagnosis.describe())}"
                     + (f"; <code>{escape(refit)}</code> estimates the model with this change" if refit else "")
                     + "</p>")
    if result.notes:
        parts.append("<h2>Notes</h2><ul>" + "".join(f"<li>{escape(str(n))}</li>" for n in result.notes) + "</ul>")
    return "".join(parts)


def result_html(result, title: str | None = None, figures: bool = True, model=None, data=None) -> str:
    """The page of an estimate (module docstring).

    Parameters
    ----------
    result : EstimateLike
    title : str, optional
        Default: the model's name, or the result's type.
    figures : bool
        Draw the figures the result can draw (needs matplotlib).
    model : Model or DynamicModel, optional
        The model whose parameters the result lists, in its order.
    data : Dataset, or sequence / mapping of Dataset, optional
        With ``model``: the fit and the residual figures on these records.

    Returns
    -------
    str
        A complete HTML document.
    """
    title = title or getattr(result, "model_name", None) or type(result).__name__
    _, conclusion = _conclusion(result)
    body = [f"<h1>{escape(title)}</h1>",
            f"<p>{escape(type(result).__name__)}: success {bool(result.success)} ({escape(str(result.status))})</p>",
            conclusion, _fit_statistics_table(result), "<h2>Parameters</h2>", _parameter_table(result),
            _noise_table(result), _filter_tables(result),
            _intervals_table(result), _likelihood_sets_table(result), _notes_and_checks(result)]
    if figures:
        drawn = _data_figures(result, model, data) + [
            f for f in (_landscape_figure(result), _correlation_figure(result), _convergence_figure(result)) if f]
        body.append("<h2>Figures</h2>" + ("".join(f"<p>{f}</p>" for f in drawn) if drawn else
                                          "<p>no figure: matplotlib is not installed, or the result has none "
                                          "to draw</p>"))
    return ("<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            f"<title>{escape(title)}</title><style>{_STYLE}</style></head><body>"
            + "".join(body) + "</body></html>")


def compact_html(result) -> str:
    """The notebook's view: the conclusion and the parameter table.

    Parameters
    ----------
    result : EstimateLike

    Returns
    -------
    str
    """
    _, conclusion = _conclusion(result)
    return f"<div>{conclusion}{_parameter_table(result)}</div>"


def write_html(result, path: str | os.PathLike | None = None, title: str | None = None, model=None,
               data=None) -> str:
    """:func:`result_html`, written atomically to ``path`` when given (the results' ``to_html``).

    Parameters
    ----------
    result : EstimateLike
    path : str or os.PathLike, optional
    title : str, optional
    model, data : optional
        The model and its records, for the fit and residual figures (:func:`result_html`).

    Returns
    -------
    str
        The page.
    """
    page = result_html(result, title, model=model, data=data)
    if path is not None:
        atomic_write_text(path, page)
    return page
