"""The data of the NLPs as CasADi symbols and vectors, and the ML cost of a static model as a
CasADi expression of them."""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..backend.noise_terms import DIAGONAL, NoiseTerm
from ..backend.penalty import GaussianPenalty
from ..backend.sums import data_outside_graph, per_sample_cost
from ..data.dataset import Dataset
from ..models import Model


__all__ = ["ml_cost_expression", "data_vector", "data_symbols", "sum_data_symbols", "static_data_views"]


def ml_cost_expression(model: Model, n_samples: int, theta, noise, p, masked: bool = False,
                       noise_term: NoiseTerm = DIAGONAL, penalty: tuple | None = None) -> ca.MX:
    """J of paper Eq. 6 as a CasADi expression, for graphs that CasADi differentiates.

    Parameters
    ----------
    model : Model
    n_samples : int
        N.
    theta : casadi.MX, shape (n_parameters, 1)
        Physical parameters.
    noise : casadi.MX
        The noise block of ``noise_term``: ``ln R`` (n_outputs), or the log-Cholesky vector of a full R.
    p : casadi.MX
        The data vector (:func:`data_vector`; with ``masked`` it carries the mask).
    masked : bool
        The data vector carries the observation mask.
    noise_term : NoiseTerm
        R's parametrisation (:mod:`casest.backend.noise_terms`; default diagonal).
    penalty : tuple of (ndarray, ndarray), optional
        Means and precisions of Gaussian priors added as penalties.

    Returns
    -------
    casadi.MX
        The per-sample cost of :mod:`casest.backend.sums` mapped over the samples and summed
        (a plain map, whose derivatives CasADi builds quickly), plus the penalty.
    """
    X, Z = static_data_views(model, n_samples, masked, p)
    f_i = per_sample_cost(model, masked, noise_term)
    J = ca.sum2(f_i.map(n_samples)(X, Z, ca.vertcat(theta, noise)))
    penalty = GaussianPenalty.coerce(penalty)
    return J if penalty is None else J + penalty.expression(theta)



def data_vector(data: Dataset) -> np.ndarray:
    """The NLP parameter vector ``p = [vec(X); vec(Z)]`` of a data set (see :meth:`Problem.data_vector`).

    Parameters
    ----------
    data : Dataset

    Returns
    -------
    ndarray, shape (N (n_signals + n_outputs),)
        Column-major signals then outputs (with the mask rows when outputs are missing).
    """
    if data.has_missing:
        z = np.hstack([data.filled_outputs(), data.output_mask()])
        return np.concatenate([data.signals.reshape(-1), z.reshape(-1)])
    return np.concatenate([data.signals.reshape(-1), data.outputs.reshape(-1)])


def static_data_views(model: Model, n_samples: int, masked: bool, p: ca.MX) -> tuple[ca.MX, ca.MX]:
    """The views X (n_signals x N) and Z (n_outputs x N, or 2 n_outputs x N with ``masked``) of a static
    model's data vector ``p`` (offsets only, no N-long index vectors)."""
    ns, ny, N = model.n_signals, model.n_outputs * (2 if masked else 1), n_samples
    # vertsplit keeps only offsets; p[a:b] would store N-long index vectors
    signals, outputs = ca.vertsplit(p, [0, ns * N, (ns + ny) * N])
    return ca.reshape(signals, ns, N), ca.reshape(outputs, ny, N)


def sum_data_symbols(model: Model, n_samples: int, masked: bool = False) -> tuple[ca.MX, list]:
    """The data parameter of graphs built on the ML sums, and the sums' data arguments.

    Parameters
    ----------
    model : Model
    n_samples : int
        N.
    masked : bool
        The outputs carry an observation mask.

    Returns
    -------
    parameter : casadi.MX
        The symbol the NLP takes as its data parameter (its value: :meth:`Problem.data_argument`).
    arguments : list of casadi.MX
        ``[record]`` for long records (:func:`casest.backend.data_outside_graph`), else ``[X, Z]``
        (:func:`data_symbols`).
    """
    if data_outside_graph(n_samples):
        record = ca.MX.sym("record")
        return record, [record]
    p, X, Z = data_symbols(model, n_samples, masked)
    return p, [X, Z]


def data_symbols(model: Model, n_samples: int, masked: bool = False) -> tuple[ca.MX, ca.MX, ca.MX]:
    """The NLP parameter ``p = [vec(X); vec(Z)]`` and its views.

    Parameters
    ----------
    model : Model
    n_samples : int
        N.
    masked : bool
        Z is ``[z; m]`` (2 n_y x N), m = 1 where an output was measured, 0 where not.

    Returns
    -------
    p : casadi.MX
    X : casadi.MX, shape (n_signals, N)
    Z : casadi.MX, shape (n_outputs, N) or (2 n_outputs, N)
    """
    p = ca.MX.sym("data", (model.n_signals + model.n_outputs * (2 if masked else 1)) * n_samples)
    X, Z = static_data_views(model, n_samples, masked, p)
    return p, X, Z
