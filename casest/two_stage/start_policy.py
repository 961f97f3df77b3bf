"""Where stage 2 starts, and when the remaining starts are not needed (paper Step 5).

Stage 2 starts from the best stage-1 candidate, the nominal values and the further local
minima of the stage-1 ranking (:func:`stage2_starts`); :func:`one_start_suffices` is the
stopping rule that skips the further minima when the evidence says they would add nothing.
"""

from __future__ import annotations

import numpy as np

from ..backend.tolerances import cost_tolerance

__all__ = ["one_start_suffices", "stage2_starts", "BEST_START", "NOMINAL_START", "AGREEING_STARTS"]


def one_start_suffices(landscape, starts, residuals_white=None, curvature_holds=None):
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
    local minimum looks like, and the other starts run until the first ``AGREEING_STARTS``
    agree (the rule without a unique verdict). With a ``flat`` verdict,
    ``residuals_white`` and ``curvature_holds`` (``theta -> bool``: the curvature check, paper
    Eq. 18, at a solution), the starts also stop once the best candidate and the nominal values
    have run (the nominal values unless in the best candidate's basin), at least two solves
    converged and all of them to the same cost (starts that converge to different minima say the
    landscape holds several: NIST Thurber from a random box reached 117.2 and 130.1 from those
    two, 111.5 from a further minimum), that solution's residuals pass their tests and the
    curvature check holds there, and no start ended below it: the flatness was the best
    candidate's (a coarse design puts it where a term of the model is misplaced), and two starts
    agree at a solution judged as a unique verdict's is. None without a landscape (a given
    start)."""
    if landscape is None or len(landscape.competing):
        return None
    if landscape.verdict == "flat" and residuals_white is not None and curvature_holds is not None:
        settled = _settled_where_flat(_needs_nominal(landscape, starts), residuals_white, curvature_holds)
        return lambda runs: _starts_agree(runs) or settled(runs)
    if landscape.verdict != "unique":
        return _starts_agree
    best = landscape.ranking[landscape.best_index]
    others = np.asarray(landscape.local_minima, dtype=int)
    others = others[others != landscape.best_index]
    if np.any(np.abs(landscape.ranking[others] - best) <= 1e-9 * abs(best)):
        return None  # an exact alias (a symmetry): every start, to settle the labelling
    in_basin = getattr(landscape, "nominal_in_best_basin", None) is True
    with_nominal = _needs_nominal(landscape, starts)
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

    # residuals that fail their tests keep the search going until independent starts agree, as without a unique verdict
    return lambda runs: enough(runs) or _starts_agree(runs)


def _needs_nominal(landscape, starts) -> bool:
    """Whether the nominal values must run before the starts may stop: they are a start and stage 1 did
    not find them in the best candidate's basin (:func:`one_start_suffices`)."""
    in_basin = getattr(landscape, "nominal_in_best_basin", None) is True
    return any(label == NOMINAL_START for label, _ in starts) and not in_basin


def _settled_where_flat(with_nominal: bool, residuals_white, curvature_holds):
    """The stopping rule of a ``flat`` verdict at a solution (:func:`one_start_suffices`): ``enough(runs)``."""
    judged: dict = {}

    def enough(runs) -> str | None:
        labels = {r.label for r in runs}
        if BEST_START not in labels or (with_nominal and NOMINAL_START not in labels):
            return None
        converged = [r for r in runs if r.valid]  # a switched solve's minimum counts as any other
        if len(converged) < 2:
            return None  # one solve is no evidence that the minimum is the box's (the trust line asks for two)
        low = min(converged, key=lambda r: r.result.cost)
        if any(r.result.cost < low.result.cost - cost_tolerance(low.result.cost) for r in runs):
            return None  # a start still falling below it: the further minima may hold a lower one
        if any(r.result.cost > low.result.cost + cost_tolerance(low.result.cost) for r in converged):
            return None  # converged to different minima: the landscape holds several, search on
        if low.label not in judged:  # each solution judged once; the curvature check first, as it costs less
            # (Pitot default, N = 7833: 26 ms against 0.63 s for the residual tests)
            judged[low.label] = curvature_holds(low.result.theta) and residuals_white(low.result.theta)
        if not judged[low.label]:
            return None
        return (f"stage 1's verdict is flat at its best candidate, but {len(converged)} starts converged to one "
                f"solution (J = {low.result.cost:.10g}), where the data determine xi2 (the curvature check, paper "
                "Eq. 18, holds there) and the residuals pass their tests, and no start ended lower; the further minima "
                "of the stage-1 ranking were not needed")

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
