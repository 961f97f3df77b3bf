"""Checks of the matrices a filter is given (shapes, finiteness, symmetry, definiteness)."""

from __future__ import annotations

import numpy as np

from ..models import OptionError

__all__ = ["matrix_argument", "covariance_argument"]


def matrix_argument(value, shape, name) -> np.ndarray:
    """``value`` as a finite float array of ``shape`` (a vector of n values stands for an (n, n) diagonal)."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 1 and len(shape) == 2 and shape[0] == shape[1] and arr.size == shape[0]:
        arr = np.diag(arr)  # a vector of variances
    if arr.shape != shape:
        raise OptionError(f"{name} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise OptionError(f"{name} has non-finite entries")
    return arr


#: covariances above this overflow when the filter squares them (P = Phi P Phi' + Q, C P C' + R)
LARGEST_COVARIANCE = 1e150


def covariance_argument(value, n, name) -> np.ndarray:
    """``value`` as a symmetric positive semi-definite (n, n) covariance (symmetrised)."""
    arr = matrix_argument(value, (n, n), name)
    peak = float(np.abs(arr).max()) if arr.size else 0.0
    if peak > LARGEST_COVARIANCE:
        raise OptionError(f"{name} reaches {peak:.3g}: the filter's products of it overflow double precision (max "
                          f"1.8e308); express the states or outputs in larger units, or give a realistic variance")
    if not np.allclose(arr, arr.T, rtol=1e-10, atol=1e-14 * max(1.0, np.abs(arr).max())):
        raise OptionError(f"{name} must be symmetric")
    if np.linalg.eigvalsh(0.5 * (arr + arr.T))[0] < -1e-12 * max(1.0, np.abs(arr).max()):
        raise OptionError(f"{name} must be positive semi-definite")
    return 0.5 * (arr + arr.T)
