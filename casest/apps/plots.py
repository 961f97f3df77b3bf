"""Figures like the paper's: the Tr[R] landscape (Figs. 2, 4, 6) and predicted outputs (Figs. 3, 5).

Needs matplotlib (``pip install casest[plot]``). Every function writes a PNG and
returns its path.
"""

from __future__ import annotations


import numpy as np

from ..errors import MissingExtraError
from ..estimation.figures import save_figure
from ..two_stage.sweep import Landscape


__all__ = ["plot_landscape", "plot_distance_landscape", "plot_predictions", "pyplot_module", "save_png"]


def pyplot_module():
    """matplotlib.pyplot on the Agg backend, or a MissingExtraError naming the extra to install."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise MissingExtraError("figures need matplotlib, which is not installed: pip install 'casest[plot]'") from exc
    return plt


def save_png(fig, path: str) -> str:
    """Write a figure as PNG atomically (:func:`casest.estimation.figures.save_figure` at 120 dpi);
    returns ``path``."""
    return save_figure(fig, path, dpi=120)


def plot_landscape(landscape: Landscape, path: str, truth=None, title: str | None = None) -> str:
    """Tr[R(xi2)] over the swept candidates.

    One swept parameter: a line (paper Fig. 2). Two: filled contours on the grid, or a
    coloured scatter for scattered designs (Fig. 4). More: Tr[R] against the distance
    ||xi2 - best|| (Fig. 6).

    Parameters
    ----------
    landscape : Landscape
    path : str
        PNG file to write.
    truth : array_like, shape (n2,), optional
        True xi2 (simulated data), marked on the plot.
    """
    plt = pyplot_module()
    cands, tr = landscape.candidates, landscape.trace_R
    ok = np.isfinite(tr)
    best = landscape.best_index
    n2 = cands.shape[1]
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    if n2 == 0:
        ax.text(0.5, 0.5, "no swept parameter (all linear)", ha="center", va="center")
    elif n2 == 1:
        order = np.argsort(cands[:, 0])
        ax.plot(cands[order, 0][ok[order]], tr[order][ok[order]], "-", lw=1.2, label="Tr[R(xi2)]")
        ax.plot(cands[best, 0], tr[best], "o", color="C3", label=f"best {landscape.nonlinear[0]} = {cands[best, 0]:.4g}")
        if truth is not None:
            ax.axvline(np.ravel(truth)[0], color="k", ls="--", lw=0.8, label="truth")
        ax.set_xlabel(landscape.nonlinear[0])
        ax.set_ylabel("Tr[R]")
    elif n2 == 2:
        if landscape.grid_shape is not None:
            shape = landscape.grid_shape
            n = int(np.prod(shape))  # the design; local refinement points follow it
            X, Y = cands[:n, 0].reshape(shape), cands[:n, 1].reshape(shape)
            T = np.where(ok, tr, np.nan)[:n].reshape(shape)
            levels = np.quantile(T[np.isfinite(T)], np.linspace(0, 1, 25) ** 2)
            cs = ax.contourf(X, Y, T, levels=np.unique(levels), cmap="viridis")
        else:
            cs = ax.scatter(cands[ok, 0], cands[ok, 1], c=tr[ok], s=6, cmap="viridis")
        fig.colorbar(cs, ax=ax, label="Tr[R]")
        ax.plot(*cands[best], "o", color="C3", label="best candidate")
        for m in landscape.competing:
            ax.plot(*cands[m], "s", mfc="none", color="C1")
        if truth is not None:
            ax.plot(*np.ravel(truth)[:2], "x", color="w", ms=9, mew=2, label="truth")
        ax.set_xlabel(landscape.nonlinear[0])
        ax.set_ylabel(landscape.nonlinear[1])
    else:
        dist = np.linalg.norm(cands - cands[best], axis=1)
        ax.semilogy(dist[ok], tr[ok], ".", ms=3)
        ax.semilogy(0, tr[best], "o", color="C3", label="best candidate")
        ax.set_xlabel("||xi2 - best xi2||")
        ax.set_ylabel("Tr[R]")
    ax.set_title(title or f"stage 1: {landscape.verdict} ({len(tr)} candidates)")
    if n2:
        ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    out = save_png(fig, path)
    plt.close(fig)
    return out


def plot_distance_landscape(landscape: Landscape, path: str, centre=None, title: str | None = None,
                            unit: str = "") -> str:
    """Tr[R(xi2)] of every candidate against its distance ``||xi2 - centre||_2`` (the paper's Fig. 6:
    with ``centre`` zero, against ``||xi2_p||``); the candidates of the paper's set S_xi2
    (:attr:`Landscape.in_set`) apart from the others, the best marked.

    Parameters
    ----------
    landscape : Landscape
    path : str
        PNG file to write.
    centre : array_like, shape (n2,), optional
        Default: zero.
    title : str, optional
    unit : str
        The unit of Tr[R] for the axis label (``"(m/s)^2"``).

    Returns
    -------
    str
        The path written.
    """
    plt = pyplot_module()
    cands, tr = landscape.candidates, landscape.trace_R
    centre = np.zeros(cands.shape[1]) if centre is None else np.asarray(centre, dtype=float).reshape(-1)
    distance = np.linalg.norm(cands - centre[None, :], axis=1)
    ok = np.isfinite(tr)
    in_set = np.ones(len(tr), dtype=bool) if landscape.in_set is None else landscape.in_set
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    ax.plot(distance[ok & in_set], tr[ok & in_set], "o", ms=3, mfc="none", label="candidates")
    if not in_set.all():
        ax.plot(distance[ok & ~in_set], tr[ok & ~in_set], ".", ms=2, color="0.7", label="outside the set S_xi2")
    best = landscape.best_index
    ax.plot(distance[best], tr[best], "o", color="C3", label="best candidate")
    ax.set_xlabel("||xi2_p||" if not np.any(centre) else "||xi2_p - centre||")
    ax.set_ylabel(f"Tr[R(xi2_p)] {unit}".strip())
    ax.set_title(title or f"stage 1: {len(tr)} candidates, verdict {landscape.verdict}")
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    out = save_png(fig, path)
    plt.close(fig)
    return out


def plot_predictions(model, data, thetas_by_method: dict, path: str, max_runs: int = 100, seed: int = 0) -> str:
    """Measured outputs and the predictions of up to ``max_runs`` randomly chosen runs per method.

    Parameters
    ----------
    model : Model
    data : Dataset
        Measurements to show (one noise draw) and the signals to predict at.
    thetas_by_method : dict of str to array, shape (runs, n_parameters)
    path : str
        PNG file to write.
    max_runs : int
        Runs drawn (without replacement) per method.
    seed : int
        Seed of that choice.
    """
    plt = pyplot_module()
    methods = list(thetas_by_method)
    rng = np.random.default_rng(seed)
    x = data.signals[:, 0] if model.n_signals == 1 else np.arange(data.n_samples)
    xlabel = model.signal_names[0] if model.n_signals == 1 else "sample"
    order = np.argsort(x)
    fig, axes = plt.subplots(len(methods), model.n_outputs, figsize=(7.0, 2.3 * len(methods)), squeeze=False, sharex=True)
    for row, method in enumerate(methods):
        thetas = np.asarray(thetas_by_method[method])
        pick = rng.choice(len(thetas), size=min(max_runs, len(thetas)), replace=False)
        for col in range(model.n_outputs):
            ax = axes[row, col]
            ax.plot(x, data.outputs[:, col], ".", color="0.3", ms=3, label="measurement")
            for k, i in enumerate(pick):
                z = model.predict(thetas[i], data.signals)[:, col]
                ax.plot(x[order], z[order], "--", color="C3", lw=0.6, alpha=0.35, label="estimate" if k == 0 else None)
            ax.set_title(method, fontsize=9)
            ax.set_ylabel(model.output_names[col])
            if row == 0 and col == 0:
                ax.legend(loc="upper right", fontsize=7)
    for ax in axes[-1]:
        ax.set_xlabel(xlabel)
    fig.tight_layout()
    out = save_png(fig, path)
    plt.close(fig)
    return out
