"""Whether the sweep resolves its landscape beyond the best candidate: the paper's Eq. 17 at the
further local minima that stage 2 would start from, each refined like the best.

Eq. 17 at the best candidate says the design is fine enough there (casest refines until it
holds). The further minima get the same refinement: one that goes below the best shows that the
best grid candidate sat in the wrong basin (an oscillating model over a box much wider than its
period aliases into scores of shallow grid minima); one at which half a sampling step still
changes the prediction by more than ``linearization_tol`` of its norm after the refinements is
not resolved, and a deeper minimum may lie between the candidates around it. Either way the
landscape cannot say that its best candidate is the one clear minimum.

The check is made on grid designs (up to two swept parameters by default), where the half step
is the grid's spacing and halving it costs four times the candidates. A scattered design in
three or more dimensions is sparse along every axis (2000 Sobol points in five dimensions are a
fifth of each range apart), so Eq. 17 fails at nearly every minimum but the best, which casest
refines: there the further stage-2 starts, not the design, carry the global search.
"""

from __future__ import annotations

import numpy as np

from .candidates import half_step

__all__ = ["FURTHER_MINIMA_CHECKED", "UnresolvedMinimum", "FurtherMinima", "resolve_further_minima"]

#: the further local minima checked (the stage-2 starts after the best candidate and the nominal values)
FURTHER_MINIMA_CHECKED = 4


class UnresolvedMinimum:
    """A further local minimum of the ranking where Eq. 17 still fails after local refinement: its
    index and Eq. 17's ratio there."""

    def __init__(self, index: int, ratio: float):
        self.index, self.ratio = index, ratio


class FurtherMinima:
    """The further minima after their local refinement: ``minima`` (best first, each checked one
    replaced by where its refinement ended), ``unresolved`` (:class:`UnresolvedMinimum`, Eq. 17
    still failing) and ``deeper`` (refined minima that went below the best candidate)."""

    def __init__(self, minima: np.ndarray, unresolved: list, deeper: list):
        self.minima, self.unresolved, self.deeper = minima, unresolved, deeper


def resolve_further_minima(samples, minima, unit, grid_shape, params, spacing, settings, refine) -> FurtherMinima:
    """Refine the sweep around the further local minima (after the best, up to
    :data:`FURTHER_MINIMA_CHECKED` of distinct ranking values, each a fit) as around the best,
    until Eq. 17 holds over their half step.

    Parameters
    ----------
    samples : the sweep's evaluated candidates (``cands``, ``xi1``, ``R``, ``rank``; refinements are added)
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
    refine : callable
        ``refine(index, half_step) -> (checks, index)``: the refinement around one candidate
        (checks with Eq. 17's ``ratio``), ending at the best candidate it found.

    Returns
    -------
    FurtherMinima
    """
    design = samples.cands[:len(unit)]
    best_rank = samples.rank[minima[0]]
    taken, out, unresolved, deeper = [best_rank], np.array(minima, dtype=int), [], []
    for pos in range(1, len(out)):
        if len(taken) > FURTHER_MINIMA_CHECKED:
            break
        m = int(out[pos])
        rank = samples.rank[m]
        if m >= len(unit) or not np.isfinite(rank) or any(abs(rank - t) <= 1e-9 * abs(t) for t in taken):
            continue  # a refinement point, not a fit, or a plateau / alias of one already checked
        taken.append(rank)
        checks, refined = refine(m, half_step(design, unit, grid_shape, params, m, spacing))
        out[pos] = refined
        if samples.rank[refined] < best_rank:
            deeper.append(int(refined))
        if checks.ratio > settings.linearization_tol:
            unresolved.append(UnresolvedMinimum(int(refined), float(checks.ratio)))
    return FurtherMinima(out, unresolved, deeper)
