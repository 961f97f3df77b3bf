"""Whether the sweep resolves its landscape beyond the best candidate: the paper's Eq. 17 at the
further local minima that stage 2 would start from.

Eq. 17 at the best candidate says the design is fine enough there (casest refines until it
holds). A minimum elsewhere at which half a sampling step still changes the prediction by more
than ``linearization_tol`` of its norm is not resolved: a deeper minimum may lie between the
candidates around it (an oscillating model over a box much wider than its period aliases into
scores of shallow grid minima). Such a landscape cannot say that its best candidate is the one
clear minimum, whatever the best candidate's own checks say.

The check is made on grid designs (up to two swept parameters by default), where the half step
is the grid's spacing and halving it costs four times the candidates. A scattered design in
three or more dimensions is sparse along every axis (2000 Sobol points in five dimensions are a
fifth of each range apart), so Eq. 17 fails at nearly every minimum but the best, which casest
refines: there the further stage-2 starts, not the design, carry the global search.
"""

from __future__ import annotations

import numpy as np

from .analysis import validity_conditions
from .candidates import half_step

__all__ = ["FURTHER_MINIMA_CHECKED", "UNRESOLVED_TRACE_RATIO", "UnresolvedMinimum", "unresolved_minima"]

#: the further local minima checked (the stage-2 starts after the best candidate and the nominal values)
FURTHER_MINIMA_CHECKED = 4
#: a further minimum counts when its Tr[R] is at most this times the best's: within a cell it does not resolve a
#: fit that close may still go below the best (ENSO's aliased periods: 1.1-1.2 times), one an order of magnitude
#: worse (Rat42, Roszman1 and Bennett5 from NIST's starts: 12-57 times) is not where a better minimum hides
UNRESOLVED_TRACE_RATIO = 2.0


class UnresolvedMinimum:
    """A further local minimum of the ranking where Eq. 17 fails: its index and Eq. 17's ratio."""

    def __init__(self, index: int, ratio: float):
        self.index, self.ratio = index, ratio


def unresolved_minima(measurement, partition, data, samples, minima, unit, grid_shape, params, spacing,
                      settings) -> list:
    """The further local minima (after the best, up to :data:`FURTHER_MINIMA_CHECKED` of distinct
    ranking values, each a fit, those with Tr[R] at most :data:`UNRESOLVED_TRACE_RATIO` times the
    best's) at which Eq. 17 fails over their own half sampling step.

    Parameters
    ----------
    measurement : Measurement
    partition : Partition
    data : Dataset
    samples : the sweep's evaluated candidates (``cands``, ``xi1``, ``R``, ``trace``, ``rank``)
    minima : ndarray of int
        The local minima, best first.
    unit : ndarray, shape (M, n2)
        The design's candidates in prior-probability coordinates (refinements excluded).
    grid_shape : tuple or None
    params : list of Parameter
        The swept parameters.
    spacing : float or None
        The scattered design's sampling distance.
    settings : SweepSettings
        ``linearization_tol``.

    Returns
    -------
    list of UnresolvedMinimum
        Best ranked first; empty when every checked minimum is resolved.
    """
    design = samples.cands[:len(unit)]
    taken, found = [samples.rank[minima[0]]], []
    for m in (int(k) for k in minima[1:]):
        if len(taken) > FURTHER_MINIMA_CHECKED:
            break
        rank = samples.rank[m]
        if m >= len(unit) or not np.isfinite(rank) or any(abs(rank - t) <= 1e-9 * abs(t) for t in taken):
            continue  # a refinement point, not a fit, or a plateau / alias of one already checked
        taken.append(rank)
        if samples.trace[m] > UNRESOLVED_TRACE_RATIO * samples.trace[minima[0]]:
            continue  # too poor a fit to hide a better one than the best within its cell
        step = half_step(design, unit, grid_shape, params, m, spacing)
        ratio = validity_conditions(measurement, partition, data, samples.xi1[m], samples.cands[m], step)[0]
        if ratio > settings.linearization_tol:
            found.append(UnresolvedMinimum(m, float(ratio)))
    return found
