"""Small dense linear algebra shared by the sums, the noise models and the NLPs: the
log-Cholesky form of a covariance (R = L L', L lower triangular with a log-diagonal)."""

from __future__ import annotations

import casadi as ca
import numpy as np


__all__ = ["cholesky_factor", "n_cholesky", "cholesky_vector", "covariance_of"]


def cholesky_factor(ell, ny: int):
    """Lower-triangular L from its log-Cholesky vector: ``ny`` log-diagonal entries, then the
    strictly lower entries column by column. ``L L'`` is the noise covariance (full R)."""
    L = ca.SX.zeros(ny, ny) if isinstance(ell, ca.SX) else ca.MX.zeros(ny, ny)
    k = ny
    for j in range(ny):
        L[j, j] = ca.exp(ell[j])
        for i in range(j + 1, ny):
            L[i, j] = ell[k]
            k += 1
    return L


def n_cholesky(ny: int) -> int:
    """Length of the log-Cholesky vector of an ny x ny covariance."""
    return ny * (ny + 1) // 2


def cholesky_vector(R_full: np.ndarray) -> np.ndarray:
    """The log-Cholesky vector of a covariance (see :func:`cholesky_factor`), shape (n_cholesky(ny),)."""
    L = np.linalg.cholesky(np.asarray(R_full, dtype=float))
    ny = L.shape[0]
    return np.concatenate([np.log(np.diag(L))] + [L[j + 1:, j] for j in range(ny)])


def covariance_of(ell: np.ndarray, ny: int) -> np.ndarray:
    """The covariance ``L L'`` of a log-Cholesky vector, shape (ny, ny)."""
    L = np.asarray(ca.evalf(cholesky_factor(ca.SX(np.asarray(ell, dtype=float)), ny)))
    return L @ L.T
