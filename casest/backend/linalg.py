"""Small dense linear algebra shared by the sums, the noise models and the NLPs: the
log-Cholesky form of a covariance (R = L L', L lower triangular with a log-diagonal), and NumPy's
BLAS held to one thread where its threads would only wait."""

from __future__ import annotations

import contextlib

import casadi as ca
import numpy as np


__all__ = ["cholesky_factor", "n_cholesky", "cholesky_vector", "covariance_of", "variances_of",
           "single_threaded_blas"]

# threadpoolctl's controller of the BLAS libraries loaded (found once: finding them takes 0.3 ms)
_CONTROLLER: list = []


def single_threaded_blas():
    """A context in which NumPy's BLAS runs on one thread (``threadpoolctl``, the ``threads`` extra;
    without it, nothing changes).

    The Gram products of a Gauss-Newton iteration (tens of columns, thousands of rows) gain
    nothing from OpenBLAS's threads, whose waiting spins: on a busy machine an identical call then
    took 5x the CPU time of its neighbours.

    Returns
    -------
    context manager
    """
    if not _CONTROLLER:
        try:
            from threadpoolctl import ThreadpoolController
        except ImportError:
            _CONTROLLER.append(None)
        else:
            _CONTROLLER.append(ThreadpoolController())
    controller = _CONTROLLER[0]
    return contextlib.nullcontext() if controller is None else controller.limit(limits=1, user_api="blas")


def variances_of(R) -> np.ndarray:
    """The noise variances of R given either way: its diagonal, or the variances themselves.

    Parameters
    ----------
    R : array_like, shape (n_outputs, n_outputs) or (n_outputs,)

    Returns
    -------
    ndarray, shape (n_outputs,)
        A new array.
    """
    R = np.asarray(R, dtype=float)
    return np.diag(R).copy() if R.ndim == 2 else R.reshape(-1).copy()


def cholesky_factor(ell, ny: int):
    """Lower-triangular L from its log-Cholesky vector; ``L L'`` is the noise covariance (full R).

    Parameters
    ----------
    ell : ndarray or casadi.SX/MX, shape (n_cholesky(ny),)
        ``ny`` log-diagonal entries, then the strictly lower entries column by column.
    ny : int
        Number of channels.

    Returns
    -------
    ndarray or casadi matrix, shape (ny, ny)
        Of the same kind as ``ell``.
    """
    L = ca.SX.zeros(ny, ny) if isinstance(ell, ca.SX) else ca.MX.zeros(ny, ny)
    k = ny
    for j in range(ny):
        L[j, j] = ca.exp(ell[j])
        for i in range(j + 1, ny):
            L[i, j] = ell[k]
            k += 1
    return L


def n_cholesky(ny: int) -> int:
    """Length of the log-Cholesky vector of an ny x ny covariance.

    Parameters
    ----------
    ny : int

    Returns
    -------
    int
        ``ny (ny + 1) / 2``.
    """
    return ny * (ny + 1) // 2


def cholesky_vector(R_full: np.ndarray) -> np.ndarray:
    """The log-Cholesky vector of a covariance (see :func:`cholesky_factor`).

    Parameters
    ----------
    R_full : ndarray, shape (ny, ny)
        A symmetric positive definite covariance.

    Returns
    -------
    ndarray, shape (n_cholesky(ny),)
        ``ny`` log-diagonal entries of L, then its strictly lower entries column by column.
    """
    L = np.linalg.cholesky(np.asarray(R_full, dtype=float))
    ny = L.shape[0]
    return np.concatenate([np.log(np.diag(L))] + [L[j + 1:, j] for j in range(ny)])


def covariance_of(ell: np.ndarray, ny: int) -> np.ndarray:
    """The covariance ``L L'`` of a log-Cholesky vector.

    Parameters
    ----------
    ell : ndarray, shape (n_cholesky(ny),)
    ny : int
        Number of channels.

    Returns
    -------
    ndarray, shape (ny, ny)
    """
    L = np.asarray(ca.evalf(cholesky_factor(ca.SX(np.asarray(ell, dtype=float)), ny)))
    return L @ L.T
