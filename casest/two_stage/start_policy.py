"""Where stage 2 starts, and when the remaining starts are not needed (paper Step 5).

Stage 2 starts from the best stage-1 candidate, the nominal values and the further local
minima of the stage-1 ranking (:func:`stage2_starts`); :func:`one_start_suffices` is the
stopping rule that skips the further minima when the evidence says they would add nothing.
"""

from __future__ import annotations

import numpy as np

from ..backend.tolerances import cost_tolerance

__all__ = ["one_start_suffices", "stage2_starts", "BEST_START", "NOMINAL_START", "AGREEING_STARTS"]


def one_start_suffices(landscape, starts, residuals_white=None):
    """The multi-start's stopping rule (paper Step 5): after the best stage-1 candidate and the
    nominal values, the other starts (further minima of the stage-1 ranking) are skipped when
    stage 1 found one clear minimum (verdict ``unique``, no competing minima, no other local
    minimum of the same ranking value: an alias) and the solve from the best candidate
    converged below its start in its first mode. The nominal values' solve runs too, so that
    equal-cost solutions of a symmetric model keep the labelling nearest the nominal values,
    unless stage 1 found the nominal values in the best candidate's basin
    (``Landscape.nominal_in_best_basin``): their solve would reach the same minimum. With
    another verdict (flat, coarse) and no competing minima, the starts stop once the first
    ``AGREEING_STARTS`` (the best candidate, the nominal values and the next minimum)
    all converged in their first mode to the same cost: independent starts that agree are the
    evidence the remaining ones would add. Competing minima or aliases, or a failed, climbing
    or switched solve run every start. With ``residuals_white`` (``theta -> bool``), a unique
    verdict's solve must also leave residuals that pass their tests: a misfit there (a
    difference of two peaks fitted to two separate ones, generated net problem 77) is what a
    local minimum looks like, and the other starts run. None without a landscape (a given
    start)."""
    if landscape is None or len(landscape.competing):
        return None
    if landscape.verdict != "unique":
        return _starts_agree
    best = landscape.ranking[landscape.best_index]
    others = np.asarray(landscape.local_minima, dtype=int)
    others = others[others != landscape.best_index]
    if np.any(np.abs(landscape.ranking[others] - best) <= 1e-9 * abs(best)):
        return None  # an exact alias (a symmetry): every start, to settle the labelling
    in_basin = getattr(landscape, "nominal_in_best_basin", None) is True
    with_nominal = any(label == NOMINAL_START for label, _ in starts) and not in_basin
    first_fit: dict = {}

    def enough(runs) -> str | None:
        first = runs[0]
        if not (first.label == BEST_START and first.valid and not first.switched):
            return None
        if residuals_white is not None:
            if "white" not in first_fit:  # tested once, on the best candidate's solve
                first_fit["white"] = residuals_white(first.result.theta)
            if not first_fit["white"]:
                return None
        if with_nominal and runs[-1].label != NOMINAL_START:
            return None
        skipped = ("the nominal values (in the best candidate's basin by stage 1) and the further minima of the "
                   "stage-1 ranking" if in_basin else "the further minima of the stage-1 ranking")
        return f"stage 1 found one clear minimum (verdict unique) and the solve from it converged; {skipped} were not needed"

    return enough


BEST_START, NOMINAL_START = "the best stage-1 candidate", "the nominal values"

#: starts that must converge to the same cost before a landscape without a unique verdict stops early
AGREEING_STARTS = 3


def _starts_agree(runs) -> str | None:
    """The stopping rule without a unique verdict: the first starts converged to one cost."""
    if len(runs) < AGREEING_STARTS or not all(r.valid and not r.switched for r in runs):
        return None
    costs = [r.result.cost for r in runs]
    if max(costs) - min(costs) > cost_tolerance(min(costs)):
        return None
    return (f"the first {len(runs)} starts "
            f"converged to the same cost J = {min(costs):.10g}; the further minima of the stage-1 ranking were not "
            "needed")


def stage2_starts(model, partition, landscape, count: int) -> list:
    """Stage-2 starts: the best candidate, the nominal values, the next-best local minima of Tr[R].

    At most ``count`` in all (the nominal values always get a place unless ``count`` is 1);
    every start is clipped into the bounds (stage 1's xi1 already respects them).

    Parameters
    ----------
    model : Model
    partition : Partition
    landscape : Landscape
        Stage 1's result.
    count : int
        At most this many starts.

    Returns
    -------
    list of (str, ndarray)
        Label and start point (shape (n_parameters,), physical units), best first.
    """
    out = [(BEST_START, partition.assemble(landscape.best_xi1, landscape.best_xi2))]
    # the nominal values second: the stopping rule (one_start_suffices) runs them before the further minima
    nominal = count > 1 and not np.allclose(out[0][1], model.nominal)
    if nominal:
        out.append((NOMINAL_START, model.nominal.copy()))
    traces = [landscape.ranking[landscape.best_index]]
    minima = np.asarray(landscape.local_minima, dtype=int)
    usable = minima[(minima != landscape.best_index) & np.isfinite(landscape.xi1[minima]).all(axis=1)]
    for m, trace in zip(usable.tolist(), landscape.ranking[usable].tolist()):
        if len(out) >= count:
            break
        # minima of the same Tr[R] as one already taken are a plateau (or an exact alias): one start is enough
        if any(abs(trace - t) <= 1e-9 * abs(t) for t in traces):
            continue
        traces.append(trace)
        out.append((f"local minimum {len(traces)} of the stage-1 ranking", partition.assemble(landscape.xi1[m], landscape.candidates[m])))
    return [(label, np.clip(theta, model.lower_bounds, model.upper_bounds)) for label, theta in out]
