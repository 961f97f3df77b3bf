"""The paper's feasible set of stage-1 candidates (Sec. II.C, Step 2): the candidates within
``epsilon`` of the nominal xi2 (``||xi2 - xi2_nominal||_2 < epsilon``) that also satisfy the
validity conditions Eq. 17 (the linearisation over half a sampling step) and Eq. 18 (the profile
curvature in xi2), among which the minimum of Tr[R] is taken."""

from __future__ import annotations

import numpy as np

from ...errors import OptionError
from .analysis import validity_conditions
from .candidates import half_step, prior_density
from .settings import SweepSettings
from .validity_batch import batched_applies, batched_conditions

__all__ = ["in_ball", "satisfies_conditions", "candidate_set"]


def in_ball(cands: np.ndarray, centre: np.ndarray, radius: float | None) -> np.ndarray:
    """Which candidates lie strictly within ``radius`` of ``centre`` (2-norm, the parameters' units).

    Parameters
    ----------
    cands : ndarray, shape (M, n2)
    centre : ndarray, shape (n2,)
    radius : float or None
        None: every candidate.

    Returns
    -------
    ndarray of bool, shape (M,)
    """
    if radius is None:
        return np.ones(len(cands), dtype=bool)
    return np.linalg.norm(cands - centre[None, :], axis=1) < radius


def satisfies_conditions(measurement, partition, data, samples, indices, steps, settings: SweepSettings,
                         params) -> np.ndarray:
    """Eq. 17 (ratio at most ``linearization_tol``) and Eq. 18 (smallest normalised eigenvalue at
    least ``curvature_tol``) at each candidate of ``indices``, each with its own half step.

    Parameters
    ----------
    measurement : Measurement
    partition : Partition
    data : Dataset
    samples : the sweep's evaluated candidates (``cands``, ``xi1``, ``R``, ``rank``)
    indices : sequence of int
    steps : ndarray, shape (len(indices), n2)
        The half sampling step of Eq. 17 at each.
    settings : SweepSettings
    params : list of Parameter
        The swept parameters.

    Returns
    -------
    ndarray of bool, shape (len(indices),)
    """
    passed = np.zeros(len(indices), dtype=bool)
    if batched_applies(measurement, data):
        fits = np.flatnonzero(np.isfinite(samples.rank[np.asarray(indices, dtype=int)]))  # the others are not fits
        chosen = np.asarray(indices, dtype=int)[fits]
        ratio, eig = batched_conditions(measurement, partition, data, samples.xi1[chosen], samples.cands[chosen],
                                        np.asarray(steps)[fits])
        passed[fits] = (ratio <= settings.linearization_tol) & (eig >= settings.curvature_tol)
        return passed
    for row, k in enumerate(indices):
        if not np.isfinite(samples.rank[k]):
            continue  # not a fit (A rank-deficient): not in the set
        ratio, eig, _, _ = validity_conditions(measurement, partition, data, samples.xi1[k], samples.cands[k], steps[row],
                                               samples.R[k], prior_density(params, samples.cands[k]))
        passed[row] = ratio <= settings.linearization_tol and eig >= settings.curvature_tol
    return passed


def candidate_set(measurement, partition, data, samples, settings: SweepSettings, unit, grid_shape, params, spacing,
                  centre: np.ndarray) -> np.ndarray | None:
    """The mask of the design's candidates in the paper's set S_xi2 (None when the settings ask for
    none), checking Eq. 17-18 only inside the ball.

    Parameters
    ----------
    measurement, partition, data, samples
        As :func:`satisfies_conditions` takes them.
    settings : SweepSettings
        ``radius`` and ``validity``.
    unit : ndarray, shape (M, n2)
        The candidates in prior-probability coordinates.
    grid_shape : tuple or None
    params : list of Parameter
    spacing : float or None
        The scattered design's sampling distance.
    centre : ndarray, shape (n2,)
        The nominal xi2.

    Returns
    -------
    ndarray of bool, shape (M,), or None

    Raises
    ------
    OptionError
        No candidate is in the set: the ball or the conditions leave nothing to choose from.
    """
    if settings.radius is None and settings.validity != "every":
        return None
    mask = in_ball(samples.cands, centre, settings.radius)
    if settings.validity == "every":
        inside = np.flatnonzero(mask)
        steps = np.array([half_step(samples.cands, unit, grid_shape, params, int(k), spacing) for k in inside])
        mask[inside] = satisfies_conditions(measurement, partition, data, samples, inside, steps.reshape(len(inside), -1),
                                            settings, params)
    if not mask.any():
        within = "" if settings.radius is None else f" within radius {settings.radius:g} of the nominal xi2"
        checked = (f" that also satisfies Eq. 17 (ratio <= {settings.linearization_tol:g}) and Eq. 18 (eigenvalue >= "
                   f"{settings.curvature_tol:g})" if settings.validity == "every" else "")
        raise OptionError(f"no stage-1 candidate{within}{checked}: the paper's set S_xi2 is empty; widen "
                          "SweepSettings.radius, draw more candidates (n_candidates), relax linearization_tol or "
                          "curvature_tol, or use validity='best'")
    return mask
