"""Total least squares: equation error when the regressors are measured with noise too
(Klein and Morelli, *Aircraft System Identification*, Sec. 5.6; Van Huffel and Vandewalle,
*The Total Least Squares Problem*, 1991, Sec. 3.5).

Ordinary least squares treats the regressors as exact; when they are measured (angle of
attack, rates, reconstructed accelerations) the estimates are biased towards zero by the
regressors' noise, and a longer record does not remove the bias. Total least squares fits
``y + e_y = (X + E_X) theta`` with the smallest ``||[E_X e_y]||`` after each noisy column is
divided by its noise std, so that the errors of every noisy column and of ``y`` have one
variance. Columns known exactly (a bias column, a commanded input) are held exact: the mixed
LS-TLS of Golub, Hoffman and Stewart, by a QR factorisation that separates them, then the SVD
of the remaining block.

The covariance is the large-sample one of Gleser (1981), with the noise variance from the
smallest singular value: ``sigma^2 (1 + |theta_n|^2) (X'X - N sigma^2 D)^-1`` in the scaled
columns, ``D`` selecting the noisy ones, ``theta_n`` their scaled coefficients.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from ..errors import DataError, OptionError
from .regression import Regression, dependent_variable, regressor_matrix

__all__ = ["total_least_squares"]


def total_least_squares(y, terms: Mapping, data, exact=(), noise_std: Mapping | None = None) -> Regression:
    """Equation error with noisy regressors: the (mixed) total least squares of ``y`` on the terms.

    Parameters
    ----------
    y : array_like, shape (N,), or str
        The dependent variable, or the name of a column of ``data``.
    terms : mapping of str to CasADi expression or number
        Regressor name -> scalar expression of signal symbols named like the columns of
        ``data``, as for :func:`casest.regress`.
    data : mapping of str to array_like, or Dataset
        The record's columns.
    exact : sequence of str
        The terms known without error (a bias term, a commanded input): held exact. Constant
        terms are always exact.
    noise_std : mapping of str to float, optional
        The noise std of ``"y"`` and of each noisy term, in their units; default one for all
        (the errors of every noisy column and of y then have one variance: scale the data so).

    Returns
    -------
    Regression
        ``method="total least squares"``; ``std`` from Gleser's covariance (white errors),
        ``fitted = X theta`` and the residuals ``y - X theta``.

    Raises
    ------
    DataError
        Fewer samples than terms, dependent regressors, a fit with no unique solution (the
        smallest singular value repeated).
    OptionError
        ``exact`` or ``noise_std`` naming terms that ``terms`` lacks, or a std not positive.
    """
    names, X = regressor_matrix(terms, data)
    y = dependent_variable(y, data, X.shape[0])
    N, p = X.shape
    if N <= p:
        raise DataError(f"{N} samples cannot determine {p} terms; give a longer record or fewer terms")
    held = _exact_columns(names, X, exact)
    scale = _noise_scales(names, noise_std or {})
    order = np.concatenate([np.flatnonzero(held), np.flatnonzero(~held)])
    k = int(held.sum())
    Z = np.column_stack([X[:, order] / scale[1:][order], y / scale[0]])
    theta_scaled, sigma2, singular = _mixed_solution(Z, k, names, order)
    theta = np.empty(p)
    theta[order] = theta_scaled * scale[0] / scale[1:][order]
    noisy_part = theta_scaled[k:]
    A = Z[:, :p].T @ Z[:, :p]
    D = np.diag(np.r_[np.zeros(k), np.ones(p - k)])
    cov_scaled = sigma2 * (1.0 + noisy_part @ noisy_part) * np.linalg.inv(A - N * sigma2 * D)
    to_natural = scale[0] / scale[1:][order]
    cov = np.empty((p, p))
    cov[np.ix_(order, order)] = cov_scaled * np.outer(to_natural, to_natural)
    return _regression(names, X, y, theta, cov, singular)


def _exact_columns(names: tuple, X: np.ndarray, exact) -> np.ndarray:
    unknown = [n for n in exact if n not in names]
    if unknown:
        raise OptionError(f"exact names {unknown}, which are not terms (terms: {list(names)})")
    constant = np.all(X == X[:1], axis=0)
    return np.array([n in exact for n in names]) | constant


def _noise_scales(names: tuple, noise_std: Mapping) -> np.ndarray:
    unknown = [n for n in noise_std if n != "y" and n not in names]
    if unknown:
        raise OptionError(f"noise_std names {unknown}, which are neither 'y' nor terms (terms: {list(names)})")
    scale = np.array([float(noise_std.get(n, 1.0)) for n in ("y",) + tuple(names)])
    if not np.all(np.isfinite(scale) & (scale > 0)):
        raise OptionError(f"noise_std must be positive and finite, got {dict(noise_std)}")
    return scale


def _mixed_solution(Z: np.ndarray, k: int, names: tuple, order: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """The mixed LS-TLS solution of ``Z = [X_exact X_noisy y]`` (scaled), the noise variance per
    column and the singular values of the noisy block."""
    N, p = Z.shape[0], Z.shape[1] - 1
    Q, R = np.linalg.qr(Z)
    diag = np.abs(np.diag(R[:p, :p]))
    if diag.min() <= 1e-10 * max(diag.max(), 1e-300):
        dependent = [names[order[j]] for j in np.flatnonzero(diag <= 1e-10 * diag.max())]
        raise DataError(f"the regressors {dependent} are linear combinations of the others on this record; drop them "
                        "or collect data that excite them separately")
    _, singular, Vt = np.linalg.svd(R[k:, k:])
    if singular.size > 1 and singular[-2] - singular[-1] <= 1e-10 * singular[0]:
        raise DataError("the total-least-squares fit has no unique solution: the two smallest singular values of "
                        "the noisy regressors and y are equal; drop a term or hold more terms exact")
    v = Vt[-1]
    if abs(v[-1]) <= 1e-12 * np.linalg.norm(v):
        raise DataError("the total-least-squares fit has no solution: y is not needed to fit the noisy regressors "
                        "(the smallest singular vector has no y component); check the terms")
    noisy = -v[:-1] / v[-1]
    exact = np.linalg.solve(R[:k, :k], R[:k, p] - R[:k, k:p] @ noisy) if k else np.zeros(0)
    sigma2 = singular[-1] ** 2 / (N - p)
    return np.concatenate([exact, noisy]), sigma2, singular


def _regression(names: tuple, X: np.ndarray, y: np.ndarray, theta: np.ndarray, cov: np.ndarray,
                singular: np.ndarray) -> Regression:
    """The statistics of :class:`Regression` at the total-least-squares estimate."""
    N, p = X.shape
    e = y - X @ theta
    sse = float(e @ e)
    sst = float(np.sum((y - y.mean()) ** 2))
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    Q, _ = np.linalg.qr(X)
    leverage = np.sum(Q * Q, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        press = float(np.sum((e / (1.0 - leverage)) ** 2))
        t_values = theta / std
    s2 = sse / (N - p)
    return Regression(tuple(names), theta, std, std, cov, X @ theta, e, s2,
                      1.0 - sse / sst if sst > 0 else np.nan,
                      (sst - sse) / (p - 1) / s2 if p > 1 and s2 > 0 else np.nan,
                      t_values, press, sse / N + sst / N * p / N, False, "total least squares")
