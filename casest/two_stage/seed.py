"""A recursive estimator's start from stage 1 on the first samples of a record.

The two-stage estimator hands the recursive estimators (:mod:`casest.recursive`) their start:
the best stage-1 candidate on a window, its Gauss-Newton covariance there, and its residual
mean square as R.
"""

from __future__ import annotations

import numpy as np

from ..backend.sums import residual_jacobian
from ..data.dataset import Dataset
from ..models import Model
from ..problem.separate import Partition, separate
from .sweep import sweep


__all__ = ["seed_from_stage1"]


def seed_from_stage1(model: Model, window: Dataset, partition: Partition | None = None, sweep_settings=None):
    """Initial estimate, covariance and R for a filter from stage 1 on an initial window.

    theta0 is the best stage-1 candidate (xi2) with its least-squares xi1; R is that
    candidate's residual mean square; P0 is the Gauss-Newton covariance
    ``(sum_k H_k' R^-1 H_k)^-1`` on the window at theta0.

    Parameters
    ----------
    model : Model
    window : Dataset
        The first samples of the record.
    partition : Partition, optional
        Default: :func:`casest.separate` of the model.
    sweep_settings : SweepSettings, optional

    Returns
    -------
    theta0 : ndarray, shape (n_parameters,)
    P0 : ndarray, shape (n_parameters, n_parameters)
    R : ndarray, shape (n_outputs,)
    landscape : Landscape
    """
    partition = partition or separate(model)
    land = sweep(model, window, partition, sweep_settings)
    theta0 = np.clip(partition.assemble(land.best_xi1, land.best_xi2), model.lower_bounds, model.upper_bounds)
    R = land.best_R
    J = residual_jacobian(model, window, theta0)
    w = np.tile(1.0 / R, window.n_samples)
    P0 = np.linalg.pinv((J * w[:, None]).T @ J)
    return theta0, P0, R, land
