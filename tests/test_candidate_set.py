"""The paper's feasible set of stage-1 candidates (Sec. II.C, Step 2): the epsilon-ball about the
nominal xi2 and the validity conditions Eq. 17-18 on every candidate.

Truths: the ball by the 2-norm of each candidate's distance to the nominal xi2, computed here; the
minimum of Tr[R] over a set taken by NumPy from the unrestricted landscape's own Tr[R]; Eq. 17-18 at
single candidates by ``validity_conditions`` (the best-candidate check the sweep already had).
"""

import os

import numpy as np
import pytest

import casest
from casest.two_stage.sweep.analysis import validity_conditions
from casest.two_stage.sweep.candidates import half_step, prior_density, to_unit


@pytest.fixture(scope="module")
def scalar2():
    m = casest.load_model_file("scalar2")
    model, data = m.model(), m.simulate(seed=0)
    return model, data, casest.separate(model)


def test_the_ball_keeps_the_best_within_epsilon_of_the_nominal_values(scalar2):
    """A radius that leaves the unrestricted best outside: the best is the smallest Tr[R] inside
    the ball, every candidate keeps its Tr[R], and the set survives a JSON round trip."""
    model, data, part = scalar2
    # one design throughout (resolve_work=0: a 20 x 20 grid of scalar 2 does not resolve its further minima)
    free = casest.sweep(model, data, part, casest.SweepSettings(n_candidates=400, max_refinements=0, resolve_work=0))
    centre = model.nominal[list(part.nonlinear_index)]
    distance = np.linalg.norm(free.candidates - centre, axis=1)
    radius = 0.5 * float(distance[free.best_index])
    ball = casest.sweep(model, data, part, casest.SweepSettings(n_candidates=400, max_refinements=0, radius=radius,
                                                               resolve_work=0))
    inside = distance < radius
    assert 0 < inside.sum() < len(inside) and not inside[free.best_index]
    np.testing.assert_array_equal(ball.in_set, inside)
    np.testing.assert_array_equal(ball.trace_R, free.trace_R)
    assert ball.best_index == int(np.flatnonzero(inside)[np.argmin(free.trace_R[inside])])
    assert "candidates compete" in ball.summary()
    np.testing.assert_array_equal(casest.Landscape.from_dict(ball.to_dict()).in_set, ball.in_set)


def test_every_candidate_checked_takes_the_best_that_satisfies_eq17_and_eq18(scalar2):
    """With a linearisation tolerance that the unrestricted best fails, validity='every' takes the
    smallest Tr[R] among the candidates that pass both conditions; each candidate with a smaller
    Tr[R] fails one of them (checked one by one)."""
    model, data, part = scalar2
    settings = dict(n_candidates=100, max_refinements=0, resolve_work=0)  # one 10 x 10 grid throughout
    free = casest.sweep(model, data, part, casest.SweepSettings(**settings))
    params = [model.parameters[i] for i in part.nonlinear_index]
    unit = to_unit(free.candidates, params)

    def conditions(k):
        step = half_step(free.candidates, unit, free.grid_shape, params, k)
        ratio, eig, _, _ = validity_conditions(model, part, data, free.xi1[k], free.candidates[k], step, free.R[k],
                                               prior_density(params, free.candidates[k]))
        return ratio, eig

    tol = 0.5 * conditions(free.best_index)[0]
    checked = casest.sweep(model, data, part, casest.SweepSettings(**settings, validity="every", linearization_tol=tol))
    best = checked.best_index
    assert best != free.best_index and checked.in_set[best]
    ratio, eig = conditions(best)
    assert ratio <= tol and eig >= 1e-8
    for k in np.flatnonzero(free.trace_R < free.trace_R[best]):
        ratio, eig = conditions(int(k))
        assert ratio > tol or eig < 1e-8, k


def test_an_empty_set_and_a_bad_radius_are_refused_with_the_fix(scalar2):
    model, data, part = scalar2
    with pytest.raises(casest.OptionError, match="S_xi2 is empty; widen SweepSettings.radius"):
        casest.sweep(model, data, part, casest.SweepSettings(n_candidates=100, validity="every",
                                                             linearization_tol=1e-12))
    for bad in (0.0, -1.0, float("nan"), "0.1", True):
        with pytest.raises(casest.OptionError, match="SweepSettings.radius must be a positive number"):
            casest.SweepSettings(radius=bad)
    with pytest.raises(casest.OptionError, match="validity"):
        casest.SweepSettings(validity="all")


@pytest.mark.parametrize("case", ["scalar2 with gaps", "Thurber"])
def test_the_batched_conditions_equal_the_one_by_one_check(case):
    """Eq. 17-18 at every candidate of a sweep, all at once (validity_batch.batched_conditions)
    against ``validity_conditions`` one candidate at a time (truth: the same formulas evaluated
    separately): ratios to 1e-9 relative, eigenvalues to 1e-12, every pass or fail the same. scalar2
    with outputs missing at every fifth sample (the mask), Thurber from NIST's file (7 parameters,
    ill-conditioned)."""
    from casest.apps.nist import read_nist
    from casest.problem.measurement import as_measurement
    from casest.two_stage.sweep.validity_batch import batched_applies, batched_conditions

    if case == "Thurber":
        problem = read_nist(os.path.join(os.path.dirname(__file__), "..", "data", "nist_strd", "Thurber.dat"))
        model, data = problem.model, problem.data
    else:
        m = casest.load_model_file("scalar2")
        model, data = m.model(), m.simulate(seed=4)
        outputs = data.outputs.copy()
        outputs[::5] = np.nan
        data = casest.Dataset.from_arrays(model, data.signals, outputs, missing="allow")
    part = casest.separate(model)
    land = casest.sweep(model, data, part, casest.SweepSettings(n_candidates=400, max_refinements=0, resolve_work=0))
    params = [model.parameters[i] for i in part.nonlinear_index]
    unit = to_unit(land.candidates, params)
    fits = np.flatnonzero(np.isfinite(land.trace_R))
    steps = np.array([half_step(land.candidates, unit, land.grid_shape, params, int(k)) for k in fits])
    measurement = as_measurement(model)
    assert batched_applies(measurement, data)
    ratio, eig = batched_conditions(measurement, part, data, land.xi1[fits], land.candidates[fits], steps)
    one_by_one = np.array([validity_conditions(measurement, part, data, land.xi1[k], land.candidates[k], steps[i])[:2]
                           for i, k in enumerate(fits)])
    np.testing.assert_allclose(ratio, one_by_one[:, 0], rtol=1e-9)
    np.testing.assert_allclose(eig, one_by_one[:, 1], rtol=0, atol=1e-12)
    passes = (ratio <= 0.05) & (eig >= 1e-8)
    np.testing.assert_array_equal(passes, (one_by_one[:, 0] <= 0.05) & (one_by_one[:, 1] >= 1e-8))
    assert 0 < passes.sum() < len(passes), passes.sum()  # the check separates candidates here
