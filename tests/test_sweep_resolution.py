"""Stage 1 judges whether its design resolves the landscape away from the best candidate (the
paper's Eq. 17 at the further local minima), sweeps again denser when it does not, and an
estimate from a landscape it could not resolve is never reported TRUSTED on agreeing starts.

The case: NIST StRD ENSO (certified values and residual sum of squares from NIST) with both
periods b4 and b7 boxed over three decades, the box of the random-box campaign
(``scripts/campaigns/random_boxes.py``, seed 20261231, box 17), where a 44 x 44 grid (log-uniform
over the boxes) is 5-8 months apart near the certified periods (44.3 and 26.9 months), wider
than their basins, and aliases into about a hundred shallow minima.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import casest
from casest.apps.nist import read_nist
from casest.errors import OptionError
from casest.two_stage.sweep.analysis import validity_conditions
from casest.two_stage.sweep.candidates import half_step, to_unit
from casest.two_stage.sweep.landscape import Landscape
from casest.status import TrustCode

#: the campaign's box 17 of ENSO for the two periods (months)
PERIOD_BOXES = {"b4": (1.285850341049943, 2290.138412070796), "b7": (1.006172077904716, 1996.831443412552)}


@pytest.fixture(scope="module")
def enso_wide():
    problem = read_nist(casest.bundled_data_dir("nist_strd", "ENSO.dat"), start=1)
    model = problem.model
    params = [replace(p, lb=PERIOD_BOXES[p.name][0], ub=PERIOD_BOXES[p.name][1], nominal=0.5 * sum(PERIOD_BOXES[p.name]),
                      prior=None, scale=None) if p.name in PERIOD_BOXES else p for p in model.parameters]
    boxed = casest.Model(params, model.signals, {o: model.h[i] for i, o in enumerate(model.output_names)},
                         name="ENSO, periods over three decades")
    return boxed, problem.data, float(problem.certified_rss)


def _rss(model, data, theta) -> float:
    return float(np.sum((data.outputs - model.predict(theta, data.signals)) ** 2))


def test_an_aliased_landscape_is_unresolved_and_its_estimate_not_trusted_on_agreeing_starts(enso_wide):
    model, data, _ = enso_wide
    once = casest.SweepSettings(resolve_work=0)
    landscape = casest.sweep(model, data, settings=once)
    assert landscape.verdict == "unresolved" and len(landscape.unresolved) >= 1
    assert "does not resolve the landscape" in landscape.reason
    # each listed minimum fails Eq. 17 over its own half step (recomputed here), the best passes
    params = [p for p in model.parameters if p.name in PERIOD_BOXES]
    design = landscape.candidates[:landscape.n_design]
    unit = to_unit(design, params)
    partition = casest.separate(model)
    for m in landscape.unresolved:
        step = half_step(design, unit, landscape.grid_shape, params, int(m))
        ratio = validity_conditions(model, partition, data, landscape.xi1[m], landscape.candidates[m], step)[0]
        assert ratio > casest.SweepSettings().linearization_tol
    assert landscape.linearization_ratio <= casest.SweepSettings().linearization_tol
    # the whole pipeline on that one sweep: wherever it ends, agreeing starts alone do not make it TRUSTED
    est = casest.estimate(model, data, sweep_settings=once)
    code, reason = est.conclusion()
    assert code is not TrustCode.TRUSTED
    assert "does not resolve its landscape" in reason


def test_swept_again_denser_it_reaches_the_certified_optimum(enso_wide):
    """With the default budget the sweep is repeated with four times the candidates (here up to
    127,449, the budget's limit); the estimate's RSS equals NIST's certified value to 1e-6."""
    model, data, certified_rss = enso_wide
    est = casest.estimate(model, data)
    assert est.landscape.n_design > casest.SweepSettings().n_candidates
    assert "swept again with" in est.landscape.reason
    assert _rss(model, data, est.theta) == pytest.approx(certified_rss, rel=1e-6)


def test_a_resolved_landscape_is_judged_as_before():
    """Misra1a (NIST, one smooth minimum): nothing unresolved, verdict unique, one sweep."""
    problem = read_nist(casest.bundled_data_dir("nist_strd", "Misra1a.dat"), start=1)
    landscape = casest.sweep(problem.model, problem.data)
    assert landscape.verdict == "unique" and len(landscape.unresolved) == 0
    assert landscape.n_design <= casest.SweepSettings().n_candidates


def test_the_unresolved_minima_survive_a_json_round_trip_and_bad_budgets_are_refused(enso_wide):
    model, data, _ = enso_wide
    landscape = casest.sweep(model, data, settings=casest.SweepSettings(resolve_work=0, n_candidates=400))
    again = Landscape.from_dict(landscape.to_dict())
    np.testing.assert_array_equal(again.unresolved, landscape.unresolved)
    assert again.unresolved.dtype.kind == "i"
    for bad in (-1.0, True, "1e8"):
        with pytest.raises(OptionError, match="resolve_work"):
            casest.SweepSettings(resolve_work=bad)
